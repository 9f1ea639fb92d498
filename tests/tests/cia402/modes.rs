//! Modes of operation 0x6060 / display 0x6061 / supported drive modes 0x6502 (IDX L5707-5748, L6735-6770;
//! Gamma L956-997; digest `shared/spec/cia402-device-control.md` §1.8), and mode changes while enabled
//! (decision documented in `firmware::cia402::modes`: on the fly at the next step, Gamma L607/L675 "dynamically
//! switchable"; held while a stop runs; bit 10 reported set on a change, Gamma L912).

use crate::support::*;
use firmware::cia402::{
    FaultClass, Mode, ModeUpdate, Motion, OptionCodes, State, Stop, StopRamp, StopThen, SUPPORTED_DRIVE_MODES,
};

#[test]
fn supported_modes_agree_with_the_dictionary() {
    // 0x6502 default and the 0x6060 value list of device.toml.
    assert_eq!(default_value(0x6502), i64::from(SUPPORTED_DRIVE_MODES));
    assert_eq!(SUPPORTED_DRIVE_MODES, 0x0000_03A5);
    let mut codes: Vec<i16> = Mode::ALL.iter().map(|m| i16::from(m.code())).collect();
    codes.insert(0, 0);
    // -2: the auto setup (PD4-E, the motor identification), a manufacturer mode outside 0x6502's CiA 402 bits.
    codes.insert(0, i16::from(Mode::AutoSetup.code()));
    assert_eq!(accepted_values(0x6060), codes, "0x6060 accepts -2 (auto setup), 0 (no change) and the supported modes");
    assert_eq!(Mode::AutoSetup.support_bit(), 0);
    // 0x6061 default is the machine's initial mode.
    let mut h = Harness::new();
    assert_eq!(default_value(0x6061), i64::from(h.step().mode.display));
    // Bit per mode (IDX/Gamma bit layout: 0 PP, 2 PV, 5 HM, 7 CSP, 8 CSV, 9 CST).
    let bits: Vec<u32> = Mode::ALL.iter().map(|m| m.support_bit().trailing_zeros()).collect();
    assert_eq!(bits, [0, 2, 5, 7, 8, 9]);
}

#[test]
fn every_i8_request_is_handled_without_panic() {
    for state in [State::SwitchOnDisabled, State::OperationEnabled, State::QuickStopActive] {
        for code in i8::MIN..=i8::MAX {
            let mut h = Harness::in_state(state, OptionCodes::DEFAULT);
            h.inputs.modes_of_operation = code;
            let out = h.step();
            match (code, Mode::from_code(code)) {
                (0, _) => assert_eq!(out.mode.update, ModeUpdate::Unchanged),
                (_, None) => {
                    assert_eq!(out.mode.update, ModeUpdate::Rejected(code));
                    assert_eq!(out.mode.display, 1, "unsupported request keeps the mode");
                }
                (_, Some(Mode::ProfilePosition)) => assert_eq!(out.mode.update, ModeUpdate::Unchanged),
                (_, Some(m)) if state == State::QuickStopActive => {
                    assert_eq!(out.mode.update, ModeUpdate::Deferred(m));
                    assert_eq!(out.mode.display, 1);
                }
                (_, Some(m)) => {
                    assert_eq!(out.mode.update, ModeUpdate::Changed { from: Mode::ProfilePosition, to: m });
                    assert_eq!(out.mode.display, code);
                }
            }
        }
    }
}

#[test]
fn mode_changes_on_the_fly_in_operation_enabled() {
    // Every ordered pair of supported modes switches at the next step while enabled, the drive staying in OE
    // and following set-points (the mode layer starts the new mode from the actual values).
    for from in Mode::ALL {
        for to in Mode::ALL {
            let mut h = Harness::in_state(State::OperationEnabled, OptionCodes::DEFAULT);
            h.inputs.modes_of_operation = from.code();
            h.step();
            h.inputs.modes_of_operation = to.code();
            let out = h.step();
            assert_eq!(out.state, State::OperationEnabled);
            assert_eq!(out.mode.active, to);
            assert_eq!(out.mode.display, to.code());
            assert_eq!(out.motion, Motion::Follow);
            if from != to {
                assert_eq!(out.mode.update, ModeUpdate::Changed { from, to });
            }
        }
    }
}

#[test]
fn mode_change_waits_for_a_running_stop() {
    // Disable operation with the slow-down ramp (0x605C = 1): the ramp is the active mode's deceleration, so a
    // new mode is held until the stop completed.
    let mut h = Harness::in_state(State::OperationEnabled, OptionCodes::DEFAULT);
    h.cw(0x0007);
    h.inputs.modes_of_operation = 9;
    for _ in 0..3 {
        let out = h.step();
        assert_eq!(out.mode.update, ModeUpdate::Deferred(Mode::CyclicSyncVelocity));
        assert_eq!(out.mode.display, 1);
    }
    h.inputs.standstill = true;
    let out = h.step();
    assert_eq!(out.state, State::SwitchedOn);
    let out = h.step();
    assert_eq!(out.mode.update, ModeUpdate::Changed { from: Mode::ProfilePosition, to: Mode::CyclicSyncVelocity });
    // Fault reaction: held too; in Fault (disabled) it applies.
    let mut h = Harness::in_state(State::OperationEnabled, OptionCodes::DEFAULT);
    h.raise(FaultClass::Reaction);
    h.inputs.modes_of_operation = 8;
    assert_eq!(h.step().mode.update, ModeUpdate::Deferred(Mode::CyclicSyncPosition));
    h.inputs.standstill = true;
    assert_eq!(h.step().state, State::Fault);
    assert_eq!(h.step().mode.display, 8);
}

#[test]
fn halt_applies_in_profile_and_homing_modes_only() {
    // IDX Table 6-116: bit 8 halt in PPM, PVM, HMM; nothing in CSP/CSV/CST.
    for mode in Mode::ALL {
        let mut h = Harness::in_state(State::OperationEnabled, OptionCodes::DEFAULT);
        h.inputs.modes_of_operation = mode.code();
        h.step();
        let out = h.cw(0x010F);
        let expected = if mode.halt_applies() {
            Motion::Stop(Stop { ramp: StopRamp::SlowDown, then: StopThen::StayEnabled })
        } else {
            Motion::Follow
        };
        assert_eq!(out.motion, expected, "{mode:?}");
        assert_eq!(mode.halt_applies(), !mode.is_cyclic());
    }
}

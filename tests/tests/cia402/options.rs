//! The stop option codes 0x605A, 0x605B, 0x605C, 0x605D, 0x605E and 0x6007: every value the dictionary accepts
//! (`firmware/device.toml`, read from the generated table) and every value the seeds define, against the
//! meaning the seeds give it (digest `shared/spec/cia402-device-control.md` §1.6: 0x605A Gamma Table 6-7
//! L999-1019, IDX L5623-5640; 0x605B/0x605C IDX L5642-5680; 0x605D Gamma Table 6-8 L1021-1036; 0x605E IDX
//! L5682-5705; 0x6007 IDX L5488-5510, E3 L6553-6580), and the standstill gating of IDX 0x30E0 (L4827-4898).

use crate::support::*;
use firmware::cia402::{
    Brake, Config, FaultClass, Motion, OptionCodes, PowerStage, State, Stop, StopRamp, StopThen, Ticks, Transition,
};
use Transition::*;

/// 0x605A: (ramp or None for "disable drive function", stays in QSA) per Gamma Table 6-7 (4 and 8 CiA 402
/// voltage limit, not in the seeds).
fn quick_stop_meaning(v: i16) -> (Option<StopRamp>, bool) {
    match v {
        0 => (None, false),
        1 => (Some(StopRamp::SlowDown), false),
        2 => (Some(StopRamp::QuickStop), false),
        3 => (Some(StopRamp::CurrentLimit), false),
        4 => (Some(StopRamp::VoltageLimit), false),
        5 => (Some(StopRamp::SlowDown), true),
        6 => (Some(StopRamp::QuickStop), true),
        7 => (Some(StopRamp::CurrentLimit), true),
        8 => (Some(StopRamp::VoltageLimit), true),
        _ => unreachable!(),
    }
}

#[test]
fn dictionary_values_are_the_ones_tested() {
    assert_eq!(accepted_values(0x605A), [0, 1, 2, 5, 6]);
    assert_eq!(accepted_values(0x605B), [0, 1]);
    assert_eq!(accepted_values(0x605C), [0, 1]);
    assert_eq!(accepted_values(0x605D), [1, 2]);
    assert_eq!(accepted_values(0x605E), [0, 1, 2]);
    assert_eq!(accepted_values(0x6007), [1, 2, 3]);
    // The machine's defaults are the dictionary's.
    let d = OptionCodes::DEFAULT;
    assert_eq!(default_value(0x605A), i64::from(d.quick_stop));
    assert_eq!(default_value(0x605B), i64::from(d.shutdown));
    assert_eq!(default_value(0x605C), i64::from(d.disable_operation));
    assert_eq!(default_value(0x605D), i64::from(d.halt));
    assert_eq!(default_value(0x605E), i64::from(d.fault_reaction));
    assert_eq!(default_value(0x6007), i64::from(d.abort_connection));
}

#[test]
fn quick_stop_option_code_every_value() {
    let mut values = accepted_values(0x605A);
    values.extend([3, 4, 7, 8]);
    for v in values {
        let (ramp, stays) = quick_stop_meaning(v);
        let mut h = Harness::in_state(State::OperationEnabled, OptionCodes { quick_stop: v, ..OptionCodes::DEFAULT });
        let out = h.cw(0x000B);
        expect_transition(&out, T11);
        // Statusword: QSA pattern, bit 5 = 0 while reacting (Gamma L910).
        assert_eq!(out.statusword.0 & 0x6F, 0x07, "605A={v}");
        match ramp {
            None => {
                // 0: drive function off at once, then 12 to SOD.
                assert_eq!(out.power, PowerStage::OFF, "605A={v}");
                assert_eq!(out.motion, Motion::Disabled);
                assert_eq!(out.brake, Brake::Engaged);
                let out = h.step();
                expect_transition(&out, T12);
                assert_eq!(out.power, PowerStage::OFF);
                continue;
            }
            Some(ramp) => {
                let then = if stays { StopThen::StayInQuickStop } else { StopThen::Disable };
                assert_eq!(out.power, PowerStage::DRIVING, "605A={v}");
                assert_eq!(out.motion, Motion::Stop(Stop { ramp, then }), "605A={v}");
                assert_eq!(out.brake, Brake::Released);
            }
        }
        // While ramping: «Enable operation» does nothing (the stop is processed completely first), bit 10 = 0.
        for _ in 0..3 {
            let out = h.cw(0x000F);
            assert_eq!((out.state, out.transition), (State::QuickStopActive, None), "605A={v}");
            assert_eq!(out.statusword.0 & 0x0400, 0);
            assert!(out.power.torque_allowed());
        }
        h.inputs.controlword = firmware::cia402::Controlword(0x000B);
        h.inputs.standstill = true;
        let out = h.step();
        if stays {
            // 5..8: stay in QSA, holding, bit 10 set once halted (Gamma L912); 16 on «Enable operation».
            assert_eq!((out.state, out.transition), (State::QuickStopActive, None), "605A={v}");
            assert_eq!(out.motion, Motion::Hold);
            assert!(out.power.torque_allowed());
            assert_ne!(out.statusword.0 & 0x0400, 0);
            for _ in 0..3 {
                assert_eq!(h.step().state, State::QuickStopActive);
            }
            let out = h.cw(0x000F);
            expect_transition(&out, T16);
            assert_eq!(out.motion, Motion::Follow);
        } else {
            // 1..4: transit into SOD (Gamma L1011-1013) without a command; 16 never possible.
            expect_transition(&out, T12);
            assert_eq!(out.power, PowerStage::OFF);
            assert_eq!(out.brake, Brake::Engaged);
            assert_eq!(h.cw(0x000F).state, State::SwitchOnDisabled);
        }
    }
}

#[test]
fn quick_stop_active_disable_voltage_is_12() {
    let mut h = Harness::in_state(State::QuickStopActive, OptionCodes::DEFAULT);
    let out = h.cw(0x0000);
    expect_transition(&out, T12);
    assert_eq!(out.power, PowerStage::OFF);
}

/// Runs a stop transition from OE with `cw` and checks the option's behaviour: immediate (`ramp` None) or
/// ramping in OE until standstill.
fn check_stop_from_oe(options: OptionCodes, cw: u16, t: Transition, ramp: Option<StopRamp>) {
    let mut h = Harness::in_state(State::OperationEnabled, options);
    let out = h.cw(cw);
    match ramp {
        None => {
            expect_transition(&out, t);
            assert!(!out.power.torque_allowed(), "{options:?} {cw:#06x}");
            assert_eq!(out.motion, Motion::Disabled);
            assert_eq!(out.brake, Brake::Engaged);
        }
        Some(ramp) => {
            // IDX 0x30E0: the transition is not performed until standstill; the drive reports OE meanwhile.
            for _ in 0..10 {
                let out = h.step();
                assert_eq!((out.state, out.transition, out.pending), (State::OperationEnabled, None, Some(t)));
                assert_eq!(out.statusword.0 & 0x6F, 0x27);
                assert_eq!(out.motion, Motion::Stop(Stop { ramp, then: StopThen::Disable }));
                assert!(out.power.torque_allowed());
            }
            h.inputs.standstill = true;
            let out = h.step();
            expect_transition(&out, t);
            assert!(!out.power.torque_allowed());
            assert_eq!(out.brake, Brake::Engaged);
        }
    }
    let expected_power = if t == T5 { PowerStage::SECTION_ON } else { PowerStage::OFF };
    assert_eq!(h.machine.power(), expected_power, "transition {}", t.number());
}

#[test]
fn shutdown_option_code_every_value() {
    // 0x605B applies to 8 (Shutdown) and 9 (Disable voltage; IDX L440).
    for v in accepted_values(0x605B) {
        let ramp = match v {
            0 => None,
            1 => Some(StopRamp::SlowDown),
            _ => unreachable!(),
        };
        let options = OptionCodes { shutdown: v, ..OptionCodes::DEFAULT };
        check_stop_from_oe(options, 0x0006, T8, ramp);
        check_stop_from_oe(options, 0x0000, T9, ramp);
    }
}

#[test]
fn disable_operation_option_code_every_value() {
    for v in accepted_values(0x605C) {
        let ramp = match v {
            0 => None,
            1 => Some(StopRamp::SlowDown),
            _ => unreachable!(),
        };
        check_stop_from_oe(OptionCodes { disable_operation: v, ..OptionCodes::DEFAULT }, 0x0007, T5, ramp);
    }
}

#[test]
fn halt_option_code_every_value() {
    let mut values = accepted_values(0x605D);
    values.extend([3, 4]);
    for v in values {
        let ramp = match v {
            1 => StopRamp::SlowDown,
            2 => StopRamp::QuickStop,
            3 => StopRamp::CurrentLimit,
            4 => StopRamp::VoltageLimit,
            _ => unreachable!(),
        };
        // PPM (the initial mode): halt stops the axis and the drive stays in OE (Gamma Table 6-8).
        let mut h = Harness::in_state(State::OperationEnabled, OptionCodes { halt: v, ..OptionCodes::DEFAULT });
        for _ in 0..5 {
            let out = h.cw(0x010F);
            assert_eq!((out.state, out.transition), (State::OperationEnabled, None));
            assert_eq!(out.motion, Motion::Stop(Stop { ramp, then: StopThen::StayEnabled }), "605D={v}");
            assert!(out.power.torque_allowed());
        }
        h.inputs.standstill = true;
        assert_eq!(h.step().state, State::OperationEnabled, "halt never leaves OE");
        // Releasing halt resumes the commanded motion (Gamma L882).
        assert_eq!(h.cw(0x000F).motion, Motion::Follow);
    }
}

#[test]
fn fault_reaction_option_code_every_value() {
    for v in accepted_values(0x605E) {
        let ramp = match v {
            0 => None,
            1 => Some(StopRamp::SlowDown),
            2 => Some(StopRamp::QuickStop),
            _ => unreachable!(),
        };
        let options = OptionCodes { fault_reaction: v, ..OptionCodes::DEFAULT };
        let mut h = Harness::in_state(State::OperationEnabled, options);
        let out = h.raise(FaultClass::Reaction);
        expect_transition(&out, T13);
        assert_eq!(out.statusword.0 & 0x4F, 0x0F);
        match ramp {
            None => {
                assert_eq!(out.power, PowerStage::OFF, "605E={v}");
                expect_transition(&h.step(), T14);
            }
            Some(ramp) => {
                assert_eq!(out.motion, Motion::Stop(Stop { ramp, then: StopThen::Disable }), "605E={v}");
                assert!(out.power.torque_allowed());
                // Voltage enabled while the reaction runs (E3 "FRA (enabled)" x001 1111).
                assert_ne!(out.statusword.0 & 0x10, 0);
                for _ in 0..5 {
                    let out = h.cw(0x000F);
                    assert_eq!((out.state, out.pending), (State::FaultReactionActive, Some(T14)));
                }
                h.inputs.standstill = true;
                let out = h.step();
                expect_transition(&out, T14);
                assert_eq!(out.power, PowerStage::OFF);
            }
        }
        // A critical (class "d") fault disables at once whatever 0x605E says (IDX L7030-7036).
        let mut h = Harness::in_state(State::OperationEnabled, options);
        let out = h.raise(FaultClass::Critical);
        expect_transition(&out, T13);
        assert_eq!(out.power, PowerStage::OFF);
        expect_transition(&h.step(), T14);
        // A fault while no torque is applied: nothing to stop (E3 "FRA (disabled)").
        let mut h = Harness::in_state(State::SwitchedOn, options);
        let out = h.raise(FaultClass::Reaction);
        expect_transition(&out, T13);
        assert_eq!(out.power, PowerStage::OFF);
    }
}

#[test]
fn critical_fault_ends_a_fault_reaction_ramp() {
    let mut h =
        Harness::in_state(State::FaultReactionActive, OptionCodes { fault_reaction: 2, ..OptionCodes::DEFAULT });
    assert!(h.step().power.torque_allowed());
    let out = h.raise(FaultClass::Critical);
    assert_eq!(out.power, PowerStage::OFF);
    expect_transition(&h.step(), T14);
}

#[test]
fn abort_connection_option_code_every_value() {
    for v in accepted_values(0x6007) {
        // 0x605A = 2 (quick-stop ramp then SOD) and 0x605B = 1 so that 2 and 3 are told apart by the ramp.
        let options = OptionCodes { abort_connection: v, quick_stop: 2, shutdown: 1, ..OptionCodes::DEFAULT };
        let mut h = Harness::in_state(State::OperationEnabled, options);
        h.inputs.connection_lost = true;
        let out = h.step();
        match v {
            1 => {
                // A fault (the CiA 402 meaning, device.toml note), stopping per 0x605E = 2.
                expect_transition(&out, T13);
                assert_eq!(out.motion, Motion::Stop(Stop { ramp: StopRamp::QuickStop, then: StopThen::Disable }));
                h.inputs.standstill = true;
                expect_transition(&h.step(), T14);
                // The cause is present while the connection is lost: reset refused.
                h.cw(0x0000);
                assert!(h.cw(0x0080).fault_reset_refused);
                h.inputs.connection_lost = false;
                h.cw(0x0000);
                expect_transition(&h.cw(0x0080), T15);
            }
            2 => {
                // «Disable voltage»: transition 9 with 0x605B's slow-down ramp; the stale 0x000F is overridden.
                assert_eq!(out.pending, Some(T9));
                assert_eq!(out.motion, Motion::Stop(Stop { ramp: StopRamp::SlowDown, then: StopThen::Disable }));
                h.inputs.standstill = true;
                expect_transition(&h.step(), T9);
                // Still lost: the master's 0x0006 does not bring the drive back.
                assert_eq!(h.cw(0x0006).state, State::SwitchOnDisabled);
            }
            3 => {
                // «Quick stop»: transition 11 with 0x605A.
                expect_transition(&out, T11);
                assert_eq!(out.motion, Motion::Stop(Stop { ramp: StopRamp::QuickStop, then: StopThen::Disable }));
                h.inputs.standstill = true;
                expect_transition(&h.step(), T12);
            }
            _ => unreachable!(),
        }
    }
}

#[test]
fn reserved_values_act_as_the_dictionary_defaults() {
    // A value the dictionary refuses (a bypassed dictionary) is read as the object's default, never a panic.
    let reserved = OptionCodes {
        quick_stop: -1,
        shutdown: 7,
        disable_operation: i16::MIN,
        halt: 0,
        fault_reaction: -1,
        abort_connection: 0,
    };
    let d = OptionCodes::DEFAULT;
    assert_eq!(reserved.quick_stop(), d.quick_stop());
    assert_eq!(reserved.shutdown(), d.shutdown());
    assert_eq!(reserved.disable_operation(), d.disable_operation());
    assert_eq!(reserved.halt(), d.halt());
    assert_eq!(reserved.fault_reaction(), d.fault_reaction());
    assert_eq!(reserved.abort_connection(), d.abort_connection());
    // 0x605A reserved -> 6: stays in QSA.
    let mut h = Harness::in_state(State::QuickStopActive, reserved);
    expect_transition(&h.cw(0x000F), T16);
}

#[test]
fn standstill_timeout_completes_a_stop() {
    // IDX 0x30E0:03 default 1000 ms = 2500 tier-2 periods.
    let mut h =
        Harness::in_state(State::OperationEnabled, OptionCodes { disable_operation: 1, ..OptionCodes::DEFAULT });
    assert_eq!(h.cw(0x0007).pending, Some(T5));
    let outs = h.steps(2_600);
    let at = outs.iter().position(|o| o.transition == Some(T5)).expect("timeout");
    assert_eq!(at + 1, 2_500);
    // Without a timeout the stop waits for standstill.
    let config = Config { standstill_timeout: None, ..Config::DEFAULT };
    let mut h = Harness::with_config(config);
    h.step();
    h.cw(0x0006);
    h.cw(0x000F);
    h.inputs.calibration_done = true;
    h.step();
    expect_transition(&h.step(), T4);
    h.cw(0x0007);
    assert!(h.steps(10_000).iter().all(|o| o.state == State::OperationEnabled));
}

#[test]
fn brake_engages_before_the_power_goes_off_and_releases_before_set_points() {
    // IDX 0x3158: rise time (engage) and fall time (release), 10 ms = 25 periods.
    let config = Config { brake_engage_delay: Ticks(25), brake_release_delay: Ticks(25), ..Config::DEFAULT };
    let mut h = Harness::with_config(config);
    h.step();
    h.cw(0x0006);
    h.cw(0x000F);
    h.inputs.calibration_done = true;
    h.step();
    let out = h.step();
    expect_transition(&out, T4);
    assert_eq!((out.brake, out.motion), (Brake::Released, Motion::Hold));
    let outs = h.steps(30);
    let follow = outs.iter().position(|o| o.motion == Motion::Follow).expect("follows after the release time");
    assert_eq!(follow + 1, 25, "set-points followed 25 periods after transition 4");
    // Shutdown with a ramp: at standstill the brake engages with the motor held, then the power goes off.
    h.inputs.options.shutdown = 1;
    h.cw(0x0006);
    h.inputs.standstill = true;
    let out = h.step();
    assert_eq!((out.state, out.brake, out.motion), (State::OperationEnabled, Brake::Engaged, Motion::Hold));
    assert!(out.power.torque_allowed());
    let outs = h.steps(30);
    let off = outs.iter().position(|o| o.transition == Some(T8)).expect("8 after the rise time");
    assert_eq!(off + 1, 25);
    assert!(outs[..off].iter().all(|o| o.brake == Brake::Engaged && o.power.torque_allowed()));
}

//! The CiA 402 state machine against its transition table: every (state, controlword command) pair, with the
//! actions of each transition.
//!
//! Expected table written out from the seeds (digest `shared/spec/cia402-device-control.md` §1.2-1.3):
//! - transitions and their from/to states: IDX Table 2-6 L416-449 (E3 Table 3-5 L434-468, Gamma Figure 6-1);
//! - command bit patterns and their transitions: IDX Table 2-7 L451-467 (Shutdown `0xxx x110` 2, 6, 8; Switch on
//!   `0xxx x111` 3; Switch on & Enable `0xxx 1111` 3 (+4); Disable voltage `0xxx xx0x` 7, 9, 10, 12; Quick stop
//!   `0xxx x01x` 11 — E3 L469-488 and Gamma L860-876 add 7, 10; Disable operation `0xxx 0111` 5; Enable operation
//!   `0xxx 1111` 4, 16; Fault reset `0 -> 1` of bit 7: 15);
//! - transition 16 only with 0x605A = 5..8 (Gamma L834), so QSA is entered here with 0x605A = 6 (IDX default).
//!
//! A command with no transition in a state leaves the state unchanged.

use crate::support::*;
use firmware::cia402::{
    Brake, Command, Controlword, FaultClass, Motion, OptionCodes, PowerStage, State, Statusword, Transition,
};

/// The command columns of the table: the five bit patterns of bits 0..3 (named by the command they are outside
/// OE) and the fault-reset edge.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Col {
    /// `x110`.
    Shutdown,
    /// `0111`: Switch on / Disable operation.
    SwitchOn,
    /// `1111`: Switch on & Enable operation / Enable operation.
    SwitchOnEnable,
    /// `xx0x`.
    DisableVoltage,
    /// `x01x`.
    QuickStop,
    /// Bit 7 rising, bits 0..3 as the state's holding controlword.
    FaultReset,
}

const COLS: [Col; 6] =
    [Col::Shutdown, Col::SwitchOn, Col::SwitchOnEnable, Col::DisableVoltage, Col::QuickStop, Col::FaultReset];

use Transition::*;

/// The expected table (IDX Tables 2-6 and 2-7, E3/Gamma for Quick stop 7 and 10). `None`: no transition.
fn expected(state: State, col: Col) -> Option<Transition> {
    use Col::*;
    use State::*;
    match (state, col) {
        (NotReadyToSwitchOn, _) => None,
        (SwitchOnDisabled, Shutdown) => Some(T2),
        (SwitchOnDisabled, _) => None,
        (ReadyToSwitchOn, SwitchOn | SwitchOnEnable) => Some(T3),
        (ReadyToSwitchOn, DisableVoltage | QuickStop) => Some(T7),
        (ReadyToSwitchOn, _) => None,
        (SwitchedOn, Shutdown) => Some(T6),
        (SwitchedOn, SwitchOnEnable) => Some(T4),
        (SwitchedOn, DisableVoltage | QuickStop) => Some(T10),
        (SwitchedOn, _) => None,
        (OperationEnabled, Shutdown) => Some(T8),
        (OperationEnabled, SwitchOn) => Some(T5),
        (OperationEnabled, DisableVoltage) => Some(T9),
        (OperationEnabled, QuickStop) => Some(T11),
        (OperationEnabled, _) => None,
        (QuickStopActive, SwitchOnEnable) => Some(T16),
        (QuickStopActive, DisableVoltage) => Some(T12),
        (QuickStopActive, _) => None,
        (FaultReactionActive, _) => None,
        (Fault, FaultReset) => Some(T15),
        (Fault, _) => None,
    }
}

/// The controlword the harness leaves in each state (it keeps the state).
fn holding_controlword(state: State) -> u16 {
    match state {
        State::ReadyToSwitchOn => 0x0006,
        State::SwitchedOn => 0x0007,
        State::OperationEnabled | State::FaultReactionActive => 0x000F,
        State::QuickStopActive => 0x000B,
        State::NotReadyToSwitchOn | State::SwitchOnDisabled | State::Fault => 0x0000,
    }
}

/// The column of a controlword with bit 7 steady, by the IDX patterns (an oracle independent of the decoder).
fn column_of(cw: u16) -> Col {
    let nibble = cw & 0x000F;
    if nibble & 0b0010 == 0 {
        Col::DisableVoltage
    } else if nibble & 0b0110 == 0b0010 {
        Col::QuickStop
    } else if nibble & 0b0111 == 0b0110 {
        Col::Shutdown
    } else if nibble == 0b0111 {
        Col::SwitchOn
    } else {
        Col::SwitchOnEnable
    }
}

/// Applies `cw` in `state` and lets the transition finish: the calibration finishes, the motor is at standstill
/// (except in FRA, where standstill would end the fault reaction by itself). Returns the first transition
/// completed within 20 steps and the state right after it (or the state after 20 steps).
fn apply(state: State, cw: u16) -> (Option<Transition>, State) {
    let mut h = Harness::in_state(state, OptionCodes::DEFAULT);
    h.inputs.calibration_done = false;
    h.inputs.standstill = state != State::FaultReactionActive;
    h.inputs.controlword = Controlword(cw);
    for i in 0..20 {
        let out = h.step();
        if let Some(t) = out.transition {
            return (Some(t), out.state);
        }
        if out.start_current_calibration {
            assert_eq!(i, 0);
            h.inputs.calibration_done = true;
        }
    }
    (None, h.machine.state())
}

#[test]
fn every_state_and_command_follows_the_transition_table() {
    // Bits 4..6, 8, 9 and 15 do not change the device-control command; bit 7 steady at 1 neither.
    let high_bits = [0x0000u16, 0x0010, 0x0070, 0x0100, 0x0200, 0x8000, 0x837F & !0x000F & !0x0080];
    let mut checked = 0;
    for state in State::ALL {
        for col in COLS {
            let want = expected(state, col);
            let cws: Vec<u16> = if col == Col::FaultReset {
                vec![holding_controlword(state) | 0x0080]
            } else {
                (0u16..16).filter(|n| column_of(*n) == col).flat_map(|n| high_bits.iter().map(move |h| n | h)).collect()
            };
            for cw in cws {
                let (got, after) = apply(state, cw);
                assert_eq!(got, want, "state {state:?}, command {col:?} (cw {cw:#06x})");
                match want {
                    Some(t) => {
                        assert_eq!(after, t.target(), "{state:?} {col:?} {cw:#06x}");
                        assert!(t.source().is_none_or(|s| s == state));
                    }
                    None => assert_eq!(after, state, "{state:?} {col:?} {cw:#06x}"),
                }
                checked += 1;
            }
        }
    }
    assert!(checked > 8 * 5 * 7);
}

#[test]
fn steady_bit7_does_not_mask_commands() {
    // With bit 7 held at 1 (no edge), Quick stop and Disable voltage still act (the patterns' bit 7 = 0 is read
    // as "no reset edge"); cf. module docs of firmware::cia402::controlword.
    let mut h = Harness::in_state(State::OperationEnabled, OptionCodes::DEFAULT);
    h.cw(0x008F);
    let out = h.cw(0x008B);
    expect_transition(&out, T11);
}

#[test]
fn reset_edge_with_zero_low_bits_outside_fault_is_disable_voltage() {
    // 0x0080 after 0x000F in OE: no fault to reset; bits 0..3 = 0000 are «Disable voltage» -> 9.
    let mut h = Harness::in_state(State::OperationEnabled, OptionCodes { shutdown: 0, ..OptionCodes::DEFAULT });
    expect_transition(&h.cw(0x0080), T9);
}

#[test]
fn commands_decode_against_the_state() {
    let p = Controlword(0);
    assert_eq!(Controlword(0x0007).command(p, State::OperationEnabled), Command::DisableOperation);
    assert_eq!(Controlword(0x0007).command(p, State::ReadyToSwitchOn), Command::SwitchOn);
    assert_eq!(Controlword(0x000F).command(p, State::QuickStopActive), Command::EnableOperation);
    assert_eq!(Controlword(0x000F).command(p, State::ReadyToSwitchOn), Command::SwitchOnAndEnableOperation);
    assert_eq!(Controlword(0x0080).command(p, State::Fault), Command::FaultReset);
}

#[test]
fn statusword_reports_each_state_as_idx_table_2_5() {
    // IDX L403-410; bit 4 (voltage enabled) is the power section, bit 9 remote (the harness is remote).
    let cases = [
        (State::NotReadyToSwitchOn, 0x0200),
        (State::SwitchOnDisabled, 0x0040 | 0x0200),
        (State::ReadyToSwitchOn, 0x0021 | 0x0200),
        (State::SwitchedOn, 0x0023 | 0x0010 | 0x0200),
        (State::OperationEnabled, 0x0027 | 0x0010 | 0x0200),
        // QSA holding after the stop: bit 10 set (Gamma L912).
        (State::QuickStopActive, 0x0007 | 0x0010 | 0x0200 | 0x0400),
        (State::FaultReactionActive, 0x000F | 0x0010 | 0x0200),
        (State::Fault, 0x0008 | 0x0200),
    ];
    for (state, sw) in cases {
        let mut h = Harness::in_state(state, OptionCodes::DEFAULT);
        let out = h.step();
        assert_eq!(out.state, state);
        assert_eq!(out.statusword, Statusword(sw), "{state:?}: {:#06x}", out.statusword.0);
        assert_eq!(out.statusword.state(), Some(state));
    }
}

#[test]
fn typical_master_sequence_reaches_operation_enabled() {
    // E4 L7378-7394: 0x0006 Shutdown, then 0x000F Switch on & Enable operation: 2, 3 (automatic 4).
    let mut h = Harness::new();
    expect_transition(&h.step(), T1);
    expect_transition(&h.cw(0x0006), T2);
    let out = h.cw(0x000F);
    assert_eq!(out.transition, None);
    assert_eq!(out.pending, Some(T3));
    assert!(out.start_current_calibration);
    // Calibration runs: power section on (50 % duty), no torque, statusword still RTSO (with voltage enabled).
    assert_eq!(out.power, PowerStage::SECTION_ON);
    assert_eq!(out.state, State::ReadyToSwitchOn);
    for _ in 0..5 {
        let out = h.step();
        assert_eq!(out.state, State::ReadyToSwitchOn);
        assert!(!out.start_current_calibration, "calibration is requested once");
    }
    h.inputs.calibration_done = true;
    let out = h.step();
    expect_transition(&out, T3);
    assert_eq!(out.power, PowerStage::SECTION_ON);
    assert_eq!(out.motion, Motion::Disabled);
    let out = h.step();
    expect_transition(&out, T4);
    assert_eq!(out.power, PowerStage::DRIVING);
    assert_eq!(out.motion, Motion::Follow);
    assert_eq!(out.brake, Brake::Released);
    assert_eq!(out.statusword.0 & 0x6F, 0x27);
}

#[test]
fn transition_actions_on_the_power_stage() {
    // 6 (SO -> RTSO) disables the power section; 7, 10 leave everything off; 2 does nothing to power.
    let mut h = Harness::in_state(State::SwitchedOn, OptionCodes::DEFAULT);
    let out = h.cw(0x0006);
    expect_transition(&out, T6);
    assert_eq!(out.power, PowerStage::OFF);
    let out = h.cw(0x0002);
    expect_transition(&out, T7);
    assert_eq!(out.power, PowerStage::OFF);
    let mut h = Harness::in_state(State::SwitchedOn, OptionCodes::DEFAULT);
    let out = h.cw(0x0000);
    expect_transition(&out, T10);
    assert_eq!(out.power, PowerStage::OFF);
    assert_eq!(out.brake, Brake::Engaged);
}

#[test]
fn calibration_waits_and_fault_aborts_it() {
    let mut h = Harness::in_state(State::ReadyToSwitchOn, OptionCodes::DEFAULT);
    assert!(h.cw(0x0007).start_current_calibration);
    // Commands wait while transition 3 runs (IDX L424).
    let out = h.cw(0x0000);
    assert_eq!((out.state, out.transition, out.pending), (State::ReadyToSwitchOn, None, Some(T3)));
    // A calibration failure is a fault: 13 at once, power off, then 14.
    let out = h.raise(FaultClass::Reaction);
    expect_transition(&out, T13);
    assert_eq!(out.power, PowerStage::OFF);
    expect_transition(&h.step(), T14);
}

#[test]
fn not_ready_to_switch_on_waits_for_initialisation() {
    let mut h = Harness::in_state(State::NotReadyToSwitchOn, OptionCodes::DEFAULT);
    for cw in [0x0006, 0x000F, 0x0080] {
        let out = h.cw(cw);
        assert_eq!((out.state, out.transition), (State::NotReadyToSwitchOn, None));
    }
    h.inputs.initialized = true;
    expect_transition(&h.step(), T1);
}

#[test]
fn fault_from_every_state_is_transition_13_and_fault_is_left_only_by_15() {
    for state in State::ALL {
        let mut h = Harness::in_state(state, OptionCodes::DEFAULT);
        let out = h.raise(FaultClass::Reaction);
        match state {
            State::FaultReactionActive | State::Fault => {
                assert_eq!((out.state, out.transition), (state, None));
                continue;
            }
            _ => expect_transition(&out, T13),
        }
        h.inputs.standstill = true;
        let out = h.steps(3).into_iter().find(|o| o.transition.is_some()).expect("14");
        expect_transition(&out, T14);
        // Present: refused, whatever the controlword.
        h.cw(0x0000);
        let out = h.cw(0x0080);
        assert!(out.fault_reset_refused);
        assert_eq!((out.state, out.transition), (State::Fault, None));
        for cw in [0x0006, 0x0007, 0x000F, 0x0000] {
            assert_eq!(h.cw(cw).state, State::Fault);
        }
        // Cleared: a new rising edge resets; a held bit 7 does not.
        assert!(h.cw(0x0080).fault_reset_refused);
        h.inputs.fault.present = false;
        assert_eq!(h.cw(0x0080).state, State::Fault, "no edge: bit 7 was already 1");
        h.cw(0x0000);
        expect_transition(&h.cw(0x0080), T15);
    }
}

#[test]
fn reset_is_transition_0() {
    let mut h = Harness::in_state(State::OperationEnabled, OptionCodes::DEFAULT);
    assert_eq!(h.machine.reset(), T0);
    assert_eq!(h.machine.state(), State::NotReadyToSwitchOn);
    assert_eq!(h.machine.power(), PowerStage::OFF);
}

#[test]
fn transition_numbers_sources_and_targets() {
    for (n, t) in Transition::ALL.iter().enumerate() {
        assert_eq!(usize::from(t.number()), n);
    }
    // IDX Table 2-6.
    let table = [
        (T1, Some(State::NotReadyToSwitchOn), State::SwitchOnDisabled),
        (T2, Some(State::SwitchOnDisabled), State::ReadyToSwitchOn),
        (T3, Some(State::ReadyToSwitchOn), State::SwitchedOn),
        (T4, Some(State::SwitchedOn), State::OperationEnabled),
        (T5, Some(State::OperationEnabled), State::SwitchedOn),
        (T6, Some(State::SwitchedOn), State::ReadyToSwitchOn),
        (T7, Some(State::ReadyToSwitchOn), State::SwitchOnDisabled),
        (T8, Some(State::OperationEnabled), State::ReadyToSwitchOn),
        (T9, Some(State::OperationEnabled), State::SwitchOnDisabled),
        (T10, Some(State::SwitchedOn), State::SwitchOnDisabled),
        (T11, Some(State::OperationEnabled), State::QuickStopActive),
        (T12, Some(State::QuickStopActive), State::SwitchOnDisabled),
        (T13, None, State::FaultReactionActive),
        (T14, Some(State::FaultReactionActive), State::Fault),
        (T15, Some(State::Fault), State::SwitchOnDisabled),
        (T16, Some(State::QuickStopActive), State::OperationEnabled),
    ];
    for (t, from, to) in table {
        assert_eq!((t.source(), t.target()), (from, to), "transition {}", t.number());
    }
}

//! Properties of the CiA 402 state machine over random input sequences (controlwords, modes, option codes,
//! fault events, connection loss, standstill and calibration reports):
//! - it never panics, whatever the `u16` controlword, `i8` mode or `i16` option codes;
//! - every state change is a reported transition whose from/to states are those of IDX Table 2-6 (L416-449);
//! - Fault is only left through transition 15, and only when no fault is present (IDX L446, Gamma L850);
//! - torque (power stage on and controllers enabled) is only allowed in OE, in QSA with a quick stop option that
//!   ramps (0x605A = 1..8, read at transition 11), and in FRA with a fault reaction that ramps (class "f",
//!   0x605E = 1, 2, torque applied before the fault); the brake is only released while torque is allowed;
//! - transition 16 only with 0x605A = 5..8 (Gamma L834);
//! - Safe Torque Off (EPOS4 AN ch. 9): with no new fault, the step ends with the power section off and in none of
//!   RTSO, SO, OE, QSA, and «Shutdown» (2) never completes while it lasts;
//! - the statusword reports the state (IDX Table 2-5), bit 4 is the power stage and bit 14 Safe Torque Off.

use crate::support::*;
use firmware::cia402::{
    Brake, Config, Controlword, FaultClass, FaultInput, Inputs, Motion, OptionCodes, QuickStopOption, State,
    StateMachine, Ticks, Transition,
};
use proptest::prelude::*;

fn controlword() -> impl Strategy<Value = u16> {
    prop_oneof![
        8 => prop::sample::select(vec![
            0x0000u16, 0x0006, 0x0007, 0x000F, 0x000B, 0x0002, 0x0080, 0x0086, 0x008F, 0x010F, 0x001F, 0x0106,
        ]),
        1 => any::<u16>(),
    ]
}

fn option(valid: &'static [i16]) -> impl Strategy<Value = i16> {
    prop_oneof![6 => prop::sample::select(valid), 1 => any::<i16>()]
}

fn options() -> impl Strategy<Value = OptionCodes> {
    (
        option(&[0, 1, 2, 3, 4, 5, 6, 7, 8]),
        option(&[0, 1]),
        option(&[0, 1]),
        option(&[1, 2, 3, 4]),
        option(&[0, 1, 2]),
        option(&[1, 2, 3]),
    )
        .prop_map(|(quick_stop, shutdown, disable_operation, halt, fault_reaction, abort_connection)| {
            OptionCodes { quick_stop, shutdown, disable_operation, halt, fault_reaction, abort_connection }
        })
}

fn inputs() -> impl Strategy<Value = Inputs> {
    (
        controlword(),
        prop_oneof![4 => prop::sample::select(vec![0i8, 1, 3, 6, 8, 9, 10]), 1 => any::<i8>()],
        options(),
        prop_oneof![
            20 => Just(None),
            1 => Just(Some(FaultClass::Reaction)),
            1 => Just(Some(FaultClass::Critical)),
        ],
        any::<bool>(),
        prop::bool::weighted(0.05),
        prop::bool::weighted(0.95),
        any::<bool>(),
        any::<bool>(),
        any::<bool>(),
        prop::bool::weighted(0.1),
    )
        .prop_map(
            |(
                cw,
                mode,
                options,
                raised,
                present,
                connection_lost,
                initialized,
                calibration_done,
                standstill,
                remote,
                safe_torque_off,
            )| {
                Inputs {
                    controlword: Controlword(cw),
                    modes_of_operation: mode,
                    options,
                    fault: FaultInput { raised, present },
                    connection_lost,
                    initialized,
                    calibration_done,
                    standstill,
                    remote,
                    safe_torque_off,
                    ..Inputs::default()
                }
            },
        )
}

fn config() -> impl Strategy<Value = Config> {
    (prop::option::of(0u32..40), 0u32..5, 0u32..5).prop_map(|(timeout, engage, release)| Config {
        standstill_timeout: timeout.map(Ticks),
        brake_engage_delay: Ticks(engage),
        brake_release_delay: Ticks(release),
        ..Config::DEFAULT
    })
}

/// Option codes in force for the present stop, as read when it started.
#[derive(Clone, Copy, Debug)]
struct Model {
    quick_stop_at_11: Option<QuickStopOption>,
    fault_reaction_ramps: bool,
}

fn check_sequence(config: Config, sequence: &[Inputs], start_time: u32) -> Result<(), TestCaseError> {
    let mut machine = StateMachine::new(config);
    let mut model = Model { quick_stop_at_11: None, fault_reaction_ramps: false };
    let mut prev_state = machine.state();
    let mut prev_torque = false;
    let mut now = start_time;
    for inputs in sequence {
        let out = machine.step(inputs, Ticks(now));
        now = now.wrapping_add(1);
        let comm_fault = inputs.connection_lost && inputs.options.abort_connection_is_fault();
        let raised = inputs.fault.raised.or(comm_fault.then_some(FaultClass::Reaction));

        // State changes are reported transitions with the table's source and target.
        if out.state != prev_state {
            prop_assert!(out.transition.is_some(), "{prev_state:?} -> {:?} without a transition", out.state);
        }
        if let Some(t) = out.transition {
            prop_assert_eq!(out.state, t.target());
            if let Some(source) = t.source() {
                prop_assert_eq!(prev_state, source, "transition {}", t.number());
            }
            match t {
                Transition::T11 => model.quick_stop_at_11 = Some(inputs.options.quick_stop()),
                Transition::T13 => {
                    prop_assert!(!matches!(prev_state, State::FaultReactionActive | State::Fault));
                    prop_assert!(raised.is_some());
                    model.fault_reaction_ramps = raised == Some(FaultClass::Reaction)
                        && inputs.options.fault_reaction().ramp().is_some()
                        && prev_torque;
                }
                Transition::T15 => {
                    prop_assert!(!inputs.fault.present && raised.is_none(), "reset while the fault is present");
                }
                Transition::T16 => {
                    prop_assert!(model.quick_stop_at_11.is_some_and(|q| q.stays_in_quick_stop()));
                }
                _ => {}
            }
        }
        if prev_state == State::Fault && out.state != State::Fault {
            prop_assert_eq!(out.transition, Some(Transition::T15), "Fault left other than by 15");
        }
        if raised == Some(FaultClass::Critical) && out.state == State::FaultReactionActive {
            model.fault_reaction_ramps = false;
        }

        // Torque only where the option codes allow it.
        let torque = out.power.torque_allowed();
        if torque {
            match out.state {
                State::OperationEnabled => {}
                State::QuickStopActive => {
                    prop_assert!(model.quick_stop_at_11.is_some_and(|q| q.ramp().is_some()), "{model:?}")
                }
                State::FaultReactionActive => prop_assert!(model.fault_reaction_ramps, "{model:?}"),
                other => prop_assert!(false, "torque in {other:?}"),
            }
        } else {
            prop_assert_eq!(out.motion, Motion::Disabled);
        }
        if out.brake == Brake::Released {
            prop_assert!(torque);
        }
        if out.motion == Motion::Follow {
            prop_assert_eq!(out.state, State::OperationEnabled);
        }
        if matches!(out.state, State::NotReadyToSwitchOn | State::SwitchOnDisabled | State::Fault) {
            prop_assert!(!out.power.enabled);
        }
        // STO: the hardware took the torque; the machine keeps no power section on and does not leave «Switch on
        // disabled» for «Ready to switch on».
        if inputs.safe_torque_off {
            if raised.is_none() {
                prop_assert!(!out.power.enabled, "power section on in {:?} with STO", out.state);
                let on_the_way = matches!(
                    out.state,
                    State::ReadyToSwitchOn | State::SwitchedOn | State::OperationEnabled | State::QuickStopActive
                );
                prop_assert!(!on_the_way, "{:?} with STO", out.state);
            }
            prop_assert_ne!(out.transition, Some(Transition::T2), "«Shutdown» accepted with STO");
        }

        // Statusword.
        prop_assert_eq!(out.statusword.state(), Some(out.state));
        prop_assert_eq!(out.statusword.0 & 0x0010 != 0, out.power.enabled);
        prop_assert_eq!(out.statusword.0 & 0x0200 != 0, inputs.remote);
        prop_assert_eq!(out.statusword.0 & 0x0100, 0, "bit 8 reserved");
        prop_assert_eq!(out.statusword.0 & 0x4000 != 0, inputs.safe_torque_off, "bit 14 Safe Torque Off");

        prev_state = out.state;
        prev_torque = torque;
    }
    Ok(())
}

/// 0x6007 = 1 in force (with the reserved-value fallback).
trait AbortIsFault {
    fn abort_connection_is_fault(&self) -> bool;
}

impl AbortIsFault for OptionCodes {
    fn abort_connection_is_fault(&self) -> bool {
        self.abort_connection() == firmware::cia402::AbortConnectionOption::Fault
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1_000, ..ProptestConfig::default() })]

    #[test]
    fn invariants_hold_for_random_inputs(
        config in config(),
        sequence in prop::collection::vec(inputs(), 1..300),
        start_time in any::<u32>(),
    ) {
        check_sequence(config, &sequence, start_time)?;
    }

    /// Runs of repeated inputs let ramps, calibrations and delays finish, reaching the deeper states.
    #[test]
    fn invariants_hold_for_held_inputs(
        config in config(),
        runs in prop::collection::vec((inputs(), 1usize..40), 1..40),
    ) {
        let sequence: Vec<Inputs> = runs
            .into_iter()
            .flat_map(|(inputs, n)| {
                // A raised fault is an event: only in the first step of a run.
                let later = Inputs { fault: FaultInput { raised: None, ..inputs.fault }, ..inputs };
                std::iter::once(inputs).chain(std::iter::repeat_n(later, n - 1))
            })
            .collect();
        check_sequence(config, &sequence, 0)?;
    }
}

#[test]
fn held_inputs_reach_every_state() {
    // The harness sequences of the table test, as a sanity check that the properties see all states.
    for state in State::ALL {
        let mut h = Harness::in_state(state, OptionCodes::DEFAULT);
        assert_eq!(h.step().state, state);
    }
}

//! Shared helpers of the CiA 402 state-machine tests (`cia402_table.rs`, `cia402_options.rs`, `cia402_modes.rs`,
//! `cia402_properties.rs`): a harness that steps `firmware::cia402::StateMachine` with a clock and brings it into
//! each state by the command sequences of the seeds (E4 L7378-7394: 0x0006 Shutdown, 0x000F Switch on & Enable,
//! 0x000B Quick stop, 0x0000 -> 0x0080 Fault reset).
#![allow(dead_code)]

use firmware::cia402::{
    Config, Controlword, FaultClass, Inputs, OptionCodes, Outputs, State, StateMachine, Ticks, Transition,
};
use firmware::od::entry::{Entry, Limits};
use firmware::od::generated::ENTRIES;

/// Steps a machine with a clock of one tick per step.
pub struct Harness {
    /// The machine under test.
    pub machine: StateMachine,
    /// The inputs of the next step (`fault.raised` is cleared after each step: it is an event).
    pub inputs: Inputs,
    /// The time of the next step.
    pub now: u32,
}

impl Harness {
    /// A machine with the default configuration, initialised, remote, default option codes.
    pub fn new() -> Self {
        Self::with_config(Config::DEFAULT)
    }

    /// A machine with `config`.
    pub fn with_config(config: Config) -> Self {
        let inputs = Inputs { initialized: true, remote: true, ..Inputs::default() };
        Self { machine: StateMachine::new(config), inputs, now: 0 }
    }

    /// One step.
    pub fn step(&mut self) -> Outputs {
        let out = self.machine.step(&self.inputs, Ticks(self.now));
        self.now = self.now.wrapping_add(1);
        self.inputs.fault.raised = None;
        out
    }

    /// One step with this controlword.
    pub fn cw(&mut self, cw: u16) -> Outputs {
        self.inputs.controlword = Controlword(cw);
        self.step()
    }

    /// `n` steps; every output.
    pub fn steps(&mut self, n: usize) -> Vec<Outputs> {
        (0..n).map(|_| self.step()).collect()
    }

    /// Raises a fault of `class` in the next step and marks it present.
    pub fn raise(&mut self, class: FaultClass) -> Outputs {
        self.inputs.fault.raised = Some(class);
        self.inputs.fault.present = true;
        self.step()
    }

    /// A harness in `state` with `options`, reached by the seeds' command sequences. QSA is reached with the
    /// quick stop finished and the drive holding, which needs 0x605A = 5..8 (6 is used if `options` has another
    /// value). FRA is reached from OE with a fault reaction ramp still running (0x605E = 1 is used if `options`
    /// has 0), and the motor not at standstill; the fault is present. Fault is reached with the fault no longer
    /// present and the controlword 0x0000. The controlword left in `inputs` keeps the state.
    pub fn in_state(state: State, options: OptionCodes) -> Self {
        let mut h = Self::new();
        h.inputs.options = options;
        if state == State::NotReadyToSwitchOn {
            h.inputs.initialized = false;
            let out = h.step();
            assert_eq!(out.state, state);
            return h;
        }
        expect_transition(&h.step(), Transition::T1);
        if state == State::SwitchOnDisabled {
            return h;
        }
        expect_transition(&h.cw(0x0006), Transition::T2);
        if state == State::ReadyToSwitchOn {
            return h;
        }
        let out = h.cw(0x0007);
        assert!(out.start_current_calibration);
        h.inputs.calibration_done = true;
        expect_transition(&h.step(), Transition::T3);
        h.inputs.calibration_done = false;
        if state == State::SwitchedOn {
            return h;
        }
        expect_transition(&h.cw(0x000F), Transition::T4);
        if state == State::OperationEnabled {
            return h;
        }
        match state {
            State::QuickStopActive => {
                if !h.inputs.options.quick_stop().stays_in_quick_stop() {
                    h.inputs.options.quick_stop = 6;
                }
                expect_transition(&h.cw(0x000B), Transition::T11);
                h.inputs.standstill = true;
                let out = h.step();
                assert_eq!(out.state, State::QuickStopActive);
                assert_eq!(out.transition, None);
                h.inputs.standstill = false;
            }
            State::FaultReactionActive | State::Fault => {
                if h.inputs.options.fault_reaction().ramp().is_none() {
                    h.inputs.options.fault_reaction = 1;
                }
                expect_transition(&h.raise(FaultClass::Reaction), Transition::T13);
                if state == State::Fault {
                    h.inputs.standstill = true;
                    expect_transition(&h.step(), Transition::T14);
                    h.inputs.standstill = false;
                    h.inputs.fault.present = false;
                    h.cw(0x0000);
                }
            }
            _ => unreachable!("{state:?}"),
        }
        assert_eq!(h.machine.state(), state);
        h
    }
}

impl Default for Harness {
    fn default() -> Self {
        Self::new()
    }
}

/// Asserts that `out` completed `t` and is in its target state.
pub fn expect_transition(out: &Outputs, t: Transition) {
    assert_eq!(out.transition, Some(t), "expected transition {} in {out:?}", t.number());
    assert_eq!(out.state, t.target(), "transition {} leads to {:?}", t.number(), t.target());
}

/// The dictionary entry of a VAR object.
pub fn entry(index: u16) -> &'static Entry {
    ENTRIES.iter().find(|e| e.index == index && e.sub == 0).expect("object in the dictionary")
}

/// The values `device.toml` accepts for an option-code object (its `values` list).
pub fn accepted_values(index: u16) -> Vec<i16> {
    match *entry(index).generated_limits() {
        Limits::OneOf(list) => list.iter().map(|&v| i16::try_from(v).expect("INTEGER16 value")).collect(),
        other => panic!("{index:#06x} has no value list: {other:?}"),
    }
}

/// The default of an object in the generated dictionary, as a signed value.
pub fn default_value(index: u16) -> i64 {
    let e = entry(index);
    let dict = firmware::od::values::Values::new(firmware::od::generated::DEFAULT_NODE_ID);
    let raw = dict.raw(e).expect("RAM entry");
    let mut bytes = [0u8; 8];
    bytes[..raw.len()].copy_from_slice(raw);
    let unsigned = u64::from_le_bytes(bytes);
    if e.data_type.is_signed() {
        let shift = 64 - 8 * raw.len() as u32;
        ((unsigned << shift) as i64) >> shift
    } else {
        unsigned as i64
    }
}

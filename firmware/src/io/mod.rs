//! Digital inputs and outputs of tier 2: input functions and polarity (0x3141, 0x3142, 0x60FD), output functions
//! (0x3150, 0x3151, 0x60FE) with the holding brake (0x3158), and the touch probe (0x60B8..0x60BD, 0x60D0,
//! 0x60D5..0x60D8).
//!
//! Files: [`inputs`] (0x3141, 0x3142, 0x60FD, limit and home switches), [`outputs`] (0x3150, 0x3151, 0x60FE:01,
//! 0x3158), [`touch_probe`] (0x60B8, 0x60B9, 0x60BA..0x60BD, 0x60D0, 0x60D5..0x60D8). [`Io::step`] runs once per
//! slow tick and is the only writer of the objects it publishes (0x60FE:01 bits 24..31 included; the master owns
//! bits 0..23).

pub mod inputs;
pub mod outputs;
pub mod touch_probe;

use crate::cia402::machine::Brake;
use crate::od::access::Dictionary;
use crate::sensors::latch::{PinLatches, SwitchEdges};

/// The input functions the drive acts on, in the coordinates of 0x6064.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct InputState {
    /// 0x60FD digital inputs (function bits, polarity applied).
    pub functions: u32,
    /// Negative limit switch (function 0).
    pub negative_limit: SwitchEdges,
    /// Positive limit switch (function 1).
    pub positive_limit: SwitchEdges,
    /// Home switch (function 2).
    pub home_switch: SwitchEdges,
    /// Quick stop input active (function 28).
    pub quick_stop: bool,
    /// Drive enable input: `true` when no input has function 27, else its level.
    pub drive_enable: bool,
    /// The negative limit switch is active and has function 0 (limit error 0x8A80); never set by function 24
    /// (limit switch without errors, homing only).
    pub negative_limit_error: bool,
    /// The positive limit switch is active and has function 1 (limit error 0x8A81); never set by function 25.
    pub positive_limit_error: bool,
}

/// What the I/O step produced.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct IoState {
    /// The input functions.
    pub inputs: InputState,
    /// Levels to drive on the output pins: bit n = output n+1 (after polarity).
    pub output_pins: u8,
}

/// The I/O of the drive.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Io {
    touch_probes: touch_probe::TouchProbes,
    brake_present: bool,
}

impl Io {
    /// Defaults of `device.toml`.
    #[must_use]
    pub const fn new() -> Self {
        Self { touch_probes: touch_probe::TouchProbes::new(), brake_present: false }
    }

    /// Whether an output is configured as holding brake (0x3151 = 24): the brake delays 0x3158 apply. As of the
    /// last [`Io::step`] (`false` before the first).
    #[must_use]
    pub fn brake_present(&self) -> bool {
        self.brake_present
    }

    /// One slow tick: reads the configuration and 0x60B8/0x60FE from `d`, maps the latched pin edges (raw encoder
    /// positions plus `position_offset` = the coordinates of 0x6064) to input functions and touch-probe results,
    /// drives the outputs from the brake request and `ready` (no fault), and publishes 0x60FD, 0x3141:01,
    /// 0x3150:01, 0x3158:03, 0x60FE:01 bits 24/25 and the touch-probe objects.
    pub fn step(
        &mut self,
        pins: &PinLatches,
        position_offset: i32,
        brake: Brake,
        ready: bool,
        d: &mut Dictionary,
    ) -> IoState {
        let state = self.inputs(pins, position_offset, d);
        let output_pins = self.outputs(brake, ready, d);
        IoState { inputs: state, output_pins }
    }

    /// The input half of [`Io::step`]: input functions, their edges and the touch probes. The axis runs it
    /// before the CiA 402 machine (the quick-stop and drive-enable inputs act in the same step).
    pub fn inputs(&mut self, pins: &PinLatches, position_offset: i32, d: &mut Dictionary) -> InputState {
        let input_config = inputs::InputConfig::read(d);
        let state = inputs::evaluate(pins, &input_config, position_offset);
        inputs::publish(pins, &state, d);
        self.touch_probes.step(pins, &input_config, position_offset, d);
        state
    }

    /// Publishes the touch probes' latched positions in the master's units (after the slow tick).
    pub fn publish_probe_positions(&self, units: &crate::motion::gear::UserUnits, d: &mut Dictionary) {
        self.touch_probes.publish_positions(units, d);
    }

    /// The output half of [`Io::step`]: the output pins for the brake request and `ready`. The axis runs it after
    /// the machine, so the brake pin changes in the step the machine asks for it (the brake delays 0x3158 are
    /// counted from there).
    pub fn outputs(&mut self, brake: Brake, ready: bool, d: &mut Dictionary) -> u8 {
        let (output_config, output_pins) = outputs::step(brake, ready, d);
        self.brake_present = output_config.brake_present();
        output_pins
    }

    /// Clears the touch-probe results (stored flags, positions, counters; the probes stay enabled) and publishes
    /// them: homing calls this when it ends (IDX L6362).
    pub fn clear_touch_probes(&mut self, d: &mut Dictionary) {
        self.touch_probes.clear(d);
    }

    /// 0x60B9 as of the last tick.
    #[must_use]
    pub fn touch_probe_status(&self) -> u16 {
        self.touch_probes.status()
    }
}

/// A drive's I/O with its dictionary and pin latches, for the unit tests of this module's files.
#[cfg(test)]
mod rig {
    use super::{Io, IoState};
    use crate::cia402::machine::Brake;
    use crate::od::access::Dictionary;
    use crate::sensors::latch::PinLatches;

    pub(super) struct Rig {
        pub io: Io,
        pub d: Dictionary,
        pub pins: PinLatches,
        /// Wired input levels now.
        pub levels: u8,
        pub offset: i32,
        pub brake: Brake,
        pub ready: bool,
    }

    impl Rig {
        /// Inputs all low (primed), one tick run so that the probes have seen the latches.
        pub fn new() -> Self {
            let mut rig = Self {
                io: Io::new(),
                d: Dictionary::new(1),
                pins: PinLatches::default(),
                levels: 0,
                offset: 0,
                brake: Brake::Engaged,
                ready: true,
            };
            rig.pins.sample_inputs(0, 0);
            rig.tick();
            rig
        }

        /// One slow tick, with the probes' positions published after it as the axis does.
        pub fn tick(&mut self) -> IoState {
            let state = self.io.step(&self.pins, self.offset, self.brake, self.ready, &mut self.d);
            let units = crate::motion::gear::UserUnits::from_dictionary(&self.d);
            self.io.publish_probe_positions(&units, &mut self.d);
            state
        }

        /// Drives input `input` (0-based) to `high` at raw encoder position `position`.
        pub fn pin(&mut self, input: u8, high: bool, position: i32) {
            let mask = 1u8 << input;
            self.levels = if high { self.levels | mask } else { self.levels & !mask };
            self.pins.sample_inputs(self.levels, position);
        }
    }
}

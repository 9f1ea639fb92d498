//! Digital I/O of the plant: limit and home switches at positions of the shaft, injected input levels, and a
//! holding brake on one of the drive's digital outputs.
//!
//! * **Inputs** (`Measurements.feedback.digital_inputs`, bit n = input n+1, levels as wired): each input is wired
//!   to an [`InputSource`]: nothing, a switch active on one side of a position, or a switch active inside a band
//!   (a cam-operated home switch). Positions are total encoder counts, the count the plant's encoder shows for the
//!   true angle (`sensors::encoder_count`, 4096 per revolution for the reference plant, 0 at start-up), evaluated
//!   at the sample instant with the encoder count of the same sample, so the firmware latches an edge at the count
//!   where the switch operates. Each input has its wiring ([`InputWiring::active_low`]: a normally-closed contact
//!   reads low when operated). A test can force any input to a level ([`super::Plant::force_digital_input`]),
//!   overriding its wiring until released.
//! * **Holding brake** ([`BrakeParams`]): a permanent-magnet brake on one output pin. It is released while the
//!   pin is at its energising level and holds otherwise; each change takes effect after its delay (the
//!   "reaction time opening / closing" of a brake data sheet, IDX 0x3158 L5116-5142) counted in simulated PWM
//!   periods. Engaged, it adds its holding torque to the Coulomb friction of the shaft: the stiction model of the
//!   mechanics then keeps a rotor at rest while the net torque stays within the friction, and brakes a moving one
//!   at the full torque until it stops (the brake is not meant to stop loads, IDX L5097-5100, but the model lets
//!   it).
//!
//! [`IoParams::reference`] is the wiring the motion tests use: input 1 negative limit switch, input 2 positive
//! limit switch, input 3 home switch, input 4 spare (the 0x3142 defaults 0, 1, 2, 19), all active high and with no
//! position set (inactive); no brake fitted.

use super::Plant;

/// Number of digital inputs.
pub const DIGITAL_INPUTS: usize = 4;

/// What operates an input.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum InputSource {
    /// Nothing: the contact is never operated.
    #[default]
    Open,
    /// A switch operated at and above `position_counts` (a positive limit switch).
    Above {
        /// Position from which on the switch is operated, in total encoder counts; `None`: never operated.
        position_counts: Option<i64>,
    },
    /// A switch operated at and below `position_counts` (a negative limit switch).
    Below {
        /// Position up to which the switch is operated, in total encoder counts; `None`: never operated.
        position_counts: Option<i64>,
    },
    /// A switch operated from `from_counts` to `to_counts` inclusive (a home cam).
    Band {
        /// Lower end, in total encoder counts.
        from_counts: i64,
        /// Upper end, in total encoder counts.
        to_counts: i64,
    },
}

impl InputSource {
    /// Whether the switch is operated at encoder count `count`.
    pub fn operated(&self, count: i64) -> bool {
        match *self {
            Self::Open => false,
            Self::Above { position_counts } => position_counts.is_some_and(|p| count >= p),
            Self::Below { position_counts } => position_counts.is_some_and(|p| count <= p),
            Self::Band { from_counts, to_counts } => (from_counts..=to_counts).contains(&count),
        }
    }
}

/// One input: its source and its wiring.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct InputWiring {
    /// What operates it.
    pub source: InputSource,
    /// The pin reads low while the switch is operated (normally-closed contact); else high.
    pub active_low: bool,
}

impl InputWiring {
    /// The pin level at encoder count `count`.
    pub fn level(&self, count: i64) -> bool {
        self.source.operated(count) != self.active_low
    }
}

/// The holding brake.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BrakeParams {
    /// The output pin driving it (0-based: bit n of [`Plant::set_digital_outputs`] = output n+1); `None`: no brake
    /// fitted.
    pub output: Option<u8>,
    /// The pin level that energises the coil and releases the brake.
    pub energising_level: bool,
    /// From de-energising until the brake holds, in s.
    pub engage_delay_s: f64,
    /// From energising until the brake is released, in s.
    pub release_delay_s: f64,
    /// Static (and sliding) holding torque, in N m.
    pub holding_torque_nm: f64,
}

impl Default for BrakeParams {
    /// No brake fitted; if fitted: on output 1, energised by a high pin, 10 ms both ways (the 0x3158 defaults),
    /// 0.5 N m (*assumption*: a small permanent-magnet brake for a 70 W motor, about 7 times the rated torque of
    /// 0.0335 N m/A x 3.2 A = 0.107 N m).
    fn default() -> Self {
        Self {
            output: None,
            energising_level: true,
            engage_delay_s: 0.010,
            release_delay_s: 0.010,
            holding_torque_nm: 0.5,
        }
    }
}

/// The digital I/O wiring of a plant.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct IoParams {
    /// Inputs 1..4.
    pub inputs: [InputWiring; DIGITAL_INPUTS],
    /// The holding brake.
    pub brake: BrakeParams,
}

impl IoParams {
    /// Input 1 negative limit switch, 2 positive limit switch, 3 home switch (operated at and above its
    /// position), 4 spare; all active high, no positions set; no brake. See the module docs.
    pub fn reference() -> Self {
        let mut io = Self::default();
        io.inputs[0].source = InputSource::Below { position_counts: None };
        io.inputs[1].source = InputSource::Above { position_counts: None };
        io.inputs[2].source = InputSource::Above { position_counts: None };
        io
    }

    /// Places the negative limit switch (input 1): operated at and below `counts`; `None` removes it.
    pub fn set_negative_limit(&mut self, counts: Option<i64>) {
        self.inputs[0].source = InputSource::Below { position_counts: counts };
    }

    /// Places the positive limit switch (input 2): operated at and above `counts`; `None` removes it.
    pub fn set_positive_limit(&mut self, counts: Option<i64>) {
        self.inputs[1].source = InputSource::Above { position_counts: counts };
    }

    /// Places the home switch (input 3) as `source`.
    pub fn set_home_switch(&mut self, source: InputSource) {
        self.inputs[2].source = source;
    }

    /// The wired input levels at encoder count `count` (bit n = input n+1), without forcing.
    pub fn input_levels(&self, count: i64) -> u8 {
        self.inputs.iter().enumerate().fold(0, |acc, (n, w)| if w.level(count) { acc | 1 << n } else { acc })
    }
}

/// The run-time state of the digital I/O (what [`Plant`] holds; the wiring is in [`IoParams`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PlantIo {
    /// Forced levels: bit n set in `forced_mask` forces input n+1 to bit n of `forced_levels`.
    forced_mask: u8,
    forced_levels: u8,
    /// Output pin levels set by the simulation (bit n = output n+1).
    outputs: u8,
    /// The brake holds.
    brake_engaged: bool,
    /// Periods the coil has been in a state that disagrees with `brake_engaged`.
    pending_periods: u64,
    /// Whether `brake_engaged` has been initialised from the wiring (the brake starts in the state its pin asks
    /// for, so a plant with a de-energised brake starts braked).
    started: bool,
}

impl PlantIo {
    /// The input levels at encoder count `count`, forcing applied.
    pub(super) fn input_levels(&self, params: &IoParams, count: i64) -> u8 {
        (params.input_levels(count) & !self.forced_mask) | (self.forced_levels & self.forced_mask)
    }

    /// Whether the brake coil is energised now (`None`: no brake fitted).
    fn energised(&self, params: &BrakeParams) -> Option<bool> {
        let pin = params.output?;
        let level = self.outputs.checked_shr(u32::from(pin)).is_some_and(|v| v & 1 != 0);
        Some(level == params.energising_level)
    }

    /// Extra Coulomb friction of the brake, in N m (0 when released or not fitted).
    pub(super) fn brake_friction_nm(&self, params: &IoParams) -> f64 {
        if params.brake.output.is_some() && self.engaged(params) {
            params.brake.holding_torque_nm
        } else {
            0.0
        }
    }

    fn engaged(&self, params: &IoParams) -> bool {
        match self.energised(&params.brake) {
            None => false,
            Some(energised) if !self.started => !energised,
            Some(_) => self.brake_engaged,
        }
    }

    /// Advances the brake by one simulated period of `period_s` with the current pin levels.
    pub(super) fn advance(&mut self, params: &IoParams, period_s: f64) {
        let Some(energised) = self.energised(&params.brake) else {
            self.started = false;
            return;
        };
        if !self.started {
            self.started = true;
            self.brake_engaged = !energised;
            self.pending_periods = 0;
        }
        if energised != self.brake_engaged {
            self.pending_periods = 0;
            return;
        }
        // The coil asks for the other state: count the periods spent so (exact integers, no accumulated time).
        self.pending_periods += 1;
        let delay = if energised { params.brake.release_delay_s } else { params.brake.engage_delay_s };
        if self.pending_periods as f64 * period_s >= delay - 1e-12 {
            self.brake_engaged = !energised;
            self.pending_periods = 0;
        }
    }
}

impl Plant {
    /// Set the levels of the drive's digital output pins (bit n = output n+1), as the firmware drives them.
    pub fn set_digital_outputs(&mut self, pins: u8) {
        self.io.outputs = pins;
    }

    /// The output pin levels last set.
    pub fn digital_outputs(&self) -> u8 {
        self.io.outputs
    }

    /// Force input `input` (0-based: bit n = input n+1) to the wired level `level`, or release it to its wiring
    /// (`None`). Inputs beyond the fourth are ignored.
    pub fn force_digital_input(&mut self, input: usize, level: Option<bool>) {
        if input >= DIGITAL_INPUTS {
            return;
        }
        let mask = 1u8 << input;
        match level {
            Some(high) => {
                self.io.forced_mask |= mask;
                self.io.forced_levels = if high { self.io.forced_levels | mask } else { self.io.forced_levels & !mask };
            }
            None => self.io.forced_mask &= !mask,
        }
    }

    /// The input levels the firmware would sample now (bit n = input n+1, as wired, forcing applied).
    pub fn digital_inputs(&self) -> u8 {
        self.io.input_levels(&self.params.io, self.last_count)
    }

    /// Whether the holding brake holds (always `false` without a brake).
    pub fn brake_engaged(&self) -> bool {
        self.io.engaged(&self.params.io)
    }
}

#[cfg(test)]
mod tests {
    use super::super::{PlantParams, PERIOD_S};
    use super::*;
    use core::f64::consts::PI;
    use firmware::hal::power::PwmCommand;

    const CPR: f64 = 4096.0;

    fn counts_to_rad(counts: f64) -> f64 {
        counts / CPR * 2.0 * PI
    }

    fn plant(io: IoParams) -> Plant {
        let params = PlantParams { io, ..PlantParams::reference_ideal_sensors() };
        Plant::new(params, 1)
    }

    /// Total count from the 16-bit counter for positions within +-32k counts of 0.
    fn count_of(m: &firmware::hal::power::Measurements) -> i64 {
        i64::from(m.feedback.encoder_count as i16)
    }

    #[test]
    fn positive_limit_toggles_where_the_rotor_crosses_it() {
        let mut io = IoParams::reference();
        io.set_positive_limit(Some(1000));
        let mut p = plant(io);
        p.set_rotor_state(counts_to_rad(950.5), 100.0); // about 2.6 counts per period
        let off = PwmCommand::default();
        let (mut toggles, mut last) = (0, 0u8);
        for _ in 0..60 {
            let m = p.step(&off);
            let level = m.feedback.digital_inputs;
            assert_eq!(level & 0b1101, 0, "other inputs stay inactive");
            assert_eq!(level & 0b10 != 0, count_of(&m) >= 1000, "at count {}", count_of(&m));
            toggles += i32::from(level != last);
            last = level;
        }
        assert_eq!(toggles, 1);
        assert_eq!(last, 0b10);
        // Back below it (and active low wiring inverts the level).
        p.params_mut().io.inputs[1].active_low = true;
        p.set_rotor_state(counts_to_rad(1040.5), -100.0);
        let mut operated_seen = false;
        for _ in 0..60 {
            let m = p.step(&off);
            let operated = count_of(&m) >= 1000;
            assert_eq!(m.feedback.digital_inputs & 0b10 == 0, operated, "at count {}", count_of(&m));
            operated_seen |= operated;
        }
        assert!(operated_seen && p.digital_inputs() & 0b10 != 0, "left the switch: pin high again");
    }

    #[test]
    fn negative_limit_and_home_band() {
        let mut io = IoParams::reference();
        io.set_negative_limit(Some(-2000));
        io.set_home_switch(InputSource::Band { from_counts: 100, to_counts: 199 });
        let mut p = plant(io);
        for (counts, expected) in
            [(-2500, 0b001), (-2000, 0b001), (-1999, 0), (99, 0), (100, 0b100), (199, 0b100), (200, 0)]
        {
            // Mid-count angles: the encoder shows `counts`.
            p.set_rotor_state(counts_to_rad(f64::from(counts) + 0.5), 0.0);
            p.lock_rotor(true);
            let m = p.step(&PwmCommand::default());
            assert_eq!(m.feedback.digital_inputs, expected, "at {counts} counts");
        }
        // Without positions the reference wiring never operates.
        let mut p = plant(IoParams::reference());
        for counts in [-1e6, 0.0, 1e6] {
            p.set_rotor_state(counts_to_rad(counts), 0.0);
            assert_eq!(p.step(&PwmCommand::default()).feedback.digital_inputs, 0);
        }
    }

    #[test]
    fn forced_inputs_override_the_wiring_until_released() {
        let mut io = IoParams::reference();
        io.set_positive_limit(Some(0));
        let mut p = plant(io);
        let off = PwmCommand::default();
        assert_eq!(p.step(&off).feedback.digital_inputs, 0b0010);
        p.force_digital_input(3, Some(true));
        p.force_digital_input(1, Some(false));
        p.force_digital_input(7, Some(true));
        assert_eq!(p.step(&off).feedback.digital_inputs, 0b1000);
        p.force_digital_input(1, None);
        assert_eq!(p.step(&off).feedback.digital_inputs, 0b1010);
        p.force_digital_input(3, Some(false));
        assert_eq!(p.step(&off).feedback.digital_inputs, 0b0010);
    }

    fn brake_plant() -> Plant {
        let mut io = IoParams::reference();
        io.brake.output = Some(1);
        plant(io)
    }

    /// Steps until the brake changes state; the number of periods it took.
    fn periods_until_brake(p: &mut Plant, engaged: bool) -> u32 {
        let mut n = 0;
        while p.brake_engaged() != engaged {
            p.step(&PwmCommand::default());
            n += 1;
            assert!(n < 10_000, "brake never changed");
        }
        n
    }

    #[test]
    fn brake_engages_and_releases_after_its_delays() {
        let mut p = brake_plant();
        assert!(p.brake_engaged(), "de-energised at start: holds");
        p.set_digital_outputs(0b01); // the other output
        p.step(&PwmCommand::default());
        assert!(p.brake_engaged());
        p.set_digital_outputs(0b10);
        // 10 ms = 250 periods.
        assert_eq!(periods_until_brake(&mut p, false), 250);
        p.set_digital_outputs(0);
        assert_eq!(periods_until_brake(&mut p, true), 250);
        // A pulse shorter than the release delay does not release it.
        p.params_mut().io.brake.release_delay_s = 20.0 * PERIOD_S;
        p.set_digital_outputs(0b10);
        for _ in 0..19 {
            p.step(&PwmCommand::default());
        }
        p.set_digital_outputs(0);
        for _ in 0..100 {
            p.step(&PwmCommand::default());
            assert!(p.brake_engaged());
        }
        // Active-low coil drive: a low pin energises.
        p.params_mut().io.brake.energising_level = false;
        p.set_digital_outputs(0b01);
        assert_eq!(periods_until_brake(&mut p, false), 20);
        // No brake fitted: never engaged.
        let mut p = plant(IoParams::reference());
        p.step(&PwmCommand::default());
        assert!(!p.brake_engaged());
    }

    #[test]
    fn brake_holds_below_its_torque_and_slips_above() {
        let mut p = brake_plant();
        let off = PwmCommand::default();
        p.set_load_torque(0.45);
        for _ in 0..2500 {
            p.step(&off);
        }
        let s = p.state();
        assert_eq!((s.theta_m_rad, s.omega_m_rad_s), (0.0, 0.0), "0.45 N m < 0.5 N m: held");
        // Released: the load turns the shaft backwards at once.
        p.set_digital_outputs(0b10);
        periods_until_brake(&mut p, false);
        p.step(&off);
        assert!(p.state().omega_m_rad_s < 0.0);
        // Held again, but 0.6 N m exceeds the holding torque (plus the 3 mN m friction): it slips.
        let mut p = brake_plant();
        p.set_load_torque(0.6);
        for _ in 0..250 {
            p.step(&off);
        }
        let s = p.state();
        // Net 0.6 - 0.503 N m over 10 ms on 17.6 g cm^2: -55 rad/s.
        let expected = -(0.6 - 0.503) / p.params().total_inertia_kg_m2() * 250.0 * PERIOD_S;
        assert!((s.omega_m_rad_s - expected).abs() < 0.02 * expected.abs(), "{} vs {expected}", s.omega_m_rad_s);
    }

    #[test]
    fn engaged_brake_stops_a_moving_rotor() {
        let mut p = brake_plant();
        p.set_rotor_state(0.0, 50.0);
        let off = PwmCommand::default();
        // 50 rad/s x 17.6e-6 kg m^2 / 0.503 N m = 1.75 ms = 44 periods.
        for _ in 0..40 {
            p.step(&off);
        }
        assert!(p.state().omega_m_rad_s > 0.0);
        for _ in 0..6 {
            p.step(&off);
        }
        assert_eq!(p.state().omega_m_rad_s, 0.0);
        let theta = p.state().theta_m_rad;
        for _ in 0..100 {
            p.step(&off);
        }
        assert_eq!(p.state().theta_m_rad, theta, "stays put");
    }
}

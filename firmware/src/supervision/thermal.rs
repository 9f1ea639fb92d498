//! Power-stage and motor temperature supervision: 0x3201, the power-stage warning and current derating, and the
//! two thermal trips (`shared/spec/control-and-protection.md` §3.2; IDX 0x3201, S2 L5451-L5486).
//!
//! Each slow tick (2.5 kHz) takes the two raw 12-bit codes tier 1 sampled ([`SupervisionInputs`]):
//! 1. **Filtering.** A median of the last three codes removes a single wild sample completely, then a first-order
//!    low-pass `y += (x - y) / 8` (time constant 8 slow ticks = 3.2 ms) averages the 1 LSB (0.08 K) noise down to
//!    about 0.02 K rms. The result, converted with [`crate::sensors::temperature::temperature_ddegc`], is published in
//!    0x3201:01 (power stage) and 0x3201:02 (motor) every step. 3.2 ms is nothing against the thermal time
//!    constants it watches (heat sink: minutes; winding: 20 s on the reference motor).
//! 2. **Power stage** (limit `T_max` = 0x3201:03, 100.0 degC; hysteresis `H` = 0x3201:05, 5.0 K):
//!    - warning [`FaultId::PowerStageTemperatureHigh`] (statusword bit 7, EMCY 0xFF81) from `T_max - 10 K`; it
//!      goes below `T_max - 10 K - H`, so a temperature hovering at the threshold does not flood the bus with
//!      EMCYs;
//!    - current derating from the same point (no seed gives a curve: §3.2 "gap"; this is the project's choice):
//!      the limit falls linearly from the limit in force before derating, `I_base` (0x6073 / 0x3001:02 with the
//!      I2t limit), at `T_max - 10 K` to the motor nominal current 0x3001:01 at `T_max`, and stays there above it
//!      (never above `I_base`). Why: the power stage's losses are mostly conduction losses, `~ I^2`; what heats
//!      it past its continuous rating is the peak-current reserve above the nominal current, which this takes
//!      away (on the reference drive 10 A -> 3.2 A cuts the conduction losses to a tenth), while the continuous
//!      operation the motor is rated for stays possible. If that still does not stop the rise, the trip follows;
//!    - trip [`FaultId::PowerStageOverTemperature`] (0x4210, class d, a level cause) above `T_max`; the cause
//!      clears below `T_max - H`, so a fault reset is refused until then (IDX L7170-L7176 "reset only possible
//!      once the temperature is back in range").
//! 3. **Motor** (limit 0x3201:04, 125.0 degC): [`FaultId::MotorThermalOverload`] (0x4380, class d) above the
//!    limit or with no sensor connected (IDX L5476-L5486); its cause clears below the limit minus `H` (120.0 degC,
//!    IDX "reset only below 120 degC") with a sensor present.
//! 4. **Sensor at a rail.** A code below [`SENSOR_CODE_MIN`] or above [`SENSOR_CODE_MAX`] (below -46 degC or
//!    above 276 degC: an open or shorted sensor or cable, not a temperature) for [`SENSOR_FAULT_STEPS`] slow ticks
//!    in a row (10 ms) counts as "no sensor connected". For the motor that is 0x4380 as IDX says; for the power
//!    stage the same fail-safe rule raises 0x4210 (without its sensor the drive cannot protect its power stage).
//!
//! Both thermal faults carry the power-stage temperature in the snapshot's `power_stage_temperature_ddegc` and
//! the supervised temperature (0.1 degC) in `detail` (the EMCY of 0x4380 shows the motor temperature).
//!
//! The derated limit is relative to [`SupervisionInputs::current_limit`], which the drive fills with the limit
//! *before* this derating, so the output is never fed back into its own base.

use super::SupervisionInputs;
use crate::control::frames::Amps;
use crate::fault::table::FaultId;
use crate::fault::FaultManager;
use crate::od::access::Dictionary;
use crate::od::entry::Storage;
use crate::od::generated::handles as h;
use crate::sensors::temperature::temperature_ddegc;

/// 0x3201 "thermal controller protection" (device.toml; IDX L5455).
const THERMAL_OBJECT: u16 = 0x3201;
/// 0x3201:03 power-stage temperature limit's default, 0.1 degC (used only if the dictionary lacks the entry).
const DEFAULT_POWER_STAGE_LIMIT: i16 = 1000;
/// 0x3201:04 motor temperature limit's default, 0.1 degC (IDX L5478: 125 degC).
const DEFAULT_MOTOR_LIMIT: i16 = 1250;
/// 0x3201:05 reset hysteresis default, 0.1 degC (IDX L5478: reset below 120 degC).
const DEFAULT_HYSTERESIS: i16 = 50;

/// The power-stage warning and the derating start this far below the power-stage limit, 0.1 degC (10 K).
pub const WARNING_MARGIN_DDEGC: i16 = 100;
/// Codes below this are no temperature (-46 degC): an open sensor or a short to ground.
pub const SENSOR_CODE_MIN: u16 = 50;
/// Codes above this are no temperature (276 degC): a sensor or cable shorted to the supply.
pub const SENSOR_CODE_MAX: u16 = 4045;
/// Slow ticks in a row a code must stay at a rail to count as "no sensor connected" (10 ms).
pub const SENSOR_FAULT_STEPS: u16 = 25;
/// Low-pass shift: `y += (x - y) >> 3`, a time constant of 8 slow ticks (3.2 ms).
const FILTER_SHIFT: u32 = 3;
/// Fraction bits of the filter state.
const FILTER_FRACTION_BITS: u32 = 8;

/// What one channel measured in one step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Reading {
    /// Filtered temperature, 0.1 degC.
    ddegc: i16,
    /// The code has been at a rail for [`SENSOR_FAULT_STEPS`] steps.
    sensor_lost: bool,
}

/// One temperature channel: median of three, low-pass, rail detection.
#[derive(Clone, Copy, Debug, Default)]
struct Channel {
    /// The two codes before the newest.
    history: [u16; 2],
    /// Low-pass state, 0.1 degC in Q8.
    filtered_q8: i32,
    /// The first sample has seeded the history and the filter.
    primed: bool,
    /// Consecutive steps with the median code at a rail.
    rail_steps: u16,
}

impl Channel {
    fn update(&mut self, code: u16) -> Reading {
        if !self.primed {
            // Seed with the first sample, so that the drive starts from the measured temperature, not from a ramp.
            self.history = [code, code];
            self.filtered_q8 = i32::from(temperature_ddegc(code)) << FILTER_FRACTION_BITS;
            self.primed = true;
        }
        let [a, b] = self.history;
        let median = a.min(b).max(a.max(b).min(code));
        self.history = [b, code];
        let at_rail = !(SENSOR_CODE_MIN..=SENSOR_CODE_MAX).contains(&median);
        self.rail_steps = if at_rail { self.rail_steps.saturating_add(1) } else { 0 };
        // |x|, |y| <= 2800 << 8 < 2^20: no wrap.
        let x = i32::from(temperature_ddegc(median)) << FILTER_FRACTION_BITS;
        self.filtered_q8 = self.filtered_q8.wrapping_add(x.wrapping_sub(self.filtered_q8) >> FILTER_SHIFT);
        let rounded = self.filtered_q8.wrapping_add(1 << (FILTER_FRACTION_BITS - 1)) >> FILTER_FRACTION_BITS;
        Reading {
            ddegc: i16::try_from(rounded).unwrap_or(i16::MAX),
            sensor_lost: self.rail_steps >= SENSOR_FAULT_STEPS,
        }
    }
}

/// Temperatures, warning, derating and trips. See the module documentation.
#[derive(Clone, Debug)]
pub struct ThermalSupervision {
    /// 0x3201:03, 0.1 degC.
    power_stage_limit: i16,
    /// 0x3201:04, 0.1 degC.
    motor_limit: i16,
    /// 0x3201:05, 0.1 degC.
    hysteresis: i16,
    /// 0x3001:01 motor nominal current: the derating's floor.
    nominal_current: Amps,
    power_stage: Channel,
    motor: Channel,
    power_stage_ddegc: i16,
    motor_ddegc: i16,
    warning: bool,
    power_stage_tripped: bool,
    motor_tripped: bool,
    derated_limit: Amps,
}

/// No derating: the value [`ThermalSupervision::step`] returns below the derating band.
const NO_LIMIT: Amps = Amps::from_bits(i32::MAX);

/// An INTEGER16 entry of 0x3201 (constant or in RAM), `None` if the dictionary has no such entry.
fn read_i16(d: &Dictionary, sub: u8) -> Option<i16> {
    let entry = d.find(THERMAL_OBJECT, sub).ok()?;
    let bytes = match entry.storage {
        Storage::Const(bytes) => *bytes,
        Storage::Ram { .. } => d.values().raw(entry)?,
        Storage::Application => return None,
    };
    Some(i16::from_le_bytes(bytes.get(..2)?.try_into().ok()?))
}

impl ThermalSupervision {
    /// Over the parameters of `d`: the limits 0x3201:03..05 and the nominal current 0x3001:01.
    #[must_use]
    pub fn new(d: &Dictionary) -> Self {
        let mut s = Self {
            power_stage_limit: read_i16(d, 3).unwrap_or(DEFAULT_POWER_STAGE_LIMIT),
            motor_limit: read_i16(d, 4).unwrap_or(DEFAULT_MOTOR_LIMIT),
            hysteresis: read_i16(d, 5).unwrap_or(DEFAULT_HYSTERESIS).max(0),
            nominal_current: Amps::ZERO,
            power_stage: Channel::default(),
            motor: Channel::default(),
            power_stage_ddegc: 0,
            motor_ddegc: 0,
            warning: false,
            power_stage_tripped: false,
            motor_tripped: false,
            derated_limit: NO_LIMIT,
        };
        s.refresh(d);
        s
    }

    /// Re-reads the nominal current 0x3001:01 (runs every slow tick: one typed read). The limits 0x3201:03..05
    /// are constants (device.toml: "they protect the hardware and are not user-tunable"), read once in
    /// [`Self::new`].
    pub fn refresh(&mut self, d: &Dictionary) {
        let nominal_ma = d.get(h::MOTOR_NOMINAL_CURRENT);
        self.nominal_current = Amps::from_milliamps(i32::try_from(nominal_ma).unwrap_or(i32::MAX));
    }

    /// One slow tick: publishes 0x3201:01/02, raises/clears the thermal faults; returns the derated current limit
    /// (`Amps::from_bits(i32::MAX)` below the derating band).
    pub fn step(&mut self, inputs: &SupervisionInputs, faults: &mut FaultManager, d: &mut Dictionary) -> Amps {
        let stage = self.power_stage.update(inputs.power_stage_temperature_code);
        let motor = self.motor.update(inputs.motor_temperature_code);
        self.power_stage_ddegc = stage.ddegc;
        self.motor_ddegc = motor.ddegc;
        d.set(h::POWER_STAGE_TEMPERATURE, stage.ddegc);
        d.set(h::MOTOR_TEMPERATURE, motor.ddegc);

        let now = inputs.now;
        let snapshot = |detail: i16| {
            let mut s = inputs.snapshot(i32::from(detail));
            s.power_stage_temperature_ddegc = stage.ddegc;
            s
        };
        let t = stage.ddegc;
        let warn_at = self.power_stage_limit.saturating_sub(WARNING_MARGIN_DDEGC);

        // Warning with hysteresis.
        if !self.warning && t >= warn_at {
            self.warning = true;
            let _ = faults.raise(FaultId::PowerStageTemperatureHigh, snapshot(t), now);
        } else if self.warning && t < warn_at.saturating_sub(self.hysteresis) {
            self.warning = false;
            faults.clear_cause(FaultId::PowerStageTemperatureHigh);
        }

        // Power-stage trip: a level cause, gone below the limit minus the hysteresis.
        if t > self.power_stage_limit || stage.sensor_lost {
            if !self.power_stage_tripped {
                self.power_stage_tripped = true;
                let _ = faults.raise(FaultId::PowerStageOverTemperature, snapshot(t), now);
            }
        } else if self.power_stage_tripped && t < self.power_stage_limit.saturating_sub(self.hysteresis) {
            self.power_stage_tripped = false;
            faults.clear_cause(FaultId::PowerStageOverTemperature);
        }

        // Motor trip: above the limit or no sensor; gone below the limit minus the hysteresis with a sensor.
        if motor.ddegc > self.motor_limit || motor.sensor_lost {
            if !self.motor_tripped {
                self.motor_tripped = true;
                let _ = faults.raise(FaultId::MotorThermalOverload, snapshot(motor.ddegc), now);
            }
        } else if self.motor_tripped && motor.ddegc < self.motor_limit.saturating_sub(self.hysteresis) {
            self.motor_tripped = false;
            faults.clear_cause(FaultId::MotorThermalOverload);
        }

        self.derated_limit = derating(inputs.current_limit, self.nominal_current, t, warn_at);
        self.derated_limit
    }

    /// The filtered power-stage temperature of the last step, 0.1 degC (0x3201:01).
    #[must_use]
    pub const fn power_stage_temperature_ddegc(&self) -> i16 {
        self.power_stage_ddegc
    }

    /// The filtered motor temperature of the last step, 0.1 degC (0x3201:02).
    #[must_use]
    pub const fn motor_temperature_ddegc(&self) -> i16 {
        self.motor_ddegc
    }

    /// The derated current limit of the last step (`Amps::from_bits(i32::MAX)`: none).
    #[must_use]
    pub const fn derated_limit(&self) -> Amps {
        self.derated_limit
    }
}

/// The derating curve (module documentation, item 2): `base` at or below `start` (0.1 degC; returned as no limit),
/// falling linearly to `min(nominal, base)` over [`WARNING_MARGIN_DDEGC`], held there above.
fn derating(base: Amps, nominal: Amps, t: i16, start: i16) -> Amps {
    let over = i64::from(t).saturating_sub(i64::from(start));
    if over <= 0 {
        return NO_LIMIT;
    }
    let base = i64::from(base.to_bits().max(0));
    let floor = i64::from(nominal.to_bits()).clamp(0, base);
    let band = i64::from(WARNING_MARGIN_DDEGC);
    let over = over.min(band);
    // (base - floor) < 2^31 and over <= 100: the product < 2^38.
    let drop = base.saturating_sub(floor).saturating_mul(over).checked_div(band).unwrap_or(0);
    Amps::from_bits(i32::try_from(base.saturating_sub(drop)).unwrap_or(i32::MAX))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::power_state::CommutationStage;

    /// The code of `ddegc` on the sensor (inverse of [`temperature_ddegc`], rounded).
    fn code(ddegc: f64) -> u16 {
        ((ddegc + 500.0) / 3300.0 * 4095.0).round() as u16
    }

    fn inputs(stage: u16, motor: u16, limit: Amps) -> SupervisionInputs {
        SupervisionInputs {
            loops_drive_motor: false,
            power_stage_temperature_code: stage,
            motor_temperature_code: motor,
            hall: 0b001,
            commutation: CommutationStage::Unknown,
            current_limit: limit,
            ..SupervisionInputs::reference_running()
        }
    }

    struct Bench {
        s: ThermalSupervision,
        f: FaultManager,
        d: Dictionary,
    }

    impl Bench {
        fn new() -> Self {
            let d = Dictionary::new(1);
            Self { s: ThermalSupervision::new(&d), f: FaultManager::new(), d }
        }

        /// `n` steps at the given temperatures (0.1 degC) with a 10 A base limit; the last output.
        fn run(&mut self, stage: f64, motor: f64, n: usize) -> Amps {
            self.run_codes(code(stage), code(motor), n)
        }

        fn run_codes(&mut self, stage: u16, motor: u16, n: usize) -> Amps {
            let mut out = NO_LIMIT;
            for _ in 0..n {
                out = self.s.step(&inputs(stage, motor, Amps::from_milliamps(10_000)), &mut self.f, &mut self.d);
            }
            out
        }
    }

    #[test]
    fn reads_the_limits_from_0x3201() {
        let s = ThermalSupervision::new(&Dictionary::new(1));
        assert_eq!((s.power_stage_limit, s.motor_limit, s.hysteresis), (1000, 1250, 50));
        assert_eq!(s.nominal_current, Amps::from_milliamps(3200));
    }

    #[test]
    fn publishes_filtered_temperatures_at_ambient_without_faults() {
        let mut b = Bench::new();
        assert_eq!(b.run(250.0, 400.0, 100), NO_LIMIT);
        // Within one code (0.8 ddegC) of the set temperature.
        assert!((b.d.get(h::POWER_STAGE_TEMPERATURE) - 250).abs() <= 1);
        assert!((b.d.get(h::MOTOR_TEMPERATURE) - 400).abs() <= 1);
        assert!(!b.f.any_fault() && !b.f.warning_active());
    }

    #[test]
    fn one_wild_sample_changes_nothing() {
        let mut b = Bench::new();
        b.run(950.0, 1200.0, 50);
        let before = (b.d.get(h::POWER_STAGE_TEMPERATURE), b.d.get(h::MOTOR_TEMPERATURE));
        // A full-scale spike on both channels for one sample: the median of three drops it.
        b.run_codes(4095, 4095, 1);
        b.run(950.0, 1200.0, 1);
        assert_eq!((b.d.get(h::POWER_STAGE_TEMPERATURE), b.d.get(h::MOTOR_TEMPERATURE)), before);
        assert!(!b.f.any_fault());
    }

    #[test]
    fn the_filter_settles_within_a_few_milliseconds() {
        let mut b = Bench::new();
        b.run(250.0, 250.0, 10);
        // A 10 K step: 1 - e^-(t / 3.2 ms); after 25 steps (10 ms), within 0.5 K of the new value.
        b.run(350.0, 350.0, 25);
        let t = b.d.get(h::POWER_STAGE_TEMPERATURE);
        assert!((345..=350).contains(&t), "{t}");
    }

    #[test]
    fn power_stage_warning_from_ten_kelvin_below_the_limit_with_hysteresis() {
        let mut b = Bench::new();
        b.run(895.0, 250.0, 100);
        assert!(!b.f.is_active(FaultId::PowerStageTemperatureHigh));
        b.run(905.0, 250.0, 100);
        assert!(b.f.is_active(FaultId::PowerStageTemperatureHigh));
        assert!(b.f.warning_active() && !b.f.any_fault(), "a warning, not a fault");
        // Stays on down to 85 degC, goes off below.
        b.run(860.0, 250.0, 100);
        assert!(b.f.is_active(FaultId::PowerStageTemperatureHigh));
        b.run(840.0, 250.0, 100);
        assert!(!b.f.is_active(FaultId::PowerStageTemperatureHigh));
    }

    #[test]
    fn derating_is_linear_from_the_base_limit_to_the_nominal_current() {
        let base = Amps::from_milliamps(10_000);
        let nominal = Amps::from_milliamps(3200);
        assert_eq!(derating(base, nominal, 900, 900), NO_LIMIT);
        assert_eq!(derating(base, nominal, 950, 900).to_milliamps(), 6600);
        assert_eq!(derating(base, nominal, 1000, 900).to_milliamps(), 3200);
        assert_eq!(derating(base, nominal, 1200, 900).to_milliamps(), 3200);
        // Never above the base, never below zero.
        assert_eq!(derating(Amps::from_milliamps(2000), nominal, 990, 900).to_milliamps(), 2000);
        assert_eq!(derating(Amps::from_bits(-5), nominal, 990, 900), Amps::ZERO);
        assert_eq!(derating(base, Amps::ZERO, 1000, 900), Amps::ZERO);
        // Monotonic over the band.
        let mut last = i32::MAX;
        for t in 900..=1010 {
            let l = derating(base, nominal, t, 900).to_bits();
            assert!(l <= last, "{t}");
            last = l;
        }
    }

    #[test]
    fn the_output_follows_the_filtered_power_stage_temperature() {
        let mut b = Bench::new();
        let out = b.run(950.0, 250.0, 100);
        assert!((out.to_milliamps() - 6600).abs() <= 10, "{}", out.to_milliamps());
        assert_eq!(b.s.derated_limit(), out);
    }

    #[test]
    fn power_stage_trip_clears_only_below_limit_minus_hysteresis() {
        let mut b = Bench::new();
        b.run(1005.0, 250.0, 50);
        assert!(b.f.is_active(FaultId::PowerStageOverTemperature));
        assert_eq!(b.f.error_code(), 0x4210);
        let snap = *b.f.snapshot(FaultId::PowerStageOverTemperature).unwrap();
        assert!(snap.power_stage_temperature_ddegc > 1000, "{snap:?}");
        // Between the limit and limit - H: reset refused.
        b.run(970.0, 250.0, 100);
        assert_eq!(b.f.reset_request().unwrap_err().blocking, FaultId::PowerStageOverTemperature);
        b.run(940.0, 250.0, 100);
        assert!(b.f.reset_request().is_ok());
        assert!(!b.f.is_active(FaultId::PowerStageOverTemperature));
        // Hot again: a new trip.
        b.run(1010.0, 250.0, 50);
        assert!(b.f.is_active(FaultId::PowerStageOverTemperature));
    }

    #[test]
    fn motor_trip_above_125_and_reset_below_120() {
        let mut b = Bench::new();
        b.run(250.0, 1245.0, 100);
        assert!(!b.f.any_fault());
        b.run(250.0, 1255.0, 100);
        assert_eq!(b.f.error_code(), 0x4380);
        let snap = *b.f.snapshot(FaultId::MotorThermalOverload).unwrap();
        assert!((1250..=1256).contains(&snap.detail), "motor temperature as detail: {snap:?}");
        assert!((snap.power_stage_temperature_ddegc - 250).abs() <= 1, "{snap:?}");
        b.run(250.0, 1210.0, 100);
        assert!(b.f.reset_request().is_err(), "refused at 121 degC");
        b.run(250.0, 1190.0, 100);
        assert!(b.f.reset_request().is_ok(), "accepted at 119 degC");
        assert!(!b.f.any_fault());
    }

    #[test]
    fn a_sensor_at_a_rail_is_no_sensor_after_ten_milliseconds() {
        for rail in [0u16, SENSOR_CODE_MIN - 1, SENSOR_CODE_MAX + 1, 4095] {
            let mut b = Bench::new();
            b.run(250.0, 250.0, 10);
            b.run_codes(code(250.0), rail, usize::from(SENSOR_FAULT_STEPS));
            if rail < SENSOR_CODE_MIN {
                // A low rail reads cold: only the rail rule trips, one step after 10 ms (the median's lag).
                assert!(!b.f.is_active(FaultId::MotorThermalOverload), "rail {rail}");
            }
            b.run_codes(code(250.0), rail, 1);
            assert!(b.f.is_active(FaultId::MotorThermalOverload), "rail {rail}");
            // The sensor comes back at 25 degC: the cause clears, a reset is accepted.
            b.run(250.0, 250.0, 50);
            assert!(b.f.reset_request().is_ok(), "rail {rail}");
        }
        // The power-stage sensor open: the fail-safe trip.
        let mut b = Bench::new();
        b.run_codes(0, code(250.0), 30);
        assert!(b.f.is_active(FaultId::PowerStageOverTemperature));
    }
}

//! Supervision of the motion in tier 2: following error (0x6065, 0x6066), standstill (0x30E0), software position
//! limits (0x607D) and the speed limit (0x6080), with their dictionary values converted once when they change.
//!
//! Rules (`shared/spec/cia402-device-control.md` §6, §1.7; IDX L5782-5812, L5963-6016, L4842-4898):
//! - Following error: |demand − actual| beyond 0x6065 for longer than 0x6066 sets statusword bit 13 in the position
//!   modes and raises the following-error fault (IDX 0x8611); 0xFFFFFFFF switches the supervision off (E3).
//! - Software position limits: both 0 disable them (IDX); otherwise position targets are clamped into
//!   [min, max] (PPM target clamped, CSP demand clamped, with statusword bit 11 "internal limit active" while a
//!   clamp acts, NT), and an actual position outside them raises the software-limit fault (IDX 0x8A82).
//!   Inactive in homing (IDX L5971).
//! - Standstill: |velocity| within 0x30E0:01 for 0x30E0:02; 0xFFFFFFFF switches the window off, so standstill is
//!   the end of the stop trajectory (the CiA 402 machine applies the timeout 0x30E0:03).
//! - Speed: velocity demands beyond 0x6080 (and, with a gear, the max gear input speed 0x3003:03, both motor rpm)
//!   are clamped, with bit 11; 0x3000:06 shows the same limit at the load (IDX L3898-3939).
//!
//! Units: with a gear ([`super::gear`]) 0x6065, 0x607D and 0x30E0:01 are the load's (increments, rpm) and convert to
//! the axis's motor increments here, when they change.

use super::gear::{Gear, UserUnits};
use crate::cia402::Ticks;
use crate::control::trajectory::{MotionScale, Velocity};
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;

/// Milliseconds to slow ticks (2.5 per ms), rounded up so that a time is never shortened.
#[must_use]
pub fn ticks_from_ms(ms: u32) -> Ticks {
    // ms * 2.5, rounded up: (5 ms + 1) / 2.
    Ticks(ms.saturating_mul(5).saturating_add(1) / 2)
}

/// The raw objects of the monitor.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
struct MonitorObjects {
    following_error_window: u32,
    following_error_timeout: u16,
    standstill_window: u32,
    standstill_time: u16,
    limit_min: i32,
    limit_max: i32,
    max_motor_speed: u32,
    inc_per_rev: u32,
    polarity: u8,
    gear: Gear,
}

impl MonitorObjects {
    /// The objects of `d`, with the gear in effect as the motion parameters read it.
    fn read(d: &Dictionary, gear: Gear) -> Self {
        Self {
            following_error_window: d.get(h::FOLLOWING_ERROR_WINDOW),
            following_error_timeout: d.get(h::FOLLOWING_ERROR_TIMEOUT),
            standstill_window: d.get(h::STANDSTILL_WINDOW),
            standstill_time: d.get(h::STANDSTILL_WINDOW_TIME),
            limit_min: d.get(h::SOFTWARE_POSITION_LIMIT_MIN),
            limit_max: d.get(h::SOFTWARE_POSITION_LIMIT_MAX),
            max_motor_speed: d.get(h::MAX_MOTOR_SPEED),
            inc_per_rev: d.get(h::MAIN_SENSOR_RESOLUTION),
            polarity: d.get(h::POLARITY),
            gear,
        }
    }
}

/// The monitor's limits in internal units.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct MonitorConfig {
    /// 0x6065, `None` when off.
    pub following_error_window: Option<u32>,
    /// 0x6066.
    pub following_error_timeout: Ticks,
    /// 0x30E0:01, `None` when off.
    pub standstill_window: Option<Velocity>,
    /// 0x30E0:02.
    pub standstill_time: Ticks,
    /// 0x607D (min, max) in the axis's coordinates (mirrored by the position polarity 0x607E bit 7:
    /// [`super::polarity::Polarity::limits`], through the gear), `None` when both are 0.
    pub software_limits: Option<(i32, i32)>,
    /// min(0x6080, 0x3003:03 with a gear), motor speed, magnitude.
    pub max_speed: Velocity,
}

/// What the following-error supervision found.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct FollowingErrorStatus {
    /// Outside the window for longer than the timeout: statusword bit 13 and the fault.
    pub exceeded: bool,
}

/// The monitor.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Monitor {
    objects: MonitorObjects,
    config: MonitorConfig,
    following_error_since: Option<Ticks>,
    standstill_since: Option<Ticks>,
}

impl Monitor {
    /// A monitor with the limits of `d`.
    #[must_use]
    pub fn new(d: &Dictionary) -> Self {
        let mut m = Self::default();
        m.objects.inc_per_rev = u32::MAX;
        let _ = m.refresh(d, &MotionScale::new(4096), &UserUnits::NONE);
        // Converted once more by the axis's first refresh, with the load's scale, which publishes 0x3000:06 from the
        // stored parameters.
        m.objects.inc_per_rev = u32::MAX;
        m
    }

    /// Re-reads the objects and converts them when they changed; `Some(0x3000:06)` then (max system speed, load
    /// rpm, for the caller to publish). `load` and `units` are the motion parameters' conversions of the same
    /// objects (`super::params::MotionParams`, refreshed first): the scale of the load's rpm and the positions'.
    pub fn refresh(&mut self, d: &Dictionary, load: &MotionScale, units: &UserUnits) -> Option<u32> {
        let o = MonitorObjects::read(d, units.gear);
        if o == self.objects {
            return None;
        }
        let motor = MotionScale::new(o.inc_per_rev.max(1));
        self.config = MonitorConfig {
            following_error_window: (o.following_error_window != u32::MAX)
                .then(|| units.distance_to_axis(o.following_error_window)),
            following_error_timeout: ticks_from_ms(u32::from(o.following_error_timeout)),
            standstill_window: (o.standstill_window != u32::MAX)
                .then(|| load.velocity_from_rpm(i64::from(o.standstill_window))),
            standstill_time: ticks_from_ms(u32::from(o.standstill_time)),
            software_limits: (o.limit_min != 0 || o.limit_max != 0)
                .then(|| units.limits_to_axis(o.limit_min, o.limit_max)),
            max_speed: motor.velocity_from_rpm(i64::from(o.max_motor_speed.min(o.gear.max_input_speed))),
        };
        self.objects = o;
        Some(o.gear.max_system_speed(o.max_motor_speed))
    }

    /// The limits in force.
    #[must_use]
    pub const fn config(&self) -> &MonitorConfig {
        &self.config
    }

    /// Following-error supervision of one tick; `supervised` is false outside the position-controlled states
    /// (the timer restarts).
    pub fn following_error(&mut self, error: i32, supervised: bool, now: Ticks) -> FollowingErrorStatus {
        let outside = match self.config.following_error_window {
            Some(window) if supervised => error.unsigned_abs() > window,
            _ => false,
        };
        if !outside {
            self.following_error_since = None;
            return FollowingErrorStatus { exceeded: false };
        }
        let since = *self.following_error_since.get_or_insert(now);
        FollowingErrorStatus { exceeded: now.since(since).0 >= self.config.following_error_timeout.0 }
    }

    /// Standstill: |velocity| within the window for the window time (always `true` with the window off, when the
    /// caller's stop trajectory has ended).
    pub fn standstill(&mut self, velocity: Velocity, now: Ticks) -> bool {
        let Some(window) = self.config.standstill_window else {
            self.standstill_since = Some(now);
            return true;
        };
        if velocity.0.unsigned_abs() > window.0.unsigned_abs() {
            self.standstill_since = None;
            return false;
        }
        let since = *self.standstill_since.get_or_insert(now);
        now.since(since).0 >= self.config.standstill_time.0
    }

    /// `position` clamped into the software position limits, and whether the clamp acted.
    #[must_use]
    pub fn clamp_position(&self, position: i32) -> (i32, bool) {
        match self.config.software_limits {
            Some((min, max)) if min <= max => {
                let p = position.clamp(min, max);
                (p, p != position)
            }
            _ => (position, false),
        }
    }

    /// The position demand `position` held within the software position limits for an axis whose previous
    /// demand was `previous`: a demand inside the limits passes, one beyond a limit stops at the limit if the
    /// previous demand was inside, and stays at the previous demand if that was beyond the limit already (the
    /// limits were changed, or the axis was moved past them while disabled). The demand never moves further out,
    /// and it never jumps back to the limit either: a jump of the demand is a full-current rush of the position
    /// loop (IDX L7476: the axis stops at the limit; moving back is the master's decision). The flag says whether
    /// the demand lay beyond a limit.
    #[must_use]
    pub fn clamp_position_from(&self, position: i32, previous: i32) -> (i32, bool) {
        match self.config.software_limits {
            Some((min, max)) if min <= max => {
                let p = if position > max {
                    max.max(previous.min(position))
                } else if position < min {
                    min.min(previous.max(position))
                } else {
                    position
                };
                // Limited whenever the demand lies beyond a limit (statusword bit 11), also on the way back.
                (p, position > max || position < min)
            }
            _ => (position, false),
        }
    }

    /// Whether `position` lies outside the software position limits.
    #[must_use]
    pub fn outside_limits(&self, position: i32) -> bool {
        self.clamp_position(position).1
    }

    /// `velocity` clamped to the speed limit, and whether the clamp acted.
    #[must_use]
    pub fn clamp_velocity(&self, velocity: Velocity) -> (Velocity, bool) {
        let max = self.config.max_speed.0.saturating_abs();
        // Max/min on the ordered bounds: `clamp` would keep its formatted panic for them (flash, issue 17).
        let v = velocity.0.max(max.saturating_neg()).min(max);
        (Velocity(v), v != velocity.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// With a 5:1 gear (0x3003 + 0x3000:02 bit 12) the following-error window 0x6065 and the software limits 0x607D
    /// are load increments: 100 load inc = 500 motor inc; [-1000, 2000] = [-5000, 10000]; the speed limit is
    /// min(0x6080, 0x3003:03) at the motor and 0x3000:06 = 1,000 / 5 = 200 load rpm.
    #[test]
    fn gear_scales_windows_limits_and_speed() {
        let mut d = Dictionary::new(1);
        d.set(h::GEAR_REDUCTION_NUMERATOR, 5);
        d.set(h::MAX_GEAR_INPUT_SPEED, 1_000);
        d.set(h::CONTROL_STRUCTURE, d.get(h::CONTROL_STRUCTURE) | crate::motion::gear::GEAR_MOUNTED);
        d.set(h::FOLLOWING_ERROR_WINDOW, 100);
        d.set(h::SOFTWARE_POSITION_LIMIT_MIN, -1000);
        d.set(h::SOFTWARE_POSITION_LIMIT_MAX, 2000);
        let mut m = Monitor::default();
        let load = MotionScale::geared(4096, 5, 1);
        let shown = m.refresh(&d, &load, &UserUnits::from_dictionary(&d));
        assert_eq!(shown, Some(200));
        assert_eq!(m.config().following_error_window, Some(500));
        assert_eq!(m.config().software_limits, Some((-5000, 10_000)));
        assert_eq!(m.config().max_speed, MotionScale::new(4096).velocity_from_rpm(1_000));
    }

    #[test]
    fn ms_to_ticks_rounds_up() {
        assert_eq!(ticks_from_ms(0), Ticks(0));
        assert_eq!(ticks_from_ms(1), Ticks(3));
        assert_eq!(ticks_from_ms(2), Ticks(5));
        assert_eq!(ticks_from_ms(1000), Ticks(2500));
    }

    #[test]
    fn following_error_needs_window_and_timeout() {
        let mut d = Dictionary::new(1);
        d.set(h::FOLLOWING_ERROR_WINDOW, 100);
        d.set(h::FOLLOWING_ERROR_TIMEOUT, 2);
        let mut m = Monitor::new(&d);
        assert!(!m.following_error(100, true, Ticks(0)).exceeded);
        assert!(!m.following_error(-101, true, Ticks(1)).exceeded);
        assert!(!m.following_error(-101, true, Ticks(5)).exceeded);
        assert!(m.following_error(-101, true, Ticks(6)).exceeded);
        assert!(!m.following_error(-101, false, Ticks(7)).exceeded);
        d.set(h::FOLLOWING_ERROR_WINDOW, u32::MAX);
        let _ = m.refresh(&d, &MotionScale::new(4096), &UserUnits::from_dictionary(&d));
        assert!(!m.following_error(i32::MIN, true, Ticks(100)).exceeded);
    }

    #[test]
    fn software_limits_zero_zero_disable() {
        let mut d = Dictionary::new(1);
        let mut m = Monitor::new(&d);
        assert_eq!(m.clamp_position(i32::MAX), (i32::MAX, false));
        d.set(h::SOFTWARE_POSITION_LIMIT_MIN, -1000);
        d.set(h::SOFTWARE_POSITION_LIMIT_MAX, 5000);
        let _ = m.refresh(&d, &MotionScale::new(4096), &UserUnits::from_dictionary(&d));
        assert_eq!(m.clamp_position(6000), (5000, true));
        assert_eq!(m.clamp_position(-1001), (-1000, true));
        assert_eq!(m.clamp_position(0), (0, false));
        // From inside: stops at the limit. From beyond the limit: holds, neither further out nor back to the limit.
        assert_eq!(m.clamp_position_from(6000, 4990), (5000, true));
        assert_eq!(m.clamp_position_from(9000, 8000), (8000, true));
        assert_eq!(m.clamp_position_from(7000, 8000), (7000, true));
        assert_eq!(m.clamp_position_from(-3000, -2000), (-2000, true));
        assert_eq!(m.clamp_position_from(100, -2000), (100, false));
        assert!(m.outside_limits(5001));
    }

    #[test]
    fn standstill_needs_the_window_time() {
        let mut d = Dictionary::new(1);
        d.set(h::STANDSTILL_WINDOW, 30);
        d.set(h::STANDSTILL_WINDOW_TIME, 2);
        let mut m = Monitor::new(&d);
        let scale = MotionScale::new(4096);
        let slow = scale.velocity_from_rpm(29);
        let fast = scale.velocity_from_rpm(31);
        assert!(!m.standstill(fast, Ticks(0)));
        assert!(!m.standstill(slow, Ticks(1)));
        assert!(!m.standstill(slow, Ticks(5)));
        assert!(m.standstill(slow, Ticks(6)));
        assert!(!m.standstill(fast, Ticks(7)));
    }
}

//! The motion parameters of the dictionary in internal units: read every slow tick as raw values (a few loads),
//! converted only when they changed (the conversions use 128-bit products: `control::trajectory::MotionScale`).
//!
//! Objects: 0x3000:05 increments per revolution; 0x6081, 0x6083..0x6086, 0x607F, 0x60C5, 0x60C6 (profile);
//! 0x6067, 0x6068, 0x606D..0x606F (windows); 0x6099, 0x609A (homing); 0x60C2 (interpolation period); 0x605A..0x605E
//! and 0x6007 (option codes, raw); 0x607E (polarity); 0x3003 and 0x3000:02 bit 12 (the gear, [`super::gear`]: the
//! rpm and rpm/s objects are load rpm with a gear, `MotionScale::geared`).
//!
//! The master's targets that the slow tick follows (0x607A in PPM, 0x60FF in PVM, the homing's 0x30B0 + 0x607C,
//! 0x30B1, 0x30B3) are converted here too, in the background step before each slow tick, when their raw value
//! changes: the slow tick reads them in the axis's units and does no conversion of its own.

use super::gear::{Gear, UserUnits};
use super::monitor::ticks_from_ms;
use super::polarity::Polarity;
use super::Windows;
use crate::cia402::OptionCodes;
use crate::control::interpolator::InterpolationPeriod;
use crate::control::trajectory::{Acceleration, MotionScale, ProfileObjects, ProfileParams, ProfileType, Velocity};
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;

/// The raw values, compared each tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct RawParams {
    inc_per_rev: u32,
    profile: ProfileObjects,
    position_window: u32,
    position_window_time: u16,
    velocity_window: u16,
    velocity_window_time: u16,
    velocity_threshold: u16,
    homing_speeds: [u32; 2],
    homing_acceleration: u32,
    period: (u8, i8),
    gear: Gear,
    polarity: u8,
}

/// The master's targets, raw (compared every background step; converted when they change).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct RawTargets {
    target_position: i32,
    target_velocity: i32,
    home_position: i32,
    home_offset: i32,
    home_offset_move_distance: i32,
    search_distance_limit: u32,
}

impl RawTargets {
    fn read(d: &Dictionary) -> Self {
        Self {
            target_position: d.get(h::TARGET_POSITION),
            target_velocity: d.get(h::TARGET_VELOCITY),
            home_position: d.get(h::HOME_POSITION),
            home_offset: d.get(h::HOME_OFFSET),
            home_offset_move_distance: d.get(h::HOME_OFFSET_MOVE_DISTANCE),
            search_distance_limit: d.get(h::HOMING_SEARCH_DISTANCE_LIMIT),
        }
    }
}

/// The master's targets in the axis's units (motor increments, internal velocity).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Targets {
    /// 0x607A through the polarity and the gear (PPM).
    pub position: i32,
    /// 0x60FF through the polarity and the geared scale (PVM).
    pub velocity: Velocity,
    /// 0x30B0 + 0x607C, the reference 0x6064 reads after homing, in the axis's coordinates (polarity bit 7; the
    /// homing moves keep the motor's direction: Gamma L1659 "no influence on homing mode").
    pub home_position: i32,
    /// 0x30B1 through the gear (a homing move: no polarity).
    pub home_offset_move_distance: i32,
    /// 0x30B3 through the gear (0 = no limit).
    pub search_distance_limit: u32,
}

impl RawParams {
    fn read(d: &Dictionary) -> Self {
        Self {
            inc_per_rev: d.get(h::MAIN_SENSOR_RESOLUTION),
            profile: ProfileObjects {
                profile_velocity: d.get(h::PROFILE_VELOCITY),
                profile_acceleration: d.get(h::PROFILE_ACCELERATION),
                profile_deceleration: d.get(h::PROFILE_DECELERATION),
                quick_stop_deceleration: d.get(h::QUICK_STOP_DECELERATION),
                max_profile_velocity: d.get(h::MAX_PROFILE_VELOCITY),
                max_acceleration: d.get(h::MAX_ACCELERATION),
                max_deceleration: d.get(h::MAX_DECELERATION),
                motion_profile_type: d.get(h::MOTION_PROFILE_TYPE),
            },
            position_window: d.get(h::POSITION_WINDOW),
            position_window_time: d.get(h::POSITION_WINDOW_TIME),
            velocity_window: d.get(h::VELOCITY_WINDOW),
            velocity_window_time: d.get(h::VELOCITY_WINDOW_TIME),
            velocity_threshold: d.get(h::VELOCITY_THRESHOLD),
            homing_speeds: [d.get(h::HOMING_SPEED_SWITCH_SEARCH), d.get(h::HOMING_SPEED_ZERO_SEARCH)],
            homing_acceleration: d.get(h::HOMING_ACCELERATION),
            period: (d.get(h::INTERPOLATION_TIME_PERIOD_VALUE), d.get(h::INTERPOLATION_TIME_INDEX)),
            gear: Gear::in_effect(d),
            polarity: d.get(h::POLARITY),
        }
    }
}

/// The motion parameters in internal units.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MotionParams {
    /// Unit conversion of the main sensor.
    pub scale: MotionScale,
    /// Profile move parameters (PPM, PVM).
    pub profile: ProfileParams,
    /// 0x6085 bounded by 0x60C5/0x60C6.
    pub quick_stop_deceleration: Acceleration,
    /// Target-reached windows.
    pub windows: Windows,
    /// 0x6099:01.
    pub homing_switch_speed: Velocity,
    /// 0x6099:02.
    pub homing_zero_speed: Velocity,
    /// 0x609A (bounded by 0x60C5).
    pub homing_acceleration: Acceleration,
    /// Homing moves: 0x6099:01 as velocity, 0x609A as acceleration and deceleration, bounded by 0x607F.
    pub homing_profile: ProfileParams,
    /// 0x60C2.
    pub period: InterpolationPeriod,
    /// The option codes (read every tick, they are plain copies).
    pub options: OptionCodes,
    /// 0x607E with the gear direction 0x3003:04 bit 0: the sign of positions and velocities ([`super::gear`]).
    pub polarity: Polarity,
    /// The master's positions to the axis's and back: polarity and gear.
    pub units: UserUnits,
    /// The dual loop's main sensor, whose increments the master's positions count ([`Self::set_main_sensor`]).
    main_sensor: Option<crate::motion::dual_loop::LoadScale>,
    /// The gear in effect.
    pub gear: Gear,
    /// The master's targets the slow tick follows, converted.
    pub targets: Targets,
    raw_targets: Option<RawTargets>,
    /// rpm per 2^-48 of a Q32 increments-per-tick velocity: `150,000 x 2^16 / N` (N increments per revolution).
    rpm_mantissa: i64,
    raw: Option<RawParams>,
}

impl MotionParams {
    /// The parameters of `d`.
    #[must_use]
    pub fn new(d: &Dictionary) -> Self {
        let scale = MotionScale::new(4096);
        let profile = ProfileObjects::default().profile_params(&scale).unwrap_or(ProfileParams {
            profile_type: ProfileType::Trapezoidal,
            velocity: Velocity::ZERO,
            max_velocity: Velocity::ZERO,
            acceleration: Acceleration::ZERO,
            deceleration: Acceleration::ZERO,
        });
        let mut p = Self {
            scale,
            profile,
            quick_stop_deceleration: Acceleration::ZERO,
            windows: Windows {
                position_window: None,
                position_window_time: crate::cia402::Ticks(0),
                velocity_window: Velocity::ZERO,
                velocity_window_time: crate::cia402::Ticks(0),
                velocity_threshold: Velocity::ZERO,
            },
            homing_switch_speed: Velocity::ZERO,
            homing_zero_speed: Velocity::ZERO,
            homing_acceleration: Acceleration::ZERO,
            homing_profile: profile,
            period: InterpolationPeriod::DISABLED,
            options: OptionCodes::DEFAULT,
            polarity: Polarity::NONE,
            units: UserUnits::NONE,
            main_sensor: None,
            gear: Gear::NONE,
            targets: Targets::default(),
            raw_targets: None,
            rpm_mantissa: 0,
            raw: None,
        };
        p.refresh(d);
        p
    }

    /// `velocity` in rpm, rounded, saturating (0x606B, 0x606C every slow tick): one 64-bit multiply; the 128-bit
    /// conversion of [`MotionScale::velocity_to_rpm`] only when the product would not fit (beyond 2^63, e.g.
    /// above about 60,000 rpm at 4,096 inc/rev) or the resolution is too fine for the mantissa (above 2^24
    /// inc/rev).
    #[must_use]
    #[inline(never)]
    pub fn rpm(&self, velocity: Velocity) -> i32 {
        let fast = if self.rpm_mantissa >= 1 << 10 { velocity.0.checked_mul(self.rpm_mantissa) } else { None };
        let rpm = match fast {
            // Round half up: 2^47 before the shift (saturating: the product may lie within 2^47 of i64::MAX).
            Some(p) => p.saturating_add(1 << 47) >> 48,
            None => self.scale.velocity_to_rpm(velocity),
        };
        i32::try_from(rpm).unwrap_or(if rpm < 0 { i32::MIN } else { i32::MAX })
    }

    /// The dual loop's main sensor (its load scale), or `None`: the master's position units follow it
    /// ([`UserUnits::with_main_sensor`]), converted again at the next [`Self::refresh`] when it changed.
    pub fn set_main_sensor(&mut self, scale: Option<crate::motion::dual_loop::LoadScale>) {
        if self.main_sensor != scale {
            self.main_sensor = scale;
            self.raw = None;
        }
    }

    /// Re-reads the dictionary; converts what changed. An invalid profile type keeps the previous profile.
    pub fn refresh(&mut self, d: &Dictionary) {
        self.options = OptionCodes {
            quick_stop: d.get(h::QUICK_STOP_OPTION_CODE),
            shutdown: d.get(h::SHUTDOWN_OPTION_CODE),
            disable_operation: d.get(h::DISABLE_OPERATION_OPTION_CODE),
            halt: d.get(h::HALT_OPTION_CODE),
            fault_reaction: d.get(h::FAULT_REACTION_OPTION_CODE),
            abort_connection: d.get(h::ABORT_CONNECTION_OPTION_CODE),
        };
        let raw = RawParams::read(d);
        if self.raw != Some(raw) {
            self.convert(raw);
            self.raw_targets = None;
        }
        let targets = RawTargets::read(d);
        if self.raw_targets != Some(targets) {
            self.convert_targets(targets);
        }
    }

    /// The master's targets in the axis's units (when they or the units changed).
    fn convert_targets(&mut self, raw: RawTargets) {
        let u = &self.units;
        self.targets = Targets {
            position: u.position_to_axis(raw.target_position),
            velocity: self.scale.velocity_from_rpm(self.polarity.velocity_rpm(raw.target_velocity)),
            home_position: u.position_to_axis(raw.home_position.wrapping_add(raw.home_offset)),
            home_offset_move_distance: u.offset_to_axis(raw.home_offset_move_distance),
            search_distance_limit: u.distance_to_axis(raw.search_distance_limit),
        };
        self.raw_targets = Some(raw);
    }

    /// Converts the parameters (when one of them changed).
    fn convert(&mut self, raw: RawParams) {
        self.gear = raw.gear;
        self.units = UserUnits::new(&raw.gear, raw.polarity).with_main_sensor(self.main_sensor);
        self.polarity = self.units.polarity;
        let gear = raw.gear;
        let scale = MotionScale::geared(raw.inc_per_rev.max(1), gear.numerator, gear.denominator);
        if let Ok(profile) = raw.profile.profile_params(&scale) {
            self.profile = profile;
        }
        self.quick_stop_deceleration = raw.profile.quick_stop_deceleration(&scale);
        self.windows = Windows {
            // 0x6067 is a load distance with a gear: in motor increments, as the axis compares.
            position_window: (raw.position_window != u32::MAX)
                .then(|| self.units.distance_to_axis(raw.position_window)),
            position_window_time: ticks_from_ms(u32::from(raw.position_window_time)),
            velocity_window: scale.velocity_from_rpm(i64::from(raw.velocity_window)),
            velocity_window_time: ticks_from_ms(u32::from(raw.velocity_window_time)),
            velocity_threshold: scale.velocity_from_rpm(i64::from(raw.velocity_threshold)),
        };
        let max = raw.profile.max_profile_velocity;
        self.homing_switch_speed = scale.velocity_from_rpm(i64::from(raw.homing_speeds[0].min(max)));
        self.homing_zero_speed = scale.velocity_from_rpm(i64::from(raw.homing_speeds[1].min(max)));
        self.homing_acceleration =
            scale.acceleration_from_rpm_per_s(raw.homing_acceleration.min(raw.profile.max_acceleration));
        if gear != Gear::NONE {
            // IDX 0x3003:03: the gear input's speed bounds the profile moves and the homing (motor rpm; PVM and CSV
            // are clamped by the monitor).
            // In load rpm (rounded down: the bound stays at or below the gear's).
            let cap = scale.velocity_from_rpm(i64::from(gear.max_system_speed(u32::MAX)));
            self.profile.velocity = self.profile.velocity.min(cap);
            self.profile.max_velocity = self.profile.max_velocity.min(cap);
            self.homing_switch_speed = self.homing_switch_speed.min(cap);
            self.homing_zero_speed = self.homing_zero_speed.min(cap);
        }
        self.homing_profile = ProfileParams {
            profile_type: self.profile.profile_type,
            velocity: self.homing_switch_speed,
            max_velocity: self.profile.max_velocity,
            acceleration: self.homing_acceleration,
            deceleration: self.homing_acceleration,
        };
        self.period = super::cyclic::period_of(raw.period.0, raw.period.1);
        // 1 inc/tick = 2,500 x 60 / N rpm (of the load: N num / den increments per load revolution); in Q32 and
        // with 16 more bits of precision for the mantissa.
        let mantissa = if gear.numerator == gear.denominator {
            u128::from((150_000_u64 << 16).checked_div(u64::from(raw.inc_per_rev)).unwrap_or(0))
        } else {
            let per_load_rev = u128::from(raw.inc_per_rev).saturating_mul(u128::from(gear.numerator));
            let rpm = 150_000_u128.saturating_mul(u128::from(gear.denominator)) << 16;
            crate::control::wide::div_rem(rpm, per_load_rev).map_or(0, |(q, _)| q)
        };
        self.rpm_mantissa = i64::try_from(mantissa).unwrap_or(0);
        self.scale = scale;
        self.raw = Some(raw);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_rpm_matches_the_exact_conversion() {
        let d = Dictionary::new(1);
        let p = MotionParams::new(&d);
        for rpm in [-25_000_i64, -3000, -1, 0, 1, 7, 100, 2449, 5000, 25_000] {
            let v = p.scale.velocity_from_rpm(rpm);
            assert_eq!(i64::from(p.rpm(v)), p.scale.velocity_to_rpm(v), "{rpm} rpm");
        }
        // Beyond the fast path's range the exact conversion takes over.
        let huge = Velocity(i64::MAX / 2);
        assert_eq!(i64::from(p.rpm(huge)), p.scale.velocity_to_rpm(huge).min(i64::from(i32::MAX)));
    }
}

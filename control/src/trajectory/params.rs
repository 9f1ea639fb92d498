//! The dictionary objects that parameterise the profile modes (0x6081, 0x6083..0x6086, 0x607F, 0x60C5, 0x60C6)
//! and the move parameters they convert to.

use super::units::{Acceleration, MotionScale, Velocity};

/// Motion profile type, object 0x6086.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum ProfileType {
    /// 0: linear ramp (trapezoidal velocity profile).
    #[default]
    Trapezoidal,
    /// 1: sin² ramp (sinusoidal profile, EPOS3 L7440): jerk-limited, peak acceleration = the profile value.
    SinSquared,
}

impl ProfileType {
    /// Decodes 0x6086: 0 trapezoidal, 1 sin² (EPOS3). Nanotec's 3 (jerk-limited with separate jerk objects
    /// 0x60A4) and any other value are rejected.
    pub fn from_0x6086(raw: i16) -> Result<Self, ProfileError> {
        match raw {
            0 => Ok(Self::Trapezoidal),
            1 => Ok(Self::SinSquared),
            other => Err(ProfileError::UnsupportedProfileType(other)),
        }
    }

    /// The 0x6086 value.
    #[must_use]
    pub const fn to_0x6086(self) -> i16 {
        match self {
            Self::Trapezoidal => 0,
            Self::SinSquared => 1,
        }
    }
}

/// Errors converting dictionary profile objects.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProfileError {
    /// 0x6086 holds a profile type this generator does not implement.
    UnsupportedProfileType(i16),
}

/// The raw dictionary objects that parameterise profile moves (units as in `firmware/device.toml`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ProfileObjects {
    /// 0x6081 profile velocity, rpm.
    pub profile_velocity: u32,
    /// 0x6083 profile acceleration, rpm/s.
    pub profile_acceleration: u32,
    /// 0x6084 profile deceleration, rpm/s.
    pub profile_deceleration: u32,
    /// 0x6085 quick-stop deceleration, rpm/s.
    pub quick_stop_deceleration: u32,
    /// 0x607F max profile velocity, rpm: bounds 0x6081 and the PVM target velocity.
    pub max_profile_velocity: u32,
    /// 0x60C5 max acceleration, rpm/s: bounds every acceleration and deceleration of the profile modes
    /// (`shared/spec/control-and-protection.md` §3.5; not used in CSx).
    pub max_acceleration: u32,
    /// 0x60C6 max deceleration, rpm/s: bounds the decelerations.
    pub max_deceleration: u32,
    /// 0x6086 motion profile type.
    pub motion_profile_type: i16,
}

impl Default for ProfileObjects {
    /// The defaults of `firmware/device.toml`.
    fn default() -> Self {
        Self {
            profile_velocity: 1000,
            profile_acceleration: 10_000,
            profile_deceleration: 10_000,
            quick_stop_deceleration: 10_000,
            max_profile_velocity: 5000,
            max_acceleration: u32::MAX,
            max_deceleration: u32::MAX,
            motion_profile_type: 0,
        }
    }
}

impl ProfileObjects {
    /// The move parameters in internal units, with the limits applied: velocity = min(0x6081, 0x607F),
    /// acceleration = min(0x6083, 0x60C5), deceleration = min(0x6084, 0x60C5, 0x60C6). Call when an object
    /// changes, not per tick.
    pub fn profile_params(&self, scale: &MotionScale) -> Result<ProfileParams, ProfileError> {
        let profile_type = ProfileType::from_0x6086(self.motion_profile_type)?;
        Ok(ProfileParams {
            profile_type,
            velocity: scale.velocity_from_rpm(i64::from(self.profile_velocity.min(self.max_profile_velocity))),
            max_velocity: scale.velocity_from_rpm(i64::from(self.max_profile_velocity)),
            acceleration: scale.acceleration_from_rpm_per_s(self.profile_acceleration.min(self.max_acceleration)),
            deceleration: scale.acceleration_from_rpm_per_s(self.limit_deceleration(self.profile_deceleration)),
        })
    }

    /// The quick-stop deceleration min(0x6085, 0x60C5, 0x60C6) in internal units.
    #[must_use]
    pub fn quick_stop_deceleration(&self, scale: &MotionScale) -> Acceleration {
        scale.acceleration_from_rpm_per_s(self.limit_deceleration(self.quick_stop_deceleration))
    }

    fn limit_deceleration(&self, raw: u32) -> u32 {
        raw.min(self.max_acceleration).min(self.max_deceleration)
    }
}

/// The parameters of one profile move or velocity command, in internal units.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ProfileParams {
    /// Ramp shape (0x6086).
    pub profile_type: ProfileType,
    /// Peak velocity of a position move (0x6081, bounded by 0x607F); magnitude, negative values count as positive.
    pub velocity: Velocity,
    /// Bound of a PVM target velocity (0x607F).
    pub max_velocity: Velocity,
    /// Acceleration (0x6083, bounded by 0x60C5); for sin² the peak of the acceleration curve.
    pub acceleration: Acceleration,
    /// Deceleration (0x6084, bounded by 0x60C5 and 0x60C6); for sin² the peak.
    pub deceleration: Acceleration,
}

//! The cyclic synchronous modes CSP (8), CSV (9) and CST (10): the master's set-points, latched when the fieldbus
//! reports one ([`Cyclic::push`], at SYNC / SM2 event), interpolated over 0x60C2 by
//! [`crate::control::interpolator`] into the loops' demand (`shared/spec/cia402-device-control.md` §2.5-§2.8).
//!
//! - CSP follows 0x607A + 0x60B0 with the interpolator's velocity and acceleration feedforward (plus 0x60B1 as
//!   velocity feedforward, E3/GT); CSV follows 0x60FF + 0x60B1 on the velocity loop; CST 0x6071 + 0x60B2.
//! - The torque offset 0x60B2 is a torque feedforward in CSP (IDX L977 "optional torque feed forward input",
//!   L6345) and in CSV (Gamma L1720, EPOS3 L7730-7740; IDX L1016 leaves it out of CSV, device.toml's note):
//!   [`Cyclic::take_torque_feedforward`], converted as CST converts it (clamped to +-0x6072, then to the current
//!   limit) and added by the loops to the position or velocity controller's output before the current limit
//!   ([`super::loops::Loops::step`]). It takes effect with the set-point it came with, is held between set-points
//!   (a step, as the master sends it) and drops to 0 when the stream is lost and the interpolator holds.
//! - Statusword bit 12 "drive follows the command value" while set-points arrive (or one lost period is bridged);
//!   0 before the first set-point and while holding after missing ones. Bits 10 and 13 are reserved here (bit 13
//!   of CSP, the following error, is the monitor's).
//! - Entering the mode, the interpolator restarts at the actual demand (E3 L8816: no following error at
//!   re-enable) and waits for the first set-point, holding position (CSP), velocity (CSV) or zero torque (CST).

use super::{LoopDemand, ModeStatus, ModeStep};
use crate::cia402::Mode;
use crate::control::interpolator::{
    CyclicInterpolator, CyclicMode, CyclicSetpoint, InterpolationPeriod, SetpointStatus,
};
use crate::control::trajectory::{Setpoint, Velocity};

/// The interpolation period of 0x60C2; an invalid one (shorter than a slow tick, out of range) falls back to no
/// interpolation (each set-point applied at the next tick), which is what IDX does for value 0.
#[must_use]
pub fn period_of(value: u8, index: i8) -> InterpolationPeriod {
    InterpolationPeriod::from_0x60c2(value, index).unwrap_or(InterpolationPeriod::DISABLED)
}

/// The interpolator mode of a cyclic CiA 402 mode.
#[must_use]
pub const fn cyclic_mode(mode: Mode) -> Option<CyclicMode> {
    match mode {
        Mode::CyclicSyncPosition => Some(CyclicMode::Position),
        Mode::CyclicSyncVelocity => Some(CyclicMode::Velocity),
        Mode::CyclicSyncTorque => Some(CyclicMode::Torque),
        _ => None,
    }
}

/// The cyclic modes.
#[derive(Clone, Debug)]
pub struct Cyclic {
    interpolator: CyclicInterpolator,
    /// The torque feedforward of the last step (CSP, CSV), per mille of rated torque.
    torque_feedforward: i32,
}

impl Default for Cyclic {
    fn default() -> Self {
        Self::new()
    }
}

impl Cyclic {
    /// CSP without interpolation, at rest at 0.
    #[must_use]
    pub fn new() -> Self {
        Self {
            interpolator: CyclicInterpolator::new(CyclicMode::Position, InterpolationPeriod::DISABLED),
            torque_feedforward: 0,
        }
    }

    /// Starts following in `mode` with `period`, from `position` moving at `velocity`.
    pub fn enter(&mut self, mode: CyclicMode, period: InterpolationPeriod, position: i32, velocity: Velocity) {
        if self.interpolator.mode() != mode || self.interpolator.period() != period {
            self.interpolator = CyclicInterpolator::new(mode, period);
        }
        self.interpolator.reset(i64::from(position), velocity);
    }

    /// A master set-point arrived (SYNC, SM2 event, or a process-data write in free run).
    pub fn push(&mut self, setpoint: CyclicSetpoint) {
        self.interpolator.push(setpoint);
    }

    /// The interpolation period in use.
    #[must_use]
    pub const fn period(&self) -> InterpolationPeriod {
        self.interpolator.period()
    }

    /// Set-points that arrived twice within one period (the later one was used).
    #[must_use]
    pub const fn overruns(&self) -> u32 {
        self.interpolator.overruns()
    }

    /// Whether the set-point stream has stopped beyond the bridged period (holding).
    #[must_use]
    pub const fn setpoint_missing(&self) -> bool {
        self.interpolator.output().setpoint_missing()
    }

    /// The torque feedforward 0x60B2 of the last step in CSP and CSV, per mille of rated torque, taken (0 until
    /// the next step); 0 in CST (there the offset is in the torque demand itself).
    #[must_use]
    pub fn take_torque_feedforward(&mut self) -> i32 {
        core::mem::take(&mut self.torque_feedforward)
    }

    /// One tick.
    pub fn step(&mut self) -> ModeStep {
        let out = self.interpolator.step();
        self.torque_feedforward = out.torque;
        let demand = match self.interpolator.mode() {
            CyclicMode::Position => LoopDemand::Position(Setpoint {
                position: out.position,
                position_fine: out.position_fine,
                velocity: out.velocity,
                acceleration: out.acceleration,
            }),
            CyclicMode::Velocity => LoopDemand::Velocity { velocity: out.velocity, acceleration: out.acceleration },
            CyclicMode::Torque => {
                self.torque_feedforward = 0;
                LoopDemand::Torque { permille: out.torque }
            }
        };
        let follows = matches!(out.status, SetpointStatus::Following | SetpointStatus::Extrapolating { .. });
        ModeStep { demand, status: ModeStatus { target_reached: false, bit12: follows, bit13: false } }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csp_waits_then_follows_and_reports_bit_12() {
        let mut c = Cyclic::new();
        c.enter(CyclicMode::Position, period_of(0, -3), 500, Velocity::ZERO);
        let s = c.step();
        assert!(!s.status.bit12);
        assert!(matches!(s.demand, LoopDemand::Position(sp) if sp.position == 500));
        c.push(CyclicSetpoint { target_position: 510, ..CyclicSetpoint::default() });
        let s = c.step();
        assert!(s.status.bit12);
        assert!(matches!(s.demand, LoopDemand::Position(sp) if sp.position == 510));
    }

    #[test]
    fn cst_demands_target_plus_offset() {
        let mut c = Cyclic::new();
        c.enter(CyclicMode::Torque, period_of(0, -3), 0, Velocity::ZERO);
        c.push(CyclicSetpoint { target_torque: 300, torque_offset: -50, ..CyclicSetpoint::default() });
        let s = c.step();
        assert_eq!(s.demand, LoopDemand::Torque { permille: 250 });
    }

    /// IDX L977: 0x60B2 is CSP's torque feedforward (CSV's too, Gamma L1720): held from its set-point on, and 0 once
    /// the set-points stop beyond the bridged period and the interpolator holds (a lost master must not leave a
    /// torque pushing the axis); in CST it is part of the torque demand, not a feedforward.
    #[test]
    fn torque_offset_is_the_feedforward_until_the_stream_is_lost() {
        for mode in [CyclicMode::Position, CyclicMode::Velocity] {
            let mut c = Cyclic::new();
            c.enter(mode, period_of(2, -3), 0, Velocity::ZERO);
            c.push(CyclicSetpoint { torque_offset: 120, ..CyclicSetpoint::default() });
            let _ = c.step();
            assert_eq!(c.take_torque_feedforward(), 120, "{mode:?}");
            assert_eq!(c.take_torque_feedforward(), 0, "{mode:?}: taken");
            // 2 ms = 5 slow ticks per period: one missing period is bridged, the next one holds.
            let held: Vec<i32> = (0..15).map(|_| (c.step(), c.take_torque_feedforward()).1).collect();
            assert_eq!(held.first(), Some(&120), "{mode:?}: {held:?}");
            assert_eq!(held.last(), Some(&0), "{mode:?}: {held:?}");
            assert!(c.setpoint_missing(), "{mode:?}");
        }
        let mut c = Cyclic::new();
        c.enter(CyclicMode::Torque, period_of(0, -3), 0, Velocity::ZERO);
        c.push(CyclicSetpoint { torque_offset: 120, ..CyclicSetpoint::default() });
        assert_eq!(c.step().demand, LoopDemand::Torque { permille: 120 });
        assert_eq!(c.take_torque_feedforward(), 0);
    }

    #[test]
    fn invalid_period_means_no_interpolation() {
        assert_eq!(period_of(1, -4), InterpolationPeriod::DISABLED);
        assert!(period_of(1, -3).is_enabled());
    }
}

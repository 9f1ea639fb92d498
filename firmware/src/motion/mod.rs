//! The motion layer of tier 2 (2.5 kHz): the operating modes of CiA 402 on top of the current loop.
//!
//! Each mode is a sans-IO state machine (ARCHITECTURE.md convention 1) stepped once per slow tick with the axis
//! feedback of that tick ([`AxisFeedback`]) and its own inputs (controlword bits, targets, parameters already
//! converted to internal units), and returns a [`ModeStep`]: what the loops must follow ([`LoopDemand`]) and the
//! mode's statusword bits ([`ModeStatus`]). The profile modes share one
//! [`ProfileGenerator`](crate::control::trajectory::ProfileGenerator), owned by the axis and lent to the active mode,
//! so a change of mode or a stop continues from the demand the previous mode left.
//!
//! Units inside the layer: positions in increments (`i32`, wrapping like 0x6064), velocities and accelerations in
//! the trajectory generator's fixed-point units ([`Velocity`], [`Acceleration`]: increments per slow tick in Q32,
//! per tick² in Q40). Dictionary units (rpm, rpm/s, ms) are converted by the caller when a parameter changes.
//!
//! Files: [`profile_position`] (PPM, 0x6060 = 1), [`profile_velocity`] (PVM, 3), [`homing`] (HMM, 6) hold the
//! modes; [`axis`] ties them, the cyclic modes (8, 9, 10), the stops of the CiA 402 machine, the position and
//! velocity loops and the monitoring together for [`crate::drive::Drive::slow_tick`]; [`torque_ramp`] is CST's
//! slow-down ramp (torque slope 0x6087); [`dual_loop`] is the dual loop's configuration and its
//! load-encoder position; [`polarity`] is 0x607E, the sign of the values exchanged with the master.

pub mod axis;
pub mod cyclic;
pub mod dual_loop;
pub mod gear;
pub mod homing;
pub mod loops;
pub mod monitor;
pub mod params;
pub mod polarity;
pub mod profile_position;
pub mod profile_velocity;
pub mod torque_ramp;

use crate::cia402::Ticks;
use crate::control::trajectory::{Acceleration, Setpoint, Velocity};
use crate::sensors::latch::{EdgeLatch, SwitchEdges};

/// What the modes know about the axis in one slow tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct AxisFeedback {
    /// Slow ticks since start-up.
    pub now: Ticks,
    /// Position actual value 0x6064, increments (home offset applied).
    pub position: i32,
    /// Velocity actual value (the estimate the velocity loop uses), increments per slow tick in Q32.
    pub velocity: Velocity,
    /// Averaged q current, mA (0x30D1:01; homing methods -1..-4 compare it with 0x30B2).
    pub current_average_ma: i32,
    /// Negative limit switch (input function 0).
    pub negative_limit: SwitchEdges,
    /// Positive limit switch (input function 1).
    pub positive_limit: SwitchEdges,
    /// Home switch (input function 2).
    pub home_switch: SwitchEdges,
    /// Encoder index pulses (rising edges only; `activated` = the index).
    pub index: EdgeLatch,
}

/// What the position and velocity loops follow in one slow tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoopDemand {
    /// Position control: the demand position with velocity and acceleration feedforward (PPM, HMM, CSP, holds).
    Position(Setpoint),
    /// Velocity control (PVM, CSV).
    Velocity {
        /// Velocity demand.
        velocity: Velocity,
        /// Acceleration demand (feedforward).
        acceleration: Acceleration,
    },
    /// Torque control (CST): torque demand, per mille of the rated torque 0x6076.
    Torque {
        /// Per mille of rated torque (0x6071 units, wider to hold the sum with 0x60B2).
        permille: i32,
    },
}

/// The statusword bits a mode owns (CiA 402 / IDX Table 2-8: bit 10 target reached, bits 12 and 13 operation
/// mode specific).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct ModeStatus {
    /// Bit 10.
    pub target_reached: bool,
    /// Bit 12 (PPM set-point acknowledge, PVM speed is zero, HMM homing attained, CSx drive follows the command
    /// value).
    pub bit12: bool,
    /// Bit 13 (PPM/CSP following error — set by the monitor, not by the mode; HMM homing error).
    pub bit13: bool,
}

/// One step of a mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ModeStep {
    /// What the loops follow.
    pub demand: LoopDemand,
    /// The mode's statusword bits.
    pub status: ModeStatus,
}

/// The windows that decide "target reached" and "speed is zero" (0x6067/0x6068, 0x606D/0x606E, 0x606F), in
/// internal units.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Windows {
    /// 0x6067 position window, increments; `None` for 0xFFFFFFFF (target reached = end of the trajectory,
    /// E3 L6922-6987).
    pub position_window: Option<u32>,
    /// 0x6068 position window time.
    pub position_window_time: Ticks,
    /// 0x606D velocity window (magnitude).
    pub velocity_window: Velocity,
    /// 0x606E velocity window time.
    pub velocity_window_time: Ticks,
    /// 0x606F velocity threshold (magnitude): PVM "speed is zero" below it.
    pub velocity_threshold: Velocity,
}

//! Pure control math in fixed point: frames, angles, transforms, controllers, modulation, and the data contract
//! of the power stage ([`power`]). The firmware re-exports this crate as `firmware::control` (and [`power`] as
//! `firmware::hal::power`).
//!
//! Everything here is `no_std`, allocation-free, float-free and panic-free for every input, so that it can run in
//! the 25 kHz interrupt (tier 1 of `shared/design/ARCHITECTURE.md`) and be property-tested on the host.
//! Arithmetic is saturating or wrapping by deliberate choice, with the range argument next to each wrapping site
//! (convention 10). Formats: currents and voltages `I16F16` ([`frames`]), sin/cos `I2F30` ([`trig`]), angles a
//! wrapping `u32` turn ([`angle`]), PI gains `I8F24` and `I1F31` ([`pi`]).
//!
//! - [`power`]: what the power stage and its sensors exchange with the current loop once per PWM period.
//! - [`units`]: every unit newtype (`Amps`, `Volts`, `ElectricalAngle`, `AngleDelta`, `Increments`, `IncPerTick`,
//!   `IncPerTick2`, `Velocity`, `Acceleration`), defined by one macro, and the conversions between units; the
//!   modules below re-export the ones they work with.
//! - [`angle`]: `ElectricalAngle`, a wrapping fraction of a turn.
//! - [`trig`]: table sin/cos with interpolation.
//! - [`frames`]: `Amps`, `Volts`, `Abc`, `AlphaBeta`, `Dq`.
//! - [`transforms`]: Clarke, Park, inverse Park.
//! - [`pi`]: PI with back-calculation anti-windup, gains from IDX 0x30A0.
//! - [`svpwm`]: voltage limit, bus compensation, SVPWM, duty clamp.
//! - [`current_loop`]: the whole FOC step, [`current_loop::foc_step`].
//! - [`dual_loop`]: EPOS4's dual-loop main loop with its gain scheduler (load position to motor velocity demand).
//! - [`wide`]: 128-bit multiply-shift, division and square root on the 32-bit core (the profile generator's).

#![cfg_attr(not(test), no_std)]
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing,
        clippy::arithmetic_side_effects
    )
)]

pub mod angle;
pub mod current_loop;
pub mod demand;
pub mod dual_loop;
pub mod frames;
pub mod interpolator;
pub mod observer;
pub mod pi;
pub mod position;
pub mod power;
pub mod svpwm;
pub mod trajectory;
pub mod transforms;
pub mod trig;
pub mod units;
pub mod velocity;
pub mod velocity_estimate;
pub mod wide;

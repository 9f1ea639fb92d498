//! A small motor and inverter model that feeds tier 1 in the QEMU image, in place of the ADC, encoder, Halls and
//! digital inputs QEMU does not model. It is deliberately simple (the full plant is `hal-sim`'s, on the host): a
//! sinusoidal PMSM with the reference motor's resistance, inductance and flux linkage, an ideal inverter on a stiff
//! 24 V bus, and a rotor that either
//! - turns freely ([`Shaft::Free`], from start-up): the motor's torque accelerates the reference inertia (rotor +
//!   load, 176 g cm^2) against viscous friction, so the drive's position and velocity loops close through it; or
//! - follows a fixed speed profile ([`Shaft::Profile`]: still for [`HOLD_TICKS`], then 0 -> 4,000 rpm -> reversed
//!   -> 0 in [`PROFILE_TICKS`]), so that the fast tick sees every angle, both directions, unsaturated and saturated
//!   voltage demands, whatever current it is asked for.
//!
//! The encoder index sits at angle 0; digital input 4 (general purpose D by default, 0x3142:04 = 19) is a cam that
//! is high over the first half of every turn, so that moves make input edges for tier 1 to latch. Its edge at angle
//! 0 falls in the same period as the index and an H1 edge: the fast tick's worst case of latching.
//! Explicit Euler in four sub-steps per PWM period; `f32` with micromath (no `std`).

use core::sync::atomic::{AtomicBool, Ordering};

use micromath::F32Ext;

use crate::hal::power::{
    AdcSamples, FeedbackSample, Measurements, PwmCommand, ADC_FULL_SCALE, PWM_FREQUENCY_HZ, PWM_PERIOD_TICKS,
};

/// Phase resistance, ohm (reference motor).
const R_OHM: f32 = 0.26;
/// Phase inductance, H.
const L_H: f32 = 0.165e-3;
/// Pole pairs.
const POLE_PAIRS: f32 = 7.0;
/// Permanent-magnet flux linkage, Wb: k_t / (1.5 x pole pairs) = 0.0335 / 10.5.
const PSI_WB: f32 = 0.0335 / 10.5;
/// DC bus, V.
const BUS_V: f32 = 24.0;
/// ADC: +-16.5 A over the 12-bit range, mid-scale at zero current.
const ADC_COUNTS_PER_A: f32 = 4096.0 / 33.0;
/// ADC: 60 V full scale on the bus divider.
const ADC_COUNTS_PER_V: f32 = 4096.0 / 60.0;
/// Torque constant, N m per A of q current: 1.5 x pole pairs x flux linkage (= 0.0335, the reference motor's k_t).
const KT_NM_PER_A: f32 = 1.5 * POLE_PAIRS * PSI_WB;
/// Inertia of rotor and load, kg m^2 (reference plant: 44 g cm^2 rotor, three times that as load).
const INERTIA_KG_M2: f32 = 4.0 * 44.0e-7;
/// Viscous friction, N m s/rad (reference plant).
const VISCOUS_NM_S: f32 = 2.0e-6;
/// Digital input driven by the cam (bit 3 = input 4).
const CAM_INPUT: u8 = 1 << 3;
/// Hall states of the six 60-degree electrical sectors from angle 0: the reference motor's (as `hal-sim`'s), H1
/// rising at 0 degrees electrical, H2 at 120, H3 at 240, so the drive's default Hall offset 0x301A:03 = 0 holds
/// and its positive q current turns the rotor forward.
const HALL_PATTERN: [u8; 6] = [0b101, 0b001, 0b011, 0b010, 0b110, 0b100];
/// Encoder counts per mechanical revolution (1,024 lines, x4).
const ENCODER_COUNTS: f32 = 4096.0;
/// Sub-steps per PWM period.
const SUBSTEPS: u32 = 4;
/// PWM period, s.
const PERIOD_S: f32 = 1.0 / PWM_FREQUENCY_HZ as f32;
/// Speed profile: peak mechanical speed, rad/s (4,000 rpm), and ticks per profile segment.
const PEAK_SPEED: f32 = 4000.0 / 60.0 * core::f32::consts::TAU;
const SEGMENT_TICKS: u32 = 500;
/// Periods at standstill before the speed profile starts (the drive's current-offset calibration needs a still
/// rotor), counted from the selection of [`Shaft::Profile`].
pub const HOLD_TICKS: u32 = 400;
/// Periods of one pass through the profile after the hold.
pub const PROFILE_TICKS: u32 = 6 * SEGMENT_TICKS;
const TAU: f32 = core::f32::consts::TAU;

/// How the rotor moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shaft {
    /// Driven by the motor's torque (the start-up state).
    Free,
    /// Forced through the speed profile, restarted (with its hold) at every selection.
    Profile,
}

/// The shaft selection: written by the QEMU bench (tier 3) through [`select`], read by the plant in tier 1 every
/// period (one writer; a single flag, so no ordering with other data is needed).
static PROFILE: AtomicBool = AtomicBool::new(false);

/// Selects how the rotor moves from the next PWM period on.
pub fn select(shaft: Shaft) {
    PROFILE.store(shaft == Shaft::Profile, Ordering::Relaxed);
}

/// State of the model.
#[derive(Debug, Clone)]
pub struct Plant {
    /// Stator current in the stationary frame, A.
    i_alpha: f32,
    i_beta: f32,
    /// Mechanical angle, rad, wrapped to [0, 2 pi).
    theta: f32,
    /// Mechanical speed, rad/s.
    omega: f32,
    /// Whole mechanical turns (wrapping; only its low bits reach the 16-bit count).
    turns: i32,
    /// Encoder count (wrapping at 2^16, as the timer).
    count: u16,
    /// Count at the last index crossing, until read.
    index: Option<u16>,
    /// Periods since [`Shaft::Profile`] was selected (0 while the shaft is free).
    profile_ticks: u32,
}

impl Default for Plant {
    fn default() -> Self {
        Self::new()
    }
}

impl Plant {
    /// At rest, no current, rotor at a quarter turn.
    pub const fn new() -> Self {
        Self { i_alpha: 0.0, i_beta: 0.0, theta: 1.5, omega: 0.0, turns: 0, count: 978, index: None, profile_ticks: 0 }
    }

    /// Samples of this period's centre.
    pub fn measure(&mut self) -> Measurements {
        // Phase currents from the stationary frame (inverse Clarke, amplitude-invariant).
        let ia = self.i_alpha;
        let ib = -0.5 * self.i_alpha + 0.866_025_4 * self.i_beta;
        let ic = -ia - ib;
        let adc = |amps: f32| (2048.0 + amps * ADC_COUNTS_PER_A).clamp(0.0, f32::from(ADC_FULL_SCALE)) as u16;
        let elec = (self.theta * POLE_PAIRS) % TAU;
        let sector = (elec / (TAU / 6.0)) as u8; // 0..=5
        Measurements {
            adc: AdcSamples {
                phase_currents: [adc(ia), adc(ib), adc(ic)],
                bus_voltage: (BUS_V * ADC_COUNTS_PER_V) as u16,
                temperature: 1200,
                motor_temperature: 1200,
            },
            feedback: FeedbackSample {
                encoder_count: self.count,
                index_latch: self.index.take(),
                hall: HALL_PATTERN.get(usize::from(sector)).copied().unwrap_or(0),
                digital_inputs: if self.theta < TAU / 2.0 { CAM_INPUT } else { 0 },
                // The QEMU image runs on the incremental encoder (no SSI sensor in this plant).
                ssi_frame: 0,
            },
            break_input: false,
        }
    }

    /// Applies `cmd` for one PWM period.
    pub fn step(&mut self, cmd: &PwmCommand) {
        let profile = PROFILE.load(Ordering::Relaxed);
        if profile {
            self.profile_ticks = self.profile_ticks.wrapping_add(1);
            // Speed profile after the hold: ramp up, hold, ramp down through zero to reverse, hold, ramp back to
            // zero.
            let t = self.profile_ticks.saturating_sub(HOLD_TICKS);
            let phase = t.checked_div(SEGMENT_TICKS).unwrap_or(0);
            let frac = t.checked_rem(SEGMENT_TICKS).unwrap_or(0) as f32 / SEGMENT_TICKS as f32;
            self.omega = PEAK_SPEED
                * match phase.checked_rem(6).unwrap_or(0) {
                    0 => frac,
                    1 => 1.0,
                    2 => 1.0 - 2.0 * frac,
                    3 => -1.0,
                    4 => -1.0 + frac,
                    _ => 0.0,
                };
        } else {
            self.profile_ticks = 0;
        }

        // Average phase voltages over the period; the common mode drops out in Clarke.
        let (v_alpha, v_beta) = if cmd.enabled {
            let v = |duty: u16| f32::from(duty.min(PWM_PERIOD_TICKS)) / f32::from(PWM_PERIOD_TICKS) * BUS_V;
            let [a, b, c] = cmd.duty;
            let (va, vb, vc) = (v(a), v(b), v(c));
            ((2.0 * va - vb - vc) / 3.0, (vb - vc) * 0.577_350_3)
        } else {
            (0.0, 0.0)
        };

        let dt = PERIOD_S / SUBSTEPS as f32;
        for _ in 0..SUBSTEPS {
            let elec = self.theta * POLE_PAIRS;
            let (s, c) = elec.sin_cos();
            let w_e = self.omega * POLE_PAIRS;
            let (e_alpha, e_beta) = (-w_e * PSI_WB * s, w_e * PSI_WB * c);
            if !profile {
                // Torque of the q current (the amplitude-invariant frames make it 1.5 p psi i_q).
                let i_q = c * self.i_beta - s * self.i_alpha;
                let torque = KT_NM_PER_A * i_q - VISCOUS_NM_S * self.omega;
                self.omega += dt / INERTIA_KG_M2 * torque;
            }
            if cmd.enabled {
                self.i_alpha += dt / L_H * (v_alpha - R_OHM * self.i_alpha - e_alpha);
                self.i_beta += dt / L_H * (v_beta - R_OHM * self.i_beta - e_beta);
            } else {
                // Outputs off: the bridge diodes clamp the current to zero within the period.
                self.i_alpha = 0.0;
                self.i_beta = 0.0;
            }
            self.advance(self.omega * dt);
        }
    }

    fn advance(&mut self, dtheta: f32) {
        let before = self.theta;
        let mut theta = before + dtheta;
        // The index sits at angle 0: latch the count when it is crossed either way.
        let crossed = !(0.0..TAU).contains(&theta);
        if theta >= TAU {
            theta -= TAU;
            self.turns = self.turns.wrapping_add(1);
        } else if theta < 0.0 {
            theta += TAU;
            self.turns = self.turns.wrapping_sub(1);
        }
        self.theta = theta;
        let within = (theta / TAU * ENCODER_COUNTS) as i32;
        // The timer's 16 bits of the total count.
        self.count = self.turns.wrapping_mul(ENCODER_COUNTS as i32).wrapping_add(within) as u16;
        if crossed {
            self.index = Some(self.count);
        }
    }
}

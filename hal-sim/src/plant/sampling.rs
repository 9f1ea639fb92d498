//! What the sensors capture: the encoder counter and its index latch, followed after every segment and half-period stretch; at the centre
//! of the period, the ADC sample of the shunts, the bus voltage and the temperatures, and the encoder and Hall
//! readings, with their noise and the injected sensor faults ([`super::faults::PlantFaults`]).

use firmware::hal::power::{AdcSamples, FeedbackSample, Measurements};

use super::inverter::{self, LegPattern, LegState};
use super::{sensors, Plant};

impl Plant {
    /// Follow the encoder after a segment: latch the counter if the index state was entered.
    ///
    /// Injected sensor faults change only what the counter shows, never the shaft: with the A/B lines swapped it
    /// counts backwards (no index latched meanwhile); with the A/B lines broken the
    /// counter holds its value while the shaft turns (the motion goes into `encoder_error`) and the index, which
    /// needs the A/B state, is not latched either; with the index line broken no pulse reaches the latch. The
    /// latched value is the counter's at the index, spurious counts included.
    pub(super) fn update_encoder(&mut self) {
        let count = self.count_now();
        if self.faults.encoder_wire_break {
            self.encoder_error -= count - self.last_count;
        } else if self.faults.encoder_reversed {
            // The counter moves by the negated motion: twice the motion taken off what the shaft adds.
            self.encoder_error -= 2 * (count - self.last_count);
        } else if let Some(n) =
            sensors::index_entry(self.last_count, count, self.params.encoder_counts_per_rev, self.params.index_count)
        {
            if !self.faults.index_lost {
                self.pending_index = Some(sensors::counter_register(n + self.encoder_error));
            }
        }
        self.last_count = count;
    }

    /// A noise burst ([`super::faults::EncoderNoise`]) adds its spurious counts once per period, at the sample, until it
    /// has lasted its periods.
    fn apply_encoder_noise(&mut self) {
        if let Some(noise) = self.faults.encoder_noise.as_mut() {
            if noise.periods_left > 0 {
                self.encoder_error += i64::from(noise.counts_per_period);
                noise.periods_left -= 1;
            }
            if noise.periods_left == 0 {
                self.faults.encoder_noise = None;
            }
        }
    }

    /// The SSI frame the drive reads in this period: the one latched at the last sample (one period's sampling
    /// delay), with the injected SSI faults; the frame of the rotor's angle now is latched for the next period.
    /// Without an SSI sensor, 0.
    pub(super) fn ssi_frame(&mut self) -> u32 {
        let p = &self.params;
        if p.ssi_single_turn_bits == 0 {
            return 0;
        }
        let frame_bits = p.ssi_single_turn_bits + p.ssi_multi_turn_bits + if p.ssi_frame_check { 2 } else { 0 };
        let now = self.ssi_frame_now();
        let mut delivered = core::mem::replace(&mut self.ssi_latched, now);
        if self.faults.ssi_clock_stuck || self.faults.ssi_missing {
            // The data line idles high: every clocked bit reads 1.
            delivered = u32::MAX >> (32 - frame_bits);
        }
        if let Some(bit) = self.faults.ssi_flip_bit_once.take() {
            delivered ^= 1 << bit;
        }
        delivered
    }

    /// The SSI frame of the rotor's true angle now (0 without an SSI sensor).
    pub(super) fn ssi_frame_now(&self) -> u32 {
        let p = &self.params;
        if p.ssi_single_turn_bits == 0 {
            return 0;
        }
        sensors::ssi_frame(
            self.theta_m,
            p.ssi_single_turn_bits,
            p.ssi_multi_turn_bits,
            p.ssi_gray,
            p.ssi_frame_check,
            p.ssi_offset_counts,
        )
    }

    /// The total encoder count of the rotor's true angle now, without the injected sensor faults.
    pub(super) fn count_now(&self) -> i64 {
        sensors::encoder_count(self.theta_m, self.params.encoder_counts_per_rev, self.params.encoder_offset_counts)
    }

    /// The currents through the shunts A, B, C at `t` into the period (with the legs switching by `patterns`, or
    /// all off) with the phase currents `i_abc`: the phase current, plus a short's share, where the low switch or
    /// the low diode conducts, else 0.
    fn shunt_currents(&self, patterns: &[LegPattern; 3], switching: bool, t: f64, i_abc: [f64; 3]) -> [f64; 3] {
        let mut i = i_abc;
        // A short between two outputs ([`inverter::OutputShort`]) adds its current to what the two legs carry
        // (zero at the centre while both low switches are on).
        let short = inverter::OutputShort::new(self.faults.phase_short, self.params.switch_resistance_ohm);
        if let Some(short) = short.filter(|_| switching) {
            let p = &self.params;
            let poles =
                core::array::from_fn(|x| patterns[x].state_at(t).pole_voltage(i[x], self.v_bus, p.diode_drop_v));
            let s = short.leg_currents(poles);
            for x in 0..3 {
                i[x] += s[x];
            }
        }
        core::array::from_fn(|x| {
            let low_conducts = if switching {
                match patterns[x].state_at(t) {
                    LegState::Low => true,
                    LegState::Off => i[x] > 0.0,
                    LegState::High => false,
                }
            } else {
                i[x] > 0.0
            };
            if low_conducts {
                i[x]
            } else {
                0.0
            }
        })
    }

    /// The sample at the centre of the period (`sample_t`, reached at `t`): ADC codes, encoder, index latch, Halls,
    /// digital inputs and the break input, as [`Plant::step`] returns them; records the true state at the sample.
    pub(super) fn sample(
        &mut self,
        patterns: &[LegPattern; 3],
        switching: bool,
        sample_t: f64,
        t: f64,
    ) -> Measurements {
        self.apply_encoder_noise();
        let i_abc = self.i_abc();
        let shunt = self.shunt_currents(patterns, switching, sample_t, i_abc);
        let p = &self.params;
        let mut phase_currents = [0u16; 3];
        for x in 0..3 {
            let noise = self.rng.gaussian() * p.shunt_noise_lsb_rms;
            let lsb = sensors::ADC_MID_SCALE + p.shunt_offset_lsb[x] + p.shunt_gain_lsb_per_a[x] * shunt[x] + noise;
            phase_currents[x] = sensors::adc_code(lsb);
        }
        let bus_noise = self.rng.gaussian() * p.bus_noise_lsb_rms;
        let bus_voltage = sensors::adc_code(p.bus_gain_lsb_per_v * self.v_bus + bus_noise);
        let temp_noise = self.rng.gaussian() * p.temp_noise_lsb_rms;
        let full_scale = f64::from(firmware::hal::power::ADC_FULL_SCALE);
        let sensor_v = p.temp_sensor_v_at_0c + p.temp_sensor_v_per_k * self.t_power_stage;
        let temperature = sensors::adc_code(sensor_v / p.adc_reference_v * full_scale + temp_noise);
        let motor_noise = self.motor_sensor_rng.gaussian() * p.temp_noise_lsb_rms;
        let motor_v = p.temp_sensor_v_at_0c + p.temp_sensor_v_per_k * self.t_winding;
        let motor_temperature = match self.faults.motor_temperature_code_stuck {
            Some(code) => code,
            None => sensors::adc_code(motor_v / p.adc_reference_v * full_scale + motor_noise),
        };
        // A stuck Hall sensor or a broken Hall cable reads its fixed state whatever the rotor does.
        let hall = match self.faults.hall_stuck {
            Some(stuck) => stuck,
            None => sensors::hall_state(f64::from(p.pole_pairs) * self.theta_m, p.hall_offset_rad),
        };
        let feedback = FeedbackSample {
            encoder_count: sensors::counter_register(self.last_count + self.encoder_error),
            index_latch: self.pending_index.take(),
            hall,
            digital_inputs: self.io.input_levels(&p.io, self.last_count),
            ssi_frame: self.ssi_frame(),
        };
        let mut state = self.state_with(t, i_abc);
        state.shunt_currents_a = shunt;
        self.at_sample = state;
        Measurements {
            adc: AdcSamples { phase_currents, bus_voltage, temperature, motor_temperature },
            feedback,
            break_input: self.break_latched,
        }
    }
}

/// The injected encoder and Hall faults ([`faults::PlantFaults`]) change what the sensors report, exactly, and
/// nothing else: the shaft is driven at a fixed speed by the dynamometer with the outputs off, so the true count
/// is known at every period.
#[cfg(test)]
mod sensor_fault_tests {
    use core::f64::consts::PI;

    use firmware::hal::power::{Measurements, PwmCommand};

    use crate::plant::{faults, sensors, Mechanics, Plant, PlantParams, PERIOD_S};

    /// Radians per encoder count of the reference encoder.
    const RAD_PER_COUNT: f64 = 2.0 * PI / 4096.0;

    /// The reference plant, shaft at `start_counts + 0.5` counts, driven at `counts_per_period` counts per period.
    fn driven(start_counts: f64, counts_per_period: f64) -> Plant {
        let mut p = Plant::new(PlantParams::reference(), 1);
        let speed = counts_per_period * RAD_PER_COUNT / PERIOD_S;
        p.set_rotor_state((start_counts + 0.5) * RAD_PER_COUNT, speed);
        p.set_mechanics(Mechanics::Driven { speed_rad_s: speed });
        p
    }

    /// Runs `n` periods with the outputs off; the measurements of each.
    fn run(p: &mut Plant, n: usize) -> Vec<Measurements> {
        (0..n).map(|_| p.step(&PwmCommand::OFF)).collect()
    }

    /// The true count at the last sample.
    fn true_count(p: &Plant) -> i64 {
        sensors::encoder_count(p.state_at_sample().theta_m_rad, 4096, 0)
    }

    #[test]
    fn wire_break_freezes_the_counter_and_the_index() {
        let mut p = driven(-100.0, 2.0);
        let before = run(&mut p, 10);
        assert_eq!(before[9].feedback.encoder_count.wrapping_sub(before[0].feedback.encoder_count), 18);
        p.faults_mut().encoder_wire_break = true;
        // 100 periods = 200 counts: the shaft passes the index at count 0 on the way. The counter stops where the
        // break found it, at the end of the last healthy period: one count (half a period) after its last sample.
        let broken = run(&mut p, 100);
        let frozen = broken[0].feedback.encoder_count;
        assert_eq!(frozen.wrapping_sub(before[9].feedback.encoder_count), 1);
        assert!(true_count(&p) > 50, "the shaft has passed the index: {}", true_count(&p));
        assert!(broken.iter().all(|m| m.feedback.encoder_count == frozen), "the counter holds its value");
        assert!(broken.iter().all(|m| m.feedback.index_latch.is_none()), "no index without the A/B lines");
        // Repaired: the counter moves on from where it stopped, by the shaft's motion from then on.
        p.faults_mut().encoder_wire_break = false;
        let t0 = sensors::encoder_count(p.state().theta_m_rad, 4096, 0); // at the end of the last broken period
        let after = run(&mut p, 10);
        let moved = after[9].feedback.encoder_count.wrapping_sub(frozen);
        assert_eq!(i64::from(moved), true_count(&p) - t0);
    }

    #[test]
    fn noise_burst_adds_its_counts_and_displaces_the_index() {
        let mut p = driven(-300.0, 0.0);
        let c0 = run(&mut p, 1)[0].feedback.encoder_count;
        p.faults_mut().encoder_noise = Some(faults::EncoderNoise { counts_per_period: 3, periods_left: 5 });
        let burst = run(&mut p, 8);
        let seen: Vec<i16> = burst.iter().map(|m| m.feedback.encoder_count.wrapping_sub(c0) as i16).collect();
        assert_eq!(seen, [3, 6, 9, 12, 15, 15, 15, 15], "3 counts per period for 5 periods, then none");
        assert_eq!(p.faults().encoder_noise, None, "the burst is over");
        // Now turning: the index (true count 0) is latched at the counter's value there, 15 counts beyond.
        let speed = 2.0 * RAD_PER_COUNT / PERIOD_S;
        p.set_mechanics(Mechanics::Driven { speed_rad_s: speed });
        let latches: Vec<u16> = run(&mut p, 200).iter().filter_map(|m| m.feedback.index_latch).collect();
        assert_eq!(latches, [15]);
    }

    #[test]
    fn lost_index_latches_nothing_until_repaired() {
        let mut p = driven(-100.0, 2.0);
        p.faults_mut().index_lost = true;
        // 2.5 turns: the index is passed twice.
        let lost = run(&mut p, 5120);
        assert!(lost.iter().all(|m| m.feedback.index_latch.is_none()));
        let counts = lost.last().map(|m| m.feedback.encoder_count).unwrap_or(0);
        assert_eq!(i64::from(counts), true_count(&p) & 0xFFFF, "the counter itself is unaffected");
        p.faults_mut().index_lost = false;
        let latches: Vec<u16> = run(&mut p, 2048).iter().filter_map(|m| m.feedback.index_latch).collect();
        assert_eq!(latches, [3 * 4096], "the next index, at three turns");
    }

    #[test]
    fn stuck_halls_read_their_state() {
        let mut p = driven(0.0, 2.0);
        for stuck in [0b000, 0b111, 0b101] {
            p.faults_mut().hall_stuck = Some(stuck);
            // 300 periods = 600 counts = 369 degrees electrical: every true state passes.
            assert!(run(&mut p, 300).iter().all(|m| m.feedback.hall == stuck), "stuck at {stuck:03b}");
        }
        p.faults_mut().hall_stuck = None;
        let m = run(&mut p, 1)[0];
        let truth = sensors::hall_state(7.0 * p.state_at_sample().theta_m_rad, 0.0);
        assert_eq!(m.feedback.hall, truth);
    }
}

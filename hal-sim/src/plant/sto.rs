//! The board's Safe Torque Off path (EPOS4 AN ch. 9, S1 L8741-8905): two inputs, each of which, de-energised,
//! removes the gate drivers' supply so that the output transistors cannot switch whatever the microcontroller
//! commands (S1 Tab. 9-87: power stage active only with both inputs energised). In the plant a period with either
//! input de-energised runs the diode bridge of disabled outputs (the same freewheel as `PwmCommand::OFF`), from the
//! period after the change: the hardware path involves no firmware and no sample.
//!
//! The inputs are what reaches the gate drivers and the microcontroller's pins alike, after the board's input
//! stage; a safety controller's test pulses (< 800 us, S1 L8821-8833), which that stage is designed to ride
//! through, are not modelled.

use firmware::hal::sto::StoInputs;

use super::Plant;

impl Plant {
    /// Sets the levels of STO-IN1 and STO-IN2 (`true` = energised); the power stage follows from the next period.
    pub fn set_sto_inputs(&mut self, inputs: StoInputs) {
        self.sto = inputs;
    }

    /// The levels of the STO inputs, as the microcontroller's pins read them.
    pub fn sto_inputs(&self) -> StoInputs {
        self.sto
    }

    /// Whether the output transistors switched in the last period (outputs enabled by the command, not tripped by
    /// the over-current break, and both STO inputs energised).
    pub fn bridge_switched(&self) -> bool {
        self.levels.iter().any(Option::is_some)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::PlantParams;
    use firmware::hal::power::PwmCommand;

    /// Either input de-energised stops the switching from the next period, whatever the command; both energised
    /// let it switch again (S1 Tab. 9-87).
    #[test]
    fn either_input_stops_the_bridge_from_the_next_period() {
        let mut cmd = PwmCommand::OFF;
        cmd.enabled = true;
        cmd.duty = [3_000, 2_000, 1_000];
        let cases = [
            (StoInputs::RELEASED, true),
            (StoInputs { channel_1: false, channel_2: true }, false),
            (StoInputs { channel_1: true, channel_2: false }, false),
            (StoInputs::DEMANDED, false),
        ];
        for (sto, switches) in cases {
            let mut p = Plant::new(PlantParams::reference(), 1);
            p.step(&cmd);
            assert!(p.bridge_switched(), "released before {sto:?}");
            p.set_sto_inputs(sto);
            p.step(&cmd);
            assert_eq!(p.bridge_switched(), switches, "{sto:?}");
            // No energy reaches the motor: with the command still switching, the current of the first period
            // decays through the diodes to zero (winding L/R = 0.61 ms; 10 ms allowed) and stays there.
            if !switches {
                for _ in 0..250 {
                    p.step(&cmd);
                    assert!(!p.bridge_switched(), "{sto:?}");
                }
                let i = p.state().i_abc_a;
                assert!(i.iter().all(|x| x.abs() < 1e-9), "{sto:?}: {i:?}");
            }
            p.set_sto_inputs(StoInputs::RELEASED);
            p.step(&cmd);
            assert!(p.bridge_switched(), "released again after {sto:?}");
        }
    }
}

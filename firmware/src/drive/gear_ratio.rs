//! 0x6091 gear ratio, the CiA 402 view of the gear 0x3003 (`crate::motion::gear`): one gear, two objects.
//!
//! Reading 0x6091 gives the ratio in effect: 0x3003:01/02 when 0x3000:02 bit 12 is set, else 1:1. A master's write
//! of 0x6091 (PD4-E p.257: motor revolutions :01, shaft revolutions :02) writes 0x3003:01/02 and sets bit 12, or
//! clears it when the ratio it leaves is 1:1 (numerator = denominator), so that a master that knows only the CiA
//! 402 object gets a gear that acts. Both are writable only with the power stage off (device.toml
//! `power-disabled`), so the gear never changes under the loops.
//!
//! The fieldbus SDO servers write the dictionary directly, so the drive tells a write of 0x6091 from one of 0x3003
//! by comparing the values with those it last reconciled: every background step (a few loads and compares), and at
//! once after a host-side [`super::Drive::sdo_write`].

use crate::motion::gear::{Gear, GEAR_MOUNTED};
use crate::od::access::Dictionary;
use crate::od::generated::handles as h;

/// The gear objects as last reconciled.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GearRatioSeen {
    /// 0x6091:01, 0x6091:02 as published.
    ratio: (u32, u32),
    /// 0x3003:01, 0x3003:02 and 0x3000:02 bit 12.
    gear: (u32, u32, u32),
}

impl GearRatioSeen {
    /// The state at start-up: 0x3003 and bit 12 (the saved objects) are the source, whatever 0x6091 holds.
    #[must_use]
    pub fn new(d: &Dictionary) -> Self {
        let ratio = (d.get(h::GEAR_RATIO_MOTOR_REVOLUTIONS), d.get(h::GEAR_RATIO_SHAFT_REVOLUTIONS));
        Self { ratio, gear: (0, 0, u32::MAX) }
    }

    /// Makes 0x6091 and 0x3003 / bit 12 agree: a changed 0x6091 is carried into 0x3003 and bit 12, then 0x6091
    /// shows the ratio in effect.
    #[inline(never)]
    pub fn reconcile(&mut self, d: &mut Dictionary) {
        let ratio = (d.get(h::GEAR_RATIO_MOTOR_REVOLUTIONS), d.get(h::GEAR_RATIO_SHAFT_REVOLUTIONS));
        let structure = d.get(h::CONTROL_STRUCTURE);
        let gear = (d.get(h::GEAR_REDUCTION_NUMERATOR), d.get(h::GEAR_REDUCTION_DENOMINATOR), structure & GEAR_MOUNTED);
        if ratio == self.ratio && gear == self.gear {
            return;
        }
        if ratio != self.ratio {
            // The master wrote 0x6091: the gear becomes its ratio (1:1 = no gear).
            d.set(h::GEAR_REDUCTION_NUMERATOR, ratio.0);
            d.set(h::GEAR_REDUCTION_DENOMINATOR, ratio.1);
            let mounted = if ratio.0 == ratio.1 { structure & !GEAR_MOUNTED } else { structure | GEAR_MOUNTED };
            d.set(h::CONTROL_STRUCTURE, mounted);
        }
        let in_effect = Gear::in_effect(d);
        let shown = (in_effect.numerator, in_effect.denominator);
        d.set(h::GEAR_RATIO_MOTOR_REVOLUTIONS, shown.0);
        d.set(h::GEAR_RATIO_SHAFT_REVOLUTIONS, shown.1);
        self.ratio = shown;
        self.gear = (
            d.get(h::GEAR_REDUCTION_NUMERATOR),
            d.get(h::GEAR_REDUCTION_DENOMINATOR),
            d.get(h::CONTROL_STRUCTURE) & GEAR_MOUNTED,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ratio(d: &Dictionary) -> (u32, u32) {
        (d.get(h::GEAR_RATIO_MOTOR_REVOLUTIONS), d.get(h::GEAR_RATIO_SHAFT_REVOLUTIONS))
    }

    /// 0x6091 shows 0x3003 only with bit 12; a write of 0x6091 sets 0x3003 and bit 12, 1:1 clears the bit.
    #[test]
    fn one_gear_in_two_objects() {
        let mut d = Dictionary::new(1);
        // Saved 3:1 with bit 12: the start-up takes it, not 0x6091's default.
        d.set(h::GEAR_REDUCTION_NUMERATOR, 3);
        d.set(h::CONTROL_STRUCTURE, d.get(h::CONTROL_STRUCTURE) | GEAR_MOUNTED);
        let mut boot = GearRatioSeen::new(&d);
        boot.reconcile(&mut d);
        assert_eq!((ratio(&d), d.get(h::GEAR_REDUCTION_NUMERATOR)), ((3, 1), 3));
        let mut d = Dictionary::new(1);
        let mut seen = GearRatioSeen::new(&d);
        seen.reconcile(&mut d);
        assert_eq!(ratio(&d), (1, 1));
        d.set(h::GEAR_REDUCTION_NUMERATOR, 5);
        seen.reconcile(&mut d);
        assert_eq!(ratio(&d), (1, 1), "bit 12 clear: no gear in effect");
        d.set(h::CONTROL_STRUCTURE, d.get(h::CONTROL_STRUCTURE) | GEAR_MOUNTED);
        seen.reconcile(&mut d);
        assert_eq!(ratio(&d), (5, 1));
        d.set(h::GEAR_RATIO_SHAFT_REVOLUTIONS, 2);
        seen.reconcile(&mut d);
        assert_eq!((d.get(h::GEAR_REDUCTION_NUMERATOR), d.get(h::GEAR_REDUCTION_DENOMINATOR)), (5, 2));
        d.set(h::GEAR_RATIO_MOTOR_REVOLUTIONS, 2);
        seen.reconcile(&mut d);
        assert_eq!((ratio(&d), d.get(h::CONTROL_STRUCTURE) & GEAR_MOUNTED), ((1, 1), 0), "2:2 is no gear");
        // 1:1 shown: a write of :01 alone makes 7:1.
        d.set(h::GEAR_RATIO_MOTOR_REVOLUTIONS, 7);
        seen.reconcile(&mut d);
        assert_eq!((ratio(&d), d.get(h::CONTROL_STRUCTURE) & GEAR_MOUNTED), ((7, 1), GEAR_MOUNTED));
    }
}

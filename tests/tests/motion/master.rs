//! What the motion tests do as a master does over SDO and the controlword: the pre-operational access context,
//! the controlword and statusword bits they use, and a PPM move to target reached.

use firmware::od::access::{AccessContext, CommState};
use firmware::od::generated::{handles as h, MAX_PDO_BYTES_ETHERCAT};
use hal_sim::sim::Simulation;

/// An SDO write in PRE-OPERATIONAL with the power stage off.
pub const PRE_OP: AccessContext = AccessContext {
    comm_state: CommState::PreOperational,
    power_stage_enabled: false,
    max_pdo_bytes: MAX_PDO_BYTES_ETHERCAT as u16,
};
/// Controlword «Enable operation», and with bit 4 (new set-point / homing start).
pub const ENABLE_OPERATION: u16 = 0x000F;
pub const BIT4: u16 = 0x0010;
/// Statusword bits 10 (target reached) and 12 (set-point acknowledge, homing attained).
pub const TARGET_REACHED: u16 = 1 << 10;
pub const BIT12: u16 = 1 << 12;

pub fn get_i32(sim: &Simulation, handle: firmware::od::entry::Handle<i32>) -> i64 {
    i64::from(sim.drive.dictionary().get(handle))
}

/// Slow ticks until the statusword has `bits`, at most `max`.
pub fn until_status(sim: &mut Simulation, bits: u16, max: u64) -> bool {
    (0..max).any(|_| {
        sim.run_slow_ticks(1);
        sim.statusword() & bits == bits
    })
}

/// A PPM absolute move to `target` (the master's units), to target reached within `max_ticks` slow ticks, plus 25
/// ticks of settling.
pub fn ppm_move(sim: &mut Simulation, target: i64, max_ticks: u64) {
    sim.drive.dictionary_mut().set(h::TARGET_POSITION, i32::try_from(target).expect("in range"));
    sim.set_controlword(ENABLE_OPERATION | BIT4);
    assert!(until_status(sim, BIT12, 50), "set-point acknowledged");
    sim.set_controlword(ENABLE_OPERATION);
    let reached = until_status(sim, TARGET_REACHED, max_ticks);
    assert!(
        reached,
        "target reached: error {:#06x} status {:#06x}, 0x6064 {}, 0x6062 {}, 0x60FC {}, 0x6063 {}",
        sim.drive.dictionary().get(h::ERROR_CODE),
        sim.statusword(),
        get_i32(sim, h::POSITION_ACTUAL_VALUE),
        get_i32(sim, h::POSITION_DEMAND_VALUE),
        get_i32(sim, h::POSITION_DEMAND_INTERNAL_VALUE),
        get_i32(sim, h::POSITION_ACTUAL_INTERNAL_VALUE)
    );
    sim.run_slow_ticks(25);
}

/// Homing method 37 (the current position is home, CiA 402 §8) with home offset 0x607C = `home_offset` (the
/// master's units), started by controlword bit 4, to «homing attained» within 2,500 slow ticks plus 25 ticks.
pub fn home_here(sim: &mut Simulation, home_offset: i32) {
    {
        let d = sim.drive.dictionary_mut();
        d.set(h::HOMING_METHOD, 37);
        d.set(h::HOME_OFFSET, home_offset);
    }
    sim.run_slow_ticks(5);
    sim.set_controlword(ENABLE_OPERATION | BIT4);
    assert!(until_status(sim, BIT12, 2_500), "homing attained");
    sim.run_slow_ticks(25);
}

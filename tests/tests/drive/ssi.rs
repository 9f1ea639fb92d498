//! The SSI absolute encoder as the only sensor (issue 20 item 1; IDX 0x3012 L4159-4408, errors L7276-7308): the
//! drive commissioned over SDO for the plant's SSI sensor (`hal_sim::scenarios::ssi`), the plant's Halls stuck at
//! 000 and its encoder lines broken, so that nothing but the SSI frames commutates or positions it.

use core::f64::consts::TAU;

use firmware::drive::{Drive, DriveConfig};
use firmware::od::generated::handles as h;
use firmware::od::store::ParamStore;
use firmware::power_state::CommutationStage;
use hal_sim::flash::SimFlash;
use hal_sim::plant::PlantParams;
use hal_sim::scenarios::{angle_error_deg, ssi};
use hal_sim::sim::Simulation;

fn error_code(sim: &Simulation) -> u16 {
    sim.drive.dictionary().get(h::ERROR_CODE)
}

#[test]
fn debug_power_cycle() {
    let p = ssi::reference_ssi_plant();
    let mut store = ParamStore::new(SimFlash::params());
    let mut sim = ssi::ssi_simulation(&p, 1, &mut store).unwrap();
    sim.run(100);
    eprintln!("before switch-on: 0x6064 {} method {:?}", sim.drive.dictionary().get::<i32>(h::POSITION_ACTUAL_VALUE), sim.drive.settings().commutation.method);
    sim.enable_through_controlword(1).unwrap();
    sim.run(100);
    eprintln!("enabled: 0x6064 {} offset {} raw {:#x}", sim.drive.dictionary().get::<i32>(h::POSITION_ACTUAL_VALUE), sim.drive.axis().position_offset(), sim.drive.dictionary().get::<u32>(h::SSI_POSITION_RAW));
    let _ = (TAU, Drive::boot(DriveConfig::DEFAULT, &mut store), CommutationStage::Unknown, PlantParams::reference(), angle_error_deg(&sim), error_code(&sim));
}

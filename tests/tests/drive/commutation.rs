//! Commutation on the reference plant: Hall start, Hall-edge and index refinement, and forced alignment when no
//! Hall sensor is configured (0x3000:01). Angle errors are the drive's angle against the plant's true electrical
//! angle at the sample instant (`hal_sim::scenarios::angle_error_deg`).

use firmware::power_state::{CommutationStage, PowerState};
use hal_sim::plant::PlantParams;
use hal_sim::scenarios::angle_error_deg;
use hal_sim::sim::Simulation;

fn simulation(start_angle_rad: f64) -> Simulation {
    let mut sim = Simulation::new(PlantParams::reference(), 7, firmware::drive::DriveConfig::DEFAULT);
    sim.plant.set_rotor_state(start_angle_rad, 0.0);
    sim.run(5);
    sim
}

/// Hall start: within +-30 degrees electrical (half a sector) at once; after the first Hall edge within a few
/// degrees (the edge is placed at the midpoint of the two samples around it: at low speed well under one degree of
/// travel per tick); after the first index pulse (learned offset) within 1 degree (encoder quantisation 0.6
/// degrees electrical per count at 7 pole pairs, plus the learned offset's error).
#[test]
fn hall_start_edge_and_index_refinement() {
    for start in [0.3, 1.0, 2.5, 4.0] {
        let mut sim = simulation(start);
        sim.switch_on().expect("calibrated");
        sim.enable().expect("enabled");
        sim.set_q_reference(0.5);
        sim.step();
        assert_eq!(sim.tier1().commutation().stage(), CommutationStage::HallSector);
        assert!(angle_error_deg(&sim).abs() <= 30.5, "start {start}: {}", angle_error_deg(&sim));
        sim.run_until(25_000, |s| s.tier1().commutation().stage() != CommutationStage::HallSector).expect("edge");
        assert_eq!(sim.tier1().commutation().stage(), CommutationStage::HallEdge);
        assert!(angle_error_deg(&sim).abs() <= 3.0, "start {start}: after edge {}", angle_error_deg(&sim));
        sim.run_until(25_000, |s| s.tier1().commutation().stage() == CommutationStage::Indexed).expect("index");
        sim.run(100);
        assert!(angle_error_deg(&sim).abs() <= 1.0, "start {start}: indexed {}", angle_error_deg(&sim));
    }
}

/// No Hall sensor configured (0x3000:01 sensor 3 type 0): forced alignment with the nominal current (first at 90,
/// then at 0 degrees), then the angle is zeroed. The remaining error is set by Coulomb friction (3 mNm against
/// kt x 3.2 A = 107 mNm: asin(0.028) = 1.6 degrees) and the residual swing of the undamped rotor: bound 5 degrees.
/// The first index pulse then learns its offset from the aligned angle.
#[test]
fn forced_alignment_without_halls() {
    for start in [0.7, 3.0] {
        let mut sim = simulation(start);
        let entry = sim.drive.dictionary().find(0x3000, 1).expect("0x3000:01 exists");
        assert!(sim.drive.dictionary_mut().values_mut().set_raw(entry, &0x0000_0001u32.to_le_bytes()));
        sim.switch_on().expect("calibrated");
        sim.enable().expect("enabled");
        sim.step();
        assert_eq!(sim.tier1().commutation().stage(), CommutationStage::Aligning);
        // 100 ms ramp + 2 x 200 ms hold.
        let ticks = sim
            .run_until(13_000, |s| s.tier1().commutation().stage() != CommutationStage::Aligning)
            .expect("alignment ends");
        assert!((12_400..=12_600).contains(&ticks), "{ticks}");
        assert_eq!(sim.tier1().commutation().stage(), CommutationStage::Aligned);
        assert!(angle_error_deg(&sim).abs() <= 5.0, "start {start}: aligned {}", angle_error_deg(&sim));
        sim.set_q_reference(0.5);
        sim.run_until(25_000, |s| s.tier1().commutation().stage() == CommutationStage::Indexed).expect("index");
        assert!(angle_error_deg(&sim).abs() <= 5.0, "start {start}: indexed {}", angle_error_deg(&sim));
        assert_eq!(sim.drive.state(), PowerState::OperationEnabled);
    }
}

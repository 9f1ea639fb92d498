//! Safe Torque Off at power-up must not block NMT or SDO (issue 19 item 1; the field trap of a CiA 402 start-up
//! that stalls on a de-energised STO input, ros2_canopen#421), on the simulated bus with a raw master in lock-step
//! (`hal_sim::sim::canopen::CanopenRunner`, 1 Mbit/s, node 1; 1 ms per SYNC).

use firmware::canopen::frame::CanFrame;
use firmware::canopen::nmt::NmtState;
use firmware::cia402::State;
use firmware::fault::FaultId;
use firmware::hal::sto::StoInputs;
use hal_sim::can::bus::Delivery;
use hal_sim::sim::canopen::{CanClock, CanopenConfig, CanopenRunner};

/// A raw CANopen master on the runner; the frames node 1 sent are kept.
struct Master {
    r: CanopenRunner,
    seen: Vec<CanFrame>,
}

impl Master {
    fn keep(&mut self, got: Vec<Delivery>) -> Vec<Delivery> {
        self.seen.extend(got.iter().map(|d| d.frame));
        got
    }

    /// `n` SYNC periods of 1 ms.
    fn syncs(&mut self, n: u32) {
        for _ in 0..n {
            let got = self.r.lock_step(CanFrame::new(0x080, &[]).unwrap());
            self.keep(got);
        }
    }

    fn sdo(&mut self, req: [u8; 8]) -> [u8; 8] {
        let got = self.r.lock_step(CanFrame::new(0x601, &req).unwrap());
        let got = self.keep(got);
        got.iter().rev().find(|d| d.frame.id() == 0x581).map(|d| d.frame.data().try_into().unwrap()).expect("an answer")
    }

    /// Expedited upload of up to 4 bytes, as a little-endian number.
    fn upload(&mut self, index: u16, sub: u8) -> Result<u32, u32> {
        let [i0, i1] = index.to_le_bytes();
        let r = self.sdo([0x40, i0, i1, sub, 0, 0, 0, 0]);
        let value = u32::from_le_bytes([r[4], r[5], r[6], r[7]]);
        if r[0] == 0x80 {
            return Err(value);
        }
        assert_eq!(r[0] & 0xE3, 0x43, "an expedited answer for {index:04X}:{sub}");
        Ok(value)
    }

    fn controlword(&mut self, value: u16) {
        let [v0, v1] = value.to_le_bytes();
        let r = self.sdo([0x2B, 0x40, 0x60, 0, v0, v1, 0, 0]);
        assert_eq!(r[0], 0x60, "controlword {value:#06x} accepted by SDO");
    }

    fn state(&self) -> State {
        self.r.drive(1).expect("node 1").sim.cia402_state()
    }
}

/// Proves, with both STO inputs de-energised before the drive's first period (EPOS4 AN ch. 9): the boot-up
/// (0x701, CiA 301 7.2.8.3.2.1) and an EMCY 0xFFA0 with the fault number of `FaultId::SafeTorqueOff` come out, the
/// node is PRE-OPERATIONAL, SDO reads 0x1000 (0x0002_0192), the statusword (0x4040: «Switch on disabled» with
/// bit 14) and 0x603F (0xFFA0), NMT Start takes it to OPERATIONAL; «Shutdown», «Switch on» and «Enable operation»
/// by SDO leave it in «Switch on disabled» with the power stage off. Once the inputs are energised: bit 14 and
/// 0x603F clear (an EMCY "error reset" 0x0000 follows), a held «Enable operation» restarts nothing, and the normal
/// sequence reaches «Operation enabled».
#[test]
fn sto_low_at_power_up_keeps_nmt_and_sdo_and_refuses_to_enable() {
    let mut r = CanopenRunner::new(CanopenConfig { clock: CanClock::LockStep, ..CanopenConfig::default() });
    r.drive_mut(1).expect("node 1").sim.plant.set_sto_inputs(StoInputs::DEMANDED);
    let mut m = Master { r, seen: Vec::new() };
    let got = m.r.run_for(2_000_000);
    m.keep(got);
    assert!(m.seen.iter().any(|f| f.id() == 0x701 && f.data() == [0x00]), "boot-up: {:02X?}", m.seen);
    assert!(m.r.all_in(NmtState::PreOperational));
    let code = FaultId::SafeTorqueOff.info().code;
    let emcy = m.seen.iter().find(|f| f.id() == 0x081 && f.data()[..2] == code.to_le_bytes());
    let emcy = emcy.unwrap_or_else(|| panic!("an EMCY {code:#06x}: {:02X?}", m.seen));
    assert_eq!(emcy.data()[3], FaultId::SafeTorqueOff.number(), "EMCY byte 3: the fault's number");

    assert_eq!(m.upload(0x1000, 0), Ok(0x0002_0192), "0x1000 device type");
    assert_eq!(m.upload(0x6041, 0), Ok(0x4040), "statusword: «Switch on disabled», bit 14 STO");
    assert_eq!(m.upload(0x603F, 0), Ok(0xFFA0), "0x603F: STO");
    assert_eq!(m.upload(0x1001, 0), Ok(0), "0x1001: STO is not an error");

    let got = m.r.lock_step(CanFrame::new(0x000, &[0x01, 1]).unwrap());
    m.keep(got);
    m.syncs(2);
    assert!(m.r.all_in(NmtState::Operational), "NMT Start with STO active");

    for cw in [0x0006, 0x0007, 0x000F] {
        m.controlword(cw);
        m.syncs(20);
        assert_eq!(m.state(), State::SwitchOnDisabled, "after controlword {cw:#06x}");
        assert!(!m.r.drive(1).unwrap().sim.command().enabled, "power stage off");
    }
    let sw = m.upload(0x6041, 0).unwrap();
    assert_eq!((sw & 0x6F, sw & 0x4000), (0x40, 0x4000), "statusword {sw:#06x}: refused, STO shown");
    assert_eq!(m.upload(0x603F, 0), Ok(0xFFA0));

    // Released, with «Enable operation» still held: nothing restarts by itself.
    m.r.drive_mut(1).unwrap().sim.plant.set_sto_inputs(StoInputs::RELEASED);
    m.seen.clear();
    m.syncs(20);
    assert_eq!(m.state(), State::SwitchOnDisabled, "no restart without «Shutdown»");
    let sw = m.upload(0x6041, 0).unwrap();
    assert_eq!(sw & 0x4000, 0, "bit 14 clear: {sw:#06x}");
    assert_eq!(m.upload(0x603F, 0), Ok(0));
    assert!(m.seen.iter().any(|f| f.id() == 0x081 && f.data()[..2] == [0, 0]), "EMCY error reset: {:02X?}", m.seen);

    // The normal sequence.
    m.controlword(0x0006);
    m.syncs(5);
    assert_eq!(m.state(), State::ReadyToSwitchOn);
    m.controlword(0x0007);
    for _ in 0..200 {
        m.syncs(1);
        if m.state() == State::SwitchedOn {
            break;
        }
    }
    assert_eq!(m.state(), State::SwitchedOn, "switched on (offset calibration)");
    m.controlword(0x000F);
    m.syncs(5);
    assert_eq!(m.state(), State::OperationEnabled);
}

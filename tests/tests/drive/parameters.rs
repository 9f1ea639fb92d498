//! The drive's parameters across resets on the simulated parameter flash (`hal_sim::flash::SimFlash::params`):
//! "persistent values are loaded at boot" through `Drive::boot`, and 0x1010/0x1011 served by the drive's
//! application objects (`firmware::drive::objects`).
//!
//! * An erased store boots with the factory defaults and says so.
//! * A persistent parameter (0x30A0:01 current P gain) and a PDO mapping (0x1600) changed through the dictionary's
//!   write API and saved with 0x1010:01 "save" are in force after a reboot, in the dictionary and in the drive
//!   built from it (CiA 301 §7.5.2.13).
//! * 0x1011:01 "load" (Pre-Operational, power stage disabled: IDX L1702) leaves the running values alone and gives
//!   the defaults after the next reboot (CiA 301 §7.5.2.14).
//! * 0x1010/0x1011 follow their device.toml write conditions (0x0800_0022 outside them) and the drive refuses them
//!   itself while its power stage is switched on, without touching the flash.
//! * A corrupt store, or one that cannot be read, boots with the defaults and reports it.
//! * 0x1F50/0x1F51 (program download, the bootloader issue) answer 0x0800_0020 and never panic.
//! * 0x3010:05 (commutation offset at index) reaches the commutation at switch-on.

use firmware::control::angle::ElectricalAngle;
use firmware::control::pi::PiGains;
use firmware::drive::objects::{ParameterSource, NODE_ID};
use firmware::drive::tier1::Tier1State;
use firmware::drive::{Drive, DriveConfig};
use firmware::od::abort::SdoAbort;
use firmware::od::access::{AccessContext, CommState, Dictionary, Download};
use firmware::od::entry::WriteCondition;
use firmware::od::generated::{handles as h, ENTRIES, MAX_PDO_BYTES_ETHERCAT};
use firmware::od::store::{ParamStore, LOAD_SIGNATURE, SAVE_SIGNATURE};
use hal_sim::flash::SimFlash;

const PRE_OP: AccessContext = AccessContext {
    comm_state: CommState::PreOperational,
    power_stage_enabled: false,
    max_pdo_bytes: MAX_PDO_BYTES_ETHERCAT as u16,
};
const OP_ENABLED: AccessContext =
    AccessContext { comm_state: CommState::Operational, power_stage_enabled: true, ..PRE_OP };

/// A changed current P gain (default 1,555,000 uV/A).
const P_GAIN: u32 = 2_000_000;
/// RxPDO 1 entry 2 changed from modes of operation (0x6060:00, 8 bits) to target torque (0x6071:00, 16 bits).
const MAPPED: u32 = 0x6071_0010;

fn store() -> ParamStore<SimFlash> {
    ParamStore::new(SimFlash::params())
}

fn boot(store: &mut ParamStore<SimFlash>) -> (Drive, firmware::drive::objects::BootReport) {
    Drive::boot(DriveConfig::DEFAULT, store)
}

/// The factory defaults as the drive boots without stored parameters.
fn defaults() -> Dictionary {
    Drive::new(DriveConfig::DEFAULT).dictionary().clone()
}

fn read_u32(drive: &Drive, store: &mut ParamStore<SimFlash>, index: u16, sub: u8) -> Result<u32, SdoAbort> {
    let mut buf = [0u8; 4];
    let outcome = drive.sdo_read(index, sub, 0, &mut buf, store)?;
    assert_eq!(outcome.len, 4, "{index:#06x}:{sub}");
    Ok(u32::from_le_bytes(buf))
}

/// Changes the P gain and the RxPDO 1 mapping through the SDO write path (CiA 301 §7.5.2.36 mapping procedure).
fn change_parameters(drive: &mut Drive, store: &mut ParamStore<SimFlash>) {
    drive.sdo_write(0x30A0, 1, &P_GAIN.to_le_bytes(), PRE_OP, store).expect("0x30A0:01");
    drive.sdo_write(0x1600, 0, &[0], PRE_OP, store).expect("disable RxPDO 1 mapping");
    drive.sdo_write(0x1600, 2, &MAPPED.to_le_bytes(), PRE_OP, store).expect("0x1600:02");
    drive.sdo_write(0x1600, 0, &[2], PRE_OP, store).expect("enable RxPDO 1 mapping");
}

fn assert_changed(drive: &Drive, store: &mut ParamStore<SimFlash>) {
    assert_eq!(drive.dictionary().get(h::CURRENT_CONTROLLER_P_GAIN), P_GAIN);
    assert_eq!(read_u32(drive, store, 0x1600, 2), Ok(MAPPED));
    // The drive hands tier 1 gains converted from the loaded value, not the default, and tier 1's current
    // controller runs with them.
    let expected = PiGains::from_idx_0x30a0(P_GAIN, drive.dictionary().get(h::CURRENT_CONTROLLER_I_GAIN));
    assert_eq!(drive.settings().gains, expected);
    let tier1 = Tier1State::new(drive.settings());
    assert_eq!(tier1.controller().pi_q().gains(), expected);
    assert_eq!(tier1.controller().pi_d().gains(), expected);
}

#[test]
fn empty_flash_boots_with_defaults() {
    let mut store = store();
    let (drive, report) = boot(&mut store);
    assert_eq!(report.source, ParameterSource::Empty);
    assert!(!report.defaults_after_error());
    assert_eq!(report.load.record, None);
    assert_eq!(report.node_id, DriveConfig::DEFAULT.node_id);
    assert_eq!(drive.dictionary().values(), defaults().values());
    assert_eq!(drive.dictionary().get(h::CURRENT_CONTROLLER_P_GAIN), 1_555_000);
    assert_eq!(store.flash().write_count(), 0, "booting never writes the flash");
    // 0x1010:n and 0x1011:n read 1 (saving and restoring on command, CiA 301 §7.5.2.13/14); sub 0 is 4.
    for index in [0x1010, 0x1011] {
        for sub in 1..=4 {
            assert_eq!(read_u32(&drive, &mut store, index, sub), Ok(1), "{index:#06x}:{sub}");
        }
        let mut buf = [0u8; 1];
        drive.sdo_read(index, 0, 0, &mut buf, &mut store).expect("sub 0");
        assert_eq!(buf, [4]);
    }
}

#[test]
fn saved_parameters_are_loaded_at_the_next_boot() {
    let mut store = store();
    let (mut drive, _) = boot(&mut store);
    change_parameters(&mut drive, &mut store);
    // Not saved yet: a reboot gives the defaults.
    let (again, report) = boot(&mut store);
    assert_eq!(report.source, ParameterSource::Empty);
    assert_eq!(again.dictionary().values(), defaults().values());

    // A wrong signature is refused (CiA 301 §7.5.2.13), then "save".
    assert_eq!(
        drive.sdo_write(0x1010, 1, &LOAD_SIGNATURE.to_le_bytes(), PRE_OP, &mut store),
        Err(SdoAbort::CannotTransfer)
    );
    drive.sdo_write(0x1010, 1, &SAVE_SIGNATURE.to_le_bytes(), PRE_OP, &mut store).expect("save");
    // The running drive takes the new gain at its next slow tick.
    drive.background();
    drive.slow_tick();
    assert_changed(&drive, &mut store);

    let (rebooted, report) = boot(&mut store);
    assert_eq!(report.source, ParameterSource::Stored);
    assert!(report.load.applied > 0);
    assert_eq!((report.load.unknown, report.load.mismatched), (0, 0));
    assert_changed(&rebooted, &mut store);
    // Every persistent value came back.
    for entry in ENTRIES.iter().filter(|e| e.persistent()) {
        let (now, before) = (rebooted.dictionary().values().raw(entry), drive.dictionary().values().raw(entry));
        assert_eq!(now, before, "{:#06x}:{}", entry.index, entry.sub);
    }
}

#[test]
fn restore_defaults_takes_effect_at_the_next_boot() {
    let mut store = store();
    let (mut drive, _) = boot(&mut store);
    change_parameters(&mut drive, &mut store);
    drive.sdo_write(0x1010, 1, &SAVE_SIGNATURE.to_le_bytes(), PRE_OP, &mut store).expect("save");
    let (mut drive, _) = boot(&mut store);
    assert_changed(&drive, &mut store);

    // Only in Pre-Operational with the power stage disabled (IDX L1702; device.toml writable_in).
    let load = LOAD_SIGNATURE.to_le_bytes();
    let op = AccessContext { comm_state: CommState::Operational, ..PRE_OP };
    let enabled = AccessContext { power_stage_enabled: true, ..PRE_OP };
    assert_eq!(drive.sdo_write(0x1011, 1, &load, op, &mut store), Err(SdoAbort::DeviceState));
    assert_eq!(drive.sdo_write(0x1011, 1, &load, enabled, &mut store), Err(SdoAbort::DeviceState));
    assert_eq!(
        drive.sdo_write(0x1011, 1, &SAVE_SIGNATURE.to_le_bytes(), PRE_OP, &mut store),
        Err(SdoAbort::CannotTransfer),
        "wrong signature (CiA 301 §7.5.2.14)"
    );
    drive.sdo_write(0x1011, 1, &load, PRE_OP, &mut store).expect("restore defaults");
    // The running values stay until the reset.
    assert_changed(&drive, &mut store);

    let (rebooted, report) = boot(&mut store);
    assert_eq!(report.source, ParameterSource::Stored, "a record without the restored groups is in force");
    assert_eq!(report.load.applied, 0);
    assert_eq!(rebooted.dictionary().values(), defaults().values());
    assert_eq!(read_u32(&rebooted, &mut store, 0x1600, 2), Ok(0x6060_0008));
}

#[test]
fn save_follows_the_write_conditions_and_the_power_stage() {
    let mut store = store();
    let (mut drive, _) = boot(&mut store);
    change_parameters(&mut drive, &mut store);
    let save = SAVE_SIGNATURE.to_le_bytes();
    let condition = drive.dictionary().find(0x1010, 1).expect("0x1010:01").write_condition();
    assert_eq!(condition, WriteCondition::PreOperationalPowerDisabled, "device.toml writable_in of 0x1010");

    // Operational with the power stage enabled: refused by the write condition (CiA 301 Table 22, 0x0800_0022).
    let writes = store.flash().write_count();
    assert!(!OP_ENABLED.allows(condition));
    assert_eq!(drive.sdo_write(0x1010, 1, &save, OP_ENABLED, &mut store), Err(SdoAbort::DeviceState));
    for ctx in [
        AccessContext { power_stage_enabled: false, ..OP_ENABLED },
        AccessContext { comm_state: CommState::SafeOperational, power_stage_enabled: false, ..OP_ENABLED },
        AccessContext { power_stage_enabled: true, ..PRE_OP },
    ] {
        assert_eq!(
            drive.sdo_write(0x1010, 1, &save, ctx, &mut store).is_ok(),
            ctx.allows(condition),
            "{ctx:?} against {condition:?}"
        );
    }
    assert_eq!(store.flash().write_count(), writes, "no refused save touched the flash");

    // The drive's own power stage: switched on (calibrating), a save is refused even if the context claims the
    // power stage is off, and the flash stays untouched.
    drive.switch_on().expect("switch on");
    assert!(drive.power_stage_enabled());
    assert_eq!(drive.sdo_write(0x1010, 1, &save, PRE_OP, &mut store), Err(SdoAbort::DeviceState));
    assert_eq!(
        drive.sdo_write(0x1011, 1, &LOAD_SIGNATURE.to_le_bytes(), PRE_OP, &mut store),
        Err(SdoAbort::DeviceState)
    );
    assert_eq!(store.flash().write_count(), writes);
    // Reads still answer.
    assert_eq!(read_u32(&drive, &mut store, 0x1010, 1), Ok(1));

    drive.shutdown();
    assert!(!drive.power_stage_enabled());
    drive.sdo_write(0x1010, 1, &save, PRE_OP, &mut store).expect("save with the power stage off");
    assert!(store.flash().write_count() > writes);
    assert_changed(&boot(&mut store).0, &mut store);
}

#[test]
fn corrupt_flash_boots_with_defaults_and_reports_it() {
    // Garbage everywhere.
    let mut flash = SimFlash::params();
    flash.fill_random(0x5EED);
    let mut store = ParamStore::new(flash);
    let (drive, report) = boot(&mut store);
    assert_eq!(report.source, ParameterSource::Invalid);
    assert!(report.defaults_after_error());
    assert_eq!(drive.dictionary().values(), defaults().values());

    // A valid record with one flipped payload bit: the CRC fails, no record is in force.
    let mut store = self::store();
    let (mut drive, _) = boot(&mut store);
    change_parameters(&mut drive, &mut store);
    drive.sdo_write(0x1010, 1, &SAVE_SIGNATURE.to_le_bytes(), PRE_OP, &mut store).expect("save");
    let record = boot(&mut store).1.load.record.expect("record");
    let base = record.sector as usize * SimFlash::params().contents().len() / 2;
    store.flash_mut().contents_mut()[base + 40] ^= 0x04;
    let (drive, report) = boot(&mut store);
    assert_eq!(report.source, ParameterSource::Invalid);
    assert_eq!(drive.dictionary().values(), defaults().values());
    assert_eq!(drive.dictionary().get(h::CURRENT_CONTROLLER_P_GAIN), 1_555_000);

    // A store that cannot be read (the supply failed during a save and is still down).
    let mut store = self::store();
    let (mut drive, _) = boot(&mut store);
    change_parameters(&mut drive, &mut store);
    store.flash_mut().cut_power_at_write(1, 7);
    assert_eq!(
        drive.sdo_write(0x1010, 1, &SAVE_SIGNATURE.to_le_bytes(), PRE_OP, &mut store),
        Err(SdoAbort::HardwareError)
    );
    let (drive, report) = boot(&mut store);
    assert!(matches!(report.source, ParameterSource::Failed(_)), "{report:?}");
    assert!(report.defaults_after_error());
    assert_eq!(drive.dictionary().values(), defaults().values());
}

#[test]
fn a_stored_node_id_is_used_at_the_next_boot() {
    let mut store = store();
    let (mut drive, report) = boot(&mut store);
    assert_eq!(report.node_id, 1);
    drive.sdo_write(NODE_ID, 0, &[5], PRE_OP, &mut store).expect("0x2000");
    drive.sdo_write(0x1010, 1, &SAVE_SIGNATURE.to_le_bytes(), PRE_OP, &mut store).expect("save");
    let (rebooted, report) = boot(&mut store);
    assert_eq!(report.node_id, 5);
    let mut id = [0u8; 1];
    rebooted.sdo_read(NODE_ID, 0, 0, &mut id, &mut store).expect("read 0x2000");
    assert_eq!(id, [5]);
    // A drive configured for another node-ID without a stored one reads its own in 0x2000.
    let (other, report) = Drive::boot(DriveConfig { node_id: 9, ..DriveConfig::DEFAULT }, &mut self::store());
    assert_eq!(report.node_id, 9);
    assert_eq!(other.dictionary().find(NODE_ID, 0).map(|e| other.dictionary().values().raw(e)), Ok(Some(&[9u8][..])));
}

#[test]
fn program_control_is_not_served_yet() {
    let mut store = store();
    let (mut drive, _) = boot(&mut store);
    let mut buf = [0u8; 4];
    // 0x1F51:01 program control: a valid command passes the value check, then the application refuses.
    assert_eq!(drive.sdo_read(0x1F51, 1, 0, &mut buf, &mut store), Err(SdoAbort::CannotTransfer));
    assert_eq!(drive.sdo_write(0x1F51, 1, &[1], PRE_OP, &mut store), Err(SdoAbort::CannotTransfer));
    assert_eq!(drive.sdo_write(0x1F51, 1, &[4], PRE_OP, &mut store), Err(SdoAbort::InvalidValue));
    // 0x1F50:01 program data: write-only DOMAIN, expedited or segmented.
    assert_eq!(drive.sdo_read(0x1F50, 1, 0, &mut buf, &mut store), Err(SdoAbort::WriteOnly));
    assert_eq!(drive.sdo_write(0x1F50, 1, &[0xAA; 4], PRE_OP, &mut store), Err(SdoAbort::CannotTransfer));
    let mut download: Download = drive.dictionary().begin_download(0x1F50, 1, Some(8), PRE_OP).expect("initiate");
    let mut objects = drive.objects(&mut store);
    assert_eq!(
        drive.dictionary_mut().download_segment(&mut download, &[0xAA; 4], false, PRE_OP, &mut objects),
        Err(SdoAbort::CannotTransfer)
    );
    assert!(download.is_done());
    // Identification objects.
    assert_eq!(drive.sdo_read(0x1F56, 1, 0, &mut buf, &mut store), Err(SdoAbort::CannotTransfer));
    assert_eq!(drive.sdo_read(0x1F57, 1, 0, &mut buf, &mut store), Err(SdoAbort::CannotTransfer));
}

#[test]
fn commutation_offset_at_index_reaches_the_commutation() {
    let mut store = store();
    let (mut drive, _) = boot(&mut store);
    assert_eq!(drive.dictionary().get(h::INDEX_COMMUTATION_OFFSET), -1, "default: not known");
    assert_eq!(Tier1State::new(drive.settings()).commutation().index_offset(), None);
    let quarter = 16_384i32.to_le_bytes();
    assert_eq!(drive.sdo_write(0x3010, 5, &65_536i32.to_le_bytes(), PRE_OP, &mut store), Err(SdoAbort::ValueTooHigh));
    assert_eq!(drive.sdo_write(0x3010, 5, &(-2i32).to_le_bytes(), PRE_OP, &mut store), Err(SdoAbort::ValueTooLow));
    drive.sdo_write(0x3010, 5, &quarter, PRE_OP, &mut store).expect("0x3010:05");
    drive.switch_on().expect("switch on");
    assert_eq!(Tier1State::new(drive.settings()).commutation().index_offset(), Some(ElectricalAngle::QUARTER_TURN));
    // Writable only with the power disabled (device.toml).
    let enabled = AccessContext { power_stage_enabled: true, ..PRE_OP };
    assert_eq!(drive.sdo_write(0x3010, 5, &quarter, enabled, &mut store), Err(SdoAbort::DeviceState));

    // Persistent: saved and booted, the drive starts with it.
    drive.shutdown();
    drive.sdo_write(0x1010, 1, &SAVE_SIGNATURE.to_le_bytes(), PRE_OP, &mut store).expect("save");
    let (rebooted, _) = boot(&mut store);
    assert_eq!(Tier1State::new(rebooted.settings()).commutation().index_offset(), Some(ElectricalAngle::QUARTER_TURN));
}

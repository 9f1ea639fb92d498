//! EtherCAT process data and synchronisation (issue 6): the PDO layout compiled from the generated dictionary
//! against the SII the drive announces, remapping through SDO writes (CiA 301 §7.5.2.36 procedure, ETG.1000.6
//! 0x1C12/0x1C13) and the abort codes of refused mappings, the images packed and unpacked through the typed
//! handles, the SM2/SM3 checks of PRE-OP -> SAFE-OP (also with sync managers a master configured on the emulated
//! ESC), the 0x1C32/0x1C33 checks with every AL status code, and the sync counters.

use std::path::Path;

use firmware::ecat::esc::{AlStatusCode, Esc, SmConfig};
use firmware::ecat::process_data::{self, Location, PdoError, ProcessDataLayout};
use firmware::ecat::sync::{self, dc_activation, SyncConfig, SyncCounters, SyncMode, Synchronisation};
use firmware::od::abort::SdoAbort;
use firmware::od::access::{AccessContext, CommState, Dictionary, NoApplicationObjects};
use firmware::od::entry::WriteCondition;
use firmware::od::generated::handles as h;
use firmware::od::pdo_map::Direction;
use hal_sim::esc::datagram::{Command, Frame, FrameBuilder};

const PRE_OP: AccessContext =
    AccessContext { comm_state: CommState::PreOperational, power_stage_enabled: false, max_pdo_bytes: 40 };
const SAFE_OP: AccessContext = AccessContext { comm_state: CommState::SafeOperational, ..PRE_OP };

fn write(d: &mut Dictionary, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoAbort> {
    d.write(index, sub, data, PRE_OP, &mut NoApplicationObjects)
}

fn read_u32(d: &Dictionary, index: u16, sub: u8) -> u32 {
    let mut buf = [0u8; 4];
    let n = d.read(index, sub, 0, &mut buf, &mut NoApplicationObjects).expect("readable").len;
    u32::from_le_bytes(buf) & (u64::MAX >> (64 - 8 * n)) as u32
}

/// Maps `entries` into mapping object `pdo` by the CiA 301 procedure (sub 0 = 0, entries, sub 0 = n).
fn map(d: &mut Dictionary, pdo: u16, entries: &[u32]) -> Result<(), SdoAbort> {
    write(d, pdo, 0, &[0])?;
    for (sub, raw) in (1u8..).zip(entries) {
        write(d, pdo, sub, &raw.to_le_bytes())?;
    }
    write(d, pdo, 0, &[u8::try_from(entries.len()).unwrap()])
}

/// Assigns `pdos` to 0x1C12/0x1C13 (sub 0 = 0, entries, sub 0 = n).
fn assign(d: &mut Dictionary, assignment: u16, pdos: &[u16]) -> Result<(), SdoAbort> {
    write(d, assignment, 0, &[0])?;
    for (sub, pdo) in (1u8..).zip(pdos) {
        write(d, assignment, sub, &pdo.to_le_bytes())?;
    }
    write(d, assignment, 0, &[u8::try_from(pdos.len()).unwrap()])
}

/// The CSV set: 0x6040, 0x60FF, 0x6060 out; 0x6041, 0x6064, 0x606C, 0x6061 in.
fn remap_csv(d: &mut Dictionary) {
    assign(d, 0x1C12, &[]).unwrap();
    assign(d, 0x1C13, &[]).unwrap();
    map(d, 0x1600, &[0x6040_0010, 0x60FF_0020, 0x6060_0008]).unwrap();
    map(d, 0x1A00, &[0x6041_0010, 0x6064_0020, 0x606C_0020, 0x6061_0008]).unwrap();
    assign(d, 0x1C12, &[0x1600]).unwrap();
    assign(d, 0x1C13, &[0x1A00]).unwrap();
}

/// (index, sub, bit offset, bits) of the mapped objects of one image.
fn objects(items: &[process_data::PdoItem]) -> Vec<(u16, u8, u16, u8)> {
    items.iter().filter(|i| i.location != Location::Padding).map(|i| (i.index, i.sub, i.bit_offset, i.bits)).collect()
}

#[test]
fn default_layout_has_the_sizes_and_entries_the_sii_announces() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware/device.toml");
    let description = od_gen::load(&path).expect("device.toml");
    let info = od_gen::sii::decode(&od_gen::sii::sii(&description)).expect("SII decodes");
    let layout = ProcessDataLayout::from_dictionary(&Dictionary::new(1)).expect("the defaults compile");

    // SII category 41: SM2 / SM3 default sizes are the process images.
    assert_eq!(info.sync_managers[2].length, layout.output_bytes);
    assert_eq!(info.sync_managers[3].length, layout.input_bytes);
    assert!(layout.output_bytes > 0 && layout.input_bytes > 0);

    // SII categories 51/50: the assigned PDOs and their entries, in image order.
    let sii_items = |pdos: &[od_gen::sii::SiiPdo]| -> Vec<(u16, u8, u16, u8)> {
        let mut offset = 0u16;
        let mut out = Vec::new();
        for e in pdos.iter().flat_map(|p| &p.entries) {
            if e.index != 0 {
                out.push((e.index, e.sub, offset, e.bit_len));
            }
            offset += u16::from(e.bit_len);
        }
        out
    };
    assert_eq!(layout.output_pdos(), info.rx_pdos.iter().map(|p| p.index).collect::<Vec<_>>());
    assert_eq!(layout.input_pdos(), info.tx_pdos.iter().map(|p| p.index).collect::<Vec<_>>());
    assert_eq!(objects(layout.output_items()), sii_items(&info.rx_pdos));
    assert_eq!(objects(layout.input_items()), sii_items(&info.tx_pdos));
}

#[test]
fn remap_to_csv_and_back() {
    let mut d = Dictionary::new(1);
    let default = ProcessDataLayout::from_dictionary(&d).unwrap();
    let defaults = Dictionary::new(1);

    remap_csv(&mut d);
    let csv = ProcessDataLayout::from_dictionary(&d).unwrap();
    assert_eq!((csv.output_bytes, csv.input_bytes), (7, 11));
    assert_eq!(csv.output_pdos(), [0x1600]);
    assert_eq!(objects(csv.output_items()), [(0x6040, 0, 0, 16), (0x60FF, 0, 16, 32), (0x6060, 0, 48, 8)]);
    assert_eq!(
        objects(csv.input_items()),
        [(0x6041, 0, 0, 16), (0x6064, 0, 16, 32), (0x606C, 0, 48, 32), (0x6061, 0, 80, 8)]
    );
    // Each object is located at its typed handle's slot: no search per cycle.
    let slot = |items: &[process_data::PdoItem], index: u16| {
        items.iter().find(|i| i.index == index).map(|i| i.location).unwrap()
    };
    let at = |offset: usize, len: u16| Location::Value { offset: u16::try_from(offset).unwrap(), len };
    assert_eq!(slot(csv.output_items(), 0x60FF), at(h::TARGET_VELOCITY.offset(), 4));
    assert_eq!(slot(csv.input_items(), 0x6061), at(h::MODES_OF_OPERATION_DISPLAY.offset(), 1));

    // Back: the default entries and assignments, written the same way, give the default layout again.
    let stored = |index: u16| -> Vec<u32> {
        let n = read_u32(&defaults, index, 0);
        (1..=n).map(|s| read_u32(&defaults, index, u8::try_from(s).unwrap())).collect()
    };
    assign(&mut d, 0x1C12, &[]).unwrap();
    assign(&mut d, 0x1C13, &[]).unwrap();
    for pdo in [0x1600, 0x1A00] {
        map(&mut d, pdo, &stored(pdo)).unwrap();
    }
    let pdos = |a: u16| stored(a).into_iter().map(|p| u16::try_from(p).unwrap()).collect::<Vec<_>>();
    assign(&mut d, 0x1C12, &pdos(0x1C12)).unwrap();
    assign(&mut d, 0x1C13, &pdos(0x1C13)).unwrap();
    assert_eq!(ProcessDataLayout::from_dictionary(&d).unwrap(), default);
}

#[test]
fn refused_mappings_carry_their_abort_codes() {
    let mut d = Dictionary::new(1);
    assign(&mut d, 0x1C12, &[]).unwrap();
    // Unmappable objects (a string; 0x1000, mappable in neither direction), missing object, wrong length.
    assert_eq!(map(&mut d, 0x1600, &[0x1008_0000]), Err(SdoAbort::CannotBeMapped));
    assert_eq!(map(&mut d, 0x1600, &[0x1000_0020]), Err(SdoAbort::CannotBeMapped));
    assert_eq!(map(&mut d, 0x1A02, &[0x1000_0020]), Err(SdoAbort::CannotBeMapped));
    assert_eq!(map(&mut d, 0x1600, &[0x6042_0010]), Err(SdoAbort::ObjectDoesNotExist));
    assert_eq!(map(&mut d, 0x1600, &[0x6040_0020]), Err(SdoAbort::ParameterIncompatibility));
    // Wrong direction: an actual value in an RxPDO, a set-point in a TxPDO.
    assert_eq!(map(&mut d, 0x1600, &[0x6041_0010]), Err(SdoAbort::CannotBeMapped));
    assert_eq!(map(&mut d, 0x1A02, &[0x6040_0010]), Err(SdoAbort::CannotBeMapped));
    // Too long: 12 x 32 bits = 48 bytes in one PDO; two PDOs of 36 + 8 bytes in one image.
    assert_eq!(map(&mut d, 0x1600, &[0x607A_0020; 12]), Err(SdoAbort::PdoLengthExceeded));
    map(&mut d, 0x1600, &[0x607A_0020; 9]).unwrap();
    map(&mut d, 0x1601, &[0x607A_0020, 0x60FF_0020]).unwrap();
    assert_eq!(assign(&mut d, 0x1C12, &[0x1600, 0x1601]), Err(SdoAbort::PdoLengthExceeded));
    // Assignment of a PDO that does not exist, or of the other direction.
    assert_eq!(assign(&mut d, 0x1C12, &[0x1604]), Err(SdoAbort::InvalidValue));
    assert_eq!(assign(&mut d, 0x1C12, &[0x1A00]), Err(SdoAbort::InvalidValue));
    assert_eq!(assign(&mut d, 0x1C13, &[0x1600]), Err(SdoAbort::InvalidValue));
    // A failed write changes nothing: the last accepted configuration (0x1C12:00 = 0) still compiles.
    let layout = ProcessDataLayout::from_dictionary(&d).unwrap();
    assert_eq!(layout.output_bytes, 0);
}

#[test]
fn the_whole_is_checked_again_at_safe_op_with_the_direction() {
    // A PDO assigned twice passes each SDO write but not the whole: 0x0609_0030, outputs -> AL 0x0025.
    let mut d = Dictionary::new(1);
    assign(&mut d, 0x1C12, &[0x1600, 0x1600]).unwrap();
    let err = ProcessDataLayout::compile(&d).unwrap_err();
    assert_eq!(err, PdoError { direction: Direction::Rx, abort: SdoAbort::InvalidValue });
    assert_eq!(err.al_status(), AlStatusCode::InvalidOutputMapping);
    assert_eq!(ProcessDataLayout::from_dictionary(&d), Err(SdoAbort::InvalidValue));

    // A stored mapping that bypassed the SDO checks (an old parameter image): inputs -> AL 0x0024.
    let mut d = Dictionary::new(1);
    let entry = d.find(0x1A00, 1).unwrap();
    assert!(d.values_mut().set_raw(entry, &0x6040_0010u32.to_le_bytes()));
    let err = ProcessDataLayout::compile(&d).unwrap_err();
    assert_eq!(err, PdoError { direction: Direction::Tx, abort: SdoAbort::CannotBeMapped });
    assert_eq!(err.al_status(), AlStatusCode::InvalidInputMapping);

    // An assignment count above what 0x1C12 holds.
    let mut d = Dictionary::new(1);
    let entry = d.find(0x1C12, 0).unwrap();
    assert!(d.values_mut().set_raw(entry, &[5]));
    assert_eq!(ProcessDataLayout::compile(&d).map(|_| ()).unwrap_err().abort, SdoAbort::ValueTooHigh);
}

#[test]
fn pdo_configuration_is_writable_in_pre_op_only() {
    let mut d = Dictionary::new(1);
    for index in [0x1600u16, 0x1601, 0x1602, 0x1603, 0x1A00, 0x1A01, 0x1A02, 0x1A03, 0x1C12, 0x1C13] {
        assert!(process_data::is_pdo_configuration(index));
        for entry in d.table().entries_of(index) {
            assert_eq!(entry.write_condition(), WriteCondition::PreOperational, "{index:04X}:{}", entry.sub);
        }
        let mut current = [0u8; 4];
        let n = d.read(index, 0, 0, &mut current, &mut NoApplicationObjects).unwrap().len;
        let r = d.write(index, 0, &current[..n], SAFE_OP, &mut NoApplicationObjects);
        assert_eq!(r, Err(SdoAbort::DeviceState), "{index:04X}");
    }
    assert!(!process_data::is_pdo_configuration(0x1C32));
    assert!(process_data::writable_in_state(CommState::PreOperational));
    for state in [CommState::Init, CommState::SafeOperational, CommState::Operational, CommState::Bootstrap] {
        assert!(!process_data::writable_in_state(state));
    }
}

#[test]
fn pack_and_unpack_go_through_the_typed_handles() {
    let mut d = Dictionary::new(1);
    remap_csv(&mut d);
    let layout = ProcessDataLayout::from_dictionary(&d).unwrap();

    // Outputs: 0x6040 at byte 0, 0x60FF at 2, 0x6060 at 6.
    let mut out = [0u8; 7];
    out[0..2].copy_from_slice(&0x000Fu16.to_le_bytes());
    out[2..6].copy_from_slice(&(-123_456i32).to_le_bytes());
    out[6] = 9u8;
    layout.unpack_outputs(&out, &mut d);
    assert_eq!(d.get(h::CONTROLWORD), 0x000F);
    assert_eq!(d.get(h::TARGET_VELOCITY), -123_456);
    assert_eq!(d.get(h::MODES_OF_OPERATION), 9);

    // Inputs: 0x6041 at byte 0, 0x6064 at 2, 0x606C at 6, 0x6061 at 10.
    d.set(h::STATUSWORD, 0x1237);
    d.set(h::POSITION_ACTUAL_VALUE, -7);
    d.set(h::VELOCITY_ACTUAL_VALUE, 0x0102_0304);
    d.set(h::MODES_OF_OPERATION_DISPLAY, -3);
    let mut input = [0xAAu8; 11];
    layout.pack_inputs(&d, &mut input);
    assert_eq!(input, [0x37, 0x12, 0xF9, 0xFF, 0xFF, 0xFF, 0x04, 0x03, 0x02, 0x01, 0xFD]);

    // The default layout: every mapped object lands in the image at its bit offset and comes back.
    let mut d = Dictionary::new(1);
    let layout = ProcessDataLayout::from_dictionary(&d).unwrap();
    let mut image = vec![0u8; usize::from(layout.output_bytes)];
    for (k, b) in image.iter_mut().enumerate() {
        *b = 0x11u8.wrapping_mul(u8::try_from(k + 1).unwrap());
    }
    layout.unpack_outputs(&image, &mut d);
    for item in layout.output_items() {
        let Location::Value { offset, len } = item.location else { continue };
        let at = usize::from(item.bit_offset / 8);
        let stored = &d.values().bytes()[usize::from(offset)..usize::from(offset + len)];
        assert_eq!(stored, &image[at..at + usize::from(len)], "{:04X}", item.index);
    }
    let mut inputs = vec![0u8; usize::from(layout.input_bytes)];
    layout.pack_inputs(&d, &mut inputs);
    for item in layout.input_items() {
        let Location::Value { offset, len } = item.location else { continue };
        let at = usize::from(item.bit_offset / 8);
        let stored = &d.values().bytes()[usize::from(offset)..usize::from(offset + len)];
        assert_eq!(&inputs[at..at + usize::from(len)], stored, "{:04X}", item.index);
    }
}

/// The firmware's view of the emulated ESC (its PDI accessors).
struct Pdi<'a>(&'a mut hal_sim::esc::Esc);

impl Esc for Pdi<'_> {
    fn read(&mut self, address: u16, buf: &mut [u8]) {
        self.0.pdi_read(address, buf);
    }
    fn write(&mut self, address: u16, data: &[u8]) {
        self.0.pdi_write(address, data);
    }
}

/// Runs one auto-increment datagram (the only slave has position 0) and returns its data and working counter.
fn master(esc: &mut hal_sim::esc::Esc, cmd: Command, ado: u16, data: &[u8]) -> (Vec<u8>, u16) {
    let mut frame = FrameBuilder::new().push(cmd, 0, ado, data).build();
    esc.process_frame(&mut frame).expect("frame processed");
    let frame = Frame::new_checked(&frame).unwrap();
    let datagram = frame.datagram(0).unwrap();
    (datagram.data().to_vec(), datagram.wkc())
}

fn sm_bytes(start: u16, length: u16, control: u8, activate: u8) -> [u8; 8] {
    let [s0, s1] = start.to_le_bytes();
    let [l0, l1] = length.to_le_bytes();
    [s0, s1, l0, l1, control, 0, activate, 0]
}

#[test]
fn sync_managers_configured_by_a_master_carry_the_images() {
    let mut d = Dictionary::new(1);
    remap_csv(&mut d);
    let layout = ProcessDataLayout::from_dictionary(&d).unwrap();
    let mut esc = hal_sim::esc::Esc::with_drive_sii().unwrap();
    // As SOEM configures them from the SII: SM2 0x1100 control 0x64, SM3 0x1180 control 0x20.
    master(&mut esc, Command::Apwr, 0x0810, &sm_bytes(0x1100, layout.output_bytes, 0x64, 1));
    master(&mut esc, Command::Apwr, 0x0818, &sm_bytes(0x1180, layout.input_bytes, 0x20, 1));
    let (sm2, sm3) = {
        let mut pdi = Pdi(&mut esc);
        (SmConfig::read(&mut pdi, 2), SmConfig::read(&mut pdi, 3))
    };
    assert_eq!(layout.check_sync_managers(&sm2, &sm3), Ok(()));

    // Outputs written by the master reach the handles; inputs packed by the drive reach the master.
    let mut out = [0u8; 7];
    out[0..2].copy_from_slice(&0x001Fu16.to_le_bytes());
    out[2..6].copy_from_slice(&5_000i32.to_le_bytes());
    out[6] = 9;
    assert_eq!(master(&mut esc, Command::Apwr, 0x1100, &out).1, 1);
    let mut image = [0u8; 7];
    Pdi(&mut esc).read(sm2.start, &mut image);
    layout.unpack_outputs(&image, &mut d);
    assert_eq!((d.get(h::CONTROLWORD), d.get(h::TARGET_VELOCITY), d.get(h::MODES_OF_OPERATION)), (0x1F, 5_000, 9));

    d.set(h::STATUSWORD, 0x0237);
    d.set(h::POSITION_ACTUAL_VALUE, 1_000_000);
    let mut inputs = [0u8; 11];
    layout.pack_inputs(&d, &mut inputs);
    Pdi(&mut esc).write(sm3.start, &inputs);
    let (seen, wkc) = master(&mut esc, Command::Aprd, 0x1180, &[0; 11]);
    assert_eq!((seen.as_slice(), wkc), (&inputs[..], 1));
    assert_eq!(&seen[0..2], &0x0237u16.to_le_bytes());
    assert_eq!(&seen[2..6], &1_000_000i32.to_le_bytes());
}

#[test]
fn sync_manager_checks_give_0x001d_and_0x001e() {
    let mut d = Dictionary::new(1);
    remap_csv(&mut d);
    let layout = ProcessDataLayout::from_dictionary(&d).unwrap();
    let sm = |start, length, control, activate| SmConfig { start, length, control, activate };
    let sm2 = sm(0x1100, 7, 0x64, 1);
    let sm3 = sm(0x1180, 11, 0x20, 1);
    assert_eq!(layout.check_sync_managers(&sm2, &sm3), Ok(()));

    let out = Err(AlStatusCode::InvalidOutputConfig);
    for (bad, why) in [
        (sm(0x1100, 7, 0x64, 0), "disabled"),
        (sm(0x1100, 8, 0x64, 1), "too long"),
        (sm(0x1100, 6, 0x64, 1), "too short"),
        (sm(0x1100, 7, 0x66, 1), "mailbox mode"),
        (sm(0x1100, 7, 0x60, 1), "master reads"),
        (sm(0x0F00, 7, 0x64, 1), "below process RAM"),
        (sm(0xFFFC, 7, 0x64, 1), "past the address space"),
    ] {
        assert_eq!(layout.check_sync_managers(&bad, &sm3), out, "SM2 {why}");
    }
    let inp = Err(AlStatusCode::InvalidInputConfig);
    for (bad, why) in [
        (sm(0x1180, 11, 0x20, 0), "disabled"),
        (sm(0x1180, 12, 0x20, 1), "wrong length"),
        (sm(0x1180, 11, 0x22, 1), "mailbox mode"),
        (sm(0x1180, 11, 0x24, 1), "master writes"),
    ] {
        assert_eq!(layout.check_sync_managers(&sm2, &bad), inp, "SM3 {why}");
    }

    // No outputs: SM2 disabled (or of length 0) is fine, an enabled window is not.
    assign(&mut d, 0x1C12, &[]).unwrap();
    let layout = ProcessDataLayout::from_dictionary(&d).unwrap();
    assert_eq!(layout.output_bytes, 0);
    assert_eq!(layout.check_sync_managers(&sm(0, 0, 0, 0), &sm3), Ok(()));
    assert_eq!(layout.check_sync_managers(&sm(0x1100, 7, 0x64, 0), &sm3), Ok(()));
    assert_eq!(layout.check_sync_managers(&sm(0x1100, 0, 0x64, 1), &sm3), Ok(()));
    assert_eq!(layout.check_sync_managers(&sm(0x1100, 7, 0x64, 1), &sm3), out);
}

fn config(output_type: u16, input_type: u16, cycle_ns: u32) -> SyncConfig {
    let mut c = SyncConfig::from_dictionary(&Dictionary::new(1));
    c.output_type = output_type;
    c.input_type = input_type;
    c.cycle_ns = cycle_ns;
    c
}

const DC_ON: u8 = dc_activation::CYCLIC_OPERATION | dc_activation::SYNC0;

#[test]
fn sync_configuration_from_the_dictionary() {
    let mut d = Dictionary::new(1);
    let c = SyncConfig::from_dictionary(&d);
    assert_eq!(
        c,
        SyncConfig { output_type: 1, input_type: 0x22, cycle_ns: 1_000_000, supported: 0x0007, min_cycle_ns: 200_000 }
    );
    assert_eq!(c.min_cycle_ns, sync::MIN_CYCLE_NS);
    for (index, sub) in [(0x1C32u16, 6u8), (0x1C32, 9), (0x1C33, 6), (0x1C33, 9), (0x1C33, 5), (0x1C33, 4)] {
        d.find(index, sub).unwrap_or_else(|_| panic!("{index:04X}:{sub:02X} exists"));
    }
    // A master sets DC through SDO (as TwinCAT does) in PRE-OP.
    write(&mut d, 0x1C32, 1, &2u16.to_le_bytes()).unwrap();
    write(&mut d, 0x1C33, 1, &2u16.to_le_bytes()).unwrap();
    write(&mut d, 0x1C32, 2, &400_000u32.to_le_bytes()).unwrap();
    let c = SyncConfig::from_dictionary(&d);
    assert_eq!((c.output_type, c.input_type, c.cycle_ns), (2, 2, 400_000));
    assert_eq!(sync::check(&c, DC_ON, 400_000), Ok(()));
}

#[test]
fn sync_checks_give_each_al_status_code() {
    use AlStatusCode::*;
    let sm = config(1, 0x22, 1_000_000);
    let dc = config(2, 2, 1_000_000);
    let free = config(0, 0, 1_000_000);

    // Accepted: SM-synchronous (cycle measured), DC through 0x1C32 or through the ESC only (SOEM, ethercrab),
    // free run at 1 ms and at 200 us.
    let mode = |c: &SyncConfig, act, cycle| c.resolve(act, cycle).map(|s| (s.mode, s.cycle_ns, s.current_periods));
    assert_eq!(mode(&sm, 0, 0), Ok((SyncMode::SmSynchronous, 1_000_000, 0)));
    assert_eq!(mode(&dc, DC_ON, 1_000_000), Ok((SyncMode::DcSync0, 1_000_000, 25)));
    assert_eq!(mode(&sm, DC_ON, 200_000), Ok((SyncMode::DcSync0, 200_000, 5)));
    assert_eq!(mode(&sm, DC_ON | dc_activation::SYNC1, 200_000).map(|m| m.0), Ok(SyncMode::DcSync0));
    assert_eq!(mode(&free, 0, 0), Ok((SyncMode::FreeRun, 1_000_000, 25)));
    assert_eq!(mode(&config(0, 0, 200_000), 0, 0), Ok((SyncMode::FreeRun, 200_000, 5)));

    // 0x0028: unknown types, mismatched pairs, a mode 0x1C32:04 does not list; 0x0027 for free run.
    assert_eq!(sync::check(&config(3, 3, 1_000_000), DC_ON, 1_000_000), Err(SyncNotSupported));
    assert_eq!(sync::check(&config(1, 1, 1_000_000), 0, 0), Err(SyncNotSupported));
    assert_eq!(sync::check(&config(2, 0x22, 1_000_000), DC_ON, 1_000_000), Err(SyncNotSupported));
    assert_eq!(sync::check(&config(0, 2, 1_000_000), 0, 0), Err(SyncNotSupported));
    assert_eq!(sync::check(&SyncConfig { supported: 0x0003, ..dc }, DC_ON, 1_000_000), Err(SyncNotSupported));
    assert_eq!(sync::check(&SyncConfig { supported: 0x0005, ..sm }, 0, 0), Err(SyncNotSupported));
    assert_eq!(sync::check(&SyncConfig { supported: 0x0006, ..free }, 0, 0), Err(FreeRunNotSupported));

    // 0x0030: the DC activation and the requested mode disagree, or SYNC0 is single shot.
    assert_eq!(sync::check(&dc, 0, 1_000_000), Err(InvalidDcSyncConfig));
    assert_eq!(sync::check(&dc, dc_activation::SYNC0, 1_000_000), Err(InvalidDcSyncConfig));
    assert_eq!(sync::check(&dc, dc_activation::CYCLIC_OPERATION, 1_000_000), Err(InvalidDcSyncConfig));
    assert_eq!(
        sync::check(&dc, dc_activation::CYCLIC_OPERATION | dc_activation::SYNC1, 1_000_000),
        Err(InvalidDcSyncConfig)
    );
    assert_eq!(sync::check(&free, DC_ON, 1_000_000), Err(InvalidDcSyncConfig));
    assert_eq!(sync::check(&dc, DC_ON, 0), Err(InvalidDcSyncConfig));

    // 0x0036: below 200 us; 0x0035: not a whole multiple of 40 us, or above 100 ms.
    assert_eq!(sync::check(&dc, DC_ON, 160_000), Err(DcSync0CycleTime));
    assert_eq!(sync::check(&sm, DC_ON, 199_999), Err(DcSync0CycleTime));
    assert_eq!(sync::check(&config(0, 0, 120_000), 0, 0), Err(DcSync0CycleTime));
    assert_eq!(sync::check(&dc, DC_ON, 250_000), Err(DcInvalidSyncCycleTime));
    assert_eq!(sync::check(&dc, DC_ON, 1_000_001), Err(DcInvalidSyncCycleTime));
    assert_eq!(sync::check(&config(0, 0, 500_000), 0, 0), Err(DcInvalidSyncCycleTime));
    assert_eq!(sync::check(&dc, DC_ON, 100_040_000), Err(DcInvalidSyncCycleTime));
    assert_eq!(sync::check(&dc, DC_ON, 100_000_000), Ok(()));
    // SM-synchronous the cycle is the master's: 0x1C32:02 is not judged.
    assert_eq!(sync::check(&config(1, 0x22, 250_000), 0, 0), Ok(()));
}

#[test]
fn dc_publishes_the_sync0_cycle() {
    let mut d = Dictionary::new(1);
    let sync = SyncConfig::from_dictionary(&d).resolve(DC_ON, 400_000).unwrap();
    sync.publish(&mut d);
    for index in [0x1C32, 0x1C33] {
        assert_eq!((read_u32(&d, index, 2), read_u32(&d, index, 0x0A)), (400_000, 400_000), "{index:04X}");
    }
    assert_eq!(read_u32(&d, 0x1C32, 1), 1, "sub 1 keeps what the master wrote");
    let sync = SyncConfig::from_dictionary(&d).resolve(0, 0).unwrap();
    sync.publish(&mut d);
    assert_eq!((read_u32(&d, 0x1C32, 2), read_u32(&d, 0x1C32, 0x0A)), (400_000, 0));
}

#[test]
fn dc_set_up_by_a_master_through_the_esc_is_found() {
    let d = Dictionary::new(1);
    let mut esc = hal_sim::esc::Esc::with_drive_sii().unwrap();
    let found = |esc: &mut hal_sim::esc::Esc| sync::check_esc(&mut Pdi(esc), &d).map(|s| (s.mode, s.cycle_ns));
    assert_eq!(found(&mut esc), Ok((SyncMode::SmSynchronous, 1_000_000)));
    // As SOEM's `ecx_dcsync0` and ethercrab do: SYNC0 cycle, then activation 0x03 at 0x0981.
    master(&mut esc, Command::Apwr, 0x09A0, &1_000_000u32.to_le_bytes());
    master(&mut esc, Command::Apwr, 0x0981, &[DC_ON]);
    assert_eq!(found(&mut esc), Ok((SyncMode::DcSync0, 1_000_000)));
    master(&mut esc, Command::Apwr, 0x09A0, &250_000u32.to_le_bytes());
    assert_eq!(found(&mut esc), Err(AlStatusCode::DcInvalidSyncCycleTime));
}

fn dc_sync(cycle_ns: u32) -> Synchronisation {
    Synchronisation { mode: SyncMode::DcSync0, cycle_ns, sync0_cycle_ns: cycle_ns, current_periods: 0 }
}

#[test]
fn dc_counts_missed_sm_events_and_raises_the_sync_error() {
    let mut d = Dictionary::new(1);
    assert_eq!(d.get(h::SYNC_ERROR_COUNTER_LIMIT), 4);
    let mut c = SyncCounters::from_dictionary(&dc_sync(1_000_000), &d);
    // Before the first SM2 event nothing counts (outputs not valid yet).
    assert_eq!(c.sync0(), Ok(()));
    assert_eq!(c.sm_event_missed(), 0);
    // 1,000 good cycles, with the clock wrapping: no miss, no too-small cycle.
    let mut now = u32::MAX - 5_000_000;
    for _ in 0..1_000 {
        c.sm_event(now);
        assert_eq!(c.sync0(), Ok(()));
        now = now.wrapping_add(1_000_000);
    }
    assert_eq!((c.sm_event_missed(), c.cycle_time_too_small(), c.measured_cycle_ns()), (0, 0, 1_000_000));
    // One miss is tolerated (internal counter 3 <= 4) and healed by good cycles; two in a row are not.
    assert_eq!(c.sync0(), Ok(()));
    assert_eq!(c.sm_event_missed(), 1);
    for _ in 0..3 {
        c.sm_event(now);
        assert_eq!(c.sync0(), Ok(()));
        now = now.wrapping_add(1_000_000);
    }
    assert_eq!(c.sync0(), Ok(()));
    assert_eq!(c.sync0(), Err(AlStatusCode::SyncError));
    assert!(c.sync_error());
    c.sm_event(now);
    assert_eq!(c.sync0(), Err(AlStatusCode::SyncError), "the sync error stays until reset");
    c.publish(&mut d);
    for index in [0x1C32, 0x1C33] {
        assert_eq!((read_u32(&d, index, 0x0B), read_u32(&d, index, 0x20)), (3, 1), "{index:04X}");
    }
    c.reset();
    c.publish(&mut d);
    assert_eq!((read_u32(&d, 0x1C32, 0x0B), read_u32(&d, 0x1C32, 0x20)), (0, 0));
}

#[test]
fn cycle_time_too_small_counts_events_closer_than_the_minimum_cycle() {
    let mut d = Dictionary::new(1);
    let mut c = SyncCounters::new(&dc_sync(200_000), 4);
    c.sm_event(0);
    c.sm_event(200_000);
    c.sm_event(399_999);
    c.sm_event(450_000);
    assert_eq!(c.cycle_time_too_small(), 2);
    c.publish(&mut d);
    assert_eq!((read_u32(&d, 0x1C32, 0x0C), read_u32(&d, 0x1C33, 0x0C)), (2, 2));
}

#[test]
fn sm_synchronous_detects_missing_frames_by_time() {
    let sm =
        Synchronisation { mode: SyncMode::SmSynchronous, cycle_ns: 1_000_000, sync0_cycle_ns: 0, current_periods: 0 };
    let mut c = SyncCounters::new(&sm, 4);
    c.sm_event(0);
    assert_eq!(c.poll(5_000_000), Ok(()), "nothing is judged before the cycle is measured");
    c.sm_event(6_000_000);
    c.sm_event(7_000_000);
    // Polled every 200 us: frames at 8 and 11 ms, 9 and 10 ms missing -> two misses.
    let mut missed = 0;
    for t in (7_200_000..11_000_000).step_by(200_000) {
        if t == 8_000_000 {
            c.sm_event(t);
        }
        let _ = c.poll(t);
        missed = c.sm_event_missed();
    }
    assert_eq!(missed, 2);
    // A master slower than 0x1C32:02 says (2 ms against 1 ms): no false misses once measured.
    let mut c = SyncCounters::new(&sm, 4);
    for k in 0..100u32 {
        c.sm_event(k * 2_000_000);
        for p in 1..10 {
            assert_eq!(c.poll(k * 2_000_000 + p * 200_000), Ok(()));
        }
    }
    assert_eq!(c.sm_event_missed(), 0);
    // Free run never counts by time.
    let free = Synchronisation { mode: SyncMode::FreeRun, ..sm };
    let mut c = SyncCounters::new(&free, 4);
    c.sm_event(0);
    c.sm_event(1_000_000);
    assert_eq!(c.poll(50_000_000), Ok(()));
    assert_eq!(c.sm_event_missed(), 0);
}

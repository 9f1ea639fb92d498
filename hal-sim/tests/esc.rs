//! In-process tests of the emulated EtherCAT slave controller: golden frames a master would send, checked
//! against the register facts of the ESC datasheet / ETG.1000.4 and the spec file
//! (`shared/spec/fieldbus-real-masters.md`).

use hal_sim::esc::datagram::{Command, Frame, FrameBuilder, FrameError};
use hal_sim::esc::registers::{al_event, al_state, reg};
use hal_sim::esc::{esm, Esc};
use proptest::prelude::*;

const STATION: u16 = 0x1001;

fn esc() -> Esc {
    Esc::with_drive_sii().expect("the drive's SII image builds from firmware/device.toml")
}

/// Processes `b` and returns the returned frame.
fn run(esc: &mut Esc, b: FrameBuilder) -> Vec<u8> {
    let mut f = b.build();
    esc.process_frame(&mut f).expect("well-formed frame");
    f
}

/// Data and working counter of datagram `n` of a returned frame.
fn dg(frame: &[u8], n: usize) -> (Vec<u8>, u16) {
    let f = Frame::new_checked(frame).expect("returned frame parses");
    let d = f.datagram(n).expect("datagram present");
    (d.data().to_vec(), d.wkc())
}

/// One datagram, returns (data, wkc).
fn one(esc: &mut Esc, cmd: Command, adp: u16, ado: u16, data: &[u8]) -> (Vec<u8>, u16) {
    let f = run(esc, FrameBuilder::new().push(cmd, adp, ado, data));
    dg(&f, 0)
}

fn fprd(esc: &mut Esc, ado: u16, len: usize) -> (Vec<u8>, u16) {
    one(esc, Command::Fprd, STATION, ado, &vec![0; len])
}

fn fpwr(esc: &mut Esc, ado: u16, data: &[u8]) -> u16 {
    one(esc, Command::Fpwr, STATION, ado, data).1
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from(u32_at(b, at)) | u64::from(u32_at(b, at + 4)) << 32
}

/// An ESC with station address 0x1001 (APWR 0x0010 as every master does first).
fn addressed() -> Esc {
    let mut e = esc();
    let (_, wkc) = one(&mut e, Command::Apwr, 0, reg::STATION_ADDRESS, &STATION.to_le_bytes());
    assert_eq!(wkc, 1);
    e
}

/// SM entry bytes (start, length, control, status, activate, PDI control).
fn sm_bytes(start: u16, len: u16, control: u8, enable: u8) -> [u8; 8] {
    let [s0, s1] = start.to_le_bytes();
    let [l0, l1] = len.to_le_bytes();
    [s0, s1, l0, l1, control, 0, enable, 0]
}

/// Configures SM0/SM1 from the SII SYNCM category, like a master (FPWR 0x0800 len 16).
fn configure_mailboxes(e: &mut Esc) -> (u16, u16, u16, u16) {
    let info = od_gen::sii::decode(&e.sii().image).expect("SII decodes");
    let (m0, m1) = (info.sync_managers[0], info.sync_managers[1]);
    let mut cfg = Vec::new();
    cfg.extend_from_slice(&sm_bytes(m0.start, m0.length, m0.control, m0.enable));
    cfg.extend_from_slice(&sm_bytes(m1.start, m1.length, m1.control, m1.enable));
    assert_eq!(fpwr(e, reg::SM0, &cfg), 1);
    (m0.start, m0.length, m1.start, m1.length)
}

fn fmmu_bytes(logical: u32, len: u16, start_bit: u8, stop_bit: u8, phys: u16, phys_bit: u8, kind: u8) -> [u8; 16] {
    let mut b = [0u8; 16];
    b[0..4].copy_from_slice(&logical.to_le_bytes());
    b[4..6].copy_from_slice(&len.to_le_bytes());
    b[6] = start_bit;
    b[7] = stop_bit;
    b[8..10].copy_from_slice(&phys.to_le_bytes());
    b[10] = phys_bit;
    b[11] = kind;
    b[12] = 1;
    b
}

#[test]
fn brd_of_0x0000_returns_the_esc_info_with_wkc_1() {
    let mut e = esc();
    let f = run(&mut e, FrameBuilder::new().push(Command::Brd, 0, 0x0000, &[0; 10]));
    let (data, wkc) = dg(&f, 0);
    assert_eq!(wkc, 1);
    // Spec file item 2: type 0x04, FMMU# 8, SM# 8, RAM 8 KiB, port descriptor 0x0F, features 0x000C.
    assert_eq!(data[0], 0x04);
    assert_eq!(&data[4..8], &[8, 8, 8, 0x0F]);
    assert_eq!(u16_at(&data, 8), 0x000C);
    let frame = Frame::new_checked(&f).unwrap();
    // Broadcast: every slave increments ADP; the returned source MAC has bit 1 of its first byte set.
    assert_eq!(frame.datagram(0).unwrap().adp(), 1);
    assert_eq!(frame.source()[0], 0x03);
    // BRD ORs: bits the master sent set stay set.
    let (data, _) = one(&mut e, Command::Brd, 0, 0x0000, &[0x80, 0, 0, 0]);
    assert_eq!(data[0], 0x84);
}

#[test]
fn read_only_registers_survive_broadcast_writes() {
    let mut e = esc();
    let (before, _) = one(&mut e, Command::Brd, 0, 0x0000, &[0; 16]);
    let (_, wkc) = one(&mut e, Command::Bwr, 0, 0x0000, &[0xAA; 16]);
    assert_eq!(wkc, 1, "a write to read-only registers still counts");
    let (after, _) = one(&mut e, Command::Brd, 0, 0x0000, &[0; 16]);
    assert_eq!(before, after);
    one(&mut e, Command::Bwr, 0, reg::DL_STATUS, &[0, 0]);
    one(&mut e, Command::Bwr, 0, reg::AL_STATUS, &[0x08, 0, 0, 0, 0x11, 0]);
    let (dl, _) = one(&mut e, Command::Brd, 0, reg::DL_STATUS, &[0, 0]);
    assert_eq!(u16_at(&dl, 0), 0x5613);
    let (al, _) = one(&mut e, Command::Brd, 0, reg::AL_STATUS, &[0; 6]);
    assert_eq!((u16_at(&al, 0), u16_at(&al, 4)), (0x0001, 0));
}

#[test]
fn apwr_sets_the_station_address_and_fprd_uses_it() {
    let mut e = esc();
    // Auto-increment: only the slave that sees ADP == 0 is addressed; position 1 (ADP 0xFFFF) is not us.
    let f = run(&mut e, FrameBuilder::new().push(Command::Apwr, 0xFFFF, reg::STATION_ADDRESS, &[0x22, 0x22]));
    assert_eq!(dg(&f, 0).1, 0);
    assert_eq!(Frame::new_checked(&f).unwrap().datagram(0).unwrap().adp(), 0);
    assert_eq!(e.station_address(), 0);
    let (_, wkc) = one(&mut e, Command::Apwr, 0, reg::STATION_ADDRESS, &STATION.to_le_bytes());
    assert_eq!(wkc, 1);
    assert_eq!(e.station_address(), STATION);
    let (d, wkc) = one(&mut e, Command::Aprd, 0, reg::STATION_ADDRESS, &[0, 0]);
    assert_eq!((u16_at(&d, 0), wkc), (STATION, 1));

    let (al, wkc) = fprd(&mut e, reg::AL_STATUS, 2);
    assert_eq!((u16_at(&al, 0), wkc), (al_state::INIT, 1));
    let (_, wkc) = one(&mut e, Command::Fprd, STATION + 1, reg::AL_STATUS, &[0, 0]);
    assert_eq!(wkc, 0, "another station address is not us");
    let (dl, _) = fprd(&mut e, reg::DL_STATUS, 2);
    assert_eq!(u16_at(&dl, 0), 0x5613);
}

#[test]
fn the_station_alias_addresses_only_when_enabled() {
    let mut e = addressed();
    e.pdi_write_u16(reg::STATION_ALIAS, 0x0042);
    let (a, _) = fprd(&mut e, reg::STATION_ALIAS, 2);
    assert_eq!(u16_at(&a, 0), 0x0042);
    // The master cannot change the alias.
    fpwr(&mut e, reg::STATION_ALIAS, &[0x99, 0]);
    assert_eq!(e.register_u16(reg::STATION_ALIAS), 0x0042);
    assert_eq!(one(&mut e, Command::Fprd, 0x0042, reg::AL_STATUS, &[0, 0]).1, 0);
    one(&mut e, Command::Bwr, 0, reg::DL_CONTROL_ALIAS, &[1]);
    assert_eq!(one(&mut e, Command::Fprd, 0x0042, reg::AL_STATUS, &[0, 0]).1, 1);
}

#[test]
fn chained_datagrams_are_processed_in_order_with_their_own_wkc() {
    let mut e = esc();
    let f = run(
        &mut e,
        FrameBuilder::new()
            .push(Command::Nop, 0, 0, &[1, 2])
            .push(Command::Apwr, 0, reg::STATION_ADDRESS, &STATION.to_le_bytes())
            .push(Command::Fprd, STATION, reg::STATION_ADDRESS, &[0, 0])
            .push(Command::Fprw, STATION, 0x0F80, &[7, 8])
            .push(Command::Brw, 0, 0x0F80, &[0x10, 0]),
    );
    let frame = Frame::new_checked(&f).unwrap();
    let ds: Vec<_> = frame.datagrams().collect();
    assert_eq!(ds.len(), 5);
    assert_eq!((ds[0].data(), ds[0].wkc()), (&[1u8, 2][..], 0));
    assert_eq!(ds[1].wkc(), 1);
    assert_eq!((u16_at(ds[2].data(), 0), ds[2].wkc()), (STATION, 1));
    assert_eq!((ds[3].data(), ds[3].wkc()), (&[0u8, 0][..], 3), "FPRW returns the old value, +1 read +2 write");
    assert_eq!((ds[4].data(), ds[4].wkc()), (&[0x17u8, 8][..], 3), "BRW ORs the read data");
    assert_eq!(ds.iter().map(|d| d.index()).collect::<Vec<_>>(), vec![0, 1, 2, 3, 4]);
    assert_eq!(e.register(0x0F80), 0x10);
}

#[test]
fn al_control_is_an_event_for_the_pdi_which_decides_the_status() {
    let mut e = addressed();
    assert!(!e.irq());
    assert_eq!(fpwr(&mut e, reg::AL_CONTROL, &[al_state::PREOP as u8, 0]), 1);
    // The ESC does not change state by itself.
    assert_eq!(u16_at(&fprd(&mut e, reg::AL_STATUS, 2).0, 0), al_state::INIT);
    assert_ne!(e.al_event_request() & al_event::AL_CONTROL, 0);
    assert!(e.irq(), "AL control is in the reset AL event mask");

    // No mailbox configured: the stand-in ESM refuses INIT -> PRE-OP with 0x0016.
    let r = esm::respond_minimal(&mut e).expect("event pending");
    assert_eq!(r.control, al_state::PREOP);
    assert_eq!(e.al_event_request() & al_event::AL_CONTROL, 0, "the PDI read of 0x0120 clears the event");
    let (st, _) = fprd(&mut e, reg::AL_STATUS, 6);
    assert_eq!((u16_at(&st, 0), u16_at(&st, 4)), (al_state::INIT | al_state::ERROR, esm::CODE_INVALID_MAILBOX));
    assert!(esm::respond_minimal(&mut e).is_none());

    // Invalid transition INIT -> OP with error acknowledge: 0x0011.
    fpwr(&mut e, reg::AL_CONTROL, &[(al_state::OP | al_state::ERROR) as u8, 0]);
    esm::respond_minimal(&mut e);
    let (st, _) = fprd(&mut e, reg::AL_STATUS, 6);
    assert_eq!((u16_at(&st, 0), u16_at(&st, 4)), (al_state::INIT | al_state::ERROR, esm::CODE_INVALID_TRANSITION));

    // With mailboxes configured and the error acknowledged, PRE-OP is reached.
    configure_mailboxes(&mut e);
    fpwr(&mut e, reg::AL_CONTROL, &[(al_state::PREOP | al_state::ERROR) as u8, 0]);
    esm::respond_minimal(&mut e);
    let (st, _) = fprd(&mut e, reg::AL_STATUS, 6);
    assert_eq!((u16_at(&st, 0), u16_at(&st, 4)), (al_state::PREOP, 0));
    // The PDI's AL status write raised the ECAT event; the master's read of 0x0130 cleared it.
    assert_eq!(e.ecat_event_request() & 0x0008, 0);
}

#[test]
fn sii_reads_vendor_and_product_from_the_od_gen_image() {
    let mut e = addressed();
    let info = od_gen::sii::decode(&e.sii().image).unwrap();
    // SOEM/ethercrab: one FPWR of control + address, then FPRD of the status and the data.
    let mut cmd = vec![0x00, 0x01];
    cmd.extend_from_slice(&0x0008u32.to_le_bytes());
    assert_eq!(fpwr(&mut e, reg::SII_CONTROL, &cmd), 1);
    let (st, _) = fprd(&mut e, reg::SII_CONTROL, 2);
    let st = u16_at(&st, 0);
    assert_eq!(st & 0x8000, 0, "never busy");
    assert_ne!(st & 0x0040, 0, "8-byte reads");
    assert_eq!(st & 0x0700, 0, "command done");
    assert_eq!(st & 0x6800, 0, "no error");
    let (d, wkc) = fprd(&mut e, reg::SII_DATA, 8);
    assert_eq!(wkc, 1);
    assert_eq!(u32_at(&d, 0), info.vendor_id);
    assert_eq!(u32_at(&d, 4), info.product_code);
    assert_eq!(info.vendor_id, 0x0000_0ACE);

    // KickCAT-style: BWR of the command word, then a 4-byte read (word 0x1C: mailbox protocols).
    one(&mut e, Command::Bwr, 0, reg::SII_ADDRESS, &0x001Cu32.to_le_bytes());
    one(&mut e, Command::Bwr, 0, reg::SII_CONTROL, &[0x00, 0x01]);
    let (d, _) = fprd(&mut e, reg::SII_DATA, 4);
    assert_eq!(u16_at(&d, 0), info.mailbox_protocols);

    // Write without write enable is refused (status bit 14); with it, it lands and reads back.
    let mut w = vec![0x00, 0x02];
    w.extend_from_slice(&0x0030u32.to_le_bytes());
    w.extend_from_slice(&[0x34, 0x12]);
    fpwr(&mut e, reg::SII_CONTROL, &w);
    assert_ne!(e.register_u16(reg::SII_CONTROL) & 0x4000, 0);
    w[0] = 0x01;
    fpwr(&mut e, reg::SII_CONTROL, &w);
    assert_eq!(e.register_u16(reg::SII_CONTROL) & 0x4000, 0);
    assert_eq!(e.sii().word(0x30), 0x1234);
    // Reload (SOEM's 0x0300) keeps the alias from word 4.
    fpwr(&mut e, reg::SII_CONTROL, &[0x00, 0x03]);
    assert_eq!(e.register_u16(reg::STATION_ALIAS), e.sii().word(4));
}

#[test]
fn mailbox_exchange_through_sm0_and_sm1() {
    let mut e = addressed();
    let (out_start, out_len, in_start, in_len) = configure_mailboxes(&mut e);
    assert_eq!((out_start, out_len, in_start, in_len), (0x1000, 128, 0x1080, 128));
    e.pdi_read_u16(0x0806); // consume the SM-activation event
    let mut request = vec![0u8; usize::from(out_len)];
    request[..6].copy_from_slice(&[10, 0, 0, 0, 0, 0x33]);

    // A write that does not reach the last byte does not complete the mailbox.
    assert_eq!(fpwr(&mut e, out_start, &request[..64]), 1);
    assert_eq!(fprd(&mut e, 0x0805, 1).0[0] & 0x08, 0);
    // The full write: SM0 full (status bit 3) and the SM0 event for the PDI.
    assert_eq!(fpwr(&mut e, out_start, &request), 1);
    assert_ne!(fprd(&mut e, 0x0805, 1).0[0] & 0x08, 0);
    assert_ne!(e.al_event_request() & al_event::sm(0), 0);
    assert!(e.irq());
    // While full, further writes are refused (WKC 0): SOEM retries on that.
    assert_eq!(fpwr(&mut e, out_start, &request), 0);

    // The PDI reads the request; reading the last byte empties the mailbox.
    let mut got = vec![0u8; usize::from(out_len)];
    e.pdi_read(out_start, &mut got);
    assert_eq!(got, request);
    assert_eq!(e.sm_status(0) & 0x08, 0);
    assert_eq!(e.al_event_request() & al_event::sm(0), 0);

    // The master's read of the empty SM1 gets WKC 0 and its data back unchanged.
    assert_eq!(fprd(&mut e, in_start, usize::from(in_len)).1, 0);
    // The PDI writes the reply: SM1 status bit 3 (0x080D) for the master.
    let reply: Vec<u8> = (0..in_len).map(|i| i as u8).collect();
    e.pdi_write(in_start, &reply);
    assert_ne!(fprd(&mut e, 0x080D, 1).0[0] & 0x08, 0);
    // The PDI cannot write again while the master has not read it.
    e.pdi_write(in_start, &[0xEE; 4]);
    let (d, wkc) = fprd(&mut e, in_start, usize::from(in_len));
    assert_eq!((d, wkc), (reply.clone(), 1));
    assert_eq!(fprd(&mut e, 0x080D, 1).0[0] & 0x08, 0, "the read of the last byte clears it");
    assert_ne!(e.al_event_request() & al_event::sm(1), 0, "SM1 read event for the PDI");
    assert_eq!(fprd(&mut e, in_start, usize::from(in_len)).1, 0);
    assert_eq!(e.sm_runtime(1).unwrap().reads, 1);
}

#[test]
fn mailbox_repeat_request_is_an_event_for_the_pdi() {
    let mut e = addressed();
    configure_mailboxes(&mut e);
    e.pdi_read_u16(0x0806);
    assert_eq!(e.al_event_request() & al_event::SM_ACTIVATION, 0);
    fpwr(&mut e, 0x080E, &[0x03]); // SM1 activate: enable + toggle repeat request
    assert_ne!(e.al_event_request() & al_event::SM_ACTIVATION, 0);
    assert_eq!(e.pdi_read_u16(0x080E) & 0x02, 0x02);
    assert_eq!(e.al_event_request() & al_event::SM_ACTIVATION, 0);
    // The PDI acknowledges by toggling PDI control bit 1; the master sees it in 0x080F.
    e.pdi_write(0x080F, &[0x02]);
    assert_eq!(fprd(&mut e, 0x080F, 1).0[0], 0x02);
    // The master cannot write the PDI control byte.
    fpwr(&mut e, 0x080F, &[0x01]);
    assert_eq!(e.register(0x080F), 0x02);
    // PDI deactivation disables the SM and locks its window towards the master (0x0807 bit 0).
    e.pdi_write(0x0807, &[0x01]);
    assert!(!e.sm_config(0).unwrap().is_active());
}

#[test]
fn a_sync_manager_the_pdi_deactivated_locks_its_window_so_the_masters_outputs_count_no_working_counter() {
    // ESC datasheet section II, 0x0807 bit 0: "SyncManager deactivated and reset, SyncManager locks access to
    // memory area"; ETG.1000.4 §5.4: a slave increments the working counter only for memory it accessed. So an
    // LRW to a slave whose SM2 the firmware deactivated (SAFE-OP after a local error) counts 1 (inputs), not 3.
    let mut e = process_data_esc();
    let mut fm = Vec::new();
    fm.extend_from_slice(&fmmu_bytes(0x0001_0000, 6, 0, 7, 0x1100, 0, 2));
    fm.extend_from_slice(&fmmu_bytes(0x0001_0006, 6, 0, 7, 0x1180, 0, 1));
    assert_eq!(fpwr(&mut e, reg::FMMU0, &fm), 1);
    let lrw = |e: &mut Esc, fill: u8| {
        let f = run(e, FrameBuilder::new().push_logical(Command::Lrw, 0x0001_0000, &[fill; 12]));
        dg(&f, 0).1
    };
    assert_eq!(lrw(&mut e, 1), 3, "SM2 active: outputs written (+2), inputs read (+1)");
    e.pdi_write(0x0817, &[0x01]);
    assert_eq!(lrw(&mut e, 2), 1, "SM2 deactivated by the PDI: only the inputs count");
    assert_eq!(fpwr(&mut e, 0x1100, &[3; 6]), 0, "a physical write into the locked window: refused, WKC 0");
    assert_eq!(fprd(&mut e, 0x1100, 6).1, 0, "a physical read of it: refused, WKC 0");
    assert_eq!(e.sm_runtime(2).unwrap().writes, 0, "the deactivated SM took no write");
    // The PDI activates it again (the master acknowledged the error): outputs count again.
    e.pdi_write(0x0817, &[0x00]);
    assert_eq!(lrw(&mut e, 4), 3);
    let mut out = [0u8; 6];
    e.pdi_read(0x1100, &mut out);
    assert_eq!(out, [4; 6], "the write after re-activation, not the refused ones");
    // A sync manager the master disabled (0x0806 bit 0 = 0) leaves plain memory: "access to memory without
    // SyncManager control" (0x0806 bit 0).
    assert_eq!(fpwr(&mut e, 0x0816, &[0x00]), 1);
    assert_eq!(fpwr(&mut e, 0x1100, &[5; 6]), 1);
}

/// SM2 outputs (0x1100, 6 bytes, 0x64) and SM3 inputs (0x1180, 6 bytes, 0x20) as a master configures them.
fn process_data_esc() -> Esc {
    let mut e = addressed();
    configure_mailboxes(&mut e);
    let mut cfg = Vec::new();
    cfg.extend_from_slice(&sm_bytes(0x1100, 6, 0x64, 1));
    cfg.extend_from_slice(&sm_bytes(0x1180, 6, 0x20, 1));
    assert_eq!(fpwr(&mut e, 0x0810, &cfg), 1);
    e
}

#[test]
fn lrw_through_fmmus_exchanges_buffered_process_data_with_wkc_3() {
    let mut e = process_data_esc();
    let mut fm = Vec::new();
    fm.extend_from_slice(&fmmu_bytes(0x0001_0000, 6, 0, 7, 0x1100, 0, 2));
    fm.extend_from_slice(&fmmu_bytes(0x0001_0006, 6, 0, 7, 0x1180, 0, 1));
    assert_eq!(fpwr(&mut e, reg::FMMU0, &fm), 1);

    let inputs = [0x11, 0x22, 0x33, 0x44, 0x55, 0x66];
    e.pdi_write(0x1180, &inputs);
    let mut data = vec![1, 2, 3, 4, 5, 6, 0, 0, 0, 0, 0, 0];
    let f = run(&mut e, FrameBuilder::new().push_logical(Command::Lrw, 0x0001_0000, &data));
    let (d, wkc) = dg(&f, 0);
    assert_eq!(wkc, 3);
    assert_eq!(&d[..6], &[1, 2, 3, 4, 5, 6], "bytes without a read FMMU come back as sent");
    assert_eq!(&d[6..], &inputs);
    assert_ne!(e.al_event_request() & al_event::sm(2), 0);
    let mut out = [0u8; 6];
    e.pdi_read(0x1100, &mut out);
    assert_eq!(out, [1, 2, 3, 4, 5, 6]);

    // Three buffers: the PDI keeps the buffer it opened while the master writes newer ones.
    let mut first = [0u8; 1];
    e.pdi_read(0x1100, &mut first); // opens the newest buffer (1..6)
    data[..6].copy_from_slice(&[9; 6]);
    run(&mut e, FrameBuilder::new().push_logical(Command::Lrw, 0x0001_0000, &data));
    data[..6].copy_from_slice(&[8; 6]);
    run(&mut e, FrameBuilder::new().push_logical(Command::Lrw, 0x0001_0000, &data));
    let mut rest = [0u8; 5];
    e.pdi_read(0x1101, &mut rest);
    assert_eq!(rest, [2, 3, 4, 5, 6], "the open buffer is consistent");
    e.pdi_read(0x1100, &mut out);
    assert_eq!(out, [8; 6], "the next read gets the newest");
    // Status bits 5..4 name the last written buffer (not 0b11 = none).
    assert_ne!(e.sm_status(2) & 0x30, 0x30);

    // LRD and LWR count 1 each; a logical range nobody maps counts 0.
    let f = run(&mut e, FrameBuilder::new().push_logical(Command::Lrd, 0x0001_0006, &[0; 6]));
    assert_eq!(dg(&f, 0), (inputs.to_vec(), 1));
    let f = run(&mut e, FrameBuilder::new().push_logical(Command::Lwr, 0x0001_0000, &[7; 6]));
    assert_eq!(dg(&f, 0).1, 1);
    let f = run(&mut e, FrameBuilder::new().push_logical(Command::Lrw, 0x0002_0000, &[0; 12]));
    assert_eq!(dg(&f, 0).1, 0);
}

#[test]
fn overlapping_read_and_write_fmmus_at_the_same_logical_address() {
    let mut e = process_data_esc();
    let mut fm = Vec::new();
    fm.extend_from_slice(&fmmu_bytes(0x100, 6, 0, 7, 0x1100, 0, 2));
    fm.extend_from_slice(&fmmu_bytes(0x100, 6, 0, 7, 0x1180, 0, 1));
    fpwr(&mut e, reg::FMMU0, &fm);
    e.pdi_write(0x1180, &[0xA0, 0xA1, 0xA2, 0xA3, 0xA4, 0xA5]);
    let f = run(&mut e, FrameBuilder::new().push_logical(Command::Lrw, 0x100, &[1, 2, 3, 4, 5, 6]));
    assert_eq!(dg(&f, 0), (vec![0xA0, 0xA1, 0xA2, 0xA3, 0xA4, 0xA5], 3));
    let mut out = [0u8; 6];
    e.pdi_read(0x1100, &mut out);
    assert_eq!(out, [1, 2, 3, 4, 5, 6]);
}

#[test]
fn bit_oriented_fmmu_maps_single_bits() {
    let mut e = addressed();
    // Logical 0x20 bits 4..=7 + 0x21 bits 0..=1 (len 2) -> physical 0x1200 bits 2..=7.
    fpwr(&mut e, reg::FMMU0, &fmmu_bytes(0x20, 2, 4, 1, 0x1200, 2, 3));
    fpwr(&mut e, 0x1200, &[0b0000_0011]);
    let f = run(&mut e, FrameBuilder::new().push_logical(Command::Lwr, 0x20, &[0b1011_0000, 0b0000_0010]));
    assert_eq!(dg(&f, 0).1, 1);
    // Logical bits 4..7 = 1,1,0,1 -> physical bits 2..5; logical 0x21 bits 0..1 = 0,1 -> physical bits 6..7.
    assert_eq!(fprd(&mut e, 0x1200, 1).0[0], 0b1010_1111);
    let f = run(&mut e, FrameBuilder::new().push_logical(Command::Lrd, 0x20, &[0x0F, 0xFC]));
    assert_eq!(dg(&f, 0), (vec![0b1011_1111, 0b1111_1110], 1));
}

#[test]
fn dc_receive_times_system_time_and_frmw() {
    let mut e = addressed();
    e.advance(1_234_567);
    let local = e.local_time();
    assert_eq!(local, 1_234_567);
    // A write to 0x0900 latches the receive times (spec file item 8).
    one(&mut e, Command::Bwr, 0, reg::DC_RECEIVE_TIME_PORT0, &[0; 4]);
    let (t, _) = fprd(&mut e, reg::DC_RECEIVE_TIME_PORT0, 16);
    assert_eq!(u32_at(&t, 0), local as u32);
    let (pu, _) = fprd(&mut e, reg::DC_RECEIVE_TIME_PU, 8);
    assert_eq!(u64_at(&pu, 0), local);
    e.advance(1000);
    assert_eq!(u32_at(&fprd(&mut e, reg::DC_RECEIVE_TIME_PORT0, 4).0, 0), local as u32, "latched, not live");

    // 0x0910 = local + offset 0x0920.
    fpwr(&mut e, reg::DC_SYSTEM_TIME_OFFSET, &5_000_000u64.to_le_bytes());
    let (st, _) = fprd(&mut e, reg::DC_SYSTEM_TIME, 8);
    assert_eq!(u64_at(&st, 0), e.local_time() + 5_000_000);

    // FRMW addressed to us (the reference clock): a read, WKC 1.
    let (d, wkc) = one(&mut e, Command::Frmw, STATION, reg::DC_SYSTEM_TIME, &[0; 8]);
    assert_eq!((u64_at(&d, 0), wkc), (e.system_time(), 1));
    // ARMW at position 0 reads too and increments ADP.
    let f = run(&mut e, FrameBuilder::new().push(Command::Armw, 0, reg::DC_SYSTEM_TIME, &[0; 8]));
    assert_eq!(dg(&f, 0).1, 1);
    assert_eq!(Frame::new_checked(&f).unwrap().datagram(0).unwrap().adp(), 1);

    // FRMW addressed to another slave (the reference upstream): we write, and the time control loop pulls the
    // local clock towards the reference even with a 50 ppm oscillator error.
    e.set_clock_error_ppb(50_000);
    let mut reference = e.system_time();
    for _ in 0..200 {
        e.advance(1_000_000);
        reference += 1_000_000;
        let (_, wkc) = one(&mut e, Command::Frmw, 0x7777, reg::DC_SYSTEM_TIME, &reference.to_le_bytes());
        assert_eq!(wkc, 1);
    }
    assert!(e.last_time_difference().abs() <= 60, "difference {} ns", e.last_time_difference());
    let diff = u32::from_le_bytes(fprd(&mut e, reg::DC_SYSTEM_TIME_DIFF, 4).0.try_into().unwrap());
    assert_eq!(diff & 0x7FFF_FFFF, e.last_time_difference().unsigned_abs() as u32);
}

#[test]
fn sync0_pulses_follow_start_time_and_cycle() {
    let mut e = addressed();
    e.advance(10_000_000);
    let start = e.system_time() + 500_000;
    one(&mut e, Command::Bwr, 0, reg::DC_SYNC0_CYCLE, &1_000_000u32.to_le_bytes());
    fpwr(&mut e, reg::DC_START_TIME, &start.to_le_bytes());
    one(&mut e, Command::Bwr, 0, reg::DC_ACTIVATION, &[0x03]);
    assert_eq!(e.next_sync0_in(), Some(500_000));
    e.advance(400_000);
    assert!(e.take_sync0().is_none());
    e.advance(100_000);
    let p = e.take_sync0().expect("pulse at the start time");
    assert_eq!((p.system_time, p.count), (start, 1));
    assert_eq!(e.register(reg::DC_SYNC0_STATUS) & 1, 1);
    assert_ne!(e.al_event_request() & al_event::SYNC0, 0, "SII word 1 maps SYNC0 to the AL event register");
    assert!(e.irq());
    assert_eq!(e.pdi_read_u16(reg::DC_SYNC0_STATUS) & 1, 1);
    assert_eq!(e.al_event_request() & al_event::SYNC0, 0, "the PDI read acknowledges it");
    // 0x0990 reads the next pulse.
    assert_eq!(u64_at(&fprd(&mut e, reg::DC_START_TIME, 8).0, 0), start + 1_000_000);
    assert_eq!(e.next_sync0_in(), Some(1_000_000));
    // A simulation that sleeps through three cycles learns it missed pulses.
    e.advance(3_000_000);
    assert_eq!(e.take_sync0().map(|p| (p.system_time, p.count)), Some((start + 3_000_000, 3)));
    // Deactivation stops the pulses.
    one(&mut e, Command::Bwr, 0, reg::DC_ACTIVATION, &[0]);
    e.advance(5_000_000);
    assert!(e.take_sync0().is_none());
    assert_eq!(e.next_sync0_in(), None);
}

#[test]
fn process_data_watchdog_expires_when_sm2_is_not_written() {
    let mut e = process_data_esc();
    fpwr(&mut e, reg::FMMU0, &fmmu_bytes(0, 6, 0, 7, 0x1100, 0, 2));
    // 100 us ticks (reset divider) x 10 = 1 ms.
    one(&mut e, Command::Bwr, 0, reg::WATCHDOG_TIME_PD, &10u16.to_le_bytes());
    assert_eq!(u16_at(&fprd(&mut e, reg::WATCHDOG_STATUS_PD, 2).0, 0) & 1, 0, "not triggered yet");
    for _ in 0..20 {
        run(&mut e, FrameBuilder::new().push_logical(Command::Lwr, 0, &[1; 6]));
        e.advance(500_000);
        assert_eq!(u16_at(&fprd(&mut e, reg::WATCHDOG_STATUS_PD, 2).0, 0) & 1, 1);
    }
    assert_eq!(e.pd_watchdog().expirations, 0);
    e.advance(600_000);
    assert_eq!(u16_at(&fprd(&mut e, reg::WATCHDOG_STATUS_PD, 2).0, 0) & 1, 0, "expired");
    assert_eq!(fprd(&mut e, reg::WATCHDOG_COUNTER_PD, 1).0[0], 1);
    assert_ne!(e.al_event_request() & al_event::WATCHDOG_PD, 0);
    assert_eq!(e.pd_watchdog().expirations, 1);
    e.pdi_read_u16(reg::WATCHDOG_STATUS_PD);
    assert_eq!(e.al_event_request() & al_event::WATCHDOG_PD, 0);
    // A master write clears the counter; the next SM2 write restarts the watchdog.
    one(&mut e, Command::Bwr, 0, reg::WATCHDOG_COUNTER_PD, &[0]);
    assert_eq!(e.register(reg::WATCHDOG_COUNTER_PD), 0);
    run(&mut e, FrameBuilder::new().push_logical(Command::Lwr, 0, &[1; 6]));
    assert_eq!(e.register(reg::WATCHDOG_STATUS_PD) & 1, 1);
}

#[test]
fn pdi_watchdog_clears_dl_status_bit_1() {
    let mut e = addressed();
    e.pdi_read_u16(reg::AL_CONTROL);
    e.advance(99_000_000);
    assert_eq!(e.register_u16(reg::DL_STATUS), 0x5613);
    e.advance(2_000_000);
    assert_eq!(e.register_u16(reg::DL_STATUS), 0x5611);
    assert_eq!(e.register(reg::WATCHDOG_COUNTER_PDI), 1);
    e.pdi_read_u16(reg::AL_CONTROL);
    assert_eq!(e.register_u16(reg::DL_STATUS), 0x5613);
}

#[test]
fn malformed_frames_are_dropped_and_counted() {
    let mut e = addressed();
    let good = FrameBuilder::new().push(Command::Fpwr, STATION, 0x0F80, &[0x5A; 4]).build();
    // Cut inside the datagram, and an EtherCAT length that claims more than the frame holds.
    let mut cut = good[..20].to_vec();
    assert_eq!(e.process_frame(&mut cut), Err(FrameError::BadLength));
    let mut lying = good.clone();
    lying[14] = 0xFF;
    lying[15] = 0x17;
    assert!(e.process_frame(&mut lying).unwrap_err().is_malformed());
    // A "more" bit with nothing after it.
    let mut more = FrameBuilder::new().push(Command::Fpwr, STATION, 0x0F80, &[0x5A; 4]).build();
    more[16 + 7] |= 0x80;
    assert_eq!(e.process_frame(&mut more), Err(FrameError::Truncated(1)));
    assert_eq!(e.stats().malformed, 3);
    assert_eq!(e.register(reg::RX_ERROR_COUNTER), 3);
    assert_eq!(e.register(0x0F80), 0, "nothing of a malformed frame is applied");
    // Not EtherCAT: ignored, not counted.
    let mut ip = good.clone();
    ip[12] = 0x08;
    ip[13] = 0x00;
    assert_eq!(e.process_frame(&mut ip), Err(FrameError::NotEtherCat(0x0800)));
    assert_eq!(e.stats().malformed, 3);
    // Any write clears the counters.
    one(&mut e, Command::Bwr, 0, reg::RX_ERROR_COUNTER, &[0; 8]);
    assert_eq!(e.register(reg::RX_ERROR_COUNTER), 0);
    // An 802.1Q-tagged frame is processed.
    let mut tagged = good[..12].to_vec();
    tagged.extend_from_slice(&[0x81, 0x00, 0x00, 0x01]);
    tagged.extend_from_slice(&good[12..]);
    assert!(e.process_frame(&mut tagged).is_ok());
    assert_eq!(e.register(0x0F80), 0x5A);
}

fn any_command() -> impl Strategy<Value = Command> {
    (0u8..=16).prop_map(Command::from_code)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    /// Random bytes after an EtherCAT Ethernet header never panic; every frame is either processed or, if
    /// malformed, counted once.
    #[test]
    fn random_frames_never_panic(body in proptest::collection::vec(any::<u8>(), 0..200)) {
        let mut e = addressed();
        let mut f = vec![0xFF; 6];
        f.extend_from_slice(&[1; 6]);
        f.extend_from_slice(&[0x88, 0xA4]);
        f.extend_from_slice(&body);
        let before = e.stats();
        let r = e.process_frame(&mut f);
        let after = e.stats();
        match r {
            Ok(_) => prop_assert_eq!(after.processed, before.processed + 1),
            Err(err) if err.is_malformed() => prop_assert_eq!(after.malformed, before.malformed + 1),
            Err(_) => prop_assert_eq!(after.ignored, before.ignored + 1),
        }
    }

    /// Random well-formed datagram chains (any command, address and data) are processed without panicking,
    /// and the returned frame still parses with the same shape.
    #[test]
    fn random_datagrams_never_panic(
        dgs in proptest::collection::vec(
            (any_command(), any::<u16>(), any::<u16>(), proptest::collection::vec(any::<u8>(), 0..64)),
            1..6,
        ),
        fmmu in proptest::collection::vec(any::<u8>(), 32),
        sms in proptest::collection::vec(any::<u8>(), 32),
    ) {
        let mut e = process_data_esc();
        fpwr(&mut e, reg::FMMU0, &fmmu);
        fpwr(&mut e, 0x0820, &sms);
        let mut b = FrameBuilder::new();
        for (cmd, adp, ado, data) in &dgs {
            b = b.push(*cmd, *adp, *ado, data);
        }
        let mut f = b.build();
        let report = e.process_frame(&mut f).expect("well-formed");
        prop_assert_eq!(report.datagrams.len(), dgs.len());
        let frame = Frame::new_checked(&f).expect("still parses");
        prop_assert_eq!(frame.datagrams().count(), dgs.len());
        e.advance(1_000_000);
        let mut buf = [0u8; 64];
        e.pdi_read(0x1000, &mut buf);
        e.pdi_write(0x1080, &buf);
    }
}

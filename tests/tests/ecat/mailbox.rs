//! The firmware's mailbox, CoE and FoE (`firmware::ecat::{mailbox, coe, foe}`; ETG.1000.6 §5.2, §5.6, ETG.1000.5
//! FoE) on the emulated ESC with an in-process master: SDO transfers of real objects, the SDO information service,
//! emergencies, the mailbox counter and repeat rules, mailbox error replies, and FoE in and outside BOOT.

use drive_tests::ecat_master::{Bench, COE, FOE};
use firmware::ecat::mailbox::{EmergencyRefused, MailboxLayout};
use firmware::od::access::Table;
use firmware::od::generated;

/// The mailbox error code of a type-0 answer, or a panic.
fn mailbox_error(answer: Option<(firmware::ecat::mailbox::Header, Vec<u8>)>) -> u16 {
    let (h, d) = answer.expect("an answer");
    assert_eq!((h.kind, h.length), (0, 4), "a mailbox error reply, got {h:?} {d:02X?}");
    assert_eq!(u16::from_le_bytes([d[0], d[1]]), 0x0001, "service: mailbox error");
    u16::from_le_bytes([d[2], d[3]])
}

fn preop() -> Bench {
    let mut b = Bench::new();
    b.to_preop();
    b
}

// ---------------------------------------------------------------------------------------------------------
// SDO
// ---------------------------------------------------------------------------------------------------------

#[test]
fn expedited_upload_of_the_identity_object_matches_the_sii_facts() {
    let mut b = preop();
    let u32_of = |v: Vec<u8>| u32::from_le_bytes(v.try_into().expect("4 bytes"));
    assert_eq!(b.sdo_upload(0x1018, 0).map(|(v, _)| v), Ok(vec![4]));
    assert_eq!(b.sdo_upload(0x1018, 1).map(|(v, _)| u32_of(v)), Ok(generated::VENDOR_ID));
    assert_eq!(b.sdo_upload(0x1018, 2).map(|(v, _)| u32_of(v)), Ok(generated::PRODUCT_CODE));
    assert_eq!(b.sdo_upload(0x1018, 3).map(|(v, _)| u32_of(v)), Ok(generated::REVISION));
}

#[test]
fn expedited_download_and_upload_of_modes_of_operation() {
    let mut b = preop();
    assert_eq!(b.sdo_download(0x6060, 0, &[8]), Ok(0));
    assert_eq!(b.sdo_upload(0x6060, 0), Ok((vec![8], 0)));
    assert_eq!(b.sdo_download(0x6060, 0, &[9]), Ok(0));
    assert_eq!(b.sdo_upload(0x6060, 0), Ok((vec![9], 0)));
}

#[test]
fn a_23_byte_string_comes_in_one_normal_upload() {
    let mut b = preop();
    let (value, segments) = b.sdo_upload(0x1009, 0).expect("hardware version");
    assert_eq!(value, generated::HARDWARE_VERSION.as_bytes());
    assert_eq!(value.len(), 23);
    assert_eq!(segments, 0, "fits the 128-byte mailbox");
}

#[test]
fn a_small_mailbox_uploads_the_string_in_segments() {
    let layout = MailboxLayout { out_start: 0x1000, out_size: 32, in_start: 0x1080, in_size: 32 };
    let mut b = Bench::with_layout(layout);
    b.to_preop();
    let (value, segments) = b.sdo_upload(0x1009, 0).expect("hardware version");
    assert_eq!(value, generated::HARDWARE_VERSION.as_bytes());
    assert!(segments >= 1, "the 16 bytes of the first answer do not hold 23");
}

#[test]
fn program_data_is_downloaded_normally_and_in_segments() {
    let mut b = preop();
    let small: Vec<u8> = (0..100u8).collect();
    assert_eq!(b.sdo_download(0x1F50, 1, &small), Ok(0), "100 bytes fit the initiate request");
    assert_eq!(b.app.program, small);
    assert!(b.app.complete);
    let big: Vec<u8> = (0..300u32).map(|i| (i * 7) as u8).collect();
    let segments = b.sdo_download(0x1F50, 1, &big).expect("segmented download");
    assert!(segments >= 2, "300 bytes need segments, took {segments}");
    assert_eq!(b.app.program, big);
    assert!(b.app.complete);
}

#[test]
fn sdo_errors_are_answered_with_abort_codes() {
    let mut b = preop();
    assert_eq!(b.sdo_upload(0x2FFF, 0), Err(0x0602_0000), "missing object");
    assert_eq!(b.sdo_upload(0x1018, 9), Err(0x0609_0011), "missing sub-index");
    assert_eq!(b.sdo_download(0x6060, 0, &[1, 2]), Err(0x0607_0012), "too long for INTEGER8");
    assert_eq!(b.sdo_download(0x1018, 1, &[1, 2, 3, 4]), Err(0x0601_0002), "read-only");
    // Nothing changed and the server still answers.
    assert_eq!(b.sdo_upload(0x1018, 1).map(|(v, _)| v), Ok(generated::VENDOR_ID.to_le_bytes().to_vec()));
}

// ---------------------------------------------------------------------------------------------------------
// SDO information
// ---------------------------------------------------------------------------------------------------------

/// Sends an SDO information request and collects the fragments of the answer: (opcode, payload, fragments).
fn sdo_info(b: &mut Bench, request: &[u8]) -> (u8, Vec<u8>, usize) {
    let mut data = vec![0x00, 0x80];
    data.extend_from_slice(request);
    let (h, mut answer) = b.exchange(COE, &data);
    let mut payload = Vec::new();
    let mut fragments = 0;
    loop {
        assert_eq!(h.kind, COE);
        assert_eq!(answer[1] >> 4, 8, "SDO information service");
        let opcode = answer[2] & 0x7F;
        let incomplete = answer[2] & 0x80 != 0;
        let left = u16::from_le_bytes([answer[4], answer[5]]);
        payload.extend_from_slice(&answer[6..]);
        fragments += 1;
        if !incomplete {
            assert_eq!(left, 0, "the last fragment has none left");
            return (opcode, payload, fragments);
        }
        b.poll();
        answer = b.receive().expect("the next fragment").1;
        let next_left = u16::from_le_bytes([answer[4], answer[5]]);
        assert_eq!(next_left + 1, left, "fragments left counts down");
    }
}

#[test]
fn the_od_list_of_all_objects_comes_in_fragments_and_names_every_object() {
    let mut b = preop();
    let (opcode, payload, fragments) = sdo_info(&mut b, &[0x01, 0x00, 0x00, 0x00, 0x01, 0x00]);
    assert_eq!(opcode, 0x02);
    assert_eq!(u16::from_le_bytes([payload[0], payload[1]]), 1, "list type echoed");
    let indices: Vec<u16> = payload[2..].chunks(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect();
    let expected: Vec<u16> = Table::GENERATED.objects().iter().map(|o| o.index).collect();
    assert_eq!(indices, expected);
    assert!(fragments >= 3, "{} objects do not fit one mailbox, took {fragments}", expected.len());
}

#[test]
fn the_od_list_lengths_count_the_lists() {
    let mut b = preop();
    let (opcode, payload, fragments) = sdo_info(&mut b, &[0x01, 0x00, 0x00, 0x00, 0x00, 0x00]);
    assert_eq!((opcode, fragments), (0x02, 1));
    let counts: Vec<u16> = payload[2..].chunks(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect();
    assert_eq!(counts.len(), 5);
    assert_eq!(usize::from(counts[0]), Table::GENERATED.objects().len());
    assert!(counts[1] > 0 && counts[2] > 0, "RxPDO and TxPDO mappable objects exist: {counts:?}");
    // List 2 (RxPDO mappable) has exactly as many indices as list 0 announced.
    let (_, rx, _) = sdo_info(&mut b, &[0x01, 0x00, 0x00, 0x00, 0x02, 0x00]);
    assert_eq!((rx.len() - 2) / 2, usize::from(counts[1]));
    assert!(rx[2..].chunks(2).any(|c| u16::from_le_bytes([c[0], c[1]]) == 0x6060));
}

#[test]
fn object_and_entry_descriptions_come_from_the_dictionary() {
    let mut b = preop();
    let (opcode, od, _) = sdo_info(&mut b, &[0x03, 0x00, 0x00, 0x00, 0x18, 0x10]);
    assert_eq!(opcode, 0x04);
    let object = Table::GENERATED.object(0x1018).expect("0x1018");
    assert_eq!(u16::from_le_bytes([od[0], od[1]]), 0x1018);
    assert_eq!((od[4], od[5]), (object.max_sub, 0x09), "max sub-index, RECORD");
    assert_eq!(&od[6..], object.name.as_str().as_bytes());

    let (opcode, ed, _) = sdo_info(&mut b, &[0x05, 0x00, 0x00, 0x00, 0x60, 0x60, 0x00, 0x00]);
    assert_eq!(opcode, 0x06);
    assert_eq!((u16::from_le_bytes([ed[0], ed[1]]), ed[2]), (0x6060, 0));
    assert_eq!(u16::from_le_bytes([ed[4], ed[5]]), 0x0002, "INTEGER8");
    assert_eq!(u16::from_le_bytes([ed[6], ed[7]]), 8, "bit length");
    let access = u16::from_le_bytes([ed[8], ed[9]]);
    assert_eq!(access & 0x07, 0x07, "readable in PRE-OP, SAFE-OP, OP");
    assert_ne!(access & 0x08, 0, "writable in PRE-OP");
    assert_ne!(access & 0x40, 0, "RxPDO mappable");
    let entry = Table::GENERATED.find(0x6060, 0).expect("0x6060");
    assert_eq!(&ed[10..], entry.name.as_str().as_bytes());
}

#[test]
fn sdo_information_errors_carry_abort_codes() {
    let mut b = preop();
    let code = |p: &[u8]| u32::from_le_bytes([p[0], p[1], p[2], p[3]]);
    let (opcode, p, _) = sdo_info(&mut b, &[0x03, 0x00, 0x00, 0x00, 0xFF, 0x2F]);
    assert_eq!((opcode, code(&p)), (0x07, 0x0602_0000), "object description of a missing object");
    let (opcode, p, _) = sdo_info(&mut b, &[0x05, 0x00, 0x00, 0x00, 0x18, 0x10, 0x09, 0x00]);
    assert_eq!((opcode, code(&p)), (0x07, 0x0609_0011), "entry description of a missing sub-index");
    let (opcode, p, _) = sdo_info(&mut b, &[0x01, 0x00, 0x00, 0x00, 0x09, 0x00]);
    assert_eq!((opcode, code(&p)), (0x07, 0x0601_0000), "unknown list type");
    let (opcode, p, _) = sdo_info(&mut b, &[0x09, 0x00, 0x00, 0x00]);
    assert_eq!((opcode, code(&p)), (0x07, 0x0504_0001), "unknown opcode");
}

// ---------------------------------------------------------------------------------------------------------
// Emergencies
// ---------------------------------------------------------------------------------------------------------

#[test]
fn an_emergency_goes_out_as_coe_service_1() {
    let mut b = Bench::new();
    let emcy = [0x10, 0x82, 0x11, 1, 2, 3, 4, 5];
    assert_eq!(b.mailbox.send_emergency(&emcy), Err(EmergencyRefused::NotRunning), "no mailbox in INIT");
    b.to_preop();
    assert_eq!(b.mailbox.send_emergency(&emcy), Ok(()));
    b.poll();
    let (h, d) = b.receive().expect("the emergency");
    assert_eq!((h.kind, h.length), (COE, 10));
    assert_eq!(d[1] >> 4, 1, "CoE service emergency");
    assert_eq!(&d[2..], &emcy);
}

// ---------------------------------------------------------------------------------------------------------
// Mailbox rules
// ---------------------------------------------------------------------------------------------------------

#[test]
fn wrong_headers_get_the_mailbox_error_codes() {
    let mut b = preop();
    // Length larger than SM0 holds (128 - 6 = 122): invalid size.
    let header = [123u8, 0, 0, 0, 0, 0x13];
    assert_eq!(b.send_raw(&header), 1);
    b.poll();
    assert_eq!(mailbox_error(b.receive()), 0x08, "length past the mailbox");
    // Channel 1: invalid channel.
    let mut m = vec![10u8, 0, 0, 0, 0x01, 0x23];
    m.extend_from_slice(&[0x00, 0x20, 0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]);
    b.send_raw(&m);
    b.poll();
    assert_eq!(mailbox_error(b.receive()), 0x03, "channel 1");
    // Types the drive does not serve: error (0), EoE (2), SoE (5), VoE (15).
    for kind in [0u8, 2, 5, 15] {
        b.send(kind, &[0; 10]);
        b.poll();
        assert_eq!(mailbox_error(b.receive()), 0x02, "type {kind}");
    }
}

#[test]
fn wrong_coe_contents_get_the_mailbox_error_codes() {
    let mut b = preop();
    let cases: [(&str, Vec<u8>, u16); 6] = [
        ("no CoE header", vec![0x00], 0x06),
        ("SDO shorter than its header", vec![0x00, 0x20, 0x40, 0x00, 0x10, 0x00], 0x06),
        ("upload request with data after it", vec![0x00, 0x20, 0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0, 0xAA, 0xBB], 0x08),
        ("expedited download with data after it", vec![0x00, 0x20, 0x2F, 0x60, 0x60, 0x00, 8, 0, 0, 0, 0xAA], 0x08),
        (
            "normal download with more data than announced",
            vec![0x00, 0x20, 0x21, 0x50, 0x1F, 0x01, 2, 0, 0, 0, 1, 2, 3],
            0x08,
        ),
        ("CoE service RxPDO", vec![0x00, 0x50, 0, 0, 0, 0, 0, 0, 0, 0], 0x04),
    ];
    for (what, data, code) in cases {
        b.send(COE, &data);
        b.poll();
        assert_eq!(mailbox_error(b.receive()), code, "{what}");
    }
    // The mailbox still serves SDOs, and nothing was written.
    assert_eq!(b.sdo_upload(0x1000, 0).map(|(v, _)| v), Ok(0x0002_0192u32.to_le_bytes().to_vec()));
    assert!(b.app.program.is_empty());
}

#[test]
fn a_repeated_counter_is_not_executed_twice() {
    let mut b = preop();
    let write = |v: u8| vec![0x00, 0x20, 0x2F, 0x60, 0x60, 0x00, v, 0, 0, 0];
    assert_eq!(b.send_with_counter(COE, 3, &write(1)), 1);
    b.poll();
    let (_, first) = b.receive().expect("the answer");
    assert_eq!(first[2], 0x60, "download response");
    // The master did not see the working counter and writes the same mailbox again (here with another value,
    // to tell whether it ran): it is dropped.
    assert_eq!(b.send_with_counter(COE, 3, &write(5)), 1);
    b.poll();
    assert_eq!(b.receive(), None, "no second answer");
    assert_eq!(b.mailbox.stats().duplicates, 1);
    // The next counter is executed again.
    assert_eq!(b.send_with_counter(COE, 4, &[0x00, 0x20, 0x40, 0x60, 0x60, 0x00, 0, 0, 0, 0]), 1);
    b.poll();
    let (_, value) = b.receive().expect("the upload");
    assert_eq!(value[6], 1, "the repeated write did not run");
}

#[test]
fn counter_zero_means_no_check() {
    let mut b = preop();
    let upload = [0x00, 0x20, 0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0];
    for _ in 0..2 {
        assert_eq!(b.send_with_counter(COE, 0, &upload), 1);
        b.poll();
        assert!(b.receive().is_some(), "answered every time");
    }
}

#[test]
fn the_drive_numbers_its_mailboxes_1_to_7() {
    let mut b = preop();
    let mut counters = Vec::new();
    for _ in 0..9 {
        let (h, _) = b.exchange(COE, &[0x00, 0x20, 0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]);
        counters.push(h.counter);
    }
    assert_eq!(counters, [1, 2, 3, 4, 5, 6, 7, 1, 2]);
}

#[test]
fn replies_wait_in_the_queue_while_sm1_is_full() {
    let mut b = preop();
    let upload = |sub: u8| [0x00, 0x20, 0x40, 0x18, 0x10, sub, 0, 0, 0, 0];
    for sub in 1..=3 {
        assert_eq!(b.send(COE, &upload(sub)), 1);
        b.poll();
    }
    let mut subs = Vec::new();
    while let Some((_, d)) = b.receive() {
        subs.push(d[5]);
        b.poll();
    }
    assert_eq!(subs, [1, 2, 3], "every reply, in order");
}

#[test]
fn a_repeat_request_sends_the_last_reply_again() {
    let mut b = preop();
    let (_, first) = b.exchange(COE, &[0x00, 0x20, 0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0]);
    // The master lost the frame with the reply: it toggles the repeat request of SM1 (0x080E bit 1).
    b.fpwr(0x080E, &[0x03]);
    b.poll();
    let (_, again) = b.receive().expect("the reply again");
    assert_eq!(again, first);
    let (ack, _) = b.fprd(0x080F, 1);
    assert_eq!(ack[0] & 0x02, 0x02, "repeat acknowledged");
    assert_eq!(b.mailbox.stats().repeats, 1);
}

#[test]
fn a_repeat_request_with_a_newer_reply_in_sm1_sends_both_in_order() {
    let mut b = preop();
    let (_, first) = b.exchange(COE, &[0x00, 0x20, 0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0]);
    // The next request's reply is in SM1, not read yet, when the master asks for the lost one.
    b.send(COE, &[0x00, 0x20, 0x40, 0x18, 0x10, 0x02, 0, 0, 0, 0]);
    b.poll();
    b.fpwr(0x080E, &[0x03]);
    b.poll();
    let (_, again) = b.receive().expect("the lost reply");
    assert_eq!(again, first);
    b.poll();
    let (_, second) = b.receive().expect("then the newer one");
    assert_eq!(second[5], 0x02);
}

#[test]
fn requests_wait_in_sm0_when_the_queue_is_full() {
    let mut b = preop();
    let upload = [0x00, 0x20, 0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0];
    let mut taken = 0;
    for _ in 0..6 {
        if b.send(COE, &upload) == 1 {
            taken += 1;
        }
        b.poll();
    }
    // One reply in SM1 and QUEUE_DEPTH - 1 queued; one more request waits in SM0, the rest were refused.
    let answers = std::iter::from_fn(|| {
        let a = b.receive();
        b.poll();
        a
    })
    .count();
    assert!(taken >= answers, "every answer belongs to a request the ESC took");
    assert!(answers >= 4, "none lost: {answers} answers for {taken} requests taken");
    // The request left waiting in SM0 is answered as well.
    assert_eq!(answers, taken);
}

// ---------------------------------------------------------------------------------------------------------
// FoE
// ---------------------------------------------------------------------------------------------------------

fn foe_request(op: u8, value: u32, data: &[u8]) -> Vec<u8> {
    let mut m = vec![op, 0];
    m.extend_from_slice(&value.to_le_bytes());
    m.extend_from_slice(data);
    m
}

fn foe_answer(b: &mut Bench, op: u8, value: u32, data: &[u8]) -> (u8, u32, Vec<u8>) {
    let (h, d) = b.exchange(FOE, &foe_request(op, value, data));
    assert_eq!(h.kind, FOE, "an FoE answer, got {h:?} {d:02X?}");
    (d[0], u32::from_le_bytes([d[2], d[3], d[4], d[5]]), d[6..].to_vec())
}

#[test]
fn foe_outside_boot_is_refused_with_bootstrap_only() {
    let mut b = preop();
    assert_eq!(foe_answer(&mut b, 2, 0, b"firmware.bin"), (5, 0x8008, vec![]), "FoE error 0x8008");
    assert_eq!(foe_answer(&mut b, 1, 0, b"firmware.bin").1, 0x8008, "read as well");
    assert!(b.sink.opened.is_none(), "the sink never saw it");
}

#[test]
fn foe_write_in_boot_reaches_the_sink() {
    let mut b = Bench::new();
    b.to_boot();
    let image: Vec<u8> = (0..300u32).map(|i| (i * 13 + 1) as u8).collect();
    assert_eq!(foe_answer(&mut b, 2, 0, b"firmware.bin"), (4, 0, vec![]), "ACK 0");
    let max = 128 - 12;
    for (k, chunk) in image.chunks(max).enumerate() {
        let packet = k as u32 + 1;
        assert_eq!(foe_answer(&mut b, 3, packet, chunk), (4, packet, vec![]), "ACK {packet}");
    }
    assert_eq!(b.sink.file, image);
    assert!(b.sink.finished, "the short last packet finishes the file");
    assert_eq!(b.mailbox.foe().stats().files_written, 1);
}

#[test]
fn foe_file_of_whole_packets_ends_with_an_empty_packet() {
    let mut b = Bench::new();
    b.to_boot();
    let image = vec![0x5A; 2 * 116];
    foe_answer(&mut b, 2, 0, b"firmware.bin");
    assert_eq!(foe_answer(&mut b, 3, 1, &image[..116]).0, 4);
    assert_eq!(foe_answer(&mut b, 3, 2, &image[116..]).0, 4);
    assert!(!b.sink.finished, "full packets do not end the file");
    assert_eq!(foe_answer(&mut b, 3, 3, &[]), (4, 3, vec![]));
    assert!(b.sink.finished);
    assert_eq!(b.sink.file, image);
}

#[test]
fn foe_errors_in_boot() {
    let mut b = Bench::new();
    b.to_boot();
    assert_eq!(foe_answer(&mut b, 2, 0, b"other.bin").1, 0x8001, "unknown file: the sink's code");
    assert_eq!(foe_answer(&mut b, 2, 7, b"firmware.bin").1, 0x800A, "wrong password");
    assert_eq!(foe_answer(&mut b, 3, 1, &[1, 2, 3]).1, 0x8004, "data without a write request");
    assert_eq!(foe_answer(&mut b, 2, 0, b"firmware.bin").0, 4);
    assert_eq!(foe_answer(&mut b, 3, 2, &[1, 2, 3]), (5, 0x8005, vec![]), "packet 2 before packet 1");
    assert!(b.sink.aborted, "the sink discards the transfer");
    // CoE is not served in BOOT.
    b.send(COE, &[0x00, 0x20, 0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]);
    b.poll();
    assert_eq!(mailbox_error(b.receive()), 0x02);
    // An FoE mailbox shorter than its header.
    b.send(FOE, &[2, 0]);
    b.poll();
    assert_eq!(mailbox_error(b.receive()), 0x06);
}

#[test]
fn foe_busy_makes_the_master_send_the_packet_again() {
    let mut b = Bench::new();
    b.to_boot();
    b.sink.busy_left = 1;
    foe_answer(&mut b, 2, 0, b"firmware.bin");
    let (op, value, _) = foe_answer(&mut b, 3, 1, &[1, 2, 3]);
    assert_eq!((op, value), (6, 1 | (2 << 16)), "BUSY done 1 of 2");
    assert_eq!(foe_answer(&mut b, 3, 1, &[1, 2, 3]), (4, 1, vec![]));
    assert_eq!(b.sink.file, [1, 2, 3]);
}

#[test]
fn foe_master_error_ends_the_transfer_without_answer() {
    let mut b = Bench::new();
    b.to_boot();
    foe_answer(&mut b, 2, 0, b"firmware.bin");
    b.send(FOE, &foe_request(5, 0x8000, b"stop"));
    b.poll();
    assert_eq!(b.receive(), None);
    assert!(b.sink.aborted);
    assert!(!b.mailbox.foe().is_busy());
}

#[test]
fn foe_read_in_boot_sends_the_file_in_packets() {
    let mut b = Bench::new();
    b.to_boot();
    b.sink.readable = (0..150u8).collect();
    let (op, packet, first) = foe_answer(&mut b, 1, 0, b"firmware.bin");
    assert_eq!((op, packet, first.len()), (3, 1, 116));
    let (op, packet, second) = foe_answer(&mut b, 4, 1, &[]);
    assert_eq!((op, packet, second.len()), (3, 2, 34));
    b.send(FOE, &foe_request(4, 2, &[]));
    b.poll();
    assert_eq!(b.receive(), None, "the last acknowledge ends the read");
    assert_eq!([first, second].concat(), b.sink.readable);
}

#[test]
fn leaving_boot_aborts_an_unfinished_download() {
    let mut b = Bench::new();
    b.to_boot();
    foe_answer(&mut b, 2, 0, b"firmware.bin");
    foe_answer(&mut b, 3, 1, &[0; 116]);
    assert_eq!(b.request(0x0001), (0x0001, 0x0000));
    b.poll();
    assert!(b.sink.aborted);
    assert!(!b.sink.finished);
}

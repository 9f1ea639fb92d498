//! Issue 7, "What it must show": an update end to end over FoE with a real master. SOEM through PyPI `pysoem`
//! (`tests/ecat/soem_foe.py`) takes `drive-sim ethercat --lock-step` from PRE-OP to INIT, puts the SII's bootstrap
//! mailbox into SM0/SM1 and requests BOOT (as SOEM's firmware-update example does), writes a signed image as the
//! file "EPOS4" with password 0 (E4 Table 4-29 L2095-2130), requests INIT, finds the drive again with a fresh
//! master and reads the identification; then the drive runs: OP, the controlword up to «Operation enabled», some
//! hundred cycles of process data with every working counter right. A second run writes a corrupted image: the
//! drive refuses it with the FoE error program control maps (`classify`: CRC -> 0x800C, IDX Table 7-155), and
//! the old image keeps running.
//!
//! SOEM's `ecx_FOEwrite` reports an FoE error only as a negative return value, not its code; the simulator
//! records a capture of the run (`--pcap`) and [`foe_from_capture`] decodes the FoE packets in the drive's
//! answers (ETG.1000.4 §5.4 datagrams, ETG.1000.6 §5.6 mailbox header and FoE) to get the code itself.
//!
//! Both runs in lock-step (simulated time stands still while the mailbox works), so the verdicts do not depend
//! on how busy the host is. When the machine lacks a prerequisite (user
//! namespaces, python3/pysoem, which `scripts/setup.sh` installs) a test fails under `CI=true` and is a reported
//! skip elsewhere (`drive_tests::prerequisite`).

use std::path::Path;

use drive_tests::can_master::WorkDir;
use drive_tests::prerequisite;
use drive_tests::real_master::{self, cannot_run_soem as cannot_run, root, RunOutput};
use firmware::boot::image::{HARDWARE_ID, HEADER_LEN};
use firmware::boot::program::{status, BOOTLOADER_ID};
use firmware::drive::calibration::CalibrationConfig;
use hal_sim::sim::ethercat::PERIOD_NS;
use hal_sim::sim::update::{dev_seed, payload, signed_image, FACTORY_VERSION, FACTORY_VERSION_STRING};

/// The new image's version (0x1F56's high word) and version string (0x100A).
const NEW_VERSION: u32 = 0x0002_0001;
const NEW_VERSION_STRING: &str = "2.0.1";
/// The payload size: 96 KiB, as the CANopen update test (tests/tests/canopen_real_master.rs).
const PAYLOAD: usize = 96 * 1024;
/// Process-data cycles after the update ("the drive runs normally").
const CYCLES: u32 = 400;

/// 0x1F56:01 as the drive reports it (IDX L3382-3412): the application's software id in the high word, the
/// bootloader's in the low.
fn sw_id(version: u32) -> String {
    format!("0x{:08x}", version & 0xFFFF_0000 | u32::from(BOOTLOADER_ID))
}

/// 0x1F57:01 with status code `code` and no download in progress (IDX L3413-3473: the code in bits 7..1, bit 0
/// set while a download runs).
fn flash_status(code: u8) -> String {
    (u32::from(code) << 1).to_string()
}

/// What the drive's answers in a capture say about FoE: the error codes of its FoE error packets and the
/// number of its FoE acknowledges.
#[derive(Debug, Default, PartialEq)]
struct FoeSeen {
    errors: Vec<u32>,
    acks: usize,
}

/// Decodes the FoE packets in a pcap file written by `drive-sim ethercat --pcap` (pcap-savefile(5): a 24-byte
/// global header, then per record a 16-byte header and the Ethernet frame). Only answered datagrams count (working
/// counter above 0: the frame on its way back from the drive); a mailbox read (FPRD) whose data starts with a
/// mailbox header of type 4 (FoE) carries the drive's FoE packet: opcode 4 = ACK, 5 = ERROR with the code in the
/// next 4 bytes (ETG.1000.6 §5.6.3).
fn foe_from_capture(pcap: &Path) -> FoeSeen {
    let bytes = std::fs::read(pcap).unwrap_or_else(|e| panic!("read {}: {e}", pcap.display()));
    let u16_at = |b: &[u8], at: usize| u16::from_le_bytes([b[at], b[at + 1]]);
    let u32_at = |b: &[u8], at: usize| u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]);
    let mut seen = FoeSeen::default();
    let mut at = 24;
    while at + 16 <= bytes.len() {
        let len = u32_at(&bytes, at + 8) as usize;
        let frame = &bytes[at + 16..(at + 16 + len).min(bytes.len())];
        at += 16 + len;
        // Ethernet header (14 bytes, EtherType 0x88A4), the EtherCAT header (2 bytes), then the datagrams.
        if frame.len() < 16 || frame[12..14] != [0x88, 0xA4] {
            continue;
        }
        let mut d = 16;
        while d + 12 <= frame.len() {
            let cmd = frame[d];
            let len_flags = u16_at(frame, d + 6);
            let n = usize::from(len_flags & 0x07FF);
            if d + 10 + n + 2 > frame.len() {
                break;
            }
            let data = &frame[d + 10..d + 10 + n];
            let wkc = u16_at(frame, d + 10 + n);
            if cmd == 4 && wkc > 0 && n >= 12 && data[5] & 0x0F == 4 {
                match data[6] {
                    4 => seen.acks += 1,
                    5 => seen.errors.push(u32_at(data, 8)),
                    _ => {}
                }
            }
            d += 10 + n + 2;
            if len_flags & 0x8000 == 0 {
                break;
            }
        }
    }
    seen
}

/// Writes `image` to a file, runs `soem_foe.py --expect <expect>` against `drive-sim ethercat --lock-step` with a
/// capture, and returns the run's figures and what the capture shows of FoE.
fn update(name: &str, image: &[u8], expect: &str) -> (RunOutput, FoeSeen) {
    let dir = WorkDir::new(&format!("foe-{name}"));
    let file = dir.join("image.bin");
    std::fs::write(&file, image).expect("write the image");
    let pcap = dir.join("foe.pcap");
    let script = root().join("tests/ecat/soem_foe.py");
    let command = format!(
        "python3 '{}' --iface ecm0 --image '{}' --expect {expect} --cycles {CYCLES}",
        script.display(),
        file.display()
    );
    let sim_args = format!("--lock-step --cycle-us 1000 --pcap '{}'", pcap.display());
    let out = real_master::run_in_namespace(name, &sim_args, &command);
    assert_eq!(out.master("verdict"), "pass", "\n{}", out.text);
    assert_eq!(out.master("master_rc"), "0", "\n{}", out.text);
    assert_eq!(out.master("sim_rc"), "0", "drive-sim's exit status\n{}", out.text);
    let seen = foe_from_capture(&pcap);
    (out, seen)
}

/// The checks both runs share: the bootstrap mailbox SOEM read from the SII, BOOT reached, INIT after it, the
/// drive found again, running (0x1F51:01 = 1), and after it OP with «Operation enabled» and every working counter
/// right for [`CYCLES`] cycles.
fn runs_normally_after(out: &RunOutput) {
    // The SII's bootstrap mailbox (od-gen's SII generator; docs/generated/drive-sii.hex words 0x14..0x17).
    let sii = hal_sim::esc::drive_sii_image().expect("SII image");
    let word = |w: usize| u16::from_le_bytes([sii[2 * w], sii[2 * w + 1]]);
    assert_eq!(out.master("sii_boot_rx"), format!("0x{:04x}/{}", word(0x14), word(0x15)));
    assert_eq!(out.master("sii_boot_tx"), format!("0x{:04x}/{}", word(0x16), word(0x17)));
    assert_eq!(out.master("boot"), "1");
    assert_eq!(out.master("init_after_boot"), "1");
    assert_eq!(out.master("found_again"), "1");
    assert_eq!(out.master("program_state_after"), "1", "the application runs");
    assert_eq!(out.master("op"), "1");
    assert_eq!(out.master("cycles"), CYCLES.to_string());
    assert_eq!(out.master("wkc_errors"), "0");
    assert_eq!(out.master("state_after_cycles"), "OP");
    let enabled_at: u64 = out.master("enabled_at_cycle").parse().expect("«Operation enabled» reached");
    // Bound: shutdown, switch on, enable operation take a cycle each and the statusword answers a cycle later
    // (6 cycles, 2 more of slack), and enabling runs the current-offset calibration, at most its timeout
    // (firmware::drive::calibration, 625 PWM periods = 25 ms = 25 cycles of 1 ms in lock-step).
    let calibration_cycles = u64::from(CalibrationConfig::DEFAULT.timeout_ticks) * PERIOD_NS / 1_000_000;
    assert!(enabled_at <= 8 + calibration_cycles, "«Operation enabled» only at cycle {enabled_at}");
    assert_eq!(out.sim("state_reached"), "OP");
    assert_eq!(out.sim("state_final"), "Init", "the master's last request");
}

/// Proves the FoE update end to end with SOEM: a 96 KiB signed image written in BOOT, INIT resets the drive
/// into it; after the reset 0x1F56:01 and 0x100A report the new image, the flash status 0x1F57:01 is 0 (no
/// error), and the drive goes to OP and enables. The capture shows the drive acknowledged every FoE data packet
/// and sent no FoE error.
#[test]
fn soem_writes_a_signed_image_over_foe_in_boot_and_after_init_the_drive_runs_the_new_image() {
    if prerequisite::skip(
        "soem_writes_a_signed_image_over_foe_in_boot_and_after_init_the_drive_runs_the_new_image",
        cannot_run(),
    ) {
        return;
    }
    let image = signed_image(&payload(PAYLOAD, NEW_VERSION), NEW_VERSION, NEW_VERSION_STRING, HARDWARE_ID, &dev_seed());
    let (out, seen) = update("accept", &image, "accept");
    assert_eq!(out.master("sw_id_before"), sw_id(FACTORY_VERSION));
    assert_eq!(out.master("version_before"), FACTORY_VERSION_STRING);
    assert_eq!(out.master("foe_bytes"), image.len().to_string());
    assert!(out.master_num("foe_write_rc") > 0.0, "SOEM reports the write done");
    assert_eq!(out.master("sw_id_after"), sw_id(NEW_VERSION), "0x1F56:01 of the new image");
    assert_eq!(out.master("version_after"), NEW_VERSION_STRING, "0x100A of the new image");
    assert_eq!(out.master("flash_status_after"), flash_status(status::OK), "0x1F57:01");
    runs_normally_after(&out);
    // FoE: the drive acknowledged the write request (ACK 0) and each data packet, the last one too (ETG.1000.6
    // §5.6.3).
    let packets: usize = out.master("foe_packets").parse().expect("foe_packets");
    assert_eq!(seen, FoeSeen { errors: vec![], acks: packets + 1 }, "FoE answers in the capture");
    println!(
        "SOEM FoE write of {} bytes ({} B header, {packets} packets of <= {} B): {} s wall; whole script {} s, \
         {} frames, {} s simulated; 0x1F56 {} -> {}, 0x100A {} -> {}",
        out.master("foe_bytes"),
        HEADER_LEN,
        image.len().div_ceil(packets),
        out.master("foe_write_s"),
        out.master("script_s"),
        out.sim("frames"),
        out.sim("simulated_s"),
        out.master("sw_id_before"),
        out.master("sw_id_after"),
        out.master("version_before"),
        out.master("version_after"),
    );
}

/// Proves a refusal through the real master: a signed image with one payload byte flipped is written over FoE
/// in BOOT; the drive answers the last packet with FoE error 0x800C (checksum: `classify` maps a CRC mismatch to
/// it, IDX Table 7-155), SOEM's write fails, 0x1F57:01 shows the data error; after INIT the old image runs:
/// 0x1F56:01 and 0x100A unchanged, OP and «Operation enabled».
#[test]
fn soem_writes_a_corrupted_image_over_foe_the_drive_refuses_it_with_0x800c_and_the_old_image_runs() {
    if prerequisite::skip(
        "soem_writes_a_corrupted_image_over_foe_the_drive_refuses_it_with_0x800c_and_the_old_image_runs",
        cannot_run(),
    ) {
        return;
    }
    let mut image =
        signed_image(&payload(PAYLOAD, NEW_VERSION), NEW_VERSION, NEW_VERSION_STRING, HARDWARE_ID, &dev_seed());
    let flip = HEADER_LEN as usize + PAYLOAD / 2;
    image[flip] ^= 0x40;
    let (out, seen) = update("refuse", &image, "refuse");
    assert_eq!(out.master("sw_id_before"), sw_id(FACTORY_VERSION));
    assert!(out.master_num("foe_write_rc") <= 0.0, "SOEM reports the write failed");
    assert_eq!(seen.errors, vec![0x800C], "the drive's FoE error in the capture");
    assert_eq!(out.master("sw_id_after"), sw_id(FACTORY_VERSION), "0x1F56:01 of the old image");
    assert_eq!(out.master("version_after"), FACTORY_VERSION_STRING, "0x100A of the old image");
    assert_eq!(out.master("flash_status_after"), flash_status(status::DATA_ERROR), "0x1F57:01");
    runs_normally_after(&out);
    println!(
        "SOEM FoE write of a corrupted image ({} bytes, byte {flip} flipped): refused with FoE error 0x{:04X} after \
         {} s; the old image {} runs",
        out.master("foe_bytes"),
        seen.errors[0],
        out.master("foe_write_s"),
        out.master("version_after"),
    );
}

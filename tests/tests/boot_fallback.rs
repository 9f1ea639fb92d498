//! Issue 7, item 4: the bootloader's fallback on CAN. A drive whose slot A holds no valid image stays in the
//! bootloader, which answers on the bus with its own compact service (`firmware::boot::fallback::FallbackNode`,
//! run by hal-sim's CAN runner in place of the application's node): its boot-up, the reduced object set (device
//! type 0x0000_012E, 0x1F51 = 3 "no program"), program control's refusals, and the way back: clear, a signed
//! image into 0x1F50, start -> the bootloader swaps it in and the application boots.
//!
//! In-process (a raw SDO client on the runner, lock-step, 1 Mbit/s) and with a real master (PyPI `canopen` over
//! socketcand against `drive-sim canopen --no-image 1 --lock-step`, tests/canopen/fallback.py). The images are
//! small (16 KiB payload) so that each test stays within seconds in the dev profile; the update path's
//! behaviour does not depend on the size (boot_program_control.rs loads 128 KiB through the application).

mod boot_fieldbus;

use std::time::Instant;

use boot_fieldbus::{new_image, u32_of, CanRig, NEW_VERSION, NEW_VERSION_STRING};
use drive_tests::can_master::{cannot_run, run, write_eds, WorkDir};
use drive_tests::prerequisite;
use drive_tests::real_master::default_u32;
use firmware::boot::image::{ImageError, HEADER_LEN};
use firmware::boot::loader::{BootEvent, Outcome};
use firmware::boot::program::{classify, status, BOOTLOADER_ID};
use firmware::boot::tables::BOOTLOADER_DEVICE_TYPE;
use firmware::boot::update::UpdateError;
use firmware::canopen::frame::CanFrame;
use firmware::cia402::State;
use firmware::od::access::Dictionary;
use hal_sim::sim::canopen::{CanClock, CanopenConfig, CanopenRunner};

/// 16 KiB: the factory image's size, small enough for a segmented download in a second or two of wall time.
const PAYLOAD: usize = 16 * 1024;
const NO_OBJECT: u32 = 0x0602_0000;
/// Program control's refusals (E4 Table 4-28 via `program::classify`).
const DEVICE_STATE: u32 = 0x0800_0022;
const CANNOT_TRANSFER: u32 = 0x0800_0020;

/// 0x1F57:01 as read: status code in bits 7..1, bit 0 "download in progress" (IDX L3413-3473).
fn flash_status(code: u8) -> u32 {
    u32::from(code) << 1
}

/// 0x1F56:01 (IDX L3382-3412): application identification in bits 31..16 (0 without one), the bootloader's in
/// bits 15..0.
fn software_id(application: u32) -> u32 {
    application & 0xFFFF_0000 | u32::from(BOOTLOADER_ID)
}

/// Node 1 with an erased slot A on a lock-step bus, powered on for 2 ms; returns the rig and the (COB-ID, data)
/// of every frame that reached the master meanwhile.
fn fallback_rig() -> (CanRig, Vec<(u16, Vec<u8>)>) {
    let config = CanopenConfig { clock: CanClock::LockStep, ..CanopenConfig::default() }.with_empty_slot(1);
    let mut r = CanopenRunner::new(config);
    let got = r.run_for(2_000_000).iter().map(|d| (d.frame.id(), d.frame.data().to_vec())).collect();
    (CanRig { r }, got)
}

/// SDO segmented download (CiA 301 §7.2.4.3.3-5, size indicated): initiate, then 7-byte segments with the toggle
/// bit, each answered; `Err` is the abort code of the first abort.
fn segmented_download(rig: &mut CanRig, index: u16, sub: u8, value: &[u8]) -> Result<(), u32> {
    let [i0, i1] = index.to_le_bytes();
    let [s0, s1, s2, s3] = (value.len() as u32).to_le_bytes();
    let a = rig.sdo([0x21, i0, i1, sub, s0, s1, s2, s3]).expect("an initiate answer");
    if a[0] == 0x80 {
        return Err(u32_of(&a[4..8]));
    }
    assert_eq!(a[..4], [0x60, i0, i1, sub], "initiate download response");
    let mut toggle = 0u8;
    for (k, chunk) in value.chunks(7).enumerate() {
        let last = (k + 1) * 7 >= value.len();
        let mut f = [0u8; 8];
        f[0] = toggle | ((7 - chunk.len() as u8) << 1) | u8::from(last);
        f[1..1 + chunk.len()].copy_from_slice(chunk);
        let a = rig.sdo(f).unwrap_or_else(|| panic!("an answer to segment {k}"));
        if a[0] == 0x80 {
            return Err(u32_of(&a[4..8]));
        }
        assert_eq!(a[0], 0x20 | toggle, "segment {k} acknowledged with its toggle");
        toggle ^= 0x10;
    }
    Ok(())
}

/// (COB-ID, data) of the frames the master received for one lock-step request.
fn exchange(rig: &mut CanRig, id: u16, data: &[u8]) -> Vec<(u16, Vec<u8>)> {
    rig.r.lock_step(CanFrame::new(id, data).unwrap()).iter().map(|d| (d.frame.id(), d.frame.data().to_vec())).collect()
}

/// Proves (issue 7 item 4; IDX L3345-3350; E4 Table 4-32/4-33): with slot A erased the bootloader stays active
/// and its fallback, not the application, answers on node-ID 1: one boot-up 0x701 [00]; 0x1000 = 0x0000_012E,
/// 0x1F51:01 = 3 "no program", 0x1F56:01 = the bootloader's id alone, 0x1F57:01 status 1 "no valid program";
/// an application object (statusword 0x6041) is absent (0x0602_0000); 0x1F50 before clear gets program
/// control's sequence refusal (0x0800_0022, status 66); after clear an image with one payload byte flipped is
/// refused at the end of the download with the CRC refusal (0x0800_0020, status 3 "data error"), a start then
/// is refused (0x0800_0022) and the node stays in the fallback, also across an NMT reset node (a new boot-up
/// from the fallback, status back to 1).
#[test]
fn the_fallback_answers_with_the_bootloaders_objects_and_refuses_a_corrupted_image() {
    let (mut rig, boot) = fallback_rig();
    assert_eq!(boot, [(0x701, vec![0])], "one boot-up from the fallback and nothing else");
    let d = rig.r.drive(1).unwrap();
    assert!(d.in_fallback(), "no valid image: the fallback serves node 1");
    assert_eq!(d.last_boot, Outcome::NoValidImage(ImageError::BadMagic), "erased slot A");

    assert_eq!(rig.upload_u32(0x1000, 0), Ok(BOOTLOADER_DEVICE_TYPE));
    assert_eq!(BOOTLOADER_DEVICE_TYPE, 0x0000_012E);
    assert_eq!(rig.upload_u32(0x1F51, 1), Ok(3), "program control: no program");
    assert_eq!(rig.upload_u32(0x1F56, 1), Ok(software_id(0)));
    assert_eq!(rig.upload_u32(0x1F57, 1), Ok(flash_status(status::NO_PROGRAM)));
    assert_eq!(rig.upload_u32(0x6041, 0), Err(NO_OBJECT), "no application objects in the bootloader");

    let image = new_image(PAYLOAD);
    let sequence = classify(UpdateError::Sequence);
    assert_eq!(sequence.abort.code(), DEVICE_STATE);
    assert_eq!(segmented_download(&mut rig, 0x1F50, 1, &image), Err(DEVICE_STATE), "0x1F50 before clear");
    assert_eq!(rig.upload_u32(0x1F57, 1), Ok(flash_status(status::SEQUENCE_ERROR)));

    assert_eq!(rig.download(0x1F51, 1, &[3]), Some(Ok(())), "clear");
    assert_eq!(rig.upload_u32(0x1F57, 1), Ok(flash_status(status::NO_PROGRAM)));
    let mut corrupted = image.clone();
    corrupted[HEADER_LEN as usize + 1000] ^= 0x01;
    assert_eq!(segmented_download(&mut rig, 0x1F50, 1, &corrupted), Err(CANNOT_TRANSFER), "CRC refusal");
    assert_eq!(rig.upload_u32(0x1F57, 1), Ok(flash_status(status::DATA_ERROR)));
    assert_eq!(rig.download(0x1F51, 1, &[1]), Some(Err(DEVICE_STATE)), "start without a verified image");
    assert!(rig.r.drive(1).unwrap().in_fallback());
    assert_eq!(rig.upload_u32(0x1000, 0), Ok(BOOTLOADER_DEVICE_TYPE), "still the bootloader");

    let got = exchange(&mut rig, 0x000, &[0x81, 1]);
    assert_eq!(got, [(0x701, vec![0])], "reset node: the bootloader runs again, a new boot-up from the fallback");
    let d = rig.r.drive(1).unwrap();
    assert!(d.in_fallback());
    assert_eq!(d.last_boot, Outcome::NoValidImage(ImageError::BadMagic), "the refused image was never activated");
    assert_eq!(rig.upload_u32(0x1F51, 1), Ok(3));
    assert_eq!(rig.upload_u32(0x1F57, 1), Ok(flash_status(status::NO_PROGRAM)));
}

/// Writes `cw` to the controlword, then polls the statusword (one SDO upload, then 1 ms of simulated time) until
/// its state bits (mask 0x6F, CiA 402 Table 30) read `want`, at most 300 polls (the offset calibration of
/// "switch on" takes up to 3,000 PWM periods = 120 ms, `Simulation::enable_through_controlword`).
fn controlword_until(rig: &mut CanRig, cw: u16, want: u16) {
    assert_eq!(rig.download(0x6040, 0, &cw.to_le_bytes()), Some(Ok(())), "controlword 0x{cw:04x}");
    for _ in 0..300 {
        let sw = rig.upload_u32(0x6041, 0).expect("statusword") as u16;
        if sw & 0x6F == want {
            return;
        }
        rig.r.run_for(1_000_000);
    }
    panic!("statusword never reached 0x{want:02x} & 0x6F after controlword 0x{cw:04x}");
}

/// Proves the way out of the fallback (issue 7 item 4, the seeds' sequence IDX L3320-3473): clear, a signed 16 KiB
/// image into 0x1F50:01 by segmented download (0x1F57 = 0, 0x1F51 = 0 "stopped": a verified program waits), start
/// (0x1F51:01 = 1: the fallback answers, then resets) -> the bootloader activates the image on trial, the
/// application boots (boot-up 0x701 after the answer) and confirms itself; 0x1F56:01 and 0x100A report the new
/// image, 0x1000 is the application's device type again, 0x1F51 = 1, and the drive goes through Ready to switch on,
/// Switched on to Operation enabled by controlword over SDO.
#[test]
fn a_signed_image_loaded_into_the_fallback_starts_and_the_drive_enables_over_sdo() {
    let (mut rig, _) = fallback_rig();
    assert_eq!(rig.download(0x1F51, 1, &[3]), Some(Ok(())), "clear");
    let image = new_image(PAYLOAD);
    let (t0, wall) = (rig.r.now_ns(), Instant::now());
    assert_eq!(segmented_download(&mut rig, 0x1F50, 1, &image), Ok(()));
    let (sim_s, wall_s) = ((rig.r.now_ns() - t0) as f64 * 1e-9, wall.elapsed().as_secs_f64());
    assert_eq!(rig.upload_u32(0x1F57, 1), Ok(0), "verified");
    assert_eq!(rig.upload_u32(0x1F51, 1), Ok(0), "a verified program waits: stopped");

    let got = exchange(&mut rig, 0x601, &[0x2F, 0x51, 0x1F, 1, 1, 0, 0, 0]);
    assert_eq!(
        got,
        [(0x581, vec![0x60, 0x51, 0x1F, 1, 0, 0, 0, 0]), (0x701, vec![0])],
        "the start's answer, then the application's boot-up"
    );
    let d = rig.r.drive(1).unwrap();
    assert!(!d.in_fallback(), "the application runs");
    assert!(matches!(d.last_boot, Outcome::Run { trial: true, event: BootEvent::Activated, .. }), "{:?}", d.last_boot);
    assert!(!d.program.on_trial(), "the application confirmed itself after its boot");

    assert_eq!(rig.upload_u32(0x1F56, 1), Ok(software_id(NEW_VERSION)));
    assert_eq!(
        rig.upload(0x100A, 0).map(|v| String::from_utf8_lossy(&v).trim_end_matches('\0').to_owned()),
        Ok(NEW_VERSION_STRING.to_owned())
    );
    let app_type = default_u32(&Dictionary::new(1), 0x1000, 0);
    assert_ne!(app_type, BOOTLOADER_DEVICE_TYPE);
    assert_eq!(rig.upload_u32(0x1000, 0), Ok(app_type), "the application's device type");
    assert_eq!(rig.upload_u32(0x1F51, 1), Ok(1), "program started");
    assert_eq!(rig.upload_u32(0x1F57, 1), Ok(0));

    // Profile velocity mode, then the CiA 402 enable sequence.
    assert_eq!(rig.download(0x6060, 0, &[3]), Some(Ok(())));
    controlword_until(&mut rig, 0x0006, 0x21);
    controlword_until(&mut rig, 0x0007, 0x23);
    controlword_until(&mut rig, 0x000F, 0x27);
    assert_eq!(rig.r.drive(1).unwrap().sim.cia402_state(), State::OperationEnabled);
    println!(
        "fallback: {} byte image by segmented SDO at 1 Mbit/s: {sim_s:.3} s simulated, {wall_s:.3} s wall",
        image.len()
    );
}

/// Proves the same with a real master: PyPI `canopen` over socketcand (tests/canopen/fallback.py) against
/// `drive-sim canopen --no-image 1 --lock-step`: the fallback's boot-up after an NMT reset node, 0x1000 =
/// 0x0000_012E, 0x1F51 = 3, 0x1F56/0x1F57, 0x6041 absent (0x0602_0000), 0x1F50 before clear refused with
/// 0x0800_0022 (the node's first abort: canopen's buffered writer flushes one more segment on close, which the
/// server answers with 0x0504_0001, and canopen raises that one); after clear a corrupted image by block
/// download refused with 0x0800_0020 (0x1F57 status 3; canopen raises it) and the node still in the fallback; then the signed image by SDO block download with CRC (`block_transfer=True`), start, the
/// application's boot-up, 0x1F56/0x100A/0x1000 of the new image, and the drive enabled by controlword (Operation
/// enabled in the statusword) with SYNCs giving the offset calibration its time.
#[test]
fn pypi_canopen_recovers_a_drive_in_the_fallback_by_block_download() {
    if prerequisite::skip("pypi_canopen_recovers_a_drive_in_the_fallback_by_block_download", cannot_run()) {
        return;
    }
    let dir = WorkDir::new("fallback");
    let eds = write_eds(&dir);
    let image = new_image(PAYLOAD);
    let mut corrupted = image.clone();
    corrupted[HEADER_LEN as usize + 1000] ^= 0x01;
    let (good, bad) = (dir.join("image.bin"), dir.join("corrupted.bin"));
    std::fs::write(&good, &image).expect("write the image");
    std::fs::write(&bad, &corrupted).expect("write the corrupted image");
    let arg = |p: &std::path::Path| p.to_str().expect("a UTF-8 temp path").to_owned();
    let out = run(
        "fallback.py",
        &["--no-image", "1", "--lock-step"],
        &eds,
        &["--image".into(), arg(&good), "--corrupted".into(), arg(&bad)],
    );
    assert_eq!(out.master("verdict"), "pass", "\n{}", out.text);
    assert_eq!(out.master("master_rc"), "0", "\n{}", out.text);
    assert_eq!(out.sim("node1_running"), "application", "at the end\n{}", out.text);
    assert_eq!(out.sim("node1_cia402"), "OperationEnabled");
    assert_eq!(out.sim("quiet_limit_hits"), "0", "every request answered within the lock-step limit");
    let hex = |v: u32| format!("0x{v:08x}");
    assert_eq!(out.master("bootup_after_reset"), "1");
    assert_eq!(out.master("device_type_fallback"), hex(BOOTLOADER_DEVICE_TYPE));
    assert_eq!(out.master("program_state_fallback"), "3");
    assert_eq!(out.master("sw_id_fallback"), hex(software_id(0)));
    assert_eq!(out.master("flash_status_fallback"), flash_status(status::NO_PROGRAM).to_string());
    assert_eq!(out.master("statusword_abort"), hex(NO_OBJECT));
    assert_eq!(out.master("write_before_clear_abort"), hex(DEVICE_STATE));
    assert_eq!(out.master("corrupted_abort"), hex(CANNOT_TRANSFER));
    assert_eq!(out.master("corrupted_raised"), hex(CANNOT_TRANSFER), "canopen's block download raises the refusal");
    assert_eq!(out.master("flash_status_corrupted"), flash_status(status::DATA_ERROR).to_string());
    assert_eq!(out.master("device_type_after_corrupted"), hex(BOOTLOADER_DEVICE_TYPE), "still the bootloader");
    assert_eq!(out.master("flash_status_after_download"), "0");
    assert_eq!(out.master("bootup_after_start"), "1");
    assert_eq!(out.master("sw_id_after"), hex(software_id(NEW_VERSION)));
    assert_eq!(out.master("version_after"), NEW_VERSION_STRING);
    assert_eq!(out.master("device_type_after"), hex(default_u32(&Dictionary::new(1), 0x1000, 0)));
    assert_eq!(out.master("program_state_after"), "1");
    assert_eq!(out.master("statusword_enabled"), "0x27", "Operation enabled (statusword & 0x6F)");
    println!(
        "fallback with PyPI canopen: {} byte image by block download: {} s simulated, {} s wall; whole run {} s \
         simulated, script {} s wall",
        out.master("image_bytes"),
        out.master("download_sim_s"),
        out.master("download_wall_s"),
        out.sim("simulated_s"),
        out.master("script_s")
    );
}

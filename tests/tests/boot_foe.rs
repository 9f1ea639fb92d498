//! Issue 7, phase 2: the firmware update over FoE in BOOT (E4 Table 4-29 L2095-2130: request BOOT, FoE write of
//! the file "EPOS4" with password 0, request INIT, the drive reboots) on the simulated EtherCAT drive in-process,
//! and the FoE refusals with their error codes (IDX Table 7-155) while the old firmware keeps running.

mod boot_fieldbus;

use boot_fieldbus::*;
use firmware::boot::image::{HARDWARE_ID, HEADER_LEN};
use firmware::boot::loader::{BootEvent, Outcome};
use hal_sim::sim::update::{dev_seed, payload, signed_image, FACTORY_VERSION_STRING};

/// Proves the FoE path end to end: BOOT, write, INIT -> reset into the new image on trial, PRE-OP -> confirmed,
/// 0x1F56 and 0x100A of the new image.
#[test]
fn foe_update_in_boot_end_to_end() {
    let mut rig = EcatRig::new();
    let image = new_image(APP_PAYLOAD);
    let (f0, t0) = (rig.frames, rig.r.simulated_ns());
    rig.enter_boot();
    assert_eq!(rig.foe_write(b"EPOS4", 0, &image), Ok(()));
    assert_eq!(rig.r.node.resets, 0, "no reset before the master leaves BOOT");
    assert_eq!(rig.request(0x0001).0 & 0x0F, 0x0001, "INIT");
    let (frames, ns) = (rig.frames - f0, rig.r.simulated_ns() - t0);
    println!(
        "FoE update of a {} KiB image ({} B header): {frames} mailbox cycles of 1 ms, {:.3} s simulated",
        APP_PAYLOAD / 1024,
        HEADER_LEN,
        ns as f64 / 1e9
    );
    assert_eq!(rig.r.node.resets, 1);
    assert!(matches!(rig.r.node.last_boot, Outcome::Run { trial: true, event: BootEvent::Activated, .. }));
    rig.enter_preop();
    assert!(!rig.r.node.program.borrow().on_trial(), "confirmed in PRE-OP");
    assert_eq!(rig.upload_u32(0x1F56, 1), Ok(NEW_VERSION & 0xFFFF_0000 | 1));
    assert_eq!(rig.upload(0x100A, 0), Ok(NEW_VERSION_STRING.as_bytes().to_vec()));
}

/// One refusal case: what, file name, password, file contents, the expected FoE error code.
type Case = (&'static str, &'static [u8], u32, Vec<u8>, u32);

/// Proves each FoE refusal's error code and that INIT afterwards starts the old application again, no reset.
#[test]
fn foe_refusals_leave_the_old_firmware_running() {
    let mut rig = EcatRig::new();
    rig.enter_preop();
    // Outside BOOT: bootstrap only.
    assert_eq!(rig.foe_write(b"EPOS4", 0, &new_image(1024)), Err(0x8008));

    let body = payload(4096, NEW_VERSION);
    let mut bad_crc = new_image(4096);
    bad_crc[HEADER_LEN as usize + 7] ^= 0x40;
    let mut truncated = new_image(4096);
    truncated.truncate(truncated.len() - 116);
    // (what, file name, password, file, FoE error)
    let cases: [Case; 7] = [
        ("wrong file name", b"firmware.bin", 0, new_image(1024), 0x8001),
        ("wrong password", b"EPOS4", 1, new_image(1024), 0x800A),
        ("bad CRC", b"EPOS4", 0, bad_crc, 0x800C),
        ("other key", b"EPOS4", 0, signed_image(&body, NEW_VERSION, "x", HARDWARE_ID, &[9; 32]), 0x8009),
        ("wrong hardware", b"EPOS4", 0, signed_image(&body, NEW_VERSION, "x", 0x1234_5678, &dev_seed()), 0x800D),
        ("not an image", b"EPOS4", 0, vec![0x55; 1000], 0x8012),
        ("truncated", b"EPOS4", 0, truncated, 0x800B),
    ];
    for (what, name, password, file, code) in cases {
        rig.enter_boot();
        assert_eq!(rig.foe_write(name, password, &file), Err(code), "{what}");
        assert_eq!(rig.request(0x0001).0 & 0x0F, 0x0001, "{what}: INIT");
        assert_eq!(rig.r.node.resets, 0, "{what}: no reset");
        rig.enter_preop();
        assert_eq!(rig.upload_u32(0x1F51, 1), Ok(1), "{what}: the application runs");
        assert_eq!(rig.upload_u32(0x1F56, 1), Ok(OLD_VERSION & 0xFFFF_0000 | 1), "{what}");
        assert_eq!(rig.upload(0x100A, 0), Ok(FACTORY_VERSION_STRING.as_bytes().to_vec()), "{what}");
        assert_eq!(rig.request(0x0001).0 & 0x0F, 0x0001);
    }
}

/// Anti-rollback over FoE (issue 19 item 7): after an image of security version 2 confirmed itself, an FoE write
/// of an image of security version 1 is refused with 0x8009 and the text of 0x1F57 status 94 (ETG.1000.5 FoE
/// error request: code and text), nothing is activated at INIT (no reset, the confirmed image reports); an image
/// of security version 2 is accepted and activated.
#[test]
fn foe_an_older_security_version_is_refused_with_its_code_and_text() {
    let mut rig = EcatRig::new();
    rig.enter_boot();
    assert_eq!(rig.foe_write(b"EPOS4", 0, &image_with_security(4096, 0x0002_0000, 2)), Ok(()));
    assert_eq!(rig.request(0x0001).0 & 0x0F, 0x0001, "INIT");
    assert_eq!(rig.r.node.resets, 1);
    rig.enter_preop();
    assert!(!rig.r.node.program.borrow().on_trial(), "security version 2 confirmed in PRE-OP");

    rig.enter_boot();
    assert_eq!(rig.foe_write(b"EPOS4", 0, &image_with_security(4096, 0x0003_0000, 1)), Err(0x8009));
    assert_eq!(rig.foe_error_text, b"image older than minimum security version".to_vec());
    assert_eq!(rig.r.node.program.borrow().status_code(), 94);
    assert_eq!(rig.request(0x0001).0 & 0x0F, 0x0001, "INIT");
    assert_eq!(rig.r.node.resets, 1, "nothing to activate: no reset");
    rig.enter_preop();
    assert_eq!(rig.upload_u32(0x1F56, 1), Ok(0x0002_0001), "the confirmed image still runs");

    // Another refusal sharing 0x8009 says its own reason.
    rig.enter_boot();
    let mut forged = image_with_security(4096, 0x0003_0000, 2);
    forged[64] ^= 1;
    assert_eq!(rig.foe_write(b"EPOS4", 0, &forged), Err(0x8009));
    assert_eq!(rig.foe_error_text, b"signature invalid".to_vec());

    assert_eq!(rig.foe_write(b"EPOS4", 0, &image_with_security(4096, 0x0003_0000, 2)), Ok(()), "equal");
    assert_eq!(rig.request(0x0001).0 & 0x0F, 0x0001, "INIT");
    assert_eq!(rig.r.node.resets, 2);
    assert!(matches!(rig.r.node.last_boot, Outcome::Run { trial: true, event: BootEvent::Activated, .. }));
}

//! The bootloader on the emulated STM32F405 (issue 7: "a QEMU test loads the bootloader and a signed application
//! image at their flash addresses, and shows that the bootloader verifies the image and jumps to it, and that it
//! refuses a corrupted one"), and its size.
//!
//! QEMU (`netduinoplus2`) gets the bootloader ELF at its link address 0x0800_0000 (where the core fetches SP and the
//! reset vector, no boot-word shim) and slot A as a factory install leaves it: the QEMU drive image packed and
//! signed by `drive-image pack` with the development key, payload from 0x0802_0000, header in the slot's last 128
//! bytes, the rest erased (0xFF). BOOT_STATE reads as QEMU's zero-filled flash: no valid record, i.e. idle. The
//! verdicts are exact (no tolerance): the bootloader either starts the image, whose own bench then runs and exits
//! 0, or stays in its fallback and exits with `EXIT_NO_VALID_IMAGE` and the reason code.
//!
//! Needs `qemu-system-arm` (`scripts/setup.sh`).

use drive_tests::qemu::{self, Run};
use firmware::boot::image::{HEADER_LEN, HEADER_OFFSET};
use firmware::flash_map::{BOOTLOADER_END, BOOTLOADER_START};

/// `Fallback::code` of `firmware/src/bin/bootloader.rs`: bad magic, CRC, signature.
const FALLBACK_BAD_MAGIC: &str = "102";
const FALLBACK_CRC: &str = "108";
const FALLBACK_SIGNATURE: &str = "109";

fn describe(run: &Run) -> String {
    format!("status {:?}\nstdout:\n{}\nstderr:\n{}", run.status, run.stdout, run.stderr)
}

/// The bootloader stayed in its fallback for `code` and started nothing.
fn assert_refused(run: &Run, code: &str, what: &str) {
    assert_eq!(run.status, Some(qemu::EXIT_NO_VALID_IMAGE), "{what}: not refused\n{}", describe(run));
    assert_eq!(run.values.get("boot.fallback").map(String::as_str), Some(code), "{what}\n{}", describe(run));
    assert!(run.insn("foc_step").is_none(), "{what}: the application ran\n{}", describe(run));
}

#[test]
fn bootloader_starts_a_signed_image_and_refuses_a_corrupted_one() {
    assert!(qemu::qemu_available(), "{}", qemu::Error::QemuMissing);
    let elfs =
        qemu::build_target_bins(&[qemu::BOOTLOADER_BIN, qemu::IMAGE_BIN], &["qemu"]).unwrap_or_else(|e| panic!("{e}"));
    let (bootloader, drive) = (&elfs[0], &elfs[1]);
    let tool = qemu::build_image_tool().unwrap_or_else(|e| panic!("{e}"));
    let image = qemu::pack_image(&tool, drive, "1.0.0").unwrap_or_else(|e| panic!("{e}"));
    let slot = qemu::slot_a_contents(&image);

    // Verified and started: the application's bench runs to its end (status 0) and reports its figures.
    let run = qemu::run_with_bootloader(bootloader, &slot, "signed").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(run.status, Some(0), "the signed image did not run to its end\n{}", describe(&run));
    let verify = run.insn("boot_verify").expect("the bootloader reports insn.boot_verify");
    assert!(verify > 0, "a count of 0 means the measurement is broken");
    assert!(run.insn("foc_step").is_some(), "the application did not report\n{}", describe(&run));
    // The jump leaves the core as a reset does: the application measures exactly what it measures when QEMU starts
    // it directly (the instruction counts are exact under -icount shift=0).
    let direct = qemu::run_image(drive).unwrap_or_else(|e| panic!("{e}"));
    let mut through_bootloader = run.insns();
    through_bootloader.remove("boot_verify");
    assert_eq!(through_bootloader, direct.insns(), "the application measured differently behind the bootloader");
    // The verification's count is exact too.
    let again = qemu::run_with_bootloader(bootloader, &slot, "signed").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(again.insn("boot_verify"), Some(verify), "insn.boot_verify differs between two runs");
    eprintln!("insn.boot_verify={verify} for a payload of {} bytes", image.len() - HEADER_LEN as usize);

    // One payload bit flipped: CRC refused, nothing started.
    let mut corrupted = slot.clone();
    corrupted[0x1000] ^= 0x01;
    let run = qemu::run_with_bootloader(bootloader, &corrupted, "corrupted").unwrap_or_else(|e| panic!("{e}"));
    assert_refused(&run, FALLBACK_CRC, "payload bit flipped");

    // One signature bit flipped (header offset 64..128): the image is intact but not authentic.
    let mut forged = slot.clone();
    forged[HEADER_OFFSET as usize + 100] ^= 0x80;
    let run = qemu::run_with_bootloader(bootloader, &forged, "forged").unwrap_or_else(|e| panic!("{e}"));
    assert_refused(&run, FALLBACK_SIGNATURE, "signature bit flipped");

    // An erased slot: no image at all.
    let erased = vec![0xFF; slot.len()];
    let run = qemu::run_with_bootloader(bootloader, &erased, "erased").unwrap_or_else(|e| panic!("{e}"));
    assert_refused(&run, FALLBACK_BAD_MAGIC, "erased slot A");
}

#[test]
fn bootloader_links_at_the_boot_address_and_fits_its_region() {
    // Every build of the bootloader must fit BOOTLOADER (32 KiB): the board's (with the CAN service of its
    // fallback), with defmt logging, and the QEMU one (semihosting output and panic formatting). Sizes from the ELF
    // program headers; the bootloader package is built size-optimised (root `Cargo.toml`,
    // `[profile.release.package.bootloader]`) in the plain release profile.
    for features in [&[][..], &["defmt"][..], &["qemu"][..]] {
        let bins = qemu::build_target_bins(&[qemu::BOOTLOADER_BIN], features).unwrap_or_else(|e| panic!("{e}"));
        let elf = std::fs::read(&bins[0]).expect("bootloader ELF");
        let (start, end) = qemu::flash_extent(&elf).expect("loadable segments in flash");
        eprintln!("bootloader {features:?}: {} bytes of {}", end - start, BOOTLOADER_END - BOOTLOADER_START);
        assert_eq!(start, BOOTLOADER_START, "the bootloader must start at the boot address");
        assert!(
            end <= BOOTLOADER_END,
            "bootloader {features:?} ends at {end:#010x}, beyond BOOTLOADER ({BOOTLOADER_END:#010x})"
        );
    }
}

/// Issue 22 ("the factory HEX boots in QEMU"): `drive-image factory` writes one Intel HEX of the QEMU bootloader
/// and the QEMU drive image (packed and signed on the fly with the development key); QEMU's generic loader puts
/// its records into flash as a programmer would, with nothing loaded besides it. The bootloader verifies slot A
/// and starts the application, whose bench runs to its end (status 0) and reports its figures. The same HEX
/// without slot A's header records (0x0807_FF80..0x0808_0000) is refused with bad magic (`boot.fallback=102`):
/// the start comes from what the HEX holds, not from anything else QEMU was given.
#[test]
fn factory_hex_boots_through_the_bootloader_and_without_its_header_is_refused() {
    assert!(qemu::qemu_available(), "{}", qemu::Error::QemuMissing);
    let elfs =
        qemu::build_target_bins(&[qemu::BOOTLOADER_BIN, qemu::IMAGE_BIN], &["qemu"]).unwrap_or_else(|e| panic!("{e}"));
    let (bootloader, drive) = (&elfs[0], &elfs[1]);
    let tool = qemu::build_image_tool().unwrap_or_else(|e| panic!("{e}"));
    let hex = drive.with_extension("factory.hex");
    let key = qemu::workspace_root().join("keys").join("dev-signing-key.secret");
    let output = std::process::Command::new(&tool)
        .arg("factory")
        .arg("--bootloader")
        .arg(bootloader)
        .arg("--elf")
        .arg(drive)
        .arg("--key")
        .arg(&key)
        .args(["--version", "1.0.0", "--out"])
        .arg(&hex)
        .output()
        .expect("drive-image runs");
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));

    let run = qemu::run_flash_hex(&hex).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(run.status, Some(0), "the factory HEX did not run to the application's end\n{}", describe(&run));
    assert!(run.insn("boot_verify").is_some(), "the bootloader did not verify slot A\n{}", describe(&run));
    assert!(run.insn("foc_step").is_some(), "the application did not report\n{}", describe(&run));

    // Slot A's header records removed: the bootloader finds erased flash where the header belongs.
    let text = std::fs::read_to_string(&hex).expect("factory HEX");
    let mut upper = 0u32;
    let mut kept = String::new();
    for line in text.lines() {
        let field = |at: usize, len: usize| u32::from_str_radix(&line[at..at + len], 16).expect("HEX digits");
        let (kind, offset) = (field(7, 2), field(3, 4));
        if kind == 4 {
            upper = field(9, 4) << 16;
        }
        let header_start = firmware::flash_map::SLOT_A_START + HEADER_OFFSET;
        if kind == 0 && (header_start..header_start + HEADER_LEN).contains(&(upper | offset)) {
            continue;
        }
        kept.push_str(line);
        kept.push('\n');
    }
    assert_eq!(kept.lines().count() + 8, text.lines().count(), "the header is 8 records of 16 bytes");
    let headless = drive.with_extension("factory-headless.hex");
    std::fs::write(&headless, kept).expect("write HEX");
    let run = qemu::run_flash_hex(&headless).unwrap_or_else(|e| panic!("{e}"));
    assert_refused(&run, FALLBACK_BAD_MAGIC, "factory HEX without slot A's header");
}

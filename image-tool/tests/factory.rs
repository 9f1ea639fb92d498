//! `drive-image factory` (issue 22, item 3): the Intel HEX it writes, read back with the `ihex` crate, holds exactly
//! the bootloader's flash contents in BOOTLOADER, the signed image in slot A as the bootloader reads it (payload from
//! 0x0802_0000, header in the slot's last 128 bytes, `firmware::boot::image`), the update state region erased
//! (0xFF, the idle state of `firmware::boot::state`), and nothing else; and each bad input is refused by name,
//! without an output file.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::{Command, Output};

use firmware::boot::image::{HEADER_LEN, HEADER_OFFSET, MAX_PAYLOAD_LEN};
use firmware::boot::keys::DEV_PUBLIC_KEY;
use firmware::boot::verify::{verify_bytes, Trust};
use firmware::flash_map::{BOOTLOADER_END, BOOTLOADER_START, BOOT_STATE_LEN, BOOT_STATE_START, SLOT_A_START};

const DEV_KEY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../keys/dev-signing-key.secret");

fn tool() -> Command {
    Command::new(env!("CARGO_BIN_EXE_drive-image"))
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("drive-image-factory-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn path(p: &std::path::Path) -> &str {
    p.to_str().unwrap()
}

/// A minimal ELF32 LE executable with program headers `(type, paddr, data, memsz extra)`; the file size of each
/// segment is the length of `data`.
fn elf(segments: &[(u32, u32, Vec<u8>)]) -> Vec<u8> {
    let phoff = 52usize;
    let mut data_at = phoff + 32 * segments.len();
    let mut e = vec![0u8; data_at];
    e[..4].copy_from_slice(b"\x7fELF");
    e[4] = 1;
    e[5] = 1;
    e[28..32].copy_from_slice(&(phoff as u32).to_le_bytes());
    e[42..44].copy_from_slice(&32u16.to_le_bytes());
    e[44..46].copy_from_slice(&(segments.len() as u16).to_le_bytes());
    for (i, (t, paddr, d)) in segments.iter().enumerate() {
        let ph = phoff + 32 * i;
        e[ph..ph + 4].copy_from_slice(&t.to_le_bytes());
        e[ph + 4..ph + 8].copy_from_slice(&(data_at as u32).to_le_bytes());
        e[ph + 12..ph + 16].copy_from_slice(&paddr.to_le_bytes());
        e[ph + 16..ph + 20].copy_from_slice(&(d.len() as u32).to_le_bytes());
        data_at += d.len();
    }
    for (_, _, d) in segments {
        e.extend_from_slice(d);
    }
    e
}

fn pattern(len: usize, seed: u32) -> Vec<u8> {
    (0..len as u32).map(|i| (i.wrapping_mul(31).wrapping_add(seed)) as u8).collect()
}

/// A bootloader as the linker lays it out: vector table, text, `.data`'s load copy in flash (run address in
/// SRAM is not flash) and a `.bss` segment without file contents.
fn bootloader_elf(text_len: usize) -> (Vec<u8>, BTreeMap<u32, u8>) {
    let vectors = pattern(0x40, 1);
    let text = pattern(text_len, 2);
    let data_load = BOOTLOADER_START + 0x40 + text_len as u32;
    let data = pattern(0x38, 3);
    let segments = vec![
        (1, BOOTLOADER_START, vectors.clone()),
        (1, BOOTLOADER_START + 0x40, text.clone()),
        (1, data_load, data.clone()),
        (1, 0x2000_0038, Vec::new()),  // .bss: no file contents
        (1, 0x2000_1000, vec![9; 16]), // a segment loaded into SRAM: not flash, not in the HEX
        (0x6474_e551, 0, Vec::new()),  // GNU_STACK
    ];
    let mut expected = BTreeMap::new();
    for (at, bytes) in [(BOOTLOADER_START, &vectors), (BOOTLOADER_START + 0x40, &text), (data_load, &data)] {
        for (i, b) in bytes.iter().enumerate() {
            expected.insert(at + i as u32, *b);
        }
    }
    (elf(&segments), expected)
}

fn write(name: &str, bytes: &[u8]) -> PathBuf {
    let p = tmp(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// Reads an Intel HEX file with the `ihex` crate: every data byte by its 32-bit address.
fn read_hex(file: &std::path::Path) -> BTreeMap<u32, u8> {
    let text = std::fs::read_to_string(file).unwrap();
    let mut bytes = BTreeMap::new();
    let mut base = 0u32;
    let mut ended = false;
    for record in ihex::Reader::new(&text) {
        match record.unwrap() {
            ihex::Record::Data { offset, value } => {
                for (i, b) in value.iter().enumerate() {
                    let at = base + u32::from(offset) + i as u32;
                    assert!(bytes.insert(at, *b).is_none(), "byte at {at:#010x} written twice");
                }
            }
            ihex::Record::ExtendedLinearAddress(high) => base = u32::from(high) << 16,
            ihex::Record::EndOfFile => ended = true,
            other => panic!("unexpected record {other:?}"),
        }
    }
    assert!(ended, "no end-of-file record");
    bytes
}

fn ok(out: &Output) -> String {
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The refusal's message (stderr), after checking the command failed and wrote no file.
fn refused(out: &Output, hex: &std::path::Path) -> String {
    assert!(!out.status.success(), "not refused: {}", String::from_utf8_lossy(&out.stdout));
    assert!(!hex.exists(), "a refused factory image must not leave a file");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Splits the HEX contents into the three regions and checks nothing lies outside them.
fn regions(bytes: &BTreeMap<u32, u8>) -> (BTreeMap<u32, u8>, Vec<u8>, Vec<u8>, Vec<u8>) {
    let mut boot = BTreeMap::new();
    let mut state = Vec::new();
    let mut payload = Vec::new();
    let mut header = Vec::new();
    for (&at, &b) in bytes {
        if (BOOTLOADER_START..BOOTLOADER_END).contains(&at) {
            boot.insert(at, b);
        } else if (BOOT_STATE_START..BOOT_STATE_START + BOOT_STATE_LEN).contains(&at) {
            assert_eq!(at, BOOT_STATE_START + state.len() as u32, "update state region written without gaps");
            state.push(b);
        } else if (SLOT_A_START + HEADER_OFFSET..SLOT_A_START + HEADER_OFFSET + HEADER_LEN).contains(&at) {
            header.push(b);
        } else if (SLOT_A_START..SLOT_A_START + HEADER_OFFSET).contains(&at) {
            assert_eq!(at, SLOT_A_START + payload.len() as u32, "payload contiguous from the slot start");
            payload.push(b);
        } else {
            panic!("byte at {at:#010x} outside bootloader, update state and slot A");
        }
    }
    (boot, state, payload, header)
}

#[test]
fn factory_hex_holds_the_bootloader_the_signed_slot_a_and_an_erased_update_state_and_nothing_else() {
    let (boot_elf, boot_bytes) = bootloader_elf(0x1234);
    let boot = write("boot.elf", &boot_elf);
    let app_text = pattern(40_001, 5);
    let app = write("app.elf", &elf(&[(1, SLOT_A_START, app_text.clone()), (1, 0x2000_0000, vec![7; 8])]));
    let hex = tmp("factory.hex");
    let out = tool()
        .args(["factory", "--bootloader", path(&boot), "--elf", path(&app), "--key", DEV_KEY])
        .args(["--version", "1.2.3", "--out", path(&hex)])
        .output()
        .unwrap();
    let text = ok(&out);
    assert!(text.contains("application 1.2.3"), "{text}");

    let (in_boot, state, payload, header) = regions(&read_hex(&hex));
    assert_eq!(in_boot, boot_bytes, "the bootloader's flash contents exactly, SRAM segments left out");
    assert_eq!(state, vec![0xFF; BOOT_STATE_LEN as usize], "update state: all 64 KiB erased (idle)");
    let mut padded = app_text.clone();
    padded.resize(40_004, 0xFF);
    assert_eq!(payload, padded, "payload from 0x0802_0000, padded to 4 bytes");
    assert_eq!(header.len(), HEADER_LEN as usize, "the header in the slot's last 128 bytes");
    let image: Vec<u8> = header.iter().chain(payload.iter()).copied().collect();
    let trust = Trust {
        public_key: DEV_PUBLIC_KEY,
        hardware_id: firmware::boot::image::HARDWARE_ID,
        max_payload: MAX_PAYLOAD_LEN,
    };
    let verified = verify_bytes(&image, &trust).expect("slot A verifies with the bootloader's key");
    assert_eq!(verified.firmware_version, 0x0102_0003);
    assert_eq!(verified.payload_len, 40_004);
}

#[test]
fn factory_with_a_signed_image_puts_that_image_into_slot_a_unchanged() {
    let (boot_elf, _) = bootloader_elf(0x100);
    let boot = write("boot2.elf", &boot_elf);
    let bin = write("app2.bin", &pattern(1_000, 9));
    let img = tmp("app2.img");
    ok(&tool()
        .args(["pack", "--bin", path(&bin), "--key", DEV_KEY, "--version", "3.0.1", "--out", path(&img)])
        .output()
        .unwrap());
    let image = std::fs::read(&img).unwrap();
    let hex = tmp("factory2.hex");
    ok(&tool()
        .args(["factory", "--bootloader", path(&boot), "--image", path(&img), "--out", path(&hex)])
        .output()
        .unwrap());
    let (_, _, payload, header) = regions(&read_hex(&hex));
    assert_eq!(header, image[..128], "header as `pack` wrote it");
    assert_eq!(payload, image[128..], "payload as `pack` wrote it");
}

#[test]
fn factory_refuses_a_bootloader_larger_than_its_32_kib_region() {
    // 0x40 vectors + text + 0x38 data: one byte past 0x0800_8000.
    let (boot_elf, _) = bootloader_elf(0x8000 - 0x40 - 0x38 + 1);
    let boot = write("big-boot.elf", &boot_elf);
    let img = write("img-for-big-boot.img", b"unused");
    let hex = tmp("big-boot.hex");
    // A valid image, so that only the bootloader can be what is refused.
    let bin = write("small.bin", &[1, 2, 3, 4]);
    ok(&tool()
        .args(["pack", "--bin", path(&bin), "--key", DEV_KEY, "--version", "1.0.0", "--out", path(&img)])
        .output()
        .unwrap());
    let out = tool()
        .args(["factory", "--bootloader", path(&boot), "--image", path(&img), "--out", path(&hex)])
        .output()
        .unwrap();
    let err = refused(&out, &hex);
    assert!(err.contains("--bootloader") && err.contains("32769 bytes do not fit the bootloader's 32 KiB"), "{err}");

    // Exactly 32 KiB fits.
    let (boot_elf, _) = bootloader_elf(0x8000 - 0x40 - 0x38);
    let boot = write("full-boot.elf", &boot_elf);
    ok(&tool()
        .args(["factory", "--bootloader", path(&boot), "--image", path(&img), "--out", path(&hex)])
        .output()
        .unwrap());
}

#[test]
fn factory_refuses_an_application_larger_than_slot_a() {
    let (boot_elf, _) = bootloader_elf(0x100);
    let boot = write("boot3.elf", &boot_elf);
    let hex = tmp("big-app.hex");
    // The ELF route: one word more than slot A's payload area (384 KiB less the 128-byte header).
    let app = write("big-app.elf", &elf(&[(1, SLOT_A_START, vec![0x5A; MAX_PAYLOAD_LEN as usize + 4])]));
    let out = tool()
        .args(["factory", "--bootloader", path(&boot), "--elf", path(&app), "--key", DEV_KEY, "--version", "1.0.0"])
        .args(["--out", path(&hex)])
        .output()
        .unwrap();
    let err = refused(&out, &hex);
    assert!(err.contains("slot A"), "{err}");
    // The image route: a file longer than slot A is refused by its size before any check.
    let img = write("big-app.img", &vec![0u8; 128 + MAX_PAYLOAD_LEN as usize + 4]);
    let out = tool()
        .args(["factory", "--bootloader", path(&boot), "--image", path(&img), "--out", path(&hex)])
        .output()
        .unwrap();
    let err = refused(&out, &hex);
    assert!(err.contains("does not fit slot A"), "{err}");
}

#[test]
fn factory_refuses_an_image_whose_signature_does_not_verify() {
    let (boot_elf, _) = bootloader_elf(0x100);
    let boot = write("boot4.elf", &boot_elf);
    let bin = write("app4.bin", &pattern(2_000, 4));
    let img = tmp("app4.img");
    ok(&tool()
        .args(["pack", "--bin", path(&bin), "--key", DEV_KEY, "--version", "1.0.0", "--out", path(&img)])
        .output()
        .unwrap());
    let hex = tmp("forged.hex");
    // One signature bit flipped (header bytes 64..128): CRC intact, signature not.
    let mut forged = std::fs::read(&img).unwrap();
    forged[100] ^= 0x01;
    let forged_file = write("forged.img", &forged);
    let out = tool()
        .args(["factory", "--bootloader", path(&boot), "--image", path(&forged_file), "--out", path(&hex)])
        .output()
        .unwrap();
    let err = refused(&out, &hex);
    assert!(err.contains("BadSignature"), "{err}");
    // Signed with another key than the one the bootloader trusts: refused at packing time already.
    let other = tmp("other");
    ok(&tool().args(["keygen", "--out", path(&other)]).output().unwrap());
    let out = tool()
        .args(["factory", "--bootloader", path(&boot), "--elf"])
        .arg(write("app4.elf", &elf(&[(1, SLOT_A_START, pattern(64, 1))])))
        .args(["--key", &format!("{}.secret", other.display()), "--version", "1.0.0", "--out", path(&hex)])
        .output()
        .unwrap();
    let err = refused(&out, &hex);
    assert!(err.contains("BadSignature"), "{err}");
}

#[test]
fn factory_refuses_files_that_are_not_elf() {
    let (boot_elf, _) = bootloader_elf(0x100);
    let boot = write("boot5.elf", &boot_elf);
    let not_elf = write("not.elf", b"this is a text file, not an executable");
    let app = write("app5.elf", &elf(&[(1, SLOT_A_START, pattern(64, 1))]));
    let hex = tmp("not-elf.hex");
    let out = tool()
        .args(["factory", "--bootloader", path(&not_elf), "--elf", path(&app), "--key", DEV_KEY, "--version", "1.0.0"])
        .args(["--out", path(&hex)])
        .output()
        .unwrap();
    let err = refused(&out, &hex);
    assert!(err.contains("--bootloader") && err.contains("not an ELF file"), "{err}");
    let out = tool()
        .args(["factory", "--bootloader", path(&boot), "--elf", path(&not_elf), "--key", DEV_KEY, "--version", "1.0.0"])
        .args(["--out", path(&hex)])
        .output()
        .unwrap();
    let err = refused(&out, &hex);
    assert!(err.contains("--elf") && err.contains("not an ELF file"), "{err}");
}

/// clap names the bad option: an unknown one, and --elf without its signing key.
#[test]
fn factory_argument_errors_name_the_option() {
    let out = tool()
        .args(["factory", "--bootloader", "b", "--elf", "a", "--version", "1.0.0", "--out", "o"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--key"), "{}", String::from_utf8_lossy(&out.stderr));
    // A header field with an already signed image would be ignored: refused, naming the option.
    let out = tool()
        .args(["factory", "--bootloader", "b", "--image", "i", "--security-version", "3", "--out", "o"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("--security-version applies only with --elf"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = tool().args(["factory", "--bootlodaer", "b"]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--bootlodaer"), "{}", String::from_utf8_lossy(&out.stderr));
}

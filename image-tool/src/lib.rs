//! `drive-image`: packs a firmware (ELF or raw binary) into the signed image format of `firmware::boot::image`,
//! generates Ed25519 key pairs, and inspects images. The format, the signer and the verifier are the firmware's
//! own code, so the tool and the drive cannot disagree about the layout.
//!
//! Key files are text: the 32-byte Ed25519 secret seed (`*.secret`) or public key (`*.pub`) as 64 hex digits.

pub mod factory;

use std::fmt::Write as _;

use firmware::boot::image::{ImageHeader, HARDWARE_ID, HEADER_LEN, MAX_PAYLOAD_LEN, VERSION_STRING_LEN};
use firmware::boot::sign::{public_key, sign_image};
use firmware::boot::verify::{verify_bytes, Trust};
use firmware::flash_map::SLOT_A_START;

/// What goes into an image besides the payload.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PackOptions {
    /// Hardware / product id (`firmware::boot::image::HARDWARE_ID` for the reference drive).
    pub hardware_id: u32,
    /// Firmware version (major << 24 | minor << 16 | patch).
    pub firmware_version: u32,
    /// 0x1F56:01 value (bits 31..16 application id, bits 15..0 bootloader id).
    pub software_id: u32,
    /// Version string (at most 16 ASCII bytes).
    pub version_string: String,
    /// Security version (anti-rollback, `firmware::boot::image`): the drive refuses images below the one it last
    /// confirmed; raise it only for a release that must not be downgraded past.
    pub security_version: u32,
}

/// Parses 64 hex digits (surrounding white space allowed) into 32 bytes.
pub fn parse_key_hex(text: &str) -> Result<[u8; 32], String> {
    let t = text.trim();
    if t.len() != 64 || !t.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err("a key file holds exactly 64 hex digits".into());
    }
    let mut out = [0u8; 32];
    for (i, o) in out.iter_mut().enumerate() {
        *o = u8::from_str_radix(&t[2 * i..2 * i + 2], 16).map_err(|e| e.to_string())?;
    }
    Ok(out)
}

/// 32 bytes as 64 lower-case hex digits.
pub fn to_hex(bytes: &[u8]) -> String {
    bytes.iter().fold(String::new(), |mut s, b| {
        let _ = write!(s, "{b:02x}");
        s
    })
}

/// Parses a version: `MAJOR.MINOR.PATCH` (packed as major << 24 | minor << 16 | patch) or a number
/// (decimal or 0x hex).
pub fn parse_version(text: &str) -> Result<u32, String> {
    let parts: Vec<&str> = text.split('.').collect();
    if parts.len() == 3 {
        let major: u8 = parts[0].parse().map_err(|_| format!("bad major version in {text:?}"))?;
        let minor: u8 = parts[1].parse().map_err(|_| format!("bad minor version in {text:?}"))?;
        let patch: u16 = parts[2].parse().map_err(|_| format!("bad patch version in {text:?}"))?;
        return Ok(u32::from(major) << 24 | u32::from(minor) << 16 | u32::from(patch));
    }
    parse_u32(text)
}

/// Parses a decimal or `0x` hexadecimal u32.
pub fn parse_u32(text: &str) -> Result<u32, String> {
    let r = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(&hex.replace('_', ""), 16),
        None => text.replace('_', "").parse(),
    };
    r.map_err(|_| format!("not a number: {text:?}"))
}

/// The PT_LOAD segments with file contents of an ELF32 little-endian executable, in file order: each one's load
/// (physical) address and its bytes. Shared by [`elf_payload`] and the factory image's ELF reading.
pub fn elf_load_segments(elf: &[u8]) -> Result<Vec<(u32, &[u8])>, String> {
    let u16_at = |at: usize| elf.get(at..at + 2).map(|b| u16::from_le_bytes([b[0], b[1]]));
    let u32_at = |at: usize| elf.get(at..at + 4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
    if elf.get(..4) != Some(b"\x7fELF".as_slice()) {
        return Err("not an ELF file".into());
    }
    if elf.get(4) != Some(&1) || elf.get(5) != Some(&1) {
        return Err("only 32-bit little-endian ELF files (ARM Cortex-M) are supported".into());
    }
    let truncated = || "truncated ELF file".to_string();
    let phoff = u32_at(28).ok_or_else(truncated)? as usize;
    let phentsize = u16_at(42).ok_or_else(truncated)? as usize;
    let phnum = u16_at(44).ok_or_else(truncated)? as usize;
    let mut segments = Vec::new();
    for i in 0..phnum {
        let ph = phoff + i * phentsize;
        let (p_type, p_offset, p_paddr, p_filesz) = (
            u32_at(ph).ok_or_else(truncated)?,
            u32_at(ph + 4).ok_or_else(truncated)? as usize,
            u32_at(ph + 12).ok_or_else(truncated)?,
            u32_at(ph + 16).ok_or_else(truncated)? as usize,
        );
        if p_type != 1 || p_filesz == 0 {
            continue;
        }
        segments.push((p_paddr, elf.get(p_offset..p_offset + p_filesz).ok_or_else(truncated)?));
    }
    Ok(segments)
}

/// The bytes of slot A from an ELF32 little-endian executable: every PT_LOAD segment with file contents whose
/// load (physical) address lies in slot A, placed at its offset from the slot start; gaps are 0xFF (erased
/// flash), the result is padded with 0xFF to a multiple of 4. Segments entirely outside slot A (RAM, .bss)
/// are skipped; one that straddles its border is an error.
pub fn elf_payload(elf: &[u8]) -> Result<Vec<u8>, String> {
    let slot_end = u64::from(SLOT_A_START) + u64::from(MAX_PAYLOAD_LEN);
    let mut out: Vec<u8> = Vec::new();
    for (p_paddr, data) in elf_load_segments(elf)? {
        let p_filesz = data.len();
        let start = u64::from(p_paddr);
        let end = start + p_filesz as u64;
        if end <= u64::from(SLOT_A_START) || start >= slot_end {
            continue;
        }
        if start < u64::from(SLOT_A_START) || end > slot_end {
            return Err(format!(
                "segment at {p_paddr:#010x} ({p_filesz} bytes) crosses the border of slot A \
                 ({SLOT_A_START:#010x}..{slot_end:#010x})"
            ));
        }
        let at = (start - u64::from(SLOT_A_START)) as usize;
        if out.len() < at + data.len() {
            out.resize(at + data.len(), 0xFF);
        }
        out[at..at + data.len()].copy_from_slice(data);
    }
    if out.is_empty() {
        return Err(format!("no loadable segment in slot A ({SLOT_A_START:#010x})"));
    }
    Ok(pad4(out))
}

/// Pads `payload` with 0xFF to a multiple of 4 bytes (the flash program granularity).
pub fn pad4(mut payload: Vec<u8>) -> Vec<u8> {
    while !payload.len().is_multiple_of(4) {
        payload.push(0xFF);
    }
    payload
}

/// Packs and signs: the image bytes (header, then the payload padded to 4 bytes).
pub fn pack(payload: &[u8], seed: &[u8; 32], options: &PackOptions, noise: [u8; 16]) -> Result<Vec<u8>, String> {
    let payload = pad4(payload.to_vec());
    if payload.is_empty() {
        return Err("empty payload".into());
    }
    if payload.len() > MAX_PAYLOAD_LEN as usize {
        return Err(format!("payload of {} bytes exceeds slot A's {MAX_PAYLOAD_LEN}", payload.len()));
    }
    let vs = options.version_string.as_bytes();
    if vs.len() > VERSION_STRING_LEN || vs.contains(&0) {
        return Err(format!("version string longer than {VERSION_STRING_LEN} bytes or with NUL"));
    }
    let mut header = ImageHeader::new(options.hardware_id, options.firmware_version, options.software_id, 0, 0);
    header.version_string[..vs.len()].copy_from_slice(vs);
    header.security_version = options.security_version;
    sign_image(&mut header, &payload, seed, noise);
    let mut image = header.to_bytes().to_vec();
    image.extend_from_slice(&payload);
    Ok(image)
}

/// A description of an image (header fields and the verdict of the verification with `public_key`).
pub fn describe(image: &[u8], public_key: &[u8; 32], hardware_id: u32) -> String {
    let mut s = String::new();
    match ImageHeader::parse(image) {
        Err(e) => {
            let _ = writeln!(s, "header: {e:?}");
        }
        Ok(h) => {
            let _ = writeln!(s, "hardware id:      {:#010x}", h.hardware_id);
            let v = h.firmware_version;
            let _ = writeln!(s, "firmware version: {}.{}.{} ({v:#010x})", v >> 24, (v >> 16) & 0xFF, v & 0xFFFF);
            let _ = writeln!(s, "version string:   {}", String::from_utf8_lossy(h.version_str()));
            let _ = writeln!(s, "software id:      {:#010x} (0x1F56:01)", h.software_id);
            let _ = writeln!(s, "security version: {}", h.security_version);
            let _ = writeln!(s, "load address:     {:#010x}", h.load_address);
            let _ = writeln!(s, "payload:          {} bytes, CRC-32 {:#010x}", h.payload_len, h.payload_crc);
            let _ = writeln!(s, "image:            {} bytes (header {HEADER_LEN})", image.len());
        }
    }
    let trust = Trust { public_key: *public_key, hardware_id, max_payload: MAX_PAYLOAD_LEN };
    match verify_bytes(image, &trust) {
        Ok(_) => {
            let _ = writeln!(s, "verification:     OK (key {})", to_hex(public_key));
        }
        Err(e) => {
            let _ = writeln!(s, "verification:     FAILED: {e:?}");
        }
    }
    s
}

/// The trust anchor for images of the reference drive signed with `public_key`.
pub fn trust(public_key: [u8; 32]) -> Trust {
    Trust { public_key, hardware_id: HARDWARE_ID, max_payload: MAX_PAYLOAD_LEN }
}

/// The public key of a secret seed.
pub fn public_of(seed: &[u8; 32]) -> [u8; 32] {
    public_key(seed)
}

/// The Rust source of `firmware/src/boot/keys.rs` for `public_key`.
pub fn rust_key_file(public_key: &[u8; 32]) -> String {
    let mut bytes = String::new();
    for (i, b) in public_key.iter().enumerate() {
        if i % 16 == 0 {
            bytes.push_str("\n    ");
        } else {
            bytes.push(' ');
        }
        let _ = write!(bytes, "0x{b:02x},");
    }
    format!(
        "//! The public key images must be signed with, compiled into the bootloader and the application.\n\
//!\n\
//! Written by `drive-image keygen --rust firmware/src/boot/keys.rs` from `keys/dev-signing-key.pub`\n\
//! (a test checks that they match). This is the DEVELOPMENT key: its secret half is in the repository\n\
//! (`keys/dev-signing-key.secret`) so that tests can sign; a production build replaces this file with the\n\
//! public key of a key kept offline.\n\
\n\
/// Ed25519 public key of the development signing key (`keys/dev-signing-key.pub`).\n\
#[rustfmt::skip]\n\
pub const DEV_PUBLIC_KEY: [u8; 32] = [{bytes}\n];\n"
    )
}

/// 16 (or 32) random bytes from the operating system.
pub fn os_random<const N: usize>() -> Result<[u8; N], String> {
    use std::io::Read;
    let mut b = [0u8; N];
    std::fs::File::open("/dev/urandom")
        .and_then(|mut f| f.read_exact(&mut b))
        .map_err(|e| format!("/dev/urandom: {e}"))?;
    Ok(b)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A minimal ELF32 LE with program headers `(type, paddr, data)`.
    fn elf(segments: &[(u32, u32, &[u8])]) -> Vec<u8> {
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

    #[test]
    fn elf_segments_in_slot_a_are_placed_at_their_offsets_and_others_skipped() {
        let e = elf(&[
            (1, SLOT_A_START, &[1, 2, 3, 4, 5, 6, 7, 8]),
            (1, 0x2000_0000, &[9; 16]), // RAM (.data's run address as a segment of its own): skipped
            (1, SLOT_A_START + 12, &[0xAA, 0xBB]),
            (6, SLOT_A_START, &[0; 4]), // not PT_LOAD
        ]);
        let p = elf_payload(&e).unwrap();
        assert_eq!(p, vec![1, 2, 3, 4, 5, 6, 7, 8, 0xFF, 0xFF, 0xFF, 0xFF, 0xAA, 0xBB, 0xFF, 0xFF]);
        let straddling = elf(&[(1, SLOT_A_START - 4, &[0; 8])]);
        assert!(elf_payload(&straddling).unwrap_err().contains("crosses"));
        assert!(elf_payload(b"MZ..").is_err());
        assert!(elf_payload(&elf(&[(1, 0x2000_0000, &[1; 4])])).is_err(), "nothing in slot A");
    }

    #[test]
    fn versions_and_numbers_parse() {
        assert_eq!(parse_version("1.2.3"), Ok(0x0102_0003));
        assert_eq!(parse_version("0x01020003"), Ok(0x0102_0003));
        assert!(parse_version("1.2.x").is_err());
        assert_eq!(parse_u32("0x0F40_5001"), Ok(0x0F40_5001));
        assert_eq!(parse_key_hex(&to_hex(&[7u8; 32])), Ok([7u8; 32]));
        assert!(parse_key_hex("abc").is_err());
    }
}

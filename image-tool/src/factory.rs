//! The factory image (issue 22, item 3): one Intel HEX file with everything a new board needs, for
//! `probe-rs download --format hex` or any programmer:
//!
//! * the bootloader's loadable contents at their load addresses in BOOTLOADER (0x0800_0000, 32 KiB);
//! * a signed application image in slot A laid out as the bootloader reads it (`firmware::boot::image`, "Where
//!   the header lives in a slot"): the payload from 0x0802_0000, the 128-byte header in the slot's last 128 bytes
//!   (`HEADER_OFFSET`); the bytes between them are not in the file (erased flash);
//! * the update state region BOOT_STATE (0x0801_0000, 64 KiB) as erased flash, every byte 0xFF.
//!
//! Why an erased update state: `firmware::boot::state` reads an erased log as `BootState::Idle`, which means
//! "slot A holds the confirmed image, nothing pending, no swap in progress", exactly the state of a board
//! that was just programmed; there is no record to write for it (the bootloader itself erases the log only in
//! that state). The minimum security version of an empty log is slot A's own (`minimum_security_version`), so
//! the factory image needs no Floor record either. The region is written out as 0xFF rather than left out of
//! the file so that a programmer erases sector 4 and a board that ran before does not keep an old log (a pending
//! image, a trial, a Floor above the new image's security version) behind a freshly programmed slot A.
//!
//! The parameter store sectors (PARAMS_A/B) are left out on purpose: a board keeps its saved node-ID, bit rate
//! and tuning across a reflash; an erased store (a new board) makes the firmware use its defaults.

use firmware::boot::image::{ImageHeader, HEADER_LEN, HEADER_OFFSET, MAX_PAYLOAD_LEN};
use firmware::boot::verify::{verify_bytes, Trust};
use firmware::flash_map::SLOT_A_START;
use ihex::Record;

/// Start of the bootloader's region (`memory.x` BOOTLOADER; where the core fetches its stack pointer and
/// reset vector through the boot alias).
pub const BOOTLOADER_START: u32 = firmware::flash_map::BOOTLOADER_START;
/// End (exclusive) of the bootloader's region.
pub const BOOTLOADER_END: u32 = firmware::flash_map::BOOTLOADER_END;
/// Start of the update state region (`memory.x` BOOT_STATE).
pub const BOOT_STATE_START: u32 = firmware::flash_map::BOOT_STATE_START;
/// Length of the update state region: sector 4 of the F405, 64 KiB (RM0090 3.3; `memory.x`).
pub const BOOT_STATE_LEN: u32 = firmware::flash_map::BOOT_STATE_LEN;
/// Data bytes per HEX data record: 16, what most tools write and read.
const RECORD_DATA_LEN: usize = 16;
/// SRAM and everything above: run addresses of `.data`/`.bss`, never flash contents.
const RAM_START: u32 = 0x2000_0000;

/// One block of bytes at a flash address.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Block {
    /// Flash address of the first byte.
    pub address: u32,
    /// The bytes.
    pub data: Vec<u8>,
}

/// The loadable flash contents of an ELF32 little-endian executable: every PT_LOAD segment with file contents
/// at its load (physical) address, so `.data`'s initial values come at the place the start-up code copies them
/// from. Segments at SRAM addresses (load address at or above 0x2000_0000) hold no flash contents and are skipped.
pub fn elf_flash_blocks(elf: &[u8]) -> Result<Vec<Block>, String> {
    Ok(crate::elf_load_segments(elf)?
        .into_iter()
        .filter(|&(address, _)| address < RAM_START)
        .map(|(address, data)| Block { address, data: data.to_vec() })
        .collect())
}

/// The bootloader's flash contents from its ELF, refused unless all of it lies in BOOTLOADER (32 KiB) and it
/// starts at the boot address.
pub fn bootloader_blocks(elf: &[u8]) -> Result<Vec<Block>, String> {
    let blocks = elf_flash_blocks(elf)?;
    if blocks.is_empty() {
        return Err("no loadable contents in flash".into());
    }
    let region = u64::from(BOOTLOADER_START)..u64::from(BOOTLOADER_END);
    let end_of = |b: &Block| u64::from(b.address) + b.data.len() as u64;
    if let Some(outside) = blocks.iter().find(|b| !region.contains(&u64::from(b.address))) {
        return Err(format!(
            "contents at {:#010x}..{:#010x} lie outside the bootloader's 32 KiB region \
             {BOOTLOADER_START:#010x}..{BOOTLOADER_END:#010x} (not a bootloader ELF?)",
            outside.address,
            end_of(outside)
        ));
    }
    let end = blocks.iter().map(end_of).max().unwrap_or(region.start);
    if end > region.end {
        return Err(format!(
            "{} bytes do not fit the bootloader's 32 KiB region {BOOTLOADER_START:#010x}..{BOOTLOADER_END:#010x} \
             ({} bytes)",
            end - region.start,
            region.end - region.start
        ));
    }
    if !blocks.iter().any(|b| b.address == BOOTLOADER_START) {
        return Err(format!(
            "nothing at {BOOTLOADER_START:#010x}, where the core reads its stack pointer and reset vector"
        ));
    }
    Ok(blocks)
}

/// Checks a signed image (header, then payload) as `inspect` does: header, CRC-32 and Ed25519 signature with
/// the compiled-in trust anchor for `public_key`.
pub fn check_image(image: &[u8], public_key: &[u8; 32], hardware_id: u32) -> Result<ImageHeader, String> {
    let trust = Trust { public_key: *public_key, hardware_id, max_payload: MAX_PAYLOAD_LEN };
    if image.len() > HEADER_LEN as usize + MAX_PAYLOAD_LEN as usize {
        return Err(format!(
            "application image of {} bytes does not fit slot A ({} bytes of payload and the 128-byte header)",
            image.len(),
            MAX_PAYLOAD_LEN
        ));
    }
    verify_bytes(image, &trust).map_err(|e| format!("application image refused: verification FAILED: {e:?}"))
}

/// Slot A's blocks for a signed image: the payload at the slot start, the header at `HEADER_OFFSET`.
pub fn slot_a_blocks(image: &[u8]) -> Result<Vec<Block>, String> {
    let (header, payload) =
        image.split_at_checked(HEADER_LEN as usize).ok_or("application image shorter than its header")?;
    if payload.len() > MAX_PAYLOAD_LEN as usize {
        return Err(format!("application payload of {} bytes exceeds slot A's {MAX_PAYLOAD_LEN}", payload.len()));
    }
    Ok(vec![
        Block { address: SLOT_A_START, data: payload.to_vec() },
        Block { address: SLOT_A_START + HEADER_OFFSET, data: header.to_vec() },
    ])
}

/// The update state region, erased (module documentation: the idle state of a freshly programmed board).
pub fn erased_boot_state() -> Block {
    Block { address: BOOT_STATE_START, data: vec![0xFF; BOOT_STATE_LEN as usize] }
}

/// The whole factory image: bootloader, erased update state, slot A.
pub fn factory_blocks(bootloader_elf: &[u8], signed_image: &[u8]) -> Result<Vec<Block>, String> {
    let mut blocks = bootloader_blocks(bootloader_elf).map_err(|e| format!("bootloader: {e}"))?;
    blocks.push(erased_boot_state());
    blocks.extend(slot_a_blocks(signed_image)?);
    blocks.sort_by_key(|b| b.address);
    for pair in blocks.windows(2) {
        let end = u64::from(pair[0].address) + pair[0].data.len() as u64;
        if end > u64::from(pair[1].address) {
            return Err(format!("overlapping contents at {:#010x}", pair[1].address));
        }
    }
    Ok(blocks)
}

/// Intel HEX text of `blocks`: extended linear address records (type 04) at each 64 KiB boundary, data records
/// of at most 16 bytes that never cross one, the end-of-file record. Written by the `ihex` crate.
pub fn to_intel_hex(blocks: &[Block]) -> Result<String, String> {
    let mut records = Vec::new();
    let mut upper: Option<u16> = None;
    for block in blocks {
        let mut address = block.address;
        let mut rest = block.data.as_slice();
        while !rest.is_empty() {
            let high = (address >> 16) as u16;
            if upper != Some(high) {
                records.push(Record::ExtendedLinearAddress(high));
                upper = Some(high);
            }
            let to_boundary = 0x1_0000 - (address & 0xFFFF) as usize;
            let take = rest.len().min(RECORD_DATA_LEN).min(to_boundary);
            let (chunk, tail) = rest.split_at(take);
            records.push(Record::Data { offset: (address & 0xFFFF) as u16, value: chunk.to_vec() });
            address = address.checked_add(take as u32).ok_or("contents run past the 4 GiB address space")?;
            rest = tail;
        }
    }
    records.push(Record::EndOfFile);
    ihex::create_object_file_representation(&records).map_err(|e| format!("Intel HEX: {e}"))
}

/// Reads Intel HEX text back into bytes by address (data records with extended linear and segment addresses).
pub fn from_intel_hex(text: &str) -> Result<std::collections::BTreeMap<u32, u8>, String> {
    let mut bytes = std::collections::BTreeMap::new();
    let mut base = 0u32;
    for record in ihex::Reader::new(text) {
        match record.map_err(|e| format!("Intel HEX: {e}"))? {
            Record::Data { offset, value } => {
                for (i, b) in value.iter().enumerate() {
                    let at = base.wrapping_add(u32::from(offset)).wrapping_add(i as u32);
                    if bytes.insert(at, *b).is_some() {
                        return Err(format!("Intel HEX: byte at {at:#010x} given twice"));
                    }
                }
            }
            Record::ExtendedLinearAddress(high) => base = u32::from(high) << 16,
            Record::ExtendedSegmentAddress(segment) => base = u32::from(segment) << 4,
            Record::EndOfFile => break,
            Record::StartLinearAddress(_) | Record::StartSegmentAddress { .. } => {}
        }
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hex_records_split_at_64_kib_boundaries_and_read_back() {
        let blocks = vec![Block { address: 0x0800_FFF8, data: (0..40u8).collect() }];
        let text = to_intel_hex(&blocks).unwrap();
        assert!(text.contains(":020000040800F2"), "upper address 0x0800: {text}");
        assert!(text.contains(":020000040801F1"), "upper address 0x0801 after the boundary: {text}");
        let back = from_intel_hex(&text).unwrap();
        assert_eq!(back.len(), 40);
        assert_eq!(back.get(&0x0801_0000), Some(&8));
        assert!(text.ends_with(":00000001FF\n") || text.ends_with(":00000001FF"), "end-of-file record: {text}");
    }
}

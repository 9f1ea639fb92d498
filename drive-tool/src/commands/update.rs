//! `update IMAGE`: a signed firmware image into the drive; over EtherCAT by FoE (`update_foe`), over CANopen by
//! program control (IDX 0x1F50..0x1F57, the sequence
//! of the EPOS4 application notes; `firmware::boot::program`):
//!
//! 1. 0x1F51:01 = 0 (stop program; refused while the power stage is on) and = 3 (clear program);
//! 2. the image into 0x1F50:01 by SDO block download with its CRC (CiA 301 §7.2.4.3.9..16), a progress bar on a
//!    terminal; the drive checks the header, the payload CRC and the signature when the last byte is in, and a
//!    refusal is an SDO abort together with a 0x1F57:01 status, both shown;
//! 3. 0x1F51:01 = 1 (start): the drive restarts without answering, its bootloader swaps the new image in, and it
//!    boots; the tool waits for the boot-up and reads 0x1F56:01, 0x100A, 0x1F51:01 and 0x1F57:01 back.
//!
//! The running firmware is never touched by a download: after a refused image the tool starts the stopped
//! program again (0x1F51:01 = 1 without a verified image resumes it, no restart), and the drive runs as before.

use std::io::IsTerminal;
use std::path::Path;
use std::time::{Duration, Instant};

use firmware::boot::image::ImageHeader;
use firmware::boot::program::status_text;
use serde_json::json;

use crate::context::Context;
use crate::sdo::SdoError;

/// Program data (the image), program control, software identification, flash status (IDX L3300-3473).
const PROGRAM_DATA: u16 = 0x1F50;
const PROGRAM_CONTROL: u16 = 0x1F51;
const SOFTWARE_ID: u16 = 0x1F56;
const FLASH_STATUS: u16 = 0x1F57;
/// Manufacturer software version (CiA 301 §7.5.2.9).
const SOFTWARE_VERSION: u16 = 0x100A;
/// Program control commands (CiA 302-3 §4.1).
const STOP: u8 = 0;
const START: u8 = 1;
const CLEAR: u8 = 3;
/// Longest wait for the boot-up after the start: the bootloader verifies and swaps the image first.
pub const BOOT_UP_TIMEOUT: Duration = Duration::from_secs(30);

/// What the drive runs: 0x1F56:01 and 0x100A.
pub struct Running {
    /// 0x1F56:01.
    pub software_id: u32,
    /// 0x100A.
    pub version: String,
}

pub fn read_u32(cx: &mut Context, index: u16, sub: u8) -> Result<u32, String> {
    let node = cx.node;
    let bytes = cx.link.upload(node, index, sub).map_err(|e| format!("node {node} 0x{index:04X}:{sub:02X}: {e}"))?;
    let mut word = [0u8; 4];
    for (w, b) in word.iter_mut().zip(&bytes) {
        *w = *b;
    }
    Ok(u32::from_le_bytes(word))
}

pub fn running(cx: &mut Context) -> Result<Running, String> {
    let node = cx.node;
    let version =
        cx.link.upload(node, SOFTWARE_VERSION, 0).map_err(|e| format!("node {node} 0x100A (software version): {e}"))?;
    let version = String::from_utf8_lossy(&version).trim_end_matches('\0').to_owned();
    Ok(Running { software_id: read_u32(cx, SOFTWARE_ID, 1)?, version })
}

/// The flash status 0x1F57:01 as the drive explains it: code (bits 7..1) and text.
pub fn flash_status(cx: &mut Context) -> String {
    match read_u32(cx, FLASH_STATUS, 1) {
        Ok(word) => {
            let code = ((word >> 1) & 0x7F) as u8;
            let text = String::from_utf8_lossy(status_text(code)).into_owned();
            if code == 0 {
                "flash status 0 (no error)".into()
            } else {
                format!("flash status {code} ({text})")
            }
        }
        Err(e) => format!("flash status unreadable: {e}"),
    }
}

fn control(cx: &mut Context, command: u8, what: &str) -> Result<(), String> {
    let node = cx.node;
    cx.link.download(node, PROGRAM_CONTROL, 1, &[command]).map_err(|e| {
        let hint = match e {
            SdoError::Abort(0x0800_0022) if command == STOP => " (disable the drive's power stage first)",
            _ => "",
        };
        format!("node {node}: {what} (0x1F51:01 = {command}): {e}{hint}")
    })
}

/// The signed image in `path` and the version its header names; a file that is no image is refused before the
/// bus is touched.
pub fn read_image(path: &Path) -> Result<(Vec<u8>, String), String> {
    let image = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let header = ImageHeader::parse(&image)
        .map_err(|e| format!("{}: not a signed drive image ({e:?}); `drive-image pack` makes one", path.display()))?;
    let version = String::from_utf8_lossy(header.version_str()).into_owned();
    Ok((image, version))
}

/// A progress bar of `len` bytes on a terminal (none for `--json` or when stderr is not a terminal).
pub fn progress_bar(cx: &Context, len: usize) -> Option<indicatif::ProgressBar> {
    (!cx.json && std::io::stderr().is_terminal()).then(|| {
        let bar = indicatif::ProgressBar::new(len as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template("{bytes}/{total_bytes} {wide_bar} {bytes_per_sec} {eta}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar
    })
}

/// `update IMAGE [--no-start]`.
pub fn update(cx: &mut Context, path: &Path, start: bool) -> Result<(), String> {
    let (image, new_version) = read_image(path)?;
    #[cfg(target_os = "linux")]
    if cx.link.ecat().is_some() {
        if !start {
            return Err("--no-start: over EtherCAT the drive activates a verified image when it leaves BOOT; \
                        program control's separate start is CANopen's"
                .into());
        }
        return crate::commands::update_foe::update(cx, path, &image, &new_version);
    }
    let node = cx.node;
    let before = running(cx)?;
    control(cx, STOP, "stop program")?;
    control(cx, CLEAR, "clear program")?;

    let started = Instant::now();
    let bar = progress_bar(cx, image.len());
    let mut progress = |done: usize| {
        if let Some(bar) = &bar {
            bar.set_position(done as u64);
        }
    };
    let sent = cx.link.download_bulk(node, PROGRAM_DATA, 1, &image, &mut progress);
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    if let Err(e) = sent {
        let status = flash_status(cx);
        // The stopped program resumes: a start without a verified image takes the running one back (no reset).
        let resumed = match control(cx, START, "resume the running program") {
            Ok(()) => format!("it runs {} again", before.version),
            Err(why) => format!("and it could not resume: {why}"),
        };
        return Err(format!("node {node} refused the image {}: {e}; {status}; {resumed}", path.display()));
    }
    let download_s = started.elapsed().as_secs_f64();
    if !start {
        if cx.json {
            cx.print_json(&json!({
                "node": node, "image_bytes": image.len(), "download_s": download_s, "started": false,
                "version_before": before.version, "image_version": new_version,
            }));
        } else {
            say!(
                "node {node}: {} bytes of {new_version} in {download_s:.1} s, not started (0x1F51:01 = 1 starts it)",
                image.len()
            );
        }
        return Ok(());
    }
    // The drive restarts at once and does not answer the start (IDX: "the device resets"): a timeout is the
    // expected outcome, an abort is a refusal. Its boot-up may come while the tool still waits for that answer.
    cx.link.expect_boot_up(node);
    match cx.link.download(node, PROGRAM_CONTROL, 1, &[START]) {
        Ok(()) | Err(SdoError::Timeout) => {}
        Err(e) => {
            let status = flash_status(cx);
            return Err(format!("node {node}: start program (0x1F51:01 = 1): {e}; {status}"));
        }
    }
    if !cx.link.wait_boot_up(node, BOOT_UP_TIMEOUT)? {
        return Err(format!("node {node}: no boot-up within {BOOT_UP_TIMEOUT:?} after the start"));
    }
    let after = running(cx)?;
    let program_state = read_u32(cx, PROGRAM_CONTROL, 1)? & 0xFF;
    let status = flash_status(cx);
    let total_s = started.elapsed().as_secs_f64();
    if cx.json {
        cx.print_json(&json!({
            "node": node, "image_bytes": image.len(), "download_s": download_s, "total_s": total_s, "started": true,
            "version_before": before.version, "version_after": after.version, "image_version": new_version,
            "software_id_before": before.software_id, "software_id_after": after.software_id,
            "program_state": program_state, "flash_status": status,
        }));
    } else {
        say!("node {node}: {} bytes in {download_s:.1} s; restarted; runs {} (was {}); 0x1F56:01 0x{:08X} (was 0x{:08X}); {status}",
            image.len(), after.version, before.version, after.software_id, before.software_id);
    }
    if after.version != new_version {
        return Err(format!("node {node} runs {} after the update, not the image's {new_version}", after.version));
    }
    Ok(())
}

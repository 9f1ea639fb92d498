//! `update IMAGE --ecat IFACE`: a signed firmware image by FoE in BOOT, the sequence of the seeds (E4 Table 4-29
//! L2095-2130; `firmware::ecat::foe`, `firmware::boot::program`):
//!
//! 1. the running firmware's 0x1F56:01 and 0x100A over CoE (PRE-OP);
//! 2. INIT, the SII's bootstrap mailbox into SM0/SM1 (where it differs from the standard one), BOOT;
//! 3. FoE write of the file `firmware::boot::program::FOE_FILE_NAME` with password `FOE_PASSWORD`, a progress
//!    bar on a terminal; the drive checks header, CRC and signature when the last packet is in and refuses a bad
//!    image with an FoE error whose text is its 0x1F57 status (93 "signature invalid" and 94 share 0x8009);
//! 4. INIT: a verified image is activated, the drive restarts; the tool finds it again (PRE-OP) and reads
//!    0x1F56:01, 0x100A, 0x1F51:01 and 0x1F57:01 back.
//!
//! After a refusal the drive's old application runs on: the tool takes it back to PRE-OP and says what it runs.

use std::path::Path;
use std::time::Instant;

use firmware::boot::program::{FOE_FILE_NAME, FOE_PASSWORD};
use serde_json::json;

use crate::commands::update::{flash_status, progress_bar, read_u32, running, BOOT_UP_TIMEOUT};
use crate::context::Context;

/// Program control (CiA 302-3 §4.1): 1 = the program runs.
const PROGRAM_CONTROL: u16 = 0x1F51;

/// The FoE update of `image` (version `new_version`, from `path`) on the drive `cx.node`.
pub fn update(cx: &mut Context, path: &Path, image: &[u8], new_version: &str) -> Result<(), String> {
    let node = cx.node;
    let before = running(cx)?;
    let started = Instant::now();
    let bar = progress_bar(cx, image.len());
    let mut progress = |done: usize| {
        if let Some(bar) = &bar {
            bar.set_position(done as u64);
        }
    };
    let ecat = cx.link.ecat().ok_or("FoE needs --ecat")?;
    let written = ecat.foe_update(node, FOE_FILE_NAME, FOE_PASSWORD, image, BOOT_UP_TIMEOUT, &mut progress);
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    if let Err(e) = written {
        let now = match running(cx) {
            Ok(r) => format!("it runs {} (0x1F56:01 0x{:08X})", r.version, r.software_id),
            Err(why) => format!("its firmware does not answer: {why}"),
        };
        let status = flash_status(cx);
        return Err(format!("drive {node} refused the image {}: {e}; {status}; {now}", path.display()));
    }
    let total_s = started.elapsed().as_secs_f64();
    let after = running(cx)?;
    let program_state = read_u32(cx, PROGRAM_CONTROL, 1)? & 0xFF;
    let status = flash_status(cx);
    if cx.json {
        cx.print_json(&json!({
            "node": node, "image_bytes": image.len(), "total_s": total_s, "started": true, "method": "FoE",
            "version_before": before.version, "version_after": after.version, "image_version": new_version,
            "software_id_before": before.software_id, "software_id_after": after.software_id,
            "program_state": program_state, "flash_status": status,
        }));
    } else {
        say!(
            "drive {node}: {} bytes by FoE in {total_s:.1} s; restarted; runs {} (was {}); 0x1F56:01 0x{:08X} (was \
             0x{:08X}); {status}",
            image.len(),
            after.version,
            before.version,
            after.software_id,
            before.software_id
        );
    }
    if after.version != new_version {
        return Err(format!("drive {node} runs {} after the update, not the image's {new_version}", after.version));
    }
    Ok(())
}

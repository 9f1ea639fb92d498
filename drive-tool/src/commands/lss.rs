//! `lss assign --from N`: node-IDs for drives that have none (CiA 305 layer setting services; the drive's LSS
//! slave is `firmware::canopen::lss`). The LSS fastscan (§6.7) finds one unconfigured drive at a time by its
//! identity (vendor, product, revision, serial: 128 bits, one bit per probe) and leaves it in the configuration
//! state; the tool gives it the next node-ID (§6.3 configure node-ID), stores it (§6.3 store configuration) and
//! switches it back to waiting, after which the drive boots with its node-ID. It goes on until no unconfigured
//! drive answers.

use std::time::Duration;

use serde_json::json;

use crate::context::Context;

/// CiA 305 command specifiers.
const SWITCH_GLOBAL: u8 = 0x04;
const CONFIGURE_NODE_ID: u8 = 0x11;
const STORE: u8 = 0x17;
const IDENTIFY_NON_CONFIGURED: u8 = 0x4C;
const FASTSCAN: u8 = 0x51;
/// The fastscan's "bit checked" of a new scan.
const NEW_SCAN: u8 = 0x80;
/// How long a drive takes to boot after the switch to waiting.
const BOOT_UP_TIMEOUT: Duration = Duration::from_secs(5);

fn frame(cs: u8, rest: &[u8]) -> [u8; 8] {
    let mut f = [0u8; 8];
    f[0] = cs;
    for (o, r) in f.iter_mut().skip(1).zip(rest) {
        *o = *r;
    }
    f
}

/// One fastscan probe: whether a slave's identity part `part` agrees with `id` from bit `bit` up.
fn probe(cx: &mut Context, wait: Duration, id: u32, bit: u8, part: u8, next: u8) -> Result<bool, String> {
    let mut f = frame(FASTSCAN, &id.to_le_bytes());
    (f[5], f[6], f[7]) = (bit, part, next);
    Ok(!cx.link.lss(f, wait)?.is_empty())
}

/// The fastscan (CiA 305 §6.7): the identity of one unconfigured drive, now in the configuration state.
fn fastscan(cx: &mut Context, wait: Duration) -> Result<Option<[u32; 4]>, String> {
    if !probe(cx, wait, 0, NEW_SCAN, 0, 0)? {
        return Ok(None);
    }
    let mut id = [0u32; 4];
    for part in 0..4u8 {
        let value = &mut id[usize::from(part)];
        for bit in (0..32u8).rev() {
            if !probe(cx, wait, *value, bit, part, part)? {
                *value |= 1 << bit;
            }
        }
        let confirmed = probe(cx, wait, *value, 0, part, (part + 1) & 3)?;
        if !confirmed {
            return Err(format!("LSS fastscan lost its drive at identity part {part} (two drives with one identity?)"));
        }
    }
    Ok(Some(id))
}

/// The error byte of a configure or store answer, as CiA 305 §6.3 defines it.
fn check(answer: &[[u8; 8]], cs: u8, what: &str) -> Result<(), String> {
    match answer.first() {
        Some(a) if a[0] == cs && a[1] == 0 => Ok(()),
        Some(a) if a[0] == cs => Err(format!("{what}: the drive answered error {} (specific {})", a[1], a[2])),
        Some(a) => Err(format!("{what}: unexpected LSS answer {a:02X?}")),
        None => Err(format!("{what}: no LSS answer")),
    }
}

/// `lss assign --from FIRST [--count N] [--no-store]`.
pub fn assign(cx: &mut Context, first: u8, count: Option<u8>, store: bool, wait: Duration) -> Result<(), String> {
    let mut assigned = Vec::new();
    let mut next_id = first;
    while count.is_none_or(|n| assigned.len() < usize::from(n)) {
        if !(1..=127).contains(&next_id) {
            return Err(format!("node-ID {next_id} is outside 1..127; {} drives assigned", assigned.len()));
        }
        let Some(identity) = fastscan(cx, wait)? else { break };
        let answer = cx.link.lss(frame(CONFIGURE_NODE_ID, &[next_id]), wait)?;
        check(&answer, CONFIGURE_NODE_ID, &format!("configure node-ID {next_id}"))?;
        if store {
            check(&cx.link.lss(frame(STORE, &[]), wait)?, STORE, "store configuration")?;
        }
        cx.link.expect_boot_up(next_id);
        cx.link.lss(frame(SWITCH_GLOBAL, &[0]), Duration::ZERO)?;
        let booted = cx.link.wait_boot_up(next_id, BOOT_UP_TIMEOUT)?;
        if !cx.json {
            say!(
                "node-ID {next_id}: vendor 0x{:08X} product 0x{:08X} revision 0x{:08X} serial 0x{:08X}{}{}",
                identity[0],
                identity[1],
                identity[2],
                identity[3],
                if store { ", stored" } else { "" },
                if booted { ", booted" } else { ", no boot-up yet" }
            );
        }
        assigned.push(json!({
            "node": next_id, "vendor_id": identity[0], "product_code": identity[1], "revision": identity[2],
            "serial": identity[3], "stored": store, "booted": booted,
        }));
        next_id = next_id.saturating_add(1);
    }
    let unconfigured_left = !cx.link.lss(frame(IDENTIFY_NON_CONFIGURED, &[]), wait)?.is_empty();
    if cx.json {
        cx.print_json(&json!({ "assigned": assigned, "unconfigured_left": unconfigured_left }));
    } else {
        say!(
            "{} drive(s) assigned; {}",
            assigned.len(),
            if unconfigured_left { "unconfigured drives remain" } else { "no unconfigured drive answers" }
        );
    }
    Ok(())
}

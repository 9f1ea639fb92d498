//! Issue 7, power cuts: the supply fails during every single flash write of a download and its activation
//! (application side), of the activation swap and of the boot steps (bootloader side), of a revert, and of the
//! confirmation. The three regions share one supply, as on the chip. Each write is torn as `SimFlash` chooses
//! from the seed (not done, some bits done, done but unacknowledged). After every cut the next boot must start a
//! valid, signed image, old or new (the bootloader verifies header, CRC and signature before it says `Run`,
//! and the test compares slot A byte for byte with the two images); an interrupted activation must resume
//! (new image on trial), an interrupted revert must complete (old image), and the old image must still be
//! intact after an interrupted activation (shown by reverting to it).
//!
//! Images: old 150 KiB payload (two sectors), new 140 KiB; bootloader buffer 4 KiB. The counts of cut points
//! are printed (`--nocapture`) and asserted to be the whole write sequence.

use crate::support::*;
use firmware::boot::loader::{boot, BootEvent, Outcome};
use firmware::boot::swap::BootError;
use firmware::boot::update::confirm;
use firmware::hal::flash::FlashError;
use hal_sim::flash::SimFlash;

const OLD: u32 = 0x0100_0000;
const NEW: u32 = 0x0200_0000;

fn old_image() -> Vec<u8> {
    image(150 * 1024, OLD)
}

fn new_image() -> Vec<u8> {
    image(140 * 1024, NEW)
}

type Regions = firmware::boot::swap::BootFlash<SimFlash, SimFlash, SimFlash>;

fn try_boot(board: &mut Board) -> Result<Outcome, BootError> {
    let mut buf = vec![0u8; BUF_LEN];
    boot(board, &trust(), &mut buf)
}

/// Boots without a cut; checks a valid image runs and slot A holds exactly the old or the new image.
fn boot_checked(board: &mut Board, what: &str) -> (u32, bool, BootEvent) {
    let o = try_boot(board).unwrap_or_else(|e| panic!("{what}: boot failed without a cut: {e:?}"));
    let Outcome::Run { header, trial, event } = o else { panic!("{what}: no valid image: {o:?}") };
    let a = slot_image(board.slot_a.flash.contents());
    let expected = if header.firmware_version == NEW { new_image() } else { old_image() };
    assert!(header.firmware_version == NEW || header.firmware_version == OLD, "{what}: {header:?}");
    assert!(a == expected, "{what}: slot A does not hold the image its header names");
    (header.firmware_version, trial, event)
}

fn factory() -> Regions {
    let mut r = regions();
    factory_install(&mut r.slot_a, &old_image());
    r
}

#[test]
fn power_cut_after_every_write_of_a_download_and_its_activation() {
    let base = factory();
    let new = new_image();
    let clean = {
        let mut b = on_supply(&base);
        download(&mut b.slot_b, &mut b.state, &new, 1000).unwrap();
        writes(&b)
    };
    let (mut old_runs, mut new_runs) = (0, 0);
    for k in 0..clean {
        let mut b = on_supply(&base);
        cut_at(&b, k, 0xD0D0 + k);
        let r = download(&mut b.slot_b, &mut b.state, &new, 1000);
        assert!(r.is_err(), "cut {k}: the download did not notice the power loss");
        power_on(&mut b);
        match boot_checked(&mut b, &format!("download cut {k}")) {
            (OLD, false, BootEvent::Normal) => old_runs += 1,
            // A cut during the last write (the Pending record) that completed it: the activation happens.
            (NEW, true, BootEvent::Activated) => new_runs += 1,
            other => panic!("download cut {k}: {other:?}"),
        }
        if k % 64 == 0 && k + 1 < clean {
            // The interrupted download is no obstacle: the next one goes through.
            download(&mut b.slot_b, &mut b.state, &new, 1000).unwrap();
            assert_eq!(boot_checked(&mut b, "retry"), (NEW, true, BootEvent::Activated));
        }
    }
    eprintln!("download + activate: {clean} cut points, old image ran {old_runs}x, new {new_runs}x");
    // 3 sector erases, the header, 140 KiB / 256-byte stage = 560 programs, the Pending record.
    assert_eq!(clean, 3 + 1 + 560 + 1, "the cut points must cover the whole download");
    assert!(old_runs > 0);
}

/// Old image in slot A, the new one downloaded and pending.
fn pending() -> Regions {
    let mut b = on_supply(&factory());
    download(&mut b.slot_b, &mut b.state, &new_image(), 4096).unwrap();
    snapshot(&b)
}

#[test]
fn power_cut_after_every_write_of_the_activation_swap_resumes_it_and_the_old_image_survives() {
    let base = pending();
    let clean = {
        let mut b = on_supply(&base);
        assert_eq!(boot_checked(&mut b, "clean"), (NEW, true, BootEvent::Activated));
        writes(&b)
    };
    let mut double_cuts = 0;
    for k in 0..clean {
        let mut b = on_supply(&base);
        cut_at(&b, k, 0xB007 + k);
        assert_eq!(try_boot(&mut b), Err(BootError::Flash(FlashError::PowerLoss)), "cut {k}");
        power_on(&mut b);
        let after_first_cut = snapshot(&b);
        assert_eq!(boot_checked(&mut b, &format!("swap cut {k}")), (NEW, true, BootEvent::Activated));
        // No confirmation: the next reset goes back to the old image, which must have survived intact.
        assert_eq!(boot_checked(&mut b, &format!("swap cut {k}, revert")), (OLD, false, BootEvent::Reverted));

        // A second cut during the resumed swap.
        let resumed = writes(&b);
        let mut b2 = on_supply(&after_first_cut);
        let second = (k * 7919 + 13) % resumed.max(1);
        cut_at(&b2, second, 0x5EC0 + k);
        if try_boot(&mut b2).is_err() {
            double_cuts += 1;
            power_on(&mut b2);
            assert_eq!(boot_checked(&mut b2, &format!("swap cuts {k}+{second}")), (NEW, true, BootEvent::Activated));
        }
    }
    eprintln!("activation swap + boot steps: {clean} cut points, {double_cuts} with a second cut while resuming");
    // Per sector 3 erases + 3 records + the non-erased 4 KiB chunks of A, B and S: sector 0 is full (3 x 32),
    // sector 1 holds 22 KiB old (6 chunks) / 12 KiB new (3), sector 2 only the headers (1 each); then Trial.
    assert_eq!(clean, (6 + 96) + (6 + 6 + 3 + 6) + (6 + 3) + 1, "the cut points must cover the whole swap");
}

/// The new image on trial (activated, not confirmed).
fn trial() -> Regions {
    let mut b = on_supply(&pending());
    assert_eq!(boot_checked(&mut b, "activate"), (NEW, true, BootEvent::Activated));
    snapshot(&b)
}

#[test]
fn power_cut_after_every_write_of_a_revert_completes_it() {
    let base = trial();
    let clean = {
        let mut b = on_supply(&base);
        assert_eq!(boot_checked(&mut b, "clean revert"), (OLD, false, BootEvent::Reverted));
        writes(&b)
    };
    for k in 0..clean {
        let mut b = on_supply(&base);
        cut_at(&b, k, 0x4E5E + k);
        assert!(try_boot(&mut b).is_err(), "cut {k}");
        power_on(&mut b);
        assert_eq!(boot_checked(&mut b, &format!("revert cut {k}")), (OLD, false, BootEvent::Reverted));
        assert_eq!(boot_checked(&mut b, &format!("revert cut {k}, next")), (OLD, false, BootEvent::Normal));
    }
    eprintln!("revert: {clean} cut points");
    // As the activation swap, with A and B exchanged in sector 1 (3 + 6 + 3 chunks), then Reverted.
    assert_eq!(clean, (6 + 96) + (6 + 3 + 6 + 3) + (6 + 3) + 1);
}

#[test]
fn power_cut_during_the_confirmation_keeps_the_new_or_reverts_to_the_old_image() {
    let base = trial();
    let (mut kept, mut reverted) = (0, 0);
    for seed in 0..24u64 {
        let mut b = on_supply(&base);
        cut_at(&b, 0, seed);
        assert!(confirm(&mut b.state, 0).is_err());
        power_on(&mut b);
        match boot_checked(&mut b, &format!("confirm cut, seed {seed}")) {
            (NEW, false, BootEvent::Normal) => kept += 1,
            (OLD, false, BootEvent::Reverted) => reverted += 1,
            other => panic!("confirm cut, seed {seed}: {other:?}"),
        }
    }
    eprintln!("confirmation: 24 cuts, the record survived {kept}x, was lost {reverted}x");
    assert!(kept > 0 && reverted > 0, "both tears (record written or not) must occur over 24 seeds");
}

#[test]
fn power_cut_while_the_full_state_log_is_compacted_loses_nothing() {
    use firmware::boot::state::{Record, RecordKind, RECORD_LEN};
    // A log with 10 free slots left, all records saying "idle" (withdrawn downloads): the activation must erase
    // the sector first (allowed: an erased log also means idle).
    let mut base = factory();
    let cap = (STATE_SECTOR / RECORD_LEN) as usize;
    let rec = Record::new(RecordKind::Cancelled, 0).to_bytes();
    for slot in base.state.contents_mut().chunks_mut(RECORD_LEN as usize).take(cap - 10) {
        slot.copy_from_slice(&rec);
    }
    let new = new_image();
    let clean = {
        let mut b = on_supply(&base);
        download(&mut b.slot_b, &mut b.state, &new, 4096).unwrap();
        writes(&b)
    };
    // The last two writes: the erase of the state sector, the Pending record.
    let mut cuts = 0;
    for k in [clean - 2, clean - 1] {
        for seed in 0..12u64 {
            let mut b = on_supply(&base);
            cut_at(&b, k, seed * 31 + k);
            assert!(download(&mut b.slot_b, &mut b.state, &new, 4096).is_err());
            power_on(&mut b);
            cuts += 1;
            match boot_checked(&mut b, &format!("compaction cut {k}/{seed}")) {
                (OLD, false, BootEvent::Normal) => {
                    // Whatever the erase left (old records, garbage, nothing): the next update goes through.
                    download(&mut b.slot_b, &mut b.state, &new, 4096).unwrap();
                    assert_eq!(boot_checked(&mut b, "after compaction cut"), (NEW, true, BootEvent::Activated));
                }
                (NEW, true, BootEvent::Activated) => {}
                other => panic!("compaction cut {k}/{seed}: {other:?}"),
            }
        }
    }
    eprintln!("state-log compaction: {cuts} cuts");
}

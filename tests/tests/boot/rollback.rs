//! Issue 19 item 7, anti-rollback on the simulated flash: the security version in the signed header against the
//! minimum in the update state (`boot::state`, "The minimum security version"). An equal security version is
//! accepted, an older one refused with `ImageError::Rollback` (program control's 0x1F57 status 94, SDO abort
//! 0x0609_0032, FoE 0x8009: `tests/tests/boot_program_control.rs`, `tests/tests/boot_foe.rs`); the minimum rises
//! when an image confirms itself, not at its download or activation, so a trial that reverts leaves the previous
//! image loadable; the bootloader refuses to activate a pending image below the log's minimum; and the minimum
//! survives the compaction of the log and a power cut at every write of the compaction and of the confirmation.

use crate::support::*;
use firmware::boot::image::ImageError;
use firmware::boot::loader::{boot, BootEvent, Outcome};
use firmware::boot::state::{self, minimum_security_version, scan, BootState, Record, RecordKind, RECORD_LEN};
use firmware::boot::update::{confirm, Phase, UpdateError};
use hal_sim::flash::SimFlash;

const OLD: u32 = 0x0100_0000;
const NEW: u32 = 0x0200_0000;
const NEWER: u32 = 0x0300_0000;

type Regions = firmware::boot::swap::BootFlash<SimFlash, SimFlash, SimFlash>;

fn run(board: &mut Board) -> (u32, bool, BootEvent) {
    let mut buf = vec![0u8; BUF_LEN];
    match boot(board, &trust(), &mut buf).expect("boot without power cut") {
        Outcome::Run { header, trial, event } => (header.firmware_version, trial, event),
        o => panic!("no valid image: {o:?}"),
    }
}

/// Slot A with the firmware `OLD` at security version `security`, nothing in the log.
fn factory(security: u32) -> Regions {
    let mut r = regions();
    factory_install(&mut r.slot_a, &image_with_security(64 * 1024, OLD, security));
    r
}

/// The download program control makes: with slot A's security version.
fn update(board: &mut Board, image: &[u8]) -> Result<u32, UpdateError> {
    let a = slot_a_security_version(&mut board.slot_a, &mut board.state);
    download_over(a, &mut board.slot_b, &mut board.state, image, 4096).map(|h| h.security_version)
}

/// The minimum in force as program control computes it (`state::minimum_security_version`).
fn minimum(board: &mut Board) -> u32 {
    let a = slot_a_security_version(&mut board.slot_a, &mut board.state);
    minimum_security_version(&scan(&mut board.state).unwrap(), a)
}

/// The header of an older image is refused as soon as it is complete (Rollback with both versions), nothing is
/// recorded and the running image stays; an image at the same security version goes through.
#[test]
fn an_older_security_version_is_refused_and_an_equal_one_accepted() {
    let mut board = on_supply(&factory(2));
    assert_eq!(minimum(&mut board), 2, "the confirmed image in slot A sets the minimum without any record");
    assert_eq!(
        update(&mut board, &image_with_security(32 * 1024, NEW, 1)),
        Err(UpdateError::Image(ImageError::Rollback { minimum: 2, found: 1 }))
    );
    assert_eq!(scan(&mut board.state).unwrap().state, BootState::Idle, "no Pending record");
    assert_eq!(run(&mut board), (OLD, false, BootEvent::Normal));
    // Refused at the header: the first 4096-byte write (which completes the header) is the one refused.
    let mut d = firmware::boot::update::Download::new();
    d.clear(&mut board.slot_b, &mut board.state, Some(2)).unwrap();
    let old = image_with_security(32 * 1024, NEW, 1);
    assert_eq!(
        d.write(&mut board.slot_b, 0, &old[..4096], &trust()),
        Err(UpdateError::Image(ImageError::Rollback { minimum: 2, found: 1 }))
    );
    assert_eq!(d.phase(), Phase::Failed(ImageError::Rollback { minimum: 2, found: 1 }));

    assert_eq!(update(&mut board, &image_with_security(32 * 1024, NEW, 2)), Ok(2), "equal security version");
    assert_eq!(run(&mut board), (NEW, true, BootEvent::Activated));
}

/// The minimum rises only with the confirmation: a trial of a newer image that reverts leaves it at the old
/// image's security version (the old image may be loaded again); once the newer image confirms itself, the
/// minimum is its security version and the older image is refused.
#[test]
fn the_minimum_rises_only_when_an_image_confirms_itself() {
    let mut board = on_supply(&factory(1));
    assert_eq!(update(&mut board, &image_with_security(32 * 1024, NEW, 3)), Ok(3));
    assert_eq!(
        scan(&mut board.state).unwrap().floor,
        1,
        "the activation records the minimum in force, not the new one"
    );
    assert_eq!(run(&mut board), (NEW, true, BootEvent::Activated));
    assert_eq!(minimum(&mut board), 1, "on trial: not raised");
    assert_eq!(run(&mut board), (OLD, false, BootEvent::Reverted), "no confirmation");
    assert_eq!(minimum(&mut board), 1, "after the revert: not raised");
    // The reverted-to image's security version is still accepted (the same image again, as a download).
    assert_eq!(update(&mut board, &image_with_security(32 * 1024, OLD + 1, 1)), Ok(1));
    assert_eq!(run(&mut board), (OLD + 1, true, BootEvent::Activated));
    assert_eq!(run(&mut board), (OLD, false, BootEvent::Reverted));

    assert_eq!(update(&mut board, &image_with_security(32 * 1024, NEW, 3)), Ok(3));
    assert_eq!(run(&mut board), (NEW, true, BootEvent::Activated));
    assert_eq!(confirm(&mut board.state, 3), Ok(true));
    let s = scan(&mut board.state).unwrap();
    assert_eq!((s.state, s.floor), (BootState::Idle, 3), "Confirmed, then Floor(3)");
    assert_eq!(
        update(&mut board, &image_with_security(32 * 1024, OLD, 1)),
        Err(UpdateError::Image(ImageError::Rollback { minimum: 3, found: 1 }))
    );
    assert_eq!(
        update(&mut board, &image_with_security(32 * 1024, NEWER, 2)),
        Err(UpdateError::Image(ImageError::Rollback { minimum: 3, found: 2 }))
    );
    assert_eq!(update(&mut board, &image_with_security(32 * 1024, NEWER, 3)), Ok(3));
    assert_eq!(run(&mut board), (NEWER, true, BootEvent::Activated));
}

/// Defence in depth: a Pending record for an image below the log's minimum (written by anything but a download
/// that passed the check) does not activate it; the bootloader records Rejected and starts slot A.
#[test]
fn the_bootloader_refuses_to_activate_a_pending_image_below_the_minimum() {
    let mut r = factory(5);
    let older = image_with_security(32 * 1024, NEW, 4);
    factory_install(&mut r.slot_b, &older);
    let mut board = on_supply(&r);
    state::append(&mut board.state, Record::floor(5)).unwrap();
    state::append(&mut board.state, Record::new(RecordKind::Pending, 0)).unwrap();
    assert_eq!(run(&mut board), (OLD, false, BootEvent::Rejected(ImageError::Rollback { minimum: 5, found: 4 })));
    assert_eq!(scan(&mut board.state).unwrap().state, BootState::Idle);
    assert_eq!(run(&mut board), (OLD, false, BootEvent::Normal));
    // The same image at the minimum is activated.
    let mut r = factory(5);
    factory_install(&mut r.slot_b, &image_with_security(32 * 1024, NEW, 5));
    let mut board = on_supply(&r);
    state::append(&mut board.state, Record::floor(5)).unwrap();
    state::append(&mut board.state, Record::new(RecordKind::Pending, 0)).unwrap();
    assert_eq!(run(&mut board), (NEW, true, BootEvent::Activated));
}

/// A log with 10 free slots and Floor(3) among "idle" records; slot A holds the image of security version 3.
/// The activation of a newer image erases the log (compaction), writes Floor(3) again, then Pending. A power cut
/// at each of those three writes (each torn several ways): afterwards the minimum in force is still 3 (an image
/// of security version 2 is refused), and when the Pending record survived, the log's own Floor is 3 before
/// the bootloader swaps (the minimum it checks against).
#[test]
fn the_minimum_survives_the_compaction_of_the_log_and_a_power_cut_at_every_write_of_it() {
    let mut base = factory(3);
    let cap = (STATE_SECTOR / RECORD_LEN) as usize;
    let cancelled = Record::new(RecordKind::Cancelled, 0).to_bytes();
    for slot in base.state.contents_mut().chunks_mut(RECORD_LEN as usize).take(cap - 10) {
        slot.copy_from_slice(&cancelled);
    }
    base.state.contents_mut()[..RECORD_LEN as usize].copy_from_slice(&Record::floor(3).to_bytes());
    let new = image_with_security(32 * 1024, NEW, 4);
    let clean = {
        let mut b = on_supply(&base);
        assert_eq!(update(&mut b, &new), Ok(4));
        assert_eq!(b.state.flash.erase_counts()[0], 1, "the activation compacted the log");
        let s = scan(&mut b.state).unwrap();
        assert_eq!((s.floor, s.next_free), (3, 2), "Floor(3) rewritten first, then Pending");
        writes(&b)
    };
    let mut cuts = 0;
    for k in [clean - 3, clean - 2, clean - 1] {
        for seed in 0..8u64 {
            let mut b = on_supply(&base);
            cut_at(&b, k, seed * 97 + k);
            assert!(update(&mut b, &new).is_err(), "cut {k}/{seed}");
            power_on(&mut b);
            cuts += 1;
            assert_eq!(minimum(&mut b), 3, "cut {k}/{seed}: the minimum in force");
            let s = scan(&mut b.state).unwrap();
            if let BootState::Pending { .. } = s.state {
                assert_eq!(s.floor, 3, "cut {k}/{seed}: Pending in force without the Floor before it");
            }
            match run(&mut b) {
                (NEW, true, BootEvent::Activated) => {}
                (OLD, false, BootEvent::Normal) => {
                    assert_eq!(
                        update(&mut b, &image_with_security(32 * 1024, NEWER, 2)),
                        Err(UpdateError::Image(ImageError::Rollback { minimum: 3, found: 2 })),
                        "cut {k}/{seed}"
                    );
                }
                other => panic!("compaction cut {k}/{seed}: {other:?}"),
            }
        }
    }
    eprintln!("minimum across the compaction: {cuts} cuts");
}

/// The confirmation writes Confirmed, then Floor. A cut at either (each torn several ways) ends in the new image
/// kept with the minimum at its security version, or the old one back with the minimum unchanged; never the
/// old image running below a raised minimum.
#[test]
fn a_power_cut_during_the_confirmation_raises_the_minimum_with_the_new_image_or_not_at_all() {
    let base = {
        let mut b = on_supply(&factory(1));
        assert_eq!(update(&mut b, &image_with_security(32 * 1024, NEW, 3)), Ok(3));
        assert_eq!(run(&mut b), (NEW, true, BootEvent::Activated));
        snapshot(&b)
    };
    let (mut kept, mut reverted) = (0, 0);
    for k in 0..2u64 {
        for seed in 0..16u64 {
            let mut b = on_supply(&base);
            cut_at(&b, k, seed * 131 + k);
            assert!(confirm(&mut b.state, 3).is_err(), "cut {k}/{seed}");
            power_on(&mut b);
            match run(&mut b) {
                (NEW, false, BootEvent::Normal) => {
                    kept += 1;
                    assert_eq!(minimum(&mut b), 3, "cut {k}/{seed}: new image kept");
                }
                (OLD, false, BootEvent::Reverted) => {
                    reverted += 1;
                    assert_eq!(minimum(&mut b), 1, "cut {k}/{seed}: old image back");
                }
                other => panic!("confirm cut {k}/{seed}: {other:?}"),
            }
        }
    }
    eprintln!("confirmation with Floor: kept {kept}x, reverted {reverted}x");
    assert!(kept > 0 && reverted > 0, "both outcomes must occur");
}

//! Issue 7, update path on the simulated flash with the real sector layout: download into slot B, activate,
//! reset -> the bootloader swaps and starts the new image on trial, confirm -> the old image is no longer a way
//! back; an image that never confirms is reverted at the next reset; a pending image damaged in slot B is
//! rejected; no new download while a trial runs.

use crate::support::*;
use firmware::boot::image::ImageError;
use firmware::boot::loader::{boot, running_image, BootEvent, Outcome};
use firmware::boot::state::{scan, BootState};
use firmware::boot::update::{confirm, Download, UpdateError};

const OLD: u32 = 0x0100_0000;
const NEW: u32 = 0x0200_0000;

fn run(board: &mut Board) -> Outcome {
    let mut buf = vec![0u8; BUF_LEN];
    boot(board, &trust(), &mut buf).expect("boot without power cut")
}

fn running(o: &Outcome) -> (u32, bool, BootEvent) {
    match o {
        Outcome::Run { header, trial, event } => (header.firmware_version, *trial, *event),
        Outcome::NoValidImage(e) => panic!("no valid image: {e:?}"),
    }
}

/// Slot A with the old image (150 KiB payload: two sectors), nothing pending.
fn factory() -> Board {
    let mut r = regions();
    factory_install(&mut r.slot_a, &image(150 * 1024, OLD));
    on_supply(&r)
}

#[test]
fn update_end_to_end_download_activate_trial_confirm() {
    let mut board = factory();
    assert_eq!(running(&run(&mut board)), (OLD, false, BootEvent::Normal));

    // 200 KiB payload in 7-byte pieces would take long in a debug build; 889-byte pieces are uneven enough.
    let new = image(200 * 1024, NEW);
    download(&mut board.slot_b, &mut board.state, &new, 889).unwrap();
    assert!(matches!(scan(&mut board.state).unwrap().state, BootState::Pending { .. }));
    assert_eq!(slot_image(board.slot_a.flash.contents()), image(150 * 1024, OLD), "the old image runs until reset");

    assert_eq!(running(&run(&mut board)), (NEW, true, BootEvent::Activated));
    assert_eq!(slot_image(board.slot_a.flash.contents()), new);
    assert_eq!(slot_image(board.slot_b.flash.contents()), image(150 * 1024, OLD), "the old image is kept in B");
    assert_eq!(confirm(&mut board.state, 0), Ok(true));
    assert_eq!(confirm(&mut board.state, 0), Ok(false), "confirming twice changes nothing");

    for _ in 0..3 {
        assert_eq!(running(&run(&mut board)), (NEW, false, BootEvent::Normal), "the confirmed image stays");
    }
    assert_eq!(scan(&mut board.state).unwrap().state, BootState::Idle);
    // The old image is gone: a new download may now overwrite slot B.
    let newer = image(100 * 1024, 0x0300_0000);
    download(&mut board.slot_b, &mut board.state, &newer, 4096).unwrap();
    assert_eq!(running(&run(&mut board)), (0x0300_0000, true, BootEvent::Activated));
}

#[test]
fn an_image_that_never_confirms_is_reverted_at_the_next_reset() {
    let mut board = factory();
    let new = image(200 * 1024, NEW);
    download(&mut board.slot_b, &mut board.state, &new, 4096).unwrap();
    assert_eq!(running(&run(&mut board)), (NEW, true, BootEvent::Activated));
    // While on trial a new download is refused: slot B holds the only way back.
    let mut d = Download::new();
    assert_eq!(d.clear(&mut board.slot_b, &mut board.state, None), Err(UpdateError::NotConfirmed));
    // No confirmation; reset.
    assert_eq!(running(&run(&mut board)), (OLD, false, BootEvent::Reverted));
    assert_eq!(slot_image(board.slot_a.flash.contents()), image(150 * 1024, OLD));
    // The reverted image is not activated again by later resets.
    assert_eq!(running(&run(&mut board)), (OLD, false, BootEvent::Normal));
    assert_eq!(scan(&mut board.state).unwrap().state, BootState::Idle);
}

#[test]
fn a_pending_image_damaged_in_slot_b_is_rejected_and_the_old_one_runs() {
    let mut board = factory();
    download(&mut board.slot_b, &mut board.state, &image(64 * 1024, NEW), 4096).unwrap();
    board.slot_b.flash.contents_mut()[1234] ^= 0x04; // a flipped bit after verification (bit rot)
    let (v, trial, event) = running(&run(&mut board));
    assert_eq!((v, trial), (OLD, false));
    assert!(matches!(event, BootEvent::Rejected(ImageError::Crc { .. })));
    assert_eq!(running(&run(&mut board)), (OLD, false, BootEvent::Normal));
}

#[test]
fn a_new_clear_withdraws_a_pending_image() {
    let mut board = factory();
    download(&mut board.slot_b, &mut board.state, &image(64 * 1024, NEW), 4096).unwrap();
    let mut d = Download::new();
    d.clear(&mut board.slot_b, &mut board.state, None).unwrap();
    assert_eq!(scan(&mut board.state).unwrap().state, BootState::Idle);
    assert_eq!(running(&run(&mut board)), (OLD, false, BootEvent::Normal));
}

#[test]
fn a_trial_without_a_valid_previous_image_is_kept_rather_than_bricking() {
    // First installation: slot A empty, the image arrives by download.
    let mut board = on_supply(&regions());
    assert!(matches!(run(&mut board), Outcome::NoValidImage(ImageError::BadMagic)));
    download(&mut board.slot_b, &mut board.state, &image(32 * 1024, NEW), 4096).unwrap();
    assert_eq!(running(&run(&mut board)), (NEW, true, BootEvent::Activated));
    assert_eq!(running(&run(&mut board)), (NEW, false, BootEvent::KeptWithoutFallback));
}

#[test]
fn the_state_log_is_compacted_only_when_idle_and_updates_keep_working() {
    // Each update takes 12 records of 16 bytes; 4096 fit in the 64 KiB sector: run past one compaction.
    let mut board = factory();
    let mut version = OLD;
    let imgs = [image(8 * 1024, 0x0500_0000), image(8 * 1024, 0x0600_0000)];
    let start_erases = board.state.flash.erase_counts()[0];
    for i in 0..400 {
        let img = &imgs[i % 2];
        download(&mut board.slot_b, &mut board.state, img, 4096).unwrap();
        let (v, trial, _) = running(&run(&mut board));
        assert!(trial);
        version = v;
        confirm(&mut board.state, 0).unwrap();
    }
    assert_eq!(version, 0x0600_0000);
    let erases = board.state.flash.erase_counts()[0] - start_erases;
    assert!(erases >= 1, "400 updates x 12 records must have needed a compaction");
    assert_eq!(running(&run(&mut board)), (0x0600_0000, false, BootEvent::Normal));
}

/// What the started application reconstructs with `loader::running_image` (it does not verify again) matches what
/// the bootloader decided: the header of the image in slot A, and the trial until the image confirms itself.
#[test]
fn the_application_finds_its_header_and_its_trial_as_the_bootloader_left_them() {
    let mut board = factory();
    let first = run(&mut board);
    let seen = running_image(&mut board.slot_a, &mut board.state, &trust());
    assert_eq!(running(&seen), running(&first));
    assert_eq!(running(&seen), (OLD, false, BootEvent::Normal));

    download(&mut board.slot_b, &mut board.state, &image(100 * 1024, NEW), 4096).unwrap();
    let Outcome::Run { header, trial: true, .. } = run(&mut board) else { panic!("the new image runs on trial") };
    let seen = running_image(&mut board.slot_a, &mut board.state, &trust());
    assert!(matches!(seen, Outcome::Run { header: h, trial: true, event: BootEvent::Normal } if h == header));
    assert_eq!(confirm(&mut board.state, 0), Ok(true));
    assert_eq!(running(&running_image(&mut board.slot_a, &mut board.state, &trust())), (NEW, false, BootEvent::Normal));

    // An erased slot A (no header): no program, with the reason.
    let mut empty = on_supply(&regions());
    assert_eq!(
        running_image(&mut empty.slot_a, &mut empty.state, &trust()),
        Outcome::NoValidImage(ImageError::BadMagic)
    );
    // A header for other hardware is not taken for this drive's program.
    let mut other = trust();
    other.hardware_id ^= 1;
    assert!(matches!(
        running_image(&mut board.slot_a, &mut board.state, &other),
        Outcome::NoValidImage(ImageError::WrongHardware { .. })
    ));
}

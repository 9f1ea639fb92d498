//! Issue 7, phase 2: program control (0x1F50/0x1F51/0x1F56/0x1F57, IDX L3320-3473, E4 Table 4-27/4-28) on the
//! simulated drives: an update end to end over CoE SDO (EtherCAT runner) and over CANopen SDO block download (CAN
//! runner, 1 Mbit/s), and every refusal with its abort code and 0x1F57 status while the old firmware keeps
//! running. Simulated times are printed (`--nocapture`) for the closing note.

mod boot_fieldbus;

use boot_fieldbus::*;
use firmware::boot::image::{HEADER_LEN, HEADER_OFFSET};
use firmware::boot::loader::{BootEvent, Outcome};
use firmware::boot::program::{Interface, Mode};
use firmware::boot::state::{scan, BootState};
use firmware::cia402::State;
use firmware::drive::objects::DriveObjects;
use firmware::od::access::{AccessContext, CommState};
use firmware::od::generated::handles as h;
use firmware::od::store::ParamStore;
use hal_sim::flash::SimFlash;
use hal_sim::sim::update::{dev_seed, payload, signed_image, FACTORY_VERSION_STRING};

const DEVICE_STATE: u32 = 0x0800_0022;
const LOCAL_CONTROL: u32 = 0x0800_0021;
const CANNOT_TRANSFER: u32 = 0x0800_0020;
const INVALID_VALUE: u32 = 0x0609_0030;
const LENGTH_TOO_LOW: u32 = 0x0607_0013;
const LENGTH_TOO_HIGH: u32 = 0x0607_0012;
const NO_OBJECT: u32 = 0x0602_0000;
const VALUE_TOO_LOW: u32 = 0x0609_0032;

/// CoE segment size: what the 128-byte mailbox holds after the mailbox, CoE and SDO command headers.
const COE_SEGMENT: usize = 128 - 9;

fn slot_header(f: &SimFlash) -> Vec<u8> {
    f.contents()[HEADER_OFFSET as usize..(HEADER_OFFSET + HEADER_LEN) as usize].to_vec()
}

fn version_of(f: &SimFlash) -> u32 {
    u32_of(&slot_header(f)[12..16])
}

/// Enables the drive in profile velocity mode, commands 2 rev/s for 0.2 s and checks the rotor moved (at least
/// 0.1 rev: a quarter of the ideal 0.4 rev, generous for the acceleration ramp and the reference plant).
fn assert_moves(sim: &mut hal_sim::sim::Simulation) {
    sim.enable_through_controlword(3).expect("enabled");
    assert_eq!(sim.cia402_state(), State::OperationEnabled);
    let p0 = sim.drive.dictionary().get(h::POSITION_ACTUAL_VALUE);
    sim.drive.dictionary_mut().set(h::TARGET_VELOCITY, 2 * 4096);
    sim.run(5_000);
    let moved = sim.drive.dictionary().get(h::POSITION_ACTUAL_VALUE).wrapping_sub(p0);
    assert!(moved > 4096 / 10, "moved {moved} increments");
}

/// Proves the CoE sequence stop -> clear -> 0x1F50 in segments -> start: the reset runs the bootloader, which
/// activates the new image on trial; the old image stays in slot B until the new one confirmed itself (on
/// reaching PRE-OP); 0x1F56 and 0x100A then report the new image and the drive enables and moves.
#[test]
fn coe_update_end_to_end_and_the_old_image_goes_only_after_the_confirmation() {
    let mut rig = EcatRig::new();
    rig.enter_preop();
    assert_eq!(rig.upload_u32(0x1F51, 1), Ok(1), "program started");
    assert_eq!(rig.upload_u32(0x1F56, 1), Ok(OLD_VERSION & 0xFFFF_0000 | 1));
    assert_eq!(rig.upload(0x100A, 0), Ok(FACTORY_VERSION_STRING.as_bytes().to_vec()));
    assert_eq!(rig.upload_u32(0x1000, 0), Ok(0x0002_0192));

    let image = new_image(APP_PAYLOAD);
    let (f0, t0) = (rig.frames, rig.r.simulated_ns());
    assert_eq!(rig.download(0x1F51, 1, &[0]), Some(Ok(())), "stop");
    // The bootloader's view (E4 Table 4-33): device type 0x012E, no CiA 402 objects.
    assert_eq!(rig.upload_u32(0x1000, 0), Ok(0x0000_012E));
    assert_eq!(rig.upload(0x6041, 0), Err(NO_OBJECT));
    assert_eq!(rig.upload_u32(0x1F51, 1), Ok(0), "program stopped");
    assert_eq!(rig.download(0x1F51, 1, &[3]), Some(Ok(())), "clear");
    assert_eq!(rig.download_domain(0x1F50, 1, &image, COE_SEGMENT), Ok(()));
    assert_eq!(rig.upload_u32(0x1F57, 1), Ok(0), "valid program, no download in progress");
    let _ = rig.download(0x1F51, 1, &[1]); // start: the drive resets (E4: no answer expected)
    let (frames, ns) = (rig.frames - f0, rig.r.simulated_ns() - t0);
    println!(
        "CoE update of a {} KiB image ({} B header): {frames} mailbox cycles of 1 ms, {:.3} s simulated",
        APP_PAYLOAD / 1024,
        HEADER_LEN,
        ns as f64 / 1e9
    );

    assert_eq!(rig.r.node.resets, 1);
    assert!(matches!(rig.r.node.last_boot, Outcome::Run { trial: true, event: BootEvent::Activated, .. }));
    {
        let mut p = rig.r.node.program.borrow_mut();
        assert!(p.on_trial());
        let f = p.flash_mut();
        assert_eq!(version_of(&f.slot_a), NEW_VERSION);
        assert_eq!(version_of(&f.slot_b), OLD_VERSION, "the old image stays until the new one confirms");
        assert!(matches!(scan(&mut f.state).unwrap().state, BootState::Trial { .. }));
    }
    rig.enter_preop();
    {
        let mut p = rig.r.node.program.borrow_mut();
        assert!(!p.on_trial(), "confirmed on reaching PRE-OP");
        assert_eq!(scan(&mut p.flash_mut().state).unwrap().state, BootState::Idle, "no way back any more");
    }
    assert_eq!(rig.upload_u32(0x1F56, 1), Ok(NEW_VERSION & 0xFFFF_0000 | 1));
    assert_eq!(rig.upload(0x100A, 0), Ok(NEW_VERSION_STRING.as_bytes().to_vec()));
    assert_eq!(rig.upload_u32(0x1F51, 1), Ok(1));
    assert_eq!(rig.upload_u32(0x1000, 0), Ok(0x0002_0192));

    // The new firmware runs the drive: enable through the controlword and a short move.
    assert_moves(&mut rig.r.node.sim);
}

/// Proves the refusals over CoE, each with its abort code and 0x1F57 status (bits 7..1), and that the old image
/// keeps running after each (0x1F56, 0x100A, slot A unchanged, no reset).
#[test]
fn coe_refusals_leave_the_old_firmware_running() {
    let mut rig = EcatRig::new();
    rig.enter_preop();
    let status = |rig: &mut EcatRig| rig.upload_u32(0x1F57, 1).map(|s| s >> 1);

    // Download without stop and clear: sequence error 66.
    assert_eq!(rig.download_domain(0x1F50, 1, &new_image(1024), COE_SEGMENT), Err(DEVICE_STATE));
    assert_eq!(status(&mut rig), Ok(66));
    // Clear without stop: sequence error too.
    assert_eq!(rig.download(0x1F51, 1, &[3]), Some(Err(DEVICE_STATE)));
    // Stop, then download without clear.
    assert_eq!(rig.download(0x1F51, 1, &[0]), Some(Ok(())));
    assert_eq!(rig.download_domain(0x1F50, 1, &new_image(1024), COE_SEGMENT), Err(DEVICE_STATE));
    assert_eq!(status(&mut rig), Ok(66));

    let seed = dev_seed();
    let other_key = [7u8; 32];
    let body = payload(4096, NEW_VERSION);
    let mut bad_crc = new_image(4096);
    bad_crc[HEADER_LEN as usize + 100] ^= 1;
    let mut bad_sig = new_image(4096);
    bad_sig[64] ^= 1;
    let mut truncated = new_image(4096);
    truncated.truncate(truncated.len() - 4);
    let mut oversized = new_image(4096);
    oversized[20..24].copy_from_slice(&(HEADER_OFFSET + 4).to_le_bytes());
    let cases: [(&str, Vec<u8>, u32, u32); 6] = [
        ("bad CRC", bad_crc, CANNOT_TRANSFER, 3),
        ("bad signature", bad_sig, CANNOT_TRANSFER, 93),
        (
            "other key",
            signed_image(&body, NEW_VERSION, "x", firmware::boot::image::HARDWARE_ID, &other_key),
            CANNOT_TRANSFER,
            93,
        ),
        ("wrong hardware id", signed_image(&body, NEW_VERSION, "x", 0x0F40_5002, &seed), INVALID_VALUE, 64),
        ("truncated", truncated, LENGTH_TOO_LOW, 3),
        ("oversized", oversized, LENGTH_TOO_HIGH, 6),
    ];
    for (what, image, abort, code) in cases {
        assert_eq!(rig.download(0x1F51, 1, &[3]), Some(Ok(())), "{what}: clear");
        // Truncated: the client announces (and sends) fewer bytes than the header's payload length.
        assert_eq!(rig.download_domain(0x1F50, 1, &image, COE_SEGMENT), Err(abort), "{what}");
        assert_eq!(status(&mut rig), Ok(code), "{what}: 0x1F57");
    }
    // Start without a valid download: the old application starts again, no reset.
    assert_eq!(rig.download(0x1F51, 1, &[1]), Some(Ok(())));
    assert_eq!(rig.r.node.resets, 0);
    assert_eq!(rig.upload_u32(0x1F51, 1), Ok(1));
    assert_eq!(rig.upload_u32(0x1F56, 1), Ok(OLD_VERSION & 0xFFFF_0000 | 1));
    assert_eq!(rig.upload(0x100A, 0), Ok(FACTORY_VERSION_STRING.as_bytes().to_vec()));
    assert_eq!(version_of(&rig.r.node.program.borrow().flash().slot_a), OLD_VERSION);

    // Stop while the power stage is on: refused, the program keeps running.
    rig.r.node.sim.enable_through_controlword(3).expect("enabled");
    assert_eq!(rig.download(0x1F51, 1, &[0]), Some(Err(DEVICE_STATE)));
    assert_eq!(rig.upload_u32(0x1F51, 1), Ok(1));
    assert_eq!(rig.r.node.sim.cia402_state(), State::OperationEnabled);
}

/// Proves the one-interface rule (IDX L3345-3350): once EtherCAT stopped the program, CANopen requests to the
/// program objects of the same drive are refused with 0x0800_0021 (local control), and they do not disturb the
/// owner's download; after the start the other interface is served again.
#[test]
fn a_second_interface_is_refused_while_the_update_owns_the_first() {
    let mut store = ParamStore::new(SimFlash::params());
    let mut program = hal_sim::sim::update::factory_program();
    hal_sim::sim::update::reset(&mut program);
    let mut drive = hal_sim::sim::update::boot_drive(&mut store, &program);
    let ctx = AccessContext { comm_state: CommState::PreOperational, power_stage_enabled: false, max_pdo_bytes: 8 };
    let ecat = |drive: &mut firmware::drive::Drive, store: &mut ParamStore<SimFlash>, p: &mut _, i: u16, v: &[u8]| {
        let mut app = DriveObjects::new(store, false).with_program_control(program_port(p, Interface::Ethercat));
        drive.dictionary_mut().write(i, 1, v, ctx, &mut app).map_err(|a| a as u32)
    };
    fn program_port(
        p: &mut hal_sim::sim::update::SimProgram,
        i: Interface,
    ) -> firmware::boot::program::ProgramPort<'_, SimFlash, SimFlash, SimFlash> {
        p.port(i, false)
    }
    assert_eq!(ecat(&mut drive, &mut store, &mut program, 0x1F51, &[0]), Ok(()));
    assert_eq!(program.mode(), Mode::Stopped { owner: Some(Interface::Ethercat) });
    assert_eq!(ecat(&mut drive, &mut store, &mut program, 0x1F51, &[3]), Ok(()));
    let image = new_image(2048);
    let entry = drive.dictionary().find(0x1F50, 1).unwrap();
    {
        let mut app =
            DriveObjects::new(&mut store, false).with_program_control(program.port(Interface::Ethercat, false));
        let mut d = drive.dictionary().begin_download::<64>(0x1F50, 1, Some(image.len()), ctx).unwrap();
        drive.dictionary_mut().download_segment(&mut d, &image[..1000], false, ctx, &mut app).unwrap();
        assert_eq!(d.entry(), entry);
    }
    // CANopen talks now: every program object refuses, reads included.
    for (index, value) in [(0x1F51u16, &[1u8][..]), (0x1F51, &[0]), (0x1F51, &[3])] {
        let mut app =
            DriveObjects::new(&mut store, false).with_program_control(program.port(Interface::Canopen, false));
        assert_eq!(
            drive.dictionary_mut().write(index, 1, value, ctx, &mut app).map_err(|a| a as u32),
            Err(LOCAL_CONTROL)
        );
    }
    {
        let mut app =
            DriveObjects::new(&mut store, false).with_program_control(program.port(Interface::Canopen, false));
        let mut buf = [0u8; 4];
        assert_eq!(drive.dictionary().read(0x1F57, 1, 0, &mut buf, &mut app).map_err(|a| a as u32), Err(LOCAL_CONTROL));
        let mut d = drive.dictionary().begin_download::<64>(0x1F50, 1, None, ctx).unwrap();
        let r = drive.dictionary_mut().download_segment(&mut d, &image, true, ctx, &mut app);
        assert_eq!(r.map_err(|a| a as u32), Err(LOCAL_CONTROL));
    }
    assert_eq!(program.download_phase(), firmware::boot::update::Phase::Receiving, "the owner's download goes on");
    assert_eq!(program.flash_status() & 1, 1, "download in progress");
}

/// Proves the same update over CANopen: SDO block download of the image at 1 Mbit/s (NMT pre-operational, drive
/// disabled), start, the NMT boot-up after the reset, the confirmation, 0x1F56 and 0x100A of the new image.
#[test]
fn canopen_block_download_update_end_to_end() {
    let mut rig = CanRig::new();
    assert_eq!(rig.upload_u32(0x1F56, 1), Ok(OLD_VERSION & 0xFFFF_0000 | 1));
    let image = new_image(APP_PAYLOAD);
    let t0 = rig.r.now_ns();
    assert_eq!(rig.download(0x1F51, 1, &[0]), Some(Ok(())));
    assert_eq!(rig.upload_u32(0x1000, 0), Ok(0x0000_012E));
    assert_eq!(rig.download(0x1F51, 1, &[3]), Some(Ok(())));
    assert_eq!(rig.block_download(0x1F50, 1, &image), Ok(()));
    let _ = rig.download(0x1F51, 1, &[1]);
    let ns = rig.r.now_ns() - t0;
    println!(
        "CANopen block download update of a {} KiB image at 1 Mbit/s: {:.3} s simulated",
        APP_PAYLOAD / 1024,
        ns as f64 / 1e9
    );
    rig.r.run_for(5_000_000);
    let d = rig.r.drive(1).unwrap();
    assert!(matches!(d.last_boot, Outcome::Run { event: BootEvent::Activated, .. }));
    assert!(!d.program.on_trial(), "confirmed after the boot-up");
    assert_eq!(rig.upload_u32(0x1F56, 1), Ok(NEW_VERSION & 0xFFFF_0000 | 1));
    assert_eq!(rig.upload(0x100A, 0), Ok(NEW_VERSION_STRING.as_bytes().to_vec()));
    assert_eq!(rig.upload_u32(0x1000, 0), Ok(0x0002_0192));
}

/// Proves that an image that never confirms itself is reverted at the next reset (NMT reset node runs the
/// bootloader), and the old image reports again.
#[test]
fn canopen_an_unconfirmed_image_is_reverted_at_the_next_reset() {
    let mut rig = CanRig::new();
    rig.r.drives[0].auto_confirm = false;
    assert_eq!(rig.download(0x1F51, 1, &[0]), Some(Ok(())));
    assert_eq!(rig.download(0x1F51, 1, &[3]), Some(Ok(())));
    assert_eq!(rig.block_download(0x1F50, 1, &new_image(8 * 1024)), Ok(()));
    let _ = rig.download(0x1F51, 1, &[1]);
    rig.r.run_for(5_000_000);
    assert!(rig.r.drive(1).unwrap().program.on_trial());
    assert_eq!(rig.upload_u32(0x1F56, 1), Ok(NEW_VERSION & 0xFFFF_0000 | 1));
    // NMT reset node.
    rig.r.lock_step(firmware::canopen::frame::CanFrame::new(0x000, &[0x81, 1]).unwrap());
    rig.r.run_for(5_000_000);
    assert!(matches!(rig.r.drive(1).unwrap().last_boot, Outcome::Run { event: BootEvent::Reverted, .. }));
    assert_eq!(rig.upload_u32(0x1F56, 1), Ok(OLD_VERSION & 0xFFFF_0000 | 1));
    assert_eq!(rig.upload(0x100A, 0), Ok(FACTORY_VERSION_STRING.as_bytes().to_vec()));
}

/// Anti-rollback through program control on CANopen (issue 19 item 7): after an image of security version 2
/// confirmed itself, the 0x1F50 download of an image of security version 1 is aborted with 0x0609_0032 (value
/// too low: the header's security version) as soon as its header is in, 0x1F57 reads status 94, and 0x1F51 = 1
/// starts the confirmed application again without a reset; an image of security version 2 goes through and is
/// activated by 0x1F51 = 1.
#[test]
fn canopen_an_older_security_version_is_refused_through_program_control() {
    let mut rig = CanRig::new();
    assert_eq!(rig.download(0x1F51, 1, &[0]), Some(Ok(())));
    assert_eq!(rig.download(0x1F51, 1, &[3]), Some(Ok(())));
    assert_eq!(rig.block_download(0x1F50, 1, &image_with_security(8 * 1024, 0x0002_0000, 2)), Ok(()));
    let _ = rig.download(0x1F51, 1, &[1]);
    rig.r.run_for(5_000_000);
    assert!(matches!(rig.r.drive(1).unwrap().last_boot, Outcome::Run { event: BootEvent::Activated, .. }));
    assert!(!rig.r.drive(1).unwrap().program.on_trial(), "security version 2 confirmed");

    assert_eq!(rig.download(0x1F51, 1, &[0]), Some(Ok(())));
    assert_eq!(rig.download(0x1F51, 1, &[3]), Some(Ok(())));
    let older = image_with_security(8 * 1024, 0x0003_0000, 1);
    assert_eq!(rig.block_download(0x1F50, 1, &older), Err(VALUE_TOO_LOW));
    assert_eq!(rig.upload_u32(0x1F57, 1).map(|s| s >> 1), Ok(94));
    assert_eq!(rig.download(0x1F51, 1, &[1]), Some(Ok(())), "start: the confirmed application again");
    rig.r.run_for(5_000_000);
    let d = rig.r.drive(1).unwrap();
    assert!(matches!(d.last_boot, Outcome::Run { event: BootEvent::Activated, .. }), "no reset since");
    assert_eq!(rig.upload_u32(0x1F56, 1), Ok(0x0002_0001));
    assert_eq!(rig.upload_u32(0x1F51, 1), Ok(1), "the application runs");

    assert_eq!(rig.download(0x1F51, 1, &[0]), Some(Ok(())));
    assert_eq!(rig.download(0x1F51, 1, &[3]), Some(Ok(())));
    assert_eq!(rig.block_download(0x1F50, 1, &image_with_security(8 * 1024, 0x0003_0000, 2)), Ok(()), "equal");
    assert_eq!(rig.upload_u32(0x1F57, 1), Ok(0));
    let _ = rig.download(0x1F51, 1, &[1]);
    rig.r.run_for(5_000_000);
    assert!(matches!(rig.r.drive(1).unwrap().last_boot, Outcome::Run { event: BootEvent::Activated, .. }));
    assert_eq!(rig.upload_u32(0x1F56, 1), Ok(0x0003_0001));
}

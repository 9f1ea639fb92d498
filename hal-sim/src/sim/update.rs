//! The firmware-update side of the simulated drives (issue 7, phase 2): the three update regions on
//! [`SimFlash`] with the real geometry of `memory.x` (slot A 3 x 128 KiB, slot B 4 x 128 KiB, BOOT_STATE 64 KiB,
//! 32-bit program granularity), a factory image in slot A signed with the development key, and the simulated
//! reset: the bootloader's decision ([`loader::boot`]) over those regions, then the drive starts anew from its
//! parameter store and "runs" the image in slot A: 0x1F56 and 0x100A report the header the loader verified
//! ([`ProgramControl::started`]). The dictionary follows program control: [`APPLICATION_TABLE`] while the
//! application runs, [`BOOTLOADER_TABLE`] while the program is stopped (or no valid image exists).
//!
//! The "application" a simulated image stands for is always this firmware: only the header (version, 0x1F56
//! identification, version string) tells images apart.

use std::cell::RefCell;
use std::sync::OnceLock;

use firmware::boot::image::{ImageError, ImageHeader, HARDWARE_ID, HEADER_LEN, HEADER_OFFSET, MAX_PAYLOAD_LEN};
use firmware::boot::keys::DEV_PUBLIC_KEY;
use firmware::boot::loader::{self, Outcome};
use firmware::boot::program::{Interface, Mode, ProgramControl, SharedPort};
use firmware::boot::sign::sign_image;
use firmware::boot::swap::BootFlash;
use firmware::boot::tables::{show_software_version, APPLICATION_TABLE, BOOTLOADER_TABLE};
use firmware::boot::verify::Trust;
use firmware::drive::objects::DriveObjects;
use firmware::drive::{Drive, DriveConfig};
use firmware::hal::flash::{FlashError, NorFlash};
use firmware::od::abort::SdoAbort;
use firmware::od::access::{Dictionary, ReadOutcome, Table};
use firmware::od::store::ParamStore;
use firmware::recorder::objects::RecorderObjects;
use firmware::recorder::Recorder;

use crate::flash::SimFlash;

/// The F405's 128 KiB sectors of slots A and B (RM0090 section 3.3).
pub const SLOT_SECTOR: u32 = 128 * 1024;
/// Sector 4, BOOT_STATE.
pub const STATE_SECTOR: u32 = 64 * 1024;
/// The bootloader's copy and verification buffer in the simulation.
pub const BOOT_BUF_LEN: usize = 4096;
/// Payload length of the factory image (the simulated application's flash contents).
pub const FACTORY_PAYLOAD_LEN: usize = 16 * 1024;
/// Firmware version of the factory image.
pub const FACTORY_VERSION: u32 = 0x0001_0000;
/// Version string of the factory image: what 0x100A read before images existed (device.toml default).
pub const FACTORY_VERSION_STRING: &str = "0.1.0";

/// The three update regions on simulated flash.
pub type SimRegions = BootFlash<SimFlash, SimFlash, SimFlash>;
/// Program control over them.
pub type SimProgram = ProgramControl<SimFlash, SimFlash, SimFlash>;

/// Erased regions with the real layout (write size 4 bytes).
pub fn regions() -> SimRegions {
    BootFlash {
        slot_a: SimFlash::new(SLOT_SECTOR, 3, 4),
        slot_b: SimFlash::new(SLOT_SECTOR, 4, 4),
        state: SimFlash::new(STATE_SECTOR, 1, 4),
    }
}

/// The development signing seed (`keys/dev-signing-key.secret`), for simulated factory images and tests.
pub fn dev_seed() -> [u8; 32] {
    let text = include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/../keys/dev-signing-key.secret")).trim();
    let mut out = [0u8; 32];
    for (i, o) in out.iter_mut().enumerate() {
        *o = text.get(2 * i..2 * i + 2).and_then(|h| u8::from_str_radix(h, 16).ok()).unwrap_or(0);
    }
    out
}

/// The trust anchor of the simulated drives: the development public key, this hardware, slot A's size.
pub fn dev_trust() -> Trust {
    Trust { public_key: DEV_PUBLIC_KEY, hardware_id: HARDWARE_ID, max_payload: MAX_PAYLOAD_LEN }
}

/// A deterministic payload of `len` bytes for firmware `version`.
pub fn payload(len: usize, version: u32) -> Vec<u8> {
    let mut x = version.wrapping_mul(0x9E37_79B9) | 1;
    (0..len)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            (x >> 8) as u8 & 0x7F
        })
        .collect()
}

/// An image (header then payload) of firmware `version` with `payload`, 0x1F56 identification
/// `version & 0xFFFF_0000`, `version_string` (at most 16 bytes), built for `hardware_id` and signed with `seed`.
pub fn signed_image(payload: &[u8], version: u32, version_string: &str, hardware_id: u32, seed: &[u8; 32]) -> Vec<u8> {
    let mut header = ImageHeader::new(hardware_id, version, version & 0xFFFF_0000, 0, 0);
    let s = version_string.as_bytes();
    let n = s.len().min(header.version_string.len());
    header.version_string[..n].copy_from_slice(&s[..n]);
    sign_image(&mut header, payload, seed, [version as u8; 16]);
    let mut image = header.to_bytes().to_vec();
    image.extend_from_slice(payload);
    image
}

/// The factory image every simulated drive starts with (signed once per process).
pub fn factory_image() -> &'static [u8] {
    static IMAGE: OnceLock<Vec<u8>> = OnceLock::new();
    IMAGE.get_or_init(|| {
        signed_image(
            &payload(FACTORY_PAYLOAD_LEN, FACTORY_VERSION),
            FACTORY_VERSION,
            FACTORY_VERSION_STRING,
            HARDWARE_ID,
            &dev_seed(),
        )
    })
}

/// Factory programming of slot A (the debugger writes payload and header; no state record).
pub fn factory_install(slot_a: &mut SimFlash, image: &[u8]) -> Result<(), FlashError> {
    let (header, payload) = image.split_at(HEADER_LEN as usize);
    slot_a.program(0, payload)?;
    slot_a.program(HEADER_OFFSET, header)
}

/// Program control over fresh regions with the factory image in slot A (not booted yet: see [`reset`]).
pub fn factory_program() -> SimProgram {
    let mut r = regions();
    // Fresh erased flash of the right size: programming it cannot fail.
    let _ = factory_install(&mut r.slot_a, factory_image());
    ProgramControl::new(r, dev_trust())
}

/// Program control over fresh regions with slot A erased (a board whose application was never programmed, or
/// erased by the debugger): the bootloader finds no valid image at [`reset`] and stays active (issue 7, item 4).
pub fn blank_program() -> SimProgram {
    ProgramControl::new(regions(), dev_trust())
}

/// The bootloader at a reset: its decision over the regions, handed to program control. A flash failure (only a
/// simulated power cut causes one) counts as no valid image: the bootloader stays active.
pub fn reset(program: &mut SimProgram) -> Outcome {
    let trust = *program.trust();
    let mut buf = vec![0u8; BOOT_BUF_LEN];
    let outcome = loader::boot(program.flash_mut(), &trust, &mut buf)
        .unwrap_or(Outcome::NoValidImage(ImageError::Flash(FlashError::PowerLoss)));
    program.started(outcome);
    outcome
}

/// The drive's dictionary under `table`, keeping every value (both tables share the generated value layout).
pub fn use_table(drive: &mut Drive, table: Table) {
    drive.dictionary_mut().set_table(table);
}

/// The table program control's mode asks for.
pub fn table_for(mode: Mode) -> Table {
    match mode {
        Mode::Running => APPLICATION_TABLE,
        Mode::Stopped { .. } => BOOTLOADER_TABLE,
    }
}

/// The drive as it starts after a reset: defaults and the stored parameters, the table for `program`'s mode.
pub fn boot_drive(store: &mut ParamStore<SimFlash>, program: &SimProgram) -> Drive {
    boot_drive_with_node_id(store, program, DriveConfig::DEFAULT.node_id)
}

/// [`boot_drive`] on a board whose node-ID, when the parameter store holds none, is `node_id` (the drive in a
/// CAN runner's slot k: k, as a board's switches would set it).
pub fn boot_drive_with_node_id(store: &mut ParamStore<SimFlash>, program: &SimProgram, node_id: u8) -> Drive {
    let mut drive = Drive::boot(DriveConfig { node_id, ..DriveConfig::DEFAULT }, store).0;
    use_table(&mut drive, table_for(program.mode()));
    if let Some(header) = program.running() {
        show_software_version(drive.dictionary_mut(), header.version_str());
    }
    drive
}

/// The simulated drive's dictionary and application objects as a runner has them right after power-on (factory
/// image booted, empty parameter store): what a master reading the dictionary over a fieldbus must see. Tests
/// that compare every object read by a real master take their expectations from here, so the application
/// entries (0x1010/0x1011 through the store, 0x100A and 0x1F5x through program control) are expected as served.
#[derive(Debug)]
pub struct PowerOnObjects {
    /// The drive as booted.
    pub drive: Drive,
    store: ParamStore<SimFlash>,
    program: RefCell<SimProgram>,
}

impl Default for PowerOnObjects {
    fn default() -> Self {
        Self::new()
    }
}

impl PowerOnObjects {
    /// Power-on: the factory program booted, the drive started from an empty store.
    pub fn new() -> Self {
        let mut program = factory_program();
        reset(&mut program);
        let mut store = ParamStore::new(SimFlash::params());
        let drive = boot_drive(&mut store, &program);
        Self { drive, store, program: RefCell::new(program) }
    }

    /// Reads `index:sub` from `offset` as an SDO upload over `interface` does (power stage off).
    pub fn read(
        &mut self,
        interface: Interface,
        index: u16,
        sub: u8,
        offset: usize,
        buf: &mut [u8],
    ) -> Result<ReadOutcome, SdoAbort> {
        let Self { drive, store, program } = self;
        read_through(drive.dictionary(), store, program, interface, index, sub, offset, buf)
    }

    /// [`PowerOnObjects::read`] of the entry values in `dictionary` (a test's own dictionary, e.g. with the
    /// node-ID a CANopen node's boot writes), with these application objects.
    #[allow(clippy::too_many_arguments)]
    pub fn read_in(
        &mut self,
        dictionary: &Dictionary,
        interface: Interface,
        index: u16,
        sub: u8,
        offset: usize,
        buf: &mut [u8],
    ) -> Result<ReadOutcome, SdoAbort> {
        read_through(dictionary, &mut self.store, &self.program, interface, index, sub, offset, buf)
    }
}

#[allow(clippy::too_many_arguments)]
fn read_through(
    dictionary: &Dictionary,
    store: &mut ParamStore<SimFlash>,
    program: &RefCell<SimProgram>,
    interface: Interface,
    index: u16,
    sub: u8,
    offset: usize,
    buf: &mut [u8],
) -> Result<ReadOutcome, SdoAbort> {
    let port = SharedPort::new(program, interface, false);
    let mut drive_objects = DriveObjects::new(store, false).with_program_control(port);
    // The data recorder's objects as the runners serve them at power-on: an idle recorder.
    let mut recorder = Recorder::new();
    let mut app = RecorderObjects::new(&mut recorder, &mut drive_objects);
    dictionary.read(index, sub, offset, buf, &mut app)
}

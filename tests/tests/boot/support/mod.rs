//! Shared helpers of the boot_* tests: the development key, signed test images, the three flash regions of an
//! update on `SimFlash` with the real sector layout of `memory.x`, a factory install into slot A, a download
//! through `boot::update`, and a common power supply for the three regions (a cut during a write to one region
//! stops all of them, as on the chip).
#![allow(dead_code)]

// The development key, trust anchor and payload generator are the simulator's (one definition).
pub use hal_sim::sim::update::{dev_seed, dev_trust as trust, payload};

use std::cell::RefCell;
use std::rc::Rc;

use firmware::boot::image::{ImageHeader, HARDWARE_ID, HEADER_LEN, HEADER_OFFSET};
use firmware::boot::sign::sign_image;
use firmware::boot::swap::BootFlash;
use firmware::boot::update::{Download, UpdateError};
use firmware::flash_map::{BOOT_STATE_LEN, FLASH_LEN, SLOT_B_LEN};
use firmware::hal::flash::{FlashError, Geometry, NorFlash};
use hal_sim::flash::SimFlash;

/// The F405's 128 KiB sectors (slots A and B) and the 64 KiB sector 4 (BOOT_STATE), RM0090 section 3.3.
pub use hal_sim::sim::update::{SLOT_SECTOR, STATE_SECTOR};
/// Copy/verify buffer of the bootloader in these tests.
pub const BUF_LEN: usize = 4096;

/// 32 bytes from a key file's 64 hex digits.
pub fn hex32(text: &str) -> [u8; 32] {
    let t = text.trim();
    assert_eq!(t.len(), 64, "a key file holds 64 hex digits");
    let mut out = [0u8; 32];
    for (i, o) in out.iter_mut().enumerate() {
        *o = u8::from_str_radix(&t[2 * i..2 * i + 2], 16).expect("hex");
    }
    out
}

/// A signed image (header then payload) of firmware `version` with a `len`-byte payload.
pub fn image_signed_with(len: usize, version: u32, hardware_id: u32, seed: &[u8; 32]) -> Vec<u8> {
    let body = payload(len, version);
    let mut header = ImageHeader::new(hardware_id, version, version & 0xFFFF_0000, 0, 0);
    header.version_string[..5].copy_from_slice(format!("v{:04x}", version >> 16).as_bytes());
    sign_image(&mut header, &body, seed, [version as u8; 16]);
    let mut image = header.to_bytes().to_vec();
    image.extend_from_slice(&body);
    image
}

pub fn image(len: usize, version: u32) -> Vec<u8> {
    image_signed_with(len, version, HARDWARE_ID, &dev_seed())
}

/// A signed image of firmware `version` with a `len`-byte payload and security version `security_version`.
pub fn image_with_security(len: usize, version: u32, security_version: u32) -> Vec<u8> {
    let body = payload(len, version);
    let mut header = ImageHeader::new(HARDWARE_ID, version, version & 0xFFFF_0000, 0, 0);
    header.security_version = security_version;
    sign_image(&mut header, &body, &dev_seed(), [version as u8 ^ security_version as u8; 16]);
    let mut image = header.to_bytes().to_vec();
    image.extend_from_slice(&body);
    image
}

/// The security version of the image in slot A as the started application finds it (`loader::running_image`,
/// what program control hands to `Download::clear`); `None` without a valid header.
pub fn slot_a_security_version<A: NorFlash, S: NorFlash>(slot_a: &mut A, state: &mut S) -> Option<u32> {
    match firmware::boot::loader::running_image(slot_a, state, &trust()) {
        firmware::boot::loader::Outcome::Run { header, .. } => Some(header.security_version),
        firmware::boot::loader::Outcome::NoValidImage(_) => None,
    }
}

/// Erased regions with the real layout: slot A 3 x 128 KiB, slot B 4 x 128 KiB, BOOT_STATE 1 x 64 KiB.
pub fn regions() -> BootFlash<SimFlash, SimFlash, SimFlash> {
    assert_eq!(3 * SLOT_SECTOR, FLASH_LEN);
    assert_eq!(4 * SLOT_SECTOR, SLOT_B_LEN);
    assert_eq!(STATE_SECTOR, BOOT_STATE_LEN);
    BootFlash {
        slot_a: SimFlash::new(SLOT_SECTOR, 3, 4),
        slot_b: SimFlash::new(SLOT_SECTOR, 4, 4),
        state: SimFlash::new(STATE_SECTOR, 1, 4),
    }
}

/// Factory programming of slot A (the debugger writes payload and header; no state record).
pub fn factory_install(slot_a: &mut SimFlash, image: &[u8]) {
    let (header, payload) = image.split_at(HEADER_LEN as usize);
    slot_a.program(0, payload).unwrap();
    slot_a.program(HEADER_OFFSET, header).unwrap();
}

/// The image (header then payload) a slot holds, read back raw.
pub fn slot_image(slot: &[u8]) -> Vec<u8> {
    let header = &slot[HEADER_OFFSET as usize..(HEADER_OFFSET + HEADER_LEN) as usize];
    let len = u32::from_le_bytes(header[20..24].try_into().unwrap()) as usize;
    let mut out = header.to_vec();
    out.extend_from_slice(&slot[..len.min(HEADER_OFFSET as usize)]);
    out
}

/// clear -> write in `chunk`-byte pieces -> finish -> activate, stopping at the first error.
pub fn download<B: NorFlash, S: NorFlash>(
    slot_b: &mut B,
    state: &mut S,
    image: &[u8],
    chunk: usize,
) -> Result<ImageHeader, UpdateError> {
    download_over(None, slot_b, state, image, chunk)
}

/// As [`download`], with the security version of the confirmed image in slot A as program control passes it.
pub fn download_over<B: NorFlash, S: NorFlash>(
    slot_a_version: Option<u32>,
    slot_b: &mut B,
    state: &mut S,
    image: &[u8],
    chunk: usize,
) -> Result<ImageHeader, UpdateError> {
    let mut d = Download::new();
    d.clear(slot_b, state, slot_a_version)?;
    for (i, c) in image.chunks(chunk).enumerate() {
        d.write(slot_b, (i * chunk) as u32, c, &trust())?;
    }
    let mut buf = vec![0u8; BUF_LEN];
    let header = d.finish(slot_b, &trust(), &mut buf)?;
    d.activate(state)?;
    Ok(header)
}

/// One power supply for several regions: counts their writes together and cuts at a chosen one.
#[derive(Debug, Default)]
pub struct Supply {
    pub writes: u64,
    pub cut_at: Option<u64>,
    pub seed: u64,
    pub dead: bool,
}

/// A region on a shared [`Supply`].
#[derive(Debug)]
pub struct Powered {
    pub flash: SimFlash,
    pub supply: Rc<RefCell<Supply>>,
}

impl Powered {
    fn write(&mut self, op: impl FnOnce(&mut SimFlash) -> Result<(), FlashError>) -> Result<(), FlashError> {
        let mut s = self.supply.borrow_mut();
        if s.dead {
            return Err(FlashError::PowerLoss);
        }
        let n = s.writes;
        s.writes += 1;
        if s.cut_at == Some(n) {
            // SimFlash tears this write (not done, partly done, or done but unacknowledged) and goes dark.
            self.flash.cut_power_at_write(0, s.seed ^ n.wrapping_mul(0x9E37_79B9_7F4A_7C15));
            s.dead = true;
            let r = op(&mut self.flash);
            return r.and(Err(FlashError::PowerLoss));
        }
        op(&mut self.flash)
    }
}

impl NorFlash for Powered {
    fn geometry(&self) -> Geometry {
        self.flash.geometry()
    }
    fn read(&mut self, offset: u32, buf: &mut [u8]) -> Result<(), FlashError> {
        if self.supply.borrow().dead {
            return Err(FlashError::PowerLoss);
        }
        self.flash.read(offset, buf)
    }
    fn program(&mut self, offset: u32, data: &[u8]) -> Result<(), FlashError> {
        self.write(|f| f.program(offset, data))
    }
    fn erase_sector(&mut self, sector: u32) -> Result<(), FlashError> {
        self.write(|f| f.erase_sector(sector))
    }
}

pub type Board = BootFlash<Powered, Powered, Powered>;

/// The regions on one supply (no cut scheduled).
pub fn on_supply(r: &BootFlash<SimFlash, SimFlash, SimFlash>) -> Board {
    let supply = Rc::new(RefCell::new(Supply::default()));
    let p = |f: &SimFlash| Powered { flash: f.clone(), supply: supply.clone() };
    BootFlash { slot_a: p(&r.slot_a), slot_b: p(&r.slot_b), state: p(&r.state) }
}

/// Schedules a cut at the `k`-th write from now.
pub fn cut_at(board: &Board, k: u64, seed: u64) {
    let mut s = board.state.supply.borrow_mut();
    s.cut_at = Some(s.writes + k);
    s.seed = seed;
}

/// Power back on (a reset): every region works again, no cut pending.
pub fn power_on(board: &mut Board) {
    {
        let mut s = board.state.supply.borrow_mut();
        s.dead = false;
        s.cut_at = None;
    }
    board.slot_a.flash.power_on();
    board.slot_b.flash.power_on();
    board.state.flash.power_on();
}

pub fn writes(board: &Board) -> u64 {
    board.state.supply.borrow().writes
}

/// A copy of the flash contents of a board (a new supply).
pub fn snapshot(board: &Board) -> BootFlash<SimFlash, SimFlash, SimFlash> {
    BootFlash {
        slot_a: board.slot_a.flash.clone(),
        slot_b: board.slot_b.flash.clone(),
        state: board.state.flash.clone(),
    }
}

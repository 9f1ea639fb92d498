//! The two dictionary tables program control switches between (built at compile time from the generated one):
//!
//! * [`APPLICATION_TABLE`]: the generated dictionary. Its 0x100A *Manufacturer software version* is a read-only
//!   RAM string that the platform sets at start to the version string of the image the loader verified (image
//!   header offset 32; [`show_software_version`]), so that it reports the running image (issue 7: "after the
//!   reset, 0x1F56 and 0x100A report the new image"). One table: a second copy of the entries for this one object
//!   would cost 27 KiB of flash.
//! * [`BOOTLOADER_TABLE`]: the reduced object set of a drive whose program is stopped (E4 Table 4-32/4-33,
//!   L2162-2209; comms-faults-bootloader.md §4.2): 0x1000 device type reads 0x0000_012E (CiA 302, E4 L2199),
//!   0x1008, 0x1018 (revision 0x0000_0000, E4 L2190-2209) and 0x1F50, 0x1F51, 0x1F56, 0x1F57 (IDX L3413 adds the
//!   flash status). Every other object answers 0x0602_0000 (object does not exist), as the seeds' bootloader
//!   does not have it.
//!
//! Both keep the generated entries' value offsets, so the drive's value storage is the same under either table.

use crate::od::access::{Dictionary, Table};
use crate::od::entry::{Access, ConstRef, Entry, Object, Storage};
use crate::od::generated::{ENTRIES, OBJECTS};

/// 0x1000 while the program is stopped: CiA 302 (0x012E) in the profile field (E4 L2199).
pub const BOOTLOADER_DEVICE_TYPE: u32 = 0x0000_012E;
/// 0x100A *Manufacturer software version*.
pub const MANUFACTURER_SOFTWARE_VERSION: u16 = 0x100A;

const DEVICE_TYPE_BYTES: &[u8] = &BOOTLOADER_DEVICE_TYPE.to_le_bytes();
const ZERO_U32: &[u8] = &[0; 4];

/// Objects the stopped program keeps (E4 Table 4-33, plus 0x1F57 from IDX L3413).
const BOOTLOADER_OBJECTS: [u16; 7] = [0x1000, 0x1008, 0x1018, 0x1F50, 0x1F51, 0x1F56, 0x1F57];

const ENTRY_COUNT: usize = ENTRIES.len();
const OBJECT_COUNT: usize = OBJECTS.len();

// The tables are computed by the compiler: an index out of range here is a build error, never a run-time panic.
#[allow(clippy::indexing_slicing, clippy::arithmetic_side_effects)]
const fn kept(index: u16) -> bool {
    let mut i = 0;
    while i < BOOTLOADER_OBJECTS.len() {
        if BOOTLOADER_OBJECTS[i] == index {
            return true;
        }
        i += 1;
    }
    false
}

#[allow(clippy::indexing_slicing, clippy::arithmetic_side_effects)]
const fn count_entries() -> usize {
    let mut n = 0;
    let mut i = 0;
    while i < ENTRY_COUNT {
        if kept(ENTRIES[i].index) {
            n += 1;
        }
        i += 1;
    }
    n
}

#[allow(clippy::indexing_slicing, clippy::arithmetic_side_effects)]
const fn count_objects() -> usize {
    let mut n = 0;
    let mut i = 0;
    while i < OBJECT_COUNT {
        if kept(OBJECTS[i].index) {
            n += 1;
        }
        i += 1;
    }
    n
}

const BOOT_ENTRY_COUNT: usize = count_entries();
const BOOT_OBJECT_COUNT: usize = count_objects();

#[allow(clippy::indexing_slicing, clippy::arithmetic_side_effects)]
const fn bootloader_entries() -> [Entry; BOOT_ENTRY_COUNT] {
    let mut out = [ENTRIES[0]; BOOT_ENTRY_COUNT];
    let mut n = 0;
    let mut i = 0;
    while i < ENTRY_COUNT {
        let mut e = ENTRIES[i];
        if kept(e.index) {
            if e.index == 0x1000 {
                e.storage = Storage::Const(ConstRef::new(&DEVICE_TYPE_BYTES));
                e.attributes = e.attributes.with_access(Access::ReadOnly);
            } else if e.index == 0x1018 && e.sub == 3 {
                // Revision: software version and application version both 0x0000 (E4 Table 4-33).
                e.storage = Storage::Const(ConstRef::new(&ZERO_U32));
                e.attributes = e.attributes.with_access(Access::ReadOnly);
            }
            out[n] = e;
            n += 1;
        }
        i += 1;
    }
    out
}

#[allow(clippy::indexing_slicing, clippy::arithmetic_side_effects)]
const fn bootloader_objects() -> [Object; BOOT_OBJECT_COUNT] {
    let mut out = [OBJECTS[0]; BOOT_OBJECT_COUNT];
    let mut n = 0;
    let mut i = 0;
    while i < OBJECT_COUNT {
        let o = OBJECTS[i];
        if kept(o.index) {
            out[n] = o;
            n += 1;
        }
        i += 1;
    }
    out
}

static BOOTLOADER_ENTRIES: [Entry; BOOT_ENTRY_COUNT] = bootloader_entries();
static BOOTLOADER_OBJECT_LIST: [Object; BOOT_OBJECT_COUNT] = bootloader_objects();

/// The application's table: the generated one (module documentation).
pub const APPLICATION_TABLE: Table = Table::GENERATED;

/// Sets 0x100A to `version` (the running image's version string, [`super::image::ImageHeader::version_str`]),
/// NUL-padded to the entry's capacity and cut to it; without the entry (the bootloader's table) nothing changes.
pub fn show_software_version(dictionary: &mut Dictionary, version: &[u8]) {
    let Ok(entry) = dictionary.find(MANUFACTURER_SOFTWARE_VERSION, 0) else { return };
    if let Some(raw) = dictionary.values_mut().raw_mut(entry) {
        raw.fill(0);
        for (to, from) in raw.iter_mut().zip(version) {
            *to = *from;
        }
    }
}

/// The stopped program's reduced table (module documentation).
pub const BOOTLOADER_TABLE: Table = Table::new(&BOOTLOADER_ENTRIES, &BOOTLOADER_OBJECT_LIST);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::od::abort::SdoAbort;

    #[test]
    fn the_bootloader_table_keeps_only_the_seed_objects_and_reports_cia302() {
        let t = BOOTLOADER_TABLE;
        assert_eq!(t.find(0x6040, 0).err(), Some(SdoAbort::ObjectDoesNotExist));
        assert_eq!(t.find(0x1010, 1).err(), Some(SdoAbort::ObjectDoesNotExist));
        assert_eq!(t.find(0x1000, 0).map(|e| e.storage.constant()), Ok(Some(&[0x2E, 0x01, 0, 0][..])));
        for index in BOOTLOADER_OBJECTS {
            assert!(!t.entries_of(index).is_empty(), "{index:#06x}");
            assert_eq!(t.object(index).map(|o| o.index), Some(index));
        }
    }

    #[test]
    fn the_software_version_shows_the_running_image_and_stays_read_only() {
        let mut d = Dictionary::new(1);
        let read = |d: &Dictionary| {
            let mut buf = [0u8; 40];
            let r = d.read(MANUFACTURER_SOFTWARE_VERSION, 0, 0, &mut buf, &mut crate::od::access::NoApplicationObjects);
            buf[..r.unwrap().len].to_vec()
        };
        assert_eq!(read(&d), b"0.1.0".to_vec(), "the device.toml default before the platform sets it");
        show_software_version(&mut d, b"2.0.3");
        assert_eq!(read(&d), b"2.0.3".to_vec());
        show_software_version(&mut d, &[b'9'; 40]);
        assert_eq!(read(&d), vec![b'9'; 32], "cut to the entry's capacity");
        let entry = APPLICATION_TABLE.find(MANUFACTURER_SOFTWARE_VERSION, 0).unwrap();
        assert_eq!(entry.access(), Access::ReadOnly);
    }
}

//! Issue 19 item 4: the bootloader fallback's node-ID and bit rate from the parameter store
//! (`boot::stored_comms`), on flash images written by the real store (`od::store::ParamStore::save` over the
//! generated dictionary on `SimFlash` with the parameter sectors' geometry): valid records, the newer of two,
//! records torn by a power cut at every write of a save, corrupt records, values out of range, a restore of the
//! manufacturer group, nothing stored. In every case the reader must agree with what the application loads
//! (`ParamStore::load`, then the start-up's own checks: node-ID 1..=127, an offered bit-rate code), and fall
//! back to the device defaults (node-ID 1, 1 Mbit/s) for what is not validly stored.

use firmware::boot::stored_comms::{stored_comms, FallbackComms};
use firmware::canopen::frame::BitRate;
use firmware::canopen::ids::{BIT_RATE_OBJECT, NODE_ID_OBJECT};
use firmware::hal::flash::NorFlash;
use firmware::od::generated::{DEFAULT_NODE_ID, ENTRIES};
use firmware::od::store::{ParamStore, Selection};
use firmware::od::values::{self, Values};
use hal_sim::flash::SimFlash;

const DEFAULTS: FallbackComms = FallbackComms { node_id: 1, bit_rate: BitRate::Kbit1000 };

/// The default value image with 0x2000 = `node_id` and 0x2001 = `rate_code` (raw, not range-checked: the store
/// saves what the image holds).
fn image_with(node_id: u8, rate_code: u8) -> Vec<u8> {
    let mut v = Values::new(DEFAULT_NODE_ID).bytes().to_vec();
    let set = |v: &mut Vec<u8>, index: u16, value: u8| {
        let entry = ENTRIES.iter().find(|e| e.index == index && e.sub == 0).expect("entry");
        assert!(values::set_unsigned(v, entry, u64::from(value)));
    };
    set(&mut v, NODE_ID_OBJECT, node_id);
    set(&mut v, BIT_RATE_OBJECT, rate_code);
    v
}

fn saved(flash: SimFlash, node_id: u8, rate_code: u8) -> SimFlash {
    let mut store = ParamStore::new(flash);
    store.save(Selection::All, &ENTRIES, &image_with(node_id, rate_code)).expect("save");
    store.into_flash()
}

/// What the application starts with from this flash: the store's load over the defaults, then its checks.
fn application_view(flash: &SimFlash) -> FallbackComms {
    let mut store = ParamStore::new(flash.clone());
    let mut v = Values::new(DEFAULT_NODE_ID).bytes().to_vec();
    store.load(Selection::All, &ENTRIES, &mut v).expect("load");
    let read = |index: u16| {
        let entry = ENTRIES.iter().find(|e| e.index == index && e.sub == 0).unwrap();
        values::unsigned(&v, entry).unwrap() as u8
    };
    let node_id = read(NODE_ID_OBJECT);
    FallbackComms {
        node_id: if (1..=127).contains(&node_id) { node_id } else { DEFAULT_NODE_ID },
        bit_rate: BitRate::from_code(read(BIT_RATE_OBJECT)).unwrap_or_default(),
    }
}

fn read(flash: &SimFlash) -> FallbackComms {
    let r = stored_comms(&mut flash.clone());
    assert_eq!(r, application_view(flash), "the bootloader and the application disagree");
    r
}

#[test]
fn nothing_stored_gives_the_device_defaults() {
    assert_eq!(read(&SimFlash::params()), DEFAULTS);
}

/// A saved node-ID and bit rate are used; of two records the newer (by sequence number) counts, whichever
/// sector holds it.
#[test]
fn the_saved_node_id_and_bit_rate_of_the_newest_record_are_used() {
    let first = saved(SimFlash::params(), 42, 3);
    assert_eq!(read(&first), FallbackComms { node_id: 42, bit_rate: BitRate::Kbit250 });
    let second = saved(first, 17, 7);
    assert_eq!(read(&second), FallbackComms { node_id: 17, bit_rate: BitRate::Kbit20 });
    let third = saved(second, 127, 2);
    assert_eq!(read(&third), FallbackComms { node_id: 127, bit_rate: BitRate::Kbit500 });
}

/// Values the store holds but the drive cannot use: node-IDs 0 and 128..=255, the bit-rate codes 5 (not offered)
/// and 8..; each falls back to its own default, the other value is kept.
#[test]
fn values_out_of_range_fall_back_to_their_defaults_one_by_one() {
    for (node_id, code, expected) in [
        (0, 2, FallbackComms { node_id: 1, bit_rate: BitRate::Kbit500 }),
        (128, 4, FallbackComms { node_id: 1, bit_rate: BitRate::Kbit125 }),
        (255, 6, FallbackComms { node_id: 1, bit_rate: BitRate::Kbit50 }),
        (5, 5, FallbackComms { node_id: 5, bit_rate: BitRate::Kbit1000 }),
        (99, 9, FallbackComms { node_id: 99, bit_rate: BitRate::Kbit1000 }),
        (0, 200, DEFAULTS),
    ] {
        assert_eq!(read(&saved(SimFlash::params(), node_id, code)), expected, "{node_id}/{code}");
    }
}

/// A flipped bit anywhere in the newest record (header, payload) invalidates it: the older record counts; with
/// only one record, the defaults. The commit word missing (a save cut before its last write) likewise.
#[test]
fn a_corrupt_or_uncommitted_record_is_ignored() {
    let one = saved(SimFlash::params(), 42, 3);
    let two = saved(one.clone(), 17, 7);
    let sector = firmware::flash_map::PARAMS_SECTOR_SIZE as usize;
    let newest_at = sector; // the second save went to sector 1
    let payload_len = u32::from_le_bytes(two.contents()[newest_at + 12..newest_at + 16].try_into().unwrap());
    for offset in [0, 6, 8, 12, 16, 24, 32, 40, 32 + payload_len as usize - 1] {
        let mut bad = two.clone();
        bad.contents_mut()[newest_at + offset] ^= 0x10;
        assert_eq!(read(&bad), FallbackComms { node_id: 42, bit_rate: BitRate::Kbit250 }, "bit flip at {offset}");
        let mut only = one.clone();
        only.contents_mut()[offset] ^= 0x10;
        assert_eq!(read(&only), DEFAULTS, "bit flip at {offset} of the only record");
    }
    let mut uncommitted = two.clone();
    uncommitted.contents_mut()[newest_at + 28..newest_at + 32].fill(0xFF);
    assert_eq!(read(&uncommitted), FallbackComms { node_id: 42, bit_rate: BitRate::Kbit250 });
}

/// A power cut at every write of a save (each write torn as `SimFlash` chooses from the seed): the reader sees
/// the old values or the new ones, never others, and always what the application loads.
#[test]
fn a_save_torn_at_every_write_gives_the_old_or_the_new_values() {
    let old = saved(SimFlash::params(), 42, 3);
    let clean_writes = {
        let mut f = old.clone();
        let before = f.write_count();
        let mut store = ParamStore::new(f.clone());
        store.save(Selection::All, &ENTRIES, &image_with(17, 7)).unwrap();
        f = store.into_flash();
        f.write_count() - before
    };
    let (mut olds, mut news) = (0, 0);
    // Every write with one tear; the last one (the commit word, which decides) with several.
    let cuts = (0..clean_writes).map(|k| (k, 0xC0DE ^ k)).chain((0..16).map(|s| (clean_writes - 1, s)));
    for (k, seed) in cuts {
        let mut f = old.clone();
        f.cut_power_at_write(k, seed);
        let mut store = ParamStore::new(f);
        let _ = store.save(Selection::All, &ENTRIES, &image_with(17, 7));
        let mut f = store.into_flash();
        f.power_on();
        match read(&f) {
            FallbackComms { node_id: 42, bit_rate: BitRate::Kbit250 } => olds += 1,
            FallbackComms { node_id: 17, bit_rate: BitRate::Kbit20 } => news += 1,
            other => panic!("cut at write {k}: {other:?}"),
        }
    }
    eprintln!("stored comms: {clean_writes} cut points, old {olds}x, new {news}x");
    assert!(olds > 0 && news > 0);
}

/// 0x1011 "load" of the manufacturer group (or of all) writes a record without 0x2000/0x2001: the defaults count
/// at the next start, also in the bootloader, although an older record still holds the saved values.
#[test]
fn restored_defaults_are_the_defaults_for_the_fallback_too() {
    for selection in [Selection::All, Selection::Only(firmware::od::store::Group::Manufacturer)] {
        let mut store = ParamStore::new(saved(SimFlash::params(), 42, 3));
        store.restore_defaults(selection).unwrap();
        assert_eq!(read(&store.into_flash()), DEFAULTS, "{selection:?}");
    }
    // A record whose header does not list the manufacturer group although its payload holds the items (not what
    // the writer makes; header edited and its CRC made valid again): the application skips them, so does the
    // reader.
    let mut f = saved(SimFlash::params(), 42, 3);
    let c = f.contents_mut();
    c[6] &= !0b100;
    let payload_len = u32::from_le_bytes(c[12..16].try_into().unwrap()) as usize;
    let mut covered = c[32..32 + payload_len].to_vec();
    covered.extend_from_slice(&c[..24]);
    let crc = firmware::od::store::crc32(&covered);
    c[24..28].copy_from_slice(&crc.to_le_bytes());
    assert_eq!(read(&f), DEFAULTS, "manufacturer group not stored");
    // Restoring another group keeps them.
    let mut store = ParamStore::new(saved(SimFlash::params(), 42, 3));
    store.restore_defaults(Selection::Only(firmware::od::store::Group::Application)).unwrap();
    assert_eq!(read(&store.into_flash()), FallbackComms { node_id: 42, bit_rate: BitRate::Kbit250 });
}

/// The reader goes through `NorFlash::read` only (no writes): the parameter sectors are untouched.
#[test]
fn reading_writes_nothing() {
    let f = saved(SimFlash::params(), 42, 3);
    let mut copy = f.clone();
    let before = copy.write_count();
    let _ = stored_comms(&mut copy);
    assert_eq!(copy.write_count(), before);
    assert_eq!(copy.contents(), f.contents());
    let _ = copy.geometry();
}

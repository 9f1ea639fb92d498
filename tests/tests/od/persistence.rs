//! Parameter persistence (0x1010 "save", 0x1011 "load") on the simulated NOR flash with power cuts.
//!
//! * A power cut during any single flash write of a save (or a restore) leaves, at the next boot, either the
//!   complete old or the complete new parameter set; both outcomes occur, and a cut during the erase keeps the old.
//! * Repeated saves alternate sectors, count the sequence up and wear both sectors alternately.
//! * Restore defaults (0x1011) leaves the running values alone and gives the defaults after the next reset
//!   (CiA 301 §7.5.2.14, IDX L1702); a group restore affects only its group; a group save keeps the others.
//! * Wrong signatures abort with 0x0800_0020 (CiA 301 §7.5.2.13/14); reads give 1.
//! * Random flash contents never panic and give the defaults; entries a firmware update changed are skipped.
//!
//! The tests run on the generated dictionary (`firmware::od::generated`) and on a small hand-written table.

use firmware::hal::flash::NorFlash;
use firmware::od::abort::SdoAbort;
use firmware::od::access::{AccessContext, CommState, Dictionary};
use firmware::od::entry::{Access, Attributes, DataType, Entry, LimitsRef, Name, PdoMapping, Storage, WriteCondition};
use firmware::od::generated::ENTRIES;
use firmware::od::store::{
    store_group_of, Group, ParamStore, Selection, StoreError, StoreObjects, LOAD_SIGNATURE, RECORD_HEADER_LEN,
    SAVE_SIGNATURE,
};
use firmware::od::values::Values;
use hal_sim::flash::{SimFlash, Tear};

const NODE_ID: u8 = 5;

/// A dictionary table and its default value image.
#[derive(Clone)]
struct Table {
    entries: Vec<Entry>,
    defaults: Vec<u8>,
}

fn generated() -> Table {
    Table { entries: ENTRIES.to_vec(), defaults: Values::new(NODE_ID).bytes().to_vec() }
}

fn ram_entry(index: u16, sub: u8, data_type: DataType, persistent: bool, offset: u16, len: u16) -> Entry {
    Entry {
        index,
        sub,
        name: Name::EMPTY,
        data_type,
        attributes: Attributes::new(Access::ReadWrite, PdoMapping::No, persistent, WriteCondition::Always),
        limits: LimitsRef::NONE,
        storage: Storage::Ram { offset, len, node_id_relative: false },
    }
}

/// A small table with persistent entries in all three groups, a non-persistent one and a string.
fn hand_table() -> Table {
    let mut entries = Vec::new();
    let mut offset = 0u16;
    let mut add = |index, sub, ty: DataType, persistent, len: u16| {
        entries.push(ram_entry(index, sub, ty, persistent, offset, len));
        offset += len;
    };
    add(0x1017, 0, DataType::Unsigned16, true, 2);
    add(0x1600, 1, DataType::Unsigned32, true, 4);
    add(0x1600, 2, DataType::Unsigned32, true, 4);
    add(0x2000, 0, DataType::Unsigned8, true, 1);
    add(0x210C, 1, DataType::VisibleString, true, 40);
    add(0x30A0, 1, DataType::Unsigned32, true, 4);
    add(0x6040, 0, DataType::Unsigned16, false, 2);
    add(0x605A, 0, DataType::Integer16, true, 2);
    add(0x6081, 0, DataType::Unsigned32, true, 4);
    add(0x6083, 0, DataType::Unsigned32, true, 4);
    let defaults = (0..offset).map(|i| (i as u8).wrapping_mul(7)).collect();
    Table { entries, defaults }
}

fn tables() -> Vec<(&'static str, Table)> {
    let mut t = vec![("hand-written", hand_table())];
    if ENTRIES.iter().any(|e| e.persistent() && matches!(e.storage, Storage::Ram { .. })) {
        t.push(("generated", generated()));
    }
    t
}

/// The RAM slot of an entry.
fn slot(e: &Entry) -> Option<std::ops::Range<usize>> {
    match e.storage {
        Storage::Ram { offset, len, .. } => Some(offset as usize..offset as usize + len as usize),
        _ => None,
    }
}

/// Changes every persistent RAM value of `selection` (the `salt` picks which different value).
fn mutate(table: &Table, values: &mut [u8], selection: Selection, salt: u8) {
    let x = 0x11u8.wrapping_mul(salt.wrapping_add(1)) | 1;
    for e in table.entries.iter().filter(|e| e.persistent() && selection.covers(e.index)) {
        if let Some(r) = slot(e) {
            for (j, b) in values[r].iter_mut().enumerate() {
                *b ^= x.rotate_left(j as u32);
            }
        }
    }
}

/// Powers the flash on and boots: defaults plus what the store loads.
fn boot(table: &Table, mut flash: SimFlash) -> (Vec<u8>, SimFlash) {
    flash.power_on();
    let mut values = table.defaults.clone();
    let mut store = ParamStore::new(flash);
    store.load(Selection::All, &table.entries, &mut values).expect("load after power-on");
    (values, store.into_flash())
}

/// Number of persistent RAM entries.
fn persistent_count(table: &Table) -> usize {
    table.entries.iter().filter(|e| e.persistent() && slot(e).is_some()).count()
}

#[derive(Default, Debug)]
struct Outcomes {
    old: usize,
    new: usize,
}

/// Runs `op` on copies of `flash` with a power cut during each of its writes (and with several tears each),
/// boots, and checks that exactly `old` or `new` is loaded. Returns how often each occurred.
fn cut_everywhere(
    table: &Table,
    flash: &SimFlash,
    op: &dyn Fn(&mut ParamStore<SimFlash>) -> Result<(), StoreError>,
    old: &[u8],
    new: &[u8],
) -> Outcomes {
    assert_ne!(old, new, "the operation must change the persistent set");
    // Count the writes of the operation on a copy without a cut.
    let mut probe = ParamStore::new(flash.clone());
    let before = probe.flash().write_count();
    op(&mut probe).expect("operation without a cut");
    let writes = probe.flash().write_count() - before;
    assert!(writes >= 4, "erase, payload, header, commit: {writes}");
    assert_eq!(boot(table, probe.into_flash()).0, new, "uninterrupted operation gives the new set");

    let mut outcomes = Outcomes::default();
    for k in 0..writes {
        // Seeds until the cut write has been torn every way (not at all, partly, completely but unacknowledged).
        let mut tears = Vec::new();
        for seed in 0..64u64 {
            if [Tear::None, Tear::Partial, Tear::Complete].iter().all(|t| tears.contains(t)) {
                break;
            }
            let mut f = flash.clone();
            f.cut_power_at_write(k, seed.wrapping_mul(0x9E37_79B9).wrapping_add(k));
            let mut store = ParamStore::new(f);
            let result = op(&mut store);
            assert_eq!(result, Err(StoreError::Flash(firmware::hal::flash::FlashError::PowerLoss)), "k = {k}");
            tears.push(store.flash().last_tear().expect("the cut happened"));
            let (loaded, f) = boot(table, store.into_flash());
            if loaded == old {
                outcomes.old += 1;
            } else if loaded == new {
                outcomes.new += 1;
            } else {
                panic!("cut at write {k} (seed {seed}) loaded neither the old nor the new set");
            }
            if k == 0 {
                assert_eq!(loaded, old, "a cut during the erase keeps the old set");
            }
            // After the cut the store works again: the next save lands and is loaded.
            if seed == 0 {
                let mut again = new.to_vec();
                mutate(table, &mut again, Selection::All, 9);
                let mut store = ParamStore::new(f);
                store.save(Selection::All, &table.entries, &again).expect("save after the cut");
                assert_eq!(boot(table, store.into_flash()).0, again, "save after a cut at write {k}");
            }
        }
        assert_eq!(tears.len().min(3), 3, "write {k} was torn every way: {tears:?}");
    }
    outcomes
}

#[test]
fn power_cut_after_every_write_of_a_save_loads_old_or_new_set() {
    for (name, table) in tables() {
        assert!(persistent_count(&table) > 0, "{name}");
        // The old set: stored once.
        let mut old = table.defaults.clone();
        mutate(&table, &mut old, Selection::All, 1);
        let mut store = ParamStore::new(SimFlash::params());
        store.save(Selection::All, &table.entries, &old).expect("first save");
        let flash = store.into_flash();
        assert_eq!(boot(&table, flash.clone()).0, old, "{name}: first save loads");

        // Save a changed set with a cut during every write.
        let mut new = old.clone();
        mutate(&table, &mut new, Selection::All, 2);
        let save = |s: &mut ParamStore<SimFlash>| s.save(Selection::All, &table.entries, &new).map(|_| ());
        let o = cut_everywhere(&table, &flash, &save, &old, &new);
        println!("{name}: {o:?}");
        assert!(o.old > 0 && o.new > 0, "{name}: both outcomes occur: {o:?}");

        // The same from the other sector (old record in sector 1, new goes to sector 0).
        let mut store = ParamStore::new(flash.clone());
        store.save(Selection::All, &table.entries, &new).expect("second save");
        assert_eq!(store.current().unwrap().map(|r| r.sector), Some(1));
        let flash2 = store.into_flash();
        let mut newer = new.clone();
        mutate(&table, &mut newer, Selection::All, 3);
        let save = |s: &mut ParamStore<SimFlash>| s.save(Selection::All, &table.entries, &newer).map(|_| ());
        let o = cut_everywhere(&table, &flash2, &save, &new, &newer);
        assert!(o.old > 0 && o.new > 0, "{name}: both outcomes occur from sector 1: {o:?}");
    }
}

#[test]
fn power_cut_during_group_save_and_restore_keeps_the_other_groups() {
    for (name, table) in tables() {
        let mut old = table.defaults.clone();
        mutate(&table, &mut old, Selection::All, 1);
        let mut store = ParamStore::new(SimFlash::params());
        store.save(Selection::All, &table.entries, &old).expect("save");
        let flash = store.into_flash();

        // Save only the application group of a set in which every group changed.
        let mut running = old.clone();
        mutate(&table, &mut running, Selection::All, 4);
        let mut new = old.clone();
        mutate(&table, &mut new, Selection::Only(Group::Application), 4);
        let save = |s: &mut ParamStore<SimFlash>| {
            s.save(Selection::Only(Group::Application), &table.entries, &running).map(|_| ())
        };
        let o = cut_everywhere(&table, &flash, &save, &old, &new);
        assert!(o.old > 0 && o.new > 0, "{name}: group save: {o:?}");

        // Restore the communication group: its defaults come back at the next boot, the others stay.
        let mut restored = old.clone();
        for e in table.entries.iter().filter(|e| e.persistent() && store_group_of(e.index) == Group::Communication) {
            if let Some(r) = slot(e) {
                restored[r.clone()].copy_from_slice(&table.defaults[r]);
            }
        }
        let restore =
            |s: &mut ParamStore<SimFlash>| s.restore_defaults(Selection::Only(Group::Communication)).map(|_| ());
        let o = cut_everywhere(&table, &flash, &restore, &old, &restored);
        assert!(o.old > 0 && o.new > 0, "{name}: group restore: {o:?}");
    }
}

#[test]
fn repeated_saves_alternate_sectors_and_wear_both() {
    let table = tables().pop().unwrap().1;
    let mut store = ParamStore::new(SimFlash::params());
    assert_eq!(store.current().unwrap(), None);
    let mut values = table.defaults.clone();
    for i in 1..=9u32 {
        mutate(&table, &mut values, Selection::All, i as u8);
        let info = store.save(Selection::All, &table.entries, &values).expect("save");
        assert_eq!(info.sequence, i);
        assert_eq!(info.sector, (i - 1) % 2, "sectors alternate");
        assert_eq!(store.current().unwrap(), Some(info));
        assert_eq!(store.flash().erase_counts(), &[i.div_ceil(2), i / 2], "wear alternates");
        let flash = store.into_flash();
        let (loaded, flash) = boot(&table, flash);
        assert_eq!(loaded, values, "save {i} is loaded");
        store = ParamStore::new(flash);
    }
    // A save writes one erase plus a handful of programs, not one per word.
    let before = store.flash().write_count();
    store.save(Selection::All, &table.entries, &values).unwrap();
    let payload: usize = table.entries.iter().filter(|e| e.persistent()).filter_map(slot).map(|r| r.len() + 5).sum();
    assert!(store.flash().write_count() - before <= 3 + payload.div_ceil(128) as u64);
}

fn pre_op() -> AccessContext {
    AccessContext { comm_state: CommState::PreOperational, power_stage_enabled: false, max_pdo_bytes: 40 }
}

#[test]
fn restore_defaults_takes_effect_at_next_reset() {
    for (name, table) in tables() {
        let mut store = ParamStore::new(SimFlash::params());
        let mut running = table.defaults.clone();
        mutate(&table, &mut running, Selection::All, 1);
        store.write_command(0x1010, 1, &SAVE_SIGNATURE.to_le_bytes(), &table.entries, &running).expect("save");

        // 0x1011:1 "load": the running values stay as they are...
        let before = running.clone();
        store.write_command(0x1011, 1, &LOAD_SIGNATURE.to_le_bytes(), &table.entries, &running).expect("restore");
        assert_eq!(running, before, "{name}: running values unchanged until reset");
        let info = store.current().unwrap().expect("a record remains");
        assert!(info.stored.is_empty() && info.restored.bits() == 0b111, "{name}: {info:?}");
        // ...and after the reset they are the defaults.
        let (loaded, flash) = boot(&table, store.into_flash());
        assert_eq!(loaded, table.defaults, "{name}: defaults after reset");

        // Group restore: only that group returns to its defaults.
        let mut store = ParamStore::new(flash);
        store.save(Selection::All, &table.entries, &running).unwrap();
        for group in Group::ALL {
            let mut s = ParamStore::new(store.flash().clone());
            s.restore_defaults(Selection::Only(group)).unwrap();
            let (loaded, _) = boot(&table, s.into_flash());
            for e in table.entries.iter().filter(|e| e.persistent()) {
                let Some(r) = slot(e) else { continue };
                let expected =
                    if store_group_of(e.index) == group { &table.defaults[r.clone()] } else { &running[r.clone()] };
                assert_eq!(&loaded[r], expected, "{name}: {:#06x}:{} after restoring {group:?}", e.index, e.sub);
            }
        }

        // Saving after a restore stores the running values again (CiA 301: save stores the current values).
        store.restore_defaults(Selection::All).unwrap();
        store.save(Selection::Only(Group::Manufacturer), &table.entries, &running).unwrap();
        let (loaded, _) = boot(&table, store.into_flash());
        let mut expected = table.defaults.clone();
        for e in table.entries.iter().filter(|e| e.persistent() && store_group_of(e.index) == Group::Manufacturer) {
            if let Some(r) = slot(e) {
                expected[r.clone()].copy_from_slice(&running[r]);
            }
        }
        assert_eq!(loaded, expected, "{name}: only the re-saved group is stored");
    }
}

#[test]
fn signatures_and_reads_follow_cia_301() {
    let table = hand_table();
    let mut store = ParamStore::new(SimFlash::params());
    let v = table.defaults.clone();
    for sub in 1..=4 {
        for index in [0x1010, 0x1011] {
            assert_eq!(ParamStore::<SimFlash>::read_command(index, sub), Ok(1));
            let wrong = if index == 0x1010 { LOAD_SIGNATURE } else { SAVE_SIGNATURE };
            let e = store.write_command(index, sub, &wrong.to_le_bytes(), &table.entries, &v).unwrap_err();
            assert_eq!(e, StoreError::WrongSignature);
            assert_eq!(e.abort(), SdoAbort::CannotTransfer);
            assert_eq!(SdoAbort::from(e) as u32, 0x0800_0020);
            let e = store.write_command(index, sub, &0u32.to_le_bytes(), &table.entries, &v).unwrap_err();
            assert_eq!(e.abort() as u32, 0x0800_0020);
        }
    }
    assert_eq!(ParamStore::<SimFlash>::read_command(0x1010, 0), Ok(4));
    assert_eq!(ParamStore::<SimFlash>::read_command(0x1010, 5), Err(StoreError::NoSuchSubIndex));
    assert_eq!(ParamStore::<SimFlash>::read_command(0x1012, 1), Err(StoreError::NoSuchObject));
    let save = SAVE_SIGNATURE.to_le_bytes();
    assert_eq!(store.write_command(0x1010, 0, &save, &table.entries, &v), Err(StoreError::ReadOnly));
    assert_eq!(store.write_command(0x1010, 5, &save, &table.entries, &v), Err(StoreError::NoSuchSubIndex));
    assert_eq!(store.write_command(0x1010, 1, &save[..3], &table.entries, &v), Err(StoreError::WrongLength));
    // None of the refused writes touched the flash.
    assert_eq!(store.flash().write_count(), 0);
}

#[test]
fn save_and_restore_through_the_dictionary() {
    if !ENTRIES.iter().any(|e| e.index == 0x1010 && e.storage == Storage::Application) {
        eprintln!("generated table has no application-served 0x1010; skipped");
        return;
    }
    let table = generated();
    let mut dict = Dictionary::new(NODE_ID);
    let mut store = ParamStore::new(SimFlash::params());
    mutate(&table, dict.values_mut().bytes_mut(), Selection::All, 1);
    let running = dict.values().bytes().to_vec();
    let mut hook = StoreObjects { store: &mut store, entries: &ENTRIES };

    let mut buf = [0u8; 4];
    let read = dict.read(0x1010, 1, 0, &mut buf, &mut hook).expect("read 0x1010:1");
    assert_eq!((read.len, u32::from_le_bytes(buf)), (4, 1));
    let bad = dict.write(0x1010, 1, &0x1234_5678u32.to_le_bytes(), pre_op(), &mut hook);
    assert_eq!(bad, Err(SdoAbort::CannotTransfer));
    dict.write(0x1010, 1, &SAVE_SIGNATURE.to_le_bytes(), pre_op(), &mut hook).expect("save");
    assert_eq!(boot(&table, hook.store.flash().clone()).0, running);

    // Restore is refused in Operational (IDX L1702) and accepted in Pre-Operational with the power disabled.
    let op = AccessContext { comm_state: CommState::Operational, ..pre_op() };
    assert!(dict.write(0x1011, 1, &LOAD_SIGNATURE.to_le_bytes(), op, &mut hook).is_err());
    dict.write(0x1011, 1, &LOAD_SIGNATURE.to_le_bytes(), pre_op(), &mut hook).expect("restore");
    assert_eq!(dict.values().bytes().as_slice(), running.as_slice(), "running values unchanged");
    assert_eq!(boot(&table, store.into_flash()).0, table.defaults);
}

#[test]
fn random_flash_contents_never_panic_and_give_defaults() {
    for (name, table) in tables() {
        for seed in 0..64 {
            let mut flash = SimFlash::params();
            flash.fill_random(seed);
            let mut store = ParamStore::new(flash);
            let mut values = table.defaults.clone();
            let report = store.load(Selection::All, &table.entries, &mut values).expect("load");
            assert_eq!(report.record, None, "{name} seed {seed}");
            assert_eq!(values, table.defaults);
            // A save on top of garbage works (it erases first).
            let mut running = table.defaults.clone();
            mutate(&table, &mut running, Selection::All, 3);
            store.save(Selection::All, &table.entries, &running).expect("save over garbage");
            assert_eq!(boot(&table, store.into_flash()).0, running);
        }
        // Valid-looking headers with garbage behind them, and single bit flips in a committed record.
        let mut running = table.defaults.clone();
        mutate(&table, &mut running, Selection::All, 5);
        let mut store = ParamStore::new(SimFlash::params());
        store.save(Selection::All, &table.entries, &running).unwrap();
        let good = store.into_flash();
        let len = (RECORD_HEADER_LEN as usize + 600).min(good.contents().len() / 2);
        for bit in (0..len * 8).step_by(7) {
            let mut f = good.clone();
            f.contents_mut()[bit / 8] ^= 1 << (bit % 8);
            let (loaded, _) = boot(&table, f);
            assert!(loaded == running || loaded == table.defaults, "{name}: bit {bit} flipped gave a mixed set");
        }
    }
}

#[test]
fn firmware_update_skips_unknown_and_resized_entries() {
    let old_fw = hand_table();
    let mut running = old_fw.defaults.clone();
    mutate(&old_fw, &mut running, Selection::All, 1);
    let mut store = ParamStore::new(SimFlash::params());
    store.save(Selection::All, &old_fw.entries, &running).unwrap();

    // The new firmware drops 0x6083, widens 0x605A to 4 bytes and makes 0x30A0:1 non-persistent.
    let mut new_fw = old_fw.clone();
    new_fw.entries.retain(|e| e.index != 0x6083);
    for e in &mut new_fw.entries {
        if e.index == 0x605A {
            e.storage = Storage::Ram { offset: old_fw.defaults.len() as u16, len: 4, node_id_relative: false };
        }
        if e.index == 0x30A0 {
            e.attributes = e.attributes.with_persistent(false);
        }
    }
    new_fw.defaults.extend_from_slice(&[1, 2, 3, 4]);
    let mut values = new_fw.defaults.clone();
    let report = store.load(Selection::All, &new_fw.entries, &mut values).unwrap();
    assert_eq!((report.unknown, report.mismatched), (2, 1), "{report:?}");
    assert_eq!(report.applied as usize, persistent_count(&old_fw) - 3);
    for e in &new_fw.entries {
        let r = slot(e).unwrap();
        let expected =
            if e.persistent() && e.index != 0x605A { &running[r.clone()] } else { &new_fw.defaults[r.clone()] };
        assert_eq!(&values[r], expected, "{:#06x}:{}", e.index, e.sub);
    }
}

#[test]
fn a_record_larger_than_a_sector_is_refused_and_the_old_one_kept() {
    let mut table = hand_table();
    let mut store = ParamStore::new(SimFlash::new(256, 2, 4));
    store.save(Selection::All, &table.entries, &table.defaults).expect("fits");
    // Grow the string entry beyond the sector.
    let base = table.defaults.len() as u16;
    table.entries.push(ram_entry(0x6090, 0, DataType::OctetString, true, base, 300));
    table.defaults.extend(std::iter::repeat_n(0xAB, 300));
    let big = table.defaults.clone();
    assert_eq!(store.save(Selection::All, &table.entries, &big), Err(StoreError::TooLarge));
    assert_eq!(store.current().unwrap().map(|r| r.sequence), Some(1));
    assert_eq!(store.flash().geometry().sector_count, 2);
}

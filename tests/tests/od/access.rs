//! Conformance of dictionary access on the generated dictionary: read/write permissions of every entry against
//! its declared access type (IDX 6.1.3), and each SDO abort code the access layer returns (CiA 301 Table 22)
//! for the failure it names, including the PDO mapping and assignment procedure (CiA 301 §7.5.2.36; IDX
//! L2196-L2216; ETG.1000.6 0x1C12/0x1C13).

use crate::support::*;
use firmware::od::abort::SdoAbort;
use firmware::od::access::{AccessContext, CommState, Download, NoApplicationObjects};
use firmware::od::entry::{Access, DataType, Entry, Limits, PdoMapping, Storage, WriteCondition};
use firmware::od::pdo_map::{self, MapEntry, MapTarget};
use firmware::recorder::Recorder;

/// A value the entry accepts, to write back: its current value for RAM entries, 1 for fixed-size application
/// entries (within any limits), some bytes for an application domain.
fn acceptable_value(dict: &firmware::od::access::Dictionary, entry: &'static Entry) -> Vec<u8> {
    match entry.storage {
        Storage::Ram { .. } => dict.values().raw(entry).expect("slot").to_vec(),
        Storage::Const(bytes) => bytes.bytes().to_vec(),
        Storage::Application => match entry.data_type.fixed_size() {
            Some(size) => {
                let value = match *entry.generated_limits() {
                    Limits::Signed { min, .. } => i128::from(min),
                    Limits::Unsigned { min, .. } => i128::from(min),
                    Limits::OneOf(list) => i128::from(list[0]),
                    Limits::None => 0,
                };
                encode(value, size)
            }
            None => b"program".to_vec(),
        },
    }
}

#[test]
fn generated_table_is_sorted_and_not_empty() {
    let entries = entries();
    assert!(!entries.is_empty(), "the generated dictionary is empty");
    for pair in entries.windows(2) {
        assert!(
            (pair[0].index, pair[0].sub) < (pair[1].index, pair[1].sub),
            "{:04X}:{:02X}",
            pair[1].index,
            pair[1].sub
        );
    }
}

#[test]
fn every_entry_is_found_and_its_neighbours_are_not() {
    let dict = dictionary();
    for entry in entries() {
        assert_eq!(dict.find(entry.index, entry.sub), Ok(entry));
        let object = dict.object(entry.index).expect("object header");
        assert!(entry.sub <= object.max_sub);
    }
    assert_eq!(dict.find(0x0FFF, 0), Err(SdoAbort::ObjectDoesNotExist));
    assert_eq!(dict.find(0xFFFF, 0), Err(SdoAbort::ObjectDoesNotExist));
}

#[test]
fn reads_match_the_access_type_of_every_entry() {
    let dict = dictionary();
    for entry in entries() {
        let what = format!("{:04X}:{:02X} {}", entry.index, entry.sub, entry.name);
        if Recorder::serves(entry.index) {
            // Served by the data recorder behind the port, from its own state (the buffer only once a recording
            // is complete): `firmware::recorder`'s tests and tests/tests/drive/recorder.rs read them.
            continue;
        }
        let mut app = TestApp::default();
        let mut buf = [0u8; 256];
        let result = dict.read(entry.index, entry.sub, 0, &mut buf, &mut app);
        if entry.access() == Access::WriteOnly {
            assert_eq!(result, Err(SdoAbort::WriteOnly), "{what}");
            continue;
        }
        let expected = expected_read(&dict, entry);
        let outcome = result.unwrap_or_else(|e| panic!("{what}: {e:?}"));
        assert_eq!(outcome.total_len, expected.len(), "{what}");
        assert_eq!(&buf[..outcome.len], &expected[..], "{what}");
        if let Some(size) = entry.data_type.fixed_size() {
            assert_eq!(outcome.len, size, "{what}: fixed-size read has the type's length");
        }
        // A partial read from offset 1 returns the rest.
        if expected.len() > 1 {
            let outcome = dict.read(entry.index, entry.sub, 1, &mut buf, &mut app).expect("partial read");
            assert_eq!(&buf[..outcome.len], &expected[1..], "{what}");
        }
    }
}

#[test]
fn writes_match_the_access_type_and_condition_of_every_entry() {
    for entry in entries() {
        let what = format!("{:04X}:{:02X} {}", entry.index, entry.sub, entry.name);
        let mut dict = dictionary();
        let mut app = TestApp::default();
        let value = acceptable_value(&dict, entry);
        if !entry.access().writable() {
            let data = if value.is_empty() { vec![0] } else { value };
            assert_eq!(
                dict.write(entry.index, entry.sub, &data, allowed(), &mut app),
                Err(SdoAbort::ReadOnly),
                "{what}"
            );
            assert_eq!(
                dict.write(entry.index, entry.sub, &data, forbidden(), &mut app),
                Err(SdoAbort::ReadOnly),
                "{what}"
            );
            continue;
        }
        let before = dict.values().bytes().to_vec();
        if entry.write_condition() != WriteCondition::Always {
            assert_eq!(
                dict.write(entry.index, entry.sub, &value, forbidden(), &mut app),
                Err(SdoAbort::DeviceState),
                "{what}"
            );
            assert_eq!(dict.values().bytes()[..], before[..], "{what}: a refused write changes nothing");
        }
        // PDO mapping and assignment entries 1..n change only while sub 0 is 0 (CiA 301 §7.5.2.36).
        let enabled = is_pdo_configuration(entry) && entry.sub > 0;
        let count = dict.find(entry.index, 0).ok().and_then(|e| dict.values().raw(e)).map(|r| r.to_vec());
        if enabled {
            dict.write(entry.index, 0, &[0], allowed(), &mut app).unwrap_or_else(|e| panic!("{what}: disable {e:?}"));
        }
        dict.write(entry.index, entry.sub, &value, allowed(), &mut app)
            .unwrap_or_else(|e| panic!("{what}: writing its own value: {e:?}"));
        if enabled {
            let count = count.expect("sub 0 in RAM");
            dict.write(entry.index, 0, &count, allowed(), &mut app).unwrap_or_else(|e| panic!("{what}: enable {e:?}"));
        }
        if let Storage::Ram { .. } = entry.storage {
            assert_eq!(dict.values().bytes()[..], before[..], "{what}: rewriting the default changes nothing");
        }
        if entry.storage == Storage::Application {
            assert_eq!(app.writes.last().map(|w| (w.0, w.1, w.4)), Some((entry.index, entry.sub, true)), "{what}");
        }
    }
}

#[test]
fn every_default_mapping_and_assignment_is_valid() {
    let dict = dictionary();
    let table = *dict.table();
    for object in table.objects() {
        if pdo_map::mapping_direction(object.index).is_some() {
            let mapping = pdo_map::mapping(&table, dict.values().bytes(), object.index)
                .unwrap_or_else(|e| panic!("{:04X}: {e:?}", object.index));
            assert!(mapping.total_bytes() <= u32::from(ethercat_limit()), "{:04X}", object.index);
            let items: Vec<_> = mapping.collect();
            assert_eq!(items.len(), usize::from(pdo_map::count(&table, dict.values().bytes(), object.index).unwrap()));
        }
        if pdo_map::assignment_direction(object.index).is_some() {
            let count = pdo_map::count(&table, dict.values().bytes(), object.index).expect("sub 0");
            let bits = pdo_map::check_assignment(&table, dict.values().bytes(), object.index, count, None)
                .unwrap_or_else(|e| panic!("{:04X}: {e:?}", object.index));
            assert!(pdo_map::bytes_for_bits(bits) <= u32::from(ethercat_limit()));
            for pdo in pdo_map::assignment(&table, dict.values().bytes(), object.index).unwrap() {
                assert_eq!(
                    pdo_map::mapping_direction(pdo),
                    pdo_map::assignment_direction(object.index),
                    "{:04X} assigns {pdo:04X}",
                    object.index
                );
            }
        }
    }
}

// ---- Abort codes, one by one -------------------------------------------------------------------------------

fn find_entry(what: &str, predicate: impl Fn(&Entry) -> bool) -> &'static Entry {
    entries().iter().find(|e| predicate(e)).unwrap_or_else(|| panic!("the dictionary has no {what}"))
}

fn writable_ram(entry: &Entry) -> bool {
    entry.access() == Access::ReadWrite
        && entry.write_condition() == WriteCondition::Always
        && matches!(entry.storage, Storage::Ram { .. })
        && !is_pdo_configuration(entry)
}

#[test]
fn missing_object_and_missing_sub_index() {
    let mut dict = dictionary();
    let app = &mut TestApp::default();
    let mut buf = [0u8; 8];
    assert_eq!(dict.read(0x5FFF, 0, 0, &mut buf, app), Err(SdoAbort::ObjectDoesNotExist));
    assert_eq!(dict.write(0x5FFF, 0, &[0], allowed(), app), Err(SdoAbort::ObjectDoesNotExist));
    // 0x1018 identity exists (IDX L1805) and ends at sub 4.
    assert_eq!(dict.read(0x1018, 0x7F, 0, &mut buf, app), Err(SdoAbort::SubindexDoesNotExist));
    assert_eq!(dict.write(0x1018, 0x7F, &[0], allowed(), app), Err(SdoAbort::SubindexDoesNotExist));
}

#[test]
fn read_only_write_only_and_device_state() {
    let mut dict = dictionary();
    let app = &mut TestApp::default();
    // 0x6041 statusword is read-only, 0x1008 a constant, 0x1F50:01 program data write-only (IDX L3320).
    assert_eq!(dict.write(0x6041, 0, &[0, 0], allowed(), app), Err(SdoAbort::ReadOnly));
    assert_eq!(dict.write(0x1008, 0, b"x", allowed(), app), Err(SdoAbort::ReadOnly));
    assert_eq!(dict.read(0x1F50, 1, 0, &mut [0u8; 8], app), Err(SdoAbort::WriteOnly));
    // PDO mappings are written only in Pre-Operational (IDX L2196).
    let op = AccessContext { comm_state: CommState::Operational, ..allowed() };
    assert_eq!(dict.write(0x1600, 0, &[0], op, app), Err(SdoAbort::DeviceState));
    let safe_op = AccessContext { comm_state: CommState::SafeOperational, ..allowed() };
    assert_eq!(dict.write(0x1600, 0, &[0], safe_op, app), Err(SdoAbort::DeviceState));
    // Power-disabled entries refuse writes with the power stage on.
    let entry = find_entry("power-disabled entry", |e| {
        e.access() == Access::ReadWrite && e.write_condition() == WriteCondition::PowerDisabled
    });
    let value = dict.values().raw(entry).map(<[u8]>::to_vec).unwrap_or_default();
    let powered = AccessContext { power_stage_enabled: true, ..allowed() };
    assert_eq!(dict.write(entry.index, entry.sub, &value, powered, app), Err(SdoAbort::DeviceState));
    assert_eq!(dict.write(entry.index, entry.sub, &value, allowed(), app), Ok(()));
}

#[test]
fn length_too_low_and_too_high() {
    let mut dict = dictionary();
    let app = &mut TestApp::default();
    // 0x6040 controlword is UNSIGNED16 (IDX L5615).
    assert_eq!(dict.write(0x6040, 0, &[1], allowed(), app), Err(SdoAbort::LengthTooLow));
    assert_eq!(dict.write(0x6040, 0, &[], allowed(), app), Err(SdoAbort::LengthTooLow));
    assert_eq!(dict.write(0x6040, 0, &[1, 2, 3], allowed(), app), Err(SdoAbort::LengthTooHigh));
    assert_eq!(dict.write(0x6040, 0, &[0x0F, 0x00], allowed(), app), Ok(()));
    let mut buf = [0u8; 2];
    dict.read(0x6040, 0, 0, &mut buf, app).unwrap();
    assert_eq!(buf, [0x0F, 0x00]);
    // A fixed-size application entry is checked before the application sees it (0x1010:01, CiA 301 §7.5.2.13).
    assert_eq!(dict.write(0x1010, 1, b"sav", allowed(), app), Err(SdoAbort::LengthTooLow));
    assert_eq!(dict.write(0x1010, 1, b"saves", allowed(), app), Err(SdoAbort::LengthTooHigh));
    assert!(app.writes.is_empty());
}

#[test]
fn value_too_low_and_too_high() {
    let mut dict = dictionary();
    let app = &mut TestApp::default();
    let mut checked_low = false;
    let mut checked_high = false;
    for entry in entries().iter().filter(|e| writable_ram(e)) {
        let (Some(size), Some((type_min, type_max))) = (entry.data_type.fixed_size(), type_range(entry.data_type))
        else {
            continue;
        };
        let (min, max) = match *entry.generated_limits() {
            Limits::Signed { min, max } => (i128::from(min), i128::from(max)),
            Limits::Unsigned { min, max } => (i128::from(min), i128::from(max)),
            _ => continue,
        };
        let before = dict.values().bytes().to_vec();
        if min > type_min {
            assert_eq!(
                dict.write(entry.index, entry.sub, &encode(min - 1, size), allowed(), app),
                Err(SdoAbort::ValueTooLow)
            );
            checked_low = true;
        }
        if max < type_max {
            assert_eq!(
                dict.write(entry.index, entry.sub, &encode(max + 1, size), allowed(), app),
                Err(SdoAbort::ValueTooHigh)
            );
            checked_high = true;
        }
        assert_eq!(dict.values().bytes()[..], before[..], "{:04X}:{:02X}", entry.index, entry.sub);
        assert_eq!(dict.write(entry.index, entry.sub, &encode(min, size), allowed(), app), Ok(()));
        assert_eq!(dict.write(entry.index, entry.sub, &encode(max, size), allowed(), app), Ok(()));
    }
    assert!(checked_low && checked_high, "the dictionary has entries with a lower and an upper bound");
}

#[test]
fn invalid_value_for_option_codes() {
    let mut dict = dictionary();
    let app = &mut TestApp::default();
    // 0x6060 modes of operation accepts only the implemented modes; 2 (velocity mode) is not one.
    let entry = dict.find(0x6060, 0).unwrap();
    assert!(matches!(*entry.generated_limits(), Limits::OneOf(list) if !list.contains(&2)));
    assert_eq!(dict.write(0x6060, 0, &[2], allowed(), app), Err(SdoAbort::InvalidValue));
    assert_eq!(dict.write(0x6060, 0, &[8], allowed(), app), Ok(()));
    // Every option-code entry refuses the first value outside its list.
    for entry in entries().iter().filter(|e| writable_ram(e)) {
        let (Limits::OneOf(list), Some(size)) = (*entry.generated_limits(), entry.data_type.fixed_size()) else {
            continue;
        };
        let (type_min, _) = type_range(entry.data_type).unwrap();
        let outside = (type_min..).find(|v| !list.iter().any(|a| i128::from(*a) == *v)).unwrap();
        let before = dict.values().bytes().to_vec();
        assert_eq!(
            dict.write(entry.index, entry.sub, &encode(outside, size), allowed(), app),
            Err(SdoAbort::InvalidValue),
            "{:04X}:{:02X}",
            entry.index,
            entry.sub
        );
        assert_eq!(dict.values().bytes()[..], before[..]);
    }
}

#[test]
fn booleans_accept_only_zero_and_one() {
    // The generated dictionary has no writable BOOLEAN today; check the rule on any it gains.
    let mut dict = dictionary();
    let app = &mut TestApp::default();
    for entry in entries().iter().filter(|e| writable_ram(e) && e.data_type == DataType::Boolean) {
        assert_eq!(dict.write(entry.index, entry.sub, &[2], allowed(), app), Err(SdoAbort::InvalidValue));
        assert_eq!(dict.write(entry.index, entry.sub, &[1], allowed(), app), Ok(()));
    }
}

fn raw(index: u16, sub: u8, bits: u8) -> [u8; 4] {
    MapEntry { index, sub, bits }.raw().to_le_bytes()
}

/// An entry mappable into an RxPDO of `bits` bits (writable RAM, so the tests can read it back).
fn rx_mappable(bits: u16) -> &'static Entry {
    find_entry("RxPDO-mappable entry", |e| e.pdo().rx() && e.bit_size() == Some(bits) && !is_pdo_configuration(e))
}

#[test]
fn mapping_entries_change_only_while_sub0_is_zero() {
    let mut dict = dictionary();
    let app = &mut TestApp::default();
    let count = dict.values().raw(dict.find(0x1600, 0).unwrap()).unwrap()[0];
    assert!(count > 0, "0x1600 is enabled by default (IDX Table 6-70)");
    let target = rx_mappable(32);
    let before = dict.values().bytes().to_vec();
    assert_eq!(
        dict.write(0x1600, 1, &raw(target.index, target.sub, 32), allowed(), app),
        Err(SdoAbort::UnsupportedAccess)
    );
    assert_eq!(dict.write(0x1600, 12, &[0; 4], allowed(), app), Err(SdoAbort::UnsupportedAccess));
    assert_eq!(dict.values().bytes()[..], before[..]);
    // The same rule for assignments.
    assert_eq!(dict.write(0x1C12, 1, &0x1601u16.to_le_bytes(), allowed(), app), Err(SdoAbort::UnsupportedAccess));
}

#[test]
fn mapping_entries_are_checked_when_written() {
    let mut dict = dictionary();
    let app = &mut TestApp::default();
    dict.write(0x1600, 0, &[0], allowed(), app).unwrap();
    let before = dict.values().bytes().to_vec();
    // Not mappable in this direction: the statusword is a TxPDO object.
    assert_eq!(dict.write(0x1600, 1, &raw(0x6041, 0, 16), allowed(), app), Err(SdoAbort::CannotBeMapped));
    // Not mappable at all: the device name.
    assert_eq!(dict.write(0x1600, 1, &raw(0x1008, 0, 8), allowed(), app), Err(SdoAbort::CannotBeMapped));
    // Does not exist (object or sub-index).
    assert_eq!(dict.write(0x1600, 1, &raw(0x5FFF, 0, 16), allowed(), app), Err(SdoAbort::ObjectDoesNotExist));
    assert_eq!(dict.write(0x1600, 1, &raw(0x6040, 9, 16), allowed(), app), Err(SdoAbort::ObjectDoesNotExist));
    // Wrong length for the object.
    assert_eq!(dict.write(0x1600, 1, &raw(0x6040, 0, 32), allowed(), app), Err(SdoAbort::ParameterIncompatibility));
    assert_eq!(dict.write(0x1600, 1, &raw(0x6040, 0, 8), allowed(), app), Err(SdoAbort::ParameterIncompatibility));
    // Dummy entries must state their type's length.
    assert_eq!(dict.write(0x1600, 1, &raw(0x0006, 0, 8), allowed(), app), Err(SdoAbort::ParameterIncompatibility));
    assert_eq!(dict.values().bytes()[..], before[..]);
    // Valid: an object, a dummy UNSIGNED8, an EtherCAT 8-bit gap, an empty entry.
    assert_eq!(dict.write(0x1600, 1, &raw(0x6040, 0, 16), allowed(), app), Ok(()));
    assert_eq!(dict.write(0x1600, 2, &raw(0x0005, 0, 8), allowed(), app), Ok(()));
    assert_eq!(dict.write(0x1600, 3, &raw(0x0000, 0, 8), allowed(), app), Ok(()));
    assert_eq!(dict.write(0x1600, 4, &[0; 4], allowed(), app), Ok(()));
    assert_eq!(dict.write(0x1600, 0, &[3], allowed(), app), Ok(()));
    let table = *dict.table();
    let items: Vec<_> = pdo_map::mapping(&table, dict.values().bytes(), 0x1600).unwrap().collect();
    assert_eq!(items.len(), 3);
    assert_eq!(items[0].target, MapTarget::Object(dict.find(0x6040, 0).unwrap()));
    assert_eq!((items[1].target, items[1].bit_offset, items[1].bits), (MapTarget::Padding, 16, 8));
    assert_eq!((items[2].target, items[2].bit_offset, items[2].bits), (MapTarget::Padding, 24, 8));
    // Enabling an empty entry fails as a whole; nothing changes.
    dict.write(0x1600, 0, &[0], allowed(), app).unwrap();
    let before = dict.values().bytes().to_vec();
    assert_eq!(dict.write(0x1600, 0, &[4], allowed(), app), Err(SdoAbort::ParameterIncompatibility));
    assert_eq!(dict.values().bytes()[..], before[..]);
}

#[test]
fn mapping_longer_than_the_pdo_is_refused_as_a_whole() {
    let mut dict = dictionary();
    let app = &mut TestApp::default();
    let target = rx_mappable(32);
    // Unassigned, so that only the mapping's own length counts.
    dict.write(0x1C12, 0, &[0], allowed(), app).unwrap();
    dict.write(0x1600, 0, &[0], allowed(), app).unwrap();
    for sub in 1..=12 {
        dict.write(0x1600, sub, &raw(target.index, target.sub, 32), allowed(), app).unwrap();
    }
    let before = dict.values().bytes().to_vec();
    // 12 x 4 bytes exceed EtherCAT's 40; 3 x 4 exceed CANopen's 8 (IDX L2196).
    assert_eq!(dict.write(0x1600, 0, &[11], allowed(), app), Err(SdoAbort::PdoLengthExceeded));
    let canopen = AccessContext { max_pdo_bytes: canopen_limit(), ..allowed() };
    assert_eq!(dict.write(0x1600, 0, &[3], canopen, app), Err(SdoAbort::PdoLengthExceeded));
    assert_eq!(dict.values().bytes()[..], before[..], "nothing changes on failure");
    assert_eq!(dict.write(0x1600, 0, &[2], canopen, app), Ok(()));
    assert_eq!(dict.write(0x1600, 0, &[0], allowed(), app), Ok(()));
    assert_eq!(dict.write(0x1600, 0, &[10], allowed(), app), Ok(()));
    // Above the declared 12 entries: the sub-0 range (IDX L2218).
    assert_eq!(dict.write(0x1600, 0, &[13], allowed(), app), Err(SdoAbort::ValueTooHigh));
}

#[test]
fn assignment_errors() {
    let mut dict = dictionary();
    let app = &mut TestApp::default();
    dict.write(0x1C12, 0, &[0], allowed(), app).unwrap();
    let before = dict.values().bytes().to_vec();
    // A TxPDO mapping in the RxPDO assignment, a mapping object that does not exist, a non-mapping index.
    assert_eq!(dict.write(0x1C12, 1, &0x1A00u16.to_le_bytes(), allowed(), app), Err(SdoAbort::InvalidValue));
    assert_eq!(dict.write(0x1C12, 1, &0x17FFu16.to_le_bytes(), allowed(), app), Err(SdoAbort::InvalidValue));
    assert_eq!(dict.write(0x1C12, 1, &0x6040u16.to_le_bytes(), allowed(), app), Err(SdoAbort::InvalidValue));
    let tx_count = pdo_map::count(dict.table(), dict.values().bytes(), 0x1C13).unwrap();
    assert_eq!(dict.write(0x1C13, 0, &[0], allowed(), app), Ok(()));
    assert_eq!(dict.write(0x1C13, 1, &0x1600u16.to_le_bytes(), allowed(), app), Err(SdoAbort::InvalidValue));
    assert_eq!(dict.write(0x1C13, 0, &[tx_count], allowed(), app), Ok(()));
    assert_eq!(dict.values().bytes()[..before.len()], before[..]);

    // Two RxPDOs of 6 x 4 bytes each fit alone, not together (40 bytes on EtherCAT).
    let target = rx_mappable(32);
    for mapping in [0x1600u16, 0x1601] {
        dict.write(mapping, 0, &[0], allowed(), app).unwrap();
        for sub in 1..=6 {
            dict.write(mapping, sub, &raw(target.index, target.sub, 32), allowed(), app).unwrap();
        }
        dict.write(mapping, 0, &[6], allowed(), app).unwrap();
    }
    dict.write(0x1C12, 1, &0x1600u16.to_le_bytes(), allowed(), app).unwrap();
    dict.write(0x1C12, 2, &0x1601u16.to_le_bytes(), allowed(), app).unwrap();
    assert_eq!(dict.write(0x1C12, 0, &[2], allowed(), app), Err(SdoAbort::PdoLengthExceeded));
    assert_eq!(dict.write(0x1C12, 0, &[1], allowed(), app), Ok(()));
    // Re-enabling an assigned mapping is checked against the assignment's total too.
    dict.write(0x1601, 0, &[0], allowed(), app).unwrap();
    dict.write(0x1601, 1, &raw(0x6040, 0, 16), allowed(), app).unwrap();
    dict.write(0x1601, 0, &[1], allowed(), app).unwrap();
    dict.write(0x1C12, 0, &[0], allowed(), app).unwrap();
    dict.write(0x1C12, 0, &[2], allowed(), app).unwrap();
    dict.write(0x1600, 0, &[0], allowed(), app).unwrap();
    dict.write(0x1600, 7, &raw(target.index, target.sub, 32), allowed(), app).unwrap();
    dict.write(0x1600, 8, &raw(target.index, target.sub, 32), allowed(), app).unwrap();
    dict.write(0x1600, 9, &raw(target.index, target.sub, 32), allowed(), app).unwrap();
    // 9 x 4 + 2 = 38 bytes fit; 10 x 4 + 2 do not.
    dict.write(0x1600, 10, &raw(target.index, target.sub, 32), allowed(), app).unwrap();
    assert_eq!(dict.write(0x1600, 0, &[10], allowed(), app), Err(SdoAbort::PdoLengthExceeded));
    assert_eq!(dict.write(0x1600, 0, &[9], allowed(), app), Ok(()));
    let table = *dict.table();
    assert_eq!(
        pdo_map::assignment(&table, dict.values().bytes(), 0x1C12).unwrap().collect::<Vec<_>>(),
        [0x1600, 0x1601]
    );
}

#[test]
fn program_download_goes_to_the_application_in_segments() {
    let mut dict = dictionary();
    let mut app = TestApp::default();
    let mut download: Download = dict.begin_download(0x1F50, 1, Some(10), allowed()).unwrap();
    dict.download_segment(&mut download, b"0123456", false, allowed(), &mut app).unwrap();
    dict.download_segment(&mut download, b"789", true, allowed(), &mut app).unwrap();
    assert_eq!(app.writes, vec![(0x1F50, 1, 0, b"0123456".to_vec(), false), (0x1F50, 1, 7, b"789".to_vec(), true)]);
    // More data than announced: the application is told to discard.
    let mut download: Download = dict.begin_download(0x1F50, 1, Some(4), allowed()).unwrap();
    assert_eq!(dict.download_segment(&mut download, b"01234", true, allowed(), &mut app), Err(SdoAbort::LengthTooHigh));
    assert_eq!(app.aborts, 1);
    // Nobody serving the entry.
    assert_eq!(dict.write(0x1F50, 1, b"x", allowed(), &mut NoApplicationObjects), Err(SdoAbort::CannotTransfer));
    // A segmented write to a read-only entry fails at initiation.
    assert_eq!(dict.begin_download::<64>(0x1008, 0, None, allowed()).map(|_| ()), Err(SdoAbort::ReadOnly));
}

#[test]
fn typed_handles_share_the_storage_with_sdo_access() {
    let mut dict = dictionary();
    let entry = find_entry("UNSIGNED16 RAM entry", |e| {
        writable_ram(e) && e.data_type == DataType::Unsigned16 && *e.generated_limits() == Limits::None
    });
    let Storage::Ram { offset, .. } = entry.storage else { unreachable!() };
    let handle = firmware::od::entry::Handle::<u16>::new(offset);
    dict.set(handle, 0xBEEF);
    assert_eq!(read_all(&dict, entry), Ok(vec![0xEF, 0xBE]));
    dict.write(entry.index, entry.sub, &[0x34, 0x12], allowed(), &mut TestApp::default()).unwrap();
    assert_eq!(dict.get(handle), 0x1234);
    let _ = PdoMapping::No;
}

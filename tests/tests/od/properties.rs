//! Properties of dictionary access on the generated dictionary (ARCHITECTURE convention 12):
//! - any write of any bytes to any (index, sub) in any context either succeeds with a value within the entry's
//!   limits that reads back equal, or fails with the code the access rules give (CiA 301 Table 22), changes
//!   nothing when it fails, and never panics;
//! - any sequence of PDO mapping and assignment writes never leaves an enabled mapping (sub 0 > 0) with an
//!   invalid entry, or an enabled assignment naming anything but mapping objects of its direction
//!   (CiA 301 §7.5.2.36; ETG.1000.6 0x1C12/0x1C13).

use crate::support::*;
use firmware::od::access::{AccessContext, CommState, Dictionary};
use firmware::od::entry::{DataType, Limits, Storage};
use firmware::od::pdo_map::{self, Direction, MapEntry};
use proptest::prelude::*;

const STATES: [CommState; 6] = [
    CommState::Init,
    CommState::PreOperational,
    CommState::SafeOperational,
    CommState::Operational,
    CommState::Stopped,
    CommState::Bootstrap,
];

fn context() -> impl Strategy<Value = AccessContext> {
    (0..STATES.len(), any::<bool>(), prop_oneof![Just(canopen_limit()), Just(ethercat_limit()), 0u16..64]).prop_map(
        |(state, power_stage_enabled, max_pdo_bytes)| AccessContext {
            comm_state: STATES[state],
            power_stage_enabled,
            max_pdo_bytes,
        },
    )
}

/// Where a write goes: an existing entry (most cases), a neighbouring sub-index, or anywhere.
#[derive(Clone, Debug)]
enum Target {
    Entry(usize),
    Sub(usize, u8),
    Anywhere(u16, u8),
}

fn target() -> impl Strategy<Value = Target> {
    let n = entries().len().max(1);
    prop_oneof![
        6 => (0..n).prop_map(Target::Entry),
        1 => (0..n, any::<u8>()).prop_map(|(i, sub)| Target::Sub(i, sub)),
        1 => (any::<u16>(), any::<u8>()).prop_map(|(index, sub)| Target::Anywhere(index, sub)),
    ]
}

/// What is written: random bytes, or a value near one of the entry's bounds encoded at its size.
#[derive(Clone, Debug)]
enum Data {
    Bytes(Vec<u8>),
    NearBound { upper: bool, delta: i8 },
    Value(i64),
}

fn data() -> impl Strategy<Value = Data> {
    prop_oneof![
        2 => proptest::collection::vec(any::<u8>(), 0..10).prop_map(Data::Bytes),
        2 => (any::<bool>(), -2i8..=2).prop_map(|(upper, delta)| Data::NearBound { upper, delta }),
        1 => any::<i64>().prop_map(Data::Value),
    ]
}

fn resolve_target(target: &Target) -> (u16, u8) {
    let all = entries();
    match *target {
        Target::Entry(i) => (all[i].index, all[i].sub),
        Target::Sub(i, sub) => (all[i].index, sub),
        Target::Anywhere(index, sub) => (index, sub),
    }
}

fn resolve_data(dict: &Dictionary, index: u16, sub: u8, data: &Data) -> Vec<u8> {
    let entry = dict.find(index, sub).ok();
    let size = entry.and_then(|e| e.data_type.fixed_size());
    match (data, entry, size) {
        (Data::Bytes(bytes), _, _) => bytes.clone(),
        (Data::NearBound { upper, delta }, Some(entry), Some(size)) => {
            let (type_min, type_max) = type_range(entry.data_type).unwrap();
            let (min, max) = match *entry.generated_limits() {
                Limits::Signed { min, max } => (i128::from(min), i128::from(max)),
                Limits::Unsigned { min, max } => (i128::from(min), i128::from(max)),
                Limits::OneOf(list) => (i128::from(list[0]), i128::from(*list.last().unwrap())),
                Limits::None => (type_min, type_max),
            };
            let bound = if *upper { max } else { min };
            let value = (bound + i128::from(*delta)).clamp(type_min, type_max);
            encode(value, size)
        }
        (Data::Value(v), Some(_), Some(size)) => encode(i128::from(*v), size),
        (Data::Value(v), _, _) => v.to_le_bytes().to_vec(),
        (Data::NearBound { .. }, _, _) => vec![0],
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn writes_succeed_within_limits_or_fail_with_the_right_code(
        target in target(),
        data in data(),
        ctx in context(),
    ) {
        let mut dict = dictionary();
        let mut app = TestApp::default();
        let (index, sub) = resolve_target(&target);
        let data = resolve_data(&dict, index, sub, &data);
        let before = dict.values().bytes().to_vec();
        let expected = oracle(&dict, index, sub, &data, ctx);
        let result = dict.write(index, sub, &data, ctx, &mut app);
        if let Some(expected) = expected {
            prop_assert_eq!(result, expected, "{:04X}:{:02X} <- {:02X?}", index, sub, data);
        }
        match result {
            Err(_) => {
                prop_assert_eq!(&dict.values().bytes()[..], &before[..], "a failed write changes nothing");
                prop_assert!(app.writes.is_empty(), "a failed check never reaches the application");
            }
            Ok(()) => {
                let entry = dict.find(index, sub).unwrap();
                if let Some(value) = decode(entry.data_type, &data) {
                    prop_assert_eq!(limits_verdict(entry, value), Ok(()));
                }
                if let Storage::Ram { len, .. } = entry.storage {
                    let mut stored = data.clone();
                    stored.resize(usize::from(len), 0);
                    prop_assert_eq!(dict.values().raw(entry).unwrap(), &stored[..]);
                    if entry.access().readable() {
                        let mut expected = data.clone();
                        if entry.data_type == DataType::VisibleString {
                            let end = expected.iter().position(|b| *b == 0).unwrap_or(expected.len());
                            expected.truncate(end);
                        }
                        prop_assert_eq!(read_all(&dict, entry).unwrap(), expected);
                    }
                }
            }
        }
    }
}

// ---- PDO mapping sequences ---------------------------------------------------------------------------------

/// The PDO configuration objects of the generated dictionary.
fn configuration_objects() -> Vec<u16> {
    let mut objects: Vec<u16> = entries().iter().filter(|e| is_pdo_configuration(e)).map(|e| e.index).collect();
    objects.dedup();
    objects
}

/// Values worth writing into mapping and assignment entries: every valid mapping of every mappable entry, the
/// same with a wrong length, dummies, gaps, empty entries, mapping-object indices of both directions, nonsense.
fn interesting_values() -> Vec<u32> {
    let mut values = vec![0, 0x0000_0008, 0x0005_0008, 0x0007_0020, 0x0006_0008, 0x0001_0001, 0xFFFF_FFFF, 0x1008_0008];
    for entry in entries() {
        if let Some(bits) = entry.bit_size() {
            let bits = u8::try_from(bits).unwrap();
            let raw = MapEntry { index: entry.index, sub: entry.sub, bits }.raw();
            values.push(raw);
            values.push(MapEntry { index: entry.index, sub: entry.sub, bits: bits.wrapping_add(8) }.raw());
        }
    }
    for index in configuration_objects() {
        values.push(u32::from(index));
    }
    values.extend([0x1604, 0x17FF, 0x1A04, 0x1C12]);
    values
}

#[derive(Clone, Debug)]
enum Op {
    Count { object: usize, count: u8 },
    Entry { object: usize, sub: u8, value: usize },
}

fn op(objects: usize, values: usize) -> impl Strategy<Value = Op> {
    prop_oneof![
        2 => (0..objects, prop_oneof![2 => Just(0u8), 3 => 1u8..=4, 1 => 0u8..=13])
            .prop_map(|(object, count)| Op::Count { object, count }),
        3 => (0..objects, prop_oneof![3 => 1u8..=4, 1 => 1u8..=13], 0..values)
            .prop_map(|(object, sub, value)| Op::Entry { object, sub, value }),
    ]
}

fn pre_op_context() -> impl Strategy<Value = AccessContext> {
    prop_oneof![
        8 => prop_oneof![Just(canopen_limit()), Just(ethercat_limit())].prop_map(|max_pdo_bytes| AccessContext {
            comm_state: CommState::PreOperational,
            power_stage_enabled: false,
            max_pdo_bytes,
        }),
        1 => context(),
    ]
}

fn check_invariant(dict: &Dictionary) -> Result<(), TestCaseError> {
    let table = *dict.table();
    let bytes = dict.values().bytes();
    for index in configuration_objects() {
        let count = pdo_map::count(&table, bytes, index).unwrap_or(0);
        if count == 0 {
            continue;
        }
        if pdo_map::mapping_direction(index).is_some() {
            let mapping = pdo_map::mapping(&table, bytes, index);
            prop_assert!(mapping.is_ok(), "{:04X} enabled with an invalid entry: {:?}", index, mapping.err());
            prop_assert_eq!(mapping.unwrap().count(), usize::from(count));
        } else {
            let direction = pdo_map::assignment_direction(index);
            let checked = pdo_map::check_assignment(&table, bytes, index, count, None);
            prop_assert!(checked.is_ok(), "{:04X} enabled with an invalid entry: {:?}", index, checked.err());
            for pdo in pdo_map::assignment(&table, bytes, index).unwrap() {
                prop_assert_eq!(pdo_map::mapping_direction(pdo), direction);
                prop_assert!(matches!(direction, Some(Direction::Rx | Direction::Tx)));
            }
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

    #[test]
    fn mapping_sequences_never_enable_an_invalid_mapping(
        ops in proptest::collection::vec(
            (op(configuration_objects().len().max(1), interesting_values().len()), pre_op_context()),
            1..60,
        ),
    ) {
        let objects = configuration_objects();
        prop_assume!(!objects.is_empty());
        let values = interesting_values();
        let mut dict = dictionary();
        let mut app = TestApp::default();
        check_invariant(&dict)?;
        for (op, ctx) in ops {
            let before = dict.values().bytes().to_vec();
            let result = match op {
                Op::Count { object, count } => dict.write(objects[object], 0, &[count], ctx, &mut app),
                Op::Entry { object, sub, value } => {
                    let index = objects[object];
                    let size = dict.find(index, sub).ok().and_then(|e| e.data_type.fixed_size()).unwrap_or(4);
                    let bytes = values[value].to_le_bytes();
                    dict.write(index, sub, &bytes[..size.min(4)], ctx, &mut app)
                }
            };
            if result.is_err() {
                prop_assert_eq!(&dict.values().bytes()[..], &before[..]);
            }
            check_invariant(&dict)?;
        }
    }
}

//! The fault table (`firmware::fault::table`) against its sources and against the generated dictionary.
//!
//! - Sanity: one row per `FaultId` in discriminant order, unique non-zero codes, valid error-register bits (bit 0
//!   "generic" set for every fault as CiA 301 object 1001h asks, bit 6 reserved never set, no bits for warnings
//!   and the Safe Torque Off state), faults latch and warnings and the STO state clear themselves.
//! - Safe Torque Off: no seed gives a code, so its two rows use the manufacturer block 0xFFA0.. (golden below).
//! - Sources: every row that cites IDX carries the code, class letter and class register bit of IDX Table 7-153
//!   (seed `002_*.txt` L7040-L7110, restated below as golden data).
//! - Dictionary: the objects the fault handling writes exist with the types and access the manager assumes
//!   (0x603F, 0x1001 and their typed handles, 0x1003, 0x1014, 0x1015, 0x605E, 0x6007).

use firmware::cia402::FaultClass;
use firmware::fault::table::{REG_GENERIC, REG_RESERVED};
use firmware::fault::{Cause, FaultId, LatchPolicy, ReactionClass, Tier, FAULT_COUNT, FAULT_TABLE};
use firmware::od::access::Dictionary;
use firmware::od::entry::{Access, DataType, Limits, ObjectCode, PdoMapping, Storage};
use firmware::od::generated::handles::{ERROR_CODE, ERROR_REGISTER};
use std::collections::HashSet;

/// IDX Table 7-153 rows the table uses: (code, error register as IDX prints it, class letter, seed line).
const IDX_TABLE_7_153: &[(u16, u8, char, u32)] = &[
    (0x2310, 0b0000_0010, 'd', 7045),
    (0x2320, 0b0000_0010, 'd', 7046),
    (0x3210, 0b0000_0100, 'd', 7047),
    (0x3220, 0b0000_0100, 'd', 7048),
    (0x4210, 0b0000_1000, 'd', 7049),
    (0x4380, 0b0000_1000, 'd', 7050),
    (0x6180, 0b0000_0001, 'd', 7061),
    (0x6380, 0b0000_0001, 'd', 7063),
    (0x7320, 0b0010_0000, 'd', 7064),
    (0x7380, 0b0010_0000, 'd', 7065),
    // The SSI absolute encoder's errors (sensors::ssi, drive::tier1, drive::ssi_position).
    (0x738C, 0b0010_0000, 'd', 7066),
    (0x738D, 0b0010_0000, 'd', 7067),
    (0x7390, 0b0010_0000, 'd', 7068),
    (0x7391, 0b0010_0000, 'd', 7069),
    // The direction supervision (supervision::direction).
    (0x7392, 0b0010_0000, 'd', 7070),
    (0x8110, 0b0001_0000, 'a', 7071),
    (0x8120, 0b0001_0000, 'a', 7073),
    (0x8130, 0b0001_0000, 'a', 7074),
    (0x8180, 0b0001_0000, 'a', 7076),
    (0x8184, 0b0001_0000, 'a', 7080),
    (0x81FD, 0b0001_0000, 'a', 7081),
    (0x8210, 0b0001_0000, 'a', 7084),
    (0x8250, 0b0001_0000, 'a', 7085),
    (0x8611, 0b1000_0000, 'f', 7088),
    (0x8A80, 0b1000_0000, 'f', 7089),
    (0x8A81, 0b1000_0000, 'f', 7090),
    (0x8A82, 0b1000_0000, 'f', 7091),
    (0xFF02, 0b0000_0001, 'd', 7093),
    (0xFF0B, 0b0000_0001, 'd', 7094),
    // The auto-tuning codes the motor identification raises (drive::auto_setup).
    (0xFF12, 0b0010_0000, 'd', 7096),
    (0xFF13, 0b0010_0000, 'd', 7097),
    (0xFF15, 0b0010_0000, 'd', 7103),
    (0xFF16, 0b0010_0000, 'd', 7104),
    (0xFF19, 0b0010_0000, 'd', 7107),
    (0xFF20, 0b0010_0000, 'd', 7108),
    (0xFF21, 0b0010_0000, 'd', 7109),
    (0xFF22, 0b0010_0000, 'd', 7110),
];

fn letter(class: ReactionClass) -> char {
    match class {
        ReactionClass::DisablePowerImmediately => 'd',
        ReactionClass::QuickStopThenDisable => 'f',
        ReactionClass::AbortConnection => 'a',
        ReactionClass::Warning => 'w',
        ReactionClass::TorqueOff => 's',
    }
}

#[test]
fn one_row_per_id_in_discriminant_order() {
    assert_eq!(FAULT_TABLE.len(), FAULT_COUNT);
    assert_eq!(FaultId::ALL.len(), FAULT_COUNT);
    for (row, (info, id)) in FAULT_TABLE.iter().zip(FaultId::ALL).enumerate() {
        assert_eq!(info.id, id, "row {row}");
        assert_eq!(usize::from(id.number()), row, "{id:?}");
        assert_eq!(FaultId::from_number(id.number()), Some(id));
        assert_eq!(id.info(), info);
        assert_eq!(FaultId::from_code(info.code), Some(id));
        assert!(!info.name.is_empty() && !info.source.is_empty(), "{id:?} needs a name and a source");
    }
    assert_eq!(FaultId::from_number(u8::try_from(FAULT_COUNT).unwrap()), None);
}

#[test]
fn codes_are_unique_and_not_the_reset_code() {
    let mut seen = HashSet::new();
    for info in &FAULT_TABLE {
        assert_ne!(info.code, 0x0000, "{:?}: 0x0000 is 'error reset / no error'", info.id);
        assert!(seen.insert(info.code), "{:?}: code {:#06X} used twice", info.id, info.code);
    }
}

#[test]
fn register_bits_follow_cia_301() {
    for info in &FAULT_TABLE {
        assert_eq!(info.register & REG_RESERVED, 0, "{:?}: bit 6 is reserved", info.id);
        if !info.reaction.is_fault() {
            assert_eq!(info.register, 0, "{:?}: warnings and the STO state are not errors", info.id);
        } else {
            assert_ne!(info.register & REG_GENERIC, 0, "{:?}: bit 0 'generic' goes with every fault", info.id);
        }
    }
}

#[test]
fn faults_latch_and_warnings_clear_themselves() {
    for info in &FAULT_TABLE {
        let expected = if info.reaction.is_fault() { LatchPolicy::Latching } else { LatchPolicy::SelfClearing };
        assert_eq!(info.latch, expected, "{:?}", info.id);
    }
    // The required warnings and their fault variants.
    assert!(FaultId::MotorI2tLimit.info().reaction.is_warning());
    assert!(!FaultId::MotorThermalOverload.info().reaction.is_warning());
    assert!(FaultId::PowerStageTemperatureHigh.info().reaction.is_warning());
    assert!(!FaultId::PowerStageOverTemperature.info().reaction.is_warning());
}

/// Safe Torque Off (EPOS4 AN ch. 9; no seed code): the state 0xFFA0 (no register bit, clears itself, takes the
/// machine to «Switch on disabled» rather than «Fault») and the input discrepancy 0xFFA1 (class d, latching until
/// the inputs agree and a fault reset), both detected in tier 2 and outside IDX's 0xFF01..0xFF22.
#[test]
fn safe_torque_off_rows() {
    let sto = FaultId::SafeTorqueOff.info();
    assert_eq!((sto.code, sto.register, sto.reaction), (0xFFA0, 0, ReactionClass::TorqueOff));
    assert_eq!((sto.latch, sto.cause, sto.tier), (LatchPolicy::SelfClearing, Cause::Level, Tier::Supervision));
    assert_eq!(sto.reaction.machine_class(), None);
    let discrepancy = FaultId::StoDiscrepancy.info();
    assert_eq!(
        (discrepancy.code, discrepancy.register, discrepancy.reaction),
        (0xFFA1, REG_GENERIC, ReactionClass::DisablePowerImmediately)
    );
    assert_eq!(
        (discrepancy.latch, discrepancy.cause, discrepancy.tier),
        (LatchPolicy::Latching, Cause::Level, Tier::Supervision)
    );
    assert!(!(0xFF01..=0xFF22).contains(&sto.code) && !(0xFF01..=0xFF22).contains(&discrepancy.code));
}

#[test]
fn idx_codes_match_table_7_153() {
    let mut cited = 0;
    for info in FAULT_TABLE.iter().filter(|i| i.source.starts_with("IDX")) {
        let &(_, register, class, line) = IDX_TABLE_7_153
            .iter()
            .find(|row| row.0 == info.code)
            .unwrap_or_else(|| panic!("{:?} cites IDX but {:#06X} is not in Table 7-153", info.id, info.code));
        assert_eq!(letter(info.reaction), class, "{:?} (IDX L{line})", info.id);
        assert_eq!(info.register & register, register, "{:?} lacks IDX's register bit (L{line})", info.id);
        assert!(info.source.contains(&format!("L{line}")), "{:?} should cite IDX L{line}", info.id);
        cited += 1;
    }
    assert_eq!(cited, IDX_TABLE_7_153.len(), "every golden IDX row is used once");
}

#[test]
fn reaction_classes_map_to_the_state_machine() {
    assert_eq!(ReactionClass::DisablePowerImmediately.machine_class(), Some(FaultClass::Critical));
    assert_eq!(ReactionClass::QuickStopThenDisable.machine_class(), Some(FaultClass::Reaction));
    assert_eq!(ReactionClass::AbortConnection.machine_class(), None);
    assert_eq!(ReactionClass::Warning.machine_class(), None);
    assert_eq!(ReactionClass::TorqueOff.machine_class(), None);
    // Communication faults are exactly those with register bit 4 (IDX Table 7-153: class a <=> 0001 0000b).
    for info in &FAULT_TABLE {
        let comm = info.register & firmware::fault::table::REG_COMMUNICATION != 0;
        assert_eq!(comm, info.reaction == ReactionClass::AbortConnection, "{:?}", info.id);
    }
}

#[test]
fn the_dictionary_holds_what_the_fault_handling_writes() {
    let dict = Dictionary::new(1);
    let ram_offset = |index: u16, sub: u8| match dict.find(index, sub).map(|e| e.storage) {
        Ok(Storage::Ram { offset, .. }) => usize::from(offset),
        other => panic!("{index:#06X}:{sub} is not in RAM: {other:?}"),
    };

    // 0x603F error code: UNSIGNED16 (every table code fits), read-only, TxPDO-mappable; the handle points at it.
    let code = dict.find(0x603F, 0).unwrap();
    assert_eq!((code.data_type, code.access(), code.pdo()), (DataType::Unsigned16, Access::ReadOnly, PdoMapping::Tx));
    assert_eq!(ERROR_CODE.offset(), ram_offset(0x603F, 0));
    assert_eq!(dict.get(ERROR_CODE), 0, "no error at start-up");

    // 0x1001 error register: UNSIGNED8, read-only; the handle points at it.
    let register = dict.find(0x1001, 0).unwrap();
    assert_eq!((register.data_type, register.access()), (DataType::Unsigned8, Access::ReadOnly));
    assert_eq!(ERROR_REGISTER.offset(), ram_offset(0x1001, 0));

    // 0x1003: an ARRAY, sub 0 UNSIGNED8 rw accepting only 0, subs 1..=max UNSIGNED32 ro.
    let object = dict.object(0x1003).unwrap();
    assert_eq!(object.object_code, ObjectCode::Array);
    assert!(object.max_sub >= 1);
    assert_eq!(firmware::fault::history::capacity(&dict), object.max_sub);
    let count = dict.find(0x1003, 0).unwrap();
    assert_eq!(
        (count.data_type, count.access(), *count.generated_limits()),
        (DataType::Unsigned8, Access::ReadWrite, Limits::OneOf(&[0]))
    );
    for sub in 1..=object.max_sub {
        let entry = dict.find(0x1003, sub).unwrap();
        assert_eq!((entry.data_type, entry.access()), (DataType::Unsigned32, Access::ReadOnly), "0x1003:{sub}");
        ram_offset(0x1003, sub);
    }

    // 0x1014 COB-ID EMCY (0x80 + node-ID) and 0x1015 inhibit time (UNSIGNED16, 100 us units, rw).
    assert_eq!(dict.find(0x1014, 0).unwrap().data_type, DataType::Unsigned32);
    let inhibit = dict.find(0x1015, 0).unwrap();
    assert_eq!((inhibit.data_type, inhibit.access()), (DataType::Unsigned16, Access::ReadWrite));

    // Class f follows 0x605E (0 coast, 1 slow-down, 2 quick stop); class a follows 0x6007.
    assert_eq!(*dict.find(0x605E, 0).unwrap().generated_limits(), Limits::OneOf(&[0, 1, 2]));
    let abort = dict.find(0x6007, 0).unwrap();
    assert_eq!(abort.data_type, DataType::Integer16);
    assert!(matches!(*abort.generated_limits(), Limits::OneOf(values) if values.contains(&1)));
}

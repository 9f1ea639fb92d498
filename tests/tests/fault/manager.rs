//! The fault manager's latch and reset rules, its reporting through 0x603F / 0x1001 / 0x1003, the trip snapshot
//! and the CiA 402 fault inputs (`firmware::fault::manager`; digest `comms-faults-bootloader.md` §3.1-§3.7).

use firmware::cia402::{FaultClass, FaultInput, State, Ticks};
use firmware::fault::history::{self, HistoryEntry};
use firmware::fault::table::{REG_CURRENT, REG_GENERIC, REG_MOTION, REG_VOLTAGE};
use firmware::fault::{DiagnosisSnapshot, FaultId, FaultManager, Raised, ResetRefused};
use firmware::od::abort::SdoAbort;
use firmware::od::access::{AccessContext, CommState, Dictionary, NoApplicationObjects};
use firmware::od::generated::handles::{ERROR_CODE, ERROR_REGISTER};

fn snap(detail: i32) -> DiagnosisSnapshot {
    DiagnosisSnapshot { detail, ..DiagnosisSnapshot::EMPTY }
}

const OP: AccessContext =
    AccessContext { comm_state: CommState::Operational, power_stage_enabled: true, max_pdo_bytes: 8 };

#[test]
fn a_latched_fault_is_reset_only_after_its_cause_has_gone() {
    let mut m: FaultManager = FaultManager::new();
    assert_eq!(m.raise(FaultId::DcBusOverVoltage, snap(0), Ticks(1)), Raised::New);
    assert_eq!(m.reset_request(), Err(ResetRefused { blocking: FaultId::DcBusOverVoltage }));
    assert!(m.is_active(FaultId::DcBusOverVoltage), "a refused reset clears nothing");
    m.clear_cause(FaultId::DcBusOverVoltage);
    assert!(m.is_active(FaultId::DcBusOverVoltage), "latched until the reset");
    assert_eq!(m.reset_request(), Ok(()));
    assert!(!m.any_fault());
}

#[test]
fn a_reset_is_all_or_nothing() {
    let mut m: FaultManager = FaultManager::new();
    m.raise(FaultId::FollowingError, snap(0), Ticks(0)); // event: cause gone at once
    m.raise(FaultId::DcBusUnderVoltage, snap(0), Ticks(0)); // level: present
    assert_eq!(m.reset_request(), Err(ResetRefused { blocking: FaultId::DcBusUnderVoltage }));
    assert!(m.is_active(FaultId::FollowingError), "the event fault stays while another blocks the reset");
    m.clear_cause(FaultId::DcBusUnderVoltage);
    assert_eq!(m.reset_request(), Ok(()));
    assert_eq!(m.active().count(), 0);
}

#[test]
fn event_faults_reset_at_once() {
    let mut m: FaultManager = FaultManager::new();
    m.raise(FaultId::OverCurrent, snap(0), Ticks(0));
    assert_eq!(m.blocking_fault(), None);
    assert_eq!(m.reset_request(), Ok(()));
    assert!(!m.is_active(FaultId::OverCurrent));
}

#[test]
fn warnings_clear_themselves_and_ignore_fault_reset() {
    let mut m: FaultManager = FaultManager::new();
    m.raise(FaultId::MotorI2tLimit, snap(0), Ticks(0));
    assert!(m.warning_active());
    assert!(!m.any_fault());
    assert_eq!((m.error_code(), m.error_register()), (0, 0), "warnings stay out of 0x603F and 0x1001");
    assert_eq!(m.reset_request(), Ok(()), "a warning never blocks a reset");
    assert!(m.warning_active(), "and a reset does not clear it");
    m.clear_cause(FaultId::MotorI2tLimit);
    assert!(!m.warning_active());
}

#[test]
fn error_register_and_error_code_reflect_the_active_set() {
    let mut m: FaultManager = FaultManager::new();
    assert_eq!((m.error_code(), m.error_register()), (0, 0));
    m.raise(FaultId::FollowingError, snap(0), Ticks(0));
    assert_eq!((m.error_code(), m.error_register()), (0x8611, REG_GENERIC | REG_MOTION));
    m.raise(FaultId::DcBusUnderVoltage, snap(0), Ticks(1));
    // Class d over class f, whatever the order.
    assert_eq!(m.error_code(), 0x3220);
    assert_eq!(m.error_register(), REG_GENERIC | REG_MOTION | REG_VOLTAGE);
    m.raise(FaultId::OverCurrent, snap(0), Ticks(2));
    assert_eq!(m.error_code(), 0x3220, "among equals the earliest (the root cause)");
    assert_eq!(m.error_register(), REG_GENERIC | REG_MOTION | REG_VOLTAGE | REG_CURRENT);
    m.clear_cause(FaultId::DcBusUnderVoltage);
    m.reset_request().unwrap();
    assert_eq!((m.error_code(), m.error_register()), (0, 0));
}

#[test]
fn publish_writes_error_code_register_and_history() {
    let mut dict = Dictionary::new(1);
    let mut m: FaultManager = FaultManager::new();
    m.raise(FaultId::OverCurrent, snap(0), Ticks(0));
    m.raise(FaultId::FollowingError, snap(0), Ticks(0));
    m.publish(&mut dict);
    assert_eq!(dict.get(ERROR_CODE), 0x2310);
    assert_eq!(dict.get(ERROR_REGISTER), REG_GENERIC | REG_CURRENT | REG_MOTION);
    let entries: Vec<_> = history::entries(&dict).collect();
    assert_eq!(
        entries,
        [
            HistoryEntry { code: 0x8611, register: REG_GENERIC | REG_CURRENT | REG_MOTION, number: 2 },
            HistoryEntry { code: 0x2310, register: REG_GENERIC | REG_CURRENT, number: 1 },
        ],
        "newest first, with the register at the trip and a running number"
    );
    // The SDO reads the same: 0x1003:00 = 2, 0x1003:01 = 0x02 83 8611.
    let mut buf = [0u8; 4];
    dict.read(0x1003, 0, 0, &mut buf, &mut NoApplicationObjects).unwrap();
    assert_eq!(buf[0], 2);
    dict.read(0x1003, 1, 0, &mut buf, &mut NoApplicationObjects).unwrap();
    assert_eq!(u32::from_le_bytes(buf), 0x0283_8611);
    m.reset_request().unwrap();
    m.publish(&mut dict);
    assert_eq!((dict.get(ERROR_CODE), dict.get(ERROR_REGISTER)), (0, 0));
    assert_eq!(history::count(&dict), 2, "the history outlives the reset");
}

#[test]
fn history_saturates_at_its_capacity_dropping_the_oldest() {
    let mut dict = Dictionary::new(1);
    let capacity = history::capacity(&dict);
    assert_eq!(capacity, 8, "device.toml declares 8 entries");
    let mut m: FaultManager = FaultManager::new();
    // Event faults raised and reset one after another: 12 events.
    let ids = [FaultId::OverCurrent, FaultId::FollowingError, FaultId::PdoLength, FaultId::NegativeLimitSwitch];
    let mut codes = Vec::new();
    for i in 0..12 {
        let id = ids[i % ids.len()];
        m.raise(id, snap(0), Ticks(0));
        codes.push(id.info().code);
        m.reset_request().unwrap();
        if i % 5 == 0 {
            m.publish(&mut dict); // publishing in between or in batches gives the same history
        }
    }
    m.publish(&mut dict);
    assert_eq!(history::count(&dict), capacity);
    let stored: Vec<u16> = history::entries(&dict).map(|e| e.code).collect();
    let expected: Vec<u16> = codes.iter().rev().take(usize::from(capacity)).copied().collect();
    assert_eq!(stored, expected);
    let numbers: Vec<u8> = history::entries(&dict).map(|e| e.number).collect();
    assert_eq!(numbers, (5..=12).rev().collect::<Vec<u8>>());
}

#[test]
fn writing_zero_to_sub_0_clears_the_history() {
    let mut dict = Dictionary::new(1);
    let mut m: FaultManager = FaultManager::new();
    m.raise(FaultId::InternalSoftware, snap(0), Ticks(0));
    m.raise(FaultId::PdoLength, snap(0), Ticks(0));
    m.publish(&mut dict);
    assert_eq!(history::count(&dict), 2);

    // CiA 301: only 0 may be written (IDX L1608).
    assert_eq!(dict.write(0x1003, 0, &[1], OP, &mut NoApplicationObjects), Err(SdoAbort::InvalidValue));
    assert_eq!(dict.write(0x1003, 1, &[0; 4], OP, &mut NoApplicationObjects), Err(SdoAbort::ReadOnly));
    assert_eq!(dict.write(0x1003, 0, &[0], OP, &mut NoApplicationObjects), Ok(()));
    history::after_sdo_write(&mut dict, 0x1003, 0);
    assert_eq!(history::count(&dict), 0);
    assert_eq!(history::entries(&dict).count(), 0);
    let mut buf = [0xAAu8; 4];
    dict.read(0x1003, 1, 0, &mut buf, &mut NoApplicationObjects).unwrap();
    assert_eq!(buf, [0; 4], "the entries are zeroed by the hook");

    // The history restarts at one entry; the hook ignores other objects.
    m.reset_request().unwrap();
    m.raise(FaultId::OverCurrent, snap(0), Ticks(0));
    m.publish(&mut dict);
    history::after_sdo_write(&mut dict, 0x6040, 0);
    assert_eq!(history::entries(&dict).map(|e| e.code).collect::<Vec<_>>(), [0x2310]);
}

#[test]
fn without_the_hook_the_count_still_rules() {
    let mut dict = Dictionary::new(1);
    let mut m: FaultManager = FaultManager::new();
    m.raise(FaultId::InternalSoftware, snap(0), Ticks(0));
    m.raise(FaultId::PdoLength, snap(0), Ticks(0));
    m.publish(&mut dict);
    dict.write(0x1003, 0, &[0], OP, &mut NoApplicationObjects).unwrap();
    m.raise(FaultId::OverCurrent, snap(0), Ticks(0));
    m.publish(&mut dict);
    assert_eq!(history::count(&dict), 1);
    assert_eq!(history::entries(&dict).map(|e| e.code).collect::<Vec<_>>(), [0x2310]);
}

#[test]
fn the_snapshot_is_the_trip_not_later_values() {
    let mut m: FaultManager = FaultManager::new();
    let trip = DiagnosisSnapshot {
        phase_currents_ma: [10_500, -5_000, -5_500],
        bus_voltage_mv: 24_100,
        power_stage_temperature_ddegc: 412,
        motor_i2t_percent: 37,
        position_inc: 123_456,
        velocity_rpm: 3_000,
        state: State::OperationEnabled,
        tick: Ticks(1000),
        detail: 0,
    };
    assert_eq!(m.raise(FaultId::OverCurrent, trip, Ticks(1000)), Raised::New);
    // The detector sees the condition again in the following samples, with other values.
    let later = DiagnosisSnapshot { phase_currents_ma: [0; 3], state: State::Fault, tick: Ticks(1001), ..trip };
    assert_eq!(m.raise(FaultId::OverCurrent, later, Ticks(1001)), Raised::AlreadyActive);
    assert_eq!(m.snapshot(FaultId::OverCurrent), Some(&trip));
    assert_eq!(m.active().next().map(|a| a.raised_at), Some(Ticks(1000)));
    // A second fault of the same episode does not replace the first trip either.
    m.raise(FaultId::DcBusOverVoltage, later, Ticks(1002));
    m.clear_cause(FaultId::DcBusOverVoltage);
    m.reset_request().unwrap();
    let first = m.first_trip().expect("kept after the reset");
    assert_eq!((first.id, first.snapshot), (FaultId::OverCurrent, trip));
    assert_eq!(m.snapshot(FaultId::OverCurrent), None, "gone from the active set");
    // After the reset a new raise is a new event with a new snapshot.
    assert_eq!(m.raise(FaultId::OverCurrent, later, Ticks(2000)), Raised::New);
    assert_eq!(m.snapshot(FaultId::OverCurrent), Some(&later));
    assert_eq!(m.first_trip().map(|t| t.snapshot), Some(later));
}

#[test]
fn machine_inputs_follow_the_reaction_class() {
    let mut m: FaultManager = FaultManager::new();
    assert_eq!(m.take_machine_input(), FaultInput::default());
    m.raise(FaultId::FollowingError, snap(0), Ticks(0));
    assert_eq!(m.take_machine_input(), FaultInput { raised: Some(FaultClass::Reaction), present: false });
    assert_eq!(m.take_machine_input(), FaultInput { raised: None, present: false }, "raised is an event");
    m.raise(FaultId::DcBusOverVoltage, snap(0), Ticks(0));
    m.raise(FaultId::SoftwarePositionLimit, snap(0), Ticks(0));
    assert_eq!(m.take_machine_input(), FaultInput { raised: Some(FaultClass::Critical), present: true });
    m.clear_cause(FaultId::DcBusOverVoltage);
    assert_eq!(m.take_machine_input(), FaultInput { raised: None, present: false });
    m.reset_request().unwrap();

    // Communication faults go to `connection_lost` (0x6007), not to `raised`; they hold until the reset.
    m.raise(FaultId::HeartbeatLost, snap(0), Ticks(0));
    assert_eq!(m.take_machine_input(), FaultInput::default());
    assert!(m.connection_lost());
    m.clear_cause(FaultId::HeartbeatLost);
    assert!(m.connection_lost(), "latched until the fault reset");
    m.reset_request().unwrap();
    assert!(!m.connection_lost());

    // The EMCY overflow is the EMCY producer's own report, never raised through the manager.
    assert_eq!(m.raise(FaultId::EmcyOverflow, snap(0), Ticks(0)), Raised::Ignored);
    assert!(!m.is_active(FaultId::EmcyOverflow));

    // Warnings touch neither.
    m.raise(FaultId::PowerStageTemperatureHigh, snap(0), Ticks(0));
    assert_eq!(m.take_machine_input(), FaultInput::default());
    assert!(!m.connection_lost());
}

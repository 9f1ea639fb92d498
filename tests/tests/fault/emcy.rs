//! The EMCY producer (`firmware::fault::emcy`) and the manager's EMCY traffic: the CiA 301 frame layout (IDX
//! Table 7-152 L7017-L7024, with this drive's manufacturer bytes), the inhibit time 0x1015 (100 us units), the
//! burst and overflow rules, and property tests that no message is ever lost silently.

use firmware::cia402::Ticks;
use firmware::fault::emcy::{EmcyFrameError, ERROR_RESET};
use firmware::fault::{DiagnosisSnapshot, EmcyMessage, EmcyProducer, FaultId, FaultManager, InhibitTime, FAULT_COUNT};
use proptest::prelude::*;

fn snap(detail: i32) -> DiagnosisSnapshot {
    DiagnosisSnapshot { detail, ..DiagnosisSnapshot::EMPTY }
}

fn drain<const Q: usize>(m: &mut FaultManager<Q>, from: u32) -> Vec<(u32, EmcyMessage)> {
    (from..from + 10_000).filter_map(|t| m.poll_emcy(Ticks(t)).map(|f| (t, EmcyMessage::parse(&f).unwrap()))).collect()
}

#[test]
fn frame_layout_golden_bytes() {
    // Over-current of +10.5 A: 0x2310 LE, register 0x03 (generic + current), fault number 0, peak phase current
    // 10_500 mA = 0x0000_2904 LE.
    let msg = EmcyMessage::fault(FaultId::OverCurrent, 0x03, 10_500);
    assert_eq!(msg.to_bytes(), [0x10, 0x23, 0x03, 0x00, 0x04, 0x29, 0x00, 0x00]);
    assert_eq!(EmcyMessage::parse(&msg.to_bytes()), Ok(msg));
    // Software position limit (number 16) at position -2 inc: a negative value, two's complement LE.
    let msg = EmcyMessage::fault(FaultId::SoftwarePositionLimit, 0x81, -2);
    assert_eq!(msg.to_bytes(), [0x82, 0x8A, 0x81, 16, 0xFE, 0xFF, 0xFF, 0xFF]);
    // Error reset: all zero but the register.
    assert_eq!(EmcyMessage::error_reset(0).to_bytes(), [0; 8]);
    assert_eq!(ERROR_RESET, 0);
    // Overflow report: 0xFF90, fault number 28, count lost.
    assert_eq!(EmcyMessage::overflow(0x01, 7).to_bytes(), [0x90, 0xFF, 0x01, 28, 7, 0, 0, 0]);
    assert!(EmcyMessage::overflow(0, 1).is_overflow());
    assert_eq!(EmcyMessage::parse(&[0; 7]), Err(EmcyFrameError::Length(7)));
    assert_eq!(EmcyMessage::parse(&[0; 9]), Err(EmcyFrameError::Length(9)));
}

#[test]
fn the_manager_puts_the_trip_value_in_the_frame() {
    let mut m: FaultManager = FaultManager::new();
    let trip = DiagnosisSnapshot { phase_currents_ma: [-4_000, 11_000, -7_000], ..DiagnosisSnapshot::EMPTY };
    m.raise(FaultId::OverCurrent, trip, Ticks(0));
    let under = DiagnosisSnapshot { bus_voltage_mv: 8_500, ..DiagnosisSnapshot::EMPTY };
    m.raise(FaultId::DcBusUnderVoltage, under, Ticks(0));
    let frames = drain(&mut m, 0);
    assert_eq!(frames.len(), 2);
    let (over, undervoltage) = (frames[0].1, frames[1].1);
    assert_eq!((over.code, over.register, over.fault_number(), over.value() as i32), (0x2310, 0x03, 0, 11_000));
    assert_eq!((undervoltage.code, undervoltage.register, undervoltage.value()), (0x3220, 0x07, 8_500));
}

#[test]
fn a_burst_within_the_inhibit_time_is_reported_completely_in_order_and_spaced() {
    let mut m: FaultManager = FaultManager::new();
    // 1 ms inhibit (0x1015 = 10 x 100 us): at 400 us per tick, 3 ticks (1.2 ms) between frames.
    m.emcy_mut().set_inhibit_time(InhibitTime(10));
    let burst = [
        FaultId::DcBusOverVoltage,
        FaultId::OverCurrent,
        FaultId::PhaseCurrentImplausible,
        FaultId::EncoderSignalLoss,
        FaultId::FollowingError,
    ];
    for (i, id) in burst.iter().enumerate() {
        m.raise(*id, snap(i as i32), Ticks(100));
    }
    let frames = drain(&mut m, 100);
    let codes: Vec<u16> = frames.iter().map(|(_, f)| f.code).collect();
    assert_eq!(codes, burst.map(|id| id.info().code), "complete and in order, the first fault first");
    let times: Vec<u32> = frames.iter().map(|(t, _)| *t).collect();
    assert_eq!(times, [100, 103, 106, 109, 112]);
    for pair in times.windows(2) {
        assert!(u64::from(pair[1] - pair[0]) * 4 >= 10, "inhibit time respected");
    }
}

#[test]
fn inhibit_zero_sends_at_once_and_the_first_message_never_waits() {
    let mut p: EmcyProducer<8> = EmcyProducer::new(InhibitTime(0));
    assert_eq!(p.poll(Ticks(0)), None);
    p.push(EmcyMessage::error_reset(0));
    p.push(EmcyMessage::error_reset(1));
    assert!(p.poll(Ticks(5)).is_some());
    assert!(p.poll(Ticks(5)).is_some(), "inhibit 0: back to back");
    let mut p: EmcyProducer<8> = EmcyProducer::new(InhibitTime(u16::MAX));
    p.push(EmcyMessage::error_reset(0));
    assert!(p.poll(Ticks(7)).is_some(), "the first message after a quiet period leaves at once");
    p.push(EmcyMessage::error_reset(0));
    assert_eq!(p.poll(Ticks(7 + 16_383)), None, "65535 x 100 us = 16383.75 ticks");
    assert!(p.poll(Ticks(7 + 16_384)).is_some());
}

#[test]
fn an_overflow_keeps_the_oldest_and_is_itself_reported() {
    let mut p: EmcyProducer<4> = EmcyProducer::new(InhibitTime(0));
    for i in 0..10 {
        p.push(EmcyMessage::fault(FaultId::InternalSoftware, 0x01, i));
    }
    let out: Vec<EmcyMessage> =
        std::iter::from_fn(|| p.poll(Ticks(0))).map(|f| EmcyMessage::parse(&f).unwrap()).collect();
    // Three messages (the fourth slot is the report's), then the report of the seven lost.
    assert_eq!(out.len(), 4);
    for (i, msg) in out.iter().take(3).enumerate() {
        assert_eq!((msg.code, msg.value()), (0x6180, i as u32));
    }
    assert!(out[3].is_overflow());
    assert_eq!(out[3].value(), 7);
    let stats = p.stats();
    assert_eq!((stats.enqueued, stats.emitted, stats.lost, stats.overflow_reports), (10, 3, 7, 1));
}

#[test]
fn a_burst_larger_than_the_queue_keeps_the_first_faults() {
    let mut m: FaultManager<4> = FaultManager::new();
    let burst = [
        FaultId::PowerStageProtection,
        FaultId::OverCurrent,
        FaultId::DcBusOverVoltage,
        FaultId::EncoderSignalLoss,
        FaultId::HallInvalidState,
        FaultId::FollowingError,
    ];
    for id in burst {
        m.raise(id, snap(0), Ticks(0));
    }
    let frames: Vec<EmcyMessage> = drain(&mut m, 0).into_iter().map(|(_, f)| f).collect();
    let codes: Vec<u16> = frames.iter().map(|f| f.code).collect();
    assert_eq!(codes, [0x2320, 0x2310, 0x3210, 0xFF90], "the root cause first, then the report of the rest");
    assert_eq!(frames[3].value(), 3);
    assert_eq!(frames[3].register, 0x27, "the register when the first loss happened (current, voltage, sensor)");
}

#[test]
fn the_last_fault_clearing_sends_an_error_reset() {
    let mut m: FaultManager = FaultManager::new();
    m.raise(FaultId::FollowingError, snap(0), Ticks(0));
    m.raise(FaultId::MotorI2tLimit, snap(0), Ticks(0));
    m.reset_request().unwrap();
    assert_eq!(drain(&mut m, 0).len(), 2, "no reset EMCY while the warning remains");
    m.clear_cause(FaultId::MotorI2tLimit);
    let frames = drain(&mut m, 0);
    assert_eq!(frames.iter().map(|(_, f)| (f.code, f.register)).collect::<Vec<_>>(), [(0x0000, 0)]);
    // A refused reset sends nothing; an accepted one with nothing active sends nothing either.
    m.raise(FaultId::DcBusUnderVoltage, snap(0), Ticks(0));
    assert!(m.reset_request().is_err());
    assert_eq!(drain(&mut m, 0).len(), 1);
    m.clear_cause(FaultId::DcBusUnderVoltage);
    m.reset_request().unwrap();
    assert_eq!(drain(&mut m, 0).iter().map(|(_, f)| f.code).collect::<Vec<_>>(), [0x0000]);
    m.reset_request().unwrap();
    assert!(drain(&mut m, 0).is_empty());
}

/// Checks an emitted stream against the enqueued sequence: every message is the next expected one, a report
/// skips exactly the messages it counts, and at the end everything is accounted for.
fn check_accounting(enqueued: &[u32], emitted: &[EmcyMessage]) {
    let mut next = 0usize;
    for msg in emitted {
        if msg.is_overflow() {
            assert!(msg.value() >= 1, "a report counts at least one loss");
            next += msg.value() as usize;
        } else {
            assert_eq!(Some(&msg.value()), enqueued.get(next), "messages leave in order, none skipped silently");
            next += 1;
        }
    }
    assert_eq!(next, enqueued.len(), "every message emitted or counted in an emitted report");
}

#[derive(Clone, Debug)]
enum QueueOp {
    Push,
    Poll(u8),
}

fn queue_op() -> impl Strategy<Value = QueueOp> {
    prop_oneof![3 => Just(QueueOp::Push), 2 => (0u8..8).prop_map(QueueOp::Poll)]
}

#[derive(Clone, Debug)]
enum ManagerOp {
    Raise(u8),
    ClearCause(u8),
    Reset,
    Poll(u8),
    Inhibit(u16),
}

fn manager_op() -> impl Strategy<Value = ManagerOp> {
    let id = 0u8..FAULT_COUNT as u8;
    prop_oneof![
        4 => id.clone().prop_map(ManagerOp::Raise),
        2 => id.prop_map(ManagerOp::ClearCause),
        2 => Just(ManagerOp::Reset),
        3 => (0u8..6).prop_map(ManagerOp::Poll),
        1 => (0u16..40).prop_map(ManagerOp::Inhibit),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    /// The queue never loses a message silently, and a message pushed into an idle queue (the first of a burst)
    /// is always emitted.
    #[test]
    fn the_queue_never_loses_silently(ops in prop::collection::vec(queue_op(), 0..200), inhibit in 0u16..20) {
        let mut p: EmcyProducer<6> = EmcyProducer::new(InhibitTime(inhibit));
        let mut now = 0u32;
        let mut enqueued = Vec::new();
        let mut firsts = Vec::new();
        let mut emitted = Vec::new();
        for op in ops {
            match op {
                QueueOp::Push => {
                    let n = enqueued.len() as u32;
                    if p.is_idle() {
                        firsts.push(n);
                    }
                    p.push(EmcyMessage::fault(FaultId::InternalSoftware, 1, n as i32));
                    enqueued.push(n);
                    prop_assert!(p.pending() <= 6);
                }
                QueueOp::Poll(dt) => {
                    now += u32::from(dt);
                    if let Some(frame) = p.poll(Ticks(now)) {
                        emitted.push(EmcyMessage::parse(&frame).unwrap());
                    }
                }
            }
        }
        for _ in 0..100 {
            now += 8;
            if let Some(frame) = p.poll(Ticks(now)) {
                emitted.push(EmcyMessage::parse(&frame).unwrap());
            }
        }
        prop_assert!(p.is_idle());
        check_accounting(&enqueued, &emitted);
        let values: Vec<u32> = emitted.iter().filter(|m| !m.is_overflow()).map(|m| m.value()).collect();
        for first in firsts {
            prop_assert!(values.contains(&first), "first of a burst {} not emitted", first);
        }
        let s = p.stats();
        prop_assert_eq!(s.enqueued as usize, enqueued.len());
        prop_assert_eq!(s.emitted + s.lost, s.enqueued);
    }

    /// Random raise / clear / reset / poll sequences on the manager never panic, keep 0x1001 and 0x603F
    /// consistent with the active set (0x603F shows the STO state when no fault is active), and account for every
    /// EMCY.
    #[test]
    fn the_manager_never_panics_and_accounts_for_every_emcy(ops in prop::collection::vec(manager_op(), 0..300)) {
        let mut m: FaultManager<4> = FaultManager::new();
        let mut dict = firmware::od::access::Dictionary::new(1);
        let mut now = 0u32;
        let mut reports_lost = 0u32;
        let mut emitted_messages = 0u32;
        let mut first_fault_code: Option<u16> = None;
        let mut first_emitted = Vec::new();
        for op in ops {
            match op {
                ManagerOp::Raise(n) => {
                    let id = FaultId::from_number(n).unwrap();
                    let idle = m.emcy().is_idle();
                    if m.raise(id, snap(i32::from(n)), Ticks(now)) == firmware::fault::Raised::New && idle {
                        first_fault_code.get_or_insert(id.info().code);
                    }
                }
                ManagerOp::ClearCause(n) => m.clear_cause(FaultId::from_number(n).unwrap()),
                ManagerOp::Reset => {
                    let blocking = m.blocking_fault();
                    prop_assert_eq!(m.reset_request().err().map(|r| r.blocking), blocking);
                }
                ManagerOp::Poll(dt) => {
                    now += u32::from(dt);
                    if let Some(frame) = m.poll_emcy(Ticks(now)) {
                        let msg = EmcyMessage::parse(&frame).unwrap();
                        if msg.is_overflow() { reports_lost += msg.value(); } else { emitted_messages += 1; }
                        first_emitted.push(msg.code);
                    }
                }
                ManagerOp::Inhibit(units) => m.emcy_mut().set_inhibit_time(InhibitTime(units)),
            }
            let register = m.active().fold(0u8, |acc, a| acc | a.id.info().register);
            prop_assert_eq!(m.error_register(), register);
            // 0x603F: a fault's code, or with no fault the Safe Torque Off state's (`fault::manager`).
            prop_assert_eq!(m.error_code() == 0, !m.any_fault() && !m.safe_torque_off_active());
            if let Some(code) = (m.error_code() != 0).then(|| m.error_code()) {
                let sto = !m.any_fault() && code == FaultId::SafeTorqueOff.info().code;
                prop_assert!(m.active().any(|a| a.id.info().code == code) || sto);
            }
            m.publish(&mut dict);
            prop_assert!(firmware::fault::history::count(&dict) <= firmware::fault::history::capacity(&dict));
        }
        for _ in 0..100 {
            now += 1000;
            if let Some(frame) = m.poll_emcy(Ticks(now)) {
                let msg = EmcyMessage::parse(&frame).unwrap();
                if msg.is_overflow() { reports_lost += msg.value(); } else { emitted_messages += 1; }
                first_emitted.push(msg.code);
            }
        }
        let s = m.emcy().stats();
        prop_assert_eq!(emitted_messages + reports_lost, s.enqueued, "every EMCY emitted or reported lost");
        prop_assert_eq!(reports_lost, s.lost);
        // The first fault or warning raised into an idle queue always reaches the bus.
        if let Some(code) = first_fault_code {
            prop_assert!(first_emitted.contains(&code));
        }
    }
}

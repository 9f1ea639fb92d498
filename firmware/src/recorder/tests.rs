//! The recorder through the dictionary and its application-objects port, as an SDO server reaches it, on
//! snapshots pushed by hand.
use super::objects::RecorderObjects;
use super::*;
use crate::control::frames::Amps;
use crate::od::access::{AccessContext, CommState, Dictionary, NoApplicationObjects};
extern crate std;
use std::boxed::Box;
use std::vec::Vec;

/// The dictionary with a recorder behind its port, as a fieldbus server holds them.
struct Drive {
    dict: Dictionary,
    recorder: Recorder,
}

impl Drive {
    fn read(
        &mut self,
        index: u16,
        sub: u8,
        offset: usize,
        buf: &mut [u8],
    ) -> Result<crate::od::access::ReadOutcome, SdoAbort> {
        let mut none = NoApplicationObjects;
        self.dict.read(index, sub, offset, buf, &mut RecorderObjects::new(&mut self.recorder, &mut none))
    }

    fn record(&mut self, ring: &SampleRing) {
        self.recorder.take_objects(self.dict.values().bytes());
        while self.recorder.drain(ring, 3) {}
    }
}

const CTX: AccessContext =
    AccessContext { comm_state: CommState::Operational, power_stage_enabled: true, max_pdo_bytes: 8 };

fn buffer(words: usize) -> &'static [AtomicU16] {
    Box::leak((0..words * 2).map(|_| AtomicU16::new(0)).collect::<Box<[AtomicU16]>>())
}

fn recorder(words: usize) -> Drive {
    let mut d = Drive { dict: Dictionary::new(1), recorder: Recorder::new() };
    d.recorder.attach(buffer(words));
    d
}

fn write(d: &mut Drive, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoAbort> {
    let mut none = NoApplicationObjects;
    d.dict.write(index, sub, data, CTX, &mut RecorderObjects::new(&mut d.recorder, &mut none))
}

fn set(d: &mut Drive, sub: u8, value: u32, len: usize) {
    let bytes = value.to_le_bytes();
    write(d, RECORDER, sub, bytes.get(..len).unwrap_or(&bytes)).expect("configuration accepted");
}

/// Channels `0xIIIISS00`.
fn channels(d: &mut Drive, list: &[u32]) {
    write(d, VARIABLES, 0, &[0]).expect("count 0");
    for (k, c) in list.iter().enumerate() {
        write(d, VARIABLES, k as u8 + 1, &c.to_le_bytes()).expect("channel accepted");
    }
    write(d, VARIABLES, 0, &[list.len() as u8]).expect("count");
}

fn arm(d: &mut Drive) -> Result<(), SdoAbort> {
    write(d, RECORDER, sub::CONTROL, &[1])
}

fn state(d: &mut Drive) -> u8 {
    let mut b = [0u8; 1];
    d.read(RECORDER, sub::STATE, 0, &mut b).expect("state readable");
    b[0]
}

fn read_u32(d: &mut Drive, s: u8) -> u32 {
    let mut b = [0u8; 4];
    d.read(RECORDER, s, 0, &mut b).expect("readable");
    u32::from_le_bytes(b)
}

/// The whole of 0x3302, in 7-byte parts as a segmented upload reads it.
fn upload(d: &mut Drive) -> Result<Vec<u8>, SdoAbort> {
    let mut out = Vec::new();
    loop {
        let mut part = [0u8; 7];
        let r = d.read(BUFFER, 0, out.len(), &mut part)?;
        out.extend_from_slice(&part[..r.len]);
        if out.len() >= r.total_len || r.len == 0 {
            return Ok(out);
        }
    }
}

/// A snapshot whose q current is `iq_ma` mA, position `k`, duty A `k`.
fn snapshot(iq_ma: i32, k: u32) -> ring::Tier1Sample {
    let mut s = [0u32; SAMPLE_WORDS];
    s[usize::from(ring::word::I_Q)] = Amps::from_milliamps(iq_ma).to_bits().cast_unsigned();
    s[usize::from(ring::word::POSITION)] = k;
    s[usize::from(ring::word::DUTY_AB)] = k & 0xFFFF;
    s
}

const IQ: u32 = 0x3303_0500;
const POSITION: u32 = 0x3303_0D00;
const DUTY_A: u32 = 0x3303_0A00;

/// Pushes snapshots and drains every ten, as tier 1 and tier 2 do.
fn run(d: &mut Drive, ring: &SampleRing, samples: impl IntoIterator<Item = ring::Tier1Sample>) {
    for (k, s) in samples.into_iter().enumerate() {
        ring.push_sample(&s);
        if k % 10 == 9 {
            d.record(ring);
        }
    }
    d.record(ring);
}

fn i16_at(bytes: &[u8], at: usize) -> i16 {
    i16::from_le_bytes([bytes[at], bytes[at + 1]])
}

fn u32_at(bytes: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]])
}

/// Issue 22 item 2: a rising crossing of the trigger channel with preceding samples. 0x3300:05 = 4 samples
/// kept before the first sample at or above the threshold, 10 in all; each sample 2 bytes of i_q (mA) and 4
/// of the position, packed.
#[test]
fn rising_trigger_keeps_the_preceding_samples() {
    let mut d = recorder(1024);
    let ring = SampleRing::new();
    ring.push_sample(&snapshot(0, 0));
    d.record(&ring);
    channels(&mut d, &[IQ, POSITION]);
    set(&mut d, sub::SAMPLES, 10, 4);
    set(&mut d, sub::PRECEDING, 4, 4);
    set(&mut d, sub::MODE, u32::from(trigger::RISING), 1);
    set(&mut d, sub::THRESHOLD, 1500, 4);
    arm(&mut d).expect("armed");
    assert_eq!(state(&mut d), RecorderState::Waiting as u8);
    assert_eq!(upload(&mut d), Err(SdoAbort::DeviceState), "no recording to read while waiting");
    // 0, 100, ... 2900 mA: the crossing of 1500 mA at k = 15.
    run(&mut d, &ring, (0..30).map(|k| snapshot(100 * k as i32, k + 1)));
    assert_eq!(state(&mut d), RecorderState::Complete as u8);
    assert_eq!(read_u32(&mut d, sub::RECORDED), 10);
    let data = upload(&mut d).expect("complete");
    assert_eq!(data.len(), 10 * 6);
    let iq: Vec<i16> = (0..10).map(|s| i16_at(&data, s * 6)).collect();
    let pos: Vec<u32> = (0..10).map(|s| u32_at(&data, s * 6 + 2)).collect();
    assert_eq!(iq, [1100, 1200, 1300, 1400, 1500, 1600, 1700, 1800, 1900, 2000]);
    assert_eq!(pos, [12, 13, 14, 15, 16, 17, 18, 19, 20, 21]);
}

/// Falling edge through the threshold, and a bit of the mask set (0x3300:06 = 2 and 4), on a 32-bit channel;
/// the sampling period 0x3300:03 = 3 takes every third snapshot.
#[test]
fn falling_and_bit_triggers_with_a_sampling_period() {
    for (mode, threshold, mask, first) in [(trigger::FALLING, 100, 0, 99u32), (trigger::BITS_SET, 0, 0x40, 64)] {
        let mut d = recorder(1024);
        let ring = SampleRing::new();
        channels(&mut d, &[POSITION]);
        set(&mut d, sub::SAMPLES, 3, 4);
        set(&mut d, sub::PERIOD, 3, 2);
        set(&mut d, sub::MODE, u32::from(mode), 1);
        set(&mut d, sub::THRESHOLD, threshold, 4);
        set(&mut d, sub::MASK, mask, 4);
        arm(&mut d).expect("armed");
        ring.push_sample(&snapshot(0, 0));
        d.record(&ring);
        // Falling: 120 down to 91 (crosses 100 at 100 or just below); bits: 50 up to 79 (bit 6 from 64).
        let values: Vec<u32> = if mode == trigger::FALLING { (91..=120).rev().collect() } else { (50..80).collect() };
        run(&mut d, &ring, values.iter().map(|v| snapshot(0, *v)));
        let data = upload(&mut d).expect("complete");
        let got: Vec<u32> = (0..3).map(|s| u32_at(&data, s * 4)).collect();
        let step = if mode == trigger::FALLING { 0u32.wrapping_sub(3) } else { 3 };
        let triggered = got[0];
        assert!(
            if mode == trigger::FALLING {
                triggered <= threshold && triggered > threshold - 3
            } else {
                triggered & mask != 0 && triggered < first + 3
            },
            "mode {mode}: first sample {triggered}"
        );
        assert_eq!(got, [triggered, triggered.wrapping_add(step), triggered.wrapping_add(step.wrapping_mul(2))]);
    }
}

/// 16-bit channels that straddle the end of a small buffer: the stream wraps and reads back in order.
#[test]
fn samples_wrap_around_the_buffer_end() {
    // 7 words = 28 bytes; 3 channels of 2 bytes: 4 samples fit, 24 bytes.
    let mut d = recorder(7);
    let ring = SampleRing::new();
    channels(&mut d, &[DUTY_A, IQ, DUTY_A]);
    assert_eq!(read_u32(&mut d, sub::MAX_SAMPLES), 4);
    set(&mut d, sub::SAMPLES, 4, 4);
    set(&mut d, sub::PRECEDING, 2, 4);
    set(&mut d, sub::MODE, u32::from(trigger::RISING), 1);
    set(&mut d, sub::TRIGGER_CHANNEL, 1, 1);
    set(&mut d, sub::THRESHOLD, 20, 4);
    arm(&mut d).expect("armed");
    ring.push_sample(&snapshot(0, 0));
    d.record(&ring);
    run(&mut d, &ring, (1..40).map(|k| snapshot(-(k as i32), k)));
    let data = upload(&mut d).expect("complete");
    let rows: Vec<[i16; 3]> = (0..4).map(|s| [0, 1, 2].map(|c| i16_at(&data, s * 6 + c * 2))).collect();
    assert_eq!(rows, [[18, -18, 18], [19, -19, 19], [20, -20, 20], [21, -21, 21]]);
}

/// 0x3300:01 = 2 (trigger now) starts the recording at once while waiting; outside the waiting state it is
/// refused with 0x0800_0022 (CiA 301 Table 22, "present device state").
#[test]
fn trigger_now_only_while_waiting() {
    let mut d = recorder(1024);
    let ring = SampleRing::new();
    assert_eq!(write(&mut d, RECORDER, sub::CONTROL, &[2]), Err(SdoAbort::DeviceState));
    channels(&mut d, &[IQ]);
    set(&mut d, sub::SAMPLES, 5, 4);
    set(&mut d, sub::MODE, u32::from(trigger::RISING), 1);
    set(&mut d, sub::THRESHOLD, 100_000, 4);
    arm(&mut d).expect("armed");
    ring.push_sample(&snapshot(0, 0));
    run(&mut d, &ring, (0..20).map(|k| snapshot(k, k as u32)));
    assert_eq!(state(&mut d), RecorderState::Waiting as u8, "an unreachable threshold never fires");
    write(&mut d, RECORDER, sub::CONTROL, &[2]).expect("trigger now");
    run(&mut d, &ring, (0..20).map(|k| snapshot(1000 + k, k as u32)));
    assert_eq!(state(&mut d), RecorderState::Complete as u8);
    let data = upload(&mut d).expect("complete");
    assert_eq!((0..5).map(|s| i16_at(&data, s * 2)).collect::<Vec<_>>(), [1000, 1001, 1002, 1003, 1004]);
    assert_eq!(write(&mut d, RECORDER, sub::CONTROL, &[2]), Err(SdoAbort::DeviceState));
    write(&mut d, RECORDER, sub::CONTROL, &[0]).expect("stop");
    assert_eq!(state(&mut d), RecorderState::Idle as u8);
    assert_eq!(upload(&mut d), Ok(Vec::new()), "idle without a recording: the buffer reads empty");
}

/// While armed or recording, every configuration write is refused with 0x0800_0022 and changes nothing;
/// after a stop it is accepted again.
#[test]
fn configuration_is_refused_while_armed() {
    let mut d = recorder(1024);
    channels(&mut d, &[IQ]);
    set(&mut d, sub::MODE, u32::from(trigger::RISING), 1);
    arm(&mut d).expect("armed");
    for (index, s, data) in [
        (RECORDER, sub::PERIOD, &[2u8, 0][..]),
        (RECORDER, sub::SAMPLES, &[5, 0, 0, 0][..]),
        (RECORDER, sub::PRECEDING, &[1, 0, 0, 0][..]),
        (RECORDER, sub::MODE, &[0][..]),
        (RECORDER, sub::TRIGGER_CHANNEL, &[1][..]),
        (RECORDER, sub::THRESHOLD, &[1, 0, 0, 0][..]),
        (RECORDER, sub::MASK, &[1, 0, 0, 0][..]),
        (VARIABLES, 0, &[1][..]),
        (VARIABLES, 2, &POSITION.to_le_bytes()[..]),
    ] {
        assert_eq!(write(&mut d, index, s, data), Err(SdoAbort::DeviceState), "{index:04X}:{s}");
    }
    let mut b = [0u8; 1];
    d.read(RECORDER, sub::MODE, 0, &mut b).expect("readable");
    assert_eq!(b[0], trigger::RISING, "the refused write changed nothing");
    write(&mut d, RECORDER, sub::CONTROL, &[0]).expect("stop");
    write(&mut d, RECORDER, sub::MODE, &[0]).expect("idle: accepted");
}

/// A channel must be recordable (CiA 301 Table 22, 0x0604_0041): an object that does not exist, one that is
/// not TxPDO-mappable (0x1008 device name, 0x3300:03), a current-loop variable number beyond 13, the buffer
/// itself. Mappable objects and the variables 1..13 are accepted.
#[test]
fn channels_that_cannot_be_recorded_are_refused() {
    let mut d = recorder(1024);
    for bad in [0x5FFF_0100u32, 0x1008_0000, 0x3300_0300, 0x3303_0E00, 0x3303_0000, 0x3302_0000] {
        assert_eq!(write(&mut d, VARIABLES, 1, &bad.to_le_bytes()), Err(SdoAbort::CannotBeMapped), "{bad:08X}");
    }
    for good in [0x6041_0000u32, 0x6064_0000, 0x606C_0000, 0x3303_0100, 0x3303_0D00] {
        assert_eq!(write(&mut d, VARIABLES, 1, &good.to_le_bytes()), Ok(()), "{good:08X}");
    }
    // The dictionary's own limits come first: 9 channels (0x0609_0031), trigger mode 6 (0x0609_0030).
    assert_eq!(write(&mut d, VARIABLES, 0, &[9]), Err(SdoAbort::ValueTooHigh));
    assert_eq!(write(&mut d, RECORDER, sub::MODE, &[6]), Err(SdoAbort::InvalidValue));
    assert_eq!(write(&mut d, RECORDER, sub::PERIOD, &[0, 0]), Err(SdoAbort::ValueTooLow));
}

/// An arm the configuration cannot carry out is refused with 0x0604_0043 (CiA 301 Table 22, "general
/// parameter incompatibility") and leaves the recorder idle: no channel, a trigger channel beyond the
/// channels, more samples than fit, as many preceding samples as samples, no buffer.
#[test]
fn inconsistent_arm_is_refused() {
    let mut d = recorder(16);
    assert_eq!(arm(&mut d), Err(SdoAbort::ParameterIncompatibility), "no channel");
    channels(&mut d, &[IQ]);
    set(&mut d, sub::TRIGGER_CHANNEL, 2, 1);
    assert_eq!(arm(&mut d), Err(SdoAbort::ParameterIncompatibility), "trigger channel 2 of 1");
    set(&mut d, sub::TRIGGER_CHANNEL, 1, 1);
    // 16 words = 64 bytes = 32 samples of one 16-bit channel.
    assert_eq!(read_u32(&mut d, sub::MAX_SAMPLES), 32);
    set(&mut d, sub::SAMPLES, 33, 4);
    assert_eq!(arm(&mut d), Err(SdoAbort::ParameterIncompatibility), "33 samples of 32");
    set(&mut d, sub::SAMPLES, 8, 4);
    set(&mut d, sub::PRECEDING, 8, 4);
    assert_eq!(arm(&mut d), Err(SdoAbort::ParameterIncompatibility), "8 preceding of 8");
    set(&mut d, sub::PRECEDING, 7, 4);
    assert_eq!(state(&mut d), RecorderState::Idle as u8);
    arm(&mut d).expect("consistent");
    let mut without = Drive { dict: Dictionary::new(1), recorder: Recorder::new() };
    channels(&mut without, &[IQ]);
    assert_eq!(arm(&mut without), Err(SdoAbort::ParameterIncompatibility), "no buffer attached");
}

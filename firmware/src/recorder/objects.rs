//! The recorder's objects 0x3300..0x3302 as the SDO servers reach them: through the dictionary's
//! application-objects port ([`RecorderObjects`], wrapped around the drive's other application objects), after the
//! dictionary checked access, length and limits (`od::access` checks 1-5). The recorder answers from its own
//! state and configuration (module documentation of [`super`] for the objects and their refusals).

use core::sync::atomic::Ordering;

use super::{channel, sub, Recorder, RecorderState, BUFFER, RECORDER, VARIABLES};
use crate::od::abort::SdoAbort;
use crate::od::access::{ApplicationObjects, ReadOutcome};
use crate::od::entry::Entry;

impl Recorder {
    /// A read of a recorder entry from byte `offset` into `buf`.
    ///
    /// # Errors
    /// 0x0800_0022 for the buffer while the recorder samples into it; 0x0609_0011 for an entry it does not serve.
    pub fn read(&self, entry: &Entry, offset: usize, buf: &mut [u8]) -> Result<ReadOutcome, SdoAbort> {
        let c = &self.config;
        let value: u32 = match (entry.index, entry.sub) {
            (BUFFER, _) => return self.read_buffer(offset, buf),
            (RECORDER, sub::CONTROL) => 0,
            (RECORDER, sub::STATE) => self.state as u32,
            (RECORDER, sub::PERIOD) => u32::from(c.period),
            (RECORDER, sub::SAMPLES) => c.samples,
            (RECORDER, sub::PRECEDING) => c.preceding,
            (RECORDER, sub::MODE) => u32::from(c.mode),
            (RECORDER, sub::TRIGGER_CHANNEL) => u32::from(c.trigger_channel),
            (RECORDER, sub::THRESHOLD) => c.threshold.cast_unsigned(),
            (RECORDER, sub::MASK) => c.mask,
            (RECORDER, sub::MAX_SAMPLES) => self.capacity_rows(self.configured().2),
            (RECORDER, sub::RECORDED) if self.state == RecorderState::Complete => self.recorded,
            (RECORDER, sub::RECORDED) => 0,
            (VARIABLES, 0) => u32::from(c.count),
            (VARIABLES, s) => *c.channels.get(usize::from(s).wrapping_sub(1)).ok_or(SdoAbort::SubindexDoesNotExist)?,
            _ => return Err(SdoAbort::SubindexDoesNotExist),
        };
        let size = entry.data_type.fixed_size().unwrap_or(4).min(4);
        let bytes = value.to_le_bytes();
        let value = bytes.get(..size).unwrap_or(&bytes);
        let rest = value.get(offset..).unwrap_or_default();
        let len = rest.len().min(buf.len());
        if let (Some(to), Some(from)) = (buf.get_mut(..len), rest.get(..len)) {
            to.copy_from_slice(from);
        }
        Ok(ReadOutcome { len, total_len: value.len() })
    }

    /// 0x3302 from byte `offset`: the complete recording, oldest sample first; empty before any recording or after
    /// a stop (every readable variable uploads, CiA 306 §4.6.3); refused while the recorder samples into it.
    fn read_buffer(&self, offset: usize, buf: &mut [u8]) -> Result<ReadOutcome, SdoAbort> {
        match self.state {
            RecorderState::Complete => {}
            RecorderState::Idle => return Ok(ReadOutcome { len: 0, total_len: 0 }),
            RecorderState::Waiting | RecorderState::Recording => return Err(SdoAbort::DeviceState),
        }
        let total = (self.recorded as usize).saturating_mul(self.row_halves as usize).saturating_mul(2);
        let len = total.saturating_sub(offset).min(buf.len());
        let cap = (self.capacity as usize).saturating_mul(2);
        let mut at = (self.start as usize).saturating_mul(2).wrapping_add(offset).checked_rem(cap).unwrap_or(0);
        for byte in buf.iter_mut().take(len) {
            let half = self.buffer.get(at / 2).map_or(0, |h| h.load(Ordering::Relaxed));
            *byte = half.to_le_bytes().get(at % 2).copied().unwrap_or(0);
            at = at.wrapping_add(1);
            if at >= cap {
                at = 0;
            }
        }
        Ok(ReadOutcome { len, total_len: total })
    }

    /// A write of `data` (whole, its length and limits checked by the dictionary) to a recorder entry: stores the
    /// configuration or acts on the control, or refuses ([`super`] module documentation).
    ///
    /// # Errors
    /// 0x0800_0022, 0x0604_0041, 0x0604_0043, 0x0609_0030 as the module documentation lists them; 0x0601_0002 for
    /// a read-only entry (the dictionary refuses those first).
    pub fn write(&mut self, entry: &Entry, data: &[u8]) -> Result<(), SdoAbort> {
        let mut word = [0u8; 4];
        for (to, from) in word.iter_mut().zip(data) {
            *to = *from;
        }
        let value = u32::from_le_bytes(word);
        let busy = matches!(self.state, RecorderState::Waiting | RecorderState::Recording);
        let c = &mut self.config;
        match (entry.index, entry.sub) {
            (RECORDER, sub::CONTROL) => return self.command(value),
            (RECORDER | VARIABLES, _) if busy => return Err(SdoAbort::DeviceState),
            (RECORDER, sub::PERIOD) => c.period = value as u16,
            (RECORDER, sub::SAMPLES) => c.samples = value,
            (RECORDER, sub::PRECEDING) => c.preceding = value,
            (RECORDER, sub::MODE) => c.mode = value as u8,
            (RECORDER, sub::TRIGGER_CHANNEL) => c.trigger_channel = value as u8,
            (RECORDER, sub::THRESHOLD) => c.threshold = value.cast_signed(),
            (RECORDER, sub::MASK) => c.mask = value,
            (VARIABLES, 0) => c.count = value as u8,
            (VARIABLES, s) => {
                if value != 0 {
                    channel(value)?;
                }
                *c.channels.get_mut(usize::from(s).wrapping_sub(1)).ok_or(SdoAbort::SubindexDoesNotExist)? = value;
            }
            _ => return Err(SdoAbort::ReadOnly),
        }
        Ok(())
    }
}

/// The application-objects port with the recorder in front: 0x3300..0x3302 to the recorder, every other
/// application entry to `next` (the drive's objects: store, program control, auto tuning). `dyn` so that one
/// instance of the SDO servers' code serves every port.
pub struct RecorderObjects<'a> {
    recorder: &'a mut Recorder,
    next: &'a mut dyn ApplicationObjects,
}

impl core::fmt::Debug for RecorderObjects<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("RecorderObjects").field("recorder", &self.recorder.state()).finish_non_exhaustive()
    }
}

impl<'a> RecorderObjects<'a> {
    /// `recorder` in front of `next`.
    pub fn new(recorder: &'a mut Recorder, next: &'a mut dyn ApplicationObjects) -> Self {
        Self { recorder, next }
    }
}

impl ApplicationObjects for RecorderObjects<'_> {
    fn read(&mut self, entry: &'static Entry, offset: usize, buf: &mut [u8]) -> Result<ReadOutcome, SdoAbort> {
        if Recorder::serves(entry.index) {
            return self.recorder.read(entry, offset, buf);
        }
        self.next.read(entry, offset, buf)
    }

    fn write(
        &mut self,
        entry: &'static Entry,
        offset: usize,
        data: &[u8],
        complete: bool,
        values: &mut [u8],
    ) -> Result<(), SdoAbort> {
        if Recorder::serves(entry.index) {
            // Every writable recorder entry is fixed-size: one whole part.
            return self.recorder.write(entry, data);
        }
        self.next.write(entry, offset, data, complete, values)
    }

    fn abort(&mut self, entry: &'static Entry) {
        if !Recorder::serves(entry.index) {
            self.next.abort(entry);
        }
    }

    fn reload_communication(&mut self, values: &mut [u8]) {
        self.next.reload_communication(values);
    }
}

//! Transfer steps shared by the CAN SDO server and the CoE SDO server: the size of an expedited download,
//! toggle-checked segmented downloads on the dictionary's staged download, and uploads streamed from
//! [`Dictionary::read_entry`] at increasing offsets.

use crate::od::abort::SdoAbort;
use crate::od::access::{AccessContext, ApplicationObjects, Dictionary, Download};
use crate::od::entry::Entry;

/// The bytes of an expedited download (CiA 301 §7.2.4.3.3; ETG.1000.6 §5.6.2.1): `4 - n` when the size is
/// indicated; otherwise the entry's size if it is a fixed-size type of at most 4 bytes (EPOS4 Table 5-48,
/// seed 001 L2779-L2797, writes a UNSIGNED16 with 0x22, size not indicated), else all 4 bytes.
pub(crate) fn expedited_data<'a>(entry: &Entry, data: &'a [u8; 4], len: Option<u8>) -> &'a [u8] {
    let len = match len {
        Some(len) => usize::from(len),
        None => entry.data_type.fixed_size().filter(|size| *size <= 4).unwrap_or(4),
    };
    data.get(..len).unwrap_or(data)
}

/// A segmented download in progress (CiA 301 §7.2.4.3.5 download segment; ETG.1000.6 §5.6.2.3), on the
/// dictionary's staged [`Download`]: RAM values are stored only with the last segment, application entries
/// receive each segment.
#[derive(Clone, Debug)]
pub(crate) struct SegmentedDownload {
    pub(crate) download: Download,
    /// The toggle bit the next segment must carry (0 for the first, CiA 301 §7.2.4.3.5).
    pub(crate) toggle: bool,
}

impl SegmentedDownload {
    pub(crate) fn new(download: Download) -> Self {
        Self { download, toggle: false }
    }

    /// Feeds one segment after the toggle check (0x0503_0000 when the toggle did not alternate). On any error
    /// the download is over and nothing is stored.
    pub(crate) fn segment<const N: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        dict: &mut Dictionary<N>,
        toggle: bool,
        data: &[u8],
        last: bool,
        ctx: AccessContext,
        app: &mut A,
    ) -> Result<(), SdoAbort> {
        if toggle != self.toggle {
            dict.abort_download(&mut self.download, app);
            return Err(SdoAbort::ToggleBit);
        }
        dict.download_segment(&mut self.download, data, last, ctx, app)?;
        self.toggle = !self.toggle;
        Ok(())
    }

    /// Ends the download without storing anything (abort by either side, timeout, new request).
    pub(crate) fn cancel<const N: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        dict: &mut Dictionary<N>,
        app: &mut A,
    ) {
        dict.abort_download(&mut self.download, app);
    }
}

/// An upload streamed from the dictionary (CiA 301 §7.2.4.3.7 upload segment; ETG.1000.6 §5.6.2.6): each
/// segment is read at the next offset, so nothing but the position is buffered.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SegmentedUpload {
    pub(crate) entry: &'static Entry,
    pub(crate) offset: usize,
    pub(crate) total: usize,
    pub(crate) toggle: bool,
}

impl SegmentedUpload {
    pub(crate) fn new(entry: &'static Entry, offset: usize, total: usize) -> Self {
        Self { entry, offset, total, toggle: false }
    }

    /// Reads the next segment into `buf` (at most `buf.len()` bytes) after the toggle check; returns the bytes
    /// read and whether they were the last. A value that shrank under the transfer aborts with 0x0604_0047.
    pub(crate) fn next<const N: usize, A: ApplicationObjects + ?Sized>(
        &mut self,
        dict: &Dictionary<N>,
        app: &mut A,
        toggle: bool,
        buf: &mut [u8],
    ) -> Result<(usize, bool), SdoAbort> {
        if toggle != self.toggle {
            return Err(SdoAbort::ToggleBit);
        }
        let remaining = self.total.saturating_sub(self.offset);
        let want = remaining.min(buf.len());
        let part = buf.get_mut(..want).ok_or(SdoAbort::InternalIncompatibility)?;
        let outcome = dict.read_entry(self.entry, self.offset, part, app)?;
        if outcome.len < want {
            return Err(SdoAbort::InternalIncompatibility);
        }
        self.offset = self.offset.saturating_add(want);
        self.toggle = !self.toggle;
        Ok((want, self.offset >= self.total))
    }
}

/// The size of `entry`'s value (for a VISIBLE_STRING up to its first NUL), with the first bytes read into
/// `first` (as many as fit).
pub(crate) fn read_start<const N: usize, A: ApplicationObjects + ?Sized>(
    dict: &Dictionary<N>,
    entry: &'static Entry,
    first: &mut [u8],
    app: &mut A,
) -> Result<(usize, usize), SdoAbort> {
    let outcome = dict.read_entry(entry, 0, first, app)?;
    Ok((outcome.len, outcome.total_len))
}

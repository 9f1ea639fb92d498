//! The SDO server shared by CANopen (CiA 301 §7.2.4) and EtherCAT CoE (ETG.1000.6 §5.6.2).
//!
//! - [`wire`]: the 8-byte CAN SDO frame (CiA 301 §7.2.4.3) as a zero-copy view and parsed requests/responses.
//! - [`server`]: [`server::SdoServer`], the CAN frame path: expedited, segmented and block transfers with the
//!   CRC, toggle and sequence checks and the server timeout.
//! - [`coe`]: [`coe::CoeSdoServer`], the SDO part of CoE: expedited, normal and segmented transfers with the
//!   mailbox's larger segments, and complete access.
//! - [`crc`]: the CRC-16 of block transfers (CiA 301 §7.2.4.3.16).
//!
//! Both servers sit on the same dictionary calls ([`crate::od::access::Dictionary::read_entry`],
//! [`write_entry`](crate::od::access::Dictionary::write_entry),
//! [`begin_download`](crate::od::access::Dictionary::begin_download),
//! [`download_segment`](crate::od::access::Dictionary::download_segment),
//! [`abort_download`](crate::od::access::Dictionary::abort_download)) and share the transfer helpers of
//! `transfer`, so a value is checked, staged and stored the same way whichever bus wrote it. Every failure is
//! answered with the [`SdoAbort`](crate::od::abort::SdoAbort) the dictionary or the protocol check returned.
//!
//! ## Rule for a new initiate during a transfer
//! SDO is a confirmed peer-to-peer service with one transfer at a time per channel (CiA 301 §7.2.4.1), and the
//! client may end a transfer at any time (CiA 301 §7.2.4.3.17). A client that sends a new initiate request has
//! therefore given the old transfer up (typically after its own timeout without sending an abort). Both servers
//! end the old transfer *without* a frame of its own (nothing is stored; an application entry is told to discard
//! what it received, [`ApplicationObjects::abort`](crate::od::access::ApplicationObjects::abort)) and serve the
//! new request: an abort frame for the old transfer would be taken by the client as the answer to its new
//! request, since CAN SDO frames carry no transaction number. CANopenNode and Lely instead answer any
//! unexpected command with 0x0504_0001 and return to idle (the client then has to repeat its request); other
//! unexpected commands (segments, block sub-commands) get 0x0504_0001 here too. The one place an initiate cannot
//! be recognised is a block download sub-block, where every frame is a segment (CiA 301 §7.2.4.3.12): there only
//! the abort frame (0x80, which as a segment would carry the invalid sequence number 0) ends the transfer.

pub mod coe;
pub mod crc;
pub mod server;
mod transfer;
pub mod wire;

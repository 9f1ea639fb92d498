//! Fault handling: the fault table, the latch and reset rules, the trip snapshots, the error history and the
//! emergency producer (`shared/spec/comms-faults-bootloader.md` §3; `shared/spec/control-and-protection.md` §3).
//!
//! Module map:
//! - [`table`]: [`FaultId`] and [`FAULT_TABLE`]: per fault the CiA 301/402 error code (IDX Table 7-153 where IDX
//!   defines one), the error-register bits (0x1001), the reaction class (IDX d/f/a, or a warning), the latch
//!   policy, level or event cause, the detecting tier and the snapshot value its EMCY carries.
//! - [`snapshot`]: [`DiagnosisSnapshot`], the measured values at the moment of the trip.
//! - [`manager`]: [`FaultManager`], the active set, fault reset, 0x603F/0x1001 and the CiA 402 fault inputs.
//! - [`history`]: the pre-defined error field 0x1003 in the dictionary (newest first; writing 0 clears).
//! - [`emcy`]: the 8-byte CiA 301 emergency message, the inhibit time 0x1015 and the overflow-safe queue.
//!
//! Detection lives in the tiers (tier-1 protection, tier-2 supervision, the fieldbus layers); they call
//! [`FaultManager::raise`] with a snapshot taken where they detect.

pub mod emcy;
pub mod history;
pub mod i2t;
pub mod manager;
pub mod snapshot;
pub mod table;

pub use emcy::{EmcyMessage, EmcyProducer, InhibitTime};
pub use manager::{ActiveFault, FaultManager, Raised, ResetRefused, Trip};
pub use snapshot::DiagnosisSnapshot;
pub use table::{Cause, FaultId, FaultInfo, LatchPolicy, ReactionClass, SnapshotField, Tier, FAULT_COUNT, FAULT_TABLE};

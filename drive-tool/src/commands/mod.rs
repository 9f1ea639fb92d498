//! The commands, one file per group.

pub mod faults;
pub mod identify;
pub mod list;
pub mod lss;
pub mod motion;
pub mod nmt;
pub mod object;
pub mod params;
pub mod record;
pub mod scan;
pub mod update;
#[cfg(target_os = "linux")]
pub mod update_foe;

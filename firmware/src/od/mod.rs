//! The object dictionary: the generated tables, typed access, SDO abort codes and persistence.

pub mod abort;
pub mod access;
pub mod entry;
pub mod pdo_map;
pub mod store;
pub mod values;

/// Everything od-gen generated from `firmware/device.toml` (tables, default values, typed handles).
#[allow(missing_docs, clippy::all)]
pub mod generated {
    use super::entry::*;
    include!(concat!(env!("OUT_DIR"), "/od_generated.rs"));
}

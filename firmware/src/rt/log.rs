//! The logging shim: defmt when the `defmt` feature is on (RTT transport), nothing otherwise. Tiers 2 and 3 and
//! start-up may log; tier 1 never does (a defmt write takes a critical section and unbounded time).

/// Logs at info level (defmt `info!`), or compiles to nothing without the `defmt` feature.
#[macro_export]
#[doc(hidden)]
macro_rules! rt_info {
    ($($arg:tt)*) => {{
        #[cfg(feature = "defmt")]
        ::defmt::info!($($arg)*);
    }};
}

/// Logs at error level (defmt `error!`), or compiles to nothing without the `defmt` feature.
#[macro_export]
#[doc(hidden)]
macro_rules! rt_error {
    ($($arg:tt)*) => {{
        #[cfg(feature = "defmt")]
        ::defmt::error!($($arg)*);
    }};
}

/// The defmt transport: RTT, read by a debug probe (`probe-rs`); harmless when none is attached.
#[cfg(feature = "defmt")]
use defmt_rtt as _;

//! Logging shim in the style of embassy-net's `fmt.rs`: the same macro names log through
//! `defmt` with the `defmt` feature, through `log` with the `log` feature, and compile to
//! nothing (arguments still type-checked) with neither.
//!
//! The backend is chosen once, here, in [`__log!`], which is exported (hidden) so that
//! arm-wiring logs through this shim rather than a copy of it. Its expansion names
//! `::defmt` or `::log`, so a crate that uses it depends on the same backend (arm-wiring's
//! `defmt` and `log` features enable arm-core's).
#![macro_use]
#![allow(unused)]

#[cfg(all(feature = "defmt", feature = "log"))]
compile_error!("You may not enable both `defmt` and `log` features.");

/// One log line at `$level` (`trace`, `debug`, `info`, `warn` or `error`) through defmt.
#[cfg(feature = "defmt")]
#[doc(hidden)]
#[macro_export]
macro_rules! __log {
    ($level:ident, $s:literal $(, $x:expr)* $(,)?) => {
        ::defmt::$level!($s $(, $x)*)
    };
}

/// One log line at `$level` (`trace`, `debug`, `info`, `warn` or `error`) through `log`.
#[cfg(feature = "log")]
#[doc(hidden)]
#[macro_export]
macro_rules! __log {
    ($level:ident, $s:literal $(, $x:expr)* $(,)?) => {
        ::log::$level!($s $(, $x)*)
    };
}

/// No backend: the arguments are still type-checked, nothing is logged.
#[cfg(not(any(feature = "defmt", feature = "log")))]
#[doc(hidden)]
#[macro_export]
macro_rules! __log {
    ($level:ident, $s:literal $(, $x:expr)* $(,)?) => {{
        let _ = ($( & $x ),*);
    }};
}

macro_rules! trace {
    ($($arg:tt)*) => { $crate::__log!(trace, $($arg)*) };
}

macro_rules! debug {
    ($($arg:tt)*) => { $crate::__log!(debug, $($arg)*) };
}

macro_rules! info {
    ($($arg:tt)*) => { $crate::__log!(info, $($arg)*) };
}

macro_rules! warn {
    ($($arg:tt)*) => { $crate::__log!(warn, $($arg)*) };
}

macro_rules! error {
    ($($arg:tt)*) => { $crate::__log!(error, $($arg)*) };
}

/// A hardware trait's error value ([`crate::hw::LogError`]) for the logging backend. With
/// defmt it is printed by its own `defmt::Format` (not `Debug2Format`: that links
/// `core::fmt`, about 3 KB of the board's flash); with `log`, by its `Debug`.
macro_rules! debug_value {
    ($e:expr) => {
        $e
    };
}

//! Logging through arm-core's shim (`arm_core::__log!`, which picks defmt or `log` by
//! arm-core's features, enabled by this crate's features of the same names), under the
//! usual macro names: only the levels this crate uses.
#![macro_use]

macro_rules! info {
    ($($arg:tt)*) => { ::arm_core::__log!(info, $($arg)*) };
}

macro_rules! warn {
    ($($arg:tt)*) => { ::arm_core::__log!(warn, $($arg)*) };
}

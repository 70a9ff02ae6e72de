//! The controller's tests use arm-core's test-support layer (the `test-support` feature).
#![allow(unused_imports)]

pub use arm_core::test_support::*;

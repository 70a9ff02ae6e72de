//! `sim-host bench`.

/// Options of the benchmark.
#[derive(Clone, Debug, clap::Args)]
pub struct BenchOptions {}

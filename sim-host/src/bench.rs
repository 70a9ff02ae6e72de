//! `sim-host bench`.

/// Options of the benchmark.
#[derive(Clone, Debug, clap::Args)]
pub struct BenchOptions {}

/// Runs the benchmark.
pub fn run(_sim: &crate::options::SimOptions, _bench: &BenchOptions) -> std::io::Result<()> {
    Err(std::io::Error::other("bench: not written yet"))
}

//! `sim-host demo`.

/// Options of the demo.
#[derive(Clone, Debug, clap::Args)]
pub struct DemoOptions {}

/// Runs the demo.
pub fn run(_sim: &crate::options::SimOptions, _demo: &DemoOptions) -> std::io::Result<()> {
    Err(std::io::Error::other("demo: not written yet"))
}

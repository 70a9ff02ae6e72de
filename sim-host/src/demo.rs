//! `sim-host demo`.

/// Options of the demo.
#[derive(Clone, Debug, clap::Args)]
pub struct DemoOptions {}

//! `sim-host`: the arm controller on a PC. See the library's documentation.

use clap::Parser;
use sim_host::options::{Cli, Command};

fn main() {
    let cli = Cli::parse();
    sim_host::app::init_logging(&cli.sim.log_level);
    let result = match cli.command {
        None => sim_host::app::run(&cli.sim),
        Some(Command::Demo(demo)) => sim_host::demo::run(&cli.sim, &demo),
        Some(Command::Bench(bench)) => sim_host::bench::run(&cli.sim, &bench),
    };
    if let Err(e) = result {
        eprintln!("sim-host: {e}");
        std::process::exit(1);
    }
}

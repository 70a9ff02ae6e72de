//! `sim-host`: the arm controller on a PC. See the library's documentation.

use clap::parser::ValueSource;
use clap::{CommandFactory, FromArgMatches};
use sim_host::options::{Cli, Command};

fn main() {
    let matches = Cli::command().get_matches();
    let cli = match Cli::from_arg_matches(&matches) {
        Ok(cli) => cli,
        Err(e) => e.exit(),
    };
    // The demo and the benchmark print their own results: the controller inside them
    // logs only warnings unless a level is asked for.
    let level = match (&cli.command, matches.value_source("log_level")) {
        (Some(_), Some(ValueSource::DefaultValue)) => "warn",
        _ => cli.sim.log_level.as_str(),
    };
    sim_host::app::init_logging(level);
    let result = match &cli.command {
        None => sim_host::app::run(&cli.sim),
        Some(Command::Demo(demo)) => sim_host::demo::run(&cli.sim, demo),
        Some(Command::Bench(bench)) => sim_host::bench::run(&cli.sim, bench),
        Some(Command::Flood(flood)) => sim_host::flood::run(flood),
    };
    if let Err(e) = result {
        eprintln!("sim-host: {e}");
        std::process::exit(1);
    }
}

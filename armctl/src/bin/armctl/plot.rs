//! `armctl plot`: a recording (CSV) or a simulator trace (VCD) drawn as SVG, no controller
//! needed.

use std::path::PathBuf;

use armctl::plot::{self, Commanded};
use armctl::{record, trajectory, vcd};
use clap::Args;
use protocol::State;

use crate::CliResult;

/// `plot` options.
#[derive(Args, Debug)]
pub struct PlotArgs {
    /// Recording CSV written by `watch --record` or `run --record`, or a VCD trace written
    /// by `sim-host --trace` (recognised by its `.vcd` name or `$` header).
    pub recording: PathBuf,
    /// The commanded trajectory file to draw dashed.
    #[arg(long, value_name = "FILE")]
    pub trajectory: Option<PathBuf>,
    /// Joint config, for a JointTrajectory .json.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Seconds into the recording at which the trajectory starts (default: the first
    /// report in state RUNNING; for a trace, the first STEP pulse less the time the
    /// trajectory takes to its first step).
    #[arg(long)]
    pub offset: Option<f64>,
    /// Output file.
    #[arg(short, long, default_value = "run.svg")]
    pub output: PathBuf,
    /// Title.
    #[arg(long)]
    pub title: Option<String>,
}

/// Runs `plot`: draws the file and prints what it wrote.
pub fn execute(args: &PlotArgs) -> CliResult {
    println!("{}", plot(args)?);
    Ok(())
}

/// Whether `path` is a VCD trace: a `.vcd` name, or a first word that is a `$` keyword.
fn is_vcd(path: &std::path::Path) -> bool {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("vcd"))
    {
        return true;
    }
    let mut start = [0u8; 256];
    std::fs::File::open(path)
        .and_then(|mut f| std::io::Read::read(&mut f, &mut start))
        .is_ok_and(|n| vcd::looks_like_vcd(&start[..n]))
}

/// `plot`: draws a recording or a trace to `args.output`; returns what to print.
pub fn plot(args: &PlotArgs) -> Result<String, String> {
    // The plot is SVG: a name promising another format would hold SVG bytes (issue 23:
    // `-o x.png` did). No extension at all is taken as meant for SVG.
    let extension = args.output.extension().and_then(|e| e.to_str());
    if extension.is_some_and(|e| !e.eq_ignore_ascii_case("svg")) {
        return Err(format!(
            "{}: plot writes SVG; name the output .svg (convert it afterwards, e.g. with \
             rsvg-convert, for a bitmap)",
            args.output.display()
        ));
    }
    let commanded = match &args.trajectory {
        Some(path) => {
            let (waypoints, _) =
                trajectory::load_files(path, args.config.as_deref()).map_err(|e| e.to_string())?;
            Some(Commanded::from_waypoints(&waypoints))
        }
        None => None,
    };
    let title = args
        .title
        .clone()
        .unwrap_or_else(|| args.recording.display().to_string());
    let (svg, summary) = if is_vcd(&args.recording) {
        let trace = vcd::read(&args.recording).map_err(|e| e.to_string())?;
        let commanded = commanded.map(|mut c| {
            // The trace has no "run started" mark: its first STEP pulse is the
            // trajectory's first step.
            c.offset_s =
                args.offset
                    .unwrap_or_else(|| match (trace.first_step_s(), c.first_step_s()) {
                        (Some(traced), Some(commanded)) => traced - commanded,
                        (traced, _) => traced.unwrap_or(0.0),
                    });
            c
        });
        let moved: Vec<String> = trace
            .joints
            .iter()
            .enumerate()
            .filter(|(_, j)| j.steps > 0)
            .map(|(i, j)| format!("joint {i}: {} steps, ends at {}", j.steps, j.position))
            .collect();
        let summary = format!(
            "trace of {:.6} s; {}",
            trace.end_tick as f64 * trace.seconds_per_tick,
            if moved.is_empty() {
                "no STEP pulses".to_string()
            } else {
                moved.join("; ")
            }
        );
        (plot::trace_svg(&trace, commanded.as_ref(), &title), summary)
    } else {
        let samples = record::read(&args.recording).map_err(|e| e.to_string())?;
        let commanded = commanded.map(|mut c| {
            // A run's points start when the controller starts RUNNING.
            c.offset_s = args.offset.unwrap_or_else(|| {
                samples
                    .iter()
                    .find(|s| s.state == State::Running as u8)
                    .map_or(0.0, |s| s.time_s)
            });
            c
        });
        let summary = format!("{} samples", samples.len());
        (plot::svg(&samples, commanded.as_ref(), &title), summary)
    };
    std::fs::write(&args.output, svg).map_err(|e| format!("{}: {e}", args.output.display()))?;
    Ok(format!("wrote {} ({summary})", args.output.display()))
}

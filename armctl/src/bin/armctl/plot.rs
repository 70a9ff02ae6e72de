//! `armctl plot`: a recording (CSV) or a simulator trace (VCD) drawn as SVG, or a
//! trajectory file's preview (the points `run` would send); no controller needed.

use std::path::PathBuf;

use armctl::plot::{self, Commanded};
use armctl::record::Sample;
use armctl::trajectory::ArmConfig;
use armctl::{record, trajectory, vcd};
use clap::Args;
use protocol::State;

use crate::CliResult;

/// `plot` options.
#[derive(Args, Debug)]
pub struct PlotArgs {
    /// Recording CSV written by `watch --record` or `run --record`, a VCD trace written by
    /// `sim-host --trace` (recognised by its `.vcd` name or `$` header), or a trajectory
    /// file (JointTrajectory .json, or a CSV whose header is not `time_s,state,...`): a
    /// preview of the points `run` would send, from 0 or the file's first waypoint.
    pub recording: PathBuf,
    /// The commanded trajectory file to draw dashed.
    #[arg(long, value_name = "FILE")]
    pub trajectory: Option<PathBuf>,
    /// Joint config: for a JointTrajectory .json or a CSV in degrees, and the joints'
    /// names in the legend.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Units of a trajectory CSV (as `run --units`).
    #[arg(long)]
    pub units: Option<armctl::motion::Units>,
    /// Segment duration of a trajectory preview, milliseconds (as `run --segment-ms`).
    #[arg(long, default_value_t = 10.0)]
    pub segment_ms: f64,
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

/// Whether `path` is a trajectory file rather than a recording: a `.json`, or a CSV whose
/// first line that is not a comment is not a recording's `time_s,state` header.
fn is_trajectory(path: &std::path::Path) -> bool {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    {
        return true;
    }
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("vcd"))
    {
        return false;
    }
    let Ok(text) = std::fs::read_to_string(path) else {
        return false;
    };
    let Some(first) = text
        .lines()
        .map(str::trim)
        .find(|l| !l.is_empty() && !l.starts_with('#'))
    else {
        return false;
    };
    let fields: Vec<&str> = first.split(',').map(str::trim).collect();
    let recording = fields.len() >= 2 && fields[0] == "time_s" && fields[1] == "state";
    !(recording || first.starts_with('$'))
}

/// A trajectory file's preview: the points `run` would send (from the file's first
/// waypoint when it is at t = 0, else from 0), drawn over the waypoints (dashed).
fn preview(
    args: &PlotArgs,
    output: &Output<'_>,
    config: Option<&ArmConfig>,
    title: &str,
    names: &[String],
) -> Result<String, String> {
    let waypoints =
        trajectory::load_in(&args.recording, config, args.units).map_err(|e| e.to_string())?;
    let joints = waypoints.positions.first().map_or(0, Vec::len);
    let mut start = [0i32; protocol::MAX_JOINTS];
    if waypoints.times_us.first() == Some(&0) {
        for (j, p) in waypoints.positions[0].iter().enumerate().take(joints) {
            start[j] = p.map_or(0, |p| p.round() as i32);
        }
    }
    let config = config
        .cloned()
        .unwrap_or_else(|| ArmConfig::unlimited(joints, u32::MAX));
    let segment_us = trajectory::segment_us(args.segment_ms, "--segment-ms")?;
    let units = args.units.unwrap_or(config.units);
    let points = trajectory::to_points(&waypoints, &start, segment_us, &config, None)
        .map_err(|e| e.in_units(&config, units).to_string())?;
    let mut t = 0.0;
    let mut samples = vec![Sample {
        time_s: 0.0,
        state: State::Running as u8,
        position: start[..joints].to_vec(),
    }];
    for p in &points {
        t += f64::from(p.duration) / 1e6;
        samples.push(Sample {
            time_s: t,
            state: State::Running as u8,
            position: p.position[..joints].to_vec(),
        });
    }
    let commanded = Commanded::from_waypoints(&waypoints);
    let summary = format!(
        "preview of {}: {} points, {t:.3} s, every one of its {} waypoints a point's end",
        args.recording.display(),
        points.len(),
        waypoints.times_us.len()
    );
    output.samples(&samples, Some(&commanded), title, names)?;
    Ok(summary)
}

/// Where the plot goes, and as what.
struct Output<'a> {
    path: &'a std::path::Path,
    /// A PNG (the name ends in .png), else SVG.
    png: bool,
}

impl Output<'_> {
    /// Writes a recording's plot.
    fn samples(
        &self,
        samples: &[Sample],
        commanded: Option<&Commanded>,
        title: &str,
        names: &[String],
    ) -> Result<(), String> {
        if self.png {
            plot::png_named(self.path, samples, commanded, title, names)
        } else {
            self.write_svg(plot::svg_named(samples, commanded, title, names))
        }
    }

    /// Writes a trace's plot.
    fn trace(
        &self,
        trace: &vcd::Trace,
        commanded: Option<&Commanded>,
        title: &str,
        names: &[String],
    ) -> Result<(), String> {
        if self.png {
            plot::trace_png_named(self.path, trace, commanded, title, names)
        } else {
            self.write_svg(plot::trace_svg_named(trace, commanded, title, names))
        }
    }

    fn write_svg(&self, svg: String) -> Result<(), String> {
        std::fs::write(self.path, svg).map_err(|e| format!("{}: {e}", self.path.display()))
    }
}

/// `plot`: draws a recording or a trace to `args.output`; returns what to print.
pub fn plot(args: &PlotArgs) -> Result<String, String> {
    // The format follows the name (issue 23: `-o x.png` wrote SVG bytes): .png is a PNG,
    // .svg or no extension SVG; anything else is refused before anything is written.
    let extension = args.output.extension().and_then(|e| e.to_str());
    let png = extension.is_some_and(|e| e.eq_ignore_ascii_case("png"));
    if extension.is_some_and(|e| !e.eq_ignore_ascii_case("svg")) && !png {
        return Err(format!(
            "{}: plot writes SVG or PNG; name the output .svg or .png",
            args.output.display()
        ));
    }
    let output = Output {
        path: &args.output,
        png,
    };
    let config = args
        .config
        .as_deref()
        .map(ArmConfig::load)
        .transpose()
        .map_err(|e| e.to_string())?;
    let names = config.as_ref().map_or(Vec::new(), ArmConfig::short_names);
    let commanded = match &args.trajectory {
        Some(path) => {
            let waypoints = trajectory::load_in(path, config.as_ref(), args.units)
                .map_err(|e| e.to_string())?;
            Some(Commanded::from_waypoints(&waypoints))
        }
        None => None,
    };
    let title = args
        .title
        .clone()
        .unwrap_or_else(|| args.recording.display().to_string());
    let summary = if is_trajectory(&args.recording) {
        preview(args, &output, config.as_ref(), &title, &names)?
    } else if is_vcd(&args.recording) {
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
        output.trace(&trace, commanded.as_ref(), &title, &names)?;
        summary
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
        output.samples(&samples, commanded.as_ref(), &title, &names)?;
        summary
    };
    Ok(format!("wrote {} ({summary})", args.output.display()))
}

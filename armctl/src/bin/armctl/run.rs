//! `armctl run`: a trajectory file converted, uploaded and run (or only checked, with
//! `--dry-run`).

use std::path::PathBuf;
use std::sync::mpsc;
use std::time::Duration;

use armctl::record::Recorder;
use armctl::trajectory::{self, ArmConfig};
use armctl::{Client, RunOptions};
use clap::Args;
use protocol::{MAX_JOINTS, Point};

use crate::CliResult;

/// `run` options.
#[derive(Args, Debug)]
pub struct RunArgs {
    /// Trajectory file: `.json` (JointTrajectory, radians; needs --config) or CSV
    /// (`time_s, positions...` in --units; with --config, joints left out hold).
    pub file: PathBuf,
    /// Joint config (JSON: steps_per_radian, zero_offset_steps, min/max_steps,
    /// max_step_rate_hz per joint).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Units of a CSV's positions: steps, deg or rad (default: the config's `units`, else
    /// steps); degrees and radians need --config.
    #[arg(long)]
    pub units: Option<armctl::motion::Units>,
    /// Longest segment duration in milliseconds (every waypoint also ends a segment).
    #[arg(long, default_value_t = 10.0)]
    pub segment_ms: f64,
    /// Frames in flight (1 = stop-and-wait, at most 32; default: the window the
    /// controller advertises in STATUS, 8 for one that advertises none).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=32))]
    pub window: Option<u16>,
    /// Send RUNING once this many points are acknowledged (default: when the buffer is full
    /// or everything is uploaded).
    #[arg(long)]
    pub start_after: Option<usize>,
    /// Write every LOCATION report during the run to this CSV file.
    #[arg(long, value_name = "FILE")]
    pub record: Option<PathBuf>,
    /// Only convert and check the file; print the points count and send nothing. Without
    /// a controller the step rate is checked against the config, and at most against
    /// `--max-step-rate`.
    #[arg(long)]
    pub dry_run: bool,
    /// For `--dry-run`: the controller's step rate limit per joint (steps/s) to check
    /// against; the board's by default.
    #[arg(long, value_name = "HZ", default_value_t = DEFAULT_MAX_STEP_RATE_HZ)]
    pub max_step_rate: u32,
    /// Do not show a progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Run at this speed, percent of the file's (1..200; OVERRIDE, issue 32): 50 takes
    /// twice as long, every point still executed exactly. Above 100 % only as far as every
    /// joint's rate and acceleration allow: the controller lowers it where a point needs
    /// (the run says so). The factor stays for later runs until changed (`armctl
    /// override`).
    #[arg(long, value_name = "PERCENT", value_parser = clap::value_parser!(u8).range(1..=200))]
    pub speed: Option<u8>,
}

/// The step rate limit `run --dry-run` checks against without a controller: the board's
/// `max_step_rate_hz` (PROTOCOL.md, "Figures of this firmware"; sim-host reports the same).
pub const DEFAULT_MAX_STEP_RATE_HZ: u32 = 100_000;

/// Runs `run --dry-run`: converts and checks the file, sends nothing.
pub fn dry_run(args: &RunArgs) -> CliResult {
    let converted = convert(args, &[0; 8], None, Some(args.max_step_rate), None)?;
    print_points_summary(&converted.points, converted.waypoints);
    println!(
        "step rates checked against {} (at most {} steps/s per joint, --max-step-rate)",
        if args.config.is_some() {
            "the joint config"
        } else {
            "the controller's limit"
        },
        args.max_step_rate
    );
    Ok(())
}

/// A trajectory file converted to points.
pub(crate) struct Converted {
    pub(crate) points: Vec<Point>,
    /// How messages name each joint: `joint 2 (elbow)`, or `joint 2` without a name.
    joint_names: Vec<String>,
    /// The file's waypoints, each the end of one of `points` at its time
    /// ([`trajectory::check_waypoints`]).
    pub(crate) waypoints: usize,
    /// The joint config's names for a recording's header (empty without a config).
    config_names: Vec<String>,
    /// The joint config (without one: unnamed joints in steps) and the file's units, for
    /// a refusal's message.
    config: ArmConfig,
    units: armctl::motion::Units,
}

/// The trajectory file as points, from `current`. `described`: the arm the controller
/// describes (issue 31), taken when no `--config` is given.
pub(crate) fn convert(
    args: &RunArgs,
    current: &[i32; 8],
    controller_joints: Option<usize>,
    controller_max_rate: Option<u32>,
    described: Option<ArmConfig>,
) -> Result<Converted, String> {
    let named = args.config.is_some() || described.is_some();
    let (waypoints, config) = match described.filter(|_| args.config.is_none()) {
        Some(described) => {
            let waypoints = trajectory::load_in(&args.file, Some(&described), args.units)
                .map_err(|e| e.to_string())?;
            (waypoints, Some(described))
        }
        None => trajectory::load_files_in(&args.file, args.config.as_deref(), args.units)
            .map_err(|e| e.to_string())?,
    };
    let joints = waypoints.positions.first().map_or(0, Vec::len);
    if let Some(n) = controller_joints
        && joints > n
    {
        return Err(format!(
            "{}: {joints} joints in the file, the controller drives {n} (`armctl joints N`)",
            args.file.display()
        ));
    }
    let config = config
        .unwrap_or_else(|| ArmConfig::unlimited(joints, controller_max_rate.unwrap_or(u32::MAX)));
    let units = args.units.unwrap_or(config.units);
    let segment_us = trajectory::segment_us(args.segment_ms, "--segment-ms")?;
    let points = trajectory::to_points(
        &waypoints,
        current,
        segment_us,
        &config,
        controller_max_rate,
    )
    .map_err(|e| e.in_units(&config, units).to_string())?;
    let waypoints = trajectory::check_waypoints(&points, &waypoints, current)
        .map_err(|e| e.in_units(&config, units).to_string())?;
    let config_names = if named {
        config.short_names()
    } else {
        Vec::new()
    };
    let joint_names = (0..MAX_JOINTS)
        .map(
            |j| match config.joints.get(j).and_then(|c| c.name.as_ref()) {
                Some(name) => format!("joint {j} ({name})"),
                None => format!("joint {j}"),
            },
        )
        .collect();
    Ok(Converted {
        points,
        joint_names,
        waypoints,
        config_names,
        config,
        units,
    })
}

fn print_points_summary(points: &[Point], waypoints: usize) {
    println!("{}", points_summary(points, waypoints));
}

/// What `check` says of converted points: count, duration, end, waypoints.
pub(crate) fn points_summary(points: &[Point], waypoints: usize) -> String {
    let us: i64 = points.iter().map(|p| i64::from(p.duration)).sum();
    format!(
        "{} points, {:.3} s, ends at {:?}; each of the {waypoints} waypoints is a point's end at its time",
        points.len(),
        us as f64 / 1e6,
        points.last().map(|p| p.position).unwrap_or_default()
    )
}

/// Without `--config`, the arm the controller describes (issue 31: names, units, scale,
/// limits); `None` with a config, or from a controller that describes none.
pub fn described_without_config(
    arm: &Client,
    no_config: bool,
    joints: usize,
    max_rate_hz: u32,
) -> Result<Option<ArmConfig>, String> {
    if !no_config {
        return Ok(None);
    }
    // The error as is: it already names the subcommand run (a NOT_OWNER says "move
    // refused with NOT_OWNER", as the first command that needs the owner would).
    arm.described_arm(joints, max_rate_hz)
        .map_err(|e| e.to_string())
}

/// Runs `run`: converts the file from the current position, uploads and runs it, and
/// checks the final positions. SIGINT, SIGTERM or SIGHUP from the upload on: STOPPED
/// (crate::interrupt).
pub fn execute(arm: &Client, args: &RunArgs) -> CliResult {
    let status = arm.status().map_err(|e| e.to_string())?;
    crate::motion::ready_to_move(&status)?;
    let joints = usize::from(status.joints).clamp(1, 8);
    let current = arm
        .current_location(Duration::from_secs(2))
        .map_err(|e| e.to_string())?;
    let Converted {
        points,
        joint_names,
        waypoints,
        config_names,
        config,
        units,
    } = convert(
        args,
        &current.position,
        Some(joints),
        Some(status.max_step_rate_hz),
        described_without_config(arm, args.config.is_none(), joints, status.max_step_rate_hz)?,
    )?;
    print_points_summary(&points, waypoints);

    // Record from a thread that owns its own report stream.
    let recording = match &args.record {
        Some(path) => {
            let mut recorder = Recorder::create_named(path, joints, &config_names)
                .map_err(|e| format!("{}: {e}", path.display()))?;
            let locations = arm.locations();
            let (stop_tx, stop_rx) = mpsc::channel::<()>();
            let handle = std::thread::spawn(move || -> std::io::Result<()> {
                while stop_rx.try_recv().is_err() {
                    if let Ok(location) = locations.recv_timeout(Duration::from_millis(50)) {
                        recorder.record(&location)?;
                    }
                }
                // What arrived before the stop.
                while let Ok(location) = locations.try_recv() {
                    recorder.record(&location)?;
                }
                recorder.flush()
            });
            Some((stop_tx, handle))
        }
        None => None,
    };

    let bar = if args.quiet {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(points.len() as u64)
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} executed  {msg}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let options = RunOptions {
        // 0: the controller's advertised window.
        window: args.window.map_or(0, usize::from),
        start_after: args.start_after,
        speed_percent: args.speed,
        // From here on a signal stops the arm rather than just ending the tool.
        cancel: Some(crate::interrupt::watch()?),
        ..RunOptions::default()
    };
    let result = arm.run_trajectory(&points, &options, |p| {
        bar.set_position(p.executed as u64);
        bar.set_message(format!(
            "{} sent, {} acked, {}",
            p.sent,
            p.acked,
            p.state.name()
        ));
    });
    // Interrupted: STOPPED first, the recording and the display after.
    let interrupted = crate::interrupt::stop_if_signalled(arm);
    if interrupted {
        bar.abandon();
    } else {
        bar.finish();
    }
    if let Some((stop, handle)) = recording {
        // A last report or two after the end.
        std::thread::sleep(Duration::from_millis(50));
        let _ = stop.send(());
        match handle.join() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => eprintln!("warning: recording: {e}"),
            Err(_) => eprintln!("warning: the recording thread failed"),
        }
    }
    if interrupted {
        // main prints what the STOPPED did and exits 130 or 143.
        return Err("interrupted".into());
    }
    let report = result.map_err(|e| {
        let sent = crate::config::Sent {
            from: current.position,
            points: &points,
            config: &config,
            units,
        };
        let message = crate::config::explain_invalid_point(e.to_string(), arm, Some(&sent));
        crate::motion::drop_partial_upload(arm, message)
    })?;
    println!(
        "uploaded {} points in {} frames, window {} ({} datagrams, {} resent, {} out of order, {} buffer full, {} timeouts) in {:.3} s; run took {:.3} s",
        report.points,
        report.frames,
        report.window,
        report.datagrams_sent,
        report.retransmissions,
        report.out_of_order,
        report.buffer_full,
        report.timeouts,
        report.upload_time.as_secs_f64(),
        report.total_time.as_secs_f64()
    );
    let expected = points.last().map(|p| p.position).unwrap_or_default();
    let Some(location) = report.final_location else {
        return Err("no LOCATION report after the run: cannot check the final positions".into());
    };
    let wrong: Vec<String> = (0..joints)
        .filter(|&j| location.position[j] != expected[j])
        .map(|j| {
            format!(
                "{} at {} steps, expected {}",
                joint_names[j], location.position[j], expected[j]
            )
        })
        .collect();
    if let Some(asked) = args.speed.filter(|&p| p != 100) {
        let motion = arm.motion().ok().and_then(|(_, m)| m);
        // Below 100 % only a lowered speed is news (the warp budget lowers it too).
        if asked > 100 || motion.is_some_and(|m| m.factor_percent < asked) {
            println!("{}", speed_line(asked, motion));
        }
    }
    if wrong.is_empty() {
        println!(
            // run_trajectory has checked that the controller executed every point, and it
            // moves each exactly: every waypoint was passed at its time.
            "final positions match the last point: {:?}; all {} points executed, so all {waypoints} waypoints were passed at their times",
            &location.position[..joints],
            points.len()
        );
        Ok(())
    } else {
        Err(format!("final positions differ: {}", wrong.join("; ")))
    }
}

/// What became of `--speed` (issue 32): the controller lowers the override where a point
/// would take a joint past its rate or acceleration limit, or the steps of all joints
/// together past the step side's warp budget (MOTION's factor and refusal).
pub fn speed_line(asked: u8, motion: Option<protocol::MotionReport>) -> String {
    match motion {
        Some(m)
            if m.factor_percent < asked
                && m.refused_limit == Some(protocol::OverrideLimit::StepBudget) =>
        {
            format!(
                "speed {asked} % lowered to {} % by the controller: the steps of all joints \
                 together would pass its warp budget (STEP_BUDGET; every step still made)",
                m.factor_percent
            )
        }
        Some(m) if m.factor_percent < asked => format!(
            "speed {asked} % lowered to {} % by the controller: joint {} would pass its {} \
             limit (every joint within its limits; `armctl override` changes it)",
            m.factor_percent,
            m.refused_joint,
            m.refused_limit.map_or("?", |l| l.name())
        ),
        Some(m) => format!("speed {} %", m.factor_percent),
        None => format!("speed {asked} % asked (the controller did not say what it ran at)"),
    }
}

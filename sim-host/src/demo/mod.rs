//! `sim-host demo`: a 6-joint pick-and-place on the simulated controller, driven over UDP
//! with the `armctl` library exactly as a host drives the board.
//!
//! The controller runs in this process (its own threads and executor) on a free loopback
//! port with a small trajectory buffer, so every run is longer than the buffer and
//! streams. The demo opens the serial pass-through (loopback: what it sends comes back),
//! signals with PIN0, closes and opens the gripper (servo PWM) between runs, ends with an
//! emergency stop in the middle of a move, then checks the final positions three ways
//! (commanded, the controller's LOCATION, the pulses the simulated motors received) and
//! writes an SVG plot of commanded versus executed joint positions.
//!
//! This file holds the arm's poses, the path planner and the progress display;
//! `scenario.rs` the phases of the run.

use std::io;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use armctl::record::Sample;
use armctl::{Client, Progress, RunOptions};
use indicatif::{ProgressBar, ProgressStyle};
use protocol::{Location, MAX_JOINTS, Point, State};

use crate::app::Board;
use crate::options::SimOptions;

mod scenario;

/// Joints of the demo arm.
const JOINTS: usize = 6;

/// Length of one trajectory point, microseconds (10 ms, a usual host rate).
const POINT_US: u32 = 10_000;

/// The demo controller's trajectory buffer: 0.64 s of points, far less than any run, so
/// every run streams while it executes.
const DEMO_BUFFER: usize = 64;

/// Options of the demo.
#[derive(Clone, Debug, clap::Args)]
pub struct DemoOptions {
    /// Where to write the SVG plot (default: sim-host-demo.svg next to the executable,
    /// i.e. in cargo's target directory).
    #[arg(long, value_name = "FILE.svg")]
    pub plot: Option<PathBuf>,
    /// No progress bar, one line per step (for logs).
    #[arg(long)]
    pub quiet: bool,
}

/// A named pose of the arm, joint positions in steps.
type Pose = [i32; JOINTS];

const HOME: Pose = [0, 0, 0, 0, 0, 0];
const ABOVE_PICK: Pose = [4000, -2500, 3000, -800, 0, 1200];
const PICK: Pose = [4000, -3400, 3800, -600, 0, 1200];
const ABOVE_PLACE: Pose = [-3500, -2300, 2600, -700, 1600, -900];
const PLACE: Pose = [-3500, -3200, 3500, -500, 1600, -900];

/// One leg of a run: to `pose` in `seconds`, minimum-jerk profile.
struct Leg {
    pose: Pose,
    seconds: f64,
}

/// Points through the legs from `start`, every [`POINT_US`].
fn plan(start: Pose, legs: &[Leg]) -> Vec<Point> {
    let mut points = Vec::new();
    let mut previous = widen(start);
    let mut from = start;
    for leg in legs {
        let n = (leg.seconds * 1e6 / f64::from(POINT_US)).round().max(1.0) as usize;
        for i in 1..=n {
            let s = i as f64 / n as f64;
            // Minimum jerk: zero velocity and acceleration at both ends of the leg.
            let blend = s * s * s * (10.0 - 15.0 * s + 6.0 * s * s);
            let mut target = [0i32; MAX_JOINTS];
            for j in 0..JOINTS {
                let a = f64::from(from[j]);
                let b = f64::from(leg.pose[j]);
                target[j] = (a + (b - a) * blend).round() as i32;
            }
            points.push(Point::from_motion(POINT_US as i32, &previous, &target));
            previous = target;
        }
        from = leg.pose;
    }
    points
}

fn widen(pose: Pose) -> [i32; MAX_JOINTS] {
    let mut all = [0; MAX_JOINTS];
    all[..JOINTS].copy_from_slice(&pose);
    all
}

/// The outcome of one check in the summary.
struct Check {
    what: String,
    passed: bool,
}

/// What the display thread shows.
#[derive(Default)]
struct Display {
    phase: String,
    progress: Progress,
    gripper: String,
}

/// Runs the demo.
pub fn run(sim: &SimOptions, demo: &DemoOptions) -> io::Result<()> {
    let mut options = sim.clone();
    // A host paces its upload by wall-clock point durations: sped-up time drains the
    // buffer faster than a host expects, so it gets proportionally more room.
    let scaled_buffer = DEMO_BUFFER * sim.time_scale.ceil().max(1.0) as usize;
    options.buffer_capacity = Some(sim.buffer_capacity.unwrap_or(scaled_buffer));
    let (board, addr, settings_dir) = crate::app::start_for_client(&options, "demo")?;
    let result = scenario::drive(&board, addr, demo);
    board.shut_down();
    let _ = std::fs::remove_dir_all(&settings_dir);
    result
}

fn to_io(e: armctl::Error) -> io::Error {
    io::Error::other(e.to_string())
}

/// Uploads and runs `points` with a progress bar showing the upload, execution and live
/// joint positions.
fn run_with_display(
    arm: &Arc<Client>,
    name: &str,
    points: &[Point],
    display: &Arc<Mutex<Display>>,
    interactive: bool,
    board: &Board,
) -> io::Result<armctl::RunReport> {
    if let Ok(mut d) = display.lock() {
        d.phase = name.to_string();
        d.progress = Progress::default();
    }
    let bar = if interactive {
        let bar = ProgressBar::new(points.len() as u64);
        bar.set_style(
            ProgressStyle::with_template(
                "  {prefix:>9} [{bar:30.cyan/blue}] {pos:>4}/{len} executed  {msg}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
        );
        bar.set_prefix(name.to_string());
        bar
    } else {
        println!(
            "  {name}: {} points ({:.1} s)",
            points.len(),
            points.len() as f64 * f64::from(POINT_US) / 1e6
        );
        ProgressBar::hidden()
    };
    // Live positions between progress callbacks.
    let done = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let ticker = {
        let arm = arm.clone();
        let bar = bar.clone();
        let display = display.clone();
        let done = done.clone();
        std::thread::spawn(move || {
            while !done.load(Ordering::Relaxed) {
                let (progress, gripper) = display
                    .lock()
                    .map(|d| (d.progress, d.gripper.clone()))
                    .unwrap_or_default();
                bar.set_position(progress.executed as u64);
                let joints = arm
                    .last_location()
                    .map(|l: Location| format!("{:?}", &l.position[..JOINTS]))
                    .unwrap_or_default();
                bar.set_message(format!(
                    "acked {:>4}  joints {joints}  gripper {gripper}",
                    progress.acked
                ));
                std::thread::sleep(Duration::from_millis(50));
            }
        })
    };
    let options = RunOptions {
        completion_timeout: Some(Duration::from_secs_f64(
            points.len() as f64 * f64::from(POINT_US) / 1e6 / board.clock.time_scale() + 10.0,
        )),
        ..RunOptions::default()
    };
    let result = arm.run_trajectory(points, &options, |p| {
        if let Ok(mut d) = display.lock() {
            d.progress = *p;
        }
    });
    done.store(true, Ordering::Relaxed);
    let _ = ticker.join();
    // The bar's last line: where the run really ended.
    let executed = match &result {
        Ok(report) => report.points,
        Err(_) => arm
            .status()
            .map(|s| usize::from(s.executed))
            .unwrap_or_default(),
    };
    bar.set_position(executed as u64);
    if let Ok(location) = arm.current_location(Duration::from_millis(200)) {
        let gripper = display
            .lock()
            .map(|d| d.gripper.clone())
            .unwrap_or_default();
        bar.set_message(format!(
            "joints {:?}  gripper {gripper}",
            &location.position[..JOINTS]
        ));
    }
    if result.is_ok() {
        bar.finish();
    } else {
        bar.abandon();
    }
    result.map_err(to_io)
}

/// When a run started moving: the first RUNNING report after `after` (seconds).
fn run_start(recording: &Arc<Mutex<Vec<Sample>>>, after: f64) -> f64 {
    recording
        .lock()
        .ok()
        .and_then(|samples| {
            samples
                .iter()
                .find(|s| s.time_s >= after && s.state == State::Running as u8)
                .map(|s| s.time_s)
        })
        .unwrap_or(after)
}

/// Appends a run's commanded positions (in real seconds from the demo's start).
fn add_commanded(
    times: &mut Vec<f64>,
    positions: &mut Vec<Vec<f64>>,
    start: Pose,
    points: &[Point],
    at_s: f64,
    time_scale: f64,
) {
    times.push(at_s);
    positions.push(start.iter().map(|&p| f64::from(p)).collect());
    let mut t = at_s;
    for p in points {
        t += f64::from(p.duration) / 1e6 / time_scale;
        times.push(t);
        positions.push(p.position[..JOINTS].iter().map(|&x| f64::from(x)).collect());
    }
}

fn default_plot_path() -> PathBuf {
    std::env::current_exe()
        .ok()
        .and_then(|exe| exe.parent().map(|dir| dir.join("sim-host-demo.svg")))
        .unwrap_or_else(|| std::env::temp_dir().join("sim-host-demo.svg"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_reaches_every_pose_within_the_step_rate() {
        let points = plan(
            HOME,
            &[
                Leg {
                    pose: PICK,
                    seconds: 1.0,
                },
                Leg {
                    pose: HOME,
                    seconds: 0.5,
                },
            ],
        );
        assert_eq!(points.len(), 150);
        assert_eq!(points[99].position[..JOINTS], PICK);
        assert_eq!(points[149].position[..JOINTS], HOME);
        let mut previous = [0; MAX_JOINTS];
        for p in &points {
            for j in 0..JOINTS {
                let steps = p.steps(&previous, j).unsigned_abs();
                // 100 kHz at most: 1000 steps in 10 ms.
                assert!(steps <= 1000, "{steps}");
            }
            previous = p.position;
        }
    }
}

//! `sim-host bench`: figures of the simulated controller, measured over loopback with the
//! `armctl` client.
//!
//! - Upload throughput (points/s): a trajectory that fits the buffer, uploaded with
//!   go-back-N windows of 32, 16 and 8 frames and stop-and-wait (window 1), side by side,
//!   with the resends, OUT_OF_ORDER refusals and ACK timeouts each needed.
//! - E-stop latency: from the moment the STOPPED datagram is read from the socket to the
//!   moment the step engine is idle (measured inside the simulator), and the host's
//!   STOPPED-to-ACK round trip; p50/p99 over repeated stops of a running trajectory.
//! - E-stop under a flood (issue 18): a STOPPED from a third host while a stranger floods
//!   the controller with valid and garbage datagrams, from its send to the engine idle
//!   (p50/p90/max, lost), beside the same without the flood, and the owner's STATUS round
//!   trips and 10 Hz polls meanwhile (p50/p90/max, lost); then 20 strangers flooding valid
//!   STATUS as fast as loopback carries (issue 30; [`crate::flood`]).
//! - CPU use of the controller's threads (executor, step timer, socket), idle and while a
//!   6-joint trajectory runs, from /proc/self/task/*/stat, and of the whole process.

use std::io;
use std::time::{Duration, Instant};

use armctl::{Client, RunOptions};
use protocol::{MAX_JOINTS, Point};

use crate::options::SimOptions;

/// Options of the benchmark.
#[derive(Clone, Debug, clap::Args)]
pub struct BenchOptions {
    /// Points per upload in the throughput measurement.
    #[arg(long, default_value_t = 6000)]
    pub points: usize,
    /// Uploads per window size (the median is reported).
    #[arg(long, default_value_t = 3)]
    pub repeats: usize,
    /// Emergency stops measured.
    #[arg(long, default_value_t = 40)]
    pub stops: usize,
    /// Seconds of each CPU measurement.
    #[arg(long, default_value_t = 3.0)]
    pub cpu_seconds: f64,
    /// STOPPEDs measured with and without a stranger's flood.
    #[arg(long, default_value_t = 20)]
    pub flood_stops: usize,
    /// The stranger's flood, datagrams per second.
    #[arg(long, default_value_t = 10_000)]
    pub flood_hz: u32,
    /// Strangers (127.0.0.10 and on) flooding valid STATUS as fast as their sockets send
    /// (issue 30), the last flood measured.
    #[arg(long, default_value_t = 20)]
    pub flood_sources: u8,
}

/// Threads that are the controller (not the benchmark's client).
const CONTROLLER_THREADS: [&str; 4] = ["executor", "step-timer", "udp-rx", "vcd-writer"];

fn to_io(e: armctl::Error) -> io::Error {
    io::Error::other(e.to_string())
}

/// Runs the benchmark and prints the figures.
pub fn run(sim: &SimOptions, bench: &BenchOptions) -> io::Result<()> {
    let (board, addr, settings_dir) = crate::app::start_for_client(sim, "benchmark")?;
    let arm = Client::connect(addr).map_err(to_io)?;
    arm.set_joints(6).map_err(to_io)?;
    let status = arm.status().map_err(to_io)?;
    println!(
        "sim-host bench: controller at {addr}, buffer {} points, step timer {} Hz, time scale {}, build {}",
        status.capacity,
        board.clock.tick_hz(),
        board.clock.time_scale(),
        if cfg!(debug_assertions) {
            "debug"
        } else {
            "release"
        }
    );

    // Upload throughput.
    let points = bench.points.clamp(1, usize::from(status.capacity));
    let trajectory: Vec<Point> = (0..points)
        .map(|_| Point::from_motion(1_000, &[0; MAX_JOINTS], &[0; MAX_JOINTS]))
        .collect();
    println!(
        "upload throughput ({points} points of 116 bytes, 12 per frame, loopback; the controller advertises window {}):",
        arm.advertised_window().map_err(to_io)?
    );
    for window in [32usize, 16, 8, 1] {
        let mut rates = Vec::new();
        let mut resent = 0;
        let mut out_of_order = 0;
        let mut timeouts = 0;
        for _ in 0..bench.repeats.max(1) {
            let run = RunOptions {
                window,
                wait: false,
                // Start only once everything is in: the upload alone is timed.
                start_after: Some(points),
                ..RunOptions::default()
            };
            let report = arm
                .run_trajectory(&trajectory, &run, |_| {})
                .map_err(to_io)?;
            arm.stop().map_err(to_io)?;
            rates.push(points as f64 / report.upload_time.as_secs_f64());
            resent += report.retransmissions;
            out_of_order += report.out_of_order;
            timeouts += report.timeouts;
        }
        rates.sort_by(f64::total_cmp);
        let median = rates[rates.len() / 2];
        let label = if window == 1 {
            "stop-and-wait (window 1)".to_string()
        } else {
            format!("windowed (window {window})")
        };
        println!(
            "  {label:<26} {median:>9.0} points/s  ({:.0} frames/s; over {} uploads: {resent} resent, {out_of_order} out of order, {timeouts} ACK timeouts)",
            median / 12.0,
            rates.len()
        );
    }

    // E-stop latency.
    let moving = crate::flood::long_run();
    board.probe.take_estop_latencies();
    let mut round_trips = Vec::new();
    let mut pseudo_random = 0x2545_F491_4F6C_DD1Du64;
    for _ in 0..bench.stops.max(1) {
        arm.set_location(&[0; 6]).map_err(to_io)?;
        let run = RunOptions {
            wait: false,
            ..RunOptions::default()
        };
        arm.run_trajectory(&moving, &run, |_| {}).map_err(to_io)?;
        // Stop at a varying moment, 20..80 ms into the run.
        pseudo_random ^= pseudo_random << 13;
        pseudo_random ^= pseudo_random >> 7;
        pseudo_random ^= pseudo_random << 17;
        std::thread::sleep(Duration::from_millis(20 + pseudo_random % 60));
        let sent = Instant::now();
        arm.stop().map_err(to_io)?;
        round_trips.push(sent.elapsed());
        std::thread::sleep(Duration::from_millis(5));
    }
    let mut inside = board.probe.take_estop_latencies();
    inside.sort();
    round_trips.sort();
    println!(
        "e-stop latency ({} stops of a 6-joint run):",
        round_trips.len()
    );
    println!(
        "  datagram read -> step engine idle   p50 {:>7.1} us   p99 {:>7.1} us   ({} measured)",
        percentile_us(&inside, 0.50),
        percentile_us(&inside, 0.99),
        inside.len()
    );
    println!(
        "  host STOPPED -> ACK (round trip)    p50 {:>7.1} us   p99 {:>7.1} us",
        percentile_us(&round_trips, 0.50),
        percentile_us(&round_trips, 0.99)
    );

    // E-stop under a flood.
    println!(
        "e-stop under a flood ({} single STOPPEDs from a third host, never resent, 20-80 ms into a 6-joint run; send -> step engine idle):",
        bench.flood_stops.max(1)
    );
    use crate::flood::Flood;
    for flood in [
        Flood::NONE,
        Flood::one(bench.flood_hz),
        Flood::one(5 * bench.flood_hz),
        Flood::many(bench.flood_sources),
    ] {
        let f = crate::flood::estop_under_flood(
            addr,
            &board.probe,
            bench.flood_stops.max(1),
            flood,
            crate::app::receive_shed,
        )?;
        println!("  {}", f.line());
    }

    // CPU use.
    let window = Duration::from_secs_f64(bench.cpu_seconds.max(0.5));
    arm.set_location(&[0; 6]).map_err(to_io)?;
    let (idle_controller, idle_process) = cpu_over(window, || {});
    let steps_per_point = 100; // 10 kHz per joint at 10 ms points
    let n = (window.as_secs_f64() * 100.0) as i32 + 50;
    let running_points: Vec<Point> = {
        let mut previous = [0; MAX_JOINTS];
        (1..=n)
            .map(|i| {
                let mut target = [0; MAX_JOINTS];
                for t in target.iter_mut().take(6) {
                    *t = i * steps_per_point;
                }
                let p = Point::from_motion(10_000, &previous, &target);
                previous = target;
                p
            })
            .collect()
    };
    let run = RunOptions {
        wait: false,
        ..RunOptions::default()
    };
    arm.run_trajectory(&running_points, &run, |_| {})
        .map_err(to_io)?;
    let (busy_controller, busy_process) = cpu_over(window, || {});
    arm.stop().map_err(to_io)?;
    println!(
        "CPU use (one core = 100 %, over {:.1} s):",
        window.as_secs_f64()
    );
    println!(
        "  idle (LOCATION reports every 10 ms)        controller {idle_controller:>5.1} %   process {idle_process:>5.1} %"
    );
    println!(
        "  running (6 joints at 10 kHz, 60k steps/s)  controller {busy_controller:>5.1} %   process {busy_process:>5.1} %"
    );
    board.shut_down();
    let _ = std::fs::remove_dir_all(&settings_dir);
    Ok(())
}

fn percentile_us(sorted: &[Duration], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i.min(sorted.len() - 1)].as_secs_f64() * 1e6
}

/// CPU time (s) of the controller's threads and of the whole process so far.
fn cpu_seconds() -> (f64, f64) {
    // SAFETY: sysconf with a valid name.
    let ticks = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1) as f64;
    let mut controller = 0.0;
    if let Ok(tasks) = std::fs::read_dir("/proc/self/task") {
        for task in tasks.flatten() {
            let comm = std::fs::read_to_string(task.path().join("comm")).unwrap_or_default();
            if !CONTROLLER_THREADS.contains(&comm.trim()) {
                continue;
            }
            if let Some(t) = stat_cpu_ticks(&task.path().join("stat")) {
                controller += t / ticks;
            }
        }
    }
    let process = stat_cpu_ticks(std::path::Path::new("/proc/self/stat")).unwrap_or(0.0) / ticks;
    (controller, process)
}

/// utime + stime from a /proc stat file, in clock ticks.
fn stat_cpu_ticks(path: &std::path::Path) -> Option<f64> {
    let stat = std::fs::read_to_string(path).ok()?;
    // The command name may hold spaces: fields count from after its closing parenthesis.
    let rest = &stat[stat.rfind(')')? + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let utime: f64 = fields.get(11)?.parse().ok()?;
    let stime: f64 = fields.get(12)?.parse().ok()?;
    Some(utime + stime)
}

/// Percent of one core used by the controller's threads and the process over `window`.
fn cpu_over(window: Duration, during: impl FnOnce()) -> (f64, f64) {
    let (c0, p0) = cpu_seconds();
    let start = Instant::now();
    during();
    std::thread::sleep(window.saturating_sub(start.elapsed()));
    let (c1, p1) = cpu_seconds();
    let elapsed = start.elapsed().as_secs_f64();
    ((c1 - c0) / elapsed * 100.0, (p1 - p0) / elapsed * 100.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stat_fields_are_read_after_the_command_name() {
        let dir = std::env::temp_dir().join(format!("sim-host-stat-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("stat");
        // pid (comm with spaces) state ppid ... utime=14th stime=15th field.
        std::fs::write(&path, "42 (a b) S 1 2 3 4 5 6 7 8 9 10 250 50 0 0\n").unwrap();
        assert_eq!(stat_cpu_ticks(&path), Some(300.0));
        assert!(stat_cpu_ticks(std::path::Path::new("/proc/self/stat")).is_some());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn percentiles() {
        let d: Vec<Duration> = (1..=100).map(Duration::from_micros).collect();
        assert_eq!(percentile_us(&d, 0.5), 51.0);
        assert_eq!(percentile_us(&d, 0.99), 99.0);
        assert!(percentile_us(&[], 0.5).is_nan());
    }
}

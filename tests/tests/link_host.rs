//! The host side of issue 14 against the real sim-host, over UDP on 127.0.0.1: a lossy
//! run at 4x real time through a small buffer ends exactly; an underrun is blamed on the
//! right side; and the command line's smaller fixes (addresses, hints, exit codes, dry run).

use std::net::UdpSocket;
use std::path::Path;
use std::process::{Command, Output};
use std::time::Instant;

use system_tests::{SimHost, armctl_bin};

fn armctl(args: &[&str]) -> Output {
    Command::new(armctl_bin())
        .args(args)
        .output()
        .expect("run armctl")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// A CSV of `seconds` of motion for `joints` joints, a waypoint every 0.1 s, sine waves of
/// at most ~2.6k steps/s per joint that end away from 0.
fn sine_csv(path: &Path, joints: usize, seconds: u32) {
    let mut csv = String::from("time_s");
    for j in 0..joints {
        csv.push_str(&format!(",j{j}"));
    }
    csv.push('\n');
    for i in 0..=seconds * 10 {
        let t = f64::from(i) / 10.0;
        csv.push_str(&format!("{t:.1}"));
        for j in 0..joints {
            let sign = if j % 2 == 0 { 1.0 } else { -1.0 };
            let amplitude = 1500.0 * (1.0 + j as f64 * 0.1);
            let p = sign * amplitude * (2.0 * std::f64::consts::PI * t / 5.0).sin();
            csv.push_str(&format!(",{}", p.round() as i64));
        }
        csv.push('\n');
    }
    std::fs::write(path, csv).unwrap();
}

/// The run of issue 14: 4x real time, 20 % loss each way, 7 joints, 10 ms segments, a
/// 256-point buffer. armctl with a fixed 100 ms resend underran after 360-924 of the 1,200
/// points; with resends that follow the round trip it must end exactly.
#[test]
fn lossy_run_at_four_times_real_time_through_256_points_ends_exactly() {
    // 2.56 s of motion in the buffer is 0.64 s at 4x: the upload must not share the CPU
    // with the 50x overload test below (beside it, 1 of 6 runs with two busy loops per
    // core still underran after issue 19's armctl fix; alone, 20 of 20 passed). Before
    // that fix it underran alone too ("after 300 of 1200 points"): RUNING overtook a lost
    // PENDING and the run started with part of the buffer.
    let _alone = system_tests::run_alone();
    for seed in ["1", "2"] {
        let sim = SimHost::start(&[
            "--joints",
            "7",
            "--buffer-capacity",
            "256",
            "--time-scale",
            "4",
            "--loss",
            "0.2",
            "--seed",
            seed,
        ]);
        let file = sim.dir().join("seven.csv");
        sine_csv(&file, 7, 12);
        let out = armctl(&[
            "--controller",
            &sim.addr.to_string(),
            "run",
            file.to_str().unwrap(),
            "--segment-ms",
            "10",
            "--quiet",
        ]);
        let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
        assert!(
            out.status.success(),
            "seed {seed}: {stdout}\n{stderr}\n{}",
            sim.log()
        );
        assert!(stdout.contains("1200 points"), "{stdout}");
        assert!(
            stdout.contains("final positions match the last point"),
            "{stdout}"
        );
        let status = armctl(&["--controller", &sim.addr.to_string(), "status"]);
        let status = text(&status.stdout);
        assert!(
            status.contains("1200 announced, 1200 received, 1200 executed"),
            "{status}"
        );
        assert!(status.contains("underrun no"), "{status}");
    }
}

/// Bug 4 of issue 14 over UDP: at 50x real time with 1 ms segments the simulator cannot
/// feed its step engine (50,000 points a second) and ends the run by underrun with
/// thousands of points received and not run. armctl must blame the controller, not the
/// upload, and its figures must agree with STATUS. (Should the simulator keep up on a
/// fast machine, the run ends cleanly and there is nothing to blame: that passes too.)
#[test]
fn an_underrun_with_points_left_is_not_blamed_on_the_upload() {
    let sim = SimHost::start(&["--joints", "2", "--time-scale", "50"]);
    let file = sim.dir().join("long.csv");
    sine_csv(&file, 2, 30);
    let controller = sim.addr.to_string();
    let out = armctl(&[
        "--controller",
        &controller,
        "run",
        file.to_str().unwrap(),
        "--segment-ms",
        "1",
        "--quiet",
    ]);
    let stderr = text(&out.stderr);
    let status = text(&armctl(&["--controller", &controller, "status", "--json"]).stdout);
    let status: serde_json::Value = serde_json::from_str(&status).expect("STATUS as JSON");
    let received = status["received"].as_u64().unwrap();
    let executed = status["executed"].as_u64().unwrap();
    if out.status.success() {
        assert_eq!(executed, 30_000, "{status}");
        eprintln!("the simulator kept up at 50x: no underrun to classify");
        return;
    }
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains(&format!(
            "after {executed} of 30000 points ({received} received"
        )),
        "{stderr}\n{status}"
    );
    if received > executed {
        assert!(stderr.contains("fell behind"), "{stderr}");
        assert!(!stderr.contains("upload was too slow"), "{stderr}");
    }
}

/// A closed port on loopback: the system answers "port unreachable" at once, and armctl
/// says so at once instead of resending for a second.
#[test]
fn a_refused_loopback_port_fails_at_once() {
    let port = UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let started = Instant::now();
    let out = armctl(&["--controller", &format!("127.0.0.1:{port}"), "status"]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    // The refusal ended it, not the resends running out ("no ACK for STATUS after 10
    // attempts in 1.0 s" before). How long it took is a figure, not a rule.
    assert!(stderr.contains("nothing listens on 127.0.0.1:"), "{stderr}");
    assert!(!stderr.contains("no ACK"), "{stderr}");
    eprintln!("refused port reported in {:?}", started.elapsed());
}

/// `armctl --attempts A --ack-timeout-ms T COMMAND...` against a loopback socket that never
/// answers: its port and armctl's output.
fn against_a_silent_socket(
    attempts: &str,
    ack_timeout_ms: &str,
    command: &[&str],
) -> (u16, Output) {
    let silent = UdpSocket::bind("127.0.0.1:0").unwrap();
    let port = silent.local_addr().unwrap().port();
    let controller = format!("127.0.0.1:{port}");
    let mut args = vec![
        "--controller",
        controller.as_str(),
        "--attempts",
        attempts,
        "--ack-timeout-ms",
        ack_timeout_ms,
    ];
    args.extend_from_slice(command);
    (port, armctl(&args))
}

/// A socket that never answers: the hint names the port actually used.
#[test]
fn no_reply_names_the_port_used() {
    let (port, out) = against_a_silent_socket("2", "20", &["status"]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains(&format!("is port {port} right")),
        "{stderr}"
    );
}

#[test]
fn resends_past_the_duplicate_window_are_warned_about() {
    let (_, out) = against_a_silent_socket("30", "100", &["frame", "encode", "status"]);
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("2 s duplicate window"), "{stderr}");
}

/// Usage errors exit with 2 (clap), failures with 1, as the README says.
#[test]
fn exit_codes() {
    assert_eq!(armctl(&["no-such-command"]).status.code(), Some(2));
    assert_eq!(
        armctl(&["run", "x.csv", "--window", "33"]).status.code(),
        Some(2)
    );
    assert_eq!(armctl(&["frame", "decode", "zz"]).status.code(), Some(1));
    assert_eq!(
        armctl(&["frame", "encode", "status"]).status.code(),
        Some(0)
    );
}

/// `run --dry-run` needs no controller, and still checks step rates: against the config,
/// and without one against the board's 100 kHz (or `--max-step-rate`).
#[test]
fn dry_run_checks_step_rates_without_a_controller() {
    let dir = std::env::temp_dir().join(format!("link-host-dry-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("fast.csv");
    // 3,000 steps in 10 ms on joint 1: 300,000 steps/s. (The header was `time_s,a,b`
    // until issue 31: a CSV's columns are joints by name now, and `a` names none.)
    std::fs::write(&file, "time_s,j0,j1\n0,0,0\n0.01,10,3000\n").unwrap();
    let path = file.to_str().unwrap();
    let out = armctl(&["run", path, "--dry-run"]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("resampled segment 0"), "{stderr}");
    assert!(stderr.contains("joint 1"), "{stderr}");
    assert!(stderr.contains("limit of 100000 steps/s"), "{stderr}");
    let out = armctl(&["run", path, "--dry-run", "--max-step-rate", "400000"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(
        text(&out.stdout).contains("1 points"),
        "{}",
        text(&out.stdout)
    );
    // With a config, its joint names and rates.
    let config = dir.join("arm.json");
    std::fs::write(
        &config,
        r#"{"joints": [{"name": "base", "max_step_rate_hz": 5000},
                       {"name": "shoulder", "max_step_rate_hz": 500000}]}"#,
    )
    .unwrap();
    let out = armctl(&[
        "run",
        path,
        "--dry-run",
        "--config",
        config.to_str().unwrap(),
    ]);
    let stderr = text(&out.stderr);
    assert!(stderr.contains("joint 1 (shoulder)"), "{stderr}");
    assert!(stderr.contains("limit of 100000 steps/s"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The issue's bug 2 as a user meets it: `armctl run` while `armctl status` polls every
/// 0.2 s from the same machine. Each poll is another socket on the owner's address; its
/// STATUS must neither break the upload's order nor take its reports. (Whether a poll's
/// seq collides with the upload's is chance here; sim-host's own UDP tests reproduce the
/// collision deterministically. This checks the tools together.)
#[test]
fn a_run_with_status_polled_alongside_ends_exactly() {
    // A buffer of 64 points: the upload streams for the whole run, between the polls.
    let sim = SimHost::start(&["--joints", "2", "--buffer-capacity", "64"]);
    let file = sim.dir().join("two.csv");
    sine_csv(&file, 2, 3);
    let controller = sim.addr.to_string();
    let done = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let poller = {
        let controller = controller.clone();
        let done = done.clone();
        std::thread::spawn(move || {
            let mut polls = 0;
            // Bounded: at most 100 polls (20 s) even if the run never ends.
            while !done.load(std::sync::atomic::Ordering::Relaxed) && polls < 100 {
                let out = armctl(&["--controller", &controller, "status"]);
                assert!(out.status.success(), "{}", text(&out.stderr));
                polls += 1;
                std::thread::sleep(std::time::Duration::from_millis(200));
            }
            polls
        })
    };
    let out = armctl(&[
        "--controller",
        &controller,
        "run",
        file.to_str().unwrap(),
        "--quiet",
    ]);
    done.store(true, std::sync::atomic::Ordering::Relaxed);
    let polls = poller.join().unwrap();
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(out.status.success(), "{stdout}\n{stderr}\n{}", sim.log());
    assert!(
        stdout.contains("final positions match the last point"),
        "{stdout}"
    );
    // About 12 in the 3 s run here; a poll (an armctl process and 200 ms) ten times
    // slower still fits 2 (5 was the bound).
    println!("{polls} STATUS polls during the run");
    assert!(polls >= 2, "only {polls} polls during the run");
}

//! Issue 23: what a new user does first, with the `armctl` binary against the real
//! sim-host: move the arm in degrees, jog a joint, home it, and run a 5-waypoint file in
//! degrees whose via points must all be reached.

use std::process::Command;

use system_tests::{SimHost, armctl_bin};

fn armctl(sim: &SimHost, args: &[&str]) -> (bool, String, String) {
    system_tests::run_armctl(Some(sim), args)
}

/// 1000 steps per radian (17.45 steps a degree); the elbow is limited to +-45 degrees.
const CONFIG: &str = r#"{"units": "deg", "joints": [
    {"name": "base", "steps_per_radian": 1000, "max_step_rate_hz": 4000},
    {"name": "elbow", "steps_per_radian": 1000, "min_steps": -785, "max_steps": 785,
     "max_step_rate_hz": 2000, "max_accel_steps_s2": 20000},
    {"name": "wrist", "steps_per_radian": -1000, "max_step_rate_hz": 4000}
]}"#;

#[test]
fn move_jog_home_and_a_file_in_degrees() {
    let sim = SimHost::start(&["--joints", "3"]);
    let config = sim.dir().join("arm.json");
    std::fs::write(&config, CONFIG).unwrap();
    let config = config.to_str().unwrap();

    // Move: base to 30 degrees, wrist to -10; the elbow holds. Positions are whole steps:
    // 30 degrees is 523.6 steps, 524 shown back as 30.02 degrees.
    let (ok, out, err) = armctl(
        &sim,
        &["move", "--config", config, "30", "elbow=0", "wrist=-10"],
    );
    assert!(ok, "{out}\n{err}");
    assert!(
        out.contains("at base 30.02 deg, elbow 0.00 deg, wrist -10.03 deg"),
        "{out}"
    );

    // Jog the elbow by 5 degrees, twice, then back by 2.5.
    for by in ["5", "5", "-2.5"] {
        let (ok, out, err) = armctl(&sim, &["jog", "--config", config, "elbow", by]);
        assert!(ok, "{out}\n{err}");
    }
    let (ok, out, _) = armctl(&sim, &["jog", "--config", config, "elbow", "0"]);
    assert!(ok);
    // Each jog rounds to whole steps (17.45 a degree): 87, 174, 130 steps = 7.45 degrees.
    assert!(out.contains("elbow 7.45 deg"), "{out}");

    // Beyond the elbow's range: refused before anything moves, naming joint and range.
    let (ok, _, err) = armctl(&sim, &["move", "--config", config, "elbow=50"]);
    assert!(!ok);
    assert!(
        err.contains(
            "elbow: target 50.02 deg (873 steps) is outside its range -44.98 deg to 44.98 deg \
             (-785 to 785 steps)"
        ),
        "{err}"
    );

    // Home: every joint back to 0, checked.
    let (ok, out, err) = armctl(&sim, &["home", "--config", config]);
    assert!(ok, "{out}\n{err}");
    assert!(
        out.contains("home: base 0.00 deg, elbow 0.00 deg, wrist 0.00 deg"),
        "{out}"
    );

    // watch with the config: names and degrees.
    let (ok, out, err) = armctl(&sim, &["watch", "--duration", "2", "--config", config]);
    assert!(ok, "{out}\n{err}");
    assert!(
        out.lines()
            .any(|l| l.contains("base") && l.contains("elbow") && l.contains("0.00 deg")),
        "{out}"
    );

    // A 5-waypoint file in degrees (the config's units), from home, with via points that
    // fall between 10 ms segment ends (0.505 s, 1.255 s).
    let file = sim.dir().join("wave-deg.csv");
    std::fs::write(
        &file,
        "time_s,base,elbow,wrist\n0,0,0,0\n0.505,20,10,-5\n1.255,-10,30,5\n1.8,15,-20,0\n2.4,0,0,0\n",
    )
    .unwrap();
    let record = sim.dir().join("rec.csv");
    let (ok, out, err) = armctl(
        &sim,
        &[
            "run",
            file.to_str().unwrap(),
            "--config",
            config,
            "--quiet",
            "--record",
            record.to_str().unwrap(),
        ],
    );
    assert!(ok, "{out}\n{err}");
    // The recording names the joints as the config does.
    let recorded = std::fs::read_to_string(&record).unwrap();
    assert!(
        recorded.starts_with("time_s,state,base,elbow,wrist\n"),
        "{}",
        recorded.lines().next().unwrap_or("")
    );
    assert!(
        out.contains("each of the 5 waypoints is a point's end at its time"),
        "{out}"
    );
    assert!(
        out.contains("all 5 waypoints were passed at their times"),
        "{out}"
    );
}

/// Issue 23: `plot` on a trajectory file gave "state \"800\": number too large"; it now
/// previews the points `run` would send, legend by the config's names; `check` is
/// `run --dry-run`.
#[test]
fn plot_previews_a_trajectory_file_and_check_checks_it() {
    let dir = std::env::temp_dir().join(format!("cli-motion-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("arm.json");
    std::fs::write(&config, CONFIG).unwrap();
    let file = dir.join("deg.csv");
    std::fs::write(&file, "time_s,base,elbow\n0,0,0\n0.505,20,10\n1.0,0,0\n").unwrap();
    let svg = dir.join("preview.svg");
    let output = Command::new(armctl_bin())
        .args(["plot", file.to_str().unwrap(), "--config"])
        .arg(&config)
        .arg("-o")
        .arg(&svg)
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{out}{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(
        out.contains("101 points, 1.000 s, every one of its 3 waypoints a point's end"),
        "{out}"
    );
    let svg = std::fs::read_to_string(&svg).unwrap();
    assert!(svg.contains("base") && svg.contains("elbow") && svg.contains("commanded"));

    let output = Command::new(armctl_bin())
        .args(["check", file.to_str().unwrap(), "--config"])
        .arg(&config)
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{out}");
    assert!(
        out.contains("each of the 3 waypoints is a point's end"),
        "{out}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn move_without_a_config_is_in_steps_and_degrees_need_one() {
    let sim = SimHost::start(&["--joints", "2"]);
    let (ok, out, err) = armctl(&sim, &["move", "400", "-300"]);
    assert!(ok, "{out}\n{err}");
    assert!(
        out.contains("at joint 0 400 steps, joint 1 -300 steps"),
        "{out}"
    );
    let (ok, out, err) = armctl(&sim, &["move", "--relative", "1=50"]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("joint 1 -250 steps"), "{out}");
    let (ok, _, err) = armctl(&sim, &["move", "--units", "deg", "10"]);
    assert!(!ok);
    assert!(err.contains("--units deg needs a joint config"), "{err}");
    // Jog by keys needs a terminal; the tool says what to do instead.
    let (ok, _, err) = armctl(&sim, &["jog"]);
    assert!(!ok);
    assert!(err.contains("jog by keys needs a terminal"), "{err}");
}

/// Issue 23: `armctl jog` by keys, in a terminal (`script` gives it one): a digit chooses
/// the joint, `+` and `-` move it, `]` doubles the increment, `q` ends. Each key waits for
/// the line that shows the previous move ended (what the user sees), not for a time.
#[test]
fn jog_by_keys_in_a_terminal() {
    use std::io::{Read, Write};
    use std::process::Stdio;
    use std::sync::mpsc;
    use std::time::{Duration, Instant};

    if Command::new("script").arg("--version").output().is_err() {
        eprintln!("SKIPPED: needs util-linux `script` (a terminal for the key reader)");
        return;
    }
    let sim = SimHost::start(&["--joints", "2"]);
    let command = format!("{} --controller {} jog", armctl_bin().display(), sim.addr);
    let mut child = Command::new("script")
        .args(["-qec", &command, "/dev/null"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("script");
    let mut stdout = child.stdout.take().unwrap();
    let (tx, rx) = mpsc::channel::<String>();
    std::thread::spawn(move || {
        let mut buf = [0u8; 4096];
        while let Ok(n) = stdout.read(&mut buf) {
            if n == 0 {
                break;
            }
            let _ = tx.send(String::from_utf8_lossy(&buf[..n]).into_owned());
        }
    });
    let mut seen = String::new();
    // Hang guard only: each wait ends as soon as the line shows up.
    let mut wait_for = |text: &str| {
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            // The last line drawn (lines are redrawn after a carriage return).
            let last = seen
                .rsplit('\r')
                .find(|l| !l.trim().is_empty())
                .unwrap_or("");
            if last.contains(text) && !last.contains("(moving)") {
                return;
            }
            let left = deadline.saturating_duration_since(Instant::now());
            assert!(!left.is_zero(), "no {text:?} in:\n{seen}");
            if let Ok(chunk) = rx.recv_timeout(left) {
                seen.push_str(&chunk);
            }
        }
    };
    let mut stdin = child.stdin.take().unwrap();
    let mut key = |k: &str| {
        stdin.write_all(k.as_bytes()).unwrap();
        stdin.flush().unwrap();
    };
    wait_for("joint 0 by 100 steps");
    key("1");
    wait_for("joint 1 by 100 steps");
    key("+");
    wait_for("joint 1 100 steps");
    key("]");
    wait_for("joint 1 by 200 steps");
    key("-");
    wait_for("joint 1 -100 steps");
    key("q");
    let deadline = Instant::now() + Duration::from_secs(30);
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        assert!(Instant::now() < deadline, "jog did not end after q");
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(status.success(), "{seen}");
}

/// A run the controller refuses part-way (a point past a limit kept on the controller) left
/// it in PENDING with the points before it buffered, and the next `run` or `move` was
/// refused ("the controller is PENDING"). The tool now drops the partial upload (STOPPED)
/// and says so.
#[test]
fn a_refused_upload_leaves_the_controller_stopped() {
    let sim = SimHost::start(&["--joints", "1"]);
    let (ok, out, err) = armctl(&sim, &["config", "set", "--joint", "0", "--max", "100"]);
    assert!(ok, "{out}\n{err}");
    let file = sim.dir().join("past.csv");
    std::fs::write(&file, "0,0\n0.5,90\n1.0,200\n").unwrap();
    let (ok, _, err) = armctl(&sim, &["run", file.to_str().unwrap(), "--quiet"]);
    assert!(!ok);
    assert!(err.contains("INVALID_POINT"), "{err}");
    assert!(err.contains("STOPPED sent"), "{err}");
    let (ok, out, err) = armctl(&sim, &["status", "--json"]);
    assert!(ok, "{err}");
    let status: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(status["state"], "Stopped", "{out}");
    // The next motion is taken.
    let (ok, out, err) = armctl(&sim, &["move", "50"]);
    assert!(ok, "{out}\n{err}");
}

/// Issue 32: `armctl run --speed 150` of a file at 4,000 steps/s with joint 0 limited to
/// 5,000 (kept on the controller): the controller lowers the override to what the points
/// allow, and the run says so and ends on its last point. Before, the points were checked
/// at 100 % and ran at 6,000 (sim-host `tests/hold.rs` measures the STEP rises).
#[test]
fn run_at_150_percent_is_lowered_to_the_joints_rate_limit_and_says_so() {
    let sim = SimHost::start(&["--joints", "1"]);
    let (ok, out, err) = armctl(
        &sim,
        &["config", "set", "--joint", "0", "--max-rate", "5000"],
    );
    assert!(ok, "{out}\n{err}");
    let file = sim.dir().join("cruise.csv");
    std::fs::write(&file, "time_s,j0\n0,0\n1,4000\n").unwrap();
    let (ok, out, err) = armctl(
        &sim,
        &["run", file.to_str().unwrap(), "--quiet", "--speed", "150"],
    );
    assert!(ok, "{out}\n{err}");
    assert!(
        out.contains("speed 150 % lowered to ")
            && out.contains("joint 0 would pass its RATE limit"),
        "{out}"
    );
    let percent: u32 = out
        .split("lowered to ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|n| n.parse().ok())
        .expect("a percent");
    println!(
        "{}",
        out.lines().find(|l| l.starts_with("speed")).unwrap_or("")
    );
    assert!((100..=125).contains(&percent), "{out}");
    assert!(out.contains("final positions match"), "{out}");
}

/// The 6-axis example config the issue 31 user had (armctl/examples/arm.json).
fn example_config() -> String {
    concat!(env!("CARGO_MANIFEST_DIR"), "/../armctl/examples/arm.json").to_string()
}

/// Issue 31: `time_s,elbow,base` (row `1.0,400,-700`) with arm.json moved joint 0 by +400
/// and joint 1 by -700, exited 0 and said the positions matched; the elbow did not move.
/// Columns map by header name now, and a name that is no joint is refused before sending.
#[test]
fn csv_columns_are_joints_by_header_name() {
    let sim = SimHost::start(&["--joints", "6"]);
    let config = example_config();
    let file = sim.dir().join("named.csv");
    std::fs::write(&file, "time_s,elbow,base\n1.0,400,-700\n").unwrap();
    let (ok, out, err) = armctl(
        &sim,
        &[
            "run",
            file.to_str().unwrap(),
            "--config",
            &config,
            "--quiet",
        ],
    );
    assert!(ok, "{out}\n{err}");
    assert!(
        out.contains("final positions match the last point: [-700, 0, 400, 0, 0, 0]"),
        "{out}"
    );
    let typo = sim.dir().join("typo.csv");
    std::fs::write(&typo, "time_s,elbw,base\n2.0,0,0\n").unwrap();
    let (ok, out, err) = armctl(
        &sim,
        &[
            "run",
            typo.to_str().unwrap(),
            "--config",
            &config,
            "--quiet",
        ],
    );
    assert!(!ok, "{out}");
    assert!(err.contains("\"elbw\", is not a joint"), "{err}");
    // Nothing moved.
    let (ok, out, err) = armctl(&sim, &["move", "--config", &config, "base=-700"]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("already there"), "{out}");
}

/// Issue 31: after `armctl config push`, `armctl move 0=5000` without --config was refused
/// INVALID_POINT ("27625 against 20000 steps/s") although a slower plan fits: the planner
/// knew only STATUS's max step rate. move, jog and home now read the limits the controller
/// keeps (LIMITS_GET) and plan within them, range included. Since config push also keeps
/// the joints' names (JOINT_DESC, issue 31), they name the joints by them.
#[test]
fn move_without_a_config_plans_within_the_limits_the_controller_keeps() {
    let sim = SimHost::start(&["--joints", "6"]);
    let (ok, out, err) = armctl(&sim, &["config", "push", &example_config()]);
    assert!(ok, "{out}\n{err}");
    let (ok, out, err) = armctl(&sim, &["move", "0=5000"]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("at base 5000 steps"), "{out}");
    let (ok, out, err) = armctl(&sim, &["jog", "1", "-300"]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("shoulder -300 steps"), "{out}");
    // The base's range on the controller is -16000..16000: refused before sending.
    let (ok, out, err) = armctl(&sim, &["move", "0=20000"]);
    assert!(!ok, "{out}");
    assert!(
        err.contains("base: target 20000 steps is outside its range -16000 steps to 16000 steps"),
        "{err}"
    );
    let (ok, out, err) = armctl(&sim, &["home"]);
    assert!(ok, "{out}\n{err}");
}

/// Issue 31: a move refused at its first PENDING left the controller in NEW, and the next
/// command failed ("`armctl stop` first"); only an upload refused later (PENDING) was
/// dropped. Every refused upload now leaves the controller STOPPED.
#[test]
fn an_upload_refused_at_its_first_frame_leaves_the_controller_stopped() {
    let sim = SimHost::start(&["--joints", "1"]);
    let (ok, out, err) = armctl(&sim, &["config", "set", "--joint", "0", "--max", "100"]);
    assert!(ok, "{out}\n{err}");
    let file = sim.dir().join("first.csv");
    std::fs::write(&file, "0,0\n0.01,150\n").unwrap();
    let (ok, _, err) = armctl(&sim, &["run", file.to_str().unwrap(), "--quiet"]);
    assert!(!ok);
    assert!(err.contains("INVALID_POINT"), "{err}");
    assert!(err.contains("STOPPED sent"), "{err}");
    let (ok, out, err) = armctl(&sim, &["status", "--json"]);
    assert!(ok, "{err}");
    let status: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(status["state"], "Stopped", "{out}");
    let (ok, out, err) = armctl(&sim, &["move", "50"]);
    assert!(ok, "{out}\n{err}");
}

/// Issue 31: `config get --json` could not be pushed back ("missing field
/// `max_step_rate_hz`"). It round-trips now: what `get --json` prints, `push` restores.
#[test]
fn config_get_json_pushes_back() {
    let sim = SimHost::start(&["--joints", "6"]);
    let (ok, out, err) = armctl(&sim, &["config", "push", &example_config()]);
    assert!(ok, "{out}\n{err}");
    let (ok, saved, err) = armctl(&sim, &["config", "get", "--json"]);
    assert!(ok, "{err}");
    let file = sim.dir().join("kept.json");
    std::fs::write(&file, &saved).unwrap();
    let (ok, out, err) = armctl(&sim, &["config", "set", "--joint", "2", "--clear"]);
    assert!(ok, "{out}\n{err}");
    let (ok, out, err) = armctl(&sim, &["config", "push", file.to_str().unwrap()]);
    assert!(ok, "{out}\n{err}");
    let (ok, again, err) = armctl(&sim, &["config", "get", "--json"]);
    assert!(ok, "{err}");
    let joints =
        |text: &str| serde_json::from_str::<serde_json::Value>(text).unwrap()["joints"].clone();
    assert_eq!(joints(&again), joints(&saved), "{again}");
    assert_eq!(joints(&again)[2]["max"], 12000, "{again}");
}

/// Issue 31: refusals name the joint by its config name, the point's time, the user's
/// units, and for a rate the slow-down that fits: from the host's own check, and from the
/// controller's (INVALID_POINT, explained from LIMITS_GET and the points sent).
#[test]
fn refusals_name_the_joint_the_time_the_units_and_the_slow_down() {
    let sim = SimHost::start(&["--joints", "3"]);
    let config = sim.dir().join("arm.json");
    std::fs::write(&config, CONFIG).unwrap();
    let config = config.to_str().unwrap();
    // 30 degrees of base (524 steps) in 0.1 s: 5236 steps/s against the config's 4000.
    let fast = sim.dir().join("fast.csv");
    std::fs::write(&fast, "time_s,base\n0,0\n0.1,30\n").unwrap();
    let (ok, out, err) = armctl(&sim, &["run", fast.to_str().unwrap(), "--config", config]);
    assert!(!ok, "{out}");
    assert!(err.contains("joint 0 (base)"), "{err}");
    assert!(err.contains("(t = 0.010000 s)"), "{err}");
    assert!(
        err.contains("deg/s) exceeds the limit of 4000 steps/s (229.18 deg/s)"),
        "{err}"
    );
    assert!(err.contains("needs 1.3x longer"), "{err}");

    // Within the config (4000 steps/s) but over the 1000 the controller keeps: 30
    // degrees in 0.3 s is 1745 steps/s. The controller refuses; the tool says where.
    let (ok, out, err) = armctl(
        &sim,
        &["config", "set", "--joint", "0", "--max-rate", "1000"],
    );
    assert!(ok, "{out}\n{err}");
    let slow = sim.dir().join("slow.csv");
    std::fs::write(&slow, "time_s,base\n0,0\n0.3,30\n").unwrap();
    let (ok, out, err) = armctl(
        &sim,
        &["run", slow.to_str().unwrap(), "--config", config, "--quiet"],
    );
    assert!(!ok, "{out}");
    assert!(err.contains("INVALID_POINT"), "{err}");
    assert!(err.contains("joint 0 (base)"), "{err}");
    assert!(err.contains("t = 0."), "{err}");
    assert!(err.contains("deg/s"), "{err}");
    assert!(
        err.contains("its max rate 1000 steps/s (57.30 deg/s)"),
        "{err}"
    );
    assert!(err.contains("needs 1.7x longer"), "{err}");
    assert!(err.contains("STOPPED sent"), "{err}");
}

//! Issue 23's wire-side tools through the `armctl` binary against the real sim-host:
//! `enable`/`disable` (SET_ENABLE) and the drivers' state in `status`.

use system_tests::SimHost;

fn armctl(sim: &SimHost, args: &[&str]) -> (bool, String, String) {
    system_tests::run_armctl(Some(sim), args)
}

#[test]
fn enable_and_disable_are_explicit_and_status_shows_each_driver() {
    let sim = SimHost::start(&["--joints", "4"]);
    let (ok, out, err) = armctl(&sim, &["disable", "0", "1"]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("joints 0, 1 disabled"), "{out}");
    assert!(out.contains("enabled: 2 3 gripper  disabled: 0 1"), "{out}");
    // Again: still disabled (the old `enable` toggled them back).
    let (ok, out, err) = armctl(&sim, &["disable", "0,1"]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("enabled: 2 3 gripper  disabled: 0 1"), "{out}");
    let (ok, out, _) = armctl(&sim, &["status"]);
    assert!(ok);
    assert!(
        out.contains("drivers          enabled: 2 3 gripper  disabled: 0 1"),
        "{out}"
    );
    let (ok, out, _) = armctl(&sim, &["status", "--json"]);
    assert!(ok);
    let json: serde_json::Value = serde_json::from_str(&out).unwrap();
    // bit 3 (reported), bit 4 (gripper), bits 8-15: joints 2-7 enabled; bits 5-7 the
    // stop cause (issue 31): 1, COMPLETE.
    assert_eq!(json["more_flags"], 0xFC38, "{out}");
    assert_eq!(json["stop_cause"], "COMPLETE", "{out}");
    let (ok, out, err) = armctl(&sim, &["enable"]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("every driver enabled"), "{out}");
    assert!(
        out.contains("enabled: 0 1 2 3 gripper  disabled: -"),
        "{out}"
    );
    let (ok, out, err) = armctl(&sim, &["enable", "9"]);
    assert!(!ok, "{out}");
    assert!(err.contains("joint numbers 0-7"), "{err}");
}

fn armctl_from(sim: &SimHost, bind: &str, args: &[&str]) -> (bool, String, String) {
    let mut all = vec!["--bind", bind];
    all.extend_from_slice(args);
    armctl(sim, &all)
}

#[test]
fn a_second_host_reads_status_and_positions_and_is_told_who_owns_the_arm_until_release() {
    let sim = SimHost::start(&["--joints", "3"]);
    // The first host takes the controller and declares positions.
    let (ok, out, err) = armctl_from(&sim, "127.0.0.1:0", &["set-location", "5", "-6", "7"]);
    assert!(ok, "{out}\n{err}");
    // The owner (this machine, 127.0.0.1) speaks before each of the second host's commands
    // until it releases: 5 s of its silence and it is no longer one (cli.rs's stop test
    // saw a loaded machine take that long between two armctl commands).
    let owner = sim.connect();
    let second_host = |args: &[&str]| {
        owner.status().unwrap();
        armctl_from(&sim, "127.0.0.2:0", args)
    };
    // A second host reads STATUS and the positions, read-only.
    let (ok, out, err) = second_host(&["status"]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("state            STOPPED"), "{out}");
    assert!(out.contains("    0                 5  enabled"), "{out}");
    assert!(out.contains("    1                -6  enabled"), "{out}");
    assert!(out.contains("    2                 7  enabled"), "{out}");
    assert!(out.contains("read-only"), "{out}");
    let (ok, out, _) = second_host(&["status", "--json"]);
    assert!(ok);
    let json: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(json["positions"], serde_json::json!([5, -6, 7]), "{out}");
    assert_eq!(json["read_only"], true);
    // It can watch too, polling read-only.
    let (ok, out, err) = second_host(&["watch", "--duration", "1"]);
    assert!(ok, "{out}\n{err}");
    assert!(err.contains("read-only"), "{err}");
    assert!(
        out.contains("STOPPED  j0         5 j1        -6 j2         7"),
        "{out}"
    );
    // Its commands are refused, and the message names the owner.
    let (ok, out, err) = second_host(&["pin", "0", "on"]);
    assert!(!ok, "{out}");
    assert!(err.contains("NOT_OWNER"), "{err}");
    assert!(err.contains("owned by 127.0.0.1"), "{err}");
    owner.status().unwrap();
    // The owner releases; the second host takes the controller at once.
    let (ok, out, err) = armctl_from(&sim, "127.0.0.1:0", &["release"]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("released"), "{out}");
    drop(owner);
    let (ok, out, err) = armctl_from(&sim, "127.0.0.2:0", &["pin", "0", "on"]);
    assert!(ok, "{out}\n{err}");
    // Now the first host is the stranger.
    let (ok, _, err) = armctl_from(&sim, "127.0.0.1:0", &["pin", "0", "off"]);
    assert!(!ok);
    assert!(err.contains("owned by 127.0.0.2"), "{err}");
}

#[test]
fn limits_set_with_armctl_config_are_kept_enforced_and_explained() {
    let dir = std::env::temp_dir().join(format!("wire-tools-limits-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let settings = dir.join("settings.txt");
    let settings_arg = settings.to_str().unwrap();
    let sim = SimHost::start(&["--joints", "2", "--settings", settings_arg]);
    let (ok, out, err) = armctl(
        &sim,
        &[
            "config", "set", "--joint", "1", "--min", "-100", "--max", "100",
        ],
    );
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("joint 1 -100..100 steps"), "{out}");
    let (ok, out, err) = armctl(
        &sim,
        &["config", "set", "--joint", "1", "--max-rate", "2000"],
    );
    assert!(ok, "{out}\n{err}");
    assert!(
        out.contains("joint 1 -100..100 steps, at most 2000 steps/s"),
        "options not given keep their value: {out}"
    );
    // A CSV run without --config past the range: refused by the controller, and the
    // message names the point, the joint and the limit.
    let csv = dir.join("far.csv");
    std::fs::write(&csv, "time_s,j0,j1\n0,0,0\n1,0,150\n").unwrap();
    let (ok, out, err) = armctl(&sim, &["run", csv.to_str().unwrap(), "--quiet"]);
    assert!(!ok, "{out}");
    assert!(err.contains("INVALID_POINT"), "{err}");
    // Issue 31: the point found among those sent, named by time, joint and limit.
    assert!(
        err.contains("ending at t = ")
            && err.contains("joint 1: position 101 steps is above its max 100 steps"),
        "{err}"
    );
    // Issue 31: the tool leaves the controller STOPPED after the refusal (it was left
    // PENDING, the points before taken, and the next command failed until `armctl stop`).
    assert!(
        err.contains("STOPPED sent: the upload was dropped"),
        "{err}"
    );
    let (ok, _, err) = armctl(&sim, &["stop"]);
    assert!(ok, "{err}");
    // set-location outside the range: refused, and said why.
    let (ok, _, err) = armctl(&sim, &["set-location", "0", "500"]);
    assert!(!ok);
    assert!(err.contains("LOCATION_SETTING seq"), "{err}");
    assert!(err.contains("(500 against 100)"), "{err}");
    // Kept across a restart of the controller.
    drop(sim);
    let text = std::fs::read_to_string(&settings).unwrap();
    assert!(text.contains("limit.1=-100,100,2000"), "{text}");
    let sim = SimHost::start(&["--joints", "2", "--settings", settings_arg]);
    let (ok, out, err) = armctl(&sim, &["config", "get"]);
    assert!(ok, "{out}\n{err}");
    assert!(
        out.contains("    1  -100..100 steps, at most 2000 steps/s"),
        "{out}"
    );
    assert!(
        out.contains("    0  any position, the controller's max step rate"),
        "{out}"
    );
    let (ok, out, _) = armctl(&sim, &["config", "get", "--json"]);
    assert!(ok);
    let json: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(json["joints"][1]["max"], 100, "{out}");
    let (ok, _, err) = armctl(&sim, &["config", "set", "--joint", "1", "--min", "200"]);
    assert!(!ok);
    assert!(err.contains("min 200 is above max 100"), "{err}");
    let (ok, out, err) = armctl(&sim, &["config", "set", "--joint", "1", "--clear"]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("joint 1 any position"), "{out}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn status_with_a_config_names_each_joint_with_its_position_and_driver() {
    let sim = SimHost::start(&["--joints", "3"]);
    let config = sim.dir().join("arm.json");
    std::fs::write(
        &config,
        r#"{"joints": [
            {"name": "base", "steps_per_radian": 1000, "max_step_rate_hz": 5000},
            {"name": "shoulder", "steps_per_radian": 1000, "zero_offset_steps": 100, "max_step_rate_hz": 5000},
            {"name": "elbow", "steps_per_radian": 1000, "max_step_rate_hz": 5000}
        ]}"#,
    )
    .unwrap();
    let (ok, out, err) = armctl(&sim, &["set-location", "0", "1671", "-500"]);
    assert!(ok, "{out}\n{err}");
    let (ok, out, err) = armctl(&sim, &["disable", "2"]);
    assert!(ok, "{out}\n{err}");
    let (ok, out, err) = armctl(&sim, &["status", "--config", config.to_str().unwrap()]);
    assert!(ok, "{out}\n{err}");
    // (1671 - 100) / 1000 rad = 90.0 degrees.
    assert!(
        out.contains("    1  shoulder               1671     90.0  enabled"),
        "{out}"
    );
    assert!(
        out.contains("    0  base                      0      0.0  enabled"),
        "{out}"
    );
    assert!(
        out.contains("    2  elbow                  -500    -28.6  disabled"),
        "{out}"
    );
    let (ok, out, _) = armctl(
        &sim,
        &["status", "--json", "--config", config.to_str().unwrap()],
    );
    assert!(ok);
    let json: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(
        json["joint_names"],
        serde_json::json!(["base", "shoulder", "elbow"]),
        "{out}"
    );
    assert_eq!(
        json["positions"],
        serde_json::json!([0, 1671, -500]),
        "{out}"
    );
    // The config's limits pushed to the controller, then read back with the names.
    let (ok, out, err) = armctl(&sim, &["config", "push", config.to_str().unwrap()]);
    assert!(ok, "{out}\n{err}");
    assert!(
        out.contains("joint 1 shoulder: any position, at most 5000 steps/s"),
        "{out}"
    );
    let (ok, out, err) = armctl(
        &sim,
        &["config", "get", "--config", config.to_str().unwrap()],
    );
    assert!(ok, "{out}\n{err}");
    assert!(
        out.contains("    2 elbow  any position, at most 5000 steps/s"),
        "{out}"
    );
    let (ok, _, err) = armctl(&sim, &["status", "--config", "/nonexistent/arm.json"]);
    assert!(!ok);
    assert!(err.contains("/nonexistent/arm.json"), "{err}");
}

/// Issue 31: after `armctl disable 1`, `move 1=500` was accepted, STATUS showed joint 1 at
/// 500 and every pulse went to a disabled driver. The controller refuses it now
/// (INVALID_POINT) and the tool names the joint from the LIMITS report's last refusal.
#[test]
fn a_limp_joint_is_not_moved_and_the_refusal_names_it() {
    let sim = SimHost::start(&["--joints", "2"]);
    let (ok, out, err) = armctl(&sim, &["disable", "1"]);
    assert!(ok, "{out}\n{err}");
    let (ok, out, err) = armctl(&sim, &["move", "1=500"]);
    assert!(!ok, "a limp joint moved: {out}\n{err}");
    assert!(err.contains("INVALID_POINT"), "{err}");
    // The point found among those sent (tools31's refusals), the joint named.
    assert!(
        err.contains("joint 1: its driver is disabled (limp)")
            && err.contains("`armctl enable 1` first"),
        "{err}"
    );
    let (ok, out, _) = armctl(&sim, &["status"]);
    assert!(ok);
    assert!(out.contains("    1                 0  disabled"), "{out}");
    assert!(
        out.contains("state            STOPPED"),
        "the refused upload dropped: {out}"
    );
    // The other joint still moves; enabled again, joint 1 does too.
    let (ok, out, err) = armctl(&sim, &["move", "0=40"]);
    assert!(ok, "{out}\n{err}");
    let (ok, out, err) = armctl(&sim, &["enable", "1"]);
    assert!(ok, "{out}\n{err}");
    let (ok, out, err) = armctl(&sim, &["move", "1=500"]);
    assert!(ok, "{out}\n{err}");
}

/// Issue 31: `armctl config init` writes an arm description from the drive's figures;
/// `config push` keeps its limits and acceleration on the controller, `config get --json`
/// reads them back (`max_accel`, one field more), and the controller refuses a point
/// over the acceleration.
#[test]
fn config_init_push_and_get_round_trip_the_acceleration() {
    let sim = SimHost::start(&["--joints", "2"]);
    let file = sim.dir().join("arm.json");
    let (ok, out, err) = system_tests::config_init_degrees_arm(&file, "90");
    assert!(ok, "{out}\n{err}");
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    let j1 = &written["joints"][1];
    // 200 * 16 * 5 = 16000 steps per revolution.
    assert_eq!(j1["name"], "shoulder", "{written}");
    assert_eq!(j1["min_steps"], -4000, "{written}");
    assert_eq!(j1["max_steps"], 4000, "{written}");
    assert_eq!(j1["max_step_rate_hz"], 2000, "{written}");
    assert_eq!(j1["max_accel_steps_s2"], 4000, "{written}");
    assert_eq!(written["units"], "deg");
    let (ok, out, err) = armctl(&sim, &["config", "push", file.to_str().unwrap()]);
    assert!(ok, "{out}\n{err}");
    assert!(
        out.contains("joint 1 shoulder: at most 4000 steps/s²"),
        "{out}"
    );
    let (ok, out, err) = armctl(&sim, &["config", "get", "--json"]);
    assert!(ok, "{out}\n{err}");
    let report: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(report["max_accel"][1], 4000, "{out}");
    assert_eq!(report["joints"][1]["max"], 4000, "{out}");
    // A 1 s file run that jumps to full rate at once: refused by the controller (a CSV
    // run without --config is checked against nothing on the host).
    let csv = sim.dir().join("jump.csv");
    std::fs::write(&csv, "time_s,j0,j1\n0,0,0\n0.01,0,20\n1,0,1000\n").unwrap();
    // In steps: since config push keeps the arm's units on the controller (issue 31), a
    // CSV without --config is in its degrees unless --units says otherwise.
    let (ok, _, err) = armctl(
        &sim,
        &["run", csv.to_str().unwrap(), "--quiet", "--units", "steps"],
    );
    assert!(!ok);
    assert!(err.contains("INVALID_POINT"), "{err}");
    assert!(
        err.contains("joint 1: steps/s² above the joint's max acceleration"),
        "{err}"
    );
}

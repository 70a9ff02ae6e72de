//! Issue 31's scripted new user: `armctl config init` for a degrees arm, `config push`,
//! then `move`, `jog`, `run` of a CSV with shuffled named columns and `home`, each WITHOUT
//! `--config` (armctl reads the names, units and limits the controller keeps: JOINT_DESC
//! and LIMITS), each ending at the right positions, checked against the controller's
//! LOCATION after each step and against the simulator's VCD trace at the end (every pulse
//! of every step counted); and limit refusals that name the joint and the units. `status`
//! and `watch` show the same names and degrees without `--config`.
//!
//! The same user's other tools, where what they need is: Python's `run()` in degrees in
//! armctl-py/tests/test_described.py (maturin, pytest); the ROS goal (a
//! FollowJointTrajectory through a bridge whose file lists no joints) in
//! ros2-bridge/tests/dds.rs `a_new_user_s_goal_with_the_arm_the_controller_keeps`, which runs
//! only in the private network namespace ros2-bridge/tests/dds.sh creates (DDS multicasts;
//! .ci/run runs it).

use armctl::{Client, vcd};
use system_tests::SimHost;

fn armctl(sim: &SimHost, args: &[&str]) -> (bool, String, String) {
    system_tests::run_armctl(Some(sim), args)
}

fn positions(sim: &SimHost) -> [i32; 2] {
    let arm = Client::connect(sim.addr).unwrap();
    let location = arm
        .current_location(std::time::Duration::from_secs(2))
        .unwrap();
    [location.position[0], location.position[1]]
}

#[test]
fn config_init_push_then_move_jog_run_without_config() {
    let mut sim = SimHost::start_traced(&["--joints", "2"]);
    let file = sim.dir().join("arm.json");
    // 200 * 16 * 5 = 16000 steps per revolution: 44.44 steps a degree; +-90 degrees is
    // +-4000 steps, 45 degrees/s 2000 steps/s.
    let (ok, out, err) = system_tests::config_init_degrees_arm(&file, "9000");
    assert!(ok, "{out}\n{err}");
    let (ok, out, err) = armctl(&sim, &["config", "push", file.to_str().unwrap()]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("joint 1 shoulder: deg"), "{out}");

    // config get shows the description; its --json round-trips through config push.
    let (ok, out, err) = armctl(&sim, &["config", "get"]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("joint 0 base: deg"), "{out}");
    let (ok, got, err) = armctl(&sim, &["config", "get", "--json"]);
    assert!(ok, "{got}\n{err}");
    let report: serde_json::Value = serde_json::from_str(&got).unwrap();
    assert_eq!(report["joint_desc"][1]["name"], "shoulder", "{got}");
    assert_eq!(report["joint_desc"][1]["unit"], "deg", "{got}");
    let scale = report["joint_desc"][1]["scale"].as_f64().unwrap();
    assert_eq!(scale, 16000.0 / std::f64::consts::TAU, "{got}");
    let saved = sim.dir().join("kept.json");
    std::fs::write(&saved, &got).unwrap();
    let (ok, out, err) = armctl(&sim, &["config", "push", saved.to_str().unwrap()]);
    assert!(ok, "{out}\n{err}");
    let (ok, again, err) = armctl(&sim, &["config", "get", "--json"]);
    assert!(ok, "{again}\n{err}");
    assert_eq!(
        serde_json::from_str::<serde_json::Value>(&again).unwrap(),
        report
    );

    // move, in the controller's degrees and names: 45 degrees is 2000 steps.
    let (ok, out, err) = armctl(&sim, &["move", "45", "shoulder=-22.5"]);
    assert!(ok, "{out}\n{err}");
    assert!(
        out.contains("at base 45.00 deg, shoulder -22.50 deg"),
        "{out}"
    );
    assert_eq!(positions(&sim), [2000, -1000]);

    // status and watch without --config: the names and degrees the controller keeps, as
    // move shows them (JOINT_DESC_GET, read-only: any host may look).
    let (ok, out, err) = armctl(&sim, &["status"]);
    assert!(ok, "{out}\n{err}");
    assert!(
        out.contains("joint  name                  steps  degrees  driver")
            && out.contains("    0  base                   2000     45.0  enabled")
            && out.contains("    1  shoulder              -1000    -22.5  enabled"),
        "{out}"
    );
    let (ok, out, err) = armctl(&sim, &["status", "--json"]);
    assert!(ok, "{out}\n{err}");
    let json: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(json["joint_names"], serde_json::json!(["base", "shoulder"]));
    let (ok, out, err) = armctl(&sim, &["watch", "--duration", "2"]);
    assert!(ok, "{out}\n{err}");
    assert!(
        out.lines()
            .any(|l| l.contains("base     45.00 deg shoulder    -22.50 deg")),
        "{out}"
    );
    // From another host too, which only looks (read-only STATUS and JOINT_DESC_GET).
    let (ok, out, err) = armctl(&sim, &["--bind", "127.0.0.2:0", "status"]);
    assert!(ok, "{out}\n{err}");
    assert!(
        out.contains("    1  shoulder              -1000    -22.5  enabled")
            && out.contains("(read-only: another host owns the controller"),
        "{out}"
    );

    // jog the shoulder by 9 degrees (400 steps).
    let (ok, out, err) = armctl(&sim, &["jog", "shoulder", "9"]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("shoulder -13.50 deg"), "{out}");
    assert_eq!(positions(&sim), [2000, -600]);

    // A limit refusal names the joint and the units, and moves nothing.
    let (ok, _, err) = armctl(&sim, &["move", "shoulder=100"]);
    assert!(!ok);
    assert!(
        err.contains("shoulder: target 99.99 deg (4444 steps) is outside its range")
            && err.contains("-90.00 deg to 90.00 deg (-4000 to 4000 steps)"),
        "{err}"
    );
    assert_eq!(positions(&sim), [2000, -600]);

    // run a CSV whose columns are named, shoulder first, in degrees: no --config.
    let csv = sim.dir().join("named.csv");
    std::fs::write(
        &csv,
        "time_s,shoulder,base\n0,-13.5,45\n1,-9,33.75\n2,-4.5,22.5\n",
    )
    .unwrap();
    let (ok, out, err) = armctl(&sim, &["run", csv.to_str().unwrap(), "--quiet"]);
    assert!(ok, "{out}\n{err}");
    assert_eq!(positions(&sim), [1000, -200]);

    // A file beyond the shoulder's range: refused, naming the joint and its degrees.
    let far = sim.dir().join("far.csv");
    std::fs::write(&far, "time_s,shoulder,base\n0,-4.5,22.5\n4,95,22.5\n").unwrap();
    let (ok, out, err) = armctl(&sim, &["run", far.to_str().unwrap(), "--quiet"]);
    assert!(!ok, "{out}");
    assert!(err.contains("shoulder") && err.contains("deg"), "{err}");
    assert_eq!(positions(&sim), [1000, -200]);

    // home, named and in degrees too.
    let (ok, out, err) = armctl(&sim, &["home"]);
    assert!(ok, "{out}\n{err}");
    assert!(
        out.contains("home: base 0.00 deg, shoulder 0.00 deg"),
        "{out}"
    );
    assert_eq!(positions(&sim), [0, 0]);

    // The trace: every pulse of the four motions (each monotone per joint) and where
    // they end.
    sim.terminate();
    let trace = vcd::read(&sim.trace()).unwrap_or_else(|e| panic!("{e}\n{}", sim.log()));
    assert_eq!(trace.positions(2), vec![0, 0]);
    // base: 0 -> 2000 (move), -> 1000 (run), -> 0 (home); shoulder: 0 -> -1000 (move)
    // -> -600 (jog) -> -200 (run) -> 0 (home).
    assert_eq!(trace.joints[0].steps, 2000 + 1000 + 1000);
    assert_eq!(trace.joints[1].steps, 1000 + 400 + 400 + 200);
}

//! Issue 23's wire-side tools through the `armctl` binary against the real sim-host:
//! `enable`/`disable` (SET_ENABLE) and the drivers' state in `status`.

use std::process::Command;

use system_tests::{SimHost, armctl_bin};

fn armctl(sim: &SimHost, args: &[&str]) -> (bool, String, String) {
    let output = Command::new(armctl_bin())
        .arg("--controller")
        .arg(sim.addr.to_string())
        .args(args)
        .output()
        .expect("run armctl");
    (
        output.status.success(),
        String::from_utf8_lossy(&output.stdout).into_owned(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
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
    // bit 3 (reported), bit 4 (gripper), bits 8-15: joints 2-7 enabled.
    assert_eq!(json["more_flags"], 0xFC18, "{out}");
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

//! `armctl discover` and `armctl net` against a sim-host on loopback, with DISCOVER sent to
//! the simulator's own address (broadcast discovery runs in a network namespace:
//! sim-host/tests/discover.sh).

use std::process::Command;
use std::time::Duration;

use armctl::{Error, RunOptions};
use protocol::{NetSettings, Point, StatusCode};
use system_tests::{SimHost, armctl_bin};

fn armctl(args: &[&str]) -> (bool, String) {
    let out = Command::new(armctl_bin())
        .args(args)
        .output()
        .expect("run armctl");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

#[test]
fn discover_answers_any_host_and_net_set_is_stored_for_the_next_reset() {
    let sim = SimHost::start(&[]);
    let to = sim.addr.to_string();
    let controller = ["--controller", to.as_str()];

    // The harness's STATUS made 127.0.0.1 the owner. Another host (127.0.0.2) is
    // answered all the same, and told who owns the controller. The armctl binary is found
    // (built, the first time in this process) before that: a build under load took over
    // the 5 s after which a silent owner is no longer one ("free" instead of "owned by").
    let _ = armctl_bin();
    let arm = sim.connect();
    let (ok, out) = armctl(&["--bind", "127.0.0.2:0", "discover", "--to", &to]);
    assert!(ok, "{out}");
    assert!(out.contains("mac 02:53:49:4d:"), "{out}");
    assert!(out.contains("6 joints") && out.contains("STOPPED"), "{out}");
    assert!(out.contains("owned by 127.0.0.1"), "{out}");
    assert!(out.contains("1 controller(s) answered"), "{out}");
    // Discovery changed nothing: 127.0.0.2 is still not the owner (its STATUS is
    // answered read-only since issue 23, its commands refused). The owner speaks before
    // each such command: 5 s of its silence and it is no longer one (cli.rs's stop test
    // saw a loaded machine take that long between two armctl commands).
    let second_host = |args: &[&str]| {
        arm.status().unwrap();
        let mut all = vec!["--bind", "127.0.0.2:0", "--controller", to.as_str()];
        all.extend_from_slice(args);
        armctl(&all)
    };
    let (ok, out) = second_host(&["status"]);
    assert!(ok && out.contains("read-only"), "{out}");
    let (ok, out) = second_host(&["pin", "0", "on"]);
    assert!(!ok && out.contains("NOT_OWNER"), "{out}");
    let (_, out) = armctl(&["discover", "--to", &to]);
    assert!(out.contains("owned by this host"), "{out}");

    // NET_SET from another host: NOT_OWNER.
    let (ok, out) = second_host(&["net", "set", "--dhcp"]);
    assert!(!ok && out.contains("NOT_OWNER"), "{out}");

    // While the arm runs: BAD_STATE.
    let start = arm.last_location().map(|l| l.position).unwrap_or_default();
    let mut target = start;
    target[0] += 2_000;
    // 10 s: still running when NET_SET comes, however slow the machine.
    let points = [Point::from_motion(10_000_000, &start, &target)];
    arm.run_trajectory(
        &points,
        &RunOptions {
            wait: false,
            ..RunOptions::default()
        },
        |_| {},
    )
    .expect("run started");
    let refused = arm.net_set(NetSettings::fixed([10, 1, 2, 3], 24, None));
    assert!(
        matches!(
            refused,
            Err(Error::Refused {
                status: StatusCode::BadState,
                ..
            })
        ),
        "{refused:?}"
    );
    arm.stop().expect("stop");

    // Stored, shown as pending, in the settings file.
    let mut args = controller.to_vec();
    args.extend(["net", "set", "--ip", "10.1.2.3/24", "--gateway", "10.1.2.1"]);
    let (ok, out) = armctl(&args);
    assert!(ok && out.contains("after its next reset"), "{out}");
    let mut args = controller.to_vec();
    args.extend(["net", "show"]);
    let (ok, out) = armctl(&args);
    assert!(ok, "{out}");
    assert!(
        out.contains("stored 10.1.2.3/24 via 10.1.2.1 (after reset)"),
        "{out}"
    );
    let settings = std::fs::read_to_string(sim.dir().join("settings.txt")).unwrap_or_default();
    assert!(settings.contains("ip=10.1.2.3"), "{settings}");
    assert!(settings.contains("gateway=10.1.2.1"), "{settings}");

    // Settings no controller can use are refused before anything is sent.
    let mut args = controller.to_vec();
    args.extend(["net", "set", "--ip", "10.1.2.255/24"]);
    let (ok, out) = armctl(&args);
    assert!(!ok && out.contains("not usable"), "{out}");
    drop(arm);
}

/// Issue 23: `discover --interface NAME` sends from that interface's address (here lo's,
/// to one controller on it: nothing is broadcast); an unknown one lists those there are.
#[test]
fn discover_from_a_named_interface() {
    let sim = SimHost::start(&["--joints", "2"]);
    let to = sim.addr.to_string();
    let (ok, out) = armctl(&["discover", "--interface", "lo", "--to", &to]);
    assert!(ok, "{out}");
    assert!(out.contains("1 controller(s) answered"), "{out}");
    let (ok, out) = armctl(&["discover", "--interface", "no-such-if0", "--to", &to]);
    assert!(!ok);
    assert!(
        out.contains("interfaces with one: ") && out.contains("lo (127.0.0.1)"),
        "{out}"
    );
}

#[test]
fn discover_of_nothing_is_an_empty_list_in_bounded_time() {
    // A closed loopback port: nothing answers. The binary is found (and built, the first
    // time in this process: a `cargo build` that took over 5 s under the issue 19 soak's
    // load) before the clock starts: only armctl's own run is bounded.
    let _ = armctl_bin();
    let started = std::time::Instant::now();
    let (ok, out) = armctl(&["discover", "--to", "127.0.0.1:9", "--wait-ms", "100"]);
    assert!(ok, "{out}");
    assert!(out.contains("0 controller(s) answered"), "{out}");
    assert!(started.elapsed() < Duration::from_secs(5));
}

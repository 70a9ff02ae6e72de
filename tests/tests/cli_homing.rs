//! Issue 33, the tools against the real sim-host with its switch model (`--position`,
//! `--home-switch`, `--limit-switch`): `armctl home` homes by RETURN while no joint is set
//! to home and on the switches once `armctl homing set` set one (the count then the
//! physical position minus the switch's plus the offset); `armctl status` prints a
//! latched limit with the joint and the side; `armctl unlock` and a jog away work, a jog
//! further in is refused.

use system_tests::SimHost;

fn armctl(sim: &SimHost, args: &[&str]) -> (bool, String, String) {
    system_tests::run_armctl(Some(sim), args)
}

#[test]
fn home_on_switches_or_by_return_status_names_the_latched_limit_and_unlock() {
    // Joint 0 is physically at 500 with its home switch at 0 (min side); joint 1's max
    // limit switch is at 200 (it starts at 0).
    let mut sim = SimHost::start_traced(&[
        "--joints",
        "2",
        "--position",
        "0:500",
        "--home-switch",
        "0:0",
        "--limit-switch",
        "1:-1000:200",
    ]);
    // Nothing set to home: RETURN (nothing to move).
    let (ok, out, err) = armctl(&sim, &["home"]);
    assert!(ok, "{out}{err}");
    assert!(out.contains("home:"), "{out}");

    let (ok, out, err) = armctl(
        &sim,
        &[
            "homing",
            "set",
            "0",
            "--travel",
            "2000",
            "--offset",
            "10",
            "--seek",
            "1000",
            "--approach",
            "1000",
            "--backoff",
            "1000",
        ],
    );
    assert!(ok, "{out}{err}");
    let (ok, out, err) = armctl(&sim, &["homing", "get", "0"]);
    assert!(
        ok && out.contains("towards min") && out.contains("offset 10"),
        "{out}{err}"
    );
    let (ok, out, err) = armctl(&sim, &["home"]);
    assert!(ok, "{out}{err}");
    assert!(out.contains("homed on the switches"), "{out}");
    let (ok, out, err) = armctl(&sim, &["status", "--json"]);
    assert!(ok, "{err}");
    let status: serde_json::Value = serde_json::from_str(&out).unwrap();
    let homed_at = status["positions"][0].as_i64().unwrap();
    // The switch closes at physical 0: the count there is the offset; the joint stands
    // where the approach stopped, at the closing step or past it (below it: the approach
    // runs towards min). Exact against the trace at the end: the CI's run on a loaded
    // machine stopped one step past (count 9), which the old bound here, 10..=40, had the
    // wrong way round. The seek and the approach may run on past the switch for as long as
    // the simulator's switch path lags: the back-off (1,000 steps at 1,000 steps/s) and
    // this bound allow 1 s of it, ten times a busy machine's (the seek at 4,000 steps/s
    // with the default 400-step back-off allowed 100 ms).
    assert!(
        (10 - 1_000..=10).contains(&homed_at),
        "homed at count {homed_at}"
    );
    let (ok, out, _) = armctl(&sim, &["status"]);
    assert!(
        ok && out.contains("switches") && out.contains("homed"),
        "{out}"
    );

    // Joint 1 into its max limit: the move fails, the latch names joint 1's max side.
    let (ok, out, err) = armctl(&sim, &["move", "--relative", "1=400"]);
    assert!(!ok, "the move ran into the limit: {out}{err}");
    // The move's own error names the switch (it said "a reason it did not say" before).
    assert!(
        err.contains("max limit switch of joint 1 tripped"),
        "{out}{err}"
    );
    let (ok, out, err) = armctl(&sim, &["status"]);
    assert!(ok, "{err}");
    assert!(out.contains("LATCHED on the max limit of joint 1"), "{out}");
    assert!(out.contains("max limit switch of joint 1 tripped"), "{out}");
    // Latched: refused, naming the limit.
    let (ok, out, err) = armctl(&sim, &["move", "--relative", "1=-20"]);
    assert!(!ok && err.contains("LIMIT_LATCHED"), "{out}{err}");
    let (ok, out, err) = armctl(&sim, &["unlock"]);
    assert!(ok, "{out}{err}");
    let (ok, out, err) = armctl(&sim, &["move", "--relative", "1=20"]);
    assert!(
        !ok && err.contains("LIMIT_LATCHED"),
        "further in: {out}{err}"
    );
    let (ok, out, err) = armctl(&sim, &["move", "--relative", "1=-50"]);
    assert!(ok, "away: {out}{err}");

    // Joint 0 has not moved since it was homed: its count is its physical position (500
    // at boot, plus every step the trace shows) less the switch's (0) plus the offset.
    sim.terminate();
    let trace = armctl::vcd::read(&sim.trace()).unwrap_or_else(|e| panic!("{e}\n{}", sim.log()));
    const SWITCH: i64 = 0;
    const OFFSET: i64 = 10;
    let physical = 500 + trace.positions(1)[0];
    assert_eq!(
        homed_at,
        physical - SWITCH + OFFSET,
        "count against the physical position"
    );
}

//! `sim-host --trace` against armctl's VCD reader and `armctl plot`: the positions counted
//! from the traced STEP/DIR pulses equal the controller's own LOCATION, and the trace plots.

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use armctl::{Client, vcd};
use protocol::State;
use system_tests::{SimHost, armctl_bin};

fn armctl(args: &[&str]) -> String {
    let output = Command::new(armctl_bin())
        .args(args)
        .output()
        .expect("run armctl");
    let stdout = String::from_utf8_lossy(&output.stdout).into_owned();
    assert!(
        output.status.success(),
        "armctl {args:?}: {stdout}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    stdout
}

fn path(p: &Path) -> &str {
    p.to_str().expect("UTF-8 temp path")
}

#[test]
fn traced_pulses_end_where_the_controller_says_and_plot() {
    let mut sim = SimHost::start_traced(&["--joints", "3"]);
    let controller = sim.addr.to_string();
    // Joint 0 out and part way back, joint 1 the other way round, joint 2 still.
    let moves = sim.dir().join("move.csv");
    std::fs::write(
        &moves,
        "time_s,j0,j1,j2\n0,0,0,0\n0.2,120,-80,0\n0.4,40,30,0\n",
    )
    .unwrap();
    let out = armctl(&[
        "--controller",
        &controller,
        "run",
        path(&moves),
        "--quiet",
        "--segment-ms",
        "20",
    ]);
    assert!(out.contains("20 points"), "{out}");

    let arm = Client::connect(sim.addr).unwrap();
    let status = arm.status().unwrap();
    assert_eq!(status.state, State::Stopped);
    assert_eq!(status.executed, 20);
    let location = arm.current_location(Duration::from_secs(2)).unwrap();
    drop(arm);
    sim.terminate();

    let trace = vcd::read(&sim.trace()).unwrap_or_else(|e| panic!("{e}\n{}", sim.log()));
    let reported: Vec<i64> = location.position[..3]
        .iter()
        .map(|&p| i64::from(p))
        .collect();
    assert_eq!(reported, vec![40, 30, 0]);
    assert_eq!(trace.positions(3), reported);
    // Every pulse of the path is there: 120 out and 80 back, 80 out and 110 back.
    assert_eq!(trace.joints[0].steps, 200);
    assert_eq!(trace.joints[1].steps, 190);
    assert_eq!(trace.joints[2].steps, 0);
    // The run lasts 0.4 s of simulated time.
    let (first, last) = (
        trace.first_step_s().unwrap(),
        trace.end_tick as f64 * trace.seconds_per_tick,
    );
    assert!(last - first >= 0.38, "trace from {first} s to {last} s");

    let svg = sim.dir().join("trace.svg");
    let out = armctl(&[
        "plot",
        path(&sim.trace()),
        "--trajectory",
        path(&moves),
        "-o",
        path(&svg),
    ]);
    assert!(out.contains("joint 0: 200 steps, ends at 40"), "{out}");
    assert!(out.contains("joint 1: 190 steps, ends at 30"), "{out}");
    let svg = std::fs::read_to_string(&svg).unwrap();
    assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
    // Joints 0..2 drawn (2 is commanded though still), each with its dashed command.
    // plotters writes each joint's line as one `<polyline>` of width 2 (axes and ticks are
    // width 1), and each dash of a commanded line as a `<polyline>` of width 1.
    let joint_lines = svg
        .lines()
        .filter(|l| l.starts_with("<polyline") && l.contains("stroke-width=\"2\""))
        .count();
    assert_eq!(joint_lines, 3, "{svg}");
    for colour in ["#1F77B4", "#D62728", "#2CA02C"] {
        let stroke = format!("stroke=\"{colour}\" stroke-width=\"1\"");
        assert!(
            svg.contains(&stroke),
            "no dashed command in {colour}: {svg}"
        );
    }
    assert!(svg.contains("joint 2") && svg.contains("commanded"));
    assert!(svg.len() < 200_000, "{} bytes", svg.len());
}

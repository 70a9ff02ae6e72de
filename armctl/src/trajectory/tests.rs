use super::*;
use crate::run::MAX_POINTS;
use protocol::Point;

const CONFIG: &str = r#"{"joints": [
    {"name": "shoulder", "steps_per_radian": 1000.0, "zero_offset_steps": 100,
     "min_steps": -2000, "max_steps": 4000, "max_step_rate_hz": 2000},
    {"name": "elbow", "steps_per_radian": -500.0, "max_step_rate_hz": 1000}
]}"#;

fn config() -> ArmConfig {
    ArmConfig::parse(CONFIG, "arm.json").unwrap()
}

fn trajectory(points: &str) -> String {
    format!(r#"{{"joint_names": ["shoulder", "elbow"], "points": [{points}]}}"#)
}

fn point(sec: i64, nanosec: u32, a: f64, b: f64) -> String {
    format!(
        r#"{{"positions": [{a}, {b}], "velocities": [], "time_from_start": {{"sec": {sec}, "nanosec": {nanosec}}}}}"#
    )
}

#[test]
fn joint_trajectory_radians_to_steps() {
    let text = trajectory(&[point(0, 0, 0.0, 0.0), point(1, 500_000_000, 1.5, 0.5)].join(","));
    let w = parse_joint_trajectory(&text, "t.json", &config()).unwrap();
    assert_eq!(w.times_us, vec![0, 1_500_000]);
    assert_eq!(w.positions[0], vec![Some(100.0), Some(0.0)]);
    assert_eq!(w.positions[1], vec![Some(1600.0), Some(-250.0)]);
}

#[test]
fn joint_names_follow_the_config_not_the_file_order() {
    let text = r#"{"joint_names": ["elbow"], "points": [
        {"positions": [1.0], "time_from_start": {"sec": 1, "nanosec": 0}}]}"#;
    let w = parse_joint_trajectory(text, "t.json", &config()).unwrap();
    assert_eq!(w.positions[0], vec![None, Some(-500.0)]);
    let unknown = r#"{"joint_names": ["wrist"], "points": []}"#;
    let err = parse_joint_trajectory(unknown, "t.json", &config()).unwrap_err();
    assert_eq!(err.kind, ErrorKind::UnknownJoint("wrist".into()));
    assert!(err.to_string().contains("\"wrist\""));
}

#[test]
fn resampling_interpolates_linearly_and_keeps_the_end_exact() {
    // Joint 0 from 100 to 1600 steps in 1.5 s, at 100 ms segments: 15 points of 100.
    let text = trajectory(&[point(0, 0, 0.0, 0.0), point(1, 500_000_000, 1.5, 0.5)].join(","));
    let w = parse_joint_trajectory(&text, "t.json", &config()).unwrap();
    let start = [100, 0, 7, 0, 0, 0, 0, 0];
    let points = to_points(&w, &start, 100_000, &config(), None).unwrap();
    assert_eq!(points.len(), 15);
    for (k, p) in points.iter().enumerate() {
        assert_eq!(p.duration, 100_000);
        assert_eq!(p.position[0], 100 + 100 * (k as i32 + 1));
        // Joints beyond the config hold their position.
        assert_eq!(p.position[2], 7);
    }
    assert_eq!(points[14].position[1], -250);
    // Hints as PROTOCOL.md, "Point (116 bytes)", wants them.
    assert_eq!(points[0].number_of_period[0], 100);
    assert_eq!(points[0].period[0], 1000);
}

#[test]
fn a_span_that_does_not_divide_is_cut_into_equal_segments() {
    // Changed with issue 23 (waypoints kept): this was "the last segment is shorter"
    // ([100, 100, 50] ms), which let a segment straddle a waypoint in longer files.
    let w = parse_csv("time_s,j0\n0,0\n0.25,100\n", "t.csv").unwrap();
    let config = ArmConfig::unlimited(1, 10_000);
    let points = to_points(&w, &[0; 8], 100_000, &config, None).unwrap();
    let durations: Vec<i32> = points.iter().map(|p| p.duration).collect();
    assert_eq!(durations, vec![83_333, 83_333, 83_334]);
    let positions: Vec<i32> = points.iter().map(|p| p.position[0]).collect();
    assert_eq!(positions, vec![33, 67, 100]);
}

/// Issue 23: with 10 ms segments a via point at 0.505 s fell inside a segment and its joint
/// got no pulses, while the run reported success.
#[test]
fn a_via_point_between_segment_ends_is_reached_at_its_time() {
    let w = parse_csv("0,0,0\n0.505,505,0\n1.0,0,7\n", "via.csv").unwrap();
    let config = ArmConfig::unlimited(2, 100_000);
    let points = to_points(&w, &[0; 8], 10_000, &config, None).unwrap();
    let mut t = 0i64;
    let at_via = points
        .iter()
        .find(|p| {
            t += i64::from(p.duration);
            t == 505_000
        })
        .expect("a segment ends at 0.505 s");
    assert_eq!(at_via.position[0], 505);
    assert!(points.iter().all(|p| p.duration <= 10_000));
    assert_eq!(points.last().unwrap().position[..2], [0, 7]);
    assert_eq!(check_waypoints(&points, &w, &[0; 8]), Ok(3));
}

/// Issue 23: `--segment-ms 1000` on wave.csv (a waypoint every 0.5 s) left joints 0 and 1
/// still: every segment ended where they were at rest.
#[test]
fn segments_longer_than_the_waypoint_spacing_still_pass_every_waypoint() {
    let wave = parse_csv(include_str!("../../examples/wave.csv"), "wave.csv").unwrap();
    let points = to_points(
        &wave,
        &[0; 8],
        1_000_000,
        &ArmConfig::unlimited(3, 100_000),
        None,
    )
    .unwrap();
    let rows: Vec<[i32; 3]> = points
        .iter()
        .map(|p| [p.position[0], p.position[1], p.position[2]])
        .collect();
    assert_eq!(
        rows,
        vec![[800, -400, 200], [0, 0, 400], [-800, 400, 200], [0, 0, 0]]
    );
    assert!(points.iter().all(|p| p.duration == 500_000));
}

#[test]
fn a_plan_that_skips_a_waypoint_is_refused_naming_it() {
    let w = parse_csv("0,0\n0.5,100\n1.0,0\n", "skip.csv").unwrap();
    // What fixed 1 s segments used to plan: one segment from 0 to 0, the via point lost.
    let lost = [Point::from_motion(1_000_000, &[0; 8], &[0; 8])];
    let err = check_waypoints(&lost, &w, &[0; 8]).unwrap_err();
    assert_eq!(err.kind, ErrorKind::WaypointMissed { planned: None });
    assert_eq!(err.point, Some(1));
    assert!(
        err.to_string()
            .contains("waypoint 1 of the file (t = 0.500000 s)"),
        "{err}"
    );
    // A segment ends at 0.5 s but in the wrong place.
    let wrong = [
        Point::from_motion(500_000, &[0; 8], &[90, 0, 0, 0, 0, 0, 0, 0]),
        Point::from_motion(500_000, &[90, 0, 0, 0, 0, 0, 0, 0], &[0; 8]),
    ];
    let err = check_waypoints(&wrong, &w, &[0; 8]).unwrap_err();
    assert_eq!(
        err.kind,
        ErrorKind::WaypointMissed {
            planned: Some((90, 100))
        }
    );
    assert_eq!(err.joint, Some(0));
}

#[test]
fn more_waypoints_than_an_upload_takes_is_refused_before_resampling() {
    let text: String = (0..=MAX_POINTS + 1)
        .map(|k| format!("{},0\n", k as f64 * 0.001))
        .collect();
    let w = parse_csv(&text, "dense.csv").unwrap();
    let err = to_points(&w, &[0; 8], 10_000, &ArmConfig::unlimited(1, 1000), None).unwrap_err();
    assert_eq!(
        err.kind,
        ErrorKind::TooManyWaypoints {
            count: MAX_POINTS + 1
        }
    );
    assert!(err.to_string().contains("split the file"), "{err}");
}

#[test]
fn a_late_first_waypoint_starts_from_the_current_position() {
    let w = parse_csv("0.1,50\n0.2,50\n", "t.csv").unwrap();
    let config = ArmConfig::unlimited(1, 10_000);
    let points = to_points(&w, &[10, 0, 0, 0, 0, 0, 0, 0], 50_000, &config, None).unwrap();
    let positions: Vec<i32> = points.iter().map(|p| p.position[0]).collect();
    assert_eq!(positions, vec![30, 50, 50, 50]);
}

#[test]
fn a_first_waypoint_at_zero_must_be_where_the_arm_is() {
    let w = parse_csv("0,5\n1,50\n", "t.csv").unwrap();
    let err = to_points(&w, &[0; 8], 10_000, &ArmConfig::unlimited(1, 10_000), None).unwrap_err();
    assert_eq!(
        err.kind,
        ErrorKind::StartMismatch {
            current: 0,
            start: 5
        }
    );
    assert_eq!((err.point, err.joint), (Some(0), Some(0)));
}

#[test]
fn step_rate_over_the_joint_limit_is_refused_with_where_and_what() {
    // Shoulder: 2000 steps/s at most. 300 steps in 100 ms = 3000 steps/s.
    let text = trajectory(&[point(0, 0, 0.0, 0.0), point(0, 100_000_000, 0.3, 0.0)].join(","));
    let w = parse_joint_trajectory(&text, "fast.json", &config()).unwrap();
    let err = to_points(&w, &[100, 0, 0, 0, 0, 0, 0, 0], 50_000, &config(), None).unwrap_err();
    assert_eq!(err.point, Some(0));
    assert_eq!(err.joint, Some(0));
    assert_eq!(
        err.kind,
        ErrorKind::StepRate {
            steps: 150,
            duration_us: 50_000,
            limit_hz: 2000
        }
    );
    let message = err.clone().with_joint_names(&config()).to_string();
    assert!(
        message.starts_with("fast.json: resampled segment 0 (t = 0.050000 s), joint 0 (shoulder)"),
        "{message}"
    );
    assert!(
        message.contains("3000 steps/s exceeds the limit of 2000"),
        "{message}"
    );
}

#[test]
fn the_controller_rate_caps_the_joint_rate() {
    let w = parse_csv("0,0\n1,1500\n", "t.csv").unwrap();
    let config = ArmConfig::unlimited(1, 10_000);
    assert!(to_points(&w, &[0; 8], 10_000, &config, Some(2000)).is_ok());
    let err = to_points(&w, &[0; 8], 10_000, &config, Some(1000)).unwrap_err();
    assert!(matches!(
        err.kind,
        ErrorKind::StepRate { limit_hz: 1000, .. }
    ));
}

#[test]
fn exactly_the_limit_is_allowed() {
    let w = parse_csv("0,0\n1,1000\n", "t.csv").unwrap();
    assert!(to_points(&w, &[0; 8], 10_000, &ArmConfig::unlimited(1, 1000), None).is_ok());
    assert!(to_points(&w, &[0; 8], 10_000, &ArmConfig::unlimited(1, 999), None).is_err());
}

#[test]
fn position_limits_are_checked_per_waypoint() {
    // Shoulder max 4000 steps = 100 + 3.9 rad * 1000.
    let text = trajectory(
        &[
            point(0, 0, 0.0, 0.0),
            point(10, 0, 3.9, 0.0),
            point(20, 0, 3.95, 0.0),
        ]
        .join(","),
    );
    let w = parse_joint_trajectory(&text, "far.json", &config()).unwrap();
    let err = to_points(&w, &[100, 0, 0, 0, 0, 0, 0, 0], 10_000, &config(), None).unwrap_err();
    assert_eq!(
        err.kind,
        ErrorKind::AboveMax {
            value: 4050,
            limit: 4000
        }
    );
    assert_eq!(
        (err.point, err.joint, err.time_s),
        (Some(2), Some(0), Some(20.0))
    );
    let low = parse_csv("0,0\n1,-2001\n", "low.csv").unwrap();
    let config = ArmConfig::parse(
        r#"{"joints": [{"min_steps": -2000, "max_step_rate_hz": 100000}]}"#,
        "c.json",
    )
    .unwrap();
    let err = to_points(&low, &[0; 8], 10_000, &config, None).unwrap_err();
    assert_eq!(
        err.kind,
        ErrorKind::BelowMin {
            value: -2001,
            limit: -2000
        }
    );
    assert!(
        err.to_string()
            .contains("low.csv: waypoint 1 of the file (t = 1.000000 s), joint 0")
    );
}

#[test]
fn more_than_65535_points_is_refused_with_the_segment_that_fits() {
    // 700 s at 10 ms = 70000 points.
    let w = parse_csv("0,0\n700,0\n", "long.csv").unwrap();
    let config = ArmConfig::unlimited(1, 1000);
    let err = to_points(&w, &[0; 8], 10_000, &config, None).unwrap_err();
    let ErrorKind::TooManyPoints {
        count,
        min_segment_us,
    } = err.kind
    else {
        panic!("{err}")
    };
    assert_eq!(count, 70_000);
    assert_eq!(min_segment_us, 10_682);
    let points = to_points(&w, &[0; 8], min_segment_us as u32, &config, None).unwrap();
    assert!(points.len() <= MAX_POINTS);
}

#[test]
fn csv_header_comments_and_blank_lines_are_skipped() {
    let text = "# made by hand\ntime_s, j0 ,j1\n\n0, 0, 0\n   \n  # halfway\n0.5,10,-10\n";
    let w = parse_csv(text, "t.csv").unwrap();
    assert_eq!(w.times_us, vec![0, 500_000]);
    assert_eq!(w.positions[1], vec![Some(10.0), Some(-10.0)]);
    let err = parse_csv("time_s,j0\n0,0\n1,x\n", "t.csv").unwrap_err();
    assert!(err.to_string().contains("line 3"), "{err}");
}

#[test]
fn csv_errors() {
    assert!(matches!(
        parse_csv("0,0\n0,1\n", "t.csv").unwrap_err().kind,
        ErrorKind::TimeNotIncreasing
    ));
    let err = parse_csv("0,0,0\n1,1\n", "t.csv").unwrap_err();
    assert_eq!(
        err.kind,
        ErrorKind::WrongJointCount {
            found: 1,
            expected: 2
        }
    );
    assert!(matches!(
        parse_csv("0,0\n1,x\n", "t.csv").unwrap_err().kind,
        ErrorKind::Parse(_)
    ));
    assert!(matches!(
        parse_csv("time_s,j0\n", "t.csv").unwrap_err().kind,
        ErrorKind::TooShort
    ));
    let one = parse_csv("0,0\n", "t.csv").unwrap();
    assert!(matches!(
        to_points(&one, &[0; 8], 1000, &ArmConfig::unlimited(1, 1000), None)
            .unwrap_err()
            .kind,
        ErrorKind::TooShort
    ));
}

#[test]
fn config_errors() {
    assert!(ArmConfig::parse(r#"{"joints": []}"#, "c").is_err());
    assert!(ArmConfig::parse(r#"{"joints": [{"steps_per_radian": 1}]}"#, "c").is_err());
    assert!(
        ArmConfig::parse(
            r#"{"joints": [{"min_steps": 5, "max_steps": 4, "max_step_rate_hz": 1}]}"#,
            "c"
        )
        .is_err()
    );
}

/// Waypoints of one joint sampled from `curve` (position, velocity in steps, steps/s)
/// every `every_us` up to `end_us`.
fn sampled(curve: impl Fn(f64) -> (f64, f64), every_us: i64, end_us: i64) -> Waypoints {
    let times_us: Vec<i64> = (0..=end_us / every_us).map(|k| k * every_us).collect();
    let (positions, velocities) = times_us
        .iter()
        .map(|&t| {
            let (p, v) = curve(t as f64 / 1e6);
            (vec![Some(p)], vec![Some(v)])
        })
        .unzip();
    Waypoints {
        file: "curve".into(),
        times_us,
        positions,
        velocities,
    }
}

#[test]
fn hermite_reproduces_a_cubic_exactly() {
    // p(t) = 100 + 400 t + 900 t^2 - 450 t^3 steps: a cubic is its own Hermite curve,
    // so every resampled point is the curve rounded to a step, whatever the waypoints.
    let cubic = |t: f64| {
        (
            100.0 + 400.0 * t + 900.0 * t * t - 450.0 * t * t * t,
            400.0 + 1800.0 * t - 1350.0 * t * t,
        )
    };
    let w = sampled(cubic, 500_000, 2_000_000);
    let points = to_points(
        &w,
        &[100, 0, 0, 0, 0, 0, 0, 0],
        10_000,
        &ArmConfig::unlimited(1, 100_000),
        None,
    )
    .unwrap();
    assert_eq!(points.len(), 200);
    for (k, p) in points.iter().enumerate() {
        let t = (k + 1) as f64 * 0.01;
        let exact = cubic(t).0;
        assert!(
            (f64::from(p.position[0]) - exact).abs() <= 0.5 + 1e-6,
            "t = {t}: {} vs {exact}",
            p.position[0]
        );
    }
    assert_eq!(points[199].position[0], cubic(2.0).0.round() as i32);
}

#[test]
fn hermite_follows_a_sine_within_its_error_bound() {
    // 2000 sin(2 pi t) steps, waypoints every 100 ms. The cubic Hermite error is at
    // most max|p''''| h^4 / 384 = 2000 (2 pi)^4 0.1^4 / 384 = 0.81 steps, plus the
    // rounding to a step; straight lines through the same waypoints miss by up to
    // 2000 (1 - cos(pi/10)) = 98 steps.
    let w = 2.0 * std::f64::consts::PI;
    let sine = |t: f64| (2000.0 * (w * t).sin(), 2000.0 * w * (w * t).cos());
    let bound = 2000.0 * w.powi(4) * 0.1f64.powi(4) / 384.0 + 0.5;
    let waypoints = sampled(sine, 100_000, 1_000_000);
    let config = ArmConfig::unlimited(1, 100_000);
    let points = to_points(&waypoints, &[0; 8], 5_000, &config, None).unwrap();
    let worst = points
        .iter()
        .enumerate()
        .map(|(k, p)| (f64::from(p.position[0]) - sine((k + 1) as f64 * 0.005).0).abs())
        .fold(0.0, f64::max);
    assert!(worst <= bound, "worst {worst} > bound {bound}");
    assert_eq!(points.last().unwrap().position[0], 0);
    // The same waypoints without velocities: straight lines, far off between them.
    let mut linear = waypoints.clone();
    linear.velocities.clear();
    let points = to_points(&linear, &[0; 8], 5_000, &config, None).unwrap();
    let worst_linear = points
        .iter()
        .enumerate()
        .map(|(k, p)| (f64::from(p.position[0]) - sine((k + 1) as f64 * 0.005).0).abs())
        .fold(0.0, f64::max);
    assert!(worst_linear > 90.0, "{worst_linear}");
}

#[test]
fn velocities_in_radians_per_second_become_steps_per_second() {
    // MoveIt-style: at rest at both ends, 1 rad in 1 s; the shoulder has 1000
    // steps/rad, the elbow -500. The Hermite curve with zero end velocities is the
    // smoothstep 3f^2 - 2f^3: a quarter of the way is 15.625 % of the move.
    let text = r#"{"joint_names": ["shoulder", "elbow"], "points": [
        {"positions": [0.0, 0.0], "velocities": [0.0, 0.0], "time_from_start": {"sec": 0}},
        {"positions": [1.0, 1.0], "velocities": [0.0, 0.0], "time_from_start": {"sec": 1}}]}"#;
    let w = parse_joint_trajectory(text, "t.json", &config()).unwrap();
    assert_eq!(w.velocities[1], vec![Some(0.0), Some(-0.0)]);
    let points = to_points(&w, &[100, 0, 0, 0, 0, 0, 0, 0], 250_000, &config(), None).unwrap();
    let shoulder: Vec<i32> = points.iter().map(|p| p.position[0]).collect();
    let elbow: Vec<i32> = points.iter().map(|p| p.position[1]).collect();
    assert_eq!(shoulder, vec![256, 600, 944, 1100]);
    assert_eq!(elbow, vec![-78, -250, -422, -500]);
    let text = r#"{"joint_names": ["shoulder", "elbow"], "points": [
        {"positions": [0.0, 0.0], "velocities": [0.0], "time_from_start": {"sec": 0}}]}"#;
    let err = parse_joint_trajectory(text, "t.json", &config()).unwrap_err();
    assert_eq!(
        err.kind,
        ErrorKind::WrongJointCount {
            found: 1,
            expected: 2
        }
    );
}

#[test]
fn a_segment_without_velocities_at_both_ends_is_a_straight_line() {
    // Velocity given at t = 0 and 2 s, not at 1 s: both segments are straight lines.
    let w = Waypoints {
        file: "mixed".into(),
        times_us: vec![0, 1_000_000, 2_000_000],
        positions: vec![vec![Some(0.0)], vec![Some(100.0)], vec![Some(300.0)]],
        velocities: vec![vec![Some(500.0)], vec![None], vec![Some(0.0)]],
    };
    let points = to_points(&w, &[0; 8], 250_000, &ArmConfig::unlimited(1, 1000), None).unwrap();
    let positions: Vec<i32> = points.iter().map(|p| p.position[0]).collect();
    assert_eq!(positions, vec![25, 50, 75, 100, 150, 200, 250, 300]);
}

#[test]
fn a_hermite_overshoot_past_a_limit_is_refused() {
    // From 0 to 100 steps with a large start velocity: the curve passes 100 between
    // the waypoints, which a limit at 100 refuses although both waypoints are inside.
    let w = Waypoints {
        file: "over".into(),
        times_us: vec![0, 1_000_000],
        positions: vec![vec![Some(0.0)], vec![Some(100.0)]],
        velocities: vec![vec![Some(600.0)], vec![Some(0.0)]],
    };
    let config = ArmConfig::parse(
        r#"{"joints": [{"max_steps": 100, "max_step_rate_hz": 100000}]}"#,
        "c.json",
    )
    .unwrap();
    let err = to_points(&w, &[0; 8], 50_000, &config, None).unwrap_err();
    assert!(
        matches!(err.kind, ErrorKind::AboveMax { limit: 100, .. }),
        "{err}"
    );
}

#[test]
fn the_shipped_examples_convert() {
    let config = ArmConfig::parse(include_str!("../../examples/arm.json"), "arm.json").unwrap();
    let reach = parse_joint_trajectory(
        include_str!("../../examples/reach.json"),
        "reach.json",
        &config,
    )
    .unwrap();
    let points = to_points(&reach, &[0; 8], 10_000, &config, Some(100_000)).unwrap();
    assert_eq!(points.len(), 350);
    assert_eq!(points[349].position, [0; 8]);
    // 0.5 rad of base at 5093 steps/rad, reached at 1.5 s (point 149).
    assert_eq!(points[149].position[0], 2547);
    let wave = parse_csv(include_str!("../../examples/wave.csv"), "wave.csv").unwrap();
    let points = to_points(
        &wave,
        &[0; 8],
        10_000,
        &ArmConfig::unlimited(3, 100_000),
        None,
    )
    .unwrap();
    assert_eq!(points.len(), 200);
    assert_eq!(&points[49].position[..3], &[800, -400, 200]);
    // The README's first session: wave-deg.csv in degrees with arm.json.
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/wave-deg.csv");
    let wave = load_in(&path, Some(&config), Some(crate::motion::Units::Deg)).unwrap();
    let points = to_points(&wave, &[0; 8], 10_000, &config, Some(100_000)).unwrap();
    assert_eq!(check_waypoints(&points, &wave, &[0; 8]), Ok(5));
    // 30 degrees of base at 5093 steps/rad, at 0.8 s (point 79).
    assert_eq!(points[79].position[0], 2667);
}

fn temp_file(name: &str, text: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("armctl-traj-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

/// Issue 23: the README said a CSV may leave joints out, but with --config it was refused
/// (2 positions, expected 3).
#[test]
fn a_csv_with_fewer_joints_than_the_config_holds_the_others() {
    let config = ArmConfig::parse(
        r#"{"joints": [{"max_step_rate_hz": 1000}, {"max_step_rate_hz": 1000},
            {"max_step_rate_hz": 1000}]}"#,
        "arm.json",
    )
    .unwrap();
    let path = temp_file("partial.csv", "0.5,10,20\n1.0,0,0\n");
    let w = load(&path, Some(&config)).unwrap();
    assert_eq!(w.positions[0], vec![Some(10.0), Some(20.0), None]);
    let points = to_points(&w, &[0, 0, 33, 0, 0, 0, 0, 0], 100_000, &config, None).unwrap();
    assert!(points.iter().all(|p| p.position[2] == 33));
    let wide = temp_file("wide.csv", "0.5,1,2,3,4\n");
    let err = load(&wide, Some(&config)).unwrap_err();
    assert_eq!(
        err.kind,
        ErrorKind::WrongJointCount {
            found: 4,
            expected: 3
        }
    );
}

#[test]
fn a_csv_in_degrees_is_read_with_the_config_units() {
    let config = ArmConfig::parse(
        r#"{"units": "deg", "joints": [{"steps_per_radian": 1000, "zero_offset_steps": 5,
            "max_step_rate_hz": 1000}]}"#,
        "arm.json",
    )
    .unwrap();
    // Changed with issue 31 (CSV columns by header name): the header was `time_s,base`
    // for this config without names, read by position; a name the config lacks is now
    // refused.
    let path = temp_file("deg.csv", "time_s,j0\n1.0,90\n");
    let w = load(&path, Some(&config)).unwrap();
    let steps = w.positions[0][0].unwrap();
    assert!((steps - (5.0 + 1000.0 * std::f64::consts::FRAC_PI_2)).abs() < 1e-9);
    // --units overrides the config's.
    let w = load_in(&path, Some(&config), Some(crate::motion::Units::Steps)).unwrap();
    assert_eq!(w.positions[0][0], Some(90.0));
    let err = load_in(&path, None, Some(crate::motion::Units::Rad)).unwrap_err();
    assert!(err.to_string().contains("needs a joint config"), "{err}");
}

/// Issue 31: `time_s,elbow,base` (row `1.0,400,-700`) with arm.json moved joint 0 by +400
/// and joint 1 by -700, and the elbow stayed; JSON files mapped by name. CSV columns map
/// by header name now.
#[test]
fn csv_columns_map_by_header_name() {
    let config = ArmConfig::parse(include_str!("../../examples/arm.json"), "arm.json").unwrap();
    let path = temp_file("named.csv", "time_s,elbow,base\n1.0,400,-700\n");
    let w = load_in(&path, Some(&config), Some(crate::motion::Units::Steps)).unwrap();
    assert_eq!(
        w.positions[0],
        vec![Some(-700.0), None, Some(400.0), None, None, None]
    );
    // jN and bare indices, in any order, with a config or without.
    let w = parse_csv("time_s,j2,0\n0.5,7,-3\n", "idx.csv").unwrap();
    assert_eq!(w.positions[0], vec![Some(-3.0), None, Some(7.0)]);
    let path = temp_file("mixed.csv", "t,wrist_3,J1\n0.5,10,20\n");
    let w = load_in(&path, Some(&config), Some(crate::motion::Units::Steps)).unwrap();
    assert_eq!(
        w.positions[0],
        vec![None, Some(20.0), None, None, None, Some(10.0)]
    );
    // Without a header: by position, as before.
    let w = parse_csv("0.5,1,2\n", "plain.csv").unwrap();
    assert_eq!(w.positions[0], vec![Some(1.0), Some(2.0)]);
}

/// Issue 31: a header name that is not a joint is refused, naming it and the names that
/// are; so is a joint given twice, and an index past the config's joints.
#[test]
fn a_csv_header_that_names_no_joint_is_refused() {
    let config = ArmConfig::parse(include_str!("../../examples/arm.json"), "arm.json").unwrap();
    let path = temp_file("typo.csv", "time_s,elbw,base\n1.0,400,-700\n");
    let err = load_in(&path, Some(&config), None).unwrap_err().to_string();
    assert!(
        err.contains("column 2 of the header, \"elbw\", is not a joint"),
        "{err}"
    );
    assert!(err.contains("base, shoulder, elbow, wrist_1"), "{err}");
    let err = parse_csv("time_s,base\n1.0,400\n", "t.csv")
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("\"base\", is not a joint (name the columns j0 to j7)"),
        "{err}"
    );
    let path = temp_file("twice.csv", "time_s,base,j0\n1.0,1,2\n");
    let err = load_in(&path, Some(&config), None).unwrap_err().to_string();
    assert!(
        err.contains("columns 2 (\"base\") and 3 (\"j0\") are both joint 0"),
        "{err}"
    );
    let path = temp_file("past.csv", "time_s,j6\n1.0,1\n");
    let err = load_in(&path, Some(&config), None).unwrap_err().to_string();
    assert!(err.contains("\"j6\", is not a joint"), "{err}");
}

/// Issue 31: the limits a controller keeps narrow a config's (range overlap, lower rate;
/// a kept rate of 0 is none of its own).
#[test]
fn a_config_within_the_controllers_kept_limits() {
    use protocol::JointLimits;
    let config = ArmConfig::unlimited(2, 100_000).within(&[
        JointLimits {
            min: -16_000,
            max: 16_000,
            max_rate_hz: 20_000,
        },
        JointLimits::NONE,
    ]);
    assert_eq!(
        (config.joints[0].min_steps, config.joints[0].max_steps),
        (-16_000, 16_000)
    );
    assert_eq!(config.joints[0].max_step_rate_hz, 20_000);
    assert_eq!(config.joints[1], ArmConfig::unlimited(2, 100_000).joints[1]);
    let narrow = config.within(&[JointLimits {
        min: 0,
        max: 50_000,
        max_rate_hz: 30_000,
    }]);
    assert_eq!(
        (narrow.joints[0].min_steps, narrow.joints[0].max_steps),
        (0, 16_000)
    );
    assert_eq!(narrow.joints[0].max_step_rate_hz, 20_000);
}

/// Issue 31: a refusal names the joint by its config name, the point's time, the values
/// in the user's units as well as steps, and for a step rate the slow-down that fits.
#[test]
fn refusals_speak_the_users_units_and_say_how_much_slower() {
    // As above: 150 steps in a 50 ms segment, 3000 steps/s against 2000.
    let text = trajectory(&[point(0, 0, 0.0, 0.0), point(0, 100_000_000, 0.3, 0.0)].join(","));
    let w = parse_joint_trajectory(&text, "fast.json", &config()).unwrap();
    let err = to_points(&w, &[100, 0, 0, 0, 0, 0, 0, 0], 50_000, &config(), None).unwrap_err();
    let message = err
        .in_units(&config(), crate::motion::Units::Deg)
        .to_string();
    assert!(message.contains("joint 0 (shoulder)"), "{message}");
    assert!(message.contains("(t = 0.050000 s)"), "{message}");
    // 3000 steps/s at 1000 steps/rad: 171.9 deg/s; the limit 2000: 114.6 deg/s.
    assert!(
        message.contains(
            "3000 steps/s (171.89 deg/s) exceeds the limit of 2000 steps/s (114.59 deg/s)"
        ),
        "{message}"
    );
    assert!(message.contains("needs 1.5x longer"), "{message}");
    let low = parse_csv("0,100,0\n1,-2101,0\n", "low.csv").unwrap();
    let err = to_points(&low, &[100, 0, 0, 0, 0, 0, 0, 0], 10_000, &config(), None).unwrap_err();
    let message = err
        .in_units(&config(), crate::motion::Units::Deg)
        .to_string();
    // Positions from the zero offset (100 steps): -2101 steps is -126.11 deg.
    assert!(
        message.contains(
            "position -2101 steps (-126.11 deg) is below the minimum -2000 steps (-120.32 deg)"
        ),
        "{message}"
    );
}

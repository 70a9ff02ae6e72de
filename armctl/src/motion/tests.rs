use super::*;

fn limit(rate: u32, accel: f64) -> JointLimit {
    JointLimit {
        min_steps: -10_000,
        max_steps: 10_000,
        max_rate_hz: rate,
        max_accel: accel,
    }
}

fn full() -> MoveSpeed {
    MoveSpeed {
        rate: 1.0,
        accel: 1.0,
    }
}

/// Per segment, per joint: steps per second.
fn rates(from: &[i32; 8], points: &[Point], joint: usize) -> Vec<f64> {
    let mut previous = from[joint];
    points
        .iter()
        .map(|p| {
            let r = f64::from((p.position[joint] - previous).abs()) * 1e6 / f64::from(p.duration);
            previous = p.position[joint];
            r
        })
        .collect()
}

#[test]
fn a_move_ends_exactly_at_the_target_and_never_breaks_a_rate() {
    let from = [0, 100, 0, 0, 0, 0, 0, 0];
    let to = [3000, -500, 0, 0, 0, 0, 0, 0];
    let limits = [limit(2000, 8000.0), limit(1000, 4000.0)];
    let points = plan_move(&from, &to, &limits, full(), 10_000).unwrap();
    assert_eq!(points.last().unwrap().position, to);
    assert!(
        points
            .iter()
            .all(|p| p.duration <= 10_000 && p.duration > 0)
    );
    for (j, l) in limits.iter().enumerate() {
        let r = rates(&from, &points, j);
        assert!(
            r.iter().all(|&r| r <= f64::from(l.max_rate_hz)),
            "joint {j}: {r:?}"
        );
    }
    // Joint 0 (3000 steps at 2000/s) needs longest: 1.5 s at full rate plus the ramps.
    let total: i64 = points.iter().map(|p| i64::from(p.duration)).sum();
    assert!((1_500_000..=2_400_000).contains(&total), "{total} us");
}

#[test]
fn joints_start_and_end_together_on_one_profile() {
    let from = [0; 8];
    let to = [1000, 250, 0, 0, 0, 0, 0, 0];
    let limits = [limit(5000, 20_000.0), limit(5000, 20_000.0)];
    let points = plan_move(&from, &to, &limits, full(), 5_000).unwrap();
    // Joint 1 is a quarter of joint 0 all along (to the rounding).
    for p in &points {
        let ratio_error = f64::from(p.position[1]) - f64::from(p.position[0]) / 4.0;
        assert!(ratio_error.abs() <= 1.0, "{:?}", &p.position[..2]);
    }
    assert!(points[0].position[1] > 0 || points[0].position[0] < 4);
}

#[test]
fn the_profile_speeds_up_and_slows_down_within_the_acceleration() {
    let from = [0; 8];
    let to = [4000, 0, 0, 0, 0, 0, 0, 0];
    let limits = [limit(2000, 4000.0)];
    let points = plan_move(&from, &to, &limits, full(), 10_000).unwrap();
    let r = rates(&from, &points, 0);
    // Slow at both ends, near the rate in the middle.
    assert!(r[0] < 200.0 && r[r.len() - 1] < 200.0, "{r:?}");
    let peak = r.iter().copied().fold(0.0, f64::max);
    assert!(peak > 1800.0 && peak <= 2000.0, "{peak}");
    // Rate change between segments within the acceleration (plus a step of rounding).
    for w in r.windows(2) {
        assert!((w[1] - w[0]).abs() <= 4000.0 * 0.01 + 2.0 * 100.0, "{w:?}");
    }
}

#[test]
fn half_speed_takes_longer() {
    let from = [0; 8];
    let to = [4000, 0, 0, 0, 0, 0, 0, 0];
    let limits = [limit(2000, 40_000.0)];
    let total = |speed| -> i64 {
        plan_move(&from, &to, &limits, speed, 10_000)
            .unwrap()
            .iter()
            .map(|p| i64::from(p.duration))
            .sum()
    };
    let half = MoveSpeed {
        rate: 0.5,
        accel: 1.0,
    };
    assert!(total(half) > total(full()) * 17 / 10);
}

#[test]
fn nothing_to_do_is_an_empty_plan() {
    let points = plan_move(&[5; 8], &[5; 8], &[limit(100, 100.0)], full(), 10_000).unwrap();
    assert!(points.is_empty());
}

#[test]
fn a_target_outside_the_range_is_refused_naming_joint_and_range() {
    let err = plan_move(
        &[0; 8],
        &[0, 20_000, 0, 0, 0, 0, 0, 0],
        &[limit(100, 100.0), limit(100, 100.0)],
        full(),
        10_000,
    )
    .unwrap_err();
    assert_eq!(
        err,
        MoveError::OutOfRange {
            joint: 1,
            target: 20_000,
            min: -10_000,
            max: 10_000
        }
    );
    assert_eq!(
        err.to_string(),
        "joint 1: target 20000 steps is outside its range -10000 to 10000 steps"
    );
}

#[test]
fn bad_speeds_and_joints_that_cannot_move_are_refused() {
    let to = [10, 0, 0, 0, 0, 0, 0, 0];
    let speed = MoveSpeed {
        rate: 1.5,
        accel: 1.0,
    };
    assert_eq!(
        plan_move(&[0; 8], &to, &[limit(100, 100.0)], speed, 10_000),
        Err(MoveError::BadSpeed(1.5))
    );
    assert_eq!(
        plan_move(&[0; 8], &to, &[limit(0, 100.0)], full(), 10_000),
        Err(MoveError::CannotMove { joint: 0 })
    );
}

#[test]
fn rounding_to_steps_never_breaks_the_hard_rate_even_with_short_segments() {
    // 1 ms segments at 1500 steps/s: 1.5 steps a segment, rounding gives 1 or 2.
    let from = [0; 8];
    let to = [3000, 0, 0, 0, 0, 0, 0, 0];
    let limits = [limit(1500, 1e9)];
    let points = plan_move(&from, &to, &limits, full(), 1_000).unwrap();
    assert!(rates(&from, &points, 0).iter().all(|&r| r <= 1500.0));
    assert_eq!(points.last().unwrap().position[0], 3000);
}

fn joint(spr: f64, zero: i32) -> JointConfig {
    JointConfig {
        name: Some("elbow".into()),
        steps_per_radian: spr,
        zero_offset_steps: zero,
        min_steps: -100_000,
        max_steps: 100_000,
        max_step_rate_hz: 1000,
        max_accel_steps_s2: None,
    }
}

#[test]
fn units_convert_with_the_calibration() {
    let j = joint(1000.0, 50);
    assert_eq!(Units::Steps.to_steps(12.0, &j), 12.0);
    assert!((Units::Rad.to_steps(1.0, &j) - 1050.0).abs() < 1e-9);
    assert!((Units::Deg.to_steps(180.0, &j) - (50.0 + 1000.0 * std::f64::consts::PI)).abs() < 1e-9);
    assert!((Units::Deg.from_steps(1050, &j) - 1f64.to_degrees()).abs() < 1e-9);
    assert_eq!(Units::Deg.show(50, &j), "0.00 deg");
    assert_eq!(Units::Deg.show(0, &joint(-1000.0, 0)), "0.00 deg");
    assert_eq!("degrees".parse::<Units>(), Ok(Units::Deg));
    assert!("furlongs".parse::<Units>().is_err());
}

#[test]
fn targets_by_order_by_index_by_name_and_relative() {
    let config = ArmConfig {
        units: Units::Deg,
        joints: vec![
            JointConfig {
                name: Some("base".into()),
                ..joint(1000.0, 0)
            },
            joint(-500.0, 10),
        ],
    };
    let current = [100, 20, 7, 0, 0, 0, 0, 0];
    let args: Vec<TargetArg> = ["90", "elbow=0"]
        .iter()
        .map(|s| s.parse().unwrap())
        .collect();
    let t = targets_in_steps(&args, Units::Deg, false, &current, 2, &config).unwrap();
    assert_eq!(t, [1571, 10, 7, 0, 0, 0, 0, 0]);
    let args: Vec<TargetArg> = ["1=-1"].iter().map(|s| s.parse().unwrap()).collect();
    let t = targets_in_steps(&args, Units::Rad, true, &current, 2, &config).unwrap();
    assert_eq!(t, [100, 520, 7, 0, 0, 0, 0, 0]);
    let args: Vec<TargetArg> = ["wrist=1"].iter().map(|s| s.parse().unwrap()).collect();
    let err = targets_in_steps(&args, Units::Deg, false, &current, 2, &config).unwrap_err();
    assert!(err.contains("base, elbow"), "{err}");
    let args: Vec<TargetArg> = ["1", "2", "3"].iter().map(|s| s.parse().unwrap()).collect();
    assert!(targets_in_steps(&args, Units::Steps, false, &current, 2, &config).is_err());
    assert!("x=abc".parse::<TargetArg>().is_err());
}

#[test]
fn limits_come_from_the_config_capped_by_the_controller() {
    let j = JointConfig {
        max_step_rate_hz: 5000,
        ..joint(1.0, 0)
    };
    let l = JointLimit::from_config(&j, Some(2000));
    assert_eq!(l.max_rate_hz, 2000);
    assert_eq!(l.max_accel, 2000.0 / DEFAULT_ACCEL_TIME_S);
    let j = JointConfig {
        max_accel_steps_s2: Some(123.0),
        ..j
    };
    assert_eq!(JointLimit::from_config(&j, None).max_accel, 123.0);
}

/// Issue 31: one range check for `armctl move` and Python's `move_to`, naming the joint as
/// the config does and speaking the user's units.
#[test]
fn a_target_out_of_range_is_named_and_shown_in_the_users_units() {
    let config = ArmConfig::parse(
        r#"{"units": "deg", "joints": [{"steps_per_radian": 1000, "max_step_rate_hz": 4000},
            {"name": "elbow", "steps_per_radian": 1000, "max_step_rate_hz": 4000,
             "min_steps": -785, "max_steps": 785}]}"#,
        "arm.json",
    )
    .unwrap();
    let limits = JointLimit::all(&config, None);
    let mut target = [0; MAX_JOINTS];
    assert_eq!(check_targets(&target, &limits, &config, Units::Deg), Ok(()));
    target[1] = 873;
    assert_eq!(
        check_targets(&target, &limits, &config, Units::Deg),
        Err(
            "elbow: target 50.02 deg (873 steps) is outside its range -44.98 deg to 44.98 deg \
             (-785 to 785 steps)"
                .into()
        )
    );
    assert_eq!(
        check_targets(&target, &limits, &config, Units::Steps),
        Err("elbow: target 873 steps is outside its range -785 steps to 785 steps".into())
    );
}

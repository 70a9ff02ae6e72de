//! [`Waypoints`] to controller [`Point`]s: segments that end on every waypoint and are no
//! longer than the segment duration asked for, linear or cubic Hermite between waypoints,
//! checked against joint limits and step rates; and [`check_waypoints`], which proves a
//! plan passes every waypoint at its time.

use protocol::{MAX_JOINTS, Point};

use super::{ArmConfig, ErrorKind, TrajectoryError, Waypoints};
use crate::run::MAX_POINTS;

/// Resamples `waypoints` into points from the arm's current position `current`: each span
/// between two waypoints in the fewest equal segments no longer than `segment_us`, so every
/// waypoint is a segment's end and is reached at its time (to the whole step). Checks every
/// position against the joint limits of `config` and every segment against the lower of the
/// joint's and the controller's (`controller_max_rate_hz`) step rate, and the result with
/// [`check_waypoints`].
pub fn to_points(
    waypoints: &Waypoints,
    current: &[i32; MAX_JOINTS],
    segment_us: u32,
    config: &ArmConfig,
    controller_max_rate_hz: Option<u32>,
) -> Result<Vec<Point>, TrajectoryError> {
    let file = waypoints.file.as_str();
    if segment_us == 0 {
        return Err(TrajectoryError::new(file, ErrorKind::BadSegment));
    }
    let joints = waypoints
        .positions
        .first()
        .map_or(0, Vec::len)
        .min(MAX_JOINTS);
    if joints != config.joints.len() {
        return Err(TrajectoryError::new(
            file,
            ErrorKind::WrongJointCount {
                found: joints,
                expected: config.joints.len(),
            },
        ));
    }
    // Waypoints in whole-number steps (held joints at the current position), with the
    // current position prepended at t = 0 when the file starts later.
    let mut times = Vec::with_capacity(waypoints.times_us.len() + 1);
    let mut rows: Vec<[f64; MAX_JOINTS]> = Vec::with_capacity(times.capacity());
    // Steps per second where given (Hermite segments), `None` where not (straight lines).
    let mut speeds: Vec<[Option<f64>; MAX_JOINTS]> = Vec::with_capacity(times.capacity());
    if waypoints.times_us[0] > 0 {
        times.push(0);
        rows.push(current.map(f64::from));
        speeds.push([None; MAX_JOINTS]);
    }
    for (i, (&t, row)) in waypoints
        .times_us
        .iter()
        .zip(&waypoints.positions)
        .enumerate()
    {
        let mut steps = current.map(f64::from);
        let mut speed = [None; MAX_JOINTS];
        for (j, value) in row.iter().enumerate().take(joints) {
            if let Some(v) = value {
                steps[j] = *v;
                speed[j] = waypoints
                    .velocities
                    .get(i)
                    .and_then(|r| r.get(j))
                    .copied()
                    .flatten();
            }
            let position = steps[j].round() as i64;
            let limits = &config.joints[j];
            if position < i64::from(limits.min_steps) {
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::BelowMin {
                        value: position,
                        limit: limits.min_steps,
                    },
                )
                .at(i, t, Some(j)));
            }
            if position > i64::from(limits.max_steps) {
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::AboveMax {
                        value: position,
                        limit: limits.max_steps,
                    },
                )
                .at(i, t, Some(j)));
            }
            if t == 0 && position != i64::from(current[j]) {
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::StartMismatch {
                        current: current[j],
                        start: position,
                    },
                )
                .at(i, t, Some(j)));
            }
        }
        times.push(t);
        rows.push(steps);
        speeds.push(speed);
    }
    let total_us = *times.last().unwrap_or(&0);
    if times.len() < 2 || total_us <= 0 {
        return Err(TrajectoryError::new(file, ErrorKind::TooShort));
    }
    let intervals: Vec<i64> = times.windows(2).map(|t| t[1] - t[0]).collect();
    if intervals.len() > MAX_POINTS {
        return Err(TrajectoryError::new(
            file,
            ErrorKind::TooManyWaypoints {
                count: intervals.len(),
            },
        ));
    }
    let count = points_for(&intervals, i64::from(segment_us));
    if count > MAX_POINTS {
        return Err(TrajectoryError::new(
            file,
            ErrorKind::TooManyPoints {
                count,
                min_segment_us: shortest_segment_that_fits(&intervals),
            },
        ));
    }
    let segment = i64::from(segment_us);
    // Segment ends: every waypoint is one, and each span between two waypoints is cut into
    // the fewest equal pieces no longer than `segment` (to the microsecond), so no waypoint
    // falls inside a segment and is cut off.
    let mut ends: Vec<(usize, i64)> = Vec::with_capacity(count);
    for (w, &d) in intervals.iter().enumerate() {
        let n = (d + segment - 1) / segment;
        ends.extend((1..=n).map(|k| (w, times[w] + d * k / n)));
    }
    let mut points = Vec::with_capacity(count);
    let mut previous = *current;
    let mut previous_t = 0i64;
    for (w, t) in ends {
        let (t0, t1) = (times[w], times[w + 1]);
        let f = (t - t0) as f64 / (t1 - t0) as f64;
        let segment_s = (t1 - t0) as f64 / 1e6;
        let mut target = previous;
        for j in 0..joints {
            let (p0, p1) = (rows[w][j], rows[w + 1][j]);
            let p = match (speeds[w][j], speeds[w + 1][j]) {
                (Some(v0), Some(v1)) => hermite(p0, v0 * segment_s, p1, v1 * segment_s, f),
                _ => p0 + (p1 - p0) * f,
            };
            target[j] = p.round().clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32;
        }
        let duration = (t - previous_t) as u32;
        let index = points.len();
        for (j, limits) in config.joints.iter().enumerate() {
            // Waypoints are checked above; a Hermite curve can overshoot between them.
            if target[j] < limits.min_steps {
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::BelowMin {
                        value: i64::from(target[j]),
                        limit: limits.min_steps,
                    },
                )
                .at(index, t, Some(j)));
            }
            if target[j] > limits.max_steps {
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::AboveMax {
                        value: i64::from(target[j]),
                        limit: limits.max_steps,
                    },
                )
                .at(index, t, Some(j)));
            }
            let limit_hz = controller_max_rate_hz
                .map_or(limits.max_step_rate_hz, |c| c.min(limits.max_step_rate_hz));
            let steps = (i64::from(target[j]) - i64::from(previous[j])).unsigned_abs();
            // steps / duration > limit, in integers.
            if u128::from(steps) * 1_000_000 > u128::from(limit_hz) * u128::from(duration) {
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::StepRate {
                        steps,
                        duration_us: duration,
                        limit_hz,
                    },
                )
                .at(index, t, Some(j)));
            }
        }
        points.push(Point::from_motion(duration as i32, &previous, &target));
        previous = target;
        previous_t = t;
    }
    check_waypoints(&points, waypoints, current)?;
    Ok(points)
}

/// Checks that `points`, run from `current`, pass every one of `waypoints` at its time:
/// some point ends exactly at the waypoint's time, at its positions rounded to whole steps
/// (joints the file leaves out: where they were). Returns how many waypoints were checked;
/// the error names the first one missed, the joint and both positions.
pub fn check_waypoints(
    points: &[Point],
    waypoints: &Waypoints,
    current: &[i32; MAX_JOINTS],
) -> Result<usize, TrajectoryError> {
    let file = waypoints.file.as_str();
    let mut ends = points.iter().scan(0i64, |t, p| {
        *t += i64::from(p.duration);
        Some((*t, p.position))
    });
    for (i, (&t, row)) in waypoints
        .times_us
        .iter()
        .zip(&waypoints.positions)
        .enumerate()
    {
        let reached = if t == 0 {
            Some(*current)
        } else {
            ends.by_ref()
                .find(|&(end, _)| end >= t)
                .filter(|&(end, _)| end == t)
                .map(|(_, position)| position)
        };
        let Some(position) = reached else {
            return Err(
                TrajectoryError::new(file, ErrorKind::WaypointMissed { planned: None })
                    .at(i, t, None),
            );
        };
        for (j, value) in row.iter().enumerate().take(MAX_JOINTS) {
            let wanted = value.map_or(i64::from(current[j]), |v| v.round() as i64);
            if i64::from(position[j]) != wanted {
                return Err(TrajectoryError::new(
                    file,
                    ErrorKind::WaypointMissed {
                        planned: Some((i64::from(position[j]), wanted)),
                    },
                )
                .at(i, t, Some(j)));
            }
        }
    }
    Ok(waypoints.times_us.len())
}

/// Points the spans between waypoints (`intervals`, microseconds) take at segments of at
/// most `segment_us`: each span in the fewest equal pieces.
fn points_for(intervals: &[i64], segment_us: i64) -> usize {
    intervals
        .iter()
        .map(|&d| ((d + segment_us - 1) / segment_us) as usize)
        .sum()
}

/// The shortest segment duration (microseconds) at which `intervals` take at most
/// [`MAX_POINTS`] points (the caller has checked that one point per span fits).
fn shortest_segment_that_fits(intervals: &[i64]) -> u64 {
    let (mut fits, mut too_short) = (intervals.iter().copied().max().unwrap_or(1).max(1), 0i64);
    while fits - too_short > 1 {
        let mid = too_short + (fits - too_short) / 2;
        if points_for(intervals, mid) <= MAX_POINTS {
            fits = mid;
        } else {
            too_short = mid;
        }
    }
    fits as u64
}

/// The cubic Hermite curve from `p0` to `p1` at `f` in 0..=1, with the end tangents `m0`
/// and `m1` already scaled to the segment (velocity times its duration).
fn hermite(p0: f64, m0: f64, p1: f64, m1: f64, f: f64) -> f64 {
    let f2 = f * f;
    let f3 = f2 * f;
    (2.0 * f3 - 3.0 * f2 + 1.0) * p0
        + (f3 - 2.0 * f2 + f) * m0
        + (-2.0 * f3 + 3.0 * f2) * p1
        + (f3 - f2) * m1
}

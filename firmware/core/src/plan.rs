//! RETURN's motion planner: every joint to zero along one shared trapezoidal velocity
//! profile, sampled into ordinary trajectory points.
//!
//! All joints follow the same normalised path `s(t)` (0 to 1), joint `j` being at
//! `start_j * (1 - s(t))`; so they move in proportion and finish together. The profile's
//! peak speed and acceleration are the largest every joint can follow within its limits:
//! `v = min_j(vmax_j / |start_j|)`, `a = min_j(amax_j / |start_j|)`. When the path is too
//! short to reach `v`, the profile is a triangle.
//!
//! Every point lasts the same time (`return_segment_us`, lengthened if the move would need
//! more than 65535 points); positions are the ideal ones rounded to whole steps, so a
//! segment's step count is the floor or the ceiling of the ideal one. The speed limit used
//! is rounded down to whole steps per segment, so a joint's steps in a segment never
//! exceed its limit; the change of its steps per segment from one segment to the next
//! exceeds `amax * segment^2` by at most 2 steps (rounding of two positions).

// `core` has no square root on no_std targets; libm's is correctly rounded.
#[cfg(not(feature = "fpu-sqrt"))]
use libm::sqrt;
use protocol::MAX_JOINTS;

use crate::buffer::StoredPoint;
use crate::config::ControllerConfig;

/// The square root by the FPU's `vsqrt.f64` (feature `fpu-sqrt`: Cortex-M7 boards built
/// with `target-cpu=cortex-m7`, whose FPU has double precision): correctly rounded as IEEE
/// 754 requires, so the same value as libm's, without libm's code and table (306 bytes).
#[cfg(feature = "fpu-sqrt")]
fn sqrt(x: f64) -> f64 {
    let root: f64;
    // SAFETY: one FPU instruction on the register the asm names; no memory, no stack.
    unsafe {
        core::arch::asm!(
            "vsqrt.f64 d0, d0",
            inout("d0") x => root,
            options(pure, nomem, nostack)
        )
    };
    root
}

/// Most points a RETURN may have: its count is reported where NEW's would be (u16).
pub const MAX_RETURN_POINTS: u64 = protocol::limits::MAX_POINTS_PER_NEW as u64;

/// A planned RETURN: produces its points one by one (the buffer is filled as it drains,
/// so a long return needs no more room than a streamed upload).
#[derive(Clone, Debug, PartialEq)]
pub struct ReturnPlan {
    start: [i32; MAX_JOINTS],
    joints: usize,
    segment_us: u32,
    count: u32,
    next: u32,
    /// Normalised acceleration, 1/s^2.
    accel: f64,
    /// Normalised peak speed, 1/s.
    peak: f64,
    /// Acceleration phase, s.
    t_accel: f64,
    /// Constant speed phase, s.
    t_cruise: f64,
}

/// Plans the move of joints `0..joints` from `start` to zero (joints `>= joints` keep
/// their positions). A move of nothing has no points.
pub fn plan_return(start: [i32; MAX_JOINTS], joints: u8, config: &ControllerConfig) -> ReturnPlan {
    let joints = usize::from(joints).min(MAX_JOINTS);
    let segment_us = config.return_segment_us.max(1);
    let mut plan = ReturnPlan {
        start,
        joints,
        segment_us,
        count: 0,
        next: 0,
        accel: 0.0,
        peak: 0.0,
        t_accel: 0.0,
        t_cruise: 0.0,
    };
    // Rounded positions make a segment's step count the floor or the ceiling of the ideal
    // one, so the ideal speed is held to a whole number of steps per segment.
    let segment_s = f64::from(segment_us) / 1e6;
    let mut speed = f64::INFINITY;
    let mut accel = f64::INFINITY;
    let limits = config.return_speed.iter().zip(&config.return_accel);
    for (&from, (&speed_limit, &accel_limit)) in start.iter().zip(limits).take(joints) {
        let distance = i64::from(from).unsigned_abs() as f64;
        if distance == 0.0 {
            continue;
        }
        let vmax = f64::from(speed_limit.min(config.max_step_rate_hz).max(1));
        let whole_steps = floor(vmax * segment_s);
        let vmax = if whole_steps >= 1.0 {
            whole_steps / segment_s
        } else {
            vmax
        };
        let amax = f64::from(accel_limit.max(1));
        speed = speed.min(vmax / distance);
        accel = accel.min(amax / distance);
    }
    if speed == f64::INFINITY {
        return plan;
    }
    // Distance (normalised) needed to reach `speed` and brake again: v^2 / a.
    let (t_accel, t_cruise, peak) = if speed * speed / accel >= 1.0 {
        let t = sqrt(1.0 / accel);
        (t, 0.0, accel * t)
    } else {
        let t = speed / accel;
        (t, (1.0 - speed * t) / speed, speed)
    };
    let total_us = ceil_u64((2.0 * t_accel + t_cruise) * 1e6).max(1);
    // Lengthen the points rather than exceed the count a u16 can report.
    let segment_us = u64::from(segment_us).max(total_us.div_ceil(MAX_RETURN_POINTS));
    plan.segment_us = u32::try_from(segment_us).unwrap_or(u32::MAX);
    plan.count = u32::try_from(total_us.div_ceil(u64::from(plan.segment_us))).unwrap_or(u32::MAX);
    plan.accel = accel;
    plan.peak = peak;
    plan.t_accel = t_accel;
    plan.t_cruise = t_cruise;
    plan
}

impl ReturnPlan {
    /// Points of the whole move.
    pub fn total_points(&self) -> u32 {
        self.count
    }

    /// Length of every point, microseconds.
    pub fn segment_us(&self) -> u32 {
        self.segment_us
    }

    /// The normalised path `s(t)`, 0..=1, at `t` seconds after the start.
    pub fn progress(&self, t: f64) -> f64 {
        let total = 2.0 * self.t_accel + self.t_cruise;
        if self.count == 0 || t >= total {
            return 1.0;
        }
        if t <= 0.0 {
            return 0.0;
        }
        if t < self.t_accel {
            0.5 * self.accel * t * t
        } else if t < self.t_accel + self.t_cruise {
            0.5 * self.accel * self.t_accel * self.t_accel + self.peak * (t - self.t_accel)
        } else {
            let left = total - t;
            1.0 - 0.5 * self.accel * left * left
        }
    }

    /// Point `k` (0-based) of the move.
    pub fn point(&self, k: u32) -> Option<StoredPoint> {
        if k >= self.count {
            return None;
        }
        let t = f64::from(k + 1) * f64::from(self.segment_us) / 1e6;
        let left = 1.0 - self.progress(t);
        let mut position = self.start;
        for (p, &from) in position.iter_mut().zip(&self.start).take(self.joints) {
            *p = if k + 1 == self.count {
                0
            } else {
                round_i32(f64::from(from) * left)
            };
        }
        Some(StoredPoint {
            duration_us: self.segment_us,
            position,
        })
    }
}

impl Iterator for ReturnPlan {
    type Item = StoredPoint;
    fn next(&mut self) -> Option<StoredPoint> {
        let p = self.point(self.next)?;
        self.next += 1;
        Some(p)
    }
}

// Float-to-integer `as` saturates (and NaN gives 0): these helpers rely on it, and their
// callers keep the values in range.
#[allow(
    clippy::cast_possible_truncation,
    reason = "float to integer `as` saturates"
)]
fn floor(x: f64) -> f64 {
    if x <= 0.0 { 0.0 } else { (x as u64) as f64 }
}

#[allow(
    clippy::cast_possible_truncation,
    reason = "float to integer `as` saturates"
)]
fn ceil_u64(x: f64) -> u64 {
    if x <= 0.0 {
        return 0;
    }
    let t = x as u64;
    if (t as f64) < x { t + 1 } else { t }
}

#[allow(
    clippy::cast_possible_truncation,
    reason = "float to integer `as` saturates"
)]
fn round_i32(x: f64) -> i32 {
    if x >= 0.0 {
        (x + 0.5) as i32
    } else {
        -((-x + 0.5) as i32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec::Vec;

    fn config() -> ControllerConfig {
        ControllerConfig {
            return_speed: [4000, 2000, 8000, 1000, 4000, 4000, 4000, 4000],
            return_accel: [8000, 3000, 20000, 500, 8000, 8000, 8000, 8000],
            ..ControllerConfig::BOARD
        }
    }

    /// Checks every produced point against the limits; returns the points.
    fn check(start: [i32; MAX_JOINTS], joints: u8, config: &ControllerConfig) -> Vec<StoredPoint> {
        let plan = plan_return(start, joints, config);
        let points: Vec<_> = plan.clone().collect();
        assert_eq!(points.len(), plan.total_points() as usize);
        let seg = f64::from(plan.segment_us()) / 1e6;
        let mut prev = start;
        let mut prev_steps = [0i64; MAX_JOINTS];
        for (k, p) in points.iter().enumerate() {
            assert_eq!(p.duration_us, plan.segment_us());
            for j in 0..MAX_JOINTS {
                let steps = i64::from(p.position[j]) - i64::from(prev[j]);
                if j >= usize::from(joints) {
                    assert_eq!(steps, 0, "joint {j} is not in use");
                    continue;
                }
                let vmax = f64::from(config.return_speed[j].min(config.max_step_rate_hz));
                assert!(
                    steps.unsigned_abs() as f64 <= vmax * seg + 1e-9,
                    "point {k} joint {j}: {steps} steps exceed {vmax} steps/s"
                );
                assert!(
                    steps * i64::from(start[j]).signum() <= 0,
                    "moves toward zero only"
                );
                let amax = f64::from(config.return_accel[j]);
                let dv = (steps - prev_steps[j]).unsigned_abs() as f64;
                assert!(
                    dv <= amax * seg * seg + 2.0 + 1e-9,
                    "point {k} joint {j}: speed change {dv} steps/segment exceeds {amax} steps/s^2"
                );
                prev_steps[j] = steps;
            }
            prev = p.position;
        }
        points
    }

    #[test]
    fn every_joint_ends_at_zero_within_limits() {
        let start = [12_000, -3_000, 40_000, 800, -1, 0, 77, 5];
        let points = check(start, 6, &config());
        let last = points.last().copied().unwrap_or_default();
        assert_eq!(last.position, [0, 0, 0, 0, 0, 0, 77, 5]);
    }

    #[test]
    fn joints_move_in_proportion_and_finish_together() {
        let start = [20_000, -10_000, 5_000, 0, 0, 0, 0, 0];
        let points = check(start, 3, &config());
        for p in &points {
            let f0 = f64::from(p.position[0]) / 20_000.0;
            for (j, d) in [(1, -10_000.0), (2, 5_000.0)] {
                let f = f64::from(p.position[j]) / d;
                assert!(
                    (f - f0).abs() <= 0.5 / 20_000.0 + 0.5 / d.abs() + 1e-12,
                    "joint {j} at fraction {f}, joint 0 at {f0}"
                );
            }
        }
        // Each joint is still moving in the last fifth of the move.
        let tail = &points[points.len() * 4 / 5..];
        for j in 0..3 {
            assert!(
                tail.windows(2)
                    .any(|w| w[0].position[j] != w[1].position[j])
            );
        }
    }

    #[test]
    fn the_slowest_joint_sets_the_pace_and_reaches_its_limit() {
        // Joint 3 (1000 steps/s, 500 steps/s^2) is the limit: 10 000 steps need
        // 2 s of acceleration, 8 s at speed, 2 s of braking.
        let start = [1000, 0, 0, 10_000, 0, 0, 0, 0];
        let cfg = config();
        let points = check(start, 4, &cfg);
        let t = points.len() as f64 * f64::from(cfg.return_segment_us) / 1e6;
        assert!((12.0..12.5).contains(&t), "took {t} s");
        let fastest = points
            .windows(2)
            .map(|w| (w[0].position[3] - w[1].position[3]).abs())
            .max()
            .unwrap_or(0);
        assert!(
            (9..=10).contains(&fastest),
            "peak {fastest} steps per 10 ms"
        );
    }

    #[test]
    fn short_moves_are_triangles_and_nothing_to_do_is_empty() {
        let cfg = config();
        let points = check([3, 0, 0, 0, 0, 0, 0, 0], 6, &cfg);
        assert!(!points.is_empty());
        assert_eq!(plan_return([0; 8], 6, &cfg).total_points(), 0);
        assert_eq!(
            plan_return([0, 0, 0, 0, 0, 0, 9, 9], 6, &cfg).total_points(),
            0
        );
    }

    #[test]
    fn huge_moves_stay_within_a_u16_point_count() {
        let cfg = ControllerConfig {
            return_speed: [10; 8],
            return_accel: [10; 8],
            ..ControllerConfig::BOARD
        };
        let plan = plan_return([i32::MAX, i32::MIN, 0, 0, 0, 0, 0, 0], 2, &cfg);
        assert!(plan.total_points() as u64 <= MAX_RETURN_POINTS);
        assert_eq!(
            plan.point(plan.total_points() - 1)
                .map(|p| p.position[..2].to_vec()),
            Some(vec![0, 0])
        );
    }

    #[test]
    fn sqrt_is_accurate() {
        for x in [1e-9, 0.25, 2.0, 1e6, 3.3e12] {
            let r = sqrt(x);
            assert!((r * r - x).abs() <= x * 1e-12, "{x}");
        }
    }
}

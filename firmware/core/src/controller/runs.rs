//! Runs: points admitted into the buffer, fed to the engine, finished; RETURN's encoder
//! read and plan (see "Runs, reports and flags" in [`crate::controller`]).

use arm_step::Segment;
use protocol::{Location, MAX_JOINTS, Refusal, RefusalReason, State, StopCause, StopReport};

use super::Controller;
use crate::buffer::StoredPoint;
use crate::hw::EncoderFault;
use crate::plan::plan_return;
use crate::plant::Plant;

impl<const CAP: usize> Controller<CAP> {
    /// The stored form of `point` after `previous`, if it obeys docs/PROTOCOL.md ("Point",
    /// "Step rate budget", LIMITS_SET): for every joint in use, an end position inside
    /// its range, at most its own and the controller's `max_step_rate_hz` steps per
    /// second and a step count that fits a segment, and all joints together at most
    /// `step_budget_hz` steps per second; else why not (`seq`, `tag` and `point` left 0
    /// for the caller). Joints not in use keep their previous position.
    pub(super) fn admit(
        &self,
        previous: &[i32; MAX_JOINTS],
        point: &protocol::Point,
    ) -> Result<StoredPoint, Refusal> {
        let refusal = |joint: usize, reason, value: i64, limit: i64| Refusal {
            joint: u8::try_from(joint).unwrap_or(u8::MAX),
            reason,
            value: saturate_i32(value),
            limit: saturate_i32(limit),
            ..Refusal::default()
        };
        let Some(duration) = u32::try_from(point.duration).ok().filter(|d| *d >= 1) else {
            return Err(refusal(
                0,
                RefusalReason::Duration,
                point.duration.into(),
                1,
            ));
        };
        let joints = usize::from(self.settings.joints).min(MAX_JOINTS);
        let mut position = *previous;
        let mut total_steps = 0u64;
        let board_hz = self.config.max_step_rate_hz;
        for (j, ((p, &to), limits)) in position
            .iter_mut()
            .zip(&point.position)
            .zip(&self.settings.limits)
            .enumerate()
            .take(joints)
        {
            if to < limits.min {
                return Err(refusal(
                    j,
                    RefusalReason::BelowMin,
                    to.into(),
                    limits.min.into(),
                ));
            }
            if to > limits.max {
                return Err(refusal(
                    j,
                    RefusalReason::AboveMax,
                    to.into(),
                    limits.max.into(),
                ));
            }
            let steps = point.steps(previous, j).unsigned_abs();
            // A limp joint does not move (issue 31): its steps would reach a disabled
            // driver while the controller counts them, and STATUS would show it where it
            // is not.
            if steps > 0 && self.enabled & (1 << j) == 0 {
                return Err(refusal(
                    j,
                    RefusalReason::JointDisabled,
                    to.into(),
                    previous.get(j).copied().unwrap_or(0).into(),
                ));
            }
            total_steps += steps;
            if steps > i32::MAX as u64 {
                return Err(refusal(
                    j,
                    RefusalReason::Duration,
                    i64::MAX,
                    i32::MAX.into(),
                ));
            }
            // steps < 2^31 and duration < 2^31: the products fit u64.
            let rate_hz = limits.rate_hz(board_hz);
            if steps * 1_000_000 > u64::from(rate_hz) * u64::from(duration) {
                let reason = if rate_hz < board_hz {
                    RefusalReason::JointRate
                } else {
                    RefusalReason::BoardRate
                };
                let asked = steps * 1_000_000 / u64::from(duration);
                return Err(refusal(
                    j,
                    reason,
                    i64::try_from(asked).unwrap_or(i64::MAX),
                    rate_hz.into(),
                ));
            }
            *p = to;
        }
        // total_steps < 2^34: the product fits u64.
        let budget = u64::from(self.step_budget_hz);
        if budget > 0 && total_steps * 1_000_000 > budget * u64::from(duration) {
            let asked = total_steps * 1_000_000 / u64::from(duration);
            return Err(Refusal {
                joint: u8::MAX,
                ..refusal(
                    0,
                    RefusalReason::StepBudget,
                    i64::try_from(asked).unwrap_or(i64::MAX),
                    i64::from(self.step_budget_hz),
                )
            });
        }
        Ok(StoredPoint {
            duration_us: duration,
            position,
        })
    }

    /// The first joint in use whose driver is disabled and that is not at `target`, as a
    /// refusal (RETURN: a limp joint does not move, issue 31).
    pub(super) fn limp_and_away(
        &self,
        from: &[i32; MAX_JOINTS],
        target: &[i32; MAX_JOINTS],
    ) -> Option<Refusal> {
        let joints = usize::from(self.settings.joints).min(MAX_JOINTS);
        let (j, (&at, &to)) = from
            .iter()
            .zip(target)
            .enumerate()
            .take(joints)
            .find(|(j, (at, to))| self.enabled & (1 << j) == 0 && at != to)?;
        Some(Refusal {
            joint: u8::try_from(j).unwrap_or(u8::MAX),
            reason: RefusalReason::JointDisabled,
            value: to,
            limit: at,
            ..Refusal::default()
        })
    }

    /// The first joint in use whose range `position` leaves, as a refusal (RETURN's
    /// target, LOCATION_SETTING's positions).
    pub(super) fn outside_limits(&self, position: &[i32; MAX_JOINTS]) -> Option<Refusal> {
        let joints = usize::from(self.settings.joints).min(MAX_JOINTS);
        let (j, (&p, limits)) = position
            .iter()
            .zip(&self.settings.limits)
            .enumerate()
            .take(joints)
            .find(|(_, (p, l))| !l.contains(**p))?;
        let (reason, limit) = if p < limits.min {
            (RefusalReason::BelowMin, limits.min)
        } else {
            (RefusalReason::AboveMax, limits.max)
        };
        Some(Refusal {
            joint: u8::try_from(j).unwrap_or(u8::MAX),
            reason,
            value: p,
            limit,
            ..Refusal::default()
        })
    }

    /// Hands as many buffered points to the engine as it takes (and, during RETURN, tops
    /// the buffer up from the plan first).
    pub fn pump(&mut self, plant: &mut impl Plant) {
        if let Some(plan) = self.return_plan.as_mut() {
            while self.buffer.free() > 0 {
                let Some(point) = plan.next() else { break };
                if self.buffer.push(point) {
                    self.received += 1;
                }
            }
        }
        if !matches!(self.state, State::Pending | State::Running) {
            return;
        }
        while let Some(point) = self.buffer.next_unfed() {
            let mut steps = [0i32; MAX_JOINTS];
            for ((s, &to), &from) in steps.iter_mut().zip(&point.position).zip(&self.fed_end) {
                let delta = i64::from(to) - i64::from(from);
                *s = i32::try_from(delta).unwrap_or(if delta < 0 { i32::MIN } else { i32::MAX });
            }
            let segment = Segment {
                duration_us: point.duration_us,
                steps,
            };
            if !plant.push_segment(segment) {
                break;
            }
            self.buffer.mark_fed();
            self.fed_end = point.position;
        }
    }

    /// The engine finished `finished` more segments and, if `ran_dry`, ran out of them
    /// and stopped. Ends the run (completion or underrun) when it ran dry, feeds more
    /// points otherwise. Returns a LOCATION report when the state changed.
    pub fn on_step_progress(
        &mut self,
        finished: u32,
        ran_dry: bool,
        plant: &mut impl Plant,
    ) -> Option<Location> {
        if self.homing() {
            // A homing move is one segment of its own (controller/homing_run.rs).
            return if ran_dry {
                self.homing_ran_dry(plant)
            } else {
                None
            };
        }
        let done = self.buffer.finish(finished as usize);
        self.executed = self
            .executed
            .saturating_add(u32::try_from(done).unwrap_or(u32::MAX));
        if ran_dry && self.state == State::Running && !self.return_pending {
            let complete = self.executed >= self.expected;
            // Clears anything pushed after the engine went idle.
            plant.stop();
            self.buffer.clear();
            self.return_plan = None;
            self.stop = if complete {
                StopReport::of(StopCause::Complete)
            } else {
                StopReport {
                    detail: u8::from(self.motion.underrun),
                    ..StopReport::of(StopCause::Underrun)
                }
            };
            self.motion.underrun = false;
            self.state = State::Stopped;
            self.claimer_heard_at_run_end();
            return self.reports_on.then(|| self.location(plant));
        }
        self.pump(plant);
        self.watch_underrun(plant);
        None
    }

    /// Ends an accepted RETURN whose encoder read failed: nothing moves, the state goes
    /// back to STOPPED (neither underrun nor STOPPED-by-host: the run never started) and
    /// the fault is kept for [`Controller::return_fault`]. Returns a LOCATION report when
    /// the state changed (reports on).
    pub fn fail_return(&mut self, fault: EncoderFault, plant: &mut impl Plant) -> Option<Location> {
        if !self.return_pending || self.state != State::Running {
            return None;
        }
        self.return_pending = false;
        self.return_plan = None;
        self.buffer.clear();
        // A RETURN of no points: STATUS shows expected = executed = 0, not the last run's.
        self.expected = 0;
        self.received = 0;
        self.executed = 0;
        self.stop = StopReport {
            detail: fault.joint,
            ..StopReport::of(StopCause::Fault)
        };
        self.return_fault = Some(fault);
        self.state = State::Stopped;
        self.reports_on.then(|| self.location(plant))
    }

    /// Why the last RETURN was refused after its ACK (`None`: it was not, or no RETURN
    /// since boot).
    pub fn return_fault(&self) -> Option<EncoderFault> {
        self.return_fault
    }

    /// Continues an accepted RETURN with the encoder reading (`None`: no encoders, trust
    /// the step count): corrects the positions of the joints in use if they differ, plans
    /// the move to zero and starts it. Returns a LOCATION report when the state changed
    /// (nothing to move: back to STOPPED).
    pub fn begin_return(
        &mut self,
        encoders: Option<[i32; MAX_JOINTS]>,
        plant: &mut impl Plant,
    ) -> Option<Location> {
        if !self.return_pending || self.state != State::Running {
            return None;
        }
        self.return_pending = false;
        let joints = usize::from(self.settings.joints).min(MAX_JOINTS);
        let mut start = plant.positions();
        if let Some(read) = encoders {
            let mut corrected = start;
            for (c, r) in corrected.iter_mut().zip(read).take(joints) {
                *c = r;
            }
            if corrected != start && plant.set_positions(corrected) {
                start = corrected;
            }
        }
        // Each joint's own rate limit (LIMITS_SET) bounds its RETURN speed too.
        let mut config = self.config;
        for (speed, limits) in config.return_speed.iter_mut().zip(&self.settings.limits) {
            *speed = (*speed).min(limits.rate_hz(self.config.max_step_rate_hz));
        }
        let plan = plan_return(start, self.settings.joints, &config);
        self.buffer.clear();
        self.expected = plan.total_points();
        self.received = 0;
        self.executed = 0;
        self.received_end = start;
        self.fed_end = start;
        if plan.total_points() == 0 {
            self.state = State::Stopped;
            return self.reports_on.then(|| self.location(plant));
        }
        self.return_plan = Some(plan);
        self.pump(plant);
        // The controller's own move: at 100 %, never held from before.
        self.motion.held = false;
        self.motion.underrun = false;
        self.motion.warped = false;
        plant.set_start_rate(arm_step::RATE_ONE);
        plant.start();
        None
    }
}

fn saturate_i32(v: i64) -> i32 {
    i32::try_from(v).unwrap_or(if v < 0 { i32::MIN } else { i32::MAX })
}

/// The last point taken, as a segment: what the acceleration check (ACCEL_SET, issue 31)
/// compares the next one with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LastSegment {
    /// Each joint's steps (signed).
    pub(super) steps: [i32; MAX_JOINTS],
    /// Its duration; 0: rest (a trajectory's start).
    pub(super) duration_us: u32,
}

impl LastSegment {
    /// At rest: before a trajectory's first point.
    pub const REST: LastSegment = LastSegment {
        steps: [0; MAX_JOINTS],
        duration_us: 0,
    };
}

/// The acceleration, steps/s², from a segment of `s0` steps in `d0` us to one of `s1` in
/// `d1` (docs/PROTOCOL.md, ACCEL_SET): the change of rate over the time between the two
/// segments' midpoints, less one step of rounding in each segment's rate. A duration of
/// 0 is rest (rate 0, no length). 0 when within the rounding.
pub(super) fn acceleration(s0: i32, d0: u32, s1: i32, d1: u32) -> u128 {
    let (s0, d0, s1, d1) = (
        i128::from(s0),
        i128::from(d0),
        i128::from(s1),
        i128::from(d1),
    );
    // (|s1/d1 - s0/d0| - 1/d0 - 1/d1) / ((d0 + d1)/2) steps/us², as 2 * excess /
    // denominator with both exact integers (times d0*d1). A rest side has no rounding and
    // no length.
    let (excess, denominator) = match (d0, d1) {
        (0, 0) => return 0,
        (0, d) => (s1.abs() - 1, d * d),
        (d, 0) => (s0.abs() - 1, d * d),
        _ => ((s1 * d0 - s0 * d1).abs() - d0 - d1, d0 * d1 * (d0 + d1)),
    };
    if excess <= 0 || denominator <= 0 {
        return 0;
    }
    // steps/us² to steps/s²: 1e12. excess < 2^64 and 2e12 < 2^41: no overflow.
    (excess as u128 * 2_000_000_000_000) / denominator as u128
}

impl<const CAP: usize> Controller<CAP> {
    /// Whether `stored`, after `previous` and the segment `last`, keeps every joint in use
    /// within its `max_accel_steps_s2` (ACCEL_SET, issue 31); `ends`: it is the
    /// trajectory's last point, which must also come to rest. Updates `last` to it.
    pub(super) fn within_accel(
        &self,
        last: &mut LastSegment,
        previous: &[i32; MAX_JOINTS],
        stored: &StoredPoint,
        ends: bool,
    ) -> Result<(), Refusal> {
        let mut steps = [0i32; MAX_JOINTS];
        for ((s, &to), &from) in steps.iter_mut().zip(&stored.position).zip(previous) {
            *s = saturate_i32(i64::from(to) - i64::from(from));
        }
        let d = stored.duration_us;
        let joints = usize::from(self.settings.joints).min(MAX_JOINTS);
        for (j, ((&max, &s1), &s0)) in self
            .settings
            .max_accel
            .iter()
            .zip(&steps)
            .zip(&last.steps)
            .enumerate()
            .take(joints)
        {
            if max == 0 {
                continue;
            }
            let mut asked = acceleration(s0, last.duration_us, s1, d);
            if ends {
                asked = asked.max(acceleration(s1, d, 0, 0));
            }
            if asked > u128::from(max) {
                return Err(Refusal {
                    joint: u8::try_from(j).unwrap_or(u8::MAX),
                    reason: RefusalReason::Acceleration,
                    value: i32::try_from(asked).unwrap_or(i32::MAX),
                    limit: i32::try_from(max).unwrap_or(i32::MAX),
                    ..Refusal::default()
                });
            }
        }
        *last = LastSegment {
            steps,
            duration_us: d,
        };
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::acceleration;

    #[test]
    fn the_worked_example_of_protocol_md() {
        // 10 ms segments of +5, +15 and +30 steps from rest.
        assert_eq!(acceleration(0, 0, 5, 10_000), 80_000);
        assert_eq!(acceleration(5, 10_000, 15, 10_000), 80_000);
        assert_eq!(acceleration(15, 10_000, 30, 10_000), 130_000);
        // Coming to rest after the +30: (30 - 1) steps in 5 ms.
        assert_eq!(acceleration(30, 10_000, 0, 0), 580_000);
        // An instant reversal at 10,000 steps/s: 2,000,000 less the rounding.
        assert_eq!(acceleration(100, 10_000, -100, 10_000), 1_980_000);
        // Steady motion, and a step of rounding: none.
        assert_eq!(acceleration(100, 10_000, 100, 10_000), 0);
        assert_eq!(acceleration(100, 10_000, 101, 10_000), 0);
        // The extremes do not overflow.
        assert!(acceleration(i32::MIN, 1, i32::MAX, 1) > 0);
        assert!(acceleration(i32::MAX, u32::MAX, i32::MIN, u32::MAX) > 0);
    }
}

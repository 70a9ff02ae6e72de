//! HOLD, RESUME and OVERRIDE (issue 32): the controller's side of motion control in
//! flight. The step side does the time warp (arm-step's `Warp`, through
//! [`Plant::change_rate`]); here are the rules: who may, in which state, how steep the
//! ramp, whether an override above 100 % is allowed, and the MOTION report.
//!
//! A hold is RUNNING with a held flag (MOTION flags bit 0), not a state of its own: the
//! manual's hosts know four states, and a held run is still a run (its points still come,
//! STOPPED still ends it, the owner cannot be taken over). The ramp's slope is the
//! gentlest any joint needs: `accel / speed` smallest over the joints with an ACCEL_SET
//! limit, `speed` the fastest rate of that joint over the points held (fed and waiting);
//! with no limit set, [`UNLIMITED_RAMP`].

use protocol::{
    ControlledStop, EStopCategory, Location, MAX_JOINTS, MoreFlags, MotionFlags, MotionReport,
    OverrideLimit, State, StatusCode,
};

use super::Controller;
use super::runs::acceleration;
use crate::plant::Plant;

/// The ramp when no joint has an acceleration limit (ACCEL_SET 0): a full swing (0 to
/// 100 %) in 0.25 s, given as the `(accel, speed)` pair `ramp_for` takes. Gentle enough
/// not to lose steps on a typical stepper arm, quick enough to feel like a hold.
pub const UNLIMITED_RAMP: (u32, u32) = (4, 1);

/// The rate an underrun ramp slows to, percent: the run ends at the last point it holds
/// at this crawl rather than at standstill, because the ramp is started from a
/// conservative count of the path left (whole points, the one being written not counted)
/// and a ramp to 0 would leave the run at rest short of its last point with nothing to end
/// it. At 5 % of 4,000 steps/s the stop is a 200 steps/s step, which a stepper takes from
/// rest; the crawl lasts at most about two points' nominal time times 20.
pub const UNDERRUN_CREEP_PERCENT: u8 = 5;

/// A category 1 e-stop's slack past its ramp and the step side's lookahead
/// ([`estop_ramp_bound_us`]): a scheduler's delay of the trajectory task's look.
pub const ESTOP_RAMP_SLACK_US: u64 = 20_000;

/// The longest lookahead of any board ([`crate::profile::ALL`]): a rate change takes
/// effect only after the edges the step side already holds, so a category 1 ramp may
/// start that late.
pub const ESTOP_RAMP_LOOKAHEAD_US: u64 = {
    let mut most = 0;
    let mut rest: &[&crate::profile::BoardProfile] = &crate::profile::ALL;
    while let [profile, tail @ ..] = rest {
        if profile.lookahead_us as u64 > most {
            most = profile.lookahead_us as u64;
        }
        rest = tail;
    }
    most
};

/// How often the trajectory task looks at a category 1 ramp (standstill reached, bound
/// passed): the drivers are disabled at most this late after the standstill.
pub const ESTOP_RAMP_POLL_US: u64 = 1_000;

/// The bound on a category 1 e-stop's ramp from `rate` (warp units) with the slope
/// `(accel, speed)`: the ramp's own time, `rate / RATE_ONE * speed / accel` (v/a of the
/// joint that sets the slope, scaled by the rate now), plus [`ESTOP_RAMP_LOOKAHEAD_US`]
/// and [`ESTOP_RAMP_SLACK_US`]. Past it the run is halted at once, as category 0.
pub fn estop_ramp_bound_us(rate: u64, accel: u32, speed: u32) -> u64 {
    let ramp = u128::from(rate) * u128::from(speed) * 1_000_000
        / (u128::from(arm_step::RATE_ONE) * u128::from(accel.max(1)));
    u64::try_from(ramp)
        .unwrap_or(u64::MAX)
        .saturating_add(ESTOP_RAMP_LOOKAHEAD_US + ESTOP_RAMP_SLACK_US)
}

/// The controller's override and hold state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Motion {
    /// The override asked for, percent (100: none).
    pub factor: u8,
    /// A HOLD is in force (until RESUME or the run's end).
    pub held: bool,
    /// The last controlled stop.
    pub last_stop: ControlledStop,
    /// The last OVERRIDE refused: joint (0xFF none) and limit.
    pub refused: (u8, Option<OverrideLimit>),
    /// An underrun ramp is in force: the host is late and the run slows to the creep.
    pub underrun: bool,
    /// The safety door is open (runs hold; RUNING and RESUME refused `DOOR_OPEN`).
    pub door_open: bool,
    /// A category 1 e-stop's ramp is under way: the time, us, past which it is halted
    /// ([`estop_ramp_bound_us`]).
    pub estop_ramp: Option<u64>,
    /// The run under way is warped: started at a factor other than 100 %, or its rate
    /// changed since (the warp stays off its unwarped fast path even back at 100 %), so
    /// its pulses count against the step side's warp budget.
    pub warped: bool,
}

impl Motion {
    /// No override, no hold (boot).
    pub const IDLE: Motion = Motion {
        factor: 100,
        held: false,
        last_stop: ControlledStop::None,
        refused: (0xFF, None),
        underrun: false,
        door_open: false,
        estop_ramp: None,
        warped: false,
    };
}

/// `percent` as a warp rate (`arm_step::RATE_ONE` = 100 %).
pub fn rate_of(percent: u8) -> u64 {
    arm_step::RATE_ONE * u64::from(percent) / 100
}

impl<const CAP: usize> Controller<CAP> {
    /// Each joint's sharpest acceleration (steps/s^2, between consecutive points) over
    /// the points held, for an OVERRIDE above 100 % (a command, not each segment: this
    /// scans every point held). The oldest held point only starts the differences: where
    /// it begins is the end of a point already finished, which the buffer no longer holds
    /// (the joints' positions are no stand-in: the step side finishes a segment when its
    /// pulses are written, a few milliseconds before they are played, and the differences
    /// from them would make a point look several times as fast). The acceleration is that
    /// between consecutive differences (a first one has none before it: not from rest,
    /// which the trajectory's first point already was checked from).
    fn held_accels(&self) -> [u128; MAX_JOINTS] {
        let mut accel = [0u128; MAX_JOINTS];
        let Some(mut previous) = self.buffer.held(0).map(|p| p.position) else {
            return accel;
        };
        let mut i = 1;
        let mut last = ([0i32; MAX_JOINTS], 0u32);
        while let Some(point) = self.buffer.held(i) {
            i += 1;
            let d = point.duration_us.max(1);
            for j in 0..MAX_JOINTS {
                let (Some(&to), Some(&from)) = (point.position.get(j), previous.get(j)) else {
                    continue;
                };
                let steps = i64::from(to) - i64::from(from);
                let steps = i32::try_from(steps).unwrap_or(i32::MAX);
                let before = last.0.get(j).copied().unwrap_or(0);
                if let Some(a) = accel.get_mut(j)
                    && last.1 != 0
                {
                    *a = (*a).max(acceleration(before, last.1, steps, d));
                }
                if let Some(s) = last.0.get_mut(j) {
                    *s = steps;
                }
            }
            last.1 = d;
            previous = point.position;
        }
        accel
    }

    /// Each joint's fastest rate (steps/s) over the points held, O(1): the buffer's bound
    /// ([`crate::buffer::TrajectoryBuffer::peak_rates`], never below the exact maximum
    /// between consecutive held points); with one point held, from the joints' positions.
    fn held_speeds(&self, plant: &impl Plant) -> [u64; MAX_JOINTS] {
        if self.buffer.buffered() != 1 {
            return self.buffer.peak_rates();
        }
        let mut speed = [0u64; MAX_JOINTS];
        if let Some(point) = self.buffer.held(0) {
            let d = u64::from(point.duration_us.max(1));
            for ((s, &to), &from) in speed
                .iter_mut()
                .zip(&point.position)
                .zip(&plant.positions())
            {
                *s = (i64::from(to) - i64::from(from)).unsigned_abs() * 1_000_000 / d;
            }
        }
        speed
    }

    /// Whether the step side can place every pulse of the run under a warp up to `rate`
    /// (issue 32): each joint's fastest rate over the points held, summed, at `rate`, within
    /// its warp budget ([`Plant::warp_budget_hz`]; 0: no limit). A warped pulse costs the
    /// NUCLEO's step interrupts some 40 times an unwarped one: past the budget its DMA
    /// buffers would run dry (a dead stop at speed) where the refusal leaves the run as it
    /// was. The sum of each joint's peak is at least the run's rate at any instant.
    pub(super) fn warp_fits(&self, plant: &impl Plant, rate: u64) -> bool {
        let budget = plant.warp_budget_hz();
        if budget == 0 {
            return true;
        }
        let total: u128 = self.held_speeds(plant).iter().map(|&v| u128::from(v)).sum();
        total * u128::from(rate) <= u128::from(budget) * u128::from(arm_step::RATE_ONE)
    }

    /// A change refused for the warp budget: `OVERRIDE_REFUSED`, MOTION's refusal the whole
    /// run (joint 0xFF) and `STEP_BUDGET`.
    pub(super) fn over_warp_budget(&mut self) -> StatusCode {
        self.motion.refused = (0xFF, Some(OverrideLimit::StepBudget));
        StatusCode::OverrideRefused
    }

    /// The ramp's `(accel, speed)`: the gentlest slope over the joints with a limit.
    fn ramp_limits(&self, plant: &impl Plant) -> (u32, u32) {
        self.accel_ramp(plant).unwrap_or(UNLIMITED_RAMP)
    }

    /// The gentlest slope over the joints with an ACCEL_SET limit; `None` without one.
    fn accel_ramp(&self, plant: &impl Plant) -> Option<(u32, u32)> {
        let speed = self.held_speeds(plant);
        let mut ramp = UNLIMITED_RAMP;
        let mut limited = false;
        for (&max, &v) in self.settings.max_accel.iter().zip(&speed) {
            if max == 0 || v == 0 {
                continue;
            }
            let v = u32::try_from(v).unwrap_or(u32::MAX);
            // max / v < ramp.0 / ramp.1, without division.
            if !limited || u64::from(max) * u64::from(ramp.1) < u64::from(ramp.0) * u64::from(v) {
                ramp = (max, v);
                limited = true;
            }
        }
        limited.then_some(ramp)
    }

    /// Watches for an underrun coming (issue 32), after each finished segment: while the
    /// host has points still to send, some joint has an ACCEL_SET limit and the buffer is
    /// at most half full (the host is falling behind), when the path
    /// held after the next point is shorter than the ramp from the rate now to
    /// [`UNDERRUN_CREEP_PERCENT`] needs (and the path after the current one is not), the
    /// run slows to the creep along what it holds: it ends at its last point at a crawl
    /// (STOPPED, UNDERRUN, detail 1) unless the host catches up, which (twice the path of
    /// the ramp from the override held after the next point, or every point in) ramps back
    /// to the override.
    /// Without a limit, or with too little path, the underrun stays the dead stop at the
    /// last point's speed it always was. A host that keeps enough path buffered sees
    /// nothing of this.
    pub(super) fn watch_underrun(&mut self, plant: &mut impl Plant) {
        if self.state != State::Running || self.return_pending || self.motion.held {
            return;
        }
        if self.received >= self.expected && !self.motion.underrun {
            // Every point is in: the trajectory's own end comes to rest.
            return;
        }
        // This runs after every finished segment: everything below is O(1) (the buffer
        // keeps the sums and rate bounds it needs; a scan of the points held, 8,192 on the
        // NUCLEO, livelocked the board and the IWDG reset it, seen on Renode streaming
        // past the buffer). A step side without a warp cannot slow down; a buffer more
        // than half full is not an underrun coming.
        let Some((rate, _)) = plant.rate_now() else {
            return;
        };
        if !self.motion.underrun && self.buffer.free() < self.buffer.capacity() / 2 {
            return;
        }
        let Some((accel, speed)) = self.accel_ramp(plant) else {
            return;
        };
        // Nominal path after the point being written (r1) and after the next (r2), us.
        let duration = |i| self.buffer.held(i).map_or(0, |p| u64::from(p.duration_us));
        let r1 = self.buffer.duration_sum_us().saturating_sub(duration(0));
        let r2 = r1.saturating_sub(duration(1));
        let creep = rate_of(UNDERRUN_CREEP_PERCENT);
        let full = rate_of(self.motion.factor);
        if self.motion.underrun {
            let caught_up = self.received >= self.expected
                || u128::from(r2) >= 2 * ramp_path_us(full, creep, accel, speed);
            if caught_up && self.change_rate(plant, full, accel, speed) {
                self.motion.underrun = false;
            }
            return;
        }
        // A buffer more than half full is a host keeping up whose buffer is too short for
        // the ramp, not a late one: slowing it would crawl every run (and it could never
        // catch up); its underrun, if one comes, stays dead.
        if self.buffer.free() < self.buffer.capacity() / 2 {
            return;
        }
        let creep = creep.min(rate);
        let need = ramp_path_us(rate, creep, accel, speed);
        // Past the step side's warp budget the underrun stays the dead stop it was.
        if u128::from(r2) < need
            && u128::from(r1) >= need
            && self.warp_fits(plant, rate)
            && self.change_rate(plant, creep, accel, speed)
        {
            self.motion.underrun = true;
            self.motion.last_stop = ControlledStop::Underrun;
        }
    }

    /// HOLD (any host): decelerate the run to a standstill. `BAD_STATE` outside RUNNING,
    /// during a RETURN's encoder read, or on a step side without a warp;
    /// `OVERRIDE_REFUSED` (MOTION `STEP_BUDGET`) past its warp budget
    /// ([`Self::warp_fits`]). RESUME is never refused for the budget: a held run must be
    /// able to go on.
    pub(super) fn hold(&mut self, plant: &mut impl Plant) -> Result<(), StatusCode> {
        if self.state != State::Running || self.return_pending {
            return Err(StatusCode::BadState);
        }
        if self.motion.held {
            return Ok(());
        }
        let now = plant
            .rate_now()
            .map_or(arm_step::RATE_ONE, |(rate, _)| rate);
        if plant.rate_now().is_some() && !self.warp_fits(plant, now) {
            return Err(self.over_warp_budget());
        }
        let (accel, speed) = self.ramp_limits(plant);
        if !self.change_rate(plant, 0, accel, speed) {
            return Err(StatusCode::BadState);
        }
        self.motion.held = true;
        self.motion.last_stop = ControlledStop::Hold;
        Ok(())
    }

    /// RESUME (the owner): back to the override after a HOLD; nothing when not held.
    /// `DOOR_OPEN` while the safety door is.
    pub(super) fn resume(&mut self, plant: &mut impl Plant) -> Result<(), StatusCode> {
        if self.state != State::Running {
            return Err(StatusCode::BadState);
        }
        if self.motion.door_open {
            return Err(StatusCode::DoorOpen);
        }
        // A category 1 e-stop's ramp is a hold no host lifts.
        if self.motion.estop_ramp.is_some() {
            return Err(StatusCode::EstopLatched);
        }
        if !self.motion.held {
            return Ok(());
        }
        let (accel, speed) = self.ramp_limits(plant);
        if !self.change_rate(plant, rate_of(self.motion.factor), accel, speed) {
            return Err(StatusCode::BadState);
        }
        self.motion.held = false;
        // The underrun watch looks again from the override's rate.
        self.motion.underrun = false;
        Ok(())
    }

    /// Joint `j`'s step rate limit, steps/s: its LIMITS_SET `max_rate_hz` within the
    /// controller's `max_step_rate_hz`, or that alone.
    fn joint_rate_limit(&self, j: usize) -> u32 {
        let board_hz = self.config.max_step_rate_hz;
        self.settings
            .limits
            .get(j)
            .map_or(board_hz, |l| l.rate_hz(board_hz))
    }

    /// The highest override above 100 % (percent, below `factor`) under which the point
    /// `stored`, after `previous` and the segment `last` (and, if it `ends` the
    /// trajectory, its stop), keeps every joint in use within its rate limit and its
    /// ACCEL_SET limit, with the joint and the limit that set it; `None` when `factor`
    /// fits (always at 100 % or less: the point was admitted at 100 %). The rules of
    /// [`Self::set_override`], for a point that arrives after the override was taken.
    pub(super) fn factor_cap(
        &self,
        factor: u8,
        last: &super::runs::LastSegment,
        previous: &[i32; MAX_JOINTS],
        stored: &crate::buffer::StoredPoint,
        ends: bool,
    ) -> Option<(u8, u8, OverrideLimit)> {
        if factor <= 100 {
            return None;
        }
        let d = stored.duration_us.max(1);
        let joints = usize::from(self.settings.joints).min(MAX_JOINTS);
        let mut cap: Option<(u8, u8, OverrideLimit)> = None;
        let mut lower = |percent: u128, joint: usize, limit| {
            let percent = u8::try_from(percent.clamp(100, u128::from(factor))).unwrap_or(100);
            if percent < cap.map_or(factor, |c| c.0) {
                cap = Some((percent, u8::try_from(joint).unwrap_or(0xFF), limit));
            }
        };
        for j in 0..joints {
            let (Some(&to), Some(&from)) = (stored.position.get(j), previous.get(j)) else {
                continue;
            };
            let steps = (i64::from(to) - i64::from(from)).unsigned_abs();
            let rate_hz = self.joint_rate_limit(j);
            // steps * 1e6 / d * p <= rate_hz * 100: the largest such p.
            if steps > 0 {
                let most =
                    u128::from(rate_hz) * u128::from(d) * 100 / (u128::from(steps) * 1_000_000);
                if most < u128::from(factor) {
                    lower(most, j, OverrideLimit::Rate);
                }
            }
            let max = u128::from(self.settings.max_accel.get(j).copied().unwrap_or(0));
            if max == 0 {
                continue;
            }
            let s1 = i32::try_from(i64::from(to) - i64::from(from)).unwrap_or(i32::MAX);
            let s0 = last.steps.get(j).copied().unwrap_or(0);
            let mut a = super::runs::acceleration(s0, last.duration_us, s1, d);
            if ends {
                a = a.max(super::runs::acceleration(s1, d, 0, 0));
            }
            // a * p^2 <= max * 10^4: the largest such p, by bisection over 100..=factor
            // (a fits at 100: the point was admitted).
            let fits = |p: u128| a * p * p <= max * 10_000;
            if !fits(u128::from(factor)) {
                let (mut ok, mut over) = (100u128, u128::from(factor));
                while over - ok > 1 {
                    let mid = (ok + over) / 2;
                    if fits(mid) {
                        ok = mid;
                    } else {
                        over = mid;
                    }
                }
                lower(ok, j, OverrideLimit::Accel);
            }
        }
        cap
    }

    /// A point arrived that the override above 100 % would take past a limit
    /// ([`Self::factor_cap`]): the override is lowered to `percent`, what it allows, and
    /// MOTION's refusal names the joint and the limit. A run under way (not held, not in
    /// an underrun ramp, where the factor applies when it ends) ramps to it from now,
    /// before the run reaches the point when the host keeps the ramp's path buffered;
    /// before RUNING the run starts at it.
    pub(super) fn lower_override(
        &mut self,
        (percent, joint, limit): (u8, u8, OverrideLimit),
        plant: &mut impl Plant,
    ) {
        if percent >= self.motion.factor {
            return;
        }
        self.motion.factor = percent;
        self.motion.refused = (joint, Some(limit));
        self.ramp_to_factor(plant);
    }

    /// [`Plant::change_rate`], noting a change taken: the run is warped from then on.
    fn change_rate(&mut self, plant: &mut impl Plant, rate: u64, accel: u32, speed: u32) -> bool {
        let taken = plant.change_rate(rate, accel, speed);
        self.motion.warped |= taken;
        taken
    }

    /// Points were taken while the run is warped: the factor it runs at (held: where
    /// RESUME goes) must keep the warped steps of every point held within the step side's
    /// warp budget ([`Self::warp_fits`]). Else the override is lowered to the highest percent
    /// that does and MOTION's refusal is the whole run's (0xFF) and `STEP_BUDGET`; the run
    /// ramps to it from now, as for a point past a joint's limit ([`Self::lower_override`]).
    /// Past the budget the step buffers would run dry, a dead stop at speed; slower, the
    /// run keeps every step. A run never warped is left alone: old hosts never warp.
    pub(super) fn fit_warp_budget(&mut self, plant: &mut impl Plant) {
        if self.state != State::Running || self.return_pending || !self.motion.warped {
            return;
        }
        if self.warp_fits(plant, rate_of(self.motion.factor)) {
            return;
        }
        // The highest percent below the factor that fits (0 always does: no steps).
        let (mut fits, mut over) = (0u8, self.motion.factor);
        while over - fits > 1 {
            let mid = fits + (over - fits) / 2;
            if self.warp_fits(plant, rate_of(mid)) {
                fits = mid;
            } else {
                over = mid;
            }
        }
        self.motion.factor = fits.max(protocol::OVERRIDE_MIN_PERCENT);
        self.motion.refused = (0xFF, Some(OverrideLimit::StepBudget));
        self.ramp_to_factor(plant);
    }

    /// The factor in force from now: a run under way ramps to it, with HOLD's slope. Held,
    /// it is where RESUME goes; during an underrun ramp it applies when the host catches
    /// up; RETURN runs at 100 %. A step side without a warp keeps 100 %; the factor still
    /// applies from the next run on that could take it.
    fn ramp_to_factor(&mut self, plant: &mut impl Plant) {
        if self.state == State::Running
            && !self.motion.held
            && !self.motion.underrun
            && !self.return_pending
        {
            let (accel, speed) = self.ramp_limits(plant);
            let _ = self.change_rate(plant, rate_of(self.motion.factor), accel, speed);
        }
    }

    /// OVERRIDE (the owner): the factor from now (ramped) and for the runs to come.
    /// `OVERRIDE_REFUSED` (MOTION `STEP_BUDGET`) past the step side's warp budget
    /// ([`Self::warp_fits`]).
    /// Above 100 %, every joint's fastest rate times the factor must stay within its rate
    /// limit and its sharpest acceleration times the factor squared within its ACCEL_SET
    /// limit, over the points held: else `OVERRIDE_REFUSED`, the joint and limit kept for
    /// MOTION.
    pub(super) fn set_override(
        &mut self,
        percent: u8,
        plant: &mut impl Plant,
    ) -> Result<(), StatusCode> {
        if percent > 100 {
            let speed = self.held_speeds(plant);
            let accel = self.held_accels();
            let p = u128::from(percent);
            for j in 0..MAX_JOINTS {
                let rate_limit = self.joint_rate_limit(j);
                let v = u128::from(speed.get(j).copied().unwrap_or(0));
                let joint = u8::try_from(j).unwrap_or(0xFF);
                if v * p > u128::from(rate_limit) * 100 {
                    self.motion.refused = (joint, Some(OverrideLimit::Rate));
                    return Err(StatusCode::OverrideRefused);
                }
                let max = self.settings.max_accel.get(j).copied().unwrap_or(0);
                let a = accel.get(j).copied().unwrap_or(0);
                if max != 0 && a * p * p > u128::from(max) * 10_000 {
                    self.motion.refused = (joint, Some(OverrideLimit::Accel));
                    return Err(StatusCode::OverrideRefused);
                }
            }
        }
        // The factor's warp must fit the step side's budget: from the rate now (the ramp
        // passes every rate between) while a run goes, else at the factor (where RESUME or
        // the next RUNING go; RUNING checks again with the points it then holds).
        let running = self.state == State::Running && !self.return_pending;
        let now = plant.rate_now().map(|(rate, _)| rate).filter(|_| running);
        let highest = now.unwrap_or(0).max(rate_of(percent));
        let warped = now.is_some() || percent != 100;
        if warped && !self.warp_fits(plant, highest) {
            return Err(self.over_warp_budget());
        }
        self.motion.factor = percent;
        self.ramp_to_factor(plant);
        Ok(())
    }

    /// The safety door input (issue 32) is now `open` (or closed). Opening holds a run
    /// (as HOLD, MOTION's last stop DOOR; a run during RETURN's encoder read or on a step
    /// side without a warp cannot hold and is stopped instead: the door must stop motion);
    /// while open, RUNING and RESUME are refused `DOOR_OPEN`. Closing only records it:
    /// a host RESUMEs. Returns a LOCATION report when the state changed (reports on).
    pub fn door_input(&mut self, open: bool, plant: &mut impl Plant) -> Option<Location> {
        let was = self.motion.door_open;
        self.motion.door_open = open;
        if !open || was || self.state != State::Running || self.motion.estop_ramp.is_some() {
            return None;
        }
        match self.hold(plant) {
            Ok(()) => {
                self.motion.last_stop = ControlledStop::Door;
                None
            }
            Err(_) => {
                let before = self.state;
                self.stop_by_host(plant, None);
                // The cause says the door (STOP_CAUSE HOLD, detail DOOR), not the wired
                // e-stop input that stop_by_host names when no host stopped it.
                self.stop = protocol::StopReport {
                    detail: ControlledStop::Door as u8,
                    ..protocol::StopReport::of(protocol::StopCause::Hold)
                };
                (before != self.state && self.reports_on).then(|| self.location(plant))
            }
        }
    }

    /// The wired e-stop input's stop category (ESTOP_CATEGORY, kept in the settings).
    pub fn estop_category(&self) -> EStopCategory {
        self.settings.estop_category
    }

    /// The wired e-stop input opened and its handler left the stop to a category 1
    /// controlled stop ([`crate::EStopSample::controlled`]; it only blocked new runs).
    /// The latch is set at once; a run under way ramps to a standstill along its path
    /// with the hold's slope (RUNNING, held, MOTION flag `ESTOP_RAMP`; RESUME refused
    /// `ESTOP_LATCHED`), bounded by [`estop_ramp_bound_us`] from `now_us`; the caller
    /// then calls [`Controller::estop_ramp_poll`] at least every
    /// [`ESTOP_RAMP_POLL_US`]. Anything else stops at once as category 0, with the
    /// drivers disabled after ([`Controller::estop_ramp_poll`]'s end): no run to ramp
    /// (a RETURN's encoder read), a step side that refuses the warp, or a ramp already
    /// under way (a second opening). Returns a LOCATION report when the state changed.
    pub fn estop_controlled(&mut self, now_us: u64, plant: &mut impl Plant) -> Option<Location> {
        self.more_flags.set(MoreFlags::ESTOP_OPEN, true);
        self.more_flags.set(MoreFlags::ESTOP_LATCHED, true);
        if self.motion.estop_ramp.is_none() && self.state == State::Running && !self.return_pending
        {
            let rate = plant
                .rate_now()
                .map_or(arm_step::RATE_ONE, |(rate, _)| rate);
            let (accel, speed) = self.ramp_limits(plant);
            if self.change_rate(plant, 0, accel, speed) {
                self.motion.held = true;
                self.motion.underrun = false;
                self.motion.last_stop = ControlledStop::EStop;
                self.motion.estop_ramp =
                    Some(now_us.saturating_add(estop_ramp_bound_us(rate, accel, speed)));
                return None;
            }
        }
        self.estop_stop_now(plant)
    }

    /// The deadline of a category 1 ramp under way ([`Controller::estop_controlled`]);
    /// the caller wakes by then (and every [`ESTOP_RAMP_POLL_US`]).
    pub fn estop_ramp_deadline(&self) -> Option<u64> {
        self.motion.estop_ramp
    }

    /// A category 1 ramp's look at `now_us`: at a standstill (the rate 0 and no longer
    /// changing, or no run any more: it ended, or a STOPPED or a second opening stopped
    /// it), or past its bound, the run is stopped at once (as category 0: no pulse after
    /// this, the trajectory dropped, state STOPPED, latched) and the drivers are disabled
    /// (ENABLE off, every joint and the gripper; SET_ENABLE enables them again after
    /// ESTOP_RESET). Returns a LOCATION report when the state changed.
    pub fn estop_ramp_poll(&mut self, now_us: u64, plant: &mut impl Plant) -> Option<Location> {
        let deadline = self.motion.estop_ramp?;
        let at_rest =
            self.state != State::Running || matches!(plant.rate_now(), None | Some((0, false)));
        if !at_rest && now_us < deadline {
            return None;
        }
        if !at_rest {
            warn!("category 1 e-stop: no standstill within its bound, halted");
        }
        self.estop_stop_now(plant)
    }

    /// The end of a category 1 stop (and its fallback): stop at once, latched, drivers
    /// disabled.
    pub(super) fn estop_stop_now(&mut self, plant: &mut impl Plant) -> Option<Location> {
        self.motion.estop_ramp = None;
        self.motion.held = false;
        self.more_flags.set(MoreFlags::ESTOP_LATCHED, true);
        let before = self.state;
        self.stop_by_host(plant, None);
        self.disable_drivers(plant);
        (before != self.state && self.reports_on).then(|| self.location(plant))
    }

    /// Whether the safety door is open.
    pub fn door_open(&self) -> bool {
        self.motion.door_open
    }

    /// The MOTION report (STATUS's request byte bit 4).
    pub fn motion_report(&self, plant: &impl Plant) -> MotionReport {
        let running = self.state == State::Running;
        let (rate, ramping) = match plant.rate_now() {
            Some(now) if running => now,
            _ => (rate_of(self.motion.factor), false),
        };
        let permille = rate * 1000 / arm_step::RATE_ONE;
        let mut flags = 0;
        if self.motion.held && running {
            flags |= MotionFlags::HELD;
        }
        if running && rate == 0 {
            flags |= MotionFlags::AT_REST;
        }
        if running && ramping {
            flags |= MotionFlags::RAMPING;
        }
        if running && self.motion.underrun {
            flags |= MotionFlags::UNDERRUN_RAMP;
        }
        if self.motion.door_open {
            flags |= MotionFlags::DOOR_OPEN;
        }
        if self.motion.estop_ramp.is_some() {
            flags |= MotionFlags::ESTOP_RAMP;
        }
        MotionReport {
            factor_percent: self.motion.factor,
            flags: MotionFlags(flags),
            rate_permille: u16::try_from(permille).unwrap_or(u16::MAX),
            last_stop: Some(self.motion.last_stop),
            refused_joint: self.motion.refused.0,
            refused_limit: self.motion.refused.1,
            estop_category: Some(self.settings.estop_category),
        }
    }
}

/// The nominal (trajectory) path, us, that a ramp of the rate from `from` to `to` (warp
/// units, `to <= from`) runs with the slope `(accel, speed)`: the ramp lasts
/// `(from - to) / RATE_ONE * speed / accel` s at the mean rate `(from + to) / 2`.
pub fn ramp_path_us(from: u64, to: u64, accel: u32, speed: u32) -> u128 {
    let (from, to) = (u128::from(from), u128::from(to.min(from)));
    let one = u128::from(arm_step::RATE_ONE);
    (from - to) * (from + to) * u128::from(speed) * 1_000_000
        / (2 * one * one * u128::from(accel.max(1)))
}

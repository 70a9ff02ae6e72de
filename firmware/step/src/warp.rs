//! [`Warp`]: time warp for HOLD, RESUME and the speed override (issue 32): a monotone map
//! from controller ticks `t` to trajectory ticks `tau(t)`, with a rate `s(t) = dtau/dt` in
//! `[0, MAX_RATE]` (`RATE_ONE` = 100 %) that changes only along ramps of bounded `ds/dt`.
//!
//! # Why a warp keeps the path and every step
//!
//! The trajectory is a function of trajectory time: joint `j` is at `x_j(tau)`. Steps are
//! placed on trajectory time exactly as without a warp (pulse `i` of a segment is due at
//! the trajectory tick `T_i` of the crate's rule); the warp only moves *when* it rises: at
//! the first controller tick `t` with `tau(t) >= T_i` ([`Warp::controller_tick`]). Every
//! joint uses the one map, so the joints stay on one time scale and the path (the curve
//! through joint space) is kept; how many steps come is untouched, so every joint still ends
//! exactly where the points say. A hold is a ramp to `s = 0`: `tau` stands still and the
//! steps due after it wait; a resume ramps back.
//!
//! # The acceleration bound
//!
//! Under the warp a joint's velocity is `dx/dt = s * v` (`v = dx/dtau`, the path's velocity)
//! and its acceleration is
//!
//! ```text
//! d2x/dt2 = s^2 * a + (ds/dt) * v          (a = d2x/dtau2, the path's acceleration)
//! ```
//!
//! With `s <= 1` the first term is at most the path's own acceleration. The second is what
//! the warp adds: a ramp with `|ds/dt| <= a_max / |v|` adds at most `a_max` where the path
//! cruises. [`ramp_for`] turns a joint's limit and speed into that slope; the caller takes the
//! smallest over the joints. A hold from `s = 1` at speed `v` then stops in `v / a_max` and
//! runs `v^2 / (2 a_max)` steps after the hold (tests/warp.rs measures both, and the
//! acceleration every two consecutive step intervals imply). Where the path itself
//! accelerates during a ramp the two terms add: a budget splitting `a_max` between path and
//! warp (or a slope that looks at `a` too) is left to the controller (issue 32's rest).
//! Above 100 % the first term grows as `s^2` and speeds as `s`: whoever allows an override
//! over 100 % checks the path's speeds and accelerations against the limits divided by
//! `s` and `s^2`.
//!
//! # Exact integer arithmetic
//!
//! No float: a rate is kept in *fine* units, `RATE_ONE * RAMP_SCALE` per 100 %, so that a
//! ramp's slope (`ramp`, fine units per tick) is an integer however gentle, and the rate at
//! any tick of a ramp is an integer too. Trajectory time is kept in units of
//! `1 / (2 * RATE_ONE * RAMP_SCALE)` tick (`PER_TICK` per tick), in which a phase starting at
//! `tau0` with rate `r0` and slope `k` reaches, after `dt` ticks, exactly
//! `tau0 + 2 * r0 * dt + k * dt^2`: u128/i128 sums and products, no rounding, no drift, however
//! long the run. The warp is a list of phases (a start tick, the trajectory time and rate
//! there, a slope); the last one never ramps. Inverting a phase is one division for a
//! constant rate, and a binary search of the quadratic (about 40 steps) on a ramp.
//!
//! # What uses it
//!
//! [`crate::StepEngine`] (the oracle) and [`crate::PulseProducer`] take the same warp
//! (`set_warp` before a run, `change_warp` during one) and map each pulse's ideal tick through it at the one place
//! they compute it; the producer's cruise fast path is left while a warp is set, and segment
//! and run ends are mapped alike, so the two agree pulse for pulse (tests/producer.rs: half
//! of its random cases carry holds, resumes and override changes). A run's `at_tick` is on
//! trajectory time under a warp (the tests start a run at the first trajectory tick the warp
//! reaches at or after the controller tick they mean). Unwarped runs cost a per-joint flag
//! test per pulse in the producer (scripts/step-cost, README).
//!
//! # Changes during a run
//!
//! `change_warp` on the engine and on the producer takes a change at a controller tick no
//! earlier than their `warp_horizon`: every edge already committed under the old map (the
//! engine's scheduled rises, the producer's written periods and computed next rise) lies at
//! or before it, and the two maps agree up to it, so nothing committed moves. Before the
//! change each forgets the phases that are over ([`Warp::forget_before`]: below the oldest
//! trajectory tick it can still ask for), so the fixed list ([`WARP_PHASES`]) is not used
//! up by a long run with many holds. The caller takes a change at `max(now, horizon)`;
//! tests/producer.rs applies random holds, resumes and overrides mid-run to both at the
//! same tick and compares them pulse for pulse.
//!
//! The controller's HOLD, RESUME and OVERRIDE drive it through arm-core's `StepBackend`
//! (`change_rate`, `set_start_rate`: the simulator's backend keeps the warp on the run's
//! clock, which restarts at 0 every run, as the board's does).
//!
//! The NUCLEO's and QEMU's backends take it too (`firmware/board/src/step_dma/backend.rs`,
//! `firmware/qemu-mps2/src/step_out.rs`). Its cost there, measured on the `cargo fw` ELF on
//! Renode (tests/tests/renode_cost.rs, `step_path_instructions_per_step_during_a_ramp`):
//! `Warp::warped_tick` is 1,770-1,920 instructions per warped pulse (the ramp's u128
//! bisection, the steady phase's u128 division), the step interrupts 1,947-2,173 per pulse
//! in all, against 34-42 unwarped; so the controller refuses a warp past the board's
//! `warp_budget_hz` (75,000 steps/s of all joints on the NUCLEO). Left for issue 32: a
//! cheaper inversion (a steady phase whose rate is a whole `RATE_ONE` unit as a shift and
//! a 64-by-32 division; a ramp's search started from the joint's previous pulse), which
//! would raise that budget, and the acceleration budget between path and warp (above).

/// A rate of 100 %: trajectory time runs as fast as controller time.
pub const RATE_ONE: u64 = 1 << 16;

/// Highest rate a warp takes: 200 % (an override above 100 % is for the caller to check
/// against the joints' limits, see the module header).
pub const MAX_RATE: u64 = 2 * RATE_ONE;

/// Fine rate units per `RATE_ONE` unit: a slope of one fine unit per tick at 200 MHz is a
/// full ramp (0 to 100 %) in 2^48 / 2e8 s (16 days), fine enough for any joint's limit.
const RAMP_SCALE: u64 = 1 << 32;

/// 100 % in fine units.
const FINE_ONE: u64 = RATE_ONE * RAMP_SCALE;

/// Trajectory time units per tick (see the module header).
const PER_TICK: u128 = 2 * FINE_ONE as u128;

/// Phases a warp holds: each rate change adds two (its ramp, then the steady rate), so 16
/// hold seven changes ahead (three holds and resumes and an override). Fixed: no heap.
pub const WARP_PHASES: usize = 16;

/// Why a warp change was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WarpError {
    /// The change lies before the warp's first phase.
    BeforeStart,
    /// The target rate is above [`MAX_RATE`].
    RateTooHigh,
    /// The slope is 0: the rate could never get there.
    NoRamp,
    /// No room for the change's phases ([`WARP_PHASES`]).
    Full,
    /// The change lies before an edge already committed under the old warp (a rise the
    /// engine scheduled, a period the producer wrote): take it at their `warp_horizon` or
    /// later.
    Committed,
}

/// One piece of the warp: from controller tick `start`, trajectory time `at` (units of
/// `1 / PER_TICK` tick), rate `rate` (fine units), slope `ramp` (fine units per tick).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Phase {
    start: u64,
    at: u128,
    rate: u64,
    ramp: i64,
}

impl Phase {
    /// Trajectory time gained `dt` ticks into the phase (the rate never goes below 0 in a
    /// phase, so this is never negative).
    fn gained(&self, dt: u64) -> u128 {
        let dt = i128::from(dt);
        let sum = 2 * i128::from(self.rate) * dt + i128::from(self.ramp) * dt * dt;
        u128::try_from(sum).unwrap_or(0)
    }

    /// Rate `dt` ticks into the phase, fine units.
    fn rate_after(&self, dt: u64) -> u64 {
        let rate = i128::from(self.rate) + i128::from(self.ramp) * i128::from(dt);
        u64::try_from(rate).unwrap_or(0)
    }
}

/// The identity: trajectory time is controller time from tick 0.
const IDENTITY: Phase = Phase {
    start: 0,
    at: 0,
    rate: FINE_ONE,
    ramp: 0,
};

/// A time warp (see the module header).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Warp {
    phases: [Phase; WARP_PHASES],
    /// Phases held (at least one).
    len: usize,
    /// No change was ever made: the map is the identity (the fast paths stay).
    identity: bool,
}

impl Default for Warp {
    fn default() -> Self {
        Self::IDENTITY
    }
}

/// The slope (fine rate units per tick, for [`Warp::change_rate`]) that adds at most
/// `accel` steps/s^2 to a joint moving at `speed` steps/s on a `tick_hz` clock:
/// `ds/dt = accel / speed` (module header), rounded down. At least 1.
pub fn ramp_for(accel: u32, speed: u32, tick_hz: u32) -> u64 {
    let numerator = u128::from(FINE_ONE) * u128::from(accel);
    let denominator = u128::from(speed.max(1)) * u128::from(tick_hz.max(1));
    u64::try_from(numerator / denominator)
        .unwrap_or(u64::MAX)
        .max(1)
}

impl Warp {
    /// Trajectory time is controller time.
    pub const IDENTITY: Warp = Warp {
        phases: [IDENTITY; WARP_PHASES],
        len: 1,
        identity: true,
    };

    /// Whether no change was ever made (the map is the identity).
    pub fn is_identity(&self) -> bool {
        self.identity
    }

    /// From controller tick `at`, ramps the rate from whatever it is there to `target`
    /// (`RATE_ONE` = 100 %) with slope `ramp` (fine units per tick, [`ramp_for`]), then keeps
    /// it. Changes planned after `at` are dropped. The ramp ends on the last tick that does
    /// not overshoot `target`; the rest (less than one tick's slope) is a step.
    pub fn change_rate(&mut self, at: u64, target: u64, ramp: u64) -> Result<(), WarpError> {
        if target > MAX_RATE {
            return Err(WarpError::RateTooHigh);
        }
        let slope = i64::try_from(ramp).map_err(|_| WarpError::NoRamp)?;
        if slope == 0 {
            return Err(WarpError::NoRamp);
        }
        if self.phases.first().is_none_or(|first| first.start > at) {
            return Err(WarpError::BeforeStart);
        }
        let mut len = self.len;
        while len > 1 && self.phases.get(len - 1).is_some_and(|p| p.start > at) {
            len -= 1;
        }
        let Some(&last) = self.phases.get(len - 1) else {
            return Err(WarpError::BeforeStart);
        };
        let dt = at - last.start;
        let here = Phase {
            start: at,
            at: last.at + last.gained(dt),
            rate: last.rate_after(dt),
            ramp: 0,
        };
        // The phase that `here` continues: replaced if it starts at `at`.
        let first_new = if dt == 0 { len - 1 } else { len };
        let goal = target * RAMP_SCALE;
        let ticks = goal.abs_diff(here.rate) / ramp;
        let needed = first_new + if ticks > 0 { 2 } else { 1 };
        if needed > WARP_PHASES {
            return Err(WarpError::Full);
        }
        let mut next = first_new;
        let mut steady = Phase { rate: goal, ..here };
        if ticks > 0 {
            let ramping = Phase {
                ramp: if goal > here.rate { slope } else { -slope },
                ..here
            };
            steady.start = at.saturating_add(ticks);
            steady.at = here.at + ramping.gained(ticks);
            if let Some(slot) = self.phases.get_mut(next) {
                *slot = ramping;
            }
            next += 1;
        }
        if let Some(slot) = self.phases.get_mut(next) {
            *slot = steady;
        }
        self.len = next + 1;
        self.identity = false;
        Ok(())
    }

    /// Forgets the phases that are over for every trajectory tick at or after
    /// `trajectory_tick`: those whose successor starts at a trajectory time strictly
    /// before it (strictly: a phase ending held, rate 0, still answers for the trajectory
    /// time it stands at). Queries for earlier trajectory ticks (or controller ticks before
    /// the first phase kept) are no longer exact; the engine and the producer forget only
    /// below every tick they can still ask for (the oldest queued segment's start, each
    /// joint's next pulse). What is kept answers exactly as before.
    pub fn forget_before(&mut self, trajectory_tick: u64) {
        let want = u128::from(trajectory_tick) * PER_TICK;
        let held = self.phases.get(..self.len).unwrap_or_default();
        // Phases 0..over end before `want` (the last phase never ends).
        let over = held
            .iter()
            .skip(1)
            .take_while(|next| next.at < want)
            .count();
        if over > 0 {
            self.phases.copy_within(over..self.len, 0);
            self.len -= over;
        }
    }

    /// Phases held (at least one; at most [`WARP_PHASES`]).
    pub fn phases(&self) -> usize {
        self.len
    }

    /// HOLD at `at`: ramps to a standstill (rate 0) with slope `ramp`.
    pub fn hold(&mut self, at: u64, ramp: u64) -> Result<(), WarpError> {
        self.change_rate(at, 0, ramp)
    }

    /// RESUME at `at`: ramps back to `rate` (`RATE_ONE` = 100 %) with slope `ramp`.
    pub fn resume(&mut self, at: u64, rate: u64, ramp: u64) -> Result<(), WarpError> {
        self.change_rate(at, rate, ramp)
    }

    /// The first controller tick at which trajectory time reaches `trajectory_tick`
    /// (`u64::MAX`: never, the warp ends held before it).
    ///
    /// Inlined to the identity test alone: the producer's refill calls it per pulse, and an
    /// unwarped run must not pay for the search (scripts/step-cost).
    #[inline(always)]
    pub fn controller_tick(&self, trajectory_tick: u64) -> u64 {
        if self.identity {
            trajectory_tick
        } else {
            self.warped_tick(trajectory_tick)
        }
    }

    /// [`Warp::controller_tick`] through the phases (whatever `is_identity` says).
    #[inline(never)]
    pub(crate) fn warped_tick(&self, trajectory_tick: u64) -> u64 {
        let want = u128::from(trajectory_tick) * PER_TICK;
        let held = self.phases.get(..self.len).unwrap_or_default();
        for (i, phase) in held.iter().enumerate() {
            if want <= phase.at {
                return phase.start;
            }
            let need = want - phase.at;
            let Some(next) = held.get(i + 1) else {
                // The last phase: a steady rate, forever.
                if phase.rate == 0 {
                    return u64::MAX;
                }
                let per_tick = 2 * u128::from(phase.rate);
                let dt = need.div_ceil(per_tick);
                return u64::try_from(dt)
                    .ok()
                    .and_then(|dt| phase.start.checked_add(dt))
                    .unwrap_or(u64::MAX);
            };
            if want > next.at {
                continue;
            }
            // Reached within this phase: the least dt in (0, length] with gained >= need.
            let (mut low, mut high) = (0u64, next.start - phase.start);
            while high - low > 1 {
                let mid = low + (high - low) / 2;
                if phase.gained(mid) >= need {
                    high = mid;
                } else {
                    low = mid;
                }
            }
            return phase.start + high;
        }
        u64::MAX
    }

    /// Trajectory tick (rounded down) at controller tick `tick`.
    pub fn trajectory_tick(&self, tick: u64) -> u64 {
        let phase = self.phase_at(tick);
        let at = phase.at + phase.gained(tick - phase.start);
        u64::try_from(at / PER_TICK).unwrap_or(u64::MAX)
    }

    /// Rate at controller tick `tick`, `RATE_ONE` = 100 % (rounded down).
    pub fn rate(&self, tick: u64) -> u64 {
        let phase = self.phase_at(tick);
        phase.rate_after(tick - phase.start) / RAMP_SCALE
    }

    /// Whether the rate is changing at controller tick `tick` (a ramp's phase holds it).
    pub fn ramping(&self, tick: u64) -> bool {
        self.phase_at(tick).ramp != 0
    }

    /// A steady `rate` (`RATE_ONE` = 100 %) from controller tick `from`, trajectory time
    /// being controller time before it: what a run started with an override takes
    /// ([`Warp::IDENTITY`] itself at 100 %, keeping the unwarped fast paths).
    pub fn steady(from: u64, rate: u64) -> Result<Warp, WarpError> {
        let mut warp = Warp::IDENTITY;
        if rate != RATE_ONE {
            // A slope so steep the ramp takes no tick: a step to `rate` at `from`.
            warp.change_rate(from, rate, i64::MAX as u64)?;
        }
        Ok(warp)
    }

    /// The phase that holds `tick` (the first one for ticks before it).
    fn phase_at(&self, tick: u64) -> Phase {
        let held = self.phases.get(..self.len).unwrap_or_default();
        let found = held.iter().rev().find(|p| p.start <= tick).copied();
        let first = held.first().copied().unwrap_or(IDENTITY);
        found.unwrap_or(Phase {
            start: tick,
            ..first
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_maps_every_tick_to_itself() {
        let warp = Warp::IDENTITY;
        for t in [0, 1, 12_345, u64::MAX / 2] {
            assert_eq!(warp.controller_tick(t), t);
            assert_eq!(warp.trajectory_tick(t), t);
        }
    }

    #[test]
    fn a_steady_half_rate_doubles_every_span() {
        let mut warp = Warp::IDENTITY;
        assert_eq!(warp.change_rate(1_000, RATE_ONE / 2, u64::MAX / 2), Ok(()));
        assert_eq!(warp.controller_tick(1_000), 1_000);
        assert_eq!(warp.controller_tick(1_001), 1_002);
        assert_eq!(warp.controller_tick(2_000), 3_000);
        assert_eq!(warp.trajectory_tick(3_001), 2_000);
        assert_eq!(warp.rate(5_000), RATE_ONE / 2);
    }

    #[test]
    fn a_hold_stands_still_until_the_resume() {
        let ramp = ramp_for(20_000, 4_000, 1_000_000);
        let mut warp = Warp::IDENTITY;
        assert_eq!(warp.hold(1_000_000, ramp), Ok(()));
        // 0.2 s to stand still, 0.1 s of trajectory time run meanwhile.
        let stop = warp.trajectory_tick(2_000_000);
        assert!((1_099_990..=1_100_010).contains(&stop), "{stop}");
        assert_eq!(warp.rate(1_200_001), 0);
        assert_eq!(warp.controller_tick(stop + 1), u64::MAX);
        assert_eq!(warp.resume(3_000_000, RATE_ONE, ramp), Ok(()));
        let back = warp.controller_tick(stop + 1);
        assert!(back > 3_000_000 && back < 3_010_000, "{back}");
        assert_eq!(warp.rate(3_300_000), RATE_ONE);
    }

    #[test]
    fn the_map_inverts_the_trajectory_time_exactly() {
        let mut warp = Warp::IDENTITY;
        let ramp = ramp_for(50_000, 3_000, 10_000_000);
        for (at, rate) in [(5_000, 0), (2_000_000, RATE_ONE * 3 / 2), (2_100_000, 7)] {
            assert_eq!(warp.change_rate(at, rate, ramp), Ok(()));
        }
        assert_eq!(warp.change_rate(30_000_000, RATE_ONE, ramp * 3), Ok(()));
        let mut last = 0;
        for tau in (0..40_000_000).step_by(9_973) {
            let t = warp.controller_tick(tau);
            assert!(t >= last, "monotone");
            last = t;
            // The first tick at which trajectory time reaches tau.
            assert!(warp.trajectory_tick(t) >= tau);
            assert!(t == 0 || warp.trajectory_tick(t - 1) < tau);
        }
    }

    #[test]
    fn refusals() {
        let mut warp = Warp::IDENTITY;
        assert_eq!(
            warp.change_rate(0, MAX_RATE + 1, 1),
            Err(WarpError::RateTooHigh)
        );
        assert_eq!(warp.change_rate(0, 0, 0), Err(WarpError::NoRamp));
        let mut at = 10;
        let mut result = Ok(());
        for _ in 0..WARP_PHASES {
            result = warp
                .hold(at, 1 << 40)
                .and_then(|()| warp.resume(at + 1_000, RATE_ONE, 1 << 40));
            at += 10_000;
        }
        assert_eq!(result, Err(WarpError::Full));
        // Forgetting what is over makes room too, and keeps the rest exact.
        let mut forgetful = warp;
        let tau = warp.trajectory_tick(60_000);
        forgetful.forget_before(tau);
        assert!(forgetful.phases() < warp.phases());
        for t in (tau..tau + 200_000).step_by(97) {
            assert_eq!(forgetful.controller_tick(t), warp.controller_tick(t), "{t}");
        }
        assert_eq!(forgetful.hold(300_000, 1 << 40), Ok(()));
        // Replanning from an earlier tick drops the later changes: room again.
        assert_eq!(warp.hold(20, 1 << 40), Ok(()));
        assert!(!warp.is_identity());
    }
}

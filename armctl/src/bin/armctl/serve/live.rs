//! What every page shows, kept once: the controller's latest STATUS and LOCATION, the arm's
//! names and units, the run in progress and its commanded points. One poller thread reads
//! the controller (LOCATION reports as the owner, read-only STATUS otherwise); each page's
//! event stream waits on [`Live`] and sends a snapshot whenever it changes, or every
//! [`Live::wait`] timeout, so that a page sees the controller go silent.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use armctl::Client;
use armctl::motion::Units;
use armctl::trajectory::ArmConfig;
use protocol::{
    Location, MAX_JOINTS, MoreFlags, MotionFlags, MotionReport, State, StatusCode, StatusFlags,
    StatusReport,
};
use serde_json::{Value, json};

/// Silence after which the page says the controller stops answering: ten report periods at
/// the default 10 ms, and four of the read-only polls.
pub const STALE_AFTER: Duration = Duration::from_millis(1000);

/// How often the owner's poller asks STATUS when no run is in progress (the flags, the
/// buffer, the e-stop input): 4 a second, and it keeps this host the owner.
const STATUS_EVERY: Duration = Duration::from_millis(250);

/// How often a read-only pendant asks its look-only STATUS: as `armctl watch` does, half
/// the controller's budget for such answers (docs/PROTOCOL.md section 1).
const READ_ONLY_POLL: Duration = Duration::from_millis(200);

/// A read-only pendant asks the MOTION report every this many polls (once a second):
/// with the look-only STATUS, within the controller's budget for such answers.
const READ_ONLY_MOTION_EVERY: u32 = 5;

/// How often a read-only pendant asks who owns the controller (DISCOVER), and tries to
/// take it once it is free.
const OWNER_EVERY: Duration = Duration::from_secs(5);

/// The run whose positions the page plots: the points' end times and positions.
#[derive(Clone, Debug, Default)]
pub struct PlotRun {
    /// Distinguishes runs: a page that has this one does not need it again.
    pub id: u64,
    /// What started it: `run FILE`, `jog base +1 deg`.
    pub what: String,
    /// Each commanded point's end, milliseconds from the start (the first is the start).
    pub t_ms: Vec<f64>,
    /// The commanded positions (steps) at those times, one row per time.
    pub commanded: Vec<Vec<i32>>,
}

/// The motion in progress (a run or a jog) and how it ended.
#[derive(Clone, Debug, Default)]
pub struct RunView {
    pub active: bool,
    pub total: usize,
    pub sent: usize,
    pub acked: usize,
    pub executed: usize,
    pub started: Option<Instant>,
    /// When it ended: the plot takes reports until [`PLOT_TAIL`] after.
    pub ended: Option<Instant>,
}

/// How long after a run's end its plot still takes the positions reported: the arm
/// settles, the last reports arrive.
pub const PLOT_TAIL: Duration = Duration::from_millis(500);

/// The shared snapshot.
#[derive(Debug, Default)]
pub struct Snapshot {
    /// Bumped on every change; a page's stream sends when it moved.
    pub version: u64,
    /// When the controller last answered.
    pub seen: Option<Instant>,
    pub status: Option<StatusReport>,
    pub location: Option<Location>,
    pub stop_text: String,
    pub read_only: bool,
    /// Who owns the controller when this pendant does not (from DISCOVER).
    pub owner: Option<String>,
    pub config: Option<ArmConfig>,
    pub run: RunView,
    pub plot: PlotRun,
    /// The last action's outcome, for every page: `jog base: at 10.00 deg`.
    pub message: String,
    /// Whether the last message is an error.
    pub error: bool,
    /// Whether the controller takes HOLD, RESUME and OVERRIDE (issue 32): it answered
    /// the MOTION report.
    pub hold_available: bool,
    /// The speed factor and hold (the MOTION report, issue 32).
    pub motion: Option<MotionReport>,
    /// Whether the stop cause is to be asked again (a STOPPED was sent).
    pub stop_stale: bool,
    /// Whether moving the arm needs the token (served on a non-loopback address).
    pub token_needed: bool,
}

/// The snapshot and the wake-up of every page's stream.
#[derive(Debug, Default)]
pub struct Live {
    snapshot: Mutex<Snapshot>,
    changed: Condvar,
    next_run: std::sync::atomic::AtomicU64,
}

impl Live {
    /// The snapshot, locked (a poisoned lock is taken as it is: it holds plain data).
    pub fn lock(&self) -> MutexGuard<'_, Snapshot> {
        self.snapshot
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Changes the snapshot and wakes every stream.
    pub fn update(&self, change: impl FnOnce(&mut Snapshot)) {
        let mut s = self.lock();
        change(&mut s);
        s.version = s.version.wrapping_add(1);
        drop(s);
        self.changed.notify_all();
    }

    /// Waits until the version differs from `seen`, at most `timeout`; the version now.
    pub fn wait(&self, seen: u64, timeout: Duration) -> u64 {
        let s = self.lock();
        let (s, _) = self
            .changed
            .wait_timeout_while(s, timeout, |s| s.version == seen)
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        s.version
    }

    /// A new run id.
    pub fn new_run_id(&self) -> u64 {
        self.next_run.fetch_add(1, Ordering::Relaxed) + 1
    }

    /// Records an action's outcome for every page.
    pub fn say(&self, message: impl Into<String>, error: bool) {
        let message = message.into();
        self.update(|s| {
            s.message = message;
            s.error = error;
        });
    }
}

impl Snapshot {
    /// The joints in use.
    pub fn joints(&self) -> usize {
        self.status
            .map_or(0, |s| usize::from(s.joints))
            .min(MAX_JOINTS)
    }

    /// The snapshot as the page's JSON.
    pub fn to_json(&self, now: Instant) -> Value {
        let joints = self.joints();
        let age = self.seen.map(|t| now.saturating_duration_since(t));
        let config = self.config.as_ref();
        let units = config.map_or(Units::Steps, |c| c.units);
        let names: Vec<String> = (0..joints)
            .map(|j| {
                config
                    .and_then(|c| c.joints.get(j))
                    .and_then(|c| c.name.clone())
                    .unwrap_or_else(|| format!("j{j}"))
            })
            .collect();
        let steps: Vec<i32> = self
            .location
            .map(|l| l.position[..joints].to_vec())
            .unwrap_or_default();
        let shown: Vec<String> = steps
            .iter()
            .enumerate()
            .map(|(j, p)| match config.and_then(|c| c.joints.get(j)) {
                Some(joint) => units.show(i64::from(*p), joint),
                None => format!("{p} steps"),
            })
            .collect();
        let status = self.status.map(|s| {
            let flag = |bit| s.flags.has(bit);
            json!({
                "state": s.state.name(),
                "version": format!("{}.{}.{}", s.version[0], s.version[1], s.version[2]),
                "buffered": s.buffered,
                "capacity": s.capacity,
                "expected": s.expected,
                "received": s.received,
                "executed": s.executed,
                "reports_on": flag(StatusFlags::REPORTS_ON),
                "drivers_enabled": flag(StatusFlags::DRIVERS_ENABLED),
                "enabled_mask": s.drivers_enabled(),
                "serial_open": flag(StatusFlags::SERIAL_OPEN),
                "pwm_active": flag(StatusFlags::PWM_ACTIVE),
                "pin0_high": flag(StatusFlags::PIN0_HIGH),
                "pin1_high": flag(StatusFlags::PIN1_HIGH),
                "estop_open": s.more_flags.has(MoreFlags::ESTOP_OPEN),
                "estop_latched": s.more_flags.has(MoreFlags::ESTOP_LATCHED),
                "report_period_us": s.upload_period_us,
            })
        });
        // The LOCATION's state is newer than the last STATUS during a run.
        let state = self
            .location
            .map(|l| State::name_of(l.state))
            .or(self.status.map(|s| s.state.name()));
        json!({
            "connected": age.is_some_and(|a| a < STALE_AFTER),
            "age_ms": age.map(|a| a.as_millis() as u64),
            "state": state,
            "status": status,
            "joints": joints,
            "names": names,
            "units": units.name(),
            "steps": steps,
            "shown": shown,
            "stop_cause": self.stop_text,
            "read_only": self.read_only,
            "owner": self.owner,
            "run": {
                "id": self.plot.id,
                "what": self.plot.what,
                "active": self.run.active,
                "total": self.run.total,
                "sent": self.run.sent,
                "acked": self.run.acked,
                "executed": self.run.executed,
                // The time on the plot's axis; none once the run's tail is over.
                "t_ms": self.run.started
                    .filter(|_| self.run.ended.is_none_or(|e| now.saturating_duration_since(e) < PLOT_TAIL))
                    .map(|t| now.saturating_duration_since(t).as_secs_f64() * 1e3),
            },
            "message": self.message,
            "error": self.error,
            "hold_available": self.hold_available,
            "motion": self.motion.map(|m| json!({
                "factor_percent": m.factor_percent,
                "rate_permille": m.rate_permille,
                "held": m.flags.has(MotionFlags::HELD),
                "at_rest": m.flags.has(MotionFlags::AT_REST),
                "ramping": m.flags.has(MotionFlags::RAMPING),
                "underrun": m.flags.has(MotionFlags::UNDERRUN_RAMP),
                "door_open": m.flags.has(MotionFlags::DOOR_OPEN),
                "estop_ramp": m.flags.has(MotionFlags::ESTOP_RAMP),
                // 0 or 1 (IEC 60204-1); null: a byte this pendant does not know.
                "estop_category": m.estop_category.map(|c| c as u8),
            })),
            "token_needed": self.token_needed,
        })
    }

    /// The plot's commanded points as JSON (the `run` event).
    pub fn plot_json(&self) -> Value {
        json!({
            "id": self.plot.id,
            "what": self.plot.what,
            "t_ms": self.plot.t_ms,
            "commanded": self.plot.commanded,
        })
    }
}

/// The arm as the controller describes it (names, units), else `joints` unnamed joints in
/// steps. From a host that does not own the controller the limits (LIMITS_GET) are not
/// told, but the descriptions are (JOINT_DESC_GET, read-only from any host): names and
/// units then, without limits (a read-only pendant moves nothing).
pub fn arm_config(arm: &Client, status: &StatusReport) -> ArmConfig {
    let joints = usize::from(status.joints).clamp(1, MAX_JOINTS);
    let mut config = ArmConfig::unlimited(joints, status.max_step_rate_hz);
    match arm.described_arm(joints, status.max_step_rate_hz) {
        Ok(Some(described)) => return described,
        Ok(None) => return config,
        Err(_) => {}
    }
    let mut described = false;
    let mut units = None;
    for (j, joint) in config.joints.iter_mut().enumerate() {
        let Ok(desc) = arm.joint_desc(u8::try_from(j).unwrap_or(0)) else {
            continue;
        };
        if desc.is_described() {
            if !described {
                described = true;
                units = Some(armctl::described::units_of(desc.unit));
            }
            joint.name = (!desc.name().is_empty()).then(|| desc.name().to_string());
            if desc.scale() != 0.0 {
                joint.steps_per_radian = desc.scale();
            }
            joint.zero_offset_steps = desc.zero_offset_steps;
        }
    }
    if let Some(units) = units {
        config.units = units;
    }
    config
}

/// Reads the controller for the pages until `quit` is set: LOCATION reports as the
/// owner (STATUS every [`STATUS_EVERY`] between runs), a look-only STATUS every
/// [`READ_ONLY_POLL`] when another host owns it.
pub fn poll(arm: &Client, live: &Live, quit: &AtomicBool) {
    let locations = arm.locations();
    let mut read_only = false;
    let mut claimed = false;
    let mut last_status = Instant::now() - STATUS_EVERY;
    let mut last_owner_check = Instant::now() - OWNER_EVERY;
    let mut last_state: Option<u8> = None;
    let mut was_active = false;
    let mut joints_described = 0u8;
    let mut read_only_polls = 0u32;
    while !quit.load(Ordering::Relaxed) {
        if !claimed && (!read_only || last_owner_check.elapsed() >= OWNER_EVERY) {
            match arm.claim_locations() {
                Ok(()) => {
                    claimed = true;
                    read_only = false;
                    live.update(|s| {
                        s.read_only = false;
                        s.owner = None;
                    });
                }
                Err(e) if e.status() == Some(StatusCode::NotOwner) => read_only = true,
                Err(_) => std::thread::sleep(READ_ONLY_POLL),
            }
        }
        let status = if read_only {
            if last_owner_check.elapsed() >= OWNER_EVERY {
                last_owner_check = Instant::now();
                let owner = owner_of(arm);
                live.update(|s| {
                    s.read_only = true;
                    s.owner = owner;
                });
            }
            std::thread::sleep(READ_ONLY_POLL);
            read_only_polls = read_only_polls.wrapping_add(1);
            if read_only_polls.is_multiple_of(READ_ONLY_MOTION_EVERY) {
                ask_motion(arm, live);
            }
            match arm.glance(true) {
                Ok(glance) => {
                    if glance.location.is_some() {
                        live.update(|s| s.location = glance.location);
                    }
                    Some((glance.status, true))
                }
                Err(_) => None,
            }
        } else {
            if let Ok(location) = locations.recv_timeout(Duration::from_millis(50)) {
                live.update(|s| {
                    s.seen = Some(Instant::now());
                    s.location = Some(location);
                });
            }
            let (running, uploaded) = {
                let s = live.lock();
                (s.run.active, s.run.total > 0 && s.run.acked >= s.run.total)
            };
            if running && !(uploaded && last_status.elapsed() >= STATUS_EVERY) {
                // STATUS waits behind an upload: the run's own STATUS reports instead.
                arm.last_status().map(|status| (status, false))
            } else if running {
                // Uploaded: the run's speed factor and hold (look only, like STATUS).
                last_status = Instant::now();
                ask_motion(arm, live).map(|status| (status, true))
            } else if last_status.elapsed() >= STATUS_EVERY {
                last_status = Instant::now();
                let status = arm.status();
                if status.is_ok() {
                    ask_motion(arm, live);
                }
                match status {
                    Ok(status) => Some((status, true)),
                    Err(e) if e.status() == Some(StatusCode::NotOwner) => {
                        // Another host took the controller over.
                        claimed = false;
                        read_only = true;
                        None
                    }
                    Err(_) => {
                        // Silent: ask for the reports again once it answers (a restarted
                        // controller sends them to nobody).
                        claimed = false;
                        None
                    }
                }
            } else {
                None
            }
        };
        // A fresh STATUS (`true`; the run's last one otherwise), published with the arm's
        // description when the joints change, so that no page shows joints without names.
        if let Some((status, fresh)) = status {
            let config = (status.joints != joints_described).then(|| {
                joints_described = status.joints;
                arm_config(arm, &status)
            });
            live.update(|s| {
                if fresh {
                    s.seen = Some(Instant::now());
                }
                s.status = Some(status);
                if let Some(config) = config {
                    s.config = Some(config);
                }
            });
        }
        // A run or a move just ended, or the first look: what ended the last run. The
        // LOCATION's state is the newest (STATUS is not asked during a run).
        let (state, active, stale) = {
            let s = live.lock();
            let state = s
                .location
                .map(|l| l.state)
                .or(s.status.map(|st| st.state as u8));
            (state, s.run.active, s.stop_stale)
        };
        let stopped = state == Some(State::Stopped as u8);
        if stopped && !active && (last_state != state || was_active || stale) {
            let text = match arm.stop_report() {
                Ok((status, stop)) => armctl::stop_cause_text(&status, stop.as_ref()),
                Err(e) => format!("unknown ({e})"),
            };
            live.update(|s| {
                s.stop_text = text;
                s.stop_stale = false;
            });
        }
        if state.is_some() {
            last_state = state;
        }
        was_active = active;
    }
}

/// The MOTION report (issue 32: speed factor, hold) into the snapshot; the STATUS that
/// came with it. A controller older than issue 32 answers none: hold stays unavailable.
fn ask_motion(arm: &Client, live: &Live) -> Option<StatusReport> {
    let (status, motion) = arm.motion().ok()?;
    live.update(|s| {
        s.hold_available = motion.is_some();
        s.motion = motion;
    });
    Some(status)
}

/// The host that owns the controller, as DISCOVER tells (`192.168.1.5`, `nobody`); `None`
/// when it does not answer DISCOVER.
fn owner_of(arm: &Client) -> Option<String> {
    let std::net::SocketAddr::V4(target) = arm.addr() else {
        return None;
    };
    let found = armctl::discover::discover(&armctl::discover::DiscoverOptions {
        target,
        bind: None,
        wait: Duration::from_millis(200),
        rounds: 1,
    })
    .ok()?;
    let reply = found.first()?.reply?;
    Some(match reply.owner {
        protocol::OwnerState::Free => "nobody".into(),
        protocol::OwnerState::Asker => "this pendant".into(),
        protocol::OwnerState::Other => std::net::Ipv4Addr::from(reply.owner_ip).to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_joints_in_degrees() -> Snapshot {
        let mut config = ArmConfig::unlimited(2, 4000);
        config.units = Units::Deg;
        for (joint, name) in config.joints.iter_mut().zip(["base", "shoulder"]) {
            joint.name = Some(name.into());
            // 4.5 steps a degree.
            joint.steps_per_radian = 4.5 * 180.0 / std::f64::consts::PI;
        }
        let status = StatusReport {
            joints: 2,
            state: State::Stopped,
            ..StatusReport::default()
        };
        let mut position = [0; MAX_JOINTS];
        position[..2].copy_from_slice(&[9, -45]);
        Snapshot {
            status: Some(status),
            location: Some(Location {
                position,
                state: State::Running as u8,
            }),
            config: Some(config),
            ..Snapshot::default()
        }
    }

    #[test]
    fn positions_by_name_in_the_arms_units_and_the_newest_state() {
        let now = Instant::now();
        let mut s = two_joints_in_degrees();
        s.seen = Some(now);
        let v = s.to_json(now);
        assert_eq!(v["names"], json!(["base", "shoulder"]));
        assert_eq!(v["units"], "deg");
        assert_eq!(v["steps"], json!([9, -45]));
        assert_eq!(v["shown"], json!(["2.00 deg", "-10.00 deg"]));
        // The LOCATION's state is newer than the last STATUS's.
        assert_eq!(v["state"], "RUNNING");
        assert_eq!(v["connected"], true);
    }

    #[test]
    fn a_silent_controller_is_not_answering() {
        let now = Instant::now();
        let mut s = two_joints_in_degrees();
        assert_eq!(s.to_json(now)["connected"], false, "never answered");
        s.seen = Some(now);
        assert_eq!(s.to_json(now + STALE_AFTER / 2)["connected"], true);
        assert_eq!(s.to_json(now + STALE_AFTER)["connected"], false);
    }

    #[test]
    fn the_plot_takes_positions_until_the_tail_after_the_run() {
        let now = Instant::now();
        let mut s = two_joints_in_degrees();
        s.run.started = Some(now);
        let at =
            |s: &Snapshot, ms| s.to_json(now + Duration::from_millis(ms))["run"]["t_ms"].as_f64();
        assert_eq!(at(&s, 250), Some(250.0));
        s.run.ended = Some(now + Duration::from_secs(1));
        assert_eq!(at(&s, 1_400), Some(1_400.0));
        assert_eq!(at(&s, 1_000 + PLOT_TAIL.as_millis() as u64), None);
    }
}

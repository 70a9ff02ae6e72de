//! What the page's buttons do: each a call on the shared [`Client`], answered at once; a
//! motion (jog, run) goes on in a thread of its own, one at a time, and its end is told to
//! every page through [`Live`]. The e-stop sends STOPPED before anything else, from the
//! request's own thread (STOPPED never waits behind an upload), then cancels the motion.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use armctl::motion::TargetArg;
use armctl::{Cancel, Client, RunOptions};
use protocol::{MAX_JOINTS, State};

use super::live::{Live, PlotRun};
use crate::motion::{Arm, MotionArgs};
use crate::run::RunArgs;

/// Why hold, resume and the speed override are not offered: the controller answers no
/// MOTION report (older than issue 32, which adds HOLD, RESUME and OVERRIDE).
pub const HOLD_NEEDED: &str = "needs a controller with HOLD (issue 32)";

/// The motion commands issue 32 adds, behind one call ([`Pendant::in_flight`]) so that the
/// page and its endpoints stay as they are when they come.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum InFlight {
    /// Pause the run on a ramp, keeping its place.
    Hold,
    /// Go on after a hold.
    Resume,
    /// The speed factor, percent.
    Override(u8),
}

/// The pendant's side of the controller: the client, the pages' snapshot, the motion in
/// progress and the last trajectory checked.
pub struct Pendant {
    pub arm: Arc<Client>,
    pub live: Arc<Live>,
    /// The motion in progress, cancelled by the e-stop.
    job: Mutex<Option<Cancel>>,
    /// Where uploaded trajectory files are kept (a directory of this process).
    dir: PathBuf,
    /// The last file checked: what `run` runs. Its bytes are kept, not a path, so a later
    /// upload (even one refused) never changes the file a run reads.
    checked: Mutex<Option<Checked>>,
    /// Numbers each check's own copy, so two checks at once never share a file.
    checks: std::sync::atomic::AtomicU64,
}

/// A trajectory file that passed its check.
#[derive(Clone)]
struct Checked {
    /// Its name as the page chose it (messages name it so).
    name: String,
    /// "json" or "csv": how it is read.
    ext: String,
    body: Arc<[u8]>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl Pendant {
    pub fn new(arm: Arc<Client>, live: Arc<Live>, dir: PathBuf) -> Pendant {
        Pendant {
            arm,
            live,
            job: Mutex::new(None),
            dir,
            checked: Mutex::new(None),
            checks: std::sync::atomic::AtomicU64::new(0),
        }
    }

    /// The e-stop: STOPPED at once, then the motion in progress cancelled.
    pub fn stop(&self) -> Result<String, String> {
        let sent = self.arm.stop();
        if let Some(cancel) = lock(&self.job).as_ref() {
            cancel.cancel();
        }
        match sent {
            Ok(_) => {
                self.live.update(|s| s.stop_stale = true);
                self.live.say("STOPPED: every joint stopped", false);
                Ok("STOPPED".into())
            }
            Err(e) => {
                let message = format!("STOPPED not acknowledged: {e}");
                self.live.say(message.clone(), true);
                Err(message)
            }
        }
    }

    /// Whether this pendant may move the arm: it owns the controller.
    fn may_move(&self) -> Result<(), String> {
        let s = self.live.lock();
        if s.read_only {
            return Err(format!(
                "read-only: {} owns the controller",
                s.owner.as_deref().unwrap_or("another host")
            ));
        }
        Ok(())
    }

    /// ESTOP_RESET, UNLOCK, RETURN (home), SET_ENABLE: one frame and its ACK.
    pub fn simple(&self, what: &str, enable: Option<bool>) -> Result<String, String> {
        self.may_move()?;
        if lock(&self.job).is_some() {
            return Err("a motion is in progress: wait for it, or STOP".into());
        }
        let result = match (what, enable) {
            ("home", _) => self.arm.go_home().map(|_| "RETURN: homing".to_string()),
            ("estop-reset", _) => self
                .arm
                .estop_reset()
                .map(|_| "ESTOP_RESET: latch cleared".to_string()),
            ("unlock", _) => self
                .arm
                .unlock()
                .map(|_| "UNLOCK: the limit switch's latch cleared".to_string()),
            ("enable", Some(on)) => {
                let joints = self.live.lock().joints().max(1);
                let mask = (1u16 << joints) - 1;
                self.arm.set_enable(mask, on).map(|_| {
                    if on {
                        "drivers enabled".to_string()
                    } else {
                        "drivers disabled (limp)".to_string()
                    }
                })
            }
            _ => return Err(format!("unknown action {what}")),
        }
        .map_err(|e| e.to_string());
        match &result {
            Ok(m) => self.live.say(m.clone(), false),
            Err(m) => self.live.say(m.clone(), true),
        }
        result
    }

    /// Hold, resume or the override (issue 32). HOLD from any host, as the controller takes
    /// it (a read-only pendant may hold another host's run); RESUME and OVERRIDE from the
    /// owner.
    pub fn in_flight(&self, what: InFlight) -> Result<String, String> {
        if !self.live.lock().hold_available {
            return Err(HOLD_NEEDED.into());
        }
        let result = match what {
            InFlight::Hold => self
                .arm
                .hold()
                .map(|_| "HOLD: the run slows to a standstill".to_string()),
            InFlight::Resume => {
                self.may_move()?;
                self.arm
                    .resume()
                    .map(|_| "RESUME: the run goes on".to_string())
            }
            InFlight::Override(percent) => {
                self.may_move()?;
                let percent = percent.clamp(
                    protocol::OVERRIDE_MIN_PERCENT,
                    protocol::OVERRIDE_MAX_PERCENT,
                );
                self.arm
                    .set_override(percent)
                    .map(|_| format!("OVERRIDE: speed {percent} %"))
            }
        }
        .map_err(|e| e.to_string());
        match &result {
            Ok(m) => self.live.say(m.clone(), false),
            Err(m) => self.live.say(m.clone(), true),
        }
        result
    }

    /// Starts a motion in a thread of its own, unless one is in progress.
    fn start_job(
        self: &Arc<Self>,
        what: String,
        body: impl FnOnce(&Pendant, Cancel) -> Result<String, String> + Send + 'static,
    ) -> Result<String, String> {
        self.may_move()?;
        let cancel = Cancel::new();
        {
            let mut job = lock(&self.job);
            if job.is_some() {
                return Err("a motion is in progress: wait for it, or STOP".into());
            }
            *job = Some(cancel.clone());
        }
        let id = self.live.new_run_id();
        self.live.update(|s| {
            s.run = Default::default();
            s.run.active = true;
            s.plot = PlotRun {
                id,
                what: what.clone(),
                ..PlotRun::default()
            };
            s.message = format!("{what}: started");
            s.error = false;
        });
        let me = Arc::clone(self);
        std::thread::spawn(move || {
            let result = body(&me, cancel.clone());
            let cancelled = cancel.is_cancelled();
            *lock(&me.job) = None;
            let (message, error) = match result {
                _ if cancelled => (format!("{what}: stopped by the e-stop"), true),
                Ok(m) => (format!("{what}: {m}"), false),
                Err(m) => (format!("{what}: {m}"), true),
            };
            me.live.update(|s| {
                s.run.active = false;
                s.run.ended = Some(Instant::now());
                s.message = message;
                s.error = error;
            });
        });
        Ok("started".into())
    }

    /// Jog: joint `joint` by `by` in the arm's units, on a planned profile.
    pub fn jog(self: &Arc<Self>, joint: usize, by: f64) -> Result<String, String> {
        if !by.is_finite() || by == 0.0 {
            return Err(format!("jog by {by}: a finite increment other than 0"));
        }
        let (name, units) = {
            let s = self.live.lock();
            if joint >= s.joints() {
                return Err(format!("joint {joint}: the arm has {} joints", s.joints()));
            }
            let config = s.config.as_ref();
            (
                config
                    .and_then(|c| c.joints.get(joint))
                    .and_then(|c| c.name.clone())
                    .unwrap_or_else(|| format!("j{joint}")),
                config.map_or(armctl::motion::Units::Steps, |c| c.units),
            )
        };
        self.start_job(
            format!("jog {name} {by:+} {}", units.name()),
            move |me, cancel| {
                let arm = Arm::new(
                    &me.arm,
                    &MotionArgs {
                        config: None,
                        units: None,
                        speed: 50,
                        segment_ms: 10.0,
                    },
                )?;
                let current = arm.position()?;
                let target = arm.targets(
                    &[TargetArg {
                        joint: Some(joint.to_string()),
                        value: by,
                    }],
                    true,
                    &current,
                )?;
                me.live.update(|s| s.run.started = Some(Instant::now()));
                let at = arm.move_to(&target, Some(cancel), true)?;
                Ok(format!("at {}", arm.positions_line(&at)))
            },
        )
    }

    /// `armctl check` of an uploaded trajectory file (`name` gives its kind: .json or
    /// .csv), from where the arm is; kept for [`Pendant::run`].
    pub fn check(&self, name: &str, body: &[u8]) -> Result<String, String> {
        let ext = std::path::Path::new(name)
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        let ext = match ext.as_deref() {
            Some(e @ ("json" | "csv")) => e.to_string(),
            _ => return Err(format!("{name}: a .json (JointTrajectory) or .csv file")),
        };
        let n = self
            .checks
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let path = self.dir.join(format!("check-{n}.{ext}"));
        *lock(&self.checked) = None;
        let converted = self.convert_copy(&path, name, body, None);
        let _ = std::fs::remove_file(&path);
        let converted = converted?;
        *lock(&self.checked) = Some(Checked {
            name: name.to_string(),
            ext,
            body: body.into(),
        });
        Ok(format!(
            "{name}: {}",
            crate::run::points_summary(&converted.points, converted.waypoints)
        ))
    }

    /// `body` written to `path` and converted (see [`Pendant::convert`]); messages name the
    /// file as the page chose it (`name`), not the copy kept here.
    fn convert_copy(
        &self,
        path: &std::path::Path,
        name: &str,
        body: &[u8],
        current: Option<[i32; MAX_JOINTS]>,
    ) -> Result<crate::run::Converted, String> {
        std::fs::write(path, body).map_err(|e| format!("{}: {e}", path.display()))?;
        self.convert(path, current).map_err(|e| {
            let e = e.replace(&path.display().to_string(), name);
            if e.contains("--config FILE") {
                // The page takes no config: the controller's description stands for it.
                format!(
                    "{e}; for the pendant, store the arm's description on the controller: `armctl config push ARM.json`"
                )
            } else {
                e
            }
        })
    }

    /// The file at `path` as points from `current` (the last position reported when
    /// `None`), with the arm the controller describes.
    fn convert(
        &self,
        path: &std::path::Path,
        current: Option<[i32; MAX_JOINTS]>,
    ) -> Result<crate::run::Converted, String> {
        let (position, joints, max_rate, config) = {
            let s = self.live.lock();
            let Some(status) = s.status else {
                return Err("the controller has not answered yet".into());
            };
            (
                current
                    .or(s.location.map(|l| l.position))
                    .unwrap_or_default(),
                s.joints().max(1),
                status.max_step_rate_hz,
                s.config.clone().filter(|c| {
                    c.units != armctl::motion::Units::Steps
                        || c.joints.iter().any(|j| j.name.is_some())
                }),
            )
        };
        let args = RunArgs {
            file: path.to_path_buf(),
            config: None,
            units: None,
            segment_ms: 10.0,
            window: None,
            start_after: None,
            record: None,
            dry_run: false,
            max_step_rate: max_rate,
            quiet: true,
            // The speed factor is the page's slider (OVERRIDE), not the run's.
            speed: None,
        };
        crate::run::convert(&args, &position, Some(joints), Some(max_rate), config)
    }

    /// Runs the trajectory checked last, converted again from where the arm is now.
    pub fn run(self: &Arc<Self>) -> Result<String, String> {
        let Some(checked) = lock(&self.checked).clone() else {
            return Err("choose a trajectory file first (it is checked before it runs)".into());
        };
        self.may_move()?;
        let status = self.live.lock().status;
        if let Some(status) = status {
            crate::motion::ready_to_move(&status)?;
        }
        self.start_job(format!("run {}", checked.name), move |me, cancel| {
            let current = me
                .arm
                .current_location(Duration::from_secs(2))
                .map_err(|e| e.to_string())?;
            // One job at a time (start_job), so the run's copy is its own.
            let path = me.dir.join(format!("run.{}", checked.ext));
            let converted =
                me.convert_copy(&path, &checked.name, &checked.body, Some(current.position))?;
            let points = converted.points;
            let joints = me.live.lock().joints().max(1);
            let mut t = 0.0;
            let mut t_ms = vec![0.0];
            let mut commanded = vec![current.position[..joints].to_vec()];
            for p in &points {
                t += f64::from(p.duration) / 1e3;
                t_ms.push(t);
                commanded.push(p.position[..joints].to_vec());
            }
            me.live.update(|s| {
                s.plot.t_ms = t_ms;
                s.plot.commanded = commanded;
                s.run.total = points.len();
            });
            let options = RunOptions {
                cancel: Some(cancel),
                ..RunOptions::default()
            };
            let report = me
                .arm
                .run_trajectory(&points, &options, |p| {
                    me.live.update(|s| {
                        s.run.total = p.total;
                        s.run.sent = p.sent;
                        s.run.acked = p.acked;
                        s.run.executed = p.executed;
                        if s.run.started.is_none() && p.state == State::Running {
                            s.run.started = Some(Instant::now());
                        }
                    });
                })
                .map_err(|e| crate::motion::drop_partial_upload(&me.arm, e.to_string()))?;
            Ok(format!(
                "{} points executed in {:.3} s",
                report.points,
                report.total_time.as_secs_f64()
            ))
        })
    }
}

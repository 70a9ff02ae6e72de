//! Uploading and running a trajectory: NEW, then PENDING frames streamed with a go-back-N
//! window and flow control from the ACKs, RUNING once enough is buffered, then waiting for
//! the controller to report the end of the run.

use std::time::{Duration, Instant};

use protocol::{
    Command, Location, MAX_POINTS_PER_FRAME, Point, State, StatusFlags, StatusReport, StopCause,
    StopReport, Tag,
};

use crate::client::{Client, check, lock, recv_cancellable};
use crate::error::{Error, Result, RunEnd};
use crate::interrupt::Cancel;

mod upload;

use upload::Upload;

/// Largest trajectory one NEW can announce. Longer ones are refused (not split): splitting
/// would stop the arm between uploads, which a caller must decide to do explicitly.
pub const MAX_POINTS: usize = protocol::limits::MAX_POINTS_PER_NEW;

/// Frames in flight at most: a controller takes a burst of 32 datagrams whole (the most
/// it may advertise in STATUS `window`), and recognises a retransmission among more frames
/// than that (docs/PROTOCOL.md, "Ordering, retransmission and duplicates"), so a go-back-N
/// resend of a whole window is still recognised.
pub const MAX_WINDOW: usize = protocol::limits::HOST_WINDOW;

/// The window of a controller that advertises none (STATUS `window` 0: an older
/// controller): what every controller takes back to back.
pub const DEFAULT_WINDOW: usize = protocol::DEFAULT_WINDOW as usize;

/// How a trajectory is uploaded and run.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Frames sent and not yet acknowledged at most (1 = stop-and-wait), up to
    /// [`MAX_WINDOW`]; 0 = the window the controller advertises in STATUS
    /// ([`DEFAULT_WINDOW`] for one that advertises none).
    pub window: usize,
    /// Points per PENDING frame, 1..=12.
    pub points_per_frame: usize,
    /// Send RUNING once this many points are acknowledged. `None`: once the buffer is full
    /// or every point is acknowledged (the largest lead over execution).
    pub start_after: Option<usize>,
    /// Wait for the run to end and check it executed every point.
    pub wait: bool,
    /// Give up waiting for the upload when no frame is acknowledged for this long.
    pub stall_timeout: Duration,
    /// Longest wait for the end of the run, from NEW; `None`: twice the trajectory's
    /// duration plus 10 s.
    pub completion_timeout: Option<Duration>,
    /// Once set, the upload and the wait for the end return [`Error::Interrupted`] within
    /// [`CANCEL_POLL`](crate::CANCEL_POLL) (no wait blocks longer without looking). Nothing
    /// is sent then: the caller stops the arm ([`Client::stop_until_acked`]).
    pub cancel: Option<Cancel>,
    /// The speed override to run at, percent 1..200 (issue 32): sent as OVERRIDE before
    /// NEW, and the upload's and the wait's timeouts stretched by 100 / percent. `None`:
    /// no OVERRIDE sent (the controller keeps whatever factor it has, 100 % unless a host
    /// set another).
    pub speed_percent: Option<u8>,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            window: 0,
            points_per_frame: MAX_POINTS_PER_FRAME,
            start_after: None,
            wait: true,
            stall_timeout: Duration::from_secs(5),
            completion_timeout: None,
            cancel: None,
            speed_percent: None,
        }
    }
}

/// Where a run is, for progress displays.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Progress {
    /// Points in the trajectory.
    pub total: usize,
    /// Points sent at least once.
    pub sent: usize,
    /// Points the controller acknowledged.
    pub acked: usize,
    /// Points executed (from ACK buffer counts during the upload, then STATUS).
    pub executed: usize,
    /// The controller's state as last reported.
    pub state: State,
}

/// What a finished run did.
#[derive(Clone, Debug, Default)]
pub struct RunReport {
    /// Points in the trajectory.
    pub points: usize,
    /// PENDING/RUNING frames in the upload.
    pub frames: usize,
    /// The window used (frames in flight at most).
    pub window: usize,
    /// Datagrams sent for the upload, retransmissions included.
    pub datagrams_sent: usize,
    /// Datagrams sent again (timeouts, go-back-N, buffer full).
    pub retransmissions: usize,
    /// OUT_OF_ORDER refusals seen.
    pub out_of_order: usize,
    /// BUFFER_FULL refusals seen.
    pub buffer_full: usize,
    /// ACK timeouts.
    pub timeouts: usize,
    /// From NEW to the last frame acknowledged.
    pub upload_time: Duration,
    /// From NEW to the end of the run (or of the upload when not waiting).
    pub total_time: Duration,
    /// STATUS after the run, when waited for.
    pub final_status: Option<StatusReport>,
    /// Positions after the run, when waited for.
    pub final_location: Option<Location>,
}

/// The error for a run that stopped early, from the STATUS after it and the STOP_CAUSE
/// report (issue 31; `None` from an older controller).
fn run_ended(status: Option<&StatusReport>, total: usize, stop: Option<&StopReport>) -> Error {
    // Received versus executed (PROTOCOL.md, "How the last run ended"): an underrun with
    // points received and not run, or with every point received, is the controller falling
    // behind its own buffer; only one that ran everything it had received, short of the
    // total, is an upload that came too slowly.
    let underrun = |s: &StatusReport| {
        if s.received > s.executed || usize::from(s.received) >= total {
            RunEnd::Starved
        } else {
            RunEnd::Underrun
        }
    };
    let reason = match status {
        // The stop cause (issue 31) first; the flags of an older controller otherwise.
        Some(s) => match s.stop_cause() {
            Some(StopCause::Stopped) => RunEnd::Stopped,
            Some(StopCause::EstopInput) => RunEnd::EstopInput,
            Some(StopCause::Fault) => RunEnd::Fault,
            Some(StopCause::Underrun) => underrun(s),
            Some(StopCause::LimitSwitch) => RunEnd::LimitSwitch,
            Some(_) => RunEnd::Unknown,
            None if s.flags.has(StatusFlags::STOPPED_BY_HOST) => RunEnd::Stopped,
            None if s.flags.has(StatusFlags::UNDERRUN) => underrun(s),
            None => RunEnd::Unknown,
        },
        None => RunEnd::Unknown,
    };
    Error::RunEnded {
        reason,
        executed: status.map(|s| s.executed),
        received: status.map(|s| s.received),
        total,
        stopped_by: crate::stopped_by(stop),
        controlled: reason == RunEnd::Underrun
            && stop.is_some_and(|s| s.cause == Some(StopCause::Underrun) && s.detail == 1),
        limit_switch: stop
            .filter(|s| reason == RunEnd::LimitSwitch && s.cause == Some(StopCause::LimitSwitch))
            .map(|s| (s.detail & 0x7f, s.detail & 0x80 != 0)),
    }
}

/// The window a STATUS advertises: datagrams the controller takes back to back
/// ([`DEFAULT_WINDOW`] when it advertises none, at most [`MAX_WINDOW`]).
pub fn window_of(status: &StatusReport) -> usize {
    match status.window {
        0 => DEFAULT_WINDOW,
        n => usize::from(n).min(MAX_WINDOW),
    }
}

impl Client {
    /// The window the controller advertises in STATUS (from the last STATUS this client
    /// received, else a fresh one): [`DEFAULT_WINDOW`] for a controller that advertises
    /// none, at most [`MAX_WINDOW`].
    pub fn advertised_window(&self) -> Result<usize> {
        let status = match self.last_status() {
            Some(status) => status,
            None => self.status()?,
        };
        Ok(window_of(&status))
    }

    /// Uploads `points` (NEW, PENDING frames through a go-back-N window with flow control,
    /// RUNING) and, if `options.wait`, waits for the run to end and checks that the
    /// controller executed every point. `progress` is called whenever the counts change.
    ///
    /// Refused past [`MAX_POINTS`] points: split long trajectories yourself (the arm stops
    /// between uploads).
    ///
    /// With [`RunOptions::cancel`] set, returns [`Error::Interrupted`] soon after it is
    /// cancelled, whether the upload is under way or the arm runs: send STOPPED then.
    pub fn run_trajectory(
        &self,
        points: &[Point],
        options: &RunOptions,
        mut progress: impl FnMut(&Progress),
    ) -> Result<RunReport> {
        let total = points.len();
        if total == 0 || total > MAX_POINTS {
            return Err(Error::InvalidTrajectory(format!(
                "{total} points: one upload takes 1 to {MAX_POINTS}"
            )));
        }
        if let Some(i) = points.iter().position(|p| p.duration < 1) {
            return Err(Error::InvalidTrajectory(format!(
                "point {i} has a duration of {} us (1 at least)",
                points[i].duration
            )));
        }
        let window = match options.window {
            0 => self.advertised_window()?,
            n => n,
        };
        let options = RunOptions {
            window: window.clamp(1, MAX_WINDOW),
            points_per_frame: options.points_per_frame.clamp(1, MAX_POINTS_PER_FRAME),
            ..options.clone()
        };
        let nominal_us: i64 = points.iter().map(|p| i64::from(p.duration)).sum();
        // Run at `speed` %: the run takes 100 / speed times as long.
        let speed = options.speed_percent.unwrap_or(100).max(1);
        let duration_us = nominal_us.saturating_mul(100) / i64::from(speed);
        let cancel = options.cancel.as_ref();
        let started = Instant::now();
        let locations = self.locations();
        let mut report = {
            let _upload = lock(&self.upload);
            if cancel.is_some_and(Cancel::is_cancelled) {
                return Err(Error::Interrupted);
            }
            if let Some(percent) = options.speed_percent {
                check(
                    Tag::Override,
                    self.exchange_unlocked(&Command::Override { percent }, cancel)?,
                )?;
            }
            let ack = check(
                Tag::New,
                self.exchange_unlocked(
                    &Command::New {
                        count: total as u16,
                    },
                    cancel,
                )?,
            )?;
            let mut upload = Upload::new(self, &options, points, &ack, duration_us);
            upload.run(&mut progress)?;
            upload.into_report()
        };
        report.points = total;
        report.upload_time = started.elapsed();
        if !options.wait {
            report.total_time = started.elapsed();
            return Ok(report);
        }
        let timeout = options
            .completion_timeout
            .unwrap_or(Duration::from_micros(duration_us as u64) * 2 + Duration::from_secs(10));
        let deadline = started + timeout;
        let status = loop {
            let status = self.status_cancellable(cancel)?;
            progress(&Progress {
                total,
                sent: total,
                acked: total,
                executed: usize::from(status.executed),
                state: status.state,
            });
            if status.state == State::Stopped {
                // Confirmed by a second report: a late duplicate of an old one (a lossy
                // link duplicates and delays) must not end the wait.
                let again = self.status_cancellable(cancel)?;
                if again.state == State::Stopped {
                    break again;
                }
            }
            if Instant::now() >= deadline {
                return Err(Error::Stalled {
                    acked: total,
                    total,
                    waited: timeout,
                });
            }
            // Every state change sends a LOCATION at once: it ends this wait early.
            let until = Instant::now() + Duration::from_millis(100);
            while let Ok(location) = recv_cancellable(
                &locations,
                until.saturating_duration_since(Instant::now()),
                cancel,
            )? {
                if location.state == State::Stopped as u8 {
                    break;
                }
            }
        };
        report.final_status = Some(status);
        if status.flags.has(StatusFlags::REPORTS_ON) {
            // The reports queued so far may predate the end; take a fresh one.
            while locations.try_recv().is_ok() {}
            let wait = Duration::from_micros(u64::from(status.upload_period_us) * 3)
                .max(Duration::from_millis(100));
            report.final_location = recv_cancellable(&locations, wait, cancel)?.ok();
            // None came in time (a busy host or controller delays the periodic report past
            // the wait): ask for one (STATUS with a LOCATION), rather than report none.
            if report.final_location.is_none() {
                report.final_location = self.glance(false).ok().and_then(|g| g.location);
            }
        }
        report.total_time = started.elapsed();
        let clean = !status.flags.has(StatusFlags::UNDERRUN)
            && !status.flags.has(StatusFlags::STOPPED_BY_HOST)
            && status.stop_cause().is_none_or(|c| c == StopCause::Complete)
            && usize::from(status.executed) == total;
        if clean {
            Ok(report)
        } else {
            // Who stopped it, if the controller tells (issue 31).
            let stop = self
                .stop_report_cancellable(cancel)
                .ok()
                .and_then(|(_, s)| s);
            Err(run_ended(Some(&status), total, stop.as_ref()))
        }
    }
}

#[cfg(test)]
mod tests;

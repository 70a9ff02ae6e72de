//! The upload engine behind [`Client::run_trajectory`]: frames built as the window allows,
//! go-back-N on a loss or OUT_OF_ORDER, BUFFER_FULL back-off, the congestion window, and
//! RUNING once enough is buffered.

use std::sync::mpsc::RecvTimeoutError;
use std::time::{Duration, Instant};

use protocol::{Command, MAX_DATAGRAM, Point, PointList, State, StatusCode, Tag};

use super::{Progress, RunOptions, RunReport, run_ended};
use crate::client::{Client, Event, lock};
use crate::error::{Error, Result};
use crate::interrupt::CANCEL_POLL;

/// One frame of the upload.
struct Outgoing {
    seq: u8,
    tag: Tag,
    bytes: Vec<u8>,
    /// Points it carries (0 for RUNING).
    points: usize,
    acked: bool,
    /// Latest transmission.
    sent_at: Instant,
    /// Transmissions so far.
    sends: u32,
    /// The session its latest copy was sealed in (with a key).
    sealed_in: crate::client::SealedIn,
}

/// The upload in progress.
///
/// `frames[..base]` are acknowledged, `frames[base..next_send]` are in flight (some may be
/// acknowledged out of order), `frames[next_send..]` wait to be sent again after a
/// go-back-N. New frames are built only when every built frame is in flight.
pub(super) struct Upload<'a, 'p> {
    controller: &'a Client,
    options: &'a RunOptions,
    points: &'p [Point],
    waiter: crate::client::AckWaiter<'a>,
    frames: Vec<Outgoing>,
    /// First frame not yet acknowledged.
    base: usize,
    /// Next frame to (re)send.
    next_send: usize,
    /// Congestion window, frames: halved on a loss, grows by one per window of ACKs, up
    /// to `options.window`. A burst the controller's receive queue cannot hold is lost
    /// whole; this keeps go-back-N from repeating it.
    cwnd: f64,
    /// Points handed to frames so far.
    points_framed: usize,
    acked_points: usize,
    /// `free` from the latest ACK that told it, and the index of the last frame that ACK
    /// accounts for (`None`: NEW's ACK).
    free: (usize, Option<usize>),
    /// `buffered` from the latest ACK.
    buffered: usize,
    /// When the latest `free` arrived: slots drain from then on while running.
    free_since: Instant,
    executed: usize,
    /// How fast the controller has been running the points, as seen from here: when
    /// `executed` was first seen above 0 and what it was then, and the points' nominal
    /// time over the real time they took (1.0 on a board; 4.0 for a simulator at
    /// `--time-scale 4`). A BUFFER_FULL back-off waits for the slots to drain at that
    /// pace, not at the points' nominal one (a simulator at 4x drained the buffer while
    /// the upload waited four times too long; issue 19's runs under load).
    drain_anchor: Option<(Instant, usize)>,
    drain_speed: Option<f64>,
    runing_sent: bool,
    /// The frame the controller last answered BUFFER_FULL, every frame before it taken:
    /// while it is the first unacknowledged one, the buffer is known to be full.
    full_at: Option<usize>,
    state: State,
    /// BUFFER_FULL back-off: resend from this frame once the instant has passed.
    resume: Option<(Instant, usize)>,
    /// Last go-back-N target and when, so that a burst of OUT_OF_ORDER is answered once.
    last_rewind: Option<(usize, Instant)>,
    last_progress: Instant,
    timeouts_in_a_row: usize,
    /// The whole upload ends by then: twice the trajectory's duration plus two stall
    /// timeouts (streaming cannot need longer than the run itself, with room for a
    /// controller whose clock runs slow).
    deadline: Instant,
    report: RunReport,
}

/// ACK timeouts in a row, without any progress, after which an upload gives up (with
/// [`UPLOAD_MAX_DOUBLINGS`], at least 1.5 s at the 3 ms floor; `stall_timeout` usually
/// ends it first).
const MAX_TIMEOUTS_IN_A_ROW: usize = 250;

/// Back-off doublings an upload frame's ACK timeout takes at most (twice the estimate):
/// on a LAN losses are random rather than congestion, a resend too many is only a
/// duplicate the controller ACKs again, and a streak of losses must not let the running
/// arm's buffer run dry while the client waits.
const UPLOAD_MAX_DOUBLINGS: u32 = 1;

impl<'a, 'p> Upload<'a, 'p> {
    /// The upload after NEW was acknowledged with `ack`; `duration_us` is the whole
    /// trajectory's, for the deadline.
    pub(super) fn new(
        controller: &'a Client,
        options: &'a RunOptions,
        points: &'p [Point],
        ack: &protocol::Ack,
        duration_us: i64,
    ) -> Self {
        Upload {
            controller,
            options,
            points,
            waiter: controller.waiter(),
            frames: Vec::new(),
            base: 0,
            next_send: 0,
            cwnd: options.window as f64,
            points_framed: 0,
            acked_points: 0,
            free: (usize::from(ack.free), None),
            buffered: usize::from(ack.buffered),
            free_since: Instant::now(),
            executed: 0,
            drain_anchor: None,
            drain_speed: None,
            runing_sent: false,
            full_at: None,
            state: ack.state,
            resume: None,
            last_rewind: None,
            last_progress: Instant::now(),
            timeouts_in_a_row: 0,
            deadline: Instant::now()
                + Duration::from_micros(duration_us as u64) * 2
                + options.stall_timeout * 2,
            report: RunReport::default(),
        }
    }

    /// The report of a finished upload, with its frame count and window.
    pub(super) fn into_report(mut self) -> RunReport {
        self.report.frames = self.frames.len();
        self.report.window = self.options.window;
        self.report
    }
}

/// Frames the upload keeps in flight however many are lost. With one, a lost PENDING is
/// found only by its ACK timeout (60-100 ms on a loaded host, while a 4x run drains 24-40
/// points); with four, the OUT_OF_ORDER answer to the next frame reveals it within a round
/// trip. Loss on this link is rarely congestion: the controller takes a whole advertised
/// window (32) at once.
pub(super) const MIN_LOSS_WINDOW: usize = 4;

/// The congestion window after a loss: halved, never below [`MIN_LOSS_WINDOW`] (nor above
/// the window the run allows).
pub(super) fn shrunk_window(cwnd: f64, window: usize) -> f64 {
    (cwnd / 2.0).max(MIN_LOSS_WINDOW.min(window).max(1) as f64)
}

impl Upload<'_, '_> {
    fn in_flight(&self) -> usize {
        self.next_send.saturating_sub(self.base)
    }

    /// Frames that may be in flight now.
    fn window(&self) -> usize {
        (self.cwnd as usize).clamp(1, self.options.window)
    }

    /// Slots the controller should have free for the next new frame.
    fn credit(&self) -> usize {
        let (free, at) = self.free;
        let after = at.map_or(0, |i| i + 1);
        let unconfirmed: usize = self.frames[after.min(self.frames.len())..]
            .iter()
            .filter(|f| !f.acked)
            .map(|f| f.points)
            .sum();
        free.saturating_sub(unconfirmed)
    }

    fn next_chunk(&self) -> usize {
        self.options
            .points_per_frame
            .min(self.points.len() - self.points_framed)
    }

    fn should_start(&self) -> bool {
        if self.runing_sent || self.acked_points == 0 {
            return false;
        }
        let total = self.points.len();
        // Full as the controller has confirmed it: RUNING is not ordered behind PENDING
        // (section 7), so sent after frames still in flight it could overtake a lost one
        // and start the run with part of the buffer (issue 19: 108 of 256 points).
        let buffer_full = self.full_at == Some(self.base)
            || (self.points_framed < total
                && self.base == self.frames.len()
                && self.credit() < self.next_chunk());
        let enough = self
            .options
            .start_after
            .is_some_and(|n| self.acked_points >= n.min(total));
        let start = enough || buffer_full || self.acked_points == total;
        if start {
            log::debug!(
                "RUNING after {} points acked ({} framed): credit {}, free {:?}, buffer full {buffer_full}",
                self.acked_points,
                self.points_framed,
                self.credit(),
                self.free
            );
        }
        start
    }

    /// Builds the next frame (sent by [`Upload::send_next`]).
    fn push(&mut self, command: &Command<'_>, points: usize) -> Result<()> {
        let mut buf = [0u8; MAX_DATAGRAM];
        let seq = self.controller.alloc_seq();
        let len = command.encode(seq, &mut buf)?;
        self.waiter.expect(seq);
        self.frames.push(Outgoing {
            seq,
            tag: command.tag(),
            bytes: buf[..len].to_vec(),
            points,
            acked: false,
            sent_at: Instant::now(),
            sends: 0,
            sealed_in: None,
        });
        Ok(())
    }

    /// Sends `frames[next_send]`, unchanged if it was sent before.
    fn send_next(&mut self) -> Result<()> {
        let frame = &mut self.frames[self.next_send];
        frame.sealed_in = self.controller.send_bytes(&frame.bytes)?;
        frame.sent_at = Instant::now();
        frame.sends += 1;
        self.report.datagrams_sent += 1;
        if frame.sends > 1 {
            self.report.retransmissions += 1;
        }
        self.next_send += 1;
        Ok(())
    }

    /// Sends `frames[i]` ahead of the frames before it (a go-back-N resend of it later is a
    /// duplicate the controller re-ACKs).
    fn send_out_of_turn(&mut self, i: usize) -> Result<()> {
        let frame = &mut self.frames[i];
        frame.sealed_in = self.controller.send_bytes(&frame.bytes)?;
        frame.sent_at = Instant::now();
        frame.sends += 1;
        self.report.datagrams_sent += 1;
        Ok(())
    }

    /// Go-back-N: every unacknowledged frame from `from` on is sent again, unchanged, as
    /// the window allows. `loss`: a frame was lost, so the window shrinks.
    fn rewind(&mut self, from: usize, loss: bool) {
        log::debug!("go back to frame {from}");
        self.last_rewind = Some((from, Instant::now()));
        self.next_send = self.next_send.min(from.max(self.base));
        if loss {
            self.cwnd = shrunk_window(self.cwnd, self.options.window);
        }
    }

    fn confirm(&mut self, i: usize) {
        if self.frames[i].acked {
            return;
        }
        self.frames[i].acked = true;
        self.acked_points += self.frames[i].points;
        self.last_progress = Instant::now();
        self.timeouts_in_a_row = 0;
        while self.base < self.frames.len() && self.frames[self.base].acked {
            self.base += 1;
        }
        self.next_send = self.next_send.max(self.base);
    }

    /// How long until about `needed` more slots drain, from the durations of the points
    /// waiting in the buffer: the back-off after BUFFER_FULL or when out of credit.
    fn drain_wait(&self, needed: usize) -> Duration {
        let first = self.executed.min(self.points.len());
        let end = (first + needed.max(1)).min(self.points.len());
        let us: i64 = self.points[first..end]
            .iter()
            .map(|p| i64::from(p.duration))
            .sum();
        // At the pace the controller has been running them (never slower than nominal:
        // a controller that has fallen behind only costs BUFFER_FULL round trips).
        let speed = self.drain_speed.unwrap_or(1.0).max(1.0);
        let us = (us as f64 / speed) as i64;
        // A tenth more and a millisecond: the controller frees a slot only once the
        // point's last step is due, and its timer may run a little behind ours. Too early
        // costs one BUFFER_FULL round trip; too late lets the buffer run low.
        Duration::from_micros((us.clamp(500, 200_000) * 11 / 10 + 1_000) as u64)
    }

    /// `executed` grew to `now_executed`: updates the observed drain speed, once at least
    /// 100 ms and a few points have passed since the anchor (shorter spans are noise).
    fn observe_drain(&mut self, now_executed: usize) {
        let now = Instant::now();
        let Some((since, from)) = self.drain_anchor else {
            if now_executed > 0 {
                self.drain_anchor = Some((now, now_executed));
            }
            return;
        };
        let real = now.duration_since(since);
        if real < Duration::from_millis(100) || now_executed < from + 4 {
            return;
        }
        let end = now_executed.min(self.points.len());
        let nominal_us: i64 = self.points[from.min(end)..end]
            .iter()
            .map(|p| i64::from(p.duration))
            .sum();
        self.drain_speed = Some(nominal_us as f64 / real.as_micros().max(1) as f64);
        self.drain_anchor = Some((now, now_executed));
    }

    fn progress(&self) -> Progress {
        Progress {
            total: self.points.len(),
            sent: self.points_framed,
            acked: self.acked_points,
            executed: self.executed,
            state: self.state,
        }
    }

    /// Whether an OUT_OF_ORDER naming frame `j`, in answer to frame `i`, is old news: it
    /// answers a copy of `i` sent before the latest go-back-N, or comes so soon after
    /// that go-back-N (within two round trips) that it may.
    fn stale_out_of_order(&self, i: usize, j: usize) -> bool {
        let Some((target, when)) = self.last_rewind else {
            return false;
        };
        if target > j {
            return false;
        }
        if self.frames[i].sent_at < when {
            return true;
        }
        // Answers to copies of `i` that left before the go-back-N arrive within about a
        // round trip of it; later ones answer copies sent after it.
        let rtt = lock(&self.controller.rtt).clone();
        let settle = rtt.srtt().map_or(rtt.rto() / 2, |srtt| {
            (srtt * 2 + Duration::from_micros(500)).min(rtt.rto())
        });
        when.elapsed() < settle
    }

    fn on_ack(&mut self, seq: u8, ack: protocol::Ack) -> Result<()> {
        if ack.status == StatusCode::AuthFailed && ack.acked_tag == Tag::Auth as u8 {
            // An envelope refused: its session is gone (the refusal names the envelope's
            // tag). The next send says HELLO again; the frame goes again when its wait
            // runs out, in the new session, where a copy that did arrive is a duplicate.
            if let Some(frame) = self.frames[self.base..].iter().find(|f| f.seq == seq) {
                self.controller.session_lost(frame.sealed_in);
            }
            return Ok(());
        }
        let Some(i) = self.frames[self.base..]
            .iter()
            .position(|f| f.seq == seq && f.tag as u8 == ack.acked_tag)
            .map(|p| p + self.base)
        else {
            // A late duplicate of something already settled.
            return Ok(());
        };
        self.state = ack.state;
        log::trace!(
            "ack of frame {i} (seq {seq}): {} next_seq {} free {} buffered {}; credit {} in flight {} window {} acked {}",
            ack.status.name(),
            ack.next_seq,
            ack.free,
            ack.buffered,
            self.credit(),
            self.in_flight(),
            self.window(),
            self.acked_points
        );
        match ack.status {
            StatusCode::Ok => {
                if self.frames[i].sends == 1 && !self.frames[i].acked {
                    // Karn's rule: only frames sent once time the round trip.
                    let sample = self.frames[i].sent_at.elapsed();
                    lock(&self.controller.rtt).sample(sample);
                }
                if !self.frames[i].acked {
                    self.cwnd = (self.cwnd + 1.0 / self.cwnd).min(self.options.window as f64);
                }
                self.confirm(i);
                if self.free.1.is_none_or(|at| at <= i) {
                    self.free = (usize::from(ack.free), Some(i));
                    self.free_since = Instant::now();
                    self.buffered = usize::from(ack.buffered);
                    if self.runing_sent {
                        let executed = self.acked_points.saturating_sub(self.buffered);
                        self.executed = self.executed.max(executed);
                        self.observe_drain(self.executed);
                    }
                }
            }
            StatusCode::OutOfOrder => {
                self.report.out_of_order += 1;
                let target = self.frames[self.base..]
                    .iter()
                    .position(|f| f.seq == ack.next_seq)
                    .map(|p| p + self.base);
                match target {
                    Some(j) => {
                        // The controller took everything before the first missing seq.
                        for k in self.base..j {
                            self.confirm(k);
                        }
                        if self.resume.is_none() && !self.stale_out_of_order(i, j) {
                            self.rewind(j, true);
                        }
                    }
                    None if self.frames.last().map(|f| f.seq.wrapping_add(1))
                        == Some(ack.next_seq) =>
                    {
                        for k in self.base..self.frames.len() {
                            self.confirm(k);
                        }
                    }
                    // Resent on timeout.
                    None => {}
                }
            }
            StatusCode::BufferFull => {
                // The controller answers: not a stall, however long its buffer takes to
                // drain (the upload's overall deadline still bounds this).
                self.last_progress = Instant::now();
                self.timeouts_in_a_row = 0;
                self.report.buffer_full += 1;
                // The controller checks the order before the room (section 7): every
                // frame before this one is in.
                for k in self.base..i {
                    self.confirm(k);
                }
                self.full_at = Some(i);
                self.free = (usize::from(ack.free), i.checked_sub(1));
                self.free_since = Instant::now();
                self.buffered = usize::from(ack.buffered);
                let needed = self.frames[i].points.saturating_sub(usize::from(ack.free));
                let wait = self.drain_wait(needed);
                // Nothing goes out until then; the frames after it come back
                // OUT_OF_ORDER, answered by the same resume.
                self.resume = Some((Instant::now() + wait, i));
                self.rewind(i, false);
            }
            StatusCode::BadCrc => self.rewind(i, true),
            StatusCode::BadState if ack.state == State::Stopped => {
                return Err(self.ended());
            }
            status => {
                return Err(Error::Refused {
                    command: self.frames[i].tag,
                    status,
                    state: ack.state,
                });
            }
        }
        Ok(())
    }

    /// The run stopped under the upload: find out why.
    fn ended(&self) -> Error {
        match self
            .controller
            .status_unlocked(self.options.cancel.as_ref())
        {
            Err(Error::Interrupted) => Error::Interrupted,
            status => {
                let status = status.ok();
                // Who stopped it, if the controller tells (issue 31).
                let stop = status
                    .filter(|s| s.stop_cause() == Some(protocol::StopCause::Stopped))
                    .and_then(|_| {
                        self.controller
                            .stop_report_unlocked(self.options.cancel.as_ref())
                            .ok()
                    })
                    .and_then(|(_, stop)| stop);
                run_ended(status.as_ref(), self.points.len(), stop.as_ref())
            }
        }
    }

    /// Sends what the window, the credit and the back-off allow; returns when a probe is
    /// due if it is waiting for slots to drain.
    fn fill(&mut self) -> Result<Option<Instant>> {
        let total = self.points.len();
        if !self.runing_sent && self.should_start() {
            self.push(&Command::Runing, 0)?;
            self.runing_sent = true;
            let runing = self.frames.len() - 1;
            if self.next_send < runing {
                // Frames before it wait to be resent after a BUFFER_FULL: RUNING is not
                // ordered behind them (section 7) and goes first, or the buffer they wait
                // for would never drain.
                self.send_out_of_turn(runing)?;
            }
        }
        if let Some((when, from)) = self.resume {
            if Instant::now() < when {
                return Ok(None);
            }
            self.resume = None;
            self.rewind(from, false);
        }
        while self.in_flight() < self.window() {
            // Frames to send again first (acknowledged ones are skipped).
            while self.next_send < self.frames.len() && self.frames[self.next_send].acked {
                self.next_send += 1;
            }
            if self.next_send < self.frames.len() {
                self.send_next()?;
                continue;
            }
            if self.should_start() {
                self.push(&Command::Runing, 0)?;
                self.runing_sent = true;
                continue;
            }
            if self.points_framed == total {
                break;
            }
            let n = self.next_chunk();
            let credit = self.credit();
            if credit < n {
                // Out of credit with nothing in flight, no ACK will bring news: once
                // the missing slots should have drained, one frame goes as a probe.
                let due = self.free_since + self.drain_wait(n - credit);
                let probe = self.in_flight() == 0 && self.runing_sent && Instant::now() >= due;
                if !probe {
                    return Ok((self.in_flight() == 0).then_some(due));
                }
            }
            let chunk = &self.points[self.points_framed..self.points_framed + n];
            self.push(&Command::Pending(PointList::Points(chunk)), n)?;
            self.points_framed += n;
        }
        Ok(None)
    }

    pub(super) fn run(&mut self, progress: &mut dyn FnMut(&Progress)) -> Result<()> {
        let total = self.points.len();
        let mut last_shown = Progress::default();
        loop {
            if self
                .options
                .cancel
                .as_ref()
                .is_some_and(|c| c.is_cancelled())
            {
                return Err(Error::Interrupted);
            }
            if self.last_progress.elapsed() > self.options.stall_timeout
                || self.timeouts_in_a_row > MAX_TIMEOUTS_IN_A_ROW
                || Instant::now() >= self.deadline
            {
                return Err(Error::Stalled {
                    acked: self.acked_points,
                    total,
                    waited: self.last_progress.elapsed(),
                });
            }
            let probe_due = self.fill()?;
            let shown = self.progress();
            if shown != last_shown {
                progress(&shown);
                last_shown = shown;
            }
            if self.base == self.frames.len() && self.points_framed == total && self.runing_sent {
                return Ok(());
            }
            let now = Instant::now();
            let ack_timeout = lock(&self.controller.rtt).rto_backed_off(UPLOAD_MAX_DOUBLINGS);
            let oldest = (self.base < self.next_send).then(|| self.frames[self.base].sent_at);
            let wake = match (self.resume, oldest) {
                (Some((when, _)), _) => when,
                (None, Some(sent)) => sent + ack_timeout,
                // Waiting for slots to drain: wake when the probe is due.
                (None, None) => probe_due.unwrap_or(now + Duration::from_millis(2)),
            };
            let mut wait = wake.saturating_duration_since(now);
            if self.options.cancel.is_some() {
                // Look at the cancel token again soon (a timeout before `wake` is harmless:
                // nothing is overdue yet, and the loop comes back here).
                wait = wait.min(CANCEL_POLL);
            }
            match self.waiter.rx.recv_timeout(wait) {
                Ok(Event::Ack(seq, ack)) => self.on_ack(seq, ack)?,
                Ok(Event::Refused) if self.controller.fails_fast_when_refused() => {
                    return Err(Error::ConnectionRefused {
                        addr: self.controller.addr(),
                    });
                }
                Ok(Event::Refused | Event::Hello | Event::WrongKey) => {}
                Err(RecvTimeoutError::Timeout) | Err(RecvTimeoutError::Disconnected) => {
                    let overdue = self.resume.is_none()
                        && self.base < self.next_send
                        && self.frames[self.base].sent_at.elapsed() >= ack_timeout;
                    if overdue {
                        log::debug!(
                            "ACK timeout ({} us), frame {}",
                            ack_timeout.as_micros(),
                            self.base
                        );
                        self.report.timeouts += 1;
                        self.timeouts_in_a_row += 1;
                        lock(&self.controller.rtt).back_off();
                        self.rewind(self.base, true);
                    }
                }
            }
        }
    }
}

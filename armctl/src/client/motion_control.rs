//! Issue 32's motion control in flight on the client: HOLD, RESUME, OVERRIDE and the MOTION
//! report (docs/PROTOCOL.md, "HOLD, RESUME, OVERRIDE").

use protocol::{Ack, Command, EStopCategory, MotionReport, StatusAsk, StatusReport, Tag};

use super::wire_tools::recv_within;
use super::{Client, check};
use crate::error::Result;

impl Client {
    /// HOLD: the run decelerates along its path to a standstill and waits (RUNNING, held);
    /// from any host. `BAD_STATE` when nothing runs; an older controller answers
    /// `UNKNOWN_TAG`.
    pub fn hold(&self) -> Result<Ack> {
        self.send(&Command::Hold)
            .and_then(|ack| check(Tag::Hold, ack))
    }

    /// RESUME: after a HOLD, back to the override; nothing when not held. The owner only.
    pub fn resume(&self) -> Result<Ack> {
        self.send(&Command::Resume)
            .and_then(|ack| check(Tag::Resume, ack))
    }

    /// OVERRIDE: the speed factor, percent 1..200, ramped in for the run under way and
    /// the start of the runs to come. Above 100 % refused `OVERRIDE_REFUSED` where a
    /// joint's rate or acceleration would go over its limit ([`Client::motion`] says
    /// which). The owner only.
    pub fn set_override(&self, percent: u8) -> Result<Ack> {
        self.send(&Command::Override { percent })
            .and_then(|ack| check(Tag::Override, ack))
    }

    /// ESTOP_CATEGORY: how the wired e-stop input stops the arm (0 at once, 1 a
    /// controlled stop then the drivers disabled), kept in the controller's settings; the
    /// ACK comes once saved. Only while STOPPED (`BAD_STATE`); the owner only; an older
    /// controller answers `UNKNOWN_TAG`. Read it back with [`Client::motion`] (MOTION's
    /// `estop_category`).
    pub fn set_estop_category(&self, category: EStopCategory) -> Result<Ack> {
        self.send(&Command::EstopCategory(category))
            .and_then(|ack| check(Tag::EstopCategory, ack))
    }

    /// STATUS with request byte bit 4 (look only, any host): the STATUS and the MOTION
    /// report (override, hold, ramp). The report is `None` from a controller older than
    /// issue 32 (it refuses the bit; the STATUS then comes from a plain STATUS) or if it
    /// was lost.
    pub fn motion(&self) -> Result<(StatusReport, Option<MotionReport>)> {
        let _upload = super::lock(&self.upload);
        let ask = StatusAsk {
            look_only: true,
            motion: true,
            ..StatusAsk::default()
        };
        let reports = self.status_reports();
        let (tx, motions) = std::sync::mpsc::channel();
        super::lock(&self.shared.motions).push(tx);
        let answer = self.ask_status(ask, None, |_| {
            let status = reports.recv_timeout(self.options.report_timeout).ok()?;
            // The MOTION report comes last after the STATUS.
            Some((status, recv_within(&motions, self.options.report_timeout)))
        })?;
        match answer {
            Some(answer) => Ok(answer),
            None => Ok((self.status_unlocked(None)?, None)),
        }
    }
}

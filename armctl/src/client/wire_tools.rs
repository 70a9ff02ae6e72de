//! Issue 23's wire-side commands on the client: SET_ENABLE, RELEASE, and STATUS with its
//! request byte (a LOCATION to the asker; look only), each docs/PROTOCOL.md section 4.

use std::time::{Duration, Instant};

use protocol::{
    Ack, Command, JointLimits, LimitsReport, LimitsSet, Location, StatusAsk, StatusCode,
    StatusReport, StopReport, Tag,
};

use super::{Client, check};
use crate::error::{Error, Result};

/// What a STATUS with a request byte brought back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Glance {
    /// The STATUS report.
    pub status: StatusReport,
    /// The LOCATION asked for; `None` from a controller older than the request byte
    /// (it refused it, and a plain STATUS was asked instead) or if it was lost.
    pub location: Option<Location>,
    /// Whether the controller answered read-only: another host owns it (or, looking
    /// only, nobody does). `false` from an older controller.
    pub read_only: bool,
}

/// What [`Client::diag`] brought back: the controller's own counters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Diagnosis {
    /// The STATUS report that came with them.
    pub status: StatusReport,
    /// The receive path's counters (RX ring overflows, shed datagrams, ...).
    pub rx: protocol::RxCounters,
    /// The board's timing (masked spans, DIR lateness, DMA slack); clocks of 0: not
    /// measured on this controller.
    pub diag: protocol::Diag,
}

impl Client {
    /// SET_ENABLE: enables (`enable`, holding) or disables (limp) the drivers of `mask`
    /// (bits 0-7 joints, bit 8 gripper), leaving the others as they are; idempotent,
    /// unlike [`Client::toggle_enable`]. Only while STOPPED. An older controller answers
    /// `UNKNOWN_TAG` (docs/PROTOCOL.md, SET_ENABLE).
    pub fn set_enable(&self, mask: u16, enable: bool) -> Result<Ack> {
        self.send(&Command::SetEnable { mask, enable })
    }

    /// RELEASE: gives the controller up (only while STOPPED): the next host to speak takes
    /// it at once. This client's next command takes it back, unless another's came first.
    pub fn release(&self) -> Result<Ack> {
        self.send(&Command::Release)
    }

    /// STATUS with a LOCATION (the positions), from any host: the owner's STATUS as
    /// ever; another host's is answered read-only (docs/PROTOCOL.md section 1). With
    /// `look_only`, it never makes this host the owner, even of a free controller. An
    /// older controller refuses the request byte (`BAD_LENGTH`): a plain STATUS then, no
    /// positions.
    pub fn glance(&self, look_only: bool) -> Result<Glance> {
        let _upload = super::lock(&self.upload);
        let ask = StatusAsk {
            location: true,
            look_only,
            stop_cause: false,
            counters: false,
            diag: false,
            motion: false,
            switches: false,
        };
        let reports = self.status_reports();
        let locations = self.locations();
        let answer = self.ask_status(ask, None, |ack| {
            // A read-only answer's ACK has the NOT_OWNER zeros; the owner's has its
            // buffer's free slots (capacity > 0).
            let read_only = ack.free == 0 && ack.buffered == 0 && ack.next_seq == 0;
            let status = reports.recv_timeout(self.options.report_timeout).ok()?;
            // The LOCATION comes right after the STATUS; any LOCATION from now on is as
            // fresh.
            let location = recv_within(&locations, self.options.report_timeout);
            Some(Glance {
                status,
                location,
                read_only: read_only && status.capacity > 0,
            })
        })?;
        match answer {
            Some(glance) => Ok(glance),
            None => Ok(Glance {
                status: self.status_unlocked(None)?,
                location: None,
                read_only: false,
            }),
        }
    }

    /// STATUS with the request byte `ask` (the caller holds the upload lock and has
    /// subscribed to the reports it waits for), `attempts` times: once one is ACKed OK,
    /// `reports` waits for its answers (`None`: one was lost, ask again). `Ok(None)`: a
    /// controller older than what `ask` asks for refused it (`INVALID_CONFIG` for a bit
    /// it does not know, `BAD_LENGTH` for the byte before issue 23).
    pub(super) fn ask_status<T>(
        &self,
        ask: StatusAsk,
        cancel: Option<&crate::Cancel>,
        mut reports: impl FnMut(&Ack) -> Option<T>,
    ) -> Result<Option<T>> {
        for _ in 0..self.options.attempts {
            let ack = self.exchange_unlocked(&Command::StatusWith(ask), cancel)?;
            if matches!(
                ack.status,
                StatusCode::InvalidConfig | StatusCode::BadLength
            ) {
                return Ok(None);
            }
            let ack = check(Tag::Status, ack)?;
            if let Some(answer) = reports(&ack) {
                return Ok(Some(answer));
            }
        }
        Err(Error::NoReport {
            command: Tag::Status,
            attempts: self.options.attempts,
        })
    }
}

impl Client {
    /// What ended the last run and who sent the STOPPED (issue 31): STATUS with request
    /// byte bit 2 (look only, from any host), answered with the STATUS and a STOP_CAUSE
    /// report. The report is `None` from a controller older than issue 31 (it refuses the
    /// bit: `INVALID_CONFIG`, or `BAD_LENGTH` before issue 23; the STATUS then comes from
    /// a plain STATUS) or if it was lost.
    pub fn stop_report(&self) -> Result<(StatusReport, Option<StopReport>)> {
        let _upload = super::lock(&self.upload);
        self.stop_report_unlocked(None)
    }

    /// As [`Client::stop_report`], every wait looking at `cancel`.
    pub(crate) fn stop_report_cancellable(
        &self,
        cancel: Option<&crate::Cancel>,
    ) -> Result<(StatusReport, Option<StopReport>)> {
        let _upload = super::lock(&self.upload);
        self.stop_report_unlocked(cancel)
    }

    pub(crate) fn stop_report_unlocked(
        &self,
        cancel: Option<&crate::Cancel>,
    ) -> Result<(StatusReport, Option<StopReport>)> {
        let ask = StatusAsk {
            look_only: true,
            stop_cause: true,
            ..StatusAsk::default()
        };
        let reports = self.status_reports();
        let (tx, stops) = std::sync::mpsc::channel();
        super::lock(&self.shared.stops).push(tx);
        let answer = self.ask_status(ask, cancel, |_| {
            let status = reports.recv_timeout(self.options.report_timeout).ok()?;
            // The STOP_CAUSE report comes right after the STATUS.
            Some((status, recv_within(&stops, self.options.report_timeout)))
        })?;
        match answer {
            Some(answer) => Ok(answer),
            None => Ok((self.status_unlocked(cancel)?, None)),
        }
    }

    /// The controller's own timing and receive counters (issue 34, `armctl diag`): a
    /// look-only STATUS with request byte bits 3 and 6 (0x4a, from any host, never taking
    /// the controller), answered with the STATUS, RX_COUNTERS and DIAG reports.
    /// `Ok(None)`: a controller older than issue 34 (it refuses bit 6 with
    /// `INVALID_CONFIG`, or the byte with `BAD_LENGTH`). A lost report is asked again.
    pub fn diag(&self) -> Result<Option<Diagnosis>> {
        let _upload = super::lock(&self.upload);
        let ask = StatusAsk {
            look_only: true,
            counters: true,
            diag: true,
            ..StatusAsk::default()
        };
        let reports = self.status_reports();
        let (tx, counters) = std::sync::mpsc::channel();
        super::lock(&self.shared.rx_counters).push(tx);
        let (tx, diags) = std::sync::mpsc::channel();
        super::lock(&self.shared.diags).push(tx);
        self.ask_status(ask, None, |_| {
            let status = reports.recv_timeout(self.options.report_timeout).ok()?;
            // RX_COUNTERS, then DIAG, right after the STATUS.
            Some(Diagnosis {
                status,
                rx: recv_within(&counters, self.options.report_timeout)?,
                diag: recv_within(&diags, self.options.report_timeout)?,
            })
        })
    }

    /// LIMITS_GET: every joint's limits on the controller and the last point it refused
    /// for one (issue 23). An older controller answers `UNKNOWN_TAG`.
    pub fn limits(&self) -> Result<LimitsReport> {
        let _upload = super::lock(&self.upload);
        let (tx, rx) = std::sync::mpsc::channel();
        super::lock(&self.shared.limits).push(tx);
        for _ in 0..self.options.attempts {
            check(
                Tag::LimitsGet,
                self.exchange_unlocked(&Command::LimitsGet, None)?,
            )?;
            if let Ok(report) = rx.recv_timeout(self.options.report_timeout) {
                return Ok(report);
            }
        }
        Err(Error::NoReport {
            command: Tag::LimitsGet,
            attempts: self.options.attempts,
        })
    }

    /// LIMITS_GET with its request byte (issue 31): the LIMITS report with each joint's
    /// `max_accel_steps_s2` (`max_accel` is `Some`). A controller older than issue 31
    /// refuses the byte (`BAD_LENGTH`): the plain report then, `max_accel` `None`.
    pub fn limits_with_accel(&self) -> Result<LimitsReport> {
        let _upload = super::lock(&self.upload);
        let (tx, rx) = std::sync::mpsc::channel();
        super::lock(&self.shared.limits).push(tx);
        let mut command = Command::LimitsGetWithAccel;
        for _ in 0..self.options.attempts {
            let ack = self.exchange_unlocked(&command, None)?;
            if ack.status == StatusCode::BadLength && command == Command::LimitsGetWithAccel {
                command = Command::LimitsGet;
                continue;
            }
            check(Tag::LimitsGet, ack)?;
            if let Ok(report) = rx.recv_timeout(self.options.report_timeout) {
                return Ok(report);
            }
        }
        Err(Error::NoReport {
            command: Tag::LimitsGet,
            attempts: self.options.attempts,
        })
    }

    /// ACCEL_SET (issue 31): joint `joint`'s most acceleration, steps/s² (0: none), kept
    /// by the controller with its limits; only while STOPPED. An older controller answers
    /// `UNKNOWN_TAG`.
    pub fn set_accel(&self, joint: u8, max_accel_steps_s2: u32) -> Result<Ack> {
        self.send(&Command::AccelSet {
            joint,
            max_accel_steps_s2,
        })
    }

    /// JOINT_DESC_GET (issue 31): joint `joint`'s description (name, units, scale) as the
    /// controller keeps it; any host that may ask LIMITS_GET may ask. An older controller
    /// answers `UNKNOWN_TAG` ([`Error::Refused`]).
    pub fn joint_desc(&self, joint: u8) -> Result<protocol::JointDesc> {
        let _upload = super::lock(&self.upload);
        let (tx, rx) = std::sync::mpsc::channel();
        super::lock(&self.shared.descs).push(tx);
        let command = Command::JointDescGet { joint };
        for _ in 0..self.options.attempts {
            check(Tag::JointDescGet, self.exchange_unlocked(&command, None)?)?;
            let deadline = std::time::Instant::now() + self.options.report_timeout;
            // Another thread's report for another joint may come first: skip it.
            while let Some(left) = deadline.checked_duration_since(std::time::Instant::now()) {
                match rx.recv_timeout(left) {
                    Ok(report) if report.joint == joint => return Ok(report.desc),
                    Ok(_) => {}
                    Err(_) => break,
                }
            }
        }
        Err(Error::NoReport {
            command: Tag::JointDescGet,
            attempts: self.options.attempts,
        })
    }

    /// JOINT_DESC_SET (issue 31): joint `joint`'s description, kept by the controller with
    /// its limits; only while STOPPED, ACKed after the save. An older controller answers
    /// `UNKNOWN_TAG`.
    pub fn set_joint_desc(&self, joint: u8, desc: protocol::JointDesc) -> Result<Ack> {
        if usize::from(joint) >= protocol::MAX_JOINTS || !desc.is_valid() {
            return Err(Error::InvalidTrajectory(format!(
                "joint {joint}: a description needs a joint of 0-{} and a finite scale",
                protocol::MAX_JOINTS - 1
            )));
        }
        self.send(&Command::JointDescSet(protocol::JointDescSet {
            joint,
            desc,
        }))
    }

    /// LIMITS_SET: joint `joint`'s position range and step rate (0: none of its own),
    /// kept by the controller across power cycles; only while STOPPED. Refused here when
    /// min is above max or the joint does not exist (the controller would refuse it with
    /// INVALID_CONFIG).
    pub fn set_limits(&self, joint: u8, limits: JointLimits) -> Result<Ack> {
        if usize::from(joint) >= protocol::MAX_JOINTS || !limits.is_valid() {
            return Err(Error::InvalidTrajectory(format!(
                "joint {joint}: limits need a joint of 0-{} and min ({}) not above max ({})",
                protocol::MAX_JOINTS - 1,
                limits.min,
                limits.max
            )));
        }
        self.send(&Command::LimitsSet(LimitsSet { joint, limits }))
    }
}

pub(super) fn recv_within<T>(rx: &std::sync::mpsc::Receiver<T>, timeout: Duration) -> Option<T> {
    let deadline = Instant::now() + timeout;
    rx.recv_timeout(deadline.saturating_duration_since(Instant::now()))
        .ok()
}

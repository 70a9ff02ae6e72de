//! Issue 33's homing on switches on the client: HOME, HOMING_SET/HOMING_GET, and the
//! SWITCHES report (STATUS's request byte bit 5: the homing cycle and the switch inputs).

use std::time::{Duration, Instant};

use protocol::{
    Ack, Command, HomingPhase, HomingSet, HomingSettings, StatusAsk, StatusCode, SwitchesReport,
    Tag,
};

use super::wire_tools::recv_within;
use super::{Client, check};
use crate::error::{Error, Result};

/// How [`Client::home`] homed the arm.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Homed {
    /// On the home switches (HOME); the SWITCHES report at the end.
    OnSwitches(SwitchesReport),
    /// By RETURN: the controller has no switch set to home (or is older than issue 33).
    ByReturn,
}

impl Client {
    /// The SWITCHES report (STATUS with request byte bit 5, look only): the homing cycle's
    /// progress and which switches are pressed; `None` from a controller older than
    /// issue 33 (it refuses the bit).
    pub fn switches(&self) -> Result<Option<SwitchesReport>> {
        let _upload = super::lock(&self.upload);
        let ask = StatusAsk {
            look_only: true,
            switches: true,
            ..StatusAsk::default()
        };
        let (tx, rx) = std::sync::mpsc::channel();
        super::lock(&self.shared.switches).push(tx);
        self.ask_status(ask, None, |_| recv_within(&rx, self.options.report_timeout))
    }

    /// HOME: starts the homing cycle on the home switches (only while STOPPED; refused
    /// `HOMING_FAILED` when no joint is set to home or the controller has no switches).
    /// See [`Client::home`] to wait for its end.
    pub fn start_homing(&self) -> Result<Ack> {
        self.send(&Command::Home)
    }

    /// Homes the arm: on its switches when it has them (HOME, waiting up to `timeout` for
    /// the cycle to end), by RETURN otherwise (as before issue 33; this does not wait for
    /// RETURN's move). A cycle that fails is an error naming the joint.
    pub fn home(&self, timeout: Duration) -> Result<Homed> {
        match self.start_homing() {
            Ok(_) => {}
            Err(Error::Refused {
                status: StatusCode::HomingFailed | StatusCode::UnknownTag,
                ..
            }) => {
                self.go_home()?;
                return Ok(Homed::ByReturn);
            }
            Err(e) => return Err(e),
        }
        let deadline = Instant::now() + timeout;
        loop {
            let report = self.switches()?.ok_or(Error::NoReport {
                command: Tag::Status,
                attempts: self.options.attempts,
            })?;
            match report.phase {
                HomingPhase::Homed => return Ok(Homed::OnSwitches(report)),
                HomingPhase::Failed => return Err(Error::HomingFailed(report)),
                _ => {}
            }
            if Instant::now() >= deadline {
                return Err(Error::HomingTimedOut { waited: timeout });
            }
            // Polled: a look every 20 ms is nothing on the wire.
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// HOMING_GET: joint `joint`'s homing settings.
    pub fn homing(&self, joint: u8) -> Result<HomingSettings> {
        let _upload = super::lock(&self.upload);
        let (tx, rx) = std::sync::mpsc::channel();
        super::lock(&self.shared.homings).push(tx);
        let command = Command::HomingGet { joint };
        for _ in 0..self.options.attempts {
            check(Tag::HomingGet, self.exchange_unlocked(&command, None)?)?;
            let deadline = Instant::now() + self.options.report_timeout;
            while let Some(left) = deadline.checked_duration_since(Instant::now()) {
                match rx.recv_timeout(left) {
                    Ok(report) if report.joint == joint => return Ok(report.settings),
                    Ok(_) => {}
                    Err(_) => break,
                }
            }
        }
        Err(Error::NoReport {
            command: Tag::HomingGet,
            attempts: self.options.attempts,
        })
    }

    /// HOMING_SET: joint `joint`'s homing settings, kept by the controller with its
    /// limits; only while STOPPED, ACKed after the save.
    pub fn set_homing(&self, joint: u8, settings: HomingSettings) -> Result<Ack> {
        if usize::from(joint) >= protocol::MAX_JOINTS || !settings.is_valid() {
            return Err(Error::InvalidTrajectory(format!(
                "joint {joint}: homing needs a joint of 0-{} and, when enabled, non-zero rates, back-off and travel",
                protocol::MAX_JOINTS - 1
            )));
        }
        self.send(&Command::HomingSet(HomingSet { joint, settings }))
    }
}

//! HOME on the controller (issue 33): runs [`crate::homing`]'s sans-io cycle with the
//! plant. Each move of the cycle is one constant-rate segment of one joint, started as a
//! run of its own (state RUNNING); its end (the step backend ran dry) or a home switch's
//! activation (which stops it) hands the cycle its count; the cycle's position set is
//! the plant's. STOPPED, the wired e-stop input and a limit switch abort it (the cycle
//! fails naming the joint); the switch being homed on, when it is also the limit, is
//! masked from the hard limits meanwhile. The SWITCHES report (STATUS request bit 5)
//! shows where it is.

use arm_step::Segment;
use protocol::{
    HomingFailure, HomingPhase, HomingSettings, Location, MAX_JOINTS, State, StatusCode, StopCause,
    StopReport, SwitchesReport,
};

use super::Controller;
use crate::homing::{HomingAction, HomingCycle, HomingError, HomingJoint};
use crate::plant::Plant;
use crate::switches::{Side, SwitchEvent};

/// The homing cycle's state on the controller.
#[derive(Clone, Debug)]
pub(crate) struct HomingRun {
    /// The cycle under way.
    cycle: Option<HomingCycle>,
    /// Where the last cycle is (the SWITCHES report).
    phase: HomingPhase,
    /// The joint being homed, or the one that failed.
    joint: u8,
    /// Why the last cycle failed.
    error: Option<HomingFailure>,
    /// Joints homed since boot, bit per joint.
    homed: u8,
    /// Home switches pressed now, bit per joint.
    home_active: u8,
    /// The board has switch inputs ([`Controller::set_switches_fitted`]).
    fitted: bool,
}

impl HomingRun {
    /// Never homed, no switch.
    pub(crate) const IDLE: HomingRun = HomingRun {
        cycle: None,
        phase: HomingPhase::Never,
        joint: 0,
        error: None,
        homed: 0,
        home_active: 0,
        fitted: false,
    };
}

/// arm-core's settings of a joint from the wire's.
fn joint_settings(s: &HomingSettings) -> HomingJoint {
    HomingJoint {
        enabled: s.enabled,
        order: s.order,
        towards: if s.towards_max { Side::Max } else { Side::Min },
        seek_rate_hz: s.seek_rate_hz,
        approach_rate_hz: s.approach_rate_hz,
        backoff_steps: s.backoff_steps,
        max_travel_steps: s.max_travel_steps,
        offset: s.offset,
        switch_is_limit: s.switch_is_limit,
    }
}

fn failure(error: HomingError) -> (u8, HomingFailure) {
    match error {
        HomingError::SeekTravel { joint } => (joint, HomingFailure::SeekTravel),
        HomingError::BackOffStillActive { joint } => (joint, HomingFailure::BackOffStillActive),
        HomingError::ApproachMissed { joint } => (joint, HomingFailure::ApproachMissed),
        HomingError::Aborted { joint } => (joint, HomingFailure::Aborted),
        HomingError::BadSettings { joint } => (joint, HomingFailure::BadSettings),
    }
}

fn bit(joint: u8) -> u8 {
    1u8.checked_shl(u32::from(joint)).unwrap_or(0)
}

impl<const CAP: usize> Controller<CAP> {
    /// Whether the board has switch inputs: HOME is refused `HOMING_FAILED` without
    /// them (the trajectory task says so at start).
    pub fn set_switches_fitted(&mut self, fitted: bool) {
        self.homing.fitted = fitted;
    }

    /// Whether a homing cycle is under way.
    pub fn homing(&self) -> bool {
        self.homing.cycle.is_some()
    }

    /// The SWITCHES report: the homing cycle and the switch inputs.
    pub fn switches_report(&self) -> SwitchesReport {
        let limits = &self.hard_limits;
        let mask = |side| {
            (0u8..8)
                .filter(|&j| limits.is_active(j, side))
                .fold(0u8, |m, j| m | bit(j))
        };
        SwitchesReport {
            phase: self.homing.phase,
            joint: self.homing.joint,
            error: self.homing.error,
            homed: self.homing.homed,
            home_active: self.homing.home_active,
            min_active: mask(Side::Min),
            max_active: mask(Side::Max),
            latched: limits
                .latched()
                .map(|(joint, side)| (joint & 0x7f) | if side == Side::Max { 0x80 } else { 0 }),
        }
    }

    /// HOME's execution (the caller checked the latches and STOPPED): starts the cycle.
    pub(super) fn start_homing(&mut self, plant: &mut impl Plant) -> Result<(), StatusCode> {
        // MAX_JOINTS is 8: a joint count of at most 8 fits the u8 bit masks.
        let joints = self.settings.joints.min(8);
        let settings = self.settings.homing.map(|s| joint_settings(&s));
        let any = settings.iter().take(usize::from(joints)).any(|s| s.enabled);
        if !self.homing.fitted || !any {
            return Err(StatusCode::HomingFailed);
        }
        self.buffer.clear();
        self.expected = 0;
        self.received = 0;
        self.executed = 0;
        self.stop = StopReport::COMPLETE;
        self.state = State::Running;
        self.homing.error = None;
        self.homing.phase = HomingPhase::Homing;
        let (cycle, first) = HomingCycle::start(settings, joints, self.homing.home_active);
        self.homing.cycle = Some(cycle);
        self.homing_act(first, plant);
        Ok(())
    }

    /// Carries out `action` and the ones that follow at once (a stop, a position set),
    /// until the cycle waits for a move or is over. Returns a LOCATION report when it
    /// ended (reports on).
    fn homing_act(&mut self, mut action: HomingAction, plant: &mut impl Plant) -> Option<Location> {
        loop {
            let cycle = self.homing.cycle.as_mut()?;
            if let Some(joint) = cycle.joint() {
                self.homing.joint = joint;
            }
            debug!(
                "homing: {:?} at {:?}",
                debug_value!(action),
                debug_value!(plant.positions()[0])
            );
            let mask = cycle.masked_limit();
            self.hard_limits.set_mask(mask);
            plant.set_limit_mask(mask);
            action = match action {
                HomingAction::Move {
                    joint,
                    steps,
                    rate_hz,
                } => {
                    let rate = u64::from(rate_hz.clamp(1, self.config.max_step_rate_hz.max(1)));
                    let duration = (u64::from(steps.unsigned_abs()) * 1_000_000).div_ceil(rate);
                    let mut segment_steps = [0i32; MAX_JOINTS];
                    if let Some(s) = segment_steps.get_mut(usize::from(joint)) {
                        *s = steps;
                    }
                    let segment = Segment {
                        duration_us: u32::try_from(duration.max(1)).unwrap_or(u32::MAX),
                        steps: segment_steps,
                    };
                    plant.stop();
                    if plant.push_segment(segment) {
                        plant.start();
                        return None;
                    }
                    // An idle backend always takes one segment: a move that cannot start
                    // ends at once (the cycle then fails naming the joint).
                    cycle.move_ended(plant.positions().get(usize::from(joint)).copied()?)
                }
                HomingAction::Stop { joint } => {
                    plant.stop();
                    cycle.move_ended(plant.positions().get(usize::from(joint)).copied()?)
                }
                HomingAction::SetPosition { joint, count } => {
                    let mut positions = plant.positions();
                    if let Some(p) = positions.get_mut(usize::from(joint)) {
                        *p = count;
                    }
                    plant.set_positions(positions);
                    self.fed_end = positions;
                    self.received_end = positions;
                    self.homing.homed |= bit(joint);
                    cycle.position_set()
                }
                HomingAction::Done => {
                    self.homing.phase = HomingPhase::Homed;
                    return self.end_homing(None, plant);
                }
                HomingAction::Failed(error) => {
                    return self.end_homing(Some(error), plant);
                }
            };
        }
    }

    /// The cycle is over: STOPPED, the mask lifted; a failure is kept for the SWITCHES
    /// report and named by STOP_CAUSE (FAULT, the joint).
    fn end_homing(
        &mut self,
        error: Option<HomingError>,
        plant: &mut impl Plant,
    ) -> Option<Location> {
        self.homing.cycle = None;
        self.hard_limits.set_mask(None);
        plant.set_limit_mask(None);
        plant.stop();
        if let Some(error) = error {
            let (joint, failure) = failure(error);
            self.homing.phase = HomingPhase::Failed;
            self.homing.joint = joint;
            self.homing.error = Some(failure);
            if !matches!(error, HomingError::Aborted { .. }) {
                self.stop = StopReport {
                    detail: joint,
                    ..StopReport::of(StopCause::Fault)
                };
            }
        }
        let changed = self.state != State::Stopped;
        self.state = State::Stopped;
        (changed && self.reports_on).then(|| self.location(plant))
    }

    /// The step backend ran dry during the cycle: the move ended.
    pub(super) fn homing_ran_dry(&mut self, plant: &mut impl Plant) -> Option<Location> {
        debug!("homing: the move ran dry");
        let cycle = self.homing.cycle.as_mut()?;
        let joint = cycle.joint()?;
        let count = plant.positions().get(usize::from(joint)).copied()?;
        let next = cycle.move_ended(count);
        self.homing_act(next, plant)
    }

    /// A home switch's event: kept for the next cycle's start and the SWITCHES report;
    /// during a cycle, an activation may end its move. Returns a LOCATION report when the
    /// cycle ended.
    pub(super) fn home_switch(
        &mut self,
        event: SwitchEvent,
        plant: &mut impl Plant,
    ) -> Option<Location> {
        match event {
            SwitchEvent::HomeActive {
                joint, position, ..
            } => {
                self.homing.home_active |= bit(joint);
                let action = self.homing.cycle.as_mut()?.home_active(joint, position)?;
                self.homing_act(action, plant)
            }
            SwitchEvent::HomeReleased { joint } => {
                self.homing.home_active &= !bit(joint);
                if let Some(cycle) = self.homing.cycle.as_mut() {
                    cycle.home_released(joint);
                }
                None
            }
            _ => None,
        }
    }

    /// A stop from outside (STOPPED, the e-stop input, a limit switch) during the cycle:
    /// it fails naming the joint it was homing.
    pub(super) fn abort_homing(&mut self, plant: &mut impl Plant) {
        let Some(mut cycle) = self.homing.cycle.take() else {
            return;
        };
        self.hard_limits.set_mask(None);
        plant.set_limit_mask(None);
        if let Some(error) = cycle.abort() {
            let (joint, failure) = failure(error);
            self.homing.phase = HomingPhase::Failed;
            self.homing.joint = joint;
            self.homing.error = Some(failure);
        }
    }
}

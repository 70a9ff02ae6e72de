//! The homing cycle on home switches (issue 33), sans-io: fed the home switches' events
//! (with the joint's count at each activation, [`crate::switches::SwitchEvent`]) and the
//! ends of the moves it asked for; returning the next [`HomingAction`].
//!
//! Per joint, in the configured order ([`HomingJoint::order`], then joint number):
//! 1. if the switch is already active, back off first (as 3);
//! 2. seek: move towards the switch at `seek_rate_hz` for at most `max_travel_steps`;
//!    the switch becoming active stops the move; the whole travel without it fails
//!    ([`HomingError::SeekTravel`], naming the joint);
//! 3. back off: `backoff_steps` away at `approach_rate_hz`; the switch must read released
//!    by the end ([`HomingError::BackOffStillActive`]; so the back-off must last longer
//!    than the input's debounce time);
//! 4. approach: towards the switch again at `approach_rate_hz`, for at most twice the
//!    back-off ([`HomingError::ApproachMissed`]); the switch's activation stops the move;
//! 5. the joint's count becomes `offset` plus the steps made since the activation
//!    ([`HomingAction::SetPosition`]), so the count equals the physical position minus
//!    the switch's plus the offset, to the step, however far the stop ran on.
//!
//! Moves run at a constant rate (seek rates are the slow ones a stepper starts at without a
//! ramp). Hard limits stay active: the controller aborts the cycle on any limit that trips
//! ([`HomingCycle::abort`]); the one exception is the switch being homed on, when it is
//! also the joint's limit on that side ([`HomingJoint::switch_is_limit`],
//! [`HomingCycle::masked_limit`]).

use protocol::MAX_JOINTS;

use crate::switches::Side;

/// One joint's homing settings (kept with its limits).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HomingJoint {
    /// Whether this joint homes on a switch.
    pub enabled: bool,
    /// Joints home in increasing `order` (ties: lower joint first).
    pub order: u8,
    /// The side of travel the switch is on: the seek's direction.
    pub towards: Side,
    /// Seek rate, steps per second (> 0).
    pub seek_rate_hz: u32,
    /// Back-off and approach rate, steps per second (> 0).
    pub approach_rate_hz: u32,
    /// Steps of the back-off (> 0).
    pub backoff_steps: u32,
    /// The longest seek, steps (> 0).
    pub max_travel_steps: u32,
    /// The count the joint has at the switch's activation point.
    pub offset: i32,
    /// The home switch is also the joint's limit switch on `towards`' side: its trips do
    /// not stop the arm while this joint homes.
    pub switch_is_limit: bool,
}

impl HomingJoint {
    /// Not homed on a switch (the default).
    pub const NONE: HomingJoint = HomingJoint {
        enabled: false,
        order: 0,
        towards: Side::Min,
        seek_rate_hz: 0,
        approach_rate_hz: 0,
        backoff_steps: 0,
        max_travel_steps: 0,
        offset: 0,
        switch_is_limit: false,
    };

    /// Whether the settings can be run (rates, back-off and travel non-zero).
    pub const fn is_valid(&self) -> bool {
        !self.enabled
            || (self.seek_rate_hz > 0
                && self.approach_rate_hz > 0
                && self.backoff_steps > 0
                && self.max_travel_steps > 0)
    }

    const fn sign(&self) -> i32 {
        match self.towards {
            Side::Min => -1,
            Side::Max => 1,
        }
    }
}

/// What the controller does next for the cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HomingAction {
    /// Move `joint` by `steps` (signed) at `rate_hz`; call [`HomingCycle::move_ended`]
    /// when it ends, by itself or by a [`HomingAction::Stop`].
    Move {
        /// The joint (0-based).
        joint: u8,
        /// Signed steps.
        steps: i32,
        /// Steps per second.
        rate_hz: u32,
    },
    /// Stop `joint`'s move now (the switch was found); then [`HomingCycle::move_ended`].
    Stop {
        /// The joint (0-based).
        joint: u8,
    },
    /// Set `joint`'s count to `count` (nothing moves); then [`HomingCycle::position_set`].
    SetPosition {
        /// The joint (0-based).
        joint: u8,
        /// The new count, steps.
        count: i32,
    },
    /// Every joint is homed.
    Done,
    /// The cycle failed; nothing more moves.
    Failed(HomingError),
}

/// Why a homing cycle failed. Each names the joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HomingError {
    /// The seek travelled its maximum without the switch.
    SeekTravel {
        /// The joint (0-based).
        joint: u8,
    },
    /// The switch still read active at the end of the back-off.
    BackOffStillActive {
        /// The joint (0-based).
        joint: u8,
    },
    /// The slow approach travelled twice the back-off without the switch.
    ApproachMissed {
        /// The joint (0-based).
        joint: u8,
    },
    /// Stopped from outside (a limit switch, STOPPED, the e-stop input) while homing it.
    Aborted {
        /// The joint (0-based).
        joint: u8,
    },
    /// A joint's settings cannot be run ([`HomingJoint::is_valid`]).
    BadSettings {
        /// The joint (0-based).
        joint: u8,
    },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    Seek,
    /// The switch was found; waiting for the move to end.
    SeekStopping,
    BackOff,
    Approach,
    /// Found on the approach with the count at activation; waiting for the move's end.
    ApproachStopping {
        at: i32,
    },
    /// [`HomingAction::SetPosition`] handed out.
    Setting,
    Finished,
}

/// A running homing cycle.
#[derive(Clone, Debug)]
pub struct HomingCycle {
    settings: [HomingJoint; MAX_JOINTS],
    /// Joints `0..joints` take part.
    joints: u8,
    /// The joint being homed (the last one once finished).
    current: Option<u8>,
    phase: Phase,
    /// Home switches active now, bit per joint.
    home_active: u8,
}

impl HomingCycle {
    /// Starts a cycle for joints `0..joints` with their `settings`, the home switches
    /// active now as bits of `home_active`. Returns the cycle and its first action.
    pub fn start(
        settings: [HomingJoint; MAX_JOINTS],
        joints: u8,
        home_active: u8,
    ) -> (Self, HomingAction) {
        let mut cycle = HomingCycle {
            settings,
            joints,
            current: None,
            phase: Phase::Finished,
            home_active,
        };
        for (joint, s) in (0..joints).zip(&settings) {
            if !s.is_valid() {
                return (
                    cycle,
                    HomingAction::Failed(HomingError::BadSettings { joint }),
                );
            }
        }
        let first = cycle.begin_joint();
        (cycle, first)
    }

    fn setting(&self, joint: u8) -> HomingJoint {
        self.settings
            .get(usize::from(joint))
            .copied()
            .unwrap_or(HomingJoint::NONE)
    }

    /// The joint to home after `after` (`None`: the first): the next by (order, joint).
    fn next_joint(&self, after: Option<u8>) -> Option<u8> {
        let key = after.map(|j| (self.setting(j).order, j));
        (0..self.joints)
            .zip(&self.settings)
            .filter(|(j, s)| s.enabled && key.is_none_or(|k| (s.order, *j) > k))
            .min_by_key(|(j, s)| (s.order, *j))
            .map(|(j, _)| j)
    }

    /// The joint being homed (`None` when finished).
    pub fn joint(&self) -> Option<u8> {
        if self.phase == Phase::Finished {
            None
        } else {
            self.current
        }
    }

    /// The limit switch whose trips must not stop the arm now: the one being homed on,
    /// when it is also the limit.
    pub fn masked_limit(&self) -> Option<(u8, Side)> {
        let joint = self.joint()?;
        let s = self.setting(joint);
        s.switch_is_limit.then_some((joint, s.towards))
    }

    fn bit(joint: u8) -> u8 {
        1u8.checked_shl(u32::from(joint)).unwrap_or(0)
    }

    fn begin_joint(&mut self) -> HomingAction {
        let Some(joint) = self.next_joint(self.current) else {
            self.phase = Phase::Finished;
            return HomingAction::Done;
        };
        self.current = Some(joint);
        if self.home_active & Self::bit(joint) != 0 {
            self.back_off(joint)
        } else {
            self.seek(joint)
        }
    }

    fn seek(&mut self, joint: u8) -> HomingAction {
        let s = self.setting(joint);
        self.phase = Phase::Seek;
        HomingAction::Move {
            joint,
            steps: s.sign() * travel(s.max_travel_steps),
            rate_hz: s.seek_rate_hz,
        }
    }

    fn back_off(&mut self, joint: u8) -> HomingAction {
        let s = self.setting(joint);
        self.phase = Phase::BackOff;
        HomingAction::Move {
            joint,
            steps: -s.sign() * travel(s.backoff_steps),
            rate_hz: s.approach_rate_hz,
        }
    }

    fn fail(&mut self, error: HomingError) -> HomingAction {
        self.phase = Phase::Finished;
        HomingAction::Failed(error)
    }

    /// `joint`'s home switch became active with the joint's count at `position`.
    /// Returns a [`HomingAction::Stop`] when it ends the move under way.
    pub fn home_active(&mut self, joint: u8, position: i32) -> Option<HomingAction> {
        self.home_active |= Self::bit(joint);
        if self.joint() != Some(joint) {
            return None;
        }
        match self.phase {
            Phase::Seek => {
                self.phase = Phase::SeekStopping;
                Some(HomingAction::Stop { joint })
            }
            Phase::Approach => {
                self.phase = Phase::ApproachStopping { at: position };
                Some(HomingAction::Stop { joint })
            }
            _ => None,
        }
    }

    /// `joint`'s home switch has read released for its debounce time.
    pub fn home_released(&mut self, joint: u8) {
        self.home_active &= !Self::bit(joint);
    }

    /// The move asked for ended (travelled, or stopped) with the joint's count at `count`.
    pub fn move_ended(&mut self, count: i32) -> HomingAction {
        let Some(joint) = self.joint() else {
            return HomingAction::Done;
        };
        let s = self.setting(joint);
        match self.phase {
            Phase::Seek => self.fail(HomingError::SeekTravel { joint }),
            Phase::SeekStopping => self.back_off(joint),
            Phase::BackOff => {
                if self.home_active & Self::bit(joint) != 0 {
                    return self.fail(HomingError::BackOffStillActive { joint });
                }
                self.phase = Phase::Approach;
                HomingAction::Move {
                    joint,
                    steps: s.sign() * travel(s.backoff_steps.saturating_mul(2)),
                    rate_hz: s.approach_rate_hz,
                }
            }
            Phase::Approach => self.fail(HomingError::ApproachMissed { joint }),
            Phase::ApproachStopping { at } => {
                self.phase = Phase::Setting;
                HomingAction::SetPosition {
                    joint,
                    count: s.offset.wrapping_add(count.wrapping_sub(at)),
                }
            }
            Phase::Setting | Phase::Finished => HomingAction::Done,
        }
    }

    /// The [`HomingAction::SetPosition`] was applied: the next joint's first action.
    pub fn position_set(&mut self) -> HomingAction {
        if self.phase != Phase::Setting {
            return HomingAction::Done;
        }
        self.begin_joint()
    }

    /// Stopped from outside (a limit switch, STOPPED, the e-stop input): the cycle fails
    /// naming the joint it was homing (or is already over: `None`).
    pub fn abort(&mut self) -> Option<HomingError> {
        let joint = self.joint()?;
        self.phase = Phase::Finished;
        Some(HomingError::Aborted { joint })
    }
}

/// A travel in steps as a signed move (at most `i32::MAX`).
fn travel(steps: u32) -> i32 {
    i32::try_from(steps).unwrap_or(i32::MAX)
}

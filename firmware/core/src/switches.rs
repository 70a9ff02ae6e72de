//! Switch inputs and hard limits (issue 33), sans-io: fed switch edges with their instants
//! and the joint's step count at the edge, returning what the controller must do.
//!
//! Per joint three inputs: a home switch and min/max limit switches ([`Switch`]). Each
//! input's polarity is configured ([`InputConfig`]); normally closed is recommended, so a
//! broken wire reads as *active* (tripped) and stops the arm, as the wired e-stop does.
//!
//! # Debounce, in hardware time
//! Asymmetric, so that safety never waits: a reading of *active* counts at once (its
//! instant and step count are the ones kept: the homing cycle sets the position from
//! them, to the step), and *inactive* counts only after the input has read inactive for
//! [`InputConfig::debounce_us`] without a bounce. The debounce is decided on the instants
//! of the edges themselves ([`SwitchBank::edge`]) and of a later look
//! ([`SwitchBank::poll`]), never by a task's sleep: the board's EXTI handler stamps each
//! edge with its timer count, the simulator with its simulated time.
//!
//! # Hard limits
//! A limit input becoming active ([`SwitchEvent::LimitTripped`]) asks for the e-stop
//! path: every joint stops at once ([`Limits::trip`] answers whether to halt) and the
//! controller latches ([`Limits::latched`]: RUNING and jogs are refused with the joint and
//! the side). An unlock ([`Limits::unlock`]) clears the latch; from then on, while that
//! switch is still active, only motion away from it is accepted ([`Limits::check_move`]),
//! until it reads inactive again. The homing cycle masks the one switch it is homing on
//! ([`Limits::set_mask`]), when that switch is also the joint's limit on that side.

use protocol::MAX_JOINTS;

/// One input of a joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Switch {
    /// The home switch (the homing cycle's reference).
    Home,
    /// The limit switch at the low end of travel (negative steps).
    Min,
    /// The limit switch at the high end of travel (positive steps).
    Max,
}

impl Switch {
    /// Every input of a joint.
    pub const ALL: [Switch; 3] = [Switch::Home, Switch::Min, Switch::Max];
}

/// One value per input of a joint.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PerSwitch<T> {
    /// The home switch's.
    pub home: T,
    /// The min limit switch's.
    pub min: T,
    /// The max limit switch's.
    pub max: T,
}

impl<T> PerSwitch<T> {
    /// The value of `switch`.
    pub const fn at(&self, switch: Switch) -> &T {
        match switch {
            Switch::Home => &self.home,
            Switch::Min => &self.min,
            Switch::Max => &self.max,
        }
    }

    /// The value of `switch`, to change.
    pub fn at_mut(&mut self, switch: Switch) -> &mut T {
        match switch {
            Switch::Home => &mut self.home,
            Switch::Min => &mut self.min,
            Switch::Max => &mut self.max,
        }
    }
}

/// The end of travel a limit switch guards.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Side {
    /// The low end: moves with negative steps run into it.
    Min,
    /// The high end: moves with positive steps run into it.
    Max,
}

impl Side {
    /// The side a move of `steps` runs towards (`None` for no move).
    pub const fn of_steps(steps: i64) -> Option<Side> {
        if steps > 0 {
            Some(Side::Max)
        } else if steps < 0 {
            Some(Side::Min)
        } else {
            None
        }
    }

    const fn switch(self) -> Switch {
        match self {
            Side::Min => Switch::Min,
            Side::Max => Switch::Max,
        }
    }
}

/// How one input is wired.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InputConfig {
    /// Whether the input is fitted at all; an input not fitted never reads active.
    pub fitted: bool,
    /// The electrical level that means *active* (tripped). For the recommended wiring, a
    /// normally closed contact to GND with a pull-up, it is `true`: the contact opening
    /// (or its wire breaking) lets the pull-up raise the input. The pull itself is the
    /// board's pin setting.
    pub active_high: bool,
    /// How long an input must read inactive, without a bounce, before it counts as
    /// released, microseconds. Activation is never delayed.
    pub debounce_us: u32,
}

impl InputConfig {
    /// No input (the default: nothing changes for controllers without switches).
    pub const NONE: InputConfig = InputConfig {
        fitted: false,
        active_high: true,
        debounce_us: 0,
    };
}

/// The inputs of every joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SwitchConfig {
    /// Per joint.
    pub inputs: [PerSwitch<InputConfig>; MAX_JOINTS],
}

impl SwitchConfig {
    /// No switch on any joint.
    pub const NONE: SwitchConfig = SwitchConfig {
        inputs: [PerSwitch {
            home: InputConfig::NONE,
            min: InputConfig::NONE,
            max: InputConfig::NONE,
        }; MAX_JOINTS],
    };
}

/// What a change of an input means, once debounced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SwitchEvent {
    /// The joint's home switch became active when its count was `position`, at `at_us`.
    HomeActive {
        /// The joint (0-based).
        joint: u8,
        /// The joint's count at the activation.
        position: i32,
        /// When, microseconds of the controller clock.
        at_us: u64,
    },
    /// The home switch has read inactive for its debounce time.
    HomeReleased {
        /// The joint (0-based).
        joint: u8,
    },
    /// A limit switch became active: the e-stop path (see [`Limits::trip`]).
    LimitTripped {
        /// The joint (0-based).
        joint: u8,
        /// The end of travel.
        side: Side,
        /// When, microseconds of the controller clock.
        at_us: u64,
    },
    /// A limit switch became active while masked at its edge (issue 33: the switch the
    /// homing cycle homes on, when it is also the limit; [`crate::switch_line::SwitchLine::set_mask`]):
    /// active (the "away only" rule holds), but no stop and no latch, whenever the
    /// controller gets to it. Made by the switch line from a [`SwitchEvent::LimitTripped`].
    LimitMasked {
        /// The joint (0-based).
        joint: u8,
        /// The end of travel.
        side: Side,
    },
    /// A limit switch has read inactive for its debounce time.
    LimitReleased {
        /// The joint (0-based).
        joint: u8,
        /// The end of travel.
        side: Side,
    },
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct InputState {
    /// The debounced state.
    active: bool,
    /// The last raw reading is inactive since this instant (release pending).
    inactive_since: Option<u64>,
}

impl InputState {
    const IDLE: InputState = InputState {
        active: false,
        inactive_since: None,
    };
}

/// Every joint's inputs, debounced. Fed raw edges; hands out [`SwitchEvent`]s.
#[derive(Clone, Debug)]
pub struct SwitchBank {
    config: SwitchConfig,
    state: [PerSwitch<InputState>; MAX_JOINTS],
}

impl SwitchBank {
    /// Inputs as configured, all inactive until their first reading.
    pub const fn new(config: SwitchConfig) -> Self {
        SwitchBank {
            config,
            state: [PerSwitch {
                home: InputState::IDLE,
                min: InputState::IDLE,
                max: InputState::IDLE,
            }; MAX_JOINTS],
        }
    }

    /// Whether `switch` of `joint` counts as active now (debounced).
    pub fn is_active(&self, joint: u8, switch: Switch) -> bool {
        self.state
            .get(usize::from(joint))
            .is_some_and(|s| s.at(switch).active)
    }

    /// Whether any input of any joint is fitted.
    pub fn any_fitted(&self) -> bool {
        self.config
            .inputs
            .iter()
            .any(|i| Switch::ALL.iter().any(|&s| i.at(s).fitted))
    }

    /// A raw edge: `joint`'s `switch` now reads electrical `level` (true: high), seen at
    /// `at_us` when the joint's count was `position`. Activation is reported at once;
    /// a release is only noted (reported by a later [`Self::poll`] or edge once it has
    /// lasted the debounce time). Unfitted inputs and joints out of range are ignored.
    pub fn edge(
        &mut self,
        joint: u8,
        switch: Switch,
        level: bool,
        position: i32,
        at_us: u64,
    ) -> Option<SwitchEvent> {
        let j = usize::from(joint);
        let config = *self.config.inputs.get(j)?.at(switch);
        if !config.fitted {
            return None;
        }
        let state = self.state.get_mut(j)?.at_mut(switch);
        let active = level == config.active_high;
        if active {
            state.inactive_since = None;
            if state.active {
                return None; // a bounce while active
            }
            state.active = true;
            return Some(match switch {
                Switch::Home => SwitchEvent::HomeActive {
                    joint,
                    position,
                    at_us,
                },
                Switch::Min => SwitchEvent::LimitTripped {
                    joint,
                    side: Side::Min,
                    at_us,
                },
                Switch::Max => SwitchEvent::LimitTripped {
                    joint,
                    side: Side::Max,
                    at_us,
                },
            });
        }
        if state.active && state.inactive_since.is_none() {
            state.inactive_since = Some(at_us);
        }
        None
    }

    /// Releases whose debounce time has passed by `now_us`, one per call (call until
    /// `None`). The board calls it from its step service or a timer; the simulator and
    /// tests on their virtual clock.
    pub fn poll(&mut self, now_us: u64) -> Option<SwitchEvent> {
        for ((joint, states), configs) in (0u8..).zip(&mut self.state).zip(&self.config.inputs) {
            for switch in Switch::ALL {
                let debounce = u64::from(configs.at(switch).debounce_us);
                let state = states.at_mut(switch);
                let Some(since) = state.inactive_since else {
                    continue;
                };
                if now_us.saturating_sub(since) < debounce {
                    continue;
                }
                state.active = false;
                state.inactive_since = None;
                return Some(match switch {
                    Switch::Home => SwitchEvent::HomeReleased { joint },
                    Switch::Min => SwitchEvent::LimitReleased {
                        joint,
                        side: Side::Min,
                    },
                    Switch::Max => SwitchEvent::LimitReleased {
                        joint,
                        side: Side::Max,
                    },
                });
            }
        }
        None
    }
}

/// Why a move is refused by the hard limits. Each names the joint and the side, which
/// STATUS and every tool print.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LimitRefusal {
    /// A limit switch tripped and the controller is latched: nothing moves until an
    /// unlock.
    Latched {
        /// The joint (0-based).
        joint: u8,
        /// The end of travel.
        side: Side,
    },
    /// Unlocked, but the switch is still active and this move goes further in.
    TowardsTripped {
        /// The joint (0-based).
        joint: u8,
        /// The end of travel.
        side: Side,
    },
}

/// The hard-limit latch and the "away only" rule after an unlock.
#[derive(Clone, Debug, Default)]
pub struct Limits {
    /// The first limit that tripped since the last unlock.
    latched: Option<(u8, Side)>,
    /// Active limit switches, per joint (`home` unused).
    active: [PerSwitch<bool>; MAX_JOINTS],
    /// The switch the homing cycle is homing on (its trips do not stop the arm).
    mask: Option<(u8, Side)>,
}

impl Limits {
    /// Nothing tripped.
    pub const fn new() -> Self {
        Limits {
            latched: None,
            active: [PerSwitch {
                home: false,
                min: false,
                max: false,
            }; MAX_JOINTS],
            mask: None,
        }
    }

    /// A limit switch became active. Returns `true` when the arm must stop at once (the
    /// e-stop path) and the controller is now latched on this switch; `false` for the
    /// switch the homing cycle has masked.
    pub fn trip(&mut self, joint: u8, side: Side) -> bool {
        if let Some(a) = self.active.get_mut(usize::from(joint)) {
            *a.at_mut(side.switch()) = true;
        }
        if self.mask == Some((joint, side)) {
            return false;
        }
        if self.latched.is_none() {
            self.latched = Some((joint, side));
        }
        true
    }

    /// A limit switch read inactive for its debounce time.
    pub fn release(&mut self, joint: u8, side: Side) {
        if let Some(a) = self.active.get_mut(usize::from(joint)) {
            *a.at_mut(side.switch()) = false;
        }
    }

    /// Feeds a [`SwitchEvent`]; returns `true` when the arm must stop at once.
    pub fn on_event(&mut self, event: SwitchEvent) -> bool {
        match event {
            SwitchEvent::LimitTripped { joint, side, .. } => self.trip(joint, side),
            SwitchEvent::LimitMasked { joint, side } => {
                if let Some(a) = self.active.get_mut(usize::from(joint)) {
                    *a.at_mut(side.switch()) = true;
                }
                false
            }
            SwitchEvent::LimitReleased { joint, side } => {
                self.release(joint, side);
                false
            }
            _ => false,
        }
    }

    /// The tripped limit the controller is latched on, if any.
    pub fn latched(&self) -> Option<(u8, Side)> {
        self.latched
    }

    /// Whether `joint`'s `side` limit switch is active now.
    pub fn is_active(&self, joint: u8, side: Side) -> bool {
        self.active
            .get(usize::from(joint))
            .is_some_and(|a| *a.at(side.switch()))
    }

    /// The host's unlock: clears the latch (the switch may still be active: then only
    /// moves away from it are accepted until it opens).
    pub fn unlock(&mut self) {
        self.latched = None;
    }

    /// The switch whose trips the homing cycle expects (`None`: every limit counts).
    pub fn set_mask(&mut self, mask: Option<(u8, Side)>) {
        self.mask = mask;
    }

    /// Whether a move of `steps[j]` steps per joint may start: refused while latched,
    /// and for a joint that would go further into an active limit switch. Joints past
    /// `steps.len()` do not move.
    pub fn check_move(&self, steps: &[i64]) -> Result<(), LimitRefusal> {
        if let Some((joint, side)) = self.latched {
            return Err(LimitRefusal::Latched { joint, side });
        }
        self.check_direction(steps)
    }

    /// [`Self::check_move`] without the latch: only whether a joint would go further
    /// into an active limit switch (points uploaded while latched, to run after unlock).
    pub fn check_direction(&self, steps: &[i64]) -> Result<(), LimitRefusal> {
        for ((joint, &s), active) in (0u8..).zip(steps).zip(&self.active) {
            let Some(side) = Side::of_steps(s) else {
                continue;
            };
            if *active.at(side.switch()) && self.mask != Some((joint, side)) {
                return Err(LimitRefusal::TowardsTripped { joint, side });
            }
        }
        Ok(())
    }

    /// The switch of `side` as a [`Switch`] (for callers mapping a side to its input).
    pub const fn switch_of(side: Side) -> Switch {
        side.switch()
    }
}

//! The joints' physical model and their switches, simulated (issue 33): where each joint
//! really is (`--position J:STEPS`: its place at boot, while its step count starts at 0),
//! a home switch (`--home-switch J:STEPS[:min|max]`) and limit switches
//! (`--limit-switch J:MIN:MAX`).
//!
//! The switches are wired as the recommended board wiring: normally closed to GND with a
//! pull-up, so an input reads high (active) when its switch is pressed (or its wire
//! broken): [`SwitchModel::config`] says so to arm-core's switch bank.
//!
//! Each STEP edge the step hardware plays moves the joint one step; the model looks at the
//! joint's physical position at that edge's simulated instant and, where an input's level
//! changes, records the edge ([`SwitchEdge`], with the joint's step count and the instant).
//! A limit switch closing asks the player to halt at that tick
//! ([`arm_step::HaltingStepPins`]): no STEP edge on any joint after it, as the board's
//! EXTI handler halting the step timers; unless the switch line masks it (the homing
//! cycle's switch when it is also the limit, [`arm_core::switch_line::SwitchLine::set_mask`]). The step thread then hands every recorded edge
//! to the same switch path the board's EXTI handler uses ([`arm_core::switch_line::SwitchLine::edge`]),
//! outside the step backend's lock.

use arm_core::switches::{InputConfig, PerSwitch, Side, Switch, SwitchConfig};
use arm_step::MAX_JOINTS;

/// How long an input must read released before it counts (arm-core's debounce): the
/// simulated contacts do not bounce, so 1 ms, well under any homing back-off.
pub const SIM_DEBOUNCE_US: u32 = 1_000;

/// One joint's physical model.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct JointModel {
    /// Physical position at boot, steps (the count starts at 0).
    pub start: i64,
    /// The home switch: pressed at or beyond this position towards the side.
    pub home: Option<(i64, Side)>,
    /// The limit switches: min pressed at or below the first, max at or above the second.
    pub limits: Option<(i64, i64)>,
}

impl JointModel {
    /// Which inputs read active (pressed) at physical position `at`.
    pub fn pressed(&self, at: i64) -> PerSwitch<bool> {
        PerSwitch {
            home: self.home.is_some_and(|(p, side)| match side {
                Side::Min => at <= p,
                Side::Max => at >= p,
            }),
            min: self.limits.is_some_and(|(min, _)| at <= min),
            max: self.limits.is_some_and(|(_, max)| at >= max),
        }
    }

    fn fitted(&self) -> PerSwitch<bool> {
        PerSwitch {
            home: self.home.is_some(),
            min: self.limits.is_some(),
            max: self.limits.is_some(),
        }
    }
}

/// An input's level changing at a step edge.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SwitchEdge {
    /// The joint.
    pub joint: u8,
    /// Which input.
    pub switch: Switch,
    /// The electrical level now (high: pressed, as wired).
    pub level: bool,
    /// The joint's step count at the edge.
    pub count: i32,
    /// Step clock tick of the edge.
    pub tick: u64,
}

/// Every joint's physical model and its inputs' levels.
#[derive(Clone, Debug, Default)]
pub struct SwitchModel {
    joints: [JointModel; MAX_JOINTS],
    /// The joints' physical positions less their motors' pulse counts are `start`; the
    /// step counts less the motors' are these (changed by a set of the positions).
    count_offset: [i64; MAX_JOINTS],
    levels: [PerSwitch<bool>; MAX_JOINTS],
    /// Edges recorded, not yet handed to the switch path.
    edges: Vec<SwitchEdge>,
}

impl SwitchModel {
    /// The model of `joints`; every fitted input's level at boot is recorded as an edge
    /// at tick 0 (a joint that starts on a switch reads it pressed at once).
    pub fn new(joints: [JointModel; MAX_JOINTS]) -> SwitchModel {
        let mut model = SwitchModel {
            joints,
            ..SwitchModel::default()
        };
        for (j, joint) in (0u8..).zip(joints) {
            let pressed = joint.pressed(joint.start);
            let fitted = joint.fitted();
            for switch in Switch::ALL {
                if *fitted.at(switch) {
                    let level = *pressed.at(switch);
                    *model.levels[usize::from(j)].at_mut(switch) = level;
                    model.edges.push(SwitchEdge {
                        joint: j,
                        switch,
                        level,
                        count: 0,
                        tick: 0,
                    });
                }
            }
        }
        model
    }

    /// Whether any joint has a switch.
    pub fn any(&self) -> bool {
        self.joints
            .iter()
            .any(|j| j.home.is_some() || j.limits.is_some())
    }

    /// The inputs as arm-core's switch bank sees them: fitted where modelled, active
    /// high (normally closed with a pull-up), [`SIM_DEBOUNCE_US`].
    pub fn config(&self) -> SwitchConfig {
        let mut config = SwitchConfig::NONE;
        for (inputs, joint) in config.inputs.iter_mut().zip(&self.joints) {
            let fitted = joint.fitted();
            for switch in Switch::ALL {
                *inputs.at_mut(switch) = InputConfig {
                    fitted: *fitted.at(switch),
                    active_high: true,
                    debounce_us: SIM_DEBOUNCE_US,
                };
            }
        }
        config
    }

    /// The physical position of `joint` whose motor counted `motor` pulses.
    pub fn physical(&self, joint: usize, motor: i64) -> i64 {
        self.joints.get(joint).map_or(motor, |j| j.start + motor)
    }

    /// The step counts were set to `counts` while the motors stood at `motors`.
    pub fn counts_set(&mut self, counts: [i32; MAX_JOINTS], motors: [i64; MAX_JOINTS]) {
        for ((offset, count), motor) in self.count_offset.iter_mut().zip(counts).zip(motors) {
            *offset = i64::from(count) - motor;
        }
    }

    /// Joint `joint`'s motor now stands at `motor` pulses, after an edge at `tick`:
    /// records the inputs whose level changed. Returns the side of a limit switch that
    /// closed, if one did.
    pub fn moved(&mut self, joint: usize, motor: i64, tick: u64) -> Option<Side> {
        let (Some(model), Some(levels)) = (self.joints.get(joint), self.levels.get_mut(joint))
        else {
            return None;
        };
        let pressed = model.pressed(model.start + motor);
        let fitted = model.fitted();
        let count = i32::try_from(motor + self.count_offset[joint]).unwrap_or(i32::MAX);
        let mut tripped = None;
        for switch in Switch::ALL {
            let level = *pressed.at(switch);
            if !*fitted.at(switch) || *levels.at(switch) == level {
                continue;
            }
            *levels.at_mut(switch) = level;
            if level {
                match switch {
                    Switch::Min => tripped = Some(Side::Min),
                    Switch::Max => tripped = Some(Side::Max),
                    Switch::Home => {}
                }
            }
            self.edges.push(SwitchEdge {
                joint: joint as u8,
                switch,
                level,
                count,
                tick,
            });
        }
        tripped
    }

    /// The edges recorded since the last call, in the order they happened.
    pub fn take_edges(&mut self) -> Vec<SwitchEdge> {
        std::mem::take(&mut self.edges)
    }
}

/// Builds the model from the options' `--position`, `--home-switch`, `--limit-switch`.
pub fn model_of(
    positions: &[(usize, i64)],
    homes: &[(usize, i64, Side)],
    limits: &[(usize, i64, i64)],
) -> SwitchModel {
    let mut joints = [JointModel::default(); MAX_JOINTS];
    for &(j, p) in positions {
        if let Some(joint) = joints.get_mut(j) {
            joint.start = p;
        }
    }
    for &(j, p, side) in homes {
        if let Some(joint) = joints.get_mut(j) {
            joint.home = Some((p, side));
        }
    }
    for &(j, min, max) in limits {
        if let Some(joint) = joints.get_mut(j) {
            joint.limits = Some((min, max));
        }
    }
    SwitchModel::new(joints)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edges_where_the_levels_change_and_trips_on_limits_only() {
        let mut model = model_of(&[(0, 50)], &[(0, 0, Side::Min)], &[(0, -20, 100)]);
        // At boot: nothing pressed, three edges at low level.
        let boot = model.take_edges();
        assert_eq!(boot.len(), 3);
        assert!(boot.iter().all(|e| !e.level));
        // Down to the home switch at physical 0: motor -50.
        assert_eq!(model.moved(0, -49, 10), None);
        assert!(model.take_edges().is_empty());
        assert_eq!(model.moved(0, -50, 11), None, "the home switch is no limit");
        assert_eq!(
            model.take_edges(),
            [SwitchEdge {
                joint: 0,
                switch: Switch::Home,
                level: true,
                count: -50,
                tick: 11
            }]
        );
        assert_eq!(
            model.moved(0, -70, 12),
            Some(Side::Min),
            "the min limit at -20"
        );
        model.counts_set([7, 0, 0, 0, 0, 0, 0, 0], [-70, 0, 0, 0, 0, 0, 0, 0]);
        assert_eq!(model.moved(0, -69, 13), None);
        let released = model.take_edges();
        assert_eq!(
            released.last().map(|e| (e.level, e.count)),
            Some((false, 8))
        );
    }
}

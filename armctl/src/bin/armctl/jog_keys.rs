//! `armctl jog` by keys: a joint chosen with a digit, jogged with the arrow keys (or `-`
//! and `+`), the increment halved and doubled with `[` and `]`, Space stops the arm at once
//! (STOPPED), `h` holds the move under way and resumes it (HOLD / RESUME, issue 32: a
//! controlled stop along the path, then on), `q` or Esc ends. A live line shows the joint,
//! the increment and the positions.
//!
//! [`Jog`] is the key handling alone (what each key asks for), tested without a terminal;
//! [`execute`] reads keys, runs each jog as a move in a thread so that Space is read while
//! the arm moves, and a second thread redraws the line from the LOCATION reports while it
//! does. Ctrl-C in a terminal's raw mode reaches `console` as a key error: the loop ends
//! and a move under way is stopped.

use std::io::Write;
use std::sync::{Mutex, PoisonError};
use std::time::Duration;

use armctl::motion::{TargetArg, Units};
use console::{Key, Term};
use protocol::MAX_JOINTS;

use crate::CliResult;
use crate::motion::Arm;

/// What a key asks for.
#[derive(Clone, Debug, PartialEq)]
pub enum JogAction {
    /// Move the selected joint by this much (units).
    Move { joint: usize, by: f64 },
    /// STOPPED now.
    Stop,
    /// HOLD the move under way, or RESUME it if held.
    HoldOrResume,
    /// End the tool.
    Quit,
    /// Only the line changes (joint or increment).
    Redraw,
    /// A key with no meaning here.
    Ignore,
}

/// The smallest and largest increment a key press may use, as multiples of the starting
/// one: halving or doubling ten times is plenty for a fine touch-up or a long traverse.
const INCREMENT_RANGE: f64 = 1024.0;

/// The key state: which joint, by how much.
#[derive(Clone, Debug, PartialEq)]
pub struct Jog {
    /// Joints the arm has.
    pub joints: usize,
    /// The selected joint.
    pub joint: usize,
    /// The increment of a key press, in the arm's units.
    pub increment: f64,
    start_increment: f64,
}

impl Jog {
    /// Joint 0 selected, `increment` per press.
    pub fn new(joints: usize, increment: f64) -> Jog {
        Jog {
            joints: joints.clamp(1, MAX_JOINTS),
            joint: 0,
            increment,
            start_increment: increment,
        }
    }

    /// The increment of a key press when none is given: 1 deg, 0.02 rad or 100 steps.
    pub fn default_increment(units: Units) -> f64 {
        match units {
            Units::Steps => 100.0,
            Units::Deg => 1.0,
            Units::Rad => 0.02,
        }
    }

    /// What `key` asks for, and the state after it.
    pub fn on_key(&mut self, key: &Key) -> JogAction {
        match key {
            Key::Char(' ') => JogAction::Stop,
            Key::Char('h') | Key::Char('H') => JogAction::HoldOrResume,
            Key::Char('q') | Key::Char('Q') | Key::Escape => JogAction::Quit,
            Key::Char(c) if c.is_ascii_digit() => {
                let j = (*c as u8 - b'0') as usize;
                if j < self.joints {
                    self.joint = j;
                    JogAction::Redraw
                } else {
                    JogAction::Ignore
                }
            }
            Key::ArrowRight | Key::ArrowUp | Key::Char('+') | Key::Char('=') => JogAction::Move {
                joint: self.joint,
                by: self.increment,
            },
            Key::ArrowLeft | Key::ArrowDown | Key::Char('-') => JogAction::Move {
                joint: self.joint,
                by: -self.increment,
            },
            Key::Char(']') => {
                self.increment = (self.increment * 2.0).min(self.start_increment * INCREMENT_RANGE);
                JogAction::Redraw
            }
            Key::Char('[') => {
                self.increment = (self.increment / 2.0).max(self.start_increment / INCREMENT_RANGE);
                JogAction::Redraw
            }
            _ => JogAction::Ignore,
        }
    }
}

/// What the line shows; shared by the key loop, the move thread and the redraw thread.
struct View {
    jog: Jog,
    position: [i32; MAX_JOINTS],
    moving: bool,
    message: String,
    quit: bool,
}

/// How often the line is redrawn while the arm moves.
const REDRAW: Duration = Duration::from_millis(100);

/// Runs the key loop until `q`, Esc or Ctrl-C.
pub fn execute(arm: &Arm<'_>, increment: Option<f64>) -> CliResult {
    let term = Term::stdout();
    if !term.is_term() {
        return Err(
            "jog by keys needs a terminal: give the joint and the increment instead \
             (`armctl jog JOINT BY`)"
                .into(),
        );
    }
    let increment = increment.unwrap_or(Jog::default_increment(arm.units));
    if !(increment.is_finite() && increment > 0.0) {
        return Err("--increment must be a number above 0".into());
    }
    println!(
        "jog: 0-{} choose a joint, arrows or -/+ move it, [ ] halve/double the step, \
         Space stops, h holds/resumes, q quits",
        arm.joints - 1
    );
    let view = Mutex::new(View {
        jog: Jog::new(arm.joints, increment),
        position: arm.position()?,
        moving: false,
        message: String::new(),
        quit: false,
    });
    let lock = &|| view.lock().unwrap_or_else(PoisonError::into_inner);
    let term = &term;
    std::thread::scope(|scope| {
        // The live line while a move runs, from the LOCATION reports.
        scope.spawn(move || {
            while !lock().quit {
                std::thread::sleep(REDRAW);
                let mut v = lock();
                if v.moving {
                    if let Some(location) = arm.client.last_location() {
                        v.position = location.position;
                    }
                    draw(term, arm, &v);
                }
            }
        });
        loop {
            draw(term, arm, &lock());
            let Ok(key) = term.read_key() else { break };
            let mut v = lock();
            match v.jog.on_key(&key) {
                JogAction::Quit => break,
                JogAction::Stop => {
                    v.message = match arm.client.stop() {
                        Ok(_) => "stopped".into(),
                        Err(e) => format!("STOPPED: {e}"),
                    };
                }
                JogAction::HoldOrResume => {
                    let held = matches!(
                        arm.client.motion(),
                        Ok((_, Some(m))) if m.flags.has(protocol::MotionFlags::HELD)
                    );
                    let (verb, result) = if held {
                        ("resumed", arm.client.resume())
                    } else {
                        ("held", arm.client.hold())
                    };
                    v.message = match result {
                        Ok(_) => verb.into(),
                        Err(e) => format!("{}: {e}", if held { "RESUME" } else { "HOLD" }),
                    };
                }
                JogAction::Move { joint, by } if !v.moving => {
                    let arg = TargetArg {
                        joint: Some(joint.to_string()),
                        value: by,
                    };
                    match arm.targets(&[arg], true, &v.position) {
                        Ok(target) => {
                            v.moving = true;
                            v.message.clear();
                            scope.spawn(move || {
                                let result = arm.move_to(&target, None, true);
                                let mut v = lock();
                                v.moving = false;
                                match result {
                                    Ok(at) => v.position = at,
                                    Err(e) => {
                                        v.message = e;
                                        if let Ok(at) = arm.position() {
                                            v.position = at;
                                        }
                                    }
                                }
                                draw(term, arm, &v);
                            });
                        }
                        Err(e) => v.message = e,
                    }
                }
                JogAction::Move { .. } => v.message = "still moving (Space stops)".into(),
                JogAction::Redraw | JogAction::Ignore => {}
            }
        }
        let mut v = lock();
        v.quit = true;
        if v.moving {
            // Leaving mid-move: stop the arm rather than leave it going.
            let _ = arm.client.stop();
        }
    });
    println!();
    Ok(())
}

fn draw(term: &Term, arm: &Arm<'_>, view: &View) {
    let line = format!(
        "{} by {} {}{} | {}{}",
        arm.joint_name(view.jog.joint),
        view.jog.increment,
        arm.units.name(),
        if view.moving { " (moving)" } else { "" },
        arm.positions_line(&view.position),
        if view.message.is_empty() {
            String::new()
        } else {
            format!(" | {}", view.message)
        }
    );
    let _ = term.clear_line();
    let mut out = term;
    let _ = write!(out, "\r{line}");
    let _ = out.flush();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn digits_choose_arrows_move_brackets_scale() {
        let mut jog = Jog::new(3, 1.0);
        assert_eq!(jog.on_key(&Key::Char('2')), JogAction::Redraw);
        assert_eq!(
            jog.on_key(&Key::ArrowRight),
            JogAction::Move { joint: 2, by: 1.0 }
        );
        assert_eq!(jog.on_key(&Key::Char(']')), JogAction::Redraw);
        assert_eq!(
            jog.on_key(&Key::Char('-')),
            JogAction::Move { joint: 2, by: -2.0 }
        );
        assert_eq!(jog.on_key(&Key::Char('5')), JogAction::Ignore);
        assert_eq!(jog.joint, 2);
        assert_eq!(jog.on_key(&Key::Char(' ')), JogAction::Stop);
        assert_eq!(jog.on_key(&Key::Char('h')), JogAction::HoldOrResume);
        assert_eq!(jog.on_key(&Key::Escape), JogAction::Quit);
    }

    #[test]
    fn the_increment_stays_within_its_range() {
        let mut jog = Jog::new(1, 1.0);
        for _ in 0..20 {
            jog.on_key(&Key::Char('['));
        }
        assert_eq!(jog.increment, 1.0 / INCREMENT_RANGE);
        for _ in 0..40 {
            jog.on_key(&Key::Char(']'));
        }
        assert_eq!(jog.increment, INCREMENT_RANGE);
    }
}

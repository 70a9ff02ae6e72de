//! Joint positions from a Value Change Dump of the STEP/DIR lines, such as the trace
//! `sim-host --trace FILE.vcd` writes, for `armctl plot`.
//!
//! Each joint j has wires `step{j}` and `dir{j}`: every rising STEP edge is one step, +1
//! when DIR is high at that moment and -1 when it is low (the driver convention the
//! simulator and the board use). Positions count from 0 at the start of the trace.
//!
//! A long trace has millions of edges, so positions are kept as a [`Track`]: the minimum,
//! maximum and last position per time bucket, with at most [`TRACK_BUCKETS`] buckets over
//! the whole trace (a bucket doubles in width whenever the trace outgrows them). The final
//! position and step count of each joint are exact.
//!
//! The reader takes the VCD subset tools write: `$var` declarations (anywhere in the
//! header, over several lines if need be), `$timescale`, `#time` lines, scalar changes
//! (`0`, `1`, `x`, `z`) and vector/real changes (`b1010 id`, `r0.5 id`), which are read
//! and ignored. A malformed file gives a [`VcdError`] naming the file, the line and the
//! problem.

use std::collections::HashMap;
use std::fmt;
use std::io::{self, BufRead};
use std::path::Path;

use protocol::MAX_JOINTS;

mod track;

pub use track::{Bucket, TRACK_BUCKETS, Track};

/// A problem reading a VCD file.
#[derive(Debug)]
pub struct VcdError {
    /// The file (or the name the text was given).
    pub file: String,
    /// 1-based line of the problem; `None` for a problem with the whole file.
    pub line: Option<usize>,
    /// What is wrong.
    pub problem: String,
}

impl fmt::Display for VcdError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line {
            Some(line) => write!(f, "{}:{line}: {}", self.file, self.problem),
            None => write!(f, "{}: {}", self.file, self.problem),
        }
    }
}

impl std::error::Error for VcdError {}

/// One joint's STEP/DIR wires in a trace.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct JointTrace {
    /// Rising STEP edges.
    pub steps: u64,
    /// Position at the end of the trace (exact): steps with DIR high minus steps with DIR
    /// low.
    pub position: i64,
    /// Position over time.
    pub track: Track,
    /// Whether the file declares this joint's STEP wire.
    pub declared: bool,
}

/// Joint positions read from a VCD file.
#[derive(Clone, Debug, PartialEq)]
pub struct Trace {
    /// Seconds per time unit (`$timescale`; 1 ns when the file has none).
    pub seconds_per_tick: f64,
    /// The last time stamp in the file, ticks.
    pub end_tick: u64,
    /// Joint 0 to [`MAX_JOINTS`] - 1 (joints the file does not declare are empty).
    pub joints: Vec<JointTrace>,
}

impl Trace {
    /// Exact final positions of joints `0..count`.
    pub fn positions(&self, count: usize) -> Vec<i64> {
        self.joints.iter().take(count).map(|j| j.position).collect()
    }

    /// Time of the first rising STEP edge of any joint, seconds.
    pub fn first_step_s(&self) -> Option<f64> {
        self.joints
            .iter()
            .filter_map(|j| j.track.buckets.first().map(|b| b.first_tick))
            .min()
            .map(|tick| tick as f64 * self.seconds_per_tick)
    }
}

/// A joint's traced line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JointWire {
    /// The STEP line: one step per rising edge.
    Step,
    /// The DIR line: high counts up.
    Dir,
    /// The driver's ENABLE line.
    Enable,
}

impl JointWire {
    fn prefix(self) -> &'static str {
        match self {
            JointWire::Step => "step",
            JointWire::Dir => "dir",
            JointWire::Enable => "enable",
        }
    }
}

/// The VCD name of joint `joint`'s `wire` (`step0`, `dir3`, `enable7`): the simulator's
/// trace writer declares its wires with it and this reader finds them by it.
pub fn wire_name(wire: JointWire, joint: usize) -> String {
    format!("{}{joint}", wire.prefix())
}

/// What a declared identifier is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    Step(usize),
    Dir(usize),
    Other,
}

/// Reads a VCD file.
pub fn read(path: &Path) -> Result<Trace, VcdError> {
    let (input, name) = open(path)?;
    parse(input, &name)
}

/// Opens a VCD file for reading, with its name for errors.
fn open(path: &Path) -> Result<(io::BufReader<std::fs::File>, String), VcdError> {
    let name = path.display().to_string();
    match std::fs::File::open(path) {
        Ok(file) => Ok((io::BufReader::with_capacity(1 << 16, file), name)),
        Err(e) => Err(VcdError {
            file: name,
            line: None,
            problem: e.to_string(),
        }),
    }
}

/// Whether the start of a file looks like a VCD (its first word is a `$` keyword).
pub fn looks_like_vcd(start: &[u8]) -> bool {
    start
        .split(|b| b.is_ascii_whitespace())
        .find(|word| !word.is_empty())
        .is_some_and(|word| word.starts_with(b"$"))
}

/// Reads VCD text; `file` names it in errors.
pub fn parse(input: impl BufRead, file: &str) -> Result<Trace, VcdError> {
    Reader::new(file).run(input)
}

/// Every value change of every signal of a VCD file, by name: for tests that check more of
/// a simulator trace than the joints' positions (gripper, pins, e-stop, edge times).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Changes {
    /// `name -> [(tick, value as written)]` in file order, the initial values included;
    /// a value is one character (`0`, `1`, `x`, `z`) or a vector/real word (`b101`, `r50`).
    pub changes: HashMap<String, Vec<(u64, String)>>,
}

impl Changes {
    /// Times of the rising edges of wire `name`.
    pub fn rising_edges(&self, name: &str) -> Vec<u64> {
        let mut edges = Vec::new();
        let mut level = false;
        for (t, v) in self
            .changes
            .get(name)
            .map(Vec::as_slice)
            .unwrap_or_default()
        {
            let high = v == "1";
            if high && !level {
                edges.push(*t);
            }
            level = high;
        }
        edges
    }

    /// When wire `name` first went high and last went low: the span of a mark such as the
    /// e-stop wires or the gripper's activity (`None` if it never did either).
    pub fn high_span(&self, name: &str) -> Option<(u64, u64)> {
        let changes = self.changes.get(name)?;
        let rose = changes.iter().find(|(_, v)| v == "1")?.0;
        let fell = changes.iter().rev().find(|(_, v)| v == "0")?.0;
        Some((rose, fell))
    }

    /// The value of `name` at `tick` (the last change at or before it).
    pub fn value_at(&self, name: &str, tick: u64) -> Option<&str> {
        self.changes
            .get(name)?
            .iter()
            .take_while(|(t, _)| *t <= tick)
            .last()
            .map(|(_, v)| v.as_str())
    }

    /// Net position of joint `j` from its STEP and DIR wires, as [`Trace`] counts it.
    pub fn joint_position(&self, j: usize) -> i64 {
        let dir = wire_name(JointWire::Dir, j);
        self.rising_edges(&wire_name(JointWire::Step, j))
            .into_iter()
            // DIR is set before the pulse: its value at the edge's time.
            .map(|t| {
                if self.value_at(&dir, t) == Some("1") {
                    1
                } else {
                    -1
                }
            })
            .sum()
    }
}

/// Reads every value change of VCD text; `file` names it in errors.
pub fn changes(input: impl BufRead, file: &str) -> Result<Changes, VcdError> {
    let mut reader = Reader::new(file);
    reader.all_changes = Some(Changes::default());
    reader.read_all(input)?;
    Ok(reader.all_changes.unwrap_or_default())
}

/// Reads every value change of a VCD file.
pub fn read_changes(path: &Path) -> Result<Changes, VcdError> {
    let (input, name) = open(path)?;
    changes(input, &name)
}

/// The reader's state while it goes through the lines.
struct Reader<'a> {
    file: &'a str,
    line: usize,
    /// `$keyword` of the section being read and the words read so far.
    section: Option<(String, Vec<String>)>,
    in_header: bool,
    /// Identifier code to the roles it has (a code may be declared more than once).
    ids: HashMap<Vec<u8>, Vec<Role>>,
    seconds_per_tick: Option<f64>,
    tick: u64,
    /// Value (`b1010`, `r0.5`) of a vector or real change waiting for its identifier.
    pending_vector: Option<Vec<u8>>,
    /// Every change by signal name, when asked for ([`changes`]).
    all_changes: Option<Changes>,
    /// Identifier code to the names declared with it, when keeping every change.
    names: HashMap<Vec<u8>, Vec<String>>,
    step_high: [bool; MAX_JOINTS],
    dir_high: [bool; MAX_JOINTS],
    joints: Vec<JointTrace>,
}

impl<'a> Reader<'a> {
    fn new(file: &'a str) -> Reader<'a> {
        Reader {
            file,
            line: 0,
            section: None,
            in_header: true,
            ids: HashMap::new(),
            seconds_per_tick: None,
            tick: 0,
            pending_vector: None,
            all_changes: None,
            names: HashMap::new(),
            step_high: [false; MAX_JOINTS],
            dir_high: [false; MAX_JOINTS],
            joints: vec![JointTrace::default(); MAX_JOINTS],
        }
    }

    fn error(&self, problem: impl Into<String>) -> VcdError {
        VcdError {
            file: self.file.to_string(),
            line: Some(self.line),
            problem: problem.into(),
        }
    }

    fn run(mut self, input: impl BufRead) -> Result<Trace, VcdError> {
        self.read_all(input)?;
        if !self.joints.iter().any(|j| j.declared) {
            return Err(VcdError {
                file: self.file.to_string(),
                line: None,
                problem: "no step0..step7 wires declared: not a trace of the arm's STEP/DIR lines"
                    .into(),
            });
        }
        Ok(Trace {
            seconds_per_tick: self.seconds_per_tick.unwrap_or(1e-9),
            end_tick: self.tick,
            joints: self.joints,
        })
    }

    /// Goes through every line and checks that the file did not stop part way.
    fn read_all(&mut self, mut input: impl BufRead) -> Result<(), VcdError> {
        let mut bytes = Vec::new();
        loop {
            bytes.clear();
            let n = input.read_until(b'\n', &mut bytes).map_err(|e| {
                let mut error = self.error(e.to_string());
                error.line = Some(self.line + 1);
                error
            })?;
            if n == 0 {
                break;
            }
            self.line += 1;
            for word in bytes
                .split(|b| b.is_ascii_whitespace())
                .filter(|w| !w.is_empty())
            {
                self.word(word)?;
            }
        }
        if let Some((keyword, _)) = &self.section {
            return Err(self.error(format!("{keyword} has no $end (file truncated?)")));
        }
        if self.pending_vector.is_some() {
            return Err(self.error("a vector or real value has no identifier (file truncated?)"));
        }
        if self.in_header {
            return Err(VcdError {
                file: self.file.to_string(),
                line: None,
                problem: "no $enddefinitions: not a VCD file, or cut short in its header".into(),
            });
        }
        Ok(())
    }

    fn word(&mut self, word: &[u8]) -> Result<(), VcdError> {
        if let Some((keyword, mut words)) = self.section.take() {
            if word == b"$end" {
                return self.end_section(&keyword, &words);
            }
            match std::str::from_utf8(word) {
                Ok(text) => words.push(text.to_string()),
                Err(_) => return Err(self.error(format!("{keyword}: text is not UTF-8"))),
            }
            self.section = Some((keyword, words));
            return Ok(());
        }
        if let Some(value) = self.pending_vector.take() {
            return self.change(&value, word);
        }
        match word.first() {
            Some(b'$') => self.keyword(word),
            _ if self.in_header => Err(self.error(format!(
                "`{}` outside a $ section before $enddefinitions",
                String::from_utf8_lossy(word)
            ))),
            Some(b'#') => self.time(&word[1..]),
            Some(b'0' | b'1' | b'x' | b'X' | b'z' | b'Z') if word.len() > 1 => {
                self.change(&word[..1], &word[1..])
            }
            Some(b'b' | b'B' | b'r' | b'R') => {
                // Vectors and reals: the identifier is the next word.
                self.pending_vector = Some(word.to_vec());
                Ok(())
            }
            _ => Err(self.error(format!(
                "`{}` is not a time (#N) or a value change (0id, 1id, b... id, r... id)",
                String::from_utf8_lossy(word)
            ))),
        }
    }

    fn keyword(&mut self, word: &[u8]) -> Result<(), VcdError> {
        let keyword = String::from_utf8_lossy(word).into_owned();
        match keyword.as_str() {
            // Markers around value changes in the body; their changes are read as usual.
            "$dumpvars" | "$dumpall" | "$dumpon" | "$dumpoff" | "$end" if !self.in_header => Ok(()),
            "$end" => Err(self.error("$end without a section")),
            "$comment" => {
                self.section = Some((keyword, Vec::new()));
                Ok(())
            }
            _ if self.in_header => {
                self.section = Some((keyword, Vec::new()));
                Ok(())
            }
            _ => Err(self.error(format!("unexpected {keyword} after $enddefinitions"))),
        }
    }

    fn end_section(&mut self, keyword: &str, words: &[String]) -> Result<(), VcdError> {
        match keyword {
            "$var" => self.declare(words),
            "$timescale" => {
                self.seconds_per_tick = Some(timescale(&words.concat()).ok_or_else(|| {
                    self.error(format!(
                        "$timescale `{}` is not 1, 10 or 100 of s, ms, us, ns, ps or fs",
                        words.join(" ")
                    ))
                })?);
                Ok(())
            }
            "$enddefinitions" => {
                self.in_header = false;
                Ok(())
            }
            // $version, $date, $comment, $scope, $upscope: nothing to take.
            _ => Ok(()),
        }
    }

    /// `$var <type> <size> <id> <reference> [range] $end`.
    fn declare(&mut self, words: &[String]) -> Result<(), VcdError> {
        let [_kind, _size, id, reference, ..] = words else {
            return Err(self.error(format!(
                "$var needs a type, size, identifier and name: `$var {} $end`",
                words.join(" ")
            )));
        };
        let role = joint_wire(reference, JointWire::Step)
            .map(Role::Step)
            .or_else(|| joint_wire(reference, JointWire::Dir).map(Role::Dir))
            .unwrap_or(Role::Other);
        if let Role::Step(j) = role
            && let Some(joint) = self.joints.get_mut(j)
        {
            joint.declared = true;
        }
        self.ids
            .entry(id.as_bytes().to_vec())
            .or_default()
            .push(role);
        if self.all_changes.is_some() {
            self.names
                .entry(id.as_bytes().to_vec())
                .or_default()
                .push(reference.clone());
        }
        Ok(())
    }

    fn time(&mut self, digits: &[u8]) -> Result<(), VcdError> {
        let tick = std::str::from_utf8(digits)
            .ok()
            .and_then(|t| t.parse::<u64>().ok())
            .ok_or_else(|| {
                self.error(format!(
                    "`#{}` is not a time",
                    String::from_utf8_lossy(digits)
                ))
            })?;
        if tick < self.tick {
            return Err(self.error(format!("time goes back from #{} to #{tick}", self.tick)));
        }
        self.tick = tick;
        Ok(())
    }

    /// A change of `id` to `value`: one scalar character, or a vector/real (`b...`, `r...`).
    fn change(&mut self, value: &[u8], id: &[u8]) -> Result<(), VcdError> {
        let Some(roles) = self.ids.get(id) else {
            return Err(self.error(format!(
                "identifier `{}` is not declared",
                String::from_utf8_lossy(id)
            )));
        };
        if let Some(all) = &mut self.all_changes {
            let text = String::from_utf8_lossy(value);
            for name in self.names.get(id).into_iter().flatten() {
                all.changes
                    .entry(name.clone())
                    .or_default()
                    .push((self.tick, text.clone().into_owned()));
            }
        }
        let [scalar] = value else {
            return Ok(());
        };
        // x and z read as low: a line that is not driven high makes no step.
        let high = *scalar == b'1';
        for &role in roles {
            match role {
                Role::Dir(j) => self.dir_high[j] = high,
                Role::Step(j) => {
                    let rising = high && !self.step_high[j];
                    self.step_high[j] = high;
                    if rising {
                        let joint = &mut self.joints[j];
                        let before = joint.position;
                        joint.position += if self.dir_high[j] { 1 } else { -1 };
                        joint.steps += 1;
                        joint.track.step(self.tick, before, joint.position);
                    }
                }
                Role::Other => {}
            }
        }
        Ok(())
    }
}

/// `j` if `reference` is [`wire_name`]`(wire, j)` with j < MAX_JOINTS.
fn joint_wire(reference: &str, wire: JointWire) -> Option<usize> {
    let digits = reference.strip_prefix(wire.prefix())?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok().filter(|&j| j < MAX_JOINTS)
}

/// Seconds of a `$timescale` such as `1ns` or `10 us` (spaces removed).
fn timescale(text: &str) -> Option<f64> {
    let split = text.find(|c: char| !c.is_ascii_digit())?;
    let (number, unit) = text.split_at(split);
    let number = match number {
        "1" => 1.0,
        "10" => 10.0,
        "100" => 100.0,
        _ => return None,
    };
    let unit = match unit {
        "s" => 1.0,
        "ms" => 1e-3,
        "us" => 1e-6,
        "ns" => 1e-9,
        "ps" => 1e-12,
        "fs" => 1e-15,
        _ => return None,
    };
    Some(number * unit)
}

#[cfg(test)]
mod tests;

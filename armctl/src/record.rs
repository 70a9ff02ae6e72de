//! Recorded runs: LOCATION reports written as CSV (`time_s,state,j0,j1,...`) by
//! `armctl watch --record` and `armctl run --record`, and read back for `armctl plot`.

use std::io::{self, Write};
use std::path::Path;
use std::time::Instant;

use protocol::{Location, MAX_JOINTS, State};

/// One recorded LOCATION report.
#[derive(Clone, Debug, PartialEq)]
pub struct Sample {
    /// Seconds since the recording started.
    pub time_s: f64,
    /// The state code in the report.
    pub state: u8,
    /// Joint positions, steps.
    pub position: Vec<i32>,
}

/// Writes LOCATION reports as CSV lines as they arrive.
pub struct Recorder<W: Write> {
    out: W,
    joints: usize,
    started: Instant,
}

impl<W: Write> std::fmt::Debug for Recorder<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("joints", &self.joints)
            .finish_non_exhaustive()
    }
}

impl Recorder<io::BufWriter<std::fs::File>> {
    /// Creates (or truncates) a recording file for `joints` joints.
    pub fn create(path: &Path, joints: usize) -> io::Result<Self> {
        Recorder::new(io::BufWriter::new(std::fs::File::create(path)?), joints)
    }
}

impl<W: Write> Recorder<W> {
    /// Writes the header; time counts from now.
    pub fn new(mut out: W, joints: usize) -> io::Result<Self> {
        let joints = joints.clamp(1, MAX_JOINTS);
        write!(out, "time_s,state")?;
        for j in 0..joints {
            write!(out, ",j{j}")?;
        }
        writeln!(out)?;
        Ok(Recorder {
            out,
            joints,
            started: Instant::now(),
        })
    }

    /// Appends one report, stamped with the time since [`Recorder::new`].
    pub fn record(&mut self, location: &Location) -> io::Result<()> {
        let t = self.started.elapsed().as_secs_f64();
        write!(self.out, "{t:.6},{}", location.state)?;
        for p in &location.position[..self.joints] {
            write!(self.out, ",{p}")?;
        }
        writeln!(self.out)
    }

    /// Flushes what is buffered.
    pub fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }
}

/// Reads a recording back.
pub fn read(path: &Path) -> io::Result<Vec<Sample>> {
    parse(&std::fs::read_to_string(path)?)
}

/// Parses a recording (the header line and malformed lines are skipped).
pub fn parse(text: &str) -> io::Result<Vec<Sample>> {
    let mut samples = Vec::new();
    for line in text.lines().skip(1) {
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() < 3 {
            continue;
        }
        let (Ok(time_s), Ok(state)) = (fields[0].parse::<f64>(), fields[1].parse::<u8>()) else {
            continue;
        };
        let Ok(position) = fields[2..].iter().map(|f| f.parse::<i32>()).collect() else {
            continue;
        };
        samples.push(Sample {
            time_s,
            state,
            position,
        });
    }
    if samples.is_empty() {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            "no samples in the recording (expected lines `time_s,state,j0,...`)",
        ));
    }
    Ok(samples)
}

/// Name of a state code for display.
pub fn state_name(code: u8) -> &'static str {
    State::from_u8(code).map_or("?", State::name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recording_round_trips() {
        let mut out = Vec::new();
        {
            let mut recorder = Recorder::new(&mut out, 3).unwrap();
            for k in 0..4 {
                let mut location = Location {
                    state: State::Running as u8,
                    ..Location::default()
                };
                location.position[..3].copy_from_slice(&[k, -k, 7]);
                recorder.record(&location).unwrap();
            }
            recorder.flush().unwrap();
        }
        let text = String::from_utf8(out).unwrap();
        assert!(text.starts_with("time_s,state,j0,j1,j2\n"));
        let samples = parse(&text).unwrap();
        assert_eq!(samples.len(), 4);
        assert_eq!(samples[3].position, vec![3, -3, 7]);
        assert_eq!(samples[3].state, 2);
        assert!(samples.windows(2).all(|w| w[0].time_s <= w[1].time_s));
        assert!(parse("time_s,state,j0\n").is_err());
    }
}

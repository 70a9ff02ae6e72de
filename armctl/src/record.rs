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
        Recorder::create_named(path, joints, &[])
    }

    /// As [`Recorder::create`], with joint names in the header ([`Recorder::new_named`]).
    pub fn create_named(path: &Path, joints: usize, names: &[String]) -> io::Result<Self> {
        Recorder::new_named(
            io::BufWriter::new(std::fs::File::create(path)?),
            joints,
            names,
        )
    }
}

impl<W: Write> Recorder<W> {
    /// Writes the header; time counts from now.
    pub fn new(out: W, joints: usize) -> io::Result<Self> {
        Recorder::new_named(out, joints, &[])
    }

    /// As [`Recorder::new`], the header naming joint `j` `names[j]` where given (a joint
    /// config's names; commas become `_`), else `jN`.
    pub fn new_named(mut out: W, joints: usize, names: &[String]) -> io::Result<Self> {
        let joints = joints.clamp(1, MAX_JOINTS);
        write!(out, "time_s,state")?;
        for j in 0..joints {
            match names.get(j) {
                Some(name) => write!(out, ",{}", name.replace([',', '\n', '\r'], "_"))?,
                None => write!(out, ",j{j}")?,
            }
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

/// A recording that cannot be read: the file, the line (1-based) when one is at fault, and
/// what is wrong.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordError {
    /// The file, as given.
    pub file: String,
    /// The line at fault, counting the header as line 1.
    pub line: Option<u64>,
    /// What is wrong.
    pub problem: String,
}

impl std::fmt::Display for RecordError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.line {
            Some(line) => write!(f, "{}: line {line}: {}", self.file, self.problem),
            None => write!(f, "{}: {}", self.file, self.problem),
        }
    }
}

impl std::error::Error for RecordError {}

/// Reads a recording back.
pub fn read(path: &Path) -> Result<Vec<Sample>, RecordError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| RecordError {
        file: file.clone(),
        line: None,
        problem: e.to_string(),
    })?;
    parse(&text, &file)
}

/// Parses a recording of `file`: a header line, then `time_s,state,j0,...` lines with as many
/// fields as the header. Any other line is an error naming its line.
pub fn parse(text: &str, file: &str) -> Result<Vec<Sample>, RecordError> {
    let error = |line: Option<u64>, problem: String| RecordError {
        file: file.to_string(),
        line,
        problem,
    };
    let mut rows = csv::ReaderBuilder::new()
        .has_headers(true)
        .trim(csv::Trim::All)
        .from_reader(text.as_bytes());
    let mut samples = Vec::new();
    for row in rows.records() {
        let row = row.map_err(|e| error(e.position().map(csv::Position::line), e.to_string()))?;
        let line = row.position().map(csv::Position::line);
        if row.len() < 3 {
            return Err(error(
                line,
                format!("{} fields, expected `time_s,state,j0,...`", row.len()),
            ));
        }
        let time_s = number(&row, 0, "time", file)?;
        let state = number(&row, 1, "state", file)?;
        let position = (2..row.len())
            .map(|at| number(&row, at, &format!("joint {} position", at - 2), file))
            .collect::<Result<Vec<i32>, RecordError>>()?;
        samples.push(Sample {
            time_s,
            state,
            position,
        });
    }
    if samples.is_empty() {
        return Err(error(
            None,
            "no samples in the recording (expected lines `time_s,state,j0,...`)".to_string(),
        ));
    }
    Ok(samples)
}

/// Field `at` of a recording's row as a number; `what` names it in the error.
fn number<T>(row: &csv::StringRecord, at: usize, what: &str, file: &str) -> Result<T, RecordError>
where
    T: std::str::FromStr,
    T::Err: std::fmt::Display,
{
    let text = &row[at];
    text.parse().map_err(|e| RecordError {
        file: file.to_string(),
        line: row.position().map(csv::Position::line),
        problem: format!("{what} {text:?}: {e}"),
    })
}

/// Name of a state code for display.
pub fn state_name(code: u8) -> &'static str {
    State::name_of(code)
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
        let samples = parse(&text, "run.csv").unwrap();
        assert_eq!(samples.len(), 4);
        assert_eq!(samples[3].position, vec![3, -3, 7]);
        assert_eq!(samples[3].state, 2);
        assert!(samples.windows(2).all(|w| w[0].time_s <= w[1].time_s));
        assert!(parse("time_s,state,j0\n", "run.csv").is_err());
    }

    #[test]
    fn a_malformed_line_is_an_error_naming_file_and_line() {
        let good = "time_s,state,j0,j1\n0.0,2,1,2\n0.1,2,3,4\n";
        assert_eq!(parse(good, "run.csv").unwrap().len(), 2);
        for (bad, line, says) in [
            (
                "time_s,state,j0,j1\n0.0,2,1,2\n0.1,2,x,4\n",
                3,
                "joint 0 position \"x\"",
            ),
            (
                "time_s,state,j0,j1\n0.0,2,1,2\n0.1,2,3\n",
                3,
                "found record with 3 fields",
            ),
            ("time_s,state,j0,j1\nnow,2,1,2\n", 2, "time \"now\""),
            ("time_s,state,j0,j1\n0.0,300,1,2\n", 2, "state \"300\""),
            ("time_s,state\n0.0,2\n", 2, "2 fields"),
        ] {
            let err = parse(bad, "run.csv").unwrap_err();
            assert_eq!(err.line, Some(line), "{err}");
            let text = err.to_string();
            assert!(
                text.starts_with(&format!("run.csv: line {line}: ")) && text.contains(says),
                "{text}"
            );
        }
    }
}

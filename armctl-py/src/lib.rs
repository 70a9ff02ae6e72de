//! The Python module `armctl`: the armctl host library for Python scripts.
//!
//! Everything here forwards to the `armctl` crate (the same client, upload and trajectory
//! conversion as the `armctl` tool); this crate only converts between Python and Rust
//! values and decides how blocking calls behave in Python. This file holds the `Arm` class,
//! `connect`, `discover` and the module; `errors.rs` the exceptions, `dicts.rs` the report
//! dicts, `run.rs` runs in the background and the LOCATION iterator, `signals.rs` the
//! SIGTERM and SIGHUP handler, `units.rs` the config's units. This file is long because
//! the `Arm` class is one `#[pymethods]` block (one per class without pyo3's
//! `multiple-pymethods` feature) of thin forwarding methods. How blocking calls behave:
//!
//! - every wait (an ACK, a run, a LOCATION report) releases the GIL, so other Python
//!   threads run meanwhile;
//! - a wait for a run or a RETURN wakes every [`SIGNAL_POLL`] to let Python handle
//!   signals: Ctrl-C (KeyboardInterrupt) during `run`, `run_file`, `RunHandle.wait` or
//!   `go_home` sends STOPPED before it propagates, and so does any error that ends them
//!   once the motion was sent (a stall, a lost link, a run ended early);
//! - leaving a `with armctl.connect(...)` block by an exception while a run or a RETURN
//!   this connection started may be under way sends STOPPED;
//! - STOPPED is resent every 100 ms until the controller ACKs it, 10 copies at most
//!   (`run::stop_arm`); a second Ctrl-C ends that wait; not ACKed, a RuntimeWarning says
//!   so;
//! - SIGTERM and SIGHUP: from `connect()` on, armctl's handler (`signals.rs`) stops every
//!   run or RETURN of this process under way, then the process dies of the signal.
//!
//! The `.pyi` stub beside Cargo.toml (`armctl.pyi`) documents the API for Python users.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use armctl::motion::{
    JointLimit, MoveSpeed, TargetArg, Units, check_targets, plan_move, targets_in_steps,
};
use armctl::trajectory::{self, ArmConfig, Waypoints};
use armctl::{Client, Options, RunOptions};
use numpy::{PyReadonlyArray1, PyReadonlyArray2};
use protocol::{Location, MAX_JOINTS, NetSettings, State, StatusReport};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// How often a blocking wait wakes up to let Python run its signal handlers (Ctrl-C).
const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// How long `positions()` and a run wait for a fresh LOCATION report.
const LOCATION_TIMEOUT: Duration = Duration::from_secs(2);

/// Sets each `"key" => value` on a Python dict (`set_item`, `?` on failure).
macro_rules! set_items {
    ($dict:expr, { $($key:literal => $value:expr),* $(,)? }) => {
        $( $dict.set_item($key, $value)?; )*
    };
}

mod described;
mod dicts;
mod errors;
mod run;
mod signals;
mod units;

use dicts::status_dict;
use errors::{
    ArmctlError, NoReplyError, RefusedError, RunEndedError, StalledError, TrajectoryError,
    to_py_err, trajectory_err,
};
use run::{Locations, RunHandle, RunState, stop_arm};
use signals::MotionKind;
use units::{array_units, parse_units, positions_array, shown_in};

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// A connection to one controller (`armctl.connect(...)`); a context manager.
#[pyclass(module = "armctl")]
struct Arm {
    inner: Mutex<Option<Arc<Client>>>,
    /// Runs started here, to stop on an exception in a `with` block.
    runs: Mutex<Vec<Arc<RunState>>>,
    /// A RETURN started here may still move the arm (not waited to its end): to stop on an
    /// exception in a `with` block.
    returning: Arc<AtomicBool>,
    /// What the serial port received since `serial_open` (its stream subscribed before
    /// the USART_START went, so nothing that comes back at once is missed).
    serial: Mutex<Option<std::sync::mpsc::Receiver<Vec<u8>>>>,
}

impl Arm {
    /// PWM_START with the registers for `freq` Hz, `duty` and `pulses` (0: servo mode) at
    /// the controller's PWM timer clock (from a STATUS).
    fn pwm_start_at(&self, py: Python<'_>, freq: f64, duty: f64, pulses: i32) -> PyResult<()> {
        let arm = self.controller()?;
        let clock = py
            .detach({
                let arm = arm.clone();
                move || arm.status()
            })
            .map_err(|e| to_py_err(py, e))?
            .pwm_timer_clock_hz;
        let pwm =
            armctl::pwm::settings(clock, freq, duty, pulses).map_err(PyValueError::new_err)?;
        py.detach(move || arm.pwm_start(pwm))
            .map(|_| ())
            .map_err(|e| to_py_err(py, e))
    }

    fn controller(&self) -> PyResult<Arc<Client>> {
        lock(&self.inner)
            .clone()
            .ok_or_else(|| ArmctlError::new_err("the connection is closed"))
    }

    /// Calls `f` on the controller with the GIL released; armctl errors become Python's.
    fn call<T: Send>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(&Client) -> armctl::Result<T> + Send,
    ) -> PyResult<T> {
        let arm = self.controller()?;
        py.detach(move || f(&arm)).map_err(|e| to_py_err(py, e))
    }

    fn start_run(
        &self,
        py: Python<'_>,
        points: Vec<protocol::Point>,
        joints: usize,
        wait: bool,
        window: usize,
        speed: Option<u8>,
    ) -> PyResult<Py<PyAny>> {
        let arm = self.controller()?;
        let options = RunOptions {
            window,
            speed_percent: speed,
            ..RunOptions::default()
        };
        let handle = RunHandle::start(arm.clone(), points, options, joints)?;
        lock(&self.runs).push(handle.state.clone());
        signals::register(py, &arm, MotionKind::Run(handle.state.clone()));
        if wait {
            handle.wait_inner(py, None)
        } else {
            Ok(Py::new(py, handle)?.into_any())
        }
    }

    /// What `run` and `run_file` share once they have waypoints: STATUS and LOCATION, the
    /// joint count check, resampling into points against the arm's position, the run.
    fn run_waypoints(
        &self,
        py: Python<'_>,
        run: WaypointRun,
        wait: bool,
        window: Option<usize>,
    ) -> PyResult<Py<PyAny>> {
        let joints = run.waypoints.positions.first().map_or(0, Vec::len);
        let (status, location) = self.before_run(py)?;
        // The window the controller advertises, as `armctl run` takes it (issue 23: the
        // package used 8 where the CLI used the advertised 32).
        let window = window.unwrap_or_else(|| armctl::window_of(&status));
        let arm_joints = usize::from(status.joints).clamp(1, MAX_JOINTS);
        if joints > arm_joints {
            return Err(TrajectoryError::new_err(match &run.file {
                None => {
                    format!("{joints} joints in the positions, the controller drives {arm_joints}")
                }
                Some(path) => format!(
                    "{}: {joints} joints in the file, the controller drives {arm_joints}",
                    path.display()
                ),
            }));
        }
        let given = run.config.is_some();
        let config = run
            .config
            .unwrap_or_else(|| ArmConfig::unlimited(joints, status.max_step_rate_hz));
        let segment_us =
            trajectory::segment_us(run.segment_ms, "segment_ms").map_err(PyValueError::new_err)?;
        let points = trajectory::to_points(
            &run.waypoints,
            &location.position,
            segment_us,
            &config,
            Some(status.max_step_rate_hz),
        )
        .map_err(|e| match given {
            true => errors::trajectory_err_in(e, &config, run.units),
            false => trajectory_err(e),
        })?;
        self.start_run(py, points, arm_joints, wait, window, run.speed)
    }

    /// What `move_to` and `jog` share: targets (joint, value in `units`) from the arm's
    /// position, planned within the config's (or the controller's) limits and run.
    #[allow(clippy::too_many_arguments)]
    fn move_joints(
        &self,
        py: Python<'_>,
        targets: Vec<(usize, f64)>,
        config: Option<PathBuf>,
        units: Option<String>,
        speed: f64,
        relative: bool,
        segment_ms: f64,
        wait: bool,
    ) -> PyResult<Option<Py<PyAny>>> {
        let config = match config {
            Some(p) => Some(ArmConfig::load(&p).map_err(trajectory_err)?),
            // No config: the arm the controller describes, if it does (issue 31).
            None => self.described(py)?,
        };
        let units = parse_units(units)?
            .or(config.as_ref().map(|c| c.units))
            .unwrap_or_default();
        if units != Units::Steps && config.is_none() {
            return Err(PyValueError::new_err(format!(
                "units {:?} need a joint config (config=PATH, or one kept on the controller: \
                 armctl config push FILE)",
                units.name()
            )));
        }
        let segment_us =
            trajectory::segment_us(segment_ms, "segment_ms").map_err(PyValueError::new_err)?;
        let (status, location) = self.before_run(py)?;
        let joints = usize::from(status.joints).clamp(1, MAX_JOINTS);
        let config =
            config.unwrap_or_else(|| ArmConfig::unlimited(joints, status.max_step_rate_hz));
        let args: Vec<TargetArg> = targets
            .into_iter()
            .map(|(j, value)| TargetArg {
                joint: Some(j.to_string()),
                value,
            })
            .collect();
        let target = targets_in_steps(&args, units, relative, &location.position, joints, &config)
            .map_err(PyValueError::new_err)?;
        let mut limits = JointLimit::all(&config, Some(status.max_step_rate_hz));
        limits.truncate(joints);
        // Issue 31: the message names the joint and gives the target in the user's units,
        // as `armctl move` does (plan_move's own check speaks steps and joint numbers).
        check_targets(&target, &limits, &config, units).map_err(TrajectoryError::new_err)?;
        let speed = MoveSpeed {
            rate: speed,
            accel: 1.0,
        };
        let points = plan_move(&location.position, &target, &limits, speed, segment_us)
            .map_err(|e| TrajectoryError::new_err(e.to_string()))?;
        if points.is_empty() {
            return Ok(None);
        }
        let window = armctl::window_of(&status);
        self.start_run(py, points, joints, wait, window, None)
            .map(Some)
    }

    /// STATUS and a fresh LOCATION: what converting a trajectory needs.
    /// The arm the controller describes (issue 31: names, units, scale, limits), for a
    /// call given no config; `None` when it describes none (or predates issue 31).
    fn described(&self, py: Python<'_>) -> PyResult<Option<ArmConfig>> {
        self.call(py, |arm| {
            let status = arm.status()?;
            let joints = usize::from(status.joints).clamp(1, MAX_JOINTS);
            arm.described_arm(joints, status.max_step_rate_hz)
        })
    }

    fn before_run(&self, py: Python<'_>) -> PyResult<(StatusReport, Location)> {
        self.call(py, |arm| {
            let status = arm.status()?;
            let location = arm.current_location(LOCATION_TIMEOUT)?;
            Ok((status, location))
        })
    }
}

/// Waits for the homing cycle's end (the SWITCHES report, polled every 20 ms), looking
/// at Python's signals in between; an error names the joint a failed cycle stopped at.
fn wait_homing(py: Python<'_>, arm: &Client, deadline: std::time::Instant) -> PyResult<()> {
    loop {
        let report = py.detach(|| arm.switches()).map_err(|e| to_py_err(py, e))?;
        match report.map(|r| (r.phase, r)) {
            Some((protocol::HomingPhase::Homed, _)) => return Ok(()),
            Some((protocol::HomingPhase::Failed, r)) => {
                return Err(to_py_err(py, armctl::Error::HomingFailed(r)));
            }
            None => return Err(ArmctlError::new_err("no SWITCHES report")),
            _ => {}
        }
        if std::time::Instant::now() >= deadline {
            return Err(to_py_err(
                py,
                armctl::Error::HomingTimedOut {
                    waited: Duration::ZERO,
                },
            ));
        }
        py.check_signals()?;
        py.detach(|| std::thread::sleep(Duration::from_millis(20)));
    }
}

/// Waits until the controller is STOPPED (a RETURN ended), at most until `deadline`, with
/// the GIL released, waking at least every [`SIGNAL_POLL`] for Python's signal handlers
/// (a LOCATION report, sent at every state change, wakes it sooner). Whether it ended; the
/// signal handler's exception (KeyboardInterrupt) or the client's error.
fn wait_return(py: Python<'_>, arm: &Arc<Client>, deadline: std::time::Instant) -> PyResult<bool> {
    let mut locations = arm.locations();
    loop {
        let client = arm.clone();
        let status = py
            .detach(move || client.status())
            .map_err(|e| to_py_err(py, e))?;
        if status.state == State::Stopped {
            return Ok(true);
        }
        let now = std::time::Instant::now();
        if now >= deadline {
            return Ok(false);
        }
        let slice = SIGNAL_POLL.min(deadline - now);
        locations = py.detach(move || {
            let _ = locations.recv_timeout(slice);
            locations
        });
        py.check_signals()?;
    }
}

/// A trajectory `run` or `run_file` has read, before it meets the arm.
/// A speed override percent as the controller takes it (1..200).
fn check_speed(speed: Option<u8>) -> PyResult<Option<u8>> {
    match speed {
        Some(p)
            if !(protocol::OVERRIDE_MIN_PERCENT..=protocol::OVERRIDE_MAX_PERCENT).contains(&p) =>
        {
            Err(PyValueError::new_err(format!("speed {p} %: 1 to 200")))
        }
        other => Ok(other),
    }
}

struct WaypointRun {
    waypoints: Waypoints,
    /// The joint config, if one was given (else every joint at the arm's step rate).
    config: Option<ArmConfig>,
    /// What the positions were given in (for messages).
    units: Units,
    /// The file they were read from (`run_file`), for errors; `None` for numpy arrays.
    file: Option<PathBuf>,
    segment_ms: f64,
    /// The speed override to run at, percent (issue 32); `None`: none sent.
    speed: Option<u8>,
}

#[pymethods]
impl Arm {
    fn __enter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    /// Closes the connection; when the block is left by an exception (Ctrl-C included)
    /// while a run or a RETURN started here may be under way, sends STOPPED first (resent
    /// until ACKed); the exception then propagates.
    #[pyo3(signature = (exc_type=None, _exc_value=None, _traceback=None))]
    fn __exit__(
        &self,
        py: Python<'_>,
        exc_type: Option<Bound<'_, PyAny>>,
        _exc_value: Option<Bound<'_, PyAny>>,
        _traceback: Option<Bound<'_, PyAny>>,
    ) -> PyResult<bool> {
        let failed = exc_type.is_some_and(|t| !t.is_none());
        let mut moving = self.returning.load(Ordering::SeqCst);
        for run in lock(&self.runs).iter() {
            if !run.done.load(Ordering::SeqCst) {
                // Its thread sends nothing more.
                run.cancel.cancel();
                moving = true;
            }
        }
        if failed
            && moving
            && let Ok(arm) = self.controller()
        {
            stop_arm(py, &arm);
        }
        self.close();
        Ok(false)
    }

    /// Closes the connection (runs still under way keep it open until they end).
    fn close(&self) {
        lock(&self.inner).take();
    }

    /// The controller's address, `host:port`.
    #[getter]
    fn address(&self) -> PyResult<String> {
        Ok(self.controller()?.addr().to_string())
    }

    /// The controller's STATUS report as a dict. After a run ended by a STOPPED,
    /// `stopped_by` is its sender ("127.0.0.2:40001") when the controller tells (issue 31:
    /// one more look-only STATUS, asking for the STOP_CAUSE report).
    fn status<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let status = self.call(py, |arm| arm.status())?;
        let d = status_dict(py, &status)?;
        if status.stop_cause() == Some(protocol::StopCause::Stopped) {
            let (_, stop) = self.call(py, |arm| arm.stop_report())?;
            if let Some(from) = armctl::stopped_by(stop.as_ref()) {
                d.set_item("stopped_by", from.to_string())?;
            }
        }
        Ok(d)
    }

    /// Joint positions (one per joint in use) from a fresh LOCATION report: the one a
    /// STATUS asks for (issue 23: from any host, read-only when another owns the
    /// controller), or, from an older controller, a periodic one. In steps (numpy int32);
    /// with a `config`, in `units` (default its `units`; float64), as `armctl watch
    /// --config` shows them (issue 31).
    #[pyo3(signature = (config=None, units=None))]
    fn positions<'py>(
        &self,
        py: Python<'py>,
        config: Option<PathBuf>,
        units: Option<String>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let shown = match config {
            Some(config) => shown_in(Some(config), units)?,
            // No config: the controller's description, if it keeps one (issue 31).
            None => match self.described(py)? {
                Some(described) => {
                    let units = parse_units(units)?.unwrap_or(described.units);
                    (units != Units::Steps).then_some((described, units))
                }
                None => shown_in(None, units)?,
            },
        };
        let glance = self.call(py, |arm| arm.glance(false))?;
        if let Some(location) = glance.location {
            let joints = usize::from(glance.status.joints).clamp(1, MAX_JOINTS);
            return Ok(positions_array(
                py,
                &location.position[..joints],
                shown.as_ref(),
            ));
        }
        let (status, location) = self.before_run(py)?;
        let joints = usize::from(status.joints).clamp(1, MAX_JOINTS);
        Ok(positions_array(
            py,
            &location.position[..joints],
            shown.as_ref(),
        ))
    }

    /// Runs a trajectory through waypoints: `times` (N,) seconds from the start,
    /// strictly increasing; `positions` (N, J) in `units`, by default the `config`'s (a
    /// joint config JSON file: units, steps_per_radian, zero_offset_steps, limits) when
    /// it states them, else radians with a config and steps without. The arm moves
    /// from where it is to the first waypoint (at t=0 it must be there already), and
    /// through the rest resampled into `segment_ms` points. `wait=False` returns a
    /// RunHandle at once. `speed`: run at this percent of the planned speed (1..200,
    /// OVERRIDE, issue 32; it stays for later runs until changed).
    #[pyo3(signature = (times, positions, config=None, wait=true, segment_ms=10.0, window=None, units=None, speed=None))]
    #[allow(clippy::too_many_arguments)]
    fn run(
        &self,
        py: Python<'_>,
        times: &Bound<'_, PyAny>,
        positions: &Bound<'_, PyAny>,
        config: Option<PathBuf>,
        wait: bool,
        segment_ms: f64,
        window: Option<usize>,
        units: Option<String>,
        speed: Option<u8>,
    ) -> PyResult<Py<PyAny>> {
        let speed = check_speed(speed)?;
        let units = parse_units(units)?;
        let numpy = py.import("numpy")?;
        let times = numpy.call_method1("ascontiguousarray", (times, "float64"))?;
        let positions = numpy.call_method1("ascontiguousarray", (positions, "float64"))?;
        let times: PyReadonlyArray1<f64> = times
            .extract()
            .map_err(|_| PyValueError::new_err("times must be a 1-D array of seconds"))?;
        let positions: PyReadonlyArray2<f64> = positions.extract().map_err(|_| {
            PyValueError::new_err("positions must be a 2-D array (N waypoints, J joints)")
        })?;
        let times = times.as_array();
        let positions = positions.as_array();
        let (n, joints) = positions.dim();
        if n != times.len() || n == 0 {
            return Err(PyValueError::new_err(format!(
                "{} times for {n} rows of positions: one time per waypoint, at least one",
                times.len()
            )));
        }
        if joints == 0 || joints > MAX_JOINTS {
            return Err(PyValueError::new_err(format!(
                "{joints} joints: 1 to {MAX_JOINTS}"
            )));
        }
        let loaded = config
            .as_deref()
            .map(ArmConfig::load)
            .transpose()
            .map_err(trajectory_err)?;
        let described = match &loaded {
            Some(_) => None,
            // No config: the arm the controller describes, in its units (issue 31).
            None => self.described(py)?,
        };
        let (units, config) = match described {
            Some(d) => (units.unwrap_or(d.units), Some(d)),
            None => (
                array_units(py, units, config.as_deref(), loaded.as_ref())?,
                loaded,
            ),
        };
        let mut times_us = Vec::with_capacity(n);
        for &t in times.iter() {
            if !t.is_finite() {
                return Err(PyValueError::new_err("times must be finite"));
            }
            times_us.push((t * 1e6).round() as i64);
        }
        let mut rows = Vec::with_capacity(n);
        for row in positions.rows() {
            let mut steps = Vec::with_capacity(joints);
            for (j, &v) in row.iter().enumerate() {
                if !v.is_finite() {
                    return Err(PyValueError::new_err("positions must be finite"));
                }
                // As armctl reads a CSV (a JointTrajectory: radians) with this config; a
                // joint past the config's is in steps.
                steps.push(Some(match &config {
                    Some(c) => c.joints.get(j).map_or(v, |jc| units.to_steps(v, jc)),
                    None => v,
                }));
            }
            // Joints of the config the arrays leave out hold, as in a CSV.
            if let Some(c) = &config {
                steps.resize(steps.len().max(c.joints.len()), None);
            }
            rows.push(steps);
        }
        let waypoints = Waypoints {
            file: "<numpy arrays>".into(),
            times_us,
            positions: rows,
            // Straight lines between the waypoints, as before armctl's Hermite resampling.
            velocities: Vec::new(),
        };
        let run = WaypointRun {
            waypoints,
            config,
            units,
            file: None,
            segment_ms,
            speed,
        };
        self.run_waypoints(py, run, wait, window)
    }

    /// Runs a trajectory file as `armctl run` does: JointTrajectory JSON (radians, needs
    /// `config`) or CSV (`time_s, steps...`).
    #[pyo3(signature = (path, config=None, wait=true, segment_ms=10.0, window=None, units=None, speed=None))]
    #[allow(clippy::too_many_arguments)]
    fn run_file(
        &self,
        py: Python<'_>,
        path: PathBuf,
        config: Option<PathBuf>,
        wait: bool,
        segment_ms: f64,
        window: Option<usize>,
        units: Option<String>,
        speed: Option<u8>,
    ) -> PyResult<Py<PyAny>> {
        let speed = check_speed(speed)?;
        let units = parse_units(units)?;
        let (waypoints, config) =
            trajectory::load_files_in(&path, config.as_deref(), units).map_err(trajectory_err)?;
        // What the file's positions are in, for messages: a JointTrajectory's radians, a
        // CSV's `units` (else the config's).
        let is_json = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"));
        let units = match units {
            _ if is_json => Units::Rad,
            Some(units) => units,
            None => config.as_ref().map(|c| c.units).unwrap_or_default(),
        };
        let run = WaypointRun {
            waypoints,
            config,
            units,
            file: Some(path),
            segment_ms,
            speed,
        };
        self.run_waypoints(py, run, wait, window)
    }

    /// Moves joints to `targets` (one value per joint from joint 0, `None` to hold, in
    /// `units`: "steps", "deg" or "rad", default the config's) on one speed profile within
    /// each joint's limits (the config's, capped by the controller's step rate), at `speed`
    /// (a fraction of the step rate). `relative`: increments. Returns the run's report (a
    /// RunHandle with `wait=False`), or None when the arm is already there.
    #[pyo3(signature = (targets, config=None, units=None, speed=0.5, relative=false, segment_ms=10.0, wait=true))]
    #[allow(clippy::too_many_arguments)]
    fn move_to(
        &self,
        py: Python<'_>,
        targets: Vec<Option<f64>>,
        config: Option<PathBuf>,
        units: Option<String>,
        speed: f64,
        relative: bool,
        segment_ms: f64,
        wait: bool,
    ) -> PyResult<Option<Py<PyAny>>> {
        let targets = targets
            .into_iter()
            .enumerate()
            .filter_map(|(j, v)| v.map(|v| (j, v)))
            .collect();
        self.move_joints(
            py, targets, config, units, speed, relative, segment_ms, wait,
        )
    }

    /// Moves one joint (an index, or a name in `config`) by `by` (in `units`), as
    /// `armctl jog JOINT BY` does. Returns the run's report, or None for a 0 increment.
    #[pyo3(signature = (joint, by, config=None, units=None, speed=0.5))]
    fn jog(
        &self,
        py: Python<'_>,
        joint: Bound<'_, PyAny>,
        by: f64,
        config: Option<PathBuf>,
        units: Option<String>,
        speed: f64,
    ) -> PyResult<Option<Py<PyAny>>> {
        let j = match joint.extract::<usize>() {
            Ok(j) => j,
            Err(_) => {
                let name: String = joint.extract().map_err(|_| {
                    PyValueError::new_err("joint: an index or a name from the config")
                })?;
                let loaded = config
                    .as_ref()
                    .map(|p| ArmConfig::load(p))
                    .transpose()
                    .map_err(trajectory_err)?;
                armctl::motion::joint_index(&name, MAX_JOINTS, loaded.as_ref())
                    .map_err(PyValueError::new_err)?
            }
        };
        self.move_joints(py, vec![(j, by)], config, units, speed, true, 10.0, true)
    }

    /// Homes the arm and returns where the joints are. On the home switches when the arm
    /// has them (HOME, issue 33: waits for the cycle's end, at most `timeout` seconds;
    /// raises naming the joint when it fails); otherwise RETURN and its end
    /// (`go_home(wait=True)`): all 0 unless it was stopped, and raises if a joint ended
    /// elsewhere. With a `config`, positions and the message in `units` (default its
    /// `units`) and the joints by name, as `armctl home --config` (issue 31). A
    /// KeyboardInterrupt while homing sends STOPPED before it propagates.
    #[pyo3(signature = (timeout=600.0, config=None, units=None))]
    fn home<'py>(
        &self,
        py: Python<'py>,
        timeout: f64,
        config: Option<PathBuf>,
        units: Option<String>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let shown = shown_in(config, units)?;
        let arm = self.controller()?;
        let started = py.detach(|| arm.start_homing());
        match started {
            Ok(_) => {
                let deadline =
                    std::time::Instant::now() + Duration::from_secs_f64(timeout.clamp(0.0, 1e9));
                if let Err(e) = wait_homing(py, &arm, deadline) {
                    stop_arm(py, &arm);
                    return Err(e);
                }
                let (status, location) = self.before_run(py)?;
                let joints = usize::from(status.joints).clamp(1, MAX_JOINTS);
                return Ok(positions_array(
                    py,
                    &location.position[..joints],
                    shown.as_ref(),
                ));
            }
            // No joint set to home, no switches, or a controller older than issue 33.
            Err(armctl::Error::Refused {
                status: protocol::StatusCode::HomingFailed | protocol::StatusCode::UnknownTag,
                ..
            }) => {}
            Err(e) => return Err(to_py_err(py, e)),
        }
        self.go_home(py, true, timeout)?;
        let (status, location) = self.before_run(py)?;
        let joints = usize::from(status.joints).clamp(1, MAX_JOINTS);
        if let Some(j) = (0..joints).find(|&j| location.position[j] != 0) {
            let at = location.position[j];
            let (joint, at) = match shown
                .as_ref()
                .and_then(|(c, u)| Some((c, u, c.joints.get(j)?)))
            {
                Some((config, units, jc)) => (
                    armctl::motion::joint_label(config, j),
                    format!("{} ({at} steps)", units.show(i64::from(at), jc)),
                ),
                None => (format!("joint {j}"), format!("{at} steps")),
            };
            return Err(ArmctlError::new_err(format!(
                "RETURN ended (state {}) with {joint} at {at}, not at its zero (0 steps)",
                status.state.name(),
            )));
        }
        Ok(positions_array(
            py,
            &location.position[..joints],
            shown.as_ref(),
        ))
    }

    /// HOMING_SET (issue 33): joint `joint` homes on its home switch on the `towards`
    /// side ("min" or "max"), seeking at `seek_rate_hz` within `max_travel_steps`, backing
    /// off `backoff_steps` and approaching at `approach_rate_hz`; its count at the switch
    /// becomes `offset`. Kept across power cycles; only while STOPPED. `enabled=False`:
    /// the joint does not home (HOME uses the others; none: `home()` uses RETURN).
    #[pyo3(signature = (joint, max_travel_steps, towards="min", seek_rate_hz=2000, approach_rate_hz=200, backoff_steps=400, offset=0, order=0, switch_is_limit=false, enabled=true))]
    #[allow(clippy::too_many_arguments)] // each a keyword of the Python call
    fn set_homing(
        &self,
        py: Python<'_>,
        joint: u8,
        max_travel_steps: u32,
        towards: &str,
        seek_rate_hz: u32,
        approach_rate_hz: u32,
        backoff_steps: u32,
        offset: i32,
        order: u8,
        switch_is_limit: bool,
        enabled: bool,
    ) -> PyResult<()> {
        let towards_max = match towards {
            "min" => false,
            "max" => true,
            other => {
                return Err(PyValueError::new_err(format!(
                    "towards must be \"min\" or \"max\", not {other:?}"
                )));
            }
        };
        let settings = protocol::HomingSettings {
            enabled,
            towards_max,
            switch_is_limit,
            order,
            seek_rate_hz,
            approach_rate_hz,
            backoff_steps,
            max_travel_steps,
            offset,
        };
        self.call(py, move |arm| arm.set_homing(joint, settings))
            .map(|_| ())
    }

    /// The SWITCHES report (issue 33) as a dict: `phase` ("never", "homing", "homed",
    /// "failed"), `joint`, `error` (None or its text), `homed` (mask), `home_active`,
    /// `min_active`, `max_active` (masks), `latched` (None or {"joint", "side"}); None
    /// from a controller older than issue 33.
    fn switches<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(s) = self.call(py, |arm| arm.switches())? else {
            return Ok(None);
        };
        let d = PyDict::new(py);
        let phase = match s.phase {
            protocol::HomingPhase::Never => "never",
            protocol::HomingPhase::Homing => "homing",
            protocol::HomingPhase::Homed => "homed",
            protocol::HomingPhase::Failed => "failed",
        };
        d.set_item("phase", phase)?;
        d.set_item("joint", s.joint)?;
        d.set_item("error", s.error.map(|e| e.text()))?;
        d.set_item("homed", s.homed)?;
        d.set_item("home_active", s.home_active)?;
        d.set_item("min_active", s.min_active)?;
        d.set_item("max_active", s.max_active)?;
        match s.latched {
            Some(l) => {
                let latched = PyDict::new(py);
                latched.set_item("joint", l & 0x7f)?;
                latched.set_item("side", if l & 0x80 != 0 { "max" } else { "min" })?;
                d.set_item("latched", latched)?;
            }
            None => d.set_item("latched", py.None())?,
        }
        Ok(Some(d))
    }

    /// STOPPED: stops every joint at once and drops the trajectory (obeyed from anyone).
    fn stop(&self, py: Python<'_>) -> PyResult<()> {
        self.call(py, |arm| arm.stop()).map(|_| ())
    }

    /// HOLD (issue 32): the run decelerates along its path to a standstill and waits
    /// (obeyed from any host). `resume()` goes on; `stop()` still stops at once.
    fn hold(&self, py: Python<'_>) -> PyResult<()> {
        self.call(py, |arm| arm.hold()).map(|_| ())
    }

    /// RESUME (issue 32): after a hold, back to the speed override and on.
    fn resume(&self, py: Python<'_>) -> PyResult<()> {
        self.call(py, |arm| arm.resume()).map(|_| ())
    }

    /// OVERRIDE (issue 32): run at `percent` of the planned speed (1..200), ramped in for
    /// the run under way and kept for the runs to come. Above 100 % only where every
    /// joint's rate and acceleration allow (else a RefusedError OVERRIDE_REFUSED).
    #[pyo3(name = "override")]
    fn set_override(&self, py: Python<'_>, percent: u8) -> PyResult<()> {
        let percent = check_speed(Some(percent))?.unwrap_or(100);
        self.call(py, move |arm| arm.set_override(percent))
            .map(|_| ())
    }

    /// The wired e-stop input's stop category (issue 32): with `category` (0 or 1), sets
    /// it (ESTOP_CATEGORY: only while STOPPED, kept in the controller's settings); then
    /// returns it as the controller reports it (MOTION; 0 from a controller older than
    /// issue 32, which stops at once). 0: every joint stops at once; 1: the run
    /// decelerates along its path, then the drivers are disabled.
    #[pyo3(signature = (category=None))]
    fn estop_category(&self, py: Python<'_>, category: Option<u8>) -> PyResult<u8> {
        if let Some(byte) = category {
            let Some(category) = protocol::EStopCategory::from_u8(byte) else {
                return Err(pyo3::exceptions::PyValueError::new_err(format!(
                    "e-stop category {byte}: give 0 or 1"
                )));
            };
            self.call(py, move |arm| arm.set_estop_category(category))?;
        }
        let (_, motion) = self.call(py, |arm| arm.motion())?;
        Ok(motion.and_then(|m| m.estop_category).map_or(0, |c| c as u8))
    }

    /// RETURN: drives every joint to zero; with `wait`, until the move ended (at most
    /// `timeout` seconds). A KeyboardInterrupt or an error while waiting sends STOPPED
    /// (resent until ACKed) before it propagates.
    #[pyo3(signature = (wait=true, timeout=600.0))]
    fn go_home(&self, py: Python<'_>, wait: bool, timeout: f64) -> PyResult<()> {
        let arm = self.controller()?;
        self.call(py, |arm| arm.go_home())?;
        self.returning.store(true, Ordering::SeqCst);
        signals::register(py, &arm, MotionKind::Return(self.returning.clone()));
        if !wait {
            return Ok(());
        }
        let deadline = std::time::Instant::now() + Duration::from_secs_f64(timeout.clamp(0.0, 1e9));
        match wait_return(py, &arm, deadline) {
            Ok(ended) => {
                if ended {
                    self.returning.store(false, Ordering::SeqCst);
                }
                Ok(())
            }
            Err(e) => {
                stop_arm(py, &arm);
                self.returning.store(false, Ordering::SeqCst);
                Err(e)
            }
        }
    }

    /// LOCATION_SETTING: declares where the joints are, in steps (calibration).
    fn set_location(&self, py: Python<'_>, positions: Vec<i32>) -> PyResult<()> {
        self.call(py, move |arm| arm.set_location(&positions))
            .map(|_| ())
    }

    /// JOINTS_COUNT: the number of joints (1..8), kept across power cycles.
    fn set_joints(&self, py: Python<'_>, joints: u8) -> PyResult<()> {
        self.call(py, move |arm| arm.set_joints(joints)).map(|_| ())
    }

    /// SET_KEY (docs/PROTOCOL.md section 13): stores the key of `key_file` (64 hex digits)
    /// in the controller, or clears it (`None`). The first key is set plain; a key set
    /// already is changed or cleared only by a connection made with it (`key_file=`).
    #[pyo3(signature = (key_file=None))]
    fn set_key(&self, py: Python<'_>, key_file: Option<PathBuf>) -> PyResult<()> {
        let key = key_file
            .map(|path| armctl::auth::read_key_file(&path))
            .transpose()
            .map_err(PyValueError::new_err)?;
        self.call(py, move |arm| arm.set_key(key)).map(|_| ())
    }

    /// LIMITS_GET: every joint's limits kept on the controller, a list of 8 dicts
    /// (`min`, `max` in steps, `max_rate_hz`, 0: the controller's own limit only).
    fn limits<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        let report = self.call(py, |arm| arm.limits())?;
        report
            .joints
            .iter()
            .map(|l| {
                let d = PyDict::new(py);
                d.set_item("min", l.min)?;
                d.set_item("max", l.max)?;
                d.set_item("max_rate_hz", l.max_rate_hz)?;
                Ok(d)
            })
            .collect()
    }

    /// LIMITS_SET: joint `joint`'s position range (steps) and step rate, kept by the
    /// controller across power cycles and enforced on every point, RETURN and
    /// set_location; arguments not given keep their value. Only while STOPPED.
    #[pyo3(signature = (joint, *, min=None, max=None, max_rate_hz=None))]
    fn set_limits(
        &self,
        py: Python<'_>,
        joint: u8,
        min: Option<i32>,
        max: Option<i32>,
        max_rate_hz: Option<u32>,
    ) -> PyResult<()> {
        if usize::from(joint) >= MAX_JOINTS {
            return Err(PyValueError::new_err(format!(
                "joint {joint} does not exist: joints are 0..{}",
                MAX_JOINTS - 1
            )));
        }
        let current = self.call(py, |arm| arm.limits())?;
        let old = current.joints[usize::from(joint)];
        let new = protocol::JointLimits {
            min: min.unwrap_or(old.min),
            max: max.unwrap_or(old.max),
            max_rate_hz: max_rate_hz.unwrap_or(old.max_rate_hz),
        };
        if !new.is_valid() {
            return Err(PyValueError::new_err(format!(
                "joint {joint}: min {} is above max {}",
                new.min, new.max
            )));
        }
        self.call(py, move |arm| arm.set_limits(joint, new))
            .map(|_| ())
    }

    /// JOINT_DESC_GET: the description the controller keeps of `joint` (issue 31), a
    /// dict: `name`, `unit` (steps, deg, rad, mm), `zero_offset` (steps), `scale` (steps
    /// per radian, per mm or per step), `described` (False: none kept). Any host may ask.
    fn joint_description<'py>(&self, py: Python<'py>, joint: u8) -> PyResult<Bound<'py, PyDict>> {
        let desc = self.call(py, move |arm| arm.joint_desc(joint))?;
        described::desc_dict(py, &desc)
    }

    /// JOINT_DESC_SET: changes what the controller keeps of `joint` (issue 31), the
    /// arguments given (the rest as kept), so that every host (armctl, Python, the ROS
    /// bridge) names and shows it alike. `scale`: steps per radian (deg, rad), per mm or 1
    /// (steps); 0 clears the description. Only while STOPPED.
    #[pyo3(signature = (joint, *, name=None, unit=None, zero_offset=None, scale=None))]
    fn set_joint_description(
        &self,
        py: Python<'_>,
        joint: u8,
        name: Option<String>,
        unit: Option<String>,
        zero_offset: Option<i32>,
        scale: Option<f64>,
    ) -> PyResult<()> {
        if usize::from(joint) >= MAX_JOINTS {
            return Err(PyValueError::new_err(format!(
                "joint {joint} does not exist: joints are 0..{}",
                MAX_JOINTS - 1
            )));
        }
        let old = self.call(py, move |arm| arm.joint_desc(joint))?;
        let desc = described::changed(
            joint,
            &old,
            name.as_deref(),
            unit.as_deref(),
            zero_offset,
            scale,
        )?;
        self.call(py, move |arm| arm.set_joint_desc(joint, desc))
            .map(|_| ())
    }

    /// What `armctl config push PATH` does (armctl::push, one code for both): the joint
    /// config's (or a `config get --json` output's) limits, accelerations and
    /// descriptions kept on the controller, only while STOPPED. Returns the lines the CLI
    /// prints for them; a controller older than issue 31 gives UserWarnings.
    fn push_config(&self, py: Python<'_>, path: PathBuf) -> PyResult<Vec<String>> {
        let pushed = armctl::push::PushedArm::load(&path).map_err(PyValueError::new_err)?;
        let arm = self.controller()?;
        let (said, result) = py.detach(move || {
            let mut said = Vec::new();
            let result = arm.push_arm(&pushed, |s| said.push(s));
            (said, result)
        });
        described::push_result(py, said, result)
    }

    /// RELEASE: gives the controller up (only while STOPPED), so that another host may
    /// take it at once; this connection's next command takes it back unless another
    /// host's came first.
    fn release(&self, py: Python<'_>) -> PyResult<()> {
        self.call(py, move |arm| arm.release()).map(|_| ())
    }

    /// SET_ENABLE: enables (holding torque) the drivers of `joints` (0-7) and, with
    /// `gripper=True`, the gripper's; with no `joints`, every driver (gripper included
    /// unless `gripper=False`). The others are left as they are. Only while STOPPED.
    #[pyo3(signature = (joints=None, *, gripper=None))]
    fn enable(
        &self,
        py: Python<'_>,
        joints: Option<Vec<i64>>,
        gripper: Option<bool>,
    ) -> PyResult<()> {
        let mask = enable_mask(joints, gripper)?;
        self.call(py, move |arm| arm.set_enable(mask, true))
            .map(|_| ())
    }

    /// SET_ENABLE: disables (limp: the joints can be moved by hand) the drivers of
    /// `joints` and, with `gripper=True`, the gripper's; with no `joints`, every driver.
    #[pyo3(signature = (joints=None, *, gripper=None))]
    fn disable(
        &self,
        py: Python<'_>,
        joints: Option<Vec<i64>>,
        gripper: Option<bool>,
    ) -> PyResult<()> {
        let mask = enable_mask(joints, gripper)?;
        self.call(py, move |arm| arm.set_enable(mask, false))
            .map(|_| ())
    }

    /// PIN0/PIN1 high (`True`) or low.
    fn pin(&self, py: Python<'_>, pin: u8, high: bool) -> PyResult<()> {
        // A wrong argument is a ValueError, not a "network error" (issue 23).
        if pin > 1 {
            return Err(PyValueError::new_err(format!(
                "pin must be 0 or 1 (the controller has GPIO pins 0 and 1), not {pin}"
            )));
        }
        self.call(py, move |arm| arm.pin(pin, high)).map(|_| ())
    }

    /// Gripper servo PWM at `freq` Hz with `duty` (0..1), until `pwm_stop()`.
    #[pyo3(signature = (duty, freq=50.0))]
    fn pwm_servo(&self, py: Python<'_>, duty: f64, freq: f64) -> PyResult<()> {
        self.pwm_start_at(py, freq, duty, 0)
    }

    /// Stepper-driven gripper: `pulses` pulses (negative: the other way) at `freq` Hz.
    #[pyo3(signature = (pulses, freq=1000.0))]
    fn pwm_stepper(&self, py: Python<'_>, pulses: i32, freq: f64) -> PyResult<()> {
        if pulses == 0 {
            return Err(PyValueError::new_err(
                "0 pulses would be servo mode: use pwm_servo",
            ));
        }
        self.pwm_start_at(py, freq, 0.5, pulses)
    }

    /// NET_SET: stores the controller's address, `"A.B.C.D/P"` with an optional gateway,
    /// or DHCP; the controller uses it from its next reset (owner only, not while running).
    #[pyo3(signature = (ip=None, gateway=None, dhcp=false))]
    fn net_set(
        &self,
        py: Python<'_>,
        ip: Option<&str>,
        gateway: Option<&str>,
        dhcp: bool,
    ) -> PyResult<()> {
        let net = match (ip, dhcp) {
            (None, true) if gateway.is_none() => NetSettings::DHCP,
            (Some(ip), false) => {
                let (ip, prefix) =
                    armctl::discover::parse_cidr(ip).map_err(PyValueError::new_err)?;
                let gateway = gateway
                    .map(|g| g.parse::<std::net::Ipv4Addr>())
                    .transpose()
                    .map_err(|_| PyValueError::new_err("gateway must be an IPv4 address"))?;
                NetSettings::fixed(ip, prefix, gateway.map(|g| g.octets()))
            }
            _ => {
                return Err(PyValueError::new_err(
                    "give ip='A.B.C.D/P' (and optionally gateway), or dhcp=True alone",
                ));
            }
        };
        if !net.is_valid() {
            return Err(PyValueError::new_err(format!(
                "{}: not usable (a unicast address with a prefix of 1..32 and a gateway inside its subnet)",
                armctl::discover::net_string(&net)
            )));
        }
        self.call(py, move |arm| arm.net_set(net)).map(|_| ())
    }

    /// USART_START: opens the controller's pass-through serial port at `baud` (8N1), as
    /// `armctl serial --baud` does; what it receives from then on is kept for
    /// `serial_read`. A baud rate the controller refuses raises RefusedError
    /// (INVALID_CONFIG, 300 to 4,000,000).
    #[pyo3(signature = (baud=115_200))]
    fn serial_open(&self, py: Python<'_>, baud: u32) -> PyResult<()> {
        let arm = self.controller()?;
        *lock(&self.serial) = Some(arm.serial_rx());
        self.call(py, move |arm| {
            arm.serial_open(protocol::UartInit {
                baud_rate: baud,
                ..protocol::UartInit::default()
            })
        })
        .map(|_| ())
    }

    /// USART_SEND: writes `data` to the serial port (in frames of 255 bytes, in order).
    fn serial_write(&self, py: Python<'_>, data: Vec<u8>) -> PyResult<()> {
        self.call(py, move |arm| arm.serial_send(&data))
    }

    /// What the serial port received: waits up to `timeout` seconds for the first bytes,
    /// then returns them with whatever else has arrived (b"" if nothing came). Raises
    /// ArmctlError if the port was not opened with `serial_open`.
    #[pyo3(signature = (timeout=1.0))]
    fn serial_read(&self, py: Python<'_>, timeout: f64) -> PyResult<Vec<u8>> {
        let deadline = std::time::Instant::now() + Duration::from_secs_f64(timeout.clamp(0.0, 1e9));
        // Taken out while waiting (the wait releases the GIL; a lock held meanwhile could
        // block another Python thread that holds it), put back after.
        let Some(mut rx) = lock(&self.serial).take() else {
            return Err(ArmctlError::new_err("serial_read before serial_open"));
        };
        let mut data = Vec::new();
        let result = loop {
            let slice =
                SIGNAL_POLL.min(deadline.saturating_duration_since(std::time::Instant::now()));
            let (back, first) = py.detach(move || {
                let first = rx.recv_timeout(slice);
                (rx, first)
            });
            rx = back;
            if let Ok(chunk) = first {
                data.extend_from_slice(&chunk);
                while let Ok(more) = rx.try_recv() {
                    data.extend_from_slice(&more);
                }
                break Ok(data);
            }
            if let Err(e) = py.check_signals() {
                break Err(e);
            }
            if std::time::Instant::now() >= deadline {
                break Ok(data);
            }
        };
        let mut slot = lock(&self.serial);
        if slot.is_none() {
            *slot = Some(rx);
        }
        result
    }

    /// USART_STOP: closes the serial port.
    fn serial_close(&self, py: Python<'_>) -> PyResult<()> {
        *lock(&self.serial) = None;
        self.call(py, |arm| arm.serial_close()).map(|_| ())
    }

    /// PWM_STOP: gripper output off at once.
    fn pwm_stop(&self, py: Python<'_>) -> PyResult<()> {
        self.call(py, |arm| arm.pwm_stop()).map(|_| ())
    }

    /// LOCATION reports as they arrive (dicts with `positions` and `state`); the iterator
    /// ends after `count` reports, or when none came for `timeout` seconds.
    #[pyo3(signature = (count=None, timeout=1.0))]
    fn locations(&self, py: Python<'_>, count: Option<usize>, timeout: f64) -> PyResult<Locations> {
        let arm = self.controller()?;
        let reports = arm.locations();
        let joints = match arm.last_status() {
            Some(s) => usize::from(s.joints),
            None => usize::from(self.call(py, |arm| arm.status())?.joints),
        };
        Ok(Locations {
            reports: Mutex::new(reports),
            timeout: Duration::from_secs_f64(timeout.max(0.0)),
            remaining: Mutex::new(count),
            joints: joints.clamp(1, MAX_JOINTS),
        })
    }

    fn __repr__(&self) -> String {
        match lock(&self.inner).as_ref() {
            Some(arm) => format!("<armctl.Arm {}>", arm.addr()),
            None => "<armctl.Arm closed>".into(),
        }
    }
}

/// Finds controllers: DISCOVER to `to` (a broadcast address, or one controller); returns
/// one dict per controller that answered (nothing changes on them).
#[pyfunction]
#[pyo3(signature = (to="255.255.255.255:8510", *, wait=0.3, rounds=2, bind=None))]
fn discover<'py>(
    py: Python<'py>,
    to: &str,
    wait: f64,
    rounds: u32,
    bind: Option<&str>,
) -> PyResult<Vec<Bound<'py, PyDict>>> {
    use armctl::discover::{DiscoverOptions, mac_string};
    let target = to
        .parse()
        .map_err(|_| PyValueError::new_err("to must be an IPv4 address:port"))?;
    let bind = bind
        .map(|b| b.parse())
        .transpose()
        .map_err(|_| PyValueError::new_err("bind must be an IPv4 address:port"))?;
    let options = DiscoverOptions {
        target,
        bind,
        wait: Duration::from_secs_f64(wait.clamp(0.001, 10.0)),
        rounds: rounds.clamp(1, 10),
    };
    let found = py
        .detach(move || armctl::discover::discover(&options))
        .map_err(|e| ArmctlError::new_err(format!("DISCOVER to {to}: {e}")))?;
    let ip = |q: [u8; 4]| std::net::Ipv4Addr::from(q).to_string();
    found
        .iter()
        .map(|f| {
            let d = PyDict::new(py);
            d.set_item("address", f.from.to_string())?;
            if let Some(r) = &f.reply {
                set_items!(d, {
                    "mac" => mac_string(&r.mac),
                    "version" => (r.version[0], r.version[1], r.version[2]),
                    "joints" => r.joints,
                    "state" => r.state.name(),
                    "owner" => r.owner.name(),
                    "owner_ip" => ip(r.owner_ip),
                    "dhcp" => r.net.dhcp,
                    "stored_ip" => ip(r.net.ip),
                    "prefix_len" => r.net.prefix_len,
                    "gateway" => ip(r.net.gateway),
                    "pending_reset" => r.pending_reset,
                });
            }
            Ok(d)
        })
        .collect()
}

/// Connects to the controller at `address` (`host:port`) and checks that it answers a
/// STATUS. `pcap`: write every datagram to this capture file. `key_file`: the controller's
/// authentication key (64 hex digits; default `$ARMCTL_KEY_FILE`, as the `armctl` tool).
#[pyfunction]
#[pyo3(signature = (address="127.0.0.1:8510", *, ack_timeout=0.1, attempts=10, bind=None, pcap=None, key_file=None))]
fn connect(
    py: Python<'_>,
    address: &str,
    ack_timeout: f64,
    attempts: u32,
    bind: Option<&str>,
    pcap: Option<PathBuf>,
    key_file: Option<PathBuf>,
) -> PyResult<Arm> {
    let key_file = key_file.or_else(|| std::env::var_os("ARMCTL_KEY_FILE").map(PathBuf::from));
    let key = key_file
        .map(|path| armctl::auth::read_key_file(&path))
        .transpose()
        .map_err(PyValueError::new_err)?;
    let bind = bind
        .map(|b| b.parse())
        .transpose()
        .map_err(|_| PyValueError::new_err("bind must be an address:port"))?;
    if !(ack_timeout.is_finite() && ack_timeout > 0.0) {
        return Err(PyValueError::new_err("ack_timeout must be above 0 seconds"));
    }
    let options = Options {
        ack_timeout: Duration::from_secs_f64(ack_timeout),
        attempts: attempts.max(1),
        bind,
        key,
        ..Options::default()
    };
    // HOST alone gets the default port, as `armctl --controller` (issue 23: "127.0.0.1"
    // without a port failed).
    let address = armctl::controller_address(address);
    let arm = py
        .detach(move || -> armctl::Result<Client> {
            let arm = Client::open(address.as_str(), options)?;
            if let Some(path) = pcap {
                arm.capture(Arc::new(armctl::pcap::PcapLog::create(&path)?));
            }
            arm.status()?;
            Ok(arm)
        })
        .map_err(|e| to_py_err(py, e))?;
    // SIGTERM and SIGHUP stop the arm from here on (issue 30; connect is usually called
    // from the main thread, the only one that may set signal handlers).
    signals::install(py);
    Ok(Arm {
        inner: Mutex::new(Some(Arc::new(arm))),
        runs: Mutex::new(Vec::new()),
        returning: Arc::new(AtomicBool::new(false)),
        serial: Mutex::new(None),
    })
}

/// The arm controller from Python: `with armctl.connect("127.0.0.1:8510") as arm: ...`
#[pymodule(name = "armctl")]
fn armctl_py(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    // ARMCTL_TRACE: the client's upload traces (ACKs, timeouts, resends) on stderr, as
    // the `armctl` tool shows them. Nothing is installed otherwise (the host program's
    // own logging stays its own).
    if armctl::trace_requested() {
        let _ = env_logger::Builder::new()
            .filter_module("armctl", log::LevelFilter::Trace)
            .try_init();
    }
    m.add_function(wrap_pyfunction!(connect, m)?)?;
    m.add_function(wrap_pyfunction!(discover, m)?)?;
    m.add_class::<Arm>()?;
    m.add_class::<RunHandle>()?;
    m.add_class::<Locations>()?;
    m.add("ArmctlError", py.get_type::<ArmctlError>())?;
    m.add("RefusedError", py.get_type::<RefusedError>())?;
    m.add("NoReplyError", py.get_type::<NoReplyError>())?;
    m.add("RunEndedError", py.get_type::<RunEndedError>())?;
    m.add("StalledError", py.get_type::<StalledError>())?;
    m.add("TrajectoryError", py.get_type::<TrajectoryError>())?;
    m.add("PORT", protocol::PORT)?;
    Ok(())
}

/// The ENABLE mask (bits 0-7 joints, bit 8 gripper) of `enable`/`disable`'s arguments.
fn enable_mask(joints: Option<Vec<i64>>, gripper: Option<bool>) -> PyResult<u16> {
    const GRIPPER: u16 = 1 << 8;
    let Some(joints) = joints else {
        return Ok(if gripper == Some(false) {
            0xFF
        } else {
            protocol::limits::ENABLE_MASK_BITS
        });
    };
    let mut mask = if gripper == Some(true) { GRIPPER } else { 0 };
    for j in joints {
        match u8::try_from(j) {
            Ok(j) if usize::from(j) < protocol::MAX_JOINTS => mask |= 1 << j,
            _ => {
                return Err(PyValueError::new_err(format!(
                    "joint {j} does not exist: joints are 0..{}",
                    protocol::MAX_JOINTS - 1
                )));
            }
        }
    }
    Ok(mask)
}

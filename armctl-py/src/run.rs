//! Runs on their own thread (`RunHandle`) and the LOCATION report iterator (`Locations`):
//! every wait releases the GIL and wakes every `SIGNAL_POLL` for Python's signal handlers.
//! [`stop_arm`] is the STOPPED every motion call and the `with` block send when an
//! exception (KeyboardInterrupt included) leaves them.

use std::ffi::CString;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::time::{Duration, Instant};

use armctl::{Cancel, Client, Error, Progress, RunOptions, RunReport, StopOutcome, StopRetry};
use protocol::Location;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::dicts::{location_dict, progress_dict, report_dict};
use crate::errors::{ArmctlError, to_py_err};
use crate::{SIGNAL_POLL, lock};

/// STOPPED, resent until the controller ACKs it (every 100 ms, 10 copies at most), with
/// the GIL released; a second Ctrl-C meanwhile ends the wait (the first copy has gone) and
/// is returned beside the outcome. Not ACKed: a `RuntimeWarning` says so (the exception
/// that led here still propagates).
pub(crate) fn stop_arm(py: Python<'_>, arm: &Arc<Client>) -> (StopOutcome, Option<PyErr>) {
    let client = arm.clone();
    let (outcome, again) = py.detach(move || {
        let mut again = None;
        let outcome = client.stop_until_acked(&StopRetry::default(), || {
            if let Err(e) = Python::attach(|py| py.check_signals()) {
                again = Some(e);
            }
            again.is_some()
        });
        (outcome, again)
    });
    if !outcome.is_acked()
        && let Ok(message) = CString::new(format!("armctl: {outcome}"))
    {
        let category = py.get_type::<pyo3::exceptions::PyRuntimeWarning>();
        let _ = PyErr::warn(py, category.as_any(), &message, 1);
    }
    (outcome, again)
}

/// A run on its own thread: its progress, and its outcome once it ended.
#[derive(Default)]
pub(crate) struct RunState {
    progress: Mutex<Progress>,
    outcome: Mutex<Option<Result<RunReport, Error>>>,
    ended: Condvar,
    pub(crate) done: AtomicBool,
    /// The run thread's own STOPPED after the run failed was ACKed (nobody else need send
    /// one).
    stopped: AtomicBool,
    /// Ends the run thread's upload and waits (it then sends nothing: the canceller sends
    /// STOPPED, [`stop_arm`]).
    pub(crate) cancel: Cancel,
}

/// A trajectory run started by `Arm.run(..., wait=False)` (or `run_file`).
#[pyclass(module = "armctl")]
pub(crate) struct RunHandle {
    arm: Arc<Client>,
    pub(crate) state: Arc<RunState>,
    joints: usize,
    /// What `wait()` returns (or raises), once known.
    result: Mutex<Option<PyResult<Py<PyAny>>>>,
}

impl RunHandle {
    pub(crate) fn start(
        arm: Arc<Client>,
        points: Vec<protocol::Point>,
        options: RunOptions,
        joints: usize,
    ) -> PyResult<RunHandle> {
        let state = Arc::new(RunState::default());
        let options = RunOptions {
            cancel: Some(state.cancel.clone()),
            ..options
        };
        let (thread_arm, thread_state) = (arm.clone(), state.clone());
        std::thread::Builder::new()
            .name("armctl-run".into())
            .spawn(move || {
                let result = thread_arm.run_trajectory(&points, &options, |p| {
                    *lock(&thread_state.progress) = *p;
                });
                // Issue 31: a refused upload (or a stall, a lost link) must not leave the
                // controller PENDING or moving when nobody waits for this run (wait=False,
                // the handle dropped): STOPPED from here. Not after our own cancel: its
                // caller sends it. Bounded (10 copies, 1 s), so it is always seen through.
                if let Err(e) = &result
                    && !matches!(e, Error::Interrupted)
                {
                    let outcome = thread_arm.stop_until_acked(&StopRetry::default(), || false);
                    thread_state
                        .stopped
                        .store(outcome.is_acked(), Ordering::SeqCst);
                }
                *lock(&thread_state.outcome) = Some(result);
                thread_state.done.store(true, Ordering::SeqCst);
                thread_state.ended.notify_all();
            })
            .map_err(|e| ArmctlError::new_err(format!("cannot start the run thread: {e}")))?;
        Ok(RunHandle {
            arm,
            state,
            joints,
            result: Mutex::new(None),
        })
    }

    /// Waits for the end of the run with the GIL released, waking to check for signals.
    /// A KeyboardInterrupt (or any signal handler's exception), and a run that ended in an
    /// error (the arm may still move after a stall or a lost link), stop the arm first:
    /// STOPPED resent until ACKed ([`stop_arm`]).
    pub(crate) fn wait_inner(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<Py<PyAny>> {
        let deadline = timeout.map(|s| Instant::now() + Duration::from_secs_f64(s.max(0.0)));
        loop {
            if let Some(result) = lock(&self.result).as_ref() {
                return match result {
                    Ok(v) => Ok(v.clone_ref(py)),
                    Err(e) => Err(e.clone_ref(py)),
                };
            }
            let state = self.state.clone();
            let outcome = py.detach(move || {
                let guard = lock(&state.outcome);
                let (mut guard, _) = state
                    .ended
                    .wait_timeout_while(guard, SIGNAL_POLL, |o| o.is_none())
                    .unwrap_or_else(PoisonError::into_inner);
                guard.take()
            });
            if let Some(outcome) = outcome {
                let result = match outcome {
                    Ok(report) => {
                        report_dict(py, &report, self.joints).map(|d| d.into_any().unbind())
                    }
                    Err(e) => {
                        if !self.state.stopped.load(Ordering::SeqCst) {
                            stop_arm(py, &self.arm);
                        }
                        Err(to_py_err(py, e))
                    }
                };
                let copy = match &result {
                    Ok(v) => Ok(v.clone_ref(py)),
                    Err(e) => Err(e.clone_ref(py)),
                };
                *lock(&self.result) = Some(copy);
                return result;
            }
            if let Err(interrupt) = py.check_signals() {
                // The run thread sends nothing more; the arm stops; then the exception
                // propagates.
                self.state.cancel.cancel();
                stop_arm(py, &self.arm);
                return Err(interrupt);
            }
            if deadline.is_some_and(|d| Instant::now() >= d) {
                return Err(pyo3::exceptions::PyTimeoutError::new_err(
                    "the run has not ended yet",
                ));
            }
        }
    }
}

#[pymethods]
impl RunHandle {
    /// Where the run is: total, sent, acked, executed points, the state, done.
    #[getter]
    fn progress<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let progress = *lock(&self.state.progress);
        progress_dict(py, &progress, self.state.done.load(Ordering::SeqCst))
    }

    /// Whether the run has ended (successfully or not).
    #[getter]
    fn done(&self) -> bool {
        self.state.done.load(Ordering::SeqCst)
    }

    /// Waits for the end of the run and returns its report (dict); raises what ended it.
    /// `timeout` in seconds: TimeoutError if still running then (the run goes on).
    #[pyo3(signature = (timeout=None))]
    fn wait(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<Py<PyAny>> {
        self.wait_inner(py, timeout)
    }

    /// Sends STOPPED (resent until ACKed) and waits for the run to end (its `wait()` then
    /// raises RunEndedError with reason 'stopped').
    fn cancel(&self, py: Python<'_>) -> PyResult<()> {
        let (outcome, again) = stop_arm(py, &self.arm);
        if let Some(interrupt) = again {
            return Err(interrupt);
        }
        if !outcome.is_acked() {
            return Err(crate::errors::NoReplyError::new_err(outcome.to_string()));
        }
        let state = self.state.clone();
        py.detach(move || {
            let guard = lock(&state.outcome);
            let _ = state
                .ended
                .wait_timeout_while(guard, Duration::from_secs(10), |_| {
                    !state.done.load(Ordering::SeqCst)
                });
        });
        Ok(())
    }

    fn __repr__(&self) -> String {
        let p = *lock(&self.state.progress);
        format!(
            "<armctl.RunHandle {}/{} executed, {}{}>",
            p.executed,
            p.total,
            p.state.name(),
            if self.state.done.load(Ordering::SeqCst) {
                ", done"
            } else {
                ""
            }
        )
    }
}

/// Iterator over LOCATION reports (`Arm.locations()`).
#[pyclass(module = "armctl")]
pub(crate) struct Locations {
    pub(crate) reports: Mutex<Receiver<Location>>,
    pub(crate) timeout: Duration,
    pub(crate) remaining: Mutex<Option<usize>>,
    pub(crate) joints: usize,
}

#[pymethods]
impl Locations {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        {
            let mut remaining = lock(&self.remaining);
            match remaining.as_mut() {
                Some(0) => return Ok(None),
                Some(n) => *n -= 1,
                None => {}
            }
        }
        let deadline = Instant::now() + self.timeout;
        loop {
            let slice = SIGNAL_POLL.min(deadline.saturating_duration_since(Instant::now()));
            let received = py.detach(|| lock(&self.reports).recv_timeout(slice));
            match received {
                Ok(location) => return location_dict(py, &location, self.joints).map(Some),
                Err(RecvTimeoutError::Disconnected) => return Ok(None),
                Err(RecvTimeoutError::Timeout) => {
                    py.check_signals()?;
                    if Instant::now() >= deadline {
                        return Ok(None);
                    }
                }
            }
        }
    }
}

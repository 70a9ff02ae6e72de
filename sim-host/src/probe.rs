//! Measurements taken inside the simulator for the benchmark: e-stop latency, from the
//! moment a STOPPED datagram leaves the socket to the moment the step engine is idle.
//! The trace shows the same interval as the `estop` wire: high from the datagram's
//! arrival until the engine is idle.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use protocol::Tag;

use crate::clock::SimClock;
use crate::vcd::{Signal, Tracer, Value};

/// Shared measurement points.
#[derive(Debug)]
pub struct Probe {
    clock: SimClock,
    tracer: Tracer,
    /// The step engine has pulses scheduled (the step thread keeps this up to date).
    pub engine_running: AtomicBool,
    /// Datagrams read from the socket.
    pub datagrams: AtomicU64,
    stop_received: Mutex<Option<Instant>>,
    estop_latencies: Mutex<Vec<Duration>>,
    /// When the step engine last went idle (for latencies from a host's send).
    last_engine_stop: Mutex<Option<Instant>>,
}

impl Probe {
    /// A probe on `clock` that marks e-stops in `tracer`.
    pub fn new(clock: SimClock, tracer: Tracer) -> Probe {
        Probe {
            clock,
            tracer,
            engine_running: AtomicBool::new(false),
            datagrams: AtomicU64::new(0),
            stop_received: Mutex::new(None),
            estop_latencies: Mutex::new(Vec::new()),
            last_engine_stop: Mutex::new(None),
        }
    }

    /// A datagram was read from the socket at `at`.
    pub fn datagram_received(&self, bytes: &[u8], at: Instant) {
        self.datagrams.fetch_add(1, Ordering::Relaxed);
        let is_stop = bytes.len() >= protocol::FRAME_OVERHEAD && bytes[1] == Tag::Stopped as u8;
        if !is_stop {
            return;
        }
        let t_ns = self.clock.sim_ns_at(at);
        self.tracer.record_at(t_ns, Signal::EStop, Value::Bit(true));
        if self.engine_running.load(Ordering::Acquire) {
            if let Ok(mut pending) = self.stop_received.lock() {
                pending.get_or_insert(at);
            }
        } else {
            // Nothing to stop: the mark is a glitch.
            self.tracer
                .record_at(t_ns, Signal::EStop, Value::Bit(false));
        }
    }

    /// The step thread saw the engine go idle at `at`, polling at simulated ns `t_ns`.
    pub fn engine_stopped(&self, at: Instant, t_ns: u64) {
        self.tracer
            .record_at(t_ns, Signal::EStop, Value::Bit(false));
        if let Ok(mut last) = self.last_engine_stop.lock() {
            *last = Some(at);
        }
        let pending = self.stop_received.lock().ok().and_then(|mut p| p.take());
        if let Some(received) = pending
            && let Ok(mut latencies) = self.estop_latencies.lock()
        {
            latencies.push(at.saturating_duration_since(received));
        }
    }

    /// When the step engine last went idle, if it did.
    pub fn last_engine_stop(&self) -> Option<Instant> {
        self.last_engine_stop.lock().ok().and_then(|l| *l)
    }

    /// E-stop latencies measured so far, and clears them.
    pub fn take_estop_latencies(&self) -> Vec<Duration> {
        self.estop_latencies
            .lock()
            .map(|mut l| std::mem::take(&mut *l))
            .unwrap_or_default()
    }
}

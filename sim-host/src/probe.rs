//! Measurements taken inside the simulator for the benchmark: e-stop latency, from the
//! moment a STOPPED datagram leaves the socket to the moment the step engine is idle.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use protocol::Tag;

/// Shared measurement points.
#[derive(Debug, Default)]
pub struct Probe {
    /// The step engine has pulses scheduled (the step thread keeps this up to date).
    pub engine_running: AtomicBool,
    /// Datagrams read from the socket.
    pub datagrams: AtomicU64,
    stop_received: Mutex<Option<Instant>>,
    estop_latencies: Mutex<Vec<Duration>>,
}

impl Probe {
    /// A datagram was read from the socket at `at`.
    pub fn datagram_received(&self, bytes: &[u8], at: Instant) {
        self.datagrams.fetch_add(1, Ordering::Relaxed);
        let is_stop = bytes.len() >= protocol::FRAME_OVERHEAD && bytes[1] == Tag::Stopped as u8;
        if is_stop
            && self.engine_running.load(Ordering::Acquire)
            && let Ok(mut pending) = self.stop_received.lock()
        {
            pending.get_or_insert(at);
        }
    }

    /// The step thread saw the engine go idle at `at`.
    pub fn engine_stopped(&self, at: Instant) {
        let pending = self.stop_received.lock().ok().and_then(|mut p| p.take());
        if let Some(received) = pending
            && let Ok(mut latencies) = self.estop_latencies.lock()
        {
            latencies.push(at.saturating_duration_since(received));
        }
    }

    /// E-stop latencies measured so far, and clears them.
    pub fn take_estop_latencies(&self) -> Vec<Duration> {
        self.estop_latencies
            .lock()
            .map(|mut l| std::mem::take(&mut *l))
            .unwrap_or_default()
    }
}

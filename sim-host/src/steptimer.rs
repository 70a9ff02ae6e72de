//! The step timer "interrupt": a dedicated thread that calls the controller's step timer
//! handler at each deadline it returns, and at once when kicked.
//!
//! It sleeps until shortly before a deadline and spins the rest, so pulses leave on time
//! in real time too. The handler is always called with the deadline's own tick, or for a
//! kick with the tick at which `kick` was called, never a later one, even when the host
//! scheduled the thread late: every edge is stamped with the exact tick the step engine
//! computed, and the trace is the same as on a board whose interrupt is never late.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use arm_core::hw::StepKick;

use crate::clock::SimClock;
use crate::probe::Probe;
use crate::steppers::SimSteppers;

/// How the step thread waits for its deadlines.
#[derive(Clone, Copy, Debug)]
pub struct StepThreadConfig {
    /// SCHED_FIFO instead of nice -10.
    pub realtime: bool,
    /// Real time before a deadline at which the thread stops sleeping and spins, to cover
    /// the kernel's wake-up latency. Pulse times in simulated time are exact whatever
    /// this is; it only aligns them with the wall clock, at the cost of CPU.
    pub spin: Duration,
}

/// `kick_at` when no kick is pending.
const NO_KICK: u64 = u64::MAX;

struct TimerShared {
    /// Tick of the earliest kick not yet served, or [`NO_KICK`].
    kick_at: AtomicU64,
    lock: Mutex<()>,
    wake: Condvar,
    clock: SimClock,
}

/// [`StepKick`] for the simulator: wakes the step thread.
#[derive(Clone)]
pub struct SimStepKick {
    shared: Arc<TimerShared>,
}

impl std::fmt::Debug for SimStepKick {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimStepKick").finish()
    }
}

impl SimStepKick {
    /// A kick for a step thread on `clock`.
    pub fn new(clock: SimClock) -> SimStepKick {
        SimStepKick {
            shared: Arc::new(TimerShared {
                kick_at: AtomicU64::new(NO_KICK),
                lock: Mutex::new(()),
                wake: Condvar::new(),
                clock,
            }),
        }
    }
}

impl StepKick for SimStepKick {
    fn kick(&self) {
        let now = self.shared.clock.now_tick();
        self.shared.kick_at.fetch_min(now, Ordering::AcqRel);
        let _guard = self.shared.lock.lock();
        self.shared.wake.notify_one();
    }

    fn now_tick(&self) -> u64 {
        self.shared.clock.now_tick()
    }
}

/// Starts the step thread. `on_timer(tick, pins)` is the controller's step timer handler:
/// it returns the tick at which it wants to run next, or `None` until kicked.
pub fn spawn_step_thread(
    kick: &SimStepKick,
    mut pins: SimSteppers,
    probe: Arc<Probe>,
    config: StepThreadConfig,
    mut on_timer: impl FnMut(u64, &mut SimSteppers) -> Option<u64> + Send + 'static,
) -> std::io::Result<()> {
    let shared = kick.shared.clone();
    std::thread::Builder::new()
        .name("step-timer".into())
        .spawn(move || {
            raise_priority(config.realtime);
            let clock = shared.clock;
            let mut deadline: Option<u64> = None;
            let mut last_tick = 0u64;
            loop {
                let now = clock.now_tick();
                let due = deadline.filter(|&d| d <= now);
                let kick_at = shared.kick_at.load(Ordering::Acquire);
                let tick = match due {
                    // The earlier of an overdue deadline and a pending kick goes first.
                    Some(d) if d <= kick_at => d,
                    _ if kick_at != NO_KICK => shared.kick_at.swap(NO_KICK, Ordering::AcqRel),
                    _ => {
                        wait(&shared, deadline, config.spin);
                        continue;
                    }
                };
                // Never back in time (a kick stamped before the last deadline served).
                let tick = tick.max(last_tick);
                last_tick = tick;
                pins.set_tick(tick);
                let was_running = deadline.is_some();
                deadline = on_timer(tick, &mut pins);
                probe
                    .engine_running
                    .store(deadline.is_some(), Ordering::Release);
                if was_running && deadline.is_none() {
                    probe.engine_stopped(Instant::now(), clock.tick_to_ns(tick));
                }
            }
        })?;
    Ok(())
}

fn kicked(shared: &TimerShared) -> bool {
    shared.kick_at.load(Ordering::Acquire) != NO_KICK
}

/// Waits until `deadline` is close (then spins to it) or a kick arrives.
fn wait(shared: &TimerShared, deadline: Option<u64>, spin: Duration) {
    let Some(due) = deadline else {
        if let Ok(guard) = shared.lock.lock()
            && !kicked(shared)
        {
            let _ = shared.wake.wait_timeout(guard, Duration::from_millis(100));
        }
        return;
    };
    let at = shared.clock.real_instant_of_tick(due);
    let now = Instant::now();
    if at <= now {
        return;
    }
    let remaining = at - now;
    if remaining > spin {
        if let Ok(guard) = shared.lock.lock()
            && !kicked(shared)
        {
            let _ = shared.wake.wait_timeout(guard, remaining - spin);
        }
    } else {
        // Spin, still answering a kick at once.
        while Instant::now() < at && !kicked(shared) {
            std::hint::spin_loop();
        }
    }
}

/// Makes the step thread preempt the executor: a finer timer slack always, then
/// SCHED_FIFO when asked (and permitted), else the highest nice level permitted.
fn raise_priority(realtime: bool) {
    // SAFETY: prctl and setpriority on the calling thread, with plain integer arguments;
    // sched_setscheduler with a valid sched_param.
    unsafe {
        libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong);
        if realtime {
            let param = libc::sched_param { sched_priority: 50 };
            if libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) == 0 {
                log::info!("step thread: SCHED_FIFO priority 50");
                return;
            }
            log::warn!(
                "step thread: SCHED_FIFO refused ({}); normal priority",
                std::io::Error::last_os_error()
            );
        }
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        if libc::setpriority(libc::PRIO_PROCESS, tid, -10) == 0 {
            log::debug!("step thread: nice -10");
        }
    }
}

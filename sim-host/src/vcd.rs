//! `--trace FILE.vcd`: every output line of the simulated board as a Value Change Dump that
//! GTKWave and PulseView open.
//!
//! Changes come from two places: the step "interrupt" thread (STEP and DIR, stamped with
//! the exact tick the step engine ran at) and the tasks (ENABLE, PIN0/PIN1, gripper). A
//! writer thread takes them through a channel, keeps them in a heap for a short reorder
//! window (VCD needs non-decreasing times) and writes them buffered. [`Tracer::finish`]
//! flushes everything: it runs at exit and on SIGINT/SIGTERM.
//!
//! The step thread says how far it has played ([`Tracer::steps_played_to`]) and the writer
//! never writes past that: a step thread stalled longer than the reorder window (a loaded
//! machine) delays the trace instead of having its edges restamped later than they were,
//! which could move a run's pulses after an e-stop input's edge in the trace.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, mpsc};
use std::thread::JoinHandle;
use std::time::Duration;

use armctl::vcd::{JointWire, wire_name};

use crate::clock::SimClock;

/// Joints traced: all the step engine can drive, whatever JOINTS_COUNT says.
pub const TRACED_JOINTS: usize = arm_step::MAX_JOINTS;

/// Real time an event may arrive late and still be written in order.
const REORDER_WINDOW: Duration = Duration::from_millis(200);

/// One traced line or value.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Signal {
    /// STEP of joint j.
    Step(u8),
    /// DIR of joint j (1 = positive).
    Dir(u8),
    /// ENABLE of joint j (1 = holding).
    Enable(u8),
    /// ENABLE of the gripper driver.
    GripperEnable,
    /// Gripper timer output running.
    GripperActive,
    /// Gripper stepper direction (1 = positive pulse count).
    GripperDir,
    /// Gripper PWM frequency, Hz.
    GripperFrequency,
    /// Gripper PWM duty, 0..1.
    GripperDuty,
    /// Gripper stepper-mode pulses of the current burst (0 = servo mode).
    GripperPulses,
    /// User pin 0.
    Pin0,
    /// User pin 1.
    Pin1,
    /// High from the arrival of a STOPPED datagram until the step engine is idle.
    EStop,
    /// The wired e-stop input (`--estop-input`): high while it is open.
    EStopInput,
    /// The safety-door input (`--door-input`, issue 32): high while it is open.
    DoorInput,
}

/// A traced value.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Value {
    /// A wire.
    Bit(bool),
    /// A real number.
    Real(f64),
    /// A 32-bit integer.
    Int(u32),
}

/// A change that is written only if `guard.0` still holds `guard.1` when its time comes.
pub type Guard = Option<(Arc<AtomicU64>, u64)>;

#[derive(Clone, Debug)]
struct Change {
    t_ns: u64,
    order: u64,
    signal: Signal,
    value: Value,
    guard: Guard,
}

impl PartialEq for Change {
    fn eq(&self, other: &Self) -> bool {
        (self.t_ns, self.order) == (other.t_ns, other.order)
    }
}
impl Eq for Change {}
impl PartialOrd for Change {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Change {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        (self.t_ns, self.order).cmp(&(other.t_ns, other.order))
    }
}

enum Message {
    Change(Change),
    Finish(mpsc::Sender<()>),
}

/// Handle to the trace writer; cheap to clone, usable from any thread. A disabled tracer
/// (no `--trace`) does nothing.
#[derive(Clone)]
pub struct Tracer {
    inner: Option<Arc<TracerInner>>,
}

struct TracerInner {
    sender: Mutex<mpsc::Sender<Message>>,
    /// Simulated ns up to which the step thread has recorded every change
    /// (`u64::MAX`: no step thread says, as on the virtual board).
    steps_played_ns: Arc<AtomicU64>,
    order: AtomicU64,
    clock: SimClock,
    writer: Mutex<Option<JoinHandle<()>>>,
}

impl std::fmt::Debug for Tracer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tracer")
            .field("enabled", &self.inner.is_some())
            .finish()
    }
}

impl Tracer {
    /// A tracer that records nothing.
    pub fn disabled() -> Tracer {
        Tracer { inner: None }
    }

    /// Creates `path` and starts the writer thread.
    pub fn create(path: &Path, clock: SimClock) -> io::Result<Tracer> {
        let file = BufWriter::with_capacity(1 << 20, File::create(path)?);
        let (sender, receiver) = mpsc::channel();
        let window_ns = (REORDER_WINDOW.as_nanos() as f64 * clock.time_scale()) as u64;
        let mut writer = VcdWriter::new(file)?;
        let steps_played_ns = Arc::new(AtomicU64::new(u64::MAX));
        let played = steps_played_ns.clone();
        let thread = std::thread::Builder::new()
            .name("vcd-writer".into())
            .spawn(move || writer.run(receiver, clock, window_ns, &played))?;
        Ok(Tracer {
            inner: Some(Arc::new(TracerInner {
                sender: Mutex::new(sender),
                steps_played_ns,
                order: AtomicU64::new(0),
                clock,
                writer: Mutex::new(Some(thread)),
            })),
        })
    }

    /// Whether changes are recorded.
    pub fn is_enabled(&self) -> bool {
        self.inner.is_some()
    }

    /// The step thread has recorded every change up to simulated nanosecond `t_ns`: the
    /// writer may write up to there (and no further than the reorder window allows).
    pub fn steps_played_to(&self, t_ns: u64) {
        if let Some(inner) = &self.inner {
            inner.steps_played_ns.store(t_ns, Ordering::Release);
        }
    }

    /// Records `signal` taking `value` at simulated nanosecond `t_ns`.
    pub fn record_at(&self, t_ns: u64, signal: Signal, value: Value) {
        self.record_guarded(t_ns, signal, value, None);
    }

    /// Records a change that may lie in the future (the end of a gripper burst): it is
    /// written only if `guard`'s counter still holds its value by then.
    pub fn record_guarded(&self, t_ns: u64, signal: Signal, value: Value, guard: Guard) {
        if let Some(inner) = &self.inner {
            let order = inner.order.fetch_add(1, Ordering::Relaxed);
            let change = Change {
                t_ns,
                order,
                signal,
                value,
                guard,
            };
            if let Ok(sender) = inner.sender.lock() {
                let _ = sender.send(Message::Change(change));
            }
        }
    }

    /// Records `signal` taking `value` now.
    pub fn record(&self, signal: Signal, value: Value) {
        if let Some(inner) = &self.inner {
            self.record_at(inner.clock.now_ns(), signal, value);
        }
    }

    /// Writes out everything recorded and closes the file. Later changes are dropped.
    pub fn finish(&self) {
        let Some(inner) = &self.inner else { return };
        let (done, wait) = mpsc::channel();
        if let Ok(sender) = inner.sender.lock() {
            let _ = sender.send(Message::Finish(done));
        }
        let _ = wait.recv_timeout(Duration::from_secs(5));
        if let Some(thread) = inner.writer.lock().ok().and_then(|mut w| w.take()) {
            let _ = thread.join();
        }
    }
}

/// VCD identifier codes: printable ASCII from '!'.
fn identifier(signal: Signal) -> String {
    let index = match signal {
        Signal::Step(j) => j as usize,
        Signal::Dir(j) => TRACED_JOINTS + j as usize,
        Signal::Enable(j) => 2 * TRACED_JOINTS + j as usize,
        Signal::GripperEnable => 3 * TRACED_JOINTS,
        Signal::GripperActive => 3 * TRACED_JOINTS + 1,
        Signal::GripperDir => 3 * TRACED_JOINTS + 2,
        Signal::GripperFrequency => 3 * TRACED_JOINTS + 3,
        Signal::GripperDuty => 3 * TRACED_JOINTS + 4,
        Signal::GripperPulses => 3 * TRACED_JOINTS + 5,
        Signal::Pin0 => 3 * TRACED_JOINTS + 6,
        Signal::Pin1 => 3 * TRACED_JOINTS + 7,
        Signal::EStop => 3 * TRACED_JOINTS + 8,
        Signal::EStopInput => 3 * TRACED_JOINTS + 9,
        Signal::DoorInput => 3 * TRACED_JOINTS + 10,
    };
    // 94 printable characters: two-character codes are never needed for < 94 signals.
    char::from(b'!' + index as u8).to_string()
}

/// Every traced signal with its VCD declaration and initial value.
fn declarations() -> Vec<(Signal, &'static str, String, Value)> {
    let mut all = Vec::new();
    for j in 0..TRACED_JOINTS as u8 {
        all.push((
            Signal::Step(j),
            "wire 1",
            wire_name(JointWire::Step, usize::from(j)),
            Value::Bit(false),
        ));
        all.push((
            Signal::Dir(j),
            "wire 1",
            wire_name(JointWire::Dir, usize::from(j)),
            Value::Bit(false),
        ));
        all.push((
            Signal::Enable(j),
            "wire 1",
            wire_name(JointWire::Enable, usize::from(j)),
            Value::Bit(false),
        ));
    }
    let gripper = [
        (
            Signal::GripperEnable,
            "wire 1",
            "gripper_enable",
            Value::Bit(false),
        ),
        (
            Signal::GripperActive,
            "wire 1",
            "gripper_pwm_active",
            Value::Bit(false),
        ),
        (
            Signal::GripperDir,
            "wire 1",
            "gripper_dir",
            Value::Bit(false),
        ),
        (
            Signal::GripperFrequency,
            "real 64",
            "gripper_freq_hz",
            Value::Real(0.0),
        ),
        (
            Signal::GripperDuty,
            "real 64",
            "gripper_duty",
            Value::Real(0.0),
        ),
        (
            Signal::GripperPulses,
            "integer 32",
            "gripper_pulses",
            Value::Int(0),
        ),
        (Signal::Pin0, "wire 1", "pin0", Value::Bit(false)),
        (Signal::Pin1, "wire 1", "pin1", Value::Bit(false)),
        (Signal::EStop, "wire 1", "estop", Value::Bit(false)),
        (
            Signal::EStopInput,
            "wire 1",
            "estop_input",
            Value::Bit(false),
        ),
        (Signal::DoorInput, "wire 1", "door_input", Value::Bit(false)),
    ];
    for (signal, kind, name, value) in gripper {
        all.push((signal, kind, name.to_string(), value));
    }
    all
}

struct VcdWriter<W: Write> {
    out: W,
    current: std::collections::HashMap<Signal, Value>,
    last_t_ns: Option<u64>,
    late: u64,
}

impl<W: Write> VcdWriter<W> {
    fn new(mut out: W) -> io::Result<Self> {
        writeln!(out, "$version sim-host {} $end", env!("CARGO_PKG_VERSION"))?;
        writeln!(out, "$comment simulated arm controller outputs $end")?;
        writeln!(out, "$timescale 1ns $end")?;
        writeln!(out, "$scope module arm $end")?;
        let mut current = std::collections::HashMap::new();
        for (signal, kind, name, _) in declarations() {
            writeln!(out, "$var {kind} {} {name} $end", identifier(signal))?;
        }
        writeln!(out, "$upscope $end")?;
        writeln!(out, "$enddefinitions $end")?;
        writeln!(out, "#0")?;
        writeln!(out, "$dumpvars")?;
        for (signal, _, _, value) in declarations() {
            write_value(&mut out, signal, value)?;
            current.insert(signal, value);
        }
        writeln!(out, "$end")?;
        Ok(VcdWriter {
            out,
            current,
            last_t_ns: Some(0),
            late: 0,
        })
    }

    fn write(&mut self, change: Change) -> io::Result<()> {
        if let Some((counter, expected)) = &change.guard
            && counter.load(Ordering::Relaxed) != *expected
        {
            return Ok(());
        }
        if self.current.get(&change.signal) == Some(&change.value) {
            return Ok(());
        }
        let mut t = change.t_ns;
        if let Some(last) = self.last_t_ns
            && t < last
        {
            // Arrived after the reorder window: stamped at the last written time.
            self.late += 1;
            t = last;
        }
        if self.last_t_ns != Some(t) {
            writeln!(self.out, "#{t}")?;
            self.last_t_ns = Some(t);
        }
        self.current.insert(change.signal, change.value);
        write_value(&mut self.out, change.signal, change.value)
    }

    fn run(
        &mut self,
        receiver: mpsc::Receiver<Message>,
        clock: SimClock,
        window_ns: u64,
        steps_played_ns: &AtomicU64,
    ) {
        let mut pending: BinaryHeap<Reverse<Change>> = BinaryHeap::new();
        let mut finished: Option<mpsc::Sender<()>> = None;
        loop {
            // Read before taking the changes: the step thread sent every change up to it
            // before storing it.
            let played = steps_played_ns.load(Ordering::Acquire);
            match receiver.recv_timeout(Duration::from_millis(20)) {
                Ok(Message::Change(c)) => pending.push(Reverse(c)),
                Ok(Message::Finish(done)) => finished = Some(done),
                Err(mpsc::RecvTimeoutError::Timeout) => {}
                Err(mpsc::RecvTimeoutError::Disconnected) => break,
            }
            while finished.is_none() {
                match receiver.try_recv() {
                    Ok(Message::Change(c)) => pending.push(Reverse(c)),
                    Ok(Message::Finish(done)) => finished = Some(done),
                    Err(_) => break,
                }
            }
            if finished.is_some() {
                break;
            }
            let horizon = clock.now_ns().saturating_sub(window_ns).min(played);
            while pending.peek().is_some_and(|c| c.0.t_ns <= horizon) {
                if let Some(Reverse(c)) = pending.pop()
                    && let Err(e) = self.write(c)
                {
                    log::error!("trace: write failed: {e}");
                    return;
                }
            }
        }
        // Finish: everything still queued, including changes stamped in the future (the
        // end of a gripper burst), then the final time.
        while let Some(Reverse(c)) = pending.pop() {
            if self.write(c).is_err() {
                break;
            }
        }
        let end = clock.now_ns().max(self.last_t_ns.unwrap_or(0));
        if self.last_t_ns != Some(end) {
            let _ = writeln!(self.out, "#{end}");
        }
        if let Err(e) = self.out.flush() {
            log::error!("trace: flush failed: {e}");
        }
        if self.late > 0 {
            log::warn!(
                "trace: {} changes arrived too late to be written at their time",
                self.late
            );
        }
        if let Some(done) = finished {
            let _ = done.send(());
        }
    }
}

fn write_value(out: &mut impl Write, signal: Signal, value: Value) -> io::Result<()> {
    let id = identifier(signal);
    match value {
        Value::Bit(b) => writeln!(out, "{}{id}", u8::from(b)),
        Value::Real(r) => writeln!(out, "r{r} {id}"),
        Value::Int(i) => writeln!(out, "b{i:b} {id}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The writer's output, readable while it runs.
    #[derive(Clone, Default)]
    struct Shared(Arc<Mutex<Vec<u8>>>);

    impl Write for Shared {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    /// A step thread stalled past the reorder window: before, a task's later change was
    /// written meanwhile and the step edges that came after it were restamped at its time
    /// (a run's pulses could land after the e-stop input's edge; found reading the code,
    /// not seen in a run). Now nothing past the step thread's mark is written, and the
    /// edges keep their times.
    #[test]
    fn a_stalled_step_thread_holds_the_trace_back_rather_than_being_restamped() {
        let clock = SimClock::virtual_time(1_000_000);
        clock.advance_ns(1_000_000_000);
        let out = Shared::default();
        let mut writer = VcdWriter::new(out.clone()).expect("header");
        let header = out.0.lock().unwrap().len();
        let (sender, receiver) = mpsc::channel();
        let played = Arc::new(AtomicU64::new(100_000_000));
        let mark = played.clone();
        let thread = std::thread::spawn(move || {
            writer.run(receiver, clock, 200_000_000, &mark);
        });
        let change = |t_ns, signal, value| {
            Message::Change(Change {
                t_ns,
                order: t_ns,
                signal,
                value,
                guard: None,
            })
        };
        // A task's change at 700 ms: inside the old horizon (1 s less the 200 ms window),
        // past the step thread's 100 ms.
        sender
            .send(change(700_000_000, Signal::EStopInput, Value::Bit(true)))
            .unwrap();
        // The writer polls every 20 ms: it had written it within this before.
        let until = std::time::Instant::now() + Duration::from_millis(500);
        while std::time::Instant::now() < until {
            assert_eq!(
                out.0.lock().unwrap().len(),
                header,
                "written past the step thread's mark"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        // The stalled thread's pulse, then its mark.
        sender
            .send(change(150_000_000, Signal::Step(0), Value::Bit(true)))
            .unwrap();
        sender
            .send(change(152_000_000, Signal::Step(0), Value::Bit(false)))
            .unwrap();
        played.store(1_000_000_000, Ordering::Release);
        let (done, wait) = mpsc::channel();
        sender.send(Message::Finish(done)).unwrap();
        wait.recv_timeout(Duration::from_secs(30))
            .expect("finished");
        thread.join().unwrap();
        let text = out.0.lock().unwrap().clone();
        let parsed = armctl::vcd::changes(text.as_slice(), "t.vcd").expect("parse");
        assert_eq!(parsed.rising_edges("step0"), vec![150_000_000]);
        assert_eq!(parsed.rising_edges("estop_input"), vec![700_000_000]);
    }

    #[test]
    fn writer_output_parses_back() {
        let mut writer = VcdWriter::new(Vec::new()).expect("header");
        let mut order = 0;
        let mut change = |t_ns, signal, value| {
            order += 1;
            Change {
                t_ns,
                order,
                signal,
                value,
                guard: None,
            }
        };
        let changes = [
            change(10, Signal::Dir(2), Value::Bit(true)),
            change(20, Signal::Step(2), Value::Bit(true)),
            change(30, Signal::Step(2), Value::Bit(false)),
            change(40, Signal::Step(2), Value::Bit(true)),
            change(50, Signal::Step(2), Value::Bit(false)),
            change(60, Signal::Dir(2), Value::Bit(false)),
            change(70, Signal::Step(2), Value::Bit(true)),
            change(80, Signal::GripperFrequency, Value::Real(50.0)),
            change(80, Signal::GripperPulses, Value::Int(5)),
        ];
        for c in changes {
            writer.write(c).expect("write");
        }
        let text = String::from_utf8(writer.out).expect("utf8");
        let parsed = armctl::vcd::changes(text.as_bytes(), "t.vcd").expect("parse");
        assert_eq!(parsed.rising_edges("step2"), vec![20, 40, 70]);
        assert_eq!(parsed.joint_position(2), 1);
        assert_eq!(parsed.value_at("gripper_freq_hz", 100), Some("r50"));
        assert_eq!(parsed.value_at("gripper_pulses", 100), Some("b101"));
        assert_eq!(parsed.joint_position(0), 0);
    }
}

//! The bus: the queues and signals that connect the tasks, and the routing of received
//! datagrams onto them ([`Bus::route`]: a CRC-valid STOPPED to `estop`, everything else to
//! `inbox`). Who sends what to whom:
//!
//! ```text
//!            Datagrams                                               StepPins
//!   UDP <-> network_task --estop (STOPPED, first)--> trajectory_task     ^
//!              ^   |     --inbox (everything else)-->   | Controller     | step
//!              |   |                                    | Outputs,       | interrupts
//!           outbox <----- ACK, STATUS, LOCATION --------+ Gripper,...  StepShared
//!              ^   ^                                    |--push, stop, start-->^ |
//!              |   |                                    ^                        |
//!              |   |                                    '---- step_progress -----'
//!              |   '-- LOCATION (period) -- upload_task <-- reports, upload_changed
//!              '------ USART_RECV --------- serial_task <-- serial_tx, serial_opened
//! ```
//!
//! The trajectory task pushes segments into the step backend itself (in [`StepShared`]'s
//! critical section) and the step interrupts wake it through `step_progress`: no task
//! relays between them, so the motion held ahead of the pulses is the backend's whole
//! queue (the board profile's `lookahead_us`).
//!
//! Every channel and signal uses [`CriticalSectionRawMutex`]: the step backend and the
//! trajectory task's wake-up are touched from the step interrupts, and one kind of mutex
//! for all keeps the rules simple. Those critical sections mask the DIR changes and the
//! e-stop input too, so the queues of datagrams and frames are [`SlotQueue`]s, whose
//! critical sections move slot numbers while the values are copied with interrupts on
//! (issue 34: embassy-sync's `Channel` copied a 1.5 KB datagram inside one, 9.5 us).

use core::cell::{Cell, RefCell};

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use heapless::Vec;
use protocol::{MAX_DATAGRAM, MAX_SERIAL_CHUNK, Tag, UartInit, crc8};

use crate::config::HOST_WINDOW;
use crate::hw::Endpoint;
use crate::log_limit::{LogLimit, LogVerdict};
use crate::outgoing::Outgoing;
use crate::reports::ReportSettings;
use crate::slot_queue::SlotQueue;
use crate::source_share::{SharedBudgets, SourceBudgets};
#[cfg(doc)]
use crate::step_shared::StepShared;

/// The mutex kind of every channel, signal and shared cell.
pub type Cs = CriticalSectionRawMutex;

/// Queued STOPPED frames: one is enough to stop the arm; a few more keep the ACKs of a
/// host that repeats STOPPED quickly (or several hosts stopping at once).
pub const ESTOP_QUEUE: usize = 4;

/// Queued datagrams for the trajectory task: a host's whole window
/// ([`HOST_WINDOW`] = 32 datagrams, each up to 1472 bytes, sent back to back) plus 8 for
/// the commands of other tools on the same machine (a STATUS poller, a watcher) arriving
/// in the same instant. The network task can route a burst faster than the trajectory
/// task handles it (on the board the Ethernet ring and the UDP socket hold the same burst
/// before it), so the inbox must hold it whole. When full, datagrams are dropped (the host
/// resends: no ACK came), never waited for, so that a STOPPED behind them is never held
/// up. Each slot is a [`Datagram`] (1472 bytes + 12): 40 slots are 58 KiB of RAM.
pub const INBOX_QUEUE: usize = HOST_WINDOW + 8;

/// Queued frames to send: two for each datagram of a full inbox (its ACK and its STATUS
/// report, or the LOCATION of the state change it made: the trajectory task handles a
/// burst without yielding, so they queue up before the network task sends any; issue 21
/// F16: with one per datagram, a window of STATUS polls lost replies, also other tools'),
/// the ACKs of the e-stop queue, plus a periodic LOCATION, a USART_RECV and a few more.
/// When full, a frame is dropped (counted, logged at most once a second): the controller
/// never waits to report. A slot holds the largest frame's content (USART_RECV, 255
/// bytes). Plus [`ESTOP_ACK_RESERVE`], the slots only STOPPEDs' ACKs may take.
pub const OUTBOX_QUEUE: usize = 2 * INBOX_QUEUE + ESTOP_QUEUE + 8 + ESTOP_ACK_RESERVE;

/// Outbox slots only the ACKs of STOPPEDs may take: one per queued STOPPED
/// ([`ESTOP_QUEUE`]). A flood's own ACKs (NOT_OWNER, BAD_CRC) may fill the rest of the
/// outbox; a host that resends STOPPED until it is ACKed must still get its ACK.
pub const ESTOP_ACK_RESERVE: usize = ESTOP_QUEUE;

/// USART_SEND payloads waiting for the serial port: at 115200 baud four are 90 ms of
/// line time; a full queue refuses USART_SEND with BUFFER_FULL.
pub const SERIAL_TX_QUEUE: usize = 4;

/// A datagram as received.
#[derive(Clone, Debug)]
pub struct Datagram {
    /// Sender.
    pub from: Endpoint,
    /// The whole frame (seq, tag, data, crc).
    pub bytes: Vec<u8, MAX_DATAGRAM>,
    /// STOPPED frames put on `bus.estop` before this one arrived (wrapping), stamped by
    /// [`Bus::route`]: tells the trajectory task which STOPPEDs it handled overtook it.
    pub stops_before: u32,
}

impl Datagram {
    /// A datagram from `from`, not yet stamped (see [`Bus::route`]).
    pub fn new(from: Endpoint, bytes: Vec<u8, MAX_DATAGRAM>) -> Self {
        Datagram {
            from,
            bytes,
            stops_before: 0,
        }
    }
}

/// The channels and signals that connect the tasks. Put one in a `static` (`new` is
/// `const`) or a `StaticCell`.
/// See the module docs for who sends what to whom.
pub struct Bus {
    /// CRC-valid STOPPED frames, routed here by `network_task`; drained by
    /// `trajectory_task` before anything else (the e-stop path).
    pub estop: SlotQueue<Datagram, ESTOP_QUEUE>,
    /// Every other datagram, from `network_task`; drained by `trajectory_task`.
    pub inbox: SlotQueue<Datagram, INBOX_QUEUE>,
    /// Frames to send, from `trajectory_task`, `upload_task` and `serial_task`; drained by
    /// `network_task`.
    pub outbox: SlotQueue<Outgoing, OUTBOX_QUEUE>,
    /// Raised by the step interrupts (through [`StepShared::on_interrupt`]) when segments
    /// finished or the backend ran dry, and by the wired e-stop input's handler; waited on
    /// by `trajectory_task`, which then collects the progress from [`StepShared`] and
    /// pushes more segments. (A spurious raise only makes it look again: the board's
    /// watchdog raises it to see the task alive.)
    pub step_progress: Signal<Cs, ()>,
    /// USART_SEND payloads, from `trajectory_task`; drained by `serial_task`.
    pub serial_tx: SlotQueue<Vec<u8, MAX_SERIAL_CHUNK>, SERIAL_TX_QUEUE>,
    /// The serial port was opened with these settings, by `trajectory_task`; taken by
    /// `serial_task`'s reader.
    pub serial_opened: Signal<Cs, UartInit>,
    /// Report destination, state and upload settings, written by `trajectory_task`; read
    /// by `upload_task` and `network_task`.
    pub reports: Mutex<Cs, Cell<ReportSettings>>,
    /// Raised by `trajectory_task` when reports were switched or the period changed;
    /// waited on by `upload_task`.
    pub upload_changed: Signal<Cs, ()>,
    /// STOPPED frames put on `estop` so far (wrapping); every datagram is stamped with it
    /// ([`Datagram::stops_before`]). Counted by [`Bus::route`] only.
    stops_routed: Mutex<Cs, Cell<u32>>,
    /// Datagrams dropped by [`Bus::route`] (full inbox), and the limit on their log lines.
    inbox_drops: Mutex<Cs, Cell<(u32, LogLimit)>>,
    /// Frames dropped by [`Bus::send`] (full outbox) not yet logged: `network_task` logs
    /// them, at most once a second.
    outbox_drops: Mutex<Cs, Cell<u32>>,
    /// Each source's share of the receive path, charged by [`Bus::receive_first`] (the
    /// first reader of datagrams: [`crate::ingress`]).
    pub(crate) budgets: SharedBudgets,
    /// USART_SEND bytes ACKed but dropped unsent by a USART_STOP (wrapping), counted by
    /// `trajectory_task`.
    serial_tx_dropped: Mutex<Cs, Cell<u32>>,
    /// Datagrams [`Bus::receive_first`] ignored for their broadcast or multicast address,
    /// and the limit on their log lines.
    pub(crate) group_ignored: Mutex<Cs, Cell<(u32, LogLimit)>>,
    /// What the board's receive interrupt counts about its ring
    /// ([`crate::ingress::RxRingCounters`]).
    pub(crate) rx_ring: Mutex<Cs, Cell<crate::ingress::RxRingCounters>>,
    /// Where the DIAG report's counters come from: the board's reader of its own timing
    /// counters ([`Bus::set_diag_source`], [`crate::diag`]); `None`: not measured.
    diag_source: Mutex<Cs, Cell<Option<DiagSource>>>,
}

/// A board's reader of its timing counters for the DIAG report ([`Bus::set_diag_source`]).
pub type DiagSource = fn() -> protocol::Diag;

impl Default for Bus {
    fn default() -> Self {
        Self::new()
    }
}

impl Bus {
    /// Empty channels, boot report settings.
    pub const fn new() -> Self {
        Bus {
            estop: SlotQueue::new(),
            inbox: SlotQueue::new(),
            outbox: SlotQueue::new(),
            step_progress: Signal::new(),
            serial_tx: SlotQueue::new(),
            serial_opened: Signal::new(),
            reports: Mutex::new(Cell::new(ReportSettings::UNPUBLISHED)),
            upload_changed: Signal::new(),
            stops_routed: Mutex::new(Cell::new(0)),
            inbox_drops: Mutex::new(Cell::new((0, LogLimit::new()))),
            outbox_drops: Mutex::new(Cell::new(0)),
            budgets: Mutex::new(RefCell::new(SourceBudgets::new())),
            group_ignored: Mutex::new(Cell::new((0, LogLimit::new()))),
            serial_tx_dropped: Mutex::new(Cell::new(0)),
            rx_ring: Mutex::new(Cell::new(crate::ingress::RxRingCounters::ZERO)),
            diag_source: Mutex::new(Cell::new(None)),
        }
    }

    /// The board reads its timing counters with `read` (issue 34; a plain function: the
    /// counters are the board's statics, [`crate::diag`]). Until it is called, DIAG says
    /// "not measured" ([`protocol::Diag::NOT_MEASURED`]).
    pub fn set_diag_source(&self, read: DiagSource) {
        self.diag_source.lock(|c| c.set(Some(read)));
    }

    /// The DIAG report's counters: the board's, or "not measured" without a source. The
    /// source runs outside the bus's lock (it may take a critical section of its own).
    pub fn diag(&self) -> protocol::Diag {
        match self.diag_source.lock(|c| c.get()) {
            Some(read) => read(),
            None => protocol::Diag::NOT_MEASURED,
        }
    }

    /// Datagrams dropped so far because the inbox was full (wrapping).
    pub fn inbox_drops(&self) -> u32 {
        self.inbox_drops.lock(|c| c.get().0)
    }

    /// Takes the count of frames dropped because the outbox was full since the last call.
    pub fn take_outbox_drops(&self) -> u32 {
        self.outbox_drops.lock(|c| c.replace(0))
    }

    /// USART_SEND bytes ACKed `OK` but dropped unsent because USART_STOP closed the port
    /// first (wrapping): every byte ACKed is written, or counted here (issue 21 F18).
    pub fn serial_tx_dropped(&self) -> u32 {
        self.serial_tx_dropped.lock(|c| c.get())
    }

    /// Drops every queued USART_SEND payload, counting its bytes in
    /// [`Bus::serial_tx_dropped`]; returns how many bytes.
    pub fn drop_serial_tx(&self) -> u32 {
        let mut bytes = 0u32;
        while let Ok(chunk) = self.serial_tx.try_receive() {
            bytes = bytes.saturating_add(u32::try_from(chunk.len()).unwrap_or(u32::MAX));
        }
        self.serial_tx_dropped
            .lock(|c| c.set(c.get().wrapping_add(bytes)));
        bytes
    }

    /// The report settings as last published.
    pub fn report_settings(&self) -> ReportSettings {
        self.reports.lock(|c| c.get())
    }

    /// Queues a frame to send; a full outbox drops it (counted; `network_task` logs the
    /// count) rather than wait. The last [`ESTOP_ACK_RESERVE`] slots are kept for the ACKs
    /// of STOPPEDs.
    pub fn send(&self, out: Outgoing) {
        let stop_ack = matches!(out, Outgoing::Ack(r) if r.ack.acked_tag == Tag::Stopped as u8);
        let room = stop_ack || self.outbox.free_capacity() > ESTOP_ACK_RESERVE;
        if !room || self.outbox.try_send(out).is_err() {
            self.outbox_drops.lock(|c| c.set(c.get().saturating_add(1)));
        }
    }

    /// Puts a CRC-valid STOPPED on `estop`, stamped like [`Bus::route`] does; a full
    /// `estop` (already that many STOPPEDs waiting, so the controller stops anyway) drops
    /// it. Never falls back to the inbox: a flood of STOPPEDs cannot crowd out other
    /// hosts' commands.
    pub fn route_stop(&self, datagram: Datagram) -> bool {
        // Copied into its slot with interrupts on; stamped and queued in one critical
        // section.
        let Ok(filled) = self.estop.try_fill(datagram) else {
            return false;
        };
        self.stops_routed.lock(|routed| {
            filled.commit_with(|d| d.stops_before = routed.get());
            routed.set(routed.get().wrapping_add(1));
        });
        true
    }

    /// Routes a received datagram: a CRC-valid STOPPED to `estop` (to `inbox` if that
    /// is full), everything else to `inbox`. Never waits: a full inbox drops the datagram
    /// (the host resends it since no ACK came; the drops are counted and logged at most
    /// once a second, `now_us` being the arrival time). Stamps it with the STOPPEDs put on
    /// `estop` before it ([`Datagram::stops_before`]).
    pub fn route(&self, datagram: Datagram, now_us: u64) {
        let from_ip = datagram.from.ip;
        // The datagram is copied into a slot with interrupts on (issue 34); the stamp and
        // the slot's place in its queue are set in one critical section, so that stamps
        // and queue order agree even if two tasks route.
        let filled = if is_stop(&datagram.bytes) {
            match self.estop.try_fill(datagram) {
                Ok(filled) => Ok((Some(filled), None)),
                Err(d) => self.inbox.try_fill(d).map(|f| (None, Some(f))),
            }
        } else {
            self.inbox.try_fill(datagram).map(|f| (None, Some(f)))
        };
        let queued = match filled {
            Ok((stop, other)) => {
                self.stops_routed.lock(|routed| {
                    if let Some(stop) = stop {
                        stop.commit_with(|d| d.stops_before = routed.get());
                        routed.set(routed.get().wrapping_add(1));
                    }
                    if let Some(other) = other {
                        other.commit_with(|d| d.stops_before = routed.get());
                    }
                });
                true
            }
            Err(_) => false,
        };
        if !queued {
            self.release(from_ip);
            let verdict = self.inbox_drops.lock(|c| {
                let (drops, mut limit) = c.get();
                let verdict = limit.event(now_us);
                c.set((drops.wrapping_add(1), limit));
                verdict
            });
            if let LogVerdict::Log { suppressed } = verdict {
                warn!(
                    "inbox full: a datagram was dropped ({} more since the last such line)",
                    suppressed
                );
            }
        }
    }
}

/// Whether a datagram is a CRC-valid STOPPED frame.
pub fn is_stop(bytes: &[u8]) -> bool {
    is_valid_frame_of(bytes, Tag::Stopped)
}

/// Whether a datagram is a CRC-valid frame with tag `tag`, whatever its length.
pub fn is_valid_frame_of(bytes: &[u8], tag: Tag) -> bool {
    match bytes.split_last() {
        Some((crc, body @ [_, t, ..])) => *t == tag as u8 && crc8(body) == *crc,
        _ => false,
    }
}

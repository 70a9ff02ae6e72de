//! The controller client: one UDP socket, a background thread that receives every report,
//! and blocking calls that send a command and wait for its ACK with bounded retries.

use std::net::{SocketAddr, ToSocketAddrs, UdpSocket};
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use protocol::{
    Ack, Command, Location, MAX_DATAGRAM, MAX_JOINTS, MAX_SERIAL_CHUNK, Pwm, State, StatusCode,
    StatusReport, Tag, UartInit,
};

use crate::error::{Error, Result};
use crate::interrupt::{CANCEL_POLL, Cancel};
use crate::pcap::PcapLog;
use crate::rtt::{DEFAULT_MIN_RTO, RESEND_HORIZON, RttEstimator};

pub mod auth;
mod homing;
mod motion_control;
pub use homing::Homed;
mod receiver;
mod wire_tools;
pub use wire_tools::{Diagnosis, Glance};

pub(crate) use receiver::{AckWaiter, Event, lock};
use receiver::{Shared, receive_loop};

/// How long the receiver thread blocks in one `recv`, so that it notices a shutdown soon.
const RECEIVER_POLL: Duration = Duration::from_millis(50);

/// How long [`Client::set_location`] waits for the LOCATION report that gives the joints
/// it leaves alone their positions: reports come every 10 ms by default, at most every
/// second.
const LOCATION_FOR_SET: Duration = Duration::from_millis(1_500);

/// The session (epoch, id) a frame was sealed in; `None` for a frame sent plain.
pub(crate) type SealedIn = Option<(u64, u32)>;

/// Registration for the answers to a HELLO ([`Client::hello`]); removed when dropped.
struct HelloWaiter<'a>(Receiver<Event>, &'a Shared);

impl<'a> HelloWaiter<'a> {
    fn new(shared: &'a Shared) -> Self {
        let (tx, rx) = mpsc::channel();
        *lock(&shared.hello) = Some(tx);
        HelloWaiter(rx, shared)
    }
}

impl Drop for HelloWaiter<'_> {
    fn drop(&mut self) {
        *lock(&self.1.hello) = None;
    }
}

/// The least time a command is waited for by default. At loopback and LAN round trips
/// the 10 attempts, from a 3 ms wait doubling to 100 ms, span only about 0.6 s: a
/// controller that stops reading for longer (a board erasing a flash sector to keep its
/// settings, a simulator on a host whose disk is saturated) would be given up on although
/// it does the command once it reads its queue. 1.5 s covers such pauses and stays inside
/// the [`RESEND_HORIZON`], so the wait ends about when the last copy could still be
/// recognised as a duplicate.
pub const GIVE_UP_AFTER: Duration = Duration::from_millis(1500);

/// Timeouts and retry bounds of a [`Client`].
#[derive(Clone, Debug)]
pub struct Options {
    /// How long to wait for an ACK before sending the frame again, before any round trip
    /// is measured; also the longest wait. Once ACKs come, the wait follows the measured
    /// round trip (RFC 6298), down to `min_ack_timeout`.
    pub ack_timeout: Duration,
    /// The shortest wait for an ACK, however short the measured round trip.
    pub min_ack_timeout: Duration,
    /// How many times a frame is sent at most (the first send included). Whatever the
    /// count, no copy of a command leaves later than [`RESEND_HORIZON`] after its first, so
    /// that the controller's 2 s duplicate window recognises every copy (exactly once).
    pub attempts: u32,
    /// The least time a command is waited for before [`Error::NoReply`], however short the
    /// measured round trip: the last copy's wait is stretched to it (no further copy is
    /// sent). See [`GIVE_UP_AFTER`].
    pub give_up_after: Duration,
    /// How long to wait for a STATUS report after its ACK before asking again.
    pub report_timeout: Duration,
    /// Local address to send from (default: 127.0.0.1 or any address, port chosen by the
    /// system). The controller's owner is an IP address: another local address such as
    /// 127.0.0.2 is another host to it.
    pub bind: Option<SocketAddr>,
    /// The controller's key (docs/PROTOCOL.md section 13): with it every frame but
    /// STOPPED, DISCOVER and HELLO goes in an envelope, after a HELLO opened a session,
    /// and only sealed reports (and plain refusals) are taken.
    pub key: Option<protocol::auth::AuthKey>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            ack_timeout: Duration::from_millis(100),
            min_ack_timeout: DEFAULT_MIN_RTO,
            attempts: 10,
            give_up_after: GIVE_UP_AFTER,
            report_timeout: Duration::from_millis(300),
            bind: None,
            key: None,
        }
    }
}

/// A connection to one controller. All methods take `&self`: share it with `Arc` to call
/// [`Client::stop`] from another thread while a run is uploading.
///
/// Commands other than STOPPED wait while [`Client::run_trajectory`] uploads, because
/// a command slipped between PENDING frames that got lost or refused would leave a hole in
/// the upload's sequence numbers.
pub struct Client {
    socket: UdpSocket,
    addr: SocketAddr,
    next_seq: AtomicU8,
    options: Options,
    shared: Arc<Shared>,
    /// Held for a whole upload (see the type's doc).
    pub(crate) upload: Mutex<()>,
    /// The round-trip estimate every command and upload frame feeds and waits by.
    pub(crate) rtt: Mutex<RttEstimator>,
    receiver: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for Client {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Client")
            .field("addr", &self.addr)
            .field("options", &self.options)
            .finish_non_exhaustive()
    }
}

impl Client {
    /// Connects to the controller at `addr` (e.g. `"127.0.0.1:8510"`) with default
    /// [`Options`] and checks that it answers a STATUS.
    pub fn connect(addr: impl ToSocketAddrs) -> Result<Client> {
        Self::connect_with(addr, Options::default())
    }

    /// Connects with the given options and checks that the controller answers a STATUS.
    pub fn connect_with(addr: impl ToSocketAddrs, options: Options) -> Result<Client> {
        let controller = Self::open(addr, options)?;
        controller.status()?;
        Ok(controller)
    }

    /// Opens the socket and starts the receiver without talking to the controller.
    pub fn open(addr: impl ToSocketAddrs, options: Options) -> Result<Client> {
        let addr = addr.to_socket_addrs()?.next().ok_or_else(|| {
            Error::Io(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "the controller address resolves to nothing",
            ))
        })?;
        let local: SocketAddr = match options.bind {
            Some(bind) => Ok(bind),
            None => match addr {
                SocketAddr::V4(a) if a.ip().is_loopback() => "127.0.0.1:0",
                SocketAddr::V4(_) => "0.0.0.0:0",
                SocketAddr::V6(a) if a.ip().is_loopback() => "[::1]:0",
                SocketAddr::V6(_) => "[::]:0",
            }
            .parse(),
        }
        .map_err(|_| Error::Io(std::io::ErrorKind::InvalidInput.into()))?;
        let socket = UdpSocket::bind(local)?;
        // Only the controller's datagrams reach us.
        socket.connect(addr)?;
        let rx_socket = socket.try_clone()?;
        rx_socket.set_read_timeout(Some(RECEIVER_POLL))?;
        let shared = Arc::new(Shared::default());
        *lock(&shared.auth) = options.key.map(auth::HostAuth::new);
        let thread_shared = shared.clone();
        let receiver = std::thread::Builder::new()
            .name("armctl-rx".into())
            .spawn(move || receive_loop(rx_socket, thread_shared))?;
        // Start away from 0 so that two quick invocations do not look alike in a capture.
        let first_seq = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos() as u8);
        Ok(Client {
            socket,
            addr,
            next_seq: AtomicU8::new(first_seq),
            rtt: Mutex::new(RttEstimator::new(
                options.ack_timeout,
                options.min_ack_timeout,
            )),
            options,
            shared,
            upload: Mutex::new(()),
            receiver: Some(receiver),
        })
    }

    /// The controller's address.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// This host's address and port, as the controller sees it on loopback.
    pub fn local_addr(&self) -> Result<SocketAddr> {
        Ok(self.socket.local_addr()?)
    }

    /// The options in force.
    pub fn options(&self) -> &Options {
        &self.options
    }

    pub(crate) fn alloc_seq(&self) -> u8 {
        self.next_seq.fetch_add(1, Ordering::Relaxed)
    }

    pub(crate) fn waiter(&self) -> AckWaiter<'_> {
        self.shared.waiter()
    }

    /// From now on, writes every datagram sent and received to `pcap` (`--pcap FILE`).
    pub fn capture(&self, pcap: Arc<PcapLog>) {
        *lock(&self.shared.pcap) = Some(pcap);
    }

    /// Sends `frame`, sealed in the session (opened first if need be) when a key is
    /// given: each send, a resend too, gets a counter of its own. Returns the session it
    /// was sealed in (`None`: sent plain), for [`Client::session_lost`].
    pub(crate) fn send_bytes(&self, frame: &[u8]) -> Result<SealedIn> {
        let tag = frame.get(1).copied().unwrap_or(0);
        let plain = [Tag::Stopped, Tag::Discover, Tag::Hello]
            .iter()
            .any(|t| *t as u8 == tag);
        if plain || lock(&self.shared.auth).is_none() {
            self.send_datagram(frame)?;
            return Ok(None);
        }
        let seal = |auth: &mut Option<auth::HostAuth>| {
            auth.as_mut()
                .and_then(|a| Some((a.session()?, a.seal(frame)?)))
        };
        let sealed = seal(&mut lock(&self.shared.auth));
        let (session, sealed) = match sealed {
            Some(sealed) => sealed,
            None => {
                self.hello()?;
                seal(&mut lock(&self.shared.auth))
                    .ok_or_else(|| Error::Auth("no session after HELLO".into()))?
            }
        };
        self.send_datagram(&sealed)?;
        Ok(Some(session))
    }

    /// An envelope sealed in `sealed_in` was refused `AUTH_FAILED` (docs/PROTOCOL.md
    /// section 13: the controller was reset, or gave the session's slot to another HELLO):
    /// the session is dropped, so that the next send says HELLO again. Refusals of
    /// envelopes from a session already replaced change nothing (a window of frames in
    /// flight is refused frame by frame, and must not make a HELLO each).
    pub(crate) fn session_lost(&self, sealed_in: SealedIn) {
        let mut auth = lock(&self.shared.auth);
        if let Some(a) = auth.as_mut()
            && sealed_in.is_some()
            && a.session() == sealed_in
        {
            a.reset();
        }
    }

    /// Opens a session (HELLO), resending at most `attempts` times.
    pub fn hello(&self) -> Result<()> {
        let mut nonce = [0u8; protocol::auth::NONCE_LEN];
        auth::getrandom(&mut nonce)?;
        // A HELLO takes no seq of this client's sequence: the controller leaves HELLO out
        // of the upload's order, so a seq allocated here in the middle of an upload (a
        // session lost and opened again) was a gap before the next PENDING, refused
        // OUT_OF_ORDER for ever. Its answers are matched by tag and nonce instead.
        let seq = self.next_seq.load(Ordering::Relaxed);
        let mut buf = [0u8; MAX_DATAGRAM];
        let len = Command::Hello { nonce }.encode(seq, &mut buf)?;
        match lock(&self.shared.auth).as_mut() {
            Some(a) => {
                a.reset();
                a.pending_nonce = Some(nonce);
            }
            None => return Err(Error::Auth("no key given (--key-file)".into())),
        }
        let waiter = HelloWaiter::new(&self.shared);
        let started = Instant::now();
        for attempt in 1..=self.options.attempts {
            self.send_datagram(&buf[..len])?;
            let mut deadline = Instant::now() + self.rto();
            if attempt == self.options.attempts {
                deadline = deadline.max(started + self.options.give_up_after);
            }
            loop {
                let left = deadline.saturating_duration_since(Instant::now());
                match waiter.0.recv_timeout(left) {
                    Ok(Event::Hello) => return Ok(()),
                    Ok(Event::WrongKey) => {
                        return Err(Error::Auth(
                            "the controller's key is not this key (HELLO_REPLY does not verify)"
                                .into(),
                        ));
                    }
                    Ok(Event::Ack(_, ack)) if ack.acked_tag == Tag::Hello as u8 => {
                        return Err(match ack.status {
                            StatusCode::BadState => Error::Auth(
                                "the controller has no key set (HELLO refused BAD_STATE); \
                                 set one with `armctl key set`"
                                    .into(),
                            ),
                            status => Error::Refused {
                                command: Tag::Hello,
                                status,
                                state: ack.state,
                            },
                        });
                    }
                    Ok(Event::Refused) if self.fails_fast_when_refused() => {
                        return Err(Error::ConnectionRefused { addr: self.addr });
                    }
                    Ok(_) => continue,
                    // The controller answers HELLO at most 10 times a second: copies
                    // back off as any command's do, so that some come after its budget
                    // refills (3 ms apart, all 10 fell in one spent budget).
                    Err(_) => {
                        lock(&self.rtt).back_off();
                        break;
                    }
                }
            }
        }
        Err(Error::NoReply {
            command: Tag::Hello,
            attempts: self.options.attempts,
            waited: started.elapsed(),
            to: self.addr,
        })
    }

    /// SET_KEY: stores `key` in the controller (`None`: clears it). The first key is
    /// accepted plain (from the owner); a key set already is changed or cleared only in a
    /// session of the current key (this client's `key`). The controller drops every
    /// session: this client forgets its own and, with `key` set, takes it as its key.
    pub fn set_key(&self, key: Option<protocol::auth::AuthKey>) -> Result<Ack> {
        let ack = self.send(&Command::SetKey(key))?;
        let mut auth = lock(&self.shared.auth);
        *auth = key.map(auth::HostAuth::new);
        Ok(ack)
    }

    /// Whether a key was given.
    pub fn keyed(&self) -> bool {
        lock(&self.shared.auth).is_some()
    }

    fn send_datagram(&self, frame: &[u8]) -> Result<()> {
        // Recorded before it leaves: the receiver thread may record the answer before
        // this thread returns from `send`, and a capture must keep the order on the wire.
        if let Some(pcap) = lock(&self.shared.pcap).as_ref() {
            let local = self.socket.local_addr()?;
            let _ = pcap.record(local, self.addr, frame);
        }
        match self.socket.send(frame) {
            Ok(_) => Ok(()),
            // A previous datagram's ICMP "port unreachable" (nobody listening): on
            // loopback that is final; elsewhere the controller may be booting, and the
            // retry loop sends the frame again.
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => {
                if self.fails_fast_when_refused() {
                    Err(Error::ConnectionRefused { addr: self.addr })
                } else {
                    Ok(())
                }
            }
            Err(e) => Err(e.into()),
        }
    }

    /// Whether a refused port ends a command at once: on loopback, an ICMP "port
    /// unreachable" means nothing listens on this machine, and waiting will not change it.
    pub(crate) fn fails_fast_when_refused(&self) -> bool {
        self.addr.ip().is_loopback()
    }

    /// The current wait for an ACK.
    pub(crate) fn rto(&self) -> Duration {
        lock(&self.rtt).rto()
    }

    /// Sends a command and returns its ACK whatever its status; resends the same bytes
    /// (same seq) until an ACK comes, at most `attempts` times.
    pub fn exchange(&self, command: &Command<'_>) -> Result<Ack> {
        if matches!(command, Command::Stopped) {
            // STOPPED never waits behind an upload.
            self.exchange_unlocked(command, None)
        } else {
            let _upload = lock(&self.upload);
            self.exchange_unlocked(command, None)
        }
    }

    /// As [`Client::exchange`] without taking the upload lock; with `cancel`, every wait
    /// for the ACK looks at it at least every [`CANCEL_POLL`] ([`Error::Interrupted`]).
    pub(crate) fn exchange_unlocked(
        &self,
        command: &Command<'_>,
        cancel: Option<&Cancel>,
    ) -> Result<Ack> {
        let mut buf = [0u8; MAX_DATAGRAM];
        let seq = self.alloc_seq();
        let len = command.encode(seq, &mut buf)?;
        let frame = &buf[..len];
        let tag = command.tag();
        let mut waiter = self.waiter();
        waiter.expect(seq);
        let started = Instant::now();
        let mut sent = 0;
        while sent < self.options.attempts {
            // Exactly once: a copy that came after the controller forgot the first could
            // be executed a second time.
            if sent > 0 && started.elapsed() >= RESEND_HORIZON {
                break;
            }
            let sealed_in = self.send_bytes(frame)?;
            sent += 1;
            let sent_at = Instant::now();
            let mut deadline = sent_at + self.rto();
            if sent == self.options.attempts {
                deadline = deadline.max(started + self.options.give_up_after);
            }
            loop {
                let left = deadline.saturating_duration_since(Instant::now());
                let slice = match cancel {
                    Some(cancel) if cancel.is_cancelled() => return Err(Error::Interrupted),
                    Some(_) => left.min(CANCEL_POLL),
                    None => left,
                };
                match waiter.rx.recv_timeout(slice) {
                    // The session is gone (the controller was reset, or gave the slot
                    // to another HELLO): its refusal names the envelope's tag, AUTH. Open
                    // another session, and resend in it. The inner frame is the same, so
                    // a copy that did arrive is a duplicate there.
                    Ok(Event::Ack(_, ack))
                        if ack.status == StatusCode::AuthFailed
                            && ack.acked_tag == Tag::Auth as u8 =>
                    {
                        self.session_lost(sealed_in);
                        break;
                    }
                    Ok(Event::Ack(_, ack)) if ack.acked_tag != tag as u8 => continue,
                    // A HELLO's answer: only `hello` waits for those.
                    Ok(Event::Hello | Event::WrongKey) => continue,
                    // Damaged on the way: send it again at once.
                    Ok(Event::Ack(_, ack)) if ack.status == StatusCode::BadCrc => break,
                    Ok(Event::Ack(_, ack)) => {
                        if sent == 1 {
                            // Karn's rule: only a frame sent once times the round trip.
                            lock(&self.rtt).sample(sent_at.elapsed());
                        }
                        return Ok(ack);
                    }
                    Ok(Event::Refused) if self.fails_fast_when_refused() => {
                        return Err(Error::ConnectionRefused { addr: self.addr });
                    }
                    Ok(Event::Refused) => continue,
                    // A slice of the wait, not the whole of it: look at `cancel` again.
                    Err(RecvTimeoutError::Timeout) if Instant::now() < deadline => continue,
                    Err(RecvTimeoutError::Timeout) => {
                        lock(&self.rtt).back_off();
                        break;
                    }
                    Err(RecvTimeoutError::Disconnected) => break,
                }
            }
        }
        Err(Error::NoReply {
            command: tag,
            attempts: sent,
            waited: started.elapsed(),
            to: self.addr,
        })
    }

    /// Sends a command and waits for its ACK: `Ok` when the controller did it, else
    /// [`Error::Refused`] with the status and what to do about it.
    pub fn send(&self, command: &Command<'_>) -> Result<Ack> {
        let ack = self.exchange(command)?;
        check(command.tag(), ack)
    }

    /// Asks for a STATUS report and waits for it (asking again with a new frame if the
    /// report is lost: a resent frame would be taken for a duplicate and not answered).
    pub fn status(&self) -> Result<StatusReport> {
        let _upload = lock(&self.upload);
        self.status_unlocked(None)
    }

    /// As [`Client::status`], every wait looking at `cancel` at least every
    /// [`CANCEL_POLL`].
    pub(crate) fn status_cancellable(&self, cancel: Option<&Cancel>) -> Result<StatusReport> {
        let _upload = lock(&self.upload);
        self.status_unlocked(cancel)
    }

    pub(crate) fn status_unlocked(&self, cancel: Option<&Cancel>) -> Result<StatusReport> {
        let reports = self.status_reports();
        for _ in 0..self.options.attempts {
            check(
                Tag::Status,
                self.exchange_unlocked(&Command::Status, cancel)?,
            )?;
            if let Ok(status) = recv_cancellable(&reports, self.options.report_timeout, cancel)? {
                return Ok(status);
            }
        }
        Err(Error::NoReport {
            command: Tag::Status,
            attempts: self.options.attempts,
        })
    }

    /// A new stream of every LOCATION report from now on (each call gets its own).
    pub fn locations(&self) -> Receiver<Location> {
        let (tx, rx) = mpsc::channel();
        lock(&self.shared.locations).push(tx);
        rx
    }

    /// A new stream of the bytes the controller's serial port receives (USART_RECV).
    pub fn serial_rx(&self) -> Receiver<Vec<u8>> {
        let (tx, rx) = mpsc::channel();
        lock(&self.shared.serial).push(tx);
        rx
    }

    /// A new stream of every STATUS report from now on.
    pub fn status_reports(&self) -> Receiver<StatusReport> {
        let (tx, rx) = mpsc::channel();
        lock(&self.shared.statuses).push(tx);
        rx
    }

    /// The most recent LOCATION report, if any came.
    pub fn last_location(&self) -> Option<Location> {
        *lock(&self.shared.last_location)
    }

    /// The most recent STATUS report, if any came.
    pub fn last_status(&self) -> Option<StatusReport> {
        *lock(&self.shared.last_status)
    }

    /// Datagrams received that were not valid reports (bad CRC, unknown tag...).
    pub fn undecodable_datagrams(&self) -> u64 {
        self.shared.undecodable.load(Ordering::Relaxed)
    }

    /// ACKs `AUTH_FAILED` received: envelopes refused because their session was gone (the
    /// controller was reset, or gave the session's slot away), each answered by a HELLO.
    pub fn auth_failures(&self) -> u64 {
        self.shared.auth_failed.load(Ordering::Relaxed)
    }

    /// STOPPED: stops every step pulse at once and drops the buffer. Never waits behind an
    /// upload. Resent as any command is (`Options::attempts`); to stop what a call started
    /// on Ctrl-C, [`Client::stop_until_acked`] resends at a fixed interval, bounded, and
    /// lets a second Ctrl-C end the wait.
    pub fn stop(&self) -> Result<Ack> {
        self.send(&Command::Stopped)
    }

    /// ESTOP_RESET: clears the latch of the controller's wired e-stop input once the input
    /// is closed again (refused with `ESTOP_LATCHED` while it is open; `OK` and no effect
    /// with nothing latched). Until then RUNING and RETURN are refused.
    pub fn estop_reset(&self) -> Result<Ack> {
        self.send(&Command::EstopReset)
    }

    /// UNLOCK (issue 33): clears the latch a limit switch set (RUNING and RETURN refused
    /// with `LIMIT_LATCHED` until then). While that switch is still active, points moving
    /// its joint further into it are refused with `LIMIT_LATCHED`; moving away is accepted.
    /// `OK` and no effect with nothing latched.
    pub fn unlock(&self) -> Result<Ack> {
        self.send(&Command::Unlock)
    }

    /// RETURN: moves every joint to zero. Returns when the controller accepted it; see
    /// [`Client::wait_stopped`] to wait for the end of the move.
    pub fn go_home(&self) -> Result<Ack> {
        self.send(&Command::Return)
    }

    /// JOINTS_COUNT: the number of joints, 1..8.
    pub fn set_joints(&self, joints: u8) -> Result<Ack> {
        self.send(&Command::JointsCount(joints))
    }

    /// LOCATION_SETTING: declares the current position of the joints in steps (the first
    /// `positions.len()` joints; the others keep theirs, read from a LOCATION report first,
    /// which needs reports on).
    pub fn set_location(&self, positions: &[i32]) -> Result<Ack> {
        if positions.len() > MAX_JOINTS {
            return Err(Error::InvalidTrajectory(format!(
                "{} positions given, the controller has {MAX_JOINTS} joints at most",
                positions.len()
            )));
        }
        let mut location = Location::default();
        if positions.len() < MAX_JOINTS {
            // The joints not given keep their positions (issue 23: they were zeroed), read
            // from a fresh LOCATION report.
            location.position = self
                .current_location(LOCATION_FOR_SET)
                .map_err(|_| {
                    Error::InvalidTrajectory(format!(
                        "{} positions given: the others would keep theirs, but no LOCATION \
                         report came in {:.1} s to tell them (reports off? UPLOAD_START, or \
                         give a position for every joint)",
                        positions.len(),
                        LOCATION_FOR_SET.as_secs_f64()
                    ))
                })?
                .position;
        }
        location.position[..positions.len()].copy_from_slice(positions);
        self.send(&Command::LocationSetting(location))
    }

    /// PIN0_ON/OFF or PIN1_ON/OFF.
    pub fn pin(&self, pin: u8, high: bool) -> Result<Ack> {
        let command = match (pin, high) {
            (0, true) => Command::Pin0On,
            (0, false) => Command::Pin0Off,
            (1, true) => Command::Pin1On,
            (1, false) => Command::Pin1Off,
            _ => {
                return Err(Error::Io(std::io::Error::new(
                    std::io::ErrorKind::InvalidInput,
                    format!("there is no GPIO pin {pin}: the controller has pins 0 and 1"),
                )));
            }
        };
        self.send(&command)
    }

    /// TOGGLE_ENABLE_PINS: toggles every driver's ENABLE (`None`) or the masked ones (bits
    /// 0-7 joints, bit 8 gripper).
    pub fn toggle_enable(&self, mask: Option<u16>) -> Result<Ack> {
        self.send(&Command::ToggleEnablePins { mask })
    }

    /// PWM_START: gripper PWM, servo (`pulse_count` 0) or stepper mode.
    pub fn pwm_start(&self, pwm: Pwm) -> Result<Ack> {
        self.send(&Command::PwmStart(pwm))
    }

    /// PWM_STOP: gripper PWM off at once.
    pub fn pwm_stop(&self) -> Result<Ack> {
        self.send(&Command::PwmStop)
    }

    /// USART_START: opens the pass-through serial port.
    pub fn serial_open(&self, init: UartInit) -> Result<Ack> {
        self.send(&Command::UsartStart(init))
    }

    /// USART_STOP: closes the pass-through serial port.
    pub fn serial_close(&self) -> Result<Ack> {
        self.send(&Command::UsartStop)
    }

    /// USART_SEND: writes bytes to the serial port, in chunks of 255 (one frame each, in
    /// order: each waits for the previous one's ACK).
    pub fn serial_send(&self, bytes: &[u8]) -> Result<()> {
        for chunk in bytes.chunks(MAX_SERIAL_CHUNK) {
            self.send(&Command::UsartSend(chunk))?;
        }
        Ok(())
    }

    /// UPLOAD_START / UPLOAD_STOP: location reports on or off.
    pub fn reports(&self, on: bool) -> Result<Ack> {
        self.send(if on {
            &Command::UploadStart
        } else {
            &Command::UploadStop
        })
    }

    /// UPLOAD_PERIOD: location report period in microseconds (1000..1000000).
    pub fn upload_period(&self, period_us: u32) -> Result<Ack> {
        self.send(&Command::UploadPeriod { period_us })
    }

    /// Routes LOCATION reports to this client: UPLOAD_PERIOD with the period in force
    /// (nothing else changes). The controller sends LOCATION to the endpoint that last
    /// started an upload or set reports (PROTOCOL.md, "The ordering rule and the reports
    /// follow endpoints"): a second tool on the same machine, or a fresh `armctl` after
    /// another, claims them this way. Uploads (NEW) and RETURN claim them by themselves.
    pub fn claim_locations(&self) -> Result<()> {
        let period_us = self.status()?.upload_period_us;
        self.upload_period(period_us).map(|_| ())
    }

    /// A fresh LOCATION report (one that arrives after this call), at most `timeout`
    /// from now, after claiming the reports for this client ([`Client::claim_locations`]).
    /// Location reports must be on (they are by default).
    pub fn current_location(&self, timeout: Duration) -> Result<Location> {
        let started = Instant::now();
        let locations = self.locations();
        self.claim_locations()?;
        locations
            .recv_timeout(timeout.saturating_sub(started.elapsed()))
            .map_err(|_| Error::NoLocation { waited: timeout })
    }

    /// Polls STATUS until the controller is STOPPED (a run or RETURN finished), at most
    /// `timeout`. Returns the last STATUS.
    pub fn wait_stopped(&self, timeout: Duration) -> Result<StatusReport> {
        self.wait_stopped_inner(timeout, None)
    }

    /// As [`Client::wait_stopped`], but returns [`Error::Interrupted`] within
    /// [`CANCEL_POLL`] of `cancel` being set (it sends nothing itself: stop what you
    /// started with [`Client::stop_until_acked`]).
    pub fn wait_stopped_cancellable(
        &self,
        timeout: Duration,
        cancel: &Cancel,
    ) -> Result<StatusReport> {
        self.wait_stopped_inner(timeout, Some(cancel))
    }

    fn wait_stopped_inner(
        &self,
        timeout: Duration,
        cancel: Option<&Cancel>,
    ) -> Result<StatusReport> {
        let deadline = Instant::now() + timeout;
        let locations = self.locations();
        loop {
            let status = self.status_cancellable(cancel)?;
            if status.state == State::Stopped || Instant::now() >= deadline {
                return Ok(status);
            }
            // A LOCATION report comes at once on a state change: wake up on it.
            let _ = recv_cancellable(&locations, Duration::from_millis(100), cancel)?;
        }
    }
}

/// The next value of `rx` within `timeout` (`Ok(Err(..))` if none came), looking at
/// `cancel` at least every [`CANCEL_POLL`]: [`Error::Interrupted`] once it is set.
pub(crate) fn recv_cancellable<T>(
    rx: &Receiver<T>,
    timeout: Duration,
    cancel: Option<&Cancel>,
) -> Result<std::result::Result<T, RecvTimeoutError>> {
    let Some(cancel) = cancel else {
        return Ok(rx.recv_timeout(timeout));
    };
    let deadline = Instant::now() + timeout;
    loop {
        if cancel.is_cancelled() {
            return Err(Error::Interrupted);
        }
        let left = deadline.saturating_duration_since(Instant::now());
        match rx.recv_timeout(left.min(CANCEL_POLL)) {
            Err(RecvTimeoutError::Timeout) if !left.is_zero() && Instant::now() < deadline => {}
            other => return Ok(other),
        }
    }
}

/// Turns a refused ACK into an error.
pub(crate) fn check(command: Tag, ack: Ack) -> Result<Ack> {
    if ack.status == StatusCode::Ok {
        Ok(ack)
    } else {
        Err(Error::Refused {
            command,
            status: ack.status,
            state: ack.state,
        })
    }
}

impl Drop for Client {
    fn drop(&mut self) {
        self.shared.shutdown.store(true, Ordering::Relaxed);
        if let Some(receiver) = self.receiver.take() {
            let _ = receiver.join();
        }
    }
}

//! Putting the simulated controller together: the hardware, the step thread, the executor
//! and the firmware's tasks.

use std::io;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use arm_core::config::ServoOnStop;
use arm_core::hw::Clock;
use arm_core::ingress::{HaltSteps, StepHalt};
use arm_core::profile::{self, BoardProfile};
use arm_core::switch_line::SwitchLine;
use arm_core::{Bus, StepShared, TrajectoryHw};
use arm_core::{Controller, ControllerConfig};
use arm_step::StepTiming;
use embassy_executor::{Executor, Spawner};
use signal_hook::consts::{SIGINT, SIGTERM};
use signal_hook::iterator::Signals;
use static_cell::StaticCell;

use crate::clock::SimClock;
use crate::devices::{FileSettings, OutputLevels, SimEncoders, SimGripper, SimOutputs};
use crate::estop::SimEStopInput;
use crate::net::{Faulty, UdpDatagrams};
use crate::options::SimOptions;
use crate::probe::Probe;
use crate::serial::SimSerial;
use crate::simnet::open_capture;
pub use crate::simnet::{SimNet, SimNetError};
use crate::steppers::{MotorState, SimSteppers};
use crate::steptimer::{SimStepKick, SimSteps};
use crate::tap::TapAddress;
use crate::vcd::Tracer;

/// The simulated board: everything the firmware's tasks drive, and what observes it.
#[derive(Clone, Debug)]
pub struct Board {
    /// The options it was built from.
    pub options: SimOptions,
    /// Simulated time.
    pub clock: SimClock,
    /// The VCD trace (disabled without `--trace`).
    pub tracer: Tracer,
    /// The motors the STEP/DIR lines move.
    pub motors: Arc<MotorState>,
    /// PIN0/PIN1 and ENABLE levels.
    pub levels: Arc<OutputLevels>,
    /// The gripper timer.
    pub gripper: SimGripper,
    /// The serial port.
    pub serial: &'static SimSerial,
    /// The absolute encoders.
    pub encoders: SimEncoders,
    /// The settings file.
    pub settings: FileSettings,
    /// Wakes the step thread.
    pub kick: SimStepKick,
    /// Measurements for the benchmark.
    pub probe: Arc<Probe>,
    /// The host UDP socket (`None` with `--tap`, whose socket opens on the executor).
    pub udp: Option<&'static UdpDatagrams>,
    /// The wired e-stop input (`--estop-input`): open and close it here in-process, or
    /// with SIGUSR1/SIGUSR2 from outside ([`crate::estop`]).
    pub estop_input: Option<Arc<SimEStopInput>>,
    /// The safety-door input (`--door-input`, issue 32): open and close it here
    /// in-process, or with SIGRTMIN+1/SIGRTMIN+2 from outside ([`crate::door`]).
    pub door_input: Option<Arc<crate::door::SimDoorInput>>,
}

impl Board {
    /// Builds the simulated hardware; binds the UDP socket unless `--tap` is given.
    pub fn build(options: &SimOptions) -> io::Result<Board> {
        Board::build_on(
            options,
            SimClock::new(options.time_scale, options.tick_hz),
            true,
        )
    }

    /// Builds the simulated hardware on `clock` (a virtual one for
    /// [`crate::virtual_board`]), with the UDP socket only if `network` (and no `--tap`).
    pub fn build_on(options: &SimOptions, clock: SimClock, network: bool) -> io::Result<Board> {
        let tracer = match &options.trace {
            Some(path) => {
                let tracer = Tracer::create(path, clock)?;
                log::info!("trace: writing {}", path.display());
                tracer
            }
            None => Tracer::disabled(),
        };
        let motors = Arc::new(MotorState::default());
        let probe = Arc::new(Probe::new(clock, tracer.clone()));
        let serial = SimSerial::create(options.serial, clock)?;
        if let Some(path) = serial.pty_path() {
            println!("sim-host: serial pty {path}");
            log::info!("serial: attach a terminal with `picocom -b 115200 {path}`");
        }
        let udp = match &options.tap {
            Some(_) => None,
            None if !network => None,
            None => Some(UdpDatagrams::bind(options.bind)?),
        };
        if let Some(path) = &options.pcap {
            let local = match (udp.and_then(|u| u.local_addr().ok()), &options.ip) {
                (Some(SocketAddr::V4(bound)), _) => bound,
                // On TAP: the static --ip, or 0.0.0.0 until DHCP has spoken.
                (_, Some(ip)) => match TapAddress::parse(ip) {
                    Ok(TapAddress::Static(ip, _)) => {
                        std::net::SocketAddrV4::new(ip, protocol::PORT)
                    }
                    _ => {
                        std::net::SocketAddrV4::new(std::net::Ipv4Addr::UNSPECIFIED, protocol::PORT)
                    }
                },
                _ => std::net::SocketAddrV4::new(std::net::Ipv4Addr::UNSPECIFIED, protocol::PORT),
            };
            open_capture(path, local)?;
        }
        let kick = SimStepKick::new(clock);
        let gripper = SimGripper::new(clock, tracer.clone());
        let estop_input = options.estop_input.then(|| {
            Arc::new(SimEStopInput::new(
                kick.clone(),
                tracer.clone(),
                gripper.clone(),
                options.servo_on_stop.into(),
            ))
        });
        let door_input = options
            .door_input
            .then(|| Arc::new(crate::door::SimDoorInput::new(tracer.clone())));
        Ok(Board {
            options: options.clone(),
            clock,
            tracer: tracer.clone(),
            motors: motors.clone(),
            levels: Arc::new(OutputLevels::default()),
            gripper,
            serial,
            encoders: SimEncoders::new(
                motors,
                options.encoder_offset_array(),
                !options.no_encoders,
            )
            .with_bus(clock, options.encoder_fault_array()),
            settings: {
                let mut settings = FileSettings::new(options.settings_path());
                settings.set_clear_key(options.clear_key);
                settings
            },
            kick,
            probe,
            udp,
            estop_input,
            door_input,
        })
    }

    /// The address the UDP socket is bound to.
    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.udp.and_then(|u| u.local_addr().ok())
    }

    /// New STEP/DIR pins on this board's motors.
    pub fn step_pins(&self) -> SimSteppers {
        SimSteppers::new(self.motors.clone(), self.tracer.clone(), self.clock)
    }

    /// New output pins.
    pub fn outputs(&self) -> SimOutputs {
        SimOutputs::new(self.levels.clone(), self.tracer.clone())
    }

    /// Logs a summary of what the board did (at exit).
    pub fn log_summary(&self) {
        let positions = self.motors.positions();
        let pulses = self.motors.pulse_counts();
        log::info!("motors: positions {positions:?}, pulses {pulses:?}");
        let serial = self.serial.counters();
        log::info!(
            "serial: {} bytes written, {} received, {} dropped on receive, {} ACKed for sending \
             and dropped by USART_STOP",
            serial.written.load(Ordering::Relaxed),
            serial.received.load(Ordering::Relaxed),
            serial.dropped.load(Ordering::Relaxed),
            BUS.serial_tx_dropped()
        );
        let dir_while_high = self.motors.dir_while_high.load(Ordering::Relaxed);
        if dir_while_high > 0 {
            log::warn!("motors: {dir_while_high} DIR changes while STEP was high");
        }
    }

    /// Flushes the trace and logs the summary: the orderly end of a run.
    pub fn shut_down(&self) {
        static DONE: AtomicBool = AtomicBool::new(false);
        if DONE.swap(true, Ordering::SeqCst) {
            return;
        }
        self.log_summary();
        self.tracer.finish();
        if let Some(path) = &self.options.trace {
            log::info!("trace: {} written", path.display());
        }
    }
}

/// On SIGINT or SIGTERM: shut the board down in order (trace flushed) and exit 0.
pub fn exit_on_signal(board: Board) -> io::Result<()> {
    // signal-hook's handler only writes to a pipe; the thread below does the work.
    let mut signals = Signals::new([SIGINT, SIGTERM])?;
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            if let Some(signal) = signals.forever().next() {
                log::info!("signal {signal}: shutting down");
            }
            board.shut_down();
            std::process::exit(0);
        })?;
    Ok(())
}

/// Initialises logging at `level` (an env_logger filter); RUST_LOG wins when set, and
/// `ARMCTL_TRACE` shows the armctl client's upload traces (demo, bench).
pub fn init_logging(level: &str) {
    let _ = armctl::logger(level).format_timestamp_micros().try_init();
}

// ---------------------------------------------------------------------------------------
// The firmware's tasks on the std executor.

/// The simulator's profile (arm-core's `profile`): by default it is the NUCLEO-H743ZI2,
/// with the same limits and figures; `--tick-hz` and `--buffer-capacity` deviate from it
/// explicitly.
pub const PROFILE: BoardProfile = profile::SIMULATOR;

/// Trajectory points the simulator can buffer: the board's size, so that a host sees the
/// same flow control; `--buffer-capacity` uses less of it.
pub const TRAJECTORY_STORAGE: usize = PROFILE.trajectory_capacity;

/// Segments the step engine holds (the "interrupt side" queue): the simulator profile's
/// lookahead in time (100 ms: a desktop scheduler delays threads by tens of ms).
pub const STEP_QUEUE: usize = arm_core::profile::SIMULATOR.step_queue();

/// The controller as the simulator builds it.
pub type SimController = Controller<TRAJECTORY_STORAGE>;
/// The step engine shared with the step thread.
pub type SimStepShared = StepShared<STEP_QUEUE, SimSteps<STEP_QUEUE>>;

/// The step timing for a step timer at `tick_hz`: the profile's drivers (the NUCLEO's
/// opto-isolated ones, its DIR latency included), each time rounded up to whole ticks.
pub fn step_timing(tick_hz: u32) -> StepTiming {
    PROFILE.step_timing_at(tick_hz)
}

/// The controller configuration for these options: the profile's, with the step rate its
/// step timer allows (the profile's unless `--tick-hz` is too coarse for the drivers'
/// times) and `--buffer-capacity`.
pub fn controller_config(options: &SimOptions) -> ControllerConfig {
    let timing = step_timing(options.tick_hz);
    let capacity = options
        .buffer_capacity
        .unwrap_or(TRAJECTORY_STORAGE)
        .clamp(1, TRAJECTORY_STORAGE);
    let config = PROFILE.controller_config();
    ControllerConfig {
        max_step_rate_hz: config.max_step_rate_hz.min(timing.max_step_rate_hz()),
        capacity,
        servo_on_stop: options.servo_on_stop.into(),
        ..config
    }
}

/// The socket as the network task sees it: behind the fault injector.
pub type SimSocket = Faulty<SimNet>;

type SimTrajectoryHw = TrajectoryHw<
    'static,
    SimStepKick,
    SimOutputs,
    SimGripper,
    SimSerial,
    FileSettings,
    SimEncoders,
>;

#[embassy_executor::task]
async fn network(socket: &'static SimSocket, bus: &'static Bus, clock: &'static SimClock) -> ! {
    arm_core::tasks::network_task(socket, bus, clock).await
}

/// The halt for the first look at each datagram ([`arm_core::ingress`]): the step
/// outputs', then a gripper burst's (and a servo's under `--servo-on-stop cut`), as the
/// board's receive path cuts them (issue 30).
pub struct SimHalt {
    /// The steps.
    pub steps: HaltSteps<'static, STEP_QUEUE, SimSteps<STEP_QUEUE>, SimStepKick>,
    /// The gripper timer.
    pub gripper: SimGripper,
    /// Whether a servo PWM is cut too.
    pub servo_on_stop: ServoOnStop,
}

impl StepHalt for SimHalt {
    fn halt(&self) {
        self.steps.halt();
        self.gripper.cut_at_stop(self.servo_on_stop);
    }
}

#[embassy_executor::task]
#[allow(clippy::too_many_arguments)]
async fn network_over_tap(
    spawner: Spawner,
    iface: String,
    address: TapAddress,
    faults: crate::faults::FaultConfig,
    bus: &'static Bus,
    clock: &'static SimClock,
    halt: SimHalt,
) {
    let seed = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0x5EED);
    let mac = sim_mac(Some(&iface), protocol::PORT);
    match crate::tap::start(spawner, &iface, address, mac, seed, (bus, halt, clock)).await {
        Ok(tap) => {
            let socket: &'static SimSocket =
                Box::leak(Box::new(Faulty::new(SimNet::Tap(tap), faults)));
            println!("sim-host: listening on {iface} udp port {}", protocol::PORT);
            arm_core::tasks::network_task(socket, bus, clock).await
        }
        Err(e) => {
            log::error!("tap: {e}");
            std::process::exit(2);
        }
    }
}

/// The controller's tasks (trajectory, upload, serial): arm-core's `controller_task`, as
/// the boards run it (arm-wiring's `controller_tasks!`).
#[embassy_executor::task]
async fn controller(
    controller: &'static mut SimController,
    bus: &'static Bus,
    step: &'static SimStepShared,
    clock: &'static SimClock,
    hw: SimTrajectoryHw,
) -> ! {
    arm_core::controller_task(controller, bus, step, clock, hw, &arm_core::Unwatched).await
}

static BUS: Bus = Bus::new();

/// Datagrams the simulated controller's receive path shed so far: over their sender's
/// share ([`arm_core::ingress`]).
pub fn receive_shed() -> u32 {
    BUS.shed()
}
static STEP: StaticCell<SimStepShared> = StaticCell::new();
static CONTROLLER: StaticCell<SimController> = StaticCell::new();

/// Everything the executor needs, made once per process.
struct Wiring {
    board: Board,
    step: &'static SimStepShared,
    controller: &'static mut SimController,
    /// The switch inputs, with `--home-switch`/`--limit-switch` (issue 33).
    switches: Option<&'static SwitchLine>,
}

fn wire(board: Board) -> io::Result<Wiring> {
    let once = || io::Error::other("the simulated controller runs once per process");
    let config = controller_config(&board.options);
    let timing = step_timing(board.options.tick_hz);
    let model = board.options.switch_model();
    // The switch path the board's EXTI handler feeds, fed by the step thread (issue 33).
    let switches: Option<&'static SwitchLine> = model
        .any()
        .then(|| &*Box::leak(Box::new(SwitchLine::new(model.config()))));
    let mut backend =
        SimSteps::new(timing, board.step_pins(), board.clock).with_probe(board.probe.clone());
    if let Some(line) = switches {
        backend = backend.with_switches(model, line);
    }
    let step: &'static SimStepShared = STEP
        .try_init(StepShared::with_backend(backend))
        .ok_or_else(once)?;
    let controller = CONTROLLER
        .try_init(Controller::new(config))
        .ok_or_else(once)?;
    if let Some(input) = &board.estop_input {
        input.wire(step, &BUS.step_progress);
    }
    if let Some(door) = &board.door_input {
        door.wire(&BUS.step_progress);
    }
    // DIAG: the simulator's own figures (issue 34), not the board's.
    crate::sim_diag::set_step_hz(timing.tick_hz);
    BUS.set_diag_source(crate::sim_diag::report);
    let port = board.local_addr().map_or(protocol::PORT, |a| a.port());
    controller.set_mac(sim_mac(board.options.tap.as_deref(), port));
    // The board draws these from its RNG: the epochs of keys set (issue 30).
    controller.set_entropy(os_random_u64());
    log::info!(
        "controller: {} trajectory points, step timer {} Hz (pulse {} ticks, DIR setup {} ticks), max {} steps/s per joint, time scale {}",
        config.capacity,
        timing.tick_hz,
        timing.pulse_width_ticks,
        timing.dir_setup_ticks,
        config.max_step_rate_hz,
        board.clock.time_scale()
    );

    // The step timers and DMA streams, played in simulated time.
    let kick = board.kick.clone();
    let clock = board.clock;
    let tracer = board.tracer.clone();
    crate::steptimer::spawn_step_thread(
        &board.kick,
        board.probe.clone(),
        crate::steptimer::StepThreadConfig {
            realtime: board.options.realtime,
        },
        move |now| {
            let (played, edges) = step.on_interrupt(&BUS.step_progress, |steps| {
                // The span the step lock is held (a critical section; issue 34's DIAG).
                let holding = std::time::Instant::now();
                let progress = steps.advance(now);
                let played = crate::steptimer::Played {
                    running: steps.is_running(),
                    due: steps.next_due(),
                    ended: progress.ran_dry,
                };
                let edges = steps.take_switch_edges();
                crate::sim_diag::played(holding.elapsed());
                ((played, edges), progress)
            });
            // The switch edges the played steps made, as the board's EXTI handler sees
            // them: outside the backend's lock (a limit's halt takes it).
            if let Some(line) = switches {
                for e in edges {
                    let at_us = clock.tick_to_ns(e.tick) / 1_000;
                    line.edge(
                        e.joint,
                        e.switch,
                        e.level,
                        e.count,
                        at_us,
                        step,
                        &kick,
                        &BUS.step_progress,
                    );
                }
            }
            // Every change up to `now` is recorded (a switch's halt too): the trace may
            // be written up to there.
            tracer.steps_played_to(clock.tick_to_ns(now));
            played
        },
    )?;
    Ok(Wiring {
        board,
        step,
        controller,
        switches,
    })
}

fn spawn_tasks(spawner: Spawner, wiring: Wiring) {
    let Wiring {
        board,
        step: shared,
        controller,
        switches,
    } = wiring;
    let bus: &'static Bus = &BUS;
    let clock: &'static SimClock = Box::leak(Box::new(board.clock));
    let kick: &'static SimStepKick = Box::leak(Box::new(board.kick.clone()));
    let options = &board.options;
    let faults = options.faults();
    if faults.is_active() {
        log::info!(
            "faults: loss {}, duplication {}, reordering {} (seed {})",
            faults.loss,
            faults.dup,
            faults.reorder,
            faults.seed
        );
    }

    let mut settings = board.settings.clone();
    settings.set_boot_joints(options.joints);
    let hw = TrajectoryHw {
        kick,
        outputs: board.outputs(),
        gripper: board.gripper.clone(),
        serial: board.serial,
        settings,
        encoders: board.encoders.clone(),
        estop: board
            .estop_input
            .as_ref()
            .map(|_| -> &'static arm_core::EStopLine { &crate::estop::LINE }),
        // `--door-input` (in-process on virtual time: VirtualBoard::set_door).
        door: board
            .door_input
            .as_ref()
            .map(|_| -> &'static arm_core::DoorLine { &crate::door::LINE }),
        switches,
    };
    let sim_halt = || SimHalt {
        steps: HaltSteps { step: shared, kick },
        gripper: board.gripper.clone(),
        servo_on_stop: options.servo_on_stop.into(),
    };
    let spawned = [
        match (&options.tap, board.udp) {
            (Some(iface), _) => {
                let address = options
                    .ip
                    .as_deref()
                    .map(TapAddress::parse)
                    .transpose()
                    .unwrap_or_else(|e| {
                        log::error!("--ip: {e}");
                        std::process::exit(2)
                    });
                let address = address.unwrap_or_else(|| stored_address(&board));
                let halt = sim_halt();
                network_over_tap(spawner, iface.clone(), address, faults, bus, clock, halt)
                    .map(|t| spawner.spawn(t))
            }
            (None, Some(udp)) => {
                // The socket reader's first look (issue 18): a STOPPED halts the steps in
                // the reader thread itself, before any queue.
                let halt = sim_halt();
                let first_look: crate::net::FirstLook = Box::new(move |from, bytes, to_group| {
                    bus.receive_first(from, bytes, to_group, clock.now_us(), &halt)
                });
                if let Err(e) = udp.start(board.probe.clone(), bus, first_look) {
                    log::error!("cannot start the socket reader: {e}");
                    std::process::exit(2);
                }
                let socket: &'static SimSocket =
                    Box::leak(Box::new(Faulty::new(SimNet::Udp(udp), faults)));
                network(socket, bus, clock).map(|t| spawner.spawn(t))
            }
            (None, None) => {
                log::error!("no network: neither a socket nor --tap");
                std::process::exit(2);
            }
        },
        self::controller(controller, bus, shared, clock, hw).map(|t| spawner.spawn(t)),
    ];
    for result in spawned {
        if let Err(e) = result {
            log::error!("cannot spawn a task: {e:?}");
            std::process::exit(2);
        }
    }
    log::info!("controller: tasks running");
}

/// The persisted address, for `--tap` without `--ip` (as the board boots): the static
/// address, or DHCP when NET_SET chose it.
fn stored_address(board: &Board) -> TapAddress {
    let stored = board.settings.read().ok().flatten().unwrap_or_default();
    if stored.dhcp {
        TapAddress::Dhcp
    } else {
        TapAddress::Static(stored.ip.into(), stored.prefix_len)
    }
}

/// The simulated controller's MAC address (DISCOVER_REPLY, and the TAP interface's):
/// locally administered `02:53:49:4d` ("SIM") and two bytes from the TAP device's name or
/// else the UDP port, so that simulators side by side differ.
pub fn sim_mac(tap: Option<&str>, port: u16) -> [u8; 6] {
    let tail = match tap {
        // FNV-1a of the name, folded to 16 bits.
        Some(iface) => {
            let hash = iface.bytes().fold(0x811c_9dc5u32, |h, b| {
                (h ^ u32::from(b)).wrapping_mul(0x0100_0193)
            });
            ((hash >> 16) ^ hash) as u16
        }
        None => port,
    };
    let [hi, lo] = tail.to_be_bytes();
    [0x02, 0x53, 0x49, 0x4d, hi, lo]
}

/// Runs the controller on this thread until SIGINT/SIGTERM.
pub fn run(options: &SimOptions) -> io::Result<()> {
    let board = Board::build(options)?;
    // SIGUSR1/SIGUSR2 open and close the e-stop input: caught before the address is
    // printed, so that a test may signal as soon as it knows where the simulator is.
    let estop_signals = match &board.estop_input {
        Some(input) => Some((crate::estop::Signals::catch()?, input.clone())),
        None => None,
    };
    // Likewise SIGRTMIN+1/SIGRTMIN+2 for the door.
    let door_signals = match &board.door_input {
        Some(door) => Some((crate::door::Signals::catch()?, door.clone())),
        None => None,
    };
    if let Some(addr) = board.local_addr() {
        // The first line on stdout: scripts and tests read the port from it.
        println!("sim-host: listening on udp {addr}");
        log::info!("listening on udp {addr}");
    }
    log::info!("settings file: {}", board.settings.path().display());
    if options.ip.is_some() && options.tap.is_none() {
        log::warn!("--ip applies to --tap only: ignored");
    }
    exit_on_signal(board.clone())?;
    let wiring = wire(board)?;
    if let Some((signals, input)) = estop_signals {
        signals.apply_to(input)?;
        log::info!("e-stop input: closed; SIGUSR1 opens it, SIGUSR2 closes it");
    }
    if let Some((signals, door)) = door_signals {
        signals.apply_to(door)?;
        log::info!("door input: closed; SIGRTMIN+1 opens it, SIGRTMIN+2 closes it");
    }
    // The executor lives as long as the process: run() never returns.
    crate::steptimer::raise_nice("executor", crate::steptimer::EXECUTOR_NICE);
    let executor: &'static mut Executor = Box::leak(Box::new(Executor::new()));
    executor.run(move |spawner| spawn_tasks(spawner, wiring))
}

/// Starts the controller for an in-process client (`demo`, `bench`): on a loopback port of
/// its own (so a controller already on 8510 does not matter), with a throwaway settings
/// file unless one was given, and Ctrl-C handled (the trace is still flushed). Returns the
/// board, its UDP address and the scratch directory to remove after `shut_down`.
pub fn start_for_client(
    options: &SimOptions,
    purpose: &str,
) -> io::Result<(Board, SocketAddr, std::path::PathBuf)> {
    let mut options = options.clone();
    options.bind.set_port(0);
    let scratch = std::env::temp_dir().join(format!("sim-host-{purpose}-{}", std::process::id()));
    if options.settings.is_none() {
        options.settings = Some(scratch.join("settings.txt"));
    }
    let board = start_in_background(&options)?;
    let addr = board
        .local_addr()
        .ok_or_else(|| io::Error::other(format!("the {purpose} needs a UDP socket, not --tap")))?;
    exit_on_signal(board.clone())?;
    Ok((board, addr, scratch))
}

/// Starts the controller on a background thread (for `demo` and `bench`); returns once
/// its socket is bound, with the board to observe it.
pub fn start_in_background(options: &SimOptions) -> io::Result<Board> {
    let board = Board::build(options)?;
    let observed = board.clone();
    let wiring = wire(board)?;
    std::thread::Builder::new()
        .name("executor".into())
        .spawn(move || {
            crate::steptimer::raise_nice("executor", crate::steptimer::EXECUTOR_NICE);
            let executor: &'static mut Executor = Box::leak(Box::new(Executor::new()));
            executor.run(move |spawner| spawn_tasks(spawner, wiring))
        })?;
    Ok(observed)
}

/// 64 random bits from the OS (its RNG: /dev/urandom), as the board's RNG gives them; the
/// time and process id if that cannot be read (not random, but never the same twice on one
/// machine).
fn os_random_u64() -> u64 {
    use std::io::Read;
    let mut bytes = [0u8; 8];
    match std::fs::File::open("/dev/urandom").and_then(|mut f| f.read_exact(&mut bytes)) {
        Ok(()) => u64::from_le_bytes(bytes),
        Err(e) => {
            log::warn!("no OS random bits ({e}): key epochs start from the time");
            let nanos = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos() as u64);
            nanos ^ (u64::from(std::process::id()) << 40)
        }
    }
}

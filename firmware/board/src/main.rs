//! The arm controller firmware for the NUCLEO-H743ZI2 (STM32H743ZI, Cortex-M7 at 400 MHz).
//!
//! The controller speaks the UDP protocol of `docs/PROTOCOL.md` on port 8510 over the
//! board's Ethernet (LAN8742A PHY, RMII), at the persisted static address (192.168.1.30/24
//! by default) or from DHCP with the `dhcp` feature. Its behaviour is arm-core's: this
//! crate implements arm-core's hardware traits with embassy-stm32 drivers and runs
//! arm-core's tasks.
//!
//! # Design
//!
//! Work is split by how late it may be, and each level has its own interrupt priority:
//!
//! | priority | what | why |
//! |---|---|---|
//! | P0 (highest) | TIM13: step clock ([`step_timer`]): DIR changes at reversals, end of run | a DIR change must come between a pulse's fall and the next pulse's setup |
//! | P1 | DMA2 streams 0-7: STEP buffer refills ([`step_dma`]); TIM15: gripper burst reloads ([`gripper`]) | a half (64 periods) of slack; 128 PWM periods |
//! | P2 | TIM12: embassy-time | task wake-ups |
//! | P3 | Ethernet, USART6, DMA, flash, RNG | driver bookkeeping; their tasks wait anyway |
//! | thread mode | every task, one executor | see below |
//!
//! The tasks (arm-core's, each wrapped below in an `#[embassy_executor::task]`):
//! - `net_task`: the embassy-net stack's runner.
//! - `network`: receives datagrams and routes them: a CRC-valid STOPPED goes to its own
//!   queue, which the trajectory task drains first; sends ACKs and reports.
//! - `trajectory`: owns the [`Controller`]: handles frames, drives pins, gripper and
//!   serial port, cuts segments for the step engine.
//! - `stepper`: moves segments into the step producer shared with the DMA refills and
//!   relays their progress.
//! - `upload`: LOCATION reports every upload period.
//! - `serial`: the USART pass-through.
//!
//! One thread-mode executor is enough: no task computes for long (a PENDING frame of 12
//! points is decoded and checked in microseconds), the e-stop has its own queue, and
//! everything with a deadline below a millisecond is an interrupt. STEP pulses are made by
//! timer hardware fed by DMA ([`step_dma`]); an emergency stop forces every STEP output
//! low and stops the timers and streams inside the critical section that handles it.
//!
//! Network input can never panic or block: arm-core decodes it with the `protocol` crate
//! and answers every error with an ACK status; queues that are full drop rather than wait.
//!
//! # Memory
//! Every task, driver and buffer is a `static` (`StaticCell`), initialised once in `main`;
//! there is no heap. The trajectory buffer (8192 points, 288 KiB) and the network buffers
//! are in AXI SRAM, the stack in DTCM (see `memory.x`).

#![no_std]
#![no_main]

mod board_hw;
mod clocks;
mod gripper;
mod net;
mod pins;
mod serial;
mod settings;
mod step_dma;
mod step_timer;

use arm_core::config::{BOARD_TRAJECTORY_CAPACITY, ControllerConfig};
use arm_core::hw::{Gripper, PersistentSettings};
use arm_core::{Bus, Controller, TrajectoryHw};
use defmt::{info, warn};
use embassy_executor::Spawner;
use embassy_net::Stack;
use embassy_net::udp::{PacketMetadata, UdpSocket};
use embassy_stm32::flash::Flash;
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::rng::Rng;
use embassy_stm32::usart::Uart;
use embassy_stm32::{Peri, bind_interrupts, dma, eth, flash, interrupt, peripherals, rng, usart};
use protocol::{MAX_DATAGRAM, PORT};
use static_cell::{ConstStaticCell, StaticCell};
use {defmt_rtt as _, panic_probe as _};

use crate::board_hw::{BoardClock, BoardSocket, NoEncoders};
use crate::gripper::GripperPwm;
use crate::pins::{DirPins, OutputLines, OutputPins, StepPins};
use crate::serial::{BoardSerial, RX_RING_BYTES};
use crate::settings::FlashSettings;
use crate::step_dma::STEP;
use crate::step_timer::StepTimer;

bind_interrupts!(
    /// Interrupt handlers of the embassy drivers.
    pub struct Irqs {
        ETH => eth::InterruptHandler;
        RNG => rng::InterruptHandler<peripherals::RNG>;
        FLASH => flash::InterruptHandler;
        USART6 => usart::InterruptHandler<peripherals::USART6>;
        DMA1_STREAM0 => dma::InterruptHandler<peripherals::DMA1_CH0>;
        DMA1_STREAM1 => dma::InterruptHandler<peripherals::DMA1_CH1>;
    }
);

/// Joints the board has STEP/DIR/ENABLE lines for.
pub const MAX_JOINTS: usize = protocol::MAX_JOINTS;

/// Trajectory points buffered (arm-core's board figure: 80 s of 10 ms points).
const CAP: usize = BOARD_TRAJECTORY_CAPACITY;

/// The controller as this board instantiates it.
type BoardController = Controller<CAP>;

/// The hardware the trajectory task drives.
type BoardTrajectoryHw = TrajectoryHw<
    'static,
    StepTimer,
    OutputLines,
    GripperPwm,
    BoardSerial,
    FlashSettings,
    NoEncoders,
>;

/// The channels between the tasks (and the step interrupt).
pub static BUS: Bus = Bus::new();
/// Time for the tasks.
static CLOCK: BoardClock = BoardClock;

static CONTROLLER: StaticCell<BoardController> = StaticCell::new();
static KICK: StaticCell<StepTimer> = StaticCell::new();
/// TIM13 (the step clock) as embassy's low-level timer: keeps its clock on and tells the
/// timer clock frequency.
static STEP_CLOCK: StaticCell<embassy_stm32::timer::low_level::Timer<'static, peripherals::TIM13>> =
    StaticCell::new();
static SERIAL: StaticCell<BoardSerial> = StaticCell::new();
static SOCKET: StaticCell<BoardSocket> = StaticCell::new();
static RX_RING: ConstStaticCell<[u8; RX_RING_BYTES]> = ConstStaticCell::new([0; RX_RING_BYTES]);

/// Datagrams the socket queues in each direction.
const UDP_PACKETS: usize = 8;
/// Receive buffer: a host keeps a window of PENDING frames (up to 1395 bytes each; armctl
/// sends 4) in flight; four full-size datagrams cover it while the stack waits for the
/// network task.
const UDP_RX_BYTES: usize = 4 * MAX_DATAGRAM;
/// Transmit buffer: arm-core's outbox holds 16 frames of at most 260 bytes (USART_RECV);
/// 4 KiB takes a whole outbox burst.
const UDP_TX_BYTES: usize = 4096;

/// The UDP socket's buffers: zeroed statics (`.bss`), taken once by [`bind_socket`].
static UDP_RX_META: ConstStaticCell<[PacketMetadata; UDP_PACKETS]> =
    ConstStaticCell::new([PacketMetadata::EMPTY; UDP_PACKETS]);
static UDP_RX: ConstStaticCell<[u8; UDP_RX_BYTES]> = ConstStaticCell::new([0; UDP_RX_BYTES]);
static UDP_TX_META: ConstStaticCell<[PacketMetadata; UDP_PACKETS]> =
    ConstStaticCell::new([PacketMetadata::EMPTY; UDP_PACKETS]);
static UDP_TX: ConstStaticCell<[u8; UDP_TX_BYTES]> = ConstStaticCell::new([0; UDP_TX_BYTES]);

#[embassy_executor::task]
async fn net_task(mut runner: net::Runner) -> ! {
    runner.run().await
}

#[embassy_executor::task]
async fn network(socket: &'static BoardSocket) -> ! {
    arm_core::network_task(socket, &BUS).await
}

#[embassy_executor::task]
async fn trajectory(controller: &'static mut BoardController, hw: BoardTrajectoryHw) -> ! {
    arm_core::trajectory_task(controller, &BUS, &STEP, &CLOCK, hw).await
}

#[embassy_executor::task]
async fn stepper(kick: &'static StepTimer) -> ! {
    arm_core::step_task(&BUS, &STEP, kick).await
}

#[embassy_executor::task]
async fn upload() -> ! {
    arm_core::upload_task(&BUS, &STEP, &CLOCK).await
}

#[embassy_executor::task]
async fn serial(port: &'static BoardSerial) -> ! {
    arm_core::serial_task(port, &BUS, &CLOCK).await
}

/// Lowers every driver interrupt below the step and gripper timers (the drivers enable
/// them at P0, the reset value).
fn set_driver_priorities() {
    interrupt::TIM8_BRK_TIM12.set_priority(Priority::P2);
    for irq in [
        interrupt::ETH,
        interrupt::USART6,
        interrupt::DMA1_STREAM0,
        interrupt::DMA1_STREAM1,
        interrupt::FLASH,
        interrupt::RNG,
    ] {
        irq.set_priority(Priority::P3);
    }
}

#[embassy_executor::main]
async fn main(spawner: Spawner) -> ! {
    let mut config = clocks::config();
    config.dma_interrupt_priority = Priority::P3;
    config.bdma_interrupt_priority = Priority::P3;
    config.mdma_interrupt_priority = Priority::P3;
    let p = embassy_stm32::init(config);
    info!("arm controller starting");
    // The instruction cache makes interrupt entry and the step engine's code fast and
    // steady despite the flash wait states. The data cache stays off: the
    // Ethernet and USART DMA buffers are not cache-maintained.
    match cortex_m::Peripherals::take() {
        Some(mut core) => core.SCB.enable_icache(),
        None => warn!("core peripherals already taken: instruction cache left off"),
    }

    // Step outputs first: from here on the STEP lines are driven low by their timers.
    let kick = start_steps(StepHardware {
        step: StepPins {
            joint0: p.PA15,
            joint1: p.PA0,
            joint2: p.PA6,
            joint3: p.PD12,
            joint4: p.PE9,
            joint5: p.PA5,
            joint6: p.PB8,
            joint7: p.PB9,
        },
        dir: DirPins {
            dir: [
                p.PD0.into(),
                p.PD1.into(),
                p.PD2.into(),
                p.PD3.into(),
                p.PD4.into(),
                p.PD5.into(),
                p.PD6.into(),
                p.PD7.into(),
            ],
        },
        clock: p.TIM13,
    });
    // The joint timers and DMA2 streams are driven through their registers
    // (step_dma.rs); their handles are not used by anything else.
    let _step_hw = (
        p.TIM1, p.TIM2, p.TIM3, p.TIM4, p.TIM5, p.TIM8, p.TIM16, p.TIM17, p.DMA2_CH0, p.DMA2_CH1,
        p.DMA2_CH2, p.DMA2_CH3, p.DMA2_CH4, p.DMA2_CH5, p.DMA2_CH6, p.DMA2_CH7,
    );
    let outputs = OutputLines::new(OutputPins {
        pin0: p.PG2,
        pin1: p.PG3,
        enable: [
            p.PF0.into(),
            p.PF1.into(),
            p.PF2.into(),
            p.PF7.into(),
            p.PF8.into(),
            p.PF9.into(),
            p.PG0.into(),
            p.PG1.into(),
            p.PE3.into(),
        ],
    });
    let gripper = GripperPwm::new(p.TIM15, p.PE5, p.PE4);

    let uart = match Uart::new(
        p.USART6,
        p.PC7,
        p.PC6,
        p.DMA1_CH0,
        p.DMA1_CH1,
        Irqs,
        usart::Config::default(),
    ) {
        Ok(uart) => uart,
        Err(e) => defmt::panic!("USART6: {}", e), // safe: boot-time bring-up
    };
    let serial_port = SERIAL.init(BoardSerial::new(uart, RX_RING.take()));

    let mut settings = FlashSettings::new(Flash::new(p.FLASH, Irqs));
    let stored = match settings.read().await {
        Ok(stored) => stored,
        Err(e) => {
            warn!("settings unreadable, using defaults: {}", e);
            None
        }
    };
    let persistent = stored.unwrap_or_default();
    info!("settings: {}", persistent);

    let controller_config = ControllerConfig {
        pwm_timer_clock_hz: gripper.timer_clock_hz(),
        max_step_rate_hz: step_dma::MAX_STEP_RATE_HZ,
        ..ControllerConfig::BOARD
    };
    let controller = CONTROLLER.init_with(|| Controller::new(controller_config));
    controller.set_step_budget_hz(step_dma::BOARD_STEP_BUDGET_HZ);

    let eth_pins = net::EthernetPins {
        eth: p.ETH,
        sma: p.ETH_SMA,
        ref_clk: p.PA1,
        crs_dv: p.PA7,
        rx_d0: p.PC4,
        rx_d1: p.PC5,
        tx_d0: p.PG13,
        tx_d1: p.PB13,
        tx_en: p.PG11,
        mdio: p.PA2,
        mdc: p.PC1,
    };
    let stack = start_network(&spawner, p.RNG, eth_pins, &persistent);
    let socket = SOCKET.init(BoardSocket::new(bind_socket(stack)));
    set_driver_priorities();

    spawner.spawn(defmt::unwrap!(network(socket)));
    spawner.spawn(defmt::unwrap!(trajectory(
        controller,
        TrajectoryHw {
            kick,
            outputs,
            gripper,
            serial: serial_port,
            settings,
            encoders: NoEncoders,
        },
    )));
    spawner.spawn(defmt::unwrap!(stepper(kick)));
    spawner.spawn(defmt::unwrap!(upload()));
    spawner.spawn(defmt::unwrap!(serial(serial_port)));

    stack.wait_config_up().await;
    if let Some(config) = stack.config_v4() {
        info!("listening on {}:{}", config.address, PORT);
    }
    loop {
        // The link can drop and come back; log it so a person at the probe can see why the
        // controller went silent.
        stack.wait_link_down().await;
        warn!("ethernet link down");
        stack.wait_link_up().await;
        info!("ethernet link up");
    }
}

/// What the step path needs besides the timers and streams it drives by register.
struct StepHardware {
    step: StepPins,
    dir: DirPins,
    clock: Peri<'static, peripherals::TIM13>,
}

/// Sets up the step timers and streams (STEP low), the pins and the step clock.
#[inline(never)]
fn start_steps(hw: StepHardware) -> &'static StepTimer {
    step_dma::init();
    hw.step.into_timer_outputs();
    hw.dir.configure();
    let step_clock = STEP_CLOCK.init(embassy_stm32::timer::low_level::Timer::new(hw.clock));
    match step_timer::start(step_clock.get_clock_frequency().0) {
        Ok(kick) => KICK.init(kick),
        Err(e) => defmt::panic!(
            // safe: boot-time bring-up, not network input
            "step timer clock is not {} Hz: {}",
            step_dma::STEP_TIMER_HZ,
            e
        ),
    }
}

/// Seeds and starts the network stack at the stored address; spawns its runner.
fn start_network(
    spawner: &Spawner,
    rng: Peri<'static, peripherals::RNG>,
    pins: net::EthernetPins,
    settings: &PersistentSettings,
) -> Stack<'static> {
    // The TCP/IP stack wants a random seed (initial sequence numbers, DHCP transaction IDs).
    let seed = Rng::new(rng, Irqs).next_u64();
    let (stack, runner) = net::init(pins, net::ip_config(settings.ip, settings.prefix_len), seed);
    spawner.spawn(defmt::unwrap!(net_task(runner)));
    stack
}

/// The controller's socket, bound to [`PORT`].
fn bind_socket(stack: Stack<'static>) -> UdpSocket<'static> {
    let mut socket = UdpSocket::new(
        stack,
        UDP_RX_META.take(),
        UDP_RX.take(),
        UDP_TX_META.take(),
        UDP_TX.take(),
    );
    if let Err(e) = socket.bind(PORT) {
        // Only possible with port 0 or a second bind; both are programming errors.
        defmt::panic!("udp bind: {}", e); // safe: boot-time bring-up
    }
    socket
}

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
//! | P0 (highest) | EXTI0: the wired e-stop input on PC0 ([`estop`]): every STEP output stopped (register writes), a gripper burst cut (two more), then the step service pended; EXTI1-3, EXTI9_5, EXTI15_10: the limit and home switches (`switches`, issue 33): stamped, a limit trip stops every STEP output the same way, the step service pended | nothing may delay an e-stop or a limit; it preempts even a DIR change, which no longer matters once the run is stopped |
//! | P1 | TIM13: step clock ([`step_timer`]): DIR changes at reversals (from lock-free queues), the run's end handed to the step service | a DIR change must come between a pulse's fall and the next pulse's setup |
//! | P2 | DMA1 and DMA2 streams 0-3: STEP buffer refills ([`step_dma`]); TIM7's vector: the step service (run end, the e-stop's halt); TIM15: gripper burst reloads ([`gripper`]) | a half (64 periods) of slack; 128 PWM periods |
//! | P3 | TIM12: embassy-time | task wake-ups |
//! | P4 | EXTI4: the safety door on PF4 (`door`, feature `door-input`, issue 32): the level recorded, the trajectory task woken; Ethernet (and its look at STOPPED in each received frame, `net::RxPeek`), USART6, DMA, flash, RNG | driver bookkeeping; their tasks wait anyway. The Ethernet look halts the steps for a STOPPED within microseconds of its frame landing, whatever thread mode does (issue 30 part 4), and keeps two receive descriptors free by dropping the oldest frames the runner has not taken, so none lands in a full ring; at P4 it never holds off P0-P3 |
//! | thread mode | every task, one executor | see below |
//!
//! P0 is the e-stop input's and the switches' alone; the others kept their order, one level lower each
//! (issue 18). Critical sections mask every interrupt (`cortex-m`'s single-core
//! implementation, timed by [`diag`] for the DIAG report: the longest one and where it was
//! opened, `armctl diag`), the e-stop's and the DIR changes' too, so the ones left are short;
//! the step path's lock (`step_dma::STEP`) is BASEPRI at P2 instead (issue 20): it holds
//! off P2 and below and never P0 or P1, which never take it.
//!
//! The tasks (arm-core's, each wrapped in an `#[embassy_executor::task]` by
//! `arm_wiring::controller_tasks!`):
//! - `net_task`: the embassy-net stack's runner.
//! - `network`: receives datagrams and routes them: a CRC-valid STOPPED goes to its own
//!   queue, which the trajectory task drains first; sends ACKs and reports.
//! - `run_controller`: arm-core's `controller_task`, three tasks in one future, wired as in
//!   the QEMU board and the simulator: the trajectory task owns the [`Controller`]
//!   (handles frames, drives pins, gripper and serial port, pushes segments into the step
//!   producer shared with the DMA refills, which wake it as segments finish); the upload
//!   task sends LOCATION reports every upload period; the serial task is the USART
//!   pass-through.
//! - `watchdog` (this board's): feeds the IWDG while `trajectory` and `network` live.
//!
//! One thread-mode executor is enough: no task computes for long (a PENDING frame of 12
//! points is decoded and checked in microseconds), the e-stop has its own queue, and
//! everything with a deadline below a millisecond is an interrupt. STEP pulses are made by
//! timer hardware fed by DMA ([`step_dma`]); an emergency stop takes every STEP output
//! low (a pulse under way at its own width) and stops the streams (under the step lock; the wired e-stop input's
//! interrupt, above that lock, with register writes alone, `step_dma::kill_step_outputs`).
//!
//! Network input can never panic or block: arm-core decodes it with the `protocol` crate
//! and answers every error with an ACK status; queues that are full drop rather than wait.
//!
//! The task wrappers, the controller's static, the UDP socket and its buffers come from
//! [`arm_wiring::controller_tasks!`], shared with the QEMU board (`firmware/qemu-mps2`), so
//! that the two cannot drift apart; this crate passes its types, and the watchdog's
//! heartbeat wrappers of the trajectory and network tasks.
//!
//! # Memory and caches
//! Every task, driver and buffer is a `static` (`StaticCell`), initialised once in `main`;
//! there is no heap. Both caches are on ([`memory`]); the layout:
//!
//! | region | what | cache |
//! |---|---|---|
//! | flash bank 1 + bank 2 up to 0x081C_0000 | code, constants (`memory.x` FLASH) | I-cache |
//! | flash 0x081C_0000..0x0820_0000 | settings (two sectors, [`settings`]) | - |
//! | AXI SRAM 0x2400_0000 (512 KiB) | `.data`, `.bss`, `.uninit`: the trajectory buffer (8192 points, 288 KiB), the bus, the tasks' futures, the UDP socket buffers, defmt's RTT buffer | MPU region 1: D-cache write-through (the probe sees every RTT write) |
//! | DTCM 0x2000_0000 (128 KiB) | the stack (CPU only, zero wait states) | never cached |
//! | SRAM1 0x3000_0000 (128 KiB) | Ethernet descriptors and packets (a ring of 40, 62 KiB, sized with the UDP socket and the inbox for a burst of 32 full datagrams: `net.rs`), serial RX ring and TX staging ([`memory::DmaBuffers`]) | MPU region 0: non-cacheable |
//! | SRAM2 0x3002_0000 (128 KiB) | the step streams' buffers, 12 KiB (`step_dma` `BUFFERS`, a `.sram2` static): off the Ethernet DMA's SRAM, so the step bursts never wait for it (issue 34) | MPU region 2: non-cacheable |
//!
//! A DMA never sees a stale cache line because nothing it touches is cacheable, and no
//! store waits in a dirty line (write-through), so nothing needs cache maintenance, not
//! even before the fault path's reset. The step producer's state (`STEP`) and the bus
//! stay in AXI SRAM: with the D-cache on they are cache hits in the step interrupt, as
//! fast as DTCM would be, without a second linker region to manage.
//!
//! Flash image: the big statics cost no flash: [`BUS`] and the step producer's `STEP`
//! (15 KiB) have all-zero initial values (`.bss`), the others are `StaticCell`s.
//! `scripts/fw-size.sh` fails above 96 KiB (issue 9's budget; docs/BOARD.md has the history).
//!
//! # Faults, watchdog, boot
//! - Panics, HardFaults and stray interrupts take one path ([`fault`]): steps and gripper
//!   stopped, STEP low, drivers holding, a defmt line, reset.
//! - The IWDG (1 s) is fed by the `watchdog` task only while the trajectory task and the
//!   network task both show signs of life (board-logic's `watchdog` module).
//! - Clocks: HSE from the ST-LINK if it starts within 10 ms, else HSI ([`clocks`]).
//! - Network: brought up only once the PHY's reference clock runs, retried every 5 s;
//!   everything else runs meanwhile ([`net`]). Link loss changes nothing in the controller:
//!   a run keeps executing what is buffered and the underrun rule stops it
//!   (board-logic's `net` module documents why).
//! - Settings: corruption is erased to defaults, an ECC double error costs one extra reset
//!   ([`settings`]).

#![no_std]
#![warn(missing_docs)]
#![warn(
    clippy::indexing_slicing,
    clippy::unwrap_used,
    clippy::cast_possible_truncation
)]
#![no_main]

mod clocks;
mod diag;
#[cfg(feature = "door-input")]
mod door;
mod encoder;
mod estop;
mod fault;
mod gripper;
mod memory;
mod net;
mod pins;
mod pre_init;
mod serial;
mod settings;
mod step_dma;
mod step_timer;
#[cfg(feature = "switch-inputs")]
mod switches;

use core::future::Future;

use arm_core::config::ControllerConfig;
use arm_core::hw::Gripper;
use arm_core::{Bus, TrajectoryHw};
use board_logic::fault::FaultKind;
use board_logic::net::RETRY_SECONDS;
use board_logic::watchdog::{
    Beating, CHECK_PERIOD_MS, Heartbeat, IWDG_TIMEOUT_MS, Liveness, Verdict, late_check,
};
use defmt::{error, info, warn};
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_stm32::flash::Flash;
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::rng::Rng;
use embassy_stm32::usart::Uart;
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{Peri, bind_interrupts, dma, eth, flash, interrupt, peripherals, rng, usart};
use embassy_time::{Duration, Instant, Timer};
use static_cell::StaticCell;

use crate::clocks::ClockSource;
use crate::encoder::{ModbusEncoders, Rs485};
use crate::gripper::GripperPwm;
use crate::pins::{DirPins, OutputLines, OutputPins, StepPins};
use crate::serial::BoardSerial;
use crate::settings::FlashSettings;
use crate::step_timer::StepTimer;

bind_interrupts!(
    /// Interrupt handlers of the embassy drivers.
    pub struct Irqs {
        // RxFlags reads the DMA's drop flags before embassy's handler clears every flag
        // set; RxPeek looks at the ring after it, so a frame landing during the look
        // raises the interrupt again.
        ETH => net::RxFlags, eth::InterruptHandler, net::RxPeek;
        RNG => rng::InterruptHandler<peripherals::RNG>;
        FLASH => flash::InterruptHandler;
        USART6 => usart::InterruptHandler<peripherals::USART6>;
        // The serial port's streams: DMA1 4 and 5 (0-3 are joints 0-3's, `step_dma`).
        DMA1_STREAM4 => dma::InterruptHandler<peripherals::DMA1_CH4>;
        DMA1_STREAM5 => dma::InterruptHandler<peripherals::DMA1_CH5>;
    }
);

/// Joints the board has STEP/DIR/ENABLE lines for.
pub const MAX_JOINTS: usize = protocol::MAX_JOINTS;

/// Trajectory points buffered (the profile's: 80 s of 10 ms points).
const CAP: usize = step_dma::PROFILE.trajectory_capacity;

/// The controller's configuration from the board's profile (a `const`: evaluated at compile
/// time, no profile arithmetic in the image); the gripper's clock is set at boot.
const CONTROLLER_CONFIG: ControllerConfig = step_dma::PROFILE.controller_config();

/// The channels between the tasks (and the step interrupt). `Bus::new()` is all zero
/// bytes, so this plain static is `.bss` and costs no flash (`scripts/fw-size.sh` fails
/// should a non-zero field ever put it in `.data`).
pub static BUS: Bus = Bus::new();

arm_wiring::controller_tasks! {
    device: net::Device,
    capacity: CAP,
    bus: crate::BUS,
    step: crate::step_dma::STEP,
    kick: StepTimer,
    outputs: OutputLines,
    gripper: GripperPwm,
    serial: BoardSerial,
    settings: FlashSettings,
    encoders: ModbusEncoders,
    // A STOPPED cuts a gripper burst where it is first seen, as the steps (issue 30).
    halt_also: crate::gripper::cut_at_stop,
    // The watchdog feeds the IWDG only while these two futures are polled.
    liveness: { trajectory: crate::TrajectoryBeat, network: crate::network_beating },
}

static KICK: StaticCell<StepTimer> = StaticCell::new();
/// TIM13 (the step clock) as embassy's low-level timer: keeps its clock on and tells the
/// timer clock frequency.
static STEP_CLOCK: StaticCell<embassy_stm32::timer::low_level::Timer<'static, peripherals::TIM13>> =
    StaticCell::new();
static SERIAL: StaticCell<BoardSerial> = StaticCell::new();

/// Polls of the trajectory task's future (watchdog liveness): the task that feeds the
/// step producer.
static TRAJECTORY_BEAT: Heartbeat = Heartbeat::new();
/// Polls of the network task's future, or of the bring-up loop until it starts.
static NETWORK_BEAT: Heartbeat = Heartbeat::new();
/// Names of the heartbeats, in [`Liveness`] order.
const BEAT_NAMES: [&str; 2] = ["trajectory task", "network task"];

/// Watches the trajectory task's future: beats [`TRAJECTORY_BEAT`] on every poll of it
/// (it is polled at every `step_progress`, also while it awaits a settings write or an
/// encoder read).
struct TrajectoryBeat;

impl arm_core::TaskWatch for TrajectoryBeat {
    fn watch<F: Future>(&self, task: F) -> impl Future<Output = F::Output> {
        Beating::new(&TRAJECTORY_BEAT, task)
    }
}

/// The network task's future, beating [`NETWORK_BEAT`] on every poll (its socket wakes it
/// at least every 100 ms).
fn network_beating<F: Future>(task: F) -> Beating<'static, F> {
    Beating::new(&NETWORK_BEAT, task)
}

/// Feeds the IWDG while the trajectory task and the network task both live. Every check
/// period it wakes the trajectory task (a spurious `step_progress` only makes it look at
/// the step producer's progress again;
/// the network task wakes itself, see arm-wiring's socket adapter), then compares the
/// heartbeats. A hung task takes the fault path (safe state, log, reset); a hung executor,
/// where this task cannot run either, is reset by the IWDG.
#[embassy_executor::task]
async fn watchdog(mut iwdg: IndependentWatchdog<'static, peripherals::IWDG1>) -> ! {
    let beats = || [TRAJECTORY_BEAT.count(), NETWORK_BEAT.count()];
    let mut liveness = Liveness::new(beats());
    loop {
        BUS.step_progress.signal(());
        let due = Instant::now() + Duration::from_millis(u64::from(CHECK_PERIOD_MS));
        Timer::at(due).await;
        if let Some(late) = late_check(due.as_millis(), Instant::now().as_millis()) {
            warn!(
                "watchdog: check {=u64} ms late: the executor or the time driver stalled",
                late
            );
        }
        match liveness.check(beats()) {
            Verdict::Feed => iwdg.pet(),
            Verdict::Late { index } => {
                warn!("watchdog: {} late", BEAT_NAMES[index]);
                iwdg.pet();
            }
            Verdict::Hung { index } => {
                error!("watchdog: {} hung", BEAT_NAMES[index]);
                // The orderly way out; if even this task could not run, the IWDG (no longer
                // fed) resets the board within IWDG_TIMEOUT_MS.
                let task = u8::try_from(index).unwrap_or(u8::MAX);
                fault::fault(FaultKind::TaskHung { task }, None);
            }
        }
    }
}

/// Lowers every driver interrupt below the step and gripper timers (the drivers enable
/// them at P0, the reset value, which is the e-stop input's alone).
fn set_driver_priorities() {
    interrupt::TIM8_BRK_TIM12.set_priority(Priority::P3);
    for irq in [
        interrupt::ETH,
        interrupt::USART6,
        interrupt::DMA1_STREAM4,
        interrupt::DMA1_STREAM5,
        interrupt::FLASH,
        interrupt::RNG,
    ] {
        irq.set_priority(Priority::P4);
    }
}

#[embassy_executor::main]
async fn main(spawner: Spawner) -> ! {
    // Why the last reset happened, read before anything else and cleared for the next
    // boot (RCC_RSR keeps its flags across resets until RMVF).
    let reset_rsr = embassy_stm32::pac::RCC.rsr().read().0;
    embassy_stm32::pac::RCC
        .rsr()
        .write_value(embassy_stm32::pac::rcc::regs::Rsr(
            board_logic::reset_cause::rsr::RMVF,
        ));
    let clock_source = clocks::probe_hse();
    let mut config = clocks::config(clock_source);
    config.dma_interrupt_priority = Priority::P4;
    config.bdma_interrupt_priority = Priority::P4;
    config.mdma_interrupt_priority = Priority::P4;
    let p = embassy_stm32::init(config);
    info!("arm controller starting");
    info!(
        "reset cause: {} (RCC_RSR {=u32:#x})",
        board_logic::reset_cause::reset_cause(reset_rsr),
        reset_rsr
    );
    match clock_source {
        ClockSource::Hse => info!("clock: HSE 8 MHz (ST-LINK MCO)"),
        ClockSource::HsiFallback => warn!("clock: HSE missing, running on HSI"),
    }
    // Caches before any DMA starts: every DMA buffer is in non-cacheable SRAM1.
    match cortex_m::Peripherals::take() {
        Some(mut core) => {
            memory::enable_caches(&mut core.MPU, &mut core.SCB, &mut core.CPUID);
            // The DIAG report's cycle counter (issue 34): masked spans from here on.
            diag::start(&mut core.DCB, &mut core.DWT);
        }
        None => warn!("core peripherals already taken: caches left off"),
    }
    let Some(dma_buffers) = memory::take_dma_buffers() else {
        defmt::panic!("DMA buffers taken twice"); // safe: boot-time bring-up
    };
    let memory::DmaBuffers {
        eth: eth_packets,
        serial_rx,
        serial_tx,
    } = dma_buffers;

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
    // The wired e-stop input once the step outputs can be stopped (an input open at boot
    // latches at once).
    estop::start(p.PC0);
    // The limit and home switches likewise (an input tripped at boot latches at once).
    #[cfg(feature = "switch-inputs")]
    let switch_line = Some(switches::start(switches::SwitchPins {
        pe2: p.PE2,
        pa3: p.PA3,
        pe6: p.PE6,
        pe7: p.PE7,
        pe8: p.PE8,
        pb1: p.PB1,
        pe10: p.PE10,
        pe11: p.PE11,
        pe12: p.PE12,
        pe13: p.PE13,
        pe14: p.PE14,
        pe15: p.PE15,
    }));
    #[cfg(not(feature = "switch-inputs"))]
    let switch_line = None;
    // The safety door (issue 32, opt-in): a door open at boot refuses RUNING at once.
    #[cfg(feature = "door-input")]
    let door_line: Option<&'static arm_core::DoorLine> = {
        door::start(p.PF4);
        Some(&door::LINE)
    };
    #[cfg(not(feature = "door-input"))]
    let door_line = None;
    // The joint timers and their DMA streams (DMA1 and DMA2 streams 0-3) are driven
    // through their registers (step_dma/); their handles are not used by anything else.
    let _step_hw = (
        p.TIM1, p.TIM2, p.TIM3, p.TIM4, p.TIM5, p.TIM8, p.TIM16, p.TIM17, p.DMA1_CH0, p.DMA1_CH1,
        p.DMA1_CH2, p.DMA1_CH3, p.DMA2_CH0, p.DMA2_CH1, p.DMA2_CH2, p.DMA2_CH3,
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
    let gripper = GripperPwm::new(p.TIM15, p.PE5, p.PE4, CONTROLLER_CONFIG.servo_on_stop);

    let uart = match Uart::new(
        p.USART6,
        p.PC7,
        p.PC6,
        p.DMA1_CH4,
        p.DMA1_CH5,
        Irqs,
        usart::Config::default(),
    ) {
        Ok(uart) => uart,
        Err(e) => defmt::panic!("USART6: {}", e), // safe: boot-time bring-up
    };
    let serial_port = SERIAL.init(BoardSerial::new(uart, serial_rx, serial_tx));

    let mut settings = FlashSettings::new(Flash::new(p.FLASH, Irqs));
    // The user button B1 (PC13; pressed = high, the NUCLEO's own pull-down) held at reset
    // clears the authentication key (issue 21): the way back when the key is lost needs
    // a hand on the board, never the network.
    let user_button = embassy_stm32::gpio::Input::new(p.PC13, embassy_stm32::gpio::Pull::Down);
    settings.set_clear_key(user_button.is_high());
    drop(user_button);
    let persistent = settings.read().await.settings();

    let encoder_uart =
        match Uart::new_blocking_with_de(p.UART4, p.PC11, p.PC10, p.PB14, encoder::uart_config()) {
            Ok(uart) => uart,
            Err(e) => defmt::panic!("UART4: {}", e), // safe: boot-time bring-up
        };
    let encoders = ModbusEncoders::detect(Rs485::new(encoder_uart), persistent.joints).await;

    // The board's profile, with the gripper clock as measured at boot.
    let controller_config = ControllerConfig {
        pwm_timer_clock_hz: gripper.timer_clock_hz(),
        ..CONTROLLER_CONFIG
    };
    set_driver_priorities();

    // The chip's RNG: the epochs of keys set (issue 30: a key set again after the settings
    // were lost starts at a random epoch, never at 1 again), and the TCP/IP stack's seed.
    let mut rng = Rng::new(p.RNG, Irqs);
    let entropy = rng.next_u64();

    // Every task but the network's: the arm works (and stops on its underrun rule) with or
    // without a network.
    defmt::unwrap!(spawn_controller(
        &spawner,
        controller_config,
        net::mac_address(),
        entropy,
        TrajectoryHw {
            kick,
            outputs,
            gripper,
            serial: serial_port,
            settings,
            encoders,
            estop: Some(&estop::LINE),
            // PF4 with `--features door-input` (docs/BOARD.md, "Safety door input").
            door: door_line,
            switches: switch_line,
        },
    ));

    // The IWDG stops while a debugger halts the core: a breakpoint does not reset the board.
    let dbgmcu = embassy_stm32::pac::DBGMCU;
    dbgmcu.apb4fzr1().modify(|w| w.set_iwdg1(true));
    // So do the joints' step timers and the step clock (TIM13), or a halted core would
    // leave the DMA replaying its buffers, pulsing forever (issue 20). A halt mid-pulse
    // keeps that one pulse's line high until the core runs again.
    dbgmcu.apb1lfzr1().modify(|w| {
        w.set_tim2(true);
        w.set_tim3(true);
        w.set_tim4(true);
        w.set_tim5(true);
        w.set_tim13(true);
    });
    dbgmcu.apb2fzr1().modify(|w| {
        w.set_tim1(true);
        w.set_tim8(true);
        w.set_tim16(true);
        w.set_tim17(true);
    });
    let mut iwdg = IndependentWatchdog::new(p.IWDG1, IWDG_TIMEOUT_MS * 1_000);
    iwdg.unleash();
    spawner.spawn(defmt::unwrap!(watchdog(iwdg)));
    info!("watchdog: IWDG on, {} ms", IWDG_TIMEOUT_MS);

    // The network last: without a PHY (or its clock) the board runs on, and tries again.
    let mut eth_pins = net::EthernetPins {
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
    // The TCP/IP stack wants a random seed (initial sequence numbers, DHCP transaction IDs).
    let seed = rng.next_u64();
    while !net::phy_clock_present(eth_pins.ref_clk.reborrow()) {
        warn!(
            "ethernet: no RMII reference clock (PHY missing or dead): no network, retry in {} s",
            RETRY_SECONDS
        );
        // Beat for the network task that does not exist yet.
        for _ in 0..RETRY_SECONDS * 10 {
            NETWORK_BEAT.beat();
            Timer::after_millis(100).await;
        }
    }
    let device = net::device(eth_pins, eth_packets);
    let stack = defmt::unwrap!(spawn_network(
        &spawner,
        device,
        arm_wiring::net::ip_config(&persistent),
        seed,
    ));
    // Logs the address, then every link change with the state it happened in.
    arm_wiring::net::watch_link(stack, &BUS).await
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
    // APB2's timer clock (joints 4-7), read as embassy set it: TIM1's.
    let apb2_timer_hz = embassy_stm32::rcc::frequency::<peripherals::TIM1>().0;
    match step_timer::start(step_clock.get_clock_frequency().0, apb2_timer_hz) {
        Ok(kick) => KICK.init(kick),
        Err(e) => defmt::panic!(
            // safe: boot-time bring-up, not network input
            "a step timer clock is not {} Hz: {}",
            step_dma::STEP_TIMER_HZ,
            e
        ),
    }
}

//! The arm controller firmware on an emulated Cortex-M7: QEMU's `mps2-an500` machine (ARM
//! MPS2 with the AN500 FPGA image) with its LAN9118 Ethernet controller.
//!
//! No board is attached to the machines this project is built on; this target runs the
//! no_std firmware (executor on Cortex-M, critical sections, interrupts, embassy-net,
//! arm-core's tasks and arm-step's pulse producer) for real, over an emulated Ethernet link, in CI. The
//! tasks, their wiring and their static allocation are the NUCLEO board's, from
//! [`arm_wiring::controller_tasks!`]; only the chip-specific parts are here:
//!
//! | what | NUCLEO-H743ZI2 | here |
//! |---|---|---|
//! | Ethernet | STM32 MAC + LAN8742A, DMA | LAN9118 by PIO ([`lan9118`]) |
//! | embassy-time | TIM5 | CMSDK timers 0 and 1 ([`time_driver`]) |
//! | step output | arm-step's producer; joint timers + DMA play its buffers | the same producer; its buffers played in software (arm-step's `StreamPlayer`) at dual timer interrupts, lines in memory ([`step_out`]) |
//! | serial pass-through | USART6 + DMA | CMSDK UART 1, interrupts ([`serial`]) |
//! | gripper, PIN0/1, ENABLE | TIM15 PWM, GPIO | timed and logged fakes ([`devices`]) |
//! | settings | flash (sequential-storage) | RAM |
//! | logs | defmt over RTT | text on UART 0 ([`logger`]) |
//! | faults | panic-probe | log, stop steps, exit QEMU with failure ([`fault`]) |
//!
//! Interrupt priorities follow the NUCLEO's: step timer highest, then time, then the
//! drivers; every task runs in one thread-mode executor, which sleeps with WFI (QEMU
//! treats WFE as a yield and would spin a host core).
//!
//! Run it (the test `tests/tests/qemu.rs` does this):
//! ```text
//! cargo qemu-fw
//! qemu-system-arm -M mps2-an500 -nographic -semihosting-config enable=on,target=native \
//!   -kernel target/thumbv7em-none-eabihf/release/firmware-qemu \
//!   -nic user,model=lan9118,hostfwd=udp:127.0.0.1:8510-:8510 \
//!   -serial stdio -serial tcp:127.0.0.1:8520,server=on,wait=off
//! ```
//! UART 0 (the first `-serial`) carries the log, UART 1 the serial pass-through.

#![no_std]
#![warn(missing_docs)]
#![warn(
    clippy::indexing_slicing,
    clippy::unwrap_used,
    clippy::cast_possible_truncation
)]
#![no_main]

mod devices;
mod fault;
mod lan9118;
mod logger;
mod marks;
mod mps2;
mod serial;
mod step_out;
mod time_driver;
mod uart;

use core::sync::atomic::{AtomicBool, Ordering};

use arm_core::config::ControllerConfig;
use arm_core::hw::{Gripper, PersistentSettings};
use arm_core::{Bus, TrajectoryHw};
use arm_wiring::NoEncoders;
use embassy_executor::raw::Executor;
use static_cell::StaticCell;

use crate::devices::{LoggedOutputs, QEMU_GUEST_IP, RamSettings, TimedGripper};
use crate::lan9118::Lan9118;
use crate::serial::QemuSerial;
use crate::step_out::{STEP, StepTimer};

/// The channels between the tasks (and the step interrupt).
pub static BUS: Bus = Bus::new();

/// Trajectory points buffered: the profile's (the NUCLEO's figure, so that uploads behave
/// the same).
const CAP: usize = step_out::PROFILE.trajectory_capacity;

/// The controller's configuration from the board's profile (a `const`: evaluated at compile
/// time, no profile arithmetic in the image); the gripper's clock is set at boot.
const CONTROLLER_CONFIG: ControllerConfig = step_out::PROFILE.controller_config();

/// The MAC address if the chip's EEPROM has none (QEMU loads one: 52:54:00:12:34:56 unless
/// `-nic ...,mac=` says otherwise). Locally administered, unicast.
const FALLBACK_MAC: [u8; 6] = [0x02, 0x00, 0x00, 0x00, 0x85, 0x10];

arm_wiring::controller_tasks! {
    device: Lan9118,
    capacity: CAP,
    bus: crate::BUS,
    step: crate::step_out::STEP,
    kick: StepTimer,
    outputs: LoggedOutputs,
    gripper: TimedGripper,
    serial: QemuSerial,
    settings: RamSettings,
    encoders: NoEncoders,
}

static KICK: StaticCell<StepTimer> = StaticCell::new();
static SERIAL: StaticCell<QemuSerial> = StaticCell::new();
static EXECUTOR: StaticCell<Executor> = StaticCell::new();

/// Set by the executor's pender (a task was woken): the idle loop must poll, not sleep.
static WORK: AtomicBool = AtomicBool::new(false);

#[unsafe(export_name = "__pender")]
fn pender(_context: *mut ()) {
    WORK.store(true, Ordering::Release);
}

#[embassy_executor::task]
async fn link_watch(stack: embassy_net::Stack<'static>) -> ! {
    arm_wiring::net::watch_link(stack, &BUS).await
}

/// Logs the pulses the step output emitted (net, and rising edges) each time it comes to
/// rest, so that a test can compare what left the "pins" with the positions the controller
/// reports and the steps its trajectory asked for; and the Ethernet driver's error
/// counters when they change.
#[embassy_executor::task]
async fn step_output_monitor() -> ! {
    let mut logged = ([0i32; arm_step::MAX_JOINTS], [0u32; arm_step::MAX_JOINTS]);
    let mut nic_errors = (0, 0);
    let mut stops_logged = 0;
    loop {
        embassy_time::Timer::after_millis(100).await;
        let errors = (
            lan9118::RX_DROPPED.load(Ordering::Relaxed),
            lan9118::TX_ERRORS.load(Ordering::Relaxed),
        );
        if errors != nic_errors {
            log::warn!(
                "LAN9118: {} frames dropped on receive, {} failed to send",
                errors.0,
                errors.1
            );
            nic_errors = errors;
        }
        let (running, late) = STEP.with_engine(|e| (e.is_running(), e.late_pulses()));
        // Issue 30's figure, once per STOPPED the receive interrupt saw, at rest: from the
        // interrupt taking its frame to the last STEP rise after it (0: none after it).
        let times = critical_section::with(|cs| step_out::STOP_TIMES.borrow(cs).get());
        if !running && times.stops != stops_logged {
            let cycles = times.last_rise.saturating_sub(times.stop_seen);
            log::info!(
                "STOPPED frame to the last STEP edge: {} us (stop {})",
                cycles / u64::from(mps2::SYSCLK_HZ / 1_000_000),
                times.stops
            );
            stops_logged = times.stops;
        }
        let lines = &step_out::LINES;
        let seen = (
            lines.pulses.each_ref().map(|p| p.load(Ordering::Relaxed)),
            lines.rising.each_ref().map(|r| r.load(Ordering::Relaxed)),
        );
        if !running && seen != logged {
            log::info!(
                "step output at rest: pulses {:?}, rising edges {:?}, late pulses {}",
                seen.0,
                seen.1,
                late
            );
            logged = seen;
        }
    }
}

/// Commits the fault QEMU's command line asked for, once the controller is up.
#[embassy_executor::task]
async fn inject_fault(fault: fault::InjectedFault) -> ! {
    embassy_time::Timer::after_millis(300).await;
    fault::inject(fault)
}

#[cortex_m_rt::entry]
fn main() -> ! {
    // Before anything steals them (enabling an interrupt does).
    let Some(mut core) = cortex_m::Peripherals::take() else {
        panic!("core peripherals taken before main"); // safe: boot-time bring-up
    };
    // Time first: the log's timestamps read it.
    time_driver::init();
    logger::init();
    log::info!("arm controller starting (QEMU mps2-an500)");
    fault::install_stack_guard(&mut core.MPU);
    let requested = fault::requested();
    if requested.runtime_check {
        fault::run_runtime_check();
    }
    let kick = KICK.init(step_out::init());
    let serial_port = SERIAL.init(QemuSerial::new());

    let ethernet = match Lan9118::new(FALLBACK_MAC) {
        Ok(ethernet) => ethernet,
        Err(e) => panic!("LAN9118: {:?}", e), // safe: boot-time bring-up
    };
    let [a, b, c, d, e, f] = ethernet.mac_address();
    log::info!(
        "LAN9118 id {:#010x}, MAC {:02x}:{:02x}:{:02x}:{:02x}:{:02x}:{:02x}",
        Lan9118::id_rev(),
        a,
        b,
        c,
        d,
        e,
        f
    );
    mps2::enable(mps2::Irq::Ethernet, mps2::priority::DRIVERS);

    let settings = RamSettings::new(PersistentSettings {
        ip: QEMU_GUEST_IP,
        ..PersistentSettings::default()
    });
    let persistent = settings.current().unwrap_or_default();
    log::info!("settings: {:?}", persistent);

    let gripper = TimedGripper::default();
    // The board's profile, with the gripper's clock as it reports it.
    let controller_config = ControllerConfig {
        pwm_timer_clock_hz: gripper.timer_clock_hz(),
        ..CONTROLLER_CONFIG
    };
    // No RNG on this board: the seed only varies TCP sequence numbers and DHCP ids.
    let seed = time_driver::now_cycles() ^ u64::from_le_bytes([a, b, c, d, e, f, 0x95, 0x18]);

    let executor = EXECUTOR.init(Executor::new(core::ptr::null_mut()));
    let spawner = executor.spawner();
    let spawned = spawn_controller(
        &spawner,
        controller_config,
        ethernet.mac_address(),
        // No RNG here either: the epochs of keys set start where the cycle count says (the
        // settings are in RAM, lost with QEMU anyway).
        seed.rotate_left(29) ^ 0x6a09_e667_f3bc_c908,
        TrajectoryHw {
            kick,
            outputs: LoggedOutputs::default(),
            gripper,
            serial: serial_port,
            settings,
            encoders: NoEncoders,
            // QEMU's mps2-an500 has no input a test could open (README, "On an emulated
            // board"): STATUS shows the wired e-stop input closed.
            estop: None,
            door: None,
            switches: None,
        },
    )
    // The LAN9118 is up as soon as `Lan9118::new` returned: the network starts at once.
    .and_then(|()| {
        spawn_network(
            &spawner,
            ethernet,
            arm_wiring::net::ip_config(&persistent),
            seed,
        )
    })
    .and_then(|stack| link_watch(stack).map(|token| spawner.spawn(token)))
    .and_then(|()| step_output_monitor().map(|token| spawner.spawn(token)))
    .and_then(|()| match requested.fault {
        Some(fault) => inject_fault(fault).map(|token| spawner.spawn(token)),
        None => Ok(()),
    });
    if let Err(e) = spawned {
        panic!("spawning the tasks: {:?}", e); // safe: boot-time bring-up
    }

    loop {
        WORK.store(false, Ordering::Release);
        // SAFETY: this executor is polled from this loop only, in thread mode.
        unsafe { executor.poll() };
        // Sleep unless a wake came meanwhile; an interrupt ends WFI even while masked, and
        // runs once the critical section ends.
        cortex_m::interrupt::free(|_| {
            if !WORK.load(Ordering::Acquire) {
                cortex_m::asm::wfi();
            }
        });
    }
}

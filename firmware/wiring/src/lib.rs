//! What the firmware boards share beyond arm-core, so that they cannot drift apart: the
//! task wiring and static allocation ([`controller_tasks!`]), the clock on embassy-time,
//! the controller's UDP socket on embassy-net with its buffers, the address
//! configuration, and the link watch.
//!
//! A board crate (the NUCLEO-H743ZI2 in `firmware/board`, the emulated MPS2-AN500 in
//! `firmware/qemu-mps2`) keeps only what is chip-specific: bring-up, its drivers for
//! arm-core's hardware traits, its Ethernet driver, its step timer and interrupt
//! priorities. It owns the [`arm_core::Bus`] and [`arm_core::StepShared`] statics (its step
//! interrupt reaches them by path) and invokes [`controller_tasks!`] once with its types;
//! the macro defines the `#[embassy_executor::task]` wrappers (which cannot be generic),
//! the controller's static, and `spawn_controller` and `spawn_network`, which start the
//! tasks in one order for both boards (the network separately: a board may bring its
//! Ethernet up later than the rest, as the NUCLEO does when its PHY's clock is missing).
//!
//! Logging goes through arm-core's shim (`defmt` or `log`, features of the same names).
#![no_std]
#![warn(missing_docs)]
#![warn(
    clippy::indexing_slicing,
    clippy::unwrap_used,
    clippy::cast_possible_truncation
)]

// This must go first so that the other modules see its macros.
mod fmt;

mod adapters;
pub mod net;
#[cfg(all(target_arch = "arm", target_os = "none"))]
pub mod runtime_check;

pub use adapters::{DatagramError, EmbassyClock, NetSocket, NoEncoders};

/// Re-exports for [`controller_tasks!`]'s expansion (the board crate need not name them).
#[doc(hidden)]
pub mod __private {
    pub use arm_core;
    pub use embassy_net;
    pub use embassy_sync::once_lock::OnceLock;
    pub use static_cell::StaticCell;
}

/// Defines a board's controller tasks and `spawn_controller`, the one place where the tasks
/// are wired to each other, to the network stack and to the hardware.
///
/// ```ignore
/// arm_wiring::controller_tasks! {
///     device: net::Device,          // the embassy-net-driver of the board's Ethernet
///     capacity: CAP,                // trajectory points the controller buffers
///     bus: BUS,                     // path of the board's `static BUS` (derefs to arm_core::Bus)
///     step: STEP,                   // path of its `static STEP` (derefs to StepShared<Q>)
///     kick: StepTimer,              // arm_core::hw::StepKick
///     outputs: OutputLines,         // arm_core::hw::Outputs
///     gripper: GripperPwm,          // arm_core::hw::Gripper
///     serial: BoardSerial,          // arm_core::hw::SerialPort
///     settings: FlashSettings,      // arm_core::hw::SettingsStore
///     encoders: ModbusEncoders,     // arm_core::hw::Encoders (or NoEncoders)
///     // Optional: a `fn()` the receive path's halt of a STOPPED calls after the steps', e.g.
///     // to cut a gripper burst at once (issue 30); callable from thread mode.
///     halt_also: gripper::cut_at_stop,
///     // Optional: what watches the trajectory task's future (an arm_core::TaskWatch value)
///     // and the network task's (a path to `fn<F: Future>(F) -> impl Future<Output =
///     // F::Output>`), e.g. to count their polls for a watchdog.
///     liveness: { trajectory: TrajectoryBeat, network: network_beating },
/// }
/// ```
///
/// It defines, in the invoking module:
/// - `BoardController` and `BoardTrajectoryHw`, the concrete controller and hardware types;
/// - the tasks `net_task` (the stack's runner), `network` and `run_controller` (arm-core's
///   [`controller_task`](arm_core::controller_task): the trajectory task, which also
///   feeds the step backend, the upload task and the serial task, as the simulator runs
///   them too), each a thin wrapper of arm-core's generic function;
/// - `spawn_controller(spawner, controller_config, mac, entropy, hw)`, which puts the controller in
///   a static (with the Ethernet MAC address DISCOVER_REPLY reports) and spawns the `run_controller` task:
///   the arm runs, and stops on its underrun rule, with or without a network;
/// - `spawn_network(spawner, device, net_config, seed)`, which creates the stack (on the
///   device behind arm-core's [`GuardedDriver`](arm_core::ingress::GuardedDriver): the
///   receive path's first look, where a STOPPED halts the steps before any queue and each
///   host gets its fair share) and the bound socket ([`net`]) and spawns the stack's
///   runner and the network task; it returns
///   the stack (for the link watch, [`net::watch_link`]). A board calls it once its
///   Ethernet works (the NUCLEO waits for the PHY's clock), right after
///   `spawn_controller` or any time later: until then the bus simply holds no frames.
///
/// Each fails only if called twice (the task pools hold one task each).
#[macro_export]
macro_rules! controller_tasks {
    (
        device: $device:ty,
        capacity: $cap:expr,
        bus: $bus:path,
        step: $step:path,
        kick: $kick:ty,
        outputs: $outputs:ty,
        gripper: $gripper:ty,
        serial: $serial:ty,
        settings: $settings:ty,
        encoders: $encoders:ty
        $(, halt_also: $halt_also:path)?
        $(, liveness: { trajectory: $trajectory_watch:expr, network: $network_watch:path $(,)? })?
        $(,)?
    ) => {
        /// The controller as this board instantiates it.
        pub type BoardController = $crate::__private::arm_core::Controller<{ $cap }>;

        /// The hardware the trajectory task drives.
        pub type BoardTrajectoryHw = $crate::__private::arm_core::TrajectoryHw<
            'static,
            $kick,
            $outputs,
            $gripper,
            $serial,
            $settings,
            $encoders,
        >;

        /// Time for the tasks.
        static CLOCK: $crate::EmbassyClock = $crate::EmbassyClock;
        /// The controller, owned by the trajectory task.
        static CONTROLLER: $crate::__private::StaticCell<BoardController> =
            $crate::__private::StaticCell::new();
        /// The controller's socket, shared by the network task's two halves.
        static SOCKET: $crate::__private::StaticCell<$crate::NetSocket> =
            $crate::__private::StaticCell::new();
        /// The step timer's kick, for the receive path's halt (set by `spawn_controller`).
        static HALT_KICK: $crate::__private::OnceLock<&'static $kick> =
            $crate::__private::OnceLock::new();

        /// The receive path's halt (arm-core's `ingress`): what the trajectory task's stop
        /// does to the steps, from the Ethernet driver's receive path (and the board's
        /// `halt_also`, if it has one, after them).
        pub struct BoardHalt;

        impl $crate::__private::arm_core::ingress::StepHalt for BoardHalt {
            fn halt(&self) {
                $step.stop();
                if let Some(kick) = HALT_KICK.try_get() {
                    $crate::__private::arm_core::hw::StepKick::kick(*kick);
                }
                $($halt_also();)?
            }
        }

        /// The board's Ethernet driver behind the receive path's first look.
        pub type GuardedDevice = $crate::__private::arm_core::ingress::GuardedDriver<
            'static,
            $device,
            BoardHalt,
            $crate::EmbassyClock,
        >;

        #[embassy_executor::task]
        async fn net_task(
            mut runner: $crate::__private::embassy_net::Runner<'static, GuardedDevice>,
        ) -> ! {
            runner.run().await
        }

        #[embassy_executor::task]
        async fn network(socket: &'static $crate::NetSocket) -> ! {
            $crate::__watched!(
                ($($network_watch)?),
                $crate::__private::arm_core::network_task(socket, &$bus, &CLOCK)
            )
            .await
        }

        /// The controller's tasks (trajectory, upload, serial), wired by arm-core once for
        /// every board and the simulator.
        #[embassy_executor::task]
        async fn run_controller(controller: &'static mut BoardController, hw: BoardTrajectoryHw) -> ! {
            $crate::__private::arm_core::controller_task(
                controller,
                &$bus,
                &$step,
                &CLOCK,
                hw,
                &$crate::__watch!($($trajectory_watch)?),
            )
            .await
        }

        /// Puts the controller in its static, with the board's Ethernet `mac` (which
        /// DISCOVER_REPLY reports) and `entropy` (random bits, from the board's RNG where
        /// it has one: the epochs of keys set, issue 30), and spawns the `run_controller`
        /// task (the network's come from `spawn_network`).
        pub fn spawn_controller(
            spawner: &embassy_executor::Spawner,
            controller_config: $crate::__private::arm_core::ControllerConfig,
            mac: [u8; 6],
            entropy: u64,
            hw: BoardTrajectoryHw,
        ) -> Result<(), embassy_executor::SpawnError> {
            // Built in place: 300 KB never pass through the stack.
            let controller = $crate::__private::arm_core::Controller::init_in_place(
                CONTROLLER.uninit(),
                controller_config,
            );
            controller.set_mac(mac);
            controller.set_entropy(entropy);
            let _ = HALT_KICK.init(hw.kick);
            spawner.spawn(run_controller(controller, hw)?);
            Ok(())
        }

        /// Starts the network stack on `device`, its runner and the network task, on the
        /// controller's port; returns the stack.
        pub fn spawn_network(
            spawner: &embassy_executor::Spawner,
            device: $device,
            net_config: $crate::__private::embassy_net::Config,
            seed: u64,
        ) -> Result<$crate::__private::embassy_net::Stack<'static>, embassy_executor::SpawnError> {
            let device = $crate::__private::arm_core::ingress::GuardedDriver::new(
                device,
                &$bus,
                BoardHalt,
                &CLOCK,
                $crate::__private::arm_core::ingress::CONTROLLER_PORT,
            );
            let (stack, runner) = $crate::net::new_stack(device, net_config, seed);
            spawner.spawn(net_task(runner)?);
            let socket = SOCKET.init($crate::NetSocket::new($crate::net::bind_socket(stack)));
            spawner.spawn(network(socket)?);
            Ok(stack)
        }
    };
}

/// The trajectory task's [`TaskWatch`](arm_core::TaskWatch) as [`controller_tasks!`]
/// runs it: the board's `liveness` one, or none.
#[doc(hidden)]
#[macro_export]
macro_rules! __watch {
    () => {
        $crate::__private::arm_core::Unwatched
    };
    ($watch:expr) => {
        $watch
    };
}

/// A task's future as [`controller_tasks!`] runs it: unchanged, or passed through the
/// board's `liveness` wrapper.
#[doc(hidden)]
#[macro_export]
macro_rules! __watched {
    ((), $task:expr) => {
        $task
    };
    (($watch:path), $task:expr) => {
        $watch($task)
    };
}

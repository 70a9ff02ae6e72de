//! The controller's side of the wiring, once for every board and the simulator: the
//! trajectory, upload and serial tasks over one set of hardware, as one future.

use core::future::Future;
use embassy_sync::blocking_mutex::raw::RawMutex;

use embassy_futures::select::{Either3, select3};

use super::{serial_task, trajectory_task, upload_task};
use crate::bus::Bus;
use crate::controller::Controller;
use crate::hw::{Clock, Encoders, Gripper, Outputs, SerialPort, SettingsStore, StepKick};
use crate::step_shared::{StepBackend, StepShared};
use crate::tasks::TrajectoryHw;

/// Wraps the trajectory task's future: the board's watchdog counts its polls
/// (`Beating`); [`Unwatched`] leaves it as it is.
pub trait TaskWatch {
    /// `task`, watched.
    fn watch<F: Future>(&self, task: F) -> impl Future<Output = F::Output>;
}

/// No watchdog: the trajectory task's future as it is (the QEMU board, the simulator).
pub struct Unwatched;

impl TaskWatch for Unwatched {
    fn watch<F: Future>(&self, task: F) -> impl Future<Output = F::Output> {
        task
    }
}

/// Runs the trajectory task (watched by `watch`), the upload task and the serial task
/// (on `hw.serial`, the port the trajectory task opens and closes) together: what every
/// board and the simulator spawn, so that none wires them differently. The network side
/// ([`super::network_task`] behind the board's or the simulator's first look) is spawned
/// beside it; the two meet only on the [`Bus`].
///
/// One future for the three: a wake-up of any polls all three, each cheap when it has
/// nothing to do (a channel, a signal or a timer not due).
pub async fn controller_task<const CAP: usize, const Q: usize, B, M, C, K, O, G, P, S, E>(
    controller: &mut Controller<CAP>,
    bus: &Bus,
    step: &StepShared<Q, B, M>,
    clock: &C,
    hw: TrajectoryHw<'_, K, O, G, P, S, E>,
    watch: &impl TaskWatch,
) -> !
where
    B: StepBackend,
    M: RawMutex,
    C: Clock,
    K: StepKick,
    O: Outputs,
    G: Gripper,
    P: SerialPort,
    S: SettingsStore,
    E: Encoders,
{
    let port = hw.serial;
    // None of them ever ends: selecting runs all three, as joining would, with less code.
    match select3(
        watch.watch(trajectory_task(controller, bus, step, clock, hw)),
        upload_task(bus, step, clock),
        serial_task(port, bus, clock),
    )
    .await
    {
        Either3::First(never) | Either3::Second(never) | Either3::Third(never) => never,
    }
}

//! The trajectory task: owns the [`Controller`], executes its effects on the hardware
//! ([`Plant`] over the shared step engine and the other devices) and waits for its
//! deferred work.

use core::future::Future;
use core::pin::pin;
use embassy_sync::blocking_mutex::raw::RawMutex;

use arm_step::Segment;
use embassy_futures::select::{Either, Either4, select, select4};
use heapless::Vec;
use protocol::{MAX_JOINTS, Pwm, UartInit};

use super::overtaken::{OvertakingStops, handle_overtaken};
use crate::bus::Bus;
use crate::controller::Controller;
use crate::estop_input::EStopLine;
use crate::hw::{
    Clock, Encoders, Gripper, Outputs, SerialError, SerialPort, SettingsStore, StepKick,
};
use crate::outgoing::{Answer, AnswerReport, Outgoing};
use crate::plant::Plant;
use crate::response::{Deferred, Response};
use crate::step_shared::{START_LEAD_US, StepBackend, StepShared, us_to_ticks};
use crate::switch_line::SwitchLine;

/// The hardware the trajectory task drives besides the step engine.
pub struct TrajectoryHw<'a, K, O, G, P, S, E> {
    /// The step timer.
    pub kick: &'a K,
    /// PIN0/PIN1 and the ENABLE lines.
    pub outputs: O,
    /// The gripper timer.
    pub gripper: G,
    /// The serial port (shared with `serial_task`; opened and closed here).
    pub serial: &'a P,
    /// Persistent settings.
    pub settings: S,
    /// Absolute encoders.
    pub encoders: E,
    /// The wired e-stop input, if the board has one ([`crate::estop_input`]; `None`:
    /// STATUS shows it closed, nothing latches).
    pub estop: Option<&'a EStopLine>,
    /// The safety-door input, if the board has one ([`crate::door_input`]; `None`: the
    /// door reads closed).
    pub door: Option<&'a crate::DoorLine>,
    /// The limit and home switches, if the board has them ([`crate::switch_line`];
    /// `None`: nothing latches on a limit).
    pub switches: Option<&'a SwitchLine>,
}

/// [`Plant`] over the shared engine and the hardware.
struct TaskPlant<'a, const Q: usize, B, M, K, O, G, P> {
    bus: &'a Bus,
    step: &'a StepShared<Q, B, M>,
    kick: &'a K,
    lead_ticks: u64,
    /// Segments were pushed since the step interrupt was last kicked.
    pushed: bool,
    outputs: &'a mut O,
    gripper: &'a mut G,
    serial: &'a P,
    /// The switch inputs (their mask, issue 33).
    switches: Option<&'a SwitchLine>,
}

impl<
    const Q: usize,
    B: StepBackend,
    M: RawMutex,
    K: StepKick,
    O: Outputs,
    G: Gripper,
    P: SerialPort,
> Plant for TaskPlant<'_, Q, B, M, K, O, G, P>
{
    fn positions(&self) -> [i32; MAX_JOINTS] {
        self.step.positions()
    }
    fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool {
        self.step.set_positions(positions)
    }
    fn stop(&mut self) {
        self.step.stop();
        self.kick.kick();
        self.pushed = false;
    }
    fn push_segment(&mut self, segment: Segment) -> bool {
        // Straight into the backend: a run pending on an empty queue starts with its
        // first segment, START_LEAD_US from now.
        let queued = self
            .step
            .push(segment, self.kick.now_tick() + self.lead_ticks);
        self.pushed |= queued;
        queued
    }
    fn start(&mut self) {
        self.step.start(self.kick.now_tick() + self.lead_ticks);
        self.kick.kick();
    }
    fn set_user_pin(&mut self, pin: u8, high: bool) {
        self.outputs.set_user_pin(pin, high);
    }
    fn set_enabled(&mut self, enabled: u16) {
        self.outputs.set_enabled(enabled);
    }
    fn gripper_start(&mut self, pwm: &Pwm) {
        self.gripper.start(pwm);
    }
    fn gripper_stop(&mut self) {
        self.gripper.stop();
    }
    fn gripper_active(&self) -> bool {
        self.gripper.is_active()
    }
    fn serial_open(&mut self, init: &UartInit) -> Result<(), SerialError> {
        self.serial.open(init)?;
        self.bus.serial_opened.signal(*init);
        Ok(())
    }
    fn serial_close(&mut self) {
        // Bytes ACKed but not yet written are dropped with the port, and counted.
        let dropped = self.bus.drop_serial_tx();
        if dropped > 0 {
            warn!(
                "USART_STOP: {} bytes ACKed but not yet sent were dropped",
                dropped
            );
        }
        self.serial.close();
    }
    fn serial_send(&mut self, bytes: &[u8]) -> bool {
        match Vec::from_slice(bytes) {
            Ok(v) => self.bus.serial_tx.try_send(v).is_ok(),
            Err(_) => false,
        }
    }
    fn change_rate(&mut self, rate: u64, accel: u32, speed: u32) -> bool {
        let taken = self
            .step
            .change_rate(self.kick.now_tick(), rate, accel, speed);
        // The step side's next deadline may have moved (a resume, a faster override).
        self.kick.kick();
        taken
    }
    fn set_start_rate(&mut self, rate: u64) {
        self.step.set_start_rate(rate);
    }
    fn rate_now(&self) -> Option<(u64, bool)> {
        self.step.rate_now(self.kick.now_tick())
    }
    fn warp_budget_hz(&self) -> u32 {
        self.step.warp_budget_hz()
    }
    fn set_limit_mask(&mut self, mask: Option<(u8, crate::switches::Side)>) {
        if let Some(line) = self.switches {
            line.set_mask(mask);
        }
    }
}

/// Owns the [`Controller`]: handles datagrams (STOPPED from `bus.estop` first; the wired
/// e-stop input's changes before any event), sends ACKs and reports, executes the effects
/// on the hardware, pushes segments into the step backend (every buffered point that
/// fits, whenever a segment finished: the lookahead is the backend's whole queue) and
/// ends runs when it runs dry. At start: loads the stored settings, takes the gripper
/// timer clock for STATUS, and drives the ENABLE lines to their boot state (all holding).
pub async fn trajectory_task<const CAP: usize, const Q: usize, B, M, C, K, O, G, P, S, E>(
    controller: &mut Controller<CAP>,
    bus: &Bus,
    step: &StepShared<Q, B, M>,
    clock: &C,
    hw: TrajectoryHw<'_, K, O, G, P, S, E>,
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
    let TrajectoryHw {
        kick,
        mut outputs,
        mut gripper,
        serial,
        mut settings,
        mut encoders,
        estop,
        door,
        switches,
    } = hw;
    match settings.load().await {
        Ok(Some(stored)) => controller.apply_settings(stored),
        Ok(None) => {}
        Err(e) => warn!("settings not loaded, using defaults: {:?}", debug_value!(e)),
    }
    // With a key, this boot's epoch is stored before any HELLO is answered
    // (docs/PROTOCOL.md section 13): a reset must never give two boots one epoch.
    if let Some(next) = controller.begin_auth_epoch() {
        match settings.save(&next).await {
            Ok(()) => controller.auth_epoch_stored(),
            Err(e) => warn!(
                "auth epoch not stored, HELLO refused: {:?}",
                debug_value!(e)
            ),
        }
    }
    controller.set_pwm_timer_clock_hz(gripper.timer_clock_hz());
    controller.set_switches_fitted(switches.is_some_and(SwitchLine::any_fitted));
    outputs.set_enabled(controller.enabled());
    publish(bus, controller);
    let lead_ticks = us_to_ticks(u64::from(START_LEAD_US), step.timing().tick_hz);
    // STOPPEDs taken from `bus.estop`, and which of them the controller executed: an
    // inbox datagram stamped with fewer arrived before them; only an executed one stops.
    let mut stops = OvertakingStops::new();
    loop {
        // Biased: a waiting STOPPED is always taken first. (The e-stop input wakes the
        // task through `step_progress`; it is applied below before any event.) A
        // category 1 e-stop's ramp is looked at every ESTOP_RAMP_POLL_US until it ends.
        let ramp_look = controller.estop_ramp_deadline().map(|deadline| {
            deadline.min(
                clock
                    .now_us()
                    .saturating_add(crate::controller::ESTOP_RAMP_POLL_US),
            )
        });
        let event = select4(
            bus.estop.receive(),
            bus.inbox.receive(),
            bus.step_progress.wait(),
            async {
                match ramp_look {
                    Some(at) => clock.sleep_until(at).await,
                    None => core::future::pending().await,
                }
            },
        )
        .await;
        // Taken from the inbox: its slot of the sender's share of the receive path is
        // free again (crate::ingress).
        if let Either4::Second(d) = &event {
            bus.release(d.from.ip);
        }
        let mut plant = TaskPlant {
            bus,
            step,
            kick,
            lead_ticks,
            pushed: false,
            outputs: &mut outputs,
            gripper: &mut gripper,
            serial,
            switches,
        };
        // The input's stop came first (its handler stopped the steps already); whatever
        // this event is, it is handled in the state that stop left. Likewise a limit
        // switch's.
        apply_estop_input(controller, estop, bus, clock.now_us(), &mut plant);
        apply_door(controller, door, bus, &mut plant);
        apply_switches(
            controller,
            switches,
            estop,
            step,
            bus,
            clock.now_us(),
            &mut plant,
        );
        let response = match event {
            Either4::First(d) => {
                let response = controller.handle(d.from, &d.bytes, clock.now_us(), &mut plant);
                // Refused (BAD_LENGTH) or a duplicate: it did nothing, and it must not
                // stop the frames it overtook either.
                stops.took(response.executed);
                response
            }
            Either4::Second(d) if stops.executed_between(d.stops_before, None) => Response {
                deferred: handle_overtaken(controller, bus, d, clock, &mut plant, &stops),
                ..Response::default()
            },
            Either4::Second(d) => controller.handle(d.from, &d.bytes, clock.now_us(), &mut plant),
            Either4::Third(()) | Either4::Fourth(()) => Response::default(),
        };
        // Published before the reports are queued: the network task addresses them when
        // it sends them, possibly while this task waits below.
        publish(bus, controller);
        deliver(bus, &response);
        match response.deferred {
            // Only while STOPPED (the controller refuses the commands otherwise): the
            // erase holds this task, and nothing runs meanwhile. The command's ACK says
            // how the save went.
            Some(Deferred::SaveSettings(s)) => {
                let saved = answering_wakeups(bus, settings.save(&s)).await;
                if let Err(e) = &saved {
                    warn!("settings not saved: {:?}", debug_value!(e));
                }
                let ack = controller.settings_saved(saved.is_ok(), clock.now_us());
                // Published first: a new key's ACK goes out plain (its sessions ended).
                publish(bus, controller);
                if let Some(ack) = ack {
                    bus.send(Outgoing::Ack(ack));
                }
            }
            Some(Deferred::ReadEncoders) => {
                let read = answering_wakeups(bus, encoders.read_joints(controller.joints())).await;
                // An input opened during the read stops the RETURN before it moves.
                apply_estop_input(controller, estop, bus, clock.now_us(), &mut plant);
                let location = match read {
                    Ok(read) => controller.begin_return(read, &mut plant),
                    Err(fault) => {
                        warn!(
                            "RETURN refused: encoder of joint {} failed: {:?}",
                            fault.joint, fault.kind
                        );
                        controller.fail_return(fault, &mut plant)
                    }
                };
                if let Some(location) = location {
                    bus.send(Outgoing::Location(location));
                }
            }
            None => {}
        }
        let (finished, ran_dry) = step.take_progress();
        controller.note_time(clock.now_us());
        if let Some(location) = controller.on_step_progress(finished, ran_dry, &mut plant) {
            bus.send(Outgoing::Location(location));
        }
        // A category 1 e-stop's ramp: at a standstill or past its bound, stopped and the
        // drivers disabled; then the line may leave the next opening to a ramp again.
        if let Some(location) = controller.estop_ramp_poll(clock.now_us(), &mut plant) {
            bus.send(Outgoing::Location(location));
        }
        if let Some(line) = estop
            && controller.estop_ramp_deadline().is_none()
        {
            line.ramp_over();
        }
        if plant.pushed {
            // A producer that was idle between refills takes the new segments now.
            kick.kick();
        }
        publish(bus, controller);
    }
}

/// Awaits deferred work (a settings write, an encoder read) while still being polled at
/// every `bus.step_progress` (the step interrupts', the e-stop input's and the board
/// watchdog's wake-up): the watchdog sees the task alive through a flash erase, and a
/// wake-up taken meanwhile is raised again for the main loop to act on.
async fn answering_wakeups<F: Future>(bus: &Bus, work: F) -> F::Output {
    let mut work = pin!(work);
    let mut woken = false;
    loop {
        match select(work.as_mut(), bus.step_progress.wait()).await {
            Either::First(out) => {
                if woken {
                    bus.step_progress.signal(());
                }
                return out;
            }
            Either::Second(()) => woken = true,
        }
    }
}

/// Brings the controller up to date with the wired e-stop input: every opening since the
/// last look (also one closed again since) stops and latches it (one the handler left to
/// a category 1 ramp starts the ramp), then the level now. First tells the line the
/// stop category (it may have changed with the settings).
fn apply_estop_input<const CAP: usize>(
    controller: &mut Controller<CAP>,
    estop: Option<&EStopLine>,
    bus: &Bus,
    now_us: u64,
    plant: &mut impl Plant,
) {
    let Some(line) = estop else { return };
    line.set_category(controller.estop_category());
    let sample = line.take();
    let location = match sample.opened {
        true if sample.controlled => controller.estop_controlled(now_us, plant),
        true => controller.estop_input(true, plant),
        false => None,
    };
    if let Some(location) = location {
        bus.send(Outgoing::Location(location));
    }
    if !sample.open {
        controller.estop_input(false, plant);
    }
}

/// Brings the controller up to date with the safety door: an opening since the last look
/// (also one closed again since) holds the run, then the level now.
fn apply_door<const CAP: usize>(
    controller: &mut Controller<CAP>,
    door: Option<&crate::DoorLine>,
    bus: &Bus,
    plant: &mut impl Plant,
) {
    let Some(line) = door else { return };
    let sample = line.take();
    if sample.opened
        && let Some(location) = controller.door_input(true, plant)
    {
        bus.send(Outgoing::Location(location));
    }
    if !sample.open {
        controller.door_input(false, plant);
    }
}

/// Brings the controller up to date with the switch inputs: each limit trip stops and
/// latches it (its edge handler halted the steps already), each release lifts the "away
/// only" rule; then the line's halt is lifted (the latch refuses runs from here on).
fn apply_switches<const CAP: usize, const Q: usize, B: StepBackend, M: RawMutex>(
    controller: &mut Controller<CAP>,
    switches: Option<&SwitchLine>,
    estop: Option<&EStopLine>,
    step: &StepShared<Q, B, M>,
    bus: &Bus,
    now_us: u64,
    plant: &mut impl Plant,
) {
    let Some(line) = switches else { return };
    line.poll(now_us);
    while let Some(event) = line.take() {
        if let Some(location) = controller.limit_switch(event, plant) {
            bus.send(Outgoing::Location(location));
        }
    }
    line.resume(step, estop);
}

/// Queues what a handled datagram produced.
pub(super) fn deliver(bus: &Bus, response: &Response) {
    if let Some(reply) = response.reply {
        bus.send(Outgoing::Ack(reply));
    }
    match (response.status, response.answer_seq) {
        (Some((to, status)), None) => bus.send(Outgoing::Status(to, status)),
        (Some((to, status)), Some(seq)) => bus.send(Outgoing::Answer(Answer {
            to,
            seq: Some(seq),
            report: AnswerReport::Status(status),
        })),
        (None, _) => {}
    }
    if let Some((to, limits)) = response.limits {
        bus.send(Outgoing::Answer(Answer {
            to,
            seq: None,
            report: AnswerReport::Limits(limits),
        }));
    }
    if let Some((to, desc)) = response.joint_desc {
        bus.send(Outgoing::Answer(Answer {
            to,
            // A read-only answer to another host carries its request's seq.
            seq: response.answer_seq,
            report: AnswerReport::JointDesc(desc),
        }));
    }
    if let Some((to, location)) = response.asked_location {
        bus.send(Outgoing::Answer(Answer {
            to,
            seq: response.answer_seq,
            report: AnswerReport::Location(location),
        }));
    }
    if let Some((to, stop)) = response.asked_stop {
        bus.send(Outgoing::Answer(Answer {
            to,
            seq: response.answer_seq,
            report: AnswerReport::StopCause(stop),
        }));
    }
    if let Some(to) = response.asked_counters {
        bus.send(Outgoing::Answer(Answer {
            to,
            seq: response.answer_seq,
            report: AnswerReport::RxCounters(bus.rx_counters()),
        }));
    }
    if let Some((to, motion)) = response.asked_motion {
        bus.send(Outgoing::Answer(Answer {
            to,
            seq: response.answer_seq,
            report: AnswerReport::Motion(motion),
        }));
    }
    if let Some((to, switches)) = response.asked_switches {
        bus.send(Outgoing::Answer(Answer {
            to,
            seq: response.answer_seq,
            report: AnswerReport::Switches(switches),
        }));
    }
    if let Some(to) = response.asked_diag {
        bus.send(Outgoing::Answer(Answer {
            to,
            seq: response.answer_seq,
            report: AnswerReport::Diag(bus.diag()),
        }));
    }
    if let Some((to, homing)) = response.homing {
        bus.send(Outgoing::Answer(Answer {
            to,
            seq: None,
            report: AnswerReport::Homing(homing),
        }));
    }
    if let Some(location) = response.location {
        bus.send(Outgoing::Location(location));
    }
    if let Some(discovery) = response.discovery {
        bus.send(Outgoing::Discovery(discovery));
    }
    if let Some(hello) = response.hello {
        bus.send(Outgoing::Hello(hello));
    }
}

/// Copies the report settings, and the addresses the receive path trusts, out for the
/// other tasks; wakes the upload task when its settings changed.
pub(super) fn publish<const CAP: usize>(bus: &Bus, controller: &Controller<CAP>) {
    let new = controller.report_settings();
    let old = bus.reports.lock(|c| c.replace(new));
    // Who takes the reserved share of the receive path (issue 30, crate::source_share).
    bus.set_trusted(controller.trusted_sources());
    if old.reports_on != new.reports_on || old.upload_period_us != new.upload_period_us {
        bus.upload_changed.signal(());
    }
}

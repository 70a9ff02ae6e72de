//! The running bridge: one ROS 2 node (ros2-client on RustDDS) whose action servers,
//! service and publisher run as futures on one thread, and the armctl [`Client`] whose
//! blocking calls run on threads of their own so that a slow controller never holds up
//! joint_states.
//!
//! ```text
//!  controller --LOCATION--> location thread --(sample, arrival stamp)--> joint_states task
//!       ^                        |                                      (one JointState each)
//!       |                        +--> latest sample (feedback, start-state check)
//!       +--- run thread: run_trajectory (NEW, PENDING..., RUNING, wait) <-- trajectory task
//!       +--- STOPPED: cancel, e-stop service;   PWM: gripper task;   STATUS: keep-alive thread
//! ```
//!
//! The FollowJointTrajectory action (goal, streaming, feedback, cancel, result) is in
//! `bridge/trajectory.rs`; the joint_states stream (newest sample first) in
//! `bridge/joint_states.rs`.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant, SystemTime};

use armctl::Client;
use armctl::protocol::{Location, StatusReport};
use armctl::trajectory::ArmConfig;
use async_io::Timer;
use futures::FutureExt;
use ros2_client::action::{ActionServerQosPolicies, AsyncActionServer, GoalEndStatus};
use ros2_client::qos::{Durability, History};
use ros2_client::{
    ActionTypeName, Context, ContextOptions, MessageTypeName, Name, NodeName, NodeOptions,
    QosProfile, ServiceMapping, ServiceTypeName,
};

use crate::config::BridgeConfig;
use crate::goal;
use crate::msgs::{
    FollowJointTrajectoryFeedback, FollowJointTrajectoryGoal, FollowJointTrajectoryResult,
    GripperCommandGoal, GripperCommandResult, Time, TriggerRequest, TriggerResponse,
};

mod joint_states;
mod speed_scaling;
mod trajectory;

type TrajectoryServer = AsyncActionServer<
    FollowJointTrajectoryGoal,
    FollowJointTrajectoryResult,
    FollowJointTrajectoryFeedback,
>;
type GripperServer =
    AsyncActionServer<GripperCommandGoal, GripperCommandResult, GripperCommandResult>;

/// How often the bridge sends STATUS while idle: the controller hands ownership to another
/// host after 5 s of silence (PROTOCOL.md, "Transport and ownership").
const KEEP_ALIVE: Duration = Duration::from_secs(1);

/// How long a finished goal's result waits for the client to ask for it.
const RESULT_WAIT: Duration = Duration::from_secs(10);

/// A LOCATION older than this does not say where the arm is now (reports come every
/// 1 ms to 1 s; the bridge asks for 1 ms to 1 s).
const STALE_LOCATION: Duration = Duration::from_millis(1500);

/// LOCATION reports queued for joint_states at most; older ones are dropped, and the
/// publisher takes the newest of those queued (`bridge/joint_states.rs`): a stale joint
/// state is worse than a missing one.
const SAMPLE_QUEUE: usize = 64;

/// One LOCATION report and the host clock when it arrived.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// The report.
    pub location: Location,
    /// When the bridge received it (the JointState stamp).
    pub stamp: SystemTime,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Runs `work` on a thread of its own and waits for it without blocking the executor;
/// `None` if it panicked.
async fn off_thread<T: Send + 'static>(work: impl FnOnce() -> T + Send + 'static) -> Option<T> {
    let (tx, rx) = async_channel::bounded(1);
    std::thread::spawn(move || {
        let _ = tx.send_blocking(work());
    });
    rx.recv().await.ok()
}

/// The bridge between one controller and the ROS 2 graph.
pub struct Bridge {
    config: BridgeConfig,
    arm: ArmConfig,
    names: Vec<String>,
    controller: Arc<Client>,
    status: StatusReport,
    latest: Arc<Mutex<Option<Sample>>>,
    observers: Arc<Mutex<Vec<mpsc::Sender<Sample>>>>,
    /// The controller's rate now (MOTION), for the feedback's trajectory time.
    rate: Arc<speed_scaling::Rate>,
    /// E-stops served so far: a run that ends STOPPED after one was aborted by it.
    estops: AtomicU64,
    shutdown: Arc<AtomicBool>,
}

impl std::fmt::Debug for Bridge {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bridge")
            .field("controller", &self.config.controller)
            .finish_non_exhaustive()
    }
}

impl Bridge {
    /// Connects to the controller, checks it has the configured joints, and asks for
    /// LOCATION reports at the JointState rate.
    pub fn connect(mut config: BridgeConfig, mut arm: ArmConfig) -> Result<Bridge, String> {
        let key = match &config.key_file {
            Some(path) => Some(armctl::auth::read_key_file(path)?),
            None => None,
        };
        let options = armctl::Options {
            key,
            ..armctl::Options::default()
        };
        let controller = Client::connect_with(config.controller.as_str(), options)
            .map_err(|e| format!("controller {}: {e}", config.controller))?;
        let status = controller.status().map_err(|e| e.to_string())?;
        // A config without joints: the arm the controller keeps (issue 31, `armctl config
        // push`), its names the ROS joint names.
        if arm.joints.is_empty() {
            arm = controller
                .described_arm(usize::from(status.joints), status.max_step_rate_hz)
                .map_err(|e| format!("reading the arm the controller keeps: {e}"))?
                .ok_or_else(|| {
                    "the config lists no joints and the controller keeps no arm description: \
                     push one (`armctl config push ARM.json`) or list `joints` in the config"
                        .to_string()
                })?;
            config.take_described(&arm)?;
        }
        if usize::from(status.joints) < arm.joints.len() {
            return Err(format!(
                "the controller has {} joints, the config {}",
                status.joints,
                arm.joints.len()
            ));
        }
        // Joints the file leaves unnamed take the names the controller keeps (issue 31:
        // `armctl config push`); a controller older than that names none.
        if config.joint_names().iter().any(String::is_empty) {
            let described: Vec<String> = (0..config.joints.len().min(armctl::protocol::MAX_JOINTS))
                .map_while(|j| {
                    controller
                        .joint_desc(u8::try_from(j).unwrap_or(u8::MAX))
                        .ok()
                })
                .map(|d| d.name().to_string())
                .collect();
            if config.name_unnamed(&described) > 0 {
                for (joint, name) in arm.joints.iter_mut().zip(config.joint_names()) {
                    if joint.name.is_none() && !name.is_empty() {
                        joint.name = Some(name);
                    }
                }
            }
        }
        let period_us = (1e6 / config.joint_state_rate_hz).round() as u32;
        controller
            .upload_period(period_us.clamp(1000, 1_000_000))
            .map_err(|e| e.to_string())?;
        controller.reports(true).map_err(|e| e.to_string())?;
        let names = config.joint_names();
        Ok(Bridge {
            config,
            arm,
            names,
            controller: Arc::new(controller),
            status,
            latest: Arc::new(Mutex::new(None)),
            observers: Arc::new(Mutex::new(Vec::new())),
            rate: Arc::new(speed_scaling::Rate::default()),
            estops: AtomicU64::new(0),
            shutdown: Arc::new(AtomicBool::new(false)),
        })
    }

    /// Every LOCATION sample the bridge turns into a JointState, as it does (for tests and
    /// tools that compare the two).
    pub fn observe(&self) -> mpsc::Receiver<Sample> {
        let (tx, rx) = mpsc::channel();
        lock(&self.observers).push(tx);
        rx
    }

    /// The controller connection (shared with the bridge's threads).
    pub fn controller(&self) -> &Arc<Client> {
        &self.controller
    }

    /// The joint config.
    pub fn arm(&self) -> &ArmConfig {
        &self.arm
    }

    /// The last LOCATION sample.
    pub fn latest(&self) -> Option<Sample> {
        *lock(&self.latest)
    }

    /// Serves ROS 2 until `stop` receives (or closes).
    pub fn run(&self, stop: async_channel::Receiver<()>) -> Result<(), String> {
        let (sample_tx, sample_rx) = async_channel::bounded(SAMPLE_QUEUE);
        let location_thread = self.start_location_thread(sample_tx, sample_rx.clone());
        let keep_alive_thread = self.start_keep_alive_thread();
        let (scaling_tx, scaling_rx) = async_channel::bounded(1);
        let motion_thread = self.start_motion_thread(scaling_tx, scaling_rx.clone());
        let result = self.serve(sample_rx, scaling_rx, stop);
        self.shutdown.store(true, Ordering::Relaxed);
        let _ = location_thread.join();
        let _ = keep_alive_thread.join();
        let _ = motion_thread.join();
        result
    }

    fn start_location_thread(
        &self,
        samples: async_channel::Sender<Sample>,
        oldest: async_channel::Receiver<Sample>,
    ) -> std::thread::JoinHandle<()> {
        let locations = self.controller.locations();
        let latest = self.latest.clone();
        let observers = self.observers.clone();
        let shutdown = self.shutdown.clone();
        std::thread::spawn(move || {
            while !shutdown.load(Ordering::Relaxed) {
                let Ok(location) = locations.recv_timeout(Duration::from_millis(100)) else {
                    continue;
                };
                let sample = Sample {
                    location,
                    stamp: SystemTime::now(),
                };
                *lock(&latest) = Some(sample);
                lock(&observers).retain(|o| o.send(sample).is_ok());
                if samples.is_full() {
                    let _ = oldest.try_recv();
                }
                let _ = samples.try_send(sample);
            }
        })
    }

    fn start_keep_alive_thread(&self) -> std::thread::JoinHandle<()> {
        let controller = self.controller.clone();
        let shutdown = self.shutdown.clone();
        std::thread::spawn(move || {
            let mut next = Instant::now() + KEEP_ALIVE;
            while !shutdown.load(Ordering::Relaxed) {
                std::thread::sleep(Duration::from_millis(100));
                if Instant::now() >= next {
                    if let Err(e) = controller.status() {
                        log::warn!("keep-alive STATUS: {e}");
                    }
                    next = Instant::now() + KEEP_ALIVE;
                }
            }
        })
    }

    /// Reads the MOTION report every `1 / speed_scaling_rate_hz` (issue 32): the rate for
    /// the feedback, and the speed scaling state in percent to publish (the newest only).
    /// A controller older than issue 32 has no MOTION: nothing is published then.
    fn start_motion_thread(
        &self,
        states: async_channel::Sender<f64>,
        oldest: async_channel::Receiver<f64>,
    ) -> std::thread::JoinHandle<()> {
        let controller = self.controller.clone();
        let shutdown = self.shutdown.clone();
        let rate = self.rate.clone();
        let period = Duration::from_secs_f64(1.0 / self.config.speed_scaling_rate_hz);
        std::thread::spawn(move || {
            let mut warned = false;
            while !shutdown.load(Ordering::Relaxed) {
                let next = Instant::now() + period;
                match controller.motion() {
                    Ok((_, Some(motion))) => {
                        rate.set(motion.rate_permille);
                        if states.is_full() {
                            let _ = oldest.try_recv();
                        }
                        let _ = states.try_send(f64::from(motion.rate_permille) / 10.0);
                    }
                    Ok((_, None)) if !warned => {
                        warned = true;
                        log::warn!(
                            "the controller sends no MOTION report (older than issue 32): no speed scaling state"
                        );
                    }
                    Ok(_) => {}
                    Err(e) => log::debug!("MOTION: {e}"),
                }
                std::thread::sleep(next.saturating_duration_since(Instant::now()));
            }
        })
    }

    fn serve(
        &self,
        samples: async_channel::Receiver<Sample>,
        scaling_states: async_channel::Receiver<f64>,
        stop: async_channel::Receiver<()>,
    ) -> Result<(), String> {
        let name = |full: &str| -> Result<Name, String> {
            let (namespace, base) = full.rsplit_once('/').unwrap_or(("", full));
            let namespace = if namespace.is_empty() && full.starts_with('/') {
                "/"
            } else {
                namespace
            };
            Name::new(namespace, base).map_err(|e| format!("ROS name {full:?}: {e:?}"))
        };
        // Every reader and writer announces its type's RIHS01 hash (Jazzy and later).
        let distro = self.config.distro();
        let type_hash: ros2_client::TypeHashFn =
            Arc::new(move |dds_type: &str| crate::typehash::dds_type_hash(distro, dds_type));
        let context = Context::with_options(
            ContextOptions::new()
                .domain_id(self.config.domain_id)
                .type_hash(type_hash),
        )
        .map_err(|e| format!("DDS: {e:?}"))?;
        let mut node = context
            .new_node(
                NodeName::new(&self.config.namespace, &self.config.node_name)
                    .map_err(|e| format!("node name: {e:?}"))?,
                NodeOptions::new(),
            )
            .map_err(|e| format!("node: {e:?}"))?;

        let joint_states_topic = node
            .create_topic(
                &name(&self.config.joint_states_topic)?,
                MessageTypeName::new("sensor_msgs", "JointState"),
                &QosProfile::publisher_default()
                    .durability(Durability::Volatile)
                    .history(History::KeepLast { depth: 10 }),
            )
            .map_err(|e| format!("joint_states topic: {e:?}"))?;
        let joint_states = node
            .create_publisher::<crate::msgs::JointState>(&joint_states_topic, None)
            .map_err(|e| format!("joint_states publisher: {e:?}"))?;

        let trajectory_server: TrajectoryServer = AsyncActionServer::new(
            node.create_action_server(
                ServiceMapping::Enhanced,
                &name(&self.config.action_name)?,
                &ActionTypeName::new("control_msgs", "FollowJointTrajectory"),
                action_qos(),
            )
            .map_err(|e| format!("FollowJointTrajectory server: {e:?}"))?,
        );
        let gripper_server: Option<GripperServer> = match &self.config.gripper {
            Some(_) => Some(AsyncActionServer::new(
                node.create_action_server(
                    ServiceMapping::Enhanced,
                    &name(&self.config.gripper_action_name)?,
                    &ActionTypeName::new("control_msgs", "GripperCommand"),
                    action_qos(),
                )
                .map_err(|e| format!("GripperCommand server: {e:?}"))?,
            )),
            None => None,
        };
        let service_qos = QosProfile::publisher_default()
            .durability(Durability::Volatile)
            .history(History::KeepLast { depth: 10 });
        let estop_server = node
            .create_server::<TriggerRequest, TriggerResponse>(
                ServiceMapping::Enhanced,
                &name(&self.config.estop_service)?,
                &ServiceTypeName::new("std_srvs", "Trigger"),
                service_qos.clone(),
                service_qos.clone(),
            )
            .map_err(|e| format!("e-stop service: {e:?}"))?;
        // HOLD and RESUME (issue 32): the same Trigger type and QoS as the e-stop's.
        let mut trigger = |service: &str, what: &str| {
            let qos = QosProfile::publisher_default()
                .durability(Durability::Volatile)
                .history(History::KeepLast { depth: 10 });
            node.create_server::<TriggerRequest, TriggerResponse>(
                ServiceMapping::Enhanced,
                &name(service)?,
                &ServiceTypeName::new("std_srvs", "Trigger"),
                qos.clone(),
                qos,
            )
            .map_err(|e| format!("{what} service: {e:?}"))
        };
        let hold_server = trigger(&self.config.hold_service, "hold")?;
        let resume_server = trigger(&self.config.resume_service, "resume")?;
        let home_server = node
            .create_server::<TriggerRequest, TriggerResponse>(
                ServiceMapping::Enhanced,
                &name(&self.config.home_service)?,
                &ServiceTypeName::new("std_srvs", "Trigger"),
                service_qos.clone(),
                service_qos,
            )
            .map_err(|e| format!("home service: {e:?}"))?;
        // Speed scaling (issue 32), as UR's: a fraction in, percent out.
        let scaling_qos = QosProfile::publisher_default()
            .durability(Durability::Volatile)
            .history(History::KeepLast { depth: 10 });
        let float64 = || MessageTypeName::new("std_msgs", "Float64");
        let scaling_topic = node
            .create_topic(
                &name(&self.config.speed_scaling_topic)?,
                float64(),
                &scaling_qos,
            )
            .map_err(|e| format!("speed scaling topic: {e:?}"))?;
        let scaling_input = node
            .create_subscription::<crate::msgs::Float64>(&scaling_topic, None)
            .map_err(|e| format!("speed scaling subscription: {e:?}"))?;
        let scaling_state_topic = node
            .create_topic(
                &name(&self.config.speed_scaling_state_topic)?,
                float64(),
                &scaling_qos,
            )
            .map_err(|e| format!("speed scaling state topic: {e:?}"))?;
        let scaling_state = node
            .create_publisher::<crate::msgs::Float64>(&scaling_state_topic, None)
            .map_err(|e| format!("speed scaling state publisher: {e:?}"))?;
        let spinner = node.spinner().map_err(|e| format!("spinner: {e:?}"))?;

        let publish_joint_states = joint_states::publish_samples(&samples, |sample: Sample| {
            let state = goal::joint_state(
                &self.names,
                &self.arm,
                &sample.location.position,
                Time::from_system(sample.stamp),
            );
            let joint_states = &joint_states;
            async move {
                if let Err(e) = joint_states.async_publish(state).await {
                    log::warn!("joint_states: {e:?}");
                }
            }
        });
        let serve_estop = async {
            loop {
                match estop_server.async_receive_request().await {
                    Ok((request, _)) => {
                        let received = Instant::now();
                        let response = self.estop().await;
                        let stopped = received.elapsed();
                        wait_reply_reader(&estop_server, request).await;
                        if let Err(e) = estop_server.async_send_response(request, response).await {
                            log::warn!("e-stop response: {e:?}");
                        }
                        log::info!(
                            "e-stop request {request:?} answered {:.1} ms after it was received (STOPPED acknowledged after {:.1} ms)",
                            received.elapsed().as_secs_f64() * 1e3,
                            stopped.as_secs_f64() * 1e3
                        );
                    }
                    Err(e) => log::warn!("e-stop request: {e:?}"),
                }
            }
        };
        let serve_hold = serve_trigger(&hold_server, "HOLD", self.controller.clone(), Client::hold);
        let serve_resume = serve_trigger(
            &resume_server,
            "RESUME",
            self.controller.clone(),
            Client::resume,
        );
        let serve_speed_scaling = async {
            loop {
                match scaling_input.async_take().await {
                    Ok((factor, _)) => self.set_speed_scaling(factor.data).await,
                    Err(e) => log::warn!("speed scaling: {e:?}"),
                }
            }
        };
        let publish_speed_scaling = async {
            while let Ok(mut percent) = scaling_states.recv().await {
                while let Ok(newer) = scaling_states.try_recv() {
                    percent = newer;
                }
                let state = crate::msgs::Float64 { data: percent };
                if let Err(e) = scaling_state.async_publish(state).await {
                    log::warn!("speed scaling state: {e:?}");
                }
            }
        };
        // Issue 33: homing, one request at a time (a second waits for the first's answer).
        let serve_home = async {
            loop {
                match home_server.async_receive_request().await {
                    Ok((request, _)) => {
                        let response = self.home().await;
                        wait_reply_reader(&home_server, request).await;
                        if let Err(e) = home_server.async_send_response(request, response).await {
                            log::warn!("home response: {e:?}");
                        }
                    }
                    Err(e) => log::warn!("home request: {e:?}"),
                }
            }
        };
        let serve_gripper = async {
            match &gripper_server {
                Some(server) => self.serve_gripper(server).await,
                None => futures::future::pending().await,
            }
        };
        let all = async {
            futures::join!(
                spinner.spin().map(|r| {
                    if let Err(e) = r {
                        log::error!("spinner: {e:?}");
                    }
                }),
                publish_joint_states,
                self.serve_trajectories(&trajectory_server),
                serve_gripper,
                serve_estop,
                serve_hold,
                serve_resume,
                serve_home,
                serve_speed_scaling,
                publish_speed_scaling,
            );
        };
        async_io::block_on(async {
            futures::select! {
                _ = all.fuse() => {},
                _ = stop.recv().fuse() => {},
            }
        });
        Ok(())
    }

    /// STOPPED, as the e-stop service's answer.
    async fn estop(&self) -> TriggerResponse {
        self.estops.fetch_add(1, Ordering::SeqCst);
        let controller = self.controller.clone();
        match off_thread(move || controller.stop()).await {
            Some(Ok(ack)) => TriggerResponse {
                success: true,
                message: format!(
                    "STOPPED acknowledged, controller state {}",
                    ack.state.name()
                ),
            },
            Some(Err(e)) => TriggerResponse {
                success: false,
                message: format!("STOPPED failed: {e}"),
            },
            None => TriggerResponse {
                success: false,
                message: "STOPPED failed: internal error".into(),
            },
        }
    }

    /// A speed scaling input: OVERRIDE to the controller (from a thread of its own), or
    /// the refusal logged. The state topic shows what the controller took.
    async fn set_speed_scaling(&self, factor: f64) {
        let percent = match speed_scaling::override_percent(factor) {
            Ok(percent) => percent,
            Err(e) => return log::warn!("{e}"),
        };
        let controller = self.controller.clone();
        match off_thread(move || controller.set_override(percent)).await {
            Some(Ok(_)) => log::info!("speed scaling {factor}: OVERRIDE {percent} % taken"),
            Some(Err(e)) => log::warn!("speed scaling {factor}: OVERRIDE {percent} %: {e}"),
            None => log::warn!("speed scaling {factor}: internal error"),
        }
    }

    /// Homes the arm, as the home service's answer: on its switches when it has them
    /// (HOME, waiting up to 10 minutes for the cycle), else RETURN (not waited for).
    async fn home(&self) -> TriggerResponse {
        let controller = self.controller.clone();
        match off_thread(move || controller.home(std::time::Duration::from_secs(600))).await {
            Some(Ok(armctl::Homed::OnSwitches(report))) => TriggerResponse {
                success: true,
                message: format!("homed on the switches (joints {:#04x})", report.homed),
            },
            Some(Ok(armctl::Homed::ByReturn)) => TriggerResponse {
                success: true,
                message: "no switch set to home: RETURN sent".into(),
            },
            Some(Err(e)) => TriggerResponse {
                success: false,
                message: format!("homing failed: {e}"),
            },
            None => TriggerResponse {
                success: false,
                message: "homing failed: internal error".into(),
            },
        }
    }

    /// Sends STOPPED from a thread of its own (it must not wait behind anything).
    fn stop_detached(&self) {
        let controller = self.controller.clone();
        std::thread::spawn(move || {
            if let Err(e) = controller.stop() {
                log::error!("STOPPED: {e}");
            }
        });
    }

    async fn serve_gripper(&self, server: &GripperServer) {
        let Some(gripper) = self.config.gripper.clone() else {
            return;
        };
        loop {
            futures::select! {
                new_goal = server.receive_new_goal().fuse() => {
                    let Ok(handle) = new_goal else { continue };
                    let Some(goal) = server.get_new_goal(handle) else { continue };
                    let position = goal.command.position;
                    // Out of the configured range: rejected, so the client knows at once
                    // (issue 22: it was accepted and aborted with `position nan`).
                    if let Err(e) = gripper.duty(position) {
                        log::warn!("gripper goal rejected: {e}");
                        let _ = server.reject_goal(handle).await;
                        continue;
                    }
                    let Ok(accepted) = server.accept_goal(handle).await else { continue };
                    let Ok(executing) = server.start_executing_goal(accepted).await else { continue };
                    let applied = match gripper.duty(position) {
                        Err(e) => Err(e),
                        Ok(duty) => {
                            let controller = self.controller.clone();
                            let clock = self.status.pwm_timer_clock_hz;
                            let hz = gripper.pwm_hz;
                            off_thread(move || {
                                let pwm = armctl::pwm::settings(clock, hz, duty, 0)?;
                                controller.pwm_start(pwm).map_err(|e| e.to_string())
                            })
                            .await
                            .unwrap_or_else(|| Err("internal error".into()))
                            .map(|_| duty)
                        }
                    };
                    let (status, reached) = match applied {
                        Ok(duty) => {
                            log::info!("gripper to {position} m: duty {duty:.4}");
                            // Feedback (issue 22: there was none): the PWM is set, the servo
                            // moving for `settle_ms` (a hobby servo reports nothing back).
                            let moving = GripperCommandResult {
                                position,
                                effort: 0.0,
                                stalled: false,
                                reached_goal: false,
                            };
                            if let Err(e) = server.publish_feedback(executing, moving).await {
                                log::warn!("gripper feedback: {e:?}");
                            }
                            Timer::after(Duration::from_millis(gripper.settle_ms)).await;
                            (GoalEndStatus::Succeeded, true)
                        }
                        Err(e) => {
                            log::warn!("gripper: {e}");
                            (GoalEndStatus::Aborted, false)
                        }
                    };
                    let result = GripperCommandResult {
                        position: if reached { position } else { f64::NAN },
                        effort: 0.0,
                        stalled: false,
                        reached_goal: reached,
                    };
                    futures::select! {
                        sent = server.send_result_response(executing, status, result).fuse() => {
                            if let Err(e) = sent { log::warn!("gripper result: {e:?}"); }
                        }
                        _ = FutureExt::fuse(Timer::after(RESULT_WAIT)) => {},
                    }
                },
                cancel = server.receive_cancel_request().fuse() => if let Ok(cancel) = cancel {
                    // A servo command is one PWM setting: nothing to cancel.
                    let _ = server.respond_to_cancel_requests(&cancel, std::iter::empty()).await;
                },
            }
        }
    }
}

/// How long a service answer waits at most for the client's reply reader to be matched.
const REPLY_MATCH_WAIT: Duration = Duration::from_secs(1);

/// Serves a `std_srvs/Trigger` service that sends one command (HOLD, RESUME; issue 32)
/// from a thread of its own, as the e-stop's: `success` once the controller acknowledged
/// it `OK`, else the refusal.
async fn serve_trigger(
    server: &ros2_client::Server<TriggerRequest, TriggerResponse>,
    what: &'static str,
    controller: Arc<Client>,
    send: fn(&Client) -> armctl::Result<armctl::protocol::Ack>,
) {
    loop {
        match server.async_receive_request().await {
            Ok((request, _)) => {
                let controller = controller.clone();
                let response = match off_thread(move || send(&controller)).await {
                    Some(Ok(ack)) => TriggerResponse {
                        success: true,
                        message: format!(
                            "{what} acknowledged, controller state {}",
                            ack.state.name()
                        ),
                    },
                    Some(Err(e)) => TriggerResponse {
                        success: false,
                        message: format!("{what} failed: {e}"),
                    },
                    None => TriggerResponse {
                        success: false,
                        message: format!("{what} failed: internal error"),
                    },
                };
                wait_reply_reader(server, request).await;
                if let Err(e) = server.async_send_response(request, response).await {
                    log::warn!("{what} response: {e:?}");
                }
            }
            Err(e) => log::warn!("{what} request: {e:?}"),
        }
    }
}

/// Waits (bounded, polling every millisecond) until the server's reply writer has matched
/// the reply reader of the client that sent `request`. A new rclpy client may send its
/// first request as soon as *it* has matched the bridge's endpoints, before the bridge
/// has discovered its reply reader; an answer written then is never delivered (a volatile
/// writer sends a reader only what it writes after the match), and the client waits
/// forever. rmw_fastrtps's own servers wait for the match the same way.
async fn wait_reply_reader<Q: ros2_client::Message + 'static, A: ros2_client::Message + 'static>(
    server: &ros2_client::Server<Q, A>,
    request: ros2_client::service::RmwRequestId,
) {
    let start = Instant::now();
    loop {
        match server.is_response_reader_matched(request) {
            Some(true) | None => break,
            Some(false) if start.elapsed() >= REPLY_MATCH_WAIT => {
                log::warn!(
                    "service answer: the client's reply reader is still not matched after {} ms; answering anyway",
                    start.elapsed().as_millis()
                );
                return;
            }
            Some(false) => {
                Timer::after(Duration::from_millis(1)).await;
            }
        }
    }
    if start.elapsed() >= Duration::from_millis(1) {
        log::info!(
            "service answer waited {:.1} ms for the client's reply reader to be matched",
            start.elapsed().as_secs_f64() * 1e3
        );
    }
}

/// ROS 2's QoS for actions: volatile services and feedback, transient-local status.
pub fn action_qos() -> ActionServerQosPolicies {
    let volatile = QosProfile::publisher_default()
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 10 });
    ActionServerQosPolicies {
        goal_service: volatile.clone(),
        result_service: volatile.clone(),
        cancel_service: volatile.clone(),
        feedback_publisher: volatile,
        status_publisher: QosProfile::publisher_default()
            .history(History::KeepLast { depth: 1 })
            .durability(Durability::TransientLocal),
    }
}

//! The FollowJointTrajectory action: a goal checked and planned (`goal.rs`), streamed with
//! `run_trajectory` on a thread of its own, with feedback from the LOCATION samples, a
//! cancel as STOPPED, and the result from where the arm ended.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use armctl::protocol::{MAX_JOINTS, State, Tag};
use armctl::{Error, Progress, RunOptions, RunReport};
use async_io::Timer;
use futures::{FutureExt, StreamExt};
use ros2_client::action::{ExecutingGoalHandle, GoalEndStatus, NewGoalHandle};

use super::{Bridge, RESULT_WAIT, STALE_LOCATION, Sample, TrajectoryServer, lock, off_thread};
use crate::goal::{self, Plan};
use crate::msgs::{FollowJointTrajectoryGoal, FollowJointTrajectoryResult, Time};

impl Bridge {
    /// Serves FollowJointTrajectory goals, one at a time, until the bridge stops.
    pub(super) async fn serve_trajectories(&self, server: &TrajectoryServer) {
        loop {
            futures::select! {
                new_goal = server.receive_new_goal().fuse() => match new_goal {
                    Ok(handle) => self.handle_goal(server, handle).await,
                    Err(e) => log::warn!("FollowJointTrajectory goal: {e:?}"),
                },
                cancel = server.receive_cancel_request().fuse() => if let Ok(cancel) = cancel {
                    // Nothing runs: nothing to cancel.
                    let _ = server.respond_to_cancel_requests(&cancel, std::iter::empty()).await;
                },
            }
        }
    }

    /// Where the arm is: the last LOCATION if recent, else a fresh one.
    async fn current_position(&self) -> Result<[i32; MAX_JOINTS], String> {
        let recent = |s: &Sample| s.stamp.elapsed().is_ok_and(|age| age < STALE_LOCATION);
        if let Some(sample) = self.latest().filter(recent) {
            return Ok(sample.location.position);
        }
        let controller = self.controller.clone();
        match off_thread(move || controller.current_location(Duration::from_secs(1))).await {
            Some(Ok(location)) => Ok(location.position),
            Some(Err(e)) => Err(e.to_string()),
            None => Err("internal error reading the position".into()),
        }
    }

    async fn handle_goal(
        &self,
        server: &TrajectoryServer,
        handle: NewGoalHandle<FollowJointTrajectoryGoal>,
    ) {
        let Some(goal) = server.get_new_goal(handle.clone()) else {
            return;
        };
        let planned = match self.current_position().await {
            Ok(current) => goal::plan(
                &goal,
                &self.config,
                &self.arm,
                &current,
                Some(self.status.max_step_rate_hz).filter(|&r| r > 0),
            ),
            Err(e) => Err(goal::Refusal {
                code: FollowJointTrajectoryResult::INVALID_GOAL,
                message: format!("the arm's position is unknown: {e}"),
            }),
        };
        // Invalid goals are accepted and aborted at once rather than rejected: a rejection
        // carries no reason, the result's error string does.
        let executing = match server.accept_goal(handle).await {
            Ok(accepted) => match server.start_executing_goal(accepted).await {
                Ok(executing) => executing,
                Err(e) => return log::warn!("start goal: {e:?}"),
            },
            Err(e) => return log::warn!("accept goal: {e:?}"),
        };
        let (status, result) = match planned {
            Err(refusal) => {
                log::info!("goal refused: {}", refusal.message);
                (
                    GoalEndStatus::Aborted,
                    FollowJointTrajectoryResult {
                        error_code: refusal.code,
                        error_string: refusal.message,
                    },
                )
            }
            Ok(plan) if plan.points.is_empty() => (
                GoalEndStatus::Succeeded,
                FollowJointTrajectoryResult {
                    error_code: FollowJointTrajectoryResult::SUCCESSFUL,
                    error_string: "the goal is where the arm is: nothing to move".into(),
                },
            ),
            Ok(plan) => self.execute(server, executing.clone(), &plan).await,
        };
        log::info!(
            "goal ended {status:?}: {} {}",
            result.error_code,
            result.error_string
        );
        futures::select! {
            sent = server.send_result_response(executing, status, result).fuse() => {
                if let Err(e) = sent {
                    log::warn!("result: {e:?}");
                }
            }
            _ = FutureExt::fuse(Timer::after(RESULT_WAIT)) => log::warn!("nobody asked for the result"),
        }
    }

    /// Streams `plan` with armctl's client, publishing feedback, serving cancels and
    /// rejecting other goals until the run ends.
    async fn execute(
        &self,
        server: &TrajectoryServer,
        executing: ExecutingGoalHandle<FollowJointTrajectoryGoal>,
        plan: &Plan,
    ) -> (GoalEndStatus, FollowJointTrajectoryResult) {
        let running_since: Arc<Mutex<Option<Instant>>> = Arc::new(Mutex::new(None));
        let executed = Arc::new(AtomicU64::new(0));
        let (done_tx, done_rx) = async_channel::bounded::<armctl::Result<RunReport>>(1);
        let estops_before = self.estops.load(Ordering::SeqCst);
        {
            let controller = self.controller.clone();
            let points = plan.points.clone();
            let running_since = running_since.clone();
            let executed = executed.clone();
            // The speed scaling input may slow the run down to 1 % at any time, and a hold
            // stops it (issue 32): wait as long as the slowest factor takes (armctl's rule:
            // twice the duration plus 10 s), not the nominal duration.
            let nominal_us: u64 = points
                .iter()
                .map(|p| u64::try_from(p.duration).unwrap_or(0))
                .sum();
            let options = RunOptions {
                completion_timeout: Some(
                    Duration::from_micros(nominal_us.saturating_mul(100 * 2))
                        + Duration::from_secs(10),
                ),
                ..RunOptions::default()
            };
            std::thread::spawn(move || {
                let result = controller.run_trajectory(&points, &options, |p: &Progress| {
                    executed.store(p.executed as u64, Ordering::Relaxed);
                    if p.state == State::Running {
                        lock(&running_since).get_or_insert_with(Instant::now);
                    }
                });
                let _ = done_tx.send_blocking(result);
            });
        }
        let period = Duration::from_secs_f64(1.0 / self.config.feedback_rate_hz);
        let mut ticker = Timer::interval(period);
        let mut clock = super::speed_scaling::Clock::default();
        let mut canceled = false;
        let mut path_violation: Option<String> = None;
        let outcome = loop {
            futures::select! {
                done = done_rx.recv().fuse() => break done.ok(),
                // After a cancel the goal is CANCELING: no more feedback for it.
                _ = ticker.next().fuse() => if !canceled {
                    // Trajectory time, at the controller's rate (speed scaling, holds).
                    let running = lock(&running_since).is_some();
                    let elapsed_us = clock.advance(Instant::now(), running, self.rate.permille());
                    let desired = plan.desired_steps(elapsed_us);
                    let actual = self.latest().map_or(plan.start, |s| s.location.position);
                    let feedback = goal::feedback(plan, &self.arm, &desired, &actual, elapsed_us,
                        Time::from_system(SystemTime::now()), self.config.distro());
                    if let Err(e) = server.publish_feedback(executing.clone(), feedback).await {
                        log::warn!("feedback: {e:?}");
                    }
                    if path_violation.is_none() && !canceled
                        && let Some(why) = goal::path_violation(plan, &self.arm, &desired, &actual)
                    {
                        path_violation = Some(why);
                        self.stop_detached();
                    }
                },
                cancel = server.receive_cancel_request().fuse() => if let Ok(cancel) = cancel {
                    let mine = executing.goal_id();
                    if cancel.contains_goal(&mine) {
                        canceled = true;
                        self.stop_detached();
                        let _ = server.respond_to_cancel_requests(&cancel, std::iter::once(mine)).await;
                    } else {
                        let _ = server.respond_to_cancel_requests(&cancel, std::iter::empty()).await;
                    }
                },
                other = server.receive_new_goal().fuse() => if let Ok(other) = other {
                    // One trajectory at a time: MoveIt waits for the running one or cancels it.
                    log::info!("goal rejected: another goal is running");
                    let _ = server.reject_goal(other).await;
                },
            }
        };
        let executed = executed.load(Ordering::Relaxed);
        let total = plan.points.len();
        let position = |p: &[i32; MAX_JOINTS]| -> String {
            let rad: Vec<String> = (0..self.arm.joints.len())
                .map(|j| format!("{:.4}", goal::radians(&self.arm, j, f64::from(p[j]))))
                .collect();
            format!("[{}] rad", rad.join(", "))
        };
        let result = |code: i32, message: String| FollowJointTrajectoryResult {
            error_code: code,
            error_string: message,
        };
        let end_position = match &outcome {
            Some(Ok(report)) => report.final_location.map(|l| l.position),
            _ => None,
        }
        .or_else(|| self.latest().map(|s| s.location.position));
        match outcome {
            _ if canceled => (
                GoalEndStatus::Canceled,
                result(
                    FollowJointTrajectoryResult::SUCCESSFUL,
                    format!(
                        "canceled: STOPPED sent to the controller after about {executed} of \
                         {total} points; the arm stopped at {}",
                        end_position.map_or("an unknown position".into(), |p| position(&p))
                    ),
                ),
            ),
            Some(Ok(_)) => match end_position {
                Some(end) => match goal::check_end(plan, &self.arm, &self.config, &end) {
                    Ok(summary) => (
                        GoalEndStatus::Succeeded,
                        result(FollowJointTrajectoryResult::SUCCESSFUL, summary),
                    ),
                    Err(why) => (
                        GoalEndStatus::Aborted,
                        result(FollowJointTrajectoryResult::GOAL_TOLERANCE_VIOLATED, why),
                    ),
                },
                None => (
                    GoalEndStatus::Aborted,
                    result(
                        FollowJointTrajectoryResult::GOAL_TOLERANCE_VIOLATED,
                        "the run ended but no LOCATION report says where the arm is".into(),
                    ),
                ),
            },
            Some(Err(e)) => {
                let code = match &e {
                    // Refused or unanswered before anything was uploaded: nothing moved.
                    Error::Refused {
                        command: Tag::New, ..
                    }
                    | Error::NoReply {
                        command: Tag::New, ..
                    }
                    | Error::InvalidTrajectory(_) => FollowJointTrajectoryResult::INVALID_GOAL,
                    _ => FollowJointTrajectoryResult::PATH_TOLERANCE_VIOLATED,
                };
                let why = if let Some(why) = path_violation {
                    format!("{why}: STOPPED sent ({e})")
                } else if self.estops.load(Ordering::SeqCst) != estops_before {
                    format!("stopped by the e-stop service: {e}")
                } else {
                    e.to_string()
                };
                (
                    GoalEndStatus::Aborted,
                    result(
                        code,
                        format!(
                            "{why}; the arm is at {}",
                            end_position.map_or("an unknown position".into(), |p| position(&p))
                        ),
                    ),
                )
            }
            None => (
                GoalEndStatus::Aborted,
                result(
                    FollowJointTrajectoryResult::PATH_TOLERANCE_VIOLATED,
                    "the streaming thread failed".into(),
                ),
            ),
        }
    }
}

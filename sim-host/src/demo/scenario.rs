//! The demo's scenario: one method per phase, in the order [`drive`] runs them.

use std::io::{self, IsTerminal};
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use armctl::Client;
use armctl::plot::Commanded;
use armctl::record::Sample;
use protocol::{Point, State, StatusFlags, UartInit};

use super::{
    ABOVE_PICK, ABOVE_PLACE, Check, DemoOptions, Display, HOME, JOINTS, Leg, PICK, PLACE, Pose,
    add_commanded, default_plot_path, plan, run_start, run_with_display, to_io,
};
use crate::app::Board;

/// The demo's scenario, phase by phase: [`Scenario::connect`], [`Scenario::serial_and_pin`],
/// [`Scenario::pick_and_place`], [`Scenario::emergency_stop`], [`Scenario::check_stopped`],
/// [`Scenario::finish`].
pub(super) fn drive(
    board: &Board,
    addr: std::net::SocketAddr,
    demo: &DemoOptions,
) -> io::Result<()> {
    let mut scenario = Scenario::connect(board, addr, demo)?;
    scenario.serial_and_pin()?;
    let at = scenario.pick_and_place()?;
    let retreat = scenario.emergency_stop(at)?;
    scenario.check_stopped(at, &retreat)?;
    scenario.finish(demo)
}

/// The state the phases of the demo share.
struct Scenario<'a> {
    board: &'a Board,
    arm: Arc<Client>,
    /// STATUS read at connection.
    status: protocol::StatusReport,
    /// When the recording started: the time origin of the plot.
    t0: Instant,
    /// Every LOCATION report, for the plot.
    recording: Arc<Mutex<Vec<Sample>>>,
    checks: Vec<Check>,
    display: Arc<Mutex<Display>>,
    interactive: bool,
    commanded_times: Vec<f64>,
    commanded_positions: Vec<Vec<f64>>,
    /// Points uploaded so far.
    streamed: usize,
}

impl<'a> Scenario<'a> {
    /// Connects, sets the joint count, reads STATUS and starts recording LOCATION reports.
    fn connect(
        board: &'a Board,
        addr: std::net::SocketAddr,
        demo: &DemoOptions,
    ) -> io::Result<Scenario<'a>> {
        println!(
            "sim-host demo: 6-joint pick-and-place on the simulated controller at {addr} (time scale {})",
            board.clock.time_scale()
        );
        let arm = Arc::new(Client::connect(addr).map_err(to_io)?);
        arm.set_joints(JOINTS as u8).map_err(to_io)?;
        let status = arm.status().map_err(to_io)?;
        println!(
            "  controller: protocol {}.{}.{}, {} joints, buffer {} points, max {} steps/s, gripper clock {} MHz",
            status.version[0],
            status.version[1],
            status.version[2],
            status.joints,
            status.capacity,
            status.max_step_rate_hz,
            status.pwm_timer_clock_hz / 1_000_000
        );

        let recording: Arc<Mutex<Vec<Sample>>> = Arc::default();
        let t0 = Instant::now();
        {
            let locations = arm.locations();
            let recording = recording.clone();
            std::thread::spawn(move || {
                for location in locations {
                    if let Ok(mut samples) = recording.lock() {
                        samples.push(Sample {
                            time_s: t0.elapsed().as_secs_f64(),
                            state: location.state,
                            position: location.position[..JOINTS].to_vec(),
                        });
                    }
                }
            });
        }
        // The display: a progress bar per run with live positions.
        let display = Arc::new(Mutex::new(Display {
            gripper: "open".into(),
            ..Display::default()
        }));
        Ok(Scenario {
            board,
            arm,
            status,
            t0,
            recording,
            checks: Vec::new(),
            display,
            interactive: !demo.quiet && io::stderr().is_terminal(),
            commanded_times: Vec::new(),
            commanded_positions: Vec::new(),
            streamed: 0,
        })
    }

    /// Prints and records the outcome of one check.
    fn check(&mut self, what: String, passed: bool) {
        let mark = if passed { "ok" } else { "FAILED" };
        println!("  [{mark}] {what}");
        self.checks.push(Check { what, passed });
    }

    /// Serial pass-through (the simulator's port is a loopback, so the line comes back),
    /// then PIN0 on.
    fn serial_and_pin(&mut self) -> io::Result<()> {
        let arm = &self.arm;
        let serial = arm.serial_rx();
        arm.serial_open(UartInit {
            baud_rate: 115_200,
            ..UartInit::default()
        })
        .map_err(to_io)?;
        let hello = b"TOOL? gripper-v2\n";
        arm.serial_send(hello).map_err(to_io)?;
        let mut echoed = Vec::new();
        let until = Instant::now() + Duration::from_secs(2);
        while echoed.len() < hello.len() && Instant::now() < until {
            if let Ok(bytes) = serial.recv_timeout(Duration::from_millis(100)) {
                echoed.extend(bytes);
            }
        }
        self.check(
            format!(
                "serial: sent {:?}, read back {:?}",
                String::from_utf8_lossy(hello).trim_end(),
                String::from_utf8_lossy(&echoed).trim_end()
            ),
            echoed == hello,
        );
        self.arm.pin(0, true).map_err(to_io)?;
        Ok(())
    }

    /// The gripper's servo PWM at `duty` (0.05 open, 0.10 closed).
    fn gripper(&self, duty: f64) -> io::Result<protocol::Pwm> {
        armctl::pwm::settings(self.status.pwm_timer_clock_hz, 50.0, duty, 0)
            .map_err(io::Error::other)
    }

    /// Opens the gripper, then the two streamed runs (approach, transfer), closing the
    /// gripper on the part after the first and opening it after the second. Returns the
    /// pose it ends at.
    fn pick_and_place(&mut self) -> io::Result<Pose> {
        let open = self.gripper(0.05)?;
        let close = self.gripper(0.10)?;
        self.arm.pwm_start(open).map_err(to_io)?;

        let runs: [(&str, Vec<Leg>); 2] = [
            (
                "approach",
                vec![
                    Leg {
                        pose: ABOVE_PICK,
                        seconds: 1.5,
                    },
                    Leg {
                        pose: PICK,
                        seconds: 0.8,
                    },
                ],
            ),
            (
                "transfer",
                vec![
                    Leg {
                        pose: ABOVE_PICK,
                        seconds: 0.8,
                    },
                    Leg {
                        pose: ABOVE_PLACE,
                        seconds: 2.0,
                    },
                    Leg {
                        pose: PLACE,
                        seconds: 0.8,
                    },
                ],
            ),
        ];
        let mut at = HOME;
        for (i, (name, legs)) in runs.iter().enumerate() {
            let points = plan(at, legs);
            let end = legs.last().map(|l| l.pose).unwrap_or(at);
            let started = self.t0.elapsed().as_secs_f64();
            let report = run_with_display(
                &self.arm,
                name,
                &points,
                &self.display,
                self.interactive,
                self.board,
            )?;
            self.streamed += points.len();
            self.add_commanded(at, &points, started);
            let location = report
                .final_location
                .map(|l| l.position)
                .unwrap_or_default();
            self.check(
                format!(
                    "{name}: {} points through a {}-point buffer in {:.2} s ({} resent), ends at {:?}",
                    points.len(),
                    self.status.capacity,
                    report.total_time.as_secs_f64(),
                    report.retransmissions,
                    &location[..JOINTS]
                ),
                location[..JOINTS] == end,
            );
            at = end;
            // Gripper: close on the part after the approach, open after the transfer.
            let (pwm, word) = if i == 0 {
                (close, "closed")
            } else {
                (open, "open")
            };
            self.arm.pwm_start(pwm).map_err(to_io)?;
            if let Ok(mut d) = self.display.lock() {
                d.gripper = word.into();
            }
            println!(
                "  gripper {word}: servo PWM {:.0} Hz, duty {:.1} %",
                pwm.frequency_hz(self.status.pwm_timer_clock_hz),
                pwm.duty() * 100.0
            );
            std::thread::sleep(Duration::from_secs_f64(0.3 / self.board.clock.time_scale()));
        }
        Ok(at)
    }

    /// Adds the commanded path of a run from `at`, started at `started` (seconds since
    /// `t0`), to the plot's commanded series.
    fn add_commanded(&mut self, at: Pose, points: &[Point], started: f64) {
        add_commanded(
            &mut self.commanded_times,
            &mut self.commanded_positions,
            at,
            points,
            run_start(&self.recording, started),
            self.board.clock.time_scale(),
        );
    }

    /// The last move home from `at`, stopped half way by an emergency stop from another
    /// thread; checks the ACK and that the run ended early. Returns the retreat's points.
    fn emergency_stop(&mut self, at: Pose) -> io::Result<Vec<Point>> {
        let points = plan(
            at,
            &[
                Leg {
                    pose: ABOVE_PLACE,
                    seconds: 0.8,
                },
                // Long enough that the stop 1.2 s in lands well before the end even on a
                // loaded machine at the test's 4x (2.0 s here left 0.4 s of real time).
                Leg {
                    pose: HOME,
                    seconds: 4.0,
                },
            ],
        );
        let retreat_started = self.t0.elapsed().as_secs_f64();
        let stopper = {
            let arm = self.arm.clone();
            let scale = self.board.clock.time_scale();
            std::thread::spawn(move || {
                // Wait until it moves, then 1.2 s (simulated) into the move: STOPPED.
                let until = Instant::now() + Duration::from_secs(30);
                while arm
                    .last_location()
                    .is_none_or(|l| l.state != State::Running as u8)
                {
                    if Instant::now() >= until {
                        return (
                            Duration::ZERO,
                            Err(armctl::Error::Io(io::Error::other(
                                "the retreat never showed RUNNING within 30 s",
                            ))),
                        );
                    }
                    std::thread::sleep(Duration::from_millis(2));
                }
                std::thread::sleep(Duration::from_secs_f64(1.2 / scale));
                let sent = Instant::now();
                let ack = arm.stop();
                (sent.elapsed(), ack.map(|a| a.state))
            })
        };
        let outcome = run_with_display(
            &self.arm,
            "retreat",
            &points,
            &self.display,
            self.interactive,
            self.board,
        );
        let (ack_time, stop_ack) = stopper
            .join()
            .map_err(|_| io::Error::other("the e-stop thread panicked"))?;
        self.add_commanded(at, &points, retreat_started);
        self.streamed += points.len();
        self.check(
            format!(
                "e-stop: STOPPED acknowledged in {:.2} ms (state {}); the run ended early: {}",
                ack_time.as_secs_f64() * 1e3,
                stop_ack
                    .as_ref()
                    .map_or_else(|e| e.to_string(), |s| s.name().to_string()),
                match &outcome {
                    Ok(_) => "no (it completed)".to_string(),
                    Err(e) => e.to_string(),
                }
            ),
            matches!(stop_ack, Ok(State::Stopped)) && outcome.is_err(),
        );
        Ok(points)
    }

    /// After the stop: STATUS, no further step, the motors' pulses equal the reported
    /// position, which lies on the retreat (from `at` along `retreat`) short of home; then
    /// gripper, pin and serial off.
    fn check_stopped(&mut self, at: Pose, retreat: &[Point]) -> io::Result<()> {
        let status = self.arm.status().map_err(to_io)?;
        self.check(
            format!(
                "STATUS after the stop: {}, stopped-by-host flag set",
                status.state.name()
            ),
            status.state == State::Stopped && status.flags.has(StatusFlags::STOPPED_BY_HOST),
        );
        let still = self
            .arm
            .current_location(Duration::from_secs(2))
            .map_err(to_io)?;
        std::thread::sleep(Duration::from_millis(200));
        let later = self
            .arm
            .current_location(Duration::from_secs(2))
            .map_err(to_io)?;
        self.check(
            format!(
                "no step after the stop: {:?} 200 ms later",
                &later.position[..JOINTS]
            ),
            still.position == later.position,
        );
        let motors = self.board.motors.positions();
        let physical: Vec<i64> = motors[..JOINTS].to_vec();
        let reported: Vec<i64> = later.position[..JOINTS]
            .iter()
            .map(|&p| i64::from(p))
            .collect();
        self.check(
            format!("the motors received exactly the reported steps: pulses {physical:?}"),
            physical == reported,
        );
        // On the commanded path (within its extent on every joint), short of home.
        let on_path = (0..JOINTS).all(|j| {
            let along = retreat.iter().map(|p| p.position[j]).chain([at[j]]);
            let (low, high) = along.fold((i32::MAX, i32::MIN), |(l, h), x| (l.min(x), h.max(x)));
            (low..=high).contains(&later.position[j])
        });
        self.check(
            "stopped part way along the retreat, short of home".to_string(),
            on_path && later.position[..JOINTS] != HOME,
        );
        let latencies = self.board.probe.take_estop_latencies();
        if let Some(latency) = latencies.first() {
            println!(
                "  e-stop latency inside the controller (datagram read to step engine idle): {:.1} us",
                latency.as_secs_f64() * 1e6
            );
        }
        self.arm.pwm_stop().map_err(to_io)?;
        self.arm.pin(0, false).map_err(to_io)?;
        self.arm.serial_close().map_err(to_io)?;
        Ok(())
    }

    /// The plot and the summary; an error naming the count if any check failed.
    fn finish(self, demo: &DemoOptions) -> io::Result<()> {
        let samples = self.recording.lock().map(|s| s.clone()).unwrap_or_default();
        let commanded = Commanded {
            times_s: self.commanded_times,
            positions: self.commanded_positions,
            offset_s: 0.0,
        };
        let svg = armctl::plot::svg(
            &samples,
            Some(&commanded),
            "sim-host demo: commanded (dashed) vs executed joint positions",
        );
        let plot_path = demo.plot.clone().unwrap_or_else(default_plot_path);
        std::fs::write(&plot_path, svg)?;
        let checks = self.checks;
        let failed = checks.iter().filter(|c| !c.passed).count();
        println!(
            "summary: {} points uploaded in 3 runs, {} location reports recorded, {} of {} checks passed",
            self.streamed,
            samples.len(),
            checks.len() - failed,
            checks.len()
        );
        println!("plot: {}", plot_path.display());
        let serial = self.board.serial.counters();
        log::debug!(
            "serial bytes written {}",
            serial.written.load(Ordering::Relaxed)
        );
        if failed > 0 {
            for c in checks.iter().filter(|c| !c.passed) {
                eprintln!("FAILED: {}", c.what);
            }
            return Err(io::Error::other(format!("{failed} demo checks failed")));
        }
        Ok(())
    }
}

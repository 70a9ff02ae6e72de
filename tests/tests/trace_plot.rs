//! `sim-host --trace` against armctl's VCD reader and `armctl plot`: the positions counted
//! from the traced STEP/DIR pulses equal the controller's own LOCATION, and the trace plots.

use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use armctl::{Controller, Options, vcd};
use protocol::State;
use system_tests::{armctl_bin, sim_host_bin};

/// How long the simulator gets to answer STATUS, and to exit after SIGTERM.
const TIMEOUT: Duration = Duration::from_secs(10);

/// A sim-host writing a trace; stopped with SIGTERM (so that it flushes the trace) by
/// [`TracedSim::terminate`], killed if the test fails before.
struct TracedSim {
    addr: SocketAddr,
    child: Option<Child>,
    dir: PathBuf,
}

impl TracedSim {
    fn start(joints: u8) -> TracedSim {
        let mut last_error = String::new();
        // A port found free can be taken before the simulator binds it: try a few.
        for attempt in 0..5 {
            let port = UdpSocket::bind("127.0.0.1:0")
                .and_then(|s| s.local_addr())
                .map(|a| a.port())
                .expect("a free UDP port on 127.0.0.1");
            let addr = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, port));
            let dir = std::env::temp_dir().join(format!(
                "trace-plot-{}-{port}-{attempt}",
                std::process::id()
            ));
            std::fs::create_dir_all(&dir).unwrap();
            let log = std::fs::File::create(dir.join("sim-host.log")).unwrap();
            let child = Command::new(sim_host_bin())
                .arg("--bind")
                .arg(addr.to_string())
                .arg("--settings")
                .arg(dir.join("settings.txt"))
                .arg("--trace")
                .arg(dir.join("run.vcd"))
                .args(["--log-level", "warn", "--joints", &joints.to_string()])
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(log)
                .spawn()
                .expect("start sim-host");
            let mut sim = TracedSim {
                addr,
                child: Some(child),
                dir,
            };
            let started = Instant::now();
            while started.elapsed() < TIMEOUT {
                if let Some(Ok(Some(status))) = sim.child.as_mut().map(Child::try_wait) {
                    last_error = format!("sim-host exited with {status}: {}", sim.log());
                    break;
                }
                let quick = Options {
                    ack_timeout: Duration::from_millis(100),
                    attempts: 2,
                    ..Options::default()
                };
                if Controller::connect_with(addr, quick).is_ok() {
                    return sim;
                }
            }
            if last_error.is_empty() {
                last_error = format!("sim-host did not answer on {addr} in {TIMEOUT:?}");
            }
        }
        panic!("{last_error}");
    }

    fn trace(&self) -> PathBuf {
        self.dir.join("run.vcd")
    }

    fn log(&self) -> String {
        std::fs::read_to_string(self.dir.join("sim-host.log")).unwrap_or_default()
    }

    /// SIGTERM, then waits for a clean exit: the trace is complete after this.
    fn terminate(&mut self) {
        let mut child = self.child.take().expect("still running");
        let sent = Command::new("kill")
            .args(["-TERM", &child.id().to_string()])
            .status()
            .expect("run kill");
        assert!(sent.success(), "kill -TERM failed");
        let asked = Instant::now();
        loop {
            if let Some(status) = child.try_wait().expect("wait for sim-host") {
                assert!(status.success(), "sim-host exited with {status}");
                return;
            }
            if asked.elapsed() > TIMEOUT {
                let _ = child.kill();
                let _ = child.wait();
                panic!("sim-host did not exit within {TIMEOUT:?} of SIGTERM");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for TracedSim {
    fn drop(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn armctl(args: &[&str]) -> String {
    let output = Command::new(armctl_bin())
        .args(args)
        .output()
        .expect("run armctl");
    let stdout = String::from_utf8_lossy(&output.stdout).into_owned();
    assert!(
        output.status.success(),
        "armctl {args:?}: {stdout}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    stdout
}

fn path(p: &Path) -> &str {
    p.to_str().expect("UTF-8 temp path")
}

#[test]
fn traced_pulses_end_where_the_controller_says_and_plot() {
    let mut sim = TracedSim::start(3);
    let controller = sim.addr.to_string();
    // Joint 0 out and part way back, joint 1 the other way round, joint 2 still.
    let moves = sim.dir.join("move.csv");
    std::fs::write(
        &moves,
        "time_s,j0,j1,j2\n0,0,0,0\n0.2,120,-80,0\n0.4,40,30,0\n",
    )
    .unwrap();
    let out = armctl(&[
        "--controller",
        &controller,
        "run",
        path(&moves),
        "--quiet",
        "--segment-ms",
        "20",
    ]);
    assert!(out.contains("20 points"), "{out}");

    let arm = Controller::connect(sim.addr).unwrap();
    let status = arm.status().unwrap();
    assert_eq!(status.state, State::Stopped);
    assert_eq!(status.executed, 20);
    let location = arm.current_location(Duration::from_secs(2)).unwrap();
    drop(arm);
    sim.terminate();

    let trace = vcd::read(&sim.trace()).unwrap_or_else(|e| panic!("{e}\n{}", sim.log()));
    let reported: Vec<i64> = location.position[..3]
        .iter()
        .map(|&p| i64::from(p))
        .collect();
    assert_eq!(reported, vec![40, 30, 0]);
    assert_eq!(trace.positions(3), reported);
    // Every pulse of the path is there: 120 out and 80 back, 80 out and 110 back.
    assert_eq!(trace.joints[0].steps, 200);
    assert_eq!(trace.joints[1].steps, 190);
    assert_eq!(trace.joints[2].steps, 0);
    // The run lasts 0.4 s of simulated time.
    let (first, last) = (
        trace.first_step_s().unwrap(),
        trace.end_tick as f64 * trace.seconds_per_tick,
    );
    assert!(last - first >= 0.38, "trace from {first} s to {last} s");

    let svg = sim.dir.join("trace.svg");
    let out = armctl(&[
        "plot",
        path(&sim.trace()),
        "--trajectory",
        path(&moves),
        "-o",
        path(&svg),
    ]);
    assert!(out.contains("joint 0: 200 steps, ends at 40"), "{out}");
    assert!(out.contains("joint 1: 190 steps, ends at 30"), "{out}");
    let svg = std::fs::read_to_string(&svg).unwrap();
    assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
    // Joints 0..2 drawn (2 is commanded though still), each with its dashed command.
    assert_eq!(svg.matches("<polyline").count(), 6, "{svg}");
    assert!(svg.contains("joint 2") && svg.contains("commanded"));
    assert!(svg.len() < 200_000, "{} bytes", svg.len());
}

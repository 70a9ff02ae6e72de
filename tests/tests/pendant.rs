//! The pendant in a real browser (issue 35): `armctl serve` against sim-host, its page in
//! headless Chromium driven over WebDriver (`system_tests::webdriver`). The page shows the
//! simulator's state and joint names; a jog click moves that joint (counted on the
//! simulator's STEP trace); the e-stop click during a run stops the arm; hold and resume
//! are offered only by a controller that has them (issue 32: disabled here, with the
//! reason as the tooltip); a second browser sees the same positions; the page says when
//! sim-host is gone.
//!
//! The e-stop's 100 ms criterion is the sum of two spans: the click to the STOPPED on the
//! wire (the page's click time, taken in its handler, against the pendant's `--pcap`
//! capture: one system clock), and the STOPPED read by the simulator (its `estop` wire) to
//! the last STEP edge (the trace's clock). It is printed against 100 ms; the assertion is
//! 1 s, a bound a machine ten times slower still meets, below the seconds of steps an
//! e-stop that did nothing would leave (as `interrupt.rs` does). The benchmark
//! (`click_to_stopped_benchmark`) prints the click to STOPPED latency's p50 and p99 over
//! many clicks and the page's update rate during a run: figures, not gates.
//!
//! Without Chromium and chromedriver the tests say so and pass (plain `cargo test` on a
//! machine without them); `.ci/run` installs them and sets PENDANT_REQUIRED=1, which turns
//! the skip into a failure.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use armctl::vcd;
use system_tests::webdriver::{Driver, Session, missing_browser};
use system_tests::{SimHost, armctl_bin, config_init_degrees_arm, run_armctl};

/// The criterion: no STEP edge later than this after the e-stop click (printed).
const LAST_STEP_CRITERION: Duration = Duration::from_millis(100);

/// What is asserted instead (see the header): room for a machine ten times slower.
const LAST_STEP_AFTER_CLICK: Duration = Duration::from_secs(1);

/// How long the page may take to show what the test waits for (bounded waits, never
/// sleeps for the controller's work).
const PAGE_WAIT: Duration = Duration::from_secs(20);

/// Whether the browser is there; if not, the message (and a failure under PENDANT_REQUIRED).
fn browser_or_skip(test: &str) -> bool {
    match missing_browser() {
        None => true,
        Some(why) if std::env::var_os("PENDANT_REQUIRED").is_some() => {
            panic!("{test}: PENDANT_REQUIRED is set but {why}")
        }
        Some(why) => {
            eprintln!("SKIPPED {test}: {why}");
            false
        }
    }
}

/// `armctl serve` on a free 127.0.0.1 port, its datagrams captured to a pcap; stopped
/// on drop.
struct Pendant {
    child: Child,
    url: String,
    pcap: PathBuf,
}

impl Pendant {
    fn start(sim: &SimHost) -> Pendant {
        Pendant::start_with(sim, &[])
    }

    /// With global options `extra` (`--key-file FILE`).
    fn start_with(sim: &SimHost, extra: &[&str]) -> Pendant {
        let pcap = sim.dir().join("pendant.pcap");
        let mut child = Command::new(armctl_bin())
            .arg("--controller")
            .arg(sim.addr.to_string())
            .arg("--pcap")
            .arg(&pcap)
            .args(extra)
            .args(["serve", "--listen", "127.0.0.1:0"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start armctl serve");
        let stdout = child.stdout.take().expect("piped stdout");
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                let _ = tx.send(line);
            }
        });
        let line = rx
            .recv_timeout(Duration::from_secs(20))
            .expect("armctl serve says where it serves");
        let url = line
            .split(" at ")
            .nth(1)
            .unwrap_or_else(|| panic!("{line}"))
            .to_string();
        Pendant { child, url, pcap }
    }
}

impl Drop for Pendant {
    fn drop(&mut self) {
        // SIGTERM: it stops what it moves and exits.
        let _ = Command::new("kill")
            .arg(self.child.id().to_string())
            .status();
        let _ = self.child.wait();
    }
}

/// A simulator with the scripted users' degrees arm (`base`, `shoulder`, 44.44 steps a
/// degree) described on it (`armctl config push`).
fn described_sim() -> SimHost {
    let sim = SimHost::start_traced(&["--joints", "2"]);
    let config = sim.dir().join("arm.json");
    let (ok, out, err) = config_init_degrees_arm(&config, "10000");
    assert!(ok, "config init: {out}{err}");
    let (ok, out, err) = run_armctl(Some(&sim), &["config", "push", config.to_str().unwrap()]);
    assert!(ok, "config push: {out}{err}");
    sim
}

/// Opens the page and waits until it shows the controller.
fn open(driver: &Driver, url: &str) -> Session {
    let page = driver.session();
    page.goto(url);
    assert!(
        page.wait_for(
            "return document.getElementById('conn').textContent === 'connected' \
             && document.querySelectorAll('#joints tr').length > 0",
            PAGE_WAIT
        ),
        "the page never showed a connected controller: {}",
        page.text("body")
    );
    page
}

/// Each joint's position as the page shows it.
fn shown_positions(page: &Session) -> Vec<String> {
    serde_json::from_value(
        page.eval(
            "return [...document.querySelectorAll('#joints tr .pos')].map(e => e.textContent)",
        ),
    )
    .unwrap_or_default()
}

/// STOPPED frames the pendant sent, with their times (s since the epoch), from its pcap.
fn stops_on_the_wire(pcap: &Path) -> Vec<f64> {
    let bytes = std::fs::read(pcap).unwrap_or_default();
    // The file header's magic says the byte order (pcap-file writes big-endian).
    let big = bytes.starts_with(&[0xa1, 0xb2, 0xc3, 0xd4]);
    let mut at = 24;
    let mut times = Vec::new();
    while at + 16 <= bytes.len() {
        let word = |o: usize| {
            let b: [u8; 4] = bytes[at + o..at + o + 4].try_into().unwrap();
            if big {
                u32::from_be_bytes(b)
            } else {
                u32::from_le_bytes(b)
            }
        };
        let (sec, usec, len) = (word(0), word(4), word(8) as usize);
        let start = at + 16;
        if start + len > bytes.len() {
            break;
        }
        // IPv4 (20 bytes) and UDP (8) headers, then the frame.
        let frame = &bytes[start..start + len];
        if frame.len() > 28
            && let Ok(f) = protocol::Command::decode(&frame[28..])
            && matches!(f.body, protocol::Command::Stopped)
        {
            times.push(f64::from(sec) + f64::from(usec) / 1e6);
        }
        at = start + len;
    }
    times
}

/// The page's e-stop clicks (ms since the epoch).
fn clicks(page: &Session) -> Vec<f64> {
    serde_json::from_value(page.eval("return window.pendantStopClicks")).unwrap_or_default()
}

/// p-th percentile of sorted values.
fn percentile(sorted: &[f64], p: f64) -> f64 {
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

/// A run of `seconds` from where the arm is (base 0, shoulder `shoulder` deg): base out to
/// 40 deg and back, shoulder down to -20 deg and back.
fn trajectory(dir: &Path, seconds: u32, shoulder: u32) -> PathBuf {
    let path = dir.join("out-and-back.csv");
    let half = f64::from(seconds) / 2.0;
    std::fs::write(
        &path,
        format!(
            "time_s,base,shoulder\n0,0,{shoulder}\n{half},40,-20\n{},0,{shoulder}\n",
            f64::from(seconds)
        ),
    )
    .unwrap();
    path
}

#[test]
fn the_pendant_in_a_browser_shows_jogs_stops_and_loses_the_simulator() {
    if !browser_or_skip("the_pendant_in_a_browser") {
        return;
    }
    let _alone = system_tests::run_alone();
    let mut sim = described_sim();
    let pendant = Pendant::start(&sim);
    let driver = Driver::start();
    let page = open(&driver, &pendant.url);

    // The simulator's state and the joints' names, in the arm's units.
    assert_eq!(page.text("#state"), "STOPPED");
    let names: Vec<String> =
        serde_json::from_value(page.eval(
            "return [...document.querySelectorAll('#joints tr .name')].map(e => e.textContent)",
        ))
        .unwrap();
    assert_eq!(names, ["base", "shoulder"]);
    assert_eq!(page.text("#units"), "deg");
    assert_eq!(shown_positions(&page), ["0.00 deg", "0.00 deg"]);

    // Jog the shoulder 2 degrees: 89 steps (44.44 a degree).
    page.eval("document.getElementById('step').value = '2'; return true");
    page.click("tr[data-joint='1'] .jog-plus");
    assert!(
        page.wait_for("return snap.steps[1] === 89 && !snap.run.active", PAGE_WAIT),
        "the jog did not end at 89 steps: {}",
        page.text("body")
    );
    assert_eq!(shown_positions(&page), ["0.00 deg", "2.00 deg"]);

    // A second browser sees the same positions.
    let second = open(&driver, &pendant.url);
    assert!(
        second.wait_for("return snap.steps[1] === 89", PAGE_WAIT),
        "the second page: {}",
        second.text("body")
    );
    assert_eq!(shown_positions(&second), shown_positions(&page));

    // Hold, resume and the override need issue 32's HOLD: offered, disabled, saying why.
    for id in ["hold", "resume", "override"] {
        let (disabled, title): (bool, String) = serde_json::from_value(page.eval(&format!(
            "const e = document.getElementById('{id}'); return [e.disabled, e.title]"
        )))
        .unwrap();
        assert!(disabled, "#{id} enabled without HOLD");
        assert_eq!(title, "needs a controller with HOLD (issue 32)");
    }

    // A run chosen in the page: the check first, then Run.
    let file = trajectory(sim.dir(), 6, 2);
    page.type_into("#file", file.to_str().unwrap());
    assert!(
        page.wait_for(
            "return document.getElementById('check').textContent.startsWith('check: ') \
             && !document.getElementById('run').disabled",
            PAGE_WAIT
        ),
        "check: {}",
        page.text("#check")
    );
    println!("{}", page.text("#check"));
    page.click("#run");
    // Well into the run (a second of it), both pages updating.
    assert!(
        page.wait_for(
            "return snap.state === 'RUNNING' && snap.run.t_ms > 1000",
            PAGE_WAIT
        ),
        "the run did not start: {}",
        page.text("body")
    );
    let events = |p: &Session| {
        p.eval("return window.pendantEvents")
            .as_f64()
            .unwrap_or(0.0)
    };
    let (e0, t0) = (events(&page), Instant::now());
    std::thread::sleep(Duration::from_millis(1000));
    let rate = (events(&page) - e0) / t0.elapsed().as_secs_f64();
    println!("page updates during the run: {rate:.0} per second (report period 10 ms)");
    if std::env::var_os("PENDANT_SCREENSHOT").is_some() {
        let path = PathBuf::from(std::env::var_os("PENDANT_SCREENSHOT").unwrap());
        page.screenshot(&path);
        println!("screenshot: {}", path.display());
    }
    // The mark on the trace's clock, then the click.
    let arm = sim.connect_with(armctl::Options::default());
    arm.pin(0, true).expect("PIN0_ON");
    page.click("#estop");
    assert!(
        page.wait_for(
            "return snap.state === 'STOPPED' && !snap.run.active",
            PAGE_WAIT
        ),
        "the e-stop did not stop the run: {}",
        page.text("body")
    );
    assert!(
        page.wait_for(
            "return document.getElementById('stopcause').textContent.startsWith('a STOPPED from 127.0.0.1')",
            PAGE_WAIT
        ),
        "{}",
        page.text("#stopcause")
    );
    let click = *clicks(&page).last().expect("the click's time") / 1e3;
    let stops = stops_on_the_wire(&pendant.pcap);
    let wire = stops
        .iter()
        .copied()
        .find(|&t| t >= click - 0.001)
        .unwrap_or_else(|| {
            panic!("no STOPPED on the wire after the click at {click:.4}: {stops:?}")
        });

    // The key: Escape sends STOPPED too.
    let before = stops_on_the_wire(&pendant.pcap).len();
    page.type_into("body", "\u{E00C}");
    let deadline = Instant::now() + PAGE_WAIT;
    while stops_on_the_wire(&pendant.pcap).len() == before && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(
        stops_on_the_wire(&pendant.pcap).len() > before,
        "Escape sent no STOPPED"
    );

    // Disable and enable the drivers; home.
    page.click("#disable");
    assert!(
        page.wait_for("return (snap.status.enabled_mask & 3) === 0", PAGE_WAIT),
        "disable: {}",
        page.text("body")
    );
    page.click("#enable");
    assert!(
        page.wait_for("return (snap.status.enabled_mask & 3) === 3", PAGE_WAIT),
        "enable: {}",
        page.text("body")
    );
    // The home's mark on the trace: its steps are not the e-stop's.
    arm.pin(1, true).expect("PIN1_ON");
    drop(arm);
    page.click("#home");
    assert!(
        page.wait_for(
            "return snap.state === 'STOPPED' && snap.steps[0] === 0 && snap.steps[1] === 0",
            PAGE_WAIT
        ),
        "home: {}",
        page.text("body")
    );

    // The simulator goes: both pages say so.
    sim.terminate();
    for p in [&page, &second] {
        assert!(
            p.wait_for(
                "return document.getElementById('conn').textContent === 'not answering' \
                 && getComputedStyle(document.getElementById('lost')).display === 'block'",
                PAGE_WAIT
            ),
            "the page did not say the controller stopped answering: {}",
            p.text("body")
        );
    }

    // The trace: the jog's 89 shoulder steps, and no STEP edge long after the click.
    let trace = vcd::read_changes(&sim.trace()).unwrap_or_else(|e| panic!("{e}\n{}", sim.log()));
    let mark = *trace.rising_edges("pin0").last().expect("the PIN0 mark");
    let steps = |j| trace.rising_edges(&vcd::wire_name(vcd::JointWire::Step, j));
    let jog_steps = steps(1).iter().filter(|&&t| t < mark).count();
    assert!(
        jog_steps >= 89,
        "shoulder steps before the run's stop: {jog_steps}"
    );
    let home = *trace.rising_edges("pin1").last().expect("the PIN1 mark");
    let last = (0..2)
        .flat_map(steps)
        .filter(|&t| t < home)
        .max()
        .expect("STEP edges");
    // The STOPPED read by the simulator (its estop wire), the first after the mark.
    let estop = trace
        .rising_edges("estop")
        .into_iter()
        .find(|&t| t >= mark)
        .expect("the STOPPED on the trace (estop wire)");
    let after_stop = Duration::from_nanos(last.saturating_sub(estop));
    let after = Duration::from_secs_f64((wire - click).max(0.0)) + after_stop;
    println!(
        "e-stop click to the last STEP edge: {:.3} ms = click to STOPPED on the wire {:.3} ms \
         + STOPPED read to the last STEP edge {:.3} ms (issue criterion {} ms: {})",
        after.as_secs_f64() * 1e3,
        (wire - click) * 1e3,
        after_stop.as_secs_f64() * 1e3,
        LAST_STEP_CRITERION.as_millis(),
        if after <= LAST_STEP_CRITERION {
            "met"
        } else {
            "missed"
        }
    );
    assert!(
        after <= LAST_STEP_AFTER_CLICK,
        "a STEP edge {after:?} after the e-stop click"
    );
}

/// Clicks the benchmark makes.
const BENCH_CLICKS: usize = 40;

/// A benchmark, not a check: `.ci/run` runs it with `--ignored --nocapture` to print its
/// figures.
#[test]
#[ignore = "a benchmark: cargo test -p system-tests --test pendant -- --ignored --nocapture"]
fn click_to_stopped_benchmark() {
    if !browser_or_skip("click_to_stopped_benchmark") {
        return;
    }
    let _alone = system_tests::run_alone();
    let sim = described_sim();
    let pendant = Pendant::start(&sim);
    let driver = Driver::start();
    let page = open(&driver, &pendant.url);

    // The page's update rate under a running trajectory.
    let file = trajectory(sim.dir(), 8, 0);
    page.type_into("#file", file.to_str().unwrap());
    assert!(
        page.wait_for("return !document.getElementById('run').disabled", PAGE_WAIT),
        "check: {}",
        page.text("#check")
    );
    page.click("#run");
    assert!(
        page.wait_for(
            "return snap.state === 'RUNNING' && snap.run.t_ms > 500",
            PAGE_WAIT
        ),
        "the run did not start: {}",
        page.text("body")
    );
    let events = || {
        page.eval("return window.pendantEvents")
            .as_f64()
            .unwrap_or(0.0)
    };
    let (e0, t0) = (events(), Instant::now());
    // A figure over a measured span, not a wait for the controller.
    std::thread::sleep(Duration::from_secs(2));
    let (e1, span) = (events(), t0.elapsed().as_secs_f64());
    println!(
        "page updates under a running trajectory: {:.1} per second over {span:.2} s (the \
         controller reports every 10 ms)",
        (e1 - e0) / span
    );

    // Click after click (the first stops the run): each click to its STOPPED on the wire.
    for _ in 0..BENCH_CLICKS {
        page.click("#estop");
    }
    let clicks = clicks(&page);
    assert_eq!(clicks.len(), BENCH_CLICKS);
    // Every STOPPED out (bounded wait): the last click's.
    let last_click = clicks[BENCH_CLICKS - 1] / 1e3;
    let deadline = Instant::now() + PAGE_WAIT;
    let mut stops = stops_on_the_wire(&pendant.pcap);
    while !stops.iter().any(|&t| t >= last_click - 0.001) && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
        stops = stops_on_the_wire(&pendant.pcap);
    }
    let mut latencies: Vec<f64> = clicks
        .iter()
        .map(|&c| {
            let c = c / 1e3;
            let wire = stops
                .iter()
                .copied()
                .find(|&t| t >= c - 0.001)
                .unwrap_or_else(|| panic!("no STOPPED after the click at {c:.4}"));
            (wire - c).max(0.0) * 1e3
        })
        .collect();
    println!(
        "the first click (during the run): {:.2} ms; then {:?}",
        latencies[0],
        latencies[1..]
            .iter()
            .map(|l| (l * 10.0).round() / 10.0)
            .collect::<Vec<_>>()
    );
    latencies.sort_by(f64::total_cmp);
    println!(
        "click to STOPPED on the wire over {BENCH_CLICKS} clicks: p50 {:.2} ms, p99 {:.2} ms, \
         max {:.2} ms (issue: p99 <= 50 ms on loopback)",
        percentile(&latencies, 0.5),
        percentile(&latencies, 0.99),
        latencies[BENCH_CLICKS - 1]
    );
    assert!(
        page.wait_for("return snap.state === 'STOPPED'", PAGE_WAIT),
        "{}",
        page.text("body")
    );
}

#[test]
fn another_hosts_controller_is_shown_read_only_with_its_owner() {
    if !browser_or_skip("another_hosts_controller_is_shown_read_only") {
        return;
    }
    let _alone = system_tests::run_alone();
    let sim = described_sim();
    // `config push` (from 127.0.0.1) gives it up, then 127.0.0.2 owns the controller, and keeps it (STATUS every 500 ms, well inside the
    // 5 s after which a silent owner loses it) until the test ends.
    let owner = sim.connect_with(armctl::Options {
        bind: Some("127.0.0.2:0".parse().unwrap()),
        ..armctl::Options::default()
    });
    let (ok, out, err) = run_armctl(Some(&sim), &["release"]);
    assert!(ok, "release: {out}{err}");
    owner.status().expect("127.0.0.2 takes the controller");
    let done = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let keeper = {
        let done = std::sync::Arc::clone(&done);
        std::thread::spawn(move || {
            // Bounded: at most 120 STATUS (a minute).
            for _ in 0..120 {
                if done.load(std::sync::atomic::Ordering::Relaxed) {
                    break;
                }
                let _ = owner.status();
                std::thread::sleep(Duration::from_millis(500));
            }
        })
    };
    let pendant = Pendant::start(&sim);
    let driver = Driver::start();
    let page = open(&driver, &pendant.url);
    assert!(
        page.wait_for(
            "return snap.read_only && snap.owner === '127.0.0.2' \
             && getComputedStyle(document.getElementById('readonly')).display === 'block'",
            PAGE_WAIT
        ),
        "not read-only with the owner named: {}",
        page.text("body")
    );
    assert_eq!(page.text("#owner"), "127.0.0.2");
    // Names and units from the descriptions, which any host may read.
    assert!(
        page.wait_for(
            "return [...document.querySelectorAll('#joints tr .name')].map(e => e.textContent).join() === 'base,shoulder'",
            PAGE_WAIT
        ),
        "{}",
        page.text("body")
    );
    assert_eq!(shown_positions(&page), ["0.00 deg", "0.00 deg"]);
    let disabled: Vec<bool> = serde_json::from_value(
        page.eval("return [...document.querySelectorAll('button.moves')].map(b => b.disabled)"),
    )
    .unwrap();
    assert!(
        disabled.iter().all(|d| *d),
        "buttons that move: {disabled:?}"
    );
    // The endpoint refuses too, saying why.
    let answer: serde_json::Value =
        serde_json::from_value(page.eval(
            "return await fetch('/api/jog?joint=0&by=1', {method: 'POST'}).then(r => r.json())",
        ))
        .unwrap();
    assert_eq!(answer["ok"], false, "{answer}");
    assert!(
        answer["message"]
            .as_str()
            .unwrap_or_default()
            .contains("read-only: 127.0.0.2 owns the controller"),
        "{answer}"
    );
    done.store(true, std::sync::atomic::Ordering::Relaxed);
    let _ = keeper.join();
}

#[test]
fn a_keyed_controller_is_driven_through_the_key() {
    if !browser_or_skip("a_keyed_controller_is_driven_through_the_key") {
        return;
    }
    let _alone = system_tests::run_alone();
    let sim = described_sim();
    let key = sim.dir().join("arm.key");
    let (ok, out, err) = run_armctl(None, &["key", "new", "-o", key.to_str().unwrap()]);
    assert!(ok, "key new: {out}{err}");
    let (ok, out, err) = run_armctl(Some(&sim), &["key", "set", key.to_str().unwrap()]);
    assert!(ok, "key set: {out}{err}");
    let pendant = Pendant::start_with(&sim, &["--key-file", key.to_str().unwrap()]);
    let driver = Driver::start();
    let page = open(&driver, &pendant.url);
    assert!(!page.eval("return snap.read_only").as_bool().unwrap_or(true));
    page.click("tr[data-joint='0'] .jog-plus");
    assert!(
        page.wait_for("return snap.steps[0] === 44 && !snap.run.active", PAGE_WAIT),
        "the keyed jog: {}",
        page.text("body")
    );
    // (A keyed controller refuses plain frames but STOPPED: the jog went sealed.) The
    // e-stop goes plain, as it may.
    page.click("#estop");
    assert!(
        page.wait_for(
            "return snap.message === 'STOPPED: every joint stopped'",
            PAGE_WAIT
        ),
        "{}",
        page.text("body")
    );
}

//! The pendant in a real browser (issue 35): `armctl serve` against sim-host, its page in
//! headless Chromium driven over WebDriver (`system_tests::webdriver`). The page shows the
//! simulator's state and joint names; a jog click moves that joint (counted on the
//! simulator's STEP trace); hold stops the run at rest (positions unchanged over 20
//! updates), resume goes on, the override slider sets 50 % (issue 32); the e-stop click
//! during a run stops the arm; a second browser sees the same positions; the page says
//! when sim-host is gone.
//!
//! The e-stop's 100 ms criterion is the sum of two spans: the click to the STOPPED on the
//! wire (the page's click time, taken in its handler, against the pendant's `--pcap`
//! capture: one system clock), and the STOPPED read by the simulator (its `estop` wire) to
//! the last STEP edge (the trace's clock). It is printed against 100 ms; the assertion is
//! 1 s, a bound a machine ten times slower still meets, below the seconds of steps an
//! e-stop that did nothing would leave (as `interrupt.rs` does). The benchmark
//! (`pendant_bench.rs`) prints the click to STOPPED latency's p50 and p99 over many clicks
//! and the page's update rate during a run: figures, not gates.
//!
//! `bad_requests_get_errors_and_leave_the_run_alone` needs no browser: malformed, oversized
//! and refused requests during a run each get an error, and the run ends with every point.
//!
//! Without Chromium and chromedriver the browser tests say so and pass (plain `cargo test` on a
//! machine without them); `.ci/run` installs them and sets PENDANT_REQUIRED=1, which turns
//! the skip into a failure.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use armctl::vcd;
use system_tests::pendant::{
    PAGE_WAIT, Pendant, browser_or_skip, clicks, described_sim, open, shown_positions,
    stops_on_the_wire, trajectory,
};
use system_tests::run_armctl;
use system_tests::webdriver::{Driver, Session};

/// The criterion: no STEP edge later than this after the e-stop click (printed).
const LAST_STEP_CRITERION: Duration = Duration::from_millis(100);

/// What is asserted instead (see the header): room for a machine ten times slower.
const LAST_STEP_AFTER_CLICK: Duration = Duration::from_secs(1);

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
    // The plot has the run: its 600 points and the start, and the positions executed so far.
    let (commanded, executed): (usize, usize) =
        serde_json::from_value(page.eval("return [plotRun.commanded.length, executed.length]"))
            .unwrap();
    assert_eq!(commanded, 601);
    assert!(executed > 10, "{executed} executed positions plotted");
    if std::env::var_os("PENDANT_SCREENSHOT").is_some() {
        let path = PathBuf::from(std::env::var_os("PENDANT_SCREENSHOT").unwrap());
        page.screenshot(&path);
        println!("screenshot: {}", path.display());
    }
    // Hold (issue 32): the run slows to a standstill and stays there, still RUNNING.
    page.click("#hold");
    assert!(
        page.wait_for(
            "return snap.state === 'RUNNING' && snap.motion.held && snap.motion.at_rest",
            PAGE_WAIT
        ),
        "hold: {}",
        page.text("body")
    );
    // At rest is the rate at the present; the simulator's positions are the pulses its
    // step thread has played, up to a few ms behind (more on a loaded machine): 20 updates
    // for them to catch up, then 20 more that must not move.
    let updates = |what: &str| {
        let e0 = events(&page);
        assert!(
            page.wait_for(
                &format!("return window.pendantEvents > {e0} + 20"),
                PAGE_WAIT
            ),
            "no updates while held ({what})"
        );
    };
    updates("settling");
    let held: Vec<i64> = serde_json::from_value(page.eval("return snap.steps")).unwrap();
    updates("standing");
    let still: Vec<i64> = serde_json::from_value(page.eval("return snap.steps")).unwrap();
    assert_eq!(still, held, "the arm moved while held (20 updates later)");
    assert!(
        page.text("#speed").contains("HELD at rest"),
        "{}",
        page.text("#speed")
    );
    // The wired input's stop category (MOTION byte 7): the default, 0.
    assert!(
        page.text("#estopin").ends_with(", category 0"),
        "{}",
        page.text("#estopin")
    );
    // Resume: the run goes on.
    page.click("#resume");
    assert!(
        page.wait_for(
            &format!(
                "return !snap.motion.held && snap.steps[0] !== {} && snap.state === 'RUNNING'",
                held[0]
            ),
            PAGE_WAIT
        ),
        "resume: {}",
        page.text("body")
    );
    // The override slider: 50 %.
    page.eval(
        "const o = document.getElementById('override'); o.value = 50; \
         o.dispatchEvent(new Event('change')); return true",
    );
    assert!(
        page.wait_for("return snap.motion.factor_percent === 50", PAGE_WAIT),
        "override: {}",
        page.text("body")
    );
    println!("speed line: {}", page.text("#speed"));

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
    assert_jog_refused(&page, "read-only: 127.0.0.2 owns the controller");
    done.store(true, std::sync::atomic::Ordering::Relaxed);
    let _ = keeper.join();
}

/// A jog asked by the page's own script (as a hand-made request would) is refused, saying
/// `why`.
fn assert_jog_refused(page: &Session, why: &str) {
    let answer: serde_json::Value =
        serde_json::from_value(page.eval(
            "return await fetch('/api/jog?joint=0&by=1', {method: 'POST'}).then(r => r.json())",
        ))
        .unwrap();
    assert_eq!(answer["ok"], false, "{answer}");
    assert!(
        answer["message"].as_str().unwrap_or_default().contains(why),
        "{answer}"
    );
}

#[test]
fn a_keyed_controller_is_driven_through_the_key_and_the_token() {
    if !browser_or_skip("a_keyed_controller_is_driven_through_the_key_and_the_token") {
        return;
    }
    let _alone = system_tests::run_alone();
    let sim = described_sim();
    let key = sim.dir().join("arm.key");
    let (ok, out, err) = run_armctl(None, &["key", "new", "-o", key.to_str().unwrap()]);
    assert!(ok, "key new: {out}{err}");
    let (ok, out, err) = run_armctl(Some(&sim), &["key", "set", key.to_str().unwrap()]);
    assert!(ok, "key set: {out}{err}");
    // Served with the token required (as beyond loopback): the printed URL carries it.
    let pendant = Pendant::start_with(
        &sim,
        &["--key-file", key.to_str().unwrap()],
        &["--require-token"],
    );
    assert!(pendant.url.contains("?token="), "{}", pendant.url);
    let driver = Driver::start();
    let page = open(&driver, &pendant.url);
    // Without the token, nothing that moves the arm.
    assert_jog_refused(&page, "needs the token");
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

/// Bad requests from the network (no browser needed): each gets an error, none stops the
/// server or disturbs the run in progress, which ends with every point executed.
#[test]
fn bad_requests_get_errors_and_leave_the_run_alone() {
    let _alone = system_tests::run_alone();
    let sim = described_sim();
    let pendant = Pendant::start(&sim);
    let url = pendant.url.as_str();
    // The page is ready once the arm is known.
    let deadline = Instant::now() + PAGE_WAIT;
    while !system_tests::pendant::request(url, "GET", "/api/state", b"")
        .1
        .contains("\"base\"")
    {
        assert!(Instant::now() < deadline, "the pendant never knew the arm");
        std::thread::sleep(Duration::from_millis(50));
    }
    let file = std::fs::read(trajectory(sim.dir(), 3, 0)).unwrap();
    let (status, body) =
        system_tests::pendant::request(url, "POST", "/api/check?name=t.csv", &file);
    assert_eq!(status, 200, "{body}");
    let (status, body) = system_tests::pendant::request(url, "POST", "/api/run", b"");
    assert_eq!(status, 200, "{body}");
    // A bad file checked while the run starts is refused and leaves the run's file alone
    // (a CI run saw the run read this upload: "cannot parse: line 2").
    let (status, body) = system_tests::pendant::request(
        url,
        "POST",
        "/api/check?name=t.csv",
        b"t,j0\nnot,a,number\n",
    );
    assert!((400..500).contains(&status), "{status} {body}");

    let host = url.trim_start_matches("http://").trim_end_matches('/');
    let raw = |bytes: &[u8]| -> String {
        use std::io::{Read, Write};
        let mut s = std::net::TcpStream::connect(host).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
        let _ = s.write_all(bytes);
        let _ = s.shutdown(std::net::Shutdown::Write);
        let mut answer = String::new();
        let _ = s.read_to_string(&mut answer);
        answer.lines().next().unwrap_or_default().to_string()
    };
    assert!(raw(b"GARBAGE\r\n\r\n").contains("400"));
    assert!(raw(b"\xff\xfe\x00 / HTTP/1.1\r\n\r\n").contains("400"));
    assert!(
        raw(format!("GET /{} HTTP/1.1\r\n\r\n", "a".repeat(10_000)).as_bytes()).contains("431")
    );
    assert!(
        raw(b"POST /api/check?name=x.csv HTTP/1.1\r\nContent-Length: 99999999\r\n\r\n")
            .contains("413")
    );
    assert!(raw(b"POST /api/check HTTP/1.1\r\nContent-Length: 50\r\n\r\nshort").contains("400"));
    // A client that opens a connection and says nothing holds one thread, nothing else.
    let _silent = std::net::TcpStream::connect(host).unwrap();
    for (path, body) in [
        ("/api/jog?joint=0&by=NaN", &b""[..]),
        ("/api/jog?joint=99&by=1", b""),
        ("/api/jog?joint=-1&by=1", b""),
        ("/api/jog?joint=0&by=1", b""),
        ("/api/override?percent=abc", b""),
        ("/api/check?name=evil.exe", b"x"),
        ("/api/check?name=x.csv", b"\x00\x01\x02not,a\ncsv"),
        ("/api/check?name=x.json", b"{\"joint_names\": 5}"),
        ("/api/nothing", b""),
    ] {
        let (status, answer) = system_tests::pendant::request(url, "POST", path, body);
        assert!(
            (400..500).contains(&status) && answer.contains("\"ok\":false"),
            "{path}: {status} {answer}"
        );
    }
    assert_eq!(
        system_tests::pendant::request(url, "GET", "/nowhere", b"").0,
        404
    );
    // The run ends on its own, every point executed.
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let (_, state) = system_tests::pendant::request(url, "GET", "/api/state", b"");
        if state.contains("300 points executed") {
            break;
        }
        assert!(
            Instant::now() < deadline && !state.contains("\"error\":true"),
            "the run did not end with every point executed: {state}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

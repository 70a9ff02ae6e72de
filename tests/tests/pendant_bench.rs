//! The pendant's benchmark (issue 35; not a gate): the click on the page's e-stop to the
//! STOPPED on the wire (the page's click time, taken in its handler, against the pendant's
//! `--pcap` capture: one system clock), p50 and p99 over [`BENCH_CLICKS`] clicks, the first
//! during a run; and the page's update rate under a running trajectory. `#[ignore]`d:
//! `.ci/run` runs it with `--ignored --nocapture` and prints the figures.

use std::time::{Duration, Instant};

use system_tests::pendant::{
    PAGE_WAIT, Pendant, browser_or_skip, clicks, described_sim, open, stops_on_the_wire, trajectory,
};
use system_tests::webdriver::Driver;

/// p-th percentile of sorted values.
fn percentile(sorted: &[f64], p: f64) -> f64 {
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

/// Clicks the benchmark makes.
const BENCH_CLICKS: usize = 100;

/// A benchmark, not a check: `.ci/run` runs it with `--ignored --nocapture` to print its
/// figures.
#[test]
#[ignore = "a benchmark: cargo test -p system-tests --test pendant_bench -- --ignored --nocapture"]
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
    // The part before the server read the request (the browser's) and after (the server's
    // and the client library's), for the clicks whose answers came.
    let received: Vec<(f64, f64)> =
        serde_json::from_value(page.eval("return window.pendantStopsReceived")).unwrap_or_default();
    let mut browser: Vec<f64> = received.iter().map(|(c, r)| (r - c).max(0.0)).collect();
    browser.sort_by(f64::total_cmp);
    if !browser.is_empty() {
        println!(
            "of which click to the server reading the request ({} clicks): p50 {:.2} ms, p99 {:.2} ms",
            browser.len(),
            percentile(&browser, 0.5),
            percentile(&browser, 0.99)
        );
    }
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

//! Issue 18: a STOPPED from a third host is obeyed at once while a stranger floods the
//! controller (valid STATUS and garbage mixed, 50,000 datagrams a second: more than the
//! simulator handles, so queues would fill), and the owner's STATUS polls are still
//! answered. Before the receive path's first look (`arm_core::ingress`) this test failed:
//! 5 of 20 STOPPEDs lost, the others up to 25 ms late, the owner's STATUS 404 ms (the
//! issue saw 1 in 20 lost and 1 s at 9k/s on a loaded machine). The simulator runs in this test's process (one per test
//! binary); all traffic is on loopback (127.0.0.1-3), bounded in count and time. The exact
//! figures are `sim-host bench`'s; this test checks none is lost and prints them (its time bounds
//! hold ten times slower).

use std::time::Duration;

use sim_host::app::{receive_shed, start_for_client};
use sim_host::flood::{Flood, estop_under_flood};
use sim_host::options::SimOptions;

#[test]
fn stoppeds_from_a_third_host_take_effect_under_a_strangers_flood() {
    let (board, addr, scratch) =
        start_for_client(&SimOptions::defaults(), "flood-test").expect("simulator");
    let f = estop_under_flood(addr, &board.probe, 20, Flood::one(50_000), receive_shed)
        .expect("measured");
    println!(
        "flood {:.0}/s: STOPPED send -> engine idle p50 {:.2} ms p90 {:.2} ms max {:.2} ms, lost {} of 20; owner STATUS max {:.2} ms; shed {}",
        f.flood_rate_hz,
        f.effect_ms(0.5),
        f.effect_ms(0.9),
        f.effect_ms(1.0),
        f.lost,
        f.status_ms(1.0),
        f.shed.unwrap_or_default()
    );
    board.shut_down();
    let _ = std::fs::remove_dir_all(&scratch);
    assert_eq!(f.lost, 0, "every single STOPPED obeyed without a resend");
    assert_eq!(f.effect.len(), 20);
    // Bounds that hold on a machine ten times slower or busier than the 200 and 250 ms
    // these were (the simulator's figures are tens of microseconds; `sim-host bench` has
    // the targets): what this test guards without a clock is that none is lost, above.
    let slowest = f.effect.iter().max().copied().unwrap_or_default();
    assert!(
        slowest < Duration::from_secs(2),
        "slowest STOPPED {slowest:?}"
    );
    let slowest_poll = f
        .status_round_trips
        .iter()
        .max()
        .copied()
        .unwrap_or_default();
    assert!(
        slowest_poll < Duration::from_millis(2_500),
        "slowest owner STATUS {slowest_poll:?}"
    );
}

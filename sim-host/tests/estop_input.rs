//! Issue 18 part 3, the wired e-stop input in the simulator (`--estop-input`), driven
//! in-process (the Board's `estop_input`, as the board's EXTI interrupt would): opened
//! during a run it stops every STEP output within one step period of its edge (measured in
//! the VCD trace: the `estop_input` wire against the last STEP edge); the controller
//! latches in STOPPED: RUNING and RETURN refused ESTOP_LATCHED, attempt after attempt,
//! while open and after closing until ESTOP_RESET, which is refused while the input is
//! open; after closing and ESTOP_RESET a run works again. STATUS shows the input and the
//! latch. (One simulated controller per process: this file is its own test binary.)

mod common;

use std::time::Duration;

use armctl::vcd;
use common::{Client, points_through, temp_path};
use protocol::{Command, MAX_JOINTS, MoreFlags, State, StatusCode, StatusFlags};
use sim_host::options::SimOptions;

/// Joint 0's step period in the long run: 250 steps/s.
const STEP_PERIOD_NS: u64 = 4_000_000;

fn latch_bits(client: &mut Client) -> (bool, bool, State) {
    let s = client.status();
    (
        s.more_flags.has(MoreFlags::ESTOP_OPEN),
        s.more_flags.has(MoreFlags::ESTOP_LATCHED),
        s.state,
    )
}

/// Waits (polling STATUS) until the controller shows `open` and `latched`.
fn wait_for_bits(client: &mut Client, open: bool, latched: bool) -> State {
    for _ in 0..100 {
        let (o, l, state) = latch_bits(client);
        if (o, l) == (open, latched) {
            return state;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    panic!("STATUS never showed open {open}, latched {latched}");
}

#[test]
fn the_wired_input_stops_a_run_within_a_step_period_latches_and_clears() {
    let trace = temp_path("estop-input.vcd");
    let mut options = SimOptions::defaults();
    options.bind.set_port(0);
    options.estop_input = true;
    options.trace = Some(trace.clone());
    options.settings = Some(temp_path("estop-input.txt"));
    let board = sim_host::app::start_in_background(&options).expect("the simulator starts");
    let input = board
        .estop_input
        .clone()
        .expect("--estop-input gives the input");
    let mut client = Client::new(board.local_addr().expect("a UDP socket"));

    assert_eq!(latch_bits(&mut client), (false, false, State::Stopped));
    // 100 points of 100 ms, joint 0 +25 steps each: 10 s at 250 steps/s.
    let targets: Vec<[i32; MAX_JOINTS]> =
        (1..=100).map(|i| [i * 25, 0, 0, 0, 0, 0, 0, 0]).collect();
    let points = points_through([0; MAX_JOINTS], &targets, 100_000);
    client.ok(&Command::New { count: 100 });
    for chunk in points.chunks(12) {
        client.ok(&Command::Pending(protocol::PointList::Points(chunk)));
    }
    client.ok(&Command::Runing);
    client.wait_moved(0, 11, Duration::from_secs(5));
    assert_eq!(client.status().state, State::Running);

    input.open();
    // The steps stopped in this thread, before any task ran: the motors move no more.
    let stopped_at = board.motors.positions()[0];
    assert!(stopped_at > 10 && stopped_at < 2_500, "{stopped_at}");

    // The controller latched in STOPPED, and says so in STATUS.
    assert_eq!(wait_for_bits(&mut client, true, true), State::Stopped);
    let status = client.status();
    assert!(
        status.flags.has(StatusFlags::STOPPED_BY_HOST),
        "as a STOPPED"
    );
    assert_eq!(status.buffered, 0, "the trajectory is dropped");

    // Open: RUNING refused however often it comes, RETURN too, ESTOP_RESET too.
    for _ in 0..3 {
        let ack = client.command(&Command::Runing);
        assert_eq!(
            (ack.status, ack.state),
            (StatusCode::EstopLatched, State::Stopped)
        );
    }
    let ack = client.command(&Command::Return);
    assert_eq!(ack.status, StatusCode::EstopLatched);
    let ack = client.command(&Command::EstopReset);
    assert_eq!(ack.status, StatusCode::EstopLatched, "not while open");

    // Closed: still latched; an upload is taken but cannot run.
    input.close();
    assert_eq!(wait_for_bits(&mut client, false, true), State::Stopped);
    client.ok(&Command::New { count: 100 });
    for chunk in points.chunks(12) {
        client.ok(&Command::Pending(protocol::PointList::Points(chunk)));
    }
    for _ in 0..3 {
        let ack = client.command(&Command::Runing);
        assert_eq!(
            (ack.status, ack.state),
            (StatusCode::EstopLatched, State::Pending)
        );
    }
    client.ok(&Command::Stopped);
    let ack = client.command(&Command::Return);
    assert_eq!(ack.status, StatusCode::EstopLatched);
    assert_eq!(
        board.motors.positions()[0],
        stopped_at,
        "nothing moved while latched"
    );

    // Cleared: a run works again.
    client.ok(&Command::EstopReset);
    assert_eq!(latch_bits(&mut client), (false, false, State::Stopped));
    let here = [stopped_at as i32, 0, 0, 0, 0, 0, 0, 0];
    let back: Vec<[i32; MAX_JOINTS]> = (1..=10)
        .map(|i| [here[0] + 10 * i, 0, 0, 0, 0, 0, 0, 0])
        .collect();
    let status = client.run_points(
        &points_through(here, &back, 10_000),
        Duration::from_secs(10),
    );
    assert_eq!(status.executed, 10);
    assert!(!status.flags.has(StatusFlags::UNDERRUN));
    assert_eq!(board.motors.positions()[0], stopped_at + 100);

    board.shut_down();
    let vcd = vcd::read_changes(&trace).unwrap();
    let (opened, closed) = vcd
        .high_span("estop_input")
        .expect("the input's opening is traced, and its closing");
    assert!(closed > opened);
    let step0 = &vcd.changes["step0"];
    let last_edge = step0
        .iter()
        .filter(|(t, _)| *t <= closed)
        .map(|(t, _)| *t)
        .max()
        .expect("STEP edges before the stop");
    eprintln!(
        "wired e-stop input opened at {opened} ns; last STEP edge {last_edge} ns ({} ns after it; step period {STEP_PERIOD_NS} ns)",
        last_edge.saturating_sub(opened)
    );
    assert!(
        last_edge <= opened + STEP_PERIOD_NS,
        "a STEP edge at {last_edge} ns, {} ns after the input opened at {opened} ns",
        last_edge - opened
    );
    assert_eq!(
        step0
            .iter()
            .filter(|(t, _)| *t > opened + STEP_PERIOD_NS && *t <= closed)
            .count(),
        0,
        "STEP moved while the input was open"
    );
    // The trace counts what the motors counted.
    assert_eq!(vcd.joint_position(0), i64::from(here[0]) + 100);
}

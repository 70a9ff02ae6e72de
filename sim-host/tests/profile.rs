//! The simulator is the NUCLEO-H743ZI2 by default (issue 19, "One board profile"): it
//! accepts what the board accepts and refuses what the board refuses.

mod common;

use std::time::Duration;

use common::{Sim, points_through, temp_path};
use protocol::{Command, MAX_JOINTS, StatusCode, StatusFlags};

/// The NUCLEO's per-joint step rate limit (its STATUS `max_step_rate_hz`: 200 kHz).
const NUCLEO_MAX_STEP_RATE_HZ: u32 = arm_core::profile::NUCLEO_H743ZI2.max_step_rate_hz();

/// Length of the test's points, microseconds.
const POINT_US: i32 = 10_000;

/// Steps of joint 0 in one `POINT_US` point at `rate_hz`.
fn steps_at(rate_hz: u32) -> i32 {
    (u64::from(rate_hz) * POINT_US as u64 / 1_000_000) as i32
}

/// A trajectory at the NUCLEO's per-joint limit, and one at 150 kHz, are accepted and run
/// to the last step; one a step above the limit is refused INVALID_POINT.
#[test]
fn the_nucleos_per_joint_limit_is_the_simulators() {
    let sim = Sim::start(&["--settings", temp_path("limit.txt").to_str().unwrap()]);
    let mut client = sim.client();
    let mut position = 0;
    for rate in [150_000, NUCLEO_MAX_STEP_RATE_HZ] {
        let mut target = [0; MAX_JOINTS];
        target[0] = position + steps_at(rate);
        let mut start = [0; MAX_JOINTS];
        start[0] = position;
        let points = points_through(start, &[target], POINT_US);
        let status = client.run_points(&points, Duration::from_secs(10));
        assert_eq!(status.executed, 1, "{rate} Hz: {status:?}");
        assert!(
            !StatusFlags(status.flags.0).has(StatusFlags::UNDERRUN),
            "{rate} Hz: {status:?}"
        );
        position = target[0];
        assert_eq!(client.location().position[0], position, "{rate} Hz");
    }

    let mut start = [0; MAX_JOINTS];
    start[0] = position;
    let mut target = start;
    target[0] += steps_at(NUCLEO_MAX_STEP_RATE_HZ) + 1;
    let points = points_through(start, &[target], POINT_US);
    client.ok(&Command::New { count: 1 });
    let ack = client.command(&Command::Pending(protocol::PointList::Points(&points)));
    assert_eq!(ack.status, StatusCode::InvalidPoint, "{ack:?}");
}

/// `hz` as the docs write a step rate: "200 kHz", "1 MHz".
fn rate(hz: u32) -> String {
    if hz.is_multiple_of(1_000_000) {
        format!("{} MHz", hz / 1_000_000)
    } else {
        format!("{} kHz", hz / 1_000)
    }
}

/// `ns` as the docs write a driver time: "2.5 us", "5 us", "100 ns".
fn time(ns: u32) -> String {
    match ns {
        ns if ns < 1_000 => format!("{ns} ns"),
        ns if ns.is_multiple_of(1_000) => format!("{} us", ns / 1_000),
        ns => format!("{} us", f64::from(ns) / 1_000.0),
    }
}

/// A document of the repository, `µs` written `us`.
fn doc(path: &str) -> String {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(path);
    std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .replace("µs", "us")
}

/// The paragraph (lines up to a blank one, or a list item's lines) that contains `marker`.
fn paragraph_with(text: &str, marker: &str) -> String {
    let at = text.find(marker).unwrap_or_else(|| panic!("no {marker:?}"));
    let start = text[..at].rfind("\n\n").map_or(0, |i| i + 2);
    let end = text[at..].find("\n\n").map_or(text.len(), |i| at + i);
    text[start..end]
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
}

/// docs/PROTOCOL.md's "Figures per board" table: row name -> (column name -> cell).
fn figures_per_board(protocol: &str) -> Vec<(String, Vec<(String, String)>)> {
    let start = protocol
        .find("#### Figures per board")
        .expect("docs/PROTOCOL.md has a \"Figures per board\" section");
    let rows: Vec<Vec<String>> = protocol[start..]
        .lines()
        .skip_while(|l| !l.starts_with('|'))
        .take_while(|l| l.starts_with('|'))
        .map(|l| {
            l.trim_matches('|')
                .split('|')
                .map(|c| c.trim().to_string())
                .collect()
        })
        .collect();
    let header = &rows[0];
    rows[2..]
        .iter()
        .map(|row| {
            let cells = header[1..]
                .iter()
                .cloned()
                .zip(row[1..].iter().cloned())
                .collect();
            (row[0].clone(), cells)
        })
        .collect()
}

/// Each board's profile against STATUS (the simulator's) and the docs' figures: the
/// simulator reports the NUCLEO's limits, docs/PROTOCOL.md's "Figures per board" table and
/// its summary of the firmware's figures, docs/BOARD.md's and README.md's driver timing
/// paragraphs state the profiles' numbers. (The QEMU board's STATUS is checked in
/// tests/tests/qemu.rs.)
#[test]
fn status_and_docs_state_each_boards_profile() {
    use arm_core::profile::{self, BoardProfile, NUCLEO_H743ZI2, NUCLEO_H743ZI2_TMC, SIMULATOR};

    // The simulator's STATUS is the NUCLEO's.
    let sim = Sim::start(&["--settings", temp_path("figures.txt").to_str().unwrap()]);
    let status = sim.client().status();
    for board in [&SIMULATOR, &NUCLEO_H743ZI2] {
        assert_eq!(
            status.max_step_rate_hz,
            board.max_step_rate_hz(),
            "{}",
            board.name
        );
        assert_eq!(
            status.step_budget_hz, board.step_budget_hz,
            "{}",
            board.name
        );
        assert_eq!(
            usize::from(status.capacity),
            board.trajectory_capacity,
            "{}",
            board.name
        );
        assert_eq!(
            status.pwm_timer_clock_hz, board.pwm_timer_clock_hz,
            "{}",
            board.name
        );
    }
    assert_eq!(usize::from(status.window), protocol::limits::HOST_WINDOW);

    // docs/PROTOCOL.md: the table, one column per profile.
    let protocol_md = doc("docs/PROTOCOL.md");
    let table = figures_per_board(&protocol_md);
    let expected = |board: &BoardProfile, figure: &str| -> String {
        let d = board.driver;
        match figure {
            "`max_step_rate_hz`" => board.max_step_rate_hz().to_string(),
            "`step_budget_hz`" => board.step_budget_hz.to_string(),
            "`capacity`" => board.trajectory_capacity.to_string(),
            "`pwm_timer_clock_hz`" => board.pwm_timer_clock_hz.to_string(),
            "step timer clock" => board.step_timer_hz.to_string(),
            "STEP high, low, DIR setup" => {
                format!("{}, {}, {}", d.high_ns, d.low_ns, d.dir_setup_ns)
            }
            "DIR latency added to the setup" => board.dir_latency_ns.to_string(),
            "per-joint ceiling of the board" => board.step_rate_ceiling_hz.to_string(),
            "periods per DMA buffer half" => board.step_buffer_half.to_string(),
            "shortest step timer period (DMA reload)" => board.min_dma_period_ns.to_string(),
            "motion held ahead of the pulses, us" => board.lookahead_us.to_string(),
            "step queue, segments" => board.step_queue().to_string(),
            other => panic!("docs/PROTOCOL.md: unknown figure {other:?}"),
        }
    };
    assert_eq!(table.len(), 12, "a row per figure");
    for board in profile::ALL {
        for (figure, cells) in &table {
            let cell = cells
                .iter()
                .find(|(name, _)| name == board.name)
                .unwrap_or_else(|| panic!("docs/PROTOCOL.md: no column {:?}", board.name));
            assert_eq!(cell.1, expected(board, figure), "{}: {figure}", board.name);
        }
    }
    // Its summary of the firmware's figures (the NUCLEO's and the simulator's).
    let summary = paragraph_with(&protocol_md, "**Figures of this firmware**");
    let nucleo = NUCLEO_H743ZI2;
    for stated in [
        format!("`capacity` {} points", nucleo.trajectory_capacity),
        format!("`max_step_rate_hz` {} per joint", nucleo.max_step_rate_hz()),
        format!("`step_budget_hz` {}", nucleo.step_budget_hz),
        format!("`pwm_timer_clock_hz` {}", nucleo.pwm_timer_clock_hz),
        format!("`window` {} datagrams", protocol::limits::HOST_WINDOW),
    ] {
        assert!(
            summary.contains(&stated),
            "docs/PROTOCOL.md: {stated:?} in {summary:?}"
        );
    }

    // docs/BOARD.md and README.md: the driver timing paragraphs.
    let opto = NUCLEO_H743ZI2.driver;
    let tmc = NUCLEO_H743ZI2_TMC.driver;
    let board_md = paragraph_with(&doc("docs/BOARD.md"), "- Driver timing is a build setting");
    for stated in [
        format!(
            "{} high, {} low, {} DIR setup; {} per joint",
            time(opto.high_ns),
            time(opto.low_ns),
            time(opto.dir_setup_ns),
            rate(NUCLEO_H743ZI2.max_step_rate_hz())
        ),
        format!(
            "({}, {}, {}: {} per joint, the board's ceiling)",
            time(tmc.high_ns),
            time(tmc.low_ns),
            time(tmc.dir_setup_ns),
            rate(NUCLEO_H743ZI2_TMC.max_step_rate_hz())
        ),
        format!(
            "The DIR setup gets {} added",
            time(NUCLEO_H743ZI2.dir_latency_ns)
        ),
        format!(
            "({} M steps/s, `step_budget_hz`",
            NUCLEO_H743ZI2.step_budget_hz / 1_000_000
        ),
    ] {
        assert!(
            board_md.contains(&stated),
            "docs/BOARD.md: {stated:?} in {board_md:?}"
        );
    }
    let readme = paragraph_with(&doc("README.md"), "Step pulses are made by timer hardware");
    for stated in [
        format!(
            "output ({} MHz ticks)",
            NUCLEO_H743ZI2.step_timer_hz / 1_000_000
        ),
        format!(
            "{} DIR setup by default (DM542/TB6600: {} per joint)",
            time(opto.dir_setup_ns),
            rate(NUCLEO_H743ZI2.max_step_rate_hz())
        ),
        format!(
            "TMC-class {} with `--features tmc-drivers` ({} per joint)",
            time(tmc.high_ns),
            rate(NUCLEO_H743ZI2_TMC.max_step_rate_hz())
        ),
    ] {
        assert!(
            readme.contains(&stated),
            "README.md: {stated:?} in {readme:?}"
        );
    }
}

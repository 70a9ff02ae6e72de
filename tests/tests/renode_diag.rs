//! `armctl diag` against the NUCLEO firmware itself (the `cargo fw` ELF) on Renode with the
//! step path's models (issue 34 part C): after a run with reversals, the board's own
//! counters (the longest span with every interrupt masked and the code that opened it,
//! the latest DIR write against TIM13's compare, the least DMA slack before an update
//! event, the receive path's) come over the wire and are printed as `armctl diag` prints
//! them, run inside the board's namespace.
//!
//! The figures are the emulator's (Renode's CPU model at 400 MIPS, DMA bursts that take no
//! time): printed, and checked only for being the board's (its clocks, counts that moved,
//! an opener in flash). On a real NUCLEO the same command reads the chip's
//! (docs/BOARD.md's bring-up checklist).
//!
//! Needs Renode (`renode` on PATH or `RENODE`; the prebuilt one needs mono) and root;
//! without them the test prints what it needs and passes.

use std::process::Command;

use armctl::RunOptions;
use protocol::{Diag, MAX_JOINTS, Point};
use system_tests::renode::emulated;
use system_tests::renode::{BOARD, HOSTS, RenodeBoard, unavailable};

/// As the other Renode suites: the emulated CPU at the chip's instruction rate.
const CHIP_MIPS: &str = "sysbus.cpu PerformanceInMips 400";

/// Joints the board drives with erased settings.
const JOINTS: usize = 6;

#[test]
fn armctl_diag_prints_the_boards_own_counters() {
    if let Some(reason) = unavailable() {
        use std::io::Write;
        let _ = writeln!(std::io::stderr().lock(), "{}: {reason}", module_path!());
        return;
    }
    let mut board = RenodeBoard::start_with_step_path(CHIP_MIPS);
    let arm = board.connect_from(HOSTS[0], emulated());
    arm.set_location(&[0; JOINTS]).unwrap();
    // 40 reversals of joint 0 (10 steps each way, 1 ms a point): DIR writes and refills.
    let mut at = [0; MAX_JOINTS];
    let points: Vec<Point> = (0..40)
        .map(|k| {
            let mut to = at;
            to[0] += if k % 2 == 0 { 10 } else { -10 };
            let point = Point::from_motion(1_000, &at, &to);
            at = to;
            point
        })
        .collect();
    arm.run_trajectory(&points, &RunOptions::default(), |_| {})
        .unwrap_or_else(|e| panic!("{e}\n{}", board.log()));

    // The library's answer, checked field by field.
    let d = arm
        .diag()
        .unwrap_or_else(|e| panic!("{e}\n{}", board.log()))
        .unwrap_or_else(|| panic!("the board refused DIAG\n{}", board.log()));
    let g = d.diag;
    assert_eq!(g.cpu_hz, 400_000_000, "{g:?}");
    assert_eq!(g.step_hz, 200_000_000, "{g:?}");
    assert!(g.masked_spans > 0, "{g:?}");
    assert!(
        (0x0800_0000..0x0820_0000).contains(&g.masked_opener),
        "the opener is a code address in flash: {g:?}"
    );
    assert!(g.masked_max_cycles > 0, "Renode's DWT model counts: {g:?}");
    // 39 reversals after the first point (its direction is set before the run starts).
    assert!(g.dir_writes >= 39, "a DIR write at each reversal: {g:?}");
    assert_ne!(g.dir_late_max_ticks, Diag::NO_DIR_WRITE, "{g:?}");
    assert!(g.dma_refills > 0, "{g:?}");
    assert_ne!(g.dma_slack_min_ticks, Diag::NO_REFILL, "{g:?}");
    drop(arm);

    // What a user runs: `armctl diag`, inside the board's namespace (another host, so it
    // also shows that it never takes the controller).
    let output = Command::new("ip")
        .args(["netns", "exec", &board.ns])
        .arg(system_tests::armctl_bin())
        .args([
            "--controller",
            &BOARD.to_string(),
            "--ack-timeout-ms",
            "400",
            "--attempts",
            "20",
            "diag",
        ])
        .output()
        .expect("run armctl in the namespace");
    let out = String::from_utf8_lossy(&output.stdout);
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{out}\n{err}\n{}", board.log());
    {
        use std::io::Write;
        let _ = writeln!(
            std::io::stderr().lock(),
            "renode: armctl diag after 40 reversals (the emulator's figures):\n{out}"
        );
    }
    assert!(out.contains("cycles at 400 MHz"), "{out}");
    assert!(out.contains("after its compare"), "{out}");
    assert!(out.contains("before an update event"), "{out}");
    assert!(out.contains("receive path:"), "{out}");
    board.assert_healthy();
}

//! `armctl diag` (issue 34): the controller's own counters, from any host, never taking
//! the controller: its timing (the longest span with every interrupt masked and the code
//! that opened it, the latest DIR change against its compare, the least DMA slack before
//! an update event) in ns or us with the clocks the DIAG report carries, and its receive
//! path (RX ring overflows, shed datagrams). A controller that does not measure a figure
//! (the simulator; clocks of 0) says "not measured": the figures are the board's own.

use armctl::{Client, Diagnosis};
use protocol::Diag;

use crate::CliResult;

/// Runs `diag`.
pub fn execute(arm: &Client, json: bool) -> CliResult {
    let Some(d) = arm.diag().map_err(|e| e.to_string())? else {
        return Err(
            "the controller does not send DIAG (older than issue 34: STATUS's request byte bit 6 refused)"
                .into(),
        );
    };
    if json {
        let value = serde_json::json!({
            "diag": d.diag,
            "rx_counters": d.rx,
            "masked_max_ns": d.diag.masked_max_ns(),
            "dir_late_max_ns": d.diag.dir_late_max_ns(),
            "dma_slack_min_ns": d.diag.dma_slack_min_ns(),
        });
        println!(
            "{}",
            serde_json::to_string_pretty(&value).map_err(|e| e.to_string())?
        );
    } else {
        for line in lines(&d) {
            println!("{line}");
        }
    }
    Ok(())
}

/// A duration in ns, shown in ns below 10 us, in us with two decimals (rounded down)
/// above.
fn time(ns: u64) -> String {
    if ns < 10_000 {
        format!("{ns} ns")
    } else {
        format!("{}.{:02} us", ns / 1_000, ns % 1_000 / 10)
    }
}

fn mhz(hz: u32) -> String {
    format!("{} MHz", f64::from(hz) / 1e6)
}

/// The text `armctl diag` prints.
fn lines(d: &Diagnosis) -> Vec<String> {
    let g: &Diag = &d.diag;
    let mut out = Vec::new();
    match g.masked_max_ns() {
        None => out.push("masked spans:   not measured on this controller".into()),
        Some(ns) => out.push(format!(
            "masked spans:   longest {} ({} cycles at {}), {}; {} spans",
            time(ns),
            g.masked_max_cycles,
            mhz(g.cpu_hz),
            // 0: none yet, or a controller with no address to give (the simulator).
            match g.masked_opener {
                0 => "no opener address".to_string(),
                at => format!("opened at {at:#010x}"),
            },
            g.masked_spans
        )),
    }
    if g.step_hz == 0 {
        out.push("DIR changes:    not measured on this controller".into());
        out.push("step DMA slack: not measured on this controller".into());
    } else {
        out.push(match g.dir_late_max_ns() {
            None => format!("DIR changes:    none yet (step clock {})", mhz(g.step_hz)),
            Some(ns) => format!(
                "DIR changes:    latest {}{} after its compare ({} ticks at {}); {} changes",
                if ns < 0 { "-" } else { "" },
                time(ns.unsigned_abs()),
                g.dir_late_max_ticks,
                mhz(g.step_hz),
                g.dir_writes
            ),
        });
        out.push(match g.dma_slack_min_ns() {
            // No refill yet, or none measured at all (the simulator has no DMA).
            None => "step DMA slack: no refill measured".into(),
            Some(ns) => format!(
                "step DMA slack: least {} before an update event ({} ticks); {} refills",
                time(ns),
                g.dma_slack_min_ticks,
                g.dma_refills
            ),
        });
    }
    let rx = &d.rx;
    out.push(format!(
        "receive path:   RX ring full {} times ({} frames dropped by the MAC), {} datagrams shed, {} dropped by a full inbox, {} STOPPEDs halted in the receive interrupt",
        rx.ring_full, rx.ring_dropped, rx.shed, rx.inbox_dropped, rx.interrupt_stops
    ));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn diagnosis(diag: Diag) -> Diagnosis {
        Diagnosis {
            status: protocol::StatusReport::default(),
            rx: protocol::RxCounters {
                ring_full: 3,
                shed: 5_000,
                ..protocol::RxCounters::default()
            },
            diag,
        }
    }

    #[test]
    fn a_board_prints_its_figures_in_its_clocks() {
        let l = lines(&diagnosis(Diag {
            cpu_hz: 400_000_000,
            masked_max_cycles: 812,
            masked_opener: 0x0801_2345,
            masked_spans: 96_000,
            step_hz: 200_000_000,
            dir_late_max_ticks: 37,
            dir_writes: 24,
            dma_slack_min_ticks: 4_321,
            dma_refills: 51_200,
        }));
        assert_eq!(
            l[0],
            "masked spans:   longest 2030 ns (812 cycles at 400 MHz), opened at 0x08012345; 96000 spans"
        );
        assert_eq!(
            l[1],
            "DIR changes:    latest 185 ns after its compare (37 ticks at 200 MHz); 24 changes"
        );
        assert_eq!(
            l[2],
            "step DMA slack: least 21.60 us before an update event (4321 ticks); 51200 refills"
        );
        assert!(l[3].contains("RX ring full 3 times"), "{l:?}");
        assert!(l[3].contains("5000 datagrams shed"), "{l:?}");
    }

    #[test]
    fn a_controller_that_does_not_measure_says_so() {
        let l = lines(&diagnosis(Diag::NOT_MEASURED));
        assert!(
            l[..3]
                .iter()
                .all(|l| l.ends_with("not measured on this controller")),
            "{l:?}"
        );
    }
}

//! `sim-host demo` runs its pick-and-place to the end, all its checks pass, and it writes
//! the plot.

use std::process::Command;

#[test]
fn demo_passes_its_checks_and_writes_the_plot() {
    let dir = std::env::temp_dir().join(format!("sim-host-demo-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let plot = dir.join("demo.svg");
    let output = Command::new(env!("CARGO_BIN_EXE_sim-host"))
        .args(["--time-scale", "4", "demo", "--quiet", "--plot"])
        .arg(&plot)
        .output()
        .expect("sim-host runs");
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "demo failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(stdout.contains("8 of 8 checks passed"), "{stdout}");
    assert!(!stdout.contains("FAILED"), "{stdout}");
    let svg = std::fs::read_to_string(&plot).expect("the plot");
    assert!(
        svg.starts_with("<svg") || svg.starts_with("<?xml"),
        "not an SVG"
    );
    assert!(
        svg.contains("polyline") || svg.contains("<path"),
        "nothing drawn"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

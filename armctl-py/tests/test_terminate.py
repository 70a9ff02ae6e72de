"""SIGTERM and SIGHUP stop the arm (issue 30, part 2): what systemd, `docker stop`, `kill` and
a closed terminal send to a script inside `arm.run(...)`. armctl's handler sends STOPPED
(resent until ACKed), then the process dies of the signal, as it would have without armctl.

Each try runs the script in a child Python on a fresh traced simulator. Just before the
signal the test raises PIN0 from its own connection (its ACK is back before `kill` runs):
the pin's rising edge marks the signal on the trace's clock. Printed per try: the signal
to the last STEP edge (the issue's criterion, 100 ms), to the STOPPED the simulator read
(its `estop` wire), and to the child's death. Asserted, as a machine ten times slower
still meets it: the STOPPED arrived (within 1 s of the signal), no STEP edge after the
step engine went idle on it, the controller STOPPED by the host with points left, the
child dead of the signal."""

import signal
import subprocess
import time

import pytest

import armctl
from conftest import SimHost, rising_edges, wait_for_line

TRIES = 5

# The script under test: a 20 s trajectory, 20000 steps on joint 0 at 1000 steps/s.
RUN_20_S = r"""
import sys
import numpy as np
import armctl

with armctl.connect(sys.argv[1]) as arm:
    start = arm.positions()[:1]
    print("running", flush=True)
    arm.run(np.array([0.0, 20.0]), np.array([start, start + 20000]))
print("the run ended", flush=True)
"""


def wait_moving(marker, timeout=20.0):
    """Until a LOCATION report shows joint 0 away from where it was: the run under way."""
    deadline = time.monotonic() + timeout
    while marker.status()["state"] != "RUNNING":
        assert time.monotonic() < deadline, "the arm never ran"
        time.sleep(0.01)
    start = marker.positions()[0]
    while marker.positions()[0] == start:
        assert time.monotonic() < deadline, "the arm never moved"


def signal_one_run(python_child, tmp_path, signum, attempt):
    trace = tmp_path / f"{signum.name}-{attempt}.vcd"
    host = SimHost("--trace", str(trace))
    try:
        child = python_child(RUN_20_S, host.address)
        wait_for_line(child, "running")
        started = time.monotonic()
        with armctl.connect(host.address) as marker:
            wait_moving(marker)
            time.sleep(max(0.0, 1.0 - (time.monotonic() - started)))
            marker.pin(0, True)
            signalled = time.monotonic()
            child.send_signal(signum)
            try:
                child.wait(timeout=10)
            except subprocess.TimeoutExpired:
                pytest.fail(f"try {attempt + 1}: the script still runs 10 s after {signum.name}")
            died_ms = (time.monotonic() - signalled) * 1e3
            stderr = child.stderr.read()
            assert child.returncode == -signum, \
                f"try {attempt + 1}: exit {child.returncode}, not death by {signum.name}\n{stderr}"
            status = marker.status()
            assert status["state"] == "STOPPED", f"the arm goes on after {signum.name}: {status}"
            assert status["flags"]["stopped_by_host"], status
            assert status["executed"] < status["expected"], status
            assert "STOPPED sent" in stderr and "not ACKed" not in stderr, stderr
    finally:
        host.close()
    edges = rising_edges(trace)
    mark = edges["pin0"][0]
    steps = [t for name, ts in edges.items() if name.startswith("step") for t in ts]
    # Moving when signalled: a STEP edge in the second before the mark. (It was 100 ms, which
    # a simulator starved that long on a busy machine misses: the Rust twin,
    # tests/tests/interrupt.rs, widened it to 1 s so; wait_moving already saw the arm move.)
    assert any(mark - 1_000_000_000 < t <= mark for t in steps), \
        f"try {attempt + 1}: no STEP edge in the second before the signal: the arm was not moving"
    estops = [t for t in edges.get("estop", []) if t >= mark]
    assert estops, f"try {attempt + 1}: no STOPPED reached the controller after {signum.name}"
    idle = [t for t in rising_edges(trace, level="0").get("estop", []) if t >= estops[0]]
    assert idle, f"try {attempt + 1}: the step engine never went idle on the STOPPED"
    last_ms = (max(steps) - mark) / 1e6
    estop_ms = (estops[0] - mark) / 1e6
    idle_ms = (idle[0] - mark) / 1e6
    print(f"{signum.name} {attempt + 1}/{TRIES}: signal to last STEP edge {last_ms:.2f} ms, "
          f"to STOPPED read {estop_ms:.2f} ms, to idle {idle_ms:.2f} ms, to death {died_ms:.1f} ms; "
          f"{status['executed']} of {status['expected']} points executed")
    return last_ms, estop_ms, idle_ms


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP], ids=lambda s: s.name)
def test_a_signal_1_s_into_run_stops_the_arm_then_kills_the_script_5_of_5(
        python_child, tmp_path, signum):
    figures = [signal_one_run(python_child, tmp_path, signum, i) for i in range(TRIES)]
    worst = max(last for last, _, _ in figures)
    print(f"{signum.name}: worst last STEP edge {worst:.2f} ms after the signal (criterion 100 ms)")
    for attempt, (last_ms, estop_ms, idle_ms) in enumerate(figures):
        # Ten times the criterion: the STOPPED went at once, not at the run's end.
        assert estop_ms < 1000.0, f"try {attempt + 1}: STOPPED read {estop_ms:.0f} ms after the signal"
        # Nothing steps once the step engine went idle on that STOPPED.
        assert last_ms <= idle_ms, \
            f"try {attempt + 1}: a STEP edge {last_ms - idle_ms:.2f} ms after the step engine stopped"


def signal_script(python_child, sim, script, signum=signal.SIGTERM):
    """Runs `script` against `sim`, sends `signum` once it printed "moving" and the arm
    moves; returns its exit code, stderr and the controller's status after."""
    child = python_child(script, sim.address)
    wait_for_line(child, "moving")
    with armctl.connect(sim.address) as marker:
        wait_moving(marker)
        child.send_signal(signum)
        try:
            child.wait(timeout=10)
        except subprocess.TimeoutExpired:
            pytest.fail(f"the script still runs 10 s after {signum.name}")
        return child.returncode, child.stderr.read(), marker.status()


def test_sigterm_in_a_with_block_stops_a_run_started_without_wait(sim, python_child):
    script = r"""
import sys, time
import numpy as np
import armctl

with armctl.connect(sys.argv[1]) as arm:
    start = arm.positions()[:1]
    arm.run(np.array([0.0, 20.0]), np.array([start, start + 20000]), wait=False)
    print("moving", flush=True)
    time.sleep(30)
"""
    code, stderr, status = signal_script(python_child, sim, script)
    assert status["state"] == "STOPPED" and status["flags"]["stopped_by_host"], status
    assert code == -signal.SIGTERM, stderr
    assert "armctl: SIGTERM: STOPPED sent, the arm is stopped" in stderr, stderr


def test_a_handler_of_the_users_own_is_kept_and_its_exception_stops_the_run(sim, python_child):
    """The user's handler runs instead of armctl's; raising from it ends run() like any
    exception: STOPPED first, then it propagates (here SystemExit(3))."""
    script = r"""
import signal, sys
import numpy as np
import armctl

def leave(signum, frame):
    print("my handler", flush=True)
    sys.exit(3)

signal.signal(signal.SIGTERM, leave)
with armctl.connect(sys.argv[1]) as arm:
    assert signal.getsignal(signal.SIGTERM) is leave
    start = arm.positions()[:1]
    print("moving", flush=True)
    arm.run(np.array([0.0, 20.0]), np.array([start, start + 20000]))
"""
    code, stderr, status = signal_script(python_child, sim, script)
    assert status["state"] == "STOPPED" and status["flags"]["stopped_by_host"], status
    assert code == 3, stderr
    assert "armctl: SIGTERM" not in stderr, stderr

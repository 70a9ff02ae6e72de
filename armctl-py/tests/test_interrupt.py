"""Motion calls stop what they started (issue 18): a KeyboardInterrupt or any other exception
inside run() or go_home(), or inside a `with armctl.connect(...)` block while a motion this
connection started is under way, sends STOPPED (resent until ACKed) before it propagates.

Each test ends with the controller STOPPED, STATUS flag bit 7 (stopped by host) set, points
left unexecuted, and positions that no longer change."""

import contextlib
import os
import signal
import threading
import time

import numpy as np
import pytest

import armctl
from conftest import SimHost, rising_edges


@pytest.fixture
def sim_no_encoders():
    """A simulator whose RETURN trusts the step count (set_location moves the arm's idea of
    where it is, so RETURN has a long way to go)."""
    host = SimHost("--no-encoders")
    yield host
    host.close()


# How long after SIGINT a motion call may return: a bound a machine ten times slower or
# busier still meets (the call looks at its token every 20 ms), and below the 2.5 s or more
# the moves below go on after the signal if the call ignored it. (It was 0.5 s after the
# signal's planned time, 1.5 s after the start: the timer thread itself can be late.)
RETURN_AFTER_SIGNAL = 2.0

# The criterion: no STEP edge more than 100 ms after the signal; printed. The
# simulator runs on the wall clock, so the assertion is 1 s (ten times slower or busier),
# below the 9 s of steps a run that was not stopped leaves.
LAST_STEP_CRITERION_MS = 100.0
LAST_STEP_AFTER_SIGNAL_MS = 1000.0


# When the Ctrl-C goes, at the earliest: one second into the motion call (the scenario, as
# SIGNAL_AFTER in tests/tests/interrupt.rs; not a wait for the controller).
SIGNAL_AFTER = 1.0

# How long the motion may take to be visibly under way. A fixed 1 s timer once assumed it
# was: on a loaded machine the 1000-point upload can take the whole second, and the signal
# then comes before the arm has stepped (the Rust twin, tests/tests/interrupt.rs, failed so
# under the issue 19 soak's load, and now waits for the arm to have moved). 20 s: room for
# a machine ten times slower or busier, and longer than the moves below (a motion that ended
# unseen fails saying so, not with a Ctrl-C at some later point).
MOVING_WITHIN = 20.0


@contextlib.contextmanager
def ctrl_c_once_moving(watcher, mark=None):
    """SIGINT to this process from a thread, once the motion call made inside the block is
    visibly under way: `watcher`, a connection of its own, polls STATUS until RUNNING, then
    LOCATION until joint 0 is away from where it was then (MOVING_WITHIN at most), and the
    signal goes no earlier than SIGNAL_AFTER after the block began. Python raises
    KeyboardInterrupt in the main thread, wherever it waits. `mark()`, if given, runs just
    before the signal. The yielded list gets the time the signal went. Leaving the block
    ends the watch (no signal after it); if the thread failed (the arm never ran or moved),
    that is raised there."""
    sent, failed = [], []
    started = time.monotonic()
    ended = threading.Event()
    lock = threading.Lock()

    def watch():
        try:
            deadline = started + MOVING_WITHIN
            while watcher.status()["state"] != "RUNNING":
                if ended.is_set():
                    return
                assert time.monotonic() < deadline, f"the arm never ran within {MOVING_WITHIN:g} s"
                time.sleep(0.01)
            start = watcher.positions()[0]
            while watcher.positions()[0] == start:
                if ended.is_set():
                    return
                assert time.monotonic() < deadline, \
                    f"the arm never moved from {start} within {MOVING_WITHIN:g} s"
                time.sleep(0.01)
            ended.wait(max(0.0, SIGNAL_AFTER - (time.monotonic() - started)))
            with lock:
                if ended.is_set():
                    return
                if mark is not None:
                    mark()
                sent.append(time.monotonic())
                os.kill(os.getpid(), signal.SIGINT)
        except BaseException as e:  # re-raised in the main thread, on leaving the block
            failed.append(e)

    thread = threading.Thread(target=watch, name="ctrl-c-once-moving", daemon=True)
    thread.start()
    try:
        yield sent
    finally:
        with lock:
            ended.set()
        thread.join()
        if failed:
            raise AssertionError(f"no Ctrl-C sent: {failed[0]}") from failed[0]


def long_ramp(arm, steps=10000, seconds=10.0):
    start = arm.positions()[:1]
    return start, np.array([0.0, seconds]), np.array([start, start + steps])


def wait_running(arm, timeout=10.0):
    deadline = time.monotonic() + timeout
    while arm.status()["state"] != "RUNNING":
        assert time.monotonic() < deadline, "the arm never ran"
        time.sleep(0.01)


def assert_stopped_mid_move(arm):
    status = arm.status()
    assert status["state"] == "STOPPED"
    assert status["flags"]["stopped_by_host"], status
    assert status["executed"] < status["expected"], status
    here = arm.positions()
    time.sleep(0.2)
    np.testing.assert_array_equal(arm.positions(), here, err_msg="the arm still moves")
    return here


def test_ctrl_c_during_run_stops_the_arm(sim):
    with armctl.connect(sim.address) as arm, armctl.connect(sim.address) as watcher:
        start, times, positions = long_ramp(arm)
        with pytest.raises(KeyboardInterrupt), ctrl_c_once_moving(watcher) as sent:
            arm.run(times, positions)
        took = time.monotonic() - sent[0]
        print(f"run() returned {took * 1000:.1f} ms after SIGINT")
        assert took < RETURN_AFTER_SIGNAL, f"run() returned {took:.2f} s after SIGINT"
        here = assert_stopped_mid_move(arm)
        assert 0 < here[0] - start[0] < 10000


def test_ctrl_c_during_go_home_stops_the_arm(sim_no_encoders):
    with armctl.connect(sim_no_encoders.address) as arm, \
            armctl.connect(sim_no_encoders.address) as watcher:
        # 12000 steps back at 4000 steps/s: about 3.5 s.
        arm.set_location([12000, -6000])
        with pytest.raises(KeyboardInterrupt), ctrl_c_once_moving(watcher) as sent:
            arm.go_home()
        took = time.monotonic() - sent[0]
        print(f"go_home() returned {took * 1000:.1f} ms after SIGINT")
        assert took < RETURN_AFTER_SIGNAL, f"go_home() returned {took:.2f} s after SIGINT: not at the Ctrl-C"
        here = assert_stopped_mid_move(arm)
        assert 0 < here[0] < 12000


def test_an_exception_in_a_with_block_stops_a_run(sim):
    with pytest.raises(RuntimeError):
        with armctl.connect(sim.address) as arm:
            start, times, positions = long_ramp(arm)
            arm.run(times, positions, wait=False)
            wait_running(arm)
            time.sleep(0.5)
            raise RuntimeError("the light curtain tripped")
    with armctl.connect(sim.address) as arm:
        here = assert_stopped_mid_move(arm)
        assert 0 < here[0] - start[0] < 10000


def test_an_exception_in_a_with_block_stops_a_go_home(sim_no_encoders):
    with pytest.raises(RuntimeError):
        with armctl.connect(sim_no_encoders.address) as arm:
            arm.set_location([12000, -6000])
            arm.go_home(wait=False)
            wait_running(arm)
            time.sleep(0.5)
            raise RuntimeError("the light curtain tripped")
    with armctl.connect(sim_no_encoders.address) as arm:
        here = assert_stopped_mid_move(arm)
        assert 0 < here[0] < 12000


def test_ctrl_c_leaves_no_step_edge_100_ms_after_the_signal_5_of_5(tmp_path):
    """The issue's criterion, read from the simulator's VCD trace: once the arm moves (seen
    from a second connection), just before SIGINT the test raises PIN0 from that connection
    (its ACK is back before the signal), which marks the signal on the trace's clock; the
    last STEP edge after the mark is printed against 100 ms and asserted within
    LAST_STEP_AFTER_SIGNAL_MS. Five runs, each on a fresh traced simulator."""
    for attempt in range(5):
        trace = tmp_path / f"run{attempt}.vcd"
        host = SimHost("--trace", str(trace))
        try:
            with armctl.connect(host.address) as arm, armctl.connect(host.address) as marker:
                start, times, positions = long_ramp(arm)
                with pytest.raises(KeyboardInterrupt), \
                        ctrl_c_once_moving(marker, mark=lambda: marker.pin(0, True)):
                    arm.run(times, positions)
                assert_stopped_mid_move(arm)
        finally:
            host.close()
        edges = rising_edges(trace)
        mark = edges["pin0"][0]
        steps = [t for name, ts in edges.items() if name.startswith("step") for t in ts]
        assert steps, "STEP edges in the trace"
        late_ms = (max(steps) - mark) / 1e6
        met = "met" if late_ms <= LAST_STEP_CRITERION_MS else "missed"
        print(f"run {attempt + 1}: last STEP edge {late_ms:.2f} ms after the signal (criterion {LAST_STEP_CRITERION_MS:.0f} ms: {met})")
        assert late_ms <= LAST_STEP_AFTER_SIGNAL_MS, f"run {attempt + 1}: a STEP edge {late_ms:.1f} ms after SIGINT"

"""The armctl Python module against a real sim-host process."""

import pathlib
import signal
import time

import numpy as np
import pytest

import armctl
from conftest import wait_for_line


def ramp(start, target, seconds, waypoints=11):
    """Waypoints from `start` to `target` (steps) over `seconds`."""
    times = np.linspace(0.0, seconds, waypoints)
    fractions = np.linspace(0.0, 1.0, waypoints)[:, None]
    positions = np.asarray(start)[None, :] + fractions * (np.asarray(target) - np.asarray(start))[None, :]
    return times, np.round(positions).astype(np.int64)


def test_status_and_positions(sim):
    with armctl.connect(sim.address) as arm:
        status = arm.status()
        assert status["state"] == "STOPPED"
        assert status["joints"] == 6
        assert status["version"][0] == 1
        positions = arm.positions()
        assert positions.dtype == np.int32
        assert positions.shape == (6,)


def test_trajectory_from_numpy_ends_exactly(sim):
    with armctl.connect(sim.address) as arm:
        start = arm.positions()
        target = start + np.array([1234, -567, 89, 0, 3000, -1], dtype=np.int32)
        times, positions = ramp(start, target, 0.6)
        report = arm.run(times, positions)
        assert report["points"] == 60
        # The window the controller advertises, as `armctl run` uses (issue 23: it was 8),
        # and STATUS's later fields (issue 23: missing).
        status = arm.status()
        assert report["window"] == status["window"] == 32
        assert status["step_budget_hz"] == 4_000_000
        assert status["more_flags"] == {
            "upload_dropped": False,
            "estop_open": False,
            "estop_latched": False,
        }
        np.testing.assert_array_equal(report["final_positions"], target)
        np.testing.assert_array_equal(arm.positions(), target)
        assert report["final_status"]["executed"] == 60
        assert not report["final_status"]["flags"]["underrun"]


def test_run_handle_progress_wait_and_cancel(sim):
    with armctl.connect(sim.address) as arm:
        start = arm.positions()[:2]
        times, positions = ramp(start, start + [2000, 2000], 0.4)
        handle = arm.run(times, positions, wait=False)
        report = handle.wait(timeout=30)
        assert handle.done and handle.progress["done"]
        assert handle.progress["total"] == report["points"] == 40
        np.testing.assert_array_equal(report["final_positions"][:2], start + 2000)

        # A long run, cancelled: it ends early with reason 'stopped'.
        start = arm.positions()[:2]
        times, positions = ramp(start, start + [4000, 0], 20.0)
        handle = arm.run(times, positions, wait=False)
        deadline = time.monotonic() + 10
        while handle.progress["state"] != "RUNNING" and time.monotonic() < deadline:
            time.sleep(0.02)
        handle.cancel()
        with pytest.raises(armctl.RunEndedError) as ended:
            handle.wait(timeout=10)
        assert ended.value.reason == "stopped"
        assert ended.value.executed < ended.value.total
        status = arm.status()
        assert status["flags"]["stopped_by_host"]
        # Issue 31: the cause, and the STOPPED's sender (this host).
        assert status["stop_cause"] == "STOPPED"
        assert status["stopped_by"] is not None and status["stopped_by"].startswith("127.0.0.1:")


def test_refusals_raise_refused_error_with_the_status(sim):
    with armctl.connect(sim.address) as arm:
        start = arm.positions()[:1]
        times, positions = ramp(start, start + [3000], 20.0)
        handle = arm.run(times, positions, wait=False)
        deadline = time.monotonic() + 10
        while handle.progress["state"] != "RUNNING" and time.monotonic() < deadline:
            time.sleep(0.02)
        # JOINTS_COUNT only while STOPPED.
        with pytest.raises(armctl.RefusedError) as refused:
            arm.set_joints(4)
        assert refused.value.status == "BAD_STATE"
        assert refused.value.command == "JOINTS_COUNT"
        assert refused.value.state == "RUNNING"
        assert isinstance(refused.value, armctl.ArmctlError)
        # Another host (address 127.0.0.2) may read STATUS (issue 23) but not drive
        # an owned controller.
        stranger = armctl.connect(sim.address, bind="127.0.0.2:0")
        assert stranger.status()["state"] == "RUNNING"
        with pytest.raises(armctl.RefusedError) as other:
            stranger.pin(0, True)
        assert other.value.status == "NOT_OWNER"
        handle.cancel()


def test_bad_trajectories_are_refused_before_sending(sim):
    with armctl.connect(sim.address) as arm:
        with pytest.raises(ValueError):
            arm.run(np.array([0.0, 1.0]), np.zeros((3, 2)))
        with pytest.raises(armctl.TrajectoryError):
            # 100000 steps in 10 ms: beyond any step rate.
            arm.run(np.array([0.0, 0.01]), np.array([[0], [100000]]))
        assert arm.status()["state"] == "STOPPED"


def test_no_controller_raises_no_reply():
    with pytest.raises(armctl.NoReplyError):
        # A closed loopback port: nothing answers.
        armctl.connect("127.0.0.1:9", ack_timeout=0.02, attempts=2)


def test_locations_iterator(sim):
    with armctl.connect(sim.address) as arm:
        reports = list(arm.locations(count=5, timeout=2.0))
        assert len(reports) == 5
        assert all(r["state"] == "STOPPED" and r["positions"].dtype == np.int32 for r in reports)


CHILD = r"""
import sys, threading, time
import numpy as np
import armctl

address, mode = sys.argv[1], sys.argv[2]


def watch(arm):
    # Runs while the main thread waits in arm.run(): the GIL is released there.
    for report in arm.locations(timeout=30):
        if report["state"] == "RUNNING":
            print("moving", flush=True)
            return


with armctl.connect(address) as arm:
    start = arm.positions()[:1]
    times = np.array([0.0, 30.0])
    positions = np.array([start, start + 100000])
    threading.Thread(target=watch, args=(arm,), daemon=True).start()
    if mode == "wait":
        arm.run(times, positions)            # Ctrl-C here: STOPPED, then KeyboardInterrupt
    else:
        handle = arm.run(times, positions, wait=False)
        time.sleep(60)                       # Ctrl-C here: the with block sends STOPPED
print("not interrupted", flush=True)
"""


@pytest.mark.parametrize("mode", ["wait", "with-block"])
def test_ctrl_c_stops_the_arm(sim, python_child, mode):
    child = python_child(CHILD, sim.address, mode)
    # The child's own report thread says when the arm moves (and so that its main thread
    # released the GIL while waiting).
    wait_for_line(child, "moving")
    with armctl.connect(sim.address) as arm:
        # STATUS only while the child runs: both are 127.0.0.1, one owner, and LOCATION
        # reports go to whichever of the two sent the latest frame.
        running = arm.status()
        assert running["state"] == "RUNNING"
        time.sleep(0.3)  # some steps made: the stop below is mid-move
        child.send_signal(signal.SIGINT)
        _, stderr = child.communicate(timeout=20)
        assert child.returncode != 0
        assert "KeyboardInterrupt" in stderr
        status = arm.status()
        assert status["state"] == "STOPPED"
        assert status["flags"]["stopped_by_host"]
        assert running["executed"] <= status["executed"] < status["expected"]
        stopped_at = arm.positions()[0]
        time.sleep(0.2)
        assert arm.positions()[0] == stopped_at, "the arm still moves"
        assert stopped_at > 0


def test_discover_and_net_set(sim):
    # DISCOVER sent to the simulator's own address (a broadcast only inside a namespace).
    found = armctl.discover(sim.address, wait=0.2)
    assert len(found) == 1
    assert found[0]["address"] == sim.address
    assert found[0]["mac"].startswith("02:53:49:4d")
    assert found[0]["joints"] == 6
    with armctl.connect(sim.address) as arm:
        arm.net_set(ip="10.4.5.6/24", gateway="10.4.5.1")
        with pytest.raises(ValueError):
            arm.net_set(ip="10.4.5.255/24")
    found = armctl.discover(sim.address, wait=0.2)[0]
    assert (found["stored_ip"], found["prefix_len"], found["gateway"]) == ("10.4.5.6", 24, "10.4.5.1")
    assert found["pending_reset"]
    assert found["owner"] == "owned by you"


EXAMPLES = pathlib.Path(__file__).resolve().parents[2] / "armctl" / "examples"


def test_radians_with_a_joint_config_and_run_file(sim):
    config = EXAMPLES / "arm.json"
    with armctl.connect(sim.address) as arm:
        np.testing.assert_array_equal(arm.positions(), np.zeros(6, dtype=np.int32))
        # Waypoints in radians: steps = zero_offset + rad * steps_per_radian.
        times = np.array([0.0, 0.3, 0.6])
        radians = np.array([[0.0] * 6, [0.1, -0.05, 0.2, 0.0, 0.3, -0.3], [0.2, -0.1, 0.4, 0.1, 0.6, -0.6]])
        report = arm.run(times, radians, config=config)
        spr = np.array([5093.0, 5093.0, 5093.0, 2546.0, 2546.0, 2546.0])
        np.testing.assert_array_equal(report["final_positions"], np.round(radians[-1] * spr).astype(np.int32))
        # A joint limit of the config: refused before anything moves.
        with pytest.raises(armctl.TrajectoryError):
            arm.run(np.array([0.0, 10.0]), np.array([radians[-1], [10.0] + [0.0] * 5]), config=config)
        # The same files `armctl run` takes: back to zero first, then the CSV (steps).
        arm.run(np.array([0.0, 0.5]), np.array([radians[-1], [0.0] * 6]), config=config)
        report = arm.run_file(EXAMPLES / "wave.csv")
        np.testing.assert_array_equal(report["final_positions"][:3], [0, 0, 0])
        assert report["points"] == 200


def test_connect_without_a_port_and_a_wrong_pin(sim):
    """Issue 23: connect("127.0.0.1") failed for want of a port (the CLI takes 8510), and
    pin(3) raised a "network error"."""
    host, _port = sim.address.rsplit(":", 1)
    # HOST alone means HOST:8510: connecting there reaches 8510 (nothing listens there in
    # this test, unless something else does), not an address error.
    try:
        with armctl.connect(host) as arm:
            assert arm.address.endswith(":8510")
    except armctl.NoReplyError as e:
        assert "127.0.0.1:8510" in str(e), str(e)
    with armctl.connect(sim.address) as arm:
        with pytest.raises(ValueError, match="pin must be 0 or 1"):
            arm.pin(3, True)
        arm.pin(1, True)
        assert arm.status()["flags"]["pin1_high"]


def test_a_keyed_controller_moves_for_the_key_holder_only(sim, tmp_path):
    """Issue 21: with a key set, a connection without it is refused AUTH_REQUIRED and
    moves nothing; one with key_file= runs a trajectory; the key is cleared with it."""
    key_file = tmp_path / "arm.key"
    key_file.write_text("7e" * 32 + "\n")
    with armctl.connect(sim.address) as arm:
        start = arm.positions()
        arm.set_key(key_file)
    with pytest.raises(armctl.RefusedError) as refused:
        armctl.connect(sim.address)
    assert "AUTH_REQUIRED" in str(refused.value)
    with armctl.connect(sim.address, key_file=key_file) as arm:
        assert (arm.positions() == start).all()
        target = start.copy()
        target[0] += 200
        times, positions = ramp(start, target, 0.3)
        arm.run(times, positions)
        assert arm.positions()[0] == start[0] + 200
        arm.set_key(None)
    with armctl.connect(sim.address) as arm:
        assert arm.status()["state"] == "STOPPED"


def test_a_refused_upload_leaves_the_controller_stopped(sim):
    """Issue 23's follow-up: a point past a limit kept on the controller is refused
    INVALID_POINT after the points before it were taken; the controller must not be left
    in PENDING with them (the next run would be refused), as `armctl run` ensures."""
    with armctl.connect(sim.address) as arm:
        arm.set_limits(1, min=-1000, max=50)
        times = np.arange(400) * 0.01
        # Joint 1 passes its limit of 50 after 200 points, several frames into the upload.
        positions = np.zeros((400, 2), dtype=np.int32)
        positions[:, 1] = np.arange(400) // 4
        with pytest.raises(armctl.RefusedError) as refused:
            arm.run(times, positions)
        assert refused.value.status == "INVALID_POINT"
        assert arm.status()["state"] == "STOPPED"
        # The next motion is taken.
        positions[:, 1] = np.minimum(positions[:, 1], 50)
        report = arm.run(times, positions)
        assert report["final_positions"][1] == 50
        arm.set_limits(1, min=-2**31, max=2**31 - 1, max_rate_hz=0)


def test_a_refused_upload_of_a_run_nobody_waits_for_leaves_the_controller_stopped(sim):
    """Issue 31: every tool leaves the controller STOPPED after a refused upload. A
    wait=False run whose handle is never waited (the script goes on, or leaves its `with`
    block normally) left it PENDING with the points taken before the refusal."""
    with armctl.connect(sim.address) as arm:
        arm.set_limits(1, min=-1000, max=50)
        times = np.arange(400) * 0.01
        positions = np.zeros((400, 2), dtype=np.int32)
        positions[:, 1] = np.arange(400) // 4
        handle = arm.run(times, positions, wait=False)
        deadline = time.monotonic() + 20
        while not handle.done:
            assert time.monotonic() < deadline, "the refused run never ended"
            time.sleep(0.01)
        assert arm.status()["state"] == "STOPPED"
        arm.set_limits(1, min=-2**31, max=2**31 - 1, max_rate_hz=0)
        with pytest.raises(armctl.RefusedError):
            handle.wait()


def test_enable_disable_release_and_limits(sim):
    """Issue 23: explicit per-joint enable, RELEASE, limits on the controller."""
    with armctl.connect(sim.address) as arm:
        arm.disable([0, 1])
        arm.disable([0, 1])
        enabled = arm.status()["enabled"]
        assert enabled is not None
        assert enabled["joints"][:2] == [False, False]
        assert all(enabled["joints"][2:]) and enabled["gripper"]
        arm.enable()
        assert all(arm.status()["enabled"]["joints"])
        with pytest.raises(ValueError):
            arm.enable([9])
        arm.set_limits(1, min=-100, max=100, max_rate_hz=2000)
        limits = arm.limits()
        assert limits[1] == {"min": -100, "max": 100, "max_rate_hz": 2000}
        arm.set_limits(1, max=50)
        assert arm.limits()[1]["max"] == 50
        with pytest.raises(ValueError):
            arm.set_limits(1, min=60)
        with pytest.raises(armctl.RefusedError) as refused:
            arm.set_location([0, 500])
        assert refused.value.status == "INVALID_POINT"
        arm.set_limits(1, min=-2**31, max=2**31 - 1, max_rate_hz=0)
        arm.set_location([12, -34])
        # Another host reads the positions without owning the controller.
        watcher = armctl.connect(sim.address, bind="127.0.0.3:0")
        assert list(watcher.positions()[:2]) == [12, -34]
        with pytest.raises(armctl.RefusedError) as other_refused:
            watcher.pin(0, True)
        assert other_refused.value.status == "NOT_OWNER"
        arm.release()
        # Another host takes the controller at once.
        other = armctl.connect(sim.address, bind="127.0.0.2:0")
        other.pin(0, True)

"""Issue 32: hold(), resume(), override(percent) and run(..., speed=) from Python against
sim-host. The timing figures are the simulator's own tests' (sim-host/tests/hold.rs, on
virtual time); here the calls and that every point still runs exactly."""

import time

import numpy as np
import pytest

import armctl


def test_run_at_half_speed_ends_exact_and_takes_at_least_twice_as_long(sim):
    times = np.array([0.0, 0.5])
    positions = np.array([[0, 0], [400, -200]])
    with armctl.connect(sim.address) as arm:
        report = arm.run(times, positions, speed=50)
        np.testing.assert_array_equal(report["final_positions"][:2], [400, -200])
        # A lower bound only: a slower machine makes a run longer, never shorter.
        assert report["total_time"] >= 0.95, report
        with pytest.raises(ValueError, match="1 to 200"):
            arm.run(times, positions, speed=0)
        arm.override(100)


def test_hold_and_resume_a_run_in_flight(sim):
    times = np.array([0.0, 3.0])
    positions = np.array([[0], [3000]])
    with armctl.connect(sim.address) as arm:
        handle = arm.run(times, positions, wait=False)
        # Bounded wait for the run to be moving (what we observe, not a guessed delay).
        deadline = time.monotonic() + 30
        while arm.positions()[0] == 0:
            assert time.monotonic() < deadline, "the run never moved"
            time.sleep(0.01)
        arm.hold()
        arm.hold()  # again: nothing more
        arm.resume()
        report = handle.wait(timeout=120)
        np.testing.assert_array_equal(report["final_positions"][:1], [3000])


def test_override_is_checked(sim):
    with armctl.connect(sim.address) as arm:
        with pytest.raises(ValueError, match="1 to 200"):
            arm.override(201)
        arm.override(25)
        arm.override(100)
        with pytest.raises(armctl.RefusedError, match="BAD_STATE"):
            arm.hold()  # nothing runs


def test_estop_category_is_set_and_read_back(sim):
    with armctl.connect(sim.address) as arm:
        assert arm.estop_category() == 0
        assert arm.estop_category(1) == 1
        assert arm.estop_category() == 1
        with pytest.raises(ValueError, match="0 or 1"):
            arm.estop_category(2)
        assert arm.estop_category(0) == 0

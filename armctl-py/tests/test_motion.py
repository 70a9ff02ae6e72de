"""Issue 23: move_to, jog and home from Python, in steps and in degrees."""

import json

import numpy as np
import pytest

import armctl


def test_move_jog_home_in_steps(sim):
    with armctl.connect(sim.address) as arm:
        report = arm.move_to([400, None, -300])
        np.testing.assert_array_equal(report["final_positions"][:3], [400, 0, -300])
        assert arm.move_to([400]) is None  # already there
        arm.jog(1, 50)
        arm.jog(1, -20)
        np.testing.assert_array_equal(arm.positions()[:3], [400, 30, -300])
        np.testing.assert_array_equal(arm.home(), np.zeros(6, dtype=np.int32))


def test_move_in_degrees_with_a_config_and_its_limits(sim, tmp_path):
    config = tmp_path / "arm.json"
    joints = [{"name": f"j{j}", "steps_per_radian": 1000, "max_step_rate_hz": 4000} for j in range(6)]
    joints[1].update(name="elbow", min_steps=-785, max_steps=785)
    config.write_text(json.dumps({"units": "deg", "joints": joints}))
    with armctl.connect(sim.address) as arm:
        report = arm.move_to([30, 10], config=config)
        # 30 deg = 523.6 steps, 10 deg = 174.5 steps: whole steps.
        np.testing.assert_array_equal(report["final_positions"][:2], [524, 175])
        arm.jog("elbow", -5, config=config)
        assert arm.positions()[1] == 88
        with pytest.raises(armctl.TrajectoryError, match="outside its range"):
            arm.move_to([None, 50], config=config)
        with pytest.raises(ValueError, match="need a joint config"):
            arm.move_to([1.0], units="deg")
        with pytest.raises(ValueError, match="units"):
            arm.move_to([1.0], config=config, units="furlongs")
        arm.home()


def test_serial_pass_through(sim):
    """Issue 23: the Python package had no serial port (sim-host's is a loopback)."""
    with armctl.connect(sim.address) as arm:
        with pytest.raises(armctl.ArmctlError, match="before serial_open"):
            arm.serial_read(timeout=0.1)
        arm.serial_open(115200)
        arm.serial_write(b"G28\n")
        received = b""
        for _ in range(20):  # bounded: the loopback answers within its line time
            received += arm.serial_read(timeout=0.5)
            if received == b"G28\n":
                break
        assert received == b"G28\n"
        with pytest.raises(armctl.RefusedError):
            arm.serial_open(12)
        arm.serial_close()

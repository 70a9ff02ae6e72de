"""Issue 31: with no config, run(), move_to and positions() use the arm the controller
describes: `armctl config push` stored each joint's name, units (degrees here) and
limits on it, so a Python user needs no file."""

import json
import os
import pathlib
import subprocess

import numpy as np
import pytest

import armctl

ROOT = pathlib.Path(__file__).resolve().parents[2]


def armctl_cli() -> pathlib.Path:
    """The armctl binary of this repository ($CARGO_TARGET_DIR respected), built when
    missing."""
    target = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    binary = target / "debug" / "armctl"
    if not binary.exists():
        subprocess.run(["cargo", "build", "-p", "armctl", "--bin", "armctl"], cwd=ROOT, check=True)
    return binary


def test_no_config_reads_names_units_and_limits_from_the_controller(sim, tmp_path):
    # 1000 steps per radian (17.45 steps a degree), every joint; the elbow +-45 degrees.
    joints = [{"name": f"j{j}", "steps_per_radian": 1000, "max_step_rate_hz": 4000}
              for j in range(6)]
    joints[1].update(name="elbow", min_steps=-785, max_steps=785)
    config = tmp_path / "arm.json"
    config.write_text(json.dumps({"units": "deg", "joints": joints}))
    pushed = subprocess.run(
        [str(armctl_cli()), "--controller", sim.address, "config", "push", str(config)],
        capture_output=True, text=True, timeout=60)
    assert pushed.returncode == 0, pushed.stdout + pushed.stderr
    with armctl.connect(sim.address) as arm:
        # move_to in the controller's degrees: 30 deg = 523.6 steps -> 524.
        report = arm.move_to([30, 10])
        np.testing.assert_array_equal(report["final_positions"][:2], [524, 175])
        # positions() in degrees, as described.
        shown = arm.positions()
        assert shown.dtype == np.float64
        assert abs(shown[0] - 30.02) < 0.01 and abs(shown[1] - 10.03) < 0.01
        # The elbow's limit, named and in degrees.
        with pytest.raises(armctl.TrajectoryError, match=r"elbow: target 50\.02 deg \(873 steps\) "
                           r"is outside its range -44\.98 deg to 44\.98 deg"):
            arm.move_to([None, 50])
        # run() with arrays in degrees, from where the arm is.
        times = np.array([0.0, 1.0])
        positions = np.array([[30.0228, 10.0268], [0.0, -20.0]])
        result = arm.run(times, positions)
        np.testing.assert_array_equal(result["final_positions"][:2], [0, -349])
        assert abs(arm.positions()[1] - (-20.0)) < 0.05
        # units= still overrides: steps.
        np.testing.assert_array_equal(arm.positions(units="steps")[:2], [0, -349])


def test_push_config_and_set_joint_description_as_the_cli_does(sim, tmp_path):
    """Issue 31: Python pushes an arm description as `armctl config push` does (one code,
    armctl::push) and changes one joint's; every host then reads the same arm."""
    joints = [{"name": f"j{j}", "steps_per_radian": 1000, "max_step_rate_hz": 4000}
              for j in range(6)]
    joints[1].update(name="elbow", min_steps=-785, max_steps=785, max_accel_steps_s2=20000)
    config = tmp_path / "arm.json"
    config.write_text(json.dumps({"units": "deg", "joints": joints}))
    with armctl.connect(sim.address) as arm:
        lines = arm.push_config(str(config))
        assert "joint 1 elbow: -785..785 steps, at most 4000 steps/s" in lines, lines
        assert "joint 1 elbow: at most 20000 steps/s²" in lines, lines
        assert arm.limits()[1] == {"min": -785, "max": 785, "max_rate_hz": 4000}
        assert arm.joint_description(1) == {
            "name": "elbow", "unit": "deg", "zero_offset": 0, "scale": 1000.0,
            "described": True}
        # move_to without a config: the pushed degrees (30 deg = 523.6 steps -> 524).
        report = arm.move_to([None, 30])
        np.testing.assert_array_equal(report["final_positions"][:2], [0, 524])

        # One joint's description changed: its name and zero; the rest kept.
        arm.set_joint_description(1, name="knee", zero_offset=100)
        assert arm.joint_description(1) == {
            "name": "knee", "unit": "deg", "zero_offset": 100, "scale": 1000.0,
            "described": True}
        # (524 - 100) / 1000 rad = 24.29 deg.
        assert abs(arm.positions()[1] - 24.29) < 0.01
        with pytest.raises(armctl.TrajectoryError, match=r"knee: target"):
            arm.move_to([None, 80])
        with pytest.raises(ValueError, match='unit "furlong"'):
            arm.set_joint_description(1, unit="furlong")
        with pytest.raises(ValueError, match="over 16 bytes"):
            arm.set_joint_description(1, name="a" * 17)
        with pytest.raises(ValueError, match="cannot parse"):
            bad = tmp_path / "bad.json"
            bad.write_text("{")
            arm.push_config(str(bad))

    # The CLI reads what Python kept, and its own push of the file says what Python's said.
    cli = str(armctl_cli())
    got = subprocess.run([cli, "--controller", sim.address, "config", "get"],
                         capture_output=True, text=True, timeout=60)
    assert got.returncode == 0, got.stdout + got.stderr
    assert "joint 1 knee: deg, 1000 steps per radian, zero at 100 steps" in got.stdout, got.stdout
    pushed = subprocess.run([cli, "--controller", sim.address, "config", "push", str(config)],
                            capture_output=True, text=True, timeout=60)
    assert pushed.returncode == 0, pushed.stdout + pushed.stderr
    assert pushed.stdout.splitlines()[:-1] == lines

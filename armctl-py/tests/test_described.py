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

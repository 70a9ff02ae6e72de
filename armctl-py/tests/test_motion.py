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
        # Issue 31: named as the config names the joint, in the user's units.
        with pytest.raises(armctl.TrajectoryError, match=r"elbow: target 50\.02 deg \(873 steps\) "
                           r"is outside its range -44\.98 deg to 44\.98 deg"):
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


def deg_config(tmp_path, units="deg"):
    """6 joints at 1000 steps/rad; the elbow (joint 1) within +-785 steps (+-44.98 deg)."""
    config = tmp_path / f"arm-{units}.json"
    joints = [{"name": f"j{j}", "steps_per_radian": 1000, "max_step_rate_hz": 4000} for j in range(6)]
    joints[1].update(name="elbow", min_steps=-785, max_steps=785)
    body = {"joints": joints} if units is None else {"units": units, "joints": joints}
    config.write_text(json.dumps(body))
    return config


def test_run_takes_the_configs_units(sim, tmp_path):
    """Issue 31: with "units": "deg" in the config, run() read 10 as 10 radians (a step
    rate error, or 10,000 steps); `units=` overrides; a config without units keeps
    radians; the run's limit messages name the joint and speak the user's units."""
    config = deg_config(tmp_path)
    with armctl.connect(sim.address) as arm:
        times = np.array([0.5, 1.5])
        report = arm.run(times, np.array([[10.0, -20.0], [30.0, 10.0]]), config=config)
        # 30 deg = 523.6 steps, 10 deg = 174.5 steps.
        np.testing.assert_array_equal(report["final_positions"][:2], [524, 175])
        report = arm.run(times, np.array([[0.1, 0.0], [0.2, -0.1]]), config=config, units="rad")
        np.testing.assert_array_equal(report["final_positions"][:2], [200, -100])
        report = arm.run(times, np.array([[0.0, 0.0], [300.0, 100.0]]), config=config, units="steps")
        np.testing.assert_array_equal(report["final_positions"][:2], [300, 100])
        report = arm.run(times, np.array([[0.0, 0.0], [0.1, 0.05]]), config=deg_config(tmp_path, None))
        np.testing.assert_array_equal(report["final_positions"][:2], [100, 50])
        with pytest.raises(armctl.TrajectoryError,
                           match=r"joint 1 \(elbow\): position 873 steps is above the maximum 785 steps "
                                 r"\(50\.02 deg against a limit of 44\.98 deg\)"):
            arm.run(times, np.array([[0.0, 0.0], [0.0, 50.0]]), config=config)
        with pytest.raises(ValueError, match="need a joint config"):
            arm.run(times, np.array([[0.0], [10.0]]), units="deg")
        # Shown in the config's units, as `armctl watch --config` and `home --config`.
        arm.move_to([30, 10], config=config)
        np.testing.assert_allclose(arm.positions(config=config)[:2], [30.02, 10.03], atol=0.01)
        np.testing.assert_allclose(arm.positions(config=config, units="rad")[:2], [0.524, 0.175])
        np.testing.assert_array_equal(arm.positions(config=config, units="steps")[:2], [524, 175])
        with pytest.raises(ValueError, match="need a joint config"):
            arm.positions(units="deg")
        home = arm.home(config=config)
        assert home.dtype == np.float64
        np.testing.assert_array_equal(home, np.zeros(6))


def test_home_on_switches_with_the_simulators_switch_model():
    """Issue 33: home() homes on the switch once set_homing() set a joint (the count at
    the switch is the offset), RETURN before; switches() says homed; a failed cycle
    raises naming the joint."""
    from conftest import SimHost

    host = SimHost("--joints", "2", "--position", "0:600", "--home-switch", "0:0")
    try:
        with armctl.connect(host.address) as arm:
            np.testing.assert_array_equal(arm.home(), [0, 0])  # RETURN: nothing to move
            assert arm.switches()["phase"] == "never"
            arm.set_homing(0, max_travel_steps=2000, offset=10, seek_rate_hz=4000)
            at = arm.home()
            assert 10 <= at[0] <= 40, at  # the approach stops a few steps past the switch
            report = arm.switches()
            assert report["phase"] == "homed" and report["homed"] == 1, report
            arm.jog(0, 1500)
            arm.set_homing(0, max_travel_steps=100)
            with pytest.raises(armctl.ArmctlError, match="homing failed on joint 0: the seek travelled its maximum"):
                arm.home()
    finally:
        host.close()

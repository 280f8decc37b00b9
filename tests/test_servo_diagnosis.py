"""A robot driven by position servos (as most MuJoCo Menagerie arms are) through the diagnosis, and a robot named
by path on the command line: the replay drives the joints by the torque the servos applied, a calibrated file's
torque is the servos' force (no sensor mapping), and `system.mjcf=<path>` takes `conf/system/auto.yaml`."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from dynamics.actuators import as_motors
from dynamics.plant import plant_from_xml
from dynamics.torque import inverse_dynamics
from envs.sensors import SensorModel
from envs.simulate import simulate_tracking
from excitation.designs import default_design
from excitation.limits import limits_for
from harness.setup import with_auto_system
from identify.derivatives import derive_states
from identify.diagnose import diagnose
from identify.diagnose.calibrate import mjcf_measured_torque
from identify.diagnose.select import _solve_gram
from identify.diagnose.simulation_error import mujoco_stepper, simulation_error
from tests.conftest import compose_config

REPO = Path(__file__).resolve().parents[1]


def _servo_two_link(directory: Path):  # type: ignore[no-untyped-def]
    """The built-in two-link arm with its motors replaced by position servos (kp 60, kv 4)."""
    spec = mujoco.MjSpec.from_file(str(REPO / "mjcf" / "two_link.xml"))
    for act in list(spec.actuators):
        spec.delete(act)
    for name in ("shoulder", "elbow"):
        act = spec.add_actuator()
        act.name, act.target = name, name
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.set_to_position(kp=60.0, kv=4.0)
        act.forcelimited, act.forcerange = True, [-12.0, 12.0]
    return plant_from_xml(spec.to_xml(), "servo_two_link", directory)


def _servo_data(tmp_path: Path):  # type: ignore[no-untyped-def]
    plant = _servo_two_link(tmp_path)
    assert plant.actuation.servo
    limits = limits_for(plant, velocity=4.0, acceleration=30.0, range_margin=0.05, torque_margin=0.9)
    design = default_design(plant, limits, harmonics=4, base_freq_hz=0.2, torque_driven=False)
    sensor = SensorModel(500.0, sigma_q=1.7e-5, q_resolution=2.4e-5, sigma_tau=np.array([0.02, 0.02]))
    rng = np.random.default_rng(3)
    train = simulate_tracking(plant, design, duration_s=10.0, sensor=sensor, rng=rng, nominal=plant)
    val = simulate_tracking(plant, design, duration_s=5.0, sensor=sensor, rng=rng, nominal=plant)
    return plant, train, val


def test_a_replay_drives_servos_by_the_torque_they_applied(tmp_path: Path) -> None:
    """Replayed with its own applied torque, a servo arm's own model follows its motion (a servo driven with
    the torque as its set point, as before, ran off by radians)."""
    plant, data, _ = _servo_data(tmp_path)
    states = derive_states(data, "butterworth", cutoff_hz=10.0)
    rows = states.valid
    err = simulation_error(
        mujoco_stepper(plant.mj_model), data.time[rows], states.q[rows], states.dq[rows], data.tau[rows], window_s=0.25
    )
    assert np.all(err.rms < 0.01), err.rms
    motors = as_motors(plant.mj_model, "test")
    assert np.all(motors.actuator_biasprm[:, :3] == 0) and np.all(motors.actuator_gainprm[:, 0] == 1)
    assert np.all(plant.mj_model.actuator_biasprm[:, 1] == -60.0)  # the model itself is not changed


def test_a_capped_simulation_error_simulates_windows_spread_over_the_whole_record(tmp_path: Path) -> None:
    """`max_windows` keeps the cost of a long log's simulation error bounded: that many of the full run's windows,
    spread evenly from the first to the last, and an RMS near the full one."""
    plant, data, _ = _servo_data(tmp_path)
    states = derive_states(data, "butterworth", cutoff_hz=10.0)
    rows = states.valid
    args = (mujoco_stepper(plant.mj_model), data.time[rows], states.q[rows], states.dq[rows], data.tau[rows])
    full = simulation_error(*args, window_s=0.25)
    capped = simulation_error(*args, window_s=0.25, max_windows=12)
    assert full.windows == full.of == capped.of > 12 and capped.windows == 12  # the whole budget, no more
    kept = np.isin(full.time, capped.time)
    np.testing.assert_array_equal(full.q_simulated[kept], capped.q_simulated)  # the same windows as the full run's
    assert capped.time[0] == full.time[0] and capped.time[-1] == full.time[-1]  # spread to both ends
    np.testing.assert_allclose(capped.rms, full.rms, rtol=0.5)
    with pytest.raises(ValueError, match="max_windows must be >= 1"):
        simulation_error(*args, window_s=0.25, max_windows=0)


def test_clean_servo_data_have_a_small_simulation_error_and_no_discrepancy(tmp_path: Path) -> None:
    plant, train, val = _servo_data(tmp_path)
    dg = diagnose(plant, [train], [val], rng=np.random.default_rng(0), derivative_options={"cutoff_hz": 10.0})
    assert dg.verdict == "no_discrepancy", (dg.verdict, [f.name for f in dg.findings])
    # envs.simulate reports the continuous robot's torque: not read as a log of MuJoCo's steps (h kv = 0.002 here)
    reading = dg.info["mujoco_steps"]
    assert not reading["read"] and abs(reading["scale"]) < 0.25, reading
    sim = dg.models["nominal"]["simulation_error"]
    assert max(sim.values()) < 0.02, sim


def test_a_servo_model_reports_the_force_it_applies(tmp_path: Path) -> None:
    """No sensor mapping is inverted for a servo (dividing by its kp, as before, gave torque / 60)."""
    plant = _servo_two_link(tmp_path)
    rng = np.random.default_rng(0)
    q, dq, ddq = (rng.uniform(-1, 1, (50, 2)) for _ in range(3))
    expected = inverse_dynamics(plant.mj_model, q, dq, ddq)
    got = mjcf_measured_torque(plant.mj_model, np.arange(50) * 0.002, q, dq, ddq)
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12)


def test_a_robot_named_by_path_takes_the_auto_system_config() -> None:
    path = str(REPO / "mjcf" / "two_link.xml")
    assert with_auto_system([f"system.mjcf={path}", "record=none"]) == [
        "system=auto",
        f"system.mjcf={path}",
        "record=none",
    ]
    for unchanged in (
        ["system.mjcf=two_link"],
        ["system.mjcf=two_link,pendulum"],
        ["system=arm3", f"system.mjcf={path}"],
    ):
        assert with_auto_system(unchanged) == unchanged
    assert with_auto_system(["record=none"]) == ["record=none"]
    # every key of auto.yaml can be overridden on the same line (the two-link config has no clearance key)
    cfg = compose_config(with_auto_system([f"system.mjcf={path}", "system.limits.clearance_m=0.05"]))
    assert cfg.system.limits.clearance_m == 0.05 and cfg.system.effects is None
    cfg = compose_config(with_auto_system([f"system.mjcf={path}"]), "diagnose")
    assert cfg.system.effects is None  # filled from the model by the diagnosis (`with_model_defaults`)


def test_a_fold_with_no_column_touched_has_zero_coefficients() -> None:
    """A fold whose training rows touch none of the columns (a weakly excited record) fits nothing, instead
    of failing on an empty eigenvalue list."""
    none = _solve_gram(np.zeros((0, 0)), np.zeros(0), np.zeros(0), np.zeros(0))  # no column seen at all
    assert none.shape == (0,)
    x = _solve_gram(np.zeros((3, 3)), np.zeros(3), np.full(3, -np.inf), np.full(3, np.inf))
    np.testing.assert_array_equal(x, np.zeros(3))
    x = _solve_gram(np.zeros((2, 2)), np.zeros(2), np.array([0.1, -np.inf]), np.full(2, np.inf))
    np.testing.assert_array_equal(x, [0.1, 0.0])


def _geared_two_link(directory: Path):  # type: ignore[no-untyped-def]
    """The built-in two-link arm with a gear-2 shoulder motor (ctrl is half the joint torque there)."""
    text = (REPO / "mjcf" / "two_link.xml").read_text()
    text = text.replace(
        '<motor name="shoulder" joint="shoulder" gear="1"', '<motor name="shoulder" joint="shoulder" gear="2"'
    )
    return plant_from_xml(text, "geared_two_link", directory)


def _general_two_link(directory: Path):  # type: ignore[no-untyped-def]
    """The built-in two-link arm whose shoulder is a `general` actuator of gear 2, gain 3 and a constant force."""
    text = (REPO / "mjcf" / "two_link.xml").read_text()
    text = text.replace(
        '<motor name="shoulder" joint="shoulder" gear="1" ctrllimited="true" ctrlrange="-12 12"/>',
        '<general name="shoulder" joint="shoulder" gear="2" gainprm="3" biastype="affine" biasprm="0.5 0 0" '
        'ctrllimited="true" ctrlrange="-4 4"/>',
    )
    assert "general" in text
    return plant_from_xml(text, "general_two_link", directory)


def test_a_calibrated_files_torque_is_the_diagnosis_own_prediction_for_gears_and_servos(tmp_path: Path) -> None:
    """`mjcf_measured_torque` (the file alone, as the bench and a user judge it) says what the diagnosis predicts
    (`predict_measured_torque`, from its own objects): the joint torque whatever the motor's gear (it returned the
    ctrl, half the torque, on a gear-2 motor), and with a sensor gain and offset on a servo too (they were left out
    of the file while the reported figures carried them)."""
    from identify.diagnose.calibrate import Extension, calibrated_xml, predict_measured_torque

    rng = np.random.default_rng(0)
    q, dq, ddq = (rng.uniform(-1, 1, (60, 2)) for _ in range(3))
    time = np.arange(60) * 0.002
    for plant in (_geared_two_link(tmp_path), _servo_two_link(tmp_path), _general_two_link(tmp_path)):
        np.testing.assert_allclose(
            mjcf_measured_torque(plant.mj_model, time, q, dq, ddq),
            inverse_dynamics(plant.mj_model, q, dq, ddq),
            atol=1e-9,
        )
        ext = Extension.none(plant)
        ext.torque_gain[:] = [1.08, 0.93]
        ext.torque_offset[:] = [0.05, -0.03]
        text = calibrated_xml(plant, ext)
        assert "sysid_torque_sensor_shoulder" in text and "sysid_torque_sensor_elbow" in text
        calibrated = plant_from_xml(text, f"{plant.name}_calibrated", tmp_path)
        want = predict_measured_torque(calibrated, ext, time, q, dq, ddq)
        got = mjcf_measured_torque(mujoco.MjModel.from_xml_string(text), time, q, dq, ddq)
        np.testing.assert_allclose(got, want, atol=1e-9)
        true = inverse_dynamics(plant.mj_model, q, dq, ddq)
        np.testing.assert_allclose(got, true * [1.08, 0.93] + [0.05, -0.03], atol=1e-9)


def test_the_replay_applies_the_joint_torque_whatever_the_actuator_and_the_sensor(tmp_path: Path) -> None:
    """`mujoco_stepper` (the diagnosis's re-started simulation) drove ctrl = tau / gear, so an actuator of gain 3
    applied three times the logged torque. On the arm with a gear-2, gain-3 shoulder with a constant force, and on
    its calibrated file with a sensor gain and offset, it now moves as the plain-motor arm does under the torque
    applied (the logged one less the offset, over the gain)."""
    from identify.diagnose.calibrate import Extension, calibrated_xml

    plain = mujoco.MjModel.from_xml_path(str(REPO / "mjcf" / "two_link.xml"))
    general = _general_two_link(tmp_path)
    ext = Extension.none(general)
    ext.torque_gain[:] = [1.1, 0.95]
    ext.torque_offset[:] = [0.2, -0.1]
    calibrated = mujoco.MjModel.from_xml_string(calibrated_xml(general, ext))
    rng = np.random.default_rng(0)
    q0, dq0 = rng.uniform(-1, 1, (3, 2)), rng.uniform(-1, 1, (3, 2))
    tau = rng.uniform(-1, 1, (3, 40, 2))
    applied = (tau - [0.2, -0.1]) / [1.1, 0.95]
    want = mujoco_stepper(plain)[0](q0, dq0, applied, 0.0)
    np.testing.assert_allclose(mujoco_stepper(general.mj_model)[0](q0, dq0, applied, 0.0), want, atol=1e-12)
    np.testing.assert_allclose(mujoco_stepper(calibrated)[0](q0, dq0, tau, 0.0), want, atol=1e-9)

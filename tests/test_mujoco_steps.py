"""A log of MuJoCo's own simulation, written as MuJoCo users write one (at each `mj_step`, the positions before it
and the actuator force of it): the inertia its integrator adds (`dynamics.stepping`) against MuJoCo step by step,
and the diagnosis of such logs (`diagnose(mujoco_steps=...)`), which before read a servo arm's log as armature on
every joint (0.9 kg m^2 on a Menagerie Panda's base joints)."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from dynamics.plant import load_plant, plant_from_xml, with_applied_friction
from dynamics.stepping import as_stepped, step_inertia
from dynamics.torque import joint_torque
from identify.derivatives import reduce_record
from identify.diagnose import diagnose
from identify.diagnose.diagnosis import _one_step_delay_notes
from identify.diagnose.testbed import ARMS, Injected, servo_log
from tests.conftest import SHARED_ROBOTS
from tests.test_servo_diagnosis import _servo_two_link

REPO = Path(__file__).resolve().parents[1]

_SWING = """<mujoco model="swing">
  <option timestep="0.002" integrator="{integrator}">{flag}</option>
  <worldbody>
    <body name="arm">
      <joint name="hinge" type="hinge" axis="0 1 0" damping="0.3" armature="0.01"{friction}/>
      <inertial pos="0 0 -0.3" mass="1.2" diaginertia="0.01 0.01 0.002"/>
    </body>
  </worldbody>
  <actuator>
    <position name="servo" joint="hinge" kp="40" kv="2"/>
  </actuator>
</mujoco>
"""


def _logged(plant, *, amplitude: float, hz: float, steps: int):  # type: ignore[no-untyped-def]
    """One joint's servo given a sine target, stepped by MuJoCo: the positions and velocities before each step,
    the step's mean velocity and acceleration, and the actuator force it applied (`qfrc_actuator`)."""
    m, h = plant.mj_model, plant.mj_model.opt.timestep
    d = mujoco.MjData(m)
    q, v, a, tau = (np.zeros((steps, 1)) for _ in range(4))
    for k in range(steps):
        d.ctrl[0] = amplitude * np.sin(2 * np.pi * hz * d.time)
        q[k], v[k] = d.qpos, d.qvel
        mujoco.mj_step(m, d)
        tau[k], a[k] = d.qfrc_actuator, (d.qvel - v[k]) / h
    return q, v + 0.5 * h * a, a, tau


@pytest.mark.parametrize(
    ("integrator", "flag", "expected"),
    [
        ("implicitfast", "", 0.002 * (2.0 + 0.15)),  # h (kv + D / 2): both taken at the step's end
        ("implicit", "", 0.002 * (2.0 + 0.15)),
        ("Euler", "", 0.002 * 0.15),  # the joint damping only
        ("Euler", '<flag eulerdamp="disable"/>', -0.002 * 0.15),  # nothing implicit: - h D / 2
        ("RK4", "", 0.0),
    ],
)
def test_the_step_inertia_is_what_mujoco_s_step_puts_into_its_log(
    tmp_path: Path, integrator: str, flag: str, expected: float
) -> None:
    """On one joint (no Coriolis torque) the logged actuator force of every semi-implicit step is the model's
    torque at the step's mean velocity plus the step inertia times the step's acceleration, to rounding."""
    plant = plant_from_xml(_SWING.format(integrator=integrator, flag=flag, friction=""), integrator, tmp_path)
    assert step_inertia(plant)[0] == pytest.approx(expected, abs=1e-15)
    if integrator == "RK4":
        return
    q, mean_v, a, tau = _logged(plant, amplitude=0.8, hz=1.3, steps=400)
    stepped = joint_torque(as_stepped(plant), q, mean_v, a)[0]
    plain = joint_torque(plant, q, mean_v, a)[0]
    np.testing.assert_allclose(stepped, tau, rtol=0, atol=1e-9 * np.abs(tau).max())
    assert np.abs(plain - tau).max() > 1e3 * np.abs(stepped - tau).max()  # without it: h kv a off


@pytest.mark.parametrize(("integrator", "tolerance"), [("implicitfast", 1e-9), ("Euler", 1e-9), ("implicit", 5e-5)])
def test_the_step_on_two_links_is_what_mujoco_logs(tmp_path: Path, integrator: str, tolerance: float) -> None:
    """With a Coriolis torque: MuJoCo takes it at the step's start (Euler, implicitfast) or, linearised, at its
    end (implicit, to second order in the step's change of velocity); with its servos' kv and the damping
    taken implicitly, the logged force of every step matches the stepped model's torque at the step's mean
    velocity. Without the Coriolis term the two-link log is off by far more."""
    spec = mujoco.MjSpec.from_file(str(_servo_arm(tmp_path)))
    spec.option.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{integrator.upper()}")
    for joint in spec.joints:
        joint.damping = [0.05, 0.0, 0.0]
    plant = plant_from_xml(spec.to_xml(), f"two_{integrator}", tmp_path / "m")
    m, h = plant.mj_model, plant.mj_model.opt.timestep
    d = mujoco.MjData(m)
    n = 500
    q, v, a, tau = (np.zeros((n, 2)) for _ in range(4))
    for k in range(n):
        d.ctrl[:] = [0.4 * np.sin(2 * np.pi * 0.9 * d.time), 0.5 * np.sin(2 * np.pi * 1.3 * d.time)]
        q[k], v[k] = d.qpos, d.qvel
        mujoco.mj_step(m, d)
        tau[k], a[k] = d.qfrc_actuator, (d.qvel - v[k]) / h
    mean_v = v + 0.5 * h * a
    stepped = as_stepped(plant)
    error = np.abs(joint_torque(stepped, q, mean_v, a)[0] - tau).max()
    assert error < tolerance * np.abs(tau).max(), error
    no_coriolis = joint_torque(plant, q, mean_v, a)[0] + stepped.stepping.inertia * a  # type: ignore[union-attr]
    assert np.abs(no_coriolis - tau).max() > 20 * error


def _servo_arm(tmp_path: Path) -> Path:
    """The built-in two-link arm through position servos (kp 60, kv 4; `_servo_two_link`), stepped at 2 ms."""
    spec = mujoco.MjSpec.from_file(str(_servo_two_link(tmp_path).path))
    spec.option.timestep = 0.002
    path = tmp_path / "servo_two_link_2ms.xml"
    path.write_text(spec.to_xml())
    return path


def _diagnosed(path: Path, seed: int, mujoco_steps: bool | None = None, effects=(), positions="before"):  # type: ignore[no-untyped-def]
    rngs = np.random.default_rng(seed).spawn(2)
    kw = {"center": (0.0, 0.0), "amplitude": (0.8, 1.0), "sigma_tau": 0.01, "effects": effects, "positions": positions}
    plant, train = servo_log(path, rng=rngs[0], duration_s=10.0, rate_hz=500.0, **kw)  # type: ignore[arg-type]
    _, val = servo_log(path, rng=rngs[1], duration_s=5.0, rate_hz=500.0, source="servo_log_val", **kw)  # type: ignore[arg-type]
    return diagnose(
        plant,
        [train],
        [val],
        rng=np.random.default_rng(0),
        derivative_options={"cutoff_hz": 10.0},
        mujoco_steps=mujoco_steps,
    )


@pytest.mark.parametrize("seed", [0, 1])
def test_a_servo_arm_s_own_mujoco_log_is_clean(tmp_path: Path, seed: int) -> None:
    """Clean, read as MuJoCo's steps (their inertia h kv = 0.008 kg m^2 is 3.7 times the rotor's): no discrepancy.
    Read as a robot's (as every log was before), the same log names effects that are not there (armature or the
    rigid body and a rotor coupling in their place)."""
    path = _servo_arm(tmp_path)
    dg = _diagnosed(path, seed)
    reading = dg.info["mujoco_steps"]
    assert reading["read"] and reading["asked"] is None and not reading["positions_after_step"]
    assert abs(reading["scale"] - 1.0) < 0.01 and reading["share"] > 0.95, reading
    assert abs(reading["torque_lag_s"]) < 3 * reading["torque_lag_std_s"] + 1e-4, reading
    assert dg.verdict == "no_discrepancy", (dg.verdict, [f.name for f in dg.findings])
    assert any("read as a log of MuJoCo's own simulation" in n for n in dg.notes)
    # read from the data, it says what else would read the same
    assert any("an armature change of that size on every joint would fit" in n for n in dg.notes)
    as_robot = _diagnosed(path, seed, mujoco_steps=False)
    assert not as_robot.info["mujoco_steps"]["read"]
    assert as_robot.findings and as_robot.verdict != "no_discrepancy", as_robot.verdict


@pytest.mark.parametrize("seed", [0, 1])
def test_a_log_with_the_positions_after_each_step_is_read_a_step_earlier(tmp_path: Path, seed: int) -> None:
    """A loop that logs `d.time`, `d.qpos` and `d.qfrc_actuator` once `mj_step` returns pairs each force with the
    positions one step later: its torque is a step (2 ms) behind its row. Before, that was named as a time delay
    of 2 ms on every joint (the Panda's, `explained`); now each row's torque is read at the step before it."""
    dg = _diagnosed(_servo_arm(tmp_path), seed, positions="after")
    reading = dg.info["mujoco_steps"]
    assert reading["read"] and reading["positions_after_step"], reading
    assert abs(reading["torque_lag_s"] - 0.002) < 0.0005, reading
    assert dg.verdict == "no_discrepancy", (dg.verdict, [f.name for f in dg.findings])
    assert any("logged after each step" in n for n in dg.notes)


def test_a_thinned_log_with_the_positions_after_each_step_is_read_a_step_earlier_too(tmp_path: Path) -> None:
    """A long log the harness thins (`max_rows`) has its states given, which ignore `tau_lead_s`: before, the
    reading said the torque was read a step earlier while nothing moved (`unexplained_structure`, the residual
    twice the full-rate one); the given states are read a step earlier instead."""
    path = _servo_arm(tmp_path)
    rngs = np.random.default_rng(0).spawn(2)
    kw = {"center": (0.0, 0.0), "amplitude": (0.8, 1.0), "sigma_tau": 0.01, "positions": "after", "rate_hz": 500.0}
    plant, train = servo_log(path, rng=rngs[0], duration_s=10.0, **kw)  # type: ignore[arg-type]
    _, val = servo_log(path, rng=rngs[1], duration_s=5.0, source="servo_log_val", **kw)  # type: ignore[arg-type]
    thin = [reduce_record(d, "butterworth", 2, cutoff_hz=10.0) for d in (train, val)]
    dg = diagnose(plant, thin[:1], thin[1:], rng=np.random.default_rng(0), derivatives="given")
    assert dg.info["mujoco_steps"]["positions_after_step"], dg.info["mujoco_steps"]
    assert dg.verdict == "no_discrepancy", (dg.verdict, dg.verdict_reason)
    assert max(dg.models["nominal"]["torque_rms"].values()) < 0.003, dg.models["nominal"]["torque_rms"]


def test_the_one_step_delay_note_needs_a_delay_determined_at_the_step(tmp_path: Path) -> None:
    """Said of a delay at the step to a quarter of it; not of 6 +- 2 ms on a 2 ms step, nor of 1 +- 0.2 ms on the
    built-in two-link arm's 0.5 ms step (the model of the DFKI logs: a real delay of that size is no MuJoCo log)."""
    from types import SimpleNamespace

    def delay(value: float, std: float) -> SimpleNamespace:
        return SimpleNamespace(effect="time_delay", target="elbow", value=value, std=std)

    servo = load_plant(_servo_arm(tmp_path))
    assert _one_step_delay_notes(servo, [delay(0.00193, 0.00016)], None)  # type: ignore[list-item]
    assert not _one_step_delay_notes(servo, [delay(0.006, 0.002)], None)  # type: ignore[list-item]
    assert not _one_step_delay_notes(load_plant("two_link"), [delay(0.001, 0.0002)], None)  # type: ignore[list-item]


def test_a_log_of_a_model_whose_step_adds_no_inertia_is_read_so_when_asked(tmp_path: Path) -> None:
    """Under Euler without joint damping the step adds no inertia (MuJoCo's default integrator takes nothing of a
    servo implicitly): nothing tells such a log from a robot's, so it is read as a robot's, and a log with the
    positions after each step names a delay of one step; the note says what it may be, and mujoco_steps=true
    reads each row's torque at the step before it (`no_discrepancy`)."""
    spec = mujoco.MjSpec.from_file(str(_servo_arm(tmp_path)))
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    path = tmp_path / "euler.xml"
    path.write_text(spec.to_xml())
    assert not np.any(step_inertia(load_plant(path)))
    as_robot = _diagnosed(path, 0, positions="after")
    assert as_robot.info["mujoco_steps"] is None
    assert {f.effect for f in as_robot.findings} == {"time_delay"}, [f.name for f in as_robot.findings]
    assert any("time delays named at the model's physics step (2 ms" in n for n in as_robot.notes), as_robot.notes
    asked = _diagnosed(path, 0, mujoco_steps=True, positions="after")
    assert asked.info["mujoco_steps"]["positions_after_step"], asked.info["mujoco_steps"]
    assert asked.verdict == "no_discrepancy", (asked.verdict, [f.name for f in asked.findings])


def test_an_effect_hidden_in_such_a_log_is_named_at_its_size(tmp_path: Path) -> None:
    dg = _diagnosed(_servo_arm(tmp_path), 0, effects=[Injected("viscous_friction", "elbow", 0.05)])
    assert dg.info["mujoco_steps"]["read"]
    first = dg.findings[0]
    assert first.name == "viscous_friction elbow", [f.name for f in dg.findings]
    assert abs(first.value - 0.05) < 3 * first.std, (first.value, first.std)


def test_a_calibrated_model_of_such_a_log_does_not_carry_the_step_inertia(tmp_path: Path) -> None:
    """MuJoCo adds it again when it steps the calibrated file: written into the armature it would count twice."""
    path = _servo_arm(tmp_path)
    dg = _diagnosed(path, 0, mujoco_steps=True)
    calibrated = plant_from_xml(dg.calibrated_xml, "calibrated", tmp_path / "out")
    np.testing.assert_allclose(calibrated.armature, load_plant(path).armature, rtol=1e-6)


def test_a_friction_ramp_in_such_a_log_sees_the_solver_s_acceleration(tmp_path: Path) -> None:
    """MuJoCo's solver makes a frictionloss from the step's start velocity and its own acceleration M^-1 (f +
    lambda), which the integrator then applies with M + h kv: the ramp MuJoCo applies, read at the step's start
    and with h M^-1 kv times the acceleration beside it, gives the logged force to the solver's tolerance; read
    at the sample's states alone it is off by a sizeable share of the friction."""
    xml = _SWING.format(integrator="implicitfast", flag="", friction=' frictionloss="0.2"')
    plant = with_applied_friction(plant_from_xml(xml, "swing_friction", tmp_path))
    assert plant.friction_speed[0] > 0 and plant.friction_lead[0] > 0  # MuJoCo's own ramp, as the diagnosis reads it
    q, mean_v, a, tau = _logged(plant, amplitude=0.3, hz=0.7, steps=600)
    error = joint_torque(as_stepped(plant), q, mean_v, a)[0] - tau
    plain = joint_torque(plant, q, mean_v, a)[0] + step_inertia(plant) * a - tau
    assert np.abs(error).max() < 1e-6, np.abs(error).max()
    assert np.abs(plain).max() > 0.02, np.abs(plain).max()  # the friction's share without the step's velocity


def test_the_stepped_torque_s_acceleration_derivative_matches_finite_differences(tmp_path: Path) -> None:
    """On a two-link servo arm with a frictionloss ramp on each joint, where the ramps are active: the step's
    velocity couples each ramp to both joints' accelerations through M^-1."""
    spec = mujoco.MjSpec.from_file(str(_servo_arm(tmp_path)))
    for joint in spec.joints:
        joint.frictionloss = 0.3
    plant = as_stepped(with_applied_friction(plant_from_xml(spec.to_xml(), "servo_friction", tmp_path / "f")))
    rng = np.random.default_rng(0)
    n = 40
    q = rng.uniform(-1.0, 1.0, (n, 2))
    ddq = rng.uniform(-0.2, 0.2, (n, 2))
    dq = rng.uniform(-0.3, 0.3, (n, 2)) * plant.friction_speed  # on the ramps, near zero speed
    _, D = joint_torque(plant, q, dq, ddq, derivatives=True)
    assert D is not None
    eps = 1e-7
    for j in range(2):
        step = np.zeros(2)
        step[j] = eps
        fd = (joint_torque(plant, q, dq, ddq + step)[0] - joint_torque(plant, q, dq, ddq - step)[0]) / (2 * eps)
        np.testing.assert_allclose(D[2][:, :, j], fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max())
        # in the speed, off the ramps' corners (a step of 1e-7 rad/s crosses none of them at these states)
        fd = (joint_torque(plant, q, dq + step, ddq)[0] - joint_torque(plant, q, dq - step, ddq)[0]) / (2 * eps)
        np.testing.assert_allclose(D[1][:, :, j], fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max())
        fd = (joint_torque(plant, q + step, dq, ddq)[0] - joint_torque(plant, q - step, dq, ddq)[0]) / (2 * eps)
        np.testing.assert_allclose(D[0][:, :, j], fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max())
    off_diagonal = np.abs(D[2][:, 0, 1] - joint_torque(plant, q, dq, ddq, derivatives=True)[1][2][:, 1, 0])
    assert off_diagonal.max() > 1e-3  # not symmetric: the ramp of one joint follows the other's acceleration


@pytest.mark.skipif(
    not (SHARED_ROBOTS / "xarm7_nohand.xml").is_file(), reason="../shared/robots/ is not beside the project"
)
def test_the_xarm7_s_own_mujoco_log_is_clean() -> None:
    """The Menagerie xArm7 as it comes (position servos, frictionloss 1 N m on every joint, implicitfast at 2 ms):
    its friction ramps see a thousand times the last joint's acceleration in MuJoCo's step. Before, its clean log
    was `unexplained_structure` with armature 0.5 kg m^2 named on joints 5 to 7."""
    arm = ARMS["xarm7_nohand"]
    kw = {"center": arm.center, "amplitude": arm.amplitude, "sigma_tau": arm.sigma_tau, "rate_hz": 500.0}
    rngs = np.random.default_rng(0).spawn(2)
    path = SHARED_ROBOTS / "xarm7_nohand.xml"
    plant, train = servo_log(path, rng=rngs[0], duration_s=10.0, **kw)  # type: ignore[arg-type]
    _, val = servo_log(path, rng=rngs[1], duration_s=5.0, source="servo_log_val", **kw)  # type: ignore[arg-type]
    dg = diagnose(plant, [train], [val], rng=np.random.default_rng(0), derivative_options={"cutoff_hz": 10.0})
    assert dg.info["mujoco_steps"]["read"], dg.info["mujoco_steps"]
    assert dg.verdict == "no_discrepancy", (dg.verdict, [f.name for f in dg.findings])


@pytest.mark.parametrize(
    ("model", "extra", "message"),
    [
        ("servo", {"effects": [Injected("cogging", "elbow", 0.1, 6.0)]}, r"cannot hide 'cogging'; valid choices: vis"),
        ("servo", {"positions": "during"}, r"servo_log positions 'during'; valid choices: after, before"),
        ("motors", {}, r"two_link.xml: servo_log needs one position servo of gear 1 on every joint"),
    ],
)
def test_the_log_generator_refuses_what_it_cannot_do(tmp_path: Path, model: str, extra: dict, message: str) -> None:  # type: ignore[type-arg]
    path = _servo_arm(tmp_path) if model == "servo" else REPO / "mjcf" / "two_link.xml"
    kw = {"center": (0, 0), "amplitude": (1, 1), "duration_s": 1.0, "sigma_tau": 0.01, **extra}
    with pytest.raises(ValueError, match=message):
        servo_log(path, rng=np.random.default_rng(0), **kw)  # type: ignore[arg-type]

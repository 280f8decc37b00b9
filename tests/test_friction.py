"""MuJoCo's frictionloss as a declared ramp (`dynamics.friction`): what is written is what MuJoCo applies."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from dynamics.friction import (
    applied_friction_parameters,
    friction_parameters,
    friction_shape,
    friction_solver,
    ideal_friction_speed,
    min_friction_speed,
    ramp_solver,
)
from dynamics.plant import load_plant, with_applied_friction
from dynamics.regressor import ParameterModel
from dynamics.torque import inverse_dynamics, joint_torque
from identify.diagnose.calibrate import Extension, calibrated_xml, mjcf_measured_torque

ROBOTS = Path(__file__).resolve().parents[2] / "shared" / "robots"


def _ramp_xml(path: Path, frictionloss: np.ndarray, speed: np.ndarray) -> str:
    """MJCF text of the model at `path` with each dof's friction the ramp of width `speed` (`friction_solver`)."""
    spec = mujoco.MjSpec.from_file(str(path))
    m = spec.compile()
    for j in range(m.njnt):
        joint = spec.joint(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j))
        joint.frictionloss = float(frictionloss[j])
        joint.solref_friction, joint.solimp_friction, _ = friction_solver(
            float(frictionloss[j]), float(speed[j]), float(m.dof_invweight0[j]), float(m.opt.timestep)
        )
    return spec.to_xml()  # type: ignore[no-any-return]


def _with_ramps(path: Path, frictionloss: np.ndarray, speed: np.ndarray) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(_ramp_xml(path, frictionloss, speed))


def _unbounded_ramp(m: mujoco.MjModel, speed: np.ndarray) -> None:
    """Set (in place) ramps of width `speed` with the damping B = 1e5 / vt a wide ramp gets, whatever the step."""
    for j in range(m.nv):
        a = float(m.dof_invweight0[j] * m.dof_frictionloss[j])
        b = 1e5 / float(speed[j])
        d = a / (a + b * float(speed[j]))
        m.dof_solref[j] = [0.0, -b * d]
        m.dof_solimp[j, :2] = d


def _friction_force(m: mujoco.MjModel, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """(N, nv) the friction part of MuJoCo's inverse dynamics (with and without the dofs' frictionloss)."""
    with_f = inverse_dynamics(m, q, dq, ddq)
    saved = m.dof_frictionloss.copy()
    m.dof_frictionloss[:] = 0.0
    without = inverse_dynamics(m, q, dq, ddq)
    m.dof_frictionloss[:] = saved
    return with_f - without  # type: ignore[no-any-return]


def _states(rng: np.random.Generator, n: int, nv: int, speed: np.ndarray) -> tuple[np.ndarray, ...]:
    q = rng.uniform(-1.5, 1.5, (n, nv))
    dq = rng.uniform(-3, 3, (n, nv)) * np.maximum(speed, 1e-3)  # most samples on the ramp, some saturated
    return q, dq, rng.uniform(-50, 50, (n, nv))


@pytest.mark.parametrize(
    ("system", "frictionloss", "speed"),
    [
        ("two_link", [0.25, 0.19], [0.03, 0.01]),
        ("two_link", [0.002, 0.5], [0.1, 0.3]),  # a small Fc: B is limited by the impedance floor
        ("two_link", [0.25, 0.19], [1e-4, 2e-3]),  # narrower than the step simulates: B is limited, a lead
        ("arm3", [0.3, 0.2, 0.05], [0.01, 0.05, 0.2]),
    ],
)
def test_mujoco_inverse_dynamics_applies_the_declared_ramp(system: str, frictionloss: list, speed: list) -> None:
    plant = load_plant(system)
    fc, vt = np.array(frictionloss), np.array(speed)
    m = _with_ramps(plant.path, fc, vt)
    got_speed, lead = friction_parameters(m)  # read back from the compiled file
    np.testing.assert_allclose(got_speed, vt, rtol=1e-5)
    assert np.all(lead > 0) and np.all(lead <= 1.0001 * m.opt.timestep)  # B is limited to about 1 / timestep
    q, dq, ddq = _states(np.random.default_rng(0), 400, plant.nv, vt)
    got = _friction_force(m, q, dq, ddq)
    np.testing.assert_allclose(got, fc * friction_shape(dq, ddq, vt, lead), atol=1e-5 * fc.max())  # MJCF: 6+ digits


def test_default_solver_parameters_declare_no_ramp_and_turn_over_early() -> None:
    """MuJoCo's defaults: no declared ramp (the torque model's ideal Coulomb), and mj_inverse turns the friction
    over where dq + ddq / 105 changes sign, far from the reversal of a fast motion."""
    plant = load_plant("two_link")
    m = mujoco.MjModel.from_xml_path(str(plant.path))
    m.dof_frictionloss[:] = 0.2
    speed, lead = friction_parameters(m)
    assert np.all(speed == 0) and np.all(lead == 0)
    q, dq, ddq = np.zeros((1, 2)), np.full((1, 2), 0.05), np.full((1, 2), -30.0)
    np.testing.assert_allclose(_friction_force(m, q, dq, ddq), -0.2, atol=1e-9)  # sliding forward, braked backward


def test_torque_model_and_regressor_use_the_declared_ramp(tmp_path: Path) -> None:
    """A plant loaded from a ramp MJCF: the one torque model and the identification regressor equal MuJoCo's
    inverse dynamics, friction included, at any acceleration."""
    base = load_plant("two_link")
    path = tmp_path / "ramp.xml"
    path.write_text(_ramp_xml(base.path, np.array([0.25, 0.19]), np.array([0.03, 1e-3])))
    plant = load_plant(path)
    np.testing.assert_allclose(plant.friction_speed, [0.03, 1e-3], rtol=1e-5)
    q, dq, ddq = _states(np.random.default_rng(1), 300, 2, plant.friction_speed)
    tau, _ = joint_torque(plant, q, dq, ddq)
    np.testing.assert_allclose(tau, inverse_dynamics(plant, q, dq, ddq), atol=1e-5)
    pm = ParameterModel(plant, ("armature", "coulomb_friction"))
    np.testing.assert_allclose(pm.regressor(q, dq, ddq) @ pm.truth(), tau, atol=1e-5)


def _release(m: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """Energy (every 0.1 s) and joint velocities (every step) of the arm released from a tilted pose, 4 s."""
    d = mujoco.MjData(m)
    d.qpos[:] = [1.2, -0.8]
    energy, qvel = [], []
    for k in range(int(4.0 / m.opt.timestep)):
        mujoco.mj_step(m, d)
        qvel.append(d.qvel.copy())
        if k % int(0.1 / m.opt.timestep) == 0:
            mujoco.mj_energyPos(m, d)
            mujoco.mj_energyVel(m, d)
            energy.append(float(d.energy.sum()))
    return np.array(energy), np.array(qvel)


def _chatter(qvel: np.ndarray, m: mujoco.MjModel) -> int:
    """Sign changes of the joint velocities over the last second (an arm at rest that chatters flips each step)."""
    last = qvel[-int(1.0 / m.opt.timestep) :]
    return int(np.count_nonzero(np.diff(np.sign(last), axis=0)))


@pytest.mark.parametrize("narrower", [1.0, 50.0])
def test_forward_simulation_of_a_written_ramp_comes_to_rest_without_chatter(narrower: float) -> None:
    """The ramps `friction_solver` writes, at the narrowest width any damping allows and 50x narrower (where B is
    held to about 1 / timestep: a lead of a step), are stable in forward simulation: the released arm loses
    energy over every 0.1 s and comes to rest without chatter. A ramp 5x narrower than the stable width with
    the damping a wide ramp gets chatters at rest (its velocities flip sign nearly every step): the limit on B
    is what keeps a narrow ramp stable."""
    plant = load_plant("two_link")
    m0 = mujoco.MjModel.from_xml_path(str(plant.path))
    fc, w, dt = np.array([0.25, 0.19]), m0.dof_invweight0, m0.opt.timestep
    stable = np.array([min_friction_speed(fc[j], w[j], dt) for j in range(2)])
    m = _with_ramps(plant.path, fc, stable / narrower)
    energy, qvel = _release(m)
    assert np.all(np.diff(energy) < 0)
    assert _chatter(qvel, m) < 10
    unbounded = _with_ramps(plant.path, fc, stable)
    _unbounded_ramp(unbounded, stable / 5)  # an explicit rate of 5 / timestep
    _, qvel_unbounded = _release(unbounded)
    assert _chatter(qvel_unbounded, unbounded) > 500


def test_calibrated_mjcf_writes_the_fitted_shape_and_mujoco_applies_it(tmp_path: Path) -> None:
    """A fitted smooth Coulomb friction (and an ideal one) in the calibrated MJCF: MuJoCo's inverse dynamics of
    the file gives the torque the diagnosis predicts with the declared shapes."""
    plant = load_plant("two_link")
    ext = Extension.none(plant)
    ext.frictionloss[:] = [0.2, 0.15]
    ext.friction_speed[:] = [0.1, 0.0]  # shoulder: a 0.1 rad/s ramp; elbow: ideal
    path = tmp_path / "calibrated.xml"
    path.write_text(calibrated_xml(plant, ext))
    model = mujoco.MjModel.from_xml_path(str(path))
    speed, _ = friction_parameters(model)
    ideal = ideal_friction_speed(0.15, float(model.dof_invweight0[1]), float(model.opt.timestep))
    np.testing.assert_allclose(speed, [0.1, ideal], rtol=1e-5)
    np.testing.assert_allclose(ext.friction_speed, speed, rtol=1e-5)  # the extension records what was written
    q, dq, ddq = _states(np.random.default_rng(2), 300, 2, speed)
    got = mjcf_measured_torque(model, np.arange(300) * 0.002, q, dq, ddq)
    want, _ = joint_torque(load_plant(path), q, dq, ddq)
    np.testing.assert_allclose(got, want, atol=1e-5)


def test_a_file_with_a_retired_custom_friction_numeric_is_refused() -> None:
    plant = load_plant("two_link")
    spec = mujoco.MjSpec.from_file(str(plant.path))
    numeric = spec.add_numeric()
    numeric.name = "sysid_smooth_coulomb_friction_elbow"
    numeric.data = [0.1, 0.03]
    model = mujoco.MjModel.from_xml_string(spec.to_xml())
    z = np.zeros((3, 2))
    with pytest.raises(ValueError, match="sysid_smooth_coulomb_friction_elbow: written by an earlier version"):
        mjcf_measured_torque(model, np.arange(3) * 0.01, z, z, z)


def test_friction_solver_refuses_a_non_positive_input() -> None:
    with pytest.raises(ValueError, match="Fc, vt, invweight0, timestep > 0"):
        friction_solver(0.1, 0.0, 10.0, 0.002)


@pytest.mark.skipif(not (ROBOTS / "panda_nohand.xml").is_file(), reason="../shared/robots/panda_nohand.xml is absent")
def test_the_ramp_holds_on_a_seven_dof_arm() -> None:
    path = ROBOTS / "panda_nohand.xml"
    m0 = mujoco.MjModel.from_xml_path(str(path))
    fc = np.linspace(0.1, 1.0, m0.nv)
    vt = np.array([ideal_friction_speed(fc[j], m0.dof_invweight0[j], m0.opt.timestep) for j in range(m0.nv)])
    m = _with_ramps(path, fc, vt)
    speed, lead = friction_parameters(m)
    q, dq, ddq = _states(np.random.default_rng(3), 200, m.nv, speed)
    got = _friction_force(m, q, dq, ddq)
    np.testing.assert_allclose(got, fc * friction_shape(dq, ddq, speed, lead), atol=1e-5)
    # the ideal friction's transition (width + lead at 100 rad/s^2) stays far below MuJoCo's defaults' (a width
    # (1 - 0.9) / 0.9 invweight0 Fc 0.0095 and a 9.5 ms lead)
    default = (1 - 0.9) / 0.9 * m0.dof_invweight0 * fc * 0.0095 + 100 * 0.0095
    assert np.all(speed + 100 * lead < 0.5 * default)


@pytest.mark.skipif(not (ROBOTS / "xarm7_nohand.xml").is_file(), reason="../shared/robots/xarm7_nohand.xml is absent")
def test_a_changed_friction_on_an_arm_with_nominal_friction_is_written_and_the_others_are_left(tmp_path: Path) -> None:
    """xArm7 (frictionloss 1 N m in its MJCF, a 2 ms step): one joint's friction changed to a 0.05 rad/s ramp is
    written as that ramp (with the lead its stability needs), the joints the fit did not touch keep MuJoCo's
    parameters, and the torque model agrees with mj_inverse on the changed joint."""
    plant = load_plant(ROBOTS / "xarm7_nohand.xml")
    j = 2
    ext = Extension.none(plant)
    ext.frictionloss[j] = 0.2
    ext.friction_speed[j] = 0.05
    path = tmp_path / "calibrated.xml"
    path.write_text(calibrated_xml(plant, ext))
    model = mujoco.MjModel.from_xml_path(str(path))
    speed, lead = friction_parameters(model)
    assert speed[j] == pytest.approx(0.05, rel=1e-5)
    assert 0.05 < min_friction_speed(float(model.dof_frictionloss[j]), float(model.dof_invweight0[j]), 0.002)
    assert lead[j] > 0.5 * model.opt.timestep  # narrower than the stable width: a lead of about a step
    assert model.dof_frictionloss[j] == pytest.approx(plant.frictionloss[j] + 0.2)
    untouched = [k for k in range(plant.nv) if k != j]
    np.testing.assert_array_equal(speed[untouched], 0.0)
    np.testing.assert_allclose(model.dof_solref[untouched], plant.mj_model.dof_solref[untouched])
    calibrated = load_plant(path)
    rng = np.random.default_rng(4)
    q, ddq = rng.uniform(-1, 1, (200, plant.nv)), rng.uniform(-20, 20, (200, plant.nv))
    dq = np.zeros((200, plant.nv))
    dq[:, j] = rng.uniform(-0.2, 0.2, 200)
    got = _friction_force(model, q, dq, ddq)[:, j]
    shape = friction_shape(dq, ddq, calibrated.friction_speed, calibrated.friction_lead)
    want = model.dof_frictionloss[j] * shape[:, j]
    np.testing.assert_allclose(got, want, atol=1e-5 * model.dof_frictionloss[j])


def test_simulating_with_hard_friction_keeps_a_declared_ramp() -> None:
    """`system.hard_friction` stiffens MuJoCo's default friction, never a ramp the model declares."""
    from envs.simulate import _hard_friction

    plant = load_plant("two_link")
    m = _with_ramps(plant.path, np.array([0.2, 0.1]), np.array([0.05, 0.05]))
    m.dof_solref[1], m.dof_solimp[1] = [0.02, 1.0], [0.9, 0.95, 0.001, 0.5, 2.0]  # elbow: MuJoCo's defaults
    ramp_ref, ramp_imp = m.dof_solref[0].copy(), m.dof_solimp[0].copy()
    hard = _hard_friction(m)
    np.testing.assert_array_equal(hard.dof_solref[0], ramp_ref)
    np.testing.assert_array_equal(hard.dof_solimp[0], ramp_imp)
    assert hard.dof_solref[1, 0] == pytest.approx(2 * hard.opt.timestep)
    assert hard.dof_solimp[1, 0] == pytest.approx(0.999)


@pytest.mark.parametrize("flag", ["frictionloss", "constraint"])
def test_disabled_dry_friction_is_left_out_of_the_torque_model(flag: str, tmp_path: Path) -> None:
    """`<option><flag frictionloss="disable"/>` (or constraint): MuJoCo applies no frictionloss, nor does the
    plant's torque model, which still equals mj_inverse; a calibrated file with a fitted friction says so."""
    base = load_plant("two_link")
    xml = _ramp_xml(base.path, np.array([0.25, 0.19]), np.array([0.03, 0.03]))
    spec = mujoco.MjSpec.from_string(xml)
    spec.option.disableflags |= int(getattr(mujoco.mjtDisableBit, f"mjDSBL_{flag.upper()}"))
    path = tmp_path / "nofriction.xml"
    path.write_text(spec.to_xml())
    plant = load_plant(path)
    assert not np.any(plant.frictionloss)
    q, dq, ddq = _states(np.random.default_rng(5), 100, 2, np.array([0.03, 0.03]))
    np.testing.assert_allclose(joint_torque(plant, q, dq, ddq)[0], inverse_dynamics(plant, q, dq, ddq), atol=1e-8)
    ext = Extension.none(plant)
    ext.frictionloss[0] = 0.1
    calibrated_xml(plant, ext)
    assert any("disables frictionloss" in n for n in ext.notes), ext.notes  # written, and said not to act


@pytest.mark.parametrize("fc", [1e-4, 1.0, 100.0])
@pytest.mark.parametrize("invweight0", [0.01, 1e5])
@pytest.mark.parametrize("timestep", [1e-4, 0.01])
@pytest.mark.parametrize("speed", [1e-4, 0.03, 10.0])
def test_the_solver_stays_within_mujocos_impedance_bounds(
    fc: float, invweight0: float, timestep: float, speed: float
) -> None:
    """Over the plausible range of Fc, inverse inertia, step and width, the impedance stays inside MuJoCo's clamp
    [1e-4, 0.9999] (a clamped value would make MuJoCo's ramp differ from the declared one), and a width too
    narrow for the step is widened, never silently misdeclared."""
    solref, solimp, written = friction_solver(fc, speed, invweight0, timestep)
    assert 1e-4 < solimp[0] == solimp[1] <= 0.999
    assert written >= speed
    if written > speed:
        assert written == pytest.approx(invweight0 * fc * timestep * 1e-3)
    d, damping = solimp[0], -solref[1] / solimp[0]
    assert (1 - d) / d * invweight0 * fc / damping == pytest.approx(written, rel=1e-9)  # friction_parameters' vt


def test_the_torque_derivatives_include_the_ramp_slope(tmp_path: Path) -> None:
    """On a declared ramp the friction's derivative is Fc / vt in dq and Fc lead / vt in ddq: against central
    differences of the torque model, away from the ramp's corners."""
    base = load_plant("two_link")
    path = tmp_path / "ramp.xml"
    path.write_text(_ramp_xml(base.path, np.array([0.25, 0.19]), np.array([0.3, 2e-3])))
    plant = load_plant(path)
    assert plant.friction_lead[1] > 0.5 * plant.mj_model.opt.timestep  # the elbow's narrow ramp has a lead
    rng = np.random.default_rng(6)
    q, ddq = rng.uniform(-1, 1, (40, 2)), rng.uniform(-0.5, 0.5, (40, 2))
    dq = rng.uniform(-0.1, 0.1, (40, 2)) * [1.0, 0.005]  # on both ramps
    _, D = joint_torque(plant, q, dq, ddq, derivatives=True)
    assert D is not None
    for which, x in ((1, dq), (2, ddq)):
        for j in range(2):
            h = np.zeros_like(x)
            h[:, j] = 1e-7 if which == 1 else 1e-5
            args = [q, dq, ddq]
            up, down = list(args), list(args)
            up[which], down[which] = x + h, x - h
            fd = (joint_torque(plant, *up)[0] - joint_torque(plant, *down)[0]) / (2 * h[:, j : j + 1])
            np.testing.assert_allclose(D[which][:, :, j], fd, rtol=1e-4, atol=1e-6)


def test_refitting_the_friction_of_a_declared_ramp_keeps_its_width(tmp_path: Path) -> None:
    """Diagnosing a calibrated file again: an ideal-Coulomb change of a joint that declares a ramp changes Fc only,
    the width stays, and the candidate's column is that ramp."""
    from types import SimpleNamespace

    from identify.diagnose.candidates import candidates

    base = load_plant("two_link")
    path = tmp_path / "ramp.xml"
    path.write_text(_ramp_xml(base.path, np.array([0.25, 0.19]), np.array([0.1, 0.05])))
    plant = load_plant(path)
    ext = Extension.none(plant)
    ext.frictionloss[0] = 0.05  # a coulomb_friction finding: no width of its own
    out = tmp_path / "again.xml"
    out.write_text(calibrated_xml(plant, ext))
    speed, _ = friction_parameters(mujoco.MjModel.from_xml_path(str(out)))
    np.testing.assert_allclose(speed, [0.1, 0.05], rtol=1e-4)
    (cand,) = [c for c in candidates(plant, ["coulomb_friction"], np.random.default_rng(0)) if c.target == "shoulder"]
    dq = np.array([[-0.2, 0.0], [-0.05, 0.0], [0.0, 0.0], [0.05, 0.0], [0.2, 0.0]])
    col = cand.build(SimpleNamespace(n_samples=5, dq=dq, ddq=np.zeros((5, 2))))  # type: ignore[arg-type]
    np.testing.assert_allclose(col[:, 0, 0], [-1, -0.5, 0, 0.5, 1], atol=1e-4)  # the declared ramp, not sign


def test_a_calibrated_file_keeps_the_friction_a_disabled_flag_hides(tmp_path: Path) -> None:
    """With frictionloss disabled by a flag the plant has none, but the calibrated file keeps the file's own value
    (and adds the fitted change to it), as it does for damping and stiffness."""
    base = load_plant("two_link")
    spec = mujoco.MjSpec.from_string(_ramp_xml(base.path, np.array([0.3, 0.2]), np.array([0.05, 0.05])))
    spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS)
    path = tmp_path / "off.xml"
    path.write_text(spec.to_xml())
    plant = load_plant(path)
    ext = Extension.none(plant)
    ext.frictionloss[1] = 0.1
    model = mujoco.MjModel.from_xml_string(calibrated_xml(plant, ext))
    np.testing.assert_allclose(model.dof_frictionloss, [0.3, 0.3], rtol=1e-5)


def test_the_bench_widens_every_joint_friction_to_the_ramp_it_asks_for() -> None:
    """`bench.diagnose.widened` (the friction-shape sensitivity of the real-data table): each dof with a
    frictionloss reads back the asked width and its Fc unchanged, MuJoCo's inverse dynamics then applies
    Fc sat(dq / vt) (at zero acceleration, where the ramp's lead does not enter), and the model it was given is
    left as it was."""
    from bench.diagnose import widened

    m = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><joint name="a" axis="0 1 0" frictionloss="0.2"/>'
        '<geom size="0.1" mass="1"/><body pos="0.3 0 0"><joint name="b" axis="0 1 0"/><geom size="0.1" mass="1"/>'
        "</body></body></worldbody></mujoco>"
    )
    before = m.dof_solref.copy()
    wide = widened(m, 0.1)
    speed, _ = friction_parameters(wide)
    assert speed[0] == pytest.approx(0.1) and speed[1] == 0.0  # joint b has no friction
    assert wide.dof_frictionloss[0] == pytest.approx(0.2) and np.array_equal(m.dof_solref, before)
    d = mujoco.MjData(wide)
    for v in (-0.2, -0.05, 0.0, 0.03, 0.3):
        d.qpos[:], d.qvel[:], d.qacc[:] = 0.0, [v, 0.0], 0.0
        mujoco.mj_inverse(wide, d)
        assert d.qfrc_constraint[0] == pytest.approx(-0.2 * np.clip(v / 0.1, -1, 1), abs=1e-6)


def _solver_variant(kind: str) -> mujoco.MjModel:
    """two_link with frictionloss on both joints and the solver parameters of `kind`."""
    m = mujoco.MjModel.from_xml_path(str(load_plant("two_link").path))
    m.dof_frictionloss[:] = [0.3, 0.2]
    if kind == "positive":  # another time constant and impedances (dmin != dmax)
        m.dof_solref[:] = [0.05, 0.7]
        m.dof_solimp[:, :2] = [0.8, 0.9]
    elif kind == "clamped":  # a time constant below two steps: MuJoCo takes two steps
        m.dof_solref[:] = [0.1 * m.opt.timestep, 1.0]
    elif kind == "unclamped":  # the same with refsafe disabled: MuJoCo takes it as given
        m.dof_solref[:] = [0.1 * m.opt.timestep, 1.0]
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_REFSAFE)
    elif kind == "direct":
        m.dof_solref[:] = [0.0, -300.0]
        m.dof_solimp[:, :2] = [0.5, 0.7]
    elif kind == "mixed":  # a solref of mixed signs: MuJoCo takes its default (0.02, 1)
        m.dof_solref[:] = [0.05, -1.0]
    elif kind == "no_width":  # a solimp transition of no width: MuJoCo takes the mean impedance
        m.dof_solimp[:, :3] = [0.3, 0.95, 0.0]
    elif kind == "override":  # <flag override="enable">: o_solref / o_solimp are for contacts, not a dof's friction
        m.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_OVERRIDE)
        m.opt.o_solref[:] = [0.05, 1.0]
        m.opt.o_solimp[:] = [0.7, 0.8, 0.001, 0.5, 2.0]
    return m


@pytest.mark.parametrize(
    "kind", ["default", "positive", "clamped", "unclamped", "direct", "mixed", "no_width", "override"]
)
def test_the_friction_mujoco_applies_is_read_whatever_the_solver_parameters(
    kind: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`applied_friction_parameters`: mj_inverse's friction force is Fc sat((dq + lead ddq) / vt) with the width and
    lead read from any solref / solimp, MuJoCo's defaults and its clamp of short time constants included;
    `friction_parameters` still reads only a declared ramp (the direct form with dmin = dmax)."""
    monkeypatch.chdir(tmp_path)  # MuJoCo writes its warning about a mixed solref to MUJOCO_LOG.TXT here
    m = _solver_variant(kind)
    speed, lead = applied_friction_parameters(m)
    assert np.all(speed > 0) and np.all(lead > 0)
    q, dq, ddq = _states(np.random.default_rng(1), 400, m.nv, speed)
    got = _friction_force(m, q, dq, ddq)
    np.testing.assert_allclose(got, m.dof_frictionloss * friction_shape(dq, ddq, speed, lead), atol=1e-9)
    if kind == "clamped":
        np.testing.assert_allclose(lead, 0.95 * m.opt.timestep)  # 1 / B = dmax timeconst / 2, timeconst 2 steps
    assert not np.any(friction_parameters(m)[0])  # dmin != dmax or a positive solref: not a declared ramp


@pytest.mark.skipif(not (ROBOTS / "xarm7_nohand.xml").is_file(), reason="../shared/robots/xarm7_nohand.xml is absent")
def test_the_xarm7s_default_friction_is_a_wide_ramp_on_its_last_joint_and_the_plant_reads_it() -> None:
    """The Menagerie xArm7 (frictionloss 1 N m, default solver parameters): MuJoCo applies a ramp 7.7 rad/s wide on
    joint 7 (dof_invweight0 7302) with a 9.5 ms lead; `with_applied_friction` gives the plant that friction, and its
    torque model is then MuJoCo's inverse dynamics at any state (away from the joint limits)."""
    plant = load_plant(ROBOTS / "xarm7_nohand.xml")
    assert not np.any(plant.friction_speed)  # the identification's reading: ideal Coulomb
    applied = with_applied_friction(plant)
    assert applied.friction_speed[6] == pytest.approx(7.707, abs=1e-3)
    np.testing.assert_allclose(applied.friction_lead, 0.02 * 0.95 / 2)
    rng = np.random.default_rng(2)
    q = rng.uniform(-0.5, 0.5, (300, plant.nv)) + np.array([0, 0.3, 0, 1.5, 0, 1, 0])
    dq, ddq = rng.normal(0, 0.3, (300, plant.nv)), rng.normal(0, 20, (300, plant.nv))
    want = inverse_dynamics(plant.mj_model, q, dq, ddq)
    np.testing.assert_allclose(joint_torque(applied, q, dq, ddq)[0], want, atol=1e-8)
    assert np.abs(joint_torque(plant, q, dq, ddq)[0] - want)[:, 6].max() > 0.9  # sign(dq): up to 2 Fc off


@pytest.mark.skipif(not (ROBOTS / "xarm7_nohand.xml").is_file(), reason="../shared/robots/xarm7_nohand.xml is absent")
def test_a_ramp_is_kept_where_an_inertia_change_moves_invweight0(tmp_path: Path) -> None:
    """MuJoCo's default ramp is as wide as dof_invweight0: `ramp_solver` gives a joint the width and lead it had
    at another inertia, and a calibrated MJCF whose armature changed keeps the nominal ramp on that joint (read as
    applied) while the joints whose inverse inertia did not move keep their own parameters."""
    plant = with_applied_friction(load_plant(ROBOTS / "xarm7_nohand.xml"))
    j = 5
    ext = Extension.none(plant)
    ext.armature[j] = 0.02
    path = tmp_path / "calibrated.xml"
    path.write_text(calibrated_xml(plant, ext))
    model = mujoco.MjModel.from_xml_path(str(path))
    assert model.dof_invweight0[j] < 0.5 * plant.mj_model.dof_invweight0[j]
    speed, lead = applied_friction_parameters(model)
    assert speed[j] == pytest.approx(plant.friction_speed[j], rel=1e-5)  # as the MJCF text rounds it
    assert lead[j] == pytest.approx(plant.friction_lead[j], rel=1e-5)
    moved = ~np.isclose(model.dof_invweight0, plant.mj_model.dof_invweight0, rtol=1e-9, atol=0.0)
    np.testing.assert_array_equal(model.dof_solref[~moved], plant.mj_model.dof_solref[~moved])
    unpinned = mujoco.MjModel.from_xml_path(str(ROBOTS / "xarm7_nohand.xml"))
    unpinned.dof_armature[j] += 0.02
    mujoco.mj_setConst(unpinned, mujoco.MjData(unpinned))
    assert applied_friction_parameters(unpinned)[0][j] < 0.5 * plant.friction_speed[j]  # what it keeps from
    assert ramp_solver(1.0, 1.0, 1e-3, 1e-9) is None  # an impedance beyond MuJoCo's bounds: no exact ramp


@pytest.mark.skipif(not (ROBOTS / "ur5e.xml").is_file(), reason="../shared/robots/ is not beside the project")
@pytest.mark.parametrize(("arm", "j", "armature"), [("ur5e", 1, 0.0), ("ur5e", 1, 0.5), ("xarm7_nohand", 6, 0.01)])
def test_mujocos_own_friction_shape_is_written_as_fitted(tmp_path: Path, arm: str, j: int, armature: float) -> None:
    """A Coulomb friction fitted in MuJoCo's own shape (`candidates.SOFT_FRICTION`: Fc sat((dq + ddq / B) / vt),
    vt = R Fc / B at the joint's solver parameters) is written as the bare frictionloss, and MuJoCo's inverse
    dynamics then applies the shape fitted. Where a fitted armature moves dof_invweight0, MuJoCo's width would move
    with it (written bare: 0.488 N m off on the xArm7's last joint, a third of its Fc); the fitted ramp is written
    as such there. The UR5e's shoulder lift has no nominal frictionloss, the xArm7's last joint 1 N m."""
    from identify.diagnose.candidates import _SoftFriction

    plant = with_applied_friction(load_plant(ROBOTS / f"{arm}.xml"))
    unit, lead = applied_friction_parameters(plant.mj_model, np.ones(plant.nv))
    shape = _SoftFriction(float(plant.frictionloss[j]), float(unit[j]), float(lead[j]))
    change = 1.5
    rng = np.random.default_rng(0)
    n = 500
    q = plant.mj_model.qpos0 + rng.normal(0.0, 0.3, (n, plant.nv))
    dq, ddq = rng.normal(0.0, 1.0, (n, plant.nv)), rng.normal(0.0, 20.0, (n, plant.nv))
    dq[:, j] = rng.uniform(-3.0, 3.0, n) * unit[j] * (shape.nominal + change)  # across the ramp
    fitted = shape.torque(dq[:, j], ddq[:, j], shape.nominal + change)
    ext = Extension.none(plant)
    ext.frictionloss[j], ext.soft_friction[j], ext.armature[j] = change, True, armature
    path = tmp_path / "calibrated.xml"
    path.write_text(calibrated_xml(plant, ext))
    model = mujoco.MjModel.from_xml_path(str(path))
    moved = not np.isclose(model.dof_invweight0[j], plant.mj_model.dof_invweight0[j], rtol=1e-9, atol=0.0)
    assert moved == (armature > 0)
    if not moved:  # MuJoCo's own parameters, untouched
        np.testing.assert_array_equal(model.dof_solref[j], plant.mj_model.dof_solref[j])
        np.testing.assert_array_equal(model.dof_solimp[j], plant.mj_model.dof_solimp[j])
    with_friction = inverse_dynamics(model, q, dq, ddq)
    model.dof_frictionloss[:] = 0.0
    applied = (with_friction - inverse_dynamics(model, q, dq, ddq))[:, j]
    scale = shape.nominal + change
    assert np.sqrt(np.mean((applied - fitted) ** 2)) < 1e-5 * scale  # the text's 6 digits
    assert ext.friction_speed[j] == pytest.approx(unit[j] * scale)


def _soft_signals(dq: np.ndarray, ddq: np.ndarray, tau: np.ndarray, used: np.ndarray | None = None):  # type: ignore[no-untyped-def]
    """Signals of a 2-joint record at 500 Hz with the given joint speeds, accelerations and residual torque
    (`used`: the (row, joint) torques fitted, None for all)."""
    from identify.diagnose.candidates import Signals

    n = len(dq)
    return Signals(
        time=np.arange(n) * 0.002,
        q=np.zeros((n, 2)),
        dq=dq,
        ddq=ddq,
        tau=tau,
        tau_nominal=np.zeros((n, 2)),
        dtau_dq=np.zeros((n, 2, 2)),
        dtau_dt=np.zeros((n, 2)),
        regressor=np.zeros((n, 2, 20)),
        record=np.zeros(n, int),
        actuated=np.ones(2, bool),
        used=used,
        band_hz=5.0,
    )


def test_the_soft_friction_change_is_read_on_its_own_joints_rows() -> None:
    """`_soft_friction_change` fits a joint's residual on its own used rows: the rows another joint leaves out
    (held at its stop, at rest) are no business of this one. It read the columns through the first joint's mask,
    which the analysis band then spreads: 0.5 N m came out 0.582 on a UR5e with every 7th row of joint 0 left out
    (0.597 here); now within 1e-5."""
    from identify.diagnose.candidates import _soft_friction_change, _SoftFriction

    rng = np.random.default_rng(0)
    n, t = 3000, np.arange(3000) * 0.002
    dq = np.column_stack([np.sin(2 * t), np.sin(3 * t) + 0.2 * rng.normal(size=n)])
    ddq = np.column_stack([2 * np.cos(2 * t), 3 * np.cos(3 * t)])
    shape = _SoftFriction(0.0, 0.01, 0.0095)
    tau = np.column_stack([np.zeros(n), shape.torque(dq[:, 1], ddq[:, 1], 0.5) + 0.1 * dq[:, 1]])
    used = np.ones((n, 2), bool)
    used[::7, 0] = False
    s = _soft_signals(dq, ddq, tau, used)
    assert _soft_friction_change(s, s.residual, 1, shape) == pytest.approx(0.5, rel=1e-5)


@pytest.mark.parametrize(("made_at", "gain"), [(0.5, None), (-0.2, None), (0.5, 1.25)])
def test_the_final_fit_makes_mujocos_friction_shape_at_the_value_it_fits(made_at: float, gain: float | None) -> None:
    """MuJoCo's friction ramp widens with Fc, so its column is a secant from the nominal F0 to F0 + dF, made at the
    dF the training residual gives alone. Fitted beside other effects the change can end elsewhere, and the MJCF
    written at the fitted value then applied another friction than the one fitted (a secant at +0.5 N m fitted at
    -0.5: here the fit came out at -0.617 and MuJoCo's friction at it 0.29 N m RMS off the fitted torque; made at
    -0.2, -0.513 and 0.09 N m). The final fit now makes the column again at the value it fits until they agree:
    the truth, -0.5, and the column that of MuJoCo's friction there; also where a torque gain is fitted beside it,
    whose own iteration had moved the value off the column again (-0.4917 for a column made at -0.6145)."""
    import dataclasses

    from identify.diagnose.candidates import _joint_effects, _soft_candidate, _SoftFriction
    from identify.diagnose.diagnosis import _final_fit
    from identify.diagnose.select import Step

    plant = load_plant("two_link")
    shape = _SoftFriction(1.0, 2.0, 0.0095)  # a light joint: the ramp 2 rad/s wide per N m
    t = np.arange(5000) * 0.002
    dq = np.column_stack([np.sin(t), 3.0 * np.sin(2.1 * t) + 0.5 * np.sin(5.3 * t)])
    ddq = np.column_stack([np.cos(t), 6.3 * np.cos(2.1 * t) + 2.65 * np.cos(5.3 * t)])
    truth = -0.5
    change = shape.torque(dq[:, 1], ddq[:, 1], shape.nominal + truth) - shape.torque(dq[:, 1], ddq[:, 1], shape.nominal)
    nominal = np.column_stack([np.zeros(len(t)), 3.0 * np.sin(0.7 * t) + 1.0])
    measured = (gain or 1.0) * (nominal[:, 1] + change)
    s = dataclasses.replace(_soft_signals(dq, ddq, np.column_stack([np.zeros(len(t)), measured])), tau_nominal=nominal)
    cand = _soft_candidate(plant, 1, shape, made_at)
    steps = [Step(cand, np.array([0]), -1.0, 1.0, 0.5)]
    X = s.columns(cand)
    if gain is not None:
        (gains,) = [c for c in _joint_effects(plant) if c.effect == "torque_gain" and c.target == "elbow"]
        steps.append(Step(gains, np.array([0]), -1.0, 1.0, 0.5))
        X = np.concatenate([X, s.columns(gains)], axis=2)
    _, fit, left, steps = _final_fit(plant, steps, X, s, np.ones(2))
    assert fit.coef[0] == pytest.approx(truth, rel=1e-5)
    if gain is not None:
        assert 1.0 + fit.coef[1] == pytest.approx(gain, rel=1e-6)
    assert steps[0].candidate.made_at == pytest.approx(fit.coef[0], rel=1e-5)
    written = shape.torque(dq[:, 1], ddq[:, 1], shape.nominal + fit.coef[0]) - shape.torque(
        dq[:, 1], ddq[:, 1], shape.nominal
    )
    np.testing.assert_allclose(steps[0].candidate.build(s)[:, 1, 0] * fit.coef[0], written, atol=1e-5)
    assert np.sqrt(np.mean(left**2)) < 1e-6


def _ramp_plant():  # type: ignore[no-untyped-def]
    """The two-link arm with a nominal frictionloss of 1 N m on the elbow that MuJoCo applies as a ramp 2 rad/s wide
    (turning over 9.5 ms early), as a light joint's at MuJoCo's default solver parameters."""
    import dataclasses

    plant = load_plant("two_link")
    return dataclasses.replace(
        plant,
        frictionloss=np.array([0.0, 1.0]),
        friction_speed=np.array([0.0, 2.0]),
        friction_lead=np.array([0.0, 0.0095]),
    )


def test_a_friction_in_a_narrower_shape_is_fitted_as_the_affine_model_the_file_holds() -> None:
    """`friction_ramp` replaces the nominal F0 N (its ramp) by Fc S (a narrower shape): the effect Fc S - F0 N is
    affine in Fc. Its column made at m is S - (F0 / m) N, exact at Fc = m; a fit of Fc on that column settles where
    the error is orthogonal to S - (F0 / m) N, not to S, so its fixed point is not the least squares of the model
    the file holds, and its std not that of Fc (on these records the fixed point is 1.1424, the least squares
    1.1454).
    The final fit now fits Fc S with F0 N moved to the torque it explains: the least-squares Fc, the column made
    at it, and the prediction c z_c = Fc S - F0 N. A residual that asks for no friction at all is not held."""
    import dataclasses

    from identify.diagnose.candidates import IDEAL, _ramp_candidate
    from identify.diagnose.diagnosis import _final_fit
    from identify.diagnose.select import Step

    plant = _ramp_plant()
    t = np.arange(5000) * 0.002
    dq = np.column_stack([np.sin(t), 1.5 * np.sin(2.1 * t) + 0.5 * np.sin(5.3 * t)])
    ddq = np.column_stack([np.cos(t), 3.15 * np.cos(2.1 * t) + 2.65 * np.cos(5.3 * t)])
    nominal = friction_shape(dq, ddq, plant.friction_speed, plant.friction_lead)[:, 1]
    # the plant's friction 1.1 sign(dq) in place of the nominal one, and something the model lacks along N
    residual = 1.1 * np.sign(dq[:, 1]) - nominal + 0.05 * np.clip(dq[:, 1] / 0.5, -1, 1)
    s = _soft_signals(dq, ddq, np.column_stack([np.zeros(len(t)), residual]))
    cand = _ramp_candidate(plant, 1, IDEAL, 1.0)
    plain, offset = s.affine_parts(cand)
    np.testing.assert_allclose(offset[:, 1], s.in_band(np.column_stack([0 * nominal, nominal]))[:, 1], atol=1e-12)
    for m in (0.5, 2.0):  # made at m: S - O / m
        np.testing.assert_allclose(s.columns(cand.remake(m))[:, 1, 0], plain[:, 1] - offset[:, 1] / m, atol=1e-12)
    least_squares = float(np.linalg.lstsq(plain[:, 1:], s.residual[:, 1] + offset[:, 1], rcond=None)[0][0])
    X, fit, left, steps = _final_fit(plant, [Step(cand, np.array([0]), -1.0, 1.0, 0.5)], s.columns(cand), s, np.ones(2))
    assert fit.coef[0] == pytest.approx(least_squares, rel=1e-9)
    assert steps[0].candidate.made_at == pytest.approx(fit.coef[0], rel=1e-12)
    np.testing.assert_allclose(X[:, 1, 0] * fit.coef[0], fit.coef[0] * plain[:, 1] - offset[:, 1], atol=1e-9)
    np.testing.assert_allclose(left[:, 1], s.residual[:, 1] - X[:, 1, 0] * fit.coef[0], atol=1e-12)
    nothing = dataclasses.replace(s, tau=np.column_stack([np.zeros(len(t)), -nominal]))  # the friction gone
    _, fit, _, steps = _final_fit(
        plant, [Step(cand, np.array([0]), -1.0, 1.0, 0.5)], nothing.columns(cand), nothing, np.ones(2)
    )
    assert not steps and not cand.holds(0.0)

"""The MJCF is the one source of truth: Pinocchio's regressor times the MJCF's parameters is MuJoCo's dynamics."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from dynamics.errors import ModelError
from dynamics.plant import MJCF_DIR, SYSTEMS, load_plant
from dynamics.regressor import ParameterModel
from dynamics.sampling import random_states

BUILT_IN = [s for s in SYSTEMS if (MJCF_DIR / f"{s}.xml").is_file()]


def _mj_inverse(plant, q, dq, ddq):  # type: ignore[no-untyped-def]
    m = plant.mj_model
    d = mujoco.MjData(m)
    out = np.empty_like(q)
    for k in range(len(q)):
        d.qpos[:], d.qvel[:], d.qacc[:] = q[k], dq[k], ddq[k]
        mujoco.mj_inverse(m, d)
        assert d.nefc == 0, "a constraint is active: the comparison would include its force"
        out[k] = d.qfrc_inverse
    return out


@pytest.mark.parametrize("system", BUILT_IN)
def test_regressor_times_truth_is_mujoco_inverse_dynamics(system: str) -> None:
    plant = load_plant(system)
    model = ParameterModel(plant, ("armature", "viscous_friction"))
    q, dq, ddq = random_states(plant, np.random.default_rng(0), 100)
    q = np.clip(q, plant.q_range[:, 0] * 0.99, plant.q_range[:, 1] * 0.99)  # keep joint limits inactive
    predicted = np.einsum("knp,p->kn", model.regressor(q, dq, ddq), model.truth())
    np.testing.assert_allclose(predicted, _mj_inverse(plant, q, dq, ddq), rtol=0, atol=1e-8)


def test_regressor_includes_damping_and_armature_when_present(tmp_path: Path) -> None:
    xml = (MJCF_DIR / "two_link.xml").read_text().replace('armature="0.00218588"', 'armature="0.003" damping="0.05"')
    path = tmp_path / "damped.xml"
    path.write_text(xml)
    plant = load_plant(path)
    np.testing.assert_allclose(plant.damping, [0.05, 0.05])
    model = ParameterModel(plant, ("armature", "viscous_friction"))
    q, dq, ddq = random_states(plant, np.random.default_rng(1), 50)
    predicted = np.einsum("knp,p->kn", model.regressor(q, dq, ddq), model.truth())
    np.testing.assert_allclose(predicted, _mj_inverse(plant, q, dq, ddq), rtol=0, atol=1e-8)
    rigid_only = np.einsum("knp,p->kn", ParameterModel(plant).regressor(q, dq, ddq), plant.theta)
    assert np.max(np.abs(rigid_only - _mj_inverse(plant, q, dq, ddq))) > 1e-3  # the effects matter here


def test_truth_matches_mujoco_body_inertials() -> None:
    plant = load_plant("two_link")
    m = plant.mj_model
    for j in range(plant.nv):
        body = m.jnt_bodyid[j]
        theta = plant.theta[10 * j : 10 * j + 10]
        assert theta[0] == pytest.approx(m.body_mass[body])
        np.testing.assert_allclose(theta[1:4], m.body_mass[body] * m.body_ipos[body], atol=1e-12)


def test_unknown_system_lists_valid_choices() -> None:
    with pytest.raises(ValueError, match=r"valid choices: .*two_link"):
        load_plant("three_link")


@pytest.mark.parametrize(
    ("joint", "message"),
    [
        ('<joint name="j" type="ball"/>', "only hinge and slide"),
        ('<joint name="j" type="free"/>', "only hinge and slide"),
    ],
)
def test_unsupported_models_are_refused(tmp_path: Path, joint: str, message: str) -> None:
    path = tmp_path / "bad.xml"
    path.write_text(
        f'<mujoco><worldbody><body name="b">{joint}<inertial pos="0 0 -0.1" mass="1" diaginertia="0.01 0.01 0.01"/>'
        "</body></worldbody></mujoco>"
    )
    with pytest.raises(ModelError, match=message):
        load_plant(path)


_DRIVEN = (
    '<mujoco>{option}<worldbody><body name="b"><joint name="j" axis="0 1 0" {joint}/>'
    '<inertial pos="0 0 -0.1" mass="1" diaginertia="0.01 0.01 0.01"/></body></worldbody>'
    '<actuator><motor name="m" joint="j" group="{group}"/></actuator></mujoco>'
)


@pytest.mark.parametrize(
    ("option", "joint", "group", "message"),
    [
        ("", 'stiffness="2" springyield="0.3"', 0, r"joint\(s\) \['j'\] have a springyield"),
        ('<option><flag actuation="disable"/></option>', "", 0, "actuation is disabled"),
        ('<option actuatorgroupdisable="1"/>', "", 1, r"actuator\(s\) \['m'\] are in disabled group\(s\) \[1\]"),
    ],
)
def test_what_the_dynamics_check_cannot_see_is_refused(
    tmp_path: Path, option: str, joint: str, group: int, message: str
) -> None:
    """A plastic spring (its rest position follows the joint's history) and actuators MuJoCo does not apply
    agree with Pinocchio at every single state, so the load-time check passes them: they are refused by name."""
    path = tmp_path / "bad.xml"
    path.write_text(_DRIVEN.format(option=option, joint=joint, group=group))
    with pytest.raises(ModelError, match=message):
        load_plant(path)
    path.write_text(_DRIVEN.format(option="", joint='stiffness="2"', group=group))
    assert load_plant(path).stiffness.tolist() == [2.0]  # the same model without them loads


def test_a_urdfs_errors_name_the_urdf(tmp_path: Path) -> None:
    """The URDF is converted to an MJCF in a cache folder; a refusal names the file the user gave."""
    path = tmp_path / "floating.urdf"
    path.write_text(
        '<robot name="r"><link name="base"/><link name="arm"><inertial><mass value="1"/>'
        '<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>'
        '<joint name="float" type="floating"><parent link="base"/><child link="arm"/></joint></robot>'
    )
    with pytest.raises(ModelError, match=r"floating\.urdf: only hinge and slide joints") as err:
        load_plant(path)
    assert "sysid_urdf_" not in str(err.value)


def test_mujocos_compile_error_is_one_line_naming_the_file(tmp_path: Path) -> None:
    """MuJoCo's compile errors take three lines (the error, the element, a note); a refusal is one line."""
    path = tmp_path / "zero.xml"
    path.write_text('<mujoco><worldbody><body><joint/><geom size="0" type="box"/></body></worldbody></mujoco>')
    with pytest.raises(ModelError, match=r"zero\.xml: MuJoCo cannot load it: Error: size 0 must be positive") as err:
        load_plant(path)
    assert "\n" not in str(err.value) and "; Element name" in str(err.value)


def test_hinge_tells_hinges_from_slides(tmp_path: Path) -> None:
    from dynamics.plant import plant_from_xml

    xml = (
        '<mujoco><worldbody><body><joint name="rail" type="slide" axis="1 0 0"/><geom size="0.1" mass="1"/>'
        '<body><joint name="arm" axis="0 1 0"/><geom size="0.1" pos="0 0 -0.2" mass="0.5"/></body></body>'
        '</worldbody><actuator><motor joint="rail"/><motor joint="arm"/></actuator></mujoco>'
    )
    assert plant_from_xml(xml, "cart", tmp_path).hinge.tolist() == [False, True]
    assert load_plant("two_link").hinge.tolist() == [True, True]


def test_a_slide_joints_effects_are_forces_in_their_units(tmp_path: Path) -> None:
    from dynamics.plant import plant_from_xml
    from identify.diagnose.candidates import CANDIDATE_EFFECTS, candidates

    xml = (
        '<mujoco><worldbody><body><joint name="rail" type="slide" axis="1 0 0"/><geom size="0.1" mass="1"/>'
        '<body><joint name="arm" axis="0 1 0"/><geom size="0.1" pos="0 0 -0.2" mass="0.5"/></body></body>'
        '</worldbody><actuator><motor joint="rail"/><motor joint="arm"/></actuator></mujoco>'
    )
    plant = plant_from_xml(xml, "cart", tmp_path)
    pool = candidates(plant, tuple(CANDIDATE_EFFECTS), np.random.default_rng(0))
    units = {(c.effect, c.target): c.unit for c in pool}
    assert units[("armature", "rail")] == "kg" and units[("armature", "arm")] == "kg m^2"
    assert units[("viscous_friction", "rail")] == "N s/m" and units[("viscous_friction", "arm")] == "N m s/rad"
    assert units[("coulomb_friction", "rail")] == "N" and units[("coulomb_friction", "arm")] == "N m"
    assert units[("joint_stiffness", "rail")] == "N/m"
    assert not any(c.target == "rail" and ("rad" in c.unit or "N m" in c.unit) for c in pool), sorted(
        {(c.effect, c.unit) for c in pool if c.target == "rail"}
    )

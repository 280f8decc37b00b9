"""The plant is what MuJoCo compiles: every MJCF form arm models use gives regressor . theta == mj_inverse.

Small fixtures, one per form: inertia from geoms, `<inertial quat diaginertia>`, `fullinertia`, an inertial
`euler`, joints away from the body origin with tilted axes, several joints in one body (hinge and slide),
default classes and `<include>`, bodies without joints (welded), angles in degrees with a joint `ref`.
Every arm in `../shared/robots/` is checked the same way.
"""

from __future__ import annotations

import copy
from pathlib import Path

import mujoco
import numpy as np
import pytest

from dynamics.errors import ModelError
from dynamics.inertia import from_mass_com_inertia
from dynamics.mjcf import write_inertial
from dynamics.plant import check_against_mujoco, load_plant, own_body_parameters
from dynamics.regressor import ParameterModel
from dynamics.sampling import random_states
from dynamics.torque import inverse_dynamics, joint_torque

ROBOTS = Path(__file__).resolve().parents[1].parent / "shared" / "robots"
ROBOT_FILES = sorted(ROBOTS.glob("*.xml")) if ROBOTS.is_dir() else []

_ARM = """<mujoco model="{name}">
  <compiler angle="{angle}"/>
  {head}
  <worldbody>
    <body name="link1" pos="0 0 0.5" {quat1}>
      {joints1}
      {inertial1}
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
      <body name="link2" pos="0.3 0 0" euler="{euler2}">
        {joints2}
        {inertial2}
        <geom type="capsule" fromto="0 0 0 0 0 -0.25" size="0.025"/>
        <body name="tool" pos="0 0 -0.25">
          <geom type="box" size="0.03 0.02 0.04" pos="0.01 0 -0.02"/>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

_FORMS: dict[str, dict[str, str]] = {
    # MuJoCo's default: no <inertial>, masses and inertias from the geoms
    "geom_inertia": {},
    "diaginertia_quat": {
        "inertial1": '<inertial pos="0.15 0.01 0" quat="0.9 0.1 0.3 0.2" mass="1.2" diaginertia="0.011 0.009 0.004"/>',
        "inertial2": '<inertial pos="0 0.005 -0.12" quat="0.7 0 0.7 0.1" mass="0.8" diaginertia="0.006 0.005 0.002"/>',
    },
    "fullinertia_euler": {
        "inertial1": '<inertial pos="0.15 0 0.01" mass="1.1" fullinertia="0.01 0.012 0.004 0.001 -0.0005 0.0002"/>',
        "inertial2": '<inertial pos="0.01 0 -0.1" euler="0.3 0.2 0.1" mass="0.7" diaginertia="0.005 0.004 0.001"/>',
    },
    "offset_tilted_joints": {
        "joints1": '<joint name="j1" type="hinge" pos="0.02 -0.01 0.03" axis="0.2 0.1 1"/>',
        "joints2": '<joint name="j2" type="hinge" pos="0 0.01 0.05" axis="0 1 0.3" damping="0.05" armature="0.01"/>',
    },
    "several_joints_per_body": {
        "joints1": '<joint name="j1" type="hinge" axis="0 0 1"/><joint name="j1b" type="hinge" pos="0.05 0 0" '
        'axis="0 1 0"/>',
        "joints2": '<joint name="j2" type="slide" axis="1 0 0.2" range="-0.1 0.1"/><joint name="j2b" type="hinge" '
        'pos="0 0 -0.05" axis="1 0 0" stiffness="2" springref="0.2"/>',
    },
    "degrees_and_ref": {
        "angle": "degree",
        "euler2": "20 0 10",
        "joints1": '<joint name="j1" type="hinge" axis="0 0 1" ref="30" range="-90 120"/>',
        "joints2": '<joint name="j2" type="hinge" axis="0 1 0" ref="-15" range="-150 150" stiffness="1" '
        'springref="10"/>',
    },
    "classes_and_include": {
        "head": '<include file="defaults.xml"/>',
        "joints1": '<joint name="j1" class="arm"/>',
        "joints2": '<joint name="j2" class="arm" axis="1 0 0"/>',
    },
}

_DEFAULTS = """<mujoco><default><default class="arm"><joint type="hinge" axis="0 1 0" damping="0.1"
 armature="0.02"/><geom density="2700"/></default></default></mujoco>"""


def _write_form(form: str, tmp_path: Path) -> Path:
    fields = {
        "name": form,
        "angle": "radian",
        "head": "",
        "quat1": 'quat="0.95 0.1 0.2 0.2"',
        "euler2": "0.3 0 0.2",
        "joints1": '<joint name="j1" type="hinge" axis="0 0 1"/>',
        "joints2": '<joint name="j2" type="hinge" axis="0 1 0"/>',
        "inertial1": "",
        "inertial2": "",
        **_FORMS[form],
    }
    (tmp_path / "defaults.xml").write_text(_DEFAULTS)
    path = tmp_path / f"{form}.xml"
    path.write_text(_ARM.format(**fields))
    return path


def _without_constraints(m: mujoco.MjModel) -> mujoco.MjModel:
    m = copy.deepcopy(m)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    return m


def _assert_regressor_is_mujoco(plant, n: int = 60, seed: int = 0, atol: float = 1e-8) -> None:  # type: ignore[no-untyped-def]
    """W theta (rigid body + armature + damping columns) + stiffness == mj_inverse with constraints off."""
    model = ParameterModel(plant, ("armature", "viscous_friction"))
    q, dq, ddq = random_states(plant, np.random.default_rng(seed), n)
    predicted = np.einsum("knp,p->kn", model.regressor(q, dq, ddq), model.truth())
    predicted += plant.stiffness * (q - plant.springref)
    expected = inverse_dynamics(_without_constraints(plant.mj_model), q, dq, ddq)
    scale = 1.0 + np.max(np.abs(expected))
    np.testing.assert_allclose(predicted, expected, rtol=0, atol=atol * scale)


@pytest.mark.parametrize("form", sorted(_FORMS))
def test_every_mjcf_form_gives_mujocos_dynamics(form: str, tmp_path: Path) -> None:
    plant = load_plant(_write_form(form, tmp_path))
    _assert_regressor_is_mujoco(plant)
    m = plant.mj_model
    # the truth is what MuJoCo compiled: the total mass of the moving bodies
    assert plant.theta[0::10].sum() == pytest.approx(m.body_mass[1:].sum(), rel=1e-12)
    assert plant.theta[0::10].sum() > 0.1


def test_geom_inertia_is_not_massless(tmp_path: Path) -> None:
    """Pinocchio's own MJCF parser reads geom-inertia bodies as mass 0; built from the compiled model they are not."""
    plant = load_plant(_write_form("geom_inertia", tmp_path))
    m = plant.mj_model
    np.testing.assert_allclose(plant.theta[[0, 10]], [m.body_mass[1], m.body_mass[2] + m.body_mass[3]], rtol=1e-12)


def test_several_joints_in_one_body_carry_one_inertia(tmp_path: Path) -> None:
    plant = load_plant(_write_form("several_joints_per_body", tmp_path))
    assert plant.nv == 4
    np.testing.assert_array_equal(plant.carries_body, [False, True, False, True])
    assert not np.any(plant.theta[0:10]) and not np.any(plant.theta[20:30])  # earlier joints carry no body
    own = own_body_parameters(plant)
    assert own[10] == pytest.approx(plant.mj_model.body_mass[1])
    assert own[30] == pytest.approx(plant.mj_model.body_mass[2])  # the welded tool belongs to the block, not own
    assert plant.theta[30] == pytest.approx(plant.mj_model.body_mass[2] + plant.mj_model.body_mass[3])


def test_degrees_are_read_as_the_compiler_says(tmp_path: Path) -> None:
    plant = load_plant(_write_form("degrees_and_ref", tmp_path))
    np.testing.assert_allclose(plant.q_range[0], np.deg2rad([-90, 120]))
    np.testing.assert_allclose(plant.springref[1], np.deg2rad(10))


@pytest.mark.skipif(not ROBOT_FILES, reason="../shared/robots/ is not beside the project (clone with shared/)")
@pytest.mark.parametrize("path", ROBOT_FILES, ids=lambda p: p.stem)
def test_every_shared_arm_gives_mujocos_dynamics(path: Path) -> None:
    plant = load_plant(path)
    assert plant.nv >= 6
    _assert_regressor_is_mujoco(plant, n=30)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('damping="0.05"', 'damping="0.05 0.3 0"', r"joint 'j2' has damping=\"0\.05 0\.3 0\", MuJoCo's polynomial"),
        ('damping="0.05"', 'damping="0.05" stiffness="0.2 0 1"', r"joint 'j2' has stiffness=\"0\.2 0 1\", .* give"),
        (
            "</mujoco>",
            '<actuator><motor name="m2" joint="j2" ctrlrange="-1 1" damping="0 0.1"/></actuator></mujoco>',
            r"actuator 'm2' has damping=\"0 0\.1 0\", a polynomial damping on its transmission",
        ),
    ],
)
def test_polynomial_damping_and_stiffness_are_refused_by_name(tmp_path: Path, old: str, new: str, message: str) -> None:
    """MuJoCo 4's higher-order damping and stiffness (b0 v + b1 v|v| + b2 v^3, k0 x + k1 x^2 + k2 x^3) are not in
    the torque model: refused by the load check as 'Pinocchio's inverse dynamics differs from MuJoCo's by 0.401 N m
    at joint ...; the model uses a feature the harness does not reproduce', now by the attribute, with its fix."""
    xml = _write_form("offset_tilted_joints", tmp_path).read_text()
    assert old in xml
    path = tmp_path / "polynomial.xml"
    path.write_text(xml.replace(old, new, 1))
    with pytest.raises(ModelError, match=message):
        load_plant(path)


def test_the_load_check_catches_a_wrong_inertia(tmp_path: Path) -> None:
    plant = load_plant(_write_form("diaginertia_quat", tmp_path))
    plant.pin_model.inertias[2].mass *= 1.01  # the twin drifts from the compiled model
    with pytest.raises(ModelError, match="differs from MuJoCo's"):
        check_against_mujoco(plant, np.random.default_rng(0))


def test_disabled_springs_and_dampers_are_left_out(tmp_path: Path) -> None:
    xml = _write_form("several_joints_per_body", tmp_path).read_text()
    xml = xml.replace(
        '<compiler angle="radian"/>', '<compiler angle="radian"/><option><flag spring="disable"/></option>'
    )
    path = tmp_path / "nospring.xml"
    path.write_text(xml)
    plant = load_plant(path)
    assert not np.any(plant.stiffness)
    q, dq, ddq = random_states(plant, np.random.default_rng(2), 10)
    expected = inverse_dynamics(_without_constraints(plant.mj_model), q, dq, ddq)
    np.testing.assert_allclose(joint_torque(plant, q, dq, ddq, coulomb=False)[0], expected, atol=1e-8)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ('<equality><joint name="couple" joint1="j1" joint2="j2"/></equality>', r"constraint\(s\) 'couple' \(joint\)"),
        (
            '<tendon><fixed name="t"><joint joint="j1" coef="1"/><joint joint="j2" coef="1"/></fixed></tendon>'
            '<actuator><motor name="pull" tendon="t" ctrlrange="-1 1"/></actuator>',
            r"tendon 't' \(over joint\(s\) j1, j2, driven by actuator 'pull'\): tendons are not supported",
        ),
    ],
)
def test_couplings_are_refused_by_name(tmp_path: Path, extra: str, message: str) -> None:
    xml = _write_form("diaginertia_quat", tmp_path).read_text().replace("</mujoco>", extra + "</mujoco>")
    path = tmp_path / "coupled.xml"
    path.write_text(xml)
    with pytest.raises(ModelError, match=message):
        load_plant(path)


def test_an_inactive_equality_applies_no_force_and_is_no_coupling(tmp_path: Path) -> None:
    """MuJoCo applies an equality with active="false" only once a user turns it on; it was refused unnamed."""
    xml = _write_form("diaginertia_quat", tmp_path).read_text()
    extra = '<equality><joint name="couple" joint1="j1" joint2="j2" active="false"/></equality>'
    path = tmp_path / "inactive.xml"
    path.write_text(xml.replace("</mujoco>", extra + "</mujoco>"))
    plant = load_plant(path)
    q, dq, ddq = random_states(plant, np.random.default_rng(3), 10)
    np.testing.assert_allclose(
        joint_torque(plant, q, dq, ddq, coulomb=False)[0], inverse_dynamics(plant.mj_model, q, dq, ddq), atol=1e-8
    )


@pytest.mark.parametrize("flag", ["equality", "constraint"])
def test_a_disabled_equality_flag_applies_no_coupling(tmp_path: Path, flag: str) -> None:
    """<flag equality="disable"/> (or constraint, every constraint): MuJoCo applies no equality; such a model was
    refused as coupled. An unlimited joint's range="-inf inf" is no number the dynamics read either."""
    xml = _write_form("diaginertia_quat", tmp_path).read_text()
    extra = '<equality><joint name="couple" joint1="j1" joint2="j2"/></equality>'
    off = xml.replace("</mujoco>", extra + "</mujoco>").replace(
        '<compiler angle="radian"/>', f'<compiler angle="radian"/><option><flag {flag}="disable"/></option>'
    )
    off = off.replace(
        '<joint name="j1" type="hinge" axis="0 0 1"/>',
        '<joint name="j1" type="hinge" axis="0 0 1" range="-inf inf" limited="false"/>',
    )
    assert 'range="-inf inf"' in off
    path = tmp_path / "off.xml"
    path.write_text(off)
    plant = load_plant(path)
    q, dq, ddq = random_states(plant, np.random.default_rng(3), 10)
    np.testing.assert_allclose(
        joint_torque(plant, q, dq, ddq, coulomb=False)[0], inverse_dynamics(plant.mj_model, q, dq, ddq), atol=1e-8
    )


_MOTORS = '<actuator><motor joint="j1" ctrlrange="-5 5"/><motor joint="j2" ctrlrange="-5 5"/></actuator>'


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            (
                '<joint name="j2" type="hinge" axis="0 1 0"/>',
                '<joint name="j2" type="hinge" axis="0 1 0" armature="nan"/>',
            ),
            r"joint 'j2': its armature is nan, not finite numbers",
        ),
        (
            ('<body name="link2" pos="0.3 0 0"', '<body name="link2" pos="nan 0 0"'),
            r"body 'link2': its pos is nan 0 0, not finite numbers",
        ),
        (
            ('<compiler angle="radian"/>', '<compiler angle="radian"/><option gravity="0 0 nan"/>'),
            r"<option gravity> is 0 0 nan, not finite numbers",
        ),
        (
            ('<compiler angle="radian"/>', '<compiler angle="radian"/><option timestep="0"/>'),
            r'<option timestep="0"> must be > 0',
        ),
        (
            (
                _MOTORS,
                '<actuator><plugin joint="j1" plugin="mujoco.pid" instance="pid"/><motor joint="j2"/></actuator>'
                '<extension><plugin plugin="mujoco.pid"><instance name="pid"><config key="kp" value="200"/></instance>'
                "</plugin></extension>",
            ),
            r"actuator\(s\) \['actuator0'\] are plugins \(<actuator><plugin>\): their force is the plugin's own law",
        ),
    ],
)
def test_a_model_the_dynamics_cannot_read_is_refused_by_element(
    tmp_path: Path, edit: tuple[str, str], message: str
) -> None:
    """A NaN in the model (MuJoCo compiles `armature="nan"`) passed the load check, a NaN difference being no
    difference, and failed later as a diverged simulation or "cannot convert float NaN to integer"; a zero step
    divided by zero; a PID plugin actuator was read as a motor of gain 1, and its run reported wrong numbers."""
    xml = _write_form("diaginertia_quat", tmp_path).read_text().replace("</mujoco>", _MOTORS + "</mujoco>")
    old, new = edit
    assert old in xml
    path = tmp_path / "bad.xml"
    path.write_text(xml.replace(old, new))
    with pytest.raises(ModelError, match=message):
        load_plant(path)


@pytest.mark.parametrize("integrator", ["implicitfast", "RK4"])
def test_the_invdiscrete_flag_leaves_the_inverse_dynamics_continuous(tmp_path: Path, integrator: str) -> None:
    """<flag invdiscrete="enable"/> makes mj_inverse read qacc as a step's discrete acceleration (refused under RK4
    with a FatalError); it changes nothing in forward simulation. The harness's accelerations are continuous: such a
    model was refused by the load check (implicitfast with damping) or crashed (RK4)."""
    xml = _write_form("offset_tilted_joints", tmp_path).read_text().replace("</mujoco>", _MOTORS + "</mujoco>")
    head = f'<compiler angle="radian"/><option integrator="{integrator}"><flag invdiscrete="enable"/></option>'
    path = tmp_path / "inv.xml"
    path.write_text(xml.replace('<compiler angle="radian"/>', head))
    plant = load_plant(path)
    assert plant.mj_model.opt.enableflags & int(mujoco.mjtEnableBit.mjENBL_INVDISCRETE)  # the model's own, kept
    q, dq, ddq = random_states(plant, np.random.default_rng(3), 10)
    np.testing.assert_allclose(
        joint_torque(plant, q, dq, ddq, coulomb=False)[0],
        inverse_dynamics(_without_constraints(plant.mj_model), q, dq, ddq),
        atol=1e-8,
    )


@pytest.mark.parametrize("kind", ["damping", "armature"])
def test_an_actuators_own_damping_or_armature_is_named_with_the_joints_value(tmp_path: Path, kind: str) -> None:
    """MuJoCo 4's actuator damping and armature (gear^2 times it on the joint) were refused as an unnamed
    'feature the harness does not reproduce'."""
    xml = (
        '<mujoco><compiler angle="radian"/><worldbody><body name="l1" pos="0 0 0.4"><joint name="j1" axis="0 1 0" '
        'range="-2 2"/><geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.03"/></body></worldbody>'
        f'<actuator><motor name="m1" joint="j1" gear="3" ctrlrange="-5 5" {kind}="0.02"/></actuator></mujoco>'
    )
    path = tmp_path / f"{kind}.xml"
    path.write_text(xml)
    with pytest.raises(ModelError, match=rf"actuator 'm1' has {kind}=0\.02 .* give its joint {kind}=\"0\.18\" more"):
        load_plant(path)


def test_a_jointinparent_transmission_drives_a_hinge_as_a_joint_one_does(tmp_path: Path) -> None:
    """`jointinparent` differs from `joint` only on ball and free joints; on a hinge it was refused as 'not a
    joint transmission'."""
    xml = (
        '<mujoco><worldbody><body name="l1" pos="0 0 0.4"><joint name="j1" axis="0 1 0" range="-2 2"/>'
        '<geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.03"/></body></worldbody>'
        '<actuator><general {0}="j1" gear="2" ctrlrange="-5 5" ctrllimited="true"/></actuator></mujoco>'
    )
    plants = []
    for kind in ("jointinparent", "joint"):
        path = tmp_path / f"{kind}.xml"
        path.write_text(xml.format(kind))
        plants.append(load_plant(path))
    (a,), (b,) = (p.actuation.actuators for p in plants)
    assert (
        (a.joint, a.gear, a.kind, a.torque_limit)
        == (b.joint, b.gear, b.kind, b.torque_limit)
        == (0, 2.0, "motor", 10.0)
    )


def test_a_model_without_joints_is_refused_and_one_without_actuators_cannot_be_run(tmp_path: Path) -> None:
    from harness.validate import ConfigError, check_driven

    still = tmp_path / "still.xml"
    still.write_text('<mujoco><worldbody><body><geom size=".1"/></body></worldbody></mujoco>')
    with pytest.raises(ModelError, match=r"still\.xml: the model has no joints"):
        load_plant(still)
    loose = tmp_path / "loose.xml"
    loose.write_text(
        '<mujoco><worldbody><body><joint name="j" axis="1 0 0"/><geom size=".1" pos="0 0 .2"/></body>'
        "</worldbody></mujoco>"
    )
    plant = load_plant(loose)  # a passive model is fine for measured data ...
    with pytest.raises(ConfigError, match=r"loose.xml: no joint of loose is driven .*<motor joint='j' "):
        check_driven(plant)  # ... but a simulated run has nothing to excite it with
    loose.write_text(loose.read_text().replace('<joint name="j" ', "<joint "))
    with pytest.raises(ConfigError, match=r"name the first joint \(<joint name='joint0' ...>\) and add <actuator>"):
        check_driven(load_plant(loose))  # the harness's own name for an unnamed joint is no name in the file


def test_joints_whose_data_columns_would_clash_are_refused(tmp_path: Path) -> None:
    """Joints `x` and `cmd_x`: tau_cmd_x is the torque of one and the command of the other; a run wrote the
    header twice and the reader then blamed the file."""
    path = tmp_path / "clash.xml"
    link = '<geom type="capsule" size=".05" fromto="0 0 0 0 0 -.2"/>'
    path.write_text(
        f'<mujoco><worldbody><body><joint name="x" axis="0 1 0"/>{link}<body pos="0 0 -.2">'
        f'<joint name="cmd_x" axis="0 1 0"/>{link}</body></body></worldbody></mujoco>'
    )
    with pytest.raises(ModelError, match=r"clash\.xml: joints 'x' and 'cmd_x' would share the data column 'tau_cmd_x'"):
        load_plant(path)


def test_a_model_path_that_is_no_model_file_says_what_it_is(tmp_path: Path) -> None:
    """A folder or a log given as the model read "unknown system '...'; valid choices: ...": true of the name,
    but the user gave a path."""
    (tmp_path / "robot").mkdir()
    with pytest.raises(ValueError, match=r"model path is a directory, not a file: .*robot \(give the \.xml MJCF"):
        load_plant(tmp_path / "robot")
    log = tmp_path / "run.csv"
    log.write_text("time,q_j\n0,0\n")
    with pytest.raises(ValueError, match=r"run\.csv is neither an MJCF \(\.xml, \.mjcf\) nor a URDF .*suffix '\.csv'"):
        load_plant(log)
    mjcf = tmp_path / "arm.mjcf"  # MuJoCo compiles it as an .xml: it was refused as no model format
    mjcf.write_text(_write_form("diaginertia_quat", tmp_path).read_text())
    assert load_plant(mjcf).joint_names == ("j1", "j2")
    with pytest.raises(ValueError, match=r"unknown system 'tow_link'; valid choices"):
        load_plant("tow_link")


def _forced_geom_inertia(tmp_path: Path) -> Path:
    """The geom-inertia form under `<compiler inertiafromgeom="true">`, with an `<inertial>` on the tool that
    MuJoCo ignores under that setting."""
    path = _write_form("geom_inertia", tmp_path)
    text = path.read_text().replace('<compiler angle="radian"/>', '<compiler angle="radian" inertiafromgeom="true"/>')
    tool = '<body name="tool" pos="0 0 -0.25">'
    path.write_text(text.replace(tool, tool + '<inertial pos="0 0 0" mass="5" diaginertia="1 1 1"/>'))
    return path


def _full_inertia(m: mujoco.MjModel, b: int) -> np.ndarray:
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, m.body_iquat[b])
    return rot.reshape(3, 3) @ np.diag(m.body_inertia[b]) @ rot.reshape(3, 3).T


@pytest.mark.filterwarnings("ignore:compiler attribute 'settotalmass' is deprecated")  # MuJoCo 4 still reads it
@pytest.mark.parametrize("setting", ['inertiafromgeom="true"', 'settotalmass="3"'])
def test_an_inertial_written_under_inertiafromgeom_true_is_the_one_compiled(setting: str, tmp_path: Path) -> None:
    """Under `inertiafromgeom="true"` MuJoCo takes every inertial from the geoms, a written one included: a payload
    found on such a model reached neither the calibrated MJCF nor a hidden plant. Under `settotalmass` it rescales
    every mass, the written one too. `write_inertial` now keeps every other body as it compiled and the written
    one is the one compiled, in memory and through the file."""
    path = _forced_geom_inertia(tmp_path)
    path.write_text(path.read_text().replace('inertiafromgeom="true"', setting))
    spec = mujoco.MjSpec.from_file(str(path))
    before = spec.compile()
    link2, tool = (mujoco.mj_name2id(before, mujoco.mjtObj.mjOBJ_BODY, n) for n in ("link2", "tool"))
    assert before.body_mass[tool] < (1.0 if "inertiafromgeom" in setting else 3.0)  # not the 5 kg written
    added = from_mass_com_inertia(
        float(before.body_mass[link2]) + 0.4, before.body_ipos[link2], _full_inertia(before, link2)
    )
    write_inertial(spec, "link2", added)
    for after in (spec.compile(), mujoco.MjModel.from_xml_string(spec.to_xml())):
        assert after.body_mass[link2] == pytest.approx(before.body_mass[link2] + 0.4, rel=1e-5)
        for b in range(1, before.nbody):
            np.testing.assert_allclose(after.body_ipos[b], before.body_ipos[b], atol=1e-6)
            np.testing.assert_allclose(_full_inertia(after, b), _full_inertia(before, b), atol=1e-6)
            if b != link2:
                assert after.body_mass[b] == pytest.approx(before.body_mass[b], rel=1e-5)


def test_a_payload_on_a_model_whose_inertia_comes_from_its_geoms_reaches_the_calibrated_mjcf(tmp_path: Path) -> None:
    """The two-link arm with `inertiafromgeom="true"` (its links' masses from the geoms): a 0.1 kg payload on
    link 2, hidden by the testbed's own loop, is named and the calibrated MJCF carries it."""
    from identify.diagnose.testbed import Injected, diagnose_case

    text = (Path(__file__).resolve().parents[1] / "mjcf" / "two_link.xml").read_text()
    path = tmp_path / "two_link.xml"
    path.write_text(text.replace('inertiafromgeom="false"', 'inertiafromgeom="true"'))
    _, dg = diagnose_case("two_link", [Injected("payload", "elbow", 0.1)], seed=0, mjcf=path)
    assert dg.verdict == "explained", dg.notes
    first = dg.findings[0]
    assert first.effect == "payload" and abs(first.value - 0.1) <= 3 * first.std, [f.to_dict() for f in dg.findings]
    # a planar arm's link mass alone is not identifiable: its first moment along the link is (the payload spread
    # like the body keeps the centre of mass, so it grows by 0.1 kg times the centre's distance)
    nominal = mujoco.MjModel.from_xml_path(str(path))
    calibrated = mujoco.MjModel.from_xml_string(dg.calibrated_xml)
    link2 = mujoco.mj_name2id(nominal, mujoco.mjtObj.mjOBJ_BODY, "link2")
    moment = [m.body_mass[link2] * m.body_ipos[link2, 2] for m in (nominal, calibrated)]
    assert moment[1] - moment[0] == pytest.approx(0.1 * nominal.body_ipos[link2, 2], rel=0.05)
    rms = [dg.models[k]["torque_rms"]["elbow"] for k in ("nominal", "calibrated")]
    assert rms[1] < 0.3 * rms[0], rms


def test_an_mjcf_named_with_an_upper_case_suffix_is_read_as_mujoco_compiles_it(tmp_path: Path) -> None:
    """`M.XML`: `MjModel.from_xml_path` compiles it, `MjSpec.from_file` refuses it (MuJoCo picks its decoder by a
    lowercase suffix), and every edit of the model (the prior, hidden effects, the calibrated MJCF) reads the
    MjSpec: the run printed its settings and then failed on 'could not find decoder'. Such a file is read from its
    text with its assets found from its folder (a mesh here); one that includes others cannot be, and is refused
    at load with the rename it needs."""
    from dynamics.prior import PriorSpec, perturbed_plant

    (tmp_path / "meshes").mkdir()
    corners = [(x, y, z) for z in (-0.02, 0.02) for y in (-0.02, 0.02) for x in (-0.02, 0.02)]
    faces = ["1 2 4", "1 4 3", "5 7 8", "5 8 6", "1 5 6", "1 6 2", "3 4 8", "3 8 7", "1 3 7", "1 7 5", "2 6 8", "2 8 4"]
    obj = "".join(f"v {x} {y} {z}\n" for x, y, z in corners) + "".join(f"f {f}\n" for f in faces)
    (tmp_path / "meshes" / "cube.obj").write_text(obj)
    xml = """<mujoco model="upper"><compiler meshdir="meshes"/><asset><mesh name="cube" file="cube.obj"/></asset>
      <worldbody><body name="a" pos="0 0 0.5"><joint name="j1" axis="0 1 0" range="-2 2"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" mass="1"/>
        <body name="b" pos="0.3 0 0"><joint name="j2" axis="0 1 0" range="-2 2"/>
          <geom type="mesh" mesh="cube" pos="0.2 0 0" density="5000"/></body></body></worldbody>
      <actuator><motor joint="j1" ctrlrange="-20 20"/><motor joint="j2" ctrlrange="-20 20"/></actuator></mujoco>"""
    path = tmp_path / "M.XML"
    path.write_text(xml)
    plant = load_plant(path)
    assert plant.mj_model.body_mass[2] == pytest.approx(5000 * 0.04**3, rel=1e-6)  # the mesh found and weighed
    prior = perturbed_plant(plant, PriorSpec(), np.random.default_rng(0), path=tmp_path / "prior.xml")
    assert prior.mj_model.nbody == plant.mj_model.nbody
    (tmp_path / "part.xml").write_text("<mujoco><worldbody/></mujoco>")
    path.write_text(xml.replace("<worldbody>", '<include file="part.xml"/><worldbody>', 1))
    with pytest.raises(ModelError, match=r"M\.XML: MuJoCo reads this model's includes only .* rename it to M\.xml"):
        load_plant(path)


_UNNAMED = """<mujoco model="unnamed"><compiler angle="radian"/><worldbody>
  <body name="{body}" pos="0 0 1"><joint name="{joint}" axis="0 1 0" range="-2 2"/>
    <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.03"/>
    <body pos="0 0 -0.3"><joint axis="0 1 0" range="-1.5 1.5" damping="0.1"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.03"/></body></body></worldbody>
  <actuator><motor joint="{joint}" ctrlrange="-10 10"/></actuator></mujoco>"""


def test_an_unnamed_passive_joint_and_body_are_edited_by_the_names_the_harness_gives_them(tmp_path: Path) -> None:
    """A joint with no name cannot be actuated (an actuator names its joint), so it is a passive one: the harness
    calls it joint<i> and its body body<i>, and every edit of the model must find them by those names (the
    calibrated MJCF and a hidden effect looked them up in the MjSpec, where they have none, and failed on None)."""
    from envs.effects import HiddenEffect, apply_effects
    from envs.sensors import SensorModel
    from identify.diagnose.calibrate import Extension, calibrated_xml

    path = tmp_path / "unnamed.xml"
    path.write_text(_UNNAMED.format(body="upper", joint="shoulder"))
    plant = load_plant(path)
    assert plant.joint_names == ("shoulder", "joint1") and plant.body_names == ("upper", "body2")
    zero = np.zeros(2)
    ext = Extension(zero, np.array([0.0, 0.05]), zero, zero, zero, np.zeros(20), zero, zero, np.ones(2), zero)
    ext.theta_delta[10] = 0.2  # 0.2 kg more on the unnamed body
    (tmp_path / "calibrated.xml").write_text(calibrated_xml(plant, ext))
    calibrated = load_plant(tmp_path / "calibrated.xml")
    assert calibrated.damping[1] == pytest.approx(0.15)
    assert calibrated.mj_model.body_mass[2] == pytest.approx(plant.mj_model.body_mass[2] + 0.2, rel=1e-5)
    sensor = SensorModel(500.0, sigma_tau=np.array([0.01, 0.0]), tau_resolution=0.001)
    hidden, _ = apply_effects(plant, [HiddenEffect("armature", "joint1", 0.01)], sensor=sensor, directory=tmp_path)
    assert hidden.armature[1] == pytest.approx(0.01)


@pytest.mark.parametrize(("body", "joint", "taken"), [("upper", "joint1", "joint 1"), ("body2", "shoulder", "body 2")])
def test_an_unnamed_joint_or_body_whose_harness_name_is_taken_is_refused(
    body: str, joint: str, taken: str, tmp_path: Path
) -> None:
    """The harness's name for an unnamed joint (body) is another's: the data columns q_joint1 would be two
    joints' (`sysid-run` wrote a data.csv with the column twice), so the model is refused with the fix."""
    path = tmp_path / "clash.xml"
    path.write_text(_UNNAMED.format(body=body, joint=joint))
    with pytest.raises(ModelError, match=rf"{taken} has no name and the name the harness gives it, .* is another"):
        load_plant(path)

"""Clearance: the smooth distance the optimiser constrains, its gradient, and the open pose starts move about.

Models are built here (two capsule links above the floor, a one-joint friction pendulum) so that the facts
are known in closed form; the shared arms add MuJoCo collision geoms where ../shared/robots/ is present.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import mujoco
import numpy as np
import pytest

from dynamics.plant import load_plant
from dynamics.regressor import ParameterModel
from envs.simulate import _hard_friction
from excitation.designs import default_design, grid, random_design
from excitation.limits import limits_for
from excitation.optimise import _open_pose, position_limit_ratios
from excitation.registry import design_excitation

ROBOTS = Path(__file__).resolve().parents[2] / "shared" / "robots"

# a planar 3-link arm on the floor: link a up from the base, links b and c fold back towards it
_ARM = """
<mujoco model="fold3">
  <compiler angle="radian"/>
  <worldbody>
    <body name="a" pos="0 0 0.1">
      <joint name="j1" axis="0 0 1" range="-3 3"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.4" size="0.03" mass="1"/>
      <body name="b" pos="0 0 0.4">
        <joint name="j2" axis="0 1 0" range="-2.8 2.8"/>
        <geom type="capsule" fromto="0 0 0 0.4 0 0" size="0.03" mass="1"/>
        <body name="c" pos="0.4 0 0">
          <joint name="j3" axis="0 1 0" range="-2.8 2.8"/>
          <geom type="capsule" fromto="0 0 0 0.4 0 0" size="0.03" mass="1"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="j1" ctrlrange="-50 50"/><motor joint="j2" ctrlrange="-50 50"/><motor joint="j3" ctrlrange="-50 50"/>
  </actuator>
</mujoco>
"""


@pytest.fixture
def arm(tmp_path: Path):
    path = tmp_path / "fold3.xml"
    path.write_text(_ARM)
    plant = load_plant(path)
    return plant, limits_for(plant, velocity=1.0, acceleration=5.0, clearance_m=0.02)


def _fd_gradient(clearance, q: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    out = np.zeros_like(q)
    for j in range(q.shape[1]):
        e = np.zeros(q.shape[1])
        e[j] = eps
        out[:, j] = (clearance.smooth_distance(q + e)[0] - clearance.smooth_distance(q - e)[0]) / (2 * eps)
    return out


def _check_smooth_distance(clearance, q: np.ndarray) -> None:
    d, g = clearance.smooth_distance(q)
    hard = np.array([clearance.min_distance(p[None]) for p in q])
    count = len(clearance.pairs) + len(clearance.floor)
    assert np.all(d <= hard + 1e-12)  # a lower bound: a constraint on it is conservative
    # and at most T log(count) below, up to where MuJoCo's distances stop (clearance + 20 T: farther geom pairs
    # count as that far, each weighing under exp(-20) in the soft minimum)
    near = np.minimum(hard, clearance.clearance_m + 20 * 0.005)
    assert np.all(near - d <= 0.005 * np.log(count) + 1e-12)
    fd = _fd_gradient(clearance, q)
    scale = np.maximum(np.abs(fd).max(axis=1, keepdims=True), 1e-3)
    assert np.max(np.abs(g - fd) / scale) < 1e-3


def test_smooth_distance_is_a_tight_lower_bound_with_its_gradient_on_capsules_and_the_floor(arm) -> None:
    plant, limits = arm
    clearance = limits.clearance
    assert clearance.pairs and clearance.floor  # link c against link a, links b and c against the floor
    q = np.random.default_rng(0).uniform(limits.q_min, limits.q_max, size=(40, plant.nv))
    _check_smooth_distance(clearance, q)
    # folded down to the floor: link c's tip at z = 0.5 - 0.4 = 0.1 m less its radius, nothing nearer
    d, _ = clearance.smooth_distance(np.array([[0.0, 0.0, np.pi / 2]]))
    assert d[0] == pytest.approx(0.1 - 0.03, abs=0.005 * np.log(len(clearance.pairs) + len(clearance.floor)))


@pytest.mark.skipif(not (ROBOTS / "ur5e.xml").is_file(), reason="../shared/robots/ is not beside the project")
def test_smooth_distance_gradient_through_mujoco_collision_geoms() -> None:
    plant = load_plant(ROBOTS / "ur5e.xml")
    limits = limits_for(plant, velocity=1.5, acceleration=8.0, clearance_m=0.02)
    assert any(
        min(limits.clearance.shapes[i].geom, limits.clearance.shapes[j].geom) >= 0 for i, j in limits.clearance.pairs
    )
    q = np.random.default_rng(1).uniform(limits.q_min, limits.q_max, size=(30, plant.nv))
    _check_smooth_distance(limits.clearance, q)


def test_open_pose_moves_a_stretched_arm_away_from_the_floor(arm) -> None:
    _, limits = arm
    stretched = np.array([0.0, 1.45, 0.0])  # links b and c pointing down-out, tip 2.5 cm above the floor
    before = limits.clearance.min_distance(stretched[None])
    opened = _open_pose(limits.clearance, limits, stretched)
    assert np.all(opened >= limits.q_min) and np.all(opened <= limits.q_max)
    assert limits.clearance.min_distance(opened[None]) > before + 0.1


_PENDULUM = """
<mujoco model="light_wrist">
  <worldbody>
    <body>
      <joint name="j" axis="0 0 1" frictionloss="0.5"/>
      <geom type="sphere" size="0.02" pos="0.05 0 0" mass="0.2" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
</mujoco>
"""


def test_hard_friction_holds_a_joint_driven_at_its_friction_in_steady_sliding_where_the_default_gives() -> None:
    """Driven by exactly Fc at speed v, Coulomb friction balances the drive (no acceleration). MuJoCo's default
    soft constraint gives way on a light joint (its friction stays under Fc below v* ~ 1 rad/s here); the
    hard setting holds it."""
    m = mujoco.MjModel.from_xml_path(str(_write(_PENDULUM)))
    d = mujoco.MjData(m)
    fc = 0.5

    def friction_at(model: mujoco.MjModel, speed: float) -> float:
        d.qpos[:], d.qvel[:] = 0.0, speed
        d.qfrc_applied[:] = fc * np.sign(speed)
        mujoco.mj_forward(model, d)
        return float(d.qfrc_constraint[0])

    speed = 0.05  # rad/s, a slow stretch of a light (5e-4 kg m^2) joint
    assert abs(friction_at(m, speed)) < 0.95 * fc  # the default soft constraint gives way
    hard = _hard_friction(m)
    assert friction_at(hard, speed) == pytest.approx(-fc, rel=1e-3)  # Coulomb: -Fc sign(v)
    assert friction_at(hard, -speed) == pytest.approx(fc, rel=1e-3)


def _write(text: str) -> Path:
    path = Path(tempfile.mkdtemp()) / "model.xml"
    path.write_text(text)
    return path


def _kept_clear(name: str, plant, limits, model: ParameterModel, t: np.ndarray):  # type: ignore[no-untyped-def]
    """The design `name` as the registry makes it, asserted 2 cm clear along the grid t."""
    safe = design_excitation(
        name,
        plant,
        limits,
        model=model,
        harmonics=3,
        base_freq_hz=0.1,
        torque_driven=False,
        rng=np.random.default_rng(3),
    )
    assert limits.clearance.min_distance(safe.evaluate(t)[0]) >= 0.02
    return safe


def test_random_and_default_designs_keep_the_clearance_that_their_plain_scaling_breaks(arm) -> None:
    plant, _ = arm
    limits = limits_for(plant, velocity=3.0, acceleration=10.0, clearance_m=0.02)  # swings that fold the arm
    model = ParameterModel(plant)
    t = grid(default_design(plant, limits, harmonics=3, base_freq_hz=0.1), 4000)
    for name in ("random", "default"):
        plain = (random_design if name == "random" else default_design)(
            plant,
            limits,
            harmonics=3,
            base_freq_hz=0.1,
            **({"rng": np.random.default_rng(3)} if name == "random" else {}),
        )
        assert limits.clearance.min_distance(plain.evaluate(t)[0]) < 0.02  # scaled to q, dq, ddq, tau only
        safe = _kept_clear(name, plant, limits, model, t)
        assert max(position_limit_ratios(plant, safe, limits, t).values()) <= 1.0


def test_an_obstacle_fixed_to_the_world_is_kept_clear_of(tmp_path: Path) -> None:
    """A box fixed to the world under link c's sweep: the clearance used to check the floor plane alone, so a
    design could fold the arm onto the box and the run stopped after simulating, on the contact. The box is now a
    shape of its own against the moving collision geoms (its distance and gradient through `mj_geomDistance`)."""
    box = '<geom name="box" type="box" pos="0.6 0 0.3" size="0.05 0.05 0.05"/>'
    path = tmp_path / "fold3_box.xml"
    path.write_text(_ARM.replace("<worldbody>", f"<worldbody>{box}"))
    plant = load_plant(path)
    limits = limits_for(plant, velocity=3.0, acceleration=10.0, clearance_m=0.02)
    clearance = limits.clearance
    fixed = [k for k, s in enumerate(clearance.shapes) if s.fixed]
    assert len(fixed) == 1 and any(fixed[0] in pair for pair in clearance.pairs)
    assert fixed[0] not in {k for k, _ in clearance.floor}
    # link c tilted down 0.5 rad: its underside at x = 0.6 is z = 0.5 - 0.2 tan 0.5 - 0.03 = 0.361, 0.011 m above
    # the box's top (0.35) at its corner nearest the joint (x = 0.55: 0.5 - 0.15 tan 0.5 - 0.03 / cos 0.5 = 0.384)
    down = np.array([[0.0, 0.0, 0.5]])
    assert clearance.min_distance(down) < 0.03  # the floor is 0.07 m from link a, nothing else as near
    data = mujoco.MjData(plant.mj_model)
    data.qpos[:] = down[0]
    mujoco.mj_kinematics(plant.mj_model, data)
    c = mujoco.mj_name2id(plant.mj_model, mujoco.mjtObj.mjOBJ_BODY, "c")
    geom_c = int(np.flatnonzero(plant.mj_model.geom_bodyid == c)[0])
    exact = mujoco.mj_geomDistance(plant.mj_model, data, clearance.shapes[fixed[0]].geom, geom_c, 1.0, None)
    assert clearance.min_distance(down) == pytest.approx(exact)
    q = np.random.default_rng(2).uniform(limits.q_min, limits.q_max, size=(40, plant.nv))
    _check_smooth_distance(clearance, q)
    plain = default_design(plant, limits, harmonics=3, base_freq_hz=0.1)
    t = grid(plain, 4000)
    assert limits.clearance.min_distance(plain.evaluate(t)[0]) < 0.02
    _kept_clear("default", plant, limits, ParameterModel(plant), t)


@pytest.mark.parametrize("height", [0.3, -0.5])
def test_the_models_own_floor_plane_is_the_floor(tmp_path: Path, height: float) -> None:
    """The floor was the world plane z = 0 whatever the model said: a table-top plane at z = 0.3 under the folding
    arm was left out (planes were no obstacles), the design drove link c through it and the run was refused on the
    contact, with a larger clearance as the advice, which did not help; an arm on a stand above a floor at z = -0.5
    was held off an imaginary floor at z = 0. The model's collision planes fixed to the world are now its floors."""
    table = f'<geom name="table" type="plane" size="1 1 0.1" pos="0 0 {height}"/>'
    path = tmp_path / "fold3_table.xml"
    path.write_text(_ARM.replace("<worldbody>", f"<worldbody>{table}"))
    plant = load_plant(path)
    limits = limits_for(plant, velocity=3.0, acceleration=10.0, clearance_m=0.02)
    clearance = limits.clearance
    assert len(clearance.planes) == 1 and clearance.planes[0].point[2] == pytest.approx(height)
    # link c tilted down 0.5 rad: its tip (x = 0.4 + 0.4 cos 0.5, z = 0.5 - 0.4 sin 0.5) less the radius, above
    # the plane; link a stands through a table at 0.3 and is not checked against it (closer at every reference pose)
    down = np.array([[0.0, 0.0, 0.5]])
    tip = 0.5 - 0.4 * np.sin(0.5) - 0.03 - height
    c = mujoco.mj_name2id(plant.mj_model, mujoco.mjtObj.mjOBJ_BODY, "c")
    checks = [k for k, (i, _) in enumerate(clearance.floor) if clearance.shapes[i].body == c]
    assert len(checks) == 1 and clearance._distances(down)[1][0, checks[0]] == pytest.approx(tip, abs=1e-9)
    assert (height > 0) == (clearance.min_distance(down) < 0.02)  # through the table: clear of a floor below
    q = np.random.default_rng(2).uniform(limits.q_min, limits.q_max, size=(40, plant.nv))
    _check_smooth_distance(clearance, q)
    if height > 0:
        t = grid(default_design(plant, limits, harmonics=3, base_freq_hz=0.1), 4000)
        _kept_clear("default", plant, limits, ParameterModel(plant), t)
    tilted = _ARM.replace("<worldbody>", '<worldbody><geom type="plane" size="1 1 0.1" pos="0.9 0 0" zaxis="-1 0 0"/>')
    wall = load_plant(_write(tilted))
    clearance = limits_for(wall, velocity=3.0, acceleration=10.0, clearance_m=0.02).clearance
    np.testing.assert_allclose(clearance.planes[0].normal, [-1.0, 0.0, 0.0], atol=1e-12)
    stretched = np.array([[0.0, 0.0, 0.0]])  # link c's tip at x = 0.8 + 0.03, before a wall at x = 0.9
    assert clearance.min_distance(stretched) == pytest.approx(0.9 - 0.8 - 0.03, abs=1e-9)
    _check_smooth_distance(clearance, q)  # the analytic gradient along a wall's normal


@pytest.mark.parametrize("case", ["masked", "paired", "excluded"])
def test_a_floor_plane_follows_mujocos_contact_filter(tmp_path: Path, case: str) -> None:
    """A model's plane is a floor for the shapes MuJoCo would collide with it: not where the bitmasks never meet,
    against its paired geom alone where it collides through a `<pair>` only, not for a body an `<exclude>` pairs
    with the world. Every moving shape had been kept above every plane, so a table MuJoCo never touches blocked
    designs (a review)."""
    text = _ARM.replace(
        '<geom type="capsule" fromto="0 0 0 0.4 0 0" size="0.03" mass="1"/>\n        </body>',
        '<geom name="gc" type="capsule" fromto="0 0 0 0.4 0 0" size="0.03" mass="1"/>\n        </body>',
    )
    bits = {"masked": 'contype="2" conaffinity="2"', "paired": 'contype="0" conaffinity="0"', "excluded": ""}[case]
    text = text.replace("<worldbody>", f'<worldbody><geom name="table" type="plane" size="1 1 .1" {bits}/>')
    contact = {"paired": '<pair geom1="table" geom2="gc"/>', "excluded": '<exclude body1="world" body2="c"/>'}
    if case in contact:
        text = text.replace("<actuator>", f"<contact>{contact[case]}</contact><actuator>")
    path = tmp_path / "fold3_plane.xml"
    path.write_text(text)
    plant = load_plant(path)
    clearance = limits_for(plant, velocity=3.0, acceleration=10.0, clearance_m=0.02).clearance
    m = plant.mj_model
    above = {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, clearance.shapes[k].body) for k, _ in clearance.floor}
    assert above == {"masked": set(), "paired": {"c"}, "excluded": {"a", "b"}}[case], above


@pytest.mark.parametrize("mount", ["world", "pedestal"])
def test_an_obstacle_on_the_body_a_link_hangs_from_is_checked(tmp_path: Path, mount: str) -> None:
    """A link and its parent body are built to touch and are not checked, but MuJoCo does check a link against
    geoms of the world or of the static body it hangs from (its filter needs both bodies welded to the world). A
    box in the world under a pendulum hung from the world, or a wall on the pedestal the pendulum hangs from, was
    left out as the link's parent: no pair, and MuJoCo reported the contact. The base built to touch the link drops
    out at the reference poses instead."""
    rod = (
        '<body name="arm" pos="0 0 0.5"><joint name="j0" axis="0 1 0" range="-2 2"/>'
        '<geom name="rod" type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02" mass="1"/></body>'
    )
    obstacle = '<geom name="wall" type="box" pos="0.25 0 0.2" size="0.05 0.05 0.05"/>'
    base = '<geom name="base" type="cylinder" pos="0 0 0.5" size="0.04 0.02"/>'
    if mount == "world":
        world = f"{obstacle}{base}{rod}"
    else:
        world = f'<body name="pedestal">{obstacle}{base}{rod}</body>'
    xml = (
        f'<mujoco model="hang"><compiler angle="radian"/><worldbody>{world}</worldbody>'
        '<actuator><motor joint="j0" ctrlrange="-20 20"/></actuator></mujoco>'
    )
    path = tmp_path / "hang.xml"
    path.write_text(xml)
    plant = load_plant(path)
    clearance = limits_for(plant, velocity=1.0, acceleration=5.0, clearance_m=0.02).clearance
    m = plant.mj_model
    geom = {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, s.geom): k for k, s in enumerate(clearance.shapes)}
    pairs = {frozenset((clearance.shapes[i].geom, clearance.shapes[j].geom)) for i, j in clearance.pairs}
    names = {frozenset(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) for g in p) for p in pairs}
    assert names == {frozenset({"rod", "wall"})}, names  # the base touches the rod at every pose: left out
    assert "base" in geom
    swung = np.array([[-0.9]])  # the rod's tip towards the wall
    data = mujoco.MjData(m)
    data.qpos[:] = swung[0]
    mujoco.mj_kinematics(m, data)
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n) for n in ("wall", "rod")]
    exact = mujoco.mj_geomDistance(m, data, ids[0], ids[1], 1.0, None)
    pair_d, _ = clearance._distances(swung)
    assert exact < 0.05 and pair_d[0, 0] == pytest.approx(exact)
    assert clearance.min_distance(swung) == pytest.approx(exact)  # the wall is the nearest (the floor: 0.29 m)


def _named_pairs(path: Path) -> tuple[set[frozenset[str]], set[str]]:
    """(the clearance's pairs as sets of geom names, the names of its geom shapes) for the model at `path`."""
    plant = load_plant(path)
    clearance = limits_for(plant, velocity=1.0, acceleration=5.0, clearance_m=0.02).clearance
    m = plant.mj_model

    def name(k: int) -> str:
        return str(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, clearance.shapes[k].geom))

    named = {frozenset(name(k) for k in pair) for pair in clearance.pairs}
    return named, {name(k) for k, s in enumerate(clearance.shapes) if s.geom >= 0}


@pytest.mark.parametrize("filterparent", [True, False])
def test_links_joined_through_a_jointless_body_are_adjacent_as_mujoco_reads_them(
    tmp_path: Path, filterparent: bool
) -> None:
    """MuJoCo's contact filter reads a link's parent through any jointless (welded) bodies between: link a, a
    flange body welded to it, link c on the flange are parent and child, and never collide. The clearance checked
    a against c (bodies two apart), which MuJoCo does not, unless the model disables the parent filter."""
    flag = "" if filterparent else '<option><flag filterparent="disable"/></option>'
    xml = f"""<mujoco model="flange">{flag}<compiler angle="radian"/><worldbody>
      <body name="a" pos="0 0 0.5"><joint name="j0" axis="0 1 0" range="-2 2"/>
        <geom name="ga" type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" mass="1"/>
        <body name="flange" pos="0.3 0 0">
          <geom name="gf" type="cylinder" size="0.01 0.005" contype="0" conaffinity="0" mass="0.1"/>
          <body name="c" pos="0.02 0 0"><joint name="j1" axis="0 1 0" range="-2.5 2.5"/>
            <geom name="gc" type="capsule" fromto="0.05 0 0 0.3 0 0" size="0.02" mass="1"/></body></body></body>
    </worldbody><actuator><motor joint="j0" ctrlrange="-20 20"/><motor joint="j1" ctrlrange="-20 20"/></actuator>
    </mujoco>"""
    path = tmp_path / "flange.xml"
    path.write_text(xml)
    named, _ = _named_pairs(path)
    assert named == (set() if filterparent else {frozenset({"ga", "gc"})}), named


@pytest.mark.parametrize("case", ["default", "masked", "masked_but_paired", "paired_without_bitmasks"])
def test_pairs_follow_mujocos_contype_conaffinity_filter_and_explicit_pairs(tmp_path: Path, case: str) -> None:
    """Links a and c of the folding arm are the one pair it has. Geoms whose contype / conaffinity bitmasks never
    meet are never brought into contact by MuJoCo, so a design need not keep them apart (they were checked,
    which could make a motion the robot can do look infeasible); a `<contact><pair>` is checked whatever the
    bitmasks say, even between geoms with none (such geoms were not shapes at all)."""
    text = _ARM
    names = ('fromto="0 0 0 0 0 0.4"', 'fromto="0 0 0 0.4 0 0" size="0.03" mass="1"/>\n        <body name="c"')
    text = text.replace(names[0], f'name="ga" {names[0]}').replace(names[1], f'name="gb" {names[1]}')
    text = text.replace(
        '<geom type="capsule" fromto="0 0 0 0.4 0 0" size="0.03" mass="1"/>\n        </body>',
        '<geom name="gc" type="capsule" fromto="0 0 0 0.4 0 0" size="0.03" mass="1"/>\n        </body>',
    )
    if case in ("masked", "masked_but_paired"):
        text = text.replace('name="gc"', 'name="gc" contype="2" conaffinity="2"')
    if case == "paired_without_bitmasks":
        text = text.replace('name="gc"', 'name="gc" contype="0" conaffinity="0"')
    if case in ("masked_but_paired", "paired_without_bitmasks"):
        text = text.replace("<actuator>", '<contact><pair geom1="ga" geom2="gc"/></contact><actuator>')
    path = tmp_path / "fold3_masks.xml"
    path.write_text(text)
    named, shapes = _named_pairs(path)
    assert named == (set() if case == "masked" else {frozenset({"ga", "gc"})}), named
    assert "gc" in shapes

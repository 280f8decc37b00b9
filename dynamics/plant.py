"""A plant: one model as MuJoCo compiles it, the same model in Pinocchio (regressor), and the truth read from it.

The Pinocchio model is built from the compiled `MjModel`, never from a second reading of the user's file:
body frames, joint anchors and axes, joint `ref`, and body inertias exactly as MuJoCo computed them (from
geoms or from an explicit `<inertial>` in any form). At load, Pinocchio's inverse dynamics is checked
against MuJoCo's at random states; a model on which they disagree is refused.

Kinematics follow MuJoCo's `mj_kinematics`: the joints of a body act one after another in the body's own
(already moved) frame, a hinge about its anchor `jnt_pos`, a slide along its axis, each by `qpos - qpos0`.
A joint's Pinocchio frame sits at its anchor with the body's orientation, turned by `-ref` about the axis,
so Pinocchio's q equals MuJoCo's qpos. Bodies without joints are welded to the joint that moves their
parent; each Pinocchio joint carries the inertia of every body it moves rigidly.
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

from dynamics.actuators import Actuation, actuation_of
from dynamics.errors import ModelError, one_line
from dynamics.friction import applied_friction_parameters, friction_enabled, friction_parameters
from dynamics.inertia import from_mass_com_inertia, transform_parameters
from dynamics.sampling import random_states
from dynamics.stepping import Stepping
from dynamics.urdf import URDF_SUFFIXES, is_urdf, urdf_as_mjcf_file

__all__ = [
    "INERTIAL_SYMBOLS",
    "MJCF_DIR",
    "SYSTEMS",
    "Plant",
    "as_simulated",
    "body_parameters",
    "check_against_mujoco",
    "load_plant",
    "load_spec",
    "mjcf_path",
    "movable_xml",
    "own_body_parameters",
    "pinocchio_from_mujoco",
    "plant_from_model",
    "plant_from_xml",
    "with_applied_friction",
]

MJCF_DIR = Path(__file__).resolve().parent.parent / "mjcf"
SYSTEMS = ("arm3", "pendulum", "two_link", "wheel_pendulum")

# Pinocchio's order of the 10 standard parameters of a body, expressed at the joint frame's origin.
INERTIAL_SYMBOLS = ("m", "MX", "MY", "MZ", "XX", "XY", "YY", "XZ", "YZ", "ZZ")

# relative agreement required between Pinocchio's and MuJoCo's inverse dynamics at load
_CHECK_RTOL = 1e-7


def mjcf_path(system: str) -> Path:
    """Path of a built-in system's MJCF, or of a user's model file (MJCF `.xml` or `.urdf`) given by path.

    Raises:
        ValueError: unknown system name (the message lists the valid ones) or missing file.
    """
    candidate = Path(system)
    if candidate.suffix.lower() in (".xml", ".mjcf", *URDF_SUFFIXES):  # MuJoCo compiles an .mjcf as it does .xml
        if candidate.is_dir():
            raise ValueError(f"model path is a directory, not a file: {candidate}")
        if not candidate.is_file():
            raise ValueError(f"model file not found: {candidate}")
        return candidate
    if system not in SYSTEMS:
        if candidate.is_dir():
            raise ValueError(f"model path is a directory, not a file: {candidate} (give the .xml MJCF or .urdf in it)")
        if candidate.is_file():
            raise ValueError(
                f"model file {candidate} is neither an MJCF (.xml, .mjcf) nor a URDF (.urdf): its suffix "
                f"{candidate.suffix or '(none)'!r} names no model format (a log goes to sysid-diagnose data.path=...)"
            )
        raise ValueError(
            f"unknown system {system!r}; valid choices: {', '.join(SYSTEMS)} (or a path to an .xml MJCF or a .urdf)"
        )
    return MJCF_DIR / f"{system}.xml"


@dataclass(frozen=True, eq=False)
class Plant:
    """One compiled MuJoCo model and its Pinocchio twin, with the quantities the harness reads from it.

    Attributes:
        name: system name (the MJCF's file stem).
        path: the MJCF file.
        mj_model: MuJoCo model (simulation, inverse dynamics).
        pin_model: Pinocchio model built from `mj_model` (regressor), one joint per MuJoCo dof.
        joint_names: (nv,) names of the 1-DoF joints, in generalised-coordinate order.
        body_names: (nv,) name of the body each joint moves.
        carries_body: (nv,) True where the joint is its body's last joint, so its inertia block holds that
            body (and the bodies welded to it); an earlier joint of a multi-joint body carries no inertia.
        joint_from_body: (nv, 4, 4) pose of the moved body's frame in the joint's frame (homogeneous).
        actuated: (nv,) True where an actuator drives the joint.
        gear: (nv,) actuator transmission (joint torque = gear * actuator force); 0 where unactuated.
        q_range: (nv, 2) joint range [rad or m]; +-inf where the joint is unlimited.
        tau_limit: (nv,) largest joint torque the actuator can apply [N m] (from its force range; a motor's
            ctrl range too); inf where nothing limits it, 0 where unactuated.
        actuation: the actuators by kind (motors, servos), how they are driven and limited.
        theta: (10 nv,) true standard inertial parameters, 10 per joint in `INERTIAL_SYMBOLS` order,
            about the joint frame's origin [kg, kg m, kg m^2].
        armature, damping, frictionloss, stiffness, springref: (nv,) joint properties of the model
            [kg m^2, N m s/rad, N m, N m/rad, rad].
        friction_speed, friction_lead: (nv,) ramp width [rad/s] and lead [s] of each joint's frictionloss
            (`dynamics.friction.friction_parameters`: 0 where the friction is taken as ideal Coulomb;
            `with_applied_friction`: the ramp MuJoCo applies, whatever the solver parameters).
        source: the file the user gave where it is not `path` itself (a URDF, compiled to the MJCF `path`).
        stepping: how MuJoCo's own step shows in a log of its simulation (`dynamics.stepping.as_stepped`): an
            inertia on each joint's torque and the velocity its friction ramps see; None as loaded.
    """

    name: str
    path: Path
    mj_model: mujoco.MjModel
    pin_model: pin.Model
    joint_names: tuple[str, ...]
    body_names: tuple[str, ...]
    carries_body: np.ndarray
    joint_from_body: np.ndarray
    actuated: np.ndarray
    gear: np.ndarray
    q_range: np.ndarray
    tau_limit: np.ndarray
    actuation: Actuation
    theta: np.ndarray
    armature: np.ndarray
    damping: np.ndarray
    frictionloss: np.ndarray
    stiffness: np.ndarray
    springref: np.ndarray
    friction_speed: np.ndarray
    friction_lead: np.ndarray
    source: Path | None = None
    stepping: Stepping | None = None

    @property
    def nv(self) -> int:
        return len(self.joint_names)

    @property
    def hinge(self) -> np.ndarray:
        """(nv,) True for hinge joints (positions in rad), False for slides (m)."""
        m = self.mj_model
        return np.asarray(m.jnt_type[m.dof_jntid] == int(mujoco.mjtJoint.mjJNT_HINGE))

    @property
    def limit_margin(self) -> np.ndarray:
        """(nv,) each limited joint's `margin` (>= 0; 0 on an unlimited joint): MuJoCo's limit force acts that far
        inside each end of its range (hinges and slides only, so joint j is dof j)."""
        limited = np.isfinite(self.q_range).all(axis=1)
        return np.where(limited, np.maximum(self.mj_model.jnt_margin, 0.0), 0.0)  # type: ignore[no-any-return]

    @property
    def torque_units(self) -> tuple[str, ...]:
        """(nv,) the unit of each joint's torque: N m on a hinge, N on a slide."""
        return tuple("N m" if h else "N" for h in self.hinge)

    @property
    def position_units(self) -> tuple[str, ...]:
        """(nv,) the unit of each joint's position: rad on a hinge, m on a slide."""
        return tuple("rad" if h else "m" for h in self.hinge)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of `theta`: symbol and 1-based joint index, e.g. `ZZ1`, `m2`."""
        return tuple(f"{s}{j + 1}" for j in range(self.nv) for s in INERTIAL_SYMBOLS)


def load_spec(path: Path) -> mujoco.MjSpec:
    """The MjSpec of an MJCF file. MuJoCo's file reader picks its decoder by the suffix and knows only a lowercase
    `.xml` (`MjModel.from_xml_path` compiles `M.XML`, `MjSpec.from_file` refuses it): a file named otherwise is
    parsed from its text, its assets (meshes, textures) found from its own folder as MuJoCo would.

    Raises:
        ModelError: such a file `<include>`s others (parsed from its text, MuJoCo cannot find them): the message
            asks for the lowercase suffix.
    """
    if path.suffix == ".xml":
        return _named(mujoco.MjSpec.from_file(str(path)))
    try:
        spec = mujoco.MjSpec.from_string(path.read_text())
    except ValueError as err:
        raise ModelError(
            f"{path}: MuJoCo reads this model's includes only from a file named with a lowercase .xml suffix "
            f"({one_line(err)}); rename it to {path.stem}.xml"
        ) from err
    spec.modelfiledir = str(path.parent)
    return _named(spec)


def _named(spec: mujoco.MjSpec) -> mujoco.MjSpec:
    """`spec` with every unnamed joint and body given the name the harness calls it by (`_name`: `joint<i>`,
    `body<i>` by its index in the compiled model), so that an edit finds it (`spec.joint(name)`); `load_plant`
    has refused a model where such a name is another's."""
    if all(e.name for e in (*spec.joints, *spec.bodies)):
        return spec
    spec.compile()
    for kind, elements in (("joint", spec.joints), ("body", spec.bodies)):
        for e in elements:
            if not e.name:
                e.name = f"{kind}{e.id}"
    return spec


def movable_xml(spec: mujoco.MjSpec, source: Path) -> str:
    """The MJCF text of `spec`, an edit of the model read from `source`, that compiles from any folder.

    MuJoCo finds a model's mesh, height-field and texture files from the file's own folder (its `meshdir` and
    `texturedir` relative to it): the edited text, written elsewhere (the calibrated MJCF in a run folder, a
    variant with hidden effects in a scratch folder), would name files that are not there. Those folders are
    written out absolute, the model's own folder where it sets none; `<include>`s are already inlined in the
    spec. `spec` is changed so.
    """
    assets = [*spec.meshes, *spec.hfields, *spec.skins, *spec.textures]
    if any(getattr(a, "file", "") for a in assets):  # a model of none keeps its text free of this machine's paths
        base = source.resolve().parent
        spec.meshdir = str(base / spec.meshdir)  # an absolute meshdir stays as it is
        spec.texturedir = str(base / spec.texturedir)
    return spec.to_xml()  # type: ignore[no-any-return]


def load_plant(system: str | Path) -> Plant:
    """Load a built-in system by name (see `SYSTEMS`), or any MJCF or URDF of hinge and slide joints by path.

    Raises:
        ValueError: unknown system name or missing file.
        ModelError: MuJoCo cannot compile it, it has joints or couplings the harness does not support, or
            MuJoCo and Pinocchio disagree on its dynamics.
    """
    source = mjcf_path(str(system))
    path = urdf_as_mjcf_file(source) if is_urdf(source) else source
    try:
        mj_model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as err:
        raise ModelError(f"{source}: MuJoCo cannot load it: {one_line(err)}") from err
    if path.suffix != ".xml":
        load_spec(path)  # every later edit of the model reads its MjSpec: refuse here what it cannot read
    try:
        plant = plant_from_model(path, mj_model)
    except ModelError as err:  # a URDF's errors name the URDF, not the MJCF converted from it in a cache folder
        if source == path:
            raise
        raise ModelError(str(err).replace(str(path), str(source))) from None
    return dataclasses.replace(plant, name=source.stem, source=source) if source != path else plant


def with_applied_friction(plant: Plant) -> Plant:
    """`plant` with every joint's frictionloss read as the ramp MuJoCo applies for its solver parameters
    (`dynamics.friction.applied_friction_parameters`), MuJoCo's defaults included, not as the ideal Coulomb
    term a frictionloss at other than a declared ramp stands for in the identification: the model as MuJoCo
    simulates it (on the Menagerie xArm7's last joint, frictionloss 1 N m at the default parameters is a ramp
    7.7 rad/s wide)."""
    speed, lead = applied_friction_parameters(plant.mj_model)
    on = np.asarray(plant.frictionloss) > 0  # zero where the model's <option><flag> disables dry friction
    return dataclasses.replace(plant, friction_speed=np.where(on, speed, 0.0), friction_lead=np.where(on, lead, 0.0))


def as_simulated(plant: Plant, hard_friction: bool = False) -> Plant:
    """`plant` with its friction read as the logs' simulator applied it: as MuJoCo does (`with_applied_friction`),
    or, with `hard_friction`, as the Coulomb friction `sysid-run` simulates (`system.hard_friction`): the plant as
    loaded, which reads a frictionloss at other than a declared ramp as the ideal Coulomb term."""
    return plant if hard_friction else with_applied_friction(plant)


def plant_from_xml(xml: str, name: str, directory: Path) -> Plant:
    """Build a plant from MJCF text (a calibrated or effect-laden variant), written under `directory`."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{name}.xml"
    path.write_text(xml)
    return load_plant(path)


def _name(m: mujoco.MjModel, kind: mujoco.mjtObj, i: int) -> str:
    return mujoco.mj_id2name(m, kind, i) or f"{kind.name.removeprefix('mjOBJ_').lower()}{i}"


def _tendons(m: mujoco.MjModel) -> str:
    """Each tendon by name, with the joints it spans (a fixed tendon) and the actuator that drives it."""
    out = []
    for t in range(m.ntendon):
        wraps = range(int(m.tendon_adr[t]), int(m.tendon_adr[t] + m.tendon_num[t]))
        joints = [
            _name(m, mujoco.mjtObj.mjOBJ_JOINT, int(m.wrap_objid[w]))
            for w in wraps
            if m.wrap_type[w] == mujoco.mjtWrap.mjWRAP_JOINT
        ]
        drivers = [
            _name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a)
            for a in range(m.nu)
            if m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_TENDON and m.actuator_trnid[a, 0] == t
        ]
        what = f"over joint(s) {', '.join(joints)}" if joints else "spatial"
        out.append(
            f"{_name(m, mujoco.mjtObj.mjOBJ_TENDON, t)!r} ({what}"
            + (f", driven by actuator {', '.join(repr(d) for d in drivers)})" if drivers else ")")
        )
    return f"tendon{'s' if len(out) > 1 else ''} {', '.join(out)}"


def _springs_and_dampers_on(m: mujoco.MjModel) -> tuple[bool, bool]:
    """Whether MuJoCo applies joint springs and dampers: an <option><flag> may disable either."""
    off = int(m.opt.disableflags)
    return not off & int(mujoco.mjtDisableBit.mjDSBL_SPRING), not off & int(mujoco.mjtDisableBit.mjDSBL_DAMPER)


def _check_polynomials(path: Path, m: mujoco.MjModel) -> None:
    """Refuse MuJoCo 4's higher-order joint damping and stiffness (`damping="b0 b1 b2"`: b0 v + b1 v|v| + b2 v^3;
    `stiffness="k0 k1 k2"`: k0 x + k1 x^2 + k2 x^3 about springref; an actuator's `damping` likewise): the harness
    models both as linear, so it would identify and report a model MuJoCo does not simulate. Named with the fix."""
    spring_on, damper_on = _springs_and_dampers_on(m)
    for j in range(m.njnt):
        name = _name(m, mujoco.mjtObj.mjOBJ_JOINT, j)
        dof = int(m.jnt_dofadr[j])
        for kind, on, first, higher, law in (
            ("damping", damper_on, m.dof_damping[dof], m.dof_dampingpoly[dof], "b0 v + b1 v|v| + b2 v^3"),
            ("stiffness", spring_on, m.jnt_stiffness[j], m.jnt_stiffnesspoly[j], "k0 x + k1 x^2 + k2 x^3"),
        ):
            if on and np.any(higher != 0):
                given = " ".join(f"{v:g}" for v in (first, *higher))
                raise ModelError(
                    f'{path}: joint {name!r} has {kind}="{given}", MuJoCo\'s polynomial {kind} ({law}); the harness '
                    f'models joint {kind} as linear: give {kind}="{first:g}" (its first value)'
                )
    for a in range(m.nu):
        if damper_on and np.any(m.actuator_dampingpoly[a] != 0):
            actuator = _name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a)
            given = " ".join(f"{v:g}" for v in (m.actuator_damping[a], *m.actuator_dampingpoly[a]))
            raise ModelError(
                f'{path}: actuator {actuator!r} has damping="{given}", a polynomial damping on its transmission; '
                "the harness reads damping from the joints, linear: remove it from the actuator"
            )


# (MjModel field, what it is, the kind of element it belongs to): every number the dynamics read from the model
_FINITE_FIELDS = (
    ("body_mass", "mass", mujoco.mjtObj.mjOBJ_BODY),
    ("body_inertia", "inertia", mujoco.mjtObj.mjOBJ_BODY),
    ("body_ipos", "centre of mass", mujoco.mjtObj.mjOBJ_BODY),
    ("body_iquat", "inertial frame", mujoco.mjtObj.mjOBJ_BODY),
    ("body_pos", "pos", mujoco.mjtObj.mjOBJ_BODY),
    ("body_quat", "orientation", mujoco.mjtObj.mjOBJ_BODY),
    ("jnt_pos", "pos", mujoco.mjtObj.mjOBJ_JOINT),
    ("jnt_axis", "axis", mujoco.mjtObj.mjOBJ_JOINT),
    ("jnt_range", "range", mujoco.mjtObj.mjOBJ_JOINT),
    ("jnt_stiffness", "stiffness", mujoco.mjtObj.mjOBJ_JOINT),
    ("dof_armature", "armature", mujoco.mjtObj.mjOBJ_DOF),
    ("dof_damping", "damping", mujoco.mjtObj.mjOBJ_DOF),
    ("dof_frictionloss", "frictionloss", mujoco.mjtObj.mjOBJ_DOF),
    ("actuator_gear", "gear", mujoco.mjtObj.mjOBJ_ACTUATOR),
    ("actuator_gainprm", "gain", mujoco.mjtObj.mjOBJ_ACTUATOR),
    ("actuator_biasprm", "bias", mujoco.mjtObj.mjOBJ_ACTUATOR),
)


def _check_finite(path: Path, m: mujoco.MjModel) -> None:
    """Refuse a model with a NaN or inf among the numbers its dynamics read (MuJoCo compiles `mass="nan"`), or a
    physics step that is not positive: a NaN there passed the load check (a NaN difference is no difference) and
    came out later as a diverged simulation or a failed integer conversion. Named by element and attribute."""
    for field, what, kind in _FINITE_FIELDS:
        values = np.asarray(getattr(m, field), dtype=float)
        values = values.reshape(len(values), -1) if values.size else values.reshape(0, 1)
        finite = np.all(np.isfinite(values), axis=1)
        if field == "jnt_range":  # an unlimited joint may say range="-inf inf"
            finite |= ~m.jnt_limited.astype(bool)
        bad = np.flatnonzero(~finite)
        if bad.size:
            i = int(bad[0])
            if kind == mujoco.mjtObj.mjOBJ_DOF:  # a dof's numbers are its joint's attributes
                kind, i = mujoco.mjtObj.mjOBJ_JOINT, int(m.dof_jntid[i])
            element = kind.name.removeprefix("mjOBJ_").lower()
            shown = " ".join(f"{v:g}" for v in values[int(bad[0])])
            raise ModelError(f"{path}: {element} {_name(m, kind, i)!r}: its {what} is {shown}, not finite numbers")
    if not np.all(np.isfinite(m.opt.gravity)):
        raise ModelError(f"{path}: <option gravity> is {' '.join(f'{v:g}' for v in m.opt.gravity)}, not finite numbers")
    if not 0 < m.opt.timestep < np.inf:
        raise ModelError(f'{path}: <option timestep="{m.opt.timestep:g}"> must be > 0 (the physics step [s])')


def _check_scope(path: Path, m: mujoco.MjModel) -> None:
    """Refuse what the rigid-body regressor does not model: other joint types and joint couplings."""
    if m.njnt == 0:
        raise ModelError(f"{path}: the model has no joints: nothing moves, so there is nothing to identify")
    simple = {int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)}
    bad = [
        f"{_name(m, mujoco.mjtObj.mjOBJ_JOINT, j)} ({mujoco.mjtJoint(m.jnt_type[j]).name.removeprefix('mjJNT_')})"
        for j in range(m.njnt)
        if m.jnt_type[j] not in simple
    ]
    if bad:
        raise ModelError(f"{path}: only hinge and slide joints are supported (no free or ball joints); found {bad}")
    # an inactive one applies no force unless a user turns it on; none does under <flag equality="disable"/>
    equality_off = int(mujoco.mjtDisableBit.mjDSBL_EQUALITY) | int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    equality_on = not m.opt.disableflags & equality_off
    active = [e for e in range(m.neq) if m.eq_active0[e] and equality_on]
    if active:
        kinds = [mujoco.mjtEq(m.eq_type[e]).name.removeprefix("mjEQ_").lower() for e in active]
        named = [f"{_name(m, mujoco.mjtObj.mjOBJ_EQUALITY, e)!r} ({k})" for e, k in zip(active, kinds, strict=True)]
        raise ModelError(
            f"{path}: equality constraint(s) {', '.join(named)} couple joints or close a chain; closed chains and "
            "coupled joints are not supported (remove the <equality> elements)"
        )
    if m.ntendon:
        raise ModelError(f"{path}: {_tendons(m)}: tendons are not supported; drive each joint by its own actuator")
    _check_finite(path, m)
    plugins = [a for a in range(m.nu) if m.actuator_plugin[a] >= 0]
    if plugins:  # its force is the plugin's own law (a PID's state): read as a motor of gain 1, it would be wrong
        acts = [_name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) for a in plugins]
        raise ModelError(
            f"{path}: actuator(s) {acts} are plugins (<actuator><plugin>): their force is the plugin's own law, "
            "which the harness does not read; drive the joint with a motor, position or general actuator"
        )
    _check_polynomials(path, m)
    for kind in ("damping", "armature"):  # MuJoCo 4: on the transmission, gear^2 times it on the joint
        values = getattr(m, f"actuator_{kind}")  # (nu,)
        if np.any(values != 0):
            a = int(np.flatnonzero(values)[0])
            actuator = _name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a)
            raise ModelError(
                f"{path}: actuator {actuator!r} has {kind}={values[a]:g} (an actuator's "
                f"{kind}, gear^2 times it on the joint); the harness reads {kind} from the joints: give its joint "
                f'{kind}="{values[a] * m.actuator_gear[a, 0] ** 2:g}" more and remove it from the actuator'
            )
    if np.any(m.body_gravcomp != 0):
        bodies = [_name(m, mujoco.mjtObj.mjOBJ_BODY, int(b)) for b in np.flatnonzero(m.body_gravcomp)]
        raise ModelError(f"{path}: gravity compensation (gravcomp) on bodies {bodies} is not supported")
    if m.opt.density != 0 or m.opt.viscosity != 0:
        raise ModelError(f"{path}: fluid forces (option density/viscosity) are not supported")
    spring_on = _springs_and_dampers_on(m)[0]
    plastic = [_name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(m.njnt) if m.jnt_springyield[j] > 0]
    if plastic and spring_on:  # the spring's rest position follows the joint's history: no fixed springref
        raise ModelError(
            f"{path}: joint(s) {plastic} have a springyield (a plastic spring whose rest position moves with the "
            "joint's history); the harness models a spring with a fixed springref: remove springyield"
        )
    if m.nu and m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_ACTUATION):
        raise ModelError(
            f'{path}: actuation is disabled (<flag actuation="disable"/>): no actuator drives a joint, so the '
            "joints could only hang; enable it"
        )
    off = [a for a in range(m.nu) if 0 <= m.actuator_group[a] < 31 and m.opt.disableactuator >> m.actuator_group[a] & 1]
    if off:
        acts = [_name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) for a in off]
        groups = sorted({int(m.actuator_group[a]) for a in off})
        raise ModelError(
            f"{path}: actuator(s) {acts} are in disabled group(s) {groups} (<option actuatorgroupdisable>): "
            "MuJoCo applies none of their force; enable the group or remove the actuators"
        )
    for kind, count, what, plural in (
        (mujoco.mjtObj.mjOBJ_JOINT, m.njnt, "joint", "joints"),
        (mujoco.mjtObj.mjOBJ_BODY, m.nbody, "body", "bodies"),
    ):
        listed = [_name(m, kind, i) for i in range(count)]
        taken = [i for i in range(count) if not mujoco.mj_id2name(m, kind, i) and listed.count(listed[i]) > 1]
        if taken:  # the harness calls an unnamed joint joint<index> (a body body<index>), and another has that name
            raise ModelError(
                f"{path}: {what} {taken[0]} has no name and the name the harness gives it, {listed[taken[0]]!r}, is "
                f"another {what}'s: name the {plural}"
            )
    names = {_name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(m.njnt)}
    clash = sorted(n for n in names if n.startswith("cmd_") and n.removeprefix("cmd_") in names)
    if clash:  # the data format's columns tau_<joint> and tau_cmd_<joint> would be one
        raise ModelError(
            f"{path}: joints {clash[0].removeprefix('cmd_')!r} and {clash[0]!r} would share the data column "
            f"'tau_{clash[0]}' (the torque of one, the command of the other): rename one of them"
        )


def _se3(quat: np.ndarray, pos: np.ndarray) -> pin.SE3:
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, np.asarray(quat, dtype=float))
    return pin.SE3(R.reshape(3, 3), np.asarray(pos, dtype=float))


def _axis_rotation(axis: np.ndarray, angle: float) -> pin.SE3:
    return pin.SE3(pin.AngleAxis(angle, axis).matrix(), np.zeros(3))


def body_parameters(m: mujoco.MjModel, b: int) -> np.ndarray:
    """(10,) body b's standard parameters in its own frame, as MuJoCo compiled them."""
    inertia = _body_inertia(m, b)
    return from_mass_com_inertia(inertia.mass, inertia.lever, inertia.inertia)


def _body_inertia(m: mujoco.MjModel, b: int) -> pin.Inertia:
    """Body b's inertia in its own frame, as MuJoCo compiled it (mass, centre, principal axes and moments)."""
    R = _se3(m.body_iquat[b], np.zeros(3)).rotation
    return pin.Inertia(float(m.body_mass[b]), m.body_ipos[b].copy(), R @ np.diag(m.body_inertia[b]) @ R.T)


def pinocchio_from_mujoco(m: mujoco.MjModel) -> tuple[pin.Model, np.ndarray, np.ndarray]:
    """The Pinocchio model of a compiled MuJoCo model of hinge and slide joints.

    Returns:
        model: one Pinocchio joint per MuJoCo joint, in MuJoCo's order and with its names; armature and
            gravity as MuJoCo has them.
        carries_body: (nv,) True where the joint is its body's last joint.
        joint_from_body: (nv, 4, 4) the moved body's frame in each joint's frame.
    """
    pm = pin.Model()
    pm.name = "sysid"
    nv = m.nv
    carries = np.zeros(nv, dtype=bool)
    joint_from_body = np.tile(np.eye(4), (nv, 1, 1))
    # for every MuJoCo body: the Pinocchio joint that moves it and its frame in that joint's frame
    frame: list[tuple[int, pin.SE3]] = [(0, pin.SE3.Identity())]
    for b in range(1, m.nbody):
        parent_joint, parent_frame = frame[int(m.body_parentid[b])]
        current = parent_frame * _se3(m.body_quat[b], m.body_pos[b])
        joint = parent_joint
        for j in range(int(m.body_jntadr[b]), int(m.body_jntadr[b]) + int(m.body_jntnum[b])):
            axis = np.asarray(m.jnt_axis[j], dtype=float)
            anchor = pin.SE3(np.eye(3), np.asarray(m.jnt_pos[j], dtype=float))
            ref = float(m.qpos0[m.jnt_qposadr[j]])
            if int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_HINGE):
                placement = current * anchor * _axis_rotation(axis, -ref)
                model: object = pin.JointModelRevoluteUnaligned(*axis)
            else:
                placement = current * anchor * pin.SE3(np.eye(3), -ref * axis)
                model = pin.JointModelPrismaticUnaligned(*axis)
            joint = pm.addJoint(joint, model, placement, _name(m, mujoco.mjtObj.mjOBJ_JOINT, j))
            current = anchor.inverse()
        pm.appendBodyToJoint(joint, _body_inertia(m, b), current)
        if int(m.body_jntnum[b]):
            last = int(m.jnt_dofadr[int(m.body_jntadr[b]) + int(m.body_jntnum[b]) - 1])
            carries[last] = True
            joint_from_body[last] = current.homogeneous
        frame.append((joint, current))
    pm.armature = np.asarray(m.dof_armature, dtype=float).copy()
    gravity_off = m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_GRAVITY)
    pm.gravity = pin.Motion(np.zeros(3) if gravity_off else np.asarray(m.opt.gravity, dtype=float), np.zeros(3))
    return pm, carries, joint_from_body


def own_body_parameters(plant: Plant) -> np.ndarray:
    """(10 nv,) each joint's own body (the one it moves, without bodies welded to it) in the joint's frame.

    Zero for a joint that carries no body (an earlier joint of a multi-joint body). Equals `plant.theta`
    where no body is welded to another.
    """
    m = plant.mj_model
    out = np.zeros(10 * plant.nv)
    for j in np.flatnonzero(plant.carries_body):
        body = body_parameters(m, int(m.jnt_bodyid[m.dof_jntid[j]]))
        out[10 * j : 10 * j + 10] = transform_parameters(body, plant.joint_from_body[j])
    return out


def check_against_mujoco(plant: Plant, rng: np.random.Generator, *, n_states: int = 20) -> None:
    """Refuse a plant whose Pinocchio inverse dynamics differs from MuJoCo's at random states.

    Compared: RNEA (with armature) plus damping and stiffness against `mj_inverse` with constraints off.

    Raises:
        ModelError: naming the joint with the largest difference and its size.
    """
    from dynamics.torque import inverse_dynamics, joint_torque  # torque builds on the plant

    m = copy.deepcopy(plant.mj_model)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)  # no limits, contacts or frictionloss
    q, dq, ddq = random_states(plant, rng, n_states)
    ours = joint_torque(plant, q, dq, ddq, coulomb=False)[0]
    theirs = inverse_dynamics(m, q, dq, ddq)
    diff = np.abs(ours - theirs)
    scale = 1.0 + float(np.max(np.abs(theirs)))
    if float(diff.max()) > _CHECK_RTOL * scale:
        k, j = np.unravel_index(int(np.argmax(diff)), diff.shape)
        raise ModelError(
            f"{plant.path}: Pinocchio's inverse dynamics differs from MuJoCo's by {diff[k, j]:.3g} N m at joint "
            f"{plant.joint_names[j]!r} (largest |tau| {scale - 1:.3g} N m); the model uses a feature the harness "
            "does not reproduce"
        )


def plant_from_model(path: Path, m: mujoco.MjModel, *, check: bool = True) -> Plant:
    """The plant of a compiled MuJoCo model (`path` names its file).

    Raises:
        ModelError: unsupported joints or couplings, or (with `check`) MuJoCo and Pinocchio disagree.
    """
    _check_scope(path, m)
    pm, carries, joint_from_body = pinocchio_from_mujoco(m)
    names = tuple(_name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(m.njnt))
    actuation = actuation_of(m, str(path))
    gear = actuation.gear()
    q_range = np.where(m.jnt_limited[:, None].astype(bool), m.jnt_range, [-np.inf, np.inf])
    # a disabled spring, damper or dry friction (an <option><flag>) is absent from MuJoCo's dynamics, so from ours
    spring_on, damper_on = _springs_and_dampers_on(m)
    friction_on = friction_enabled(m)
    theta = np.concatenate([pm.inertias[i].toDynamicParameters() for i in range(1, pm.njoints)])
    friction_speed, friction_lead = friction_parameters(m)
    plant = Plant(
        name=path.stem,
        path=path,
        mj_model=m,
        pin_model=pm,
        joint_names=names,
        body_names=tuple(_name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.jnt_bodyid[j])) for j in range(m.njnt)),
        carries_body=carries,
        joint_from_body=joint_from_body,
        actuated=gear != 0,
        gear=gear,
        q_range=np.asarray(q_range, dtype=float),
        tau_limit=actuation.torque_limit(),
        actuation=actuation,
        theta=theta,
        armature=m.dof_armature.copy(),
        damping=m.dof_damping * float(damper_on),
        frictionloss=m.dof_frictionloss * float(friction_on),
        stiffness=m.jnt_stiffness * float(spring_on),
        springref=m.qpos_spring.copy(),
        friction_speed=friction_speed,
        friction_lead=friction_lead,
    )
    if check:
        check_against_mujoco(plant, np.random.default_rng(0))
    return plant

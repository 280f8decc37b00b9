"""A plant: one MJCF loaded into MuJoCo (simulation) and Pinocchio (regressor), and the truth read from it."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

from envs.errors import ModelError

__all__ = ["INERTIAL_SYMBOLS", "MJCF_DIR", "SYSTEMS", "Plant", "load_plant", "mjcf_path", "plant_from_xml"]

MJCF_DIR = Path(__file__).resolve().parent.parent / "mjcf"
SYSTEMS = ("arm3", "pendulum", "two_link", "wheel_pendulum")

# Pinocchio's order of the 10 standard parameters of a body, expressed at the joint frame's origin.
INERTIAL_SYMBOLS = ("m", "MX", "MY", "MZ", "XX", "XY", "YY", "XZ", "YZ", "ZZ")


def mjcf_path(system: str) -> Path:
    """Path of a built-in system's MJCF, or of a user's MJCF file given by path.

    Raises:
        ValueError: unknown system name (the message lists the valid ones) or missing file.
    """
    candidate = Path(system)
    if candidate.suffix == ".xml":
        if not candidate.is_file():
            raise ValueError(f"MJCF file not found: {candidate}")
        return candidate
    if system not in SYSTEMS:
        raise ValueError(f"unknown system {system!r}; valid choices: {', '.join(SYSTEMS)} (or a path to an .xml)")
    return MJCF_DIR / f"{system}.xml"


@dataclass(frozen=True, eq=False)
class Plant:
    """One MJCF in MuJoCo and in Pinocchio, with the quantities the harness reads from it.

    Attributes:
        name: system name (the MJCF's file stem).
        path: the MJCF file.
        mj_model: MuJoCo model (simulation, inverse dynamics).
        pin_model: Pinocchio model built from the same file (regressor).
        joint_names: (nv,) names of the 1-DoF joints, in generalised-coordinate order.
        body_names: (nv,) name of the body each joint moves.
        actuated: (nv,) True where an actuator drives the joint.
        gear: (nv,) actuator transmission (joint torque = gear * actuator force); 0 where unactuated.
        q_range: (nv, 2) joint range [rad]; +-inf where the joint is unlimited.
        tau_limit: (nv,) largest joint torque the actuator can apply [N m]; 0 where unactuated.
        theta: (10 nv,) true standard inertial parameters, 10 per body in `INERTIAL_SYMBOLS` order,
            about the joint frame's origin [kg, kg m, kg m^2].
        armature, damping, frictionloss, stiffness, springref: (nv,) joint properties of the MJCF
            [kg m^2, N m s/rad, N m, N m/rad, rad].
    """

    name: str
    path: Path
    mj_model: mujoco.MjModel
    pin_model: pin.Model
    joint_names: tuple[str, ...]
    body_names: tuple[str, ...]
    actuated: np.ndarray
    gear: np.ndarray
    q_range: np.ndarray
    tau_limit: np.ndarray
    theta: np.ndarray
    armature: np.ndarray
    damping: np.ndarray
    frictionloss: np.ndarray
    stiffness: np.ndarray
    springref: np.ndarray

    @property
    def nv(self) -> int:
        return len(self.joint_names)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of `theta`: symbol and 1-based joint index, e.g. `ZZ1`, `m2`."""
        return tuple(f"{s}{j + 1}" for j in range(self.nv) for s in INERTIAL_SYMBOLS)


def load_plant(system: str | Path) -> Plant:
    """Load a built-in system by name (see `SYSTEMS`) or any MJCF of 1-DoF hinge/slide joints by path.

    Raises:
        ValueError: unknown system name or missing file.
        ModelError: the model has joints the harness does not support, or MuJoCo and Pinocchio disagree.
    """
    path = mjcf_path(str(system))
    try:
        mj_model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as err:
        raise ModelError(f"{path}: MuJoCo cannot load it: {err}") from err
    return _plant_from_models(path, mj_model, pin.buildModelFromMJCF(str(path)))


def plant_from_xml(xml: str, name: str, directory: Path) -> Plant:
    """Build a plant from MJCF text (a calibrated or effect-laden variant), written under `directory`."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{name}.xml"
    path.write_text(xml)
    return load_plant(path)


def _plant_from_models(path: Path, m: mujoco.MjModel, pm: pin.Model) -> Plant:
    simple = {int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)}
    bad = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(m.njnt) if m.jnt_type[j] not in simple]
    if bad:
        raise ModelError(f"{path}: only hinge and slide joints are supported; found other joints: {bad}")
    names = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(m.njnt))
    if tuple(pm.names[1:]) != names or pm.nv != m.nv:
        raise ModelError(f"{path}: Pinocchio's joints {list(pm.names[1:])} differ from MuJoCo's {list(names)}")
    bodies = [int(m.jnt_bodyid[j]) for j in range(m.njnt)]
    if len(set(bodies)) != len(bodies):
        raise ModelError(f"{path}: each body may carry at most one joint")
    nonzero_pos = [names[j] for j in range(m.njnt) if np.any(m.jnt_pos[j] != 0)]
    if nonzero_pos:
        raise ModelError(f"{path}: joints must sit at their body's origin (pos='0 0 0'); offending: {nonzero_pos}")

    nv = m.nv
    gear = np.zeros(nv)
    tau_limit = np.zeros(nv)
    for a in range(m.nu):
        if m.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
            raise ModelError(f"{path}: actuator {a} is not a joint transmission")
        j = int(m.jnt_dofadr[m.actuator_trnid[a, 0]])
        gear[j] += m.actuator_gear[a, 0]
        limit = np.inf
        if m.actuator_ctrllimited[a]:
            limit = float(np.max(np.abs(m.actuator_ctrlrange[a]))) * abs(m.actuator_gear[a, 0])
        if m.actuator_forcelimited[a]:
            limit = min(limit, float(np.max(np.abs(m.actuator_forcerange[a]))) * abs(m.actuator_gear[a, 0]))
        tau_limit[j] += limit
    q_range = np.where(m.jnt_limited[:, None].astype(bool), m.jnt_range, [-np.inf, np.inf])
    theta = np.concatenate([pm.inertias[i].toDynamicParameters() for i in range(1, pm.njoints)])
    return Plant(
        name=path.stem,
        path=path,
        mj_model=m,
        pin_model=pm,
        joint_names=names,
        body_names=tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in bodies),
        actuated=gear != 0,
        gear=gear,
        q_range=np.asarray(q_range, dtype=float),
        tau_limit=tau_limit,
        theta=theta,
        armature=m.dof_armature.copy(),
        damping=m.dof_damping.copy(),
        frictionloss=m.dof_frictionloss.copy(),
        stiffness=m.jnt_stiffness.copy(),
        springref=m.qpos_spring.copy(),
    )

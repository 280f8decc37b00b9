"""Hidden effects, by name: what a test or benchmark hides in the simulated system and the diagnosis must find.

MJCF-side effects change the simulated model itself (through `mujoco.MjSpec`, so the variant is a real MJCF
that MuJoCo and Pinocchio both load); sensor-side effects change how the true signals are reported
(`SensorModel`). The names are those of DESIGN.md's diagnosis contract:

    effect            side    target  value                               MuJoCo / sensor counterpart
    armature          MJCF    joint   rotor inertia added [kg m^2]        joint `armature`
    coulomb_friction  MJCF    joint   dry friction torque [N m]           joint `frictionloss`
    viscous_friction  MJCF    joint   damping added [N m s/rad]           joint `damping`
    joint_stiffness   MJCF    joint   stiffness [N m/rad], `springref`    joint `stiffness`, `springref`
    payload           MJCF    body    point mass added [kg] at `position` the body's `inertial`
    joint_offset      sensor  joint   added to the reported angle [rad]   `SensorModel.joint_offset`
    torque_offset     sensor  joint   added to the reported torque [N m]  `SensorModel.torque_offset`
    torque_gain       sensor  joint   reported over applied torque [-]    `SensorModel.torque_gain`
    time_delay        sensor  all     reported torque lags by [s]         `SensorModel.delay_s`
"""

from __future__ import annotations

import dataclasses
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from dynamics.inertia import from_mass_com_inertia
from dynamics.mjcf import write_inertial
from dynamics.plant import Plant, body_parameters, load_spec, movable_xml, plant_from_xml
from envs.sensors import SensorModel

__all__ = ["HIDDEN_EFFECTS", "MJCF_EFFECTS", "SENSOR_EFFECTS", "HiddenEffect", "apply_effects"]

MJCF_EFFECTS = ("armature", "coulomb_friction", "joint_stiffness", "payload", "viscous_friction")
SENSOR_EFFECTS = ("joint_offset", "time_delay", "torque_gain", "torque_offset")
HIDDEN_EFFECTS = tuple(sorted(MJCF_EFFECTS + SENSOR_EFFECTS))


@dataclass(frozen=True)
class HiddenEffect:
    """One effect hidden in the simulated system.

    Attributes:
        effect: a name of `HIDDEN_EFFECTS`.
        target: the joint name (the body name for `payload`; ignored by `time_delay`, which acts on all).
        value: its size in the effect's SI unit (see the module docstring); for `torque_gain` the ratio
            reported / applied torque.
        springref: `joint_stiffness` only: the spring's rest angle [rad].
        position: `payload` only: (3,) where the point mass sits in the body frame [m].
    """

    effect: str
    target: str = ""
    value: float = 0.0
    springref: float = 0.0
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if self.effect not in HIDDEN_EFFECTS:
            raise ValueError(f"unknown effect {self.effect!r}; valid choices: {', '.join(HIDDEN_EFFECTS)}")
        if self.effect == "payload" and self.value <= 0:
            raise ValueError(f"a payload's mass must be > 0 kg, got {self.value}")
        if self.effect == "time_delay" and self.value < 0:
            raise ValueError(f"a time delay must be >= 0 s, got {self.value}")
        if self.effect == "torque_gain" and self.value <= 0:
            raise ValueError(f"a torque gain must be > 0, got {self.value}")
        if len(self.position) != 3:
            raise ValueError(f"position must have 3 entries, got {self.position}")


def apply_effects(
    plant: Plant,
    effects: Sequence[HiddenEffect],
    *,
    sensor: SensorModel,
    directory: Path | None = None,
) -> tuple[Plant, SensorModel]:
    """The plant and sensor with `effects` hidden in them.

    Args:
        plant: the nominal system.
        effects: what to hide (MJCF-side effects add to the nominal joint properties).
        sensor: the nominal sensor model (its noise is kept).
        directory: where the variant MJCF is written (a fresh temporary folder when None).

    Returns:
        (plant with the MJCF-side effects, sensor with the sensor-side ones); the nominal plant itself when
        no MJCF-side effect is asked for.

    Raises:
        ValueError: unknown joint or body name, or a sensor effect on an unactuated joint.
    """
    mjcf_side = [e for e in effects if e.effect in MJCF_EFFECTS]
    out_plant = plant
    if mjcf_side:
        spec = load_spec(plant.path)
        for e in mjcf_side:
            _apply_mjcf(spec, plant, e)
        spec.compile()
        folder = Path(directory) if directory is not None else Path(tempfile.mkdtemp(prefix="sysid_effects_"))
        out_plant = plant_from_xml(movable_xml(spec, plant.path), f"{plant.name}_hidden", folder)
    return out_plant, _apply_sensor(plant, sensor, [e for e in effects if e.effect in SENSOR_EFFECTS])


def _joint_index(plant: Plant, name: str) -> int:
    if name not in plant.joint_names:
        raise ValueError(f"unknown joint {name!r}; valid choices: {', '.join(plant.joint_names)}")
    return plant.joint_names.index(name)


def _apply_mjcf(spec: mujoco.MjSpec, plant: Plant, e: HiddenEffect) -> None:
    if e.effect == "payload":
        if spec.body(e.target) is None or e.target not in plant.body_names:
            raise ValueError(f"unknown body {e.target!r}; valid choices: {', '.join(plant.body_names)}")
        # the body as compiled (its inertia may come from geoms) plus a point mass at `position`
        m = plant.mj_model
        own = body_parameters(m, mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, e.target))
        point = from_mass_com_inertia(e.value, np.asarray(e.position, dtype=float), np.zeros((3, 3)))
        write_inertial(spec, e.target, own + point)
        return
    _joint_index(plant, e.target)
    joint = spec.joint(e.target)
    if e.effect == "armature":
        joint.armature = joint.armature + e.value
    elif e.effect == "coulomb_friction":
        joint.frictionloss = joint.frictionloss + e.value
    elif e.effect == "viscous_friction":
        damping = np.array(joint.damping, dtype=float)
        damping[0] += e.value
        joint.damping = damping
    elif e.effect == "joint_stiffness":
        stiffness = np.array(joint.stiffness, dtype=float)
        stiffness[0] += e.value
        joint.stiffness = stiffness
        joint.springref = e.springref


def _apply_sensor(plant: Plant, sensor: SensorModel, effects: list[HiddenEffect]) -> SensorModel:
    if not effects:
        return sensor
    nv = plant.nv
    joint_offset = sensor.joint_offset.copy() if sensor.joint_offset.size else np.zeros(nv)
    torque_offset = sensor.torque_offset.copy() if sensor.torque_offset.size else np.zeros(nv)
    torque_gain = sensor.torque_gain.copy() if sensor.torque_gain.size else np.ones(nv)
    delay_s = sensor.delay_s
    for e in effects:
        if e.effect == "time_delay":
            delay_s += e.value
            continue
        j = _joint_index(plant, e.target)
        if e.effect in ("torque_offset", "torque_gain") and not plant.actuated[j]:
            raise ValueError(f"{e.effect} on {e.target!r}: the joint is unactuated (its torque is not measured)")
        if e.effect == "joint_offset":
            joint_offset[j] += e.value
        elif e.effect == "torque_offset":
            torque_offset[j] += e.value
        else:
            torque_gain[j] *= e.value
    return dataclasses.replace(
        sensor, joint_offset=joint_offset, torque_offset=torque_offset, torque_gain=torque_gain, delay_s=delay_s
    )

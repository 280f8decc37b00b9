"""The identification model: rigid-body columns from Pinocchio plus per-joint effect columns.

    tau = Y_rb(q, dq, ddq) theta  +  sum over effects  E(q, dq, ddq) phi

Effect columns (per joint j, only on the joint's own row):
    armature          Ia_j   ddq_j            (MJCF `armature`, kg m^2)
    viscous_friction  Fv_j   dq_j             (MJCF `damping`, N m s/rad)
    coulomb_friction  Fc_j   shape(dq_j)      (MJCF `frictionloss`, N m; sign(dq_j), or the ramp the model
                                              declares: `dynamics.friction.friction_shape`)
    joint_stiffness   K_j    q_j - springref_j (MJCF `stiffness`, N m/rad; about the model's spring rest angle)
    torque_offset     off_j  1                (sensor bias, N m; actuated joints only)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from dynamics.friction import friction_shape
from dynamics.plant import Plant

__all__ = ["EFFECT_COLUMNS", "ParameterModel", "rigid_body_regressor"]

# effect name -> (parameter symbol, whether only actuated joints get the column)
EFFECT_COLUMNS: dict[str, tuple[str, bool]] = {
    "armature": ("Ia", False),
    "viscous_friction": ("Fv", False),
    "coulomb_friction": ("Fc", False),
    "joint_stiffness": ("K", False),
    "torque_offset": ("off", True),
}


def rigid_body_regressor(plant: Plant, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """Pinocchio's joint-torque regressor at each sample.

    Args:
        q, dq, ddq: (N, nv) joint positions [rad], velocities [rad/s], accelerations [rad/s^2].

    Returns:
        (N, nv, 10 nv) with Y[k] @ plant.theta = rigid-body inverse dynamics at sample k [N m].
    """
    pm = plant.pin_model
    data = pm.createData()
    out = np.empty((len(q), pm.nv, 10 * (pm.njoints - 1)))
    for k in range(len(q)):
        out[k] = pin.computeJointTorqueRegressor(pm, data, q[k], dq[k], ddq[k])
    return out


@dataclass(frozen=True)
class ParameterModel:
    """Which parameters a fit estimates: the rigid-body ones and the chosen effects.

    Attributes:
        plant: the model the columns come from.
        effects: effect names (keys of `EFFECT_COLUMNS`), in column order after the rigid-body block.
    """

    plant: Plant
    effects: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        unknown = [e for e in self.effects if e not in EFFECT_COLUMNS]
        if unknown:
            raise ValueError(f"unknown effect(s) {unknown}; valid choices: {', '.join(sorted(EFFECT_COLUMNS))}")
        if len(set(self.effects)) != len(self.effects):
            raise ValueError(f"effects listed twice: {list(self.effects)}")

    def _effect_joints(self, effect: str) -> list[int]:
        actuated_only = EFFECT_COLUMNS[effect][1]
        return [j for j in range(self.plant.nv) if self.plant.actuated[j] or not actuated_only]

    @property
    def names(self) -> tuple[str, ...]:
        """Standard parameter names (`m1`, `MX1`, ..., `ZZ2`), then effect names (`Fv1`, ...)."""
        out = list(self.plant.parameter_names)
        for e in self.effects:
            out += [f"{EFFECT_COLUMNS[e][0]}{j + 1}" for j in self._effect_joints(e)]
        return tuple(out)

    @property
    def n_params(self) -> int:
        return len(self.names)

    def truth(self) -> np.ndarray:
        """(p,) the MJCF's values of every parameter (a sensor offset is 0 in the model)."""
        p = self.plant
        values = {
            "armature": p.armature,
            "viscous_friction": p.damping,
            "coulomb_friction": p.frictionloss,
            "joint_stiffness": p.stiffness,
        }
        parts = [p.theta]
        for e in self.effects:
            joints = self._effect_joints(e)
            parts.append(values[e][joints] if e in values else np.zeros(len(joints)))
        return np.concatenate(parts)

    def regressor(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """(N, nv, p) regressor: rigid-body block then one column per effect and joint."""
        blocks = [rigid_body_regressor(self.plant, q, dq, ddq)]
        signal = {
            "armature": ddq,
            "viscous_friction": dq,
            "coulomb_friction": friction_shape(dq, ddq, self.plant.friction_speed, self.plant.friction_lead),
            "joint_stiffness": q - self.plant.springref,
            "torque_offset": None,
        }
        for e in self.effects:
            joints = self._effect_joints(e)
            cols = np.zeros((len(q), self.plant.nv, len(joints)))
            for c, j in enumerate(joints):
                s = signal[e]
                cols[:, j, c] = 1.0 if s is None else s[:, j]
            blocks.append(cols)
        return np.concatenate(blocks, axis=2)

"""The joint torque an MJCF model needs along a measured motion, evaluated in closed form.

    tau = RNEA(q, dq, ddq) (rigid body + armature, Pinocchio)  +  damping dq  +  frictionloss sign(dq)
          +  stiffness (q - springref)

This is MuJoCo's passive-force model with its constraint-based `frictionloss` replaced by the ideal Coulomb
term it approximates (see `calibrate.frictionloss_mapping` for how close MuJoCo's version comes). Joint
angles are in the MJCF's own coordinates, so a joint `ref` (a calibrated joint offset) is honoured.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from envs.plant import Plant

__all__ = ["model_torque", "torque_jacobian_q"]


def model_torque(plant: Plant, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """(N, nv) joint torque [N m] the plant's MJCF needs at the states q, dq, ddq (each (N, nv))."""
    pm = plant.pin_model
    data = pm.createData()
    out = np.empty_like(q, dtype=float)
    for k in range(len(q)):
        out[k] = pin.rnea(pm, data, q[k], dq[k], ddq[k])
    out += plant.damping * dq + plant.frictionloss * np.sign(dq) + plant.stiffness * (q - plant.springref)
    return out


def torque_jacobian_q(
    plant: Plant, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, *, step: float = 1e-6
) -> np.ndarray:
    """(N, nv, nv) derivative of `model_torque` with respect to each joint angle: [k, i, j] = d tau_i / d q_j."""
    out = np.empty((len(q), plant.nv, plant.nv))
    for j in range(plant.nv):
        dqj = np.zeros(plant.nv)
        dqj[j] = step
        out[:, :, j] = (model_torque(plant, q + dqj, dq, ddq) - model_torque(plant, q - dqj, dq, ddq)) / (2 * step)
    return out

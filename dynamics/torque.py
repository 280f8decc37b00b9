"""The one torque model: the joint torque a plant needs along a motion, in closed form, with its derivatives.

    tau = RNEA(q, dq, ddq) (rigid body + armature, Pinocchio)  +  damping dq  +  stiffness (q - springref)
          +  frictionloss shape(dq, ddq)  [+ a log of MuJoCo's own steps: inertia ddq, the ramps' step velocity:
                                          `dynamics.stepping`]

This is MuJoCo's passive-force model with its constraint-based `frictionloss` as the friction shape the model
declares (`dynamics.friction`): the ramp sat((dq + lead ddq) / vt) MuJoCo's inverse dynamics applies where the
joint's solver parameters say so (a calibrated MJCF), otherwise the ideal Coulomb term sign(dq) MuJoCo's soft
constraint approximates: its force never exceeds `frictionloss` and reaches it once the joint slides (see
`identify.diagnose.calibrate.frictionloss_mapping` for how close it comes), so the ideal term is the torque an
actuator must be able to supply. Its derivative is zero for the ideal term (piecewise constant) and Fc / vt (in
dq; Fc lead / vt in ddq) on a ramp. Joint angles are in the model's own coordinates, so a joint `ref` is
honoured.

Used by the excitation's torque limits, the limit check after simulation and the diagnosis alike.
`inverse_dynamics` is MuJoCo's own `mj_inverse` (constraints included), for the simulated controller's
feedforward and for checks against the simulator.
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np
import pinocchio as pin

from dynamics.friction import friction_shape
from dynamics.plant import Plant

__all__ = ["inverse_dynamics", "joint_torque", "torque_jacobian_q"]


def joint_torque(
    plant: Plant, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, *, derivatives: bool = False, coulomb: bool = True
) -> tuple[np.ndarray, np.ndarray | None]:
    """The plant's joint torque at each sample.

    Args:
        q, dq, ddq: (N, nv) joint positions [rad], velocities [rad/s], accelerations [rad/s^2].
        derivatives: also return the torque's derivatives.
        coulomb: include the frictionloss term (False: the smooth part only).

    Returns:
        tau: (N, nv) [N m].
        D: (3, N, nv, nv) dtau/dq, dtau/ddq, dtau/dddq per sample ([.., i, j] = d tau_i / d x_j), or None.
    """
    pm = plant.pin_model
    data = pm.createData()
    q, dq, ddq = (np.asarray(x, dtype=float) for x in (q, dq, ddq))
    tau = np.empty_like(q)
    D = np.empty((3, *q.shape, q.shape[1])) if derivatives else None
    for k in range(len(q)):
        if D is None:
            tau[k] = pin.rnea(pm, data, q[k], dq[k], ddq[k])
            continue
        d_q, d_v, d_a = pin.computeRNEADerivatives(pm, data, q[k], dq[k], ddq[k])
        tau[k] = data.tau
        D[0, k], D[1, k], D[2, k] = d_q, d_v, d_a  # copies: Pinocchio hands back views of `data`
    tau += plant.damping * dq + plant.stiffness * (q - plant.springref)
    stepping = plant.stepping
    coriolis_D = None
    if stepping is not None:
        tau += stepping.inertia * ddq
        change, coriolis_D = stepping.coriolis_change(plant, q, dq, ddq, derivatives=D is not None)
        tau += change
    friction_dq, friction_jac = dq, None
    if coulomb and stepping is not None and np.any(plant.frictionloss > 0):
        friction_dq, friction_jac = stepping.friction_velocity(plant, q, dq, ddq, jacobian=D is not None)
    if coulomb:
        tau += plant.frictionloss * friction_shape(friction_dq, ddq, plant.friction_speed, plant.friction_lead)
    if D is not None:
        D[0] += np.diag(plant.stiffness)
        D[1] += np.diag(plant.damping)
        if stepping is not None:
            D[2] += np.diag(stepping.inertia)
        if coriolis_D is not None:
            D += coriolis_D
        if coulomb and np.any(plant.friction_speed > 0):  # on a declared ramp: slope Fc / vt
            ramp = plant.friction_speed > 0
            width = np.where(ramp, plant.friction_speed, 1.0)
            on_ramp = ramp & (np.abs(friction_dq + plant.friction_lead * ddq) < width)
            slope = np.where(on_ramp, plant.frictionloss / width, 0.0)
            idx = np.arange(plant.nv)
            D[1][:, idx, idx] += slope
            D[2][:, idx, idx] += slope * plant.friction_lead
            if friction_jac is not None:  # the step's velocity: d friction_dq / d q and d ddq
                D[0] += slope[:, :, None] * friction_jac[0]
                D[2] += slope[:, :, None] * friction_jac[1]
    return tau, D


def torque_jacobian_q(plant: Plant, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """(N, nv, nv) derivative of `joint_torque` with respect to each joint angle: [k, i, j] = d tau_i / d q_j."""
    D = joint_torque(plant, q, dq, ddq, derivatives=True)[1]
    assert D is not None
    return D[0]


def inverse_dynamics(plant: Plant | mujoco.MjModel, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """MuJoCo's inverse dynamics (rigid body, armature, passive and active constraint forces).

    Args:
        plant: the plant, or a MuJoCo model (a variant being evaluated).
        q, dq, ddq: (N, nv) joint positions [rad], velocities [rad/s], accelerations [rad/s^2].

    Returns:
        (N, nv) joint torques [N m].
    """
    m = plant.mj_model if isinstance(plant, Plant) else plant
    discrete = int(mujoco.mjtEnableBit.mjENBL_INVDISCRETE)
    if m.opt.enableflags & discrete:
        # <flag invdiscrete>: mj_inverse would read qacc as the step's discrete acceleration (and refuses RK4);
        # these are the states' own, continuous ones. The flag changes nothing in forward simulation: a copy
        # without it (the caller's model untouched)
        m = copy.deepcopy(m)
        m.opt.enableflags &= ~discrete
    d = mujoco.MjData(m)
    out = np.empty_like(np.asarray(q, dtype=float))
    for k in range(len(q)):
        d.qpos[:], d.qvel[:], d.qacc[:] = q[k], dq[k], ddq[k]
        mujoco.mj_inverse(m, d)
        out[k] = d.qfrc_inverse
    return out

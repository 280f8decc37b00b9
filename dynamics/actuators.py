"""The actuators of a compiled model, by kind, and how each is driven and limited.

MuJoCo's actuator with a joint transmission applies the joint torque gear * force, with

    force = gain * ctrl + b0 + b1 * length + b2 * velocity,   length = gear * q,  velocity = gear * dq

clamped to `forcerange` (and the joint's `actuatorfrcrange`). The kinds the harness tells apart:

    motor     fixed gain, no bias                      ctrl is a torque command: ctrl = tau / (gear gain)
    position  fixed gain, affine bias with b1 < 0       a servo to an angle: ctrl = the target (gear q_ref)
    velocity  fixed gain, affine bias, b1 = 0, b2 < 0   a servo to a speed: ctrl = the target (gear dq_ref)
    general   fixed gain, any other affine bias         driven by inverting the affine law for a torque

A servo arm is driven through its own servos (its gains and force limits as the model has them); the
identified torque is what the actuators apply (`qfrc_actuator`). Actuator dynamics (`dyntype`) and
non-fixed gains are refused.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import mujoco
import numpy as np

from dynamics.errors import ModelError

__all__ = ["ACTUATOR_KINDS", "Actuation", "Actuator", "actuation_of", "as_motors", "two_sided"]

ACTUATOR_KINDS = ("general", "motor", "position", "velocity")


@dataclass(frozen=True)
class Actuator:
    """One actuator on one joint.

    Attributes:
        name: the actuator's name.
        joint: its joint's dof index.
        kind: one of `ACTUATOR_KINDS`.
        gear: transmission (joint torque = gear * force).
        gain: fixed gain (force per unit ctrl).
        bias: (3,) affine bias b0, b1, b2 (force, per length, per velocity).
        ctrl_range: (2,) ctrl limits, or None where unlimited.
        torque_limit: largest |joint torque| it can apply in both directions [N m]: force range (and, for a
            motor, ctrl range times gain) times gear, the joint's `actuatorfrcrange` where tighter, each range's
            smaller side (0 for a one-sided range); inf where nothing limits it.
    """

    name: str
    joint: int
    kind: str
    gear: float
    gain: float
    bias: np.ndarray
    ctrl_range: np.ndarray | None
    torque_limit: float

    @property
    def is_servo(self) -> bool:
        return self.kind in ("position", "velocity")

    def bias_force(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Its affine bias b0 + b1 gear q + b2 gear dq [N] at its joint's angles q and speeds dq (any shape)."""
        return self.bias[0] + self.bias[1] * self.gear * q + self.bias[2] * self.gear * dq  # type: ignore[no-any-return]

    @property
    def state_dependent(self) -> bool:
        """Its force depends on the joint's angle or speed (b1, b2): its ctrl is no torque command."""
        return bool(self.bias[1] != 0 or self.bias[2] != 0)


def _kind(gain: float, bias_type: int, bias: np.ndarray) -> str:
    if bias_type == int(mujoco.mjtBias.mjBIAS_NONE) or not np.any(bias[:3]):
        return "motor"
    if bias[1] < 0 and np.isclose(-bias[1], gain, rtol=1e-9) and bias[0] == 0:
        return "position"
    if bias[1] == 0 and bias[2] < 0 and np.isclose(-bias[2], gain, rtol=1e-9) and bias[0] == 0:
        return "velocity"
    return "general"


def _actuator(m: mujoco.MjModel, a: int, where: str) -> Actuator:
    name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) or f"actuator{a}"
    # `jointinparent` differs from `joint` only on ball and free joints, which the harness refuses anyway
    if int(m.actuator_trntype[a]) not in (int(mujoco.mjtTrn.mjTRN_JOINT), int(mujoco.mjtTrn.mjTRN_JOINTINPARENT)):
        raise ModelError(f"{where}: actuator {name!r} is not a joint transmission; only joint actuators are supported")
    if int(m.actuator_dyntype[a]) != int(mujoco.mjtDyn.mjDYN_NONE):
        raise ModelError(
            f"{where}: actuator {name!r} has activation dynamics (dyntype); only direct actuators are supported"
        )
    if int(m.actuator_gaintype[a]) != int(mujoco.mjtGain.mjGAIN_FIXED):
        raise ModelError(f"{where}: actuator {name!r} has a non-fixed gain (gaintype); only fixed gains are supported")
    if int(m.actuator_biastype[a]) not in (int(mujoco.mjtBias.mjBIAS_NONE), int(mujoco.mjtBias.mjBIAS_AFFINE)):
        raise ModelError(
            f"{where}: actuator {name!r} has a non-affine bias (biastype); only affine biases are supported"
        )
    jid = int(m.actuator_trnid[a, 0])
    gear, gain = float(m.actuator_gear[a, 0]), float(m.actuator_gainprm[a, 0])
    bias = np.zeros(3)  # MuJoCo applies biasprm only under an affine biastype
    if int(m.actuator_biastype[a]) == int(mujoco.mjtBias.mjBIAS_AFFINE):
        bias = np.asarray(m.actuator_biasprm[a, :3], dtype=float).copy()
    kind = _kind(gain, int(m.actuator_biastype[a]), bias)
    limit = np.inf
    if m.actuator_forcelimited[a]:
        limit = two_sided(m.actuator_forcerange[a]) * abs(gear)
    ctrl_range = np.asarray(m.actuator_ctrlrange[a], dtype=float).copy() if m.actuator_ctrllimited[a] else None
    if kind == "motor" and ctrl_range is not None:
        limit = min(limit, two_sided(ctrl_range) * abs(gain * gear))
    if m.jnt_actfrclimited[jid]:
        limit = min(limit, two_sided(m.jnt_actfrcrange[jid]))
    return Actuator(name, int(m.jnt_dofadr[jid]), kind, gear, gain, bias, ctrl_range, limit)


def two_sided(bounds: np.ndarray) -> float:
    """The largest magnitude a range [lo, hi] allows in both directions: min(-lo, hi), 0 where it is one-sided
    (a range "0 20" pushes one way only; a symmetric bound must not take 20 from it)."""
    lo, hi = float(bounds[0]), float(bounds[1])
    return max(min(-lo, hi), 0.0)


@dataclass(frozen=True)
class Actuation:
    """All actuators of a model: at most one per joint."""

    actuators: tuple[Actuator, ...]
    nv: int

    @property
    def joints(self) -> np.ndarray:
        return np.array([a.joint for a in self.actuators], dtype=int)

    @property
    def servo(self) -> bool:
        """True when every actuator is a servo (the arm is driven by targets, not torques)."""
        return bool(self.actuators) and all(a.is_servo for a in self.actuators)

    def torque_limit(self) -> np.ndarray:
        """(nv,) largest joint torque the actuators can apply [N m]; 0 where unactuated."""
        out = np.zeros(self.nv)
        for a in self.actuators:
            out[a.joint] = a.torque_limit
        return out

    def gear(self) -> np.ndarray:
        """(nv,) each joint's actuator gear; 0 where unactuated."""
        out = np.zeros(self.nv)
        for a in self.actuators:
            out[a.joint] = a.gear
        return out

    def ctrl_for_torque(self, tau: np.ndarray, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """(..., nu) ctrl that makes each actuator apply the joint torque tau (..., nv) at the state q, dq (..., nv)
        (any leading dimensions: one sample, or a batch of windows)."""
        out = np.empty((*np.shape(tau)[:-1], len(self.actuators)))
        for i, a in enumerate(self.actuators):
            j = a.joint
            out[..., i] = (tau[..., j] / a.gear - a.bias_force(q[..., j], dq[..., j])) / a.gain
        return out

    def ctrl_for_reference(self, tau: np.ndarray, q: np.ndarray, dq: np.ndarray, setpoints: np.ndarray) -> np.ndarray:
        """(nu,) ctrl along a reference: each servo its setpoint (`setpoints` (nu,), a row of `servo_setpoints`),
        any other actuator the joint torque tau (nv,) at the state q, dq."""
        return np.where(np.isnan(setpoints), self.ctrl_for_torque(tau, q, dq), setpoints)

    def servo_setpoints(self, q_ref: np.ndarray, dq_ref: np.ndarray, tau_ref: np.ndarray | None) -> np.ndarray:
        """(n, nu) each servo's setpoint along a reference q_ref, dq_ref (n, nv) (NaN for the other actuators).

        Without `tau_ref` (n, nv) it is the reference itself (gear q_ref or gear dq_ref). With it, the setpoint at
        which the servo applies tau_ref on the reference state: kp (s - gear q) - kv gear dq = tau_ref / gear
        for a position servo, s = gear q_ref + (tau_ref / gear + kv gear dq_ref) / kp, and kv (s - gear dq) =
        tau_ref / gear for a velocity servo. A servo given the bare reference needs a tracking error of
        tau / kp to apply any torque: gravity and inertia make it lag (0.146 rad on an SO-ARM100's full run);
        fed forward, its own gains only correct what the feedforward model gets wrong."""
        out = np.full((len(q_ref), len(self.actuators)), np.nan)
        for i, a in enumerate(self.actuators):
            if not a.is_servo:
                continue
            j = a.joint
            out[:, i] = a.gear * (q_ref[:, j] if a.kind == "position" else dq_ref[:, j])
            if tau_ref is not None:
                out[:, i] = (tau_ref[:, j] / a.gear - a.bias_force(q_ref[:, j], dq_ref[:, j])) / a.gain
        return out

    def unclamped_torque(self, ctrl: np.ndarray, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """(nv,) the joint torque the ctrl (nu,) asks for at q, dq (nv,), before any ctrl or force clamping."""
        out = np.zeros(self.nv)
        for a, force in zip(self.actuators, self.forces(ctrl, q, dq), strict=True):
            out[a.joint] = a.gear * force
        return out

    def forces(self, ctrl: np.ndarray, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """(nu,) each actuator's force gain ctrl + bias at q, dq (nv,) for the ctrl (nu,), before any clamping."""
        return np.array(
            [a.gain * ctrl[i] + a.bias_force(q[a.joint], dq[a.joint]) for i, a in enumerate(self.actuators)]
        )


def actuation_of(m: mujoco.MjModel, where: str) -> Actuation:
    """The actuators of a compiled model (`where` names it in errors).

    Raises:
        ModelError: an actuator the harness cannot drive, or two actuators on one joint.
    """
    acts = tuple(_actuator(m, a, where) for a in range(m.nu))
    joints = [a.joint for a in acts]
    if len(set(joints)) != len(joints):
        twice = sorted({j for j in joints if joints.count(j) > 1})
        names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, int(m.dof_jntid[j])) for j in twice]
        raise ModelError(f"{where}: several actuators drive joint(s) {names}; at most one per joint is supported")
    return Actuation(acts, m.nv)


def as_motors(m: mujoco.MjModel, where: str, which: np.ndarray | None = None) -> mujoco.MjModel:
    """`m`, or a copy in which every actuator whose force depends on the state (a servo: force = kp ctrl -
    kp q - kv dq) is a plain motor, force = ctrl, unclamped in ctrl (its force range kept): driven by the joint
    torque it applied (ctrl = tau / gear, a log's measured torque), as a replay needs. Motors and affine actuators
    with a constant bias (a calibrated torque sensor) are kept. `which`: (nu,) bool, those actuators only."""
    if which is None:
        which = np.array([act.state_dependent for act in actuation_of(m, where).actuators], dtype=bool)
    if not np.any(which):
        return m
    out = copy.deepcopy(m)
    for a in np.flatnonzero(which):
        out.actuator_biastype[a] = mujoco.mjtBias.mjBIAS_NONE
        out.actuator_gainprm[a], out.actuator_biasprm[a] = 0.0, 0.0
        out.actuator_gainprm[a, 0] = 1.0
        out.actuator_ctrllimited[a] = 0
    return out

"""What MuJoCo's discrete step puts into a log of its own simulation: the inertia its integrator adds.

MuJoCo's semi-implicit integrators (Euler, implicit, implicitfast) take some velocity derivatives of the forces
at the end of the step (`implicit_terms`), while `qfrc_actuator` and `actuator_force` report the force at its
start. A log written the way MuJoCo users write one (at each physics step, the positions and the actuator force
of that step) then satisfies, on the states a zero-phase derivative of its positions gives (the velocity at a
sample is the step's mean, v + dv / 2):

    logged torque = the model's torque  +  h (kv + D / 2) ddq          (joint damping D taken implicitly)
                                        +  h (kv - D / 2) ddq          (joint damping explicit: Euler without
                                                                        `eulerdamp`)

with h the model's step, kv = -b2 gear^2 the joint-torque velocity gain of a servo the integrator takes
implicitly (the implicit integrators), 0 otherwise; the Coriolis and centrifugal torque is that of the step's
start velocity (Euler, implicitfast) or, linearised, of its end (implicit), and a frictionloss ramp sees the
solver's acceleration (`Stepping.friction_velocity`). RK4 integrates the continuous equations: nothing. On the
Menagerie Panda (its position servos, kv 450 on joint 1, damping 1, implicitfast at 2 ms) this is an inertia of
0.901 kg m^2 per joint 1 and 2, nine times the rotor inertia the model gives it; a diagnosis that reads such a
log as a robot's names that much armature on every joint (`identify.diagnose`: `mujoco_steps`).

`envs.simulate` writes its data the other way round: it corrects the torque it reports to the continuous-time
robot's (`_StepTerms`), so its logs carry none of this.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import mujoco
import numpy as np
import pinocchio as pin

if TYPE_CHECKING:
    from dynamics.plant import Plant

__all__ = ["Stepping", "as_stepped", "implicit_terms", "integrator_name", "step_inertia", "stepping_of"]


@dataclass(frozen=True)
class Stepping:
    """How MuJoCo's semi-implicit step of a model shows in a log of it (module docstring).

    Attributes:
        timestep: the physics step h [s].
        gain: (nv,) the velocity gains the integrator takes at the step's end, kv + D where it takes them
            [N m s/rad or N s/m].
        inertia: (nv,) what the step adds to each joint's logged torque per unit acceleration, h gain - h D / 2.
        coriolis_shift: where in the step the integrator takes the Coriolis and centrifugal torque, from the
            step's mean velocity, times its acceleration [s]: -h / 2 (at its start: Euler, implicitfast) or
            +h / 2 (at its end: implicit, which takes their velocity derivative too).
    """

    timestep: float
    gain: np.ndarray
    inertia: np.ndarray
    coriolis_shift: float = 0.0

    def coriolis_change(
        self, plant: Plant, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, *, derivatives: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """(N, nv) bias(q, dq + coriolis_shift ddq) - bias(q, dq): the Coriolis torque of the step's velocity
        against that of the states a log gives (dq the step's mean velocity), and its derivatives in q, dq and
        ddq (3, N, nv, nv) where asked. Zero where a single joint turns about a fixed axis."""
        pm = plant.pin_model
        data = pm.createData()
        zero = np.zeros(plant.nv)
        used = dq + self.coriolis_shift * ddq
        out = np.empty_like(dq)
        D = np.zeros((3, *dq.shape, plant.nv)) if derivatives else None
        for k in range(len(q)):
            if D is None:
                out[k] = pin.rnea(pm, data, q[k], used[k], zero) - pin.rnea(pm, data, q[k], dq[k], zero)
                continue
            dq_used, dv_used, _ = (np.array(x) for x in pin.computeRNEADerivatives(pm, data, q[k], used[k], zero))
            at_used = data.tau.copy()
            dq_mean, dv_mean, _ = (np.array(x) for x in pin.computeRNEADerivatives(pm, data, q[k], dq[k], zero))
            out[k] = at_used - data.tau
            D[0, k], D[1, k], D[2, k] = dq_used - dq_mean, dv_used - dv_mean, self.coriolis_shift * dv_used
        return out, D

    def friction_velocity(
        self, plant: Plant, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, *, jacobian: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """(N, nv) the velocity a frictionloss ramp sat((v + lead a) / vt) of the compiled model sees in a
        step, as a velocity of the states a log gives (dq: the step's mean velocity, ddq its acceleration), and
        where `jacobian` its derivatives in q and in ddq (2, N, nv, nv) (in dq: the identity).

        MuJoCo's constraint solver takes the step's start velocity v = dq - h ddq / 2 and its own acceleration
        M^-1 (f + lambda), while the integrator then applies (M + h gain)^-1 (f + lambda): the solver's
        acceleration is ddq + h M^-1 (gain ddq). So the ramp's argument is dq - h ddq / 2 + lead h M^-1 (gain
        ddq) + lead ddq: the xArm7's last joint (inertia 1.4e-4 kg m^2, servo kv 200 at 2 ms) sees a thousand
        times its own acceleration there, and a log of it is matched to round-off where the plain ramp is off by
        0.86 N m RMS. M^-1 x is Pinocchio's forward dynamics at rest, aba(q, 0, x) - aba(q, 0, 0), and so is its
        derivative in q.
        """
        h = self.timestep
        out = dq - 0.5 * h * ddq
        ramp = (plant.friction_speed > 0) & (plant.friction_lead > 0)
        coupled = bool(np.any(self.gain) and np.any(ramp))
        jac = np.zeros((2, len(dq), plant.nv, plant.nv)) if jacobian else None
        if jac is not None:
            jac[1] = -0.5 * h * np.eye(plant.nv)
        if not coupled:
            return out, jac
        pm = plant.pin_model
        data = pm.createData()
        lead = np.where(ramp, plant.friction_lead, 0.0)
        zero = np.zeros(plant.nv)
        for k in range(len(q)):
            qk = np.asarray(q[k], dtype=float)
            if jac is None:
                upper = pin.computeMinverse(pm, data, qk)
                m_inv = np.triu(upper) + np.triu(upper, 1).T  # Pinocchio fills the upper triangle
            else:  # the derivatives give M^-1 whole as d aba / d tau
                with_load, _, m_inv = (
                    np.array(x) for x in pin.computeABADerivatives(pm, data, qk, zero, self.gain * ddq[k])
                )
                at_rest = np.array(pin.computeABADerivatives(pm, data, qk, zero, zero)[0])
                jac[0, k] = h * lead[:, None] * (with_load - at_rest)
            coupling = h * lead[:, None] * m_inv * self.gain[None, :]  # d(extra)/d(ddq)
            out[k] += coupling @ ddq[k]
            if jac is not None:
                jac[1, k] += coupling
        return out, jac


def implicit_terms(m: mujoco.MjModel) -> tuple[bool, bool]:
    """Whether the integrator takes (joint damping, actuator velocity gain) at the end of the step.

    `implicit` and `implicitfast` take every velocity derivative of the smooth forces (never a position one);
    Euler takes the joint damping only, unless `eulerdamp` is disabled; RK4 takes nothing.
    """
    integrator = int(m.opt.integrator)
    implicit = integrator in (int(mujoco.mjtIntegrator.mjINT_IMPLICIT), int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST))
    eulerdamp = not m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    return implicit or (integrator == int(mujoco.mjtIntegrator.mjINT_EULER) and eulerdamp), implicit


def integrator_name(m: mujoco.MjModel) -> str:
    """The model's integrator as MJCF spells it (`implicitfast`, `Euler`, `RK4`, `implicit`)."""
    return {
        int(mujoco.mjtIntegrator.mjINT_EULER): "Euler",
        int(mujoco.mjtIntegrator.mjINT_RK4): "RK4",
        int(mujoco.mjtIntegrator.mjINT_IMPLICIT): "implicit",
        int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST): "implicitfast",
    }.get(int(m.opt.integrator), str(int(m.opt.integrator)))


def stepping_of(plant: Plant) -> Stepping | None:
    """How MuJoCo's step at the model's own timestep shows in a log of its simulation; None under RK4."""
    m = plant.mj_model
    if int(m.opt.integrator) == int(mujoco.mjtIntegrator.mjINT_RK4):
        return None
    joint_implicit, actuator_implicit = implicit_terms(m)
    h = float(m.opt.timestep)
    damping = np.asarray(plant.damping, dtype=float)
    gain = damping.copy() if joint_implicit else np.zeros(plant.nv)
    if actuator_implicit:
        for a in plant.actuation.actuators:
            gain[a.joint] -= float(a.bias[2]) * a.gear**2  # b2 <= 0 on a servo: a damper, kv = -b2 gear^2
    coriolis_implicit = int(m.opt.integrator) == int(mujoco.mjtIntegrator.mjINT_IMPLICIT)
    return Stepping(
        timestep=h,
        gain=gain,
        inertia=h * gain - 0.5 * h * damping,
        coriolis_shift=(0.5 if coriolis_implicit else -0.5) * h,
    )


def step_inertia(plant: Plant) -> np.ndarray:
    """(nv,) the inertia [kg m^2 or kg] MuJoCo's step at the model's own timestep adds to each joint's torque in a
    log of its simulation (module docstring); zeros under RK4."""
    s = stepping_of(plant)
    return np.zeros(plant.nv) if s is None else s.inertia


def as_stepped(plant: Plant) -> Plant:
    """`plant` as a log of MuJoCo's simulation of it at its own step shows it: `Plant.stepping` set, which
    `dynamics.torque.joint_torque` applies (the step inertia and the friction ramps' velocity)."""
    return dataclasses.replace(plant, stepping=stepping_of(plant))

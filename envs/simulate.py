"""Forward simulation in MuJoCo under excitation, sampled by a sensor model.

Two drives: tracking a reference trajectory (PD feedback plus inverse-dynamics feedforward of the nominal
model, for fully actuated systems) and an open-loop joint torque (underactuated systems). The controller
runs at the sensor's sample rate with a zero-order hold; physics runs at the MJCF's timestep. The reported
torque is the torque the actuators really applied (after saturation), plus the sensor model's effects.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from typing import Protocol

import mujoco
import numpy as np

from dynamics.actuators import Actuation, as_motors
from dynamics.errors import ModelError
from dynamics.friction import friction_parameters, ideal_friction
from dynamics.plant import Plant
from dynamics.stepping import implicit_terms
from dynamics.torque import inverse_dynamics
from envs.dataset import Dataset
from envs.sensors import SensorModel

__all__ = ["Reference", "simulate_open_loop", "simulate_tracking", "unstable"]


class Reference(Protocol):
    """Anything that gives joint positions, velocities and accelerations at given times."""

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


def simulate_tracking(
    plant: Plant,
    reference: Reference,
    *,
    duration_s: float,
    sensor: SensorModel,
    rng: np.random.Generator,
    nominal: Plant | None = None,
    bandwidth_hz: float = 4.0,
    damping_ratio: float = 1.0,
    hard_friction: bool = False,
    servo_feedforward: bool = True,
) -> Dataset:
    """Track `reference` through the plant's actuators.

    A torque actuator (motor, general) gets PD feedback plus feedforward from the nominal model's inverse
    dynamics; a servo (position, velocity) gets as its setpoint the reference shifted by that feedforward
    (`Actuation.servo_setpoints`: on the reference it then applies the nominal torque) and tracks with its own
    gains.

    Args:
        plant: the simulated system (it may hide effects the nominal model lacks).
        reference: the trajectory to track, evaluated at the controller's sample times.
        duration_s: simulated time [s].
        sensor: sample rate, noise, quantisation and sensor-side effects.
        rng: source of the sensor noise.
        nominal: the model used for feedforward and gains (defaults to `plant`).
        bandwidth_hz, damping_ratio: closed-loop bandwidth and damping of the PD loop (its gains are the
            nominal mass matrix along the reference times omega^2 and 2 zeta omega).
        hard_friction: simulate `frictionloss` as Coulomb friction (`_hard_friction`), not MuJoCo's default
            soft constraint.
        servo_feedforward: False gives a servo the bare reference as its target (firmware without torque
            feedforward: it lags by the torque it applies over its kp).

    Returns:
        The measured dataset (angles and torques; velocities are not measured). `ddq` and
        `meta["q_true"]`, `meta["dq_true"]` hold the simulated motion's exact states at the sample times (the
        velocity of the continuous motion through the sampled positions, see `_StepTerms`), and
        `meta["tau_applied"]` the torque that gives that motion's acceleration at those states.
    """
    if not np.all(plant.actuated):
        unact = [n for n, a in zip(plant.joint_names, plant.actuated, strict=True) if not a]
        raise ModelError(f"{plant.name}: tracking needs every joint actuated; unactuated: {unact} (use open loop)")
    nominal = nominal or plant
    t = _sample_times(duration_s, sensor.sample_rate_hz)
    q_ref, dq_ref, ddq_ref = reference.evaluate(t)
    tau_ff = inverse_dynamics(nominal, q_ref, dq_ref, ddq_ref)
    # the feedback is shaped by the nominal mass matrix along the reference (computed torque): per-joint gains
    # from its diagonal ignore the coupling, and M^-1 of an outstretched arm is far larger than 1 / M_ii, so the
    # sampled loop's velocity gain 2 zeta omega h lambda(M^-1 Kd) passed 2 (a limit cycle at the Nyquist rate) at
    # 200 Hz on the two-link arm
    mass = _mass_matrices(nominal, q_ref)
    omega = 2 * np.pi * bandwidth_hz
    kp, kd = omega**2, 2 * damping_ratio * omega

    actuation = plant.actuation
    setpoints = actuation.servo_setpoints(q_ref, dq_ref, tau_ff if servo_feedforward else None)  # once, not per step

    def control(k: int, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        tau = tau_ff[k] + mass[k] @ (kp * (q_ref[k] - q) + kd * (dq_ref[k] - dq))
        return actuation.ctrl_for_reference(tau, q, dq, setpoints[k])

    targets = None
    if any(a.is_servo for a in actuation.actuators):
        # a servo's setpoint comes from a fast trajectory generator, not a 2 ms staircase: a kp 2000 servo on
        # a light wrist answers each step within a physics step, and the sampled torque would be its spike

        def targets(times: np.ndarray) -> np.ndarray:
            q_sub, dq_sub, ddq_sub = reference.evaluate(times)
            ff = inverse_dynamics(nominal, q_sub, dq_sub, ddq_sub) if servo_feedforward else None
            return actuation.servo_setpoints(q_sub, dq_sub, ff)

    return _run(
        plant,
        t,
        control,
        q0=q_ref[0],
        dq0=dq_ref[0],
        sensor=sensor,
        rng=rng,
        targets=targets,
        hard_friction=hard_friction,
    )


def simulate_open_loop(
    plant: Plant,
    torque: Callable[[np.ndarray], np.ndarray],
    *,
    duration_s: float,
    sensor: SensorModel,
    rng: np.random.Generator,
    q0: np.ndarray | None = None,
    dq0: np.ndarray | None = None,
) -> Dataset:
    """Apply an open-loop joint torque `torque(t) -> (N, nv)` (zero-order hold at the sample rate)."""
    t = _sample_times(duration_s, sensor.sample_rate_hz)
    tau = np.asarray(torque(t), dtype=float)
    if tau.shape != (len(t), plant.nv):
        raise ValueError(f"torque(t) returned shape {tau.shape}, expected ({len(t)}, {plant.nv})")
    q0 = np.zeros(plant.nv) if q0 is None else q0
    dq0 = np.zeros(plant.nv) if dq0 is None else dq0
    actuation = plant.actuation
    return _run(
        plant,
        t,
        lambda k, q, dq: actuation.ctrl_for_torque(tau[k], q, dq),
        q0=q0,
        dq0=dq0,
        sensor=sensor,
        rng=rng,
        regulated=_state_dependent(plant, servos=True),  # a servo asked for a torque holds it, as a motor
    )


def _sample_times(duration_s: float, rate_hz: float) -> np.ndarray:
    if duration_s <= 0:
        raise ValueError(f"duration_s must be > 0, got {duration_s}")
    return np.arange(int(round(duration_s * rate_hz))) / rate_hz


def _mass_matrices(plant: Plant, q: np.ndarray) -> np.ndarray:
    """(N, nv, nv) the joint-space mass matrix (armature included) at each pose of q (N, nv)."""
    m, d = plant.mj_model, mujoco.MjData(plant.mj_model)
    out = np.zeros((len(q), m.nv, m.nv))
    for k, pose in enumerate(q):
        d.qpos[:] = pose
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_crb(m, d)
        mujoco.mj_fullM(m, d, out[k])
    return out


def _mass_diagonal(plant: Plant, q: np.ndarray) -> np.ndarray:
    """(nv,) the mass matrix's diagonal at the pose q (nv,)."""
    return np.diag(_mass_matrices(plant, q[None])[0]).copy()


# largest (rate x physics step) of a servo's spring sqrt(kp / M) or damper (kv + d) / M that the simulation
# accepts: Menagerie's servo arms are tuned to be stable at 2 ms, not accurate (0.6 rad/step on a gen3 wrist).
# A damper the integrator takes implicitly is not counted (`_servo_rates`): (kv + d) / M reaches 6e5 1/s on
# the xarm7's 1.4e-4 kg m^2 wrist, 2350 physics steps per sample
_MAX_RATE_STEP = 0.5

# servo setpoints evaluated per call of the reference (a chunk of samples at a time): the whole grid is
# samples x physics steps x actuators, and the reference's own temporaries are larger still
_SETPOINTS_PER_CALL = 1 << 16


# impedance of the dry-friction constraint: the friction stays below its bound F only under |v| < v*,
# v* ~ (1 - d) / d * F * timeconst / (2 M) [rad/s] (M the dof's inertia)
_FRICTION_IMPEDANCE = 0.999


def _resolved_model(
    plant: Plant, q0: np.ndarray, *, hard_friction: bool = False, regulated: np.ndarray | None = None
) -> mujoco.MjModel:
    """The plant's model, its physics step divided (by a whole number) until stiff servos are resolved, and
    (with `hard_friction`) its dry friction resolved at that step (`_hard_friction`); `regulated`: the actuators
    driven as motors (`_state_dependent`)."""
    m = _servo_resolved(plant, q0, regulated)
    if not hard_friction or not np.any(m.dof_frictionloss > 0):
        return m
    return _hard_friction(copy.deepcopy(m))


def _hard_friction(m: mujoco.MjModel) -> mujoco.MjModel:
    """`m` (changed in place) with the dry friction of every dof that has some as stiff as the step allows.

    MuJoCo's `frictionloss` is a soft constraint: below v* ~ (1 - d) / d * F * timeconst / (2 M) it acts as a
    viscous damper, not as the Coulomb friction F sign(v) the model declares (and the identification's
    Coulomb column assumes). With the defaults (timeconst 0.02 s, d = 0.9) v* reaches 1 rad/s on a light
    wrist. The stiffest setting that is still stable, timeconst = 2 physics steps (MuJoCo's own lower clamp)
    and impedance 0.999, brings v* below 1e-3 rad/s on every shared arm at no extra cost per step. A dof
    whose friction is a declared ramp (`dynamics.friction`, as a calibrated MJCF writes it) keeps its own.
    """
    dofs = ideal_friction(m.dof_frictionloss, friction_parameters(m)[0])  # a declared ramp stays as written
    m.dof_solref[dofs] = [2.0 * m.opt.timestep, 1.0]
    m.dof_solimp[dofs, :2] = _FRICTION_IMPEDANCE
    return m


def _servo_resolved(plant: Plant, q0: np.ndarray, regulated: np.ndarray | None = None) -> mujoco.MjModel:
    """The plant's model, its physics step divided (by a whole number) until stiff servos are resolved."""
    m = plant.mj_model
    split = _split(_servo_rates(plant, q0, m, regulated=regulated), m.opt.timestep)
    if split <= 1:
        return m
    fine = copy.deepcopy(m)
    fine.opt.timestep = m.opt.timestep / split
    return fine


def _servo_rates(
    plant: Plant, q0: np.ndarray, m: mujoco.MjModel, *, clamped: bool = False, regulated: np.ndarray | None = None
) -> np.ndarray:
    """(nu,) each actuator's fastest rate [1/s] that `m`'s integrator takes explicitly, at the pose q0 (nv,).

    That is its spring sqrt(kp / M) (MuJoCo's implicit integrators take velocity derivatives only) and the
    part of its damper (kv + d) / M that the integrator does not take implicitly
    (`dynamics.stepping.implicit_terms`). With `clamped`, the rates while a force-limited actuator's force is at
    its range: MuJoCo then drops its velocity derivative, and its kv is explicit under any integrator.
    `regulated`: the actuators driven as motors (`_state_dependent`, its default).
    """
    inertia = _mass_diagonal(plant, q0)
    joint_implicit, actuator_implicit = implicit_terms(m)
    regulated = _state_dependent(plant) if regulated is None else regulated
    out = np.zeros(len(plant.actuation.actuators))
    for i, a in enumerate(plant.actuation.actuators):
        j = a.joint
        # a regulated actuator's law acts through its ctrl, set at each step's start: explicitly, and only at its
        # ctrl limit (`_holding`): without a ctrl range, never (an open-loop servo arm took 3200 physics steps per
        # 2 ms sample for it under implicitfast, where its tracking takes 12)
        law = 0.0 if regulated[i] and a.ctrl_range is None else 1.0
        kv_explicit = regulated[i] or not actuator_implicit or (clamped and bool(m.actuator_forcelimited[i]))
        damping = (-a.bias[2] * a.gear**2 * law if kv_explicit else 0.0) + (0.0 if joint_implicit else plant.damping[j])
        out[i] = max(np.sqrt(max(-a.bias[1] * a.gear**2 * law, 0.0) / inertia[j]), max(damping, 0.0) / inertia[j])
    return out


def _velocity_gains(plant: Plant, regulated: np.ndarray) -> np.ndarray:
    """(nu,) each actuator's joint-torque velocity gain b2 gear^2 [N m s/rad] (-kv for a servo; <= 0) that MuJoCo
    applies (0 for the `regulated` actuators, which the simulation drives as motors: `_state_dependent`)."""
    return np.array(
        [0.0 if r else a.bias[2] * a.gear**2 for a, r in zip(plant.actuation.actuators, regulated, strict=True)]
    )


def _split(rates: np.ndarray, h: float) -> int:
    """Physics steps per step h [s] that bring every rate (1/s) times the step within `_MAX_RATE_STEP`."""
    return max(1, int(np.ceil(float(rates.max(initial=0.0)) * h / _MAX_RATE_STEP)))


def _at_force_range(m: mujoco.MjModel, d: mujoco.MjData) -> np.ndarray:
    """(nu,) whether each actuator's force (of d's last forward pass) is at its force range: clamped."""
    force, (lo, hi) = d.actuator_force, m.actuator_forcerange.T
    return m.actuator_forcelimited.astype(bool) & ((force <= lo) | (force >= hi))


@dataclass(frozen=True)
class _Clamp:
    """The finer model for a sample interval in which a `watched` actuator (nu,) reaches its force range.

    Under an implicit integrator a servo's damper is stable at any step, but not while its force is clamped
    (`_servo_rates`): a 20 N m xarm7 wrist servo, clamped for one 0.2 ms step, gains 28 rad/s and stays in a
    clamped cycle at 5.7 rad/s for the rest of the run. Each arm's servos clamp in the first sample (a
    position servo pulls towards zero speed: -kv dq_ref[0] exceeds the wrists' range), rarely after.
    """

    model: mujoco.MjModel
    watched: np.ndarray

    @staticmethod
    def of(plant: Plant, q0: np.ndarray, m: mujoco.MjModel, regulated: np.ndarray | None = None) -> _Clamp | None:
        """The clamp fallback of the resolved model `m`; None where `m`'s step resolves every clamped damper."""
        rates = _servo_rates(plant, q0, m, clamped=True, regulated=regulated)
        watched = rates * m.opt.timestep > _MAX_RATE_STEP
        if not np.any(watched):
            return None
        h0 = plant.mj_model.opt.timestep
        fine = copy.deepcopy(m)  # `m`'s own settings (hard friction) at the finer step
        fine.opt.timestep = h0 / _split(rates, h0)
        return _Clamp(fine, watched)

    def touched(self, m: mujoco.MjModel, d: mujoco.MjData) -> bool:
        return bool(np.any(_at_force_range(m, d)[self.watched]))


class _StepTerms:
    """What turns one MuJoCo step into data of the continuous-time robot at the sample instant.

    MuJoCo's semi-implicit integrators (Euler, implicit, implicitfast) move the positions by the velocity at
    the end of the step: the sampled positions are those of a continuous motion whose velocity at the sample
    is the step's mean, v + dv / 2 (`mean_velocity`), and that is what a zero-phase derivative of the
    positions recovers. But the step's forces are evaluated at v (Coriolis, explicit dampers) or at the end
    of the step, v + dv (what the integrator takes implicitly): a damper d then acts as an extra inertia of
    d h / 2 (-0.001 kg m^2 on each of the Panda's wrist armatures, 3 std, for d = 1 at h = 2 ms) and the
    Coriolis torque is half a step old. The reported torque is the one that gives the same acceleration at
    the mean velocity: the actuator's force in the step (its implicit velocity gain b2 gear^2 taken at
    v + dv, unless it is clamped: `_run` drops it there), plus d (v + dv / 2 - v_used) for the joint dampers
    and bias(q, v + dv / 2) - bias(q, v_used) for the Coriolis forces (v_used: v + dv where the integrator
    takes them implicitly, implicit alone for Coriolis; v otherwise). RK4's state is the continuous one: none.
    """

    def __init__(self, plant: Plant, m: mujoco.MjModel, regulated: np.ndarray) -> None:
        joint_implicit, actuator_implicit = implicit_terms(m)
        integrator = int(m.opt.integrator)
        self.semi_implicit = integrator != int(mujoco.mjtIntegrator.mjINT_RK4)
        self.coriolis_implicit = integrator == int(mujoco.mjtIntegrator.mjINT_IMPLICIT)
        self.gains = (
            _velocity_gains(plant, regulated) if actuator_implicit else np.zeros(len(plant.actuation.actuators))
        )
        half = 0.5 * plant.damping
        self.damping = -half if joint_implicit else half  # times dv: d (v + dv / 2 - v_used)
        self.joints = plant.actuation.joints
        self.any_gain = bool(np.any(self.gains))  # only then may a clamp change the correction
        self._joint_gains = np.bincount(self.joints, self.gains, minlength=plant.nv)
        # one joint on the world has a constant inertia, hence no Coriolis torque
        self._coriolis = plant.nv > 1
        self._scratch = mujoco.MjData(m)

    @property
    def midpoint(self) -> bool:
        """Whether a servo's setpoint is the target at each physics step's middle (RK4). RK4 moves the state
        within a step while the ctrl stays: a stiff servo's force then falls along the step from the law at its
        start (kp gear^2 dq h / 2 below it on average, which the identification read as viscous friction: 0.8 N m
        s/rad, z 600, for kp gear^2 800 at h 2 ms); with the middle's target the law's error averages out."""
        return not self.semi_implicit

    def mean_velocity(self, v: np.ndarray, dv: np.ndarray) -> np.ndarray:
        """(nv,) the continuous motion's velocity at the sample, from the step's start v and change dv."""
        return v + 0.5 * dv if self.semi_implicit else v

    def correction(
        self, m: mujoco.MjModel, q: np.ndarray, v: np.ndarray, dv: np.ndarray, clamped: np.ndarray | None
    ) -> np.ndarray:
        """(nv,) what to add to the step's qfrc_actuator, for the step from (q, v) that changed v by dv, with
        `clamped` (nu,) the actuators at their force range, or None where none can be (`any_gain` False).
        Semi-implicit integrators only (`semi_implicit`): RK4's data need none."""
        gains = self._joint_gains
        if clamped is not None and np.any(clamped):
            gains = np.bincount(self.joints, np.where(clamped, 0.0, self.gains), minlength=len(dv))
        out = (gains + self.damping) * dv
        if not self._coriolis:
            return out
        v_used = v + dv if self.coriolis_implicit else v
        return out + self._bias_change(m, q, v_used, self.mean_velocity(v, dv))

    def _bias_change(self, m: mujoco.MjModel, q: np.ndarray, v_from: np.ndarray, v_to: np.ndarray) -> np.ndarray:
        """(nv,) bias(q, v_to) - bias(q, v_from): Coriolis and centrifugal torque by MuJoCo's RNE (without
        acceleration), both at one kinematics pass (no collision or mass matrix: the bias needs neither)."""
        s = self._scratch
        s.qpos[:] = q
        mujoco.mj_kinematics(m, s)
        mujoco.mj_comPos(m, s)
        out = np.empty((2, m.nv))
        for i, v in enumerate((v_to, v_from)):
            s.qvel[:] = v
            mujoco.mj_comVel(m, s)
            mujoco.mj_rne(m, s, 0, out[i])
        return out[0] - out[1]


def _setpoints(
    targets: Callable[[np.ndarray], np.ndarray] | None, t: np.ndarray, h: float, substeps: int, midpoint: bool
) -> Iterator[np.ndarray | None]:
    """For each sample time t (n,), the ctrl (substeps, nu) of each of its physics steps of h [s] from `targets`
    (None where the held ctrl applies throughout), evaluated `_SETPOINTS_PER_CALL` setpoints at a time: at each
    step's start, or with `midpoint` at its middle (`_StepTerms.midpoint`)."""
    if targets is None or (substeps == 1 and not midpoint):
        yield from (None for _ in t)
        return
    rows = max(1, _SETPOINTS_PER_CALL // substeps)
    for start in range(0, len(t), rows):
        block = t[start : start + rows]
        times = (block[:, None] + (np.arange(substeps)[None, :] + (0.5 if midpoint else 0.0)) * h).ravel()
        yield from targets(times).reshape(len(block), substeps, -1)


def _interval(
    m: mujoco.MjModel,
    d: mujoco.MjData,
    setpoints: np.ndarray | None,
    substeps: int,
    clamp: _Clamp | None,
    hold: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    midpoint: bool = False,
) -> np.ndarray | None:
    """Step d through one sample interval of `substeps` physics steps of `m`, the ctrl held except where
    `setpoints` (substeps, nu) is not NaN (from the second step on: the first step's are the sample's own, set
    by the controller; from the first where they are the steps' midpoints, `_StepTerms.midpoint`) and where
    `hold` (q, dq -> ctrl (nu,), NaN for the actuators it leaves alone) gives the ctrl at each step's state
    (`_holding`).
    Returns the first step's velocity change (nv,), or None as soon as an actuator that `clamp` watches reaches
    its force range (d is then mid-way)."""
    v0, held = d.qvel.copy(), d.ctrl.copy()
    first = None
    for i in range(substeps):
        if setpoints is not None and (i or midpoint):
            d.ctrl[:] = np.where(np.isnan(setpoints[i]), held, setpoints[i])
        if i and hold is not None:
            regulated = hold(d.qpos, d.qvel)
            d.ctrl[:] = np.where(np.isnan(regulated), d.ctrl, regulated)
        mujoco.mj_step(m, d)
        if clamp is not None and clamp.touched(m, d):
            return None
        if i == 0:
            first = d.qvel - v0
    return first


def _pressing(d: mujoco.MjData, k: int, touching: dict[tuple[int, int], list[int]]) -> None:
    """Count sample k for each geom pair of d's contacts that carries a normal force (d after a forward pass), once
    however many contact points the pair has (two capsules overlapping along their length have several: a pair was
    reported pressing in 15003 of 15000 samples)."""
    pairs = {
        (int(min(c.geom1, c.geom2)), int(max(c.geom1, c.geom2)))
        for c in d.contact[: d.ncon]
        if c.efc_address >= 0 and d.efc_force[c.efc_address] != 0.0
    }
    for pair in pairs:
        touching.setdefault(pair, [0, k])[0] += 1


def _at_limit(d: mujoco.MjData, k: int, out: np.ndarray) -> None:
    """Row k of `out` (n, nv): the force of each joint's range limit in d (after a forward pass)."""
    rows = np.flatnonzero(d.efc_type[: d.nefc] == int(mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT))
    for r in rows:
        out[k, d.efc_id[r]] += d.efc_force[r]


# a joint's range-limit force counts as pressing the stop above this share of the joint's RMS applied torque
LIMIT_SHARE = 1e-3


def _limit_report(plant: Plant, t: np.ndarray, force: np.ndarray, applied: np.ndarray) -> list[dict]:
    """One entry per joint whose range limit pushed back (a force above `LIMIT_SHARE` of its RMS applied
    torque): the joint, the samples, the first time [s] and the largest force, most samples first."""
    scale = np.sqrt(np.mean(applied**2, axis=0)) + 1e-9
    out = []
    for j in range(force.shape[1]):
        rows = np.flatnonzero(np.abs(force[:, j]) > LIMIT_SHARE * scale[j])
        if rows.size:
            out.append(
                {
                    "joint": plant.joint_names[j],
                    "samples": int(rows.size),
                    "first_t_s": float(t[rows[0]]),
                    "max_force": float(np.abs(force[:, j]).max()),
                    "unit": plant.torque_units[j],
                }
            )
    return sorted(out, key=lambda e: -e["samples"])


def _contact_report(m: mujoco.MjModel, t: np.ndarray, touching: dict[tuple[int, int], list[int]]) -> list[dict]:
    """One entry per geom pair that pressed: both geoms (and their bodies) by name, samples, first time [s]."""

    def name(g: int) -> str:
        body = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.geom_bodyid[g])) or f"body{m.geom_bodyid[g]}"
        return f"{mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f'geom{g}'} ({body})"

    return [
        {"geoms": [name(a), name(b)], "samples": n, "first_t_s": float(t[first])}
        for (a, b), (n, first) in sorted(touching.items(), key=lambda kv: -kv[1][0])
    ]


_INSTABILITY = {
    mujoco.mjtWarning.mjWARN_BADQPOS: "position",
    mujoco.mjtWarning.mjWARN_BADQVEL: "velocity",
    mujoco.mjtWarning.mjWARN_BADQACC: "acceleration",
}


def unstable(d: mujoco.MjData, joint_names: tuple[str, ...] = ()) -> str:
    """ "" where MuJoCo has not had to reset `d`; else what it found (a NaN, Inf or huge position, velocity or
    acceleration, and at which dof): MuJoCo then resets the state and goes on, so the record is silently wrong."""
    for kind, what in _INSTABILITY.items():
        w = d.warning[int(kind)]
        if w.number > 0:
            dof = int(w.lastinfo)
            name = f" ({joint_names[dof]})" if 0 <= dof < len(joint_names) else ""
            return (
                f": MuJoCo found a NaN, Inf or huge {what} at dof {dof}{name} and reset the state; lower the "
                "physics timestep or the gains"
            )
    return ""


def _state_dependent(plant: Plant, servos: bool = False) -> np.ndarray:
    """(nu,) the actuators that are no servo but whose force depends on the joint's angle or speed (a `general`
    actuator with an affine bias b1, b2). The controller asks each for a joint torque held over the sample, as it
    asks a motor; with its ctrl held, the force drifted with the state within the sample (and within an RK4
    step's stages), and the torque logged at the sample was not the one that moved the arm: a bias b1 gear^2 or
    b2 gear^2 came out of the identification as (dt - h) / 2 of itself in viscous friction or inertia (Fv 0.258
    +- 0.004 for 0.05 on a gear-3 joint, z 53). The simulation drives each as a motor (`as_motors`) whose
    force is set at every physics step (`_holding`), as a drive's current loop holds a torque: the sample's torque
    exactly, under every integrator, while its ctrl stays within its range; at its ctrl limit the actuator's own
    law, force = gain ctrl_limit + bias(q, dq), at each step's start. With `servos` (an open-loop torque, which
    a servo is asked for through its setpoint) the servos too: with its setpoint held, a stiff servo's force fell
    along each RK4 step (0.93 of the torque's RMS left by inverse dynamics on filtered states, kp 200)."""
    return np.array([a.state_dependent and (servos or not a.is_servo) for a in plant.actuation.actuators], dtype=bool)


def _holding(
    actuation: Actuation, regulated: np.ndarray, torque: np.ndarray, q: np.ndarray, dq: np.ndarray
) -> np.ndarray:
    """(nu,) the force each `regulated` actuator applies (its ctrl as a motor) at q, dq when asked for the joint
    torque (nv,): its ctrl for that torque (`ctrl_for_torque`) within its ctrl range, through its own law (NaN for
    the other actuators)."""
    ctrl = actuation.ctrl_for_torque(torque, q, dq)
    for i in np.flatnonzero(regulated):
        ctrl_range = actuation.actuators[i].ctrl_range
        if ctrl_range is not None:
            ctrl[i] = np.clip(ctrl[i], *ctrl_range)
    return np.where(regulated, actuation.forces(ctrl, q, dq), np.nan)


def _run(
    plant: Plant,
    t: np.ndarray,
    control: Callable[[int, np.ndarray, np.ndarray], np.ndarray],
    *,
    q0: np.ndarray,
    dq0: np.ndarray,
    sensor: SensorModel,
    rng: np.random.Generator,
    targets: Callable[[np.ndarray], np.ndarray] | None = None,
    hard_friction: bool = False,
    regulated: np.ndarray | None = None,
) -> Dataset:
    """Simulate sample by sample: ctrl from `control` at each sample (held), except where `targets` (times
    (M,) -> ctrl (M, nu), NaN where the held ctrl applies) sets it at every physics step. A sample interval in
    which a servo's force clamps is simulated again at the finer step of `_Clamp` (`meta["refined_samples"]`)."""
    regulated = _state_dependent(plant) if regulated is None else regulated
    m = as_motors(_resolved_model(plant, q0, hard_friction=hard_friction, regulated=regulated), plant.name, regulated)
    d = mujoco.MjData(m)
    dt_sample = t[1] - t[0]
    substeps = int(round(dt_sample / m.opt.timestep))
    if substeps < 1 or abs(substeps * m.opt.timestep - dt_sample) > 1e-9:
        raise ModelError(
            f"{plant.name}: sample interval {dt_sample} s is not a whole multiple of the physics timestep "
            f"{m.opt.timestep} s"
        )
    n, nv = len(t), m.nv
    q, dq, ddq, applied, clamped, cmd, constraint = (np.empty((n, nv)) for _ in range(7))
    terms = _StepTerms(plant, m, regulated)
    clamp = _Clamp.of(plant, q0, m, regulated)
    kind = mujoco.mjtState.mjSTATE_INTEGRATION
    start = np.empty(mujoco.mj_stateSize(m, kind))
    refined: list[int] = []
    touching: dict[tuple[int, int], list[int]] = {}  # geom pair -> [samples with a contact force, first sample]
    limited = bool(m.jnt_limited.any())
    at_limit = np.zeros((n, nv))  # each joint's range-limit force [N m or N] (hinges and slides: joint j is dof j)
    d.qpos[:], d.qvel[:] = q0, dq0
    for k, fine in enumerate(_setpoints(targets, t, m.opt.timestep, substeps, terms.midpoint)):
        state = d.qpos.copy(), d.qvel.copy()
        ctrl = control(k, *state)
        cmd[k] = plant.actuation.unclamped_torque(ctrl, *state)
        # the torque of the sample, not its ctrl, is held where an actuator's force follows the state
        hold = partial(_holding, plant.actuation, regulated, cmd[k].copy()) if regulated.any() else None
        d.ctrl[:] = ctrl if hold is None else np.where(regulated, hold(*state), ctrl)
        mujoco.mj_forward(m, d)
        q[k], dq[k], ddq[k] = d.qpos, d.qvel, d.qacc
        clamped[k] = d.qfrc_actuator
        applied[k] = clamped[k]
        constraint[k] = d.qfrc_constraint
        if d.ncon:
            _pressing(d, k, touching)
        if limited:
            _at_limit(d, k, at_limit)
        # MuJoCo drops a clamped actuator's velocity derivative from its step
        at_range = _at_force_range(m, d) if terms.any_gain else None
        if clamp is not None:
            mujoco.mj_getState(m, d, start, kind)
            warnings = [int(w.number) for w in d.warning]
        h, step = m.opt.timestep, _interval(m, d, fine, substeps, clamp, hold, terms.midpoint)
        if step is None:  # a watched servo clamped: this interval again, from its start, at the finer step
            assert clamp is not None
            mujoco.mj_setState(m, d, start, kind)
            for w, number in zip(d.warning, warnings, strict=True):  # what the coarse try met is undone with it
                w.number = number
            h, count = clamp.model.opt.timestep, int(round(dt_sample / clamp.model.opt.timestep))
            fine = next(_setpoints(targets, t[k : k + 1], h, count, terms.midpoint))
            step = _interval(clamp.model, d, fine, count, None, hold, terms.midpoint)
            refined.append(k)
        assert step is not None
        if terms.semi_implicit:  # the step's own acceleration, the velocity and torque of the continuous motion
            ddq[k], dq[k] = step / h, terms.mean_velocity(state[1], step)
            applied[k] = applied[k] + terms.correction(m, *state, step, at_range)
        reason = unstable(d, plant.joint_names)
        if reason or not np.all(np.isfinite(d.qpos)):
            raise ModelError(f"{plant.name}: simulation diverged at t = {t[k]:.3f} s{reason}")
    if sensor.delay_s > 0:
        lag = np.floor((t - sensor.delay_s - t[0]) / dt_sample + 1e-9).astype(int)
        reported = applied[np.clip(lag, 0, n - 1)]
    else:
        reported = applied
    # saturation is the ctrl and force clamp alone: `applied` also holds the implicit-damping correction
    saturated = np.abs(cmd - clamped) > 1e-9 * (1 + np.abs(cmd))
    return Dataset(
        time=t,
        q=sensor.measure_q(q, rng),
        tau=sensor.measure_tau(reported, plant.actuated, rng),
        joint_names=plant.joint_names,
        actuated=plant.actuated.copy(),
        ddq=ddq,
        tau_cmd=cmd,
        # the command is held over [t_k, t_k + dt); semi-implicit Euler makes the sampled positions trail the
        # continuous motion by half a physics step, so the torque's instant is (dt - h) / 2 after the sample
        # (dt / 2 under RK4, whose state is the continuous one; a servo's torque is not held: it is sampled
        # with the state it depends on, at the same instant)
        tau_lead_s=0.0
        if plant.actuation.servo and not regulated.any()
        else 0.5 * (dt_sample - (m.opt.timestep if terms.semi_implicit else 0)),
        meta={
            "q_true": q,
            "dq_true": dq,
            "tau_applied": applied,
            "saturated_fraction": saturated[:, plant.actuated].mean(axis=0).tolist(),
            "refined_samples": refined,
            # joint limits, contacts and frictionloss act through constraints: the largest such torque [N m]
            "constraint_torque_max": np.abs(constraint).max(axis=0).tolist(),
            "contacts": _contact_report(m, t, touching),
            "limits": _limit_report(plant, t, at_limit, applied),
        },
    )

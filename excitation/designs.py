"""Feasible Fourier designs: the default rule, random draws, and scaling a shape into the limits."""

from __future__ import annotations

import mujoco
import numpy as np
from mujoco import rollout

from dynamics.actuators import as_motors
from dynamics.errors import InfeasibleExcitationError
from dynamics.plant import Plant
from dynamics.torque import joint_torque
from excitation.fourier import FourierDesign
from excitation.limits import Limits

__all__ = [
    "default_design",
    "default_shape",
    "fit_to_limits",
    "grid",
    "on_actuated",
    "random_design",
    "random_shape",
    "torque_rollout",
]

_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


def grid(design: FourierDesign, points_per_period: int = 400) -> np.ndarray:
    """Times covering one period densely enough for the highest harmonic (>= 25 points per its period)."""
    n = max(points_per_period, 25 * design.harmonics)
    return np.arange(n) * (design.period_s / n)


def default_shape(n_joints: int, harmonics: int, base_freq_hz: float, q0: np.ndarray) -> FourierDesign:
    """The fixed default shape, unscaled: every joint gets every harmonic with amplitude 1/l and quasi-random
    phases (golden ratio and sqrt 2 in a joint-harmonic product), so that no two joints move alike."""
    j, h = np.arange(1, n_joints + 1)[:, None], np.arange(1, harmonics + 1)[None, :]
    # phases must not split into a joint term plus a harmonic term: then every joint's motion would be a mix
    # of the same two signals, and some parameter combinations would not be excited at all
    phase = 2 * np.pi * ((_GOLDEN * j * h**2 + np.sqrt(2.0) * j**2 * h) % 1.0)
    return FourierDesign(base_freq_hz, np.cos(phase) / h, np.sin(phase) / h, q0)


def random_shape(
    n_joints: int, harmonics: int, base_freq_hz: float, q0: np.ndarray, rng: np.random.Generator
) -> FourierDesign:
    """A random shape, unscaled: Gaussian coefficients with amplitude falling as 1/l."""
    amp = 1.0 / np.arange(1, harmonics + 1)[None, :]
    a = rng.normal(size=(n_joints, harmonics)) * amp
    b = rng.normal(size=(n_joints, harmonics)) * amp
    return FourierDesign(base_freq_hz, a, b, q0)


def default_design(
    plant: Plant,
    limits: Limits,
    *,
    harmonics: int,
    base_freq_hz: float,
    torque_driven: bool = False,
    q0: np.ndarray | None = None,
) -> FourierDesign:
    """The fixed default shape (`default_shape`) about `q0` (None: the ranges' middle), scaled to the limits;
    every base parameter is excited."""
    q0 = _centre(limits) if q0 is None else q0
    return _fit(plant, default_shape(plant.nv, harmonics, base_freq_hz, q0), limits, torque_driven)


def random_design(
    plant: Plant,
    limits: Limits,
    *,
    harmonics: int,
    base_freq_hz: float,
    rng: np.random.Generator,
    torque_driven: bool = False,
    q0: np.ndarray | None = None,
) -> FourierDesign:
    """A random shape (`random_shape`) about `q0` (None: the ranges' middle), scaled to the limits."""
    q0 = _centre(limits) if q0 is None else q0
    return _fit(plant, random_shape(plant.nv, harmonics, base_freq_hz, q0, rng), limits, torque_driven)


def _fit(plant: Plant, shape: FourierDesign, limits: Limits, torque_driven: bool) -> FourierDesign:
    if torque_driven:
        return fit_torque_design(plant, on_actuated(plant, shape), limits)
    return fit_to_limits(plant, shape, limits)


def on_actuated(plant: Plant, shape: FourierDesign) -> FourierDesign:
    """A shape read as a drive torque: the unactuated joints' rows zeroed, no offsets."""
    mask = plant.actuated[:, None]
    return FourierDesign(shape.base_freq_hz, shape.a * mask, shape.b * mask, np.zeros(plant.nv))


def _units(plant: Plant) -> str:
    """The unit of the joints' motion: rad, m for slides, or both where they mix."""
    return " or ".join(sorted(set(plant.position_units), reverse=True))


def _centre(limits: Limits) -> np.ndarray:
    finite = np.isfinite(limits.q_min) & np.isfinite(limits.q_max)
    return np.where(finite, 0.5 * (np.where(finite, limits.q_min, 0) + np.where(finite, limits.q_max, 0)), 0.0)


def fit_to_limits(plant: Plant, shape: FourierDesign, limits: Limits, *, min_motion_rad: float = 0.02) -> FourierDesign:
    """Scale a position design's amplitudes to the largest that keeps every limit on a dense grid.

    One factor for every joint keeps the shape's relative amplitudes, bound by every limit, among joints of one
    unit. Ranges in metres and in radians do not compare: the slides and the hinges each take the factor their own
    ranges allow (a gripper's 4 cm slide, a SCARA's 20 cm lift beside hinges of +-2.5 rad do not hold the
    hinges to a few hundredths of a radian), then one factor for all bound by the speeds, accelerations and torques.

    Raises:
        InfeasibleExcitationError: the offset already breaks a limit, or the limits leave less than
            `min_motion_rad` of motion on every joint (the message names the binding bound).
    """
    t = grid(shape, 4000)  # the linear bounds are cheap: check them densely
    _, dq1, ddq1 = shape.evaluate(t)
    dq_unit = np.max(np.abs(dq1), axis=0)
    ddq_unit = np.max(np.abs(ddq1), axis=0)
    dev = shape.evaluate(t)[0] - shape.q0
    up, down = np.max(dev, axis=0), np.max(-dev, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.minimum((limits.q_max - shape.q0) / up, (shape.q0 - limits.q_min) / down)  # (n,) per joint
        room = np.where(np.isnan(room), np.inf, room)  # 0 / 0: a joint that does not move, at its range's end
        bounds = {
            "q": float(np.min(room)),
            "dq": np.min(limits.dq_max / dq_unit),
            "ddq": np.min(limits.ddq_max / ddq_unit),
        }
    if bounds["q"] < 0:
        raise InfeasibleExcitationError(f"offset q0 = {shape.q0} lies outside the joint range (binding: q)", bound="q")
    common = float(min(bounds["dq"], bounds["ddq"]))
    units = np.array(plant.position_units)
    by_unit = np.array([np.min(room[units == u]) for u in units])  # (n,) the room of the joints of each one's unit
    per_joint = np.minimum(by_unit, common)
    if not np.all(np.isfinite(per_joint)):  # a unit with no range, speed or acceleration limit: as the others
        per_joint = np.where(np.isfinite(per_joint), per_joint, np.max(per_joint[np.isfinite(per_joint)], initial=0.0))
    binding = min(bounds, key=lambda k: bounds[k])

    per_joint = per_joint * (1.0 - 1e-6)  # stay strictly inside: the continuous maximum may fall between grid points
    shape = shape.scaled(per_joint)
    t_tau = grid(shape, 1000)

    def torque_ratio(s: float) -> float:
        q, dq, ddq = shape.scaled(s).evaluate(t_tau)
        return float(np.max(np.abs(joint_torque(plant, q, dq, ddq)[0]) / limits.tau_max))

    if torque_ratio(0.0) > 1.0:
        raise InfeasibleExcitationError(
            f"holding the offset q0 = {shape.q0} already needs more torque than tau_max = {limits.tau_max} "
            "(binding: tau)",
            bound="tau",
        )
    s_tau = 1.0
    if torque_ratio(1.0) > 1.0:
        binding, lo, hi = "tau", 0.0, 1.0
        for _ in range(30):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if torque_ratio(mid) <= 1.0 else (lo, mid)
        s_tau = lo * 0.995  # margin for torque peaks between the grid's points
    motion = float(np.max(np.maximum(up, down) * per_joint) * s_tau)
    if motion < min_motion_rad:
        raise limits.infeasible(
            f"the limits allow at most {motion:.3g} {_units(plant)} of motion (< {min_motion_rad})", {binding: 1.0}
        )
    return shape.scaled(s_tau)


def torque_rollout(
    plant: Plant, designs: list[FourierDesign], *, periods: float = 2.0, q0: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Batched open-loop MuJoCo rollouts of torque designs from rest (`mujoco.rollout`), each actuator made a
    unit-gain motor (`torque_model`): the controls of every step are given in advance, where a servo's ctrl for a
    torque depends on the state.

    Returns:
        q, dq: (batch, nstep, nv) joint positions [rad] and velocities [rad/s] at every physics step.
    """
    m = torque_model(plant)
    dt = m.opt.timestep
    nstep = int(round(periods * designs[0].period_s / dt))
    t = np.arange(nstep) * dt
    act_joint = np.array([int(m.jnt_dofadr[m.actuator_trnid[a, 0]]) for a in range(m.nu)], dtype=int)
    gear = m.actuator_gear[:, 0]
    control = np.stack([d.torque(t)[:, act_joint] / gear for d in designs])
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    data = mujoco.MjData(m)
    if q0 is not None:
        data.qpos[:] = q0
    state0 = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, data, state0, spec)
    states, _ = rollout.rollout(m, data, state0[None, :], control)
    # the full-physics state is [time, qpos, qvel, act, ...]
    q = states[:, :, 1 : 1 + m.nq]
    dq = states[:, :, 1 + m.nq : 1 + m.nq + m.nv]
    return q, dq


def torque_model(plant: Plant) -> mujoco.MjModel:
    """`plant`'s model with every actuator that is not a unit-gain motor made one, without bias or ctrl limits
    (`as_motors`; force ranges kept): its ctrl is the joint torque / gear whatever the actuator's own law, as an
    open-loop torque design is applied (the simulation inverts each actuator's law at every step:
    `Actuation.ctrl_for_torque`). A model of unit-gain motors is itself, no copy."""
    other = [not (a.kind == "motor" and a.gain == 1.0) for a in plant.actuation.actuators]
    return as_motors(plant.mj_model, plant.name, np.array(other, dtype=bool))


def fit_torque_design(plant: Plant, shape: FourierDesign, limits: Limits, *, periods: float = 3.0) -> FourierDesign:
    """Scale a torque design to the largest amplitude whose simulated response keeps every limit.

    The response is nonlinear in the amplitude, so a batch of scales is rolled out at once and the largest
    feasible one is kept, then refined once around it. Where none of the first batch (down to 1/16 of the torque
    limit) keeps the limits, batches 16 and 256 times lower are tried before giving up (a light arm whose motors
    would spin it far beyond its speed bound).

    Raises:
        InfeasibleExcitationError: even the smallest tried amplitude breaks a limit (named in the message).
    """
    t = grid(shape)
    peak = np.max(np.abs(shape.torque(t)), axis=0)
    with np.errstate(divide="ignore"):
        s_tau = float(np.min(np.where(peak > 0, limits.tau_max / peak, np.inf)))
    lo, hi = 0.0, s_tau
    last_ratios: dict[str, float] = {}
    lower, refined = 2, False  # batches 16 times lower still to try; whether the refining batch has run
    while True:
        scales = np.linspace(hi / 16, hi, 16) if lo == 0 else np.linspace(lo, hi, 16)
        q, dq = torque_rollout(plant, [shape.scaled(s) for s in scales], periods=periods)
        ok = []
        for b in range(len(scales)):
            last_ratios = limits.ratios(q[b], dq[b])
            ok.append(max(last_ratios.values()) <= 1.0)
        feasible = np.flatnonzero(ok)
        if feasible.size == 0:
            if lo > 0:
                break
            if lower:
                lower, hi = lower - 1, float(scales[0])
                continue
            raise limits.infeasible(
                f"no torque amplitude down to {scales[0]:.3g} x the shape keeps the limits", last_ratios
            )
        best = int(feasible.max())
        lo = float(scales[best])
        if refined or best == len(scales) - 1:
            break
        hi, refined = float(scales[best + 1]), True
    return shape.scaled(lo)

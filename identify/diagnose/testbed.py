"""A data generator independent of the harness's simulation pipeline, to test the diagnosis on data it was
not designed around.

Nothing here uses `envs.simulate`, `envs.effects`, `envs.sensors` or the excitation designs: its own
`mj_step` loop runs a copy of the MJCF under its own PD controller (with the nominal model's inverse
dynamics as feed-forward) that tracks a random multi-sine of its own; the hidden effects are its own
edits of the compiled model or its own applied forces; its own sensor adds white noise and quantisation.
The torque logged at a row is the command held over the following control interval (a zero-order hold),
as a real driver logs it.

Effects (`Injected.effect`):
- in the diagnosis's vocabulary: `viscous_friction`, `coulomb_friction` (MuJoCo frictionloss), `armature`,
  `payload` (mass added to the joint's body at its centre of mass, or with `extra` a point mass on the joint's
  axis, `extra` metres from its anchor), `joint_stiffness`, `cogging`
  (size sin(extra q)), `stribeck_friction` (size sign(dq) exp(-(dq / extra)^2)), `torque_gain` (logged =
  (1 + size) applied), `torque_offset`, `time_delay` (logged torque late by size s), `joint_offset`
  (logged angle = true + size);
- outside it: `quadratic_drag` (size dq |dq|), `torque_disturbance` (size sin(2 pi extra t), a torque
  that follows time, not the motion), `friction_drift` (a viscous friction that grows from 0 at the record's
  start by size every `FRICTION_DRIFT_S`: a drive warming up), and two of the torque sensor: `torque_dead_zone`
  (logged = sign(tau) max(|tau| - size, 0)) and `torque_drift` (a zero that drifts from 0 to size over the record).

A second generator owes nothing to MuJoCo (`lab_rollout`): the DFKI lab's own analytic model of the double
pendulum (`identify.diagnose.authors`, with any of their identified parameter sets, or the nominal MJCF's
numbers in their form: `author_params_of`) integrated by SciPy under open-loop sinusoidal torques, as the lab
excited the real arm, and measured through the drivers' CAN quantisation. Its friction is theirs, cf atan(100 dq)
+ b dq, a shape outside the candidates' exact forms (its limit cf pi / 2 is the Coulomb level), and its rotor
enters as they write it (`lab_model_table`).

A third owes nothing to MuJoCo's stepping or to the harness's model layer, for any arm (`pinocchio_rollout`): the
model as Pinocchio's own MJCF parser reads it, integrated by RK4 of the articulated-body algorithm with hardware's
Coulomb friction, under a PD loop with gravity feed-forward tracking chirps (`pinocchio_table`).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from scipy.integrate import solve_ivp

from dynamics.errors import ModelError
from dynamics.friction import applied_friction_parameters, kept_ramp
from dynamics.plant import Plant, load_plant, load_spec, movable_xml
from dynamics.sampling import random_states
from dynamics.torque import inverse_dynamics
from envs.dataset import Dataset
from envs.simulate import unstable
from identify.diagnose.authors import author_accel, author_torque, load_author_model

__all__ = [
    "ARMS",
    "IN_VOCABULARY",
    "OUT_OF_VOCABULARY",
    "SERVO_ONLY",
    "SYSTEMS",
    "Injected",
    "TestbedSystem",
    "arm_cases",
    "arm_effect_table",
    "author_params_of",
    "diagnose_lab_model",
    "hidden_effect_cases",
    "hidden_effect_table",
    "hidden_markdown",
    "lab_markdown",
    "lab_model_table",
    "lab_rollout",
    "pinocchio_cases",
    "pinocchio_rollout",
    "pinocchio_table",
    "rollout",
    "servo_log",
    "servo_log_cases",
    "servo_log_markdown",
    "servo_log_table",
    "torque_driven",
]

IN_VOCABULARY = (
    "armature",
    "cogging",
    "coulomb_friction",
    "joint_offset",
    "joint_stiffness",
    "payload",
    "stribeck_friction",
    "time_delay",
    "torque_gain",
    "torque_offset",
    "viscous_friction",
)
OUT_OF_VOCABULARY = ("quadratic_drag", "torque_disturbance", "friction_drift", "torque_dead_zone", "torque_drift")
FRICTION_DRIFT_S = 10.0  # [s] `friction_drift`: its viscous friction grows by its size over this time


@dataclass(frozen=True)
class Injected:
    """One hidden effect.

    Attributes:
        effect: its name (see the module docstring).
        joint: the joint it acts on (for `payload`: the joint whose body carries it).
        size: its size in SI units (for `torque_gain`: the departure from 1).
        extra: a shape parameter (cycles per revolution for `cogging`, Stribeck speed [rad/s], disturbance
            frequency [Hz]; for `payload`, where nonzero, a point mass on the joint's axis this far [m] from its
            anchor).
    """

    effect: str
    joint: str
    size: float
    extra: float = 0.0

    @property
    def value(self) -> float:
        """Its size as the diagnosis reports the effect's headline value (a gain's is 1 + size)."""
        return 1.0 + self.size if self.effect == "torque_gain" else self.size

    def __post_init__(self) -> None:
        if self.effect not in IN_VOCABULARY + OUT_OF_VOCABULARY:
            valid = ", ".join(IN_VOCABULARY + OUT_OF_VOCABULARY)
            raise ValueError(f"unknown injected effect {self.effect!r}; valid choices: {valid}")


@dataclass(frozen=True)
class Expected:
    """A finding expected where nothing is hidden: the plant itself differs from the nominal model (the xArm7's
    hardware friction against its MJCF's wide frictionloss ramp, `_narrowed_friction_row`). Its `effect`, `joint`,
    `size` and `value` as an `Injected`'s, to be named first."""

    effect: str
    joint: str
    size: float

    @property
    def value(self) -> float:
        return self.size


@dataclass(frozen=True)
class TestbedSystem:
    """How a built-in system is excited and measured by the testbed.

    Attributes:
        amplitude: (nv,) multi-sine reference amplitude per joint [rad] (0: the joint is not tracked).
        kp, kd: (nv,) PD gains [N m/rad, N m s/rad].
        sigma_tau: (nv,) torque noise std [N m]; tau_resolution: its quantum [N m].
        max_hz: highest reference frequency [Hz].
        center: (nv,) the pose the motion starts at and swings about [rad] (empty: zero), inside the joint
            ranges.
        rk4: integrate with RK4 instead of the model's integrator. An implicit integrator applies the joint
            damping D implicitly, which acts as h D of extra inertia (0.002 kg m^2 on the Panda's joints, damping
            1 at a 2 ms step): a discretisation the diagnosis rightly reports as armature, and no hardware has.
        timestep: the physics step [s] of the rollout (None: the model's); a whole fraction of the sample period.
    """

    amplitude: tuple[float, ...]
    kp: tuple[float, ...]
    kd: tuple[float, ...]
    sigma_tau: tuple[float, ...]
    tau_resolution: float
    max_hz: float = 1.2
    center: tuple[float, ...] = ()
    rk4: bool = False
    timestep: float | None = None


SYSTEMS: dict[str, TestbedSystem] = {
    "pendulum": TestbedSystem((1.0,), (8.0,), (0.4,), (0.01,), 0.001),
    "two_link": TestbedSystem((0.8, 1.0), (40.0, 20.0), (1.5, 0.8), (0.02, 0.02), 0.00586),
    "arm3": TestbedSystem(
        (0.6, 0.5, 0.6), (60.0, 120.0, 60.0), (3.0, 6.0, 3.0), (0.03, 0.03, 0.03), 0.005, center=(0.0, -1.3, 0.6)
    ),
    # only the wheel is driven: it tracks a multi-sine angle and the passive pendulum swings in reaction
    "wheel_pendulum": TestbedSystem((0.0, 12.0), (0.0, 0.05), (0.0, 0.004), (0.0, 0.003), 0.0002, max_hz=1.0),
}


def _arm(
    amplitude: tuple[float, ...],
    kp: tuple[float, ...],
    kd: tuple[float, ...],
    sigma_tau: tuple[float, ...],
    center: tuple[float, ...],
    timestep: float | None = None,
) -> TestbedSystem:
    """A Menagerie arm as the testbed drives it: torques read to 0.01 N m, multi-sines up to 1 Hz, RK4."""
    return TestbedSystem(amplitude, kp, kd, sigma_tau, 0.01, max_hz=1.0, center=center, rk4=True, timestep=timestep)


_SEVEN_AMPLITUDE = (0.4, 0.3, 0.4, 0.4, 0.5, 0.5, 0.5)  # [rad] the seven-joint arms' multi-sines
_SEVEN_NOISE = (0.1, 0.1, 0.1, 0.1, 0.03, 0.03, 0.03)  # [N m] their torque noise, base and wrist joints

# Menagerie arms (../shared/robots/<name>.xml) as the testbed excites them, driven through `torque_driven`: a
# multi-sine of a few tenths of a radian about a pose clear of the joint limits and of self-contact
ARMS: dict[str, TestbedSystem] = {
    "ur5e": _arm(
        (0.5, 0.4, 0.5, 0.6, 0.6, 0.6),
        (2000.0, 2000.0, 1000.0, 200.0, 200.0, 100.0),
        (100.0, 100.0, 50.0, 10.0, 10.0, 5.0),
        (0.15, 0.15, 0.15, 0.05, 0.05, 0.05),
        (0.0, -1.3, 1.3, -1.5, -1.5, 0.0),
    ),
    "panda_nohand": _arm(
        _SEVEN_AMPLITUDE,
        (600.0, 600.0, 600.0, 600.0, 100.0, 100.0, 50.0),
        (30.0, 30.0, 30.0, 30.0, 5.0, 5.0, 2.5),
        _SEVEN_NOISE,
        (0.0, -0.3, 0.0, -2.0, 0.0, 2.0, 0.8),
    ),
    # continuous joints 1, 3, 5 and 7 (no range); the light ones get gains explicit integration keeps stable
    "gen3": _arm(
        _SEVEN_AMPLITUDE,
        (20.0, 600.0, 10.0, 200.0, 5.0, 40.0, 3.0),
        (1.0, 30.0, 0.5, 10.0, 0.25, 2.0, 0.15),
        _SEVEN_NOISE,
        (0.0, 0.5, 0.0, 1.5, 0.0, 1.0, 0.0),
    ),
    # frictionloss 1 N m on every joint at MuJoCo's default solver parameters: on the last joint (damping 2 on
    # an inertia of 1.4e-4 kg m^2) a ramp 7.7 rad/s wide. Its implicitfast integrator adds apparent armature on
    # joints 5 and 7 (0.0035 to 0.0049 kg m^2 even at a 0.2 ms step), and RK4 needs a step below about
    # 2.8 / (7302 x 2.13 /s) = 0.18 ms there: RK4 at 2 ms / 15
    "xarm7_nohand": _arm(
        _SEVEN_AMPLITUDE,
        (200.0, 200.0, 100.0, 100.0, 20.0, 20.0, 10.0),
        (10.0, 10.0, 5.0, 5.0, 0.5, 0.5, 0.2),
        _SEVEN_NOISE,
        (0.0, 0.3, 0.0, 1.5, 0.0, 1.0, 0.0),
        timestep=0.002 / 15,
    ),
}


def arm_cases(arm: str) -> list[list[Injected]]:
    """The hidden effects the benchmark tries on a Menagerie arm of `ARMS` (the clean case first), each at a
    size well above its noise, on joints from the base to the wrist."""
    j = {
        "ur5e": ("shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"),
        "panda_nohand": ("joint2", "joint4", "joint6", "joint5", "joint7"),
        "gen3": ("joint_2", "joint_4", "joint_6", "joint_5", "joint_7"),
        "xarm7_nohand": ("joint2", "joint4", "joint6", "joint5", "joint7"),
    }[arm]
    big = 1.0 if arm == "ur5e" else 0.5  # the UR5e's joints carry about twice the Panda's torques
    return [
        [],
        [Injected("viscous_friction", j[1], big)],
        [Injected("coulomb_friction", j[0], 2.0 * big)],
        [Injected("payload", j[4], 0.5)],
        [Injected("armature", j[2], 0.05 * big)],
        [Injected("armature", j[4], 0.005)],  # the last wrist joint: a small share of the arm's torque error
        [Injected("torque_gain", j[0], 0.1)],
        [Injected("time_delay", j[1], 0.006)],
        [Injected("torque_offset", j[3], 0.3 * big)],
    ]


def torque_driven(mjcf: str | Path, folder: str | Path) -> Path:
    """A copy of `mjcf` whose every actuator is a motor (unit gain, no bias) limited to the force its original
    could apply, written into `folder` as `<stem>_motors.xml` (mesh and texture folders made absolute).

    The testbed drives its joints by torque; Menagerie arms carry position servos, which would pull towards their
    set-points on top of it. The limit is the actuator's `forcerange`; a plain motor without one keeps its
    control range times its gain.

    Raises:
        ValueError: no actuator, an actuator that does not drive one joint with gear 1 (the testbed logs the
            control as the joint's torque), or a servo without a `forcerange` (the force it could apply is
            unknown).
    """
    spec = load_spec(Path(mjcf))
    compiled = spec.compile()
    if compiled.nu == 0:
        raise ValueError(f"{mjcf}: no actuator; the testbed drives the joints through them")
    for a, act in enumerate(spec.actuators):
        name = act.name or f"#{a}"
        if compiled.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT or not np.allclose(
            compiled.actuator_gear[a], [1, 0, 0, 0, 0, 0]
        ):
            raise ValueError(
                f"{mjcf}: actuator {name} does not drive one joint with gear 1; the testbed cannot drive it"
            )
        plain = (
            compiled.actuator_gaintype[a] == mujoco.mjtGain.mjGAIN_FIXED
            and compiled.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_NONE
            and compiled.actuator_dyntype[a] == mujoco.mjtDyn.mjDYN_NONE
        )
        if compiled.actuator_forcelimited[a]:
            lo, hi = (float(v) for v in compiled.actuator_forcerange[a])
        elif plain and compiled.actuator_ctrllimited[a]:
            lo, hi = sorted(float(v) * float(compiled.actuator_gainprm[a, 0]) for v in compiled.actuator_ctrlrange[a])
        else:
            raise ValueError(
                f"{mjcf}: actuator {name} has no forcerange, so the force it could apply is unknown; give it one"
            )
        act.set_to_motor()
        act.ctrlrange, act.forcerange = [lo, hi], [lo, hi]
        act.ctrllimited = act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
    out = Path(folder) / f"{Path(mjcf).stem}_motors.xml"
    out.write_text(movable_xml(spec, Path(mjcf)))
    return out


_ENCODER_SIGMA = 2e-5  # [rad]
_ENCODER_RESOLUTION = 2.4e-5  # [rad]


def _multisine(
    rng: np.random.Generator, amplitude: np.ndarray, max_hz: float, n_sines: int = 5
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frequencies (k,) [Hz], phases (nv, k) and amplitudes (nv, k) [rad] of a random multi-sine per joint."""
    freqs = np.sort(rng.uniform(0.15, max_hz, n_sines))
    phases = rng.uniform(0, 2 * np.pi, (len(amplitude), n_sines))
    weights = rng.uniform(0.5, 1.0, (len(amplitude), n_sines)) / freqs[None, :] ** 0.5
    weights *= (amplitude / np.maximum(weights.sum(axis=1), 1e-12))[:, None]
    return freqs, phases, weights


def _reference(t: float, freqs: np.ndarray, phases: np.ndarray, amps: np.ndarray) -> tuple[np.ndarray, ...]:
    w = 2 * np.pi * freqs
    arg = w[None, :] * t + phases
    # faded in over the first second so that the arm starts at rest
    fade = min(t, 1.0) ** 2 * (3 - 2 * min(t, 1.0))
    q = fade * np.sum(amps * (np.sin(arg) - np.sin(phases)), axis=1)
    dq = fade * np.sum(amps * w * np.cos(arg), axis=1)
    ddq = fade * np.sum(-amps * w**2 * np.sin(arg), axis=1)
    return q, dq, ddq


# hidden in the plant's compiled model (`_hidden_model`), not applied as forces of the testbed's own
MODEL_EFFECTS = ("viscous_friction", "coulomb_friction", "armature", "joint_stiffness", "payload")


def _hidden_model(plant: Plant, effects: list[Injected]) -> mujoco.MjModel:
    m = mujoco.MjModel.from_xml_path(str(plant.path))
    for e in effects:
        j = plant.joint_names.index(e.joint)
        dof = int(m.jnt_dofadr[j])
        if e.effect == "viscous_friction":
            m.dof_damping[dof] += e.size
        elif e.effect == "coulomb_friction":
            m.dof_frictionloss[dof] += e.size
        elif e.effect == "armature":
            m.dof_armature[dof] += e.size
        elif e.effect == "joint_stiffness":
            m.jnt_stiffness[j] += e.size
        elif e.effect == "payload" and e.extra:
            _add_point_mass(m, int(m.jnt_bodyid[j]), e.size, m.jnt_pos[j] + e.extra * m.jnt_axis[j])
        elif e.effect == "payload":
            body = int(m.jnt_bodyid[j])
            ratio = (m.body_mass[body] + e.size) / m.body_mass[body]
            m.body_mass[body] += e.size
            m.body_inertia[body] *= ratio  # the payload spread like the body: its centre of mass stays
    mujoco.mj_setConst(m, mujoco.MjData(m))
    _keep_friction_ramps(
        plant, m, {plant.joint_names.index(e.joint) for e in effects if e.effect == "coulomb_friction"}
    )
    return m


def _add_point_mass(m: mujoco.MjModel, body: int, mass: float, point: np.ndarray) -> None:
    """Add a point `mass` [kg] at `point` (3,) of `body`'s frame to `m` (in place): its centre of mass, principal
    inertia and principal frame are those of the body and the point together (parallel-axis theorem)."""
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, m.body_iquat[body])
    R, total = rot.reshape(3, 3), m.body_mass[body] + mass
    com = m.body_ipos[body].copy()
    new_com = (m.body_mass[body] * com + mass * point) / total

    def shifted(r: np.ndarray) -> np.ndarray:  # a unit mass's inertia about the new centre of mass
        return float(r @ r) * np.eye(3) - np.outer(r, r)

    inertia = R @ np.diag(m.body_inertia[body]) @ R.T
    inertia += m.body_mass[body] * shifted(com - new_com) + mass * shifted(point - new_com)
    moments, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, axes.ravel())
    m.body_mass[body], m.body_ipos[body] = total, new_com
    m.body_inertia[body], m.body_iquat[body] = moments, quat


def _keep_friction_ramps(plant: Plant, m: mujoco.MjModel, changed: set[int]) -> None:
    """Give every joint of `m` with a frictionloss, but the `changed` ones, the friction ramp its nominal MJCF
    has (`dynamics.friction.applied_friction_parameters`).

    MuJoCo's ramp at its default solver parameters is as wide as the joint's `dof_invweight0`: an armature or a
    payload would otherwise change the friction too (a 0.5 kg payload on the xArm7's last link narrows that
    joint's 7.7 rad/s ramp to a near step, which the diagnosis rightly names as a friction change of 2.8 N m)."""
    speed, lead = applied_friction_parameters(plant.mj_model)
    for j in range(plant.nv):
        dof = int(m.jnt_dofadr[j])
        if j in changed or speed[dof] <= 0:
            continue
        fc, invweight = float(m.dof_frictionloss[dof]), float(m.dof_invweight0[dof])
        m.dof_solref[dof], m.dof_solimp[dof], _ = kept_ramp(fc, speed[dof], lead[dof], invweight, m.opt.timestep)


# applied by the testbed as forces against the motion (`_applied_forces`)
_FORCE_EFFECTS = ("cogging", "stribeck_friction", "quadratic_drag", "torque_disturbance", "friction_drift")


def _applied_forces(
    effects: list[Injected], names: tuple[str, ...], t: float, q: np.ndarray, dq: np.ndarray
) -> np.ndarray:
    out = np.zeros(len(q))
    for e in effects:
        j = names.index(e.joint)
        if e.effect == "cogging":
            out[j] -= e.size * np.sin(e.extra * q[j])
        elif e.effect == "stribeck_friction":
            out[j] -= e.size * np.tanh(dq[j] / 1e-3) * np.exp(-((dq[j] / e.extra) ** 2))
        elif e.effect == "quadratic_drag":
            out[j] -= e.size * dq[j] * abs(dq[j])
        elif e.effect == "torque_disturbance":
            out[j] -= e.size * np.sin(2 * np.pi * e.extra * t)
        elif e.effect == "friction_drift":
            out[j] -= e.size * t / FRICTION_DRIFT_S * dq[j]
    return out


def rollout(
    system: str,
    effects: list[Injected],
    *,
    rng: np.random.Generator,
    duration_s: float = 10.0,
    rate_hz: float = 500.0,
    source: str = "testbed",
    mjcf: str | Path | None = None,
    settings: TestbedSystem | None = None,
) -> tuple[Plant, Dataset]:
    """Simulate `system` (a built-in name) with hidden `effects` under the testbed's own controller.

    The forces of `cogging`, `stribeck_friction` and the out-of-vocabulary effects act against the motion
    as the plant's passive forces (MuJoCo's `qfrc_applied`); what the sensor reports is the motor torque.
    `mjcf`: another nominal MJCF of the same joints (a variant of the built-in one, e.g. with a frictionloss),
    excited and measured with `system`'s settings; or, with `settings`, any torque-driven MJCF (a Menagerie
    arm through `torque_driven`), `system` then only its name.

    Returns:
        (the nominal plant, the measured record: time, q, tau, with the tau_lead_s of its held torque).
    """
    if settings is None and system not in SYSTEMS:
        raise ValueError(
            f"unknown testbed system {system!r}; valid choices: {', '.join(SYSTEMS)} (or pass settings=, as ARMS has)"
        )
    plant = load_plant(mjcf if mjcf is not None else system)
    cfg = settings if settings is not None else SYSTEMS[system]
    sizes = {k: len(v) for k, v in vars(cfg).items() if isinstance(v, tuple) and (v or k != "center")}
    if any(n != plant.nv for n in sizes.values()):
        raise ValueError(f"testbed settings for {system}: {sizes} values per field, the model has {plant.nv} joints")
    m = _hidden_model(plant, effects)
    if cfg.rk4:
        m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    if cfg.timestep is not None:
        m.opt.timestep = cfg.timestep
    d = mujoco.MjData(m)
    nominal = plant.mj_model
    dn = mujoco.MjData(nominal)
    freqs, phases, amps = _multisine(rng, np.array(cfg.amplitude), cfg.max_hz)
    center = np.array(cfg.center) if cfg.center else np.zeros(plant.nv)
    d.qpos[:] = center
    kp, kd = np.array(cfg.kp), np.array(cfg.kd)
    act = np.asarray(plant.actuated, bool)
    lo, hi = nominal.actuator_ctrlrange[:, 0], nominal.actuator_ctrlrange[:, 1]
    dof_of_act = nominal.jnt_dofadr[nominal.actuator_trnid[:, 0]]
    substeps = max(int(round(1.0 / (rate_hz * m.opt.timestep))), 1)
    n = int(duration_s * rate_hz)
    time, q_log, tau_log = np.arange(n) / rate_hz, np.zeros((n, plant.nv)), np.zeros((n, plant.nv))
    for k in range(n):
        t = time[k]
        qr, dqr, ddqr = _reference(t, freqs, phases, amps)
        qr = qr + center
        dn.qpos[:], dn.qvel[:], dn.qacc[:] = qr, dqr, ddqr
        mujoco.mj_inverse(nominal, dn)
        tau = np.where(act, dn.qfrc_inverse + kp * (qr - d.qpos) + kd * (dqr - d.qvel), 0.0)
        d.ctrl[:] = np.clip(tau[dof_of_act], lo, hi)
        applied = np.zeros(plant.nv)
        applied[dof_of_act] = d.ctrl
        q_log[k], tau_log[k] = d.qpos, applied
        for _ in range(substeps):
            d.qfrc_applied[:] = _applied_forces(effects, plant.joint_names, float(d.time), d.qpos, d.qvel)
            mujoco.mj_step(m, d)
        reason = unstable(d, plant.joint_names)
        if reason:
            raise ModelError(f"testbed {system}: the simulation diverged at t = {t:.3f} s{reason}")
    # the torque is held over a sample; the semi-implicit integrators' positions trail the continuous motion by
    # half a physics step, so the torque's instant is (dt - h) / 2 after the sample (dt / 2 under RK4), as
    # `envs.simulate` has it
    h = 0.0 if m.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4 else float(m.opt.timestep)
    return plant, _measure(plant, effects, time, q_log, tau_log, cfg, rng, source, lead_s=0.5 * (1.0 / rate_hz - h))


def servo_log(
    mjcf: str | Path,
    *,
    center: Sequence[float],
    amplitude: Sequence[float],
    rng: np.random.Generator,
    duration_s: float,
    sigma_tau: float | Sequence[float],
    effects: Sequence[Injected] = (),
    max_hz: float = 1.0,
    rate_hz: float | None = None,
    positions: str = "before",
    source: str = "servo_log",
) -> tuple[Plant, Dataset]:
    """A log of a servo-driven model as MuJoCo users write one (a Menagerie arm as it comes): its own position
    servos given a multi-sine about `center` as their targets, `mj_step` at the model's own integrator and step,
    and at each sample the positions before a step and the actuator force of that step (`qfrc_actuator`), with
    white torque noise `sigma_tau` [N m] and encoder noise. No feed-forward, no torque-driven copy, no
    correction of the integrator's end-of-step terms (`dynamics.stepping`): what `envs.simulate` does, this does
    not.

    Args:
        mjcf: the model; every actuator a position servo of gear 1 on its own joint.
        center, amplitude: (nv,) the pose the targets swing about and each joint's multi-sine amplitude [rad].
        effects: hidden in the simulated copy (`MODEL_EFFECTS`) or in what the sensors report (`SENSOR_EFFECTS`).
        rate_hz: samples per second, a whole fraction of the physics rate (None: one per physics step).
        positions: `before` the step (with its time), or `after` it (with the time after it: a loop that logs
            `d.time`, `d.qpos` and `d.qfrc_actuator` once `mj_step` returns, whose force is the step's).

    Returns:
        (the nominal plant, the record).
    """
    plant = load_plant(mjcf)
    servos = [a for a in plant.actuation.actuators if a.kind == "position" and a.gear == 1.0]
    if len(servos) != plant.nv or len({a.joint for a in servos}) != plant.nv:
        raise ValueError(f"{mjcf}: servo_log needs one position servo of gear 1 on every joint")
    if positions not in ("before", "after"):
        raise ValueError(f"servo_log positions {positions!r}; valid choices: after, before")
    bad = [e.effect for e in effects if e.effect not in MODEL_EFFECTS + SENSOR_EFFECTS]
    if bad:
        valid = ", ".join(MODEL_EFFECTS + SENSOR_EFFECTS)
        raise ValueError(f"servo_log cannot hide {bad[0]!r}; valid choices: {valid}")
    m = _hidden_model(plant, [e for e in effects if e.effect in MODEL_EFFECTS])
    d = mujoco.MjData(m)
    h = float(m.opt.timestep)
    every = 1 if rate_hz is None else max(int(round(1.0 / (rate_hz * h))), 1)
    freqs, phases, amps = _multisine(rng, np.asarray(amplitude, dtype=float), max_hz)
    joint_of = np.array([a.joint for a in plant.actuation.actuators])
    pose = np.asarray(center, dtype=float)
    d.qpos[:] = pose
    mujoco.mj_forward(m, d)
    n = int(round(duration_s / (every * h)))
    time, q_log, tau_log = np.zeros(n), np.zeros((n, plant.nv)), np.zeros((n, plant.nv))
    for k in range(n):
        for i in range(every):
            target = pose + _reference(float(d.time), freqs, phases, amps)[0]
            d.ctrl[:] = target[joint_of]
            if i == 0 and positions == "before":
                time[k], q_log[k] = d.time, d.qpos
            mujoco.mj_step(m, d)
            if i == 0:
                tau_log[k] = d.qfrc_actuator
                if positions == "after":
                    time[k], q_log[k] = d.time, d.qpos
        reason = unstable(d, plant.joint_names)
        if reason:
            raise ModelError(f"servo_log {plant.name}: the simulation diverged at t = {time[k]:.3f} s{reason}")
    time = time - time[0]
    q, tau = _sensed(plant.joint_names, effects, time, q_log, tau_log)
    tau = tau + rng.normal(0.0, 1.0, tau.shape) * np.asarray(sigma_tau, dtype=float)
    q = q + rng.normal(0.0, _ENCODER_SIGMA, q.shape)
    data = Dataset(
        time=time,
        q=q,
        tau=tau,
        joint_names=plant.joint_names,
        actuated=np.ones(plant.nv, bool),
        source=source,
        meta={"generator": "identify.diagnose.testbed.servo_log", "effects": [e.__dict__ for e in effects]},
    )
    return plant, data


# what the sensors do, not the plant
SENSOR_EFFECTS = ("time_delay", "torque_gain", "torque_offset", "joint_offset", "torque_dead_zone", "torque_drift")


def _sensed(
    names: tuple[str, ...], effects: Sequence[Injected], time: np.ndarray, q: np.ndarray, tau: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(q, tau) as the sensors with the `SENSOR_EFFECTS` among `effects` report them (copies)."""
    q, tau = q.copy(), tau.copy()
    for e in effects:
        j = names.index(e.joint)
        if e.effect == "time_delay":
            tau[:, j] = np.interp(time - e.size, time, tau[:, j], left=tau[0, j])
        elif e.effect == "torque_gain":
            tau[:, j] *= 1.0 + e.size
        elif e.effect == "torque_offset":
            tau[:, j] += e.size
        elif e.effect == "joint_offset":
            q[:, j] += e.size
        elif e.effect == "torque_dead_zone":
            tau[:, j] = np.sign(tau[:, j]) * np.maximum(np.abs(tau[:, j]) - e.size, 0.0)
        elif e.effect == "torque_drift":
            tau[:, j] += e.size * (time - time[0]) / max(float(time[-1] - time[0]), 1e-12)
    return q, tau


def _measure(
    plant: Plant,
    effects: list[Injected],
    time: np.ndarray,
    q: np.ndarray,
    tau: np.ndarray,
    cfg: TestbedSystem,
    rng: np.random.Generator,
    source: str,
    *,
    lead_s: float,
) -> Dataset:
    q, tau = _sensed(plant.joint_names, effects, time, q, tau)
    act = np.asarray(plant.actuated, bool)
    tau = tau + rng.normal(0.0, 1.0, tau.shape) * np.array(cfg.sigma_tau)
    tau = np.where(act, np.round(tau / cfg.tau_resolution) * cfg.tau_resolution, 0.0)
    q = q + rng.normal(0.0, _ENCODER_SIGMA, q.shape)
    q = np.round(q / _ENCODER_RESOLUTION) * _ENCODER_RESOLUTION
    return Dataset(
        time=time,
        q=q,
        tau=tau,
        joint_names=plant.joint_names,
        actuated=act,
        source=source,
        tau_lead_s=lead_s,
        meta={"generator": "identify.diagnose.testbed", "effects": [e.__dict__ for e in effects]},
    )


# the hidden effects `pinocchio_rollout` puts in its plant (besides `_applied_forces`' and `SENSOR_EFFECTS`)
PINOCCHIO_EFFECTS = ("viscous_friction", "coulomb_friction", "armature", "joint_stiffness")
PINOCCHIO_FRICTION_WIDTH = 0.01  # [rad/s] its Coulomb friction F tanh(dq / width): nearly a step, and smooth


def pinocchio_rollout(
    mjcf: str | Path,
    *,
    settings: TestbedSystem,
    effects: Sequence[Injected] = (),
    rng: np.random.Generator,
    duration_s: float,
    rate_hz: float = 500.0,
    control_hz: float = 1000.0,
    physics_hz: float = 4000.0,
    actuator_lag_s: float = 0.0,
    friction_width: float = PINOCCHIO_FRICTION_WIDTH,
    source: str = "pinocchio_rollout",
) -> tuple[Plant, Dataset]:
    """A plant that owes nothing to MuJoCo: the model as Pinocchio's own MJCF parser reads it (not the harness's
    Pinocchio twin of the compiled model), integrated by a fixed-step RK4 of Pinocchio's articulated-body
    algorithm at `physics_hz`, with the file's joint damping, frictionloss (a Coulomb friction F tanh(dq /
    `friction_width`), as hardware has it, not MuJoCo's soft ramp; a light joint's sharp friction asks for a
    fine step) and stiffness as plain forces.

    Its controller is not the testbed's either: a PD loop at `control_hz` on the measured (noisy, quantised) angles
    and their smoothed differences, with the gravity torque of the parsed model as feed-forward, tracking per
    joint a chirp from 0.1 to `settings.max_hz` plus two sines about `settings.center`, at `settings.amplitude`,
    with `settings.kp` and `settings.kd`. Each command is held over its control period; every sample logs the
    angles at its control tick and the command computed there (a lead of half a control period), as the testbed's
    sensor reports them (`_measure`: its own encoder noise, torque noise `settings.sigma_tau` read to
    `settings.tau_resolution`, and the `SENSOR_EFFECTS`). `actuator_lag_s` > 0: the drives apply each
    command through a first-order lag of that time constant (a current loop's), and the log holds the command.

    Raises:
        ValueError: an effect it cannot hide, a model Pinocchio reads otherwise than MuJoCo compiles it (inverse
            dynamics that differ: `_check_parsed`), or rates that are not whole multiples.
        ModelError: the integration diverged.
    """
    import pinocchio as pin  # the generator's own dependency, as SciPy is `lab_rollout`'s

    hideable = PINOCCHIO_EFFECTS + _FORCE_EFFECTS + SENSOR_EFFECTS
    bad = [e.effect for e in effects if e.effect not in hideable]
    if bad:
        raise ValueError(f"pinocchio_rollout cannot hide {bad[0]!r}; valid choices: {', '.join(hideable)}")
    per_control, per_sample = physics_hz / control_hz, control_hz / rate_hz
    if abs(per_control - round(per_control)) > 1e-9 or abs(per_sample - round(per_sample)) > 1e-9:
        raise ValueError(f"pinocchio_rollout: rates {physics_hz:g} / {control_hz:g} / {rate_hz:g} Hz are not multiples")
    plant = load_plant(mjcf)
    nominal = pin.buildModelFromMJCF(str(plant.path))
    _check_parsed(plant, nominal, pin)
    model = pin.Model(nominal)  # the plant: a copy that takes the hidden armature
    n, names = plant.nv, plant.joint_names
    damping, friction, stiffness = plant.damping.copy(), plant.frictionloss.copy(), plant.stiffness.copy()
    springref = plant.springref
    for e in effects:
        j = names.index(e.joint)
        if e.effect == "viscous_friction":
            damping[j] += e.size
        elif e.effect == "coulomb_friction":
            friction[j] += e.size
        elif e.effect == "armature":
            model.armature[j] += e.size
        elif e.effect == "joint_stiffness":
            stiffness[j] += e.size
    data, nominal_data = model.createData(), nominal.createData()
    forced = [e for e in effects if e.effect in _FORCE_EFFECTS]
    limit = plant.actuation.torque_limit()

    def accel(t: float, q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> np.ndarray:
        passive = (
            -damping * dq
            - friction * np.tanh(dq / friction_width)
            - stiffness * (q - springref)
            + _applied_forces(forced, names, t, q, dq)
        )
        return np.asarray(pin.aba(model, data, q, dq, tau + passive))

    center = np.array(settings.center) if settings.center else np.zeros(n)
    amplitude = np.array(settings.amplitude)
    kp, kd = np.array(settings.kp), np.array(settings.kd)
    phase = rng.uniform(0, 2 * np.pi, (n, 3))
    sines = rng.uniform(0.15, 0.75 * settings.max_hz, (n, 2))
    sweep = (settings.max_hz - 0.1) / duration_s  # [Hz/s] the chirp's rise
    weight = np.array([0.5, 0.25, 0.25])  # of the chirp and the two sines

    def reference(t: float) -> tuple[np.ndarray, np.ndarray]:
        arg = np.column_stack([2 * np.pi * (0.1 * t + 0.5 * sweep * t * t) * np.ones(n), 2 * np.pi * sines * t]) + phase
        rate = np.column_stack([2 * np.pi * (0.1 + sweep * t) * np.ones(n), 2 * np.pi * sines])
        swing, swing_rate = (np.sin(arg) - np.sin(phase)) @ weight, (rate * np.cos(arg)) @ weight
        fade, fade_rate = (t, 1.0) if t < 1.0 else (1.0, 0.0)  # the swing grows over the first second from rest
        return center + amplitude * fade * swing, amplitude * (fade * swing_rate + fade_rate * swing)

    h = 1.0 / physics_hz
    # the lag over one step from y0 towards the held command u: y(h) = u + (y0 - u) decay, its mean over the
    # step u + (y0 - u) mean (the torque the step applies; its end value would put it half a step early)
    decay = float(np.exp(-h / actuator_lag_s)) if actuator_lag_s > 0 else 0.0
    mean = actuator_lag_s / h * (1.0 - decay) if actuator_lag_s > 0 else 0.0
    steps_per_control, controls_per_sample = int(round(per_control)), int(round(per_sample))
    samples = int(round(duration_s * rate_hz))
    q, dq = center.copy(), np.zeros(n)
    time, q_log, tau_log = np.arange(samples) / rate_hz, np.zeros((samples, n)), np.zeros((samples, n))
    read_before, speed = None, np.zeros(n)
    act = np.asarray(plant.actuated, bool)
    for k in range(samples * controls_per_sample):
        t = k / control_hz
        read = np.round((q + rng.normal(0.0, _ENCODER_SIGMA, n)) / _ENCODER_RESOLUTION) * _ENCODER_RESOLUTION
        if read_before is not None:
            speed = 0.7 * speed + 0.3 * (read - read_before) * control_hz
        read_before = read
        target, target_speed = reference(t)
        gravity = pin.computeGeneralizedGravity(nominal, nominal_data, read)
        tau = np.where(act, np.clip(kp * (target - read) + kd * (target_speed - speed) + gravity, -limit, limit), 0.0)
        if k % controls_per_sample == 0:
            q_log[k // controls_per_sample], tau_log[k // controls_per_sample] = q, tau
        if k == 0:
            lagged = tau.copy()  # the arm starts at rest under its first command
        for i in range(steps_per_control):
            s = t + i * h
            applied = tau + (lagged - tau) * mean
            lagged = tau + (lagged - tau) * decay
            k1q, k1v = dq, accel(s, q, dq, applied)
            k2q, k2v = dq + h / 2 * k1v, accel(s + h / 2, q + h / 2 * k1q, dq + h / 2 * k1v, applied)
            k3q, k3v = dq + h / 2 * k2v, accel(s + h / 2, q + h / 2 * k2q, dq + h / 2 * k2v, applied)
            k4q, k4v = dq + h * k3v, accel(s + h, q + h * k3q, dq + h * k3v, applied)
            q = q + h / 6 * (k1q + 2 * k2q + 2 * k3q + k4q)
            dq = dq + h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(dq))):
            raise ModelError(f"pinocchio_rollout {plant.name}: the integration diverged at t = {t:.3f} s")
    return plant, _measure(plant, list(effects), time, q_log, tau_log, settings, rng, source, lead_s=0.5 / control_hz)


def _check_parsed(plant: Plant, parsed: Any, pin: Any) -> None:
    """Refuse a model Pinocchio's MJCF parser reads otherwise than MuJoCo compiles it: its inverse dynamics (RNEA
    with armature, plus the file's damping and stiffness) against MuJoCo's with constraints off, at random states
    (`dynamics.plant.check_against_mujoco` checks the harness's own Pinocchio twin so)."""
    m = plant.mj_model
    if parsed.nq != m.nq or parsed.nv != m.nv:
        raise ValueError(
            f"{plant.path}: Pinocchio's MJCF parser reads {parsed.nq} positions and {parsed.nv} joint speeds, MuJoCo "
            f"{m.nq} and {m.nv} (the parser takes the first body under worldbody and its subtree only)"
        )
    q, dq, ddq = random_states(plant, np.random.default_rng(0), 5)
    free = copy.deepcopy(m)
    free.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)  # no limits, contacts or frictionloss
    theirs = inverse_dynamics(free, q, dq, ddq)
    data = parsed.createData()
    ours = np.array([pin.rnea(parsed, data, *state) for state in zip(q, dq, ddq, strict=True)])
    ours += plant.damping * dq + plant.stiffness * (q - plant.springref)
    diff = float(np.max(np.abs(ours - theirs)))
    if diff > 1e-6 * max(1.0, float(np.max(np.abs(theirs)))):
        raise ValueError(
            f"{plant.path}: Pinocchio's MJCF parser reads its inertia otherwise than MuJoCo compiles it (their inverse "
            f"dynamics differ by {diff:.3g}): a compiler option it does not apply (settotalmass, boundmass, "
            "boundinertia) or an inertia it does not read; write the inertials MuJoCo computes into the file"
        )


def hidden_effect_cases() -> list[tuple[str, list[Injected], str]]:
    """(system, effects, expectation) of the benchmark's table: `named` (the first effect is named first),
    `unexplained` (outside the vocabulary) or `clean`. Effects at two sizes and on several joints."""
    cases: list[tuple[str, list[Injected], str]] = [(s, [], "clean") for s in SYSTEMS]
    for size in (0.02, 0.06):
        cases.append(("two_link", [Injected("viscous_friction", "elbow", size)], "named"))
        cases.append(("two_link", [Injected("coulomb_friction", "shoulder", 2 * size)], "named"))
    for size in (0.002, 0.006):
        cases.append(("two_link", [Injected("armature", "elbow", size)], "named"))
    cases += [
        ("two_link", [Injected("torque_offset", "shoulder", 0.08)], "named"),
        ("two_link", [Injected("torque_gain", "elbow", 0.1)], "named"),
        ("two_link", [Injected("time_delay", "shoulder", 0.006)], "named"),
        ("two_link", [Injected("payload", "elbow", 0.1)], "named"),
        ("two_link", [Injected("cogging", "shoulder", 0.08, 6.0)], "named"),
        ("two_link", [Injected("stribeck_friction", "elbow", 0.08, 0.1)], "named"),
        ("two_link", [Injected("quadratic_drag", "shoulder", 0.03)], "unexplained"),
        ("two_link", [Injected("torque_disturbance", "elbow", 0.1, 0.37)], "unexplained"),
        ("two_link", [Injected("friction_drift", "elbow", 0.05)], "unexplained"),
        ("pendulum", [Injected("viscous_friction", "swing", 0.01)], "named"),
        ("pendulum", [Injected("coulomb_friction", "swing", 0.03)], "named"),
        ("pendulum", [Injected("torque_disturbance", "swing", 0.05, 0.37)], "unexplained"),
        ("arm3", [Injected("viscous_friction", "pitch", 0.1)], "named"),
        ("arm3", [Injected("coulomb_friction", "elbow", 0.1)], "named"),
        ("arm3", [Injected("quadratic_drag", "yaw", 0.1)], "unexplained"),
        ("wheel_pendulum", [Injected("viscous_friction", "wheel", 2e-4)], "named"),
        ("wheel_pendulum", [Injected("coulomb_friction", "wheel", 0.01)], "named"),
        ("wheel_pendulum", [Injected("torque_disturbance", "wheel", 0.01, 0.37)], "unexplained"),
    ]
    return cases


def diagnose_case(system: str, effects: list[Injected], seed: int = 0, **kwargs: Any) -> Any:
    """Train on a 10 s record and validate on a 5 s record of another multi-sine, both from `rollout` (`mjcf` and
    `settings` pass on to it)."""
    return diagnose_records(system, [effects], effects, seed, train_s=10.0, validation_s=5.0, **kwargs)


def diagnose_records(
    system: str,
    per_record: list[list[Injected]],
    validation: list[Injected],
    seed: int = 5,
    *,
    train_s: float = 6.0,
    validation_s: float = 4.0,
    mjcf: str | Path | None = None,
    settings: TestbedSystem | None = None,
    generate: Callable[..., tuple[Plant, Dataset]] | None = None,
    **kwargs: Any,
) -> tuple[Plant, Any]:
    """Train on one `train_s` record per entry of `per_record` (each its own multi-sine and hidden effects, such
    as a torque zero that changes between power-ups) and validate on a `validation_s` record with `validation`
    (`mjcf`, `settings`: the nominal model and how it is excited, see `rollout`). `generate(effects=, rng=,
    duration_s=, source=)` makes each record instead of `rollout` (`servo_log_table`: a model's own servos)."""
    from identify.diagnose.diagnosis import diagnose  # the generator does not need the diagnosis

    if generate is None:
        generate = partial(rollout, system, mjcf=mjcf, settings=settings)
    rngs = np.random.default_rng(seed).spawn(len(per_record) + 1)
    train = []
    for i, effects in enumerate(per_record):
        source = "testbed_train" if len(per_record) == 1 else f"testbed_train_{i}"
        plant, data = generate(effects=effects, rng=rngs[i], duration_s=train_s, source=source)
        train.append(data)
    _, val = generate(effects=validation, rng=rngs[-1], duration_s=validation_s, source="testbed_validation")
    return plant, diagnose(
        plant, train, [val], rng=np.random.default_rng(0), derivative_options={"cutoff_hz": 10.0}, **kwargs
    )


def several_records_cases() -> list[tuple[str, str, list[list[Injected]], list[Injected], str]]:
    """(system, label, per-record effects, validation effects, expectation) with three training records: clean
    data of every system, and effects that are the same in every record or change between them."""
    zeros = [0.08, -0.05, 0.06]
    cases: list[tuple[str, str, list[list[Injected]], list[Injected], str]] = [
        (s, "none", [[], [], []], [], "clean") for s in SYSTEMS
    ]
    for effect, joint, size in (
        ("torque_offset", "shoulder", 0.06),
        ("joint_offset", "shoulder", 0.15),
        ("payload", "elbow", 0.1),
    ):
        same = Injected(effect, joint, size)
        cases.append(("two_link", f"{effect} {joint} {size:g} in every record", [[same]] * 3, [same], "named"))
    cases.append(
        (
            "two_link",
            "torque_offset shoulder " + " / ".join(f"{z:+g}" for z in zeros) + " (re-zeroed per record)",
            [[Injected("torque_offset", "shoulder", z)] for z in zeros],
            [Injected("torque_offset", "shoulder", 0.03)],
            "changing",
        )
    )
    return cases


def several_records_table(seed: int = 5) -> list[dict[str, Any]]:
    """One row per case of `several_records_cases`: what was named, the verdict, the records' changing torque
    zeros and whether that is what the expectation asks (`changing`: the joint's spread named and the verdict
    `unexplained_structure`)."""
    rows = []
    for system, label, per_record, validation, expect in several_records_cases():
        plant, dg = diagnose_records(system, per_record, validation, seed)
        truth = per_record[0][0] if per_record[0] else None
        drift = dg.info["changing_offsets"]
        if expect == "changing":
            assert truth is not None
            ok = dg.verdict == "unexplained_structure" and [d["joint"] for d in drift] == [truth.joint]
        else:
            ok = not drift and _ok(expect, truth, dg, plant)
        rows.append(
            {
                "system": system,
                "truth": label,
                "expect": expect,
                "named_first": dg.findings[0].name if dg.findings else "-",
                "verdict": dg.verdict,
                "changing": "; ".join(f"{d['joint']} {d['spread']:.3g} N m" for d in drift) or "-",
                "ok": bool(ok),
            }
        )
        print(system, label, rows[-1]["named_first"], dg.verdict, rows[-1]["changing"], ok, flush=True)
    return rows


def several_markdown(rows: list[dict[str, Any]]) -> str:
    lines = [
        "| system | hidden (3 training records) | expected | named first | verdict | torque zeros changing | ok |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['system']} | {r['truth']} | {r['expect']} | {r['named_first']} | {r['verdict']} | "
            f"{r['changing']} | {'yes' if r['ok'] else '**no**'} |"
        )
    return "\n".join(lines)


def hidden_effect_table(seed: int = 0) -> list[dict[str, Any]]:
    """One row per case of `hidden_effect_cases`: truth, what was named, verdict, validation RMS."""
    rows = []
    for system, effects, expect in hidden_effect_cases():
        plant, dg = diagnose_case(system, effects, seed)
        rows.append(_row(system, effects[0] if effects else None, expect, plant, dg))
    return rows


def arm_effect_table(robots: str | Path, folder: str | Path, seeds: range = range(4)) -> list[dict[str, Any]]:
    """One row per arm of `ARMS` and case of `arm_cases`, the arm read from `robots`/<arm>.xml and driven by
    torque (`torque_driven`, written into `folder`): the row of the first seed, and in `z_seeds` the
    (value - truth) / std of every seed where the hidden effect is named first (None where it is not)."""
    rows = []
    for arm, settings in ARMS.items():
        path = torque_driven(Path(robots) / f"{arm}.xml", folder)
        for effects in arm_cases(arm):
            runs = [diagnose_case(arm, effects, seed, mjcf=path, settings=settings) for seed in seeds]
            rows.append(_seeds_row(arm, effects, runs, seeds))
    return rows


def pinocchio_cases(arm: str) -> list[tuple[list[Injected], str]]:
    """(effects, expectation) `pinocchio_table` hides in a built-in system of `SYSTEMS` or an arm of `ARMS`:
    clean first, then effects in and out of the vocabulary, on joints from the base to the wrist."""
    if arm in SYSTEMS:
        return {
            "pendulum": [([], "clean"), ([Injected("viscous_friction", "swing", 0.01)], "named")],
            "two_link": [
                ([], "clean"),
                ([Injected("viscous_friction", "elbow", 0.02)], "named"),
                ([Injected("coulomb_friction", "shoulder", 0.08)], "named"),
                ([Injected("armature", "elbow", 0.004)], "named"),
                ([Injected("time_delay", "shoulder", 0.006)], "named"),
                ([Injected("torque_offset", "shoulder", 0.08)], "named"),
                ([Injected("cogging", "shoulder", 0.08, 6.0)], "named"),
                ([Injected("stribeck_friction", "elbow", 0.08, 0.1)], "named"),
                ([Injected("quadratic_drag", "shoulder", 0.03)], "unexplained"),
                ([Injected("torque_disturbance", "elbow", 0.1, 0.37)], "unexplained"),
            ],
            "arm3": [
                ([], "clean"),
                ([Injected("viscous_friction", "pitch", 0.1)], "named"),
                ([Injected("coulomb_friction", "elbow", 0.1)], "named"),
                ([Injected("quadratic_drag", "yaw", 0.1)], "unexplained"),
            ],
            "wheel_pendulum": [([], "clean"), ([Injected("coulomb_friction", "wheel", 0.01)], "named")],
        }[arm]
    j = {
        "ur5e": ("shoulder_lift_joint", "elbow_joint", "wrist_1_joint"),
        "panda_nohand": ("joint2", "joint4", "joint6"),
        "gen3": ("joint_2", "joint_4", "joint_6"),
    }[arm]
    big = 1.0 if arm == "ur5e" else 0.5  # as `arm_cases`
    return [
        ([], "clean"),
        ([Injected("viscous_friction", j[1], big)], "named"),
        ([Injected("coulomb_friction", j[0], 2.0 * big)], "named"),
        ([Injected("armature", j[2], 0.1 * big)], "named"),
        ([Injected("torque_gain", j[0], 0.1)], "named"),
        ([Injected("quadratic_drag", j[1], big)], "unexplained"),
    ]


# the Menagerie arms of `pinocchio_table`'s hidden effects: the xArm7 has a row of its own (`_narrowed_friction_row`),
# its frictionloss at MuJoCo's default solver parameters a ramp 7.7 rad/s wide on its last joint, which a plant with
# hardware's friction does not have (the discrepancy there is that friction), and that friction sharp on its light
# last link needs a 40 kHz step
PINOCCHIO_ARMS = ("ur5e", "panda_nohand", "gen3")


def pinocchio_table(robots: str | Path, folder: str | Path, seeds: range = range(4)) -> list[dict[str, Any]]:
    """One row per built-in system and arm of `PINOCCHIO_ARMS` (from `robots`, driven by torque through
    `torque_driven`, written into `folder`) and case of `pinocchio_cases`, every record made by
    `pinocchio_rollout` (10 s to train on, 5 s to validate): the row of the first seed, with `z_seeds` and
    `ok_seeds` of every seed as in `arm_effect_table`; then the xArm7's row (`_narrowed_friction_row`)."""
    rows = []
    models = {s: load_plant(s).path for s in SYSTEMS} | {
        a: torque_driven(Path(robots) / f"{a}.xml", folder) for a in PINOCCHIO_ARMS
    }
    for system, path in models.items():
        generate = partial(pinocchio_rollout, path, settings=SYSTEMS.get(system) or ARMS[system])
        for effects, expect in pinocchio_cases(system):
            runs = [diagnose_case(system, effects, seed, generate=generate) for seed in seeds]
            rows.append(_seeds_row(system, effects, runs, seeds, expect))
    return [*rows, _narrowed_friction_row(robots, folder, seeds)]


def _narrowed_friction_row(robots: str | Path, folder: str | Path, seeds: range) -> dict[str, Any]:
    """The xArm7, clean, in the Pinocchio plant with hardware's friction on every joint (1 N m tanh(dq / 0.05), at
    40 kHz, which that friction on the 1e-4 kg m^2 last link asks for) against its MJCF's frictionloss, a ramp 7.7
    rad/s wide on joint 7 at MuJoCo's default solver parameters: the plant's friction is the discrepancy, to be
    named as joint 7's friction in a narrower shape (`friction_ramp`) at the plant's 1 N m. A row as `_seeds_row`
    makes, its truth that friction."""
    arm = "xarm7_nohand"
    path = torque_driven(Path(robots) / f"{arm}.xml", folder)
    generate = partial(pinocchio_rollout, path, settings=ARMS[arm], friction_width=0.05, physics_hz=40000.0)
    runs = [diagnose_case(arm, [], seed, generate=generate) for seed in seeds]
    row = _seeds_row(arm, [], runs, seeds, "named", Expected("friction_ramp", "joint7", 1.0))
    row["truth"] = f"hardware friction: {row['truth']}"
    return row


# two more Menagerie arms logged through their own servos (`servo_log_table`), clean only: the iiwa14 (servo kv
# 200 on every joint, implicitfast at 2 ms) and the SO-ARM100 (frictionloss 0.1 N m, MuJoCo's default Euler, which
# takes nothing of its servos implicitly)
SERVO_ONLY: dict[str, TestbedSystem] = {
    "iiwa14": _arm(_SEVEN_AMPLITUDE, (0.0,) * 7, (0.0,) * 7, _SEVEN_NOISE, (0.0, 0.3, 0.0, -1.5, 0.0, 1.0, 0.0)),
    "so_arm100": _arm(
        (0.4, 0.3, 0.4, 0.4, 0.5, 0.3), (0.0,) * 6, (0.0,) * 6, (0.005,) * 6, (0.0, -1.5, 1.5, 0.0, 0.0, 0.8)
    ),
}


def servo_log_cases(arm: str) -> list[list[Injected]]:
    """The effects `servo_log_table` hides in an arm of `ARMS` (the clean case first): in the plant and in the
    sensor, on joints from the base to the wrist (those of `arm_cases`); the clean case alone for `SERVO_ONLY`."""
    if arm in SERVO_ONLY:
        return [[]]
    cases = arm_cases(arm)
    return [cases[0], cases[1], cases[4], cases[6]]  # clean, viscous, armature, torque gain


def servo_log_table(robots: str | Path, seeds: range = range(2)) -> list[dict[str, Any]]:
    """One row per arm of `ARMS` and `SERVO_ONLY` and case of `servo_log_cases`: each arm as it comes in
    `robots`/<arm>.xml, through its own position servos at its own integrator and step, logged as MuJoCo users
    log it (`servo_log`: 10 s to train on, 5 s to validate, 500 Hz), diagnosed with the step read from the data
    (`diagnose(mujoco_steps=None)`); `z_seeds` and `ok_seeds` as in `arm_effect_table`, `steps_seeds` the
    reading of each seed (read, scale, its std, positions after the step; None where the step adds nothing to
    read). Each arm is logged clean with the positions after each step too (`servo_log(positions="after")`)."""
    rows = []
    for arm, settings in {**ARMS, **SERVO_ONLY}.items():
        path = Path(robots) / f"{arm}.xml"
        cases = [(effects, "before") for effects in servo_log_cases(arm)] + [([], "after")]
        for effects, positions in cases:
            generate = partial(
                servo_log,
                path,
                center=settings.center,
                amplitude=settings.amplitude,
                sigma_tau=settings.sigma_tau,
                rate_hz=500.0,
                positions=positions,
            )
            runs = [diagnose_case(arm, effects, seed, generate=generate) for seed in seeds]
            row = _seeds_row(arm, effects, runs, seeds)
            if positions == "after":
                row["truth"] += " (positions logged after each step)"
            row["steps_seeds"] = [
                None
                if dg.info["mujoco_steps"] is None
                else [dg.info["mujoco_steps"][k] for k in ("read", "scale", "scale_std", "positions_after_step")]
                for _, dg in runs
            ]
            rows.append(row)
    return rows


def servo_log_markdown(rows: list[dict[str, Any]]) -> str:
    """`hidden_markdown`'s table for `servo_log_table`, with how the first seed's records were read."""
    lines = [
        "| system | hidden | read as MuJoCo's steps: scale ± std | named first | value ± std | (value − truth) / std | "
        "verdict | ok (seeds) |",
        "|---|---|---|---|---:|---:|---|---|",
    ]
    for r in rows:
        steps = r["steps_seeds"][0]
        read = "-" if steps is None else f"{'yes' if steps[0] else 'no'}: {steps[1]:.4f} ± {steps[2]:.1g}"
        if steps is not None and steps[3]:
            read += ", positions after the step"
        value = "-" if r["value"] is None else f"{r['value']:.4g} ± {r['std']:.2g}"
        z = "-" if r.get("z") is None else f"{r['z']:+.1f}"
        oks = f"{sum(r['ok_seeds'])} of {len(r['ok_seeds'])}"
        lines.append(
            f"| {r['system']} | {r['truth']} | {read} | {r['named_first']} | {value} | {z} | {r['verdict']} | {oks} |"
        )
    ok = sum(sum(r["ok_seeds"]) for r in rows)
    total = sum(len(r["ok_seeds"]) for r in rows)
    zs = [z for r in rows for z in r["z_seeds"] if z is not None]
    lines += [
        "",
        f"Over seeds {rows[0]['seeds'][0]}-{rows[0]['seeds'][-1]}: {ok} of {total} diagnoses as expected; of the "
        f"{len(zs)} values where the hidden effect is named first, {sum(abs(z) <= 1 for z in zs)} lie within 1 std "
        f"of the truth and {sum(abs(z) <= 2 for z in zs)} within 2.",
    ]
    return "\n".join(lines)


def _seeds_row(
    system: str,
    effects: list[Injected],
    runs: list[tuple[Plant, Any]],
    seeds: range,
    expect: str | None = None,
    expected: Expected | None = None,
) -> dict[str, Any]:
    """The row of the first seed's (plant, diagnosis), with in `z_seeds` the (value - truth) / std of every seed
    where the hidden effect (or the finding `expected` where none is hidden) is named first (None where it is not)
    and in `ok_seeds` whether each is as `expect`ed (None: `named`, or `clean` without effects)."""
    truth: Injected | Expected | None = expected or (effects[0] if effects else None)
    row = _row(system, truth, expect or ("named" if truth else "clean"), *runs[0])
    row["z_seeds"] = [_z(dg.findings[0] if dg.findings else None, truth, plant) for plant, dg in runs]
    row["ok_seeds"] = [_ok(row["expect"], truth, dg, plant) for plant, dg in runs]
    row["seeds"] = list(seeds)
    return row


def _row(system: str, truth: Injected | Expected | None, expect: str, plant: Plant, dg: Any) -> dict[str, Any]:
    """A table row: truth, what was named first with its value, the verdict and the validation RMS."""
    first = dg.findings[0] if dg.findings else None
    joint = plant.joint_names.index(truth.joint) if truth else int(np.argmax(plant.actuated))
    name = plant.joint_names[joint]
    row = {
        "system": system,
        "truth": f"{truth.effect} {truth.joint} {truth.size:g}" if truth else "none",
        "expect": expect,
        "named_first": first.name if first else "-",
        "value": first.value if first else None,
        "std": first.std if first else None,
        "z": _z(first, truth, plant),
        "verdict": dg.verdict,
        "findings": [f.name for f in dg.findings],
        "nominal_rms": dg.models["nominal"]["torque_rms"][name],
        "calibrated_rms": dg.models["calibrated"]["torque_rms"][name],
        "joint": name,
        "ok": _ok(expect, truth, dg, plant),
    }
    print(row["system"], row["truth"], row["named_first"], dg.verdict, row["ok"], flush=True)
    return row


def _z(first: Any, truth: Injected | Expected | None, plant: Plant) -> float | None:
    """(value - truth) / std of the first finding where it is the hidden effect itself (its headline value the
    injected size; a gain's is 1 + size), on its joint (or among the equivalent ones it names), with a std; None
    otherwise (an armature named on joint 7 for one hidden on joint 6 says nothing of that one's size)."""
    if first is None or truth is None or first.effect != truth.effect or not (first.std and np.isfinite(first.std)):
        return None
    if (truth.effect, _target(truth, plant)) not in _names(first):
        return None
    return float((first.value - truth.value) / first.std)


def _target(truth: Injected | Expected, plant: Plant) -> str:
    """What a finding of the hidden effect names: its joint, or for a payload the joint's body."""
    return plant.body_names[plant.joint_names.index(truth.joint)] if truth.effect == "payload" else truth.joint


def _names(f: Any) -> set[tuple[str, str]]:
    """(effect, target) of a finding and of the alternatives it is confounded with."""
    return {(f.effect, f.target)} | {(c["effect"], c["target"]) for c in f.confounded_with}


def _ok(expect: str, truth: Injected | Expected | None, dg: Any, plant: Plant) -> bool:
    if expect == "clean":
        return bool(dg.verdict == "no_discrepancy")
    if expect == "unexplained":
        return bool(dg.verdict == "unexplained_structure")
    assert truth is not None
    if not dg.findings:
        return False
    return (truth.effect, _target(truth, plant)) in _names(dg.findings[0]) and dg.verdict in (
        "explained",
        "unexplained_structure",
    )


def hidden_markdown(rows: list[dict[str, Any]]) -> str:
    """The table, with (value - truth) / std where the first finding is the hidden effect itself, and a line
    counting those within 3 std (`ok` judges the name and the verdict only)."""
    lines = [
        "| system | hidden | expected | named first | value ± std | (value − truth) / std | verdict | "
        "RMS nominal → calibrated [N m] | ok |",
        "|---|---|---|---|---:|---:|---|---:|---|",
    ]
    for r in rows:
        value = "-" if r["value"] is None else f"{r['value']:.4g} ± {r['std']:.2g}"
        z = "-" if r.get("z") is None else f"{r['z']:+.1f}"
        rms = f"{r['joint']}: {r['nominal_rms']:.4f} → {r['calibrated_rms']:.4f}"
        lines.append(
            f"| {r['system']} | {r['truth']} | {r['expect']} | {r['named_first']} | {value} | {z} | {r['verdict']} | "
            f"{rms} | {'yes' if r['ok'] else '**no**'} |"
        )
    zs = [(r["z"], r["truth"]) for r in rows if r.get("z") is not None]
    if zs:
        within = sum(abs(z) <= 3 for z, _ in zs)
        off = ", ".join(f"{t} ({z:+.1f})" for z, t in zs if abs(z) > 3) or "none"
        head = "Values within 3 std of the truth where the hidden effect is named first"
        lines += ["", f"{head}: {within} of {len(zs)}; beyond: {off}."]
    seeds = [r for r in rows if "ok_seeds" in r]
    if seeds:
        every = [z for r in seeds for z in r["z_seeds"] if z is not None]
        used = seeds[0]["seeds"]
        named = sum(len(r["ok_seeds"]) for r in seeds)
        lines += [
            "",
            f"Over seeds {used[0]}-{used[-1]}: {sum(sum(r['ok_seeds']) for r in seeds)} of {named} "
            f"diagnoses as expected; of the {len(every)} values where the hidden effect is named first, "
            f"{sum(abs(z) <= 1 for z in every)} lie within 1 std of the truth and {sum(abs(z) <= 2 for z in every)} "
            "within 2 (68 % and 95 % if the stds are honest).",
        ]
    return "\n".join(lines)


# The DFKI drivers' CAN frames: angles as 16 bits over +-12.5 rad, torques as 12 bits over +-12 N m
DFKI_ANGLE_QUANTUM = 25.0 / 2**16  # [rad]
DFKI_TORQUE_QUANTUM = 24.0 / 2**12  # [N m]
# (shoulder, elbow) torque amplitudes [N m] and angular frequency [rad/s] of the open-loop records, as the lab
# drove the arm (A sin(w t) on the shoulder, A cos(w t) on the elbow); the last one validates. The 7 rad/s record
# gives the fit a second frequency: with it at 10 or 13 rad/s like the others, model 3.0's viscous frictions are no
# longer named and its verdict is unexplained_structure. It is near the frictionless arm's resonance: the clean plant
# spins through 20 rad there, past the MJCF's joint range, which the measured-data reader would refuse in a file
# (the lab's form and the diagnosis's inverse dynamics have no limits, so the clean case stays clean)
LAB_RECORDS = (((0.4, 0.8), 10.0), ((0.6, 0.6), 10.0), ((0.8, 0.3), 7.0), ((0.6, 0.4), 10.0))


def author_params_of(plant: Plant, gear: float = 1000.0) -> dict[str, float]:
    """The two-link MJCF's own numbers in the DFKI lab's model form (`identify.diagnose.authors`): the plant
    without friction, so that `lab_rollout` of these is clean data of the nominal model from another generator.

    Their form puts the rotor inertia Ir through the gear ratio gr on both joints (gr^2 Ir, the armature) and an
    off-diagonal -gr Ir; the MJCF's equal armatures a are Ir = a / gr^2 at a `gear` large enough that the
    coupling a / gr is negligible (2e-6 kg m^2 at 1000).

    Raises:
        ValueError: the model is not a planar two-link arm about parallel y axes with equal armatures.
    """
    m = plant.mj_model
    if plant.nv != 2 or m.nbody != 3 or not np.allclose(m.jnt_axis, [0.0, 1.0, 0.0]):
        raise ValueError(f"{plant.name}: the lab's form needs a planar two-link arm about parallel y axes")
    if not np.isclose(m.dof_armature[0], m.dof_armature[1]):
        raise ValueError(f"{plant.name}: the lab's form has one rotor inertia, the joints' armatures differ")

    def about_axis(b: int) -> tuple[float, float, float]:  # (mass, COM distance below the joint, I about the axis)
        flat = np.zeros(9)
        mujoco.mju_quat2Mat(flat, m.body_iquat[b])
        rot = flat.reshape(3, 3)
        x, _, z = m.body_ipos[b]
        mass = float(m.body_mass[b])
        return mass, float(-z), float((rot @ np.diag(m.body_inertia[b]) @ rot.T)[1, 1] + mass * (x * x + z * z))

    (m1, r1, i1), (m2, r2, i2) = about_axis(1), about_axis(2)
    if not np.allclose(m.body_ipos[1:, 0], 0.0) or not np.allclose(m.body_pos[2, :2], 0.0):
        raise ValueError(f"{plant.name}: the lab's form has no lateral centre of mass or elbow offset")
    return {
        "I1": i1,
        "I2": i2,
        "Ir": float(m.dof_armature[0]) / gear**2,
        "b1": float(m.dof_damping[0]),
        "b2": float(m.dof_damping[1]),
        "cf1": 0.0,
        "cf2": 0.0,
        "g": float(-m.opt.gravity[2]),
        "gr": gear,
        "l1": float(-m.body_pos[2, 2]),
        "l2": float("nan"),  # not in the equations
        "m1": m1,
        "m2": m2,
        "r1": r1,
        "r2": r2,
    }


def lab_rollout(
    params: dict[str, float],
    amplitudes: tuple[float, float],
    omega: float,
    *,
    rng: np.random.Generator,
    duration_s: float = 10.0,
    rate_hz: float = 500.0,
    sigma_tau: float = 0.005,
    joint_names: tuple[str, ...] = ("shoulder", "elbow"),
    source: str = "lab_model",
    sensor: Sequence[Injected] = (),
) -> tuple[Dataset, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The lab's analytic model (`author_accel`) integrated by SciPy (LSODA, rtol 1e-9) from rest at the bottom
    under open-loop torques (A1 sin(w t), A2 cos(w t)), the torque logged at the instant with white noise
    `sigma_tau` and both signals quantised as the DFKI drivers send them, after the `sensor` effects (of
    `SENSOR_EFFECTS`: what the plant does is in `params`).

    Returns:
        (the measured record; the exact (q, dq, ddq) at its samples, each (N, 2)).
    """
    amp = np.asarray(amplitudes, float)
    plant_side = [e.effect for e in sensor if e.effect not in SENSOR_EFFECTS]
    if plant_side:
        raise ValueError(
            f"lab_rollout: {plant_side} act on the plant, set them in its parameters; sensor effects: "
            f"{', '.join(SENSOR_EFFECTS)}"
        )

    def torque(t: np.ndarray) -> np.ndarray:
        return np.column_stack([amp[0] * np.sin(omega * t), amp[1] * np.cos(omega * t)])

    def rhs(t: float, x: np.ndarray) -> np.ndarray:
        return np.concatenate([x[2:], author_accel(params, x[None, :2], x[None, 2:], torque(np.array([t])))[0]])

    time = np.arange(int(round(duration_s * rate_hz))) / rate_hz
    sol = solve_ivp(rhs, (0.0, time[-1]), np.zeros(4), t_eval=time, method="LSODA", rtol=1e-9, atol=1e-11)
    if not sol.success:
        raise RuntimeError(f"lab_rollout: the integration failed ({sol.message})")
    q, dq = sol.y[:2].T, sol.y[2:].T
    tau = torque(time)
    ddq = author_accel(params, q, dq, tau)
    q_seen, tau_seen = _sensed(joint_names, sensor, time, q, tau)
    noisy = tau_seen + rng.normal(0.0, sigma_tau, tau.shape)
    data = Dataset(
        time=time,
        q=np.round(q_seen / DFKI_ANGLE_QUANTUM) * DFKI_ANGLE_QUANTUM,
        tau=np.round(noisy / DFKI_TORQUE_QUANTUM) * DFKI_TORQUE_QUANTUM,
        joint_names=joint_names,
        actuated=np.ones(2, bool),
        source=source,
        meta={"generator": "identify.diagnose.testbed.lab_rollout", "amplitudes": amp.tolist(), "omega": omega},
    )
    return data, (q, dq, ddq)


def diagnose_lab_model(
    params: dict[str, float], seed: int = 0, sensor: Sequence[Injected] = (), **kwargs: Any
) -> tuple[Plant, Any, dict[str, Any]]:
    """`lab_rollout` of `params` (and `sensor` effects) for each of `LAB_RECORDS` (three to train on, the last to
    validate), diagnosed against the two-link MJCF as the DFKI logs are (10 Hz states, 5 Hz band; `kwargs` pass on
    to `diagnose`).

    Returns:
        (the nominal plant, the diagnosis, what the truth says: `model_error` (nv,) RMS [N m] of the calibrated
        MJCF's torque against the lab model's on the exact validation states, and `truth` the Coulomb level
        cf pi / 2 and viscous b of each joint).
    """
    from identify.diagnose.calibrate import mjcf_measured_torque  # the generator needs neither
    from identify.diagnose.diagnosis import diagnose

    plant = load_plant("two_link")
    rngs = np.random.default_rng(seed).spawn(len(LAB_RECORDS))
    records = [
        lab_rollout(params, amps, omega, rng=r, joint_names=plant.joint_names, source=f"lab_model_{i}", sensor=sensor)
        for i, ((amps, omega), r) in enumerate(zip(LAB_RECORDS, rngs, strict=True))
    ]
    kwargs.setdefault("derivative_options", {"cutoff_hz": 10.0})
    kwargs.setdefault("band_hz", 5.0)
    dg = diagnose(plant, [d for d, _ in records[:-1]], [records[-1][0]], rng=np.random.default_rng(0), **kwargs)
    val, (q, dq, ddq) = records[-1]
    model = mujoco.MjModel.from_xml_string(dg.calibrated_xml)  # the two-link arm's file names no asset
    # what the sensors report of the plant's torque, against what the calibrated MJCF says they report at the
    # angles the encoders read
    q_seen, reported = _sensed(plant.joint_names, sensor, val.time, q, author_torque(params, q, dq, ddq))
    error = mjcf_measured_torque(model, val.time, q_seen, dq, ddq) - reported
    truth = {
        name: {"coulomb_friction": params[f"cf{j + 1}"] * np.pi / 2, "viscous_friction": params[f"b{j + 1}"]}
        | {e.effect: e.value for e in sensor if e.joint == name}
        for j, name in enumerate(plant.joint_names)
    }
    return plant, dg, {"model_error": np.sqrt(np.mean(error**2, axis=0)), "truth": truth}


def lab_model_table(models: dict[str, Path], seed: int = 0) -> list[dict[str, Any]]:
    """One row per plant: the nominal MJCF's own numbers (`author_params_of`, clean) and each of the lab's parameter
    files in `models` (label -> yml): the verdict, the findings with (value - truth) / std where the truth knows
    the effect (Coulomb level cf pi / 2, viscous b), the calibrated MJCF's torque error against the plant's own on
    the exact validation states, and the validation RMS against the measured torque."""
    plants = {"nominal MJCF (clean)": author_params_of(load_plant("two_link"))}
    plants.update({label: load_author_model(path) for label, path in models.items()})
    rows = []
    for label, params in plants.items():
        _, dg, truth = diagnose_lab_model(params, seed)
        findings = []
        for f in dg.findings:
            known = truth["truth"].get(f.target, {}).get(f.effect)
            z = (f.value - known) / f.std if known is not None and f.std and np.isfinite(f.std) else None
            findings.append({"name": f.name, "value": f.value, "std": f.std, "truth": known, "z": z})
        rows.append(
            {
                "plant": label,
                "verdict": dg.verdict,
                "findings": findings,
                "model_error": truth["model_error"].tolist(),
                "nominal_rms": list(dg.models["nominal"]["torque_rms"].values()),
                "calibrated_rms": list(dg.models["calibrated"]["torque_rms"].values()),
            }
        )
        print(label, dg.verdict, [f["name"] for f in findings], flush=True)
    return rows


def lab_markdown(rows: list[dict[str, Any]]) -> str:
    """The table of `lab_model_table`, and a line counting the values within 3 std of the truth."""
    lines = [
        "| plant | verdict | findings: value ± std (truth, z) | calibrated − plant on exact states [N m] | "
        "RMS nominal → calibrated [N m] |",
        "|---|---|---|---:|---:|",
    ]
    zs = []
    for r in rows:
        cells = []
        for f in r["findings"]:
            text = f"{f['name'].split(' or ')[0]} {f['value']:.4g} ± {f['std']:.2g}"
            if f["z"] is not None:
                text += f" ({f['truth']:.4g}, {f['z']:+.1f})"
                zs.append(f["z"])
            cells.append(text)
        error = " / ".join(f"{v:.4f}" for v in r["model_error"])
        rms = " / ".join(f"{a:.4f} → {b:.4f}" for a, b in zip(r["nominal_rms"], r["calibrated_rms"], strict=True))
        lines.append(f"| {r['plant']} | {r['verdict']} | {'; '.join(cells) or '-'} | {error} | {rms} |")
    if zs:
        lines += ["", f"Friction values within 3 std of the plant's: {sum(abs(z) <= 3 for z in zs)} of {len(zs)}."]
    return "\n".join(lines)

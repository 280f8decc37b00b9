"""The library of candidate effects: each one's regressor columns, value, unit and MuJoCo counterpart.

The residual r = tau_measured - tau_nominal is explained, to first order, by a sum of effect columns
times unknown coefficients (one group of columns per effect and joint or body):

    effect            columns on the rows of joint j           value (unit)               counterpart
    armature          ddq_j                                    c (kg m^2)                 joint `armature`
    viscous_friction  dq_j                                     c (N m s/rad)              joint `damping`
    coulomb_friction  sign(dq_j)                               c (N m)                    joint `frictionloss`
    joint_stiffness   q_j - springref_j, 1                     k = c0 (N m/rad)           `stiffness`, `springref`
    torque_offset     1                    (actuated only)     c (N m)                    actuator `biasprm`
    torque_gain       tau_nominal_j        (actuated only)     1 + c (measured / true)    actuator `gainprm`
    time_delay        -d tau_nominal_j/dt  (actuated only)     c (s)                      custom numeric
    joint_offset      -d tau_nominal/d q_j (every row)         c (rad)                    joint `ref`
    rotor_coupling    ddq_i in tau_j, ddq_j in tau_i (i: the   rho = Ir gr (kg m^2)       child and parent `inertial`,
                      ancestor joints of j, parallel axes)                               joint `armature` (exact)
    payload           the body's identifiable inertial cols    added mass (kg)            body `inertial`
    rigid_body        the base rigid-body columns              RMS torque change (N m)    every `inertial`

`rotor_coupling` is the rotor of the motor that drives joint j, its stator on the parent link: the rotor turns
at (the parent's angular velocity + gr dq_j), so its kinetic energy 1/2 Ir (w_parent + gr dq_j)^2 adds the
`armature` Ir gr^2 on joint j (the nominal MJCF has it) and an off-diagonal inertia Ir gr between joint j and
every ancestor joint, which no joint attribute holds (the DFKI double pendulum's elbow motor sits at the end
of link 1: M12 += Ir gr). The sign of rho follows the gear's sense of rotation (the DFKI authors write -gr Ir).

Sensor-side effects are linearised about the nominal torque: exact to first order in their size, which is
what decides between candidates; the calibrated model then applies them exactly.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy import signal as sp_signal

from dynamics.base import base_parameters
from dynamics.plant import INERTIAL_SYMBOLS, Plant
from dynamics.regressor import ParameterModel, rigid_body_regressor
from dynamics.sampling import independent_columns, random_states
from dynamics.torque import joint_torque, torque_jacobian_q
from envs.dataset import Dataset
from identify.derivatives import States

__all__ = ["CANDIDATE_EFFECTS", "Candidate", "Signals", "candidates", "rotor_chain", "signals", "stack_signals"]


@dataclass(frozen=True)
class Signals:
    """What the candidates' columns are built from, on the trusted rows of one or more records.

    Attributes:
        time: (N,) sample times [s].
        q, dq, ddq: (N, nv) filtered joint states [rad, rad/s, rad/s^2].
        tau: (N, nv) measured joint torque [N m] (0 on unactuated joints).
        tau_nominal: (N, nv) the nominal MJCF's torque along the motion [N m].
        dtau_dq: (N, nv, nv) d tau_nominal_i / d q_j [N m/rad].
        dtau_dt: (N, nv) time derivative of tau_nominal [N m/s].
        regressor: (N, nv, 10 nv) rigid-body regressor (standard parameters).
        record: (N,) index of the record each row comes from.
        actuated: (nv,) True where the joint torque is measured.
        band_hz: parallel low-pass [Hz] applied, record by record, to the measured torque and to every
            model output or column before they are compared (None: none). Filtering both sides of
            tau = Y theta alike keeps the equation exact while removing what no rigid model predicts
            (structural vibration, current ripple); every model is judged in the same band.
    """

    time: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    tau: np.ndarray
    tau_nominal: np.ndarray
    dtau_dq: np.ndarray
    dtau_dt: np.ndarray
    regressor: np.ndarray
    record: np.ndarray
    actuated: np.ndarray
    band_hz: float | None = None

    @property
    def residual(self) -> np.ndarray:
        """(N, nv) measured minus nominal torque [N m], in the analysis band."""
        return self.smooth(self.tau - self.tau_nominal)

    def smooth(self, x: np.ndarray) -> np.ndarray:
        """(N, ...) -> the same low-passed at `band_hz`, record by record (identity when band_hz is None)."""
        if self.band_hz is None:
            return x
        fs = 1.0 / float(np.median(np.diff(self.time)))
        sos = sp_signal.butter(4, min(self.band_hz, 0.45 * fs), fs=fs, output="sos")
        out = np.empty_like(x, dtype=float)
        for r in np.unique(self.record):
            rows = self.record == r
            out[rows] = sp_signal.sosfiltfilt(sos, x[rows], axis=0)
        return out

    def columns(self, candidate: Candidate) -> np.ndarray:
        """(N, nv, k) the candidate's columns in the analysis band."""
        return self.smooth(candidate.build(self))

    @property
    def n_samples(self) -> int:
        return len(self.time)


def signals(plant: Plant, data: Dataset, states: States, *, record: int = 0, band_hz: float | None = None) -> Signals:
    """The signals of one record on the rows its derivative filter trusts (a contiguous block)."""
    rows = np.flatnonzero(states.valid)
    if rows.size < 10:
        raise ValueError(f"{data.source}: only {rows.size} trusted rows after filtering; the record is too short")
    rows = np.arange(rows[0], rows[-1] + 1)
    q, dq, ddq = states.q[rows], states.dq[rows], states.ddq[rows]
    time = data.time[rows]
    tau_nom = joint_torque(plant, q, dq, ddq)[0]
    return Signals(
        time=time,
        q=q,
        dq=dq,
        ddq=ddq,
        tau=np.where(plant.actuated, data.tau[rows], 0.0),
        tau_nominal=tau_nom,
        dtau_dq=torque_jacobian_q(plant, q, dq, ddq),
        dtau_dt=np.gradient(tau_nom, time, axis=0),
        regressor=rigid_body_regressor(plant, q, dq, ddq),
        record=np.full(len(rows), record),
        actuated=np.asarray(plant.actuated, dtype=bool),
        band_hz=band_hz,
    )


def stack_signals(parts: list[Signals]) -> Signals:
    """Rows of several records, one after the other."""
    if not parts:
        raise ValueError("no records to stack")
    fields = ("time", "q", "dq", "ddq", "tau", "tau_nominal", "dtau_dq", "dtau_dt", "regressor", "record")
    stacked = {f: np.concatenate([getattr(p, f) for p in parts]) for f in fields}
    return Signals(**stacked, actuated=parts[0].actuated, band_hz=parts[0].band_hz)


@dataclass(frozen=True)
class Candidate:
    """One candidate explanation: an effect on one joint (or body), with its columns.

    Attributes:
        effect: the effect's name (DESIGN.md's names; `rigid_body` for the re-identified inertials).
        target: joint name, body name, or "" for the whole model.
        unit: unit of `value`.
        counterpart: where it goes in the calibrated model.
        parameter_names: (k,) names of its coefficients.
        build: signals -> (N, nv, k) columns.
        value: (coef (k,), cov (k, k), columns (N, nv, k)) -> (value, std) in `unit`.
        minimum: smallest physical value (a joint's damping, friction, armature or stiffness cannot end
            below zero); a fit below it rejects the candidate rather than forcing a wrong name.
    """

    effect: str
    target: str
    unit: str
    counterpart: str
    parameter_names: tuple[str, ...]
    build: Callable[[Signals], np.ndarray]
    value: Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[float, float]]
    minimum: float = -np.inf

    @property
    def key(self) -> str:
        return f"{self.effect}:{self.target}" if self.target else self.effect


def _first(coef: np.ndarray, cov: np.ndarray, _: np.ndarray) -> tuple[float, float]:
    return float(coef[0]), float(np.sqrt(max(cov[0, 0], 0.0)))


def _gain(coef: np.ndarray, cov: np.ndarray, _: np.ndarray) -> tuple[float, float]:
    return 1.0 + float(coef[0]), float(np.sqrt(max(cov[0, 0], 0.0)))


def _torque_rms(coef: np.ndarray, cov: np.ndarray, cols: np.ndarray) -> tuple[float, float]:
    """RMS of the torque change the coefficients make, with its delta-method std."""
    A = cols.reshape(-1, cols.shape[-1])
    change = A @ coef
    rms = float(np.sqrt(np.mean(change**2)))
    if rms == 0:
        return 0.0, float("nan")
    grad = A.T @ change / (len(change) * rms)
    return rms, float(np.sqrt(max(grad @ cov @ grad, 0.0)))


def _own_row(nv: int, j: int, signal: Callable[[Signals], np.ndarray]) -> Callable[[Signals], np.ndarray]:
    def build(s: Signals) -> np.ndarray:
        out = np.zeros((s.n_samples, nv, 1))
        out[:, j, 0] = signal(s)
        return out

    return build


def _joint_effects(plant: Plant) -> list[Candidate]:
    nv, out = plant.nv, []
    table: list[tuple[str, str, str, str, Callable[[Signals, int], np.ndarray], bool]] = [
        ("armature", "kg m^2", "joint armature", "Ia", lambda s, j: s.ddq[:, j], False),
        ("viscous_friction", "N m s/rad", "joint damping", "Fv", lambda s, j: s.dq[:, j], False),
        ("coulomb_friction", "N m", "joint frictionloss", "Fc", lambda s, j: np.sign(s.dq[:, j]), False),
        ("torque_offset", "N m", "actuator biasprm", "off", lambda s, j: np.ones(s.n_samples), True),
        ("torque_gain", "1", "actuator gainprm", "dgain", lambda s, j: s.tau_nominal[:, j], True),
        ("time_delay", "s", "custom numeric (sensor side)", "delay", lambda s, j: -s.dtau_dt[:, j], True),
    ]
    nominal = {"armature": plant.armature, "viscous_friction": plant.damping, "coulomb_friction": plant.frictionloss}
    for j, name in enumerate(plant.joint_names):
        for effect, unit, counterpart, symbol, signal, actuated_only in table:
            if actuated_only and not plant.actuated[j]:
                continue
            value = _gain if effect == "torque_gain" else _first
            build = _own_row(nv, j, lambda s, j=j, f=signal: f(s, j))  # type: ignore[misc]
            minimum = -float(nominal[effect][j]) if effect in nominal else (0.0 if effect == "torque_gain" else -np.inf)
            out.append(Candidate(effect, name, unit, counterpart, (f"{symbol}{j + 1}",), build, value, minimum))
        out.append(_stiffness(plant, j))
        out.append(_joint_offset(plant, j))
    return out


def _stiffness(plant: Plant, j: int) -> Candidate:
    nv, ref = plant.nv, float(plant.springref[j])

    def build(s: Signals) -> np.ndarray:
        out = np.zeros((s.n_samples, nv, 2))
        out[:, j, 0] = s.q[:, j] - ref
        out[:, j, 1] = 1.0
        return out

    names = (f"K{j + 1}", f"Koff{j + 1}")
    return Candidate(
        "joint_stiffness",
        plant.joint_names[j],
        "N m/rad",
        "joint stiffness, springref",
        names,
        build,
        _first,
        -float(plant.stiffness[j]),
    )


def _joint_offset(plant: Plant, j: int) -> Candidate:
    def build(s: Signals) -> np.ndarray:
        return -s.dtau_dq[:, :, j : j + 1]

    return Candidate("joint_offset", plant.joint_names[j], "rad", "joint ref", (f"dq0_{j + 1}",), build, _first)


def rotor_chain(plant: Plant, j: int) -> tuple[np.ndarray, int] | None:
    """The joints whose rows a rotor on joint j's parent link couples to, and the parent body.

    Returns:
        ((nv,) +-1 on joint j's ancestor joints whose axes are parallel to j's (the sign of their dot
        product), 0 elsewhere; the parent body's index), or None when joint j has no ancestor joint, or an
        ancestor's axis is not parallel to j's, or a body carries more than one joint (the coupling is then
        not a constant inertia).
    """

    m = plant.mj_model
    if m.njnt != plant.nv or len(set(m.jnt_bodyid.tolist())) != m.njnt:
        return None
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    body_joint = {int(b): k for k, b in enumerate(m.jnt_bodyid)}
    sign = np.zeros(plant.nv)
    body, parent = int(m.body_parentid[m.jnt_bodyid[j]]), -1
    while body > 0:
        if body in body_joint:
            i = body_joint[body]
            dot = float(d.xaxis[i] @ d.xaxis[j])
            if abs(abs(dot) - 1) > 1e-9:
                return None
            sign[i] = np.sign(dot)
            parent = i if parent < 0 else parent
        body = int(m.body_parentid[body])
    return (sign, parent) if parent >= 0 else None


def _rotor_couplings(plant: Plant) -> list[Candidate]:
    out = []
    for j, name in enumerate(plant.joint_names):
        chain = rotor_chain(plant, j)
        if chain is None:
            continue
        sign = chain[0]

        def build(s: Signals, j: int = j, sign: np.ndarray = sign) -> np.ndarray:
            col = np.zeros((s.n_samples, plant.nv, 1))
            col[:, :, 0] = sign[None, :] * s.ddq[:, j : j + 1]
            col[:, j, 0] = s.ddq @ sign
            return col

        counterpart = "child and parent inertial, joint armature; custom numeric"
        out.append(Candidate("rotor_coupling", name, "kg m^2", counterpart, (f"Irgr{j + 1}",), build, _first))
    return out


def _random_regressor(plant: Plant, rng: np.random.Generator, n: int = 300) -> np.ndarray:
    return rigid_body_regressor(plant, *random_states(plant, rng, n)).reshape(n * plant.nv, -1)


def _payloads(plant: Plant, rng: np.random.Generator) -> list[Candidate]:
    """A body's identifiable inertial columns with every other body held at its nominal values."""
    W, out = _random_regressor(plant, rng), []
    for b, body in enumerate(plant.body_names):
        cols = independent_columns(W, list(range(10 * b, 10 * b + 10)), zero_tol=1e-7)
        if not cols or cols[0] != 10 * b:
            continue  # the body's mass is not identifiable (it does not move the joints' torques)
        idx = np.array(cols)

        def build(s: Signals, idx: np.ndarray = idx) -> np.ndarray:
            return s.regressor[:, :, idx]

        names = tuple(f"d{INERTIAL_SYMBOLS[c - 10 * b]}{b + 1}" for c in cols)
        out.append(Candidate("payload", body, "kg", "body inertial", names, build, _first))
    return out


def _rigid_body(plant: Plant, rng: np.random.Generator) -> list[Candidate]:
    base = base_parameters(ParameterModel(plant, ()), rng)
    idx = base.independent

    def build(s: Signals) -> np.ndarray:
        return s.regressor[:, :, idx]

    names = tuple(f"d({n})" for n in base.names)
    return [Candidate("rigid_body", "", "N m", "every body inertial", names, build, _torque_rms)]


CANDIDATE_EFFECTS: dict[str, Callable[[Plant, np.random.Generator], list[Candidate]]] = {
    "armature": lambda p, rng: [c for c in _joint_effects(p) if c.effect == "armature"],
    "coulomb_friction": lambda p, rng: [c for c in _joint_effects(p) if c.effect == "coulomb_friction"],
    "joint_offset": lambda p, rng: [_joint_offset(p, j) for j in range(p.nv)],
    "joint_stiffness": lambda p, rng: [_stiffness(p, j) for j in range(p.nv)],
    "payload": _payloads,
    "rotor_coupling": lambda p, rng: _rotor_couplings(p),
    "rigid_body": _rigid_body,
    "time_delay": lambda p, rng: [c for c in _joint_effects(p) if c.effect == "time_delay"],
    "torque_gain": lambda p, rng: [c for c in _joint_effects(p) if c.effect == "torque_gain"],
    "torque_offset": lambda p, rng: [c for c in _joint_effects(p) if c.effect == "torque_offset"],
    "viscous_friction": lambda p, rng: [c for c in _joint_effects(p) if c.effect == "viscous_friction"],
}


def candidates(plant: Plant, effects: list[str] | tuple[str, ...], rng: np.random.Generator) -> list[Candidate]:
    """Every candidate of the named effects (see `CANDIDATE_EFFECTS`) for this plant.

    Raises:
        ValueError: unknown effect name (the message lists the valid ones).
    """
    unknown = [e for e in effects if e not in CANDIDATE_EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {unknown}; valid choices: {', '.join(sorted(CANDIDATE_EFFECTS))}")
    return [c for e in effects for c in CANDIDATE_EFFECTS[e](plant, rng)]

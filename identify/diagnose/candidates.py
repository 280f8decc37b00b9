"""The library of candidate effects: each one's regressor columns, value, unit and MuJoCo counterpart.

The residual r = tau_measured - tau_nominal is explained, to first order, by a sum of effect columns
times unknown coefficients (one group of columns per effect and joint or body):

    effect            columns on the rows of joint j           value (unit)               counterpart
    armature          ddq_j                                    c (kg m^2)                 joint `armature`
    viscous_friction  dq_j                                     c (N m s/rad)              joint `damping`
    coulomb_friction  sign(dq_j) (the joint's ramp if it       c (N m)                    joint `frictionloss`
                      declares one, `dynamics.friction`);
                      variant `mujoco`: the change of MuJoCo's                            (its solver parameters
                      own frictionloss shape at the joint's                               left as they are)
                      solver parameters, Fc sat((dq_j + ddq_j
                      / B) / vt), vt = R Fc / B, from F0 to F0 + c
    joint_stiffness   q_j - springref_j, 1                     k = c0 (N m/rad)           `stiffness`, `springref`
    torque_offset     1                    (actuated only)     c (N m)                    actuator `biasprm`
    torque_gain       tau_nominal_j        (actuated only)     1 + c (measured / true)    actuator `gainprm`
    time_delay        (tau_nominal_j(t - m) - tau_nominal_j(t)) c (s)                     custom numeric
                      / m, made at the delay fitted m
                      (-d tau_nominal_j/dt at m = 0; actuated
                      only)
    joint_offset      -d tau_nominal/d q_j (every row)         c (rad)                    joint `ref`
    rotor_coupling    ddq_i in tau_j, ddq_j in tau_i (i: the   rho = Ir gr (kg m^2)       child and parent `inertial`,
                      ancestor joints of j, parallel axes)                               joint `armature` (exact)
    payload           the body's identifiable inertial cols    added mass (kg)            body `inertial`
    rigid_body        the base rigid-body columns              RMS torque change (N m)    every `inertial`
    cogging           sin(n q_j), cos(n q_j) (actuated only)   amplitude (N m)            custom numeric [n, a, b]
    stribeck_friction sign(dq_j) exp(-(dq_j / vs)^2)           breakaway excess Fs (N m)  custom numeric [Fs, vs]
    smooth_coulomb_   sat(dq_j / vt) (a ramp of width vt)      Fc (N m)                   joint `frictionloss` with
      friction                                                                            solref/solimpfriction
                                                                                          making it that ramp
    friction_ramp     the change from the nominal frictionloss Fc (N m)                   joint `frictionloss` Fc
                      F0 in its shape to Fc in a narrower one                             with solref/solimpfriction
                      (ideal sign(dq_j), or a ramp), per unit                             making it that shape
                      Fc: shape - (F0 / Fc) nominal shape
    load_friction     |tau_nominal_j| sign(dq_j) (actuated)    mu (1)                     custom numeric [mu]
    backlash          -d tau_nominal/d q_j sign(dq_j)          lost motion b (rad)        custom numeric [b]
    joint_elasticity  -d tau_nominal/d q_j tau_nominal_j       stiffness k (N m/rad)      custom numeric [k]
                      (actuated only)

Physical ranges (`Candidate.bounds`, constants below): a joint's total armature, damping, frictionloss and
stiffness >= 0 (the smooth Coulomb friction is the joint's frictionloss too); 0 <= delay <= `MAX_DELAY_S`; gain
within 1 +- `GAIN_BAND`; |joint offset| <= `MAX_JOINT_OFFSET`; added payload mass >= 0; Stribeck amplitude >= 0;
0 <= mu <= `MAX_LOAD_FRICTION`; 0 <= b <= `MAX_BACKLASH`; k >= 1 / `MAX_COMPLIANCE`. The cogging period is the one
the training residual shows (`cogging_harmonic` scans `COGGING_HARMONICS`), the Stribeck and transition speeds a
small grid (each a candidate of its own, `variant`).

A joint has one frictionloss, so one friction shape: `coulomb_friction` (ideal, written as sharp as the model's
step allows, or a change of the level in the joint's own shape), `smooth_coulomb_friction` (a ramp of width vt)
and `friction_ramp` exclude each other on a joint (`FRICTIONLOSS_EFFECTS`). Where the nominal MJCF already has a
frictionloss F0 on the joint, the written ramp carries F0 too; that change of F0's shape, F0 (sat(dq / vt) - its
nominal shape), nonzero only below vt, is left out of a ramp's fit. So a ramp is tried only where the nominal
shape is no wider than vt: under a wider one (MuJoCo's default ramp is as wide as the joint's inverse inertia,
7.7 rad/s on the xArm7's last joint) the file written would hold a friction the fit never saw (1.2 N m at 0.2
rad/s there, for a fitted 0.23). There `friction_ramp` fits that change of shape itself (`_friction_ramps`): the
joint's friction in a narrower shape (the ideal one, or a ramp of the grid's widths) in place of F0 in its own.

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
from dataclasses import dataclass, replace
from functools import partial

import mujoco
import numpy as np
from scipy import signal as sp_signal

from dynamics.base import base_parameters
from dynamics.friction import applied_friction_parameters, friction_enabled, friction_shape
from dynamics.plant import INERTIAL_SYMBOLS, Plant
from dynamics.regressor import ParameterModel, rigid_body_regressor
from dynamics.sampling import independent_columns, random_states
from dynamics.torque import joint_torque, torque_jacobian_q
from envs.dataset import Dataset
from identify.derivatives import States

__all__ = [
    "CANDIDATE_EFFECTS",
    "FRICTIONLOSS_EFFECTS",
    "IDEAL",
    "SHARP_EFFECTS",
    "Candidate",
    "Signals",
    "band_lowpass",
    "candidates",
    "cogging_harmonic",
    "period_edge",
    "position_harmonic",
    "rotor_chain",
    "signals",
    "stack_signals",
]


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
        used: (N, nv) False where a row's torque of a joint says nothing the columns can explain (a joint that
            never moves in a record is held by static friction, anywhere within its breakaway): the residual
            and every column are zero there, so no fit sees it. None: every row is used.
        state_hz: (record, cut-off [Hz]) of the filter each record's states went through (None or left out:
            exact states). The residual sees a force the plant feels only through the filtered acceleration,
            low-passed at that cut-off; a column sharp in the velocity (`SHARP_EFFECTS`) goes through the same
            filter before the band, so the two are alike (`columns`).
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
    used: np.ndarray | None = None
    state_hz: tuple[tuple[int, float | None], ...] = ()

    @property
    def residual(self) -> np.ndarray:
        """(N, nv) measured minus nominal torque [N m], in the analysis band (0 where not `used`)."""
        return self.in_band(self.tau - self.tau_nominal)

    def in_band(self, x: np.ndarray) -> np.ndarray:
        """(N, nv, ...) -> the same as every fit sees it: 0 where not `used`, then low-passed at `band_hz`
        (`smooth`), then 0 there again. Zeroing before the filter keeps tau = Y theta exact through it on every
        row (0 = 0 theta where a torque is left out) and keeps what was left out from leaking into the rows beside
        it (a joint held by friction: a torque anywhere within its breakaway, which the filter would spread)."""
        return self.zero_unused(self.smooth(self.zero_unused(x)))

    def zero_unused(self, x: np.ndarray) -> np.ndarray:
        """(N, nv, ...) -> the same with the (row, joint) values that are not `used` set to 0."""
        if self.used is None:
            return x
        return x * self.used.reshape(self.used.shape + (1,) * (x.ndim - 2))

    @property
    def n_used(self) -> int:
        """Number of (row, joint) torque values the fits use."""
        return int(self.tau.size if self.used is None else np.count_nonzero(self.used))

    def used_rms(self, x: np.ndarray) -> np.ndarray:
        """(nv,) RMS of an (N, nv) array over the used rows of each joint (0 for a joint with none)."""
        if self.used is None:
            return np.sqrt(np.mean(x**2, axis=0))
        count = np.count_nonzero(self.used, axis=0)
        return np.sqrt(np.sum(np.where(self.used, x, 0.0) ** 2, axis=0) / np.maximum(count, 1))

    def smooth(self, x: np.ndarray) -> np.ndarray:
        """(N, ...) -> the same low-passed at `band_hz`, record by record (identity when band_hz is None)."""
        return x if self.band_hz is None else self._lowpass(x, lambda _: self.band_hz)

    def through_states(self, x: np.ndarray) -> np.ndarray:
        """(N, ...) -> the same low-passed as each record's states were (`state_hz`; identity for exact states)."""
        cutoffs = dict(self.state_hz)
        return x if all(c is None for c in cutoffs.values()) else self._lowpass(x, cutoffs.get)

    def _lowpass(self, x: np.ndarray, hz: Callable[[int], float | None]) -> np.ndarray:
        """(N, ...) -> each record's rows low-passed at hz(record) (`band_lowpass`; unchanged where None)."""
        fs = 1.0 / float(np.median(np.diff(self.time)))
        out = np.empty_like(x, dtype=float)
        for r in np.unique(self.record):
            rows = self.record == r
            out[rows] = band_lowpass(x[rows], fs, hz(int(r)))
        return out

    def affine_parts(self, candidate: Candidate) -> tuple[np.ndarray, np.ndarray]:
        """((N, nv) S, (N, nv) O) of a candidate whose effect is affine in its value c (`Candidate.affine`): c S - O,
        both as `columns` gives them; its column made at m is S - O / m."""
        assert candidate.affine and candidate.remake is not None and candidate.made_at is not None, candidate.key
        made, plain = self.columns(candidate)[:, :, 0], self.columns(candidate.remake(np.inf))[:, :, 0]
        return plain, candidate.made_at * (plain - made)

    def columns(self, candidate: Candidate) -> np.ndarray:
        """(N, nv, k) the candidate's columns in the analysis band (0 where not `used`); those of
        `SHARP_EFFECTS` through the state filter first, as the residual sees them (`state_hz`)."""
        built = candidate.build(self)
        return self.in_band(self.through_states(built) if candidate.effect in SHARP_EFFECTS else built)

    @property
    def n_samples(self) -> int:
        return len(self.time)


def band_lowpass(x: np.ndarray, fs: float, band_hz: float | None) -> np.ndarray:
    """(N, ...) -> the same low-passed along axis 0 at `band_hz` (zero phase, order 4 each way; capped at 0.45 of
    the rate `fs` [Hz]): the analysis band every fit and model is compared in (identity when band_hz is None)."""
    if band_hz is None:
        return x
    sos = sp_signal.butter(4, min(band_hz, 0.45 * fs), fs=fs, output="sos")
    return sp_signal.sosfiltfilt(sos, x, axis=0)  # type: ignore[no-any-return]


def signals(
    plant: Plant,
    data: Dataset,
    states: States,
    *,
    record: int = 0,
    band_hz: float | None = None,
    state_hz: float | None = None,
) -> Signals:
    """The signals of one record on the rows its derivative filter trusts (a contiguous block); `state_hz`: the
    cut-off of the filter `states` went through (None: exact)."""
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
        state_hz=((record, state_hz),),
    )


def stack_signals(parts: list[Signals]) -> Signals:
    """Rows of several records, one after the other."""
    if not parts:
        raise ValueError("no records to stack")
    fields = ("time", "q", "dq", "ddq", "tau", "tau_nominal", "dtau_dq", "dtau_dt", "regressor", "record")
    stacked = {f: np.concatenate([getattr(p, f) for p in parts]) for f in fields}
    used = None
    if any(p.used is not None for p in parts):
        used = np.concatenate([np.ones(p.tau.shape, bool) if p.used is None else p.used for p in parts])
    state_hz = tuple(pair for p in parts for pair in p.state_hz)
    return Signals(**stacked, actuated=parts[0].actuated, band_hz=parts[0].band_hz, used=used, state_hz=state_hz)


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
        bounds: per coefficient, its physical range (lower, upper) in coefficient units (a joint's total
            damping, friction, armature or stiffness cannot end below zero, a delay is causal and short,
            a gain lies in a band around 1, an added mass is positive); empty: unbounded. Every fit stays
            inside it, and a value that ends on a bound is reported as such.
        variant: the shape parameter that tells candidates of one effect and joint apart (a Stribeck
            speed, a cogging period), "" where there is one.
        note: what the effect is physically and how the calibrated MJCF holds it (for effects MuJoCo has
            no attribute for).
        made_at: for a column that depends on its own coefficient (the secant of MuJoCo's friction, whose width
            goes with Fc), the coefficient it was made at; None for every other candidate.
        remake: with `made_at`, coefficient -> the same candidate with its column made at that coefficient (the
            final fit iterates it to the value it fits, `diagnosis._final_fit`).
        affine: with `made_at`, its effect is affine in its value c, c S - O (`Signals.affine_parts`; its column
            made at m is S - O / m, made at inf S): fitted as such, not iterated (`select._settled`,
            `diagnosis._final_fit`).
    """

    effect: str
    target: str
    unit: str
    counterpart: str
    parameter_names: tuple[str, ...]
    build: Callable[[Signals], np.ndarray]
    value: Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[float, float]]
    bounds: tuple[tuple[float, float], ...] = ()
    note: str = ""
    variant: str = ""
    made_at: float | None = None
    remake: Callable[[float], Candidate] | None = None
    affine: bool = False

    @property
    def null(self) -> float:
        """The value that means no effect: a gain of 1, zero for every other effect."""
        return 1.0 if self.effect == "torque_gain" else 0.0

    @property
    def native(self) -> bool:
        """True where MuJoCo has an attribute for the effect (the selection prefers those on a tie)."""
        return self.counterpart != "custom numeric"

    def __post_init__(self) -> None:
        if self.bounds and len(self.bounds) != len(self.parameter_names):
            raise ValueError(f"{self.key}: {len(self.bounds)} bounds for {len(self.parameter_names)} coefficients")
        if any(lo > hi for lo, hi in self.bounds):
            raise ValueError(f"{self.key}: a lower bound above its upper bound in {self.bounds}")

    @property
    def key(self) -> str:
        key = f"{self.effect}:{self.target}" if self.target else self.effect
        return f"{key}@{self.variant}" if self.variant else key

    def agrees(self, value: float, tol: float) -> bool:
        """Whether a self-dependent column (`made_at`) fitted at `value` agrees with the value it was made at (to
        `tol` of the larger), or is no change (the secant's limit: the column it has is as good); True for
        every other candidate."""
        if self.made_at is None or abs(value) < 1e-9:
            return True
        return abs(value - self.made_at) <= tol * max(abs(self.made_at), abs(value))

    def holds(self, value: float) -> bool:
        """Whether the calibrated MJCF can hold this self-dependent candidate fitted at `value`: an affine one
        above no friction (c S - O at c = 0 is the nominal friction taken away, which no column made at c holds),
        any other one where its value agrees with the value its column was made at (`SETTLED_TOL`); True for a
        candidate that is not self-dependent."""
        return value > 0 if self.affine else self.agrees(value, SETTLED_TOL)

    def next_made_at(self, value: float, last: tuple[float, float] | None) -> float:
        """Where a self-dependent column fitted at `value` is made again: the value fitted c is a function of the
        value made at m, and the one wanted is its fixed point c(m) = m. Made again at c, it settles where c(m)
        is flat (MuJoCo's friction secant); where a column made a little off moves c far (`friction_ramp`,
        whose column holds the nominal shape times F0 / m), that walks away. So with `last`, the (made at,
        fitted) before, it is made at the secant's root of c(m) - m through the two, where that lies within the
        bounds; at `value` otherwise."""
        if last is None or self.made_at is None:
            return value
        g, g_last = value - self.made_at, last[1] - last[0]
        if g == g_last:
            return value
        root = self.made_at - g * (self.made_at - last[0]) / (g - g_last)
        inside = np.isfinite(root) and abs(root) >= 1e-9 and self.lower[0] < root < self.upper[0]
        return float(root) if inside else value

    @property
    def lower(self) -> np.ndarray:
        """(k,) lower bounds of the coefficients."""
        return np.array([b[0] for b in self.bounds]) if self.bounds else np.full(len(self.parameter_names), -np.inf)

    @property
    def upper(self) -> np.ndarray:
        """(k,) upper bounds of the coefficients."""
        return np.array([b[1] for b in self.bounds]) if self.bounds else np.full(len(self.parameter_names), np.inf)


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


MAX_DELAY_S = 0.02  # longest sensor delay named [s]: a current-loop or bus delay is a few ms; beyond, a model error
GAIN_BAND = 0.3  # a torque gain (reported / applied) is named within 1 +- this; beyond, the torque constant is wrong
# largest encoder zero offset named [rad]: a calibration error of the zero, not a resting pose's (that is
# `diagnosis.RESTING_ZERO`); at 0.2 an elbow offset of 0.3 rad was named as a rigid-body change alone (link 2's
# centre of mass 8 cm sideways), the offset beyond its range; the half-turn is refused as a data error
MAX_JOINT_OFFSET = 0.5
MAX_LOAD_FRICTION = 0.5  # largest load-dependent friction coefficient (friction torque / load torque) [1]
MAX_BACKLASH = 0.05  # widest backlash (lost motion) named [rad]
MAX_COMPLIANCE = 0.05  # most compliant transmission named (stiffness >= 20 N m/rad) [rad/(N m)]
STRIBECK_SPEEDS = (0.1, 0.5)  # Stribeck speeds tried [rad/s]
SOFT_FRICTION = "mujoco"  # the variant of `coulomb_friction` shaped as MuJoCo's own frictionloss constraint
SETTLED_TOL = 1e-3  # relative agreement of a self-dependent column's value and the value it was made at, settled
SMOOTH_COULOMB_SPEEDS = (0.03, 0.1, 0.3)  # ramp widths of a smooth Coulomb friction tried [rad/s]
FRICTIONLOSS_EFFECTS = ("coulomb_friction", "smooth_coulomb_friction", "friction_ramp")  # shapes of one frictionloss
IDEAL = "ideal"  # the variant of `friction_ramp` that makes the nominal frictionloss the ideal Coulomb friction
# forces the plant feels that change within a few ms as the velocity crosses zero: the residual holds them only
# low-passed at the state filter's cut-off (through the filtered acceleration), so their columns go through it too
# (`friction_ramp` filters its own: its nominal part is the nominal model's, made from the filtered states)
SHARP_EFFECTS = ("coulomb_friction", "smooth_coulomb_friction", "stribeck_friction", "load_friction", "backlash")
# harmonics n of sin(n q) scanned for position-periodic torque [cycles per revolution]: 2 to 40 can be named, and
# 40.5 is scanned so that a period shorter than the shortest named shows as such (`cogging_harmonic`)
COGGING_HARMONICS = np.arange(2.0, 41.0, 0.5)
MIN_COGGING_PERIODS = 1.0  # the training motion of the joint spans at least this many periods 2 pi / n


def _joint_effects(plant: Plant) -> list[Candidate]:
    nv, out = plant.nv, []
    inf = np.inf

    def coulomb(s: Signals, j: int) -> np.ndarray:  # the joint's own shape: sign(dq), or the ramp it declares
        speed, lead = plant.friction_speed[j : j + 1], plant.friction_lead[j : j + 1]
        return friction_shape(s.dq[:, j : j + 1], s.ddq[:, j : j + 1], speed, lead)[:, 0]

    table: list[tuple[str, str, str, str, Callable[[Signals, int], np.ndarray], bool]] = [
        ("armature", "kg m^2", "joint armature", "Ia", lambda s, j: s.ddq[:, j], False),
        ("viscous_friction", "N m s/rad", "joint damping", "Fv", lambda s, j: s.dq[:, j], False),
        ("coulomb_friction", "N m", "joint frictionloss", "Fc", coulomb, False),
        ("torque_offset", "N m", "actuator biasprm", "off", lambda s, j: np.ones(s.n_samples), True),
        ("torque_gain", "1", "actuator gainprm", "dgain", lambda s, j: s.tau_nominal[:, j], True),
    ]
    nominal = {"armature": plant.armature, "viscous_friction": plant.damping, "coulomb_friction": plant.frictionloss}
    for j, name in enumerate(plant.joint_names):
        for effect, unit, counterpart, symbol, signal, actuated_only in table:
            if actuated_only and not plant.actuated[j]:
                continue
            value = _gain if effect == "torque_gain" else _first
            build = _own_row(nv, j, lambda s, j=j, f=signal: f(s, j))  # type: ignore[misc]
            if effect in nominal:
                bounds = ((-float(nominal[effect][j]), inf),)  # the joint's total value stays >= 0
            elif effect == "torque_gain":
                bounds = ((-GAIN_BAND, GAIN_BAND),)
            else:
                bounds = ((-inf, inf),)
            out.append(Candidate(effect, name, unit, counterpart, (f"{symbol}{j + 1}",), build, value, bounds))
        if plant.actuated[j]:
            out.append(_delay_candidate(plant, j, 0.0))
        out.append(_stiffness(plant, j))
        out.append(_joint_offset(plant, j))
    return out


def _delay_candidate(plant: Plant, j: int, delay: float) -> Candidate:
    """Joint j's torque sensor reporting `delay` [s] late: tau(t - d) - tau(t), the nominal torque's secant
    (`_delayed_secant`) per unit d, made at `delay` and made again at the delay fitted (`Candidate.remake`), so
    that the delay written is the one the fit used exactly. Made at 0 it is the first-order -d tau/dt; a delay of
    12-19 ms fitted so came with a torque gain 7 to 11 std below 1, which took the second-order part (1 - d^2
    w^2 / 2 on a motion at w)."""

    def secant(s: Signals) -> np.ndarray:
        return _delayed_secant(s, j, delay)

    return Candidate(
        "time_delay",
        plant.joint_names[j],
        "s",
        "custom numeric (sensor side)",
        (f"delay{j + 1}",),
        _own_row(plant.nv, j, secant),
        _first,
        ((0.0, MAX_DELAY_S),),  # causal: the sensor reports after the torque acts
        made_at=delay,
        remake=partial(_delay_candidate, plant, j),
    )


_FIRST_ORDER_DELAY_S = 1e-6  # [s] a delay this short is made as the first-order column -d tau / dt


def _delayed_secant(s: Signals, j: int, delay: float) -> np.ndarray:
    """(N,) (tau_nominal_j(t - delay) - tau_nominal_j(t)) / delay on the signals' rows, record by record
    (before a record's first row, its first row's slope carries it back); -d tau_nominal_j / dt for a delay of
    `_FIRST_ORDER_DELAY_S` or less."""
    if delay <= _FIRST_ORDER_DELAY_S:
        return -s.dtau_dt[:, j]  # type: ignore[no-any-return]
    out = np.empty(s.n_samples)
    for r in np.unique(s.record):
        rows = np.flatnonzero(s.record == r)
        t, tau = s.time[rows], s.tau_nominal[rows, j]
        back = t - delay
        shifted = np.interp(back, t, tau)
        early = back < t[0]
        shifted[early] = tau[0] + (back[early] - t[0]) * s.dtau_dt[rows[0], j]
        out[rows] = (shifted - tau) / delay
    return out


def _shape_friction(plant: Plant) -> list[Candidate]:
    """Velocity-dependent friction shapes: Stribeck (breakaway above Coulomb at low speed) and smooth Coulomb."""
    out = []
    for j, name in enumerate(plant.joint_names):
        for vs in STRIBECK_SPEEDS:

            def stribeck(s: Signals, j: int = j, vs: float = vs) -> np.ndarray:
                return np.sign(s.dq[:, j]) * np.exp(-((s.dq[:, j] / vs) ** 2))

            note = (
                f"Stribeck friction: an extra Fs sign(dq) exp(-(dq/{vs:g})^2) at low speed (breakaway). MuJoCo has "
                "no velocity-shaped friction: written as numeric sysid_stribeck_friction_<joint> = [Fs, vs]"
            )
            out.append(
                Candidate(
                    "stribeck_friction",
                    name,
                    "N m",
                    "custom numeric",
                    (f"Fs{j + 1}",),
                    _own_row(plant.nv, j, stribeck),
                    _first,
                    ((0.0, np.inf),),
                    note,
                    f"{vs:g}",
                )
            )
        for vt in SMOOTH_COULOMB_SPEEDS:
            if plant.frictionloss[j] > 0 and plant.friction_speed[j] > vt:
                continue  # a ramp under a wider nominal one: not what the file written would hold

            def smooth(s: Signals, j: int = j, vt: float = vt) -> np.ndarray:
                return np.clip(s.dq[:, j] / vt, -1.0, 1.0)

            note = (
                f"smooth Coulomb friction Fc sat(dq/{vt:g}) (no friction force at rest, full once sliding faster "
                f"than {vt:g} rad/s): the joint's frictionloss Fc, its solreffriction and solimpfriction set so "
                "that MuJoCo applies that ramp (dynamics.friction)"
            )
            out.append(
                Candidate(
                    "smooth_coulomb_friction",
                    name,
                    "N m",
                    "joint frictionloss (ramp)",
                    (f"Fct{j + 1}",),
                    _own_row(plant.nv, j, smooth),
                    _first,
                    ((-float(plant.frictionloss[j]), np.inf),),  # the joint's total friction stays >= 0
                    note,
                    f"{vt:g}",
                )
            )
    return out


def _friction_ramps(plant: Plant, train: Signals | None) -> list[Candidate]:
    """A nominal frictionloss F0 whose ramp (as MuJoCo applies it at the joint's solver parameters: at its defaults
    as wide as the joint's inverse inertia, 7.7 rad/s on the Menagerie xArm7's last joint) is wider than the
    robot's friction: the joint's friction in a narrower shape, the ideal sign(dq) or a ramp sat(dq / vt) of a
    width of `SMOOTH_COULOMB_SPEEDS` narrower than the nominal one, at a level Fc. No other column holds that
    change of F0's shape (a level change keeps the nominal shape, and a ramp is not tried under a wider nominal
    one). The change from F0 in its nominal shape N to Fc in the narrower one S, Fc S - F0 N, is affine in Fc
    (`Candidate.affine`): the fits take it as such (`select._settled`, `diagnosis._final_fit`), and its column is
    the change per unit Fc made at Fc = m, S - (F0 / m) N, first at the Fc the training residual gives
    (`_ramp_levels`), then at the value fitted (`Candidate.remake`), so that the file written, Fc with the
    solreffriction and solimpfriction of that shape (`calibrate`), applies the friction the fit used. Without
    training signals, none."""
    if train is None:
        return []
    residual = train.residual  # low-passed on every access: once for every joint
    out = []
    for j in range(plant.nv):
        if plant.frictionloss[j] > 0 and plant.friction_speed[j] > 0:  # one not read as the ideal term already
            widths = [f"{vt:g}" for vt in SMOOTH_COULOMB_SPEEDS if vt < plant.friction_speed[j]]
            levels = _ramp_levels(plant, train, residual, j, (IDEAL, *widths))
            out += [_ramp_candidate(plant, j, variant, level) for variant, level in levels.items()]
    return out


def _narrower_shape(dq: np.ndarray, variant: str) -> np.ndarray:
    """The shape of `friction_ramp`'s `variant`: sign(dq) (`IDEAL`) or sat(dq / vt)."""
    return np.sign(dq) if variant == IDEAL else np.clip(dq / float(variant), -1.0, 1.0)  # type: ignore[no-any-return]


def _nominal_shape(plant: Plant, s: Signals, j: int) -> np.ndarray:
    """(N,) joint j's nominal frictionloss shape along the signals' motion, as the nominal torque holds it: at the
    velocity its ramp sees, which in a log of MuJoCo's own steps is not the joint's (`dynamics.stepping`)."""
    dq = s.dq if plant.stepping is None else plant.stepping.friction_velocity(plant, s.q, s.dq, s.ddq)[0]
    one = slice(j, j + 1)
    shape = friction_shape(dq[:, one], s.ddq[:, one], plant.friction_speed[one], plant.friction_lead[one])
    return shape[:, 0]  # type: ignore[no-any-return]


def _ramp_levels(
    plant: Plant, train: Signals, residual: np.ndarray, j: int, variants: tuple[str, ...]
) -> dict[str, float]:
    """variant -> the level Fc of joint j's friction in that narrower shape that the training residual gives with
    the nominal F0 taken out whole (r + F0 nominal shape ~ Fc shape), the joint's viscous friction and armature
    beside it, as the fits see the columns (`_seen`); a variant is left out where the joint's torque is not
    measured, where its shape does not differ from the nominal one on these rows, or where the level is not
    positive."""
    rows = _fitted_rows(train, j)
    if rows is None:
        return {}
    held = _seen(train, j, rows, _nominal_shape(plant, train, j))
    target = residual[rows, j] + plant.frictionloss[j] * held
    beside = [_seen(train, j, rows, train.dq[:, j]), _seen(train, j, rows, train.ddq[:, j])]
    levels = {}
    for variant in variants:
        shape = _seen(train, j, rows, _narrower_shape(train.dq[:, j], variant), sharp=True)
        if np.any(np.abs(shape - held) > 1e-9):
            level = float(np.linalg.lstsq(np.column_stack([shape, *beside]), target, rcond=None)[0][0])
            if level > 0:
                levels[variant] = level
    return levels


def _fitted_rows(train: Signals, j: int) -> np.ndarray | None:
    """(N,) the rows where joint j's torque is fitted (`Signals.used`); None where there are none, or where the
    joint is not actuated."""
    rows = train.used[:, j] if train.used is not None else np.ones(train.n_samples, bool)
    return rows if np.any(rows) and train.actuated[j] else None


def _seen(train: Signals, j: int, rows: np.ndarray, x: np.ndarray, sharp: bool = False) -> np.ndarray:
    """(rows,) a column of joint j as the fits see it: in the analysis band, through the state filter first where
    it is `sharp` in the velocity (`Signals.columns`)."""
    full = np.zeros(train.dq.shape)
    full[:, j] = x
    return train.in_band(train.through_states(full) if sharp else full)[rows, j]  # type: ignore[no-any-return]


def _ramp_candidate(plant: Plant, j: int, variant: str, level: float) -> Candidate:
    """Joint j's friction replaced by one of level Fc in the narrower shape `variant` (`_friction_ramps`), its
    column the secant from the nominal friction to Fc = `level` [N m]."""
    f0 = float(plant.frictionloss[j])

    def column(s: Signals) -> np.ndarray:  # the plant's friction as the residual holds it, less the nominal's
        shape = np.zeros(s.dq.shape)
        shape[:, j] = _narrower_shape(s.dq[:, j], variant)
        return s.through_states(shape)[:, j] - (f0 / level) * _nominal_shape(plant, s, j)  # type: ignore[no-any-return]

    unit = "rad/s" if plant.hinge[j] else "m/s"
    narrower = "the ideal Fc sign(dq)" if variant == IDEAL else f"a ramp Fc sat(dq/{variant}) ({variant} {unit} wide)"
    note = (
        f"the joint's friction acts as {narrower}, not as the nominal frictionloss {f0:g} in the ramp "
        f"{plant.friction_speed[j]:.3g} {unit} wide that the joint's solver parameters make of it (value: Fc); "
        "written as the joint's frictionloss Fc with the solreffriction and solimpfriction of that shape "
        "(dynamics.friction)"
    )
    return Candidate(
        "friction_ramp",
        plant.joint_names[j],
        "N m",
        "joint frictionloss, solreffriction and solimpfriction",
        (f"Fcr{j + 1}",),
        _own_row(plant.nv, j, column),
        _first,
        ((0.0, np.inf),),  # a friction
        note,
        variant,
        made_at=level,
        remake=partial(_ramp_candidate, plant, j, variant),
        affine=True,
    )


def _soft_friction(plant: Plant, train: Signals | None) -> list[Candidate]:
    """Coulomb friction as MuJoCo applies a joint `frictionloss` at the joint's own solver parameters (MuJoCo's
    defaults, solref 0.02 1 and solimp 0.9 0.95, where the joint sets none): Fc sat((dq + ddq / B) / vt) with
    vt = R Fc / B (`dynamics.friction`). It turns over 1 / B (9.5 ms at the defaults) before the joint reverses;
    an ideal sign(dq) leaves that turnover as structure, and an armature takes part of it. The width goes with
    Fc, so the column is the change of that friction from the joint's nominal F0 to F0 + dF per unit dF, at the
    dF the training residual gives (`_soft_friction_change`), made again at the dF the final fit gives
    (`Candidate.remake`); without training signals, none."""
    m = plant.mj_model
    if train is None or not friction_enabled(m):
        return []
    unit_speed, lead = applied_friction_parameters(m, np.ones(plant.nv))
    residual = train.residual  # low-passed on every access: once for every joint
    out = []
    for j in range(plant.nv):
        if lead[j] <= 0:
            continue
        shape = _SoftFriction(float(plant.frictionloss[j]), float(unit_speed[j]), float(lead[j]))
        change = _soft_friction_change(train, residual, j, shape)
        if change is not None:
            out.append(_soft_candidate(plant, j, shape, change))
    return out


def _soft_candidate(plant: Plant, j: int, shape: _SoftFriction, change: float) -> Candidate:
    """Joint j's Coulomb friction in MuJoCo's own shape (`_soft_friction`), its column the secant from the nominal
    frictionloss to nominal + `change` [N m]."""

    def soft(s: Signals) -> np.ndarray:
        return shape.column(s.dq[:, j], s.ddq[:, j], change)

    note = (
        f"Coulomb friction as MuJoCo applies a joint frictionloss at the joint's own solver parameters: "
        f"Fc sat((dq + {shape.lead:.3g} ddq) / vt), vt = {shape.unit_speed:.3g} Fc "
        f"{'rad/s per N m' if plant.hinge[j] else 'm/s per N'} (turning over "
        f"{1e3 * shape.lead:.3g} ms before the joint reverses); written as the joint's frictionloss, its "
        "solreffriction and solimpfriction left as they are"
    )
    return Candidate(
        "coulomb_friction",
        plant.joint_names[j],
        "N m",
        "joint frictionloss (MuJoCo's own constraint)",
        (f"Fcm{j + 1}",),
        _own_row(plant.nv, j, soft),
        _first,
        ((-shape.nominal, np.inf),),  # the joint's total friction stays >= 0
        note,
        SOFT_FRICTION,
        made_at=change,
        remake=partial(_soft_candidate, plant, j, shape),
    )


@dataclass(frozen=True)
class _SoftFriction:
    """MuJoCo's friction of a joint at its own solver parameters: Fc sat((dq + lead ddq) / (unit_speed Fc)),
    from its nominal frictionloss `nominal` [N m]."""

    nominal: float
    unit_speed: float
    lead: float

    def torque(self, dq: np.ndarray, ddq: np.ndarray, fc: float) -> np.ndarray:
        """(N,) the friction torque of a frictionloss fc [N m] (0 for none)."""
        if fc == 0:
            return np.zeros(len(dq))
        width = np.array([self.unit_speed * fc])
        return fc * friction_shape(dq[:, None], ddq[:, None], width, np.array([self.lead]))[:, 0]  # type: ignore[no-any-return]

    def unit(self, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """(N,) the shape at the nominal frictionloss per unit Fc (without one, the limit of a vanishing one: the
        sign of dq + lead ddq): the column of a small change."""
        if self.nominal == 0:
            return np.sign(dq + self.lead * ddq)  # type: ignore[no-any-return]
        return self.torque(dq, ddq, self.nominal) / self.nominal

    def column(self, dq: np.ndarray, ddq: np.ndarray, change: float) -> np.ndarray:
        """(N,) the change of the friction torque from the nominal frictionloss to nominal + `change`, per unit
        change (exact at that change; the secant of a friction whose width goes with Fc)."""
        return (self.torque(dq, ddq, self.nominal + change) - self.torque(dq, ddq, self.nominal)) / change


def _soft_friction_change(train: Signals, residual: np.ndarray, j: int, shape: _SoftFriction) -> float | None:
    """The change dF [N m] of joint j's MuJoCo-shaped frictionloss that the training residual (N, nv) gives, fitted with
    the joint's viscous friction and armature beside it (three passes from the shape at F0: the column
    goes with dF); None where the joint's torque is not measured, where the total would not be positive, or
    where the change is not one (a joint without friction, or a lower one where it has none to lose)."""
    rows = _fitted_rows(train, j)
    if rows is None:
        return None
    dq, ddq = train.dq[:, j], train.ddq[:, j]
    seen = partial(_seen, train, j, rows)
    column = shape.unit(dq, ddq)
    change = 0.0
    for _ in range(3):
        sharp = seen(column, sharp=True)
        if not np.any(np.abs(sharp) > 1e-9):  # a motion within the nominal ramp: the friction is not Fc's
            return None
        cols = np.column_stack([sharp, seen(dq), seen(ddq)])
        change = float(np.linalg.lstsq(cols, residual[rows, j], rcond=None)[0][0])
        if shape.nominal + change <= 0 or change == 0:
            return None
        column = shape.column(dq, ddq, change)
    return change


def _load_friction(plant: Plant) -> list[Candidate]:
    """Friction that grows with the transmitted load: mu |tau_nominal_j| sign(dq_j) (gear and bearing friction)."""
    out = []
    for j, name in enumerate(plant.joint_names):
        if not plant.actuated[j]:
            continue

        def build(s: Signals, j: int = j) -> np.ndarray:
            return np.abs(s.tau_nominal[:, j]) * np.sign(s.dq[:, j])

        note = "load-dependent friction mu |tau| sign(dq); numeric sysid_load_friction_<joint> = [mu]"
        out.append(
            Candidate(
                "load_friction",
                name,
                "1",
                "custom numeric",
                (f"mu{j + 1}",),
                _own_row(plant.nv, j, build),
                _first,
                ((0.0, MAX_LOAD_FRICTION),),
                note,
            )
        )
    return out


def _compliance(plant: Plant) -> list[Candidate]:
    """Backlash and transmission elasticity, seen by a motor-side encoder: the link lags the reported angle.

    Backlash (lost motion b, in contact): q_link = q - (b/2) sign(dq_j); elasticity (stiffness k):
    q_link = q - tau_j / k. To first order both are a joint offset that switches with the direction of motion
    or grows with the load, so their columns are the joint-offset column times sign(dq_j) or tau_j.
    """
    out = []
    for j, name in enumerate(plant.joint_names):

        def backlash(s: Signals, j: int = j) -> np.ndarray:
            return -s.dtau_dq[:, :, j : j + 1] * np.sign(s.dq[:, j])[:, None, None]

        def elastic(s: Signals, j: int = j) -> np.ndarray:
            return -s.dtau_dq[:, :, j : j + 1] * s.tau_nominal[:, j][:, None, None]

        out.append(
            Candidate(
                "backlash",
                name,
                "rad",
                "custom numeric",
                (f"bl{j + 1}",),
                backlash,
                _backlash,
                ((0.0, MAX_BACKLASH / 2),),
                "backlash: the link lags the motor by half the lost motion b, switching side with the direction of "
                "motion; numeric sysid_backlash_<joint> = [b]",
            )
        )
        if plant.actuated[j]:
            out.append(
                Candidate(
                    "joint_elasticity",
                    name,
                    "N m/rad",
                    "custom numeric",
                    (f"c{j + 1}",),
                    elastic,
                    _stiffness_value,
                    ((0.0, MAX_COMPLIANCE),),
                    "transmission elasticity: the link angle is the reported one less tau/k; numeric "
                    "sysid_joint_elasticity_<joint> = [k]",
                )
            )
    return out


def _backlash(coef: np.ndarray, cov: np.ndarray, _: np.ndarray) -> tuple[float, float]:
    return 2.0 * float(coef[0]), 2.0 * float(np.sqrt(max(cov[0, 0], 0.0)))


def _stiffness_value(coef: np.ndarray, cov: np.ndarray, _: np.ndarray) -> tuple[float, float]:
    """k = 1 / c with its delta-method std (inf for a rigid transmission)."""
    c, sd = float(coef[0]), float(np.sqrt(max(cov[0, 0], 0.0)))
    if c <= 0:
        return float("inf"), float("nan")
    return 1.0 / c, sd / c**2


def _scanned_harmonics(q: np.ndarray) -> np.ndarray:
    """The harmonics of `COGGING_HARMONICS` whose period the motion q (N,) spans `MIN_COGGING_PERIODS` times."""
    return COGGING_HARMONICS[COGGING_HARMONICS * np.ptp(q) >= 2 * np.pi * MIN_COGGING_PERIODS]


def position_harmonic(s: Signals, j: int, r: np.ndarray) -> tuple[float, float, float] | None:
    """The position-periodic torque a sin(n q_j) + b cos(n q_j) that best explains `r` (N,): (harmonic n
    [cycles per revolution], amplitude [N m], the share of r's energy the fit explains), or None where
    joint j's motion spans no period of any harmonic scanned.

    Scans the harmonics of `COGGING_HARMONICS` whose period 2 pi / n the joint's range of motion covers
    `MIN_COGGING_PERIODS` times (a longer period is a smooth function of q on these data, as gravity, an
    offset or a spring are, and it would extrapolate as a sinusoid to angles the data never reached), each
    fitted in the analysis band with a constant; the n explaining the most variance wins.
    """
    shown = _scanned_harmonics(s.q[:, j])
    if not shown.size:
        return None
    total = float(np.sum(r**2))
    best = (float(shown[0]), 0.0, -1.0)
    for n in shown:
        cols = s.smooth(np.column_stack([np.sin(n * s.q[:, j]), np.cos(n * s.q[:, j]), np.ones(s.n_samples)]))
        c, *_ = np.linalg.lstsq(cols, r, rcond=None)
        explained = float(np.sum((cols @ c) ** 2))
        if explained > best[2]:
            best = (float(n), float(np.hypot(c[0], c[1])), explained)
    return best[0], best[1], best[2] / total if total > 0 else 0.0


def cogging_harmonic(s: Signals, j: int) -> tuple[float, float] | None:
    """The position-periodic torque that best explains joint j's training residual (`position_harmonic`):
    (harmonic n [cycles per revolution], amplitude), or None where the joint's motion spans no period, or where
    the best is the longest or the shortest period the scan allows (of several): the scan cut it there, the
    torque's period may lie beyond, and a candidate at the cut would name a wrong period with a biased amplitude
    (a UR5e wrist's 6-cycle cogging over 0.85 rad of motion came out as n = 7.5 at 0.21 N m for 0.3; on another
    generator a 42-cycle ripple as n = 40 at 0.0228 +- 0.0009 N m for 0.03). The residual's signature still
    reports that harmonic."""
    found = position_harmonic(s, j, s.residual[:, j])
    if found is None or period_edge(found[0], s.q[:, j]) is not None:
        return None
    return found[0], found[1]


def period_edge(n: float, q: np.ndarray) -> str | None:
    """Where harmonic n [cycles per revolution] sits in the scan over a joint's motion q (N,): `shortest` at the
    shortest period scanned (the torque's own may be shorter), `longest` at the longest the motion spans, of
    several (it may be longer), None inside the scan (or for no harmonic, n = 0)."""
    if not n:
        return None
    if n >= COGGING_HARMONICS[-1]:
        return "shortest"
    shown = _scanned_harmonics(q)
    return "longest" if shown.size > 1 and n == shown[0] else None


def _cogging(plant: Plant, train: Signals | None) -> list[Candidate]:
    """Position-periodic torque (cogging, commutation ripple) per actuated joint, at the period the training
    residual shows (`cogging_harmonic`); without training signals, none."""
    if train is None:
        return []
    out = []
    for j, name in enumerate(plant.joint_names):
        harmonic = cogging_harmonic(train, j) if plant.actuated[j] else None
        if harmonic is None:
            continue
        n = harmonic[0]

        def build(s: Signals, j: int = j, n: float = n) -> np.ndarray:
            out = np.zeros((s.n_samples, plant.nv, 2))
            out[:, j, 0], out[:, j, 1] = np.sin(n * s.q[:, j]), np.cos(n * s.q[:, j])
            return out

        def amplitude(coef: np.ndarray, cov: np.ndarray, _: np.ndarray) -> tuple[float, float]:
            a = float(np.hypot(coef[0], coef[1]))
            if a == 0:
                return 0.0, float("nan")
            grad = coef[:2] / a
            return a, float(np.sqrt(max(grad @ cov[:2, :2] @ grad, 0.0)))

        note = (
            f"position-periodic torque (cogging) a sin(n q) + b cos(n q), n = {n:g} cycles per revolution (period "
            f"{2 * np.pi / n:.4g} rad); MuJoCo has no such attribute: numeric sysid_cogging_<joint> = [n, a, b]"
        )
        out.append(
            Candidate(
                "cogging",
                name,
                "N m",
                "custom numeric",
                (f"cs{j + 1}", f"cc{j + 1}"),
                build,
                amplitude,
                (),
                note,
                f"{n:g}",
            )
        )
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
        ((-float(plant.stiffness[j]), np.inf), (-np.inf, np.inf)),  # a spring: total stiffness >= 0
    )


def _joint_offset(plant: Plant, j: int) -> Candidate:
    def build(s: Signals) -> np.ndarray:
        return -s.dtau_dq[:, :, j : j + 1]

    return Candidate(
        "joint_offset",
        plant.joint_names[j],
        "rad",
        "joint ref",
        (f"dq0_{j + 1}",),
        build,
        _first,
        ((-MAX_JOINT_OFFSET, MAX_JOINT_OFFSET),),
    )


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
        bounds = ((0.0, np.inf),) + ((-np.inf, np.inf),) * (len(cols) - 1)  # a payload adds mass
        out.append(Candidate("payload", body, "kg", "body inertial", names, build, _first, bounds))
    return out


def _rigid_body(plant: Plant, rng: np.random.Generator) -> list[Candidate]:
    base = base_parameters(ParameterModel(plant, ()), rng)
    idx = base.independent

    def build(s: Signals) -> np.ndarray:
        return s.regressor[:, :, idx]

    names = tuple(f"d({n})" for n in base.names)
    return [Candidate("rigid_body", "", "N m", "every body inertial", names, build, _torque_rms)]


_Factory = Callable[[Plant, np.random.Generator, "Signals | None"], list[Candidate]]

CANDIDATE_EFFECTS: dict[str, _Factory] = {
    "armature": lambda p, rng, s: [c for c in _joint_effects(p) if c.effect == "armature"],
    "backlash": lambda p, rng, s: [c for c in _compliance(p) if c.effect == "backlash"],
    "cogging": lambda p, rng, s: _cogging(p, s),
    "coulomb_friction": lambda p, rng, s: [
        *(c for c in _joint_effects(p) if c.effect == "coulomb_friction"),
        *_soft_friction(p, s),
    ],
    "friction_ramp": lambda p, rng, s: _friction_ramps(p, s),
    "joint_elasticity": lambda p, rng, s: [c for c in _compliance(p) if c.effect == "joint_elasticity"],
    "joint_offset": lambda p, rng, s: [_joint_offset(p, j) for j in range(p.nv)],
    "joint_stiffness": lambda p, rng, s: [_stiffness(p, j) for j in range(p.nv)],
    "load_friction": lambda p, rng, s: _load_friction(p),
    "payload": lambda p, rng, s: _payloads(p, rng),
    "rotor_coupling": lambda p, rng, s: _rotor_couplings(p),
    "rigid_body": lambda p, rng, s: _rigid_body(p, rng),
    "smooth_coulomb_friction": lambda p, rng, s: [c for c in _shape_friction(p) if c.effect.startswith("smooth")],
    "stribeck_friction": lambda p, rng, s: [c for c in _shape_friction(p) if c.effect == "stribeck_friction"],
    "time_delay": lambda p, rng, s: [c for c in _joint_effects(p) if c.effect == "time_delay"],
    "torque_gain": lambda p, rng, s: [c for c in _joint_effects(p) if c.effect == "torque_gain"],
    "torque_offset": lambda p, rng, s: [c for c in _joint_effects(p) if c.effect == "torque_offset"],
    "viscous_friction": lambda p, rng, s: [c for c in _joint_effects(p) if c.effect == "viscous_friction"],
}


# a joint effect's unit on a slide joint (a force, a position in m) instead of a hinge's (a torque, an angle in rad)
_SLIDE_UNITS = {"kg m^2": "kg", "N m s/rad": "N s/m", "N m": "N", "N m/rad": "N/m", "rad": "m"}


def candidates(
    plant: Plant,
    effects: list[str] | tuple[str, ...],
    rng: np.random.Generator,
    train: Signals | None = None,
    *,
    hard_friction: bool = False,
) -> list[Candidate]:
    """Every candidate of the named effects (see `CANDIDATE_EFFECTS`) for this plant.

    Args:
        train: the training signals, for candidates whose shape is read from the data (the cogging period).
        hard_friction: the logs come from a simulation that applied each frictionloss as Coulomb friction: no
            candidate shaped as MuJoCo's own frictionloss constraint (`SOFT_FRICTION`).

    Raises:
        ValueError: unknown effect name (the message lists the valid ones).
    """
    unknown = [e for e in effects if e not in CANDIDATE_EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {unknown}; valid choices: {', '.join(sorted(CANDIDATE_EFFECTS))}")
    slides = {n for n, hinge in zip(plant.joint_names, plant.hinge, strict=True) if not hinge}
    return [
        replace(c, unit=_SLIDE_UNITS.get(c.unit, c.unit)) if c.target in slides else c
        for e in effects
        for c in CANDIDATE_EFFECTS[e](plant, rng, train)
        if not (hard_friction and c.variant == SOFT_FRICTION)
    ]

"""`diagnose`: what the simulation gets wrong on measured data, the named cause, the extended model, the gain.

residual = measured torque - nominal MJCF torque (inverse dynamics along the measured motion)
-> residual analysis (size against the noise floor, spectrum, correlations, worst window, whiteness)
-> candidate effects chosen greedily on the training records (BIC + blocked cross-validation)
-> extended model (calibrated MJCF + sensor corrections)
-> validation records: torque RMS and windowed re-start simulation error of the nominal MJCF, the
   rigid-body refit, the calibrated model and any reference models (such as the authors' own).
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage, optimize

from dynamics.base import base_parameters
from dynamics.errors import DataError
from dynamics.plant import Plant, as_simulated, plant_from_xml
from dynamics.regressor import ParameterModel
from dynamics.stepping import as_stepped, integrator_name, stepping_of
from dynamics.torque import joint_torque, torque_jacobian_q
from envs.dataset import Dataset, scratch_folder
from identify.derivatives import States, derive_states, state_cutoff_hz
from identify.diagnose.anomalies import (
    Anomaly,
    at_limit,
    describe_outside,
    find_anomalies,
    moving_joints,
    outside_training,
    still_joints,
)
from identify.diagnose.calibrate import (
    Extension,
    applied_from_measured,
    calibrated_xml,
    extension_from_fit,
    frictionloss_mapping,
    predict_measured_torque,
)
from identify.diagnose.candidates import (
    IDEAL,
    MAX_DELAY_S,
    SMOOTH_COULOMB_SPEEDS,
    SOFT_FRICTION,
    Candidate,
    Signals,
    candidates,
    signals,
    stack_signals,
)
from identify.diagnose.residuals import (
    analyse_residual,
    changing_offsets,
    describe_signature,
    noise_floor,
    residual_signature,
    whiteness,
)
from identify.diagnose.select import SelectionOptions, Step, _flat, _span_free, fit_columns, select_effects
from identify.diagnose.simulation_error import (
    SimulationError,
    Stepper,
    mujoco_stepper,
    ode_stepper,
    simulation_error,
)
from identify.diagnose.state_noise import check_state_noise, state_noise_share, state_noise_torque
from identify.diagnose.statistics import LinearFit, correlation_time
from identify.estimators.least_squares import safe_sigma

__all__ = [
    "DEFAULT_EFFECTS",
    "Diagnosis",
    "Finding",
    "ReferenceModel",
    "analysis_band",
    "check_torque_columns",
    "diagnose",
    "with_found_lead",
]

DEFAULT_EFFECTS = (
    "armature",
    "backlash",
    "cogging",
    "coulomb_friction",
    "friction_ramp",
    "joint_elasticity",
    "joint_offset",
    "joint_stiffness",
    "load_friction",
    "payload",
    "rigid_body",
    "rotor_coupling",
    "smooth_coulomb_friction",
    "stribeck_friction",
    "time_delay",
    "torque_gain",
    "torque_offset",
    "viscous_friction",
)


# how far [rad] an encoder zeroed where the arm rested (held by its friction) is expected to be from the
# model's zero: a record's angle zero beyond it is pointed out as a likely convention error
RESTING_ZERO = 0.2


@dataclass(frozen=True)
class ReferenceModel:
    """A model that is not an MJCF (such as the authors' identified ones), to compare on the same data.

    Attributes:
        torque: (q, dq, ddq) -> (N, nv) joint torque [N m].
        accel: (q, dq, tau) -> (N, nv) joint acceleration [rad/s^2] (for the simulation error), or None.
    """

    torque: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
    accel: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] | None = None


@dataclass(frozen=True)
class Finding:
    """One named cause, most important first in a diagnosis.

    Attributes:
        effect: DESIGN.md's effect name (or `rigid_body`).
        target: the joint (the body for `payload`; "" for `rigid_body`).
        value, std: the effect's size and standard deviation in `unit`.
        unit: SI unit of value.
        counterpart: where it went in the calibrated MJCF.
        evidence: the numbers it was chosen on (BIC drop, held-out MSE before/after, z).
        torque_rms_after: validation torque RMS per joint with the findings up to this one [N m].
        parameters: its coefficients: name, value, std, at_bound (`lower`, `upper` or None).
        at_bound: `lower` or `upper` when the headline value sits on its physical bound (its std is then
            not defined), else None.
        fold_gains: relative drop of the held-out error in each cross-validation fold when it was added.
        confounded_with: the alternatives these data cannot separate from it: effect, target and the share
            of its column left unexplained by the alternative (0: indistinguishable); for one its columns
            absorb (`_with_confounding`), the share of the alternative's column instead, and the value and std
            it takes in the same fit.
        separate_by: the motion that would separate it from those alternatives.
        note: how the calibrated MJCF holds it where MuJoCo has no attribute for it.
        held_nominal: parameters of the effect left at their nominal values: offset-like rigid-body columns
            whose refit did not lower the held-out error (`identify.diagnose.select`).
    """

    effect: str
    target: str
    value: float
    std: float
    unit: str
    counterpart: str
    evidence: dict[str, float]
    torque_rms_after: dict[str, float]
    parameters: list[dict[str, Any]] = field(default_factory=list)
    at_bound: str | None = None
    fold_gains: list[float] = field(default_factory=list)
    confounded_with: list[dict[str, Any]] = field(default_factory=list)
    separate_by: str = ""
    note: str = ""
    held_nominal: list[str] = field(default_factory=list)

    @property
    def name(self) -> str:
        """The effect and its target, and its confounded alternatives (`a shoulder or b`)."""
        own = f"{self.effect} {self.target}".strip()
        alts = [f"{c['effect']} {c['target']}".strip() for c in self.confounded_with]
        return " or ".join([own, *alts])

    def to_dict(self) -> dict[str, Any]:
        where = {"body": self.target} if self.effect == "payload" else {"joint": self.target or None}
        return {
            "effect": self.effect,
            **where,
            "value": _num(self.value),
            "std": _num(self.std),
            "unit": self.unit,
            "counterpart": self.counterpart,
            "evidence": {k: _num(v) for k, v in self.evidence.items()},
            "torque_rms_after": self.torque_rms_after,
            "parameters": self.parameters,
            "at_bound": self.at_bound,
            "fold_gains": self.fold_gains,
            "fold_gain_spread": _spread(self.fold_gains),
            "confounded": bool(self.confounded_with),
            "confounded_with": self.confounded_with,
            "separate_by": self.separate_by or None,
            "note": self.note or None,
            "held_nominal": self.held_nominal,
        }


@dataclass(frozen=True)
class Diagnosis:
    """The answer of `diagnose`; `to_dict()` is diagnosis.json.

    Attributes:
        system: plant name.
        joint_names: (nv,) joints.
        verdict: `explained`, `unexplained_structure` or `no_discrepancy`.
        findings: most important first.
        models: per model name (`nominal`, `rigid_body_refit`, `calibrated`, references):
            {`torque_rms` {joint}, `simulation_error` {joint}} on the validation records, and where some
            torques are left out of the fit and the verdict (a joint resting in its nominal frictionloss, too
            slow for Coulomb friction) `torque_rms_judged` {joint} over the rest.
        residual: residual analysis of the nominal model on the training records.
        whiteness: per joint, of the nominal and the calibrated residual on the validation records.
        noise_floor: per joint torque noise std [N m].
        frictionloss_mapping: per joint, MuJoCo's frictionloss against the fitted Coulomb term.
        calibrated_xml: the calibrated MJCF text.
        notes: anything the caller should know (clipped values, unidentifiable directions).
        series: validation time series for the recording, one entry per validation record, in the analysis
            band as the table compares them (see `_validation_series`; not in to_dict).
        remaining: per joint, the signature of what the calibrated model leaves on the validation records
            (spectral peaks, correlation with q, dq, sign(dq), ddq, position-periodic content).
        anomalies: data anomalies named before fitting (`anomalies.find_anomalies`).
        verdict_reason: why the verdict is what it is.
    """

    system: str
    joint_names: tuple[str, ...]
    verdict: str
    findings: list[Finding]
    models: dict[str, dict[str, dict[str, float]]]
    residual: dict[str, Any]
    whiteness: dict[str, Any]
    noise_floor: dict[str, float]
    frictionloss_mapping: dict[str, dict[str, float]]
    calibrated_xml: str
    info: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    series: dict[str, Any] = field(default_factory=dict)
    remaining: dict[str, Any] = field(default_factory=dict)
    anomalies: list[dict[str, Any]] = field(default_factory=list)
    verdict_reason: str = ""

    def to_dict(self, *, mjcf_name: str | None = None) -> dict[str, Any]:
        """diagnosis.json: the DESIGN.md contract plus the supporting analysis."""
        nominal, calibrated = self.models["nominal"], self.models["calibrated"]
        return {
            "system": self.system,
            "verdict": self.verdict,
            "baseline": {"torque_rms": nominal["torque_rms"], "simulation_error": nominal["simulation_error"]},
            "findings": [f.to_dict() for f in self.findings],
            "extended": {
                "torque_rms": calibrated["torque_rms"],
                "mjcf": mjcf_name or f"{self.system}_calibrated.xml",
                "simulation_error": {
                    "nominal": nominal["simulation_error"],
                    "extended": calibrated["simulation_error"],
                },
            },
            "models": self.models,
            "noise_floor": self.noise_floor,
            "residual": self.residual,
            "whiteness": self.whiteness,
            "verdict_reason": self.verdict_reason,
            "remaining": self.remaining,
            "anomalies": self.anomalies,
            "frictionloss_mapping": self.frictionloss_mapping,
            "info": self.info,
            "notes": self.notes,
        }


def _spread(gains: list[float]) -> dict[str, float] | None:
    if not gains:
        return None
    g = np.asarray(gains, dtype=float)
    g = g[np.isfinite(g)]  # a fold with no value fitted has no gain
    if not g.size:
        return None
    return {"min": float(g.min()), "median": float(np.median(g)), "max": float(g.max()), "std": float(g.std())}


def _num(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _per_joint(names: tuple[str, ...], values: np.ndarray) -> dict[str, float]:
    return {n: float(v) for n, v in zip(names, values, strict=True)}


@dataclass(frozen=True)
class _Record:
    data: Dataset
    states: States
    signals: Signals


_STRUCTURE_HZ = 10.0  # the band a residual's structure is judged in, at most [Hz]: where model errors live


def _structure_band(data: Dataset, method: str, options: dict[str, Any]) -> float:
    """The band [Hz] a residual's whiteness is judged in: `_STRUCTURE_HZ`, or half the derivative filter's cut-off
    where that is lower. Encoder noise differentiated twice grows as f^2 up to the cut-off and, through the
    inertia, is torque noise the sensor's floor does not count (a UR5e's base joint on clean data: a residual 4
    times its floor, peaking at 11-14 Hz above a 10 Hz cut-off); below half the cut-off it has a 32nd of that
    power, while the motion's own harmonics, which the cut-off passes 4 times over, stay in the band."""
    cutoff = state_cutoff_hz(data, method, **options)
    return _STRUCTURE_HZ if cutoff is None else min(_STRUCTURE_HZ, 0.5 * cutoff)


def analysis_band(
    band_hz: float | None, datasets: Sequence[Dataset], method: str, options: dict[str, Any]
) -> float | None:
    """The band [Hz] measured and model torques are compared in: `band_hz`, and never above the cut-off of the
    filter the states went through (the lowest over `datasets`; None for exact states and no band asked).

    Above that cut-off the states (so every column and the nominal torque built from them) hold nothing, while the
    measured torque still does: a force the plant feels as a short pulse (a Stribeck peak at a reversal, some
    20 ms at 0.1 rad/s) is in the measured motion's acceleration, which the filter smooths, so the residual
    tau - ID(q, dq, ddq) holds that force low-passed at the cut-off, and its column, built from the smooth dq,
    holds it whole. A fit of the one on the other is pulled towards zero (a 0.08 N m Stribeck peak came out
    0.043 +- 0.005); filtering both sides at the cut-off keeps them alike (0.076 +- 0.004; 0.079 +- 0.004 with the
    column through the state filter too, `Signals.columns`).
    """
    cutoffs = [c for c in (state_cutoff_hz(d, method, **options) for d in datasets) if c is not None]
    if not cutoffs:
        return band_hz
    return min(min(cutoffs), band_hz) if band_hz is not None else min(cutoffs)


def _state_cutoffs(records: Sequence[_Record]) -> list[dict[str, Any]]:
    """Per record (training, then validation; two blocks of one file are two records): its `source` and the
    `cutoff_hz` [Hz] its states were filtered at, as its signals carry it (`_records`: the one asked for, or the one
    derived from its excitation; None for exact states)."""
    return [{"source": str(r.data.source), "cutoff_hz": r.signals.state_hz[0][1]} for r in records]


def _records(
    plant: Plant, datasets: Sequence[Dataset], method: str, options: dict[str, Any], band_hz: float | None
) -> list[_Record]:
    out = []
    for i, data in enumerate(datasets):
        if tuple(data.joint_names) != plant.joint_names:
            raise ValueError(
                f"{data.source}: joints {list(data.joint_names)} differ from the MJCF's {list(plant.joint_names)}"
            )
        states = derive_states(data, method, **options)
        sig = signals(plant, data, states, record=i, band_hz=band_hz, state_hz=state_cutoff_hz(data, method, **options))
        out.append(_Record(data, states, sig))
    return out


SIGN_CORRELATION = -0.5  # a measured torque this anti-correlated with the nominal model's ...
SIGN_SIZE = -0.1  # ... and at least this large a share of it with the opposite sign has a flipped sign (C.1 143704's
# shoulder, all but passive, carries 0.18 of the nominal torque) ...
FRICTION_EXPLAINS = 0.9  # ... unless the nominal torque with a joint friction >= 0 beside it explains this share of it

# the measured torque of a moving actuated joint varies at least / at most this many times as much as the nominal
# model's (outside: a dead sensor, another unit, a time axis off by a factor). The DFKI logs span 0.083 (C.1
# 144115's elbow, commanded zero torque: such a joint is not held to the lower bound) to 1.78. The upper bound
# leaves room for a nominal model without the rotor inertia a geared joint reflects (a URDF's: tens of times a
# wrist link's inertia) and still catches a factor of 1000
TORQUE_SHARE = (0.04, 200.0)
# a measured torque of which the nominal torque, a viscous and a Coulomb friction and a spring (each with a free
# coefficient) explain less than this share, and less than `CHANCE_FACTOR` times what four columns explain of noise
# by chance (4 / the record's independent samples in the band), does not follow the motion at all: noise, another
# motion's log, a time axis not the angles'. The DFKI logs' driven joints are explained to 0.94-0.997
UNRELATED_SHARE = 0.2
CHANCE_FACTOR = 3.0
SWAP_CORRELATION = 0.5  # two torques each correlated this well with the other joint's nominal torque ...
SWAP_MARGIN = 0.2  # ... and by this much better than with their own are swapped columns


def check_torque_columns(plant: Plant, data: Dataset, signal: Signals, moving: np.ndarray | None = None) -> None:
    """Refuse a record whose torque column has the opposite sign of the torque the nominal model needs along
    the motion, varies far less or more than it (`TORQUE_SHARE`: a dead sensor, another unit), or two columns
    that follow each other's joint: a model error moves the torque by a share of
    its size, never turns it around or over to another joint, and a fit would turn the model instead (negative
    masses, a gain of -1).

    Only joints that move in the record are compared (a joint held by static friction carries any torque
    within its breakaway): `moving` (nv,), None to find them.

    Raises:
        DataError: the file, the column (as the file names it) and the two correlations.
    """
    a = signal.smooth(signal.tau_nominal)
    tau_band = signal.smooth(signal.tau)
    b = tau_band
    if moving is None:
        moving = moving_joints(data, plant.hinge)
    joints = [int(j) for j in np.flatnonzero(np.asarray(plant.actuated, bool) & moving)]
    commanded_zero = np.zeros(plant.nv, bool) if data.tau_cmd is None else np.all(np.abs(data.tau_cmd) < 1e-9, axis=0)
    a = a - a.mean(axis=0)
    b = b - b.mean(axis=0)
    na, nb = np.linalg.norm(a, axis=0), np.linalg.norm(b, axis=0)
    ok = (na > 0) & (nb > 0)
    r = np.where(np.outer(ok, ok), (b.T @ a) / np.maximum(np.outer(nb, na), 1e-300), 0.0)  # r[i, j]: tau_i, nominal_j
    names = plant.joint_names
    src = data.source or "the record"  # the full path: two folders may hold files of one name

    def column(j: int) -> str:
        return _file_column(data, f"tau_{names[j]}")

    band = f" below {signal.band_hz:g} Hz" if signal.band_hz else ""
    for x, i in enumerate(joints):
        for j in joints[x + 1 :]:
            if min(r[i, j], r[j, i]) > SWAP_CORRELATION and max(r[i, i], r[j, j]) < min(r[i, j], r[j, i]) - SWAP_MARGIN:
                raise DataError(
                    f"{src}: {column(i)} follows the torque the nominal model needs at {names[j]} (correlation "
                    f"{r[i, j]:.2f}{band}) and {column(j)} that at {names[i]} ({r[j, i]:.2f}), better than their own "
                    f"joints' ({r[i, i]:.2f}, {r[j, j]:.2f}): the two columns look swapped; map them the other way "
                    "round in data.columns (or set diagnose.check_torque_signs=false)"
                )
    _check_angle_columns(plant, data, signal, tau_band, [int(j) for j in np.flatnonzero(moving)], src)
    # the friction and spring columns beside the nominal torque, centred, in the band: (N, nv) each
    speed, sign, angle = (x - x.mean(axis=0) for x in map(signal.smooth, (signal.dq, np.sign(signal.dq), signal.q)))
    for j in joints:
        size = float(b[:, j] @ a[:, j]) / max(float(na[j]) ** 2, 1e-300)
        share = float(nb[j]) / max(float(na[j]), 1e-300)
        low = share < TORQUE_SHARE[0] and not commanded_zero[j]  # a joint driven with zero torque carries ~none
        if low or share > TORQUE_SHARE[1]:
            why = (
                "a dead or disconnected sensor, a torque in another unit (a factor near 1000: kN m), time in "
                "another unit (the torque needed goes with its square), angles logged in degrees (a motion 57 times "
                "as large) or another joint's column"
                if low
                else "a torque in another unit (a factor near 1000: mN m), or a nominal model far lighter than the "
                "robot"
            )
            raise DataError(
                f"{src}: {column(j)} varies {share:.3g} times as much as the torque the nominal model needs at "
                f"{names[j]} along the motion{band}: {why}; give a scale or the right column in the column mapping "
                f"(data.columns.tau_{names[j]}), or set diagnose.check_torque_signs=false if the nominal model is "
                "that far off"
            )
        explained, chance = _motion_explains(a[:, j], b[:, j], (speed[:, j], sign[:, j], angle[:, j]), signal.record)
        if explained < UNRELATED_SHARE and explained < CHANCE_FACTOR * chance and not commanded_zero[j]:
            raise DataError(
                f"{src}: {column(j)} does not follow the motion: the torque the nominal model needs at {names[j]}, "
                f"a friction and a spring, each scaled freely, explain {100 * explained:.2g} % of its variance"
                f"{band} (noise: {100 * chance:.2g} % by chance): noise only, another joint's or another run's "
                "column, or a time column not the angles'; give the right column in data.columns, or set "
                "diagnose.check_torque_signs=false if the joint's torque really is unrelated to its motion"
            )
        friction = (speed[:, j], sign[:, j])
        if r[j, j] < SIGN_CORRELATION and size < SIGN_SIZE and not _friction_explains(a[:, j], b[:, j], friction):
            raise DataError(
                f"{src}: {column(j)} runs against the torque the nominal model needs at {names[j]} along the motion "
                f"(correlation {r[j, j]:.2f}{band}, {size:.2f} times its size): its sign looks flipped: negate its "
                f"scale in the column mapping (data.columns.tau_{names[j]}); or, where the joint's angle counts the "
                "other way round than the model's axis, negate the angle's and the velocity's scales instead; or "
                "set diagnose.check_torque_signs=false if the motion really needs the opposite torque"
            )


def _motion_explains(
    nominal: np.ndarray, measured: np.ndarray, columns: tuple[np.ndarray, ...], record: np.ndarray
) -> tuple[float, float]:
    """(The share of the variance of a joint's measured torque that its nominal torque and `columns` (its speed,
    sign of speed and angle: a viscous and a Coulomb friction and a spring) explain, each with a free coefficient;
    the share as many columns explain of noise by chance, their number / the independent samples, from the measured
    torque's correlation time within each `record`.) Every (N,) array centred, in the band."""
    X = np.column_stack([nominal, *columns])
    X = X[:, np.linalg.norm(X, axis=0) > 0]
    fit = np.linalg.lstsq(X, measured, rcond=None)[0]
    total = max(float(measured @ measured), 1e-300)
    explained = 1.0 - float(np.sum((measured - X @ fit) ** 2)) / total
    independent = len(measured) / correlation_time(measured, record)
    return explained, min(1.0, X.shape[1] / independent)


def _friction_explains(nominal: np.ndarray, measured: np.ndarray, friction: tuple[np.ndarray, np.ndarray]) -> bool:
    """Whether a measured torque that runs against the nominal one (both (N,), centred, in the band) is that torque
    plus the joint's friction, which the nominal model may lack: with a viscous and a Coulomb friction >= 0 fitted
    (`friction`: the joint's speed and sign of speed, centred, in the band)
    beside it, the nominal torque's coefficient is at least `SIGN_SIZE` and the fit explains `FRICTION_EXPLAINS` of
    the measured torque's variance. A friction larger than the torque the model needs (a heavily damped joint driven
    above its resonance) can turn the plain correlation negative while the torque's sign is right: on the lab's
    analytic model with an elbow viscous friction of 0.05 N m s/rad driven at 12 rad/s, the correlation was -0.51
    (-3.02 times the size) and the record was refused as flipped; beside the friction the coefficient is 0.999 and
    the share explained 0.99998. A flipped column's friction would have to be negative; the share asked keeps a
    flipped column of a joint that hardly moves refused (a C.1 shoulder: coefficient 0.77, share 0.65)."""
    X = np.column_stack([nominal, *friction])
    scale = np.maximum(np.linalg.norm(X, axis=0), 1e-300)
    fit = optimize.lsq_linear(X / scale, measured, bounds=([-np.inf, 0.0, 0.0], [np.inf, np.inf, np.inf]))
    left = float(np.sum((measured - (X / scale) @ fit.x) ** 2)) / max(float(np.sum(measured**2)), 1e-300)
    return float(fit.x[0] / scale[0]) >= SIGN_SIZE and 1.0 - left >= FRICTION_EXPLAINS


# two angle columns look swapped where the nominal model, given them the other way round, leaves at most this
# share of its torque misfit (RMS over the actuated joints, in the analysis band)
ANGLE_SWAP_RATIO = 0.5
_ANGLE_SWAP_ROWS = 2000  # rows (evenly spaced) the swapped models are evaluated on
# every torque column reads as flipped only where negating all of them leaves at most this share of the misfit
# that negating the best single one leaves
ONE_FLIPPED_RATIO = 0.8


def _file_column(data: Dataset, ours: str) -> str:
    """A column by our name, with the file's own name where the column mapping gave it another."""
    cols = data.meta.get("columns", {})
    return f"{ours} (the file's {cols[ours]})" if ours in cols and cols[ours] != ours else ours


def _check_angle_columns(
    plant: Plant, data: Dataset, signal: Signals, tau_band: np.ndarray, moving: list[int], src: str
) -> None:
    """Refuse a record whose angle zero is half a turn off the model's (a hinge's, or every moving hinge's: the
    zero upright where the model's hangs), whose two angle columns (of joints that move) are swapped, or whose
    every torque column has the wrong sign: the nominal model fed the angles turned by pi, or the other way round,
    or its torque negated, fits the measured torque (`tau_band`: in the analysis band) far better
    (`ANGLE_SWAP_RATIO`) than as given; the best of these readings is named. Joints of other kinds (a hinge and a
    slide) are not paired. Every torque flipped had been read as both zeros half a turn off (gravity pulls the
    other way under both), and the offset it advised gave a wrong calibrated MJCF.

    Raises:
        DataError: the two columns (as the file names them) and both misfits.
    """
    rows = np.unique(np.linspace(0, signal.n_samples - 1, min(_ANGLE_SWAP_ROWS, signal.n_samples)).astype(int))
    act = np.asarray(plant.actuated, bool)
    measured = tau_band[rows][:, act]

    def misfit(tau_nominal: np.ndarray) -> float:  # tau_nominal (rows, nv): of the filtered states, smooth
        return float(np.sqrt(np.mean((measured - tau_nominal[:, act]) ** 2)))

    nominal = signal.tau_nominal[rows]
    own = misfit(nominal)
    q, dq, ddq = signal.q[rows], signal.dq[rows], signal.ddq[rows]

    def column(j: int) -> str:
        return _file_column(data, f"q_{plant.joint_names[j]}")

    found: list[tuple[float, str]] = []  # (misfit, what the refusal says) of every alternative reading
    driven = [int(j) for j in moving if act[j]]
    negated = misfit(-nominal)

    def one_negated(j: int) -> float:
        flip = nominal.copy()
        flip[:, j] *= -1.0
        return misfit(flip)

    # every torque negated (pi on the angles flips gravity alone, a flipped sign inertia and friction too), where
    # it does clearly better than any single column negated (one flipped column, beside one that carries about no
    # torque such as a passive joint's: the sign check below names it)
    if driven and (len(driven) == 1 or negated < ONE_FLIPPED_RATIO * min(one_negated(j) for j in driven)):
        names = ", ".join(_file_column(data, f"tau_{plant.joint_names[j]}") for j in driven)
        subject = f"the torque column {names}" if len(driven) == 1 else f"every torque column ({names})"
        found.append(
            (
                negated,
                f"{subject} runs against the torque the nominal model needs: the model misses "
                f"the measured torque by {own:.3g} (RMS over the actuated joints) as given and by {negated:.3g} "
                "with it negated: the sign looks flipped; negate the scale in the column mapping "
                "(data.columns.tau_<joint>: {column, scale: -1}); or, where the angles count the other way round "
                "than the model's axes, negate the angles' and the velocities' scales instead",
            )
        )
    hinges = [j for j in moving if plant.hinge[j]]
    for turned in [[j] for j in hinges] + ([hinges] if len(hinges) > 1 else []):
        shifted = q.copy()
        shifted[:, turned] += np.pi
        other = misfit(joint_torque(plant, shifted, dq, ddq)[0])
        found.append(
            (
                other,
                f"the zero of {' and '.join(column(j) for j in turned)} looks half a turn off the model's: the "
                f"nominal model misses the measured torque by {own:.3g} (RMS over the actuated joints) with the "
                f"angles as given and by {other:.3g} with pi added (gravity then pulls the other way); give an "
                "offset of 3.14159 (or -3.14159) in the column mapping (data.columns.q_<joint>: {column, offset}); "
                "where the model is at fault instead (a centre of mass on the other side of the axis), fix it or "
                "set diagnose.check_torque_signs=false",
            )
        )
    for x, i in enumerate(moving):
        for j in moving[x + 1 :]:
            if plant.hinge[i] != plant.hinge[j]:
                continue
            order = np.arange(plant.nv)
            order[[i, j]] = j, i
            other = misfit(joint_torque(plant, q[:, order], dq[:, order], ddq[:, order])[0])
            found.append(
                (
                    other,
                    f"{column(i)} and {column(j)} look swapped: the nominal model misses the measured torque by "
                    f"{own:.3g} (RMS over the actuated joints) with the angles as given and by {other:.3g} with "
                    "them exchanged; map them the other way round in data.columns (or set "
                    "diagnose.check_torque_signs=false)",
                )
            )
    if found:
        other, what = min(found, key=lambda f: f[0])
        if other < ANGLE_SWAP_RATIO * own:
            raise DataError(f"{src}: {what}")


def _rows(rec: _Record) -> np.ndarray:
    valid = np.flatnonzero(rec.states.valid)
    return np.arange(valid[0], valid[-1] + 1)


def _weights(plant: Plant, floor: np.ndarray) -> np.ndarray:
    sigma = floor.copy()
    act = np.asarray(plant.actuated, dtype=bool)
    best = float(np.min(sigma[act])) if np.any(act) else 1.0
    sigma[~act] = best
    sigma = np.maximum(sigma, 1e-6 * max(float(sigma.max()), 1e-12) + 1e-12)
    return 1.0 / sigma**2


@dataclass(frozen=True)
class _Simulated:
    """One model's re-started simulation of the validation records: `rms` (nv,) pooled over every record [rad],
    `runs` each record's `SimulationError` (its time series are the recording's)."""

    rms: np.ndarray
    runs: list[SimulationError]


def _simulate(
    stepper: tuple[Stepper, float],
    records: list[_Record],
    tau_in: Callable[[_Record], np.ndarray],
    window_s: float,
    max_windows: int | None,
) -> _Simulated:
    """The simulation error of one model on every record; `max_windows` shared among the records by duration
    (one at least each), so that a long log's error is estimated on windows spread over all of it."""
    spans = np.array([float(r.data.time[-1] - r.data.time[0]) for r in records])
    runs = []
    for rec, span in zip(records, spans, strict=True):
        rows = _rows(rec)
        cap = None if max_windows is None else max(1, int(max_windows * span / max(spans.sum(), 1e-12)))
        runs.append(
            simulation_error(
                stepper,
                rec.data.time[rows],
                rec.states.q[rows],
                rec.states.dq[rows],
                tau_in(rec)[rows],
                window_s=window_s,
                max_windows=cap,
            )
        )
    n = sum(len(r.time) for r in runs)
    sq = sum(r.rms**2 * len(r.time) for r in runs)
    return _Simulated(rms=np.sqrt(sq / max(n, 1)), runs=runs)


def _rms(pred: np.ndarray, meas: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean((meas - pred) ** 2, axis=0))


def diagnose(
    plant: Plant,
    train: Sequence[Dataset],
    validation: Sequence[Dataset],
    *,
    rng: np.random.Generator,
    effects: Sequence[str] = DEFAULT_EFFECTS,
    derivatives: str = "butterworth",
    derivative_options: dict[str, Any] | None = None,
    selection: SelectionOptions | None = None,
    window_s: float = 0.25,
    max_windows: int | None = 2000,
    references: dict[str, ReferenceModel] | None = None,
    band_hz: float | None = None,
    record_offsets: bool = False,
    anomalies: Sequence[Anomaly] | None = None,
    check_torque_signs: bool = True,
    hard_friction: bool = False,
    record_joint_offsets: bool = False,
    mujoco_steps: bool | None = None,
) -> Diagnosis:
    """Diagnose the nominal MJCF of `plant` on measured records.

    Args:
        plant: the nominal model.
        train: records the effects are chosen and fitted on.
        validation: records the fit never sees (the gain is measured on them).
        rng: randomness (generic states for the identifiability of candidate columns).
        effects: candidate effect names (see `candidates.CANDIDATE_EFFECTS`).
        derivatives, derivative_options: how q is filtered and differentiated (`identify.derivatives`).
        selection: thresholds of the selection.
        window_s: re-start window of the simulation error [s].
        max_windows: the simulation error's windows at most (all validation records together, shared by
            duration, one at least per record, so more records than this simulate one each): a longer log
            simulates that many, spread evenly over it (`simulation_error`); None: every window.
        references: other models to evaluate on the validation records (e.g. the authors' identified ones).
        band_hz: parallel low-pass of measured and model torques before they are compared (see `Signals`);
            never above the derivative filter's cut-off, which is the band where it is None (`analysis_band`).
        record_offsets: fit a torque offset per training record and actuated joint as a nuisance (sensors
            re-zeroed at every power-up drift between recordings); the calibrated model uses their mean.
            Needs two or more training records; the torque_offset candidate is then never named.
        record_joint_offsets: fit an angle offset per training record and joint as a nuisance (reported minus
            true angle): encoders zeroed wherever the arm rested when each record began, as the DFKI logs' are
            (every file starts at 0.0002 rad on both joints, where friction held the arm, not where it hangs).
            Made exact in the final fit (the nominal torque re-evaluated at each record's q - offset); reported
            with their stds in `info["record_joint_offsets"]`. The calibrated model carries none of them: the
            zero of a record to come is where that arm will rest, unknown, and the model's own q = 0 is its best
            guess (their mean was measured worse on the shared logs, see bench/diagnose.md). Needs two or more
            training records; a joint_offset shared by every record is then never named (their columns span it).
            Not with `record_offsets` (refused): on C.1's logs the two traded a torque zero of -1.1 N m against an
            angle zero of -0.38 rad on two files, and the model carried the torque zeros' mean without the angles.
        anomalies: the records' anomalies when found before (on the full-rate records of reduced ones);
            None finds them on `train` and `validation`.
        check_torque_signs: refuse a record whose torque columns look flipped or swapped
            (`check_torque_columns`).
        hard_friction: the records come from a simulation that applied each frictionloss as Coulomb friction
            (`sysid-run`'s `system.hard_friction`): the plant's friction is read as `plant` reads it (ideal
            Coulomb but for a declared ramp). False: as MuJoCo applies it (`dynamics.plant.as_simulated`).
        mujoco_steps: the records are a log of MuJoCo's own simulation of the model at its step (positions and the
            actuator force of each step), whose integrator adds an inertia to the logged torque
            (`dynamics.stepping`): read them so (True), as a robot's (False), or so where that inertia, at its
            size, fits the training residual (None: one factor within 1 +- `STEP_SCALE_BAND` and `STEP_MIN_Z` std
            from 0, `_steps_reading`; an armature change of that size on every joint would read the same, and
            the note says so).

    Returns:
        The diagnosis (see `Diagnosis`).
    """
    if not train or not validation:
        raise ValueError("diagnose needs at least one training and one validation record")
    if record_offsets and record_joint_offsets:
        raise ValueError(
            "record_offsets and record_joint_offsets together: a torque zero and an angle zero per record are nearly "
            "the same column on motions about one pose; fit the one the sensors call for"
        )
    simulated = partial(as_simulated, hard_friction=hard_friction)  # each model as the logs' simulator applied it
    plant = simulated(plant)
    selection = selection or SelectionOptions()
    if anomalies is None:
        anomalies = find_anomalies([*train, *validation], plant.hinge, plant.q_range, plant.limit_margin)
    anomalies = list(anomalies)
    options = dict(derivative_options or {})
    asked_band_hz = band_hz
    band_hz = analysis_band(band_hz, [*train, *validation], derivatives, options)
    tr = _records(plant, train, derivatives, options, band_hz)
    steps_read = _steps_reading(plant, tr, mujoco_steps)
    if steps_read is not None and steps_read["read"]:
        simulated = partial(_stepped_after, simulated)
        plant = as_stepped(plant)
        if steps_read["positions_after_step"]:  # each row's torque is the step before it's: read it there
            h = steps_read["timestep_s"]
            train = [_a_step_earlier(d, h, derivatives) for d in train]
            validation = [_a_step_earlier(d, h, derivatives) for d in validation]
        tr = _records(plant, train, derivatives, options, band_hz)
    rest = np.zeros((len(tr), plant.nv))  # each training record's angle offset, found before the selection
    if record_joint_offsets and len(tr) > 1:
        # every column is then evaluated at each record's q - offset, not only the nominal torque in the final fit
        rest = _record_angles_alone(plant, tr)
        shifted = [dataclasses.replace(d, q=d.q - o) for d, o in zip(train, rest, strict=True)]
        tr = _records(plant, shifted, derivatives, options, band_hz)
    va = _records(plant, validation, derivatives, options, band_hz)
    state_noise_va: list[np.ndarray] = []  # what the angles' noise adds to each validation record's torque
    for k, rec in enumerate([*tr, *va]):
        # a joint in its stops on much of the record carries the stop's force there: not compared, as a still one
        stopped = np.mean(_at_stops(plant, rec.data.q), axis=0) > STOPPED_SHARE
        moving = moving_joints(rec.data, plant.hinge) & ~stopped
        if check_torque_signs:
            check_torque_columns(plant, rec.data, rec.signals, moving)
        s = rec.signals
        noise = state_noise_torque(
            plant, rec.data, rec.states, s.tau_nominal, derivatives, options, np.random.default_rng(0)
        )
        noise_band = None if noise is None else s.smooth(noise)
        share = state_noise_share(s.smooth(s.tau_nominal), noise_band)
        check_state_noise(plant, rec.data, share, derivatives, options, moving=moving, band_hz=band_hz)
        if k >= len(tr):  # none where the states are not the angles' (0 there: no such noise in that record)
            state_noise_va.append(np.zeros_like(s.tau_nominal) if noise_band is None else noise_band)
    names = plant.joint_names
    s_tr, unfitted, held_tr, stopped_tr = _training_signals(plant, tr)
    left_out = [{"source": tr[i].data.source, "joint": names[j]} for i, j in zip(*np.nonzero(unfitted), strict=True)]
    s_va = stack_signals([r.signals for r in va])
    held_va = _held_by_friction(plant, s_va, _never_moving(va, plant.hinge))
    at_rest = {  # per joint: the share of the training rows its nominal frictionloss holds (set-valued torque)
        names[j]: float(np.mean(held_tr[:, j])) for j in range(plant.nv) if held_tr[:, j].any()
    }
    stopped_va = _near_limit(plant, s_va)
    at_stops = {  # per joint: the share of the training rows left out at or beside its range limits
        names[j]: float(np.mean(stopped_tr[:, j])) for j in range(plant.nv) if stopped_tr[:, j].any()
    }
    s_va = _left_out(s_va, held_va | stopped_va)
    for what, sig, recs in (("training", s_tr, tr), ("validation", s_va, va)):
        if sig.used is not None and not np.any(sig.used[:, np.asarray(plant.actuated, bool)]):
            files = ", ".join(Path(r.data.source).name for r in recs)
            in_these = {r.data.source for r in recs}
            why = "; ".join(
                f"{a.joint} at the end of its range on {a.detail['fraction']:.0%} of {Path(a.source).name}"
                if a.kind == "joint_at_limit"
                else f"{a.joint} still in {Path(a.source).name}"
                for a in anomalies
                if a.source in in_these and a.kind in ("joint_at_limit", "joint_never_moves")
            )
            raise DataError(
                f"{files}: no {what} torque is left to judge: on every row each joint is at the end of its range, "
                f"held by its friction at rest, or never moves ({why or 'no anomaly named'}); give files in which "
                "the joints move clear of their stops"
            )
    floor = _noise_floor(tr, unfitted) * plant.actuated
    weights = _weights(plant, floor)

    pool = candidates(plant, list(effects), rng, s_tr, hard_friction=hard_friction)
    nuisance = (
        _record_offset_columns(s_tr) if record_offsets and len(tr) > 1 else np.zeros((s_tr.n_samples, plant.nv, 0))
    )
    m_t = nuisance.shape[2]  # the torque offsets', then the angle offsets' columns
    if record_joint_offsets and len(tr) > 1:
        nuisance = np.concatenate([nuisance, _record_joint_offset_columns(s_tr)], axis=2)
    m = nuisance.shape[2]
    steps, X = select_effects(pool, s_tr, weights, selection, nuisance=nuisance)
    z_floor = selection.min_z_records if len(tr) > 1 else selection.min_z  # the most lenient the selection asks
    sliding = _sliding_rows(s_tr, steps, names)
    chosen = steps
    X, fit, left_tr, steps = _final_fit(
        plant, steps, X, s_tr, weights, m, sliding, record_angles=m_t if m > m_t else None
    )
    not_held = [st.candidate.key for st in chosen if st.candidate.key not in {s.candidate.key for s in steps}]
    lead = _torque_lead(plant, steps, X, s_tr, weights, m, sliding)
    fitted_rows = np.ones((s_tr.n_samples, plant.nv), bool) if s_tr.used is None else s_tr.used
    sticking = {  # per joint: the share of the torques it fits that the final fit left out as sticking
        names[j]: float(np.mean(~sliding[fitted_rows[:, j], j]))
        for j in range(plant.nv)
        if sliding is not None and fitted_rows[:, j].any() and not sliding[fitted_rows[:, j], j].all()
    }
    sources = [r.data.source for r in tr]
    # every anomaly makes a record's mean meaningless, and so does a torque left out of the fit
    unusable = frozenset((a.source, a.joint) for a in anomalies) | {(d["source"], d["joint"]) for d in left_out}
    one_start = _one_start_pose(train, plant.hinge)
    drift = (
        [] if m_t else changing_offsets(left_tr, s_tr.record, names, s_tr.actuated, floor, sources, exclude=unusable)
    )
    offsets_by_record = fit.coef[:m_t].reshape(len(tr), -1) if m_t else np.zeros((0, plant.nv))
    if m_t:
        full = np.zeros((len(tr), plant.nv))
        full[:, plant.actuated] = offsets_by_record
        if s_tr.used is not None:  # no offset is estimated where none of a record's torque of a joint is fitted
            for i in range(len(tr)):  # (a joint that never moves there, at rest in its friction, in its stops)
                full[i, ~np.any(s_tr.used[s_tr.record == i], axis=0)] = np.nan
        offsets_by_record = full
    fitted_here = fitted_rows if sliding is None else fitted_rows & sliding
    angles_by_record, angle_stds = _record_angles(X, fit, start=m_t, stop=m, fitted=fitted_here, n_records=len(tr))
    if angles_by_record.size:
        angles_by_record = angles_by_record + rest  # the final fit's are increments on the pre-pass's
    base_idx = base_parameters(ParameterModel(plant, ()), rng).independent
    sw = np.sqrt(weights)
    metric: np.ndarray = np.linalg.qr(  # type: ignore[assignment]
        (s_tr.smooth(s_tr.regressor) * sw[None, :, None]).reshape(-1, s_tr.regressor.shape[2]), mode="r"
    )
    cols_va = [s_va.columns(st.candidate)[:, :, st.kept] for st in steps]  # the chosen columns, validation rows
    findings = _findings(steps, fit, X, s_tr, s_va, cols_va, weights, names, m, offsets_by_record)
    spread = _prediction_std(cols_va, fit, m, plant.nv)
    outside = outside_training(
        s_tr.q,
        s_tr.dq,
        s_tr.record,
        s_va.q,
        s_va.dq,
        s_va.record,
        names=names,
        sources=[r.data.source for r in va],
        hinge=plant.hinge,
        periodic=np.asarray(plant.stiffness) == 0,  # a joint spring's torque does not repeat every turn
        position_matters=_position_matters(s_tr),
    )
    findings = _with_confounding(findings, steps, pool, s_tr, weights, X, m, fit, selection, z_floor)
    # the selection names an effect only off its value of no effect; refitted with the effects chosen after it,
    # one can still end there (pinned at its bound): it then adds nothing to the model and is not named
    pinned = _pinned_at_null(findings, [st.candidate.null for st in steps])
    findings = [f for f in findings if f not in pinned]
    ext = extension_from_fit(plant, steps, fit, base_idx, record_offsets=offsets_by_record if m_t else None, nuisance=m)
    refit_ext = _rigid_refit(plant, pool, s_tr, weights, base_idx, selection.min_independence)

    with scratch_folder("sysid_diagnose_") as tmp:

        def build(ext: Extension, comment: str = "", suffix: str = "trial") -> tuple[str, Plant]:
            """The calibrated MJCF of `ext` and its model, written as <system>_<suffix>.xml in the scratch folder
            (a trial's file does not replace the calibrated one its Plant was read from)."""
            text = calibrated_xml(plant, ext, metric=metric, comment=comment)
            return text, simulated(plant_from_xml(text, f"{plant.name}_{suffix}", tmp))

        def calibrate(ext: Extension, named: list[Finding]) -> tuple[str, Plant, np.ndarray]:
            comment = ", ".join(f"{f.effect} {f.target}".strip() for f in named) or "no effect found"
            text, model = build(ext, comment, "calibrated")
            return text, model, _predict_records(model, ext, va)

        xml, calibrated, preds_cal = calibrate(ext, findings)
        held_out = _held_out_mse(s_va, s_va.tau_nominal, weights), _held_out_mse(s_va, preds_cal, weights)
        demoted: list[Finding] = []
        if findings and not held_out[1] < held_out[0]:
            # chosen on the training records' folds, but the records held out of the whole fit say otherwise: a
            # finding must generalise, and the calibrated MJCF must not carry what makes it worse there
            demoted, findings = findings, []
            ext = extension_from_fit(
                plant, [], fit, base_idx, record_offsets=offsets_by_record if m_t else None, nuisance=m
            )
            xml, calibrated, preds_cal = calibrate(ext, findings)
        # the friction below sliding speed of each joint whose named Coulomb friction the final fit took from its
        # sliding rows: chosen on the training rows it left out, after the findings were judged (apart from it);
        # what it does on the records held out of the fit is reported, not used to choose (they judge the result)
        named = np.array([any(f.target == n and f.effect in _SIGN_FRICTION for f in findings) for n in names])
        ramped, ramps = _slow_friction_ramps(
            ext,
            None if sliding is None else sliding | ~named,
            s_tr,
            names,
            lambda e: _predict_records(build(e)[1], e, tr),
            preference=selection.native_preference,
            nominal_speed=np.asarray(plant.friction_speed, float),
            own_zeros=m_t > 0,
        )
        ramps_held_out: list[float] = []
        if ramps:
            narrow_mse = _held_out_mse(s_va, preds_cal, weights)
            ext = ramped
            xml, calibrated, preds_cal = calibrate(ext, findings)
            ramps_held_out = [narrow_mse, _held_out_mse(s_va, preds_cal, weights)]
        refit_xml = calibrated_xml(plant, refit_ext, metric=metric)
        refit = simulated(plant_from_xml(refit_xml, f"{plant.name}_refit", tmp))
        models: dict[str, dict[str, dict[str, float]]] = {}
        preds: dict[str, np.ndarray] = {}

        def measured(rec: _Record) -> np.ndarray:
            return rec.data.tau

        def advanced(rec: _Record) -> np.ndarray:
            return applied_from_measured(ext, rec.data.time, rec.data.tau)

        def simulate(model: Plant, tau_in: Callable[[_Record], np.ndarray]) -> _Simulated:
            return _simulate(mujoco_stepper(model.mj_model), va, tau_in, window_s, max_windows)

        preds["nominal"] = s_va.tau_nominal
        preds["rigid_body_refit"] = predict_measured_torque(refit, refit_ext, s_va.time, s_va.q, s_va.dq, s_va.ddq)
        preds["calibrated"] = preds_cal
        sims = {
            "nominal": simulate(plant, measured),
            "rigid_body_refit": simulate(refit, measured),
            "calibrated": simulate(calibrated, advanced),
        }
        for name, ref in (references or {}).items():
            preds[name] = ref.torque(s_va.q, s_va.dq, s_va.ddq)
            if ref.accel is not None:
                sims[name] = _simulate(ode_stepper(ref.accel), va, measured, window_s, max_windows)
        some_left_out = s_va.used is not None and not bool(np.all(s_va.used))
        for name, pred in preds.items():
            error = s_va.smooth(s_va.tau) - s_va.smooth(pred)
            models[name] = {"torque_rms": _per_joint(names, np.sqrt(np.mean(error**2, axis=0)))}
            if some_left_out:  # the rows the fit and the verdict judge (resting in friction, too slow: left out)
                judged = s_va.used_rms(s_va.in_band(s_va.tau - pred))  # as the fit sees them: nothing leaks in
                judged = np.where(np.any(s_va.used, axis=0), judged, np.nan)  # none judged (null in the JSON)
                models[name]["torque_rms_judged"] = _per_joint(names, judged)
            if name in sims:
                models[name]["simulation_error"] = _per_joint(names, sims[name].rms)
        friction = frictionloss_mapping(calibrated, s_va.q, s_va.dq, s_va.ddq)
        series = _validation_series(plant, va, s_va, preds, sims["nominal"], sims["calibrated"])

    fs = 1.0 / va[0].data.dt
    # an unactuated joint has no torque sensor: its residual (the torque the model needs there, which must be
    # zero) is judged against the finest actuated joint's noise, as in the fit's weights
    sigma = 1.0 / np.sqrt(weights)
    band = _structure_band(va[0].data, derivatives, options)
    # the torques left out (`Signals.used`) are zeros in the residual: the noise expected is the share kept
    kept = sigma * np.sqrt(np.mean(s_va.used, axis=0) if s_va.used is not None else 1.0)
    noise_va = s_va.zero_unused(np.concatenate(state_noise_va))  # as the residual: 0 where a torque is left out
    own_zeros = s_va.record if record_offsets else None  # each validation record's torque zero is its own then
    white_nom = whiteness(s_va.residual, kept, fs, band_hz=band, state_noise=noise_va, own_zeros=own_zeros)
    left = s_va.in_band(s_va.tau - preds["calibrated"])
    white_cal = whiteness(left, kept, fs, band_hz=band, state_noise=noise_va, own_zeros=own_zeros)
    verdict, reason = _with_drift(*_verdict(findings, s_va, preds, weights, white_nom, white_cal), drift)
    if demoted:
        reason = (
            f"the effects the selection chose ({', '.join(f.name for f in demoted)}) raise the error on the records "
            f"held out of the fit ({held_out[0]:.4g} -> {held_out[1]:.4g}, weighted MSE): not named, and not in the "
            f"calibrated MJCF; {reason}"
        )
    remaining = (
        residual_signature(s_va, left, names, sigma, slow=_slow_rows(s_va, np.ones(plant.nv, bool)))
        if verdict == "unexplained_structure"
        else {}
    )
    if remaining:
        reason = f"{reason}: {describe_signature(remaining)}"
    return Diagnosis(
        system=plant.name,
        joint_names=names,
        verdict=verdict,
        findings=findings,
        models=models,
        residual=analyse_residual(s_tr, names, floor),
        whiteness={
            "nominal": dict(zip(names, white_nom, strict=True)),
            "calibrated": dict(zip(names, white_cal, strict=True)),
        },
        noise_floor=_per_joint(names, floor),
        frictionloss_mapping=friction,
        calibrated_xml=xml,
        info={
            "train": [r.data.source for r in tr],
            "validation": [r.data.source for r in va],
            "train_samples": int(s_tr.n_samples),
            "validation_samples": int(s_va.n_samples),
            "candidates": [c.key for c in pool],
            "selection": selection.__dict__,
            "derivatives": {
                "method": derivatives,
                **options,
                "cutoff_by_record": _state_cutoffs([*tr, *va]),
            },
            "window_s": window_s,
            "simulation_windows": {
                "simulated": sum(r.windows for r in sims["calibrated"].runs),
                "of": sum(r.of for r in sims["calibrated"].runs),
            },
            "band_hz": band_hz,
            "record_offsets": [
                {"source": r.data.source, **_per_joint(names, o)} for r, o in zip(tr, offsets_by_record, strict=False)
            ],
            "record_joint_offsets": [
                {"source": r.data.source, **_per_joint(names, o), "std": _per_joint(names, sd)}
                for r, o, sd in zip(tr, angles_by_record, angle_stds, strict=False)
            ],
            "changing_offsets": drift,
            "prediction_std": _per_joint(names, spread),
            "left_out_of_fit": left_out,
            "left_out_sticking": sticking,
            "slow_friction_ramps": ramps,
            "slow_friction_ramps_held_out_mse": ramps_held_out,
            "held_by_nominal_friction": at_rest,
            "left_out_at_limit": at_stops,
            "outside_training": outside,
            "torque_lead": None if lead is None else {"delay_s": lead[0], "std_s": lead[1]},
            "mujoco_steps": steps_read,
        },
        notes=[a.describe() for a in anomalies]
        + _steps_note(steps_read)
        + (
            [
                "diagnose.mujoco_steps=true: the model integrates with RK4, which puts nothing of its step into a log "
                "of its simulation; the records are read as they are"
            ]
            if mujoco_steps and steps_read is None
            else []
        )
        + _one_step_delay_notes(plant, findings, steps_read)
        + _lead_note(lead, float(min(d.dt for d in train)), float(train[0].tau_lead_s))
        + (
            [
                f"band_hz: {asked_band_hz:g} Hz was asked, the torques are compared below {band_hz:g} Hz, the cut-off "
                "of the filter the states went through (above it the model torques hold nothing); a wider band needs "
                "a higher state cut-off (diagnose.cutoff_hz)"
            ]
            if asked_band_hz is not None and band_hz is not None and band_hz < asked_band_hz
            else []
        )
        + [
            f"{f.name}: chosen by the selection on the training records ({f.value:.4g} {f.unit}), but with the "
            "effects chosen beside it the held-out error rises: not named"
            for f in demoted
        ]
        + [
            f"{key}: chosen by the selection, but fitted beside the effects chosen with it, its column (made at its "
            "own value) found no value the file can hold (none it agrees with, or no friction at all): not named"
            for key in not_held
        ]
        + [
            f"{f.name}: chosen by the selection, but fitted with the effects chosen after it, it ends at its "
            f"{f.at_bound} bound, its value of no effect ({f.value:g} {f.unit}): not named"
            for f in pinned
        ]
        + _at_bound_notes(findings)
        + _weak_structure_notes(names, white_cal if findings else white_nom)
        + [
            f"{s.candidate.effect}: {', '.join(s.held_nominal)} not refitted (nominal): on these records they act "
            "much as torque offsets, and refitting them did not lower the error on the records held out in turn"
            for s in steps
            if s.held_nominal
        ]
        + [
            f"{d['joint']}: the training records' mean torque residuals differ by {d['spread']:.3g} N m "
            f"({min(d['means']):+.3g} to {max(d['means']):+.3g}; p {_p_text(d['p_value'])} against their noise), "
            "for example a torque zero that changes between recordings (re-zeroed at power-up), an angle zero that "
            "does (encoders zeroed where the arm rested: a gravity torque that differs), or a load that does; "
            "a parameter set shared by the records does not predict it "
            + (
                "and the angle zeros fitted per record leave it (diagnose.record_offsets=true with "
                "diagnose.record_joint_offsets=false fits a torque offset per record instead)"
                if angles_by_record.size
                else "(diagnose.record_offsets=true fits a torque offset per record as a nuisance, "
                "diagnose.record_joint_offsets=true an angle offset)"
            )
            + (
                f"; every training record starts at the same angles (to {START_POSE_TOL:g} rad) and ends elsewhere: "
                "either a pose each is driven to first, or encoders zeroed at each start, which give each record its "
                "own angle zero (where the arm rested)"
                if one_start and not angles_by_record.size
                else ""
            )
            for d in drift
        ]
        + [
            f"{names[j]}: the angle zero of {Path(tr[i].data.source).name} is {angles_by_record[i, j]:+.3g} "
            f"{plant.position_units[j]} from the model's, beyond the {RESTING_ZERO:g} {plant.position_units[j]} "
            "an encoder zeroed where the arm rested is expected to be: check the log's angle convention (its zero "
            "pose, its sign, its unit)"
            for i, j in zip(*np.nonzero(np.abs(np.nan_to_num(angles_by_record)) > RESTING_ZERO), strict=True)
        ]
        + [
            f"{f.name}: |value - null| / std is {z:.2f} in the joint fit of every finding, below "
            f"{z_floor:g}: the held-out gain named it, its size is not well determined beside the "
            "others"
            for f, z in _weak_findings(findings, z_floor)
        ]
        + [describe_outside(d) for d in outside]
        + [
            f"{joint}: at rest or turning round (below {SLIDING_FRACTION:.0%} of its RMS speed) in {share:.1%} of the "
            f"training rows, where the nominal frictionloss {float(plant.frictionloss[names.index(joint)]):.4g} N m "
            "holds it with any torque within its breakaway: those torques are left out of the fit and the verdict"
            for joint, share in at_rest.items()
        ]
        + [
            f"{joint}: at the end of its range, or within half a state-filter period of it, in {share:.1%} of the "
            "training rows, where the stop's force acts: those torques are left out of the fit and the verdict"
            for joint, share in at_stops.items()
        ]
        + [
            f"{Path(d['source']).name}: {d['joint']}'s torque left out of the fit there (the joint never moves; "
            "static friction held it)"
            for d in left_out
        ]
        + [
            f"{joint}: its friction below sliding speed is written as a ramp of {r['ramp_speed']:g} rad/s, for the "
            "training rows the final fit left out (sticking, turning round): its training torque RMS "
            f"{r['training_rms_before']:.4g} -> {r['training_rms_ramp']:.4g} N m against the shape as fitted; in "
            f"forward simulation the joint creeps at about {r['ramp_speed']:g} L / Fc rad/s under a load L below its Fc"
            for joint, r in ramps.items()
        ]
        + (
            [
                f"the friction ramps below sliding speed ({', '.join(ramps)}), chosen on the training records, raise "
                f"the weighted error on the records held out of the fit: {ramps_held_out[0]:.4g} -> "
                f"{ramps_held_out[1]:.4g} (analysis band)"
            ]
            if ramps_held_out and ramps_held_out[1] > ramps_held_out[0]
            else []
        )
        + list(ext.notes),
        series=series,
        remaining=remaining,
        anomalies=[a.to_dict() for a in anomalies],
        verdict_reason=reason,
    )


def _prediction_std(cols_va: list[np.ndarray], fit: LinearFit, n_nuisance: int, nv: int) -> np.ndarray:
    """(nv,) RMS over the validation rows of the std of the effects' torque that the fit's covariance gives [N m]
    (`cols_va`: each step's kept columns on the validation rows, in the analysis band; the per-record nuisance
    is left out, as the validation records have their own).

    It is what the parameters' uncertainty alone makes the calibrated prediction uncertain by: a validation
    error far above it and the noise floor is model error (or a record unlike the training ones), not
    estimation noise. A joint offset's or a torque gain's column is taken to first order (the nominal torque's
    Jacobian and the nominal torque), as in the findings; a coefficient on its bound adds nothing (its
    covariance is zero), so there the std is a lower bound.
    """
    if not cols_va:
        return np.zeros(nv)
    cols = np.concatenate(cols_va, axis=2)
    cov = fit.cov[n_nuisance:, n_nuisance:]
    return np.sqrt(np.mean(np.clip(np.einsum("knp,pq,knq->kn", cols, cov, cols), 0, None), axis=0))


def _position_matters(s: Signals) -> np.ndarray:
    """(nv,) False where a joint's angle changes no nominal torque on the training rows (a wheel's angle)."""
    scale = max(float(np.max(np.abs(s.tau_nominal), initial=0.0)), 1e-12)
    return np.max(np.abs(s.dtau_dq), axis=(0, 1), initial=0.0) > 1e-9 * scale


def _p_text(p: float) -> str:
    return f"= {p:.1g}" if p >= 1e-12 else "< 1e-12"


def _with_drift(verdict: str, reason: str, drift: Sequence[dict[str, Any]]) -> tuple[str, str]:
    """The verdict once training records whose mean residual differs beyond their noise (`drift`, from
    `residuals.changing_offsets`) are counted: structure no parameter set removes, whatever the validation shows."""
    if not drift:
        return verdict, reason
    joints = ", ".join(f"{d['joint']} ({d['spread']:.3g} N m)" for d in drift)
    return "unexplained_structure", (
        f"{reason}; and the mean torque residual differs between the training records on {joints}, for example "
        "a torque zero or a load that changes between recordings (see `notes`)"
    )


def _held_out_mse(s_va: Signals, pred: np.ndarray, weights: np.ndarray) -> float:
    """The weighted torque MSE of a prediction (N, nv) on the validation records, in the analysis band, over the
    torques the fit uses (`Signals.used`: not where a joint rests in its friction)."""
    return float(np.mean(s_va.zero_unused(s_va.smooth(s_va.tau) - s_va.smooth(pred)) ** 2 @ weights))


def _verdict(
    findings: list[Finding],
    s_va: Signals,
    preds: dict[str, np.ndarray],
    weights: np.ndarray,
    white_nom: list[dict[str, Any]],
    white_cal: list[dict[str, Any]],
) -> tuple[str, str]:
    """The verdict from the residual that is left on the validation records.

    - `explained`: effects were found, the held-out (validation) weighted torque MSE drops with them, and what
      the calibrated model leaves is white within the noise on every joint;
    - `unexplained_structure`: structure remains, in the nominal residual when nothing was found (effects that
      do not lower the held-out error are not findings: `diagnose` demotes them), or in the calibrated one;
    - `no_discrepancy`: nothing found and the nominal residual is white within the noise.
    Unactuated joints count where their residual is structured: a passive joint's torque must be zero.
    Training records whose mean residual differs beyond their noise are structure too (`_with_drift`).
    """

    def mse(pred: np.ndarray) -> float:
        return _held_out_mse(s_va, pred, weights)

    structured_nom = [bool(w["structured"]) for w in white_nom]
    structured_cal = [bool(w["structured"]) for w in white_cal]
    if not findings:
        if any(structured_nom):
            return "unexplained_structure", "no candidate effect explains the structure of the nominal residual"
        return "no_discrepancy", "the nominal residual is white within the noise"
    before, after = mse(preds["nominal"]), mse(preds["calibrated"])  # after < before: `diagnose` demotes the rest
    if any(structured_cal):
        return "unexplained_structure", (
            f"the effects found lower the held-out error ({before:.4g} -> {after:.4g}, weighted MSE) but the "
            "calibrated residual is still structured (see `remaining`)"
        )
    return "explained", (
        f"held-out error {before:.4g} -> {after:.4g} (weighted MSE); the residual left is white within the noise (no "
        "structure above half its floor; see `notes` for weaker structure)"
    )


def _separation(a: str, b: str, a_name: str = "", b_name: str = "") -> str:
    """What motion would tell effect a from effect b (`a_name`, `b_name`: how to name them, with their joint or
    body, where no rule of thumb applies)."""
    pair = {a, b}
    body = {"rigid_body", "payload"}
    if "armature" in pair and pair & body:
        return (
            "armature acts on its joint's row alone and does not change with the outer joints' angles: move the "
            "joint with the outer links at several angles (or measure the rotor inertia on a bench); these data "
            "fix only the sum"
        )
    if "torque_offset" in pair and pair & (body | {"joint_offset", "joint_stiffness"}):
        return (
            "swing past horizontal (large angles): a first-moment change goes as sin q and a spring as q, an "
            "offset stays constant"
        )
    if "joint_offset" in pair and pair & body:
        return (
            "a joint's offset turns the first moments of the links beyond it: past the first joint of a chain of "
            "parallel axes (a planar arm's elbow), and at the joint of a single link, that is a first-moment change "
            "exactly and no motion tells them apart: measure the joint's zero against a reference pose; elsewhere "
            "it turns gravity against the outer links' inertial coupling, which a first-moment change does not: "
            "swing the outer joints fast over large angles"
        )
    if "torque_gain" in pair:
        return (
            "a motion in which gravity and inertial torques vary independently (slow swings over large angles, "
            "then fast small ones): a gain scales every torque alike, an inertial change only some"
        )
    if "time_delay" in pair:
        return "faster excitation: a delay's torque grows with frequency (as d tau/dt), the alternative's does not"
    if pair & _FRICTION_SHAPES:
        return "dwell at low speed and reverse slowly, at several loads: friction shapes differ near zero speed"
    return (
        f"a motion on which the columns of {a_name or a} and {b_name or b} differ (they are nearly parallel on "
        "these data)"
    )


_FRICTION_SHAPES = frozenset(
    {"coulomb_friction", "smooth_coulomb_friction", "friction_ramp", "stribeck_friction", "backlash", "load_friction"}
)  # told apart near zero speed (`_separation`)


# (finding's effect, alternative's effect) pairs where the finding's columns can hold the alternative whole: a
# payload's inertia about a joint's axis holds that joint's rotor inertia (`_with_confounding`)
ABSORBED = frozenset({("payload", "armature"), ("payload", "rotor_coupling")})


def _with_confounding(
    findings: list[Finding],
    steps: list[Step],
    pool: list[Candidate],
    s: Signals,
    weights: np.ndarray,
    X: np.ndarray,
    n_nuisance: int,
    fit: LinearFit,
    selection: SelectionOptions,
    min_z: float,
) -> list[Finding]:
    """Name, with each finding, the candidates (chosen too or not) that these data cannot tell from it.

    A finding's headline column (weighted, in the band) is confounded with an alternative when the
    alternative's columns, together with the other findings' columns, leave less than `confound_independence`
    (of `selection`) of its norm unexplained, while the other findings alone leave more (it is the alternative
    that explains it; `_explains`). Another finding is such an alternative the same way: with its columns the
    rest leave less than that, without them more (a shoulder joint offset and a rigid-body change chosen one
    after the other: on a planar arm the offset only turns the first moments, which the rigid-body columns hold).
    A rigid-body finding is judged by the torque its coefficients make instead (`_torque_alternatives`), and a
    payload by both: its headline, and the torque it makes.

    The other way round, a payload's inertia can absorb an inertial effect of a joint (`ABSORBED`): the
    alternative's headline column lies (to within the selection's `min_independence`) in the span of the
    chosen columns, and only with the payload's columns among them (a payload's inertia about a
    vertical axis holds that joint's armature). The alternative was then never chosen (nothing new). It is
    named with the finding where the fit carries evidence of it (`_absorbed_value`): swapped in for the
    payload's column it leans on most, the same fitted torque gives it a value inside its physical range,
    `min_z` std or more from no effect. That value and its std are reported with it; it holds the payload's own
    inertia along that direction too (a 0.03 kg payload on arm3's link 3 with a 0.02 yaw armature: 0.0211 +-
    0.0004). Only these pairs: the payload's mass columns also span gravity-like effects (gains, offsets) that
    the forward check above already names where they explain the payload's mass.
    """
    if not findings:
        return findings
    sw = np.sqrt(weights)
    start = n_nuisance + np.cumsum([0] + [len(st.kept) for st in steps])
    chosen = {st.candidate.key for st in steps}
    alternatives = [c for c in pool if c.key not in chosen]
    blocks = [(X * sw[None, :, None]).reshape(-1, X.shape[2])]
    offsets = [X.shape[2]]
    for c in alternatives:
        blocks.append((s.columns(c) * sw[None, :, None]).reshape(-1, len(c.parameter_names)))
        offsets.append(offsets[-1] + blocks[-1].shape[1])
    M = np.concatenate(blocks, axis=1)
    gram = M.T @ M  # every share below is read from it: no further pass over the rows
    out = []
    for i, (f, st) in enumerate(zip(findings, steps, strict=True)):
        cols = list(range(int(start[i]), int(start[i + 1])))
        others = [k for k in range(X.shape[2]) if not start[i] <= k < start[i + 1]]
        if st.candidate.effect == "rigid_body":
            out.append(
                _confounded(
                    f, st.candidate, _torque_alternatives(cols, others, alternatives, offsets, gram, fit, selection)
                )
            )
            continue
        head = int(start[i])
        alone = _share_left(gram, head, others)
        alts: list[dict[str, Any]] = []
        for j, other in enumerate(steps):  # another finding whose columns leave this one's nearly nothing new
            own = range(int(start[j]), int(start[j + 1]))
            if j == i or (
                other.candidate.target == st.candidate.target and other.candidate.effect == st.candidate.effect
            ):
                continue
            if _explains(
                alone, _share_left(gram, head, [k for k in others if k not in own]), selection.confound_independence
            ):
                alts.append({"effect": other.candidate.effect, "target": other.candidate.target, "independence": alone})
        for k, c in enumerate(alternatives):
            if c.effect == st.candidate.effect and c.target == st.candidate.target:
                continue
            share = _share_left(gram, head, others + list(range(offsets[k], offsets[k + 1])))
            if _explains(share, alone, selection.confound_independence):
                alts.append({"effect": c.effect, "target": c.target, "independence": share})
                continue
            if (st.candidate.effect, c.effect) not in ABSORBED:
                continue
            a = offsets[k]
            absorbed = _share_left(gram, a, list(range(X.shape[2])))
            if not _explains(absorbed, _share_left(gram, a, others), selection.min_independence):
                continue  # not the selection's "nothing new" (`min_independence`): it was scored and not chosen
            swapped = _absorbed_value(gram, fit.coef, fit.cov, list(range(int(start[i]), int(start[i + 1]))), a)
            if swapped is None:
                continue
            value, std = swapped
            inside = float(c.lower[0]) <= value <= float(c.upper[0])
            if inside and abs(value) > min_z * std:  # a coefficient of 0 is no effect (a gain's value is 1 + it)
                alts.append(
                    {"effect": c.effect, "target": c.target, "independence": absorbed, "value": value, "std": std}
                )
        if st.candidate.effect == "payload":  # what a body's change does is its torque, not its mass column
            named = {(a["effect"], a["target"]) for a in alts}
            alts += [
                a
                for a in _torque_alternatives(cols, others, alternatives, offsets, gram, fit, selection)
                if (a["effect"], a["target"]) not in named
            ]
        out.append(_confounded(f, st.candidate, alts))
    return out


def _confounded(f: Finding, cand: Candidate, alts: list[dict[str, Any]]) -> Finding:
    """The finding with its alternatives (`confounded_with`: each effect and target once, the one its column leaves
    least of first) and what motion would separate them (`separate_by`); itself where there are none."""
    if not alts:
        return f
    first: dict[tuple[str, str], dict[str, Any]] = {}
    for a in sorted(alts, key=lambda a: a["independence"]):
        first.setdefault((a["effect"], a["target"]), a)
    unique = list(first.values())
    here = f"{cand.effect} {cand.target}".strip()
    sep = "; ".join(
        dict.fromkeys(
            _separation(cand.effect, a["effect"], here, f"{a['effect']} {a['target']}".strip()) for a in unique
        )
    )
    return dataclasses.replace(f, confounded_with=unique, separate_by=sep)


def _torque_alternatives(
    own: list[int],
    others: list[int],
    alternatives: list[Candidate],
    offsets: list[int],
    gram: np.ndarray,
    fit: LinearFit,
    selection: SelectionOptions,
) -> list[dict[str, Any]]:
    """The effects not chosen that do on these data what a rigid-body or payload finding's change does
    (`confounded_with`).

    The rigid-body change is many columns and no headline; what it does is the torque its coefficients make. So
    is a payload's: its mass column is a point mass at the body's origin, its first moments move it, and a payload
    on the Panda's last joint axis (which loads joints 1-6 as a mass on link 6 does) was named `payload link6`
    without link 7, whose columns make the same torque but not the mass column at link 6's origin. An
    alternative does the same where, with the other findings, its columns leave less than `confound_independence`
    of that torque (in norm) and the others alone leave more (`_explains`). An encoder offset on a planar arm's
    joint turns the first moments of the links beyond it, which is a rigid-body change: the lab-model generator's
    0.1 rad elbow offset was named `rigid_body` alone. A one-column alternative is reported with the value that
    makes the same torque and its std from the rigid-body coefficients' covariance.
    """
    c_own = fit.coef[own]
    gy = gram[:, own] @ c_own  # the columns against the torque the change makes
    yy = float(c_own @ gram[np.ix_(own, own)] @ c_own)
    if yy <= 0:
        return []
    alone = _share_outside(gram, gy, yy, others)
    alts: list[dict[str, Any]] = []
    for k, c in enumerate(alternatives):
        cols = list(range(offsets[k], offsets[k + 1]))
        share = _share_outside(gram, gy, yy, others + cols)
        if c.effect == "rigid_body" or not _explains(share, alone, selection.confound_independence):
            continue
        alt: dict[str, Any] = {"effect": c.effect, "target": c.target, "independence": share}
        if len(cols) == 1:  # the coefficient that makes the same torque, a linear map of the change's
            span = others + cols
            row = np.linalg.lstsq(gram[np.ix_(span, span)], gram[np.ix_(span, own)], rcond=1e-12)[0][-1]
            coef = float(row @ c_own)
            if not float(c.lower[0]) <= coef <= float(c.upper[0]):
                continue  # outside its physical range: not this effect
            var = float(row @ fit.cov[np.ix_(own, own)] @ row)
            alt["value"], alt["std"] = c.value(np.array([coef]), np.array([[var]]), np.zeros((0, 0, 1)))
        alts.append(alt)
    return alts


def _explains(share: float, alone: float, threshold: float) -> bool:
    """Whether a column that other columns leave `share` of (in norm) is explained by the one added to them:
    under `threshold` with it, and over `threshold` (or half as much again) without it, where `alone` is left."""
    return share < threshold < alone or (share < threshold and alone >= 1.5 * share)


def _absorbed_value(
    gram: np.ndarray, coef: np.ndarray, cov: np.ndarray, own: list[int], a: int
) -> tuple[float, float] | None:
    """(coefficient, std) column `a` takes when it replaces the finding's column it leans on most, the fitted
    torque unchanged; None where it leans on none of them.

    Args:
        gram: Gram matrix of the weighted columns: the fit's first (as many as `coef`), the alternatives' after.
        coef, cov: (n,) the fit's coefficients and their covariance.
        own: the finding's columns (indices below n).
        a: the alternative's headline column.
    """
    span = list(range(len(coef)))
    w = np.linalg.lstsq(gram[np.ix_(span, span)], gram[span, a], rcond=1e-12)[0]
    lean = np.abs(w[own]) * np.sqrt(np.maximum(np.diag(gram)[own], 0.0))
    if float(lean.max()) <= 1e-9 * np.sqrt(max(float(gram[a, a]), 0.0)):
        return None
    k = own[int(np.argmax(lean))]
    new = list(span)
    new[k] = a
    T = np.linalg.lstsq(gram[np.ix_(new, new)], gram[np.ix_(new, span)], rcond=1e-12)[0]  # coef -> swapped coef
    return float(T[k] @ coef), float(np.sqrt(max(float(T[k] @ cov @ T[k]), 0.0)))


def _share_left(gram: np.ndarray, head: int, span: list[int]) -> float:
    """Share (in norm) of column `head` outside the span of columns `span`, from their Gram matrix."""
    return _share_outside(gram, gram[:, head], float(gram[head, head]), span)


def _share_outside(gram: np.ndarray, g: np.ndarray, hh: float, span: list[int]) -> float:
    """Share (in norm) of a vector y outside the span of columns `span`, from the columns' Gram matrix, their
    products with y (`g`, one per column of `gram`) and y's squared norm `hh`."""
    if hh <= 0:
        return 0.0
    if not span:
        return 1.0
    explained = float(g[span] @ np.linalg.lstsq(gram[np.ix_(span, span)], g[span], rcond=1e-12)[0])
    return float(np.sqrt(max(1.0 - explained / hh, 0.0)))


def _predict_records(calibrated: Plant, ext: Extension, records: list[_Record]) -> np.ndarray:
    """Calibrated measured-torque prediction record by record (the delay shifts within a record)."""
    return np.concatenate(
        [
            predict_measured_torque(calibrated, ext, r.signals.time, r.signals.q, r.signals.dq, r.signals.ddq)
            for r in records
        ]
    )


def _record_angles(
    X: np.ndarray, fit: LinearFit, *, start: int, stop: int, fitted: np.ndarray, n_records: int
) -> tuple[np.ndarray, np.ndarray]:
    """((records, nv) the angle offset per record and joint [rad] and (records, nv) its std, from the nuisance
    columns start:stop of the final fit (none: (0, nv) each); NaN where the column is 0 (to round-off) on every row
    the fit used (`fitted`, (N, nv)): no torque of that record it fitted depends on that angle (a vertical first
    axis)."""
    nv = X.shape[1]
    if stop <= start:
        return np.zeros((0, nv)), np.zeros((0, nv))
    values = fit.coef[start:stop].copy()
    stds = np.sqrt(np.clip(np.diag(fit.cov)[start:stop], 0.0, None))
    norms = np.sqrt(np.sum((X[:, :, start:stop] * fitted[:, :, None]) ** 2, axis=(0, 1)))
    seen = norms > 1e-9 * max(float(norms.max()), 1e-300)  # round-off (a vertical first axis) is not a column
    values[~seen], stds[~seen] = np.nan, np.nan
    return values.reshape(n_records, nv), stds.reshape(n_records, nv)


START_POSE_TOL = 0.01  # records whose first angles agree this well [rad] start at one pose ...
END_POSE_SPREAD = 0.05  # ... and, where their last angles spread more than this [rad], were not all parked there


def _one_start_pose(records: Sequence[Dataset], hinge: np.ndarray) -> bool:
    """Whether two or more records start at the same angles (every hinge within `START_POSE_TOL`) and end at
    different ones (some hinge spreading more than `END_POSE_SPREAD`): what encoders zeroed at each start give
    (every DFKI log starts at 0.0002 rad, within 0.004 once its start-up rows are dropped, and ends mid-motion),
    not a pose each record is driven to and parked at."""
    hinge = np.asarray(hinge, bool)
    if len(records) < 2 or not np.any(hinge):
        return False
    first = np.array([d.q[0, hinge] for d in records])
    last = np.array([d.q[-1, hinge] for d in records])
    return bool(np.all(np.ptp(first, axis=0) <= START_POSE_TOL) and np.any(np.ptp(last, axis=0) > END_POSE_SPREAD))


def _training_signals(plant: Plant, records: list[_Record]) -> tuple[Signals, np.ndarray, np.ndarray, np.ndarray]:
    """The training records' signals stacked, with the torques no column explains left out (`Signals.used`):
    a joint that never moves in a record (`_still_joints`), rows its nominal frictionloss holds at rest
    (`_held_by_friction`) and rows at or beside its range limits, where the stop's force acts (`_near_limit`).

    Returns:
        (the signals; (records, nv) the still joints; (N, nv) the rows held by friction; (N, nv) the rows at the
        stops).
    """
    unfitted = _still_joints(records, plant.hinge)
    s = _without(stack_signals([r.signals for r in records]), unfitted)
    held = _held_by_friction(plant, s, _never_moving(records, plant.hinge))
    stopped = _near_limit(plant, s)
    return _left_out(s, held | stopped), unfitted, held, stopped


def _record_angles_alone(plant: Plant, records: list[_Record]) -> np.ndarray:
    """(records, nv) an angle offset per record and joint that the nominal model alone fits best (the final fit's
    Gauss-Newton on `_record_joint_offset_columns`, on the torques the diagnosis fits, no effect beside them): the
    point the selection's first-order columns are evaluated at. Offsets of 0.1 to 0.25 rad, linearised about the
    reported angles, came out up to 0.02 rad wrong and left a rigid-body change of their own (the testbed's
    two-link arm). The selection's records held out in turn then keep their own offset: it judges the effects
    with each training record's zero known, as a sensor's nuisance, not as a validation record (whose zero is
    unknown) would be."""
    s, unfitted, _, _ = _training_signals(plant, records)
    X = _record_joint_offset_columns(s)
    weights = _weights(plant, _noise_floor(records, unfitted) * plant.actuated)
    fit = _final_fit(plant, [], X, s, weights, X.shape[2], record_angles=0)[1]
    return fit.coef.reshape(len(records), plant.nv)  # type: ignore[no-any-return]


def _record_joint_offset_columns(s: Signals) -> np.ndarray:
    """(N, nv, records x nv) an angle offset per record and joint (reported minus true angle), record-major: the
    joint offset candidate's column -d tau / d q_j on that record's rows, in the band."""
    jac = s.dtau_dq
    records, nv = np.unique(s.record), jac.shape[2]
    out = np.zeros((s.n_samples, jac.shape[1], len(records) * nv))
    for i, r in enumerate(records):
        rows = s.record == r
        out[rows, :, i * nv : (i + 1) * nv] = -jac[rows]
    return s.in_band(out)


def _record_offset_columns(s: Signals) -> np.ndarray:
    """(N, nv, records x actuated joints) a constant torque offset per record and actuated joint."""
    records, joints = np.unique(s.record), np.flatnonzero(s.actuated)
    out = np.zeros((s.n_samples, len(s.actuated), len(records) * len(joints)))
    for i, r in enumerate(records):
        for k, j in enumerate(joints):
            out[s.record == r, j, i * len(joints) + k] = 1.0
    return s.zero_unused(out)


def _noise_floor(records: list[_Record], unfitted: np.ndarray) -> np.ndarray:
    """(nv,) the median over the training records of each joint's torque noise floor, leaving out the records
    where that joint's torque is not fitted (`unfitted`, (records, nv): a motor that reports zero there has no
    noise; a joint is never unfitted in every record, `_still_joints`)."""
    floors = np.array([record_noise_floor(r.data) for r in records], dtype=float)
    return np.nanmedian(np.where(unfitted, np.nan, floors), axis=0)


def record_noise_floor(data: Dataset) -> np.ndarray:
    """(nv,) a record's torque noise floor [N m] (`residuals.noise_floor`). A record thinned to every k-th row
    (`identify.derivatives.reduce_record`) had its torque anti-aliased first, which hides the noise from the
    third differences (a pendulum's 0.0099 N m read as 0.0021, and its clean residual as structure): there the
    floor read at the full rate (`meta["reduced"]["noise_floor"]`, where the caller kept it) is used, as the
    white noise of the same density at the kept rate, floor / sqrt(k)."""
    reduced = data.meta.get("reduced") or {}
    if reduced.get("noise_floor") is not None:
        return np.asarray(reduced["noise_floor"], dtype=float) / np.sqrt(float(reduced["factor"]))
    return noise_floor(data.tau)


def _never_moving(records: list[_Record], hinge: np.ndarray) -> np.ndarray:
    """(records, nv) True where a joint never moves in the record (`anomalies.still_joints`)."""
    still = np.zeros((len(records), len(hinge)), bool)
    for i, rec in enumerate(records):
        still[i, still_joints(rec.data, hinge)] = True
    return still


def _still_joints(records: list[_Record], hinge: np.ndarray) -> np.ndarray:
    """(records, nv) True where a joint never moves in a training record and its torque there is left out of
    the fit (`Signals.used`): static friction holds such a joint with any torque within its breakaway, which no
    column explains, and fitted it would bias the parameters its other columns share (a link's mass against the
    torque that held it). A joint still in every record is kept here: there is nothing else to fit it on (where
    its nominal model gives it a frictionloss, `_held_by_friction` leaves it out all the same)."""
    still = _never_moving(records, hinge)
    still[:, np.all(still, axis=0)] = False
    return still


def _without(s: Signals, unfitted: np.ndarray) -> Signals:
    """The signals with the torques of `unfitted` (records, nv) left out (`Signals.used`)."""
    if not np.any(unfitted):
        return s
    return _left_out(s, unfitted[s.record])


def _left_out(s: Signals, rows: np.ndarray) -> Signals:
    """The signals with the (row, joint) torques of `rows` (N, nv) left out too (`Signals.used`)."""
    if not np.any(rows):
        return s
    return dataclasses.replace(s, used=~rows if s.used is None else s.used & ~rows)


_FGLS_ITERATIONS = 20  # re-weightings of the final fit at most (they settle within a few)


STOPPED_SHARE = 0.25  # a joint at its range limit on more than this share of a record is not checked for its torque
SLIDING_FRACTION = 0.1  # below this share of a joint's RMS speed in a record, its Coulomb friction is not fitted
_SIGN_FRICTION = frozenset({"coulomb_friction", "load_friction"})  # friction laws of sign(dq)
_LOW_SPEED_SHAPES = frozenset({"smooth_coulomb_friction", "stribeck_friction", "backlash"})  # told apart below it


def _slow_rows(s: Signals, joints: np.ndarray, ramp: np.ndarray | None = None) -> np.ndarray:
    """(N, nv) True where a joint of `joints` (nv,) bool moves at most `SLIDING_FRACTION` of its RMS speed in
    that record (a joint at rest or turning round). `ramp`: (nv,) the width [rad/s] of each joint's friction
    ramp; a joint counts in a record only where its ramp is no wider than that slow band (a wider one makes
    the friction a smooth function of the speed there, not a set)."""
    slow = np.zeros(s.dq.shape, bool)
    width = np.zeros(s.dq.shape[1]) if ramp is None else np.asarray(ramp, dtype=float)
    for r in np.unique(s.record):
        rows = s.record == r
        band = SLIDING_FRACTION * np.sqrt(np.mean(s.dq[rows] ** 2, axis=0))
        slow[rows] = (np.abs(s.dq[rows]) <= band) & (width <= band)
    return slow & np.asarray(joints, bool)


def _held_by_friction(plant: Plant, s: Signals, still: np.ndarray) -> np.ndarray:
    """(N, nv) True where a joint whose nominal MJCF gives it a frictionloss F, as a ramp no wider than the slow
    band (`_slow_rows`; `dynamics.friction`), moves slower than `SLIDING_FRACTION` of its RMS speed in that
    record, and on every row of a record in which a joint with any frictionloss never moves (`still`:
    (records, nv), `_never_moving`).

    There the joint sticks or turns round, and its friction is anywhere within +-F, not F sign(dq) at the
    filtered velocity: the nominal torque model is set-valued there, and the measured torque says nothing a
    column can explain (on an SO-ARM100 simulated by sysid-run with its own frictionloss 0.1 N m, the jaw rests in
    37 % of its training rows, and the clean log was named a jaw friction change of 0.0002 +- 0.0013 N m). Those
    torques are left out of the fit and of the verdict, as a joint that never moves is (`_still_joints`). A joint
    that never moves has only noise for a speed, whose RMS the rule above would take for its motion: left in,
    the same clean SO-ARM100 log with the jaw held still throughout was called `explained` by a jaw Coulomb
    friction at its bound, a torque gain at its bound and a torque offset.
    """
    held = _slow_rows(s, np.asarray(plant.frictionloss) > 0, plant.friction_speed)
    return held | (still[s.record] & (np.asarray(plant.frictionloss) > 0))


def _at_stops(plant: Plant, q: np.ndarray) -> np.ndarray:
    """(N, nv) True where a joint of `plant` is at an end of its range (`anomalies.at_limit`, with its margin)."""
    return at_limit(q, plant.q_range, plant.hinge, plant.limit_margin)


def _near_limit(plant: Plant, s: Signals) -> np.ndarray:
    """(N, nv) True where a joint is at an end of its range (`anomalies.at_limit`, with the joint's `margin`), and
    on the rows within half a period of its record's state-filter cut-off of those: the stop's force is in no
    model, and the filtered acceleration spreads its impulse around the contact (a testbed arm pressed into its
    stops named a time delay at its bound from the rows beside them)."""
    near = _at_stops(plant, s.q)
    if not near.any():
        return near
    cutoff = dict(s.state_hz)
    out = near.copy()
    for r in np.unique(s.record):
        rows = np.flatnonzero(s.record == r)
        hz = cutoff.get(int(r)) or s.band_hz
        if not hz or rows.size < 2:
            continue
        k = int(np.ceil(0.5 / (hz * float(np.median(np.diff(s.time[rows]))))))
        for j in np.flatnonzero(near[rows].any(axis=0)):
            out[rows, j] = ndimage.binary_dilation(near[rows, j], structure=np.ones(2 * k + 1, bool))
    return out


def _sliding_rows(s: Signals, steps: list[Step], names: tuple[str, ...]) -> np.ndarray | None:
    """(N, nv) False where a joint whose friction the findings give as Fc sign(dq) moves slower than
    `SLIDING_FRACTION` of its RMS speed in that record: the final fit leaves those torques out (None: none).

    Near a reversal the joint sticks while the drive's torque is within the breakaway: the friction torque is then
    anything within +-Fc, not Fc sign(dq) at the filtered velocity, and fitted there the law is biased low (on the
    testbed 2 to 5 of its stds: 0.0389 +- 0.0004 for 0.04 N m; on a UR5e from another generator 0.984 +- 0.0035
    for 1 N m). Where the findings give the joint a low-speed shape (a ramp, Stribeck, backlash), those rows are
    what tells it, and they are kept. The selection, which compares the shapes, sees every row."""
    joints = np.zeros(len(names), bool)
    for j, name in enumerate(names):
        chosen = [st.candidate for st in steps if st.candidate.target == name]
        effects = {c.effect for c in chosen}
        # MuJoCo's own frictionloss shape is a ramp of the speed and acceleration: its slow rows are its law too
        soft = any(c.variant == SOFT_FRICTION for c in chosen)
        # a friction in a narrower shape (`friction_ramp`): the ideal one is a law of sign(dq), a ramp a shape
        ramps = [c.variant for c in chosen if c.effect == "friction_ramp"]
        sign = bool(effects & _SIGN_FRICTION) or IDEAL in ramps
        shaped = bool(effects & _LOW_SPEED_SHAPES) or any(v != IDEAL for v in ramps)
        joints[j] = sign and not shaped and not soft
    mask = ~_slow_rows(s, joints)
    return None if mask.all() else mask


def _weak_findings(findings: list[Finding], min_z: float) -> list[tuple[Finding, float]]:
    """The findings (not the rigid body, not one at its bound) whose reported |value - null| / std
    (`evidence["z"]`, NaN at a bound) is below `min_z`: the selection judged each beside the findings before
    it, the report fits them all together."""
    zs = [(f, abs(float(f.evidence.get("z", np.nan)))) for f in findings if f.effect != "rigid_body"]
    return [(f, z) for f, z in zs if np.isfinite(z) and z < min_z]


def _slow_friction_ramps(
    ext: Extension,
    sliding: np.ndarray | None,
    s: Signals,
    names: tuple[str, ...],
    predict: Callable[[Extension], np.ndarray],
    *,
    preference: float,
    nominal_speed: np.ndarray,
    own_zeros: bool = False,
) -> tuple[Extension, dict[str, dict[str, Any]]]:
    """`ext` with the shape below sliding speed of each joint whose Coulomb friction the final fit took from its
    sliding rows only (`_sliding_rows`), chosen on the training records' rows that fit left out; and per joint so
    changed, what chose it.

    There the joint sticks or turns round, and its friction is anywhere within +-Fc: the fit says nothing about
    those rows, yet the calibrated MJCF must give a torque on them. Written as MuJoCo's narrowest stable ramp, its
    inverse dynamics puts the whole +-Fc on the sign of whatever speed the filtered states carry there; a joint the
    drive holds at zero torque while it sticks (the DFKI C.1 elbow, commanded zero in a whole file) reads 0 there
    whatever its friction holds. Each of the ramps `SMOOTH_COULOMB_SPEEDS` is tried in turn, its Fc unchanged (the
    torques of rows sliding faster than the ramp are the fitted ones), and the calibrated MJCF predicts every
    training record as MuJoCo applies it (`predict`: an Extension's calibrated MJCF's (N, nv) torque on the rows
    of `s`); a joint takes the ramp with the lowest mean square error over its used training torques in the
    analysis band, where that is below
    the narrow shape's by `preference` of it (`SelectionOptions.native_preference`, as the selection asks of a
    ramp against the ideal shape: the width is a choice from a grid). The final fit's coefficients never saw
    these rows. On the DFKI C.1 logs, one file of which commands the elbow zero torque throughout, the elbow takes
    0.1 rad/s wherever that file is among the training records (its mean square error 13-16 % lower), and no joint
    changes where it is not (below 0.4 %). A joint is tried only where rows the fit left out are among the torques
    the error counts (`Signals.used`: a joint whose nominal frictionloss holds it at rest has those rows left out
    of everything, `_held_by_friction`). A joint whose nominal MJCF declares a ramp keeps it where it fits a new
    Fc (`calibrate._write_friction_shapes`): only wider ones are tried there (`nominal_speed`, (nv,) [rad/s]).
    `diagnose` applies them after it has judged the findings on the records held out of the fit (apart from the
    ramps), and reports what they do there (`info.slow_friction_ramps_held_out_mse`; a note where they raise it)
    without using it to choose: those records judge the result.
    `own_zeros`: each record's torque zero was fitted as a nuisance (not in `ext`): the errors are taken less their
    mean per record.

    In forward simulation a ramp of width vt lets a joint under a load L below Fc creep at about vt L / Fc: the
    price of a torque model that predicts the middle of the set, not a random edge of it, where the data say
    nothing finer."""
    if sliding is None:
        return ext, {}
    used = np.ones(s.tau.shape, bool) if s.used is None else s.used
    joints = np.flatnonzero(np.any(~sliding & used, axis=0))  # rows left out of the fit that the error counts
    if not joints.size:
        return ext, {}
    count = np.maximum(np.count_nonzero(used, axis=0), 1)
    records = np.unique(s.record)
    measured = s.smooth(s.tau)  # low-passed once, for every width tried

    def errors(vt: float | None) -> tuple[np.ndarray, np.ndarray]:
        """(nv,) mean square error over the used training torques, and (records, nv) per record, with every
        tried joint's friction a ramp of width vt (None: as fitted)."""
        speeds = ext.friction_speed.copy()
        if vt is not None:
            speeds[joints] = vt
        trial = dataclasses.replace(ext, friction_speed=speeds, notes=[])  # calibrated_xml adds to the notes
        error = np.where(used, measured - s.smooth(predict(trial)), 0.0)
        sse = np.zeros((len(records), error.shape[1]))
        for k, r in enumerate(records):
            rows = s.record == r
            e = error[rows]
            if own_zeros:
                n_r = np.maximum(np.count_nonzero(used[rows], axis=0), 1)
                e = np.where(used[rows], e - e.sum(axis=0) / n_r, 0.0)
            sse[k] = np.sum(e**2, axis=0)
        return sse.sum(axis=0) / count, sse

    before, before_r = errors(None)
    tried = {vt: errors(vt) for vt in SMOOTH_COULOMB_SPEEDS}
    speeds = ext.friction_speed.copy()
    chosen: dict[str, dict[str, Any]] = {}
    for j in joints:
        wider = [v for v in tried if v > nominal_speed[j]]
        if not wider:
            continue
        vt = min(wider, key=lambda v: float(tried[v][0][j]))
        if tried[vt][0][j] < (1.0 - preference) * before[j]:
            speeds[j] = vt
            chosen[names[j]] = {
                "ramp_speed": vt,
                "training_rms_before": float(np.sqrt(before[j])),
                "training_rms_ramp": float(np.sqrt(tried[vt][0][j])),
                "records_lowered": int(np.count_nonzero(tried[vt][1][:, j] < before_r[:, j])),
                "records": len(records),
            }
    if not chosen:
        return ext, {}
    return dataclasses.replace(ext, friction_speed=speeds), chosen


def _final_fit(
    plant: Plant,
    steps: list[Step],
    X: np.ndarray,
    s: Signals,
    weights: np.ndarray,
    n_nuisance: int = 0,
    sliding: np.ndarray | None = None,
    *,
    record_angles: int | None = None,
) -> tuple[np.ndarray, LinearFit, np.ndarray, list[Step]]:
    """Joint fit of the chosen columns, with joint offsets, torque gains and self-dependent columns made exact.

    `sliding`: (N, nv) the (row, joint) torques the fit uses (`_sliding_rows`; None: every used one); the
    columns and the residual returned cover every row. `record_angles`: where the nuisance columns of an angle
    offset per record and joint begin (`_record_joint_offset_columns`, records x nv of them, the nuisance's last
    ones); None: there are none.

    Returns:
        (the columns, re-made where offsets, gains and self-dependent columns were iterated; the fit; (N, nv) the
        residual it leaves, with the nominal torque at the fitted joint offsets, not its first-order expansion;
        the steps, each candidate whose column depends on its own value re-made at the value fitted).

    The joints are weighted by the variance of what the fit leaves on each (feasible GLS from `weights`,
    re-weighted until the weights settle): on a simulation that is the sensor noise the selection weighs by,
    on real logs the model error that remains, several times the noise floor and unequal between joints;
    weighting by the floor would let the quietest joint decide parameters (link inertias) that every joint's
    torque depends on.

    The selection linearises joint offsets and torque gains; here they are iterated to a fixed point. A joint
    offset o re-evaluates the nominal torque at q - o (Gauss-Newton on the offset); a gain multiplies the whole
    true torque, not only the nominal one, so its column is re-made from the nominal torque plus the other
    fitted effects.
    At the fixed point measured = gain (nominal(q - offset) + effects) + torque offset holds exactly, as
    in the calibrated model. Every coefficient stays within its candidate's physical range.

    A column made at a value of its own coefficient (`Candidate.made_at`: MuJoCo's friction, whose ramp widens
    with Fc, as a secant from the nominal Fc) is made again at the value fitted, after every solve, until the two
    agree (to `_REMAKE_TOL` of the larger): the calibrated MJCF then applies the friction the fit used.
    Made once from the training residual alone, a change fitted beside other effects could end far from it (a
    secant at +0.5 N m fitted at -0.5 was 0.24 N m off MuJoCo's friction at the written value). It is made again
    at the secant's root of c(m) - m after the first time (`Candidate.next_made_at`), and a step that has not
    settled after `_REMAKE_ITERATIONS` is dropped (with a note by the caller). A candidate whose effect is affine
    in its value (`Candidate.affine`: a friction in a narrower shape, c S - O) is not iterated: every solve fits c
    S with O moved to the torque it explains, the least squares of the model the file holds, and makes its column
    at that c; one fitted at no friction is dropped.
    """
    lo, hi = _step_bounds(steps, n_nuisance)
    residual = s.residual  # low-passed record by record on every access: once
    fitted = _on_sliding_rows(s, sliding)
    X, steps = X.copy(), list(steps)  # self-dependent columns are made again in place (`_remade_at_fit`)
    start = n_nuisance + np.cumsum([0] + [len(st.kept) for st in steps])
    affine = {st.candidate.key: s.affine_parts(st.candidate) for st in steps if st.candidate.affine}

    def solve(X: np.ndarray, r: np.ndarray, weights: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> LinearFit:
        """The bounded fit; a candidate whose effect is affine in its value (`Candidate.affine`: c S - O) fitted
        as such, its column S and its fixed part O added to the torque it explains (least squares of the model
        the file holds, and the std of its value), then made again at the value fitted (c z_c = c S - O)."""
        at = [i for i, st in enumerate(steps) if st.candidate.key in affine]
        XS, rS = X.copy(), r.copy()
        for i in at:
            XS[:, :, start[i]], offset = affine[steps[i].candidate.key]
            rS = rS + offset
        fit = _fit_on(s, sliding, XS, rS, weights, lo, hi)
        for i in at:
            cand, value = steps[i].candidate, float(fit.coef[start[i]])
            if cand.holds(value) and cand.remake is not None:
                steps[i] = dataclasses.replace(steps[i], candidate=cand.remake(value))
                X[:, :, start[i]] = s.columns(steps[i].candidate)[:, :, 0]
        return fit

    fit = solve(X, residual, weights, lo, hi)
    for _ in range(_FGLS_ITERATIONS):
        left = fitted.used_rms(residual - np.einsum("knp,p->kn", X, fit.coef))
        if not np.any(left > 0):
            break  # an exact fit: nothing to weigh by
        new = 1.0 / safe_sigma(left, s.actuated) ** 2  # an unactuated joint: at most the best actuated weight
        done = bool(np.allclose(new / new.sum(), weights / weights.sum(), rtol=1e-3, atol=0))
        weights = new
        fit = solve(X, residual, weights, lo, hi)
        if done:
            break
    tried: dict[str, tuple[float, float]] = {}  # each one's last (value made at, value fitted), by its key
    for _ in range(_REMAKE_ITERATIONS):
        if not _remade_at_fit(s, steps, X, fit.coef, start, tried):
            break
        fit = solve(X, residual, weights, lo, hi)
    # one that found no fixed point, or an affine one fitted at no friction at all (c S - O at c = 0: the nominal
    # friction taken away, which no column made at c holds): the file would not hold what the fit used
    keep = [i for i, st in enumerate(steps) if st.candidate.holds(float(fit.coef[start[i]]))]
    if len(keep) < len(steps):
        columns = [np.arange(n_nuisance)] + [np.arange(start[i], start[i] + len(steps[i].kept)) for i in keep]
        X, steps = X[:, :, np.concatenate(columns)], [steps[i] for i in keep]
        lo, hi = _step_bounds(steps, n_nuisance)
        start = n_nuisance + np.cumsum([0] + [len(st.kept) for st in steps])
        fit = solve(X, residual, weights, lo, hi)
    records = np.unique(s.record)
    # (column, joint, record index or None for an offset of every record)
    offsets: list[tuple[int, int, int | None]] = [
        (int(start[i]), plant.joint_names.index(st.candidate.target), None)
        for i, st in enumerate(steps)
        if st.candidate.effect == "joint_offset"
    ]
    if record_angles is not None:
        offsets += [(record_angles + r * plant.nv + j, j, r) for r in range(len(records)) for j in range(plant.nv)]
    gains = [int(start[i]) for i, st in enumerate(steps) if st.candidate.effect == "torque_gain"]
    if not offsets and not gains:
        return X, fit, residual - np.einsum("knp,p->kn", X, fit.coef), steps
    nominal = s.tau_nominal  # X is this fit's own copy (above)
    shift = np.zeros((len(records) + 1, plant.nv))  # the offsets found so far: every record's, then each record's
    row_record = 1 + np.searchsorted(records, s.record)
    others = [c for c in range(X.shape[2]) if c not in gains and c not in {o[0] for o in offsets}]
    for _ in range(20):
        previous = fit.coef.copy()
        if offsets:
            for c, j, r in offsets:
                shift[0 if r is None else 1 + r, j] += fit.coef[c]
                previous[c] = 0.0
            q = s.q - shift[0] - shift[row_record]
            nominal = joint_torque(plant, q, s.dq, s.ddq)[0]
            jac = torque_jacobian_q(plant, q, s.dq, s.ddq)
            for c, j, r in offsets:
                X[:, :, c] = s.in_band(-jac[:, :, j] * (1.0 if r is None else (row_record == 1 + r)[:, None]))
        if gains:
            effects = np.einsum("knp,p->kn", X[:, :, others], fit.coef[others])
            total = s.in_band(nominal) + effects
            for c in gains:
                row = np.flatnonzero(np.any(X[:, :, c] != 0, axis=0))
                X[:, row, c] = total[:, row]
        lo_it, hi_it = lo.copy(), hi.copy()
        for c, j, r in offsets:  # the bounds hold for the total offset, the coefficient is its increment
            done = shift[0 if r is None else 1 + r, j]
            lo_it[c], hi_it[c] = lo[c] - done, hi[c] - done
        measured = s.in_band(s.tau - nominal)
        fit = solve(X, measured, weights, lo_it, hi_it)
        # a self-dependent column follows its value here too (a gain or an offset moves it after the pass above)
        remade = _remade_at_fit(s, steps, X, fit.coef, start, tried)
        if not remade and np.allclose(fit.coef, previous, rtol=1e-8, atol=1e-12):
            break
    left = measured - np.einsum("knp,p->kn", X, fit.coef)
    coef = fit.coef.copy()
    for c, j, r in offsets:
        coef[c] += shift[0 if r is None else 1 + r, j]
    return X, LinearFit(coef, fit.cov, fit.sigma, fit.at_bound, fit.correlation_time), left, steps


_REMAKE_TOL = 1e-6  # relative agreement of a self-dependent column's value and the value it was made at


_REMAKE_ITERATIONS = 20


def _remade_at_fit(
    s: Signals,
    steps: list[Step],
    X: np.ndarray,
    coef: np.ndarray,
    start: np.ndarray,
    tried: dict[str, tuple[float, float]],
) -> bool:
    """The columns of candidates made at a value of their own coefficient (`Candidate.made_at`) made again, in
    place in `X` (N, nv, p) and `steps`, where the value `coef` gives them differs from it (`_REMAKE_TOL`), at
    `Candidate.next_made_at` (`tried`: each one's last (made at, fitted), by its key); `start`: each step's first
    column. Returns whether any was made again (the caller refits, `_final_fit`). An affine one is made at its
    value by the fit itself (`_final_fit`)."""
    moved = False
    for i, st in enumerate(steps):
        cand = st.candidate
        if cand.remake is None or cand.made_at is None or cand.affine:
            continue
        assert len(st.kept) == 1, "a self-dependent candidate has one column"
        col, value = int(start[i]), float(coef[int(start[i])])
        if cand.agrees(value, _REMAKE_TOL):
            continue
        at = cand.next_made_at(value, tried.get(cand.key))
        tried[cand.key] = (cand.made_at, value)
        cand = cand.remake(at)
        steps[i] = dataclasses.replace(st, candidate=cand)
        X[:, :, col] = s.columns(cand)[:, :, 0]
        moved = True
    return moved


LEAD_Z = 4.0  # a torque lead beside the effects named is pointed out where it is this many std from zero ...
LEAD_SAMPLES = 0.2  # ... and at least this share of a sample


def _found_lead(lead: tuple[float, float], dt: float) -> bool:
    """Whether a torque lead (`_torque_lead`: delay, std [s]) is clear of zero and of round-off."""
    return lead[0] < -LEAD_SAMPLES * dt and -lead[0] > LEAD_Z * lead[1]


def with_found_lead(
    run: Callable[..., Diagnosis],
    train: Sequence[Dataset],
    validation: Sequence[Dataset],
    rng: np.random.Generator,
    *,
    known: bool = False,
) -> Diagnosis:
    """`run(train, validation, rng=rng)` (a `diagnose` with its options bound), once where the records' torque lead
    is `known` (declared: `data.tau_lead_s` set). Where it is not (`Dataset.tau_lead_s` then holds 0) and the
    measured torque leads the motion clearly (`_found_lead`) by less than a sample in all (the declared `tau_lead_s`
    with it), the same run again on the records read with that lead, from the same random state
    (`info["torque_lead_found"]`, and a note). A lead is no effect of the plant (a sensor reports after the torque
    acts, `time_delay` >= 0) but the log's timing: a torque held over each sample and logged at its start, as
    MuJoCo's RK4 or a controller's zero-order hold applies it. A lead of a sample or more is left to the note
    (`_lead_note`): no timing of a held torque makes it. States a record gives (`given`, `simulator`) cannot be
    moved to the torque's instant: read as they are."""
    if known:
        return run(train, validation, rng=rng)
    again = copy.deepcopy(rng)
    first = run(train, validation, rng=rng)
    found = first.info["torque_lead"]
    if found is None or first.info["derivatives"]["method"] in ("simulator", "given"):
        return first
    lead, dt = (float(found["delay_s"]), float(found["std_s"])), float(min(d.dt for d in [*train, *validation]))
    declared = float(train[0].tau_lead_s)
    if not _found_lead(lead, dt):
        return first
    total = declared - lead[0]
    if total >= dt:
        return first
    dg = run(
        [dataclasses.replace(d, tau_lead_s=total) for d in train],
        [dataclasses.replace(d, tau_lead_s=total) for d in validation],
        rng=again,
    )
    dg.info["torque_lead_found"] = {"delay_s": lead[0], "std_s": lead[1], "declared_s": declared, "read_s": total}
    dg.notes.insert(
        0,
        f"{_lead_size(lead, dt)} first): the torque of each row acted over an interval centred "
        f"{total * 1e3:.3g} ms after it (half a sample for a torque held over each sample and logged at its start, "
        "as MuJoCo's RK4 step or a zero-order hold applies it); the records were read so and diagnosed again. "
        "Declare data.tau_lead_s to read them otherwise (0: each torque at its row)",
    )
    return dg


def _lead_size(lead: tuple[float, float], dt: float) -> str:
    """The start of a note on a torque lead (delay, std [s]) at the sample interval dt, its parenthesis open."""
    return (
        f"the measured torque leads the motion by {-lead[0] * 1e3:.3g} ms ({-lead[0] / dt:.2g} samples; "
        f"{-lead[0] / lead[1]:.1f} std, fitted beside the effects named"
    )


def _lead_note(lead: tuple[float, float] | None, dt: float, declared: float) -> list[str]:
    """The note on a torque that leads the motion (`_torque_lead`), where it is clear of zero and of round-off."""
    if lead is None or not _found_lead(lead, dt):
        return []
    size = f"{_lead_size(lead, dt)})"
    total = declared - lead[0]
    if total >= dt:  # no timing of a held torque: it acts within the sample it is logged for
        held = f"{size}: with the {declared:g} s declared (data.tau_lead_s) that is a sample or more, more than a "
        held += "torque held over each sample makes (half a sample)"
        stand_in = (
            "A lead left so is fitted as armature and a negative change of damping, and the effects named beside it "
            "may stand in for it"
        )
        if total > MAX_DELAY_S:
            return [
                f"{held}, and more than {MAX_DELAY_S * 1e3:g} ms, more than a drive's lag or a bus's latency: the "
                f"torque and the angles were logged at different instants: check the files' time columns. {stand_in}"
            ]
        return [
            f"{held}. A torque column that is a command the drive applies later (its current loop's lag), or angles "
            "reported later than the torque (a bus's latency), lead so: for such a log declare "
            f"data.tau_lead_s={total:.3g} and diagnose again; otherwise the torque and the angles were logged at "
            f"different instants: check the files' time columns. {stand_in}"
        ]
    return [
        f"{size}: a torque held over each sample and logged "
        "at its start acts centred half a sample after its row, which data.tau_lead_s declares "
        f"(now {declared:g} s); a lead left undeclared is fitted as armature and a negative change of damping, "
        "and the effects named beside it may stand in for it (a 2 ms lead on another generator's data was named as "
        "backlash and a Stribeck friction): declare it and diagnose again"
    ]


def _torque_lead(
    plant: Plant,
    steps: list[Step],
    X: np.ndarray,
    s: Signals,
    weights: np.ndarray,
    n_nuisance: int,
    sliding: np.ndarray | None = None,
) -> tuple[float, float] | None:
    """(delay, std) [s] of the measured torque against the motion, one for every actuated joint, fitted without
    a bound beside the chosen columns `X`: negative where the torque leads the states (a torque held over each
    sample and logged at its start, read as acting at its row: `Dataset.tau_lead_s`). The selection's
    `time_delay` is bounded at 0, and what stands in for a lead there is armature and a negative change of damping
    (a lead of h scales the torque's rate, M x jerk + ...: -h w^2 M dq at a frequency w). None: no actuated joint.
    On the rows the final fit uses (`sliding`, as `_final_fit`: not where a joint sticks in its friction).
    """
    pool = candidates(plant, ["time_delay"], np.random.default_rng(0), s)
    if not pool:
        return None
    lead = sum(s.columns(c) for c in pool)  # (N, nv, 1): each actuated joint's -d tau / dt on its own row
    lo, hi = _step_bounds(steps, n_nuisance)
    fit = _fit_on(
        s,
        sliding,
        np.concatenate([X, lead], axis=2),
        s.residual,
        weights,
        np.append(lo, -np.inf),
        np.append(hi, np.inf),
    )
    return float(fit.coef[-1]), float(np.sqrt(fit.cov[-1, -1]))


def _on_sliding_rows(s: Signals, sliding: np.ndarray | None) -> Signals:
    """`s` with only the torques the final fit uses: those `Signals.used` keeps and, of them, the sliding ones
    (`_sliding_rows`; None: every used one)."""
    if sliding is None:
        return s
    return dataclasses.replace(s, used=sliding if s.used is None else s.used & sliding)


def _fit_on(
    s: Signals,
    sliding: np.ndarray | None,
    X: np.ndarray,
    r: np.ndarray,
    weights: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
) -> LinearFit:
    """The fit of `r` (N, nv) on the columns `X` of `s` on the rows the final fit uses (`_on_sliding_rows`; the
    others zero on both sides, as `Signals.used` asks: `s`'s own band already zeroes those it leaves out)."""
    if sliding is not None:
        s = _on_sliding_rows(s, sliding)
        X, r = s.zero_unused(X), s.zero_unused(r)
    return fit_columns(X, r, weights, lower=lower, upper=upper, record=s.record, used=s.used)


def _step_bounds(steps: list[Step], n_nuisance: int) -> tuple[np.ndarray, np.ndarray]:
    """(p,) lower and upper bounds of the nuisance (unbounded) then the steps' kept coefficients."""
    lo = [np.full(n_nuisance, -np.inf)] + [st.candidate.lower[st.kept] for st in steps]
    hi = [np.full(n_nuisance, np.inf)] + [st.candidate.upper[st.kept] for st in steps]
    return np.concatenate(lo), np.concatenate(hi)


def _rigid_refit(
    plant: Plant, pool: list[Candidate], s: Signals, weights: np.ndarray, base_idx: np.ndarray, min_independence: float
) -> Extension:
    """The rigid-body parameters re-identified alone (no other effect), as an extension of the nominal model.

    A base parameter whose column has less than `min_independence` of its norm outside the span of the columns
    before it on these data stays nominal, as the selection treats a candidate: nearly unexcited, it would take
    any value (on an SO-ARM100 that tracks multi-sines of a few tenths of a radian with its jaw held still, the
    refit of every column predicted the held-out torques 12 to 21 N m wrong, against 0.01 N m for the nominal)."""
    rb = [c for c in pool if c.effect == "rigid_body"]
    if not rb:
        return Extension.none(plant)
    X = s.columns(rb[0])
    kept = np.array(_span_free(np.zeros((X.shape[0] * X.shape[1], 0)), _flat(X, np.sqrt(weights)), min_independence))
    if not kept.size:
        return Extension.none(plant)
    fit = fit_columns(X[:, :, kept], s.residual, weights, record=s.record, used=s.used)
    step = Step(rb[0], kept, 0.0, 0.0, 0.0)
    return extension_from_fit(plant, [step], fit, base_idx)


STEP_SCALE_BAND = 0.25  # the integrator's inertia fitted to the training residual at 1 +- this ...
STEP_MIN_Z = 5.0  # ... and this many std from 0 reads the records as MuJoCo's steps
STEP_LAG_BAND = 0.25  # a torque behind the motion by one physics step, to this share of it: positions logged after


def _stepped_after(simulated: Callable[[Plant], Plant], plant: Plant) -> Plant:
    """`simulated(plant)` as a log of MuJoCo's steps of it shows it (`dynamics.stepping.as_stepped`)."""
    return as_stepped(simulated(plant))


def _one_step_delay_notes(plant: Plant, findings: list[Finding], reading: dict[str, Any] | None) -> list[str]:
    """Time delays named at the model's physics step, in records not read as MuJoCo's steps with the positions
    after each step: what a MuJoCo log that pairs each step's force with the positions after it looks like."""
    if stepping_of(plant) is None or (reading is not None and reading["positions_after_step"]):
        return []
    h = float(plant.mj_model.opt.timestep)
    at_step = [
        f"{f.target} {f.value * 1e3:.3g} ms"
        for f in findings
        if f.effect == "time_delay"
        and np.isfinite(f.std)
        and f.std <= STEP_LAG_BAND * h  # determined to a quarter of a step, and there
        and abs(f.value - h) <= STEP_LAG_BAND * h + 2.0 * f.std
    ]
    if not at_step:
        return []
    return [
        f"time delays named at the model's physics step ({h * 1e3:g} ms: {', '.join(at_step)}): a log of MuJoCo's "
        "simulation that pairs the force of each step with the positions after it is one step late so; if these "
        "records are such a log, diagnose.mujoco_steps=true reads each row's torque at the step before it"
    ]


def _steps_note(reading: dict[str, Any] | None) -> list[str]:
    """What the report says of the reading of the records as MuJoCo's steps (`_steps_reading`)."""
    if reading is None:
        return []
    inertia = ", ".join(f"{n} {v:.4g}" for n, v in reading["inertia"].items() if v)
    step = f"{reading['integrator']} at its {reading['timestep_s'] * 1e3:g} ms step"
    fitted = (
        f"fitted to the training residual at {reading['scale']:.4g} +- {reading['scale_std']:.2g} times its size, it "
        f"explains {reading['share']:.1%} of it"
    )
    if reading["read"]:
        why = (
            "as asked (diagnose.mujoco_steps=true)"
            if reading["asked"]
            else f"{fitted}; an armature change of that size on every joint would fit these data the same way, "
            "and a robot's log should be diagnosed with diagnose.mujoco_steps=false"
        )
        if reading["positions_after_step"]:
            why += (
                f"; the positions were logged after each step, beside the force of that step (the torque "
                f"{reading['torque_lag_s'] * 1e3:.3g} +- {reading['torque_lag_std_s'] * 1e3:.2g} ms behind its row, "
                "one step): each row's torque is read at the step before it"
            )
        return [
            f"the records read as a log of MuJoCo's own simulation of this model ({step}): its integrator takes the "
            f"joint damping and the servos' velocity gains at the end of each step, which adds an inertia to the "
            f"torque logged ({inertia}; dynamics.stepping) and moves the velocity a frictionloss ramp sees, as no "
            f"robot does; the step is taken into every model's torque here, and not into the calibrated MJCF, which "
            f"MuJoCo steps the same way ({why}; "
            "diagnose.mujoco_steps=false reads them as a robot's)"
        ]
    if reading["asked"] is False:
        return []
    return (
        [
            f"not read as a log of MuJoCo's own simulation of this model ({step}), whose integrator would add an "
            f"inertia to the torque logged ({inertia}): {fitted} (diagnose.mujoco_steps=true reads them so)"
        ]
        if abs(reading["scale"] - 1.0) <= STEP_SCALE_BAND
        else []
    )


def _a_step_earlier(data: Dataset, h: float, derivatives: str) -> Dataset:
    """`data` with each row's torque read with the states `h` earlier: a log that pairs each step's force with
    the positions after the step. States derived from the angles are evaluated there (`tau_lead_s`); states the
    record gives (`given`, `simulator`: a long log the harness thinned, whose `tau_lead_s` the filters ignore) are
    interpolated there, first row held. The torque is left as logged: interpolating it would colour its noise."""
    if derivatives not in ("given", "simulator"):
        return dataclasses.replace(data, tau_lead_s=data.tau_lead_s - h)

    def earlier(x: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(data.time - h, data.time, col) for col in x.T]).reshape(x.shape)

    return dataclasses.replace(
        data,
        q=earlier(data.q),
        dq=None if data.dq is None else earlier(data.dq),
        ddq=None if data.ddq is None else earlier(data.ddq),
    )


def _steps_reading(plant: Plant, records: list[_Record], asked: bool | None) -> dict[str, Any] | None:
    """Whether the records are read as a log of MuJoCo's own steps of `plant` (`dynamics.stepping`), and why.

    None under RK4, and where the model's integrator adds no inertia (no joint damping and no implicit servo
    damping) unless it is asked. Asked (True or False) it is what was asked; otherwise what the step changes in
    the nominal torque (the inertia h (kv +- D / 2) of each joint, the Coriolis torque's velocity and the velocity
    its friction ramps see), scaled by one factor fitted to the training residual in the analysis band (each
    joint weighted by its residual's inverse mean square), must come out within `STEP_SCALE_BAND` of 1 and
    `STEP_MIN_Z` std from 0: a log of MuJoCo's Panda through its own servos at 2 ms (0.9 kg m^2 on joints 1 and
    2) does, and so does one of its motor-driven copy (h D / 2 = 0.001 kg m^2 on every joint); a robot would
    need rotor inertias off the model's by that much, in that joint-by-joint ratio. Beside it one torque delay
    shared by the joints is fitted: at one physics step (to `STEP_LAG_BAND` of it and `STEP_MIN_Z` std) the
    positions were logged after each step (`positions_after_step`).
    """
    stepping = stepping_of(plant)
    if stepping is None or not (np.any(stepping.inertia) or asked):
        return None
    inertia = stepping.inertia
    sig = stack_signals([r.signals for r in records])
    residual = sig.residual
    # what the step changes in the nominal torque: its inertia, and the velocity the friction ramps see
    stepped = joint_torque(dataclasses.replace(plant, stepping=stepping), sig.q, sig.dq, sig.ddq)[0]
    column = sig.in_band(stepped - sig.tau_nominal)[:, :, None]
    # beside it, one delay of the torque shared by the joints: the force of a step logged with the positions after
    # it is one step behind its row (-d tau/dt, the time_delay candidate's column)
    rate = np.concatenate(
        [np.gradient(stepped[sig.record == i], sig.time[sig.record == i], axis=0) for i in np.unique(sig.record)]
    )
    delay = sig.in_band(-rate * sig.actuated)[:, :, None]  # of the stepped torque: its inertia's rate too
    power = np.mean(residual**2, axis=0)
    stepped_joints = inertia != 0 if np.any(inertia) else np.ones(plant.nv, bool)  # none: asked, every joint
    weights = np.where(stepped_joints & (power > 0), 1.0 / np.where(power > 0, power, 1.0), 0.0)
    both = np.concatenate([column, delay], axis=2)
    fit = fit_columns(both, residual, weights, record=sig.record, used=sig.used)
    (scale, lag), (std, lag_std) = fit.coef, np.sqrt(np.clip(np.diag(fit.cov), 0.0, None))
    left = residual - np.einsum("knp,p->kn", both, fit.coef)
    share = 1.0 - float(np.sum(weights * np.sum(left**2, axis=0)) / np.sum(weights * np.sum(residual**2, axis=0)))
    fits = abs(scale - 1.0) <= STEP_SCALE_BAND and scale >= STEP_MIN_Z * std
    read = bool(fits if asked is None else asked)
    h = float(plant.mj_model.opt.timestep)
    return {
        "read": read,
        "asked": asked,
        "integrator": integrator_name(plant.mj_model),
        "timestep_s": h,
        "inertia": _per_joint(plant.joint_names, inertia),
        "scale": float(scale),
        "scale_std": float(std),
        "share": share,
        "torque_lag_s": float(lag),
        "torque_lag_std_s": float(lag_std),
        # the positions logged after each step beside the force of that step: the torque a step behind its row
        "positions_after_step": bool(
            read and abs(lag - h) <= STEP_LAG_BAND * h + STEP_MIN_Z * lag_std and lag >= STEP_MIN_Z * lag_std
        ),
    }


# what a value at the end of its physical range says, by effect (`_at_bound_notes`)
_BEYOND_RANGE = {
    "torque_gain": "a torque scale this far from 1 is a torque constant, gear ratio or unit that is wrong: check the "
    "scale of the torque column",
    "time_delay": "a delay this long is a clock or time column that differs between the angles and the torques, or a "
    "model error the library does not name",
    "joint_offset": "an angle zero this far off is a calibration or angle-column mistake: check the angle columns",
}


def _weak_structure_notes(names: Sequence[str], white: list[dict[str, Any]]) -> list[str]:
    """Per joint whose judged residual (`whiteness`: the calibrated one where effects were found, else the
    nominal) is `weak`ly structured (the Ljung-Box test finds structure, more than the noise in the band, yet
    below the verdict's effect size): said, so that a white verdict is not read as no structure at all. An effect
    that small (an out-of-vocabulary position-dependent viscous friction of 0.05 N m s/rad on the two-link arm
    left 2.3 times the in-band noise, p 0.001) is not named; clean logs of MuJoCo's own servos reach 2.8 times
    (the SO-ARM100's first joint), so a lower threshold would call clean data structured."""
    return [
        f"{names[j]}: the residual left holds {w['structured_rms']:.3g} N m of structure, "
        f"{w['structured_rms'] / w['noise_in_band']:.1f} times the noise in the band (Ljung-Box p = "
        f"{w['ljung_box_p']:.2g}), below the verdict's effect size ({w['effect_size']:.3g} N m, half the noise "
        "floor): an effect too small to name on these records, or colour of the noise; longer or larger motions "
        "would tell"
        for j, w in enumerate(white)
        if w["weak"]
    ]


def _at_bound_notes(findings: list[Finding]) -> list[str]:
    """A note per finding whose headline value ended on a bound of its physical range (not its value of no
    effect: those are dropped, `_pinned_at_null`): the data ask for a value beyond what the effect can be, so the
    finding may stand for another cause (a torque gain of 0.6 ended at 0.7, with a joint elasticity at its own
    bound beside it)."""
    return [
        f"{f.name}: at its {f.at_bound} bound ({f.value:.4g}{'' if f.unit == '1' else ' ' + f.unit}), the end of the "
        "range the effect can physically have; the data ask for a value beyond it, so it may stand for another cause"
        + (f": {_BEYOND_RANGE[f.effect]}" if f.effect in _BEYOND_RANGE else ", one the library may not name")
        for f in findings
        if f.at_bound is not None
    ]


def _pinned_at_null(findings: list[Finding], nulls: list[float]) -> list[Finding]:
    """The findings whose headline ended on a bound that is its value of no effect (`Candidate.null`), read on
    the value or on its coefficient (a joint elasticity's compliance 0 is a stiffness of inf: its value cannot
    be stated, and it had been named, value None, credited with a held-out gain its columns never gave)."""
    return [
        f
        for f, null in zip(findings, nulls, strict=True)
        if f.at_bound is not None
        and (
            abs(float(f.value) - null) <= 1e-12
            or not np.isfinite(f.value)
            or (f.parameters and abs(float(f.parameters[0]["value"])) <= 1e-12)
        )
    ]


def _findings(
    steps: list[Step],
    fit: Any,
    X: np.ndarray,
    s_tr: Signals,
    s_va: Signals,
    cols_va: list[np.ndarray],
    weights: np.ndarray,
    names: tuple[str, ...],
    n_nuisance: int = 0,
    record_offsets: np.ndarray | None = None,
) -> list[Finding]:
    out: list[Finding] = []
    offset = n_nuisance
    # NaN where a record's torque was left out of the fit: averaged over the records where it was estimated
    mean_offset = np.nanmean(record_offsets, axis=0) if record_offsets is not None and record_offsets.size else 0.0
    lo, hi = _step_bounds(steps, n_nuisance)
    flags = fit.bound_flags()
    side = {-1: "lower", 1: "upper", 0: None}
    for i, s in enumerate(steps):
        k = len(s.kept)
        sl = slice(offset, offset + k)
        value, std = s.candidate.value(fit.coef[sl], fit.cov[sl, sl], X[:, :, sl])
        # the validation RMS with the findings up to this one, refitted on the training rows
        partial = fit_columns(
            X[:, :, : offset + k], s_tr.residual, weights, lower=lo[: offset + k], upper=hi[: offset + k]
        )
        pred = (
            s_va.smooth(s_va.tau_nominal)
            + mean_offset
            + np.einsum("knp,p->kn", np.concatenate(cols_va[: i + 1], axis=2), partial.coef[n_nuisance:])
        )
        pnames = [s.candidate.parameter_names[j] for j in s.kept]
        stds = np.sqrt(np.clip(np.diag(fit.cov)[sl], 0, None))
        at_bound = side[int(flags[sl][0])]
        if at_bound is not None:
            std = float("nan")
        out.append(
            Finding(
                effect=s.candidate.effect,
                target=s.candidate.target,
                value=value,
                std=std,
                unit=s.candidate.unit,
                counterpart=s.candidate.counterpart,
                evidence={
                    "delta_bic": s.delta_bic,
                    "heldout_mse_before": s.cv_mse_before,
                    "heldout_mse_after": s.cv_mse_after,
                    "heldout_gain": 1.0 - s.cv_mse_after / s.cv_mse_before if s.cv_mse_before > 0 else 0.0,
                    "z": (value - s.candidate.null) / std if std > 0 else float("nan"),
                    "correlation_time_samples": fit.correlation_time,
                },
                torque_rms_after=_per_joint(names, _rms(pred, s_va.smooth(s_va.tau))),
                parameters=[
                    {"name": n, "value": float(v), "std": None if side[int(b)] else float(e), "at_bound": side[int(b)]}
                    for n, v, e, b in zip(pnames, fit.coef[sl], stds, flags[sl], strict=True)
                ],
                at_bound=at_bound,
                fold_gains=[float(g) for g in s.fold_gains],
                note=s.candidate.note,
                held_nominal=list(s.held_nominal),
            )
        )
        offset += k
    return out


def _validation_series(
    plant: Plant,
    records: list[_Record],
    stacked: Signals,
    preds: dict[str, np.ndarray],
    nominal_sim: _Simulated,
    calibrated_sim: _Simulated,
) -> dict[str, Any]:
    """Time series of every validation record for the recording, exactly as the table compares them.

    The torques are those `models[...]["torque_rms"]` is computed from: measured and model torque, both
    low-passed in the analysis band by `stacked.smooth` (record by record), so that the RMS of a plotted
    residual over all records is the table's number.

    Returns:
        `joint_names`, `band_hz`, and `records`: per validation record `source`, `time` (N,) [s],
        `tau_measured`, `tau_nominal`, `tau_calibrated` (N, nv) in the band [N m], `q_time` (M,) and
        `q_measured` (M, nv) [rad], `sim_time` (K,) and `q_nominal`, `q_calibrated` (K, nv) [rad] (the
        re-started simulations).
    """
    tau = stacked.smooth(stacked.tau)
    nominal = stacked.smooth(preds["nominal"])
    model = stacked.smooth(preds["calibrated"])
    out = []
    for i, rec in enumerate(records):
        rows = _rows(rec)
        mine = stacked.record == i
        out.append(
            {
                "source": rec.data.source,
                "time": stacked.time[mine],
                "tau_measured": tau[mine],
                "tau_nominal": nominal[mine],
                "tau_calibrated": model[mine],
                "q_time": rec.data.time[rows],
                "q_measured": rec.states.q[rows],
                "sim_time": nominal_sim.runs[i].time,
                "q_nominal": nominal_sim.runs[i].q_simulated,
                "q_calibrated": calibrated_sim.runs[i].q_simulated,
            }
        )
    return {"joint_names": plant.joint_names, "band_hz": stacked.band_hz, "records": out}

"""Data anomalies named before anything is fitted: a joint that never moves, a torque stuck at zero, a
saturated torque.

Each one changes what a file can say: a joint that never moves in a file carries no information on its own
friction or inertia there (its columns are zero, and the file only constrains the others); a torque stuck at
zero on an actuated joint is a dead sensor or driver, not a model error; a torque that sits on a plateau at
its largest value is clipped (checked on the measured torque and, where logged, on the commanded one: a
controller that clips its command no longer tracks, and the measured torque is then all the motor gave).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from envs.dataset import Dataset

__all__ = ["Anomaly", "describe_outside", "find_anomalies", "outside_training"]

STILL_RANGE = 0.01  # a joint whose angle spans less than this in a file never moves there [rad]
STUCK_FRACTION = 0.5  # a torque that is exactly zero on more than this share of rows is stuck at zero
SATURATED_FRACTION = 0.002  # share of rows on the plateau at the largest |torque| that counts as saturation
SATURATION_RUN = 3  # ... in runs of at least this many consecutive rows
SATURATION_RATIO = 8.0  # ... and this many times the rows of the level just below it


@dataclass(frozen=True)
class Anomaly:
    """One anomaly of one file.

    Attributes:
        kind: `joint_never_moves`, `torque_stuck_at_zero` or `torque_saturated`.
        source: the file.
        joint: the joint.
        detail: the numbers it was named on.
    """

    kind: str
    source: str
    joint: str
    detail: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "source": self.source, "joint": self.joint, **self.detail}

    def describe(self) -> str:
        what = {
            "joint_never_moves": "never moves",
            "torque_stuck_at_zero": "reports a torque stuck at zero",
            "torque_saturated": "has a saturated torque",
        }[self.kind]
        numbers = ", ".join(f"{k} {v:.4g}" for k, v in self.detail.items())
        return f"{Path(self.source).name}: {self.joint} {what} ({numbers})"


def _longest_run(mask: np.ndarray) -> int:
    if not np.any(mask):
        return 0
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return int(np.max(np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)))


def _quantum(x: np.ndarray) -> float:
    steps = np.abs(np.diff(np.unique(np.round(x, 12))))
    return float(np.min(steps)) if steps.size else 0.0


def find_anomalies(datasets: list[Dataset]) -> list[Anomaly]:
    """Every anomaly of every file, in file then joint order."""
    out: list[Anomaly] = []
    for data in datasets:
        for j, name in enumerate(data.joint_names):
            q = data.q[:, j]
            span = float(np.percentile(q, 99.5) - np.percentile(q, 0.5))
            if span < STILL_RANGE:
                out.append(Anomaly("joint_never_moves", data.source, name, {"range_rad": span}))
            if not data.actuated[j]:
                continue
            tau = data.tau[:, j]
            zero = tau == 0.0
            if np.mean(zero) > STUCK_FRACTION:
                out.append(
                    Anomaly(
                        "torque_stuck_at_zero",
                        data.source,
                        name,
                        {"zero_fraction": float(np.mean(zero)), "longest_zero_run": float(_longest_run(zero))},
                    )
                )
                continue
            for column, values in (("measured", data.tau), ("commanded", data.tau_cmd)):
                found = None if values is None else _saturation(values[:, j])
                if found is not None:
                    out.append(
                        Anomaly(
                            "torque_saturated", data.source, name, {**found, "commanded": float(column == "commanded")}
                        )
                    )
    return out


def _saturation(tau: np.ndarray) -> dict[str, float] | None:
    """The plateau at the largest |torque| when it is a clip, else None.

    The top level (within 1.5 quanta or 0.1 % of the peak) of a clipped signal holds many more rows than the level
    below it; the top of a smooth (even quantised) swing holds at most a few times as many (a sine spends
    about 2.4 times as long in its top bin as in the next one). A clip is named when the top level holds
    `SATURATION_RATIO` times the next one, at least `SATURATED_FRACTION` of the rows, in a run of at least
    `SATURATION_RUN` rows.
    """
    mag = np.abs(tau)
    peak = float(np.max(mag))
    if peak == 0:
        return None
    tol = max(1.5 * _quantum(tau), 1e-3 * peak)
    top = mag >= peak - tol
    below = int(np.count_nonzero((mag < peak - tol) & (mag >= peak - 2 * tol)))
    run = _longest_run(top)
    if (
        np.mean(top) >= SATURATED_FRACTION
        and run >= SATURATION_RUN
        and np.count_nonzero(top) >= SATURATION_RATIO * max(below, 1)
    ):
        return {"level_Nm": peak, "fraction": float(np.mean(top)), "longest_run": float(run)}
    return None


COVERAGE_BINS = 72  # bins of a joint's angle (5 degrees on a hinge) in which the training motion is counted
OUTSIDE_SHARE = 0.05  # a validation record with this share of its rows outside the training motion is named
SPEED_MARGIN = 1.1  # a speed beyond this many times the fastest training speed is outside the training motion


def outside_training(
    q_train: np.ndarray,
    dq_train: np.ndarray,
    q_val: np.ndarray,
    dq_val: np.ndarray,
    record_val: np.ndarray,
    *,
    names: tuple[str, ...],
    sources: list[str],
    hinge: np.ndarray,
    position_matters: np.ndarray,
) -> list[dict[str, Any]]:
    """Where a validation record moves a joint outside what the training records covered.

    A calibrated model is judged on data the fit never saw; where those data reach angles or speeds the
    training records never did, the model extrapolates, and a parameter that the training motion did not
    exercise (a first moment only seen near hanging, a friction only seen slow) can be wrong there however
    well it fits. Per validation record and joint:

    - angles: the joint's range is cut into `COVERAGE_BINS` bins (a hinge's angle wrapped to one turn, since
      the torque repeats every turn); a validation row is outside where its bin holds no training row. Only
      for joints whose angle changes the nominal torque (`position_matters`): a wheel's angle does not.
    - speeds: a validation row is outside where |dq| exceeds `SPEED_MARGIN` times the fastest training |dq|.

    A (record, joint) is reported where either share reaches `OUTSIDE_SHARE`.

    Args:
        q_train, dq_train: (N, nv) training angles and speeds (the fit's filtered states).
        q_val, dq_val: (M, nv) validation angles and speeds; record_val: (M,) their record index.
        names: (nv,) joint names; sources: the validation files, by record index.
        hinge: (nv,) True for hinge joints (angles wrap), False for slides.
        position_matters: (nv,) False where the joint's angle enters no nominal torque (a cyclic joint).

    Returns:
        One dict per (record, joint) named: source, joint, share outside by angle and by speed, the training
        angle span and fastest speed, and the validation record's.
    """
    out: list[dict[str, Any]] = []
    for j, name in enumerate(names):
        wrap = bool(hinge[j])
        a_tr = np.mod(q_train[:, j] + np.pi, 2 * np.pi) - np.pi if wrap else q_train[:, j]
        speed_tr = float(np.max(np.abs(dq_train[:, j]))) if len(dq_train) else 0.0
        for r, source in enumerate(sources):
            rows = record_val == r
            if not np.any(rows):
                continue
            q, dq = q_val[rows, j], dq_val[rows, j]
            a = np.mod(q + np.pi, 2 * np.pi) - np.pi if wrap else q
            if position_matters[j]:
                lo, hi = (-np.pi, np.pi) if wrap else (min(a_tr.min(), a.min()), max(a_tr.max(), a.max()))
                edges = np.linspace(lo, hi, COVERAGE_BINS + 1)
                seen = np.histogram(a_tr, edges)[0] > 0
                idx = np.clip(np.searchsorted(edges, a, side="right") - 1, 0, COVERAGE_BINS - 1)
                by_angle = float(np.mean(~seen[idx])) if hi > lo else 0.0
            else:
                by_angle = 0.0
            by_speed = float(np.mean(np.abs(dq) > SPEED_MARGIN * speed_tr))
            if max(by_angle, by_speed) >= OUTSIDE_SHARE:
                out.append(
                    {
                        "source": source,
                        "joint": name,
                        "share_outside_by_angle": by_angle,
                        "share_outside_by_speed": by_speed,
                        "train_angle": [float(q_train[:, j].min()), float(q_train[:, j].max())],
                        "validation_angle": [float(q.min()), float(q.max())],
                        "train_max_speed": speed_tr,
                        "validation_max_speed": float(np.max(np.abs(dq))),
                        "unit": "rad" if wrap else "m",
                    }
                )
    return out


def describe_outside(d: dict[str, Any]) -> str:
    """One line for `notes`: where a validation record leaves the training motion."""
    parts = []
    if d["share_outside_by_angle"] >= OUTSIDE_SHARE:
        parts.append(
            f"{d['share_outside_by_angle']:.0%} of its rows at positions the training records never reach "
            f"({d['validation_angle'][0]:.3g} to {d['validation_angle'][1]:.3g} {d['unit']}; training "
            f"{d['train_angle'][0]:.3g} to {d['train_angle'][1]:.3g})"
        )
    if d["share_outside_by_speed"] >= OUTSIDE_SHARE:
        parts.append(
            f"{d['share_outside_by_speed']:.0%} faster than {SPEED_MARGIN:g} x the training records' fastest "
            f"({d['validation_max_speed']:.3g} {d['unit']}/s; training {d['train_max_speed']:.3g})"
        )
    return (
        f"{Path(d['source']).name}: {d['joint']} moves outside the training motion, {' and '.join(parts)}. The "
        "calibrated model extrapolates there: an error there may come from a parameter the training motion did not "
        "exercise; record training motion that covers it"
    )

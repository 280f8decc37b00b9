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

__all__ = ["Anomaly", "find_anomalies"]

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

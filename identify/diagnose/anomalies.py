"""Data anomalies named before anything is fitted: a joint that never moves, a joint that rests at its range
limit, a torque stuck at zero, a saturated torque.

Each one changes what a file can say: a joint that never moves in a file carries no information on its own
friction or inertia there (its columns are zero, and the file only constrains the others); a torque stuck at
zero on an actuated joint is a dead sensor or driver, not a model error; a torque that sits on a plateau at
its largest value is clipped (checked on the measured torque and, where logged, on the commanded one: a
controller that clips its command no longer tracks, and the measured torque is then all the motor gave); a
joint pressed into the end of its range takes the stop's force there, which no model of the diagnosis holds.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from envs.dataset import Dataset

__all__ = [
    "Anomaly",
    "at_limit",
    "describe_outside",
    "find_anomalies",
    "moving_joints",
    "outside_training",
    "still_joints",
]

STILL_RANGE = 0.01  # a hinge whose angle spans less than this in a file never moves there [rad]
STILL_SLIDE_RANGE = 1e-3  # ... a slide whose position spans less than this [m]
STUCK_FRACTION = 0.5  # a torque that is exactly zero on more than this share of rows is stuck at zero
STUCK_RUN_SHARE = 0.05  # ... and so is one exactly zero over a run of this share of the rows (and `STUCK_RUN_MIN`)
STUCK_RUN_MIN = 100  # rows, while its joint moves: a dropout, not a torque (noise never rests at exactly 0)
STUCK_QUANTA = 10.0  # ... unless the torque's RMS is under this many steps of its resolution
SATURATED_FRACTION = 0.002  # share of rows on the plateau at the largest |torque| that counts as saturation
SATURATION_RUN = 3  # ... in a run of at least this many consecutive rows,
SATURATION_EPISODES = 3  # ... or reached again and again: in at least this many separate runs
SATURATION_RATIO = 8.0  # ... and this many times the rows of the level just below it
AT_LIMIT_SHARE = 0.002  # a range end within this share of the range (or `AT_LIMIT_MIN`) is where the stop acts
AT_LIMIT_MIN = 1e-3  # [rad, or m x 0.1 on a slide]: the least such distance (filtering rounds a resting angle)
AT_LIMIT_FRACTION = 0.01  # a joint at its range limit on this share of a file's rows is named
PRESSED_MAX = 0.05  # [rad, or m x 0.1]: beyond its range by more, a joint is not pressed into a stop (the range is
# not the joint's: a plant without limits); as `envs.measured` reads a log (a hinge whole turns off beyond it)


@dataclass(frozen=True)
class Anomaly:
    """One anomaly of one file.

    Attributes:
        kind: `joint_never_moves`, `joint_at_limit`, `torque_stuck_at_zero` or `torque_saturated`.
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
            "joint_at_limit": "rests at the end of its range",
            "torque_stuck_at_zero": "reports a torque stuck at zero",
            "torque_saturated": "has a saturated torque",
        }[self.kind]
        numbers = ", ".join(f"{k} {v:.4g}" for k, v in self.detail.items())
        why = {
            "joint_never_moves": (
                ": its friction there is static, anywhere within its breakaway, which no function of its speed "
                "predicts; a torque error of that size on it there says nothing for or against a friction model"
            ),
            "joint_at_limit": (
                ": the stop's force acts there, which no model holds; those rows of its torque are left out of the "
                "fit and the verdict"
            ),
        }.get(self.kind, "")
        return f"{Path(self.source).name}: {self.joint} {what} ({numbers}){why}"


def _run_bounds(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(starts, stops) of the runs of consecutive True values of `mask` (each run is mask[start:stop])."""
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def _runs(mask: np.ndarray) -> np.ndarray:
    """Lengths of the runs of consecutive True values of `mask`."""
    starts, stops = _run_bounds(mask)
    return stops - starts


def _longest_run(mask: np.ndarray) -> int:
    return int(np.max(_runs(mask), initial=0))


def _zero_while_moving(zero: np.ndarray, q: np.ndarray, moves: float, tau: np.ndarray) -> bool:
    """Whether a torque is exactly 0 over a run of at least `STUCK_RUN_SHARE` of the rows (and `STUCK_RUN_MIN`)
    in which its joint moves (its position spans `moves`): a log that dropped the reading for a while (40 % of
    a file so was called clean, its zeros fitted as the rigid body's). A joint at rest may read 0 for long, and
    so may a torque within a few steps of its sensor's resolution (RMS under `STUCK_QUANTA` of its quantum: a
    light wrist joint of a Menagerie arm on a 0.001 N m sensor reads 0 on an eighth of its rows)."""
    least = max(STUCK_RUN_MIN, STUCK_RUN_SHARE * len(zero))
    if not any(
        stop - start >= least and _span(q[start:stop]) > moves for start, stop in zip(*_run_bounds(zero), strict=True)
    ):
        return False
    rest = tau[~zero]  # the resolution (a sort of the column) only where such a run is there to excuse
    return not (rest.size and np.sqrt(np.mean(rest**2)) < STUCK_QUANTA * _quantum(rest))


def _quantum(x: np.ndarray) -> float:
    steps = np.abs(np.diff(np.unique(np.round(x, 12))))
    return float(np.min(steps)) if steps.size else 0.0


def _noise(x: np.ndarray) -> float:
    """Robust std of the sample-to-sample noise of `x`: from the median absolute second difference, which a
    smooth motion sampled fast leaves near zero (white noise of std s has second differences of std s sqrt 6)."""
    d2 = np.diff(x, 2)
    return float(np.median(np.abs(d2 - np.median(d2))) / 0.6745 / np.sqrt(6.0)) if d2.size else 0.0


def _span(q: np.ndarray) -> float:
    return float(np.percentile(q, 99.5) - np.percentile(q, 0.5))


def _still_range(hinge: np.ndarray | None, j: int) -> float:
    return STILL_RANGE if hinge is None or hinge[j] else STILL_SLIDE_RANGE


def still_joints(data: Dataset, hinge: np.ndarray | None = None) -> list[int]:
    """Indices of the joints that never move in the file: a hinge's angle spans less than `STILL_RANGE`, a
    slide's position less than `STILL_SLIDE_RANGE` (`hinge`: (nv,) True for hinges; None: every joint a hinge)."""
    return [j for j in range(data.q.shape[1]) if _span(data.q[:, j]) < _still_range(hinge, j)]


def moving_joints(data: Dataset, hinge: np.ndarray | None = None) -> np.ndarray:
    """(nv,) False for the joints that never move in the file (`still_joints`), True for the others."""
    moving = np.ones(data.q.shape[1], bool)
    moving[still_joints(data, hinge)] = False
    return moving


def at_limit(
    q: np.ndarray, q_range: np.ndarray, hinge: np.ndarray | None = None, margin: np.ndarray | None = None
) -> np.ndarray:
    """(N, nv) True where a joint is at (or pressed beyond) an end of its range: within `AT_LIMIT_SHARE` of the
    range (at least `AT_LIMIT_MIN` rad, a tenth of that in m on a slide, and at least its `margin`) inside it, or
    up to `PRESSED_MAX` beyond it, where MuJoCo's limit force acts on the simulated joint and a real joint's stop
    pushes back. False on an unlimited joint, and farther beyond (no stop there: the joint has none at that range).

    Args:
        q: (N, nv) joint positions; q_range: (nv, 2) the model's ranges (+-inf: unlimited).
        margin: (nv,) the joints' limit `margin` (MuJoCo's limit acts that far inside each end): the distance
            inside an end is at least that.

    Raises:
        ValueError: q_range is not one (low, high) row per column of q.
    """
    q_range = np.asarray(q_range, dtype=float)
    if q_range.shape != (q.shape[1], 2):
        raise ValueError(
            f"q_range has shape {q_range.shape}; one (low, high) row per joint, ({q.shape[1]}, 2), expected"
        )
    lo, hi = q_range[:, 0], q_range[:, 1]
    finite = np.isfinite(lo) & np.isfinite(hi)
    unit = np.ones(len(lo)) if hinge is None else np.where(np.asarray(hinge, bool), 1.0, 0.1)
    tol = np.maximum(AT_LIMIT_SHARE * np.where(finite, hi - lo, 0.0), AT_LIMIT_MIN * unit)
    if margin is not None:
        tol = np.maximum(tol, np.asarray(margin, dtype=float))
    out = PRESSED_MAX * unit
    with np.errstate(invalid="ignore"):
        low = (q <= lo + tol) & (q >= lo - out)
        high = (q >= hi - tol) & (q <= hi + out)
        return (low | high) & finite  # type: ignore[no-any-return]


def find_anomalies(
    datasets: list[Dataset],
    hinge: np.ndarray | None = None,
    q_range: np.ndarray | None = None,
    margin: np.ndarray | None = None,
) -> list[Anomaly]:
    """Every anomaly of every file, in file then joint order (`hinge` as for `still_joints`; `q_range`: (nv, 2)
    the model's joint ranges and `margin` their limits' margins, for `joint_at_limit` (`at_limit`), None: not
    checked)."""
    out: list[Anomaly] = []
    for data in datasets:
        still = still_joints(data, hinge)
        stopped = at_limit(data.q, q_range, hinge, margin) if q_range is not None else np.zeros(data.q.shape, bool)
        for j, name in enumerate(data.joint_names):
            if j in still:
                unit = "rad" if hinge is None or hinge[j] else "m"
                out.append(Anomaly("joint_never_moves", data.source, name, {f"range_{unit}": _span(data.q[:, j])}))
            if np.mean(stopped[:, j]) >= AT_LIMIT_FRACTION:
                lo, hi = (float(v) for v in np.asarray(q_range)[j])  # type: ignore[index]
                end = hi if np.median(data.q[stopped[:, j], j]) >= (lo + hi) / 2 else lo  # where most rows rest
                out.append(
                    Anomaly(
                        "joint_at_limit",
                        data.source,
                        name,
                        {"fraction": float(np.mean(stopped[:, j])), "limit": end},
                    )
                )
            if not data.actuated[j]:
                continue
            # the torques as logged where the reader resampled them (`envs.measured`): interpolation between
            # rows would blur a value stuck at zero or a plateau at a limit
            measured = data.meta.get("logged_tau", data.tau)
            commanded = data.meta.get("logged_tau_cmd", data.tau_cmd)
            tau = measured[:, j]
            zero = tau == 0.0
            moves = STILL_RANGE if hinge is None or hinge[j] else STILL_SLIDE_RANGE
            if np.mean(zero) > STUCK_FRACTION or _zero_while_moving(zero, data.q[:, j], moves, tau):
                out.append(
                    Anomaly(
                        "torque_stuck_at_zero",
                        data.source,
                        name,
                        {"zero_fraction": float(np.mean(zero)), "longest_zero_run": float(_longest_run(zero))},
                    )
                )
                continue
            for column, values in (("measured", measured), ("commanded", commanded)):
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
    `SATURATION_RUN` rows or in `SATURATION_EPISODES` separate runs (a fast controller's command touches its
    limit for a row or two at a time, again and again, as in the DFKI C.0 swing-up logged at ~600 Hz). A measured
    torque carries noise on its plateau: a level is then at least six times its noise wide (`_noise`; a
    Kinova Gen3 whose PD loop chattered at its 105 N m limits, read with 0.1 N m of noise, was named nothing). A
    torque that never leaves its top two levels is not clipped but constant (a joint held at rest: an SO-ARM100's jaw
    held by its feed-forward read 0.006 N m on every row, and was called saturated).
    """
    mag = np.abs(tau)
    peak = float(np.max(mag))
    if peak == 0:
        return None
    exact = max(1.5 * _quantum(tau), 1e-3 * peak)
    # a clip measured through noise of std s is a pile-up within about 3 s of the limit, above and below it: a top
    # level 6 s wide holds the plateau rather than the upper half of its noise (an exact plateau, a clipped
    # command, is read at the fine level first: the noise of the rest of the signal would blur it)
    for tol in dict.fromkeys((exact, max(exact, 6.0 * _noise(mag)))):
        if np.ptp(tau) <= 2 * tol or peak <= 2 * tol:
            # never leaves its top levels (a torque held constant: a joint at rest), or noise alone: no swing to clip
            continue
        top = mag >= peak - tol
        below = int(np.count_nonzero((mag < peak - tol) & (mag >= peak - 2 * tol)))
        runs = _runs(top)
        run, episodes = int(np.max(runs, initial=0)), len(runs)
        if (
            np.mean(top) >= SATURATED_FRACTION
            and (run >= SATURATION_RUN or episodes >= SATURATION_EPISODES)
            and np.count_nonzero(top) >= SATURATION_RATIO * max(below, 1)
        ):
            return {
                "level_Nm": peak,
                "fraction": float(np.mean(top)),
                "longest_run": float(run),
                "episodes": float(episodes),
            }
    return None


ANGLE_TOLERANCE = np.deg2rad(5.0)  # a hinge angle within this of the training motion is inside it [rad]
SLIDE_TOLERANCE = 1e-3  # ... a slide position within this (or 1/72 of the positions' span, if more) [m]
OUTSIDE_SHARE = 0.05  # a validation record with this share of its rows outside the training motion is named
SPEED_MARGIN = 1.1  # a speed beyond this many times the fastest training speed, plus SPEED_FLOOR, is outside
SPEED_FLOOR = 0.01  # [rad/s or m/s]: a joint held still in training is not 'outside' at filter-rounding speeds


def _covered(q: np.ndarray, record: np.ndarray, wrap: bool) -> tuple[np.ndarray, np.ndarray]:
    """(starts, ends) of the disjoint sorted intervals of positions the training motion passes through: between
    consecutive rows of a record it passes every position in between, however sparse the rows; a hinge's
    intervals are wrapped to [-pi, pi) (one that spans a turn covers all of it)."""
    same = record[:-1] == record[1:]
    lo = np.concatenate([q, np.minimum(q[:-1], q[1:])[same]])
    hi = np.concatenate([q, np.maximum(q[:-1], q[1:])[same]])
    if wrap:
        if np.any(hi - lo >= 2 * np.pi):
            return np.array([-np.pi]), np.array([np.pi])
        start = np.mod(lo + np.pi, 2 * np.pi) - np.pi
        end = start + (hi - lo)
        over = end > np.pi  # crosses the wrap: split in two
        lo = np.concatenate([start, np.full(np.count_nonzero(over), -np.pi)])
        hi = np.concatenate([np.minimum(end, np.pi), end[over] - 2 * np.pi])
    order = np.argsort(lo)
    lo, reach = lo[order], np.maximum.accumulate(hi[order])  # reach: the furthest end of any interval so far
    first = np.flatnonzero(np.concatenate([[True], lo[1:] > reach[:-1]]))  # starts after all before it ended
    return lo[first], reach[np.concatenate([first[1:] - 1, [len(lo) - 1]])]


def _inside(a: np.ndarray, starts: np.ndarray, ends: np.ndarray, tol: float) -> np.ndarray:
    """Whether each position lies within `tol` of one of the disjoint sorted intervals."""
    k = np.searchsorted(starts, a + tol, side="right") - 1
    return (k >= 0) & (a - tol <= ends[np.maximum(k, 0)])


def outside_training(
    q_train: np.ndarray,
    dq_train: np.ndarray,
    record_train: np.ndarray,
    q_val: np.ndarray,
    dq_val: np.ndarray,
    record_val: np.ndarray,
    *,
    names: tuple[str, ...],
    sources: list[str],
    hinge: np.ndarray,
    periodic: np.ndarray,
    position_matters: np.ndarray,
) -> list[dict[str, Any]]:
    """Where a validation record moves a joint outside what the training records covered.

    A calibrated model is judged on data the fit never saw; where those data reach positions or speeds the
    training records never did, the model extrapolates, and a parameter that the training motion did not
    exercise (a first moment only seen near hanging, a friction only seen slow) can be wrong there however
    well it fits. Per validation record and joint:

    - positions: a validation row is outside where no training motion passes within `ANGLE_TOLERANCE` of it
      (a slide: `SLIDE_TOLERANCE`, or 1/72 of the span of the positions if more). The training motion covers
      every position between two consecutive rows of a record. A hinge whose torque repeats every turn (no
      joint spring) is compared within one turn. Only for joints whose position changes the nominal torque
      (`position_matters`): a wheel's angle does not.
    - speeds: a validation row is outside where |dq| exceeds `SPEED_MARGIN` times the fastest training |dq|
      plus `SPEED_FLOOR`.

    A (record, joint) is reported where either share reaches `OUTSIDE_SHARE`.

    Args:
        q_train, dq_train: (N, nv) training positions and speeds (the fit's filtered states); record_train:
            (N,) their record index.
        q_val, dq_val: (M, nv) validation positions and speeds; record_val: (M,) their record index.
        names: (nv,) joint names; sources: the validation files, by record index.
        hinge: (nv,) True for hinges (positions in rad), False for slides (m).
        periodic: (nv,) True for a hinge whose torque repeats every turn (no joint spring): its positions are
            compared within one turn.
        position_matters: (nv,) False where the joint's position enters no nominal torque (a cyclic joint).

    Returns:
        One dict per (record, joint) named: source, joint, share outside by position and by speed, the
        training positions' range and fastest speed, the validation record's, and the unit of position.
    """
    out: list[dict[str, Any]] = []
    for j, name in enumerate(names):
        wrap = bool(hinge[j] and periodic[j])
        starts, ends = _covered(q_train[:, j], record_train, wrap)
        speed_tr = float(np.max(np.abs(dq_train[:, j]), initial=0.0))
        for r, source in enumerate(sources):
            rows = record_val == r
            if not np.any(rows):
                continue
            q, dq = q_val[rows, j], dq_val[rows, j]
            by_angle = 0.0
            if position_matters[j]:
                if wrap:
                    a = np.mod(q + np.pi, 2 * np.pi) - np.pi
                    inside = np.zeros(len(a), dtype=bool)
                    for turn in (-2 * np.pi, 0.0, 2 * np.pi):  # within the tolerance across the wrap too
                        inside |= _inside(a + turn, starts, ends, float(ANGLE_TOLERANCE))
                else:
                    tol = ANGLE_TOLERANCE if hinge[j] else max(SLIDE_TOLERANCE, np.ptp(np.r_[q_train[:, j], q]) / 72)
                    inside = _inside(q, starts, ends, float(tol))
                by_angle = float(np.mean(~inside))
            by_speed = float(np.mean(np.abs(dq) > SPEED_MARGIN * speed_tr + SPEED_FLOOR))
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
                        "unit": "rad" if hinge[j] else "m",
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

"""The DFKI double pendulum authors' identified models, evaluated as torque predictors and simulators.

Their model (`dfki-ric-underactuated-lab/double_pendulum`, "UnderactuatedLecture" formulas), with q = 0
hanging down and q2 relative to link 1:

    M = [[I1 + I2 + m2 l1^2 + 2 m2 l1 r2 c2 + gr^2 Ir + Ir,   I2 + m2 l1 r2 c2 - gr Ir],
         [I2 + m2 l1 r2 c2 - gr Ir,                           I2 + gr^2 Ir]]
    C q' = [-2 m2 l1 r2 s2 q1' q2' - m2 l1 r2 s2 q2'^2,  m2 l1 r2 s2 q1'^2]
    G = [-m1 g r1 s1 - m2 g (l1 s1 + r2 s12),  -m2 g r2 s12]
    F = b q' + cf atan(100 q')
    M q'' + C q' - G + F = tau

I1, I2 are the link inertias about the joint axes; the parameters come from their yml files.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

from dynamics.errors import DataError, one_line

__all__ = [
    "AUTHOR_BASE_NAMES",
    "AUTHOR_KEYS",
    "author_accel",
    "author_base",
    "author_regressor",
    "author_torque",
    "load_author_model",
]

# what a physical model of theirs has >= 0 (the gear ratio has a sign; the centres of mass r1, r2 may lie either side)
_NON_NEGATIVE = ("I1", "I2", "Ir", "b1", "b2", "cf1", "cf2", "l2", "m1", "m2")
AUTHOR_KEYS = ("I1", "I2", "Ir", "b1", "b2", "cf1", "cf2", "g", "gr", "l1", "l2", "m1", "m2", "r1", "r2")
# the combinations their model is linear in (l1, g and gr are fixed by the design)
AUTHOR_BASE_NAMES = ("I1 + m2 l1^2", "I2", "m2 r2", "m1 r1 + m2 l1", "Ir", "b1", "b2", "cf1", "cf2")


def load_author_model(path: Path) -> dict[str, float]:
    """The parameters of one of the authors' yml files.

    Raises:
        DataError: the file cannot be read or parsed, is not a mapping, or a parameter of `AUTHOR_KEYS` is
            missing or not a finite number (the message names the file and the key).
    """
    try:
        with open(path, encoding="utf-8") as f:
            raw = yaml.safe_load(f)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        why = err.strerror if isinstance(err, OSError) and err.strerror else one_line(err)
        raise DataError(f"{path}: cannot read it as a reference model: {why}") from None
    if not isinstance(raw, dict):
        raise DataError(
            f"{path}: a reference model is a mapping of {', '.join(AUTHOR_KEYS)}; the file holds {raw!r:.60}"
        )
    missing = [k for k in AUTHOR_KEYS if k not in raw]
    if missing:
        raise DataError(f"{path}: missing parameters {missing}")
    out = {}
    for k in AUTHOR_KEYS:
        try:
            out[k] = float(raw[k])
        except (TypeError, ValueError):
            out[k] = math.nan
        if not math.isfinite(out[k]):
            raise DataError(f"{path}: parameter {k} is {raw[k]!r}, not a finite number")
    negative = [k for k in _NON_NEGATIVE if out[k] < 0] + [k for k in ("g", "l1") if out[k] <= 0]
    if negative:
        raise DataError(
            f"{path}: parameter {negative[0]} is {out[negative[0]]:g}, not physical (masses, lengths, inertias, "
            "friction and gravity are >= 0, g and l1 > 0)"
        )
    return out


def _terms(p: dict[str, float], q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mass matrices (N, 2, 2) and the rest C q' - G + F (N, 2)."""
    c2, s2 = np.cos(q[:, 1]), np.sin(q[:, 1])
    s1, s12 = np.sin(q[:, 0]), np.sin(q[:, 0] + q[:, 1])
    h = p["m2"] * p["l1"] * p["r2"]
    M = np.empty((len(q), 2, 2))
    M[:, 0, 0] = p["I1"] + p["I2"] + p["m2"] * p["l1"] ** 2 + 2 * h * c2 + p["gr"] ** 2 * p["Ir"] + p["Ir"]
    M[:, 0, 1] = M[:, 1, 0] = p["I2"] + h * c2 - p["gr"] * p["Ir"]
    M[:, 1, 1] = p["I2"] + p["gr"] ** 2 * p["Ir"]
    coriolis = np.column_stack([-2 * h * s2 * dq[:, 0] * dq[:, 1] - h * s2 * dq[:, 1] ** 2, h * s2 * dq[:, 0] ** 2])
    gravity = np.column_stack(
        [
            -p["m1"] * p["g"] * p["r1"] * s1 - p["m2"] * p["g"] * (p["l1"] * s1 + p["r2"] * s12),
            -p["m2"] * p["g"] * p["r2"] * s12,
        ]
    )
    b, cf = np.array([p["b1"], p["b2"]]), np.array([p["cf1"], p["cf2"]])
    friction = b * dq + cf * np.arctan(100 * dq)
    return M, coriolis - gravity + friction


def author_torque(p: dict[str, float], q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """(N, 2) joint torque [N m] of the authors' model at states q, dq, ddq (each (N, 2))."""
    M, rest = _terms(p, q, dq)
    return np.einsum("kij,kj->ki", M, ddq) + rest


def author_accel(p: dict[str, float], q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """(N, 2) joint acceleration [rad/s^2] of the authors' model under joint torque tau (N, 2)."""
    M, rest = _terms(p, q, dq)
    return np.linalg.solve(M, (tau - rest)[:, :, None])[:, :, 0]


def author_base(p: dict[str, float]) -> np.ndarray:
    """(9,) the combinations of `AUTHOR_BASE_NAMES` of one of the authors' parameter sets [SI]."""
    return np.array(
        [
            p["I1"] + p["m2"] * p["l1"] ** 2,
            p["I2"],
            p["m2"] * p["r2"],
            p["m1"] * p["r1"] + p["m2"] * p["l1"],
            p["Ir"],
            p["b1"],
            p["b2"],
            p["cf1"],
            p["cf2"],
        ]
    )


def author_regressor(q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, *, l1: float, g: float, gr: float) -> np.ndarray:
    """(N, 2, 9) the authors' model as a regressor: `author_torque(p, ...) = author_regressor(...) @ author_base(p)`.

    Their model form is linear in the nine combinations of `AUTHOR_BASE_NAMES` once the link length l1,
    gravity g and gear ratio gr are fixed; this lets the same form be refitted by least squares on other data.

    Args:
        q, dq, ddq: (N, 2) joint states [rad, rad/s, rad/s^2].
        l1: shoulder-to-elbow length [m]; g: gravity [m/s^2]; gr: gear ratio [1].
    """
    c2, s2 = np.cos(q[:, 1]), np.sin(q[:, 1])
    s1, s12 = np.sin(q[:, 0]), np.sin(q[:, 0] + q[:, 1])
    a1, a2 = ddq[:, 0], ddq[:, 1]
    out = np.zeros((len(q), 2, 9))
    out[:, 0, 0] = a1
    out[:, :, 1] = (a1 + a2)[:, None]
    out[:, 0, 2] = l1 * (2 * c2 * a1 + c2 * a2 - 2 * s2 * dq[:, 0] * dq[:, 1] - s2 * dq[:, 1] ** 2) + g * s12
    out[:, 1, 2] = l1 * (c2 * a1 + s2 * dq[:, 0] ** 2) + g * s12
    out[:, 0, 3] = g * s1
    out[:, 0, 4] = (gr**2 + 1) * a1 - gr * a2
    out[:, 1, 4] = gr**2 * a2 - gr * a1
    out[:, 0, 5], out[:, 1, 6] = dq[:, 0], dq[:, 1]
    out[:, 0, 7], out[:, 1, 8] = np.arctan(100 * dq[:, 0]), np.arctan(100 * dq[:, 1])
    return out

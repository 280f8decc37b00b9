"""Random joint states and the independent columns of a stacked regressor (used wherever a generic state is needed)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from dynamics.plant import Plant

__all__ = ["independent_columns", "random_states"]


def random_states(
    plant: Plant, rng: np.random.Generator, n: int, *, speed: float = 3.0, acceleration: float = 10.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, nv) each: q uniform over the joint ranges ([-pi, pi] where unlimited), dq and ddq normal.

    Args:
        speed, acceleration: standard deviations of dq [rad/s] and ddq [rad/s^2].
    """
    lo = np.where(np.isfinite(plant.q_range[:, 0]), plant.q_range[:, 0], -np.pi)
    hi = np.where(np.isfinite(plant.q_range[:, 1]), plant.q_range[:, 1], np.pi)
    q = rng.uniform(lo, hi, size=(n, plant.nv))
    return q, rng.normal(0.0, speed, size=(n, plant.nv)), rng.normal(0.0, acceleration, size=(n, plant.nv))


def independent_columns(
    W: np.ndarray, order: list[int] | None = None, *, zero_tol: float = 1e-9, span_tol: float = 1e-6
) -> list[int]:
    """Columns of W (rows, p), taken in `order`, that are not in the span of the ones kept before them.

    Args:
        zero_tol: a column whose norm is below zero_tol times the largest column norm is skipped (zero up to
            rounding, e.g. a mass moment along its own joint axis).
        span_tol: a unit column is dependent when less than this much of it lies outside the kept span.
    """
    norms = np.linalg.norm(W, axis=0)
    top = max(float(norms.max()), 1e-300) if W.size else 1.0
    basis = np.zeros((W.shape[0], 0))
    keep: list[int] = []
    for c in range(W.shape[1]) if order is None else order:
        if norms[c] <= zero_tol * top:
            continue
        v = W[:, c] / norms[c]
        for _ in range(2):  # classical Gram-Schmidt twice is stable enough here
            v = v - basis @ (basis.T @ v)
        if np.linalg.norm(v) > span_tol:
            basis = np.column_stack([basis, v / np.linalg.norm(v)])
            keep.append(c)
    return keep

"""Estimates against the MJCF truth, torque prediction, and validation on data the fit never saw."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from dynamics.base import BaseParameters
from dynamics.regressor import ParameterModel
from identify.problem import Estimate

__all__ = ["ParameterComparison", "compare_with_truth", "linear_combination", "predict_torque", "torque_rms"]


@dataclass(frozen=True)
class ParameterComparison:
    """One base parameter against its truth.

    Attributes:
        name: the base parameter's combination.
        true, estimate, std: values in the parameter's SI unit.
        rel_error: (estimate - true) / |true|, or None where |true| is near zero (see `abs_error`).
        abs_error: estimate - true.
        z: (estimate - true) / std: the error in units of the estimator's own uncertainty.
    """

    name: str
    true: float
    estimate: float
    std: float
    rel_error: float | None
    abs_error: float
    z: float

    def to_dict(self) -> dict[str, Any]:
        """Plain values; non-finite floats become None (JSON has no NaN)."""
        return {k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in self.__dict__.items()}


def compare_with_truth(
    estimate: Estimate, beta_true: np.ndarray, *, zero_tol: float = 1e-9
) -> list[ParameterComparison]:
    """Per base parameter: truth, estimate, std, relative error (absolute where the truth is ~0) and z."""
    scale = max(float(np.max(np.abs(beta_true))), 1.0)
    out = []
    for name, t, e, s in zip(estimate.names, beta_true, estimate.beta, estimate.std, strict=True):
        err = float(e - t)
        rel = None if abs(t) <= zero_tol * scale else err / abs(float(t))
        z = err / s if s > 0 else (0.0 if err == 0 else float("inf"))
        out.append(ParameterComparison(name, float(t), float(e), float(s), rel, err, float(z)))
    return out


def linear_combination(
    base: BaseParameters, estimate: Estimate, c: np.ndarray, *, tol: float = 1e-8
) -> tuple[float, float]:
    """Estimate and std of c @ theta, a linear combination of the standard parameters.

    Raises:
        ValueError: c @ theta is not identifiable (c is not a combination of the base parameters' rows).
    """
    d, *_ = np.linalg.lstsq(base.K.T, c, rcond=None)
    if np.linalg.norm(base.K.T @ d - c) > tol * max(float(np.linalg.norm(c)), 1.0):
        raise ValueError("this combination of standard parameters is not identifiable from the base parameters")
    value = float(d @ estimate.beta)
    std = float(np.sqrt(d @ estimate.cov @ d)) if estimate.cov is not None else float("nan")
    return value, std


def predict_torque(
    model: ParameterModel, base: BaseParameters, beta: np.ndarray, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray
) -> np.ndarray:
    """(N, nv) joint torque the identified model predicts along the given states [N m]."""
    return np.einsum("knr,r->kn", base.columns(model.regressor(q, dq, ddq)), beta)


def torque_rms(predicted: np.ndarray, measured: np.ndarray, joint_names: tuple[str, ...]) -> dict[str, float]:
    """Per joint RMS of measured minus predicted torque [N m]."""
    rms = np.sqrt(np.mean((measured - predicted) ** 2, axis=0))
    return {n: float(r) for n, r in zip(joint_names, rms, strict=True)}

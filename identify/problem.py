"""The data an estimator works on, and what it returns."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dynamics.base import BaseParameters
from dynamics.regressor import ParameterModel
from envs.dataset import Dataset
from identify.derivatives import States

__all__ = ["Estimate", "Problem", "build_problem"]


@dataclass(frozen=True)
class Problem:
    """A linear-in-parameters identification problem y = W beta + e on the trusted rows.

    Attributes:
        W: (N, nv, r) base regressor per sample and joint.
        y: (N, nv) measured joint torque [N m] (0 on unactuated joints: known exactly).
        model: the parameter model the columns come from.
        base: its base-parameter map.
        data: the dataset (time, raw q, tau) for estimators that filter the signals themselves.
        states: the states W was built from.
        rows: (N,) bool, the samples used (filter edges removed).
    """

    W: np.ndarray
    y: np.ndarray
    model: ParameterModel
    base: BaseParameters
    data: Dataset
    states: States
    rows: np.ndarray

    @property
    def names(self) -> tuple[str, ...]:
        return self.base.names


def build_problem(data: Dataset, states: States, model: ParameterModel, base: BaseParameters) -> Problem:
    """Stack the base regressor on the rows `states` trusts."""
    rows = states.valid
    W = base.columns(model.regressor(states.q[rows], states.dq[rows], states.ddq[rows]))
    return Problem(W=W, y=data.tau[rows], model=model, base=base, data=data, states=states, rows=rows)


@dataclass(frozen=True)
class Estimate:
    """An estimator's answer.

    Attributes:
        estimator: its registry name.
        names: (r,) base-parameter names.
        beta: (r,) estimate.
        cov: (r, r) covariance of the estimate, or None where the estimator defines none.
        sigma: (nv,) residual std per joint [N m].
        diagnostics: estimator-specific facts (iterations, convergence history, ...).
    """

    estimator: str
    names: tuple[str, ...]
    beta: np.ndarray
    cov: np.ndarray | None
    sigma: np.ndarray
    diagnostics: dict = field(default_factory=dict)

    @property
    def std(self) -> np.ndarray:
        """(r,) standard deviations (NaN where there is no covariance)."""
        if self.cov is None:
            return np.full(len(self.beta), np.nan)
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

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
        prior: (p,) standard parameters of the prior model (`dynamics.prior`): what estimators that need a
            model before the data (regularised and physically consistent fits) start from and pull towards.
            None: no prior given; such estimators then refuse to run rather than use the MJCF's values,
            which in simulation are the truth.
    """

    W: np.ndarray
    y: np.ndarray
    model: ParameterModel
    base: BaseParameters
    data: Dataset
    states: States
    rows: np.ndarray
    prior: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.prior is not None and np.shape(self.prior) != (self.model.n_params,):
            raise ValueError(
                f"prior has shape {np.shape(self.prior)}, expected ({self.model.n_params},): one value per "
                f"parameter of {list(self.model.names)}"
            )

    @property
    def names(self) -> tuple[str, ...]:
        return self.base.names

    def prior_theta(self, nominal: np.ndarray | None = None) -> np.ndarray:
        """(p,) the prior's standard parameters: `nominal` if given, else the problem's prior.

        Raises:
            ValueError: neither is given (a fit must never fall back on the MJCF, the truth in simulation).
        """
        if nominal is not None:
            theta = np.asarray(nominal, dtype=float)
            if theta.shape != (self.model.n_params,):
                raise ValueError(f"nominal has shape {theta.shape}, expected ({self.model.n_params},)")
            return theta
        if self.prior is None:
            raise ValueError(
                "this estimator needs a prior model and the problem has none: build it with "
                "build_problem(..., prior=dynamics.prior.make_prior(...).theta) (the nominal MJCF on real "
                "data, a perturbed truth in simulation), or pass nominal=<theta>"
            )
        return self.prior


def build_problem(
    data: Dataset,
    states: States,
    model: ParameterModel,
    base: BaseParameters,
    *,
    prior: np.ndarray | None = None,
) -> Problem:
    """Stack the base regressor on the rows `states` trusts; `prior`: (p,) prior standard parameters."""
    rows = states.valid
    W = base.columns(model.regressor(states.q[rows], states.dq[rows], states.ddq[rows]))
    theta0 = None if prior is None else np.asarray(prior, dtype=float)
    return Problem(W=W, y=data.tau[rows], model=model, base=base, data=data, states=states, rows=rows, prior=theta0)


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

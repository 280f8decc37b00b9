"""Base parameters: the identifiable linear combinations of the standard parameters.

Columns of the regressor are taken in order (rigid-body body by body from the base, then effects); a
column is dependent when it lies in the span of the independent ones before it (tested on a generic
regressor of random states). Dependent parameters are regrouped into the independent ones,
beta = theta_indep + K_dep theta_dep, which gives the classical names such as `ZZ1 + 0.04*m2`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dynamics.errors import RankDeficientError
from dynamics.regressor import ParameterModel
from dynamics.sampling import independent_columns, random_states

__all__ = ["BaseParameters", "base_parameters"]


@dataclass(frozen=True)
class BaseParameters:
    """The map from a model's p parameters to its r base parameters.

    Attributes:
        independent: (r,) column indices kept (the base columns of the regressor).
        dependent: (p - r,) column indices regrouped into the kept ones.
        K: (r, p) beta = K @ theta.
        names: (r,) readable combination for each base parameter.
    """

    independent: np.ndarray
    dependent: np.ndarray
    K: np.ndarray
    names: tuple[str, ...]

    @property
    def rank(self) -> int:
        return len(self.independent)

    def project(self, theta: np.ndarray) -> np.ndarray:
        """(p,) standard parameters -> (r,) base parameters."""
        return self.K @ theta

    def columns(self, W: np.ndarray) -> np.ndarray:
        """(..., p) full regressor -> (..., r) base regressor (W_base @ beta == W @ theta)."""
        return W[..., self.independent]


def base_parameters(
    model: ParameterModel, rng: np.random.Generator, *, n_samples: int = 400, tol: float = 1e-9
) -> BaseParameters:
    """Find the base parameters of `model` from its regressor at random states.

    Args:
        model: rigid-body plant plus effect columns.
        rng: draws the random states (joint angles over their range or [-pi, pi], speeds and accelerations).
        n_samples: random states stacked.
        tol: a column is dependent when its residual, after projecting out the kept columns, is below
            tol times its norm.
    """
    W = model.regressor(*random_states(model.plant, rng, n_samples)).reshape(n_samples * model.plant.nv, -1)
    keep = independent_columns(W, zero_tol=tol, span_tol=tol * 1e3)
    if not keep:
        raise RankDeficientError(f"{model.plant.name}: the regressor is zero; nothing is identifiable")
    indep = np.array(keep)
    dep = np.array([c for c in range(W.shape[1]) if c not in set(keep)], dtype=int)
    coeff, *_ = np.linalg.lstsq(W[:, indep], W[:, dep], rcond=None)  # W_dep = W_indep @ coeff
    coeff[np.abs(coeff) < 1e-8] = 0.0  # least-squares rounding (1e-10 on an arm's ZZ), not a dependence
    K = np.zeros((len(indep), W.shape[1]))
    K[np.arange(len(indep)), indep] = 1.0
    K[:, dep] = coeff
    names = tuple(_name(model.names, K[i], indep[i]) for i in range(len(indep)))
    return BaseParameters(independent=indep, dependent=dep, K=K, names=names)


def _name(names: tuple[str, ...], row: np.ndarray, lead: int) -> str:
    terms = [names[lead]]
    for c in np.flatnonzero(row):
        if c == lead:
            continue
        k = row[c]
        sign = "-" if k < 0 else "+"
        mag = abs(k)
        terms.append(f"{sign} {names[c]}" if np.isclose(mag, 1.0, rtol=1e-9) else f"{sign} {mag:.4g}*{names[c]}")
    return " ".join(terms)

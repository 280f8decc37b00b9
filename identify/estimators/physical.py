"""Physically consistent least squares through the log-Cholesky parametrisation of each body's inertia.

A body's 10 standard parameters (mass m, first moment h, inertia I about the joint frame's origin) are
physically consistent exactly when its pseudo-inertia

    J = [[Sigma, h], [h', m]],    Sigma = tr(I)/2 * 1 - I

is positive definite (Wensing, Kim and Slotine 2017). Writing J = U U' with U upper triangular and a
positive diagonal, U = e^a [[e^d1, s12, s13, t1], [0, e^d2, s23, t2], [0, 0, e^d3, t3], [0, 0, 0, 1]]
(Rucker and Wensing 2022), every real vector (a, d, s, t) gives a consistent body and every consistent body
has such a vector. Rotor inertia and friction are kept non-negative by an exponential; offsets are free.
The fit minimises the weighted torque residual over these unconstrained variables with scipy's
least_squares (no SDP solver), plus a weak pull towards the prior model (`dynamics.prior`: the nominal MJCF
on real data, a perturbed truth in simulation, never the truth) that decides the directions the data leave
free or nearly free (parameters outside every base parameter, motions too small to excite some).
"""

from __future__ import annotations

import numpy as np
from scipy import optimize

from dynamics.base import BaseParameters
from dynamics.inertia import body_and_jacobian, log_cholesky_from_body, pseudo_inertia
from dynamics.regressor import EFFECT_COLUMNS, ParameterModel
from identify.estimators.covariance import sandwich, score
from identify.estimators.least_squares import ols
from identify.estimators.signals import torque_sigma
from identify.problem import Estimate, Problem

__all__ = ["physical"]

_SIGNED_EFFECTS = {"torque_offset"}


def _effect_signs(model: ParameterModel) -> np.ndarray:
    """(p - 10 nv,) True where an effect parameter must be non-negative (all but sensor offsets)."""
    signed = {EFFECT_COLUMNS[e][0] for e in _SIGNED_EFFECTS}
    return np.array([name.rstrip("0123456789") not in signed for name in model.names[10 * model.plant.nv :]], bool)


def _theta_and_jacobian(model: ParameterModel, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Standard parameters theta(x) (p,) and d theta / dx (p, p)."""
    nv = model.plant.nv
    p = len(x)
    theta, jac = np.empty(p), np.zeros((p, p))
    for j in range(nv):
        cut = slice(10 * j, 10 * j + 10)
        theta[cut], jac[cut, cut] = body_and_jacobian(x[cut])
    effects = x[10 * nv :].copy()
    slope = np.ones_like(effects)
    positive = _effect_signs(model)
    effects[positive] = np.exp(np.clip(effects[positive], -40.0, 40.0))
    slope[positive] = effects[positive]
    theta[10 * nv :] = effects
    idx = np.arange(10 * nv, p)
    jac[idx, idx] = slope
    return theta, jac


def _theta(model: ParameterModel, x: np.ndarray) -> np.ndarray:
    return _theta_and_jacobian(model, x)[0]


def _x(model: ParameterModel, theta: np.ndarray) -> np.ndarray:
    nv = model.plant.nv
    parts = [log_cholesky_from_body(theta[10 * j : 10 * j + 10]) for j in range(nv)]
    effects = theta[10 * nv :].copy()
    positive = _effect_signs(model)
    effects[positive] = np.log(np.maximum(effects[positive], 1e-12))
    return np.concatenate([*parts, effects])


def _fit(
    model: ParameterModel,
    base: BaseParameters,
    R: np.ndarray,
    target: np.ndarray,
    x0: np.ndarray,
    regularisation: float,
    max_nfev: int = 2000,
    x_start: np.ndarray | None = None,
) -> optimize.OptimizeResult:
    """Minimise |R (K theta(x) - target)|^2 + regularisation |x - x0|^2, from x_start (default x0)."""
    reg = np.sqrt(regularisation)
    RK = R @ base.K
    eye = reg * np.eye(len(x0))

    def residual(x: np.ndarray) -> np.ndarray:
        return np.concatenate([RK @ _theta(model, x) - R @ target, reg * (x - x0)])

    def jacobian(x: np.ndarray) -> np.ndarray:
        return np.vstack([RK @ _theta_and_jacobian(model, x)[1], eye])

    return optimize.least_squares(
        residual,
        x0 if x_start is None else x_start,
        jac=jacobian,
        method="trf",
        x_scale="jac",
        max_nfev=max_nfev,
        ftol=1e-12,
        xtol=1e-12,
    )


def _normal_root(A: np.ndarray) -> np.ndarray:
    """R with R'R = A'A, also when A'A is singular (poorly excited data)."""
    w, V = np.linalg.eigh(A.T @ A)
    return np.sqrt(np.clip(w, 0.0, None))[:, None] * V.T


def _start_and_pull(problem: Problem, target: np.ndarray, theta0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start point x and pull target x0 of the fit, from the prior `theta0` (p,).

    An effect whose prior is 0 while it must be positive (friction the prior does not know) is started at
    (and weakly pulled towards) the value the data give it, not towards zero, where its log would sit at
    -inf: friction unknown means no pull.
    """
    model, base = problem.model, problem.base
    x0 = _x(model, theta0)
    theta_data = np.array(theta0, dtype=float)
    theta_data[base.independent] = target - base.K[:, base.dependent] @ theta0[base.dependent]
    n_rb = 10 * model.plant.nv
    positive = _effect_signs(model)
    unknown = positive & (theta0[n_rb:] <= 0)
    scale = max(float(np.max(np.abs(theta_data[n_rb:]), initial=0.0)), 1e-9)
    x0[n_rb:][unknown] = np.log(np.maximum(theta_data[n_rb:][unknown], 1e-6 * scale))
    return x0.copy(), x0


def _covariance(problem: Problem, Aw: np.ndarray, resid_w: np.ndarray) -> tuple[np.ndarray, dict]:
    """HAC covariance of the unconstrained weighted fit (`target`), which the consistent estimate reports.

    Where the constraints and the prior's pull are inactive the consistent estimate is that fit, and so is
    its covariance. Where a constraint binds, the estimate is (for a vanishing pull) the projection of the
    fit, in the metric Aw'Aw, onto the consistent set, which is convex and holds the truth: the projection
    does not move it further from the truth, so the fit's covariance is conservative there, never too small.
    (A covariance linearised at the constrained estimate would shrink along the bound and the prior's pull,
    by exactly the bias it leaves out.)
    """
    r = Aw.shape[1]
    nv = problem.W.shape[1]
    bread_inv = np.linalg.inv(Aw.T @ Aw)
    g = score(Aw.reshape(-1, nv, r), resid_w.reshape(-1, nv))
    cov, info = sandwich(bread_inv, g)
    return cov, info.to_dict()


def physical(
    problem: Problem,
    *,
    regularisation: float = 1e-2,
    nominal: np.ndarray | None = None,
) -> Estimate:
    """Weighted least squares over physically consistent parameters (every pseudo-inertia positive definite).

    Args:
        problem: W and y on its rows, and its prior model (`problem.prior`).
        regularisation: weight of |x - x0|^2 (x the log-Cholesky variables, x0 the prior's), against
            residuals normalised by each joint's noise std (one sample's worth of data weighs 1).
        nominal: (p,) standard parameters to start from and pull towards instead of `problem.prior`. Never
            the MJCF truth: without a prior the estimator refuses to run.

    Returns:
        The consistent estimate; cov is the HAC covariance of the unconstrained weighted fit (equal where no constraint
        binds, conservative where one does; `diagnostics["covariance"]["shift_std"]` says how far the constraints and
        the prior moved the estimate, in stds); diagnostics hold the standard parameters `theta`, each body's smallest
        pseudo-inertia eigenvalue, and the optimiser's status.

    Raises:
        ValueError: neither `problem.prior` nor `nominal` is given.
    """
    theta0 = problem.prior_theta(nominal)
    W, y = problem.W, problem.y
    r = W.shape[2]
    start = ols(problem)
    actuated = np.asarray(problem.data.actuated, bool)
    sigma = start.sigma.copy()
    if np.any(actuated):
        sigma[~actuated] = np.maximum(sigma[~actuated], sigma[actuated].min())
    sigma = np.maximum(sigma, 1e-9 * max(float(sigma.max()), 1e-12))
    Aw = (W / sigma[None, :, None]).reshape(-1, r)
    yw = (y / sigma[None, :]).ravel()
    R = _normal_root(Aw)
    target, *_ = np.linalg.lstsq(Aw, yw, rcond=None)
    x_start, x0 = _start_and_pull(problem, target, theta0)
    result = _fit(problem.model, problem.base, R, target, x0, regularisation, x_start=x_start)
    theta = _theta(problem.model, result.x)
    beta = problem.base.K @ theta
    cov, info = _covariance(problem, Aw, yw - Aw @ target)
    info["shift_std"] = float(np.max(np.abs(beta - target) / np.sqrt(np.clip(np.diag(cov), 1e-300, None))))
    nv = problem.model.plant.nv
    eig = [float(np.linalg.eigvalsh(pseudo_inertia(theta[10 * j : 10 * j + 10]))[0]) for j in range(nv)]
    diagnostics = {
        "theta": theta,
        "min_pseudo_inertia_eig": eig,
        "status": int(result.status),
        "nfev": result.nfev,
        "covariance": info,
    }
    return Estimate("physical", problem.names, beta, cov, torque_sigma(problem, beta), diagnostics)

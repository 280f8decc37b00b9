"""Ordinary and weighted least squares with parameter covariance.

Both report the HAC sandwich (`covariance.sandwich`): (W'VW)^-1 M (W'VW)^-1 with V the per-joint weights that
produced the estimate and M the long-run variance of the score sum_j W_kj' v_j e_kj, so that the std stays
right when the joints' noise levels differ, when they move together, and when the residuals are correlated
in time (band-limited sensor noise, states from filtered positions). WLS weights each joint's rows by
1/sigma_j^2 (sigma_j from the residuals of the previous solve, iterated); for white Gaussian torque noise its
covariance tends to (W' S^-1 W)^-1, the Cramer-Rao bound.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from dynamics.errors import RankDeficientError
from identify.estimators.covariance import sandwich, score
from identify.problem import Estimate, Problem

__all__ = ["ols", "safe_sigma", "wls"]


def _solve(W: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted least squares: W (N, nv, r), y (N, nv), row weights w (nv,)."""
    sw = np.sqrt(w)
    A = (W * sw[None, :, None]).reshape(-1, W.shape[2])
    b = (y * sw[None, :]).ravel()
    # normal equations of the column-scaled matrix, refined twice (as accurate as QR while cond(A) << 1e8):
    # lstsq's SVD of the tall (N nv, r) matrix costs twenty times more for the same answer
    norms = np.linalg.norm(A, axis=0)
    scale = np.where(norms > 0, norms, 1.0)
    As = A / scale
    G = np.einsum("kr,ks->rs", As, As)
    w_min, w_max = np.linalg.eigvalsh(G)[[0, -1]]
    rank = W.shape[2] if w_max > 0 and w_min > w_max * 1e-14 else W.shape[2] - 1
    if rank == W.shape[2]:
        factor = cho_factor(G)
        beta = cho_solve(factor, As.T @ b)
        for _ in range(2):
            beta = beta + cho_solve(factor, As.T @ (b - As @ beta))
        beta = beta / scale
    if rank < W.shape[2]:
        raise RankDeficientError(
            "the base regressor is rank deficient on these data (cond(X'X) of its scaled columns > 1e14); "
            "the excitation does not excite every base parameter"
        )
    return beta


def _joint_sigma(W: np.ndarray, y: np.ndarray, beta: np.ndarray) -> np.ndarray:
    resid = y - np.einsum("knr,r->kn", W, beta)
    dof = max(W.shape[0] - W.shape[2] / W.shape[1], 1.0)
    return np.sqrt(np.sum(resid**2, axis=0) / dof)


def safe_sigma(sigma: np.ndarray, actuated: np.ndarray) -> np.ndarray:
    """Per-joint noise levels safe to weight by.

    An unactuated joint's equation (0 = W_j beta) is homogeneous: its residual comes from errors in the
    regressor and shrinks with |beta|, so weighting it by its own residual pulls the estimate towards zero.
    Such rows get at most the weight of the best actuated joint. Exact rows (noise-free data) are floored
    so that the weights stay finite.
    """
    out = sigma.copy()
    if np.any(actuated) and not np.all(actuated):
        out[~actuated] = np.maximum(out[~actuated], out[actuated].min())
    return np.maximum(out, 1e-6 * max(float(out.max()), 1e-300))


def _covariance(W: np.ndarray, y: np.ndarray, beta: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, dict]:
    """HAC covariance of the fit that used per-joint weights `weight` (nv,) and gave `beta`."""
    bread_inv = np.linalg.inv(np.einsum("knr,n,kns->rs", W, weight, W))
    resid = y - np.einsum("knr,r->kn", W, beta)
    cov, info = sandwich(bread_inv, score(W, resid, weight))
    return cov, info.to_dict()


def ols(problem: Problem) -> Estimate:
    """Ordinary least squares over all rows, with the HAC sandwich covariance."""
    W, y = problem.W, problem.y
    ones = np.ones(W.shape[1])
    beta = _solve(W, y, ones)
    cov, info = _covariance(W, y, beta, ones)
    return Estimate("ols", problem.names, beta, cov, _joint_sigma(W, y, beta), {"covariance": info})


def wls(problem: Problem, *, iterations: int = 3) -> Estimate:
    """Weighted least squares with per-joint weights 1/sigma_j^2 re-estimated from the residuals.

    The covariance uses the weights the last solve used (those that produced the estimate), not the noise
    levels re-estimated after it.
    """
    if iterations < 1:
        raise ValueError(f"wls needs iterations >= 1, got {iterations}")
    W, y = problem.W, problem.y
    actuated = np.asarray(problem.data.actuated, dtype=bool)
    sigma = safe_sigma(_joint_sigma(W, y, _solve(W, y, np.ones(W.shape[1]))), actuated)
    for _ in range(iterations):
        weight = 1.0 / sigma**2
        beta = _solve(W, y, weight)
        sigma = safe_sigma(_joint_sigma(W, y, beta), actuated)
    cov, info = _covariance(W, y, beta, weight)
    return Estimate("wls", problem.names, beta, cov, sigma, {"iterations": iterations, "covariance": info})

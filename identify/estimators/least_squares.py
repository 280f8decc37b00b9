"""Ordinary and weighted least squares with parameter covariance.

OLS's covariance is the sandwich (W'W)^-1 W' S W (W'W)^-1 with S the per-joint residual variance, which stays
right when the joints' noise levels differ. WLS weights each joint's rows by 1/sigma_j^2 (sigma_j from the
OLS residuals, iterated), so its covariance is (W' S^-1 W)^-1: the Cramer-Rao bound for Gaussian torque noise.
"""

from __future__ import annotations

import numpy as np

from envs.errors import RankDeficientError
from identify.problem import Estimate, Problem

__all__ = ["ols", "wls"]


def _solve(W: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted least squares: W (N, nv, r), y (N, nv), row weights w (nv,)."""
    sw = np.sqrt(w)
    A = (W * sw[None, :, None]).reshape(-1, W.shape[2])
    b = (y * sw[None, :]).ravel()
    beta, _, rank, sv = np.linalg.lstsq(A, b, rcond=None)
    if rank < W.shape[2]:
        raise RankDeficientError(
            f"the base regressor has rank {rank} < {W.shape[2]} on these data (condition {sv[0] / sv[-1]:.3g}); "
            "the excitation does not excite every base parameter"
        )
    return beta


def _joint_sigma(W: np.ndarray, y: np.ndarray, beta: np.ndarray) -> np.ndarray:
    resid = y - np.einsum("knr,r->kn", W, beta)
    dof = max(W.shape[0] - W.shape[2] / W.shape[1], 1.0)
    return np.sqrt(np.sum(resid**2, axis=0) / dof)


def _floor(sigma: np.ndarray) -> np.ndarray:
    # a joint whose equation is exact (unactuated, noise-free) would get infinite weight
    return np.maximum(sigma, 1e-9 * max(float(sigma.max()), 1e-12) + 1e-15)


def ols(problem: Problem) -> Estimate:
    """Ordinary least squares over all rows, with the joint-heteroscedastic sandwich covariance."""
    W, y = problem.W, problem.y
    beta = _solve(W, y, np.ones(W.shape[1]))
    sigma = _joint_sigma(W, y, beta)
    A = W.reshape(-1, W.shape[2])
    bread = np.linalg.inv(A.T @ A)
    meat = np.einsum("knr,n,kns->rs", W, sigma**2, W)
    return Estimate("ols", problem.names, beta, bread @ meat @ bread, sigma)


def wls(problem: Problem, *, iterations: int = 3) -> Estimate:
    """Weighted least squares with per-joint weights 1/sigma_j^2 re-estimated from the residuals."""
    W, y = problem.W, problem.y
    sigma = _floor(_joint_sigma(W, y, _solve(W, y, np.ones(W.shape[1]))))
    for _ in range(iterations):
        beta = _solve(W, y, 1.0 / sigma**2)
        sigma = _floor(_joint_sigma(W, y, beta))
    info = np.einsum("knr,n,kns->rs", W, 1.0 / sigma**2, W)
    return Estimate("wls", problem.names, beta, np.linalg.inv(info), sigma, {"iterations": iterations})

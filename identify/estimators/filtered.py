"""Least squares on the filtered, acceleration-free model (the thesis's sections 2.3 and 5.1.1).

Both sides of the dynamics are filtered by omega / (s + omega) (see `signals.filtered_model`), which needs
joint angles and speeds but never the acceleration; the filtered equations are then solved in one batch.
The filtered noise is coloured (correlated over about 1/omega), so the covariance is a sandwich whose middle
term sums the score over blocks several correlation times long (batch means).
"""

from __future__ import annotations

import numpy as np

from dynamics.errors import RankDeficientError
from identify.estimators.signals import filtered_model, torque_sigma
from identify.problem import Estimate, Problem

__all__ = ["batch_means_cov", "filtered"]


def batch_means_cov(psi: np.ndarray, resid: np.ndarray, *, block: int) -> np.ndarray:
    """Sandwich covariance of a least-squares fit with serially correlated residuals.

    Args:
        psi: (n, nv, r) regressor rows.
        resid: (n, nv) residuals.
        block: samples per block; blocks should be longer than the residuals' correlation time.

    Returns:
        (r, r) (psi' psi)^-1 (sum_b g_b g_b') (psi' psi)^-1 with g_b the block sums of psi' resid.
    """
    A = psi.reshape(-1, psi.shape[2])
    bread = np.linalg.inv(A.T @ A)
    score = np.einsum("knr,kn->kr", psi, resid)
    n_blocks = max(len(score) // block, 1)
    sums = np.add.reduceat(score[: n_blocks * block], np.arange(0, n_blocks * block, block), axis=0)
    return bread @ (sums.T @ sums) @ bread


def filtered(problem: Problem, *, omega: float = 20.0, settle_s: float | None = None) -> Estimate:
    """Batch least squares on F tau = psi beta, F = omega / (s + omega).

    Args:
        problem: uses q, dq (states) and the measured torque on its contiguous span; not W, not ddq.
        omega: filter corner [rad/s] (the thesis uses 10-20); above the excitation's bandwidth.
        settle_s: filter start-up discarded [s] (default 3 / omega).
    """
    fm = filtered_model(problem, omega=omega, settle_s=settle_s)
    psi, y = fm.psi[fm.settled], fm.y[fm.settled]
    A = psi.reshape(-1, psi.shape[2])
    beta, _, rank, _ = np.linalg.lstsq(A, y.ravel(), rcond=None)
    if rank < A.shape[1]:
        raise RankDeficientError(f"the filtered regressor has rank {rank} < {A.shape[1]}: poorly excited data")
    resid = y - np.einsum("knr,r->kn", psi, beta)
    dt = float(np.median(np.diff(fm.time)))
    cov = batch_means_cov(psi, resid, block=int(np.ceil(5.0 / (omega * dt))))
    diagnostics = {"omega": omega, "samples": int(len(psi)), "filtered_residual_std": resid.std(axis=0).tolist()}
    return Estimate("filtered", problem.names, beta, cov, torque_sigma(problem, beta), diagnostics)

"""Least squares on the filtered, acceleration-free model (the thesis's sections 2.3 and 5.1.1).

Both sides of the dynamics are filtered by omega / (s + omega) (see `signals.filtered_model`), which needs
joint angles and speeds but never the acceleration; the filtered equations are then solved in one batch.
The filtered noise is coloured (correlated over about 1/omega), so the covariance is the HAC sandwich of
`covariance.sandwich`, whose lag follows the residuals' measured autocorrelation.
"""

from __future__ import annotations

import numpy as np

from dynamics.errors import RankDeficientError
from identify.estimators.covariance import sandwich, score
from identify.estimators.signals import filtered_model, torque_sigma
from identify.problem import Estimate, Problem

__all__ = ["converged_cov", "filtered", "filtered_cov", "filtered_lstsq"]


def filtered_cov(psi: np.ndarray, resid: np.ndarray) -> tuple[np.ndarray, dict]:
    """HAC sandwich covariance of a least-squares fit of the filtered model.

    Args:
        psi: (n, nv, r) filtered regressor rows (settled samples).
        resid: (n, nv) residuals at the estimate.

    Returns:
        (r, r) (psi' psi)^-1 M (psi' psi)^-1, M the HAC long-run variance of psi' resid with the lag read
        from its autocorrelation (the filter makes the residuals correlated over about 1/omega), and how it
        was computed.
    """
    A = psi.reshape(-1, psi.shape[2])
    cov, info = sandwich(np.linalg.inv(A.T @ A), score(psi, resid))
    return cov, info.to_dict()


def converged_cov(
    psi: np.ndarray, y: np.ndarray, beta: np.ndarray, *, max_offset_std: float = 0.25
) -> tuple[np.ndarray | None, dict]:
    """Covariance of a recursive estimate that should have settled on the filtered least-squares solution.

    The recursive estimators (`rls`, `gradient`) converge to the batch solution of the same filtered model;
    only then is that solution's HAC covariance theirs. When `beta` is further than `max_offset_std` of the
    batch solution's own std from it in any parameter, the estimate has not converged and no covariance is
    reported (None), with the offset as the reason.

    Args:
        psi: (n, nv, r) filtered regressor (settled rows); y: (n, nv) filtered torque.
        beta: (r,) the recursive estimate.

    Returns:
        The covariance (or None) and how it was computed, with `offset_std` = max |beta - beta_ls| / std.
    """
    batch = filtered_lstsq(psi, y)
    cov, info = filtered_cov(psi, y - np.einsum("knr,r->kn", psi, batch))
    std = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    offset = float(np.max(np.abs(beta - batch) / std))
    info["offset_std"] = offset
    if not offset <= max_offset_std:
        info["method"] = "none"
        info["reason"] = (
            f"not converged: {offset:.2g} std from the filtered least-squares solution it tends to "
            f"(> {max_offset_std}); more data or passes, or use `filtered`"
        )
        return None, info
    return cov, info


def filtered_lstsq(psi: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(r,) least-squares solution of psi beta = y over all rows (psi (n, nv, r), y (n, nv)).

    Raises:
        RankDeficientError: the filtered regressor does not excite every base parameter.
    """
    A = psi.reshape(-1, psi.shape[2])
    beta, _, rank, _ = np.linalg.lstsq(A, y.ravel(), rcond=None)
    if rank < A.shape[1]:
        raise RankDeficientError(f"the filtered regressor has rank {rank} < {A.shape[1]}: poorly excited data")
    return beta


def filtered(problem: Problem, *, omega: float = 20.0, settle_s: float | None = None) -> Estimate:
    """Batch least squares on F tau = psi beta, F = omega / (s + omega).

    Args:
        problem: uses q, dq (states) and the measured torque on its contiguous span; not W, not ddq.
        omega: filter corner [rad/s] (the thesis uses 10-20); above the excitation's bandwidth.
        settle_s: filter start-up discarded [s] (default 3 / omega).
    """
    fm = filtered_model(problem, omega=omega, settle_s=settle_s)
    psi, y = fm.psi[fm.settled], fm.y[fm.settled]
    beta = filtered_lstsq(psi, y)
    resid = y - np.einsum("knr,r->kn", psi, beta)
    cov, info = filtered_cov(psi, resid)
    diagnostics = {
        "omega": omega,
        "samples": int(len(psi)),
        "filtered_residual_std": resid.std(axis=0).tolist(),
        "covariance": info,
    }
    return Estimate("filtered", problem.names, beta, cov, torque_sigma(problem, beta), diagnostics)

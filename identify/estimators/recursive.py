"""The thesis's unnormalised least squares (section 2.3, eq. 2.28-2.29), discretised, on the filtered model.

    d beta / dt = alpha P psi' e,      dP / dt = -alpha P psi' psi P,      e = F tau - psi beta

Over one sample of length dt with psi frozen, the exact update is recursive least squares with measurement
weight alpha dt (the information P^-1 grows by alpha dt psi' psi), written with the matrix-inversion lemma so
that P stays symmetric positive definite:

    S = I / (alpha dt) + psi P psi',   K = P psi' S^-1,   beta += K e,   P -= K psi P

The estimate's trajectory over time is kept in `diagnostics["history"]` (the thesis's convergence plots).
"""

from __future__ import annotations

import numpy as np

from identify.estimators.filtered import converged_cov
from identify.estimators.signals import filtered_model, torque_sigma
from identify.problem import Estimate, Problem

__all__ = ["history_indices", "rls"]


def history_indices(n: int, points: int) -> np.ndarray:
    """(<= points,) sample indices, evenly spread, that the convergence history keeps (the last included)."""
    return np.unique(np.linspace(0, n - 1, max(min(points, n), 2)).round().astype(int))


def rls(
    problem: Problem,
    *,
    omega: float = 20.0,
    alpha: float = 1.0,
    p0: float = 1e6,
    history_points: int = 300,
) -> Estimate:
    """Unnormalised (continuous-time) least squares on the filtered model, one sample at a time.

    Args:
        problem: uses q, dq (states) and the measured torque on its contiguous span.
        omega: corner of the omega / (s + omega) filter [rad/s].
        alpha: the adaptation gain of eq. 2.28 [1/s]; with the exact discretisation it only scales P.
        p0: P(0) = p0 diag(1 / mean psi_c^2): the prior's strength, relative to one second of data.
        history_points: how many snapshots of (time, beta, min eig P) the history keeps.

    Returns:
        The estimate at the end of the data, with the HAC covariance of the batch filtered fit it converges
        to (None, with the reason in `diagnostics["covariance"]`, when it is not there yet; P itself, in
        `diagnostics["P"]`, is the covariance only for white equation errors, which filtering does not leave);
        `diagnostics["history"]` = {"time": (T,), "beta": (T, r), "min_eig_P": (T,)}.
    """
    fm = filtered_model(problem, omega=omega, settle_s=0.0)
    psi, y, time = fm.psi, fm.y, fm.time
    n, nv, r = psi.shape
    dt = float(np.median(np.diff(time)))
    scale = np.mean(psi**2, axis=(0, 1))
    P = p0 * np.diag(1.0 / np.where(scale > 0, scale, 1.0))
    beta = np.zeros(r)
    keep = history_indices(n, history_points)
    hist_beta, hist_eig = np.empty((len(keep), r)), np.empty(len(keep))
    noise = np.eye(nv) / (alpha * dt)
    h = 0
    for k in range(n):
        pk = psi[k]
        Ppt = P @ pk.T
        gain = np.linalg.solve(noise + pk @ Ppt, Ppt.T).T
        beta = beta + gain @ (y[k] - pk @ beta)
        P = P - gain @ Ppt.T
        P = 0.5 * (P + P.T)
        if h < len(keep) and k == keep[h]:
            hist_beta[h], hist_eig[h] = beta, np.linalg.eigvalsh(P)[0]
            h += 1
    cov, info = converged_cov(psi[fm.settled], y[fm.settled], beta)
    history = {"time": time[keep], "beta": hist_beta, "min_eig_P": hist_eig}
    diagnostics = {"omega": omega, "alpha": alpha, "p0": p0, "P": P, "history": history, "covariance": info}
    return Estimate("rls", problem.names, beta, cov, torque_sigma(problem, beta), diagnostics)

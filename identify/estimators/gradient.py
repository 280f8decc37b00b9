"""The thesis's unnormalised gradient estimator (section 2.2, eq. 2.13), discretised, on the filtered model.

    d beta / dt = Gamma psi' e,     e = F tau - psi beta

Lemma 1 of the thesis holds for any constant symmetric positive definite gain Gamma (take V = e' Gamma^-1 e);
here Gamma = h diag(1 / mean psi_c^2), so that one gain h [1/s] suits parameters of every unit. Explicit Euler
over each sample is stable while h dt psi Gamma psi' < 2, but a constant gain leaves the estimate hovering
around the least-squares solution, off by an amount that grows with h; the default h, 1/80 of the stability
bound, keeps that below 1 % on noise-free data. Convergence along a direction of small excitation is slow
(rate h times its eigenvalue), so the data are replayed for several `epochs` (the periodic excitation makes
this a longer experiment).
"""

from __future__ import annotations

import numpy as np

from identify.estimators.filtered import converged_cov
from identify.estimators.recursive import history_indices
from identify.estimators.signals import filtered_model, torque_sigma
from identify.problem import Estimate, Problem

__all__ = ["gradient"]


def gradient(
    problem: Problem,
    *,
    omega: float = 20.0,
    gain: float | None = None,
    epochs: int = 20,
    average: bool = True,
    anneal: bool = True,
    history_points: int = 300,
) -> Estimate:
    """Unnormalised gradient adaptation on the filtered model, one sample at a time.

    Args:
        problem: uses q, dq (states) and the measured torque on its contiguous span.
        omega: corner of the omega / (s + omega) filter [rad/s].
        gain: h [1/s]; None: 0.025 / (dt max_k trace(psi_k Gamma_1 psi_k')), 1/80 of the stability bound.
        epochs: passes over the data (the history's time runs on across passes).
        average: return the mean of the estimate over the last pass (Polyak-Ruppert averaging), which
            removes the fluctuation a constant gain leaves along the excitation's period; False returns the
            last value, as the continuous-time law would.
        anneal: over the second half of the passes let the gain fall as 1/t (stochastic approximation),
            so that the estimate settles on the least-squares solution instead of hovering near it.
        history_points: snapshots of (time, beta) the history keeps.

    Returns:
        The estimate, with the HAC covariance of the filtered least-squares fit it settles on (as
        `filtered`), or None (reason in `diagnostics["covariance"]`) when it has not settled there;
        `diagnostics["history"]` = {"time": (T,), "beta": (T, r)}.
    """
    if epochs < 1:
        raise ValueError(f"epochs must be >= 1, got {epochs}")
    fm = filtered_model(problem, omega=omega, settle_s=0.0)
    psi, y = fm.psi, fm.y
    n, _, r = psi.shape
    dt = float(np.median(np.diff(fm.time)))
    scale = np.mean(psi**2, axis=(0, 1))
    unit = 1.0 / np.where(scale > 0, scale, 1.0)
    if gain is None:
        gain = 0.025 / (dt * float(np.max(np.einsum("knr,r,knr->k", psi, unit, psi))))
    step = gain * dt * unit
    total = n * epochs
    keep = history_indices(total, history_points)
    hist = np.empty((len(keep), r))
    beta = np.zeros(r)
    mean = np.zeros(r)
    h = 0
    anneal_from = max(total // 2, 1) if anneal else total
    for i in range(total):
        k = i % n
        decay = anneal_from / i if i > anneal_from else 1.0
        beta = beta + (decay * step) * (psi[k].T @ (y[k] - psi[k] @ beta))
        if i >= total - n:
            mean += beta / n
        if h < len(keep) and i == keep[h]:
            hist[h] = beta
            h += 1
    if average:
        beta = mean
    history = {"time": fm.time[0] + keep * dt, "beta": hist}
    diagnostics = {"omega": omega, "gain": gain, "epochs": epochs, "history": history}
    cov, diagnostics["covariance"] = converged_cov(psi[fm.settled], y[fm.settled], beta)
    return Estimate("gradient", problem.names, beta, cov, torque_sigma(problem, beta), diagnostics)

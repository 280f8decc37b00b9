"""The power / energy model (no acceleration): work done by the joint torques equals the energy gained.

Over a window [t_a, t_b]:   int tau' dq dt = H(t_b) - H(t_a) + int (dissipated power) dt

with H = T + U the rigid body's kinetic and potential energy (Pinocchio's energy regressors) plus the
rotor's 1/2 Ia dq^2, and the dissipated power sum_j dq_j E_j beta of the friction and offset columns. Each
window gives one scalar equation, linear in the base parameters, needing only q and dq. The windows do not
overlap, so white torque noise leaves the equations independent; states from filtered positions (and
band-limited sensor noise) correlate neighbouring samples, which the HAC sandwich (`covariance.sandwich`)
accounts for. Its score is taken per sample, on the increments of the energy balance that sum to each
window's residual, not per window: the long-run variance is then read from thousands of increments.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from scipy import integrate

from dynamics.errors import RankDeficientError
from identify.estimators.covariance import sandwich
from identify.estimators.signals import span, torque_sigma
from identify.problem import Estimate, Problem

__all__ = ["energy", "energy_regressor"]


def energy_regressor(problem: Problem) -> tuple[np.ndarray, np.ndarray]:
    """Energy and dissipated-power regressors of the base parameters on the problem's span.

    Returns:
        H: (n, r) with H beta the stored energy [J] (up to a constant).
        D: (n, r) with D beta the power not stored (friction, offsets) [W].
    """
    rows = span(problem)
    q, dq = problem.states.q[rows], problem.states.dq[rows]
    model = problem.model
    pm = model.plant.pin_model
    data = pm.createData()
    p, n_rb = model.n_params, 10 * model.plant.nv
    H = np.zeros((len(q), p))
    for k in range(len(q)):
        H[k, :n_rb] = pin.computeKineticEnergyRegressor(pm, data, q[k], dq[k]) + pin.computePotentialEnergyRegressor(
            pm, data, q[k]
        )
    effects = model.regressor(q, dq, np.zeros_like(dq))[:, :, n_rb:]  # (n, nv, p - n_rb)
    power = np.einsum("kn,knc->kc", dq, effects)
    D = np.zeros((len(q), p))
    D[:, n_rb:] = power
    # the rotor's kinetic energy 1/2 Ia dq^2: the effect columns that multiply ddq (zero in `power` above)
    zero = np.zeros_like(dq)
    inertial = (model.regressor(q, zero, dq) - model.regressor(q, zero, zero))[:, :, n_rb:]
    H[:, n_rb:] = 0.5 * np.einsum("kn,knc->kc", dq, inertial)
    return problem.base.columns(H), problem.base.columns(D)


def energy(problem: Problem, *, window_s: float = 0.1) -> Estimate:
    """Least squares on the work-energy balance over consecutive windows.

    Args:
        problem: uses q, dq (states) and the measured torque on its contiguous span; not ddq.
        window_s: window length [s]: shorter gives more equations, each with less signal.
    """
    rows = span(problem)
    t = problem.data.time[rows]
    dq, tau = problem.states.dq[rows], problem.data.tau[rows]
    H, D = energy_regressor(problem)
    step = max(int(round(window_s / float(np.median(np.diff(t))))), 1)
    edges = np.arange(0, len(t), step)
    if len(edges) < H.shape[1] + 2:
        raise RankDeficientError(f"{len(edges) - 1} energy windows of {window_s} s for {H.shape[1]} parameters")
    work = integrate.cumulative_trapezoid(np.sum(tau * dq, axis=1), t, initial=0.0)
    lost = integrate.cumulative_trapezoid(D, t, axis=0, initial=0.0)
    A = np.diff(H[edges] + lost[edges], axis=0)
    y = np.diff(work[edges])
    beta, _, rank, _ = np.linalg.lstsq(A, y, rcond=None)
    if rank < A.shape[1]:
        raise RankDeficientError(f"the energy regressor has rank {rank} < {A.shape[1]}: poorly excited data")
    resid = y - A @ beta
    # the window residuals are sums of the energy balance's per-sample increments: the score of window i,
    # A_i e_i, is the sum over its samples of A_i dr_k. The HAC over those samples reads the noise's own
    # correlation (tens of samples) from thousands of increments instead of a few hundred window sums
    # (whose long-run variance estimate varied by 20-30 % from record to record)
    balance = work - (H + lost) @ beta
    increments = np.diff(balance[edges[0] : edges[-1] + 1])
    window_of = np.arange(len(increments)) // step
    cov, info = sandwich(np.linalg.inv(A.T @ A), A[window_of] * increments[:, None])
    diagnostics = {
        "window_s": window_s,
        "windows": len(y),
        "energy_residual_std": float(resid.std()),
        "covariance": info.to_dict(),
    }
    return Estimate("energy", problem.names, beta, cov, torque_sigma(problem, beta), diagnostics)

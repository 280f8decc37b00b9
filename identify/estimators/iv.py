"""IDIM-IV: instrumental variables from simulating the identified model (Janot, Vandanjon and Gautier).

The regressor W is built from states filtered out of noisy positions, so its errors are correlated with
themselves (errors in variables: least squares is biased once the noise passes the filter). The instruments
Z are the same regressor evaluated along a simulation of the model identified so far, driven in closed loop
along a smooth reference drawn from the measured angles: Z carries no measurement noise, yet stays close to
W. The estimate beta = (Z'W)^-1 Z'y is repeated with the new model until it settles.

Simulating needs the full standard parameters: the independent ones follow from beta, the dependent ones
(not identifiable, and without effect on the dynamics) keep the prior model's values (`standard_from_base`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pinocchio as pin

from dynamics.base import BaseParameters
from dynamics.errors import RankDeficientError
from dynamics.regressor import EFFECT_COLUMNS, ParameterModel
from identify.derivatives import derive_states
from identify.estimators.covariance import sandwich, score
from identify.estimators.least_squares import ols
from identify.estimators.signals import span, torque_sigma
from identify.problem import Estimate, Problem

__all__ = ["iv", "simulate_model", "standard_from_base"]


def standard_from_base(base: BaseParameters, beta: np.ndarray, nominal: np.ndarray) -> np.ndarray:
    """(p,) standard parameters theta with K theta = beta: dependent ones nominal, independent ones solved."""
    theta = np.array(nominal, dtype=float)
    theta[base.independent] = beta - base.K[:, base.dependent] @ nominal[base.dependent]
    return theta


def _pin_model(model: ParameterModel, theta: np.ndarray) -> pin.Model:
    pm = model.plant.pin_model.copy()
    for j in range(model.plant.nv):
        pm.inertias[j + 1] = pin.Inertia.FromDynamicParameters(theta[10 * j : 10 * j + 10])
    pm.armature[:] = 0.0
    symbol = EFFECT_COLUMNS["armature"][0]
    for j in range(model.plant.nv):
        if f"{symbol}{j + 1}" in model.names:
            pm.armature[j] = theta[model.names.index(f"{symbol}{j + 1}")]
    return pm


def simulate_model(
    model: ParameterModel,
    theta: np.ndarray,
    reference: tuple[np.ndarray, np.ndarray, np.ndarray],
    *,
    dt: float,
    bandwidth_hz: float = 4.0,
    substeps: int = 2,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Track `reference` with the model of standard parameters `theta` (Pinocchio, semi-implicit Euler).

    The controller is like the harness's: feedforward from the model's own inverse dynamics along the reference
    plus PD feedback at `bandwidth_hz`, held over each sample, its gains from the mass matrix's diagonal at the
    first pose (the harness shapes them by the whole matrix along the reference); a simulation that leaves its
    reference is not used as an instrument (`_tracks`).

    Args:
        model: the parameter model (rigid body, armature, friction and offset columns).
        theta: (p,) its standard parameters.
        reference: q, dq, ddq, each (n, nv), on a grid of interval dt.
        dt: sample interval [s].

    Returns:
        q, dq, ddq: (n, nv) simulated states at the sample times (NaN after a divergence).
    """
    qr, dqr, ddqr = reference
    n_rb = 10 * model.plant.nv
    full = model.regressor(qr, dqr, ddqr)
    tau_ff = full @ theta
    pm = _pin_model(model, theta)
    data = pm.createData()
    m_diag = np.diag(pin.crba(pm, data, qr[0])).copy()
    w = 2 * np.pi * bandwidth_hz
    kp, kd = m_diag * w**2, 2 * w * m_diag
    phi = theta[n_rb:]
    # friction and offsets act at zero acceleration; the rotor inertia (armature) is in the Pinocchio model
    has_effects = any(e != "armature" for e in model.effects) and bool(np.any(phi))
    h = dt / substeps
    n, nv = qr.shape
    q, dq = qr[0].copy(), dqr[0].copy()
    out = np.empty((3, n, nv))
    zero = np.zeros((1, nv))
    for k in range(n):
        tau = tau_ff[k] + kp * (qr[k] - q) + kd * (dqr[k] - dq)
        for s in range(substeps):
            drive = tau
            if has_effects:  # friction and offsets: the effect columns at zero acceleration
                drive = tau - model.regressor(q[None], dq[None], zero)[0, :, n_rb:] @ phi
            ddq = pin.aba(pm, data, q, dq, drive)
            if s == 0:
                out[:, k] = q, dq, ddq
            dq = dq + h * ddq
            q = q + h * dq
        if not np.all(np.abs(q - qr[k]) < 1e3):  # diverged (or NaN): the rest is undefined
            out[:, k + 1 :] = np.nan
            break
    return out[0], out[1], out[2]


def _tracks(q: np.ndarray, q_ref: np.ndarray, *, tol_rad: float = 0.05) -> bool:
    """Whether a simulation stayed finite and within tol_rad of its reference throughout."""
    return bool(np.all(np.isfinite(q)) and np.max(np.abs(q - q_ref)) <= tol_rad)


def _reference(problem: Problem, cutoff_hz: float | None, period_s: float | None) -> Any:
    # None: twice the excitation's bandwidth, within what the method allows (the differences' limit without a period)
    options = {"cutoff_hz": cutoff_hz, "cutoff_factor": 2.0}
    if period_s is not None:
        return derive_states(problem.data, "spectral", period_s=period_s, **options)
    return derive_states(problem.data, "butterworth", **options)


def iv(
    problem: Problem,
    *,
    iterations: int = 3,
    tol: float = 1e-4,
    bandwidth_hz: float = 4.0,
    reference_cutoff_hz: float | None = None,
    period_s: float | None = None,
    substeps: int = 2,
) -> Estimate:
    """Instrumental-variable estimate with instruments from simulating the previous estimate.

    Args:
        problem: W and y on its rows; its data's q give the reference.
        iterations: most simulate-and-solve rounds after the OLS start.
        tol: stop once |beta_new - beta| <= tol |beta| (well below the estimate's own relative spread).
        bandwidth_hz: PD bandwidth of the simulated closed loop.
        reference_cutoff_hz: low-pass of the reference (None: twice the excitation's bandwidth).
        period_s: the excitation's period: the reference keeps only its harmonics (spectral); None filters.
        substeps: integration steps per sample.

    Returns:
        The estimate with the IV sandwich covariance (Z'W)^-1 M (W'Z)^-1, M the HAC long-run variance of the score sum_j
        Z_kj' e_kj (`covariance.sandwich`); diagnostics: iterations run, the relative change of each, where each round's
        instruments came from ("simulation", or "reference" when the estimate's simulation diverged), and the
        instruments' correlation with W.
    """
    W, y = problem.W, problem.y
    r = W.shape[2]
    A = W.reshape(-1, r)
    ref = _reference(problem, reference_cutoff_hz, period_s)
    rows = span(problem)
    sel = problem.rows[rows]
    reference = (ref.q[rows], ref.dq[rows], ref.ddq[rows])
    # the dependent parameters do not change the simulated dynamics (only K theta = beta does), so they carry
    # no information about the answer; they come from the prior model where there is one
    nominal = problem.prior if problem.prior is not None else problem.model.truth()
    beta = ols(problem).beta
    changes: list[float] = []
    sources: list[str] = []
    Z = W
    for _ in range(iterations):
        theta = standard_from_base(problem.base, beta, nominal)
        with np.errstate(all="ignore"):
            q, dq, ddq = simulate_model(
                problem.model, theta, reference, dt=problem.data.dt, bandwidth_hz=bandwidth_hz, substeps=substeps
            )
        if _tracks(q, reference[0]):
            sources.append("simulation")
        else:
            # the estimate is not a stable, physical model (an inertia gone negative): its simulation tells
            # nothing; the smooth reference itself is noise-free and serves as the instruments
            q, dq, ddq = reference
            sources.append("reference")
        Z = problem.base.columns(problem.model.regressor(q[sel], dq[sel], ddq[sel]))
        Zf = Z.reshape(-1, r)
        ZtW = Zf.T @ A
        if np.linalg.matrix_rank(ZtW) < r:
            raise RankDeficientError("the instruments do not excite every base parameter (Z'W is singular)")
        new = np.linalg.solve(ZtW, Zf.T @ y.ravel())
        changes.append(float(np.linalg.norm(new - beta)) / max(float(np.linalg.norm(beta)), 1e-300))
        beta = new
        if changes[-1] <= tol:
            break
    sigma = torque_sigma(problem, beta)
    Zf = Z.reshape(-1, r)
    resid = y - np.einsum("knr,r->kn", W, beta)
    cov, info = sandwich(np.linalg.inv(Zf.T @ A), score(Z, resid))
    corr = float(np.sum(Zf * A) / (np.linalg.norm(Zf) * np.linalg.norm(A)))
    diagnostics = {
        "iterations": len(changes),
        "relative_change": changes,
        "instruments": sources,
        "instrument_correlation": corr,
        "covariance": info.to_dict(),
    }
    return Estimate("iv", problem.names, beta, cov, sigma, diagnostics)

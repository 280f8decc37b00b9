"""Physically consistent least squares through the log-Cholesky parametrisation of each body's inertia.

A body's 10 standard parameters (mass m, first moment h, inertia I about the joint frame's origin) are
physically consistent exactly when its pseudo-inertia

    J = [[Sigma, h], [h', m]],    Sigma = tr(I)/2 * 1 - I

is positive definite (Wensing, Kim and Slotine 2017). Writing J = U U' with U upper triangular and a
positive diagonal, U = e^a [[e^d1, s12, s13, t1], [0, e^d2, s23, t2], [0, 0, e^d3, t3], [0, 0, 0, 1]]
(Rucker and Wensing 2022), every real vector (a, d, s, t) gives a consistent body and every consistent body
has such a vector. Rotor inertia and friction are kept non-negative by an exponential; offsets are free.
The fit minimises the weighted torque residual over these unconstrained variables with scipy's
least_squares (no SDP solver), plus a weak pull towards the nominal model that decides the directions the
data leave free or nearly free (parameters outside every base parameter, motions too small to excite some).
"""

from __future__ import annotations

import numpy as np
from scipy import optimize

from identify.base import BaseParameters
from identify.estimators.least_squares import ols
from identify.estimators.signals import torque_sigma
from identify.model import EFFECT_COLUMNS, ParameterModel
from identify.problem import Estimate, Problem

__all__ = ["body_from_log_cholesky", "log_cholesky_from_body", "physical", "pseudo_inertia"]

_SIGNED_EFFECTS = {"torque_offset"}


def pseudo_inertia(body: np.ndarray) -> np.ndarray:
    """(4, 4) pseudo-inertia of one body's 10 parameters (m, MX, MY, MZ, XX, XY, YY, XZ, YZ, ZZ)."""
    m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = body
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    J = np.empty((4, 4))
    J[:3, :3] = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    J[:3, 3] = J[3, :3] = hx, hy, hz
    J[3, 3] = m
    return J


def _from_pseudo(J: np.ndarray) -> np.ndarray:
    """(..., 4, 4) pseudo-inertia -> (..., 10) body parameters (linear)."""
    S = J[..., :3, :3]
    return np.stack(
        [
            J[..., 3, 3],
            J[..., 0, 3],
            J[..., 1, 3],
            J[..., 2, 3],
            S[..., 1, 1] + S[..., 2, 2],
            -S[..., 0, 1],
            S[..., 0, 0] + S[..., 2, 2],
            -S[..., 0, 2],
            -S[..., 1, 2],
            S[..., 0, 0] + S[..., 1, 1],
        ],
        axis=-1,
    )


# where each of the 10 variables (a, d1, d2, d3, s12, s23, s13, t1, t2, t3) sits in U (a scales all of U)
_ENTRY = ((0, 0), (1, 1), (2, 2), (0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3))


def _body_and_jacobian(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(10,) consistent body parameters from 10 unconstrained numbers, and their (10, 10) Jacobian."""
    a, d1, d2, d3 = np.clip(x[:4], -40.0, 40.0)
    s12, s23, s13, t1, t2, t3 = x[4:]
    scale = np.exp(a)
    U = scale * np.array(
        [[np.exp(d1), s12, s13, t1], [0.0, np.exp(d2), s23, t2], [0.0, 0.0, np.exp(d3), t3], [0.0, 0.0, 0.0, 1.0]]
    )
    dU = np.zeros((10, 4, 4))
    dU[0] = U
    for i, (r, c) in enumerate(_ENTRY):
        dU[i + 1, r, c] = U[r, c] if i < 3 else scale
    dJ = dU @ U.T
    dJ = dJ + np.swapaxes(dJ, 1, 2)
    return _from_pseudo(U @ U.T), _from_pseudo(dJ).T


def body_from_log_cholesky(x: np.ndarray) -> np.ndarray:
    """(10,) consistent body parameters from the 10 unconstrained numbers (a, d1, d2, d3, s12, s23, s13, t1-3)."""
    return _body_and_jacobian(np.asarray(x, float))[0]


def log_cholesky_from_body(body: np.ndarray, *, floor: float = 1e-9) -> np.ndarray:
    """Inverse of `body_from_log_cholesky`; an inconsistent body is first lifted to eigenvalues >= floor * m."""
    J = pseudo_inertia(body)
    w, V = np.linalg.eigh(J)
    J = (V * np.maximum(w, floor * max(abs(body[0]), 1e-6))) @ V.T
    # U U' = J with U upper triangular: reverse-order Cholesky
    flip = np.eye(4)[::-1]
    L = np.linalg.cholesky(flip @ J @ flip)
    U = flip @ L @ flip
    a = np.log(U[3, 3])
    U = U / U[3, 3]
    return np.array([a, *np.log(np.diag(U)[:3]), U[0, 1], U[1, 2], U[0, 2], U[0, 3], U[1, 3], U[2, 3]])


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
        theta[cut], jac[cut, cut] = _body_and_jacobian(x[cut])
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
) -> optimize.OptimizeResult:
    """Minimise |R (K theta(x) - target)|^2 + regularisation |x - x0|^2."""
    reg = np.sqrt(regularisation)
    RK = R @ base.K
    eye = reg * np.eye(len(x0))

    def residual(x: np.ndarray) -> np.ndarray:
        return np.concatenate([RK @ _theta(model, x) - R @ target, reg * (x - x0)])

    def jacobian(x: np.ndarray) -> np.ndarray:
        return np.vstack([RK @ _theta_and_jacobian(model, x)[1], eye])

    return optimize.least_squares(
        residual, x0, jac=jacobian, method="trf", x_scale="jac", max_nfev=max_nfev, ftol=1e-12, xtol=1e-12
    )


def _normal_root(A: np.ndarray) -> np.ndarray:
    """R with R'R = A'A, also when A'A is singular (poorly excited data)."""
    w, V = np.linalg.eigh(A.T @ A)
    return np.sqrt(np.clip(w, 0.0, None))[:, None] * V.T


def physical(problem: Problem, *, regularisation: float = 1e-2, nominal: np.ndarray | None = None) -> Estimate:
    """Weighted least squares over physically consistent parameters (every pseudo-inertia positive definite).

    Args:
        problem: W and y on its rows.
        regularisation: weight of |x - x0|^2 (x the log-Cholesky variables, x0 the nominal model's), against
            residuals normalised by each joint's noise std (one sample's worth of data weighs 1).
        nominal: (p,) standard parameters to start from and pull towards; None: the MJCF's values.

    Returns:
        The consistent estimate; cov is the weighted-least-squares covariance at it (the constraints make
        it conservative near the boundary); diagnostics hold the standard parameters `theta`, each body's
        smallest pseudo-inertia eigenvalue, and the optimiser's status.
    """
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
    theta0 = problem.model.truth() if nominal is None else np.asarray(nominal, float)
    x0 = _x(problem.model, theta0)
    result = _fit(problem.model, problem.base, R, target, x0, regularisation)
    theta = _theta(problem.model, result.x)
    beta = problem.base.K @ theta
    cov = np.linalg.pinv(Aw.T @ Aw)
    nv = problem.model.plant.nv
    eig = [float(np.linalg.eigvalsh(pseudo_inertia(theta[10 * j : 10 * j + 10]))[0]) for j in range(nv)]
    diagnostics = {"theta": theta, "min_pseudo_inertia_eig": eig, "status": int(result.status), "nfev": result.nfev}
    return Estimate("physical", problem.names, beta, cov, torque_sigma(problem, beta), diagnostics)

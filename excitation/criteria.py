"""Excitation criteria, chosen by name, with analytic gradients down to the Fourier coefficients.

A criterion J(A) scores the stacked base regressor A = W (N nv, r) of a trajectory (lower is better):

    cond          log cond(W)                  (cond(X'X) = cond(W)^2, the number the literature reports)
    cond_colnorm  log cond(W D^-1)             D = diag(column norms): comparable across unit choices
    logdet        -log det(W'W) / r            D-optimality

The two cond criteria are minimised through a smooth upper bound (soft max and soft min of the singular
values, `sharpness` p): J_p = (log sum s^p + log sum s^-p) / p, which lies between log cond and
log cond + 2 log(r) / p. The value reported is always the true cond. Every effect column of the model
(friction, armature, ...) is part of W.

The gradient is the chain rule, not a finite difference of J: dJ/dA from the singular values and vectors
(ds_i = u_i' dA v_i, with s and v from the eigenpairs of A'A), dY/d(q, dq, ddq) per sample (one small step
per joint and state: exact in ddq, where the regressor is linear), and the Fourier basis maps from the
coefficients to (q, dq, ddq).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from dynamics.base import BaseParameters
from dynamics.regressor import ParameterModel
from excitation.fourier import FourierDesign

__all__ = ["CRITERIA", "conditioning", "criterion", "design_criterion", "regressor_derivatives"]

# Per-sample forward steps of the regressor. It is linear in ddq (a unit step is exact) and quadratic in dq
# (the error of a step h is h Y(q, e_j, 0)-like, ~1e-7 relative at 1e-6 rad/s; a Coulomb column's sign(dq)
# is flat except within the step of dq = 0); in q the truncation and round-off errors are ~1e-7 and ~1e-9.
_STEP_Q = 1e-7  # [rad]
_STEP_DQ = 1e-6  # [rad/s]

MatrixCriterion = Callable[[np.ndarray, float | None], tuple[float, np.ndarray]]


def _singular(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Singular values s (descending) and right vectors V (r, r) of A (M, r), from the eigenpairs of A'A.

    The (r, r) eigenproblem replaces an SVD of the tall A (the criterion's hot spot: 75 % of a 7-DoF design's
    time); s_min is exact to eps s_max^2 / s_min, ample while cond(X'X) << 1e12.
    """
    w, V = np.linalg.eigh(A.T @ A)
    return np.sqrt(np.clip(w[::-1], 0.0, None)), V[:, ::-1]


def _soft_log_cond(A: np.ndarray, sharpness: float | None) -> tuple[float, np.ndarray]:
    # ds_i = u_i' dA v_i with u_i = A v_i / s_i: the gradient sum_i w_i u_i v_i' is A V diag(w / s) V'
    s, V = _singular(A)
    if s[-1] <= 0:
        return np.inf, np.zeros_like(A)
    if sharpness is None:  # the exact cond: its gradient jumps where the extreme singular values cross
        w = np.zeros_like(s)
        w[0], w[-1] = 1.0 / s[0], -1.0 / s[-1]
        return float(np.log(s[0] / s[-1])), (A @ (V * (w / s))) @ V.T
    p = float(sharpness)
    hi = p * np.log(s / s[0])  # shifted for overflow safety
    lo = -p * np.log(s / s[-1])
    e_hi, e_lo = np.exp(hi), np.exp(lo)
    value = np.log(s[0] / s[-1]) + (np.log(e_hi.sum()) + np.log(e_lo.sum())) / p
    w = (e_hi / e_hi.sum() - e_lo / e_lo.sum()) / s
    return float(value), (A @ (V * (w / s))) @ V.T


def _cond(A: np.ndarray, sharpness: float | None) -> tuple[float, np.ndarray]:
    return _soft_log_cond(A, sharpness)


def _cond_colnorm(A: np.ndarray, sharpness: float | None) -> tuple[float, np.ndarray]:
    d = np.linalg.norm(A, axis=0)
    d = np.where(d > 0, d, 1.0)
    value, G = _soft_log_cond(A / d, sharpness)
    # A_n[:, j] = a_j / |a_j|  =>  dJ/da_j = g_j / d_j - a_j (a_j' g_j) / d_j^3
    return value, G / d - A * (np.sum(A * G, axis=0) / d**3)


def _logdet(A: np.ndarray, sharpness: float | None) -> tuple[float, np.ndarray]:
    r = A.shape[1]
    sign, logdet = np.linalg.slogdet(A.T @ A)
    if sign <= 0:
        return np.inf, np.zeros_like(A)
    # d log det(A'A) = 2 tr((A'A)^-1 A' dA)
    return float(-logdet / r), -2.0 / r * np.linalg.solve(A.T @ A, A.T).T


CRITERIA: dict[str, MatrixCriterion] = {"cond": _cond, "cond_colnorm": _cond_colnorm, "logdet": _logdet}


def criterion(name: str, A: np.ndarray, *, sharpness: float | None = None) -> tuple[float, np.ndarray]:
    """The criterion `name` of a stacked regressor and its gradient.

    Args:
        name: a key of `CRITERIA`.
        A: (M, r) stacked base regressor.
        sharpness: p of the smooth cond bound; None for the exact (non-smooth) log cond. Ignored by `logdet`.

    Returns:
        J and dJ/dA (M, r); J = inf (zero gradient) where A is rank deficient.

    Raises:
        ValueError: unknown name (the message lists the valid ones).
    """
    if name not in CRITERIA:
        raise ValueError(f"unknown excitation criterion {name!r}; valid choices: {', '.join(sorted(CRITERIA))}")
    return CRITERIA[name](A, sharpness)


def conditioning(A: np.ndarray) -> tuple[float, float]:
    """cond(X'X) of a regressor (raw) and cond(W) with unit-norm columns.

    Args:
        A: (..., r) base regressor; every leading axis is stacked into rows.
    """
    A = A.reshape(-1, A.shape[-1])
    # from the eigenvalues of X'X itself (exact to rounding for cond(X'X) << 1e14): an SVD of the tall
    # regressor of a long record costs many times more
    G = np.einsum("kr,ks->rs", A, A)
    w = np.linalg.eigvalsh(G)
    d = np.sqrt(np.diag(G))
    d = np.where(d > 0, d, 1.0)
    wn = np.linalg.eigvalsh(G / np.outer(d, d))
    return float(w[-1] / w[0]) if w[0] > 0 else float("inf"), float(np.sqrt(wn[-1] / wn[0])) if wn[0] > 0 else float(
        "inf"
    )


def regressor_derivatives(
    model: ParameterModel, base: BaseParameters, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The base regressor along a trajectory and its derivatives with respect to each sample's state.

    Args:
        q, dq, ddq: (N, nv) joint positions [rad], velocities [rad/s], accelerations [rad/s^2].

    Returns:
        Y: (N, nv, r) base regressor.
        dY: (3, nv, N, nv, r): dY[d, j] = dY/dq_j, dY/d(dq_j), dY/d(ddq_j) for d = 0, 1, 2.
    """
    n, nv = q.shape
    eye = np.eye(nv)
    steps = (_STEP_Q, _STEP_DQ, 1.0)
    states = [(q, dq, ddq)]
    for d in range(3):
        for j in range(nv):
            shifted = [q, dq, ddq]
            shifted[d] = shifted[d] + steps[d] * eye[j]
            states.append((shifted[0], shifted[1], shifted[2]))
    stacked = [np.concatenate([s[i] for s in states]) for i in range(3)]
    Y_all = base.columns(model.regressor(*stacked)).reshape(len(states), n, nv, -1)
    dY = (Y_all[1:] - Y_all[0]).reshape(3, nv, n, nv, -1) / np.reshape(steps, (3, 1, 1, 1, 1))
    return Y_all[0], dY


def design_criterion(
    name: str,
    design: FourierDesign,
    model: ParameterModel,
    base: BaseParameters,
    t: np.ndarray,
    *,
    sharpness: float | None = None,
    gradient: bool = True,
) -> tuple[float, np.ndarray | None]:
    """A position design's criterion on the times `t` and its gradient wrt `design.to_vector()`.

    Args:
        name: a key of `CRITERIA`.
        t: (N,) sample times [s] at which the regressor is stacked.
        sharpness: see `criterion`.
        gradient: False to skip the derivatives (returns None in their place).

    Returns:
        J and dJ/dx, (2 n H + n,) in the layout [a, b, q0] of `FourierDesign.to_vector`.
    """
    q, dq, ddq = design.evaluate(t)
    if not gradient:
        Y = base.columns(model.regressor(q, dq, ddq))
        return criterion(name, Y.reshape(-1, Y.shape[-1]), sharpness=sharpness)[0], None
    Y, dY = regressor_derivatives(model, base, q, dq, ddq)
    value, G = criterion(name, Y.reshape(-1, Y.shape[-1]), sharpness=sharpness)
    G = G.reshape(Y.shape)
    s = np.einsum("kir,djkir->dkj", G, dY)  # (3, N, nv): dJ/dq, dJ/ddq, dJ/dddq per sample and joint
    Bq, Bdq, Bddq = design.basis(t)  # (N, 2H) each
    g = Bq.T @ s[0] + Bdq.T @ s[1] + Bddq.T @ s[2]  # (2H, nv)
    H = design.harmonics
    return value, np.concatenate([g[:H].T.ravel(), g[H:].T.ravel(), s[0].sum(axis=0)])

"""Honest statistics for band-limited residuals: effective sample size and block-robust covariances.

A torque residual low-passed at a few hertz and sampled at hundreds is strongly correlated: at 4 Hz and
500 Hz neighbouring samples repeat each other for tens of samples, and treating every sample as
independent inflates an information criterion's evidence and shrinks every standard deviation by the
square root of that factor.

- `correlation_time`: the integrated autocorrelation time tau_int = 1 + 2 sum_k rho_k of a residual, summed
  over the initial positive sequence of its autocorrelation (Geyer's rule), record by record; the
  effective sample size is n / tau_int.
- `fit_bounded`: weighted least squares within bounds (`scipy.optimize.lsq_linear`), with the
  covariance of the free coefficients the larger (per coefficient) of two honest ones:
  - the least-squares covariance with the effective sample size: s^2 tau_int (A'A)^-1, s^2 = RSS /
    (n - p tau_int). Exact for stationary noise when the columns vary slowly on the scale of tau_int (the
    usual case: effects live below the analysis band), and stable with few records;
  - a block sandwich: the scores summed over contiguous time blocks of `BLOCK_CORRELATION_TIMES`
    correlation times (never across records), G / (G - 1) for G blocks. It holds where the noise is not
    stationary (larger on fast parts of the motion), where the first does not.
  A coefficient that ends at a bound gets no standard deviation (it is reported as at its bound).
  `tests/test_diagnose_statistics.py` checks by Monte Carlo that +-2 std covers the truth 95 % of the time on
  band-limited noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize

__all__ = ["BLOCK_CORRELATION_TIMES", "LinearFit", "block_ids", "correlation_time", "fit_bounded"]

BLOCK_CORRELATION_TIMES = 4.0  # covariance blocks are this many correlation times long


@dataclass(frozen=True)
class LinearFit:
    """Coefficients of chosen columns and their covariance.

    Attributes:
        coef: (p,) coefficients.
        cov: (p, p) block-sandwich covariance [coefficient units^2]; rows and columns of coefficients at a
            bound are zero.
        sigma: (nv,) residual std per joint [N m].
        at_bound: (p,) -1 at the lower bound, +1 at the upper, 0 free.
        correlation_time: integrated autocorrelation time of the weighted residual [samples].
    """

    coef: np.ndarray
    cov: np.ndarray
    sigma: np.ndarray
    at_bound: np.ndarray | None = None
    correlation_time: float = 1.0

    def bound_flags(self) -> np.ndarray:
        return np.zeros(len(self.coef), int) if self.at_bound is None else self.at_bound


def correlation_time(e: np.ndarray, record: np.ndarray | None = None, *, max_lag: int | None = None) -> float:
    """Integrated autocorrelation time [samples] of a residual, pooled over its columns and records.

    Args:
        e: (N,) or (N, m) residual.
        record: (N,) record index of each row (autocorrelations are computed within records), or None.
        max_lag: longest lag summed (default N // 10 of the shortest record).

    Returns:
        tau_int >= 1 (1 for white noise).
    """
    e = e.reshape(len(e), -1)
    record = np.zeros(len(e), int) if record is None else record
    parts = [e[record == r] for r in np.unique(record)]
    n_min = min(len(p) for p in parts)
    lags = max(min(max_lag or n_min // 10, n_min - 1), 1)
    acov = np.zeros(lags + 1)
    for p in parts:
        x = p - p.mean(axis=0)
        spec = np.fft.rfft(x, n=2 * len(x), axis=0)
        full = np.fft.irfft(np.abs(spec) ** 2, axis=0)[: lags + 1]
        acov += full.sum(axis=1)
    if acov[0] <= 0:
        return 1.0
    rho = acov / acov[0]
    # Geyer's initial positive sequence: sum pairs rho_2k + rho_2k+1 while they stay positive
    tau = -1.0
    for k in range(0, lags, 2):
        pair = rho[k] + rho[k + 1]
        if pair <= 0:
            break
        tau += 2.0 * pair
    return float(max(tau, 1.0))


def block_ids(n: int, record: np.ndarray | None, length: int) -> np.ndarray:
    """(n,) contiguous block index of each row: blocks of `length` rows that never straddle two records."""
    record = np.zeros(n, int) if record is None else record
    out = np.empty(n, int)
    start = 0
    for r in np.unique(record):
        rows = np.flatnonzero(record == r)
        local = np.arange(len(rows)) // max(length, 1)
        k = int(local.max()) + 1
        if len(rows) % max(length, 1) and k > 1 and len(rows) % length < length // 2:
            local[local == k - 1] = k - 2  # a short tail joins the block before it
            k -= 1
        out[rows] = start + local
        start += k
    return out


def fit_bounded(
    X: np.ndarray,
    r: np.ndarray,
    weights: np.ndarray,
    *,
    lower: np.ndarray | None = None,
    upper: np.ndarray | None = None,
    record: np.ndarray | None = None,
    used: np.ndarray | None = None,
) -> LinearFit:
    """Weighted least squares r ~ X c with lower <= c <= upper and a block-sandwich covariance.

    Args:
        X: (N, nv, p) columns.
        r: (N, nv) residual torque [N m].
        weights: (nv,) per-joint weights (1 / sigma_j^2).
        lower, upper: (p,) bounds (None: unbounded).
        record: (N,) record of each row (blocks never straddle records).
        used: (N, nv) the (row, joint) values that are observations; the others are zero in X and r
            (`Signals.used`) and count neither in the degrees of freedom nor in `sigma`. None: all.
    """
    n, nv, p = X.shape
    count = np.full(nv, n) if used is None else np.maximum(np.count_nonzero(used, axis=0), 1)
    if p == 0:
        return LinearFit(np.zeros(0), np.zeros((0, 0)), np.sqrt(np.sum(r**2, axis=0) / count))
    lo = np.full(p, -np.inf) if lower is None else np.asarray(lower, float)
    hi = np.full(p, np.inf) if upper is None else np.asarray(upper, float)
    sw = np.sqrt(weights)
    A, b = (X * sw[None, :, None]).reshape(-1, p), (r * sw).ravel()
    coef, *_ = np.linalg.lstsq(A, b, rcond=None)
    flags = np.zeros(p, int)
    if np.any(coef < lo) or np.any(coef > hi):
        scale = np.maximum(np.linalg.norm(A, axis=0), 1e-300)
        res = optimize.lsq_linear(A / scale, b, bounds=(lo * scale, hi * scale), method="bvls")
        coef = res.x / scale
        tol = 1e-9 * np.maximum(np.abs(coef), 1.0)
        flags = np.where(np.isfinite(lo) & (coef <= lo + tol), -1, np.where(np.isfinite(hi) & (coef >= hi - tol), 1, 0))
    e = b - A @ coef
    per_row = e.reshape(n, nv)
    tau = correlation_time(per_row, record)
    cov = np.zeros((p, p))
    free = np.flatnonzero(flags == 0)
    if free.size:
        Af = A[:, free]
        blocks = block_ids(n, record, int(np.ceil(BLOCK_CORRELATION_TIMES * tau)))
        sandwich = _block_sandwich(Af, e, nv, blocks)
        dof = max((len(b) if used is None else np.count_nonzero(used)) - free.size * tau, 1.0)
        ess = float(e @ e) / dof * tau * np.linalg.pinv(Af.T @ Af)
        d_ess, d_sw = np.clip(np.diag(ess), 1e-300, None), np.clip(np.diag(sandwich), 0, None)
        scale = np.sqrt(np.maximum(d_sw / d_ess, 1.0))
        cov[np.ix_(free, free)] = ess * np.outer(scale, scale)
    resid = r - np.einsum("knp,p->kn", X, coef)
    return LinearFit(coef, cov, np.sqrt(np.sum(resid**2, axis=0) / count), flags, tau)


def _block_sandwich(A: np.ndarray, e: np.ndarray, nv: int, blocks: np.ndarray) -> np.ndarray:
    """(A'A)^-1 (sum_b s_b s_b') (A'A)^-1 G/(G-1), s_b the scores summed over block b (and over joints)."""
    bread = np.linalg.pinv(A.T @ A)
    scores = (A * e[:, None]).reshape(-1, nv, A.shape[1]).sum(axis=1)
    g = int(blocks.max()) + 1
    summed = np.zeros((g, A.shape[1]))
    np.add.at(summed, blocks, scores)
    meat = summed.T @ summed * (g / max(g - 1, 1))
    return bread @ meat @ bread

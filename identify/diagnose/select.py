"""Choosing the effects that explain the residual: greedy forward selection by information criterion and
held-out torque RMS, with honest (autocorrelation-robust) standard deviations.

At each step every remaining candidate is fitted together with the ones already chosen, on the training
rows, by weighted least squares (per-joint weights 1/sigma_j^2 from the torque noise floor). A candidate is
admissible when it lowers the BIC and its cross-validation (each training record held out in turn, or
contiguous time blocks of a single record) lowers the held-out weighted torque MSE by at least `min_gain`
(`min_gain_records` when records are held out) of the current one, and when the chosen ones do not
already explain most of its column; among the admissible ones the lowest BIC wins (the parsimonious
explanation: one armature column beats a whole rigid-body refit that fits the same data). Columns that
the chosen ones already span are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from identify.diagnose.candidates import Candidate, Signals

__all__ = ["LinearFit", "SelectionOptions", "Step", "fit_columns", "select_effects"]


@dataclass(frozen=True)
class SelectionOptions:
    """Knobs of the selection.

    Attributes:
        min_gain: smallest relative drop of the held-out weighted torque MSE that counts, when the held-out
            data are time blocks of a single record.
        min_gain_records: the same when whole records are held out in turn: a gain that holds on recordings
            the fit never saw is stronger evidence than one on another stretch of the same recording, so
            a smaller one counts.
        bic_margin: smallest BIC drop that counts.
        folds: contiguous blocks of the training rows for cross-validation.
        max_findings: at most this many effects are chosen.
        min_z: smallest |value| / std of a chosen effect's headline value.
        min_delay_samples: smallest |time delay| named, in sample intervals: below it a delay is within the
            log's timing conventions (zero-order hold, time stamps, the simulator's half-step) [1].
        min_independence: smallest share of a candidate's headline column (in norm) that the effects
            already chosen do not explain; below it the candidate is confounded with them and its value
            would only trade off against theirs, so it is not named.
    """

    min_gain: float = 0.02
    min_gain_records: float = 0.002
    bic_margin: float = 10.0
    folds: int = 5
    max_findings: int = 6
    min_z: float = 3.0
    min_independence: float = 0.1
    min_delay_samples: float = 0.5

    def __post_init__(self) -> None:
        for name in ("min_gain", "min_gain_records"):
            if not 0 <= getattr(self, name) < 1:
                raise ValueError(f"{name} must lie in [0, 1), got {getattr(self, name)}")
        if self.folds < 2:
            raise ValueError(f"folds must be >= 2, got {self.folds}")


@dataclass(frozen=True)
class LinearFit:
    """Coefficients of chosen columns and their covariance.

    Attributes:
        coef: (p,) coefficients.
        cov: (p, p) Newey-West covariance (robust to residual autocorrelation) [coefficient units^2].
        sigma: (nv,) residual std per joint [N m].
    """

    coef: np.ndarray
    cov: np.ndarray
    sigma: np.ndarray


@dataclass(frozen=True)
class Step:
    """One accepted candidate.

    Attributes:
        candidate: the effect.
        kept: indices of its columns that were not already spanned.
        delta_bic: change of the BIC when it was added.
        cv_mse_before, cv_mse_after: held-out weighted torque MSE before and after [1] (weighted units).
    """

    candidate: Candidate
    kept: np.ndarray
    delta_bic: float
    cv_mse_before: float
    cv_mse_after: float


def _flat(X: np.ndarray, sw: np.ndarray) -> np.ndarray:
    return (X * sw[None, :, None]).reshape(-1, X.shape[-1])


def _newey_west(A: np.ndarray, e: np.ndarray, nv: int, lags: int) -> np.ndarray:
    """Sandwich covariance of least squares with per-sample scores summed over joints, Bartlett weights."""
    bread = np.linalg.pinv(A.T @ A)
    scores = (A * e[:, None]).reshape(-1, nv, A.shape[1]).sum(axis=1)
    meat = scores.T @ scores
    for lag in range(1, lags + 1):
        g = scores[lag:].T @ scores[:-lag]
        meat += (1 - lag / (lags + 1)) * (g + g.T)
    return bread @ meat @ bread


def fit_columns(X: np.ndarray, r: np.ndarray, weights: np.ndarray, *, lags: int | None = None) -> LinearFit:
    """Weighted least squares r ~ X c.

    Args:
        X: (N, nv, p) columns.
        r: (N, nv) residual torque [N m].
        weights: (nv,) per-joint weights (1 / sigma_j^2).
        lags: Newey-West lags (None: the usual 4 (N/100)^(2/9)).
    """
    n, nv, p = X.shape
    if p == 0:
        return LinearFit(np.zeros(0), np.zeros((0, 0)), np.sqrt(np.mean(r**2, axis=0)))
    sw = np.sqrt(weights)
    A, b = _flat(X, sw), (r * sw).ravel()
    coef, *_ = np.linalg.lstsq(A, b, rcond=None)
    e = b - A @ coef
    lags = int(np.ceil(4 * (n / 100) ** (2 / 9))) if lags is None else lags
    resid = r - np.einsum("knp,p->kn", X, coef)
    return LinearFit(coef, _newey_west(A, e, nv, lags), np.sqrt(np.mean(resid**2, axis=0)))


def _independence(basis: np.ndarray, col: np.ndarray) -> float:
    """Share (in norm) of `col` outside the span of `basis` (orthonormal columns)."""
    norm = float(np.linalg.norm(col))
    if norm == 0:
        return 0.0
    v = col / norm
    for _ in range(2):
        v = v - basis @ (basis.T @ v)
    return float(np.linalg.norm(v))


def _span_free(basis: np.ndarray, cols: np.ndarray, tol: float = 1e-6) -> list[int]:
    """Indices of `cols` (rows, k) not in the span of `basis` (orthonormal, rows x m) nor of earlier kept ones."""
    keep: list[int] = []
    B = basis
    for c in range(cols.shape[1]):
        norm = np.linalg.norm(cols[:, c])
        if norm == 0:
            continue
        v = cols[:, c] / norm
        for _ in range(2):
            v = v - B @ (B.T @ v)
        if np.linalg.norm(v) > tol:
            B = np.column_stack([B, v / np.linalg.norm(v)])
            keep.append(c)
    return keep


def _scores(A: np.ndarray, b: np.ndarray, folds: np.ndarray, n_folds: int) -> tuple[float, float]:
    """(weighted RSS of the full fit, held-out weighted MSE over the folds)."""
    coef, *_ = np.linalg.lstsq(A, b, rcond=None)
    rss = float(np.sum((b - A @ coef) ** 2))
    held = 0.0
    for f in range(n_folds):
        test = folds == f
        c, *_ = np.linalg.lstsq(A[~test], b[~test], rcond=None)
        held += float(np.sum((b[test] - A[test] @ c) ** 2))
    return rss, held / len(b)


def select_effects(
    pool: list[Candidate],
    train: Signals,
    weights: np.ndarray,
    options: SelectionOptions,
    *,
    nuisance: np.ndarray | None = None,
) -> tuple[list[Step], np.ndarray]:
    """Greedy forward selection over `pool` on the training signals.

    Args:
        pool: candidate effects.
        train: training signals (residual = tau - tau_nominal).
        weights: (nv,) per-joint weights 1 / sigma_j^2.
        options: thresholds.
        nuisance: (N, nv, m) columns always fitted and never named (such as per-record torque offsets).

    Returns:
        (steps in the order chosen, (N, nv, m + p) the nuisance then the chosen columns in that order).
    """
    n, nv = train.tau.shape
    sw = np.sqrt(weights)
    b = (train.residual * sw).ravel()
    n_obs = len(b)
    dt = float(np.median(np.diff(train.time)))
    records = np.unique(train.record)
    if len(records) >= 2:  # leave one record out: held out as the validation files will be
        folds = np.repeat(np.searchsorted(records, train.record), nv)
        n_folds = len(records)
        min_gain = options.min_gain_records
    else:  # contiguous time blocks of the single record
        folds = np.repeat(np.minimum(np.arange(n) * options.folds // n, options.folds - 1), nv)
        n_folds = options.folds
        min_gain = options.min_gain
    built = {c.key: train.columns(c) for c in pool}
    chosen: list[Step] = []
    X = np.zeros((n, nv, 0)) if nuisance is None else nuisance
    basis = np.linalg.qr(_flat(X, sw))[0] if X.shape[2] else np.zeros((n_obs, 0))
    if X.shape[2]:
        rss, cv = _scores(_flat(X, sw), b, folds, n_folds)
        bic = n_obs * np.log(rss / n_obs) + X.shape[2] * np.log(n_obs)
    else:
        rss, cv = float(b @ b), float(b @ b) / n_obs
        bic = n_obs * np.log(rss / n_obs)
    while len(chosen) < options.max_findings:
        best: tuple[float, Candidate, list[int], float, float] | None = None
        for cand in pool:
            if any(s.candidate.key == cand.key for s in chosen):
                continue
            cols = built[cand.key]
            kept = _span_free(basis, _flat(cols, sw))
            if not kept or (cand.effect not in ("rigid_body",) and kept[0] != 0):
                continue  # nothing new, or its headline column is already explained
            if (
                cand.effect != "rigid_body"
                and _independence(basis, _flat(cols[:, :, :1], sw)[:, 0]) < options.min_independence
            ):
                continue  # confounded with what is already chosen
            A = _flat(np.concatenate([X, cols[:, :, kept]], axis=2), sw)
            rss_c, cv_c = _scores(A, b, folds, n_folds)
            bic_c = n_obs * np.log(max(rss_c, 1e-300) / n_obs) + A.shape[1] * np.log(n_obs)
            if bic_c - bic > -options.bic_margin or cv_c > (1 - min_gain) * cv:
                continue
            if best is None or bic_c < best[0]:
                best = (bic_c, cand, kept, rss_c, cv_c)
        if best is None:
            break
        bic_c, cand, kept, rss_c, cv_c = best
        X_new = np.concatenate([X, built[cand.key][:, :, kept]], axis=2)
        fit = fit_columns(X_new, train.residual, weights)
        sl = slice(X.shape[2], X_new.shape[2])
        value, std = cand.value(fit.coef[sl], fit.cov[sl, sl], X_new[:, :, sl])
        null = 1.0 if cand.effect == "torque_gain" else 0.0
        too_short = cand.effect == "time_delay" and abs(value) < options.min_delay_samples * dt
        if not abs(value - null) > options.min_z * std or value < cand.minimum or too_short:
            pool = [c for c in pool if c.key != cand.key]  # not significant or not physical: never again
            continue
        chosen.append(Step(cand, np.array(kept), float(bic_c - bic), cv, cv_c))
        X = X_new
        A = _flat(X, sw)
        q, _ = np.linalg.qr(A)
        basis, bic, rss, cv = q, bic_c, rss_c, cv_c
    return chosen, X

"""Whether data excite the parameters asked for: refuse a regressor that is too short or poorly conditioned."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dynamics.errors import DataError

__all__ = ["MAX_COND", "ExcitationCheck", "check_excitation", "excitation_report"]

MAX_COND = 1e3
"""Largest column-normalised condition number of well-excited data: a direction whose singular value is below the
largest one / MAX_COND is poorly excited (a run reports it, the diagnosis refuses such data)."""


@dataclass(frozen=True)
class ExcitationCheck:
    """How well the data excite the parameters of a regressor.

    Attributes:
        n_equations: rows of the stacked regressor (samples x joints).
        n_parameters: its columns.
        rank: numerical rank of the column-normalised regressor.
        cond: 2-norm condition number of the column-normalised regressor [-] (inf when rank deficient).
        weakest: names of the parameters in the poorly excited directions (those above `max_cond`, else the
            least excited one), largest share first.
        poorly_excited: number of directions of the column-normalised regressor whose singular value is below
            the largest one / `max_cond`.
        weakest_direction: the least excited direction as text (`+0.71 [p1] -0.70 [p2]`, entries of share >= 1 %).
    """

    n_equations: int
    n_parameters: int
    rank: int
    cond: float
    weakest: tuple[str, ...]
    poorly_excited: int = 0
    weakest_direction: str = ""


def check_excitation(
    regressor: np.ndarray,
    *,
    names: Sequence[str],
    source: str = "data",
    max_cond: float = MAX_COND,
    min_equations_per_parameter: int = 10,
) -> ExcitationCheck:
    """Refuse data that are too short for, or do not excite, the parameters of a regressor.

    The regressor is column-normalised (so that units do not matter) before its condition number is taken;
    the parameters named in a refusal are those with the largest share of the least excited direction(s).

    Args:
        regressor: (N, nv, p) or (M, p) regressor of the parameters to identify (normally the base regressor:
            `BaseParameters.columns(ParameterModel.regressor(q, dq, ddq))`), on the rows the fit will use.
        names: (p,) parameter names, for the messages.
        source: what the data are (a file name), for the messages.
        max_cond: largest acceptable column-normalised condition number.
        min_equations_per_parameter: fewest equations (rows) per parameter.

    Raises:
        DataError: too few equations, a parameter whose column is zero, or a condition number above max_cond.
    """
    W = _stacked(regressor, names, source)
    m, p = W.shape
    if m < min_equations_per_parameter * p:
        raise DataError(
            f"{source}: too little data: {m} equations for {p} parameters; at least "
            f"{min_equations_per_parameter} per parameter ({min_equations_per_parameter * p}) are needed"
        )
    norms = np.linalg.norm(W, axis=0)
    dead = [names[int(c)] for c in np.flatnonzero(norms <= 1e-12 * max(norms.max(), 1e-300))]
    if dead:
        raise DataError(f"{source}: the data do not excite {', '.join(dead)} at all (their regressor columns are 0)")
    check = _report(W, names, max_cond)
    if check.cond > max_cond:
        raise DataError(
            f"{source}: too little excitation for the parameters asked for: {check.poorly_excited} direction(s) of "
            f"the column-normalised regressor are poorly excited (condition number {check.cond:.3g} > "
            f"{max_cond:.3g}); weakest: {', '.join(check.weakest)} (weakest direction {check.weakest_direction}). "
            "Use data that move these, or drop them from the model"
        )
    return check


def excitation_report(regressor: np.ndarray, *, names: Sequence[str], max_cond: float = MAX_COND) -> ExcitationCheck:
    """How well a regressor's columns are excited, without refusing anything (`check_excitation` refuses).

    Args:
        regressor: (N, nv, p) or (M, p) regressor.
        names: (p,) parameter names.
        max_cond: a direction whose singular value of the column-normalised regressor is below the largest one /
            max_cond counts as poorly excited.
    """
    return _report(_stacked(regressor, names, "data"), names, max_cond)


def _stacked(regressor: np.ndarray, names: Sequence[str], source: str) -> np.ndarray:
    """(M, p) rows of a (N, nv, p) or (M, p) regressor, its names and values checked."""
    W = np.asarray(regressor, dtype=float)
    W = W.reshape(-1, W.shape[-1])
    if len(names) != W.shape[1]:
        raise ValueError(f"{len(names)} names for a regressor of {W.shape[1]} columns")
    if not np.all(np.isfinite(W)):
        raise DataError(f"{source}: the regressor holds NaN or inf (check the derivatives of the data)")
    return W


def _report(W: np.ndarray, names: Sequence[str], max_cond: float) -> ExcitationCheck:
    """`excitation_report` of the checked rows W (M, p)."""
    m, p = W.shape
    norms = np.linalg.norm(W, axis=0)
    norms = np.where(norms > 0, norms, np.inf)  # a zero column stays zero: a direction not excited at all
    # the singular values and right vectors of W are those of its R factor (p x p): no m x p U of a long record
    # (fewer rows than columns: all p right vectors, the missing singular values 0)
    R = np.linalg.qr(W / norms, mode="r") if m >= p else W / norms
    s, vt = np.linalg.svd(R, full_matrices=True)[1:]
    s = np.concatenate([s, np.zeros(p - len(s))])
    cond = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    rank = int(np.sum(s > s[0] * max(m, p) * np.finfo(float).eps))
    weak = s <= s[0] / max_cond  # all of them where nothing is excited (s[0] = 0)
    share = np.sum(vt[weak] ** 2, axis=0) if weak.any() else vt[-1] ** 2  # each parameter's part of the weak space
    order = np.argsort(share)[::-1]
    weakest = tuple(names[c] for c in order if share[c] >= 0.1 or c == order[0])
    last = np.argsort(vt[-1] ** 2)[::-1][:4]
    combo = " ".join(f"{vt[-1, c]:+.2f} [{names[c]}]" for c in last if vt[-1, c] ** 2 >= 0.01)
    return ExcitationCheck(
        n_equations=m,
        n_parameters=p,
        rank=rank,
        cond=cond,
        weakest=weakest,
        poorly_excited=int(weak.sum()),
        weakest_direction=combo,
    )

"""Whether data excite the parameters asked for: refuse a regressor that is too short or poorly conditioned."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dynamics.errors import DataError

__all__ = ["ExcitationCheck", "check_excitation"]


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
    """

    n_equations: int
    n_parameters: int
    rank: int
    cond: float
    weakest: tuple[str, ...]


def check_excitation(
    regressor: np.ndarray,
    *,
    names: Sequence[str],
    source: str = "data",
    max_cond: float = 1e3,
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
    W = np.asarray(regressor, dtype=float)
    W = W.reshape(-1, W.shape[-1])
    m, p = W.shape
    if len(names) != p:
        raise ValueError(f"{len(names)} names for a regressor of {p} columns")
    if not np.all(np.isfinite(W)):
        raise DataError(f"{source}: the regressor holds NaN or inf (check the derivatives of the data)")
    if m < min_equations_per_parameter * p:
        raise DataError(
            f"{source}: too little data: {m} equations for {p} parameters; at least "
            f"{min_equations_per_parameter} per parameter ({min_equations_per_parameter * p}) are needed"
        )
    norms = np.linalg.norm(W, axis=0)
    dead = [names[int(c)] for c in np.flatnonzero(norms <= 1e-12 * max(norms.max(), 1e-300))]
    if dead:
        raise DataError(f"{source}: the data do not excite {', '.join(dead)} at all (their regressor columns are 0)")
    s, vt = np.linalg.svd(W / norms, full_matrices=False)[1:]
    cond = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    rank = int(np.sum(s > s[0] * max(m, p) * np.finfo(float).eps))
    weak = s < s[0] / max_cond
    share = np.sum(vt[weak] ** 2, axis=0) if weak.any() else vt[-1] ** 2  # each parameter's part of the weak space
    order = np.argsort(share)[::-1]
    weakest = tuple(names[c] for c in order if share[c] >= 0.1 or c == order[0])
    check = ExcitationCheck(n_equations=m, n_parameters=p, rank=rank, cond=cond, weakest=weakest)
    if cond > max_cond:
        last = np.argsort(vt[-1] ** 2)[::-1][:4]
        combo = " ".join(f"{vt[-1, c]:+.2f} [{names[c]}]" for c in last if vt[-1, c] ** 2 >= 0.01)
        raise DataError(
            f"{source}: too little excitation for the parameters asked for: {int(weak.sum())} direction(s) of the "
            f"column-normalised regressor are poorly excited (condition number {cond:.3g} > {max_cond:.3g}); "
            f"weakest: {', '.join(weakest)} (weakest direction {combo}). Use data that move these, or drop them "
            "from the model"
        )
    return check

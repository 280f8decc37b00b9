"""Estimators chosen by name: each takes a `Problem` (and options) and returns an `Estimate`."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from identify.estimators.energy import energy
from identify.estimators.filtered import filtered
from identify.estimators.gradient import gradient
from identify.estimators.iv import iv
from identify.estimators.least_squares import ols, wls
from identify.estimators.physical import physical
from identify.estimators.recursive import rls
from identify.problem import Estimate, Problem

__all__ = ["ESTIMATORS", "estimate"]

ESTIMATORS: dict[str, Callable[..., Estimate]] = {
    "energy": energy,
    "filtered": filtered,
    "gradient": gradient,
    "iv": iv,
    "ols": ols,
    "physical": physical,
    "rls": rls,
    "wls": wls,
}


def estimate(name: str, problem: Problem, **options: Any) -> Estimate:
    """Run the estimator called `name` on `problem`.

    Raises:
        ValueError: unknown name (the message lists the valid ones).
    """
    if name not in ESTIMATORS:
        raise ValueError(f"unknown estimator {name!r}; valid choices: {', '.join(sorted(ESTIMATORS))}")
    return ESTIMATORS[name](problem, **options)

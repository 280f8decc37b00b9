"""Estimators chosen by name: each takes a `Problem` (and options) and returns an `Estimate`."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from identify.estimators.energy import energy
from identify.estimators.filtered import filtered
from identify.estimators.gradient import gradient
from identify.estimators.iv import iv
from identify.estimators.least_squares import ols, wls
from identify.estimators.physical import physical
from identify.estimators.recursive import rls
from identify.problem import Estimate, Problem

__all__ = ["ESTIMATORS", "OPTION_RANGES", "OptionRange", "estimate"]

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


@dataclass(frozen=True)
class OptionRange:
    """The values an estimator option may take: a number (an integer where `integer`) in [lo, hi], each end
    open where said; None is accepted where the option's default is None."""

    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    hi_open: bool = False
    integer: bool = False
    unit: str = ""

    def contains(self, value: float) -> bool:
        above = value > self.lo if self.lo_open else value >= self.lo
        below = value < self.hi if self.hi_open else value <= self.hi
        return above and below and (not self.integer or float(value).is_integer())

    def describe(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        kind = "an integer" if self.integer else "a number"
        if math.isinf(self.hi):
            return f"{kind} {'>' if self.lo_open else '>='} {self.lo:g}{unit}"
        return f"{kind} in {'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}{')' if self.hi_open else ']'}{unit}"


_POSITIVE = OptionRange(0.0, lo_open=True)
_COUNT = OptionRange(1.0, integer=True)
# per estimator, the range of each numeric option (the estimators' own checks raise on a value outside it, after
# the data are made; the config is checked against this before anything runs)
OPTION_RANGES: dict[str, dict[str, OptionRange]] = {
    "energy": {"window_s": OptionRange(0.0, lo_open=True, unit="s")},
    "filtered": {"omega": OptionRange(0.0, lo_open=True, unit="rad/s"), "settle_s": OptionRange(0.0, unit="s")},
    "gradient": {
        "omega": OptionRange(0.0, lo_open=True, unit="rad/s"),
        "gain": _POSITIVE,
        "epochs": _COUNT,
        "history_points": _COUNT,
    },
    "iv": {
        "iterations": _COUNT,
        "tol": _POSITIVE,
        "bandwidth_hz": OptionRange(0.0, lo_open=True, unit="Hz"),
        "reference_cutoff_hz": OptionRange(0.0, lo_open=True, unit="Hz"),
        "period_s": OptionRange(0.0, lo_open=True, unit="s"),
        "substeps": _COUNT,
    },
    "ols": {},
    "physical": {"regularisation": OptionRange(0.0)},
    "rls": {
        "omega": OptionRange(0.0, lo_open=True, unit="rad/s"),
        "alpha": OptionRange(0.0, 1.0, lo_open=True),  # the forgetting factor
        "p0": _POSITIVE,
        "history_points": _COUNT,
    },
    "wls": {"iterations": _COUNT},
}


def estimate(name: str, problem: Problem, **options: Any) -> Estimate:
    """Run the estimator called `name` on `problem`.

    Raises:
        ValueError: unknown name (the message lists the valid ones).
    """
    if name not in ESTIMATORS:
        raise ValueError(f"unknown estimator {name!r}; valid choices: {', '.join(sorted(ESTIMATORS))}")
    return ESTIMATORS[name](problem, **options)

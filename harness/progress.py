"""Progress lines for stages that take more than a few seconds (optimisation, Monte Carlo, sweeps).

The numerical core takes an optional `progress(fraction, message)` callback and never prints; this module
turns the calls into throttled lines on stderr.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO

__all__ = ["Progress", "printer"]

Progress = Callable[[float, str], None]


def printer(stage: str, *, every_s: float = 1.0, stream: TextIO | None = None) -> Progress:
    """A callback printing `[stage] 40% message` at most every `every_s` seconds (and always at 100 %)."""
    out = stream or sys.stderr
    start = time.perf_counter()
    last = -float("inf")

    def report(fraction: float, message: str) -> None:
        nonlocal last
        now = time.perf_counter()
        if fraction < 1.0 and now - last < every_s:
            return
        last = now
        print(f"[{stage}] {100 * fraction:3.0f}% {message} ({now - start:.1f} s)", file=out, flush=True)

    return report

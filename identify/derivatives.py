"""Joint velocities and accelerations from sampled positions, chosen by name.

- `simulator`: the simulator's exact states (only simulated datasets carry them): the noise-free reference.
- `butterworth`: zero-phase Butterworth low-pass of q (filtfilt), then central differences; `trim`
  samples at each end are dropped afterwards by the caller, where the filter's edge effects live.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import signal

from envs.dataset import Dataset
from envs.errors import DataError

__all__ = ["DERIVATIVES", "States", "derive_states"]


@dataclass(frozen=True)
class States:
    """Joint states for the regressor, with the rows the method trusts.

    Attributes:
        q, dq, ddq: (N, nv) [rad, rad/s, rad/s^2].
        valid: (N,) False where a filter's edge effects make the row unreliable.
    """

    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    valid: np.ndarray


def _simulator(data: Dataset, **_: float) -> States:
    if data.ddq is None or "q_true" not in data.meta:
        raise DataError(f"{data.source}: derivatives='simulator' needs a simulated dataset with its exact states")
    return States(data.meta["q_true"], data.meta["dq_true"], data.ddq, np.ones(data.n_samples, bool))


def _butterworth(data: Dataset, *, cutoff_hz: float = 10.0, order: int = 4, trim_s: float | None = None) -> States:
    fs = 1.0 / data.dt
    if not 0 < cutoff_hz < 0.5 * fs:
        raise ValueError(f"cutoff_hz must lie in (0, {0.5 * fs:g}) Hz for a {fs:g} Hz signal, got {cutoff_hz}")
    jitter = np.max(np.abs(np.diff(data.time) - data.dt)) / data.dt
    if jitter > 0.01:
        raise DataError(f"{data.source}: sampling is irregular ({jitter:.1%} step jitter); resample it first")
    sos = signal.butter(order, cutoff_hz, fs=fs, output="sos")
    q = signal.sosfiltfilt(sos, data.q, axis=0)
    dq = np.gradient(q, data.time, axis=0)
    ddq = np.gradient(dq, data.time, axis=0)
    trim = int(np.ceil((trim_s if trim_s is not None else 3.0 / cutoff_hz) * fs))
    valid = np.zeros(data.n_samples, bool)
    valid[trim : data.n_samples - trim] = True
    return States(q, dq, ddq, valid)


DERIVATIVES: dict[str, Callable[..., States]] = {"butterworth": _butterworth, "simulator": _simulator}


def derive_states(data: Dataset, method: str, **options: float) -> States:
    """q, dq, ddq of `data` by the named method (see `DERIVATIVES`), with its options."""
    if method not in DERIVATIVES:
        raise ValueError(f"unknown derivative method {method!r}; valid choices: {', '.join(sorted(DERIVATIVES))}")
    return DERIVATIVES[method](data, **options)

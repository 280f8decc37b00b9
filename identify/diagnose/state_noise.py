"""How much of the nominal model's torque along a record is the angles' own noise, differentiated.

Every column the diagnosis fits is built from states derived from the logged angles (q, then dq and ddq through
the derivative filter). Noise on the angles reaches the model torque through ddq, amplified by the square of the
frequency up to the filter's cut-off. A fit of the measured torque on columns that carry such noise is a fit with
errors in the variables: every coefficient is pulled towards zero. With `share` the noise's variance over the
model torque's (in the band), the measured torque regressed on the model torque has a slope of 1 / (1 + share),
not 1: the model torque's own scale (a torque gain), the inertias and the delays are then biased by what the
noise is, and would be reported as findings (tests/test_diagnose_state_noise.py checks that slope).

`state_noise_share` measures that share per joint. It estimates the angle noise from the log's third
differences (the motion's own third difference at these rates is orders of magnitude smaller), runs white noise
of that size through the same derivative filter, and compares the model torque it moves with the model torque
itself, both in the analysis band.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from dynamics.errors import DataError
from dynamics.plant import Plant
from dynamics.torque import joint_torque
from envs.dataset import Dataset
from identify.derivatives import States, derive_states, state_cutoff_hz
from identify.diagnose.anomalies import moving_joints
from identify.diagnose.candidates import band_lowpass

__all__ = [
    "STATE_NOISE_SHARE",
    "angle_noise",
    "check_full_rate_state_noise",
    "check_state_noise",
    "state_noise_share",
    "state_noise_torque",
]

STATE_NOISE_SHARE = 0.05  # most of the model torque's variance (in the band) that may be the angles' noise
_THIRD_DIFFERENCE_GAIN = np.sqrt(20.0)  # std of the third difference of white noise of std 1
_UNFILTERED = ("given", "simulator")  # states that do not come from differentiating the logged angle


def angle_noise(q: np.ndarray) -> np.ndarray:
    """(nv,) the white-noise std of each logged angle [rad], robustly from its third differences.

    Args:
        q: (N, nv) the angles as logged (before any filter).
    """
    if len(q) < 8:
        return np.zeros(q.shape[1])
    d3 = np.diff(q, 3, axis=0)
    d3 = d3 - np.median(d3, axis=0)
    return 1.4826 * np.median(np.abs(d3), axis=0) / _THIRD_DIFFERENCE_GAIN  # type: ignore[no-any-return]


def state_noise_share(tau_band: np.ndarray, noise_band: np.ndarray | None) -> np.ndarray:
    """(nv,) the share of the variance of the nominal torque along the record that the angles' noise makes.

    Args:
        tau_band: (M, nv) the nominal torque on the rows from the first to the last valid one, in the analysis
            band (`Signals.smooth`).
        noise_band: (M, nv) what the angles' noise adds to it (`state_noise_torque`), in the same band, or None
            (a share of 0).

    Returns:
        0 for every joint where there is no such noise (`given`, `simulator` states, noiseless angles) or the
        model torque does not vary.
    """
    if noise_band is None:
        return np.zeros(tau_band.shape[1])
    var = np.var(tau_band, axis=0)
    return np.where(var > 0, np.var(noise_band, axis=0) / np.maximum(var, 1e-300), 0.0)  # type: ignore[no-any-return]


def state_noise_torque(
    plant: Plant,
    data: Dataset,
    states: States,
    tau_nominal: np.ndarray,
    method: str,
    options: dict[str, Any],
    rng: np.random.Generator,
) -> np.ndarray | None:
    """(M, nv) a draw of what the angles' noise adds to the nominal torque along the record (on the rows from the
    first to the last valid one, as `tau_nominal`): white noise of the logged angles' own size (`angle_noise`)
    through the derivative filter and the model. None where the states do not come from the angles or the
    angles carry no noise."""
    sigma = angle_noise(data.q)
    if method in _UNFILTERED or not np.any(sigma > 0):
        return None
    noise = dataclasses.replace(data, q=rng.normal(0.0, 1.0, data.q.shape) * sigma, dq=None)
    moved = derive_states(noise, method, **options)
    valid = np.flatnonzero(states.valid)
    rows = np.arange(valid[0], valid[-1] + 1)
    q, dq, ddq = states.q[rows], states.dq[rows], states.ddq[rows]
    return joint_torque(plant, q + moved.q[rows], dq + moved.dq[rows], ddq + moved.ddq[rows])[0] - tau_nominal


def check_state_noise(
    plant: Plant,
    data: Dataset,
    share: np.ndarray,
    method: str,
    options: dict[str, Any],
    *,
    moving: np.ndarray,
    band_hz: float | None = None,
) -> None:
    """Refuse a record whose angles are so noisy, at this derivative filter, that more than `STATE_NOISE_SHARE`
    of the model torque's variance on an actuated joint that moves is their noise (see the module docstring).

    Args:
        plant, data, method, options: as `state_noise_share`.
        share: (nv,) its result.
        moving: (nv,) False for a joint that never moves in the record (its torque is not fitted there).
        band_hz: the analysis band, for the message.

    Raises:
        DataError: the file, the joint, the angle noise, the share, and the cut-off that would bring the share
            to half the limit (the share falls about as the fourth power of the cut-off).
    """
    share = np.where(np.asarray(plant.actuated, bool) & moving, share, 0.0)
    j = int(np.argmax(share))
    if share[j] <= STATE_NOISE_SHARE:
        return
    sigma = angle_noise(data.q)
    cutoff = state_cutoff_hz(data, method, **options)
    limit = min(c for c in (cutoff, band_hz) if c is not None) if (cutoff or band_hz) else None
    lower = (
        f"; lower diagnose.cutoff_hz{' and diagnose.band_hz' if band_hz and cutoff and band_hz < cutoff else ''} "
        f"to about {limit * (0.5 * STATE_NOISE_SHARE / share[j]) ** 0.25:.3g} Hz (if the motion has content above "
        "that, the angles are too noisy for this diagnosis)"
        if limit
        else ""
    )
    band = f", analysis band {band_hz:g} Hz" if band_hz else ""
    raise DataError(
        f"{data.source}: the angles' noise (std {', '.join(f'{s:.3g}' for s in sigma)} rad, from their third "
        f"differences) adds noise of {share[j]:.0%} of the variance of the model torque at {plant.joint_names[j]} "
        f"through the derivative filter ({method}{f', cut-off {cutoff:.3g} Hz' if cutoff else ''}{band}), more than "
        f"the {STATE_NOISE_SHARE:.0%} the diagnosis accepts: fitted on it, every effect that scales the model torque "
        f"(a gain, an inertia, a delay) would be pulled towards zero, the model torque's scale to 1 / (1 + "
        f"{share[j]:.2g}) (errors in the variables)"
        f"{lower}"
    )


_FULL_RATE_ROWS = 1 << 18  # rows of a long log the full-rate check reads (its noise and motion are stationary enough)


def check_full_rate_state_noise(
    plant: Plant,
    data: Dataset,
    method: str,
    options: dict[str, Any],
    *,
    band_hz: float | None = None,
    rng: np.random.Generator | None = None,
) -> None:
    """`check_state_noise` on a log that is about to be thinned (`diagnose.max_rows`): once its states are derived
    and every k-th row kept ('given' states), the angles no longer show their noise, so the check runs here, on
    the log as logged (its first `_FULL_RATE_ROWS` rows), with the derivative filter and band the states come from.

    Raises:
        DataError: as `check_state_noise`.
    """
    if method in _UNFILTERED:
        return
    head = data if data.n_samples <= _FULL_RATE_ROWS else data.slice(0, _FULL_RATE_ROWS)
    states = derive_states(head, method, **options)
    valid = np.flatnonzero(states.valid)
    if valid.size < 10:
        return
    rows = np.arange(valid[0], valid[-1] + 1)
    tau_nominal = joint_torque(plant, states.q[rows], states.dq[rows], states.ddq[rows])[0]
    fs = 1.0 / head.dt

    def smooth(x: np.ndarray) -> np.ndarray:
        return band_lowpass(x, fs, band_hz)

    rng = rng or np.random.default_rng(0)
    noise = state_noise_torque(plant, head, states, tau_nominal, method, options, rng)
    share = state_noise_share(smooth(tau_nominal), None if noise is None else smooth(noise))
    moving = moving_joints(data, plant.hinge)
    check_state_noise(plant, head, share, method, options, moving=moving, band_hz=band_hz)

"""Joint velocities and accelerations from sampled positions, chosen by name.

- `simulator`: the simulator's exact states (only simulated datasets carry them): the noise-free reference.
- `butterworth`: zero-phase Butterworth low-pass of q (filtfilt), then central differences. The filter's
  edge effects are either trimmed (`edges="trim"`) or avoided by periodic padding (`edges="periodic"`, for
  records that span whole periods of a periodic excitation). Its cut-off is at most an eighth of the rate
  (`differences_cutoff_limit_hz`): above it the differences lose a fifth of the acceleration and more.
- `spectral`: differentiation in the frequency domain (multiplication by i omega) over the whole periods of
  a periodic excitation: exact for a band-limited periodic signal, no edge effects, and with
  `harmonics_only` every bin that is not a harmonic of the excitation (pure noise) is dropped.
- `kalman`: Rauch-Tung-Striebel smoother of a white-jerk model (state q, dq, ddq per joint), with the
  jerk intensity chosen so that the smoother's (zero-phase, 6th-order) cut-off sits at `cutoff_hz`.
- `given`: the dataset's own q, dq and ddq, derived before (`reduce_record`: a long record's states derived at
  its full rate, then thinned to what its band needs).

Every method takes `cutoff_hz` (None: `cutoff_factor` times the excitation's bandwidth, measured from the
spectrum of q by `excitation_bandwidth_hz`) and `decimate` (keep every k-th row: the filtered signals carry
nothing above the cut-off, so neighbouring rows are strongly correlated and add little information).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import linalg, signal

from dynamics.errors import DataError
from envs.dataset import Dataset

__all__ = [
    "DERIVATIVES",
    "FOURTH_ORDER_BAND",
    "States",
    "derive_states",
    "differences_cutoff_limit_hz",
    "differences_cutoff_problem",
    "excitation_bandwidth_hz",
    "gradient",
    "reduce_record",
    "reduction_factor",
    "state_cutoff_hz",
]


@dataclass(frozen=True)
class States:
    """Joint states for the regressor, with the rows the method trusts.

    Attributes:
        q, dq, ddq: (N, nv) [rad, rad/s, rad/s^2].
        valid: (N,) False where a filter's edge effects make the row unreliable (or decimation drops it).
    """

    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    valid: np.ndarray


def excitation_bandwidth_hz(q: np.ndarray, sample_rate_hz: float, *, snr: float = 1e3) -> float:
    """Highest frequency at which the motion stands clearly above the measurement noise.

    The periodogram of each (Hann-windowed, detrended) joint angle is compared with its noise floor (the
    median of the upper half of the spectrum); the bandwidth is the highest frequency below fs/4 whose power
    exceeds `snr` times that floor, the largest over joints.

    Args:
        q: (N, nv) joint angles [rad].
        sample_rate_hz: sampling rate [Hz].
        snr: power ratio over the noise floor that counts as motion.

    Returns:
        The bandwidth [Hz] (at least two frequency bins).
    """
    n = len(q)
    x = signal.detrend(q, axis=0) * np.hanning(n)[:, None]
    power = np.abs(np.fft.rfft(x, axis=0)) ** 2
    f = np.fft.rfftfreq(n, 1.0 / sample_rate_hz)
    upper = f > sample_rate_hz / 4
    floor = np.median(power[upper], axis=0) + 1e-30 * np.max(power, axis=0) + 1e-300
    above = (power > snr * floor) & ~upper[:, None]
    hits = np.flatnonzero(np.any(above, axis=1))
    return float(max(f[hits[-1]] if hits.size else 0.0, 2 * f[1]))


_GRADIENT_BLOCK = 1 << 16


def gradient(f: np.ndarray, x: np.ndarray) -> np.ndarray:
    """`np.gradient(f, x, axis=0)` (second-order central differences on a non-uniform grid, first-order at the
    ends), bit for bit, computed a block of rows at a time: numpy's builds five full-length temporaries, which
    on a long log are several times the signal.

    Args:
        f: (N,) or (N, m) samples.
        x: (N,) strictly increasing sample points.
    """
    n = len(x)
    if n < 2:
        raise ValueError(f"a gradient needs at least 2 samples, got {n}")
    out = np.empty(f.shape, dtype=np.result_type(f, x, float))
    col = (slice(None),) + (None,) * (f.ndim - 1)  # broadcast the spacing over f's other axes
    for start in range(1, n - 1, _GRADIENT_BLOCK):
        stop = min(start + _GRADIENT_BLOCK, n - 1)
        dx = np.diff(x[start - 1 : stop + 1])
        dx1, dx2 = dx[:-1], dx[1:]
        a = -(dx2) / (dx1 * (dx1 + dx2))
        b = (dx2 - dx1) / (dx1 * dx2)
        c = dx1 / (dx2 * (dx1 + dx2))
        out[start:stop] = a[col] * f[start - 1 : stop - 1] + b[col] * f[start:stop] + c[col] * f[start + 1 : stop + 1]
    out[0] = (f[1] - f[0]) / (x[1] - x[0])
    out[-1] = (f[-1] - f[-2]) / (x[-1] - x[-2])
    return out


# The fourth-order terms are added where second-order differences lose more than `SECOND_ORDER_LOSS` of the
# acceleration at the cut-off ((sin x / x)^2 at x = w h: above 1/36 of the rate; a 100 Hz log at 10 Hz, not a 500 Hz
# one, whose states stay as they were) and where the filter keeps no more than `FOURTH_ORDER_BAND` of the rate
# (x <= pi / 4): Taylor terms, they amplify what is left near the Nyquist rate (the fourth difference by 16 / 3 at
# x = pi, where the gradient of the gradient passes nothing), at a cut-off of 0.4 of the rate the filter's start-up.
SECOND_ORDER_LOSS = 0.01
FOURTH_ORDER_BAND = 0.125


def _needs_fourth_order(cutoff: float, fs: float) -> bool:
    x = 2 * np.pi * cutoff / fs
    return bool(
        1 - (np.sin(x) / x) ** 2 > SECOND_ORDER_LOSS and cutoff <= FOURTH_ORDER_BAND * fs * (1 + _RATE_TOLERANCE)
    )


def _fourth_order(q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, h: float) -> None:
    """Raise `dq` = `gradient`(q) and `ddq` = `gradient`(dq) (second order) to fourth order in place, on the rows
    with two neighbours each side, by their leading truncation terms on the uniform step h: q''' h^2 / 6 and
    q'''' h^2 / 3. A sine of x = w h radians per sample came out scaled by sin(x) / x and (sin(x) / x)^2: at a
    100 Hz log's 10 Hz cut-off 0.94 and 0.83 (clean two-link data were named a shoulder torque gain of 1.0015
    and an elbow armature), now 1 - x^4 / 30 and 1 - x^4 / 90 to leading order (0.995 and 0.998 there).

    The terms are those of the uniform grid (a log's step jitters by 1 % at most, `_regular_fs`); the second-order
    part keeps the actual time stamps."""
    if len(q) < 5:
        return
    inner = slice(2, len(q) - 2)
    third, fourth = _differences(q)
    dq[inner] -= third / (12 * h)
    ddq[inner] -= fourth / (3 * h**2)


def _differences(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The central third and fourth differences of `x` (N, ...) on its rows with two neighbours each side (N - 4):
    2 h^3 x''' and h^4 x'''' to leading order."""
    third = (x[4:] - x[:-4]) - 2 * (x[3:-1] - x[1:-3])
    fourth = (x[4:] + x[:-4]) - 4 * (x[3:-1] + x[1:-3]) + 6 * x[2:-2]
    return third, fourth


def _regular_fs(data: Dataset) -> float:
    jitter = np.max(np.abs(np.diff(data.time) - data.dt)) / data.dt
    if jitter > 0.01:
        raise DataError(f"{data.source}: sampling is irregular ({jitter:.1%} step jitter); resample it first")
    return 1.0 / data.dt


def differences_cutoff_limit_hz(fs: float) -> float:
    """The highest cut-off [Hz] of the `butterworth` method at sampling rate `fs` [Hz]: `FOURTH_ORDER_BAND` of it
    (an eighth). Up to it the differences are made exact to 0.4 % of the acceleration (`_fourth_order`); above it
    they are second-order only and lose (sin x / x)^2 of it, a fifth at fs / 8 and more above: on clean two-link
    logs at 500 Hz a 120 Hz cut-off named a rigid-body change that is not there (sysid-run's, compared below 120 Hz;
    the testbed's, below 62.5 Hz), 60 Hz none."""
    return FOURTH_ORDER_BAND * fs


_RATE_TOLERANCE = 0.02  # a cut-off set at the limit passes a log whose median step jitters (1 % at most)


def differences_cutoff_problem(cutoff_hz: float, fs: float, sampled: str) -> str | None:
    """What is wrong with a `butterworth` cut-off [Hz] above `differences_cutoff_limit_hz` of `fs` (within the rate's
    jitter), for a message that names the key before it and `sampled` (what sampled at fs: a file, a setting); None
    where it is within the limit."""
    top = differences_cutoff_limit_hz(fs)
    if cutoff_hz <= top * (1 + _RATE_TOLERANCE):
        return None
    return (
        f"{cutoff_hz:g} Hz is above {top:g} Hz, an eighth of {sampled}: the differences that make the accelerations "
        "lose a fifth of them there and more above"
    )


def _cutoff(
    data: Dataset, fs: float, cutoff_hz: float | None, cutoff_factor: float, *, differences: bool = False
) -> float:
    """The filter's cut-off [Hz]: `cutoff_hz`, or `cutoff_factor` times the excitation's bandwidth; with
    `differences` (states by finite differences) at most `differences_cutoff_limit_hz`, an explicit one above it
    refused, otherwise at most 0.4 of the rate."""
    top = differences_cutoff_limit_hz(fs) if differences else 0.4 * fs
    if cutoff_hz is None:
        cutoff_hz = min(cutoff_factor * excitation_bandwidth_hz(data.q, fs), top)
    if not 0 < cutoff_hz < 0.5 * fs:
        raise ValueError(f"cutoff_hz must lie in (0, {0.5 * fs:g}) Hz for a {fs:g} Hz signal, got {cutoff_hz}")
    problem = differences_cutoff_problem(cutoff_hz, fs, f"its {fs:g} Hz sampling") if differences else None
    if problem:
        raise DataError(
            f"{data.source}: cutoff_hz={problem}; lower it (or derive the states by the 'spectral' or 'kalman' method)"
        )
    return float(cutoff_hz)


def _decimated(valid: np.ndarray, decimate: int) -> np.ndarray:
    if int(decimate) < 1:
        raise ValueError(f"decimate must be a positive integer, got {decimate}")
    out = valid.copy()
    out[np.arange(len(valid)) % int(decimate) != 0] = False
    return out


def _whole_periods(data: Dataset, period_s: float | None) -> int:
    """Number of leading samples that span whole periods (all of them when period_s is None)."""
    if period_s is None:
        return data.n_samples
    per = period_s / data.dt
    if abs(per - round(per)) > 1e-6 * per:
        raise ValueError(f"period_s = {period_s} s is not a whole number of {data.dt:g} s samples")
    periods = data.n_samples // int(round(per))
    if periods < 1:
        raise DataError(f"{data.source}: the record ({data.n_samples} samples) is shorter than one period")
    return periods * int(round(per))


def _simulator(data: Dataset, *, decimate: int = 1, **_: Any) -> States:
    """The exact states (options of the other methods, such as `cutoff_hz`, are accepted and ignored)."""
    if data.ddq is None or "q_true" not in data.meta:
        raise DataError(f"{data.source}: derivatives='simulator' needs a simulated dataset with its exact states")
    valid = _decimated(np.ones(data.n_samples, bool), decimate)
    return States(data.meta["q_true"], data.meta["dq_true"], data.ddq, valid)


def _given(data: Dataset, *, decimate: int = 1, **_: Any) -> States:
    """The dataset's own q, dq, ddq (options of the other methods, such as `cutoff_hz`, are accepted and ignored)."""
    if data.dq is None or data.ddq is None:
        raise DataError(f"{data.source}: derivatives='given' needs dq and ddq in the data; use butterworth")
    return States(data.q, data.dq, data.ddq, _decimated(np.ones(data.n_samples, bool), decimate))


def _butterworth(
    data: Dataset,
    *,
    cutoff_hz: float | None = None,
    cutoff_factor: float = 4.0,
    order: int = 4,
    trim_s: float | None = None,
    edges: str = "trim",
    period_s: float | None = None,
    decimate: int = 1,
) -> States:
    fs = _regular_fs(data)
    cutoff = _cutoff(data, fs, cutoff_hz, cutoff_factor, differences=True)
    sos = signal.butter(order, cutoff, fs=fs, output="sos")
    if edges == "trim":
        if data.n_samples <= 3 * (2 * len(sos) + 1):  # not longer than SciPy's padding (at most this): none trusted
            return States(data.q, data.q, data.q, np.zeros(data.n_samples, bool))
        q = signal.sosfiltfilt(sos, data.q, axis=0)
        dq = gradient(q, data.time)
        ddq = gradient(dq, data.time)
        if _needs_fourth_order(cutoff, fs):
            _fourth_order(q, dq, ddq, data.dt)
        trim = int(np.ceil((trim_s if trim_s is not None else 3.0 / cutoff) * fs))
        valid = np.zeros(data.n_samples, bool)
        valid[trim : data.n_samples - trim - 1] = True
    elif edges == "periodic":
        n = _whole_periods(data, period_s)
        q, dq, ddq = (np.array(data.q) for _ in range(3))
        pad = min(n, int(np.ceil(6.0 / cutoff * fs)) + 20 * order)  # long enough for the ringing near Nyquist
        wrapped = np.concatenate([data.q[n - pad : n], data.q[:n], data.q[:pad]])
        smooth = signal.sosfiltfilt(sos, wrapped, axis=0, padtype=None)[pad : pad + n]
        q[:n] = smooth
        ahead, behind = np.roll(smooth, -1, axis=0), np.roll(smooth, 1, axis=0)
        dq[:n] = (ahead - behind) * (0.5 * fs)
        ddq[:n] = (ahead - 2 * smooth + behind) * fs**2
        if _needs_fourth_order(cutoff, fs):  # as `_fourth_order`, on the three-point second difference
            third, fourth = _differences(np.concatenate([smooth[-2:], smooth, smooth[:2]]))  # one period, wrapped
            dq[:n] -= third * (fs / 12)
            ddq[:n] -= fourth * (fs**2 / 12)
        valid = np.arange(data.n_samples) < n
    else:
        raise ValueError(f"unknown edges {edges!r}; valid choices: periodic, trim")
    return States(q, dq, ddq, _decimated(valid, decimate))


def _spectral(
    data: Dataset,
    *,
    period_s: float | None = None,
    cutoff_hz: float | None = None,
    cutoff_factor: float = 4.0,
    harmonics_only: bool = True,
    decimate: int = 1,
) -> States:
    fs = _regular_fs(data)
    n = _whole_periods(data, period_s)
    cutoff = _cutoff(data, fs, cutoff_hz, cutoff_factor)
    spectrum = np.fft.rfft(data.q[:n], axis=0)
    f = np.fft.rfftfreq(n, 1.0 / fs)
    keep = f <= cutoff
    if harmonics_only and period_s is not None:
        periods = n // int(round(period_s * fs))
        keep &= np.arange(len(f)) % periods == 0
    spectrum[~keep] = 0.0
    jw = (2j * np.pi * f)[:, None]
    q, dq, ddq = (np.array(data.q) for _ in range(3))
    q[:n] = np.fft.irfft(spectrum, n, axis=0)
    dq[:n] = np.fft.irfft(jw * spectrum, n, axis=0)
    ddq[:n] = np.fft.irfft(jw**2 * spectrum, n, axis=0)
    return States(q, dq, ddq, _decimated(np.arange(data.n_samples) < n, decimate))


def _kalman(
    data: Dataset,
    *,
    cutoff_hz: float | None = None,
    cutoff_factor: float = 4.0,
    sigma_q: float | None = None,
    trim_s: float | None = None,
    decimate: int = 1,
) -> States:
    """Steady-state RTS smoother of q'''= w (white jerk), one independent filter per joint.

    The smoother's gain |H(f)| = 1 / (1 + (f / f_c)^6) has f_c = (s / (R dt))^(1/6) / (2 pi) for jerk
    intensity s and measurement variance R; s is set from the requested cut-off. R (`sigma_q`, [rad]) only
    fixes the scale, so its default (the high-frequency noise of q itself) matters little.
    """
    fs = _regular_fs(data)
    dt = 1.0 / fs
    cutoff = _cutoff(data, fs, cutoff_hz, cutoff_factor)
    if sigma_q is None:
        sigma_q = float(np.median(np.std(np.diff(data.q, 3, axis=0), axis=0)) / np.sqrt(20.0))
    r = max(sigma_q, 1e-9) ** 2
    s = r * dt * (2 * np.pi * cutoff) ** 6
    A = np.array([[1.0, dt, dt**2 / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    Q = s * np.array(
        [[dt**5 / 20, dt**4 / 8, dt**3 / 6], [dt**4 / 8, dt**3 / 3, dt**2 / 2], [dt**3 / 6, dt**2 / 2, dt]]
    )
    H = np.array([[1.0, 0.0, 0.0]])
    P_pred = linalg.solve_discrete_are(A.T, H.T, Q, np.array([[r]]))
    K = P_pred @ H.T / (P_pred[0, 0] + r)  # (3, 1)
    P_filt = (np.eye(3) - K @ H) @ P_pred
    G = P_filt @ A.T @ np.linalg.inv(P_pred)
    # batched over joints: x has shape (3, nv)
    n, nv = data.q.shape
    xf = np.empty((n, 3, nv))
    x = np.vstack([data.q[0], np.zeros((2, nv))])
    F, Kz = A - K @ H @ A, K[:, 0]
    for k in range(n):
        x = F @ x + np.outer(Kz, data.q[k]) if k else x
        xf[k] = x
    xs = np.empty_like(xf)
    xs[-1] = xf[-1]
    for k in range(n - 2, -1, -1):
        xs[k] = xf[k] + G @ (xs[k + 1] - A @ xf[k])
    trim = int(np.ceil((trim_s if trim_s is not None else 3.0 / cutoff) * fs))
    valid = np.zeros(n, bool)
    valid[trim : n - trim - 1] = True
    return States(xs[:, 0], xs[:, 1], xs[:, 2], _decimated(valid, decimate))


def _shift(x: np.ndarray, samples: float) -> np.ndarray:
    """x evaluated `samples` sample intervals later (any real number: whole rows, then linear interpolation between
    neighbours); the rows it would take from beyond an end hold that end's value (`_shifted_valid` marks them)."""
    if samples == 0:
        return x
    whole = int(np.floor(samples + 1e-9))  # a whole number of rows, to the round-off of the times it came from
    part = max(samples - whole, 0.0)
    n = len(x)
    rows = np.clip(np.arange(n) + whole, 0, n - 1)
    if part <= 1e-12:
        return x[rows]  # type: ignore[no-any-return]
    after = np.clip(np.arange(n) + whole + 1, 0, n - 1)
    return (1 - part) * x[rows] + part * x[after]  # type: ignore[no-any-return]


def _shifted_valid(valid: np.ndarray, samples: float) -> np.ndarray:
    """(N,) the trusted rows whose states, `samples` later, come from trusted rows within the record (`_shift`)."""
    n = len(valid)
    lo, hi = int(np.floor(samples + 1e-9)), int(np.ceil(samples - 1e-9))
    out = valid.copy()
    for k in {lo, hi}:
        src = np.arange(n) + k
        inside = (src >= 0) & (src < n)
        out &= inside & valid[np.clip(src, 0, n - 1)]
    return out


DERIVATIVES: dict[str, Callable[..., States]] = {
    "butterworth": _butterworth,
    "given": _given,
    "kalman": _kalman,
    "simulator": _simulator,
    "spectral": _spectral,
}


def state_cutoff_hz(data: Dataset, method: str, **options: Any) -> float | None:
    """The cut-off [Hz] of the filter the states of `derive_states(data, method, **options)` went through: the
    method's `cutoff_hz`, or the one it derives from the excitation; for `given` states, the cut-off they were
    derived with where `reduce_record` says so (`meta["reduced"]`); None for exact states."""
    if method == "simulator":
        return None
    if method == "given":
        derived = data.meta.get("reduced", {}).get("derivatives", {})
        cutoff = derived.get("cutoff_hz")
        return float(cutoff) if cutoff is not None and derived.get("method") not in ("simulator", "given") else None
    fs = 1.0 / float(np.median(np.diff(data.time)))
    return _cutoff(
        data,
        fs,
        options.get("cutoff_hz"),
        float(options.get("cutoff_factor", 4.0)),
        differences=method == "butterworth",
    )


MIN_TRUSTED_ROWS = 10  # fewest rows the derivative filter must trust in a record


def derive_states(data: Dataset, method: str, **options: Any) -> States:
    """q, dq, ddq of `data` by the named method (see `DERIVATIVES`), with its options.

    Raises:
        ValueError: unknown method (the message lists the valid ones) or a bad option.
        DataError: the filter's start-up at both ends leaves fewer than `MIN_TRUSTED_ROWS` rows.
    """
    if method not in DERIVATIVES:
        raise ValueError(f"unknown derivative method {method!r}; valid choices: {', '.join(sorted(DERIVATIVES))}")
    states = DERIVATIVES[method](data, **options)
    if method not in ("simulator", "given") and data.tau_lead_s != 0:
        # Evaluate the (smooth, filtered) states at the instant the reported torque belongs to: a zero-order
        # hold's half-sample offset would otherwise bias the parameters by about two standard deviations. A lead
        # of a sample or more (a drive's lag behind a commanded torque, angles reported late) moves whole rows.
        # The simulator's states already belong to the instant of the torque.
        samples = data.tau_lead_s / data.dt
        states = States(
            _shift(states.q, samples),
            _shift(states.dq, samples),
            _shift(states.ddq, samples),
            _shifted_valid(states.valid, samples),
        )
    trusted = int(np.count_nonzero(states.valid))
    if trusted < MIN_TRUSTED_ROWS:
        span = float(data.time[-1] - data.time[0])
        cutoff = state_cutoff_hz(data, method, **options)
        trim_s = options.get("trim_s")
        edge = ""
        if cutoff:
            edge = f" ({trim_s if trim_s is not None else 3.0 / cutoff:.3g} s at each end at {cutoff:.3g} Hz)"
        raise DataError(
            f"{data.source}: the derivative filter ({method}) trusts {trusted} of the {data.n_samples} rows: "
            f"its start-up{edge} takes the whole record, which lasts {span:.4g} s at {1.0 / data.dt:.4g} Hz by its "
            "time column. Give a longer record, or check that the time column is in seconds (a 500 Hz log timed in "
            "minutes reads as 30 kHz over a sixtieth of its length)"
        )
    return states


# A reduced record keeps its rate at least this many times the band it must carry: states band-limited at
# the cut-off (order-8 zero-phase roll-off) alias by less than -17 dB at 1.25 x the cut-off.
_RATE_PER_BAND = 2.5


def reduction_factor(n_rows: int, sample_rate_hz: float, *, max_rows: int, band_hz: float) -> int:
    """Every how many rows a long record keeps one: enough to bring `n_rows` to `max_rows`, but never so many
    that the kept rate falls below 2.5 x `band_hz` (the derivative cut-off, or the analysis band if higher).

    Returns:
        k >= 1 (1: the record is kept whole).
    """
    if n_rows <= max_rows:
        return 1
    wanted = int(np.ceil(n_rows / max_rows))
    allowed = int(np.floor(sample_rate_hz / (_RATE_PER_BAND * band_hz)))
    return max(1, min(wanted, allowed))


def reduce_record(data: Dataset, method: str, factor: int, **options: Any) -> Dataset:
    """A long record thinned to every `factor`-th row, with the states derived at its full rate first.

    The states come from `derive_states` on the whole record, one joint at a time (so the derivative filter
    sees every sample, and memory is the record plus one joint's states); rows the method does not trust are
    dropped. States and torques then pass the same zero-phase 4th-order Butterworth anti-alias filter, at the
    kept rate / 2.5, before every `factor`-th row is kept: one linear filter on both sides of the dynamics,
    which leaves the band below it (where `reduction_factor` keeps the motion) as it was. The result carries
    q, dq, ddq: diagnose it with derivatives='given'.

    Args:
        data: the full-rate record.
        method, options: how its states are derived (`derive_states`).
        factor: keep every factor-th row (>= 1; 1 returns the states of the whole record).

    Returns:
        The reduced record: time, q, dq, ddq, tau (and tau_cmd) on the kept rows, `tau_lead_s` 0 (the states
        already belong to the torque's instant), and `meta["reduced"]` saying what was done.
    """
    if int(factor) < 1:
        raise ValueError(f"factor must be a positive integer, got {factor}")
    factor = int(factor)
    fs = _regular_fs(data)
    anti_alias = fs / factor / _RATE_PER_BAND
    sos = signal.butter(4, anti_alias, fs=fs, output="sos") if factor > 1 else None

    def thin(x: np.ndarray, keep: np.ndarray) -> np.ndarray:
        """x (N,) or (N, m) filtered and thinned, a column at a time (the filter's copies are one column's)."""
        if x.ndim == 2:
            return np.column_stack([thin(x[:, j], keep) for j in range(x.shape[1])])
        return (x if sos is None else signal.sosfiltfilt(sos, x))[keep]

    if options.get("cutoff_hz") is None and method not in ("simulator", "given"):  # one cut-off for all joints
        derived = _cutoff(data, fs, None, float(options.get("cutoff_factor", 4.0)), differences=method == "butterworth")
        options = {**options, "cutoff_hz": derived}
    keep: np.ndarray | None = None
    blocks: dict[str, list[np.ndarray]] = {"q": [], "dq": [], "ddq": []}
    for j, name in enumerate(data.joint_names):
        one = Dataset(
            time=data.time,
            q=data.q[:, j : j + 1],
            tau=data.tau[:, j : j + 1],
            joint_names=(name,),
            actuated=np.asarray(data.actuated)[j : j + 1],
            source=data.source,
            tau_lead_s=data.tau_lead_s,
        )
        states = derive_states(one, method, **options)
        if keep is None:
            trusted = np.flatnonzero(states.valid)
            if trusted.size < 2:
                raise DataError(f"{data.source}: no rows left after the derivative filter's edges")
            keep = np.arange(trusted[0], trusted[-1] + 1, factor)
        parts = [states.q, states.dq, states.ddq]
        del states, one
        for key in blocks:  # each full-rate state goes as soon as it is thinned
            blocks[key].append(thin(parts.pop(0), keep))
    assert keep is not None
    meta = {k: v for k, v in data.meta.items() if not isinstance(v, np.ndarray)}  # full-rate arrays stay behind
    meta["reduced"] = {
        "factor": factor,
        "rows": int(data.n_samples),
        "kept": int(len(keep)),
        "sample_rate_hz": float(fs),
        "kept_rate_hz": float(fs / factor),
        "anti_alias_hz": float(anti_alias) if factor > 1 else None,
        "derivatives": {"method": method, **options},
    }
    return Dataset(
        time=np.ascontiguousarray(data.time[keep]),
        q=np.hstack(blocks["q"]),
        tau=thin(data.tau, keep),
        joint_names=data.joint_names,
        actuated=data.actuated,
        dq=np.hstack(blocks["dq"]),
        ddq=np.hstack(blocks["ddq"]),
        tau_cmd=None if data.tau_cmd is None else thin(data.tau_cmd, keep),
        source=data.source,
        tau_lead_s=0.0,
        meta=meta,
    )

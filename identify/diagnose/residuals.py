"""What the residual torque looks like: its size against the noise floor, its spectrum, what it correlates
with, where in the motion it is worst, and whether it is white.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import signal, stats

from identify.diagnose.candidates import Signals, period_edge, position_harmonic
from identify.diagnose.statistics import correlation_time

__all__ = [
    "analyse_residual",
    "changing_coefficient",
    "changing_offsets",
    "describe_signature",
    "noise_floor",
    "residual_signature",
    "whiteness",
]


def noise_floor(tau: np.ndarray) -> np.ndarray:
    """(nv,) std of the white part of measured torque (N, nv) [N m], from its third differences.

    The third difference of white noise of std s has variance 20 s^2, while a smooth motion's torque
    (a few Hz sampled at hundreds of Hz) all but vanishes in it; quantisation counts as noise.
    """
    d3 = np.diff(tau, 3, axis=0)
    mad = np.median(np.abs(d3 - np.median(d3, axis=0)), axis=0) * 1.4826
    return np.minimum(np.std(d3, axis=0), np.where(mad > 0, mad, np.inf)) / np.sqrt(20.0)


def changing_offsets(
    e: np.ndarray,
    record: np.ndarray,
    names: tuple[str, ...],
    actuated: np.ndarray,
    floor: np.ndarray,
    sources: list[str],
    *,
    exclude: frozenset[tuple[str, str]] = frozenset(),
    alpha: float = 1e-3,
    min_correlation_times: float = 10.0,
) -> list[dict[str, Any]]:
    """Joints whose residual has a different mean in each record: for example a torque zero that changes between
    recordings (a sensor re-zeroed at power-up), or a load that does.

    Per actuated joint, the records' mean residuals are compared with what their noise allows: each mean's
    std is the record's residual std times sqrt(tau_int / n), with tau_int the record's own integrated
    autocorrelation time (records shorter than `min_correlation_times` tau_int are left out: their mean is
    not known well enough). The spread is named where the chi-square of the means about their weighted mean
    has a p-value below `alpha` and the means span at least the torque noise floor.

    Args:
        e: (N, nv) residual left by the fit, in the analysis band.
        record: (N,) record index of each row (0 .. R-1).
        names: (nv,) joint names; actuated: (nv,) bool; floor: (nv,) torque noise std [N m].
        sources: (R,) where each record came from.
        exclude: (source, joint) pairs left out: a joint that never moves in that record (its mean is the
            stiction it rests in), a torque that is stuck at zero or saturated there.

    Returns:
        One dict per such joint: joint, per-record `means` [N m] (with their `sources`), `spread` [N m],
        `p_value`; empty with fewer than two usable records.
    """
    out: list[dict[str, Any]] = []
    for j in np.flatnonzero(actuated):
        means, sds, used = [], [], []
        for r in np.unique(record):
            if (sources[int(r)], names[j]) in exclude:
                continue
            x = e[record == r, j]
            tau = correlation_time(x)
            if len(x) < min_correlation_times * tau:
                continue
            # a residual that is constant to rounding has a known mean: its std is held at a tiny fraction of the
            # floor, so that it weighs most without dividing by zero
            sd = max(float(x.std()) * np.sqrt(tau / len(x)), 1e-9 * max(float(floor[j]), 1e-12))
            means.append(float(x.mean()))
            sds.append(sd)
            used.append(sources[int(r)])
        if len(means) < 2:
            continue
        m, sd_arr = np.array(means), np.array(sds)
        w = 1.0 / sd_arr**2
        centre = float(np.sum(w * m) / np.sum(w))
        chi2 = float(np.sum(((m - centre) / sd_arr) ** 2))
        p = float(stats.chi2.sf(chi2, len(means) - 1))
        spread = float(m.max() - m.min())
        if np.isfinite(chi2) and p < alpha and spread >= floor[j]:
            out.append(
                {
                    "joint": names[j],
                    "means": [round(v, 6) for v in means],
                    "sources": used,
                    "spread": spread,
                    "p_value": p,
                }
            )
    return out


def whiteness(
    residual: np.ndarray,
    floor: np.ndarray,
    sample_rate_hz: float,
    *,
    band_hz: float = 10.0,
    lags: int = 20,
    alpha: float = 0.01,
    min_structure: float = 0.5,
    max_excess: float = 1.0,
    state_noise: np.ndarray | None = None,
    own_zeros: np.ndarray | None = None,
) -> list[dict[str, float | bool]]:
    """Per joint: is there structure in the residual beyond white noise?

    The residual is low-passed at `band_hz` (where model errors live) and decimated to 2 band_hz, where
    white noise would give uncorrelated samples of variance floor^2 (2 band_hz / fs): the sensor noise's share of
    the band. With the angles' noise differentiated into the model torque (`state_noise`, whose power in the low
    band the torque sensor's floor does not count) that makes `noise_in_band`, the noise's RMS there. What the
    low band holds beyond it, its mean included (a torque offset is structure too, whatever its scatter), is
    `structured_rms`. Structured means that `structured_rms` exceeds `min_structure` times the noise floor (an
    effect size, so that huge records do not flag harmless colour, such as the state filter's own error on a
    large torque) and the low band is not noise:
    - a Ljung-Box test of it (about its mean) rejects whiteness at level `alpha`, and `structured_rms` exceeds
      `max_excess` times the angles' noise in the band (that noise is coloured by the derivative filter, so the
      test rejects it too; its power is known only from one draw, a few tens of independent samples in a short
      record, and a share of it is no structure), or
    - whatever the test says, the low band holds more than (1 + `max_excess`^2) times `noise_in_band`^2. This
      finds what the correlation test misses: a sensor's dead zone left a residual three times the noise's share
      that Ljung-Box took for white (p 0.5, `explained` by a torque gain of 0.92), and a torque zero that drifted
      within the record left 0.13 N m of mean, which a test about the mean does not see (`no_discrepancy`).

    Args:
        residual: (N, nv) torque residual [N m].
        floor: (nv,) noise floor [N m].
        sample_rate_hz: sampling rate [Hz].
        state_noise: (N, nv) a draw of the torque the angles' noise adds to the model torque on these rows
            (`state_noise.state_noise_torque`, in the analysis band; 0 where a record has none), or None.
        own_zeros: (N,) the record of each row, where every record's torque zero is its own (fitted per record
            as a nuisance): each record's mean residual is then no structure, and is taken out.

    Returns:
        One dict per joint: `ljung_box_p`, `structured_rms` [N m], `noise_in_band` [N m] (the sensor's and the
        angles'), `structured` (bool), `effect_size` [N m] (the least `structured_rms` counted: `min_structure`
        times the floor), `weak` (bool: not structured, yet the test rejects whiteness and `structured_rms`
        exceeds the noise in the band: structure below the effect size).
    """
    band = min(band_hz, 0.45 * sample_rate_hz)
    share = min(2 * band / sample_rate_hz, 1.0)
    sos = signal.butter(4, band, fs=sample_rate_hz, output="sos")
    if own_zeros is not None:
        residual = residual.copy()
        for r in np.unique(own_zeros):
            residual[own_zeros == r] -= residual[own_zeros == r].mean(axis=0)
    mean = residual.mean(axis=0)
    low = signal.sosfiltfilt(sos, residual - mean, axis=0)
    states_var = np.zeros(residual.shape[1])
    if state_noise is not None and len(state_noise) > 24:  # sosfiltfilt's padding needs a few filter lengths
        states_var = np.var(signal.sosfiltfilt(sos, state_noise - state_noise.mean(axis=0), axis=0), axis=0)
    step = max(int(sample_rate_hz / (2 * band)), 1)
    out = []
    for j in range(residual.shape[1]):
        x = low[::step, j]
        n = len(x)
        h = min(lags, n // 4)
        acf = np.array([np.sum(x[k:] * x[: n - k]) for k in range(h + 1)]) / max(float(np.sum(x * x)), 1e-300)
        q_stat = n * (n + 2) * float(np.sum(acf[1:] ** 2 / (n - np.arange(1, h + 1))))
        p = float(stats.chi2.sf(q_stat, h)) if h > 0 else 1.0
        expected = floor[j] ** 2 * share + states_var[j]
        excess = float(np.var(low[:, j]) + mean[j] ** 2 - expected)
        srms = float(np.sqrt(max(excess, 0.0)))
        in_band = max(float(np.sqrt(expected)), 1e-12)
        beyond = float(np.sqrt(states_var[j])) if p < alpha else in_band
        effect_size = min_structure * max(float(floor[j]), 1e-12)
        structured = bool(srms > effect_size and srms > max_excess * beyond)
        out.append(
            {
                "ljung_box_p": p,
                "structured_rms": srms,
                "noise_in_band": float(in_band),
                "structured": structured,
                "effect_size": effect_size,
                "weak": bool(not structured and p < alpha and srms > in_band),
            }
        )
    return out


def analyse_residual(
    s: Signals, joint_names: tuple[str, ...], floor: np.ndarray, *, window_s: float = 0.25
) -> dict[str, Any]:
    """Per joint: RMS against the noise floor, dominant frequencies, correlations with the motion and with
    time-shifted nominal torque, and the window of the motion where the model is worst."""
    r = s.residual
    fs = 1.0 / float(np.median(np.diff(s.time)))
    out: dict[str, Any] = {}
    for j, name in enumerate(joint_names):
        x = r[:, j] - r[:, j].mean()
        f, pxx = signal.welch(x, fs=fs, nperseg=min(1024, len(x)))
        top = np.argsort(pxx)[::-1][:3]
        probes = {"q": s.q[:, j], "dq": s.dq[:, j], "sign_dq": np.sign(s.dq[:, j]), "ddq": s.ddq[:, j]}
        corr = {k: _corr(r[:, j], v) for k, v in probes.items()}
        corr["tau_nominal"] = _corr(r[:, j], s.tau_nominal[:, j])
        lag_s, lag_corr = _best_lag(r[:, j], s.dtau_dt[:, j], s.tau_nominal[:, j], fs)
        win = max(int(window_s * fs), 1)
        power = np.convolve(r[:, j] ** 2, np.ones(win) / win, mode="valid")
        k = int(np.argmax(power))
        fitted = r[:, j] if s.used is None else r[s.used[:, j], j]  # not the torques left out of the fit
        # NaN (null in the JSON) for a joint with no torque fitted (one that never moves, held by its friction)
        rms = float(np.sqrt(np.mean(fitted**2))) if fitted.size else float("nan")
        out[name] = {
            "rms": rms,
            "mean": float(np.mean(fitted)) if fitted.size else float("nan"),
            "noise_floor": float(floor[j]),
            "rms_over_noise": rms / max(float(floor[j]), 1e-12),
            "dominant_hz": [float(f[i]) for i in top],
            "correlation": corr,
            "shifted_torque": {"lag_s": lag_s, "correlation": lag_corr},
            "worst_window": {
                "t_start": float(s.time[k]),
                "rms": float(np.sqrt(power[k])),
                "mean_abs_dq": float(np.mean(np.abs(s.dq[k : k + win, j]))),
                "mean_q": float(np.mean(s.q[k : k + win, j])),
            },
        }
    return out


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    sa, sb = float(np.std(a)), float(np.std(b))
    if sa == 0 or sb == 0:
        return 0.0
    return float(np.mean((a - a.mean()) * (b - b.mean())) / (sa * sb))


def _best_lag(
    r: np.ndarray, dtau: np.ndarray, tau: np.ndarray, fs: float, max_lag_s: float = 0.05
) -> tuple[float, float]:
    """The shift d (|d| <= max_lag_s) for which tau(t - d) - tau(t) best correlates with the residual."""
    best = (0.0, 0.0)
    for k in range(-int(max_lag_s * fs), int(max_lag_s * fs) + 1):
        if k == 0:
            continue
        shifted = np.roll(tau, k) - tau
        c = _corr(r[abs(k) : -abs(k)], shifted[abs(k) : -abs(k)])
        if abs(c) > abs(best[1]):
            best = (k / fs, c)
    return best


def residual_signature(
    s: Signals,
    residual: np.ndarray,
    joint_names: tuple[str, ...],
    floor: np.ndarray,
    *,
    peaks: int = 3,
    slow: np.ndarray | None = None,
) -> dict[str, Any]:
    """Per joint: what a residual left by a model looks like, to say what remains unexplained.

    Args:
        s: the signals the residual lives on (its q, dq, ddq).
        residual: (N, nv) measured minus model torque, in the analysis band [N m].
        floor: (nv,) noise floor [N m].

    Returns:
        Per joint: `rms` [N m] and `rms_over_noise`; `spectral_peaks` [{`hz`, `share`}] (the strongest
        Welch peaks and their share of the residual's power); `correlation` with q, dq, sign(dq), ddq;
        `changes_over_time` (`changing_coefficient`: a coefficient that drifts over each record, or None);
        `position_periodic` {`cycles_per_revolution`, `period_rad`, `amplitude` [N m], `share`}
        (`candidates.position_harmonic`: the best a sin(n q) + b cos(n q) over the periods the motion spans, and
        the share of the residual variance it explains; 0 where it spans none); where `slow` (N, nv) marks the
        rows where each joint is at rest or turns round, `turning_round` {`share_of_rows`, `share_of_residual`}:
        a residual there far above its share of the rows is the friction's shape at low speed, or sticking,
        which the filtered velocity does not resolve.
    """
    fs = 1.0 / float(np.median(np.diff(s.time)))
    out: dict[str, Any] = {}
    for j, name in enumerate(joint_names):
        x = residual[:, j] - residual[:, j].mean()
        total = float(np.sum(x**2))
        if total == 0:
            continue
        f, pxx = signal.welch(x, fs=fs, nperseg=min(2048, len(x)))
        idx, _ = signal.find_peaks(pxx)
        idx = idx[np.argsort(pxx[idx])[::-1][:peaks]] if idx.size else np.argsort(pxx)[::-1][:1]
        probes = {"q": s.q[:, j], "dq": s.dq[:, j], "sign_dq": np.sign(s.dq[:, j]), "ddq": s.ddq[:, j]}
        best = position_harmonic(s, j, x) or (0.0, 0.0, 0.0)
        rms = float(np.sqrt(np.mean(x**2)))
        out[name] = {
            "rms": rms,
            "rms_over_noise": rms / max(float(floor[j]), 1e-12),
            "spectral_peaks": [{"hz": float(f[i]), "share": float(pxx[i] / np.sum(pxx))} for i in idx],
            "correlation": {k: _corr(x, v) for k, v in probes.items()},
            "changes_over_time": changing_coefficient(x, probes, s.record, s.time),
            "position_periodic": {
                "cycles_per_revolution": best[0],
                "period_rad": 2 * np.pi / best[0] if best[0] else float("nan"),
                "amplitude": best[1],
                "share": best[2],
                "edge": period_edge(best[0], s.q[:, j]),  # the residual's own period may lie beyond
            },
        }
        if slow is not None:
            out[name]["turning_round"] = {
                "share_of_rows": float(np.mean(slow[:, j])),
                "share_of_residual": float(np.sum(x[slow[:, j]] ** 2) / total),
            }
    return out


# a coefficient that changes over each record is reported where that change explains this share of a joint's
# residual and this share of what the constant coefficient leaves of it, or more, at this t-value or more (its std
# from the residual's own correlation time)
_CHANGE_SHARE, _CHANGE_OF_LEFT, _CHANGE_T = 0.1, 0.5, 5.0
# what each probe's coefficient is, and its unit, in the words of `describe_signature`
_PROBE_WORDS = {
    "zero": ("torque zero", "N m"),
    "q": ("coefficient on q (a spring)", "N m/rad"),
    "dq": ("coefficient on dq (a viscous friction)", "N m s/rad"),
    "sign_dq": ("coefficient on sign(dq) (a dry friction)", "N m"),
    "ddq": ("coefficient on ddq (an inertia)", "kg m^2"),
}


def changing_coefficient(
    x: np.ndarray, probes: dict[str, np.ndarray], record: np.ndarray, time: np.ndarray
) -> dict[str, Any] | None:
    """The probe whose coefficient, changing linearly over each record, explains most of a residual: a parameter
    that drifts while the robot runs (a friction as the drive warms up, a torque zero that creeps), which no
    constant effect holds.

    Per probe p (and the torque zero), x is fitted with each record's mean, p, and p times the time within its
    record (u, -1/2 at its start to 1/2 at its end); the change's share is what the last column explains of x's
    variance. The probe of largest share is returned where it is `_CHANGE_SHARE` or more, and `_CHANGE_OF_LEFT` of
    what the fit without the last column leaves, at a t-value of `_CHANGE_T` or more (the std from the fit's
    residual and its correlation time). A viscous friction that grows from 0 to 0.025 N m s/rad over a record
    leaves a quarter of its torque's variance to the change.

    Args:
        x: (N,) residual [N m], centred; probes: name -> (N,) signal (`q`, `dq`, `sign_dq`, `ddq`).
        record: (N,) record of each row; time: (N,) [s].

    Returns:
        {`probe` (`zero` for the torque zero), `start` and `end` (the coefficient at the records' start and end,
        the zero's as a change from its mean), `share`, `t`, `motion_ratio` (the joint's RMS speed over the last
        quarter of the records against the first: above 1.5 or below 1 / 1.5 the motion's size changes too, and an
        effect not linear in the probe fits the same)}; None where no change is that clear.
    """
    records = np.unique(record)
    u = np.zeros(len(x))
    for r in records:
        rows = record == r
        span = float(np.ptp(time[rows]))
        u[rows] = (time[rows] - time[rows].min()) / span - 0.5 if span > 0 else 0.0
    means = (record[:, None] == records[None, :]).astype(float)
    total = float(x @ x)
    if total <= 0 or len(x) < 4 * (means.shape[1] + 3):
        return None
    best: dict[str, Any] | None = None
    speed = probes["dq"]
    for name, p in {"zero": np.ones(len(x)), **probes}.items():
        base = means if name == "zero" else np.column_stack([means, p])
        full = np.column_stack([base, p * u])
        coef, *_ = np.linalg.lstsq(full, x, rcond=None)
        left = x - full @ coef
        rss0 = float(np.sum((x - base @ np.linalg.lstsq(base, x, rcond=None)[0]) ** 2))
        rss1 = float(left @ left)
        share = (rss0 - rss1) / total
        gram_inv = np.linalg.pinv(full.T @ full)
        var = rss1 / max(len(x) - full.shape[1], 1) * correlation_time(left)
        t = abs(float(coef[-1])) / float(np.sqrt(max(var * float(gram_inv[-1, -1]), 1e-300)))
        if min(share - _CHANGE_SHARE, (rss0 - rss1) / max(rss0, 1e-300) - _CHANGE_OF_LEFT, t - _CHANGE_T) < 0:
            continue
        if best is not None and share <= best["share"]:
            continue
        level = 0.0 if name == "zero" else float(coef[-2])
        early, late = speed[u < -0.25], speed[u > 0.25]
        ratio = float(np.sqrt(np.mean(late**2) / max(np.mean(early**2), 1e-300)))
        best = {
            "probe": name,
            "start": level - 0.5 * float(coef[-1]),
            "end": level + 0.5 * float(coef[-1]),
            "share": share,
            "t": t,
            "motion_ratio": ratio,
        }
    return best


_PERIOD_EDGES = {"shortest": " or shorter: the shortest scanned", "longest": " or longer: the longest the motion spans"}


def describe_signature(remaining: dict[str, Any]) -> str:
    """One clause per joint of a `residual_signature`: its size against the noise and what stands out in it: a
    share where the joint turns round or rests at least three times that of the rows (and 15 % of the residual),
    a position-periodic part of 30 % or more; else its strongest correlation."""
    parts = []
    for joint, sig in remaining.items():
        notes = []
        turning = sig.get("turning_round")
        if turning and turning["share_of_residual"] >= max(3 * turning["share_of_rows"], 0.15):
            notes.append(
                f"{turning['share_of_residual']:.0%} of it where the joint turns round or rests "
                f"({turning['share_of_rows']:.0%} of the rows: the friction's shape at low speed, or sticking)"
            )
        periodic = sig["position_periodic"]
        if periodic["share"] >= 0.3:
            # the shortest period scanned, or the longest the motion spans: the torque's own may lie beyond (a
            # 42-cycle ripple read as 40.5; on a UR5e wrist moving 0.6 rad a sin(3 q) read as 0.546 rad)
            edge = _PERIOD_EDGES.get(periodic.get("edge") or "", "")
            notes.append(f"{periodic['share']:.0%} of it periodic in position ({periodic['period_rad']:.3g} rad{edge})")
        change = sig.get("changes_over_time")
        if change:
            what, unit = _PROBE_WORDS[change["probe"]]
            grows = (
                f" (the joint's speed changes over the records too (x {change['motion_ratio']:.2g} from the first "
                "quarter to the last): an effect not linear in the motion fits the same, or "
                if not 1 / 1.5 <= change["motion_ratio"] <= 1.5
                else " ("
            )
            how = (
                f"by {change['end'] - change['start']:+.3g} {unit}"
                if change["probe"] == "zero"
                else f"from {change['start']:.3g} to {change['end']:.3g} {unit}"
            )
            notes.insert(
                0,
                f"{change['share']:.0%} of it a {what} that changes over each record, {how}{grows}a parameter that "
                "drifts while the robot runs: a friction as the drive warms up, a torque zero that creeps)",
            )
        finite = {k: v for k, v in sig["correlation"].items() if np.isfinite(v)}
        if not notes and finite:
            probe = max(finite, key=lambda k: abs(finite[k]))
            notes.append(f"correlation {finite[probe]:+.2f} with {probe}")
        parts.append(", ".join([f"{joint} {sig['rms_over_noise']:.1f} x noise", *notes]))
    return "; ".join(parts)

"""Derivatives from sampled positions: each method against a Fourier signal whose derivatives are known."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dynamics.errors import DataError
from envs.dataset import Dataset
from envs.sensors import SensorModel
from excitation.fourier import FourierDesign
from identify.derivatives import DERIVATIVES, derive_states, excitation_bandwidth_hz, state_cutoff_hz

FS = 500.0
F0 = 0.2  # [Hz]; five harmonics: the motion's bandwidth is 1 Hz
PERIOD = 1.0 / F0


def _design() -> FourierDesign:
    rng = np.random.default_rng(7)
    amp = 1.0 / np.arange(1, 6)
    return FourierDesign(F0, rng.normal(size=(2, 5)) * amp, rng.normal(size=(2, 5)) * amp, np.array([0.3, -0.2]))


def _dataset(sigma_q: float = 0.0, q_resolution: float = 0.0, periods: int = 3) -> tuple[Dataset, tuple]:
    t = np.arange(int(periods * PERIOD * FS)) / FS
    truth = _design().evaluate(t)
    q = SensorModel(sigma_q=sigma_q, q_resolution=q_resolution).measure_q(truth[0], np.random.default_rng(3))
    data = Dataset(time=t, q=q, tau=np.zeros_like(q), joint_names=("a", "b"), actuated=np.ones(2, bool))
    return data, truth


def _rel_rms(estimate: np.ndarray, truth: np.ndarray, rows: np.ndarray) -> float:
    return float(np.sqrt(np.mean((estimate[rows] - truth[rows]) ** 2) / np.mean(truth[rows] ** 2)))


@pytest.mark.parametrize(
    ("method", "options", "tol_ddq"),
    [
        ("butterworth", {}, 2e-3),
        ("butterworth", {"edges": "periodic", "period_s": PERIOD}, 2e-3),
        ("spectral", {"period_s": PERIOD}, 1e-8),
        ("kalman", {}, 2e-3),
    ],
)
def test_noise_free_derivatives_match_the_analytic_ones(method: str, options: dict, tol_ddq: float) -> None:
    data, (q, dq, ddq) = _dataset()
    s = derive_states(data, method, **options)
    assert s.valid.sum() > 0.9 * data.n_samples
    assert _rel_rms(s.q, q, s.valid) < 1e-6
    assert _rel_rms(s.dq, dq, s.valid) < tol_ddq
    assert _rel_rms(s.ddq, ddq, s.valid) < tol_ddq


@pytest.mark.parametrize(
    ("method", "options"),
    [
        ("butterworth", {}),
        ("butterworth", {"edges": "periodic", "period_s": PERIOD}),
        ("spectral", {"period_s": PERIOD}),
        ("kalman", {}),
    ],
)
def test_noisy_quantised_positions_give_accurate_accelerations(method: str, options: dict) -> None:
    # an 18-bit encoder with electrical noise; the cut-off follows the measured bandwidth
    data, (_, dq, ddq) = _dataset(sigma_q=1.7e-4, q_resolution=2.4e-5)
    s = derive_states(data, method, **options)
    assert _rel_rms(s.dq, dq, s.valid) < 2e-3
    assert _rel_rms(s.ddq, ddq, s.valid) < 2e-2


@pytest.mark.parametrize("edges", ["trim", "periodic"])
def test_a_100_hz_log_is_differentiated_to_fourth_order(edges: str) -> None:
    """A 4 Hz sine sampled at 100 Hz, below the 10 Hz cut-off: second-order central differences (the gradient
    of the gradient) scaled its speed by sin(x) / x = 0.990 and its acceleration by (sin(x) / x)^2 = 0.979
    (x = w h), which on another generator's clean 100 Hz two-link log was named a shoulder torque gain of 1.0015
    and an elbow armature. Fourth-order terms bring both within 2e-4 of the derivatives of what the filter kept."""
    fs, f = 100.0, 4.0
    t = np.arange(int(10 * fs)) / fs
    w = 2 * np.pi * f
    q = np.column_stack([np.sin(w * t), 0.5 * np.cos(w * t)])
    dq = np.column_stack([w * np.cos(w * t), -0.5 * w * np.sin(w * t)])
    data = Dataset(time=t, q=q, tau=np.zeros_like(q), joint_names=("a", "b"), actuated=np.ones(2, bool))
    options = {"edges": "periodic", "period_s": 1.0 / f} if edges == "periodic" else {}
    s = derive_states(data, "butterworth", cutoff_hz=10.0, **options)
    rows = s.valid
    kept = float(np.sum(s.q[rows] * q[rows]) / np.sum(q[rows] ** 2))  # the filter's gain at 4 Hz (0.9993)
    assert _rel_rms(s.q, kept * q, rows) < 1e-5
    assert _rel_rms(s.dq, kept * dq, rows) < 2e-4  # x^4 / 30 = 1.3e-4
    assert _rel_rms(s.ddq, -(w**2) * kept * q, rows) < 1e-4
    assert _rel_rms(np.gradient(s.q, t, axis=0), kept * dq, rows) > 5e-3  # second order, as before


def test_differences_are_cut_off_at_an_eighth_of_the_rate() -> None:
    """Above an eighth of the rate the gradient of the gradient loses (sin x / x)^2 of the acceleration (a fifth at
    fs / 8) and the fourth-order terms are not added: a 9 Hz sine at 100 Hz (x = 0.57) comes out 10 % short that
    way, and on clean 500 Hz two-link logs a 120 Hz cut-off named a rigid-body change that is not there. A derived
    cut-off (4 x the motion's 9 Hz) stops at 12.5 Hz, where the fourth-order terms hold, and an explicit one above
    it is refused naming the file; the spectral method, exact below Nyquist, keeps 0.4 of the rate."""
    fs, f = 100.0, 9.0
    t = np.arange(int(10 * fs)) / fs
    w = 2 * np.pi * f
    q = np.column_stack([np.sin(w * t), 0.5 * np.cos(w * t)])
    data = Dataset(
        time=t, q=q, tau=np.zeros_like(q), joint_names=("a", "b"), actuated=np.ones(2, bool), source="fast.csv"
    )
    assert state_cutoff_hz(data, "butterworth") == pytest.approx(12.5)
    s = derive_states(data, "butterworth")
    kept = float(np.sum(s.q[s.valid] * q[s.valid]) / np.sum(q[s.valid] ** 2))
    assert _rel_rms(s.ddq, -(w**2) * kept * q, s.valid) < 2e-3  # fourth order: x^4 / 90 = 1.2e-3
    second = np.gradient(np.gradient(s.q, t, axis=0), t, axis=0)  # what a cut-off above fs / 8 gets
    assert _rel_rms(second, -(w**2) * kept * q, s.valid) > 0.09
    assert state_cutoff_hz(data, "spectral", period_s=1.0 / f) == pytest.approx(40.0)
    assert derive_states(data, "butterworth", cutoff_hz=12.7).valid.any()  # at the limit, within the rate's jitter
    with pytest.raises(DataError, match=r"fast\.csv: cutoff_hz=30 Hz is above 12\.5 Hz, an eighth of its 100 Hz"):
        derive_states(data, "butterworth", cutoff_hz=30.0)


def test_harmonics_only_spectral_removes_almost_all_noise() -> None:
    # over 10 periods only one frequency bin in 10 is a harmonic of the excitation; the others hold noise
    data, (_, _, ddq) = _dataset(sigma_q=1.7e-4, periods=10)
    every_bin = derive_states(data, "spectral", period_s=PERIOD, cutoff_hz=4.0, harmonics_only=False)
    harmonics = derive_states(data, "spectral", period_s=PERIOD, cutoff_hz=4.0)
    rows = harmonics.valid
    assert _rel_rms(harmonics.ddq, ddq, rows) < 0.5 * _rel_rms(every_bin.ddq, ddq, rows)


def test_bandwidth_is_that_of_the_motion_not_of_the_noise() -> None:
    data, _ = _dataset(sigma_q=1.7e-5, q_resolution=2.4e-5)
    bw = excitation_bandwidth_hz(data.q, FS)
    assert 0.5 <= bw <= 2.0, bw


def test_decimation_keeps_every_kth_trusted_row() -> None:
    data, _ = _dataset()
    full = derive_states(data, "butterworth")
    thin = derive_states(data, "butterworth", decimate=5)
    assert np.all(np.flatnonzero(thin.valid) % 5 == 0)
    assert np.array_equal(thin.valid, full.valid & (np.arange(data.n_samples) % 5 == 0))


def test_periodic_padding_trusts_every_row_of_whole_periods() -> None:
    data, _ = _dataset()
    s = derive_states(data, "butterworth", edges="periodic", period_s=PERIOD)
    assert s.valid.all()
    part = derive_states(data, "spectral", period_s=PERIOD * 0.8)  # 3 periods of 4 s fit in 15 s: 12 s kept
    assert part.valid.sum() == int(12.0 * FS)


def test_simulator_method_needs_simulated_data() -> None:
    data, _ = _dataset()
    with pytest.raises(ValueError, match="simulator"):
        derive_states(data, "simulator")


def test_bad_choices_list_the_valid_ones() -> None:
    data, _ = _dataset()
    with pytest.raises(ValueError, match=", ".join(sorted(DERIVATIVES))):
        derive_states(data, "savgol")
    with pytest.raises(ValueError, match="periodic, trim"):
        derive_states(data, "butterworth", edges="mirror")
    with pytest.raises(ValueError, match="whole number"):
        derive_states(data, "spectral", period_s=1.0001 / FS * 1000)


def test_reduced_record_keeps_the_full_rate_states_and_the_motions_torque() -> None:
    """`reduce_record`: states derived at the full rate, then states and torque through one anti-alias filter
    and every k-th row: where the motion lives (below the filter) they are the full-rate ones, and
    derivatives='given' reads them back unchanged."""
    from identify.derivatives import reduce_record, reduction_factor

    data, truth = _dataset(sigma_q=1e-5)
    tau = truth[2] * np.array([0.3, 0.1]) + np.sin(truth[0])  # a smooth torque of the motion
    data = Dataset(time=data.time, q=data.q, tau=tau, joint_names=data.joint_names, actuated=data.actuated)
    full = derive_states(data, "butterworth", cutoff_hz=20.0)
    band = excitation_bandwidth_hz(data.q, FS)
    k = reduction_factor(data.n_samples, FS, max_rows=data.n_samples // 50, band_hz=2 * band)
    assert 1 < k <= FS / (2.5 * 2 * band)
    small = reduce_record(data, "butterworth", k, cutoff_hz=20.0)
    rows = np.flatnonzero(full.valid)
    kept = np.arange(rows[0], rows[-1] + 1, k)
    np.testing.assert_array_equal(small.time, data.time[kept])
    inner = np.arange(len(kept) // 10, len(kept) - len(kept) // 10)  # away from the anti-alias filter's edges
    assert _rel_rms(small.q, full.q[kept], inner) < 1e-4
    assert _rel_rms(small.tau, tau[kept], inner) < 1e-4
    for mine, theirs, exact in ((small.dq, full.dq, truth[1]), (small.ddq, full.ddq, truth[2])):
        assert mine is not None  # as close to the truth as the full-rate states (closer: less noise)
        assert _rel_rms(mine, exact[kept], inner) <= 1.05 * _rel_rms(theirs[kept], exact[kept], inner)
    assert small.meta["reduced"]["factor"] == k and small.tau_lead_s == 0.0
    given = derive_states(small, "given")
    np.testing.assert_array_equal(given.dq, small.dq)
    assert given.valid.all()


def test_reduction_never_drops_below_the_band_and_given_needs_states() -> None:
    from dynamics.errors import DataError
    from identify.derivatives import reduction_factor

    assert reduction_factor(10_000, 500.0, max_rows=20_000, band_hz=5.0) == 1
    assert reduction_factor(3_000_000, 500.0, max_rows=60_000, band_hz=5.0) == 40  # 500 / (2.5 * 5)
    assert reduction_factor(3_000_000, 500.0, max_rows=60_000, band_hz=1.0) == 50
    data, _ = _dataset()
    with pytest.raises(DataError, match="derivatives='given' needs dq and ddq"):
        derive_states(data, "given")


@pytest.mark.parametrize("n", [2, 3, 7, 1000, 70_001])
def test_blockwise_gradient_is_numpys_bit_for_bit(n: int, monkeypatch: pytest.MonkeyPatch) -> None:
    from identify.derivatives import gradient

    monkeypatch.setattr("identify.derivatives._GRADIENT_BLOCK", 1000)  # many blocks, and a ragged last one
    rng = np.random.default_rng(n)
    x = np.cumsum(rng.uniform(0.5, 1.5, n))
    f = rng.normal(size=(n, 3))
    for column in (f, f[:, 0], f[:, 1:2]):
        np.testing.assert_array_equal(gradient(column, x), np.gradient(column, x, axis=0))


def test_the_cut_off_of_reduced_states_is_the_one_they_were_derived_with() -> None:
    """A long log is reduced with its states derived at the cut-off and then diagnosed as `given` states: the
    whiteness band follows that cut-off, as it does for the same log unreduced."""
    from identify.derivatives import reduce_record, state_cutoff_hz

    t = np.arange(0.0, 20.0, 0.002)
    q = np.column_stack([np.sin(2 * np.pi * 0.5 * t)])
    data = Dataset(time=t, q=q, tau=np.zeros_like(q), joint_names=("j",), actuated=np.array([True]))
    assert state_cutoff_hz(data, "butterworth", cutoff_hz=10.0) == 10.0
    reduced = reduce_record(data, "butterworth", 2, cutoff_hz=10.0)
    assert state_cutoff_hz(reduced, "given") == 10.0
    assert state_cutoff_hz(data, "given") is None and state_cutoff_hz(data, "simulator") is None


@pytest.mark.parametrize("samples", [0.5, 1.0, 2.75])
def test_states_are_read_at_a_torque_lead_of_any_number_of_samples(samples: float) -> None:
    """`Dataset.tau_lead_s`: the states are evaluated that much after each row, half a sample for a held torque
    and several for a drive that applies a commanded torque later; the rows whose states would come from beyond
    the record are not trusted. (A lead of a sample or more was refused before: a drive's lag had no reading.)"""
    rate, f = 500.0, 0.7
    t = np.arange(3000) / rate
    q = np.column_stack([np.sin(2 * np.pi * f * t), 0.5 * np.cos(2 * np.pi * 1.3 * f * t)])
    data = Dataset(time=t, q=q, tau=np.zeros_like(q), joint_names=("a", "b"), actuated=np.ones(2, bool))
    at_rows = derive_states(data, "butterworth", cutoff_hz=10.0)
    lead = samples / rate
    later = derive_states(dataclasses.replace(data, tau_lead_s=lead), "butterworth", cutoff_hz=10.0)
    exact = np.column_stack([np.sin(2 * np.pi * f * (t + lead)), 0.5 * np.cos(2 * np.pi * 1.3 * f * (t + lead))])
    rows = later.valid
    assert np.max(np.abs(later.q[rows] - exact[rows])) < 2e-5
    assert np.max(np.abs(at_rows.q[rows] - exact[rows])) > 50 * np.max(np.abs(later.q[rows] - exact[rows]))
    assert not np.any(later.valid & ~at_rows.valid)
    ends = np.flatnonzero(at_rows.valid)
    last = ends[-1] - int(np.ceil(samples))  # the last row whose states come from trusted rows
    assert later.valid[last] and not later.valid[last + 1 :].any()

"""Derivatives from sampled positions: each method against a Fourier signal whose derivatives are known."""

from __future__ import annotations

import numpy as np
import pytest

from envs.dataset import Dataset
from envs.sensors import SensorModel
from excitation.fourier import FourierDesign
from identify.derivatives import DERIVATIVES, derive_states, excitation_bandwidth_hz

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

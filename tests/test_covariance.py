"""The HAC covariance's maths: the kernel sum reaches the long-run variance, the degrees of freedom follow it.

Band-limited noise here is unit white noise through the coverage study's driver filter (2nd-order Butterworth
at 10 Hz, sampled at 500 Hz). Its long-run variance is exactly the filter's DC gain squared, 1, while its
variance is sum h^2, so the integrated autocorrelation time is 1 / sum h^2 (about 22.6 samples).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from identify.estimators.covariance import autocorrelation_window, hac_meat, sandwich

_B, _A = signal.butter(2, 10.0, fs=500.0)


def _band_limited(rng: np.random.Generator, n: int) -> np.ndarray:
    return signal.lfilter(_B, _A, rng.normal(size=n + 2000))[2000:, None]


def _tau() -> float:
    h = signal.lfilter(_B, _A, np.r_[1.0, np.zeros(8191)])
    return float(1.0 / np.sum(h**2))


def test_parzen_sum_reaches_the_long_run_variance_where_bartlett_falls_short() -> None:
    rng = np.random.default_rng(0)
    n = 100_000
    parzen, bartlett = [], []
    for _ in range(16):
        g = _band_limited(rng, n)
        lag, _ = autocorrelation_window(g)
        parzen.append(hac_meat(g, lag, kernel="parzen")[0, 0] / n)
        bartlett.append(hac_meat(g, lag, kernel="bartlett")[0, 0] / n)
    # long-run variance 1 (DC gain of the filter); Parzen within 1 % in expectation, Bartlett about 5 % short
    assert 0.97 < np.mean(parzen) < 1.02, np.mean(parzen)
    assert np.mean(parzen) / np.mean(bartlett) > 1.025, (np.mean(parzen), np.mean(bartlett))


def test_the_degrees_of_freedom_follow_the_estimates_variance_inflation() -> None:
    rng = np.random.default_rng(1)
    n = 50_000
    ones = np.ones((n, 1))
    bread = np.array([[1.0 / n]])
    # the mean of the series as the estimate: white noise inflates nothing, band-limited noise by its tau
    _, white = sandwich(bread, ones * rng.normal(size=(n, 1)))
    _, coloured = sandwich(bread, ones * _band_limited(rng, n))
    assert abs(white.inflation - 1.0) < 0.1, white
    assert abs(coloured.inflation / _tau() - 1.0) < 0.15, (coloured, _tau())
    assert coloured.lag > 3 * _tau(), coloured


def test_the_sandwich_std_of_a_mean_of_band_limited_noise_is_its_long_run_std() -> None:
    # over many records the reported variance of the mean averages to the true one, sum of the long-run
    # variance over n^2 (= 1 / n), and the z-scores have unit spread
    rng = np.random.default_rng(2)
    n = 20_000
    bread = np.array([[1.0 / n]])
    z, var = [], []
    for _ in range(200):
        x = _band_limited(rng, n)
        mean = float(x.mean())
        cov, _ = sandwich(bread, x - mean)
        var.append(cov[0, 0])
        z.append(mean / np.sqrt(cov[0, 0]))
    assert 0.93 < np.mean(var) * n < 1.07, np.mean(var) * n
    assert 0.9 < np.sqrt(np.mean(np.square(z))) < 1.15, np.sqrt(np.mean(np.square(z)))

"""The reported standard deviations are honest: they match the spread of estimates over noise seeds."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from envs.dataset import Dataset
from envs.sensors import SensorModel
from harness.setup import design_from_config, experiment_from_config, simulate_design
from identify.derivatives import derive_states
from identify.estimators import estimate
from identify.problem import build_problem
from tests.conftest import compose_config


@pytest.mark.slow
@pytest.mark.parametrize("estimator", ["ols", "wls"])
def test_reported_std_matches_spread_over_50_seeds(estimator: str) -> None:
    cfg = compose_config(["system=two_link", "excitation=default"])
    exp = experiment_from_config(cfg, np.random.default_rng(0))
    plant, model, base, sensor = exp.plant, exp.model, exp.base, exp.sensor
    design = design_from_config(cfg, exp, "default", np.random.default_rng(0))
    # the motion does not depend on the sensor noise: simulate once, measure it 50 times
    clean = simulate_design(
        plant, design, cfg, SensorModel(sample_rate_hz=sensor.sample_rate_hz), np.random.default_rng(0), 2.0
    )
    betas, stds = [], []
    for seed in range(50):
        rng = np.random.default_rng(1000 + seed)
        noisy = dataclasses.replace(
            clean,
            q=sensor.measure_q(clean.meta["q_true"], rng),
            tau=sensor.measure_tau(clean.meta["tau_applied"], plant.actuated, rng),
        )
        assert isinstance(noisy, Dataset)
        states = derive_states(noisy, "butterworth", cutoff_hz=5.0)
        est = estimate(estimator, build_problem(noisy, states, model, base))
        betas.append(est.beta)
        stds.append(est.std)
    spread = np.std(np.array(betas), axis=0, ddof=1)
    reported = np.mean(np.array(stds), axis=0)
    ratio = reported / spread
    assert np.all((ratio > 0.7) & (ratio < 1.3)), dict(zip(base.names, ratio.round(3), strict=True))

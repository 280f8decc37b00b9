"""Noise on the logged angles, differentiated into the model torque, biases every fitted scale (errors in the
variables): the diagnosis measures that share and refuses a record where it is large, instead of naming the
bias as a torque gain or an inertia."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from dynamics.errors import DataError
from envs.dataset import Dataset
from identify.diagnose.diagnosis import _records, diagnose
from identify.diagnose.state_noise import STATE_NOISE_SHARE, angle_noise, state_noise_share, state_noise_torque
from identify.diagnose.testbed import SYSTEMS, rollout

OPTIONS = {"cutoff_hz": 10.0}


def _noisy(system: str, sigma: float, seed: int, duration_s: float = 10.0) -> tuple:  # type: ignore[type-arg]
    plant, data = rollout(system, [], rng=np.random.default_rng(seed), duration_s=duration_s, source=f"log{seed}")
    noise = np.random.default_rng(100 + seed).normal(0.0, sigma, data.q.shape)
    return plant, dataclasses.replace(data, q=data.q + noise)


def _share(plant, data: Dataset, band_hz: float | None = None) -> tuple[np.ndarray, object]:  # type: ignore[no-untyped-def]
    rec = _records(plant, [data], "butterworth", OPTIONS, band_hz)[0]
    s = rec.signals
    rng = np.random.default_rng(0)
    noise = state_noise_torque(plant, data, rec.states, s.tau_nominal, "butterworth", OPTIONS, rng)
    return state_noise_share(s.smooth(s.tau_nominal), None if noise is None else s.smooth(noise)), s


def test_the_angle_noise_is_read_from_the_third_differences_under_the_motion() -> None:
    _, data = _noisy("two_link", 0.004, seed=0)
    np.testing.assert_allclose(angle_noise(data.q), 0.004, rtol=0.05)


@pytest.mark.parametrize("sigma", [0.003, 0.0045])
def test_the_share_predicts_how_far_the_model_torque_s_scale_is_pulled_towards_zero(sigma: float) -> None:
    """The testbed's torque is the true model's (no hidden effect): regressed on the model torque at the noisy
    angles' states, its slope is 1 / (1 + share) on every joint, as errors in the variables say."""
    plant, data = _noisy("two_link", sigma, seed=1, duration_s=20.0)
    share, s = _share(plant, data)
    a = s.tau_nominal - s.tau_nominal.mean(axis=0)
    b = s.tau - s.tau.mean(axis=0)
    slope = np.sum(a * b, axis=0) / np.sum(a * a, axis=0)
    assert np.all(share > 0.03)  # a bias the test can see
    predicted = 1.0 / (1.0 + share)
    assert np.all(np.abs(slope - predicted) < 0.3 * (1.0 - predicted)), (slope, predicted)


@pytest.mark.parametrize("system", list(SYSTEMS))
def test_clean_logs_of_every_built_in_system_are_far_below_the_limit(system: str) -> None:
    plant, data = rollout(system, [], rng=np.random.default_rng(3), duration_s=10.0)
    share, _ = _share(plant, data)
    assert np.all(share[np.asarray(plant.actuated, bool)] < STATE_NOISE_SHARE / 100)


def test_the_shared_logs_are_far_below_the_limit() -> None:
    from dynamics.plant import load_plant
    from tests.test_diagnose_anomalies import shared_log, shared_logs

    plant = load_plant("two_link")
    for path in shared_logs():
        share, _ = _share(plant, shared_log(path), band_hz=5.0)
        assert np.all(share < STATE_NOISE_SHARE / 100), (path.name, share)


def test_a_log_with_noisy_angles_is_refused_with_a_cut_off_that_the_diagnosis_then_accepts() -> None:
    """0.01 rad of angle noise at a 10 Hz cut-off: about 40 % of the model torque's variance. Diagnosed as it
    is, the bias would be named (a torque gain of 0.72 was, by a probe, at 0.05 rad); the refusal names the
    file, the joint, the noise and a cut-off, at which the same logs are diagnosed with no torque gain."""
    plant, train = _noisy("two_link", 0.01, seed=2)
    _, val = _noisy("two_link", 0.01, seed=3, duration_s=5.0)
    with pytest.raises(
        DataError,
        match=r"log2: the angles' noise \(std 0\.0\d+, 0\.0\d+ rad, from their third "
        r"differences\) adds noise of \d+% of the variance of the model torque at \w+ .*cut-off 10 Hz",
    ):
        diagnose(plant, [train], [val], rng=np.random.default_rng(0), derivative_options=OPTIONS)
    try:
        diagnose(plant, [train], [val], rng=np.random.default_rng(0), derivative_options=OPTIONS)
    except DataError as err:
        cutoff = float(re.search(r"to about ([\d.]+) Hz", str(err)).group(1))  # type: ignore[union-attr]
    assert 3.0 < cutoff < 8.0
    dg = diagnose(plant, [train], [val], rng=np.random.default_rng(0), derivative_options={"cutoff_hz": cutoff})
    assert not [f for f in dg.findings if f.effect == "torque_gain"]


def test_a_long_noisy_log_is_refused_before_it_is_thinned(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A log past `diagnose.max_rows` has its states derived at the full rate and then every k-th row kept
    ('given' states), where the angles no longer show their noise: the check runs at the full rate first. The
    same logs, kept whole, are refused by the diagnosis itself with the same reason; nothing is written."""
    import harness.diagnose as cli
    from envs.dataset import write_csv
    from tests.conftest import compose_config

    paths = []
    for seed, duration in ((2, 10.0), (3, 5.0)):
        _, data = _noisy("two_link", 0.01, seed=seed, duration_s=duration)
        paths.append(tmp_path / f"log{seed}.csv")
        write_csv(data, paths[-1])
    listed = ",".join(str(p) for p in paths)
    for rows in ("1000", "null"):
        out = tmp_path / f"out_{rows}"
        cfg = compose_config(
            [
                "system=two_link",
                f"data.path=[{listed}]",
                f"output_dir={out}",
                "diagnose.references=null",
                "diagnose.recording=false",
                f"diagnose.max_rows={rows}",
            ],
            config_name="diagnose",
        )
        with pytest.raises(DataError, match=r"log2\.csv: the angles' noise .* cut-off 10 Hz.*to about [\d.]+ Hz"):
            cli.run(cfg)
        assert not out.exists() or not any(out.iterdir())


def test_the_full_rate_check_passes_a_clean_log_and_refuses_a_noisy_one() -> None:
    from dynamics.plant import load_plant
    from identify.diagnose.state_noise import check_full_rate_state_noise

    plant, data = rollout("two_link", [], rng=np.random.default_rng(4), duration_s=10.0)
    check_full_rate_state_noise(plant, data, "butterworth", OPTIONS, band_hz=None)  # clean: no refusal
    _, noisy = _noisy("two_link", 0.01, seed=2)
    with pytest.raises(DataError, match="the angles' noise"):
        check_full_rate_state_noise(load_plant("two_link"), noisy, "butterworth", OPTIONS, band_hz=None)
    check_full_rate_state_noise(plant, noisy, "given", {}, band_hz=None)  # states not from the angles: nothing to check

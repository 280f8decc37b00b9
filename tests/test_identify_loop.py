"""The end-to-end loop recovers the MJCF's base parameters: exactly without noise, within its std with it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from harness.run import run
from tests.conftest import compose_config

SYSTEMS = ["pendulum", "two_link", "wheel_pendulum"]


def _run(tmp_path: Path, overrides: list[str]) -> dict:
    return run(compose_config(["record=none", *overrides]), output_dir=tmp_path)


@pytest.mark.parametrize("system", SYSTEMS)
def test_noise_free_data_recover_every_base_parameter(system: str, tmp_path: Path) -> None:
    results = _run(tmp_path, [f"system={system}", "noise=none", "identify.derivatives=simulator"])
    for p in results["base_parameters"]:
        if p["rel_error"] is None:
            assert abs(p["abs_error"]) <= 1e-9, p
        else:
            assert abs(p["rel_error"]) <= 1e-6, p


@pytest.mark.parametrize("system", SYSTEMS)
def test_default_noise_estimates_lie_within_four_std(system: str, tmp_path: Path) -> None:
    results = _run(tmp_path, [f"system={system}"])
    z = np.array([p["z"] for p in results["base_parameters"]])
    assert np.all(np.abs(z) <= 4.0), results["base_parameters"]
    val = results["validation"]
    # an unactuated joint has no torque noise: its residual comes from the derivative filter's errors in the
    # regressor, which depend on the motion (designed on the prior model, not the truth); allow a tenth of
    # the sensor noise there
    floor = 0.1 * max(val["noise_std"].values())
    for joint, rms in val["torque_rms"].items():
        # a right model predicts unseen torque down to the sensor's noise
        assert rms <= 1.2 * val["noise_std"][joint] + max(floor, 1e-4), (joint, rms, val["noise_std"][joint])


def test_wheel_pendulum_identifies_the_thesis_parameters(tmp_path: Path) -> None:
    results = _run(tmp_path, ["system=wheel_pendulum"])
    derived = {d["name"]: d for d in results["derived"]}
    assert set(derived) == {"J", "ml", "J_wheel"}
    for d in derived.values():
        assert abs(d["estimate"] - d["true"]) <= 3 * d["std"], d
        assert d["std"] < 0.05 * abs(d["true"]), d  # and the fit is informative, not just uncertain

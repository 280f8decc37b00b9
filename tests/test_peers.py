"""The peer comparison with `mujoco.sysid` runs on a short record and scores both tools with finite numbers."""

from __future__ import annotations

import numpy as np
import pytest

sysid = pytest.importorskip("mujoco.sysid", reason="mujoco.sysid is not part of this MuJoCo build")
if not hasattr(sysid, "optimize"):  # mujoco.sysid hides its names when its optional dependencies are missing
    pytest.skip(
        "mujoco.sysid's optional dependencies are not installed: .venv/bin/python -m pip install -e '.[dev,bench]'",
        allow_module_level=True,
    )

from bench.peers import compare, perturbed_spec, theta_of  # noqa: E402


def test_theta_of_the_mjcf_is_the_plants_truth() -> None:
    from bench.peers import make_case

    case = make_case("pendulum", periods=0.4, val_periods=0.4)
    np.testing.assert_allclose(theta_of(case, case.plant.mj_model), case.model.truth(), atol=1e-12)
    start = theta_of(case, perturbed_spec(case, np.random.default_rng(0)).compile())
    assert not np.allclose(start, case.model.truth())


def test_compare_scores_both_tools_with_finite_numbers() -> None:
    result = compare("pendulum", periods=0.6, val_periods=0.4, max_iters=5)
    tools = {row["tool"]: row for row in result["rows"]}
    assert {"harness (WLS)", "mujoco.sysid"} <= set(tools)
    r = len(result["base_names"])
    for name in ("harness (WLS)", "mujoco.sysid"):
        row = tools[name]
        assert len(row["beta"]) == r and np.all(np.isfinite(row["beta"]))
        assert np.isfinite(row["wall_s"]) and row["wall_s"] > 0
        assert np.isfinite(row["max_abs_error_over_wls_std"])
        assert all(np.isfinite(v) for v in row["validation_torque_rms"].values())
        assert all(np.isfinite(v) for v in row["simulation_error_rad"].values())
    # the truth predicts the unseen torque down to the sensor noise; the fitted models come close to it
    truth = tools["MJCF truth (reference)"]["validation_torque_rms"]["swing"]
    assert tools["harness (WLS)"]["validation_torque_rms"]["swing"] < 1.5 * truth

"""The thesis's 3-DoF spatial arm: its MJCF against mj_inverse, against the thesis's closed forms, and identified."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from dynamics.plant import load_plant
from dynamics.regressor import ParameterModel
from dynamics.torque import inverse_dynamics
from identify.compare import compare_with_truth
from identify.derivatives import derive_states
from identify.estimators import estimate
from identify.problem import build_problem
from tests.conftest import compose_config
from tests.test_estimators import case, measure

D3 = 0.35  # [m] the DH distance d3 of mjcf/arm3.xml


def _random_states(n: int = 200) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    plant = load_plant("arm3")
    rng = np.random.default_rng(11)
    q = rng.uniform(plant.q_range[:, 0], plant.q_range[:, 1], size=(n, plant.nv))
    return q, rng.normal(0.0, 2.0, size=(n, plant.nv)), rng.normal(0.0, 10.0, size=(n, plant.nv))


def test_regressor_times_truth_is_mujoco_inverse_dynamics() -> None:
    plant = load_plant("arm3")
    model = ParameterModel(plant, ("armature",))
    q, dq, ddq = _random_states()
    tau = inverse_dynamics(plant, q, dq, ddq)
    assert np.max(np.abs(model.regressor(q, dq, ddq) @ model.truth() - tau)) <= 1e-8


def test_inertia_matrix_and_gravity_are_the_thesis_closed_forms() -> None:
    """Section 3.2.4, eq. 3.89-3.99, with the MJCF's numbers (A11 as in Khalil; the thesis's print garbles it)."""
    plant = load_plant("arm3")
    pm = plant.pin_model
    data = pm.createData()
    p = dict(zip(plant.parameter_names, plant.theta, strict=True))
    ia = plant.armature
    g3 = -9.81
    for q in _random_states(20)[0]:
        _, q2, q3 = q
        c2, s2, c3, s3 = np.cos(q2), np.sin(q2), np.cos(q3), np.sin(q3)
        c23, s23 = np.cos(q2 + q3), np.sin(q2 + q3)
        A = pin.crba(pm, data, q)
        A = np.triu(A) + np.triu(A, 1).T  # Pinocchio adds the MJCF armature to the diagonal itself
        a11 = (
            ia[0]
            + p["ZZ1"]
            + s2**2 * p["XX2"]
            + 2 * c2 * s2 * p["XY2"]
            + c2**2 * p["YY2"]
            + s23**2 * p["XX3"]
            + 2 * c23 * s23 * p["XY3"]
            + c23**2 * p["YY3"]
            + 2 * c2 * c23 * D3 * p["MX3"]
            - 2 * c2 * s23 * D3 * p["MY3"]
            + c2**2 * D3**2 * p["m3"]
        )
        a22 = ia[1] + p["ZZ2"] + p["ZZ3"] + 2 * c3 * D3 * p["MX3"] - 2 * s3 * D3 * p["MY3"] + D3**2 * p["m3"]
        a23 = p["ZZ3"] + c3 * D3 * p["MX3"] - s3 * D3 * p["MY3"]
        a33 = ia[2] + p["ZZ3"]
        np.testing.assert_allclose([A[0, 0], A[1, 1], A[1, 2], A[2, 2]], [a11, a22, a23, a33], rtol=1e-10)
        gravity = pin.computeGeneralizedGravity(pm, data, q)
        q2_thesis = -g3 * (c2 * p["MX2"] - s2 * p["MY2"] + c23 * p["MX3"] - s23 * p["MY3"] + D3 * c2 * p["m3"])
        q3_thesis = -g3 * (c23 * p["MX3"] - s23 * p["MY3"])
        np.testing.assert_allclose(gravity, [0.0, q2_thesis, q3_thesis], atol=1e-12)


def test_products_of_inertia_are_in_the_model() -> None:
    plant = load_plant("arm3")
    products = [plant.theta[10 * j + i] for j in range(plant.nv) for i in (5, 7, 8)]  # XY, XZ, YZ
    assert np.all(np.abs(products) > 1e-5)


def test_config_composes_and_names_the_model() -> None:
    cfg = compose_config(["system=arm3"])
    assert cfg.system.mjcf == "arm3" and len(cfg.system.sensor.sigma_tau) == 3


@pytest.mark.slow
@pytest.mark.parametrize("name", ["wls", "iv"])
def test_base_parameters_are_recovered_within_four_std(name: str) -> None:
    c = case("arm3")
    data = measure(c, np.random.default_rng(3), sigma_q=1.7e-5, q_resolution=2.4e-5)
    problem = build_problem(data, derive_states(data, "butterworth", cutoff_hz=5.0), c.model, c.base)
    comparison = compare_with_truth(estimate(name, problem), c.base.project(c.model.truth()))
    z = np.array([p.z for p in comparison])
    assert np.all(np.abs(z) <= 4.0), {p.name: round(p.z, 2) for p in comparison}

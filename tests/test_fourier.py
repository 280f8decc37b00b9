"""Fourier designs: analytic derivatives, periodicity, and designs that keep their limits."""

from __future__ import annotations

import numpy as np
import pytest

from dynamics.errors import InfeasibleExcitationError
from dynamics.plant import load_plant
from dynamics.torque import inverse_dynamics
from excitation.designs import default_design, grid, random_design
from excitation.fourier import FourierDesign
from excitation.limits import limits_for


def _design(rng: np.random.Generator) -> FourierDesign:
    return FourierDesign(0.3, rng.normal(size=(2, 4)), rng.normal(size=(2, 4)), rng.normal(size=2))


def test_derivatives_match_finite_differences() -> None:
    d = _design(np.random.default_rng(0))
    t = np.linspace(0.0, 3.0, 301)
    h = 1e-6
    _, dq, ddq = d.evaluate(t)
    qp, dqp, _ = d.evaluate(t + h)
    qm, dqm, _ = d.evaluate(t - h)
    np.testing.assert_allclose((qp - qm) / (2 * h), dq, atol=1e-6)
    np.testing.assert_allclose((dqp - dqm) / (2 * h), ddq, atol=1e-5)


def test_design_is_periodic_and_basis_is_linear() -> None:
    d = _design(np.random.default_rng(1))
    t = np.linspace(0.0, d.period_s, 50)
    for a, b in zip(d.evaluate(t), d.evaluate(t + d.period_s), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-9)
    bq, bdq, bddq = d.basis(t)
    coeffs = np.hstack([d.a, d.b])  # (n, 2H)
    q, dq, ddq = d.evaluate(t)
    np.testing.assert_allclose(bq @ coeffs.T + d.q0, q, atol=1e-12)
    np.testing.assert_allclose(bdq @ coeffs.T, dq, atol=1e-12)
    np.testing.assert_allclose(bddq @ coeffs.T, ddq, atol=1e-12)
    np.testing.assert_allclose(
        FourierDesign.from_vector(d.to_vector(), n_joints=2, harmonics=4, base_freq_hz=0.3).a, d.a
    )


@pytest.mark.parametrize("system", ["pendulum", "two_link"])
def test_default_and_random_designs_keep_every_limit_on_a_dense_grid(system: str) -> None:
    plant = load_plant(system)
    limits = limits_for(plant, velocity=8.0, acceleration=60.0)
    for design in (
        default_design(plant, limits, harmonics=5, base_freq_hz=0.1),
        random_design(plant, limits, harmonics=5, base_freq_hz=0.1, rng=np.random.default_rng(2)),
    ):
        t = grid(design, 20000)
        q, dq, ddq = design.evaluate(t)
        ratios = limits.ratios(q, dq, ddq, inverse_dynamics(plant, q, dq, ddq))
        assert max(ratios.values()) <= 1.0, ratios
        assert max(ratios.values()) > 0.95, ratios  # and they use the limits, not a timid fraction


def test_impossible_acceleration_limit_names_the_binding_constraint() -> None:
    plant = load_plant("two_link")
    limits = limits_for(plant, velocity=8.0, acceleration=1e-5)
    with pytest.raises(InfeasibleExcitationError, match="binding constraint ddq"):
        default_design(plant, limits, harmonics=5, base_freq_hz=0.1)


def test_wheel_pendulum_torque_design_keeps_angle_and_speed_limits() -> None:
    from excitation.designs import torque_rollout

    plant = load_plant("wheel_pendulum")
    limits = limits_for(plant, velocity=[10.0, 150.0], acceleration=[200.0, 2000.0], range_margin=0.1)
    design = default_design(plant, limits, harmonics=3, base_freq_hz=0.2, torque_driven=True)
    assert np.all(design.a[0] == 0) and np.all(design.b[0] == 0)  # the pendulum joint is not driven
    q, dq = torque_rollout(plant, [design], periods=3.0)
    ratios = limits.ratios(q[0], dq[0])
    assert ratios["q"] <= 1.0 and ratios["dq"] <= 1.0, ratios
    assert max(ratios.values()) > 0.5, ratios

"""`consistent_parameters`: a fit of base parameters that leaves a body with no physical realisation is
projected onto consistent inertials, to the optimum of its convex problem."""

from __future__ import annotations

import numpy as np
import pytest

from dynamics.inertia import from_pseudo_inertia, is_consistent, mass_com_inertia, pseudo_inertia
from dynamics.plant import load_plant
from identify.diagnose.calibrate import (
    _PSEUDO,  # theta_b -> vec J_b
    CONSISTENT_MARGIN,
    _barrier_solve,
    _newton_step,
    consistent_parameters,
)


def _realisable(body: np.ndarray) -> bool:
    """Positive mass and an inertia about the centre of mass that is positive semi-definite."""
    return bool(body[0] > 0 and np.linalg.eigvalsh(mass_com_inertia(body)[2]).min() > -1e-12)


def _inconsistent() -> tuple[np.ndarray, np.ndarray]:
    plant = load_plant("two_link")
    theta = plant.theta.copy()
    theta[10 + 4] = -0.01  # link 2's XX about the joint: no rigid body has it
    return theta, np.eye(len(theta))


def test_an_inconsistent_body_is_projected_to_a_consistent_one() -> None:
    theta, metric = _inconsistent()
    assert not _realisable(theta[10:20])
    notes: list[str] = []
    fixed = consistent_parameters(load_plant("two_link"), theta, metric, notes)
    assert all(_realisable(fixed[10 * b : 10 * b + 10]) for b in range(2))
    assert notes and "nearest consistent" in notes[0]


def test_the_projection_reaches_the_optimum_a_frobenius_metric_makes_known() -> None:
    """With the metric || J(theta') - J(theta) ||_F the nearest consistent body is J's eigenvalues clipped at the
    margin; the log-Cholesky least squares before stopped short of it (its coordinates run off to infinity at
    the boundary where the optimum lies)."""
    plant = load_plant("two_link")
    theta, _ = _inconsistent()
    metric = np.kron(np.eye(2), _PSEUDO)  # (32, 20): each body's pseudo-inertia, entry by entry
    fixed = consistent_parameters(plant, theta, metric, [])
    _assert_clipped(fixed[10:20], theta[10:20], plant.theta[10:20])
    np.testing.assert_allclose(fixed[:10], theta[:10], atol=1e-7)  # the consistent body stays
    assert is_consistent(fixed[10:20])


def _assert_clipped(fixed: np.ndarray, theta: np.ndarray, anchor: np.ndarray) -> None:
    """`fixed`'s pseudo-inertia is `theta`'s with its eigenvalues clipped at the margin."""
    a, b = CONSISTENT_MARGIN
    eps = a + b * max(float(np.trace(pseudo_inertia(v)[:3, :3])) for v in (theta, anchor))
    w, V = np.linalg.eigh(pseudo_inertia(theta))
    assert w[0] < eps  # the body is inconsistent: the clip moves it
    want = (V * np.maximum(w, eps)) @ V.T
    np.testing.assert_allclose(pseudo_inertia(fixed), want, atol=1e-6 * np.abs(w).max())


def test_a_fit_barely_inconsistent_is_projected_as_exactly_as_one_far_off() -> None:
    """The stopping rule is relative to the objective at the optimum, not at the start: a fit just past the
    boundary, with a nominal far from it, still lands on the clip (relative to the start it stopped 0.25 % above
    the optimum, the directions only the weak pull holds off by 30 %)."""
    plant = load_plant("two_link")
    theta = plant.theta.copy()
    J = pseudo_inertia(theta[10:20])
    w, V = np.linalg.eigh(J)
    w[0] = -1e-6  # just past the boundary
    theta[10:20] = from_pseudo_inertia((V * w) @ V.T)
    nominal = 1.5 * plant.theta  # far from the fit
    fixed = consistent_parameters(plant, theta, np.kron(np.eye(2), _PSEUDO), [], nominal=nominal)
    _assert_clipped(fixed[10:20], theta[10:20], nominal[10:20])


def test_a_light_body_is_consistent_with_the_margin_the_mjcf_text_needs() -> None:
    """The barrier's margin scales with each body's second moments, so that `is_consistent` (the margin the MJCF
    text's six digits need) holds without a repair: a 0.011 kg link came out inside J >= 1e-6 ||J|| and still
    failed it."""
    plant = load_plant("two_link")
    theta, metric = _inconsistent()
    theta[10:20] *= 0.011 / theta[10]
    nominal = plant.theta.copy()
    nominal[10:20] *= 0.011 / nominal[10]
    fixed = consistent_parameters(plant, theta, metric, [], nominal=nominal)
    assert all(is_consistent(fixed[10 * b : 10 * b + 10]) for b in range(2))


def test_a_block_of_a_joint_that_carries_no_body_is_held() -> None:
    """Only the bodies are projected; a joint that carries none (its block is no MJCF body) keeps the fit's
    values instead of absorbing the torque change the projection makes."""
    theta, metric = _inconsistent()
    metric = metric + 0.1  # couples every block
    fixed, converged = _barrier_solve(theta, metric, load_plant("two_link").theta, np.array([1]), (theta,))
    assert converged and np.array_equal(fixed[:10], theta[:10]) and is_consistent(fixed[10:20])


def test_a_nominal_body_at_the_boundary_still_gives_a_consistent_one() -> None:
    """The barrier method starts inside the consistent set: a nominal body without extent (a point mass, its
    pseudo-inertia of rank one) is lifted first."""
    plant = load_plant("two_link")
    nominal = plant.theta.copy()
    m, c = 0.5, np.array([0.0, 0.0, -0.2])
    nominal[10:20] = [m, *(m * c), m * (c[1] ** 2 + c[2] ** 2), 0.0, m * (c[0] ** 2 + c[2] ** 2), 0.0, 0.0, 0.0]
    assert np.linalg.eigvalsh(pseudo_inertia(nominal[10:20]))[0] < 1e-12
    theta, metric = _inconsistent()
    fixed = consistent_parameters(plant, theta, metric, [], nominal=nominal)
    assert np.all(np.isfinite(fixed)) and all(_realisable(fixed[10 * b : 10 * b + 10]) for b in range(2))


def test_a_newton_step_that_lapack_cannot_solve_is_still_a_descent_direction(monkeypatch: pytest.MonkeyPatch) -> None:
    """Where neither Cholesky nor LAPACK's SVD (which failed to converge on a UR5e refit's 1e-22 .. 8e5 entries)
    solves the Newton system, the step is the scaled gradient: the barrier method goes on, the diagnosis does not
    stop."""
    H, g = np.diag([1e6, 1.0, 1e-6]), np.array([1.0, -2.0, 3.0])
    np.testing.assert_allclose(_newton_step(H, g), np.linalg.solve(H, g), rtol=1e-12)

    def failing(*args, **kwargs):  # type: ignore[no-untyped-def]
        raise np.linalg.LinAlgError("SVD did not converge")

    monkeypatch.setattr(np.linalg, "lstsq", failing)
    step = _newton_step(H - np.diag([0.0, 2.0, 0.0]), g)  # indefinite: Cholesky fails, then the SVD
    assert np.all(np.isfinite(step)) and g @ step > 0
    theta, metric = _inconsistent()
    monkeypatch.setattr(np.linalg, "cholesky", _failing_for_scaled(np.linalg.cholesky))
    fixed = consistent_parameters(load_plant("two_link"), theta, metric, [])
    assert all(_realisable(fixed[10 * b : 10 * b + 10]) for b in range(2))


def _failing_for_scaled(real):  # type: ignore[no-untyped-def]
    """Cholesky that fails on every Newton system (unit diagonal after the Jacobi scaling) but still tests the
    pseudo-inertias for the line search."""

    def cholesky(a):  # type: ignore[no-untyped-def]
        if a.shape[0] > 4:
            raise np.linalg.LinAlgError("not positive definite")
        return real(a)

    return cholesky

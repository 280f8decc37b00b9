"""`consistent_parameters`: a fit of base parameters that leaves a body with no physical realisation is
projected onto consistent inertials, and the projection survives a LAPACK SVD that does not converge."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from dynamics.inertia import mass_com_inertia
from dynamics.plant import load_plant
from identify.diagnose.calibrate import consistent_parameters

calibrate = importlib.import_module("identify.diagnose.calibrate")


def _realisable(body: np.ndarray) -> bool:
    """Positive mass and an inertia about the centre of mass that is positive semi-definite (the projection may
    land on the boundary: the metric here sees every direction alike)."""
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


def test_the_projection_survives_an_svd_that_does_not_converge(monkeypatch: pytest.MonkeyPatch) -> None:
    """SciPy's trust-region solver takes the SVD of the Jacobian; on a UR5e refit (entries 1e-22 .. 8e5) LAPACK's
    gesdd did not converge and the diagnosis stopped. The solve is retried with LSMR, which needs no SVD."""
    real = calibrate.optimize.least_squares
    calls: list[str] = []

    def failing(*args, **kwargs):  # type: ignore[no-untyped-def]
        calls.append(kwargs.get("tr_solver", "exact"))
        if kwargs.get("tr_solver") != "lsmr":
            raise np.linalg.LinAlgError("SVD did not converge")
        return real(*args, **kwargs)

    monkeypatch.setattr(calibrate.optimize, "least_squares", failing)
    theta, metric = _inconsistent()
    fixed = consistent_parameters(load_plant("two_link"), theta, metric, [])
    assert calls == ["exact", "lsmr"]
    assert all(_realisable(fixed[10 * b : 10 * b + 10]) for b in range(2))

"""The prior model: the truth perturbed as a CAD model is wrong, physically consistent, never the truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dynamics.errors import ModelError
from dynamics.inertia import mass_com_inertia, pseudo_inertia
from dynamics.plant import load_plant
from dynamics.prior import PriorSpec, make_prior
from dynamics.regressor import ParameterModel
from dynamics.torque import inverse_dynamics


@pytest.mark.parametrize("system", ["pendulum", "two_link", "arm3"])
def test_perturbed_prior_is_consistent_within_its_spread_and_never_the_truth(system: str) -> None:
    plant = load_plant(system)
    model = ParameterModel(plant, ("armature", "viscous_friction"))
    spec = PriorSpec(mass_rel=0.2, com_m=0.01, inertia_rel=0.3, armature_rel=0.3)
    truth = model.truth()
    for seed in range(5):
        prior = make_prior(model, spec, np.random.default_rng(seed), simulated=True)
        assert prior.plant.joint_names == plant.joint_names
        assert not np.allclose(prior.theta, truth)
        for j in range(plant.nv):
            body, true_body = prior.theta[10 * j : 10 * j + 10], truth[10 * j : 10 * j + 10]
            assert np.linalg.eigvalsh(pseudo_inertia(body))[0] > 0
            m, c, _ = mass_com_inertia(body)
            m0, c0, _ = mass_com_inertia(true_body)
            assert abs(m / m0 - 1) <= 0.2 + 1e-12
            # a joint's body may weld several MuJoCo bodies: their combined centre moves by at most 1 cm per axis
            assert np.all(np.abs(c - c0) <= 0.01 + 1e-9)
        n_rb = 10 * plant.nv
        armature = prior.theta[n_rb : n_rb + plant.nv]
        assert np.all(np.abs(armature - plant.armature) <= 0.3 * plant.armature + 1e-15)
        assert np.all(prior.theta[n_rb + plant.nv :] == 0)  # friction unknown
        assert prior.summary(truth)["is_truth"] is False
        assert prior.summary(truth)["path"] is None  # compiled in memory: no file to point at (it named one)


def test_prior_plant_drives_feedforward_with_its_own_wrong_inertials() -> None:
    plant = load_plant("two_link")
    model = ParameterModel(plant, ("armature",))
    prior = make_prior(model, PriorSpec(seed=3), np.random.default_rng(0), simulated=True)
    rng = np.random.default_rng(1)
    q, dq, ddq = rng.normal(size=(3, 20, plant.nv))
    ours = inverse_dynamics(prior.plant.mj_model, q, dq, ddq)
    np.testing.assert_allclose(
        ours, np.einsum("knp,p->kn", ParameterModel(prior.plant, ("armature",)).regressor(q, dq, ddq), prior.theta)
    )
    assert not np.allclose(ours, inverse_dynamics(plant.mj_model, q, dq, ddq), rtol=1e-3)


def test_prior_refuses_the_truth() -> None:
    model = ParameterModel(load_plant("pendulum"))
    with pytest.raises(ValueError, match="truth itself"):
        PriorSpec(mass_rel=0.0, com_m=0.0, inertia_rel=0.0)
    with pytest.raises(ValueError, match="simulated truth"):
        make_prior(model, PriorSpec(kind="mjcf"), np.random.default_rng(0), simulated=True)
    # on real data the system's MJCF is the user's nominal model, and it is the prior
    nominal = make_prior(model, PriorSpec(kind="mjcf"), np.random.default_rng(0), simulated=False)
    np.testing.assert_array_equal(nominal.theta, model.truth())
    assert Path(nominal.summary(model.truth())["path"]).is_file()
    with pytest.raises(ValueError, match="valid choices: mjcf, perturbed"):
        PriorSpec(kind="cad")
    with pytest.raises(ValueError, match="valid keys"):
        PriorSpec.from_dict({"mass": 0.2})


def test_prior_mjcf_with_other_joints_is_refused() -> None:
    model = ParameterModel(load_plant("pendulum"))
    from dynamics.plant import mjcf_path

    with pytest.raises((ValueError, ModelError), match="differ"):
        make_prior(
            model, PriorSpec(kind="mjcf", mjcf=str(mjcf_path("two_link"))), np.random.default_rng(0), simulated=True
        )
    # a missing file is named by its key, as system.mjcf's is (it said only "model file not found: <path>")
    with pytest.raises(ValueError, match=r"^prior\.mjcf: model file not found: .*nope\.xml"):
        make_prior(
            model, PriorSpec(kind="mjcf", mjcf="/nonexistent/nope.xml"), np.random.default_rng(0), simulated=True
        )

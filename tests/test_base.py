"""Base parameters: the regrouping is exact and carries the classical names."""

from __future__ import annotations

import re

import numpy as np
import pytest

from dynamics.base import base_parameters
from dynamics.errors import RankDeficientError
from dynamics.plant import load_plant
from dynamics.regressor import ParameterModel


@pytest.mark.parametrize(
    ("system", "effects", "rank"),
    [
        ("pendulum", (), 3),
        ("two_link", ("armature",), 7),
        ("wheel_pendulum", (), 6),
        ("two_link", ("armature", "viscous_friction", "coulomb_friction", "torque_offset"), 13),
    ],
)
def test_base_regressor_reproduces_the_full_model(system: str, effects: tuple[str, ...], rank: int) -> None:
    model = ParameterModel(load_plant(system), effects)
    base = base_parameters(model, np.random.default_rng(0))
    assert base.rank == rank
    rng = np.random.default_rng(5)
    n, nv = 50, model.plant.nv
    q, dq, ddq = rng.normal(size=(n, nv)), rng.normal(size=(n, nv)), rng.normal(size=(n, nv))
    W = model.regressor(q, dq, ddq)
    theta = rng.normal(size=model.n_params)  # any parameters, not only the true ones
    np.testing.assert_allclose(base.columns(W) @ base.project(theta), W @ theta, atol=1e-10)


def test_two_link_base_parameters_have_the_classical_names() -> None:
    base = base_parameters(ParameterModel(load_plant("two_link"), ("armature",)), np.random.default_rng(0))
    assert base.names == ("MX1", "MZ1 - 0.2*m2", "YY1 + 0.04*m2 + Ia1", "MX2", "MZ2", "YY2", "Ia2")


def test_a_menagerie_arms_base_parameters_carry_no_rounding_terms() -> None:
    """The SO-ARM100's first moments regroup as MX1 + MX2 + MX3 + MX4 (least squares left 1e-10 * ZZ terms in
    it, named as if they were a dependence), and the regrouping stays exact."""
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "shared" / "robots" / "so_arm100.xml"
    if not path.is_file():
        pytest.skip(f"{path} is not here (the shared Menagerie arms)")
    model = ParameterModel(load_plant(str(path)), ())
    base = base_parameters(model, np.random.default_rng(0))
    assert "MX1 + MX2 + MX3 + MX4" in base.names, base.names
    rounding = [n for n in base.names if re.search(r"e-(09|1\d)\*", n)]  # 1.2e-06*MZ6 is geometry, not rounding
    assert not rounding, rounding
    rng = np.random.default_rng(5)
    q, dq, ddq = (rng.normal(size=(50, model.plant.nv)) for _ in range(3))
    W = model.regressor(q, dq, ddq)
    theta = rng.normal(size=model.n_params)
    np.testing.assert_allclose(base.columns(W) @ base.project(theta), W @ theta, atol=1e-9)


def test_rank_deficient_data_are_refused() -> None:
    from envs.dataset import Dataset
    from identify.derivatives import States
    from identify.estimators import estimate
    from identify.problem import build_problem

    model = ParameterModel(load_plant("pendulum"))
    base = base_parameters(model, np.random.default_rng(0))
    n = 100
    still = np.zeros((n, 1))  # a pendulum at rest excites only part of its parameters
    data = Dataset(time=np.arange(n) * 0.01, q=still, tau=still, joint_names=("swing",), actuated=np.ones(1, bool))
    problem = build_problem(data, States(still, still, still, np.ones(n, bool)), model, base)
    with pytest.raises(RankDeficientError, match="does not excite"):
        estimate("ols", problem)


def test_unknown_effect_lists_valid_choices() -> None:
    with pytest.raises(ValueError, match="valid choices: armature, coulomb_friction"):
        ParameterModel(load_plant("pendulum"), ("backlash",))

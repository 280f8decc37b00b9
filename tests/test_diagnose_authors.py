"""The DFKI authors' model as a regressor: the same torque as their formulas, for any parameter set."""

from __future__ import annotations

import numpy as np

from identify.diagnose.authors import AUTHOR_KEYS, author_base, author_regressor, author_torque


def _parameters(rng: np.random.Generator) -> dict[str, float]:
    p = {k: float(rng.uniform(0.01, 1.0)) for k in AUTHOR_KEYS}
    p.update(g=9.81, gr=6.0, l1=0.2, l2=0.3, Ir=float(rng.uniform(1e-5, 1e-4)))
    return p


def test_regressor_reproduces_the_authors_torque() -> None:
    rng = np.random.default_rng(3)
    q, dq, ddq = (rng.uniform(-a, a, (200, 2)) for a in (3.0, 10.0, 50.0))
    for _ in range(3):
        p = _parameters(rng)
        Y = author_regressor(q, dq, ddq, l1=p["l1"], g=p["g"], gr=p["gr"])
        np.testing.assert_allclose(Y @ author_base(p), author_torque(p, q, dq, ddq), rtol=1e-12, atol=1e-12)


def test_regressor_columns_are_independent_on_generic_motion() -> None:
    # every combination of AUTHOR_BASE_NAMES is identifiable: refitting the form is well posed
    rng = np.random.default_rng(4)
    q, dq, ddq = (rng.uniform(-a, a, (300, 2)) for a in (3.0, 10.0, 50.0))
    Y = author_regressor(q, dq, ddq, l1=0.2, g=9.81, gr=6.0).reshape(-1, 9)
    assert np.linalg.matrix_rank(Y) == 9

"""The cogging candidate's period: scanned only among periods the joint's motion spans at least once
(`MIN_COGGING_PERIODS`). A longer period is a smooth function of q on the data (as gravity, an offset or a
spring), and fitted as a sinusoid it would extrapolate to angles the data never reached."""

from __future__ import annotations

import numpy as np
import pytest

from dynamics.plant import load_plant
from identify.diagnose.candidates import (
    COGGING_HARMONICS,
    MIN_COGGING_PERIODS,
    Signals,
    candidates,
    cogging_harmonic,
    position_harmonic,
)


def _signals(amplitude_rad: float, torque: np.ndarray | None = None, n_true: float = 0.0) -> Signals:
    """A shoulder swinging +-`amplitude_rad` for 20 s at 100 Hz (the elbow still) whose residual is
    0.05 sin(n_true q) (none where n_true is 0)."""
    t = np.arange(0.0, 20.0, 0.01)
    q = np.zeros((len(t), 2))
    q[:, 0] = amplitude_rad * np.sin(2 * np.pi * 0.37 * t) * np.sin(2 * np.pi * 0.05 * t + 0.3)
    tau = np.zeros_like(q)
    if n_true:
        tau[:, 0] = 0.05 * np.sin(n_true * q[:, 0])
    zeros = np.zeros_like(q)
    return Signals(
        time=t,
        q=q,
        dq=zeros,
        ddq=zeros,
        tau=tau,
        tau_nominal=zeros.copy(),
        dtau_dq=np.zeros((len(t), 2, 2)),
        dtau_dt=zeros,
        regressor=np.zeros((len(t), 2, 20)),
        record=np.zeros(len(t), dtype=int),
        actuated=np.ones(2, dtype=bool),
    )


def test_a_period_the_motion_spans_is_found() -> None:
    s = _signals(1.0, n_true=8.0)  # range 2 rad: periods up to 2 rad (n >= pi) are scanned
    n, amplitude = cogging_harmonic(s, 0)  # type: ignore[misc]
    assert n == 8.0 and amplitude == pytest.approx(0.05, rel=0.05)


def test_a_period_longer_than_the_motion_is_not_scanned() -> None:
    """n = 2 (period pi rad) over a 1.4 rad range: that residual is a smooth bump, not a periodic torque. The scan
    does not try the long period; the best harmonic it may try is its longest one (its edge), where the true period
    may be longer still: no cogging candidate is made (the residual's signature still reports that harmonic)."""
    s = _signals(0.7, n_true=2.0)
    span = float(np.ptp(s.q[:, 0]))
    found = position_harmonic(s, 0, s.residual[:, 0])
    assert found is not None
    n = found[0]
    assert n * span >= 2 * np.pi * MIN_COGGING_PERIODS and n > 2.0
    assert n == COGGING_HARMONICS[COGGING_HARMONICS * span >= 2 * np.pi * MIN_COGGING_PERIODS][0]  # the edge
    assert cogging_harmonic(s, 0) is None
    # the old scan, over every harmonic, did pick the long period
    assert 2 * np.pi / COGGING_HARMONICS[0] > span


def test_a_joint_that_spans_no_period_has_no_cogging_candidate() -> None:
    """The elbow does not move and the shoulder moves +-0.05 rad: no scanned period (the shortest is 2 pi / 40.5
    = 0.155 rad) fits in 0.1 rad."""
    s = _signals(0.05, n_true=40.0)
    assert cogging_harmonic(s, 0) is None
    assert cogging_harmonic(s, 1) is None
    plant = load_plant("two_link")
    assert [c for c in candidates(plant, ["cogging"], np.random.default_rng(0), s) if c.effect == "cogging"] == []


def test_a_period_shorter_than_the_scan_is_not_named_at_the_scans_end() -> None:
    """A 42-cycle ripple (a 7-cycle motor ripple through a 6:1 gear) lies beyond the shortest period scanned
    (n = 40): the best harmonic is the scan's end, and a candidate there named n = 40 with an amplitude 24 % low
    and a std that knew nothing of the period. No candidate is made; a period inside the scan still is."""
    s = _signals(1.0, n_true=42.0)
    found = position_harmonic(s, 0, s.residual[:, 0])
    assert found is not None and found[0] == COGGING_HARMONICS[-1]
    assert cogging_harmonic(s, 0) is None
    for inside in (37.0, 40.0):  # 40, the shortest period named, too: the scan goes half a step beyond it
        n, _ = cogging_harmonic(_signals(1.0, n_true=inside), 0)  # type: ignore[misc]
        assert n == inside

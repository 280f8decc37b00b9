"""Data anomalies are named before anything is fitted, and the verdict follows the residual that is left."""

from __future__ import annotations

import numpy as np
import pytest

from envs.dataset import Dataset
from identify.diagnose.anomalies import find_anomalies
from identify.diagnose.diagnosis import Finding, _verdict, _with_drift


def _record(q: np.ndarray, tau: np.ndarray, tau_cmd: np.ndarray | None = None) -> Dataset:
    n = len(q)
    return Dataset(
        time=np.arange(n) / 500.0,
        q=q,
        tau=tau,
        joint_names=("shoulder", "elbow"),
        actuated=np.array([True, True]),
        tau_cmd=tau_cmd,
        source="log.csv",
    )


def test_a_joint_that_never_moves_a_torque_stuck_at_zero_and_a_saturated_torque_are_named() -> None:
    t = np.arange(3000) / 500.0
    rng = np.random.default_rng(0)
    swing = np.sin(2 * np.pi * 0.5 * t)
    # the elbow stays within +-0.002 rad while the shoulder swings (as in one DFKI C.1 log)
    q = np.column_stack([swing, 0.002 * np.sin(2 * np.pi * 3 * t)])
    tau = np.column_stack([np.clip(3 * swing, -2.0, 2.0), np.zeros_like(t)])
    found = {(a.kind, a.joint) for a in find_anomalies([_record(q, tau)])}
    assert found == {
        ("joint_never_moves", "elbow"),
        ("torque_stuck_at_zero", "elbow"),
        ("torque_saturated", "shoulder"),
    }
    still = next(a for a in find_anomalies([_record(q, tau)]) if a.kind == "joint_never_moves")
    # a joint that never moves is held by static friction: its torque error there is no evidence on friction
    assert still.describe().startswith("log.csv: elbow never moves (range_rad ") and "static" in still.describe()
    # clean data: nothing
    clean = _record(
        np.column_stack([swing, np.cos(t)]), np.column_stack([swing, np.cos(t)]) + rng.normal(0, 0.01, (3000, 2))
    )
    assert find_anomalies([clean]) == []


def test_a_clipped_command_is_named_even_when_the_measured_torque_is_not_clipped() -> None:
    t = np.arange(3000) / 500.0
    cmd = np.clip(12 * np.sin(2 * np.pi * 0.5 * t), -8, 8)
    q = np.column_stack([np.sin(t), np.cos(t)])
    tau = np.column_stack([0.5 * cmd + 0.01 * np.sin(7 * t), np.sin(3 * t)])
    anomalies = find_anomalies([_record(q, tau, np.column_stack([cmd, np.sin(3 * t)]))])
    assert [(a.kind, a.joint, a.detail["commanded"]) for a in anomalies] == [("torque_saturated", "shoulder", 1.0)]
    assert "saturated" in anomalies[0].describe()


class _Signals:
    """The two attributes `_verdict` reads."""

    def __init__(self, tau: np.ndarray) -> None:
        self.tau = tau

    @staticmethod
    def smooth(x: np.ndarray) -> np.ndarray:
        return x


def _finding() -> Finding:
    return Finding("viscous_friction", "elbow", 0.1, 0.01, "N m s/rad", "joint damping", {}, {})


WHITE = [{"structured": False}, {"structured": False}]
STRUCTURED = [{"structured": False}, {"structured": True}]


@pytest.mark.parametrize(
    ("findings", "cal_err", "nominal_white", "calibrated_white", "verdict"),
    [
        ([], 0.2, WHITE, WHITE, "no_discrepancy"),
        ([], 0.2, STRUCTURED, STRUCTURED, "unexplained_structure"),
        # effects found, held-out error drops, the rest is white: explained
        ([_finding()], 0.05, STRUCTURED, WHITE, "explained"),
        # found and better, but structure remains: unexplained, whatever was found
        ([_finding()], 0.05, STRUCTURED, STRUCTURED, "unexplained_structure"),
        # found on the training data but worse on the held-out data: never explained
        ([_finding()], 0.3, STRUCTURED, WHITE, "unexplained_structure"),
        ([_finding()], 0.3, WHITE, WHITE, "no_discrepancy"),
    ],
)
def test_verdict_rules(
    findings: list[Finding], cal_err: float, nominal_white: list, calibrated_white: list, verdict: str
) -> None:
    tau = np.zeros((100, 2))
    preds = {"nominal": np.full((100, 2), 0.2), "calibrated": np.full((100, 2), cal_err)}
    got, reason = _verdict(findings, _Signals(tau), preds, np.ones(2), nominal_white, calibrated_white)  # type: ignore[arg-type]
    assert got == verdict, reason
    assert reason
    # training records whose torque zero differs are structure whatever the validation says, and both are said
    drift = [{"joint": "shoulder", "spread": 0.2}]
    with_drift, both = _with_drift(got, reason, drift)
    assert with_drift == "unexplained_structure"
    assert both.startswith(reason) and "shoulder (0.2 N m)" in both
    assert _with_drift(got, reason, []) == (got, reason)


def test_a_command_that_touches_its_limit_a_row_at_a_time_again_and_again_is_clipped() -> None:
    """A fast controller's command at 616 Hz hits its 8 N m limit for one or two rows per swing, 9 times: named
    (runs of two rows alone would not be); a quantised sine whose peaks repeat exactly every period is not."""
    t = np.arange(3000) / 616.0
    rng = np.random.default_rng(3)
    cmd = rng.uniform(-7.5, 7.5, len(t))  # a jumpy PID command
    hits = np.arange(40, 700, 80)  # 9 swings, each clipped for one row or two
    cmd[hits] = 8.0
    cmd[hits[::2] + 1] = 8.0
    q = np.column_stack([np.sin(t), np.cos(t)])
    tau = np.column_stack([0.5 * np.sin(2 * np.pi * 1.3 * t), np.sin(3 * t)])
    named = find_anomalies([_record(q, tau, np.column_stack([cmd, np.sin(3 * t)]))])
    assert [(a.kind, a.joint) for a in named] == [("torque_saturated", "shoulder")]
    assert named[0].detail["longest_run"] <= 2 and named[0].detail["episodes"] >= 3
    quantised = np.round(2.0 * np.sin(2 * np.pi * 1.25 * t) / 0.0059) * 0.0059  # 12 bits over +-12 N m
    assert find_anomalies([_record(q, np.column_stack([quantised, np.sin(3 * t)]))]) == []

"""What the validation records say about the fit beyond their RMS: where they leave the training motion (the
calibrated model extrapolates there) and how uncertain the calibrated prediction is from the parameters alone.

The data: small-angle motions of the two-link arm with a known change of link 2's mass along the link, torques
from the plant's own inverse dynamics (`tests/test_diagnose_offset_like.py`), white noise on the training
records and none on the validation record, whose torque RMS is then the prediction's own error.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_diagnose_offset_like import ALONG_LINK, SIGMA, _record

from dynamics.plant import Plant, load_plant
from dynamics.regressor import rigid_body_regressor
from dynamics.torque import joint_torque
from envs.dataset import Dataset
from identify.derivatives import derive_states
from identify.diagnose import diagnose
from identify.diagnose.anomalies import OUTSIDE_SHARE, describe_outside, outside_training
from identify.diagnose.candidates import Signals, candidates, signals
from identify.diagnose.diagnosis import _position_matters

NAMES = ("a", "b")


def _truth(plant: Plant, rng: np.random.Generator, record: int, scale: float = 1.0, noise: float = SIGMA) -> Dataset:
    """A record of the two-link arm with link 2's `ALONG_LINK` change; its motion scaled by `scale`."""
    rigid = next(c for c in candidates(plant, ["rigid_body"], np.random.default_rng(0)) if c.effect == "rigid_body")
    delta = np.zeros(len(rigid.parameter_names))
    for name, value in ALONG_LINK.items():
        delta[rigid.parameter_names.index(name)] = value
    s = _record(plant, rng, record)
    if scale != 1.0:
        q, dq, ddq = scale * s.q, scale * s.dq, scale * s.ddq
        moved = {"q": q, "dq": dq, "ddq": ddq, "regressor": rigid_body_regressor(plant, q, dq, ddq)}
        s = Signals(**{**s.__dict__, **moved, "tau_nominal": joint_torque(plant, q, dq, ddq)[0]})
    tau = s.tau_nominal + rigid.build(s) @ delta + rng.normal(0.0, 1.0, s.tau.shape) * noise
    return Dataset(s.time, s.q, tau, plant.joint_names, np.asarray(plant.actuated), dq=s.dq, ddq=s.ddq)


def test_the_prediction_std_is_the_size_of_the_calibrated_prediction_error() -> None:
    """Over 40 seeds, the mean squared error of the calibrated torque on a noise-free validation record (the
    truth) is the mean variance `info.prediction_std` claims, on each joint (measured: 1.12 / 0.93 on these seeds,
    0.96 to 1.24 on three other sets of 40)."""
    plant = load_plant("two_link")
    err2, var2 = [], []
    for seed in range(40):
        rng = np.random.default_rng(7000 + seed)
        train = [_truth(plant, rng, r) for r in range(2)]
        held = _truth(plant, rng, 2, noise=0.0)
        dg = diagnose(plant, train, [held], rng=np.random.default_rng(0), effects=("rigid_body",), derivatives="given")
        assert [f.effect for f in dg.findings] == ["rigid_body"]
        err2.append(np.square(list(dg.models["calibrated"]["torque_rms"].values())))
        var2.append(np.square(list(dg.info["prediction_std"].values())))
    ratio = np.mean(err2, axis=0) / np.mean(var2, axis=0)
    assert np.all((ratio > 0.7) & (ratio < 1.45)), ratio


def test_a_validation_record_that_swings_wider_is_named_as_outside_the_training_motion() -> None:
    """Training records swing a few tenths of a radian; a validation record three times wider is named (angles
    and speeds), one like the training records is not."""
    plant = load_plant("two_link")
    rng = np.random.default_rng(11)
    train = [_truth(plant, rng, r) for r in range(2)]
    alike, wider = _truth(plant, rng, 2), _truth(plant, rng, 3, scale=3.0)
    wider = Dataset(wider.time, wider.q, wider.tau, wider.joint_names, wider.actuated, dq=wider.dq, ddq=wider.ddq,
                    source="wider.csv")  # fmt: skip
    dg = diagnose(plant, train, [alike, wider], rng=np.random.default_rng(0), effects=("rigid_body",),
                  derivatives="given")  # fmt: skip
    named = dg.info["outside_training"]
    assert {d["source"] for d in named} == {"wider.csv"}, named
    assert {d["joint"] for d in named} == {"shoulder", "elbow"}
    for d in named:
        assert d["share_outside_by_angle"] > 0.2 and d["share_outside_by_speed"] > 0.2
        assert d["validation_angle"][1] > d["train_angle"][1]
    notes = [n for n in dg.notes if "outside the training motion" in n]
    assert len(notes) == 2 and all(n.startswith("wider.csv: ") and "extrapolates" in n for n in notes), notes


def test_angles_inside_the_training_motion_are_not_named() -> None:
    t = np.linspace(0, 10, 2000)
    q = np.column_stack([np.sin(t), 0.5 * np.cos(2 * t)])
    dq = np.column_stack([np.cos(t), -np.sin(2 * t)])
    found = outside_training(
        q, dq, 0.9 * q[::3], 0.9 * dq[::3], np.zeros(len(q[::3]), int), names=NAMES, sources=["v"],
        hinge=np.array([True, True]), position_matters=np.array([True, True]),
    )  # fmt: skip
    assert found == []


def test_a_hinge_angle_one_turn_away_is_inside() -> None:
    """The torque of a hinge repeats every turn: an oscillation about pi is covered by one about -pi."""
    t = np.linspace(0, 10, 2000)
    q = np.column_stack([np.pi + 0.3 * np.sin(t), 0.3 * np.sin(t)])
    dq = np.column_stack([0.3 * np.cos(t), 0.3 * np.cos(t)])
    kwargs = {"names": NAMES, "sources": ["v"], "position_matters": np.array([True, True])}
    shifted = q - np.array([2 * np.pi, 0.0])
    assert outside_training(q, dq, shifted, dq, np.zeros(len(q), int), hinge=np.array([True, True]), **kwargs) == []
    slide = outside_training(q, dq, shifted, dq, np.zeros(len(q), int), hinge=np.array([False, True]), **kwargs)
    assert [d["joint"] for d in slide] == ["a"] and slide[0]["unit"] == "m"  # a slide does not wrap
    assert slide[0]["share_outside_by_angle"] == 1.0 and slide[0]["share_outside_by_speed"] == 0.0
    assert " m; training " in describe_outside(slide[0]) and "m/s" not in describe_outside(slide[0])


def test_speeds_beyond_the_fastest_training_speed_are_named_and_a_cyclic_angle_is_not() -> None:
    t = np.linspace(0, 10, 2000)
    q = np.column_stack([0.3 * np.sin(t), 5.0 * t])  # joint b: a wheel turning at 5 rad/s
    dq = np.column_stack([0.3 * np.cos(t), np.full_like(t, 5.0)])
    q_val = np.column_stack([0.3 * np.sin(t), 100.0 + 5.0 * t])  # the wheel elsewhere, no faster
    dq_val = np.column_stack([0.6 * np.cos(t), np.full_like(t, 5.0)])  # joint a: twice as fast, same angles
    found = outside_training(
        q, dq, q_val, dq_val, np.zeros(len(t), int), names=NAMES, sources=["v.csv"],
        hinge=np.array([True, True]), position_matters=np.array([True, False]),
    )  # fmt: skip
    assert [d["joint"] for d in found] == ["a"]
    assert found[0]["share_outside_by_angle"] == 0.0
    assert found[0]["share_outside_by_speed"] == pytest.approx(np.mean(np.abs(0.6 * np.cos(t)) > 1.1 * 0.3), abs=1e-9)
    text = describe_outside(found[0])
    assert text.startswith("v.csv: a moves outside") and "faster than 1.1 x" in text and "positions" not in text


def test_a_share_below_the_threshold_is_not_named() -> None:
    t = np.linspace(0, 10, 1000)
    q = np.column_stack([0.3 * np.sin(t), 0.3 * np.sin(t)])
    q_val = q.copy()
    n_out = int(0.5 * OUTSIDE_SHARE * len(t))
    q_val[:n_out, 0] = 2.0  # a few rows far outside
    found = outside_training(
        q, q, q_val, q, np.zeros(len(t), int), names=NAMES, sources=["v"],
        hinge=np.array([True, True]), position_matters=np.array([True, True]),
    )  # fmt: skip
    assert found == []


def test_the_wheel_angle_changes_no_torque_and_the_pendulum_angle_does() -> None:
    plant = load_plant("wheel_pendulum")
    t = np.arange(0.0, 4.0, 0.01)
    q = np.column_stack([0.4 * np.sin(2 * t), 3.0 * t + np.sin(t)])
    data = Dataset(t, q, np.zeros_like(q), plant.joint_names, np.asarray(plant.actuated))
    s = signals(plant, data, derive_states(data, "butterworth", cutoff_hz=10.0))
    assert dict(zip(plant.joint_names, _position_matters(s).tolist(), strict=True)) == {
        plant.joint_names[0]: True,
        plant.joint_names[1]: False,
    }

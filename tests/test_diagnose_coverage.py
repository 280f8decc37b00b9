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

from dynamics.plant import Plant, load_plant, plant_from_xml
from dynamics.regressor import rigid_body_regressor
from dynamics.torque import joint_torque
from envs.dataset import Dataset
from identify.derivatives import derive_states
from identify.diagnose import diagnose
from identify.diagnose.anomalies import OUTSIDE_SHARE, describe_outside, outside_training
from identify.diagnose.candidates import Signals, candidates, signals
from identify.diagnose.diagnosis import _absorbed_value, _position_matters, _prediction_std
from identify.diagnose.statistics import LinearFit

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


HINGES = {"hinge": np.array([True, True]), "periodic": np.array([True, True])}


def _outside(q, dq, q_val, dq_val, **kwargs):  # type: ignore[no-untyped-def]
    """`outside_training` of one training and one validation record, both position-dependent hinges by default."""
    options = {"names": NAMES, "sources": ["v.csv"], **HINGES, "position_matters": np.array([True, True])}
    options.update(kwargs)
    return outside_training(q, dq, np.zeros(len(q), int), q_val, dq_val, np.zeros(len(q_val), int), **options)


def test_angles_inside_the_training_motion_are_not_named() -> None:
    t = np.linspace(0, 10, 2000)
    q = np.column_stack([np.sin(t), 0.5 * np.cos(2 * t)])
    dq = np.column_stack([np.cos(t), -np.sin(2 * t)])
    assert _outside(q, dq, 0.9 * q[::3], 0.9 * dq[::3]) == []


def test_a_hinge_angle_one_turn_away_is_inside_unless_a_spring_makes_the_torque_differ() -> None:
    """The torque of a hinge repeats every turn: an oscillation about pi is covered by one about -pi; with a
    joint spring it does not repeat, and a slide never wraps."""
    t = np.linspace(0, 10, 2000)
    q = np.column_stack([np.pi + 0.3 * np.sin(t), 0.3 * np.sin(t)])
    dq = np.column_stack([0.3 * np.cos(t), 0.3 * np.cos(t)])
    shifted = q - np.array([2 * np.pi, 0.0])
    assert _outside(q, dq, shifted, dq) == []
    spring = _outside(q, dq, shifted, dq, periodic=np.array([False, True]))
    assert [d["joint"] for d in spring] == ["a"] and spring[0]["unit"] == "rad"
    slide = _outside(q, dq, shifted, dq, hinge=np.array([False, True]))
    assert [d["joint"] for d in slide] == ["a"] and slide[0]["unit"] == "m"
    assert slide[0]["share_outside_by_angle"] == 1.0 and slide[0]["share_outside_by_speed"] == 0.0
    assert " m; training " in describe_outside(slide[0]) and "m/s" not in describe_outside(slide[0])


def test_speeds_beyond_the_fastest_training_speed_are_named_and_a_cyclic_angle_is_not() -> None:
    t = np.linspace(0, 10, 2000)
    q = np.column_stack([0.3 * np.sin(t), 0.3 * np.sin(t)])  # joint b: a wheel swinging 0.3 rad
    dq = np.column_stack([0.3 * np.cos(t), 0.3 * np.cos(t)])
    q_val = np.column_stack([0.3 * np.sin(t), 2.0 + 0.3 * np.sin(t)])  # the wheel elsewhere, no faster
    dq_val = np.column_stack([0.6 * np.cos(t), 0.3 * np.cos(t)])  # joint a: twice as fast, same angles
    found = _outside(q, dq, q_val, dq_val, position_matters=np.array([True, False]))
    assert [d["joint"] for d in found] == ["a"]
    assert found[0]["share_outside_by_angle"] == 0.0
    expected = np.mean(np.abs(0.6 * np.cos(t)) > 1.1 * 0.3 + 0.01)
    assert found[0]["share_outside_by_speed"] == pytest.approx(expected, abs=1e-9)
    text = describe_outside(found[0])
    assert text.startswith("v.csv: a moves outside") and "faster than 1.1 x" in text and "positions" not in text


def test_a_share_below_the_threshold_is_not_named() -> None:
    t = np.linspace(0, 10, 1000)
    q = np.column_stack([0.3 * np.sin(t), 0.3 * np.sin(t)])
    q_val = q.copy()
    q_val[: int(0.5 * OUTSIDE_SHARE * len(t)), 0] = 2.0  # a few rows far outside
    assert _outside(q, q, q_val, q) == []


def test_a_joint_held_still_is_not_outside_at_rounding_speeds_or_a_hair_away() -> None:
    """Held still in training (speed exactly 0) and in validation a hair away: filter rounding speeds and a
    position 0.0005 rad (or 1e-9 m) off are inside."""
    n = 500
    q = np.column_stack([np.full(n, 0.0870), np.full(n, 0.5)])
    q_val = np.column_stack([np.full(n, 0.0875), np.full(n, 0.5 + 1e-9)])
    rounding = np.full((n, 2), 3e-14)
    assert _outside(q, np.zeros((n, 2)), q_val, rounding, hinge=np.array([True, False])) == []


def test_sparse_rows_of_a_fast_rotation_cover_the_angles_between_them() -> None:
    """15 rad/s sampled at 50 Hz: 0.3 rad between rows. The motion passes every angle between two rows, so a
    phase-shifted validation record of the same rotation is inside."""
    t = np.arange(0, 4, 0.02)
    q = np.column_stack([15 * t, 0.3 * np.sin(t)])
    dq = np.column_stack([np.full_like(t, 15.0), 0.3 * np.cos(t)])
    assert _outside(q, dq, q + np.array([0.15, 0.0]), dq) == []


def test_training_records_are_not_joined_across_their_boundary() -> None:
    """Two training records at -1 and +1 rad do not cover the angles between them."""
    n = 200
    q = np.column_stack([np.r_[np.full(n, -1.0), np.full(n, 1.0)], np.zeros(2 * n)])
    found = outside_training(
        q, np.zeros_like(q), np.repeat([0, 1], n), np.zeros((n, 2)), np.zeros((n, 2)), np.zeros(n, int),
        names=NAMES, sources=["v.csv"], **HINGES, position_matters=np.array([True, True]),
    )  # fmt: skip
    assert [d["joint"] for d in found] == ["a"] and found[0]["share_outside_by_angle"] == 1.0


def test_the_prediction_std_is_the_rms_of_each_rows_std() -> None:
    """Rows of different uncertainty: the RMS of the per-row std (the square root of the mean variance), with
    the coefficients' covariance, correlations included; the nuisance block is left out."""

    columns = np.array([[[1.0, 0.0]], [[3.0, 3.0]]])  # one step's kept columns: (rows, joints, columns)
    cov = np.zeros((3, 3))
    cov[0, 0] = 100.0  # a nuisance coefficient: not part of the prediction
    cov[1:, 1:] = [[0.04, -0.03], [-0.03, 0.04]]
    fit = LinearFit(coef=np.zeros(3), cov=cov, sigma=np.ones(1))
    var = np.array([0.04, 9 * (0.04 + 0.04 - 2 * 0.03)])  # x' C x per row
    assert _prediction_std([columns], fit, 1, 1)[0] == pytest.approx(np.sqrt(var.mean()))


def _sines(plant: Plant, rng: np.random.Generator, shift: np.ndarray, amplitude: float = 0.4) -> Dataset:
    """A 6 s multi-sine record at 200 Hz about `shift`, its torque the plant's own inverse dynamics plus noise."""
    t = np.arange(0.0, 6.0, 0.005)
    q, dq, ddq = (np.zeros((len(t), plant.nv)) for _ in range(3))
    for j in range(plant.nv):
        for f in (0.4, 0.9):
            w, phase = 2 * np.pi * f * (1 + 0.1 * rng.random()), rng.uniform(0, 2 * np.pi)
            q[:, j] += amplitude * np.sin(w * t + phase)
            dq[:, j] += amplitude * w * np.cos(w * t + phase)
            ddq[:, j] -= amplitude * w**2 * np.sin(w * t + phase)
    q += shift
    tau = joint_torque(plant, q, dq, ddq)[0] + rng.normal(0.0, SIGMA, q.shape) * np.asarray(plant.actuated)
    return Dataset(t, q, tau, plant.joint_names, np.asarray(plant.actuated), dq=dq, ddq=ddq, source="v.csv")


def _named(plant: Plant, shift: np.ndarray) -> list[str]:
    rng = np.random.default_rng(4)
    train = [_sines(plant, rng, np.zeros(plant.nv)) for _ in range(2)]
    dg = diagnose(plant, train, [_sines(plant, rng, shift)], rng=np.random.default_rng(0),
                  effects=("viscous_friction",), derivatives="given")  # fmt: skip
    return [d["joint"] for d in dg.info["outside_training"]]


def test_diagnose_compares_a_hinge_within_one_turn_unless_a_spring_acts_on_it(tmp_path) -> None:  # type: ignore[no-untyped-def]
    plant = load_plant("two_link")
    turn = np.array([2 * np.pi, 0.0])
    assert _named(plant, turn) == []
    sprung = plant_from_xml(
        plant.path.read_text().replace('name="shoulder"', 'name="shoulder" stiffness="0.5"', 1), "sprung", tmp_path
    )
    assert float(sprung.stiffness[0]) == 0.5
    assert _named(sprung, turn) == ["shoulder"]


def test_diagnose_does_not_compare_the_wheel_angle() -> None:
    """The inertia-wheel pendulum's wheel angle changes no torque: a validation record with the wheel turned
    1.5 rad from where the training records kept it is inside; the pendulum turned as far is not."""
    plant = load_plant("wheel_pendulum")
    wheel = plant.joint_names.index("wheel")
    shift = np.zeros(plant.nv)
    shift[wheel] = 1.5
    assert _named(plant, shift) == []
    shift[1 - wheel] = 1.0
    assert _named(plant, shift) == [plant.joint_names[1 - wheel]]


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


def test_an_absorbed_column_takes_the_value_the_fit_gives_it_when_swapped_in() -> None:
    """Columns w, u, v fitted as 0.5 w + 2 u + 3 v, and a = 3 w + u + v (absorbed: in their span). The finding is
    (u, v); a leans most on w, outside it, so the swap takes the finding's column it leans on most, v (the larger
    column): the same torque is -8.5 w - u + 3 a, so a takes 3, with the std of v's coefficient (the covariance,
    a full one, carried through the same linear map)."""
    rng = np.random.default_rng(0)
    u, v, w = rng.normal(size=200), 2.0 * rng.normal(size=200), rng.normal(size=200)
    a = 3.0 * w + u + v
    M = np.column_stack([w, u, v, a])
    gram = M.T @ M
    coef = np.array([0.5, 2.0, 3.0])
    L = np.array([[0.1, 0.0, 0.0], [0.05, 0.2, 0.0], [0.02, 0.1, 0.3]])
    cov = L @ L.T  # a full covariance
    value, std = _absorbed_value(gram, coef, cov, [1, 2], 3)
    T = np.array([0.0, 0.0, 1.0])  # c_a is the coefficient of v
    assert value == pytest.approx(3.0, abs=1e-9) and std == pytest.approx(float(np.sqrt(T @ cov @ T)), abs=1e-9)
    assert _absorbed_value(gram, coef, cov, [0], 3) is not None  # w alone: a leans on it too
    assert _absorbed_value(np.eye(4), coef, cov, [1, 2], 3) is None  # orthogonal: a leans on none of them

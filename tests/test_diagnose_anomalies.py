"""Data anomalies are named before anything is fitted, and the verdict follows the residual that is left."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_ROBOTS

from dynamics.errors import DataError
from envs.dataset import Dataset
from identify.diagnose.anomalies import find_anomalies
from identify.diagnose.candidates import Signals
from identify.diagnose.diagnosis import Finding, _verdict, _with_drift, check_torque_columns


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


def test_a_torque_dropped_to_zero_for_a_while_on_a_moving_joint_is_named() -> None:
    """A log whose elbow torque reads exactly 0 over 40 % of its rows (a dropout) was called `no_discrepancy`
    with no anomaly: only a torque zero on more than half of the rows counted as stuck. A run of exact zeros
    while the joint moves is named too; the same zeros while the joint rests are not (a resting joint commanded
    nothing may read 0), nor are a few scattered ones."""
    t = np.arange(5000) / 500.0
    rng = np.random.default_rng(1)
    q = np.column_stack([np.sin(2 * np.pi * 0.5 * t), 0.8 * np.sin(2 * np.pi * 0.3 * t)])
    tau = np.column_stack([np.sin(t), np.cos(t)]) + rng.normal(0, 0.01, (5000, 2))
    dropped = tau.copy()
    dropped[1000:3000, 1] = 0.0
    (found,) = find_anomalies([_record(q, dropped)])
    assert (found.kind, found.joint, found.detail["longest_zero_run"]) == ("torque_stuck_at_zero", "elbow", 2000)
    resting = q.copy()
    resting[1000:3000, 1] = 0.3  # the same zeros while the elbow rests
    assert find_anomalies([_record(resting, dropped)]) == []
    short = tau.copy()
    short[1000:1090, 1] = 0.0  # 90 rows: under the 100 a dropout needs
    assert find_anomalies([_record(q, short)]) == []
    # a light joint's torque within a few steps of a 0.001 N m sensor's resolution reads 0 for long stretches
    coarse = tau.copy()
    coarse[:, 1] = np.round(0.002 * np.sin(2 * np.pi * 0.1 * t) + rng.normal(0, 0.0005, 5000), 3)
    coarse[1000:3000, 1] = 0.0
    assert find_anomalies([_record(q, coarse)]) == []


def test_a_clipped_command_is_named_even_when_the_measured_torque_is_not_clipped() -> None:
    t = np.arange(3000) / 500.0
    cmd = np.clip(12 * np.sin(2 * np.pi * 0.5 * t), -8, 8)
    q = np.column_stack([np.sin(t), np.cos(t)])
    tau = np.column_stack([0.5 * cmd + 0.01 * np.sin(7 * t), np.sin(3 * t)])
    anomalies = find_anomalies([_record(q, tau, np.column_stack([cmd, np.sin(3 * t)]))])
    assert [(a.kind, a.joint, a.detail["commanded"]) for a in anomalies] == [("torque_saturated", "shoulder", 1.0)]
    assert "saturated" in anomalies[0].describe()


class _Signals:
    """The attributes `_verdict` reads (every torque used)."""

    def __init__(self, tau: np.ndarray) -> None:
        self.tau = tau

    @staticmethod
    def smooth(x: np.ndarray) -> np.ndarray:
        return x

    @staticmethod
    def zero_unused(x: np.ndarray) -> np.ndarray:
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
        # found on the training data but worse on the held-out data: `diagnose` demotes them before the verdict
        # (tests/test_diagnose.py::test_an_effect_the_held_out_records_reject_is_not_named), which then sees none
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


def _swing(plant, truth, rng: np.random.Generator, source: str, *, elbow_still: bool = False) -> Dataset:  # type: ignore[no-untyped-def]
    """8 s of multi-sine motion at 200 Hz with the torque of `truth` plus 0.01 N m noise. `elbow_still`: the
    elbow is held at 0 by static friction while the shoulder swings, so its motor reports zero torque."""
    from dynamics.torque import joint_torque

    t = np.arange(0.0, 8.0, 0.005)
    q, dq, ddq = (np.zeros((len(t), 2)) for _ in range(3))
    for j in range(1 if elbow_still else 2):
        for f in (0.4, 0.9, 1.3):
            w, phase = 2 * np.pi * f * (1 + 0.1 * rng.random()), rng.uniform(0, 2 * np.pi)
            q[:, j] += 0.3 * np.sin(w * t + phase)
            dq[:, j] += 0.3 * w * np.cos(w * t + phase)
            ddq[:, j] -= 0.3 * w * w * np.sin(w * t + phase)
    tau = joint_torque(truth, q, dq, ddq)[0]
    if elbow_still:
        tau[:, 1] = 0.0
    tau += rng.normal(0.0, 0.01, tau.shape)
    return Dataset(t, q, tau, plant.joint_names, np.asarray(plant.actuated), dq=dq, ddq=ddq, source=source)


def test_a_joint_that_never_moves_in_a_training_file_is_left_out_of_the_fit_there(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Link 2 is 0.1 kg heavier than the nominal model; one of three training files has the elbow held by static
    friction (its motor reports zero) while the shoulder swings. Fitted, those zeros would say the heavier link
    needs no holding torque: without the exclusion the diagnosis names a shoulder torque gain and leaves 0.22 N m
    on the elbow (checked last). Left out there, the rigid-body change is found and the validation error is the
    noise; diagnosis.json and the notes say what was left out."""
    import identify.diagnose.diagnosis as diagnosis_module
    from dynamics.plant import load_plant, plant_from_xml
    from identify.diagnose import diagnose

    plant = load_plant("two_link")
    truth = plant_from_xml(plant.path.read_text().replace('mass="0.57"', 'mass="0.67"'), "heavier", tmp_path)
    rng = np.random.default_rng(1)
    train = [_swing(plant, truth, rng, "a.csv"), _swing(plant, truth, rng, "still.csv", elbow_still=True)]
    train.append(_swing(plant, truth, rng, "b.csv"))
    dg = diagnose(plant, train, [_swing(plant, truth, rng, "v.csv")], rng=np.random.default_rng(0), derivatives="given")
    assert dg.info["left_out_of_fit"] == [{"source": "still.csv", "joint": "elbow"}]
    assert any(n.startswith("still.csv: elbow's torque left out of the fit") for n in dg.notes), dg.notes
    assert dg.verdict == "explained" and {f.effect for f in dg.findings} <= {"rigid_body", "payload"}, dg.findings
    for joint, rms in dg.models["calibrated"]["torque_rms"].items():
        assert rms < 0.0115, (joint, rms)
    monkeypatch.setattr(
        diagnosis_module, "_still_joints", lambda records, hinge: np.zeros((len(records), len(hinge)), bool)
    )
    fooled = diagnose(plant, train, [_swing(plant, truth, np.random.default_rng(9), "v.csv")],
                      rng=np.random.default_rng(0), derivatives="given")  # fmt: skip
    assert fooled.verdict != "explained" and fooled.models["calibrated"]["torque_rms"]["elbow"] > 0.2
    assert "torque_gain shoulder" in [f.name for f in fooled.findings]


def test_a_joint_still_in_every_training_file_is_kept() -> None:
    """With the elbow still in every training file there is nothing else to fit it on: nothing is left out."""
    from dynamics.plant import load_plant
    from identify.diagnose import diagnose

    plant = load_plant("two_link")
    rng = np.random.default_rng(2)
    train = [_swing(plant, plant, rng, f"{k}.csv", elbow_still=True) for k in "ab"]
    dg = diagnose(plant, train, [_swing(plant, plant, rng, "v.csv")], rng=np.random.default_rng(0), derivatives="given")
    assert dg.info["left_out_of_fit"] == []


def test_rows_not_used_count_neither_in_the_fit_nor_in_its_noise_estimate() -> None:
    """`fit_bounded` with `used`: zeroed rows change no coefficient, and the noise level is that of the used rows
    alone (counted as observations, the zeros would dilute it and the degrees of freedom)."""
    from identify.diagnose.statistics import fit_bounded

    rng = np.random.default_rng(0)
    n = 4000
    X = rng.normal(size=(n, 2, 3))
    r = X @ np.array([1.0, -2.0, 0.5]) + rng.normal(0, 0.1, (n, 2))
    used = np.ones((n, 2), bool)
    used[: n // 2, 1] = False  # half of joint 2's rows say nothing
    masked = fit_bounded(X * used[:, :, None], r * used, np.ones(2), used=used)
    alone = fit_bounded(X[n // 2 :], r[n // 2 :], np.ones(2))  # the used rows of joint 2 with joint 1's alike
    assert np.allclose(
        masked.sigma,
        np.sqrt([np.mean((r - X @ masked.coef)[:, 0] ** 2), np.mean((r - X @ masked.coef)[n // 2 :, 1] ** 2)]),
    )
    assert masked.sigma[1] == pytest.approx(alone.sigma[1], rel=0.05)
    assert np.allclose(masked.coef, [1.0, -2.0, 0.5], atol=0.01)
    counted = fit_bounded(X * used[:, :, None], r * used, np.ones(2))  # the zeros counted as observations
    assert counted.sigma[1] < 0.75 * masked.sigma[1]  # what `used` prevents: a noise level diluted by zeros
    assert np.all(np.diag(masked.cov) >= np.diag(counted.cov))


def test_per_record_offsets_average_over_the_records_where_the_torque_was_fitted() -> None:
    """With a torque offset per record fitted as a nuisance, a record whose elbow torque is left out has no
    elbow offset: the calibrated offset is the mean over the others (a 0 for it would pull 0.08 to 0.053)."""
    from dynamics.plant import load_plant
    from identify.diagnose import diagnose

    plant = load_plant("two_link")
    rng = np.random.default_rng(5)
    files = [_swing(plant, plant, rng, "a.csv"), _swing(plant, plant, rng, "still.csv", elbow_still=True)]
    files += [_swing(plant, plant, rng, "b.csv"), _swing(plant, plant, rng, "v.csv")]
    for d in files:
        d.tau[:, 1] += 0.08  # the elbow's torque zero, the same in every file
    dg = diagnose(plant, files[:3], files[3:], rng=np.random.default_rng(0), derivatives="given", record_offsets=True)
    elbow = [o["elbow"] for o in dg.info["record_offsets"]]
    assert elbow[0] == pytest.approx(0.08, abs=0.005) and elbow[2] == pytest.approx(0.08, abs=0.005)
    assert dg.residual["elbow"]["mean"] == pytest.approx(0.08, abs=0.005)  # over the torques that were fitted
    assert np.isnan(elbow[1])  # no estimate where the torque was not fitted
    assert dg.models["calibrated"]["torque_rms"]["elbow"] < 0.0115


def test_a_record_where_nothing_moves_is_no_fold_that_a_candidate_wins() -> None:
    """A pendulum with hidden viscous friction; one of three training records never moves, so its only torque is
    left out and its fold has no value: the finding's fold gains say nothing there (no free gain of 1)."""
    from dynamics.plant import load_plant
    from dynamics.torque import joint_torque
    from identify.diagnose import diagnose

    plant = load_plant("pendulum")
    rng = np.random.default_rng(6)
    t = np.arange(0.0, 8.0, 0.005)

    def record(amplitude: float, source: str) -> Dataset:
        w, phase = 2 * np.pi * 0.7, rng.uniform(0, 2 * np.pi)
        q = amplitude * np.sin(w * t + phase)[:, None] + 0.2
        dq = amplitude * w * np.cos(w * t + phase)[:, None]
        ddq = -amplitude * w * w * np.sin(w * t + phase)[:, None]
        tau = joint_torque(plant, q, dq, ddq)[0] + 0.02 * dq + rng.normal(0, 0.005, q.shape)
        return Dataset(t, q, tau, plant.joint_names, np.asarray(plant.actuated), dq=dq, ddq=ddq, source=source)

    train = [record(0.5, "a.csv"), record(0.0, "still.csv"), record(0.6, "b.csv")]
    dg = diagnose(plant, train, [record(0.5, "v.csv")], rng=np.random.default_rng(0), derivatives="given")
    assert dg.info["left_out_of_fit"] == [{"source": "still.csv", "joint": "swing"}]
    viscous = [f for f in dg.findings if f.effect == "viscous_friction"]
    assert viscous and viscous[0].value == pytest.approx(0.02, rel=0.05), [f.name for f in dg.findings]
    gains = viscous[0].fold_gains
    assert len(gains) == 3 and np.isnan(gains[1]) and all(0 < g < 1 for g in (gains[0], gains[2])), gains


def test_a_slide_is_still_below_a_millimetre_not_below_a_centimetre() -> None:
    """0.01 is a hinge's threshold in rad (0.57 degrees); a slide's is 1 mm: a linear stage moving 5 mm moves."""
    t = np.arange(3000) / 500.0
    q = np.column_stack([np.sin(t), 0.0025 * np.sin(2 * np.pi * t)])  # the slide spans 5 mm
    tau = np.column_stack([np.sin(3 * t), np.cos(3 * t)]) + np.random.default_rng(1).normal(0, 0.01, (3000, 2))
    data = _record(q, tau)
    assert [a.joint for a in find_anomalies([data])] == ["elbow"]  # read as a hinge, 0.005 rad is still
    assert find_anomalies([data], hinge=np.array([True, False])) == []
    data.q[:, 1] *= 0.1  # 0.5 mm
    still = find_anomalies([data], hinge=np.array([True, False]))
    assert [(a.kind, a.joint) for a in still] == [("joint_never_moves", "elbow")] and "range_m" in still[0].detail


def shared_logs() -> list[Path]:
    from conftest import SHARED_DATA

    files = sorted(SHARED_DATA.glob("dfki_double_pendulum_c*/*.csv"))
    if not files:
        pytest.skip(f"real DFKI logs not found under {SHARED_DATA} (the project was cloned without ../shared)")
    return files


def shared_log(path: Path) -> Dataset:
    """One shared DFKI log read as `two_link` through its session's data config."""
    from omegaconf import OmegaConf

    from dynamics.plant import load_plant
    from envs.measured import read_measured

    conf = Path(__file__).resolve().parents[1] / "conf" / "data"
    name = "dfki_double_pendulum_c1" if "_c1" in str(path.parent) else "dfki_double_pendulum"
    columns = OmegaConf.to_container(OmegaConf.load(conf / f"{name}.yaml").columns)
    return read_measured(path, load_plant("two_link"), columns=columns)  # type: ignore[arg-type]


def _shared_record(path: Path, edit: Callable[[np.ndarray], np.ndarray] | None = None) -> tuple[Dataset, Signals]:
    from dynamics.plant import load_plant
    from identify.diagnose.diagnosis import _records

    plant = load_plant("two_link")
    data = shared_log(path)
    if edit is not None:
        data = dataclasses.replace(data, tau=edit(data.tau.copy()))
    rec = _records(plant, [data], "butterworth", {"cutoff_hz": 10.0}, 5.0)[0]
    return data, rec.signals


def test_every_shared_log_passes_the_torque_column_check_and_a_flipped_or_swapped_one_does_not() -> None:
    """Flipped: every file on the shoulder, and on the elbow wherever it is driven (C.1 144115's elbow is passive:
    its torque is about zero, no sign to read); both: every file (they had been read as both angle zeros half a
    turn off, the offset advised giving a wrong calibrated MJCF). Swapped: where the two joints' nominal torques
    differ enough along the motion (six of the ten files); a swap in a file where they do not is not named (no
    false claim)."""
    from dynamics.plant import load_plant

    plant = load_plant("two_link")
    flipped = {"shoulder": 0, "elbow": 0}
    swapped = 0
    files = shared_logs()
    for path in files:
        check_torque_columns(plant, *_shared_record(path))  # the logs as they are: no refusal
        for j, joint in enumerate(plant.joint_names):

            def flip(tau: np.ndarray, j: int = j) -> np.ndarray:
                tau[:, j] *= -1.0
                return tau

            try:
                check_torque_columns(plant, *_shared_record(path, flip))
            except DataError as err:
                assert f"{path.name}: tau_{joint} (the file's tau_meas{j + 1}) runs against" in str(err)
                assert "its sign looks flipped" in str(err)
                flipped[joint] += 1
        try:
            check_torque_columns(plant, *_shared_record(path, lambda tau: tau[:, ::-1].copy()))
        except DataError as err:
            if "the two columns look swapped" in str(err):
                swapped += 1
            else:  # 144115: its passive elbow's torque, about zero, on the driven shoulder
                assert path.name == "20230629-144115.csv" and "tau_shoulder (the file's tau_meas1) varies" in str(err)
                assert "or another joint's column" in str(err)
    assert flipped == {"shoulder": len(files), "elbow": len(files) - 1}
    assert swapped == 6
    every = 0  # both columns negated: refused in every file, as every column where the elbow carries torque enough
    for path in files:
        with pytest.raises(DataError, match="flipped") as err:
            check_torque_columns(plant, *_shared_record(path, lambda tau: -tau))
        every += "every torque column (tau_shoulder (the file's tau_meas1), tau_elbow" in str(err.value)
        assert str(err.value).startswith(f"{path}: ")  # the full path: two folders may hold files of one name
    assert every == 7  # 05, 143704 and 144115: the shoulder named first (negating it alone does about as well)


def test_a_finding_the_final_fit_leaves_at_its_value_of_no_effect_is_not_named() -> None:
    """The selection names an effect off its null; the final joint fit can still end it there (a friction at
    zero, a gain of exactly 1 at a bound): such a finding adds nothing to the model and must not be named. At a
    bound off the null, or at the null but not on a bound (an estimate that happens to be small), it stays."""
    from identify.diagnose.diagnosis import _pinned_at_null

    zero_at_bound = dataclasses.replace(_finding(), value=0.0, at_bound="lower")
    gain_at_bound = dataclasses.replace(_finding(), effect="torque_gain", value=1.0, at_bound="upper")
    off_null_at_bound = dataclasses.replace(_finding(), value=0.1, at_bound="lower")
    zero_inside = dataclasses.replace(_finding(), value=0.0)
    # a joint elasticity's compliance 0 at its bound: a stiffness of inf, whose value cannot be stated (it was
    # named, value None, and the run's summary failed on formatting it); a compliance off 0 at a bound stays
    rigid = dataclasses.replace(
        _finding(),
        effect="joint_elasticity",
        value=float("inf"),
        at_bound="lower",
        parameters=[{"name": "c2", "value": 0.0, "std": None, "at_bound": "lower"}],
    )
    compliant = dataclasses.replace(
        rigid,
        value=50.0,
        at_bound="upper",
        parameters=[{"name": "c2", "value": 0.02, "std": None, "at_bound": "upper"}],
    )
    findings = [zero_at_bound, gain_at_bound, off_null_at_bound, zero_inside, rigid, compliant]
    assert _pinned_at_null(findings, [0.0, 1.0, 0.0, 0.0, 0.0, 0.0]) == [zero_at_bound, gain_at_bound, rigid]


def test_a_torque_held_constant_is_not_called_saturated() -> None:
    """A joint held at rest by a constant torque never leaves its top level: no swing for a plateau to clip (an
    SO-ARM100 jaw read 0.006 N m on every row and was called saturated). A clipped swing still is."""
    t = np.arange(3000) / 500.0
    q = np.column_stack([np.sin(t), np.zeros_like(t)])
    tau = np.column_stack([np.sin(3 * t), np.full_like(t, 0.006)])
    assert [(a.kind, a.joint) for a in find_anomalies([_record(q, tau)])] == [("joint_never_moves", "elbow")]
    tau[:, 1] = np.round(np.clip(0.012 * np.sin(3 * t), -0.006, 0.006), 4)  # the same level, reached by a clip
    assert ("torque_saturated", "elbow") in {(a.kind, a.joint) for a in find_anomalies([_record(q, tau)])}


@pytest.mark.skipif(
    not (SHARED_ROBOTS / "so_arm100.xml").is_file(), reason="../shared/robots/ is not beside the project"
)
def test_a_joint_with_a_frictionloss_that_never_moves_in_any_file_names_nothing(tmp_path: Path) -> None:
    """An SO-ARM100 (frictionloss 0.1 N m on every joint) whose jaw is held still in every file while the other
    joints track multi-sines (the testbed: its own PD loop, not the harness's pipeline). The jaw's torque is
    static friction, set-valued: left in the fit, clean data were called `explained` by a jaw Coulomb friction and
    a torque gain both at their bounds and a torque offset, and a hidden elbow viscous friction was not named. The
    rigid-body refit reported beside them fitted columns these data barely excite."""
    from identify.diagnose.testbed import Injected, TestbedSystem, diagnose_case, torque_driven

    settings = TestbedSystem(
        (0.4, 0.3, 0.3, 0.4, 0.5, 0.0),  # the jaw is not tracked: its feed-forward holds it where it starts
        (20.0, 20.0, 20.0, 10.0, 5.0, 0.0),
        (1.0, 1.0, 1.0, 0.5, 0.2, 0.0),
        (0.01, 0.01, 0.01, 0.01, 0.01, 0.0),
        0.001,
        max_hz=1.0,
        center=(0.0, -1.5, 1.5, 0.0, 0.0, 0.0),
        rk4=True,
    )
    path = torque_driven(SHARED_ROBOTS / "so_arm100.xml", tmp_path)
    _, clean = diagnose_case("so_arm100", [], 0, mjcf=path, settings=settings)
    assert clean.verdict == "no_discrepancy" and clean.findings == [], [f.name for f in clean.findings]
    assert {(a["kind"], a["joint"]) for a in clean.anomalies} == {("joint_never_moves", "Jaw")}
    # the rigid-body refit leaves what these data barely excite nominal: 12 to 21 N m off on held-out data before
    nominal, refit = (clean.models[m]["torque_rms"] for m in ("nominal", "rigid_body_refit"))
    assert all(refit[j] < 1.5 * nominal[j] for j in nominal), (nominal, refit)
    _, viscous = diagnose_case(
        "so_arm100", [Injected("viscous_friction", "Elbow", 0.05)], 0, mjcf=path, settings=settings
    )
    first = viscous.findings[0]
    assert first.name == "viscous_friction Elbow" and abs(first.value - 0.05) < 3 * first.std, (first.name, first.value)
    assert all("Jaw" not in f.name for f in viscous.findings), [f.name for f in viscous.findings]


@pytest.mark.parametrize("seed", range(3))
def test_a_clip_read_through_noise_is_named_and_a_noisy_swing_or_noise_alone_is_not(seed: int) -> None:
    """A torque clipped at 5 N m and measured with 0.1 N m of noise: the noise spreads the plateau over a few
    of its stds, and read at the fine level (0.1 % of the peak) its top held about as many rows as the level
    below, so nothing was named (a Kinova Gen3 chattering at its limits in the testbed). An unclipped swing
    with the same noise, and the noise of a passive joint alone, are not clips."""
    rng = np.random.default_rng(seed)
    t = np.arange(5000) / 500.0
    q = np.column_stack([np.sin(t), np.cos(t)])
    swing = 8.0 * np.sin(2 * np.pi * 0.7 * t)
    clipped = np.round(np.clip(swing, -5.0, 5.0) + rng.normal(0, 0.1, t.size), 2)
    noisy = np.round(5.0 * np.sin(2 * np.pi * 0.7 * t) + rng.normal(0, 0.1, t.size), 2)
    found = {(a.kind, a.joint) for a in find_anomalies([_record(q, np.column_stack([clipped, noisy]))])}
    assert found == {("torque_saturated", "shoulder")}
    quiet = np.round(rng.normal(0, 0.03, (t.size, 2)), 3)  # commanded zero: the current loop's noise alone
    assert find_anomalies([_record(q, quiet)]) == []


_STOP_ARM = """<mujoco model="stoparm">
  <compiler angle="radian"/>
  <option timestep="0.002" integrator="RK4"/>
  <worldbody>
    <body name="l1" pos="0 0 1">
      <joint name="shoulder" type="hinge" axis="0 1 0" range="{lo} 3" stiffness="2" springref="0.1" armature="0.01"/>
      <inertial pos="0 0 -0.15" mass="1.2" diaginertia="0.01 0.012 0.004" quat="0.9 0.1 0 0"/>
      <body name="l2" pos="0 0 -0.3">
        <joint name="elbow" type="hinge" axis="0 1 0" range="{elbow}" ref="0.3" damping="0.05" armature="0.005"/>
        <inertial pos="0.05 0 -0.12" mass="0.6" fullinertia="0.004 0.005 0.002 0.0005 0.0003 0.0001"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="shoulder" forcerange="-30 30" ctrlrange="-30 30"/>
    <motor joint="elbow" forcerange="-15 15" ctrlrange="-15 15"/>
  </actuator>
</mujoco>
"""


def test_a_joint_pressed_into_its_stop_is_named_and_those_rows_are_left_out(tmp_path: Path) -> None:
    """An arm (a joint `ref`, a spring with its `springref`, damping, armature, a full inertia) whose shoulder
    swings into the end of its range on 7 % of the training rows and 35 % of the validation rows (the testbed's
    own PD loop; seed 1). The stop's force is in no model: left in, clean data were `unexplained_structure` and a
    hidden elbow viscous friction was not named. Rows near the stop are left out (half a state-filter period
    around it), the anomaly is named; data that never leave the stops are refused, naming the joints."""
    from identify.diagnose.testbed import Injected, TestbedSystem, diagnose_case

    settings = TestbedSystem((0.8, 0.8), (40.0, 15.0), (2.0, 0.8), (0.02, 0.02), 0.001, center=(0.0, 0.3), rk4=True)
    path = tmp_path / "stop.xml"
    path.write_text(_STOP_ARM.format(lo=-0.45, elbow="-2.5 2.5"))
    _, clean = diagnose_case("stoparm", [], 1, mjcf=path, settings=settings)
    assert clean.verdict == "no_discrepancy" and clean.findings == [], [f.name for f in clean.findings]
    stopped = {(Path(a["source"]).name, a["joint"]) for a in clean.anomalies if a["kind"] == "joint_at_limit"}
    assert stopped == {("testbed_train", "shoulder"), ("testbed_validation", "shoulder")}
    # reported as the stop's, not as friction's (the arm has no frictionloss): it was under held_by_nominal_friction
    assert clean.info["held_by_nominal_friction"] == {} and 0.05 < clean.info["left_out_at_limit"]["shoulder"] < 0.3
    _, viscous = diagnose_case(
        "stoparm", [Injected("viscous_friction", "elbow", 0.03)], 1, mjcf=path, settings=settings
    )
    first = viscous.findings[0]
    assert first.name == "viscous_friction elbow" and abs(first.value - 0.03) < 3 * first.std, (first.name, first.value)
    # the ranges read as degrees, as MJCF does by default: both joints spend 80 to 98 % of the rows in their stops.
    # Named so, with no finding (a 218 N m/rad elbow spring before); none of seeds 0-3 is refused by the torque
    # check (seed 2 was: the stopped elbow's torque "varies 0.0075 times as much as the nominal model's")
    path.write_text(_STOP_ARM.format(lo=-3, elbow="-2.5 2.5").replace('angle="radian"', 'angle="degree"'))
    for seed in (0, 2):
        _, degrees = diagnose_case("stoparm", [], seed, mjcf=path, settings=settings)
        assert degrees.findings == [], [f.name for f in degrees.findings]
        shares = {a["joint"]: a["fraction"] for a in degrees.anomalies if a["kind"] == "joint_at_limit"}
        assert set(shares) == {"shoulder", "elbow"} and min(shares.values()) > 0.75, shares
    # ranges of +-0.5 degree: no torque is left to judge, and the refusal names the joints
    path.write_text(
        _STOP_ARM.format(lo=-0.5, elbow="-0.5 0.5")
        .replace('angle="radian"', 'angle="degree"')
        .replace('="-0.5 3"', '="-0.5 0.5"')
    )
    with pytest.raises(
        DataError, match=r"no training torque is left to judge: .*shoulder at the end of its range on 9"
    ):
        diagnose_case("stoparm", [], 0, mjcf=path, settings=settings)


def test_a_stop_is_the_end_of_the_range_and_a_little_beyond_it_not_far_beyond() -> None:
    """`at_limit`: within 0.2 % of the range inside an end (at least 1 mrad, and at least the joint's `margin`), or
    pressed up to 0.05 rad beyond it (a soft stop); far beyond, the range is not the joint's (a plant without
    limits spun past it) and there is no stop; a slide's distances are a tenth in m; an unlimited joint never is."""
    from identify.diagnose.anomalies import at_limit

    q_range = np.array([[-1.0, 1.0], [-0.1, 0.1], [-np.inf, np.inf]])
    q = np.array([[0.0, 0.0, 5.0], [0.997, -0.0995, 1e9], [0.99, -0.098, 0.0], [-1.04, 0.1049, 0.0], [1.06, -0.16, 0]])
    assert at_limit(q, q_range).tolist() == [
        [False, False, False],
        [True, True, False],  # 0.003 inside a 2 rad range's end (tol 0.004); 0.0005 inside a 0.2 rad one (0.001)
        [False, False, False],  # 0.01 and 0.002 inside: clear of the stops
        [True, True, False],  # pressed 0.04 and 0.0049 beyond
        [False, False, False],  # 0.06 beyond: no stop holds a joint there
    ]
    assert at_limit(q, q_range, margin=np.array([0.02, 0.0, 0.0]))[2].tolist() == [True, False, False]
    assert at_limit(np.array([[0.0, 0.104, 0.0]]), q_range, hinge=np.array([True, False, True]))[0, 1]  # 4 mm
    assert not at_limit(np.array([[0.0, 0.106, 0.0]]), q_range, hinge=np.array([True, False, True]))[0, 1]
    with pytest.raises(ValueError, match=r"q_range has shape \(2, 2\); one \(low, high\) row per joint, \(3, 2\)"):
        at_limit(q, q_range[:2])


def test_the_rows_beside_a_stop_are_left_out_in_a_record_shorter_than_the_filter_window() -> None:
    """Half a period of a 1 Hz state filter at 500 Hz is 250 rows: a 20-row record at a stop crashed the dilation
    (a convolution longer than the record); the whole record is left out instead."""
    from types import SimpleNamespace

    from dynamics.plant import load_plant
    from identify.diagnose.diagnosis import _near_limit

    plant = load_plant("two_link")
    q = np.zeros((40, 2))
    q[5:8, 0] = plant.q_range[0, 1] - 1e-4  # the first record touches the shoulder's upper end for three rows
    s = SimpleNamespace(
        q=q, record=np.repeat([0, 1], 20), time=np.arange(40) / 500.0, state_hz=((0, 1.0), (1, 1.0)), band_hz=None
    )
    near = _near_limit(plant, s)  # type: ignore[arg-type]
    assert near[:20, 0].all() and not near[20:].any() and not near[:, 1].any()

"""The DFKI authors' model as a regressor: the same torque as their formulas, for any parameter set."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dynamics.errors import DataError
from identify.diagnose.authors import AUTHOR_KEYS, author_base, author_regressor, author_torque, load_author_model


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


def test_lab_form_refit_is_the_least_squares_optimum_of_their_form() -> None:
    """bench.diagnose.lab_form fitted on every C.0 file predicts them, in the judging band, at least as well (total
    squared error) as the lab's own parameters, which lie in the same form: the refit is the form's optimum."""
    from conftest import SHARED_DATA

    from bench.diagnose import _judged, lab_form
    from dynamics.plant import load_plant
    from envs.measured import read_many
    from identify.diagnose.authors import load_author_model

    folder = SHARED_DATA / "dfki_double_pendulum_c0"
    if not folder.is_dir():
        pytest.skip(f"real DFKI logs not found at {folder} (the project was cloned without ../shared)")
    columns = {
        "time": "time",
        **{
            f"{k}_{j}": f"{c}{i}"
            for i, j in ((1, "shoulder"), (2, "elbow"))
            for k, c in (("q", "pos_meas"), ("dq", "vel_meas"), ("tau", "tau_meas"))
        },
    }
    data = read_many(sorted(folder.glob("trajectory_0*.csv")), load_plant("two_link"), columns=columns)
    p = load_author_model(folder / "authors_identified" / "design_C.0_model_3.0.yml")
    refit = lab_form(data, p)
    sse_refit = sse_lab = 0.0
    for d, rms in zip(data, refit["all"], strict=True):
        _, q, dq, ddq, tau = _judged(d)
        sse_refit += len(q) * float(np.sum(np.square(rms)))
        sse_lab += float(np.sum((tau - author_torque(p, q, dq, ddq)) ** 2))
    assert sse_refit <= sse_lab * (1 + 1e-9)
    # and it is a real improvement on the files it was fitted to, not a copy of the lab's numbers
    assert sse_refit < 0.9 * sse_lab


def _split(name: str, calibrated: list[float], in_sample: list[float], lab: list[float]) -> dict:
    """One split of a `lofo_table`, with `lab` the best lab model's RMS."""
    return {
        "held_out": name,
        "torque_rms": {
            "nominal": [1.0, 1.0],
            "calibrated": calibrated,
            "authors_x": lab,
            "lab_form_others": [0.5, 0.5],
            "lab_form_all": [0.4, 0.4],
            "calibrated_all": in_sample,
        },
        "best_authors": lab,
        "wins": [c <= b for c, b in zip(calibrated, lab, strict=True)],
        "both_filtered": {"calibrated": calibrated, "authors_x": lab},
        "wins_both_filtered": [c <= b for c, b in zip(calibrated, lab, strict=True)],
        "reachable_in_sample": [True, True],
        "calibrated_in_sample": [c <= b for c, b in zip(in_sample, lab, strict=True)],
        "findings": [],
    }


def test_the_lofo_summary_counts_the_diagnosis_in_sample_bound_on_its_own_line() -> None:
    """The diagnosis fitted on every file (`calibrated_all`) is counted apart from the held-out splits: a split
    lost held out but won in sample (and the reverse) moves each count its own way."""
    from bench.diagnose import _lofo_markdown, lofo_summary

    table = {
        "session": "X",
        "authors": ["authors_x"],
        "splits": [
            _split("a.csv", [0.1, 0.3], [0.1, 0.1], [0.2, 0.2]),  # held out: elbow lost; in sample: both won
            _split("b.csv", [0.1, 0.1], [0.3, 0.1], [0.2, 0.2]),  # held out: both won; in sample: shoulder lost
        ],
    }
    lines = lofo_summary({"X": table}).split("\n")
    assert lines[0] == "torque_rms: sum 0.6000 N m, 3 of 4 joints and 1 of 2 splits <= the lab's best"
    assert lines[2] == "in-sample bound (fitted on every file): sum 0.6000 N m, 3 of 4 joints and 1 of 2 files " + (
        "<= the lab's best"
    )
    md = _lofo_markdown(table)
    lab = "| 0.2000 / 0.2000 | 0.5000 / 0.5000 | 0.4000 / 0.4000 | yes / yes |"
    assert f"| a.csv {lab} 0.1000 / 0.1000 | yes / yes |" in md
    assert f"| b.csv {lab} 0.3000 / 0.1000 | **no** / yes |" in md
    del table["splits"][0]["torque_rms"]["calibrated_all"]  # a table from before the bound: no line, no table
    assert "in-sample" not in lofo_summary({"X": table})
    assert "calibrated, all files" not in _lofo_markdown(table)


def test_the_cross_validated_rms_pools_every_held_out_row_of_a_session() -> None:
    """`bench.diagnose.cross_validated`: each split weighs by its judged rows (in `moving`, by the rows each joint
    keeps), so a long file lost by a little outweighs a short one won by a lot; the summary counts the joints whose
    pooled RMS is at most the better lab model's, and tables without row counts give no such line."""
    from bench.diagnose import cross_validated, cross_validated_markdown, lofo_summary

    splits = [
        _split("a.csv", [0.3, 0.1], [0.1, 0.1], [0.2, 0.2]),  # shoulder lost by 0.1 on 3000 rows
        _split("b.csv", [0.1, 0.1], [0.1, 0.1], [0.35, 0.2]),  # shoulder won by 0.25 on 1000 rows
    ]
    table = {"session": "X", "authors": ["authors_x"], "joints": ["shoulder", "elbow"], "splits": splits}
    assert cross_validated(table, "torque_rms") is None and "cross-validated" not in lofo_summary({"X": table})
    moving = (
        {"calibrated": [0.25, 0.1], "authors_x": [0.2, 0.2]},
        {"calibrated": [0.1, 0.1], "authors_x": [0.2, 0.05]},
    )
    for s, n, share, m in zip(splits, (3000, 1000), ([1.0, 0.5], [0.5, 1.0]), moving, strict=True):
        s["judged_rows"], s["moving_share"], s["moving"] = n, share, m
        s["mujoco_only"] = s["angle_zeroed"] = s["torque_rms"]
    pooled = cross_validated(table, "torque_rms")
    assert pooled is not None  # the summed RMS would win the shoulder (0.4 against 0.55); pooled, it is lost
    np.testing.assert_allclose(pooled["calibrated"], [np.sqrt((3000 * 0.09 + 1000 * 0.01) / 4000), 0.1])
    np.testing.assert_allclose(pooled["authors_x"], [np.sqrt((3000 * 0.04 + 1000 * 0.35**2) / 4000), 0.2])
    pooled_moving = cross_validated(table, "moving")
    assert pooled_moving is not None  # shoulder: 3000 rows and 500; elbow: 1500 and 1000
    np.testing.assert_allclose(pooled_moving["calibrated"][0], np.sqrt((3000 * 0.0625 + 500 * 0.01) / 3500))
    np.testing.assert_allclose(pooled_moving["authors_x"][1], np.sqrt((1500 * 0.04 + 1000 * 0.0025) / 2500))
    line = [x for x in lofo_summary({"X": table}).split("\n") if x.startswith("cross-validated")]
    assert line == [
        "cross-validated (every held-out row of a session, each file held out once): torque_rms 1 of 2, "
        "both_filtered 1 of 2, mujoco_only 1 of 2, angle_zeroed 1 of 2, moving 1 of 2 joints <= the better lab model"
    ]
    md = cross_validated_markdown({"X": table})
    assert "| X | torque_rms | 0.2646 / 0.1000 | authors_x: 0.2462 / 0.2000 | 0.2462 / 0.2000 | **no** / yes |" in md
    assert "| X | moving | 0.2345 / 0.1000 | authors_x: 0.2000 / 0.1581 | 0.2000 / 0.1581 | **no** / yes |" in md
    splits[1]["moving"] = {"calibrated": [0.1, float("nan")], "authors_x": [0.2, float("nan")]}  # elbow never moves
    splits[1]["moving_share"] = [0.5, 0.0]
    pooled_moving = cross_validated(table, "moving")
    assert pooled_moving is not None  # the NaN of a joint with no rows kept weighs nothing
    np.testing.assert_allclose([pooled_moving["calibrated"][1], pooled_moving["authors_x"][1]], [0.1, 0.2])


def test_the_judged_files_own_angle_zero_is_found_on_the_file() -> None:
    """`bench.diagnose._angle_zeroed` (the reading that gives every model the held-out file's encoder zero): angles
    logged from a zero 0.07 / 0.05 rad off the model's are put back, and the error left is the noise's."""
    from bench.diagnose import _angle_zeroed

    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 10.0, 2000)
    true_q = np.column_stack([0.8 * np.sin(2.0 * t), 1.1 * np.cos(3.0 * t)])
    shift = np.array([0.07, 0.05])  # true = logged + shift

    def predict(q: np.ndarray) -> np.ndarray:  # a gravity-like torque, (N, 2)
        return np.column_stack([2.0 * np.sin(q[:, 0]) + 0.5 * np.sin(q[:, 0] + q[:, 1]), np.sin(q.sum(axis=1))])

    rows = np.arange(10, 1990)
    measured = predict(true_q)[rows] + rng.normal(0.0, 0.01, (len(rows), 2))
    rms, found = _angle_zeroed(predict, true_q - shift, measured, rows)
    np.testing.assert_allclose(found, shift, atol=1e-3)
    np.testing.assert_allclose(rms, 0.01, rtol=0.1)
    off = np.sqrt(np.mean((measured - predict(true_q - shift)[rows]) ** 2, axis=0))
    assert np.all(off > 5 * np.asarray(rms))  # without the zero the same model is far off


def test_the_lofo_summary_counts_the_angle_zeroed_reading_where_it_was_judged() -> None:
    """The summary's `angle_zeroed` line counts that reading's own wins, and is left out for tables judged before
    it existed."""
    from bench.diagnose import lofo_summary

    table = {
        "session": "X",
        "authors": ["authors_x"],
        "splits": [_split("a.csv", [0.1, 0.3], [0.1, 0.1], [0.2, 0.2])],
    }
    table["splits"][0]["both_filtered"] = table["splits"][0]["torque_rms"]
    assert "angle_zeroed" not in lofo_summary({"X": table})
    table["splits"][0]["angle_zeroed"] = {"calibrated": [0.25, 0.05], "authors_x": [0.2, 0.1]}
    line = lofo_summary({"X": table}).split("\n")[2]
    assert line == "angle_zeroed: sum 0.3000 N m, 1 of 2 joints and 0 of 1 splits <= the lab's best"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", r"a reference model is a mapping of I1, .*; the file holds None"),
        ("I1: [1, 2\n", r"cannot read it as a reference model: .*"),
        ("- 1\n- 2\n", r"a reference model is a mapping of .* the file holds \[1, 2\]"),
        ("I1: 1\n", r"missing parameters \['I2', "),
        ("\n".join(f"{k}: 1.0" for k in AUTHOR_KEYS).replace("m2: 1.0", "m2: abc"), r"parameter m2 is 'abc', not a"),
        ("\n".join(f"{k}: 1.0" for k in AUTHOR_KEYS).replace("r1: 1.0", "r1: .nan"), r"parameter r1 is nan, not a"),
        # a negative mass was read and simulated (an error of a whole radian, no word)
        ("\n".join(f"{k}: 1.0" for k in AUTHOR_KEYS).replace("m1: 1.0", "m1: -5"), r"parameter m1 is -5, not physical"),
        ("\n".join(f"{k}: 1.0" for k in AUTHOR_KEYS).replace("g: 1.0", "g: 0"), r"parameter g is 0, not physical"),
    ],
)
def test_a_bad_reference_model_file_is_one_line_naming_the_file_and_the_key(
    text: str, message: str, tmp_path: Path
) -> None:
    """A lab's yml beside the logs (found by diagnose.references=auto) or given by path: an empty one, one that is
    no YAML, no mapping or a non-number ended in a traceback ('NoneType' is not iterable, could not convert
    string to float: 'abc')."""
    from harness.diagnose import reference_models

    path = tmp_path / "authors_identified" / "design_X_model_1.0.yml"
    path.parent.mkdir()
    path.write_text(text)
    with pytest.raises(DataError, match=rf"design_X_model_1\.0\.yml: {message}"):
        load_author_model(path)
    with pytest.raises(DataError, match=r"\(found beside the data: diagnose.references=auto\); diagnose.references=n"):
        reference_models("auto", [tmp_path / "log.csv"])
    with pytest.raises(DataError, match=r"diagnose.references=null compares with none$"):
        reference_models([str(path)], [tmp_path / "log.csv"])


def test_the_mujoco_only_reading_leaves_out_what_mujoco_has_no_attribute_for(tmp_path: Path) -> None:
    """`bench.diagnose.judge`'s `mujoco_only` reading: the calibrated MJCF through `mj_inverse` alone, as a
    MuJoCo user without this harness reads the file. A torque sensor offset of 0.05 N m on the shoulder, written as
    the harness's `sysid_torque_sensor_shoulder` numeric, is in the first reading and not in this one: there the
    shoulder is off by the offset, the elbow the same in both."""
    from bench.diagnose import judge
    from dynamics.plant import load_plant
    from dynamics.torque import inverse_dynamics
    from envs.dataset import Dataset

    plant = load_plant("two_link")
    t = np.arange(0.0, 8.0, 0.002)
    w = 2 * np.pi * np.array([0.4, 0.7])
    q = np.column_stack([0.6 * np.sin(w[0] * t), 0.9 * np.sin(w[1] * t + 0.3)])
    dq = np.column_stack([0.6 * w[0] * np.cos(w[0] * t), 0.9 * w[1] * np.cos(w[1] * t + 0.3)])
    ddq = np.column_stack([-0.6 * w[0] ** 2 * np.sin(w[0] * t), -0.9 * w[1] ** 2 * np.sin(w[1] * t + 0.3)])
    tau = inverse_dynamics(plant, q, dq, ddq) + np.array([0.05, 0.0])
    data = Dataset(t, q, tau, plant.joint_names, np.ones(2, bool))
    text = Path(plant.path).read_text()
    numeric = '<custom><numeric name="sysid_torque_sensor_shoulder" size="2" data="1 0.05"/></custom>\n</mujoco>'
    path = tmp_path / "offset.xml"
    path.write_text(text[: text.rindex("</mujoco>")] + numeric)
    judged = judge(path, {}, data)
    rms, mujoco_only = judged["torque_rms"], judged["mujoco_only"]
    assert rms["calibrated"][0] < 0.005 and rms["calibrated"][1] < 0.005, rms
    assert mujoco_only["calibrated"][0] == pytest.approx(0.05, abs=0.005)
    assert mujoco_only["calibrated"][1] == pytest.approx(rms["calibrated"][1], abs=1e-9)


def test_the_moving_reading_leaves_out_the_rows_where_a_joint_rests() -> None:
    """`bench.diagnose.judge`'s `moving` reading: each joint judged only where it moves faster than a tenth of its
    RMS speed. The elbow swings for 4.25 s, then rests at its peak while the shoulder keeps swinging, and from
    4.45 s its measured torque is 0 (a joint commanded zero torque, held by its friction: the drive's current
    shows nothing). The exact model misses there by the holding torque; on the moving rows it is exact, and the
    reading says what share of the rows it kept."""
    from bench.diagnose import judge
    from dynamics.plant import load_plant
    from dynamics.torque import inverse_dynamics
    from envs.dataset import Dataset

    plant = load_plant("two_link")
    t = np.arange(0.0, 8.0, 0.002)
    w = 2 * np.pi * np.array([0.4, 1.0])
    stop = 4.25  # the elbow's fifth peak: w[1] * stop = pi / 2 + 8 pi, its speed zero there
    moving = t < stop
    q = np.column_stack([0.6 * np.sin(w[0] * t), 0.9 * np.sin(w[1] * np.minimum(t, stop))])
    dq = np.column_stack([0.6 * w[0] * np.cos(w[0] * t), np.where(moving, 0.9 * w[1] * np.cos(w[1] * t), 0.0)])
    ddq = np.column_stack(
        [-0.6 * w[0] ** 2 * np.sin(w[0] * t), np.where(moving, -0.9 * w[1] ** 2 * np.sin(w[1] * t), 0.0)]
    )
    tau = inverse_dynamics(plant, q, dq, ddq)
    tau[t >= stop + 0.2, 1] = 0.0
    judged = judge(Path(plant.path), {}, Dataset(t, q, tau, plant.joint_names, np.ones(2, bool)))
    every, kept = judged["torque_rms"]["calibrated"], judged["moving"]["calibrated"]
    assert every[1] > 0.3, every  # the link's weight held at 0.9 rad, in half of the file
    assert kept[1] < 0.01 and kept[0] == pytest.approx(every[0], abs=0.005), (kept, every)
    share = judged["moving_share"]
    assert share[0] > 0.85 and 0.4 < share[1] < stop / t[-1], share  # the elbow's rest and its turns left out

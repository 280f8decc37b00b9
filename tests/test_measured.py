"""Reading measured data: every input check refuses a bad file with file, column and row, or repairs and reports."""

from __future__ import annotations

import codecs
import gzip
import os
import re
import warnings
from collections.abc import Callable
from decimal import Decimal
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from dynamics.base import base_parameters
from dynamics.errors import DataError
from dynamics.plant import Plant, load_plant
from dynamics.regressor import ParameterModel
from envs.dataset import Dataset, write_csv
from envs.measured import read_many, read_measured
from envs.split import split_train_validation
from identify.excitation_check import check_excitation, excitation_report
from tests.conftest import SHARED_ROBOTS

CONF_DATA = Path(__file__).resolve().parents[1] / "conf" / "data"
FS = 500.0


@pytest.fixture(scope="module")
def plant() -> Plant:
    return load_plant("two_link")


def motion(t: np.ndarray, *, amplitude: tuple[float, float] = (0.5, 0.8)) -> tuple[np.ndarray, ...]:
    """Smooth two-joint motion: q, dq, ddq (N, 2) [rad, rad/s, rad/s^2]."""
    w = 2 * np.pi * np.array([1.0, 1.7])
    a = np.array(amplitude)
    phase = np.array([0.0, 0.3])
    q = a * np.sin(w * t[:, None] + phase) + np.array([0.1, -0.2])
    dq = a * w * np.cos(w * t[:, None] + phase)
    ddq = -a * w**2 * np.sin(w * t[:, None] + phase)
    return q, dq, ddq


def table(n: int = 1000, *, amplitude: tuple[float, float] = (0.5, 0.8)) -> dict[str, np.ndarray]:
    """Columns of a clean file in the measured-data format."""
    t = np.arange(n) / FS
    q, dq, _ = motion(t, amplitude=amplitude)
    return {
        "time": t,
        "q_shoulder": q[:, 0],
        "q_elbow": q[:, 1],
        "dq_shoulder": dq[:, 0],
        "dq_elbow": dq[:, 1],
        "tau_shoulder": np.sin(3 * t),
        "tau_elbow": np.cos(2 * t),
    }


def write(path: Path, columns: dict[str, np.ndarray], *, cell: tuple[str, int, str] | None = None) -> Path:
    """Write columns as a CSV; `cell` = (column, row, text) overwrites one cell with raw text."""
    names = list(columns)
    body = np.column_stack([np.asarray(columns[c], float) for c in names])
    lines = [",".join(names)] + [",".join(repr(float(v)) for v in row) for row in body]
    if cell is not None:
        column, row, text = cell
        fields = lines[row + 1].split(",")
        fields[names.index(column)] = text
        lines[row + 1] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")
    return path


def edited(edit: Callable[[dict[str, np.ndarray]], None], n: int = 1000) -> dict[str, np.ndarray]:
    cols = table(n)
    edit(cols)
    return cols


def test_clean_file_reads_without_repairs(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    data = read_measured(write(tmp_path / "clean.csv", cols), plant)
    assert data.joint_names == ("shoulder", "elbow")
    assert data.meta["repairs"] == ()
    np.testing.assert_array_equal(data.q[:, 1], cols["q_elbow"])
    np.testing.assert_array_equal(data.tau[:, 0], cols["tau_shoulder"])
    assert data.meta["sample_rate_hz"] == pytest.approx(FS)


def test_round_trip_with_write_csv(tmp_path: Path, plant: Plant) -> None:
    t = np.arange(400) / FS
    q, dq, ddq = motion(t)
    original = Dataset(
        time=t,
        q=q,
        tau=np.column_stack([np.sin(t), np.cos(t)]),
        joint_names=plant.joint_names,
        actuated=plant.actuated,
        dq=dq,
        ddq=ddq,  # written as ddq_<joint>: accepted by the reader and ignored
        tau_cmd=np.column_stack([np.sin(t), -np.cos(t)]),
    )
    write_csv(original, tmp_path / "data.csv")
    back = read_measured(tmp_path / "data.csv", plant)
    for name in ("time", "q", "dq", "tau", "tau_cmd"):
        np.testing.assert_allclose(getattr(back, name), getattr(original, name), rtol=1e-9, atol=1e-12)
    assert back.ddq is None
    assert set(back.meta["ignored_columns"]) == {"ddq_shoulder", "ddq_elbow"}


def test_unactuated_joint_needs_no_torque_column(tmp_path: Path) -> None:
    wheel = load_plant("wheel_pendulum")
    t = np.arange(200) / FS
    q = motion(t)[0]
    write(tmp_path / "wheel.csv", {"time": t, "q_pendulum": q[:, 0], "q_wheel": q[:, 1], "tau_wheel": np.sin(t)})
    data = read_measured(tmp_path / "wheel.csv", wheel)
    assert np.all(data.tau[:, 0] == 0) and list(data.actuated) == [False, True]
    cols = {"time": t, "q_pendulum": q[:, 0], "q_wheel": q[:, 1], "tau_pendulum": t, "tau_wheel": t}
    write(tmp_path / "torque.csv", cols)
    with pytest.raises(
        DataError, match=r"unknown column\(s\) tau_pendulum: .*\(actuated: wheel\); a torque of a joint no"
    ):
        read_measured(tmp_path / "torque.csv", wheel)
    # mapped, the columns named are read and the rest ignored, as the message says
    mapped = read_measured(tmp_path / "torque.csv", wheel, columns={"tau_wheel": "tau_wheel"})
    assert "tau_pendulum" in mapped.meta["ignored_columns"] and np.all(mapped.tau[:, 0] == 0)


def test_missing_column_is_named(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    del cols["tau_elbow"]
    with pytest.raises(DataError, match=r"missing\.csv: missing column\(s\) tau_elbow .*its columns are: time"):
        read_measured(write(tmp_path / "missing.csv", cols), plant)


@pytest.mark.parametrize(
    "names",
    [
        {"q": "position_{}", "dq": "velocity_{}", "tau": "effort_{}"},  # a ROS joint_states export, 0-based
        {"q": "pos_meas{}", "dq": "vel_meas{}", "tau": "tau_meas{}", "tau_cmd": "tau_con{}", "des": "pos_des{}"},
        {"q": "q[{}]", "tau": "tau_J{}", "des": "q_d{}"},  # brackets need quoting; Franka's desired q_d is no q
        {"q": "{name}_pos", "tau": "{name}_effort", "tau_cmd": "{name}_effort_cmd"},  # by joint name
    ],
)
def test_a_mapping_guessed_from_the_column_names_is_suggested_and_reads_the_file(
    tmp_path: Path, plant: Plant, names: dict[str, str]
) -> None:
    """A log whose columns are named otherwise (indexed or by joint) gets a mapping to paste: parsed as Hydra
    parses the command line, it reads the file into what the measured-data format gives."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    cols = table()
    cols["tau_cmd_shoulder"], cols["tau_cmd_elbow"] = cols["tau_shoulder"] + 0.01, cols["tau_elbow"] - 0.01
    base = 0 if "position_{}" in names.values() else 1
    renamed = {"time": cols["time"]}
    for kind, pattern in names.items():
        for j, joint in enumerate(plant.joint_names):
            source = cols[f"{kind}_{joint}"] if kind != "des" else cols[f"q_{joint}"] + 0.5
            renamed[pattern.format(j + base, name=joint)] = source
    with pytest.raises(DataError, match=r"missing column\(s\) q_shoulder.*suggest the mapping") as caught:
        read_measured(write(tmp_path / "other.csv", renamed), plant)
    override = re.search(r"'(\+\+data\.columns=.*)'", str(caught.value))
    assert override is not None, str(caught.value)
    mapping = OverridesParser.create().parse_overrides([override.group(1)])[0].value()
    assert set(mapping) == {f"{k}_{j}" for k in names if k != "des" for j in plant.joint_names}
    guessed = read_measured(tmp_path / "other.csv", plant, columns=mapping)
    kept = {"time": cols["time"]} | {
        f"{k}_{j}": cols[f"{k}_{j}"] for k in names if k != "des" for j in plant.joint_names
    }
    reference = read_measured(write(tmp_path / "format.csv", kept), plant)
    np.testing.assert_array_equal(guessed.q, reference.q)
    np.testing.assert_array_equal(guessed.tau, reference.tau)
    for optional in ("dq", "tau_cmd"):
        if optional in names:
            np.testing.assert_array_equal(getattr(guessed, optional), getattr(reference, optional))


@pytest.mark.skipif(
    not (SHARED_ROBOTS / "panda_nohand.xml").is_file(), reason="../shared/robots/ is not beside the project"
)
@pytest.mark.parametrize("base", [0, 1])
def test_joints_named_by_number_are_counted_in_the_models_order(base: int) -> None:
    """The Panda's joint1..joint7 are counted like its columns, whether the log counts from 0 or from 1: the
    number in 'joint1' does not name position_1 of a 0-based log."""
    from envs.measured import _guess_columns

    panda = load_plant(str(SHARED_ROBOTS / "panda_nohand.xml"))
    header = ["time"] + [f"{kind}_{j + base}" for kind in ("position", "effort") for j in range(panda.nv)]
    guess = _guess_columns(panda, header)
    for j, joint in enumerate(panda.joint_names):
        assert (guess[f"q_{joint}"], guess[f"tau_{joint}"]) == (f"position_{j + base}", f"effort_{j + base}")


def test_no_mapping_is_suggested_where_the_names_do_not_say(tmp_path: Path, plant: Plant) -> None:
    cols = {"time": table()["time"], "a": table()["q_shoulder"], "b": table()["q_elbow"]}
    cols |= {"c1": table()["tau_shoulder"], "c2": table()["tau_elbow"]}
    with pytest.raises(DataError, match=r"its columns are: time, a, b, c1, c2$"):
        read_measured(write(tmp_path / "plain.csv", cols), plant)
    two = {"time": cols["time"], "pos1": cols["a"], "pos2": cols["b"], "pos3": cols["b"]}  # three for two joints
    two |= {"tau1": cols["c1"], "tau2": cols["c2"]}
    with pytest.raises(DataError, match=r"its columns are: time, pos1, pos2, pos3, tau1, tau2$"):
        read_measured(write(tmp_path / "three.csv", two), plant)


def test_partial_optional_columns_are_refused(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    del cols["dq_elbow"]
    with pytest.raises(DataError, match=r"missing column\(s\) dq_elbow: give them for every joint or for none"):
        read_measured(write(tmp_path / "partial.csv", cols), plant)


@pytest.mark.parametrize(
    ("rename", "columns", "message"),
    [
        ({"dq_elbow": "dq_elbo"}, None, r"unknown column\(s\) dq_elbo: two_link has the joints shoulder, elbow"),
        ({}, {"q_wrist": "q_elbow"}, r"unknown name 'q_wrist' in the column mapping"),
        ({}, {"q_elbow": "pos_meas2"}, r"column 'pos_meas2' \(mapped to q_elbow\) is not in the file"),
    ],
)
def test_unknown_column_is_named(
    tmp_path: Path, plant: Plant, rename: dict[str, str], columns: dict[str, str] | None, message: str
) -> None:
    cols = {rename.get(k, k): v for k, v in table().items()}
    with pytest.raises(DataError, match=message):
        read_measured(write(tmp_path / "unknown.csv", cols), plant, columns=columns)


# Python's float() reads 1_0 as 10, and Arabic-Indic or full-width digits as numbers: the cell was not located
@pytest.mark.parametrize("cell", ["n/a", "1_0", "\u0661\u0662", "\uff11.\uff15"])
def test_non_numeric_cell_is_located(tmp_path: Path, plant: Plant, cell: str) -> None:
    path = write(tmp_path / "text.csv", table(), cell=("tau_elbow", 7, cell))
    with pytest.raises(DataError, match=rf"text\.csv: column 'tau_elbow', row 7 \(line 9\): '{cell}' is not a number"):
        read_measured(path, plant)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (None, r"absent\.csv: no such file"),
        ("", r"absent\.csv: the file is empty"),
        ("\n\n", r"absent\.csv: the file is empty"),
        ("\n\ntime,q_shoulder,q_elbow,tau_shoulder,tau_elbow\n0,1,2,3,4\n", r"line 1 is blank; the header row"),
        ("time q_shoulder q_elbow tau_shoulder tau_elbow\n0 1 2 3 4\n", r"the file seems separated by spaces"),
        ("time,q_shoulder,q_elbow,tau_shoulder,tau_elbow\n", r"no data rows after the header"),
        ("time,q_shoulder,q_elbow,tau_shoulder,tau_elbow\n0,1,2,3,4\n1,2,3\n", r"row 1 \(line 3\) has 3 fields"),
        ("# logged 2026-11-30\ntime,q_shoulder,q_elbow,tau_shoulder,tau_elbow\n", r"line 1 is a comment \('# logged"),
        ("sep=;\ntime;q_shoulder;q_elbow;tau_shoulder;tau_elbow\n0;1;2;3;4\n", r"line 1 is a spreadsheet's delimiter"),
        ("0,1,2,3,4\n0.002,1,2,3,4\n", r"line 1 holds numbers \(0, 1, 2, \.\.\.\), not column names: the file has no"),
        (
            "time;q_shoulder;q_elbow;tau_shoulder;tau_elbow\n0;0,5;1;2;3\n",
            r"column 'q_shoulder', row 0 \(line 2\): '0,5' is not a number \(a decimal comma\?",
        ),
    ],
)
def test_malformed_files_are_refused(tmp_path: Path, plant: Plant, text: str | None, message: str) -> None:
    path = tmp_path / "absent.csv"
    if text is not None:
        path.write_text(text)
    with pytest.raises(DataError, match=message):
        read_measured(path, plant)


@pytest.mark.parametrize(
    ("text", "kind"),
    [
        ('\ufeff\n  <mujoco model="arm">\n  <worldbody/>\n</mujoco>\n', r"XML, a MuJoCo model \(MJCF\): it begins "),
        ('<?xml version="1.0"?>\n<robot name="arm">\n</robot>\n', r"XML, a URDF robot model: it begins with '<\?xml"),
        ("<data a='1'>\n</data>\n", r"XML or HTML \(markup\): it begins with"),
    ],
)
def test_a_model_or_other_markup_file_given_as_data_is_named(
    tmp_path: Path, plant: Plant, text: str, kind: str
) -> None:
    """An MJCF given as data.path was called 'separated by spaces' (its first line, one column of words)."""
    path = tmp_path / "model.xml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(DataError, match=rf"model\.xml: not CSV but {kind}.*data\.path takes CSV logs") as err:
        read_measured(path, plant)
    assert "spaces" not in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_nan_and_inf_are_located(tmp_path: Path, plant: Plant, value: float) -> None:
    cols = table()
    cols["q_elbow"][123] = value
    cols["q_elbow"][500] = value
    path = write(tmp_path / "bad.csv", cols)
    with pytest.raises(DataError, match=r"bad\.csv: column 'q_elbow', row 123 \(line 125\): .* 1 more rows"):
        read_measured(path, plant)


@pytest.mark.parametrize(
    ("defect", "message"),
    [
        ("nan", r"column 'q_elbow', row 123 \(line 128\): nan is not a finite number"),
        ("back", r"column 'time' goes backwards at row 300 \(line 305\)"),
        ("repeat", r"column 'time' repeats .* at rows 299 and 300 \(lines 304 and 305\)"),
        ("gap", r"gap of 102 ms before row 600 \(line 605\)"),
        ("spike", r"column 'tau_elbow' is 1e\+30 at row 420 \(line 425"),
    ],
)
def test_a_row_is_named_by_its_own_line_after_blank_lines(
    tmp_path: Path, plant: Plant, defect: str, message: str
) -> None:
    """Blank lines are skipped when a file is read; every message still gives the line the row is on (three blank
    lines after row 99 put row k on line k + 5 from there), not row + 2."""
    cols = table()
    if defect == "nan":
        cols["q_elbow"][123] = np.nan
    elif defect in ("back", "repeat"):
        cols["time"][300] = cols["time"][298 if defect == "back" else 299]
    elif defect == "gap":
        cols["time"][600:] += 0.1
    else:
        cols["tau_elbow"][420] = 1e30
    path = write(tmp_path / "blank.csv", cols)
    lines = path.read_text().splitlines()
    path.write_text("\n".join([*lines[:101], "", "", "", *lines[101:]]) + "\n")  # after row 99 (line 101)
    with pytest.raises(DataError, match=message):
        read_measured(path, plant, repair=False)


def test_a_numbered_header_is_read_through_a_mapping_that_names_its_columns(tmp_path: Path, plant: Plant) -> None:
    """pandas writes an unnamed frame's header as 0,1,2,...: without a mapping that is no header row (refused as
    such); a mapping that names those columns reads it."""
    cols = table()
    path = write(tmp_path / "numbered.csv", cols)
    lines = path.read_text().splitlines()
    path.write_text("\n".join([",".join(str(i) for i in range(len(cols))), *lines[1:]]) + "\n")
    with pytest.raises(DataError, match=r"line 1 holds numbers \(0, 1, 2, \.\.\.\), not column names"):
        read_measured(path, plant)
    data = read_measured(path, plant, columns={name: str(i) for i, name in enumerate(cols)})
    np.testing.assert_array_equal(data.q[:, 1], cols["q_elbow"])


def test_a_time_written_with_too_few_decimals_is_said_so(tmp_path: Path, plant: Plant) -> None:
    """500 Hz stamps written with two decimals: 0.00, 0.00, 0.01, ... The refusal named the first repeat and the
    count of them, not why."""
    cols = table()
    cols["time"] = np.round(cols["time"], 2)
    with pytest.raises(DataError, match=r"repeats 0 s at rows 0 and 1 .* steps of 0\.01 s: the time was written with"):
        read_measured(write(tmp_path / "rounded.csv", cols), plant)
    cols = table()
    cols["time"][300] = cols["time"][299]  # one repeat is no rounding
    with pytest.raises(DataError, match=r"1 duplicate time stamp\(s\) in all\)$"):
        read_measured(write(tmp_path / "once.csv", cols), plant)
    doubled = {k: np.repeat(v, 1 + (np.arange(len(v)) % 5 == 0), axis=0) for k, v in table().items()}
    with pytest.raises(DataError, match=r"200 duplicate time stamp\(s\) in all\)$"):  # rows written twice
        read_measured(write(tmp_path / "doubled.csv", doubled), plant)


def test_a_coarsely_quantised_angle_is_read_not_refused_as_slips(tmp_path: Path, plant: Plant) -> None:
    """An angle logged in steps of 0.05 rad without a velocity column: most steps are 0, so the running rate and
    the noise were 0 and each count was refused as a jump "no velocity allows (0.02 at 0 rad/s)". A step of a
    count is read as one; a slip of many counts is still found."""
    cols = {k: v for k, v in table().items() if not k.startswith("dq_")}
    cols["q_elbow"] = np.round(cols["q_elbow"] / 0.05) * 0.05
    data = read_measured(write(tmp_path / "coarse.csv", cols), plant)
    np.testing.assert_array_equal(data.q[:, 1], cols["q_elbow"])
    cols["q_elbow"][600:] += 0.5  # ten counts at once
    with pytest.raises(DataError, match=r"column 'q_elbow' jumps by 0\.5 between rows 599 and 600"):
        read_measured(write(tmp_path / "slip.csv", cols), plant, repair=False)
    # a joint at rest reads one value: its only steps are the defect's, which are no count of its encoder
    rest = table()
    rest["q_elbow"][:] = -0.2
    rest["dq_elbow"][:] = 0.0
    spike, slip = {k: v.copy() for k, v in rest.items()}, rest
    spike["q_elbow"][500] += 0.3
    data = read_measured(write(tmp_path / "spike.csv", spike), plant)
    assert [r.kind for r in data.meta["repairs"]] == ["glitch"] and np.all(data.q[:, 1] == -0.2)
    slip["q_elbow"][600:] += 0.5
    with pytest.raises(DataError, match=r"column 'q_elbow' jumps by 0\.5 between rows 599 and 600"):
        read_measured(write(tmp_path / "rest_slip.csv", slip), plant, repair=False)


def test_time_going_backwards_is_refused(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    cols["time"][300] = cols["time"][298]
    with pytest.raises(
        DataError, match=r"column 'time' goes backwards at row 300 \(line 302\): 0\.596 s after 0\.598 s"
    ):
        read_measured(write(tmp_path / "back.csv", cols), plant)


@pytest.mark.parametrize("form", ["{:.6f}", '"{:.6f}"', "{:.15e}"])
def test_unix_time_stamps_are_read_to_the_microseconds_they_were_written_with(
    tmp_path: Path, plant: Plant, form: str
) -> None:
    """Unix time (1.7e9 s) read as a double resolves 2.4e-7 s: each 2 ms step came out off by up to 1.2e-7 s, and a
    diagnosis of such a file differed from the same file timed from 0 (its re-start windows and the rows it
    trusted). The time column is read less the first row's whole seconds, in decimal, so that both read alike;
    `meta["time_origin_s"]` keeps them. A bad cell is still named by row."""
    cols = table()
    relative = write(tmp_path / "zero.csv", {**cols, "time": np.round(cols["time"], 6)})
    lines = relative.read_text().splitlines()
    # the decimal text of each whole stamp, as a logger writes it
    stamps = [form.format(Decimal("1700000000.25") + Decimal(line.split(",")[0])) for line in lines[1:]]
    unix = tmp_path / "unix.csv"
    body = [",".join([stamp, *line.split(",")[1:]]) for stamp, line in zip(stamps, lines[1:], strict=True)]
    unix.write_text("\n".join([lines[0], *body]) + "\n")
    a, b = read_measured(relative, plant), read_measured(unix, plant)
    assert b.meta["time_origin_s"] == 1_700_000_000.0 and a.meta["time_origin_s"] == 0.0
    np.testing.assert_allclose(b.time - 0.25, a.time, rtol=0, atol=1e-12)
    assert np.max(np.abs(np.diff(b.time) - 0.002)) < 1e-12
    np.testing.assert_array_equal(b.q, a.q)
    bad = body[:]
    bad[40] = "x" + bad[40]
    unix.write_text("\n".join([lines[0], *bad]) + "\n")
    with pytest.raises(DataError, match=r"column 'time', row 40 \(line 42\)"):
        read_measured(unix, plant)


def test_a_unix_time_mapped_with_an_offset_that_takes_the_origin_out_reads_as_mapped(
    tmp_path: Path, plant: Plant
) -> None:
    """ours = scale * file + offset: a user who made Unix time relative with offset -1.7e9 got -1.7e9 s once the
    reader took the origin out itself (review of the change above); the two now cancel, exactly."""
    cols = table()
    lines = write(tmp_path / "zero.csv", {**cols, "time": np.round(cols["time"], 6)}).read_text().splitlines()
    stamps = [str(Decimal("1700000000.25") + Decimal(line.split(",")[0])) for line in lines[1:]]
    body = [",".join([stamp, *line.split(",")[1:]]) for stamp, line in zip(stamps, lines[1:], strict=True)]
    path = tmp_path / "unix.csv"
    path.write_text("\n".join([lines[0], *body]) + "\n")
    data = read_measured(path, plant, columns={"time": {"column": "time", "offset": -1_700_000_000.0}})
    assert data.time[0] == 0.25 and data.meta["time_origin_s"] == 0.0
    assert np.max(np.abs(np.diff(data.time) - 0.002)) < 1e-12


def test_duplicate_time_is_refused(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    cols["time"][300] = cols["time"][299]
    with pytest.raises(DataError, match=r"column 'time' repeats 0\.598 s at rows 299 and 300 \(lines 301 and 302\)"):
        read_measured(write(tmp_path / "dup.csv", cols), plant)


def test_startup_rows_are_trimmed_with_a_note(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    steps = np.full(999, 1 / FS)
    steps[:4] = [0.0034, 0.0036, 0.0032, 0.0033]  # as in the DFKI logs
    cols["time"] = np.concatenate([[0.0], np.cumsum(steps)])
    data = read_measured(write(tmp_path / "startup.csv", cols), plant)
    (note,) = data.meta["repairs"]
    assert note.kind == "startup_trim" and note.rows == (0, 1, 2, 3)
    assert data.n_samples == 996
    assert data.time[0] == pytest.approx(cols["time"][4])


def test_jittery_sampling_is_resampled_onto_a_uniform_grid_with_a_report(tmp_path: Path, plant: Plant) -> None:
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.7, 1.3, 1500)) / FS  # +-30 % jitter, like DFKI file 12
    q = motion(t)[0]
    cols = {"time": t, "q_shoulder": q[:, 0], "q_elbow": q[:, 1], "tau_shoulder": t, "tau_elbow": -t}
    data = read_measured(write(tmp_path / "jitter.csv", cols), plant)
    (report,) = data.meta["repairs"]
    assert report.kind == "resample" and "resampled onto a uniform" in report.message
    steps = np.diff(data.time)
    assert np.ptp(steps) < 1e-9
    np.testing.assert_allclose(data.q, motion(data.time)[0], atol=2e-4)  # the spline keeps the motion
    np.testing.assert_allclose(data.tau[:, 0], data.time, atol=1e-12)


def test_irregular_sampling_is_refused_when_resampling_is_off(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    cols["time"][600:] += 1.5 / FS  # a dropped sample and a half
    with pytest.raises(DataError, match=r"column 'time' is irregularly sampled: 1 of 999 steps .* before row 600"):
        read_measured(write(tmp_path / "irregular.csv", cols), plant, resample=False)


def test_a_gap_too_long_to_interpolate_is_refused(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    cols["time"][600:] += 0.1  # 50 samples missing
    with pytest.raises(DataError, match=r"gap of 102 ms before row 600 \(line 602\).*Split the file there"):
        read_measured(write(tmp_path / "gap.csv", cols), plant)


@pytest.mark.parametrize("shift_s", [0.5, 5.0])
def test_a_gap_is_named_before_the_angle_units_are_judged(tmp_path: Path, plant: Plant, shift_s: float) -> None:
    """Rows missing (the motion jumps across the gap) or the clock jumping: the angles then change by a different
    amount than the velocity's time integral, which the unit check would read as a wrong scale of q or dq; the gap
    is the cause and is named first."""
    cut = table(2000)
    cut = {k: np.delete(v, np.s_[800:1050], axis=0) for k, v in cut.items()}  # 250 rows deleted
    with pytest.raises(DataError, match=r"gap of 502 ms before row 800 \(line 802\).*Split the file there"):
        read_measured(write(tmp_path / "deleted.csv", cut), plant)
    shifted = table(2000)
    shifted["time"][1000:] += shift_s
    with pytest.raises(DataError, match=r"column 'time' has a gap of .* before row 1000 .*Split the file there"):
        read_measured(write(tmp_path / "shifted.csv", shifted), plant)


def test_angles_in_degrees_are_refused(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    cols["q_elbow"] = np.degrees(cols["q_elbow"])
    with pytest.raises(DataError, match=r"column 'q_elbow' changes 57\.\d+ times .* looks like degrees"):
        read_measured(write(tmp_path / "deg.csv", cols), plant)


def test_a_scale_in_the_mapping_converts_degrees(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    cols["elbow_deg"] = np.degrees(cols.pop("q_elbow"))
    mapping = {"q_elbow": {"column": "elbow_deg", "scale": np.pi / 180}}
    data = read_measured(write(tmp_path / "deg.csv", cols), plant, columns=mapping)
    np.testing.assert_allclose(data.q[:, 1], table()["q_elbow"], atol=1e-12)
    assert data.meta["columns"]["q_elbow"] == "0.0174532925 * elbow_deg"


@pytest.mark.parametrize(
    ("part", "value", "need"),
    [
        ("scale", "abc", "a finite nonzero number"),
        ("scale", 0, "a finite nonzero number"),
        ("offset", "x", "a finite number"),
    ],
)
def test_a_mappings_scale_or_offset_that_is_not_a_number_is_named(
    tmp_path: Path, plant: Plant, part: str, value: object, need: str
) -> None:
    mapping = {"time": {"column": "time", part: value}}
    with pytest.raises(DataError, match=rf"the {part} of time's mapping must be {need}, got {value!r}"):
        read_measured(write(tmp_path / "a.csv", table()), plant, columns=mapping)


def test_angles_in_degrees_without_velocity_are_refused_by_the_joint_range(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    del cols["dq_shoulder"], cols["dq_elbow"]
    cols["q_shoulder"] = np.degrees(cols["q_shoulder"])
    with pytest.raises(
        DataError, match=r"column 'q_shoulder' spans .* far beyond the joint range .* looks like degrees \(then give"
    ):
        read_measured(write(tmp_path / "deg.csv", cols), plant)
    # an angle three whole turns off its zero reads as degrees inside the range too: both readings are named (the
    # reader repairs whole turns, but this check came first and said only "degrees")
    cols = table()
    del cols["dq_shoulder"], cols["dq_elbow"]
    cols["q_shoulder"] = 0.3 * np.sin(np.linspace(0, 6, len(cols["time"]))) + 6 * np.pi
    with pytest.raises(DataError, match=r"looks like degrees .* or lies \+3 whole turn\(s\) off its zero .* -18\.8496"):
        read_measured(write(tmp_path / "turns.csv", cols), plant)


def test_velocity_of_the_wrong_sign_is_refused(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    cols["dq_shoulder"] = -cols["dq_shoulder"]
    with pytest.raises(DataError, match=r"column 'dq_shoulder' has the opposite sign"):
        read_measured(write(tmp_path / "sign.csv", cols), plant)


def test_encoder_wrap_around_is_unwrapped_with_a_report(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    clean = cols["q_shoulder"].copy()
    cols["q_shoulder"] = np.where(clean > 0.3, clean - 2 * np.pi, clean)  # an encoder reading (-5.98, 0.3]
    data = read_measured(write(tmp_path / "wrap.csv", cols), plant)
    (report,) = data.meta["repairs"]
    assert report.kind == "wrap" and "q_shoulder" in report.column and len(report.rows) > 1
    np.testing.assert_allclose(data.q[:, 0] - data.q[0, 0], clean - clean[0], atol=1e-12)


def test_wrap_around_is_refused_when_repair_is_off(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    cols["q_elbow"][400:] += 2 * np.pi
    with pytest.raises(
        DataError, match=r"column 'q_elbow' jumps by 6\.2\d* between rows 399 and 400 .*whole turn.*repair=False"
    ):
        read_measured(write(tmp_path / "wrap.csv", cols), plant, repair=False)


@pytest.mark.parametrize("value", [1e17, -1e300, np.finfo(float).max])
def test_a_huge_angle_is_a_glitch_not_a_wrap_around(tmp_path: Path, plant: Plant, value: float) -> None:
    """1e17 rad is a whole number of turns to within its rounding: it had been "unwrapped", leaving the sample
    3.4 rad off and the rigid-body refit 27 times the noise (the largest double also printed overflow warnings)."""
    cols = table()
    clean = cols["q_shoulder"].copy()
    cols["q_shoulder"][500] = value
    path = write(tmp_path / "huge.csv", cols)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        data = read_measured(path, plant)
    (report,) = data.meta["repairs"]
    assert report.kind == "glitch" and report.rows == (500,)
    np.testing.assert_allclose(data.q[:, 0], clean, atol=1e-4)


def test_a_velocity_column_stuck_at_zero_is_refused(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    cols["dq_elbow"] = np.zeros_like(cols["dq_elbow"])
    with pytest.raises(DataError, match=r"column 'dq_elbow' stays near zero while column 'q_elbow' moves"):
        read_measured(write(tmp_path / "stuck.csv", cols), plant)


@pytest.mark.parametrize("kind", ["wrap", "glitch"])
def test_a_slow_joint_with_a_wrap_or_a_glitch_keeps_its_velocity_column(
    tmp_path: Path, plant: Plant, kind: str
) -> None:
    """The stuck-velocity check reads the angle unwrapped and through a running median: a joint swinging +-0.1 rad
    across pi (its encoder wrapping there) or +-0.01 rad with a 5-sample glitch of 3 rad, with a right velocity,
    is repaired, not refused (found in review: both had been called a stuck velocity)."""
    cols = table(5000)
    w = 2 * np.pi * 0.3
    if kind == "wrap":
        swing = np.pi + 0.1 * np.sin(w * cols["time"])
        cols["q_elbow"], cols["dq_elbow"] = (swing + np.pi) % (2 * np.pi) - np.pi, 0.1 * w * np.cos(w * cols["time"])
    else:
        cols["q_elbow"], cols["dq_elbow"] = 0.01 * np.sin(w * cols["time"]), 0.01 * w * np.cos(w * cols["time"])
        cols["q_elbow"][2000:2005] += 3.0
    data = read_measured(write(tmp_path / f"{kind}.csv", cols), plant)
    assert [r.kind for r in data.meta["repairs"]] == [kind]


def test_one_file_column_mapped_to_two_names_is_refused(tmp_path: Path, plant: Plant) -> None:
    path = write(tmp_path / "run.csv", table())
    with pytest.raises(DataError, match=r"column 'tau_shoulder' is mapped to tau_elbow, tau_shoulder: each needs"):
        read_measured(path, plant, columns={"tau_elbow": "tau_shoulder", "tau_shoulder": "tau_shoulder"})
    cmd = table()  # a log of commands only: a joint's torque and its command may share a column
    both = {"tau_cmd_shoulder": "tau_shoulder", "tau_cmd_elbow": "tau_elbow"}
    read_measured(write(tmp_path / "cmd.csv", cmd), plant, columns=both)


def test_glitches_are_interpolated_with_a_report(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    clean = cols["q_elbow"].copy()
    cols["q_elbow"][250] += 0.7  # one bad sample
    cols["q_elbow"][600:603] = [3.0, -2.0, 3.0]  # three
    data = read_measured(write(tmp_path / "glitch.csv", cols), plant)
    (report,) = data.meta["repairs"]
    assert report.kind == "glitch" and report.rows == (250, 600)
    assert "2 glitch(es) of 4 sample(s)" in report.message
    np.testing.assert_allclose(data.q[:, 1], clean, atol=1e-5)


def test_a_max_speed_the_joints_move_faster_than_is_refused_and_one_above_bounds_the_glitches(
    tmp_path: Path, plant: Plant
) -> None:
    """`max_speed` is the fastest a joint can move; one below what the angles do (0.001 rad/s, for joints that swing
    at 3 and 8.5 rad/s at most) was taken silently. Its glitches still go at a max_speed above the motion."""
    cols = table()
    cols["q_elbow"][250] += 0.7
    path = write(tmp_path / "fast.csv", cols)
    with pytest.raises(DataError, match=r"fast\.csv: column 'q_\w+' moves at [0-9.]+ rad/s .* max_speed=0\.001 \("):
        read_measured(path, plant, max_speed=0.001)
    (report,) = read_measured(path, plant, max_speed=10.0).meta["repairs"]
    assert report.kind == "glitch" and report.rows == (250,)


@pytest.mark.parametrize("size", [1e30, 1e6, 30.0])
def test_a_torque_spike_is_interpolated_with_a_report(tmp_path: Path, plant: Plant, size: float) -> None:
    """A logging glitch of one or two samples far outside the torque's own range (1 N m here): left in, a 1e30
    broke the refit and a 1e6 gave a 447 N m RMS model and a clean verdict."""
    cols = table()
    cols["tau_shoulder"][300] = size
    cols["tau_elbow"][700:702] = -size
    data = read_measured(write(tmp_path / "spike.csv", cols), plant)
    spikes = {r.column: r for r in data.meta["repairs"] if r.kind == "torque_spike"}
    assert spikes["column 'tau_shoulder'"].rows == (300,) and spikes["column 'tau_elbow'"].rows == (700,)
    np.testing.assert_allclose(data.tau[:, 0], table()["tau_shoulder"], atol=1e-4)
    np.testing.assert_allclose(data.tau[:, 1], table()["tau_elbow"], atol=1e-4)


def test_a_torque_spike_is_refused_with_its_row_without_repair(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    cols["tau_elbow"][420] = 1e30
    with pytest.raises(DataError, match=r"column 'tau_elbow' is 1e\+30 at row 420 \(line 422.*repair=False"):
        read_measured(write(tmp_path / "spike.csv", cols), plant, repair=False)


def test_a_torque_that_leaves_its_range_for_long_is_refused_not_interpolated(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    cols["tau_shoulder"][500:509] = 50.0  # 9 samples: more than a glitch
    with pytest.raises(DataError, match=r"column 'tau_shoulder' is 50 at row 500 .* the longest 9"):
        read_measured(write(tmp_path / "run.csv", cols), plant)


def test_torque_steps_and_a_clean_torque_are_not_spikes(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    cols["tau_shoulder"] = np.where(np.arange(1000) < 500, -1.0, 1.0)  # a commanded step is not a glitch
    data = read_measured(write(tmp_path / "step.csv", cols), plant)
    assert not [r for r in data.meta["repairs"] if r.kind == "torque_spike"]


def test_glitches_and_wraps_are_found_without_a_velocity_column(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    del cols["dq_shoulder"], cols["dq_elbow"]
    t = cols["time"]
    spin = 5.0 * t  # the shoulder turns continuously: an encoder in [-pi, pi) wraps at every turn
    cols["q_shoulder"] = np.mod(spin + np.pi, 2 * np.pi) - np.pi
    cols["q_elbow"][300] -= 0.5
    data = read_measured(write(tmp_path / "spin.csv", cols), plant)
    kinds = {r.kind: r for r in data.meta["repairs"]}
    assert {"wrap", "glitch"} <= set(kinds) and len(kinds["wrap"].rows) == 2 and kinds["glitch"].rows == (300,)
    assert set(kinds) - {"wrap", "glitch"} <= {"whole_turns"}  # unwrapped past the joint range: a turn back in it
    np.testing.assert_allclose(data.q[:, 0] - data.q[0, 0], spin - spin[0], atol=1e-12)
    np.testing.assert_allclose(data.q[:, 1], table()["q_elbow"], atol=1e-5)


def test_a_glitch_at_the_edge_drops_the_row(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    cols["q_shoulder"][-1] += 1.0
    data = read_measured(write(tmp_path / "edge.csv", cols), plant)
    (report,) = data.meta["repairs"]
    assert report.kind == "edge_glitch" and report.rows == (999,)
    assert data.n_samples == 999


def test_too_many_glitches_are_refused(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    cols["q_elbow"][100:1000:50] += 0.7  # 18 glitches: 1.8 % of the rows
    with pytest.raises(DataError, match=r"column 'q_elbow' has 18 glitch samples \(first at rows 100, 150"):
        read_measured(write(tmp_path / "glitchy.csv", cols), plant)


def test_a_jump_that_stays_is_refused(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    cols["q_elbow"][500:] += 1.0
    with pytest.raises(DataError, match=r"jumps by (0\.99|1\.0)\d* between rows 499 and 500 .* and stays there"):
        read_measured(write(tmp_path / "slip.csv", cols), plant)


def test_too_little_data_is_refused(tmp_path: Path, plant: Plant) -> None:
    with pytest.raises(
        DataError,
        match=r"short\.csv: too little data: 20 rows, at least 50 are needed \(the least is data\.min_samples\)",
    ):
        read_measured(write(tmp_path / "short.csv", table(20)), plant)


def excitation_regressor(plant: Plant, data: Dataset) -> tuple[np.ndarray, tuple[str, ...]]:
    """Base regressor of two_link with armature and viscous friction on the data's (exact) states."""
    model = ParameterModel(plant, ("armature", "viscous_friction"))
    base = base_parameters(model, np.random.default_rng(0))
    amplitude = (float(np.ptp(data.q[:, 0])) / 2, float(np.ptp(data.q[:, 1])) / 2)
    q, dq, ddq = motion(data.time, amplitude=amplitude)
    return base.columns(model.regressor(q, dq, ddq)), base.names


def test_check_excitation_accepts_rich_motion(tmp_path: Path, plant: Plant) -> None:
    data = read_measured(write(tmp_path / "rich.csv", table()), plant)
    W, names = excitation_regressor(plant, data)
    check = check_excitation(W, names=names, source=data.source)
    assert check.rank == len(names) and check.cond < 1e3


def test_too_little_excitation_names_the_parameters(tmp_path: Path, plant: Plant) -> None:
    data = read_measured(write(tmp_path / "still.csv", table(amplitude=(0.5, 0.0))), plant)  # the elbow never moves
    W, names = excitation_regressor(plant, data)
    with pytest.raises(DataError, match=r"still\.csv: the data do not excite Ia2, Fv2 at all"):
        check_excitation(W, names=names, source=data.source)
    # both joints barely move: the gravity columns of a nearly fixed posture are nearly collinear
    data = read_measured(write(tmp_path / "small.csv", table(amplitude=(1e-3, 1e-3))), plant)
    W, names = excitation_regressor(plant, data)
    with pytest.raises(DataError, match=r"small\.csv: too little excitation .*condition number .* weakest: .*MX1"):
        check_excitation(W, names=names, source=data.source)


def test_the_excitation_report_counts_every_direction_the_data_do_not_move() -> None:
    rng = np.random.default_rng(0)
    W = rng.normal(size=(400, 4))
    assert excitation_report(W, names=list("abcd")).poorly_excited == 0
    W[:, 3] = 2.0 * W[:, 1] - W[:, 0] + 1e-6 * rng.normal(size=400)  # d in the span of a and b, to 1e-6
    report = excitation_report(W, names=list("abcd"))
    assert report.poorly_excited == 1 and report.cond > 1e5 and "d" in report.weakest and "c" not in report.weakest
    nothing = excitation_report(np.zeros((50, 3)), names=list("abc"))  # no motion at all: every direction
    assert nothing.poorly_excited == 3 and nothing.rank == 0
    wide = excitation_report(rng.normal(size=(2, 5)), names=list("abcde"))  # fewer rows than columns
    assert wide.poorly_excited == 3 and wide.rank == 2
    with pytest.raises(ValueError, match="3 names for a regressor of 4 columns"):
        excitation_report(W, names=list("abc"))


def test_too_little_data_for_the_parameters_is_refused(plant: Plant) -> None:
    with pytest.raises(DataError, match=r"too little data: 20 equations for 11 parameters"):
        check_excitation(np.ones((10, 2, 11)), names=[f"p{i}" for i in range(11)], source="x.csv")


def test_split_by_file_and_by_time_block(tmp_path: Path, plant: Plant) -> None:
    paths = [write(tmp_path / f"run{i}.csv", table(amplitude=(0.5 + 0.1 * i, 0.8))) for i in range(3)]
    datasets = read_many(paths, plant)
    split = split_train_validation(datasets)
    assert split.by == "file" and [Path(d.source).name for d in split.validation] == ["run2.csv"]
    named = split_train_validation(datasets, validation=["run0"])
    assert [Path(d.source).name for d in named.train] == ["run1.csv", "run2.csv"]
    with pytest.raises(ValueError, match=r"'run9' is not among the files read: .*data\.validation=null to hold out"):
        split_train_validation(datasets, validation=["run9"])
    block = split_train_validation(datasets[:1], validation_fraction=0.25)
    assert block.by == "time_block"
    # a fraction that holds out too few rows is named with the range that works (it said "too few to split")
    with pytest.raises(DataError, match=r"data\.validation_fraction 1e-06 holds 0 out; .* between 0\.05 and 0\.9 "):
        split_train_validation(datasets[:1], validation_fraction=1e-6)
    # a data config's validation file, kept while a single file is given on the command line: the key and the
    # remedy are named (it said "set validation_fraction", which cannot help)
    with pytest.raises(ValueError, match=r"validation names \['run2.csv'\] but only one file was read \(run0.csv\)"):
        split_train_validation(datasets[:1], validation=["run2.csv"])
    # two folders' files of one name: the name alone is refused as naming both (it said "every file is held
    # out for validation"), the full path holds out the one it names
    for sub in ("d1", "d2"):
        (tmp_path / sub).mkdir()
    files = [write(tmp_path / sub / "x.csv", table(amplitude=(a, 0.8))) for sub, a in (("d1", 0.6), ("d2", 0.7))]
    twins = read_many(files, plant)
    with pytest.raises(ValueError, match=r"'x.csv' names 2 of the files read \(.*d1/x.csv, .*d2/x.csv\): give"):
        split_train_validation(twins, validation=["x.csv"])
    one = split_train_validation(twins, validation=[str(tmp_path / "d2" / "x.csv")])
    assert [d.source for d in one.validation] == [str(tmp_path / "d2" / "x.csv")]
    (train,), (val,) = block.train, block.validation
    assert (train.n_samples, val.n_samples) == (750, 250) and train.time[-1] < val.time[0]
    assert block.describe()["validation"][0]["n_samples"] == 250


def test_read_many_reports_every_bad_file(tmp_path: Path, plant: Plant) -> None:
    good = write(tmp_path / "good.csv", table())
    short = write(tmp_path / "short.csv", table(10))
    nan = write(tmp_path / "nan.csv", edited(lambda c: c["tau_elbow"].__setitem__(5, np.nan)))
    with pytest.raises(DataError) as err:
        read_many([good, short, nan], plant)
    assert "short.csv: too little data" in str(err.value) and "nan.csv: column 'tau_elbow', row 5" in str(err.value)
    with pytest.raises(DataError, match="listed more than once"):
        read_many([good, good], plant)
    copy = tmp_path / "copy.csv"
    copy.write_bytes(good.read_bytes())  # fitted on one and validated on the other, it validated on the fit's data
    with pytest.raises(DataError, match=r"copy\.csv holds the same samples as .*good\.csv \(a copy\?\)"):
        read_many([good, copy], plant)
    # the same samples compressed, or saved with other line endings: other bytes, the same data (it was accepted)
    packed = tmp_path / "good.csv.gz"
    packed.write_bytes(gzip.compress(good.read_bytes()))
    crlf = tmp_path / "crlf.csv"
    crlf.write_bytes(good.read_bytes().replace(b"\n", b"\r\n"))
    # ... or with its clock started elsewhere (a log re-exported with the controller's uptime): the same motion
    later = write(tmp_path / "later.csv", edited(lambda c: c["time"].__iadd__(1234.5)))
    for other in (packed, crlf, later):
        with pytest.raises(DataError, match=rf"{other.name} holds the same samples as .*good\.csv"):
            read_many([good, other], plant)
    read_many([good, write(tmp_path / "other.csv", table(amplitude=(0.4, 0.7)))], plant)  # other data: accepted


def test_a_mapping_or_problem_shared_by_every_file_is_reported_once(tmp_path: Path, plant: Plant) -> None:
    """A data config's mapping for another system (system=pendulum data=dfki_double_pendulum_c1) repeated 'unknown
    name' once per file in the one line of the error."""
    pendulum = load_plant("pendulum")
    paths = [write(tmp_path / f"log{k}.csv", table()) for k in range(3)]
    with pytest.raises(DataError) as err:
        read_many(paths, pendulum, columns={"q_shoulder": "q_shoulder", "tau_shoulder": "tau_shoulder"})
    message = str(err.value)
    assert message.startswith(
        "data.columns (shared by all 3 files): unknown names 'q_shoulder', 'tau_shoulder' in the column mapping; "
        "for pendulum the names are: time, q_swing,"
    )
    assert message.count("unknown") == 1 and "log0.csv" not in message and "\n" not in message
    # a problem of each file's own that reads the same in all (the same header) is named once, with the files
    with pytest.raises(DataError) as err:
        read_many(paths, pendulum)
    message = str(err.value)
    assert message.startswith(f"3 files, {paths[0]}, {paths[1]}, {paths[2]}: missing column(s) q_swing, tau_swing")
    assert message.count("missing") == 1 and "\n" not in message


def test_dfki_logs_read_through_the_data_config(shared_data: Path, plant: Plant, monkeypatch) -> None:
    monkeypatch.setitem(os.environ, "SYSID_DATA_DIR", str(shared_data))
    cfg = OmegaConf.load(CONF_DATA / "dfki_double_pendulum.yaml")
    datasets = read_many(cfg.path, plant, columns=cfg.columns, repair=cfg.repair, resample=cfg.resample)
    assert len(datasets) == 5
    for data in datasets:
        kinds = [r.kind for r in data.meta["repairs"]]
        assert kinds[0] == "startup_trim" and "glitch" not in kinds and "wrap" not in kinds
        assert np.all(np.abs(data.q) < 3.5) and np.all(np.abs(data.tau) < 8.5)
        assert np.ptp(np.diff(data.time)) < 0.02 * data.dt  # within 1 % of uniform, as the derivative filters require
    rates = {Path(d.source).stem: d.meta["sample_rate_hz"] for d in datasets}
    assert rates["trajectory_00"] == pytest.approx(500, rel=1e-3)
    assert rates["trajectory_12"] == pytest.approx(616, rel=0.01)
    split = split_train_validation(datasets, validation=list(cfg.validation))
    assert [Path(d.source).stem for d in split.validation] == ["trajectory_01"]
    assert sorted(Path(d.source).stem for d in split.train) == [f"trajectory_{k}" for k in ("00", "02", "05", "12")]
    OmegaConf.load(CONF_DATA / "csv.yaml")  # the format's config parses too


@pytest.mark.parametrize("block_rows", [1, 7, 999, 1000, 5000])
def test_reading_block_by_block_gives_the_whole_file(
    tmp_path: Path, plant: Plant, block_rows: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The body is read a block of rows at a time into the dataset's arrays: any block size, the last line
    with or without its newline, blank lines and mapped (scaled) columns give what a one-shot read gives."""
    cols = table()
    cols["tau_cmd_shoulder"], cols["tau_cmd_elbow"] = 0.5 * cols["tau_shoulder"], 0.5 * cols["tau_elbow"]
    cols["time"] = 1000.0 * cols["time"]  # logged in ms, mapped below
    path = write(tmp_path / "log.csv", cols)
    path.write_text(path.read_text().rstrip("\n") + ("\n\n" if block_rows % 2 else ""))
    monkeypatch.setattr("envs.measured._BLOCK_ROWS", block_rows)
    mapping = {"time": {"column": "time", "scale": 0.001}, "tau_elbow": {"column": "tau_elbow", "offset": 1.0}}
    data = read_measured(path, plant, columns=mapping, min_samples=10)
    np.testing.assert_array_equal(data.time, 0.001 * cols["time"])
    np.testing.assert_array_equal(data.q, np.column_stack([cols["q_shoulder"], cols["q_elbow"]]))
    assert data.dq is not None and data.tau_cmd is not None
    np.testing.assert_array_equal(data.dq[:, 1], cols["dq_elbow"])
    np.testing.assert_array_equal(data.tau[:, 1], cols["tau_elbow"] + 1.0)
    np.testing.assert_array_equal(data.tau_cmd[:, 0], cols["tau_cmd_shoulder"])
    assert data.meta["rows_read"] == len(cols["time"])


def test_a_bad_cell_in_a_later_block_is_located(tmp_path: Path, plant: Plant, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("envs.measured._BLOCK_ROWS", 100)
    path = write(tmp_path / "bad.csv", table(), cell=("q_elbow", 750, "oops"))
    with pytest.raises(DataError, match=r"column 'q_elbow', row 750 \(line 752\): 'oops' is not a number"):
        read_measured(path, plant)


@pytest.mark.parametrize("delimiter", [";", "\t"])
def test_semicolon_and_tab_separated_files_read_like_commas(tmp_path: Path, plant: Plant, delimiter: str) -> None:
    """Spreadsheets export ';' or tab separated text: the delimiter is taken from the header row."""
    cols = table()
    path = write(tmp_path / "log.csv", cols)
    path.write_text(path.read_text().replace(",", delimiter))
    data = read_measured(path, plant)
    np.testing.assert_array_equal(data.q[:, 1], cols["q_elbow"])
    np.testing.assert_array_equal(data.tau[:, 0], cols["tau_shoulder"])


def with_lines(path: Path, edit: Callable[[int, str], str], *, end: str = "\n") -> Path:
    """Rewrite every line of a file: `edit(k, text)` gets the line's index (0: the header) and text."""
    path.write_text(end.join(edit(k, text) for k, text in enumerate(path.read_text().splitlines())) + end)
    return path


@pytest.mark.parametrize("mapped", [False, True])
def test_unused_text_columns_are_ignored(tmp_path: Path, plant: Plant, mapped: bool) -> None:
    """A comment, a status word or a clock time beside the data is not read (the reviewer's `comment` column)."""
    cols = table()
    extra = ["comment", "stamp", "status"]

    def annotated(path: Path) -> Path:
        return with_lines(
            path,
            lambda k, text: text + (",".join(["", *extra]) if k == 0 else f",hello,2024-01-01T00:00:{k % 60:02d},ok"),
        )

    mapping = {"q_elbow": "q_elbow", "time": "time"} if mapped else None
    data = read_measured(annotated(write(tmp_path / "notes.csv", cols)), plant, columns=mapping)
    np.testing.assert_array_equal(data.q[:, 1], cols["q_elbow"])
    np.testing.assert_array_equal(data.time, cols["time"])
    assert data.meta["ignored_columns"] == tuple(extra)
    # only the columns used must be numbers: a bad cell there is still located
    bad = annotated(write(tmp_path / "bad.csv", cols, cell=("tau_elbow", 7, "n/a")))
    with pytest.raises(DataError, match=r"bad\.csv: column 'tau_elbow', row 7 \(line 9\): 'n/a' is not a number$"):
        read_measured(bad, plant, columns=mapping)


def test_a_clock_time_mapped_to_time_asks_for_seconds(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    path = with_lines(
        write(tmp_path / "stamped.csv", cols),
        lambda k, text: text + (",stamp" if k == 0 else f",2024-01-01T00:00:{k % 60:02d}.000"),
    )
    with pytest.raises(
        DataError,
        match=r"column 'stamp' \(time\), row 0 \(line 2\): '2024-01-01T00:00:01\.000' is not a number \(a date or "
        r"clock time\? the harness expects time in seconds",
    ):
        read_measured(path, plant, columns={"time": "stamp"})


def test_a_sample_index_as_time_is_named_with_the_scale_that_reads_it(tmp_path: Path, plant: Plant) -> None:
    """A time column 0, 1, 2, ... was taken for milliseconds ('1000 Hz then'): it is a counter of samples."""
    cols = table()
    cols["time"] = np.arange(1000.0)
    path = write(tmp_path / "index.csv", cols)
    with pytest.raises(
        DataError,
        match=r"index\.csv: column 'time' counts 0, 1, 2, \.\.\. \(consecutive integers on all 1000 rows\): a "
        r"sample index or counter, not a time in seconds; .*\{column: \"time\", scale: 0\.002\} as data\.columns\.time",
    ) as err:
        read_measured(path, plant)
    assert "milliseconds" not in str(err.value)
    data = read_measured(path, plant, columns={"time": {"column": "time", "scale": 0.002}})
    assert data.meta["sample_rate_hz"] == pytest.approx(FS)


def test_quoted_cells_are_read(tmp_path: Path, plant: Plant) -> None:
    """pandas' QUOTE_ALL quotes every cell, numbers too; a quoted text cell may hold the delimiter."""
    cols = table()
    path = with_lines(
        write(tmp_path / "quoted.csv", cols),
        lambda k, text: ",".join(f'"{c}"' for c in text.split(",")) + (',"note"' if k == 0 else ',"a, ""b"""'),
    )
    data = read_measured(path, plant)
    np.testing.assert_array_equal(data.q[:, 0], cols["q_shoulder"])
    np.testing.assert_array_equal(data.tau[:, 1], cols["tau_elbow"])
    assert data.meta["ignored_columns"] == ("note",)


@pytest.mark.parametrize("note", [False, True])  # every column converted, or one left as text
def test_a_quote_left_open_is_refused(tmp_path: Path, plant: Plant, note: bool) -> None:
    """An open quote would swallow the lines after it into one cell."""
    path = with_lines(
        write(tmp_path / "open.csv", table()),
        lambda k, text: text.replace(",", ',"', 1) if k == 41 else text + (("," + ("note" if k == 0 else "x")) * note),
    )
    with pytest.raises(DataError, match=r"open\.csv: row 40 \(line 42\) has an unmatched double quote"):
        read_measured(path, plant)


@pytest.mark.parametrize("note", [False, True])
def test_a_row_with_another_number_of_fields_is_located(tmp_path: Path, plant: Plant, note: bool) -> None:
    path = with_lines(
        write(tmp_path / "ragged.csv", table()),
        lambda k, text: text + (",note" if k == 0 and note else ",x" * note + ",1" * (k == 300)),
    )
    with pytest.raises(DataError, match=rf"ragged\.csv: row 299 \(line 301\) has {8 + note} fields; the header has"):
        read_measured(path, plant)


def test_a_trailing_comma_on_every_line_is_ignored(tmp_path: Path, plant: Plant) -> None:
    cols = table()
    path = with_lines(write(tmp_path / "trailing.csv", cols), lambda k, text: text + ",")
    data = read_measured(path, plant)
    np.testing.assert_array_equal(data.q[:, 1], cols["q_elbow"])
    assert data.meta["ignored_columns"] == ("",)


@pytest.mark.parametrize("end", ["\r", "\r\n"])
def test_old_mac_and_windows_line_ends_are_read(tmp_path: Path, plant: Plant, end: str) -> None:
    cols = table()
    path = with_lines(write(tmp_path / "ends.csv", cols), lambda k, text: text, end=end)
    data = read_measured(path, plant)
    assert data.meta["rows_read"] == 1000
    np.testing.assert_array_equal(data.q[:, 1], cols["q_elbow"])


@pytest.mark.parametrize("form", ["gzip", "gzip named .csv", "utf-16", "utf-16-be", "utf-32"])
def test_gzip_and_utf16_files_are_read(tmp_path: Path, plant: Plant, form: str) -> None:
    cols = table()
    text = write(tmp_path / "plain.csv", cols).read_text()
    path = tmp_path / ("log.csv.gz" if form == "gzip" else "log.csv")
    if form.startswith("gzip"):
        path.write_bytes(gzip.compress(text.encode()))
    elif form == "utf-16-be":  # with its byte-order mark, as the encoder `utf-16` writes on a big-endian machine
        path.write_bytes(codecs.BOM_UTF16_BE + text.encode("utf-16-be"))
    else:
        path.write_text(text, encoding=form)
    data = read_measured(path, plant)
    np.testing.assert_array_equal(data.q[:, 1], cols["q_elbow"])
    np.testing.assert_array_equal(data.tau[:, 0], cols["tau_shoulder"])


@pytest.mark.parametrize("encoding", ["utf-16-le", "utf-16-be"])
def test_utf16_without_a_byte_order_mark_is_read(tmp_path: Path, plant: Plant, encoding: str) -> None:
    """UTF-16 saved without its byte-order mark was refused as 'a binary file (a NUL byte at byte 1)'; its NULs
    at every odd (little-endian) or even (big-endian) byte tell its order."""
    cols = table()
    text = write(tmp_path / "plain.csv", cols).read_text()
    path = tmp_path / "bare.csv"
    path.write_bytes(text.encode(encoding))
    data = read_measured(path, plant)
    np.testing.assert_array_equal(data.q[:, 1], cols["q_elbow"])
    np.testing.assert_array_equal(data.tau[:, 0], cols["tau_shoulder"])
    # a header with a character beyond Latin-1 (a NUL-free high byte) is text too
    lines = text.splitlines()
    noted = "\n".join([lines[0] + ",τ_note", *(line + ",0" for line in lines[1:])]) + "\n"
    path.write_bytes(noted.encode(encoding))
    assert read_measured(path, plant).q.shape == data.q.shape
    # binary files are still refused as such: NULs at even bytes, and little-endian int16 samples of 1 to 255
    # (NULs at every odd byte, as UTF-16 text has, but control characters, not text)
    path.write_bytes(text.encode("utf-8")[:100] + bytes(range(256)) * 8)
    with pytest.raises(DataError, match=r"bare\.csv: a binary file \(a NUL byte at byte 100"):
        read_measured(path, plant)
    path.write_bytes(np.tile(np.arange(1, 256, dtype="<i2"), 8).tobytes())
    with pytest.raises(DataError, match=r"bare\.csv: a binary file \(a NUL byte at byte 1,"):
        read_measured(path, plant)


def test_a_cut_gzip_file_is_named(tmp_path: Path, plant: Plant) -> None:
    packed = gzip.compress(write(tmp_path / "plain.csv", table()).read_bytes())
    (tmp_path / "cut.csv.gz").write_bytes(packed[: len(packed) // 2])
    with pytest.raises(DataError, match=r"cut\.csv\.gz: a gzip-compressed file that cannot be decompressed"):
        read_measured(tmp_path / "cut.csv.gz", plant)


def test_a_single_row_is_refused_before_any_warning(tmp_path: Path, plant: Plant) -> None:
    path = write(tmp_path / "one.csv", table(1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's "Mean of empty slice" would come first
        with pytest.raises(DataError, match=r"one\.csv: too little data: 1 rows, at least 50 are needed"):
            read_measured(path, plant)
        with pytest.raises(DataError, match=r"one\.csv: too little data: 1 rows, at least 2 are needed"):
            read_measured(path, plant, min_samples=1)


def test_a_joint_name_with_a_comma_or_quote_round_trips_through_the_csv(tmp_path: Path) -> None:
    """The header was joined with bare commas: 'elbow joint,1' became two columns and the file could not be
    read back."""
    model = tmp_path / "weird.xml"
    model.write_text(
        '<mujoco><worldbody><body name="a"><joint name="elbow joint,1" axis="0 1 0"/>'
        '<geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02" mass="0.5"/><body name="b" pos="0 0 -0.3">'
        '<joint name=\'wrist "2"\' axis="0 1 0"/><geom type="capsule" fromto="0 0 0 0 0 -0.2" size="0.02" '
        'mass="0.3"/></body></body></worldbody><actuator><motor joint="elbow joint,1"/>'
        "<motor joint='wrist \"2\"'/></actuator></mujoco>"
    )
    weird = load_plant(model)
    cols = table()
    t = cols["time"]
    q = np.column_stack([cols["q_shoulder"], cols["q_elbow"]])
    data = Dataset(
        t,
        q,
        np.column_stack([cols["tau_shoulder"], cols["tau_elbow"]]),
        weird.joint_names,
        np.ones(2, dtype=bool),
        dq=np.column_stack([cols["dq_shoulder"], cols["dq_elbow"]]),
    )
    write_csv(data, tmp_path / "w.csv")
    back = read_measured(tmp_path / "w.csv", weird)
    np.testing.assert_allclose(back.q, q, atol=1e-9)
    np.testing.assert_allclose(back.tau, data.tau, atol=1e-9)


def test_pulses_and_quantum_flicker_in_a_torque_are_not_spikes(tmp_path: Path, plant: Plant) -> None:
    """A torque zero for most of the file with short pulses (a command of kicks), or a quantised constant that
    flickers by one step: against the 99th-percentile excursion alone (zero) every pulse sample was a spike and
    was flattened. The spike must also stand out from the column's own steps."""
    cols = table()
    pulses = np.zeros(1000)
    for start in range(50, 1000, 100):
        pulses[start : start + 3] = 0.5
    cols["tau_shoulder"] = pulses
    flicker = np.full(1000, 0.2)
    flicker[::150] += 0.00586  # one quantum, in 0.7 % of the rows
    cols["tau_elbow"] = flicker
    data = read_measured(write(tmp_path / "pulses.csv", cols), plant)
    assert not [r for r in data.meta["repairs"] if r.kind == "torque_spike"]
    np.testing.assert_array_equal(data.tau[:, 0], pulses)


def test_two_header_only_files_are_refused_for_what_they_are_not_as_copies(tmp_path: Path, plant: Plant) -> None:
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    for p in (a, b):
        p.write_text("time,q_shoulder,q_elbow,tau_shoulder,tau_elbow\n")
    with pytest.raises(DataError) as err:
        read_many([a, b], plant)
    assert "a copy" not in str(err.value) and "a.csv" in str(err.value) and "b.csv" in str(err.value)


# units and ranges the model can check ----------------------------------------------------------------------------


def test_a_torque_in_milli_newton_metres_is_refused_with_an_override_that_reads_it(
    tmp_path: Path, plant: Plant
) -> None:

    from tests.conftest import compose_config

    cols = table()
    cols["tau_elbow"] = 1000.0 * cols["tau_elbow"]  # up to 1000 mN m, 83 x the 12 N m actuator limit
    path = write(tmp_path / "mnm.csv", cols)
    with pytest.raises(
        DataError,
        match=r"mnm\.csv: column 'tau_elbow' is 99\d\.\d* N m .*83\.\d times the actuator "
        r"limit 12 N m of two_link; it looks like mN m \(1000 per N m\)",
    ) as err:
        read_measured(path, plant)
    override = re.search(r"command line: '([^']+)'", str(err.value)).group(1)  # type: ignore[union-attr]
    cfg = compose_config(["system=two_link", "data=csv", override], config_name="diagnose")
    mapped = OmegaConf.to_container(cfg.data.columns)
    data = read_measured(path, plant, columns=mapped)  # type: ignore[arg-type]
    np.testing.assert_allclose(data.tau[:, 1], table()["tau_elbow"], atol=1e-12)


@pytest.mark.parametrize("factor", [1e300, -1e12])
def test_a_torque_no_robot_carries_is_refused_even_without_an_actuator_limit(
    tmp_path: Path, plant: Plant, factor: float
) -> None:
    import dataclasses

    unlimited = dataclasses.replace(plant, tau_limit=np.full(plant.nv, np.inf))
    cols = table()
    cols["tau_shoulder"] = factor * cols["tau_shoulder"]
    with pytest.raises(DataError, match=r"column 'tau_shoulder' is .* beyond any robot joint \(1e\+06 N m\); a wrong "):
        read_measured(write(tmp_path / "huge.csv", cols), unlimited)
    # ... and a torque of a few times the limit (a motor's peak) is read as it is
    cols = table()
    cols["tau_shoulder"] = 30.0 * cols["tau_shoulder"]
    read_measured(write(tmp_path / "peak.csv", cols), plant)


def test_an_angle_logged_a_whole_turn_off_is_turned_back_into_the_joint_range(tmp_path: Path) -> None:
    pendulum = load_plant("pendulum")  # a hinge limited to [-pi, pi]
    t = np.arange(1000) / FS
    q = 1.2 * np.sin(2 * np.pi * 0.7 * t)
    cols = {"time": t, "q_swing": q + 2 * np.pi, "tau_swing": np.sin(t)}
    data = read_measured(write(tmp_path / "turn.csv", cols), pendulum)
    (fix,) = [r for r in data.meta["repairs"] if r.kind == "whole_turns"]
    assert "added -1 x 2 pi" in fix.message
    np.testing.assert_allclose(data.q[:, 0], q, atol=1e-12)
    with pytest.raises(
        DataError,
        match=r"column 'q_swing' leaves the joint range .* fits -1 whole turn\(s\) over; not "
        r"repaired \(repair=False\)",
    ):
        read_measured(write(tmp_path / "turn.csv", cols), pendulum, repair=False)


def test_an_angle_far_outside_the_joint_range_is_refused_and_one_pressed_into_its_stop_is_read(tmp_path: Path) -> None:
    pendulum = load_plant("pendulum")
    t = np.arange(1000) / FS
    cols = {"time": t, "q_swing": 2.9 * np.sin(2 * np.pi * 0.7 * t) + 1.0, "tau_swing": np.sin(t)}  # up to 3.9 rad
    far = (
        r"turn\.csv: column 'q_swing' leaves the joint range \[-3\.142, 3\.142\] rad of pendulum by more than 0\.5 "
        r"rad on \d+ of 1000 rows \(the farthest row \d+, line \d+, t = [\d.]+ s: 3\.9\).* widen the joint's range"
    )
    with pytest.raises(DataError, match=far):
        read_measured(write(tmp_path / "turn.csv", cols), pendulum)
    # a swing of +-8 degrees logged in degrees: out of the range as radians, not far enough to be read as degrees
    # at once (3 times the range); the refusal named only the range and the zero
    cols["q_swing"] = 8.0 * np.sin(2 * np.pi * 0.7 * t)
    with pytest.raises(
        DataError, match=r"widen the joint's range .* read as degrees it lies inside the range: .* 0\.0174533"
    ):
        read_measured(write(tmp_path / "degrees.csv", cols), pendulum)
    cols["q_swing"] = np.clip(3.4 * np.sin(2 * np.pi * 0.7 * t), -3.3, 3.3)  # 0.16 rad into both stops
    data = read_measured(write(tmp_path / "stop.csv", cols), pendulum)
    assert not data.meta["repairs"]
    np.testing.assert_allclose(data.q[:, 0], cols["q_swing"], atol=1e-12)


def test_a_slide_logged_in_millimetres_is_refused_with_the_scale_that_reads_it(tmp_path: Path) -> None:
    """A slide's position in mm left its range with only 'widen the range, or correct the zero'; the hint for an
    angle in degrees had no counterpart for millimetres."""
    model = tmp_path / "slide.xml"
    model.write_text(
        '<mujoco><compiler angle="radian"/><worldbody><body name="a" pos="0 0 1">'
        '<joint name="j1" axis="0 1 0" range="-2 2" limited="true"/>'
        '<geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02" mass="0.5"/><body name="b" pos="0 0 -0.3">'
        '<joint name="j2" type="slide" axis="1 0 0" range="-0.1 0.1" limited="true"/><geom type="capsule" '
        'fromto="0 0 0 0 0 -0.3" size="0.02" mass="0.3"/></body></body></worldbody><actuator><motor joint="j1"/>'
        '<motor joint="j2"/></actuator></mujoco>'
    )
    slide = load_plant(model)
    t = np.arange(1000) / FS
    x = 0.08 * np.sin(2 * np.pi * 0.7 * t)  # [m]
    cols = {"time": t, "q_j1": 0.5 * np.sin(2 * np.pi * t), "q_j2": 1e3 * x, "tau_j1": np.sin(t), "tau_j2": np.cos(t)}
    path = write(tmp_path / "mm.csv", cols)
    with pytest.raises(
        DataError,
        match=r"mm\.csv: column 'q_j2' leaves the joint range \[-0\.1, 0\.1\] m .* correct the position's zero .*; "
        r"read as millimetres it lies inside the range: if it is, give the scale 0\.001$",
    ):
        read_measured(path, slide)
    data = read_measured(path, slide, columns={"q_j2": {"column": "q_j2", "scale": 0.001}})
    np.testing.assert_allclose(data.q[:, 1], x, atol=1e-12)

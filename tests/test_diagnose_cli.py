"""`sysid-diagnose` through its plain `run(cfg)`: the composed config writes diagnosis.json, diagnosis.rrd,
<system>_calibrated.xml and <system>_calibrated_all.xml, and a failure leaves nothing half-written."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_diagnose import simulate

import harness.diagnose as cli
from dynamics.errors import DataError
from dynamics.plant import load_plant
from envs.dataset import Dataset, write_csv
from envs.effects import HiddenEffect
from harness.validate import ConfigError
from tests.conftest import compose_config, rrd_has_blueprint, rrd_rows

SHARED_ROBOTS = Path(__file__).resolve().parents[2] / "shared" / "robots"
OUTPUTS = ("diagnosis.json", "diagnosis.rrd", "pendulum_calibrated.xml", "pendulum_calibrated_all.xml")


@pytest.fixture(scope="module")
def csv_files(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """A pendulum with hidden viscous friction: a training and a validation file."""
    folder = tmp_path_factory.mktemp("data")
    _, train, validation = simulate("pendulum", [HiddenEffect("viscous_friction", "swing", 0.01)], 2, folder)
    paths = [folder / "train.csv", folder / "validation.csv"]
    write_csv(train, paths[0])
    write_csv(validation, paths[1])
    return paths


def _config(paths: list[Path], out: Path, *extra: str):  # type: ignore[no-untyped-def]
    listed = ",".join(str(p) for p in paths)
    return compose_config(
        ["system=pendulum", f"data.path=[{listed}]", f"output_dir={out}", "diagnose.references=null", *extra],
        config_name="diagnose",
    )


def test_diagnose_writes_its_four_files(csv_files: list[Path], tmp_path: Path) -> None:
    result = cli.run(_config(csv_files, tmp_path))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(OUTPUTS)
    payload = json.loads((tmp_path / "diagnosis.json").read_text())
    assert payload == json.loads(json.dumps(result))
    assert payload["system"] == "pendulum"
    assert payload["verdict"] == "explained"
    assert payload["findings"][0]["effect"] == "viscous_friction"
    assert payload["findings"][0]["joint"] == "swing"
    assert payload["split"]["by"] == "file"
    assert payload["units"] == {"swing": {"torque": "N m", "angle": "rad"}}
    assert payload["extended"]["mjcf"] == "pendulum_calibrated.xml"
    assert set(payload["extended"]["simulation_error"]) == {"nominal", "extended"}
    assert payload["extended"]["torque_rms"]["swing"] < 0.5 * payload["baseline"]["torque_rms"]["swing"]
    calibrated = load_plant(tmp_path / "pendulum_calibrated.xml")
    assert calibrated.damping[0] == pytest.approx(0.01, rel=0.1)
    rows = rrd_rows(tmp_path / "diagnosis.rrd")
    root = "/validation/0_validation"  # one tab per validation record, keyed by its file
    assert rows[f"{root}/joints/swing/tau/measured"] > 100
    assert rows[f"{root}/joints/swing/q/simulated_calibrated"] > 100
    assert "/findings" in rows
    assert rows[f"{root}/robot/measured/pendulum"] > 10  # the measured motion replayed in 3D
    assert rrd_has_blueprint(tmp_path / "diagnosis.rrd")


def test_the_final_fit_uses_every_record_and_can_be_left_out(csv_files: list[Path], tmp_path: Path) -> None:
    """`<system>_calibrated_all.xml` is the diagnosis run again on the training and the validation file: its
    friction std is that of one and a half times the data (a 5000-row and a 2500-row file; a copy of the training
    fit would keep the training std), and
    `diagnose.final_fit=false` writes none, also removing one an earlier run in that folder left."""
    payload = cli.run(_config(csv_files, tmp_path, "diagnose.recording=false"))
    final = payload["final_fit"]
    assert final["mjcf"] == "pendulum_calibrated_all.xml"
    assert final["records"] == [str(p) for p in csv_files]
    assert final["findings"][0]["name"].startswith("viscous_friction swing")
    trained, every = payload["findings"][0], final["findings"][0]
    assert every["value"] == pytest.approx(0.01, rel=0.05)
    # 1/sqrt(1.5) of the std with the same correlation time; each fit reads its own from its residual (0.87 measured)
    assert every["std"] < 0.95 * trained["std"]
    damping = load_plant(tmp_path / "pendulum_calibrated_all.xml").damping[0]
    assert damping == pytest.approx(every["value"], rel=1e-5)  # 6 digits in the MJCF
    again = cli.run(
        _config(csv_files, tmp_path, "diagnose.recording=false", "diagnose.final_fit=false", "overwrite=true")
    )
    assert "final_fit" not in again
    assert not (tmp_path / "pendulum_calibrated_all.xml").exists()
    with pytest.raises(ConfigError, match=r"diagnose\.final_fit"):
        cli.run(_config(csv_files, tmp_path / "bad", "diagnose.final_fit=maybe"))


def test_single_file_is_split_by_time_block(csv_files: list[Path], tmp_path: Path) -> None:
    payload = cli.run(_config(csv_files[:1], tmp_path, "diagnose.recording=false"))
    assert payload["split"]["by"] == "time_block"
    train, validation = payload["split"]["train"][0], payload["split"]["validation"][0]
    assert train["t_end"] < validation["t_start"]
    assert not (tmp_path / "diagnosis.rrd").exists()


def test_failure_leaves_nothing_half_written(
    csv_files: list[Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(path: Path, payload: dict) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(cli, "write_json", broken)
    with pytest.raises(OSError, match="disk full"):
        cli.run(_config(csv_files, tmp_path))
    assert list(tmp_path.iterdir()) == []


def test_unknown_effect_fails_before_any_work(csv_files: list[Path], tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="valid choices"):
        cli.run(_config(csv_files, tmp_path, "diagnose.effects=[hysteresis]"))
    assert not any(tmp_path.iterdir())


def test_band_comes_from_the_data_config_unless_set() -> None:
    # the DFKI arm's 5 Hz band belongs to its data config: `sysid-diagnose data=dfki_double_pendulum` needs no
    # other override, and `diagnose.band_hz` still wins
    dfki = compose_config(["system=two_link", "data=dfki_double_pendulum"], config_name="diagnose")
    assert cli._band_hz(dfki) == 5.0
    assert list(dfki.data.validation) == ["trajectory_01.csv"]
    override = compose_config(
        ["system=two_link", "data=dfki_double_pendulum", "diagnose.band_hz=2"], config_name="diagnose"
    )
    assert cli._band_hz(override) == 2.0
    assert cli._band_hz(compose_config(["system=pendulum"], config_name="diagnose")) is None


@pytest.mark.parametrize("key", ["record_offsets", "record_joint_offsets"])
def test_record_offsets_come_from_the_data_config_unless_set(key: str) -> None:
    # a sensor re-zeroed at every power-up (a torque's or an encoder's) is a property of the logs, like the band:
    # `diagnose.<key>` (null by default) defers to the data config's `<key>`, false where neither says
    flag = {"record_offsets": cli.record_offsets, "record_joint_offsets": cli.record_joint_offsets}
    plain = compose_config(["system=two_link", "data=dfki_double_pendulum"], config_name="diagnose")
    assert flag[key](plain) is False
    from_data = compose_config(
        ["system=two_link", "data=dfki_double_pendulum", f"++data.{key}=true"], config_name="diagnose"
    )
    assert flag[key](from_data) is True
    other = "record_joint_offsets" if key == "record_offsets" else "record_offsets"
    assert flag[other](from_data) is False  # each its own flag
    both = compose_config(
        ["system=two_link", "data=dfki_double_pendulum", f"++data.{key}=true", f"diagnose.{key}=false"],
        config_name="diagnose",
    )
    assert flag[key](both) is False


@pytest.mark.parametrize("key", ["record_offsets", "record_joint_offsets"])
def test_record_offsets_must_be_a_flag(key: str, csv_files: list[Path], tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=rf"diagnose\.{key} must be true or false"):
        cli.run(_config(csv_files, tmp_path, f"diagnose.{key}=3"))
    assert not any(tmp_path.iterdir())


def test_a_text_column_the_diagnosis_does_not_use_is_listed_not_refused(csv_files: list[Path], tmp_path: Path) -> None:
    lines = csv_files[0].read_text().splitlines()
    noted = tmp_path / "noted.csv"
    noted.write_text("\n".join([lines[0] + ",comment"] + [ln + ",ok 2026-12-01T10:00" for ln in lines[1:]]) + "\n")
    result = cli.run(_config([noted, csv_files[1]], tmp_path / "out"))
    ignored = result["ignored_columns"]
    assert ignored[str(noted)] == [*ignored[str(csv_files[1])], "comment"]  # (ddq: the states are derived)


@pytest.mark.parametrize("key", ["diagnose.band_hz", "diagnose.cutoff_hz", "data.cutoff_hz"])
def test_a_filter_at_the_nyquist_frequency_of_the_files_is_refused(
    csv_files: list[Path], tmp_path: Path, key: str
) -> None:
    """Known once the files are read (their rate), named by its key and the file; nothing is written. So is one
    too slow for the shortest file (the 5 s validation record: 1 Hz), which was blamed on the data (the columns
    "look swapped")."""
    with pytest.raises(ConfigError, match=rf"{key}=300 Hz is not below the Nyquist frequency 250 Hz of .*\.csv"):
        cli.run(_config(csv_files, tmp_path, f"{key}=300"))
    with pytest.raises(ConfigError, match=rf"{key}=0\.001 Hz is below 5 cycles over .*validation\.csv \(.* 1 Hz\)"):
        cli.run(_config(csv_files, tmp_path, f"{key}=0.001"))
    assert not any(tmp_path.iterdir())


def test_a_slow_rate_that_a_time_in_milliseconds_would_explain_is_said_so(
    csv_files: list[Path], tmp_path: Path
) -> None:
    """A log sampled at 8 kHz and timed in milliseconds reads as 8 Hz, fast enough for the unit check (5 Hz); the
    band's refusal blamed the setting alone. It now says what the rate would be in ms. A fast log's refusal does not
    (at 500 Hz a 300 Hz band is the setting's fault), and a window of exactly 5 samples is not refused as shorter."""
    import dataclasses

    from envs.measured import read_measured

    data = read_measured(csv_files[0], load_plant("pendulum"))
    slow = dataclasses.replace(data, time=np.arange(len(data.time)) * 0.125)  # 8 kHz, its time read in ms
    cfg = _config(csv_files, tmp_path)
    with pytest.raises(ConfigError, match=r"sampled at 8 Hz\); or check that its time column is in seconds .* 8000 Hz"):
        cli._check_filters(cfg, [slow])
    with pytest.raises(ConfigError, match=r"sampled at 500 Hz\)$"):
        cli._check_filters(_config(csv_files, tmp_path, "diagnose.band_hz=300"), [data])
    coarse = dataclasses.replace(data, time=np.arange(len(data.time)) * 0.05)  # 20 Hz: 0.25 s is 5 samples
    cli._check_filters(
        _config(csv_files, tmp_path, "diagnose.band_hz=2", "data.cutoff_hz=2", "diagnose.window_s=0.25"), [coarse]
    )


def test_a_state_cut_off_above_an_eighth_of_the_files_rate_is_refused_or_capped(
    csv_files: list[Path], tmp_path: Path
) -> None:
    """Below the Nyquist frequency, but above 62.5 Hz at 500 Hz the differences lose a fifth of the acceleration
    and more: clean two-link data from sysid-run at 120 Hz were named a rigid-body change and an elbow damping (the
    torques compared below 120 Hz), where 60 Hz names nothing. `diagnose.cutoff_hz`, set for these files, is refused
    by its key once their rate is known, and nothing is written; the data config's `cutoff_hz` (conf/data/csv.yaml's
    10 Hz knows nothing of a file's rate: a 50 Hz log would be refused by default) is lowered to the limit, and a
    note says so."""
    with pytest.raises(ConfigError, match=r"diagnose\.cutoff_hz=100 Hz is above 62\.5 Hz, an eighth of the 500 Hz "):
        cli.run(_config(csv_files, tmp_path, "diagnose.cutoff_hz=100"))
    assert not any(tmp_path.iterdir())
    quick = ("diagnose.recording=false", "diagnose.final_fit=false")
    cli.run(_config(csv_files, tmp_path / "at", "diagnose.cutoff_hz=62.5", *quick))
    capped = cli.run(_config(csv_files, tmp_path / "capped", "data.cutoff_hz=100", *quick))
    assert [r["cutoff_hz"] for r in capped["info"]["derivatives"]["cutoff_by_record"]] == pytest.approx([62.5, 62.5])
    assert any(n.startswith("data.cutoff_hz=100 Hz is above 62.5 Hz") for n in capped["notes"]), capped["notes"]


def test_the_state_filter_is_the_data_configs_unless_diagnose_sets_one(csv_files: list[Path], tmp_path: Path) -> None:
    """The angles' cut-off before they are differentiated: `diagnose.cutoff_hz` when set, else the data config's
    `cutoff_hz` (the DFKI configs: 5 Hz, the band their models are judged in, so that the fit sees the judge's
    states), null there: 4 x the excitation's bandwidth; a data config without the key: 10 Hz."""
    quick = ("diagnose.recording=false", "diagnose.final_fit=false")

    def cutoffs(*extra: str) -> list[float]:
        used = cli.run(_config(csv_files, tmp_path, "overwrite=true", *quick, *extra))["info"]["derivatives"]
        assert [r["source"] for r in used["cutoff_by_record"]] == [str(p) for p in csv_files]
        return [r["cutoff_hz"] for r in used["cutoff_by_record"]]

    assert cutoffs() == [10.0, 10.0]  # conf/data/csv.yaml
    assert cutoffs("data.cutoff_hz=7") == [7.0, 7.0]
    assert cutoffs("data.cutoff_hz=7", "diagnose.cutoff_hz=8") == [8.0, 8.0]
    derived = cutoffs("data.cutoff_hz=null")  # each file's own excitation: two multi-sines, two bandwidths
    assert derived[0] != derived[1] and all(5.0 < c < 100.0 and c != 10.0 for c in derived)
    assert cutoffs("~data.cutoff_hz") == [cli.DEFAULT_CUTOFF_HZ] * 2
    for data in ("dfki_double_pendulum", "dfki_double_pendulum_c1"):
        cfg = compose_config(["system=two_link", f"data={data}"], config_name="diagnose")
        assert cli.state_cutoff(cfg) == ("data.cutoff_hz", 5.0) == ("data.cutoff_hz", float(cfg.data.band_hz))


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("diagnose.selection.min_z=nan", r"diagnose\.selection\.min_z must be a finite number, got nan"),
        ("diagnose.selection.bic_margin=-1", r"diagnose\.selection\.bic_margin must be >= 0"),
        ("diagnose.selection.min_independence=5", r"diagnose\.selection\.min_independence must lie in \[0, 1\]"),
        ("diagnose.selection.max_findings=-1", r"diagnose\.selection\.max_findings must be an integer >= 1"),
        ("diagnose.selection.folds=2.5", r"diagnose\.selection\.folds must be an integer in \[2, 50\], got 2\.5"),
        ("diagnose.selection.folds=100000", r"diagnose\.selection\.folds must be an integer in \[2, 50\]"),
        ("+diagnose.selection.min_zz=3", r"diagnose\.selection\.min_zz is not a threshold .* valid keys: .*min_z,"),
        ("diagnose.effects=null", r"diagnose\.effects must be a list of effect names"),
        ("diagnose.effects=armature", r"diagnose\.effects must be a list .* got 'armature'"),
        ("diagnose.derivatives=spectral", r"unknown diagnose\.derivatives 'spectral'; valid choices: butterworth"),
        ("diagnose.window_s=0.001", r"diagnose\.window_s=0\.001 s is shorter than 5 samples of .*train\.csv"),
        ("diagnose.max_windows=0", r"diagnose\.max_windows must be >= 1, got 0"),
        ("data.cutoff_hz=-1", r"data\.cutoff_hz must be > 0, got -1"),
        ("data.cutoff_hz=fast", r"data\.cutoff_hz must be a number, got 'fast'"),
        ("diagnose.window_s=1000", r"diagnose\.window_s=1000 s is longer than .*\.csv \([0-9.]+ s\)"),
        ("data.columns=5", r"data\.columns must map the harness's names to the file's columns .* got 5"),
        ("++data.band_hz=abc", r"data\.band_hz must be a number, got 'abc'"),
        ("++data.band_hz=0", r"data\.band_hz must be > 0"),
        ("++data.band_hz=[1,2]", r"data\.band_hz must be a number, got \[1, 2\]"),
        ("data.tau_lead_s=-0.001", r"data\.tau_lead_s must be >= 0, got -0\.001"),
        (
            "data.tau_lead_s=0.1",
            r"data\.tau_lead_s=0\.1 s is above 20 ms and a sample or more \(0\.002 s\) of .*train\.csv: .*time columns",
        ),
        (
            "diagnose.derivatives=given",
            r"diagnose\.derivatives=given reads .* holds no accelerations .* butterworth or",
        ),
        ("diagnose.recording=maybe", r"diagnose\.recording must be true or false, got 'maybe'"),
        (
            "diagnose.mujoco_steps=auto",
            r"diagnose\.mujoco_steps must be true, false or null \(null: decided from the data\), got 'auto'",
        ),
        ("diagnose=foo", r"diagnose must be a mapping of settings .* got 'foo'"),
        ("data.validation=[]", r"data\.validation must name the held-out file\(s\) .* got \[\]"),
        ("data.validation={a:1}", r"data\.validation must name the held-out file\(s\) .* got \{'a': 1\}"),
        ("data.validation=[b.csv,b.csv]", r"data\.validation names 'b\.csv' more than once; name each held-out file"),
    ],
)
def test_a_bad_diagnosis_setting_is_named_before_anything_is_written(
    csv_files: list[Path], tmp_path: Path, override: str, message: str
) -> None:
    """Each of these ran before: NaN thresholds changed the findings, a string was read letter by letter,
    `spectral` (which needs whole periods of a known excitation) gave a confident false result, a window shorter
    than a sample printed a NaN error, and folds=2.5 or effects=null raised a TypeError."""
    with pytest.raises(ConfigError, match=message):
        cli.run(_config(csv_files, tmp_path, *override.split(" ")))
    assert not any(tmp_path.iterdir())


def test_an_overwrite_retires_the_calibrated_models_of_another_systems_diagnosis(
    csv_files: list[Path], tmp_path: Path
) -> None:
    """A folder that held a two_link diagnosis, rediagnosed for the pendulum with overwrite=true, kept
    two_link_calibrated.xml beside the pendulum's diagnosis.json."""
    (tmp_path / "diagnosis.json").write_text(json.dumps({"system": "two_link"}))
    for name in ("two_link_calibrated.xml", "two_link_calibrated_all.xml", "notes.txt"):
        (tmp_path / name).write_text("old")
    cli.run(_config(csv_files, tmp_path, "overwrite=true", "diagnose.final_fit=false", "diagnose.recording=false"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["diagnosis.json", "notes.txt", "pendulum_calibrated.xml"]


def test_one_validation_file_may_be_given_as_a_string(csv_files: list[Path], tmp_path: Path) -> None:
    """It was read letter by letter ("validation file 'v' is not among the files read")."""
    result = cli.run(_config(csv_files, tmp_path, f"data.validation={csv_files[0].name}", "diagnose.final_fit=false"))
    assert [p["source"] for p in result["split"]["validation"]] == [str(csv_files[0])]


def test_data_that_do_not_excite_the_refit_are_refused(tmp_path: Path) -> None:
    """A pendulum barely swinging about its rest position cannot tell its inertia from its mass moments."""
    plant = load_plant("pendulum")
    t = np.arange(0.0, 4.0, 0.002)
    paths = [tmp_path / "a.csv", tmp_path / "b.csv"]
    for k, p in enumerate(paths):  # two records of their own (two copies of one are refused as such)
        q = 1e-3 * np.sin(2 * np.pi * 0.5 * t + k)[:, None]
        tau = 0.05 * q  # a reading (a torque stuck at exactly zero is refused before this check)
        write_csv(Dataset(time=t, q=q, tau=tau, joint_names=plant.joint_names, actuated=plant.actuated), p)
    out = tmp_path / "out"
    with pytest.raises(DataError, match=r"a\.csv.*excite"):
        cli.run(_config(paths, out))
    assert not out.exists() or not any(out.iterdir())


def test_a_time_column_in_minutes_is_named_not_zero_equations(csv_files: list[Path], tmp_path: Path) -> None:
    """A 500 Hz log timed in minutes reads as 30 kHz over a sixtieth of its length: the derivative filter's
    start-up takes it all, and the refusal said "0 equations for 3 parameters". The 10 Hz state filter is then
    too slow for records so short, which is refused with the time unit named."""
    paths = []
    for p in csv_files:
        lines = p.read_text().splitlines()
        col = lines[0].split(",").index("time")
        rows = [r.split(",") for r in lines[1:]]
        for r in rows:
            r[col] = repr(float(r[col]) / 60.0)
        paths.append(tmp_path / p.name)
        paths[-1].write_text("\n".join([lines[0], *(",".join(r) for r in rows)]) + "\n")
    out = tmp_path / "out"
    with pytest.raises(ConfigError, match=r"cutoff_hz=10 Hz is below 5 cycles .*time column is in seconds"):
        cli.run(_config(paths, out))
    assert not out.exists() or not any(out.iterdir())


def test_a_file_shorter_than_the_state_filter_is_named_not_a_scipy_padlen_error(
    csv_files: list[Path], tmp_path: Path
) -> None:
    """data.min_samples=2 lets a 12-row file through the reader; the state filter then raised SciPy's "The length
    of the input vector x must be greater than padlen, which is 15", naming neither the file nor the fix. The
    command line refuses the filter as too slow for so short a file; the filter itself names the rows it trusts."""
    from envs.measured import read_measured
    from identify.derivatives import derive_states

    lines = csv_files[0].read_text().splitlines()
    short = tmp_path / "short.csv"
    short.write_text("\n".join(lines[:13]) + "\n")
    with pytest.raises(ConfigError, match=r"cutoff_hz=10 Hz is below 5 cycles over .*short\.csv \(0\.022 s"):
        cli.run(_config([short, csv_files[1]], tmp_path / "out", "data.min_samples=2"))
    data = read_measured(short, load_plant("pendulum"), min_samples=2)
    with pytest.raises(DataError, match=r"short\.csv: the derivative filter \(butterworth\) trusts 0 of the 12 rows"):
        derive_states(data, "butterworth", cutoff_hz=10.0)


def test_a_data_configs_paths_are_relative_to_that_config_not_the_working_directory(tmp_path: Path) -> None:
    """A user's data config kept outside the repository (--config-dir) names its logs relative to itself."""
    from envs.sensors import SensorModel
    from envs.simulate import simulate_open_loop

    plant = load_plant("pendulum")
    sensor = SensorModel(500.0, sigma_tau=np.array([0.01]), sigma_q=1.7e-5, q_resolution=2.4e-5)
    logs = tmp_path / "conf" / "data" / "logs"
    logs.mkdir(parents=True)
    for i, seed in enumerate((1, 2)):

        def drive(t: np.ndarray, seed: int = seed) -> np.ndarray:
            return 0.8 * np.sin(2 * np.pi * 0.4 * t)[:, None] + 0.3 * np.sin(2 * np.pi * 1.1 * t + seed)[:, None]

        data = simulate_open_loop(
            plant,
            drive,
            duration_s=8.0,
            sensor=sensor,
            rng=np.random.default_rng(seed),
        )
        write_csv(data, logs / f"run{i}.csv")
    # the format's own fields (conf/data/csv.yaml), with paths relative to this file
    text = (cli.CONF_DIR / "data" / "csv.yaml").read_text().replace("name: csv", "name: mylogs")
    text = text.replace("path: ???", "path: [logs/run0.csv, logs/run1.csv]")
    (tmp_path / "conf" / "data" / "mylogs.yaml").write_text(text)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    proc = subprocess.run(
        [
            str(Path(sys.executable).parent / "sysid-diagnose"),
            "--config-dir",
            str(tmp_path / "conf"),
            "system=pendulum",
            "data=mylogs",
            "diagnose.recording=false",
            f"hydra.run.dir={tmp_path / 'out'}",
        ],
        cwd=elsewhere,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (tmp_path / "out" / "diagnosis.json").is_file()


def test_a_long_log_is_thinned_to_max_rows_and_diagnosed_the_same(csv_files: list[Path], tmp_path: Path) -> None:
    """Past `diagnose.max_rows` the states are derived at the full rate, then every k-th row is kept: the
    hidden friction is still named, with its value, and diagnosis.json says what was thinned."""
    full = cli.run(_config(csv_files, tmp_path / "full", "diagnose.recording=false"))
    thinned = cli.run(_config(csv_files, tmp_path / "thin", "diagnose.max_rows=1000", "diagnose.recording=false"))
    reduced = thinned["reduced"]
    assert set(reduced) == {str(p) for p in csv_files}
    total = sum(r["rows"] for r in reduced.values())
    assert total > 1000 and "reduced" not in full
    for r in reduced.values():
        assert r["factor"] > 1 and r["kept_rate_hz"] == pytest.approx(r["sample_rate_hz"] / r["factor"])
    assert sum(r["kept"] for r in reduced.values()) <= 1000 * 1.05
    assert thinned["findings"][0]["effect"] == "viscous_friction"
    v_full, v_thin = full["findings"][0], thinned["findings"][0]
    assert abs(v_thin["value"] - v_full["value"]) < 3 * max(v_thin["std"], v_full["std"])
    assert thinned["verdict"] == full["verdict"]
    # the anti-aliased torque hides its noise from the third differences: the full-rate floor is used, so the
    # noise expected in the verdict's band is the same (it read 0.0008 for 0.0014 N m, and the clean residual
    # as structure)
    band = [log["whiteness"]["calibrated"]["swing"]["noise_in_band"] for log in (full, thinned)]
    assert band[1] == pytest.approx(band[0], rel=0.05)


def test_a_pattern_stands_for_its_files_and_one_that_matches_none_is_named(
    csv_files: list[Path], tmp_path: Path
) -> None:
    cfg = compose_config(["system=pendulum", f"data.path={csv_files[0].parent}/*.csv"], config_name="diagnose")
    assert cli.data_paths(cfg) == sorted(csv_files)
    cfg = compose_config(["system=pendulum", f"data.path={tmp_path}/nope_*.csv"], config_name="diagnose")
    with pytest.raises(DataError, match=r"nope_\*\.csv: the pattern matches no file"):
        cli.data_paths(cfg)
    # a file named with a pattern's characters is itself, not the files the pattern would match (run1.csv here)
    (tmp_path / "run[1].csv").write_text("x")
    (tmp_path / "run1.csv").write_text("x")
    cfg = compose_config(["system=pendulum", f"data.path='{tmp_path}/run[1].csv'"], config_name="diagnose")
    assert cli.data_paths(cfg) == [tmp_path / "run[1].csv"]


def test_a_file_whose_torque_is_stuck_at_zero_is_left_out_or_refused(csv_files: list[Path], tmp_path: Path) -> None:
    """A zero reading is no measurement: such a file is left out of the fit (said in diagnosis.json), and
    when it is the only one the diagnosis refuses it instead of explaining zeros by a huge effect."""
    text = csv_files[0].read_text().splitlines()
    names = text[0].split(",")
    col = names.index("tau_swing")
    rows = [",".join("0" if i == col else c for i, c in enumerate(line.split(","))) for line in text[1:]]
    stuck = tmp_path / "stuck.csv"
    stuck.write_text("\n".join([text[0], *rows]) + "\n")
    with pytest.raises(DataError, match=r"stuck\.csv: torque of swing \(100% of rows exactly 0\).*nothing to fit"):
        cli.run(_config([stuck], tmp_path / "alone", "diagnose.recording=false"))
    payload = cli.run(_config([stuck, *csv_files], tmp_path / "with", "diagnose.recording=false"))
    assert payload["excluded"] == ["stuck.csv: torque of swing (100% of rows exactly 0)"]
    assert payload["findings"][0]["effect"] == "viscous_friction"
    # named as the validation file, it was left out and then said to be "not among the files read"
    with pytest.raises(DataError, match=r"stuck\.csv: torque of swing .* left out, and data\.validation names it"):
        cli.run(
            _config([stuck, *csv_files], tmp_path / "named", "diagnose.recording=false", "data.validation=stuck.csv")
        )


def test_a_torque_spike_in_a_log_is_repaired_and_listed(
    csv_files: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One sample of 1e30 N m (a logging glitch) broke the calibrated model's inertias with a traceback. The
    repair is said on the terminal as well (it was only in diagnosis.json)."""
    spiked = tmp_path / "spiked.csv"
    lines = csv_files[0].read_text().splitlines()
    header = lines[0].split(",")
    fields = lines[200].split(",")
    fields[header.index("tau_swing")] = "1e30"
    lines[200] = ",".join(fields)
    spiked.write_text("\n".join(lines) + "\n")
    out = tmp_path / "run"
    payload = cli.run(_config([spiked, csv_files[1]], out))
    (repair,) = [r for r in payload["repairs"][str(spiked)] if r["kind"] == "torque_spike"]
    assert repair["rows"] == [199] and "tau_swing" in repair["column"]
    assert payload["findings"][0]["effect"] == "viscous_friction"
    assert f"repaired spiked.csv: {repair['message']}" in capsys.readouterr().err


def test_a_slide_joints_torques_and_errors_are_reported_in_its_units(tmp_path: Path) -> None:
    """A cart on a rail (a slide) with a pendulum: the summary and the findings table print N and m for the
    rail, N m and rad for the hinge."""
    model = tmp_path / "cart.xml"
    model.write_text(
        '<mujoco model="cart"><worldbody><body name="cart"><joint name="rail" type="slide" axis="1 0 0"/>'
        '<geom type="box" size="0.1 0.05 0.05" mass="1"/><body name="arm"><joint name="arm" axis="0 1 0"/>'
        '<geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02" mass="0.5"/></body></body></worldbody>'
        '<actuator><motor joint="rail"/><motor joint="arm"/></actuator></mujoco>'
    )
    units = cli._units(load_plant(model))
    assert units == {"rail": {"torque": "N", "angle": "m"}, "arm": {"torque": "N m", "angle": "rad"}}
    payload = {
        "system": "cart",
        "verdict": "no_discrepancy",
        "findings": [],
        "units": units,
        "models": {"nominal": {"torque_rms": {"rail": 0.5, "arm": 0.02}, "simulation_error": {"rail": 0.01}}},
    }
    out = cli._summary(payload)
    assert "rail 0.5000 N, arm 0.0200 N m" in out and "simulation error: rail 0.0100 m" in out


def test_a_value_at_its_bound_is_printed_without_a_std() -> None:
    """It was printed as `0.7 +- nan 1 (at its lower bound)`."""
    finding = {"effect": "torque_gain", "joint": "elbow", "value": 0.7, "std": None, "unit": "1"}
    payload = {"system": "two_link", "verdict": "explained", "models": {}}
    text = cli._summary({**payload, "findings": [{**finding, "at_bound": "lower"}]})
    assert "torque_gain       elbow      0.7 1 (at its lower bound, no std)" in text and "nan" not in text
    free = cli._summary({**payload, "findings": [{**finding, "std": 0.004}]})
    assert "0.7 +- 0.004 1" in free


@pytest.mark.skipif(
    not (SHARED_ROBOTS / "panda_nohand.xml").is_file(), reason="../shared/robots/ is not beside the project"
)
def test_a_torque_logged_at_the_start_of_its_hold_is_read_at_its_centre(tmp_path: Path) -> None:
    """The Panda in the testbed's own loop (the torque held over each 2 ms sample, logged at its start), written to
    CSV, which has no field for that 1 ms lead. Read as sampled at the row's instant (`data.tau_lead_s=0`),
    states and torque are 1 ms apart, and clean data are called `explained` by a joint-2 viscous friction of
    -0.067 N m s/rad; with `data.tau_lead_s=0.001` they are clean, and so they are with none declared: the lead is
    found (1 ms to within its std) and the records read with it (before, that was a note, and the verdict the
    first one's; the declared 0.001 is tested no more, the found 0.88 ms standing for it)."""
    from identify.diagnose.testbed import ARMS, rollout, torque_driven

    mjcf = torque_driven(SHARED_ROBOTS / "panda_nohand.xml", tmp_path)
    paths = []
    for i, (seed, duration) in enumerate(((0, 10.0), (1, 5.0))):
        _, data = rollout(
            "panda_nohand",
            [],
            rng=np.random.default_rng(seed),
            duration_s=duration,
            mjcf=mjcf,
            settings=ARMS["panda_nohand"],
        )
        assert data.tau_lead_s == pytest.approx(0.001)  # half a sample under RK4
        paths.append(tmp_path / f"arm_{i}.csv")
        write_csv(data, paths[-1])
    listed = ",".join(str(p) for p in paths)

    def diagnosis(*extra: str) -> dict[str, Any]:
        out = tmp_path / f"out{sum(1 for _ in tmp_path.glob('out*'))}"
        overrides = [f"system.mjcf={mjcf}", f"data.path=[{listed}]", f"output_dir={out}", "diagnose.final_fit=false"]
        cfg = compose_config([*overrides, "diagnose.recording=false", *extra], config_name="diagnose")
        return cli.run(cfg)

    assert diagnosis("data.tau_lead_s=0")["verdict"] == "explained"
    found = diagnosis()
    assert found["verdict"] == "no_discrepancy", found["verdict_reason"]
    lead = found["info"]["torque_lead_found"]
    assert abs(lead["read_s"] - 0.001) < 3 * lead["std_s"] and lead["declared_s"] == 0.0, lead
    assert found["notes"][0].startswith("the measured torque leads the motion by"), found["notes"][0]
    assert "diagnosed again" in found["notes"][0]


def test_the_diagnosis_reads_a_friction_as_the_logs_simulator_applied_it(tmp_path: Path) -> None:
    """`system.hard_friction` is false for sysid-diagnose whatever the system config says (the any-robot config sets
    it true for sysid-run): the MJCF is read as MuJoCo applies it. A log that sysid-run simulated with its Coulomb
    friction (the xArm7, frictionloss 1 N m at MuJoCo's default parameters, which MuJoCo applies as ramps 0.11 to
    7.7 rad/s wide) is told apart from that file: its friction is named as 1 N m in a narrower shape than the
    file's ramp (`friction_ramp`; before that candidate, as Stribeck frictions and a friction change), and it is
    clean to the diagnosis once `system.hard_friction=true` says how it was simulated. A value that is no flag is
    refused."""
    xarm = SHARED_ROBOTS / "xarm7_nohand.xml"
    if not xarm.is_file():
        pytest.skip("../shared/robots/ is not beside the project")
    cfg = compose_config([f"system.mjcf={xarm}"], config_name="diagnose")
    assert cfg.system.hard_friction is False
    run_dir = tmp_path / "run"
    command = [sys.executable, "-m", "harness.run", f"system.mjcf={xarm}", "system.periods=1", "excitation=random"]
    proc = subprocess.run(
        [*command, f"hydra.run.dir={run_dir}"],
        cwd=Path(__file__).resolve().parents[1],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads((run_dir / "results.json").read_text())["config"]["system"]["hard_friction"] is True

    def diagnosis(*extra: str) -> dict:  # type: ignore[type-arg]
        out = tmp_path / f"out{len(extra)}"
        overrides = [f"system.mjcf={xarm}", f"data.path={run_dir / 'data.csv'}", f"output_dir={out}"]
        return cli.run(compose_config([*overrides, "diagnose.final_fit=false", *extra], config_name="diagnose"))

    as_file = diagnosis()
    assert as_file["verdict"] != "no_discrepancy"
    ramps = [f for f in as_file["findings"] if f["effect"] == "friction_ramp"]
    assert ramps, [f["effect"] for f in as_file["findings"]]
    for f in ramps:  # the level the log's simulator applied, in a narrower shape than the file's
        assert abs(f["value"] - 1.0) < 3 * f["std"], f
    assert diagnosis("system.hard_friction=true")["verdict"] == "no_discrepancy"
    with pytest.raises(ConfigError, match=r"system\.hard_friction must be true or false, got 'sometimes'"):
        diagnosis("system.hard_friction=sometimes")


def test_record_joint_offsets_reach_the_diagnosis(
    csv_files: list[Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the flag as resolved reaches both fits (the training one and the final fit on every record), and the final
    # fit on the two files then finds an angle offset for each
    seen: list[bool] = []

    def spy(*args: object, **kwargs: object) -> object:
        seen.append(bool(kwargs["record_joint_offsets"]))
        return original(*args, **kwargs)

    original = cli.diagnose
    monkeypatch.setattr(cli, "diagnose", spy)
    payload = cli.run(_config(csv_files, tmp_path, "diagnose.recording=false", "+data.record_joint_offsets=true"))
    # each fit twice: the simulator's torque, held over each sample, leads its rows; found and read (with_found_lead)
    assert "torque_lead_found" in payload["info"]
    assert seen == [True, True, True, True]
    assert [Path(r["source"]).name for r in payload["final_fit"]["record_joint_offsets"]] == [
        "train.csv",
        "validation.csv",
    ]


def test_mujoco_steps_reaches_both_fits(csv_files: list[Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # asked outright, the reading reaches the training fit and the final fit on every record, and both say it
    seen: list[object] = []

    def spy(*args: object, **kwargs: object) -> object:
        seen.append(kwargs["mujoco_steps"])
        return original(*args, **kwargs)

    original = cli.diagnose
    monkeypatch.setattr(cli, "diagnose", spy)
    payload = cli.run(_config(csv_files, tmp_path, "diagnose.recording=false", "diagnose.mujoco_steps=true"))
    assert "torque_lead_found" in payload["info"]  # each fit twice: the held torque's lead found and read
    assert seen == [True, True, True, True]
    assert payload["info"]["mujoco_steps"]["read"] and payload["info"]["mujoco_steps"]["asked"] is True
    assert payload["final_fit"]["mujoco_steps"]["read"]


def test_the_report_lists_each_training_records_angle_zero() -> None:
    # the recording's findings document carries each training record's angle offset with its std (a nuisance,
    # not a finding), and nothing of the kind where none was fitted
    from identify.diagnose.testbed import Injected, diagnose_records

    zeros = (0.05, -0.04, 0.03)
    per_record = [[Injected("joint_offset", "shoulder", z)] for z in zeros]
    plant, dg = diagnose_records("two_link", per_record, [], record_joint_offsets=True)
    text = cli._findings_markdown(dg, cli._units(plant))
    rows = [line for line in text.splitlines() if "(angle offset)" in line]
    assert [row.split(" | ")[0] for row in rows] == [f"| testbed_train_{i} (angle offset)" for i in range(3)]
    for row, r in zip(rows, dg.info["record_joint_offsets"], strict=True):
        assert f"{r['shoulder']:.4g} ± {r['std']['shoulder']:.2g} rad" in row
    plain = diagnose_records("two_link", per_record[:1], [])[1]
    assert "(angle offset)" not in cli._findings_markdown(plain, cli._units(plant))


@pytest.mark.parametrize(
    ("overrides", "named"),
    [
        (
            ["diagnose.record_offsets=true", "diagnose.record_joint_offsets=true"],
            "diagnose.record_offsets and diagnose",
        ),
        (["++data.record_offsets=true", "diagnose.record_joint_offsets=true"], "data.record_offsets and diagnose"),
    ],
)
def test_both_zeros_per_file_are_refused_by_their_keys(
    overrides: list[str], named: str, csv_files: list[Path], tmp_path: Path
) -> None:
    with pytest.raises(ConfigError, match=named.replace(".", r"\.")):
        cli.run(_config(csv_files, tmp_path, *overrides))
    assert not any(tmp_path.iterdir())
    # the data config's flag overridden to false by the diagnose key: no conflict
    both_off = ["++data.record_offsets=true", "diagnose.record_offsets=false", "diagnose.record_joint_offsets=true"]
    cli.run(_config(csv_files, tmp_path / "ok", "diagnose.recording=false", "diagnose.final_fit=false", *both_off))


def test_a_model_with_mesh_files_is_diagnosed_and_its_calibrated_mjcf_loads_from_the_run_folder(tmp_path: Path) -> None:
    """Links drawn by meshes in a `meshes/` folder beside the MJCF, as Menagerie arms ship: the variant with the
    hidden effect is written to a scratch folder and the calibrated MJCF to the run folder, and each must still find
    the meshes (the diagnosis stopped with "Error opening file 'meshes/link.obj'" on its scratch copy of the
    calibrated file). The mesh also weighs the link, so a model that lost it would not be the same robot."""
    from envs.effects import apply_effects
    from envs.sensors import SensorModel
    from envs.simulate import simulate_open_loop
    from excitation.designs import default_design, random_design
    from excitation.limits import limits_for

    robot = tmp_path / "robot"
    (robot / "meshes").mkdir(parents=True)
    corners = [(x, y, z) for z in (-0.03, 0.03) for y in (-0.03, 0.03) for x in (-0.03, 0.03)]
    faces = ["1 2 4", "1 4 3", "5 7 8", "5 8 6", "1 5 6", "1 6 2", "3 4 8", "3 8 7", "1 3 7", "1 7 5", "2 6 8", "2 8 4"]
    obj = "".join(f"v {x} {y} {z}\n" for x, y, z in corners) + "".join(f"f {f}\n" for f in faces)
    (robot / "meshes" / "link.obj").write_text(obj)
    (robot / "bot.xml").write_text(
        '<mujoco model="bot"><compiler meshdir="meshes"/><asset><mesh name="link" file="link.obj"/></asset>'
        '<worldbody><body name="link" pos="0 0 1"><joint name="swing" axis="0 1 0" range="-170 170"/>'
        '<geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.01" mass="0.1"/>'
        '<geom type="mesh" mesh="link" pos="0 0 -0.3" density="4000"/></body></worldbody>'
        '<actuator><motor joint="swing" ctrlrange="-5 5"/></actuator></mujoco>'
    )
    plant = load_plant(robot / "bot.xml")
    mass = float(plant.mj_model.body_mass[1])
    assert mass == pytest.approx(0.1 + 4000 * 0.06**3, rel=1e-6)  # the mesh found and weighed
    sensor = SensorModel(500.0, sigma_tau=np.array([0.005]), tau_resolution=0.001, sigma_q=1.7e-5, q_resolution=2.4e-5)
    hidden, sensor = apply_effects(
        plant, [HiddenEffect("viscous_friction", "swing", 0.02)], sensor=sensor, directory=tmp_path / "scratch"
    )
    assert float(hidden.mj_model.body_mass[1]) == pytest.approx(mass, rel=1e-9)
    limits = limits_for(plant, torque_margin=0.9, velocity=8.0, acceleration=60.0, range_margin=0.05)
    rng_train, rng_val, rng_design = np.random.default_rng(0).spawn(3)
    designs = [
        default_design(plant, limits, harmonics=5, base_freq_hz=0.2, torque_driven=True),
        random_design(plant, limits, harmonics=5, base_freq_hz=0.2, rng=rng_design, torque_driven=True),
    ]
    paths = []
    for k, (design, rng, duration) in enumerate(zip(designs, (rng_train, rng_val), (10.0, 5.0), strict=True)):
        data = simulate_open_loop(hidden, design.torque, duration_s=duration, sensor=sensor, rng=rng)
        paths.append(tmp_path / f"log{k}.csv")
        write_csv(data, paths[-1])
    out = tmp_path / "out"
    cfg = compose_config(
        [f"system.mjcf={robot / 'bot.xml'}", f"data.path=[{paths[0]},{paths[1]}]", f"output_dir={out}"],
        config_name="diagnose",
    )
    cfg.diagnose.references = None
    result = cli.run(cfg)
    assert result["findings"][0]["effect"] == "viscous_friction", result["findings"]
    for name in ("bot_calibrated.xml", "bot_calibrated_all.xml"):
        calibrated = load_plant(out / name)  # from the run folder, the meshes beside the user's model
        assert float(calibrated.mj_model.body_mass[1]) == pytest.approx(mass, rel=1e-5)
        assert calibrated.damping[0] == pytest.approx(0.02, rel=0.2)


def test_a_declared_torque_lead_is_refused_only_above_20_ms_and_a_sample() -> None:
    """`data.tau_lead_s`: a drive's lag of a few samples is accepted (it was refused from one sample up); a lead
    over 20 ms and a sample is a time column of another clock and is refused naming the file; under a sample any
    lead is a held torque's offset, the half sample of a 20 Hz log's zero-order hold (25 ms) included."""
    t = np.arange(200) / 500.0
    zeros, both = np.zeros((200, 2)), np.ones(2, bool)
    fast = Dataset(time=t, q=zeros, tau=zeros, joint_names=("a", "b"), actuated=both, source="fast.csv")
    slow = Dataset(time=t * 25.0, q=zeros, tau=zeros, joint_names=("a", "b"), actuated=both, source="slow.csv")
    assert cli._with_torque_lead([fast], 0.005)[0].tau_lead_s == 0.005
    assert cli._with_torque_lead([slow], 0.025)[0].tau_lead_s == 0.025
    assert cli._with_torque_lead([slow], 0.04)[0].tau_lead_s == 0.04  # above 20 ms, under the 50 ms sample
    with pytest.raises(ConfigError, match=r"data\.tau_lead_s=0\.1 s is above 20 ms and a sample or more .* fast\.csv"):
        cli._with_torque_lead([fast], 0.1)

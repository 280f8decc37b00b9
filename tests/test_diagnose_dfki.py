"""The diagnosis on the DFKI double pendulum's real logs: fit on some files, validate on another, and
compare with the nominal MJCF, the rigid-body refit and the authors' own identified models on the same
validation file. Skipped when ../shared/data is absent.

One split only, for speed: whether the calibrated model beats the authors' is a claim over every
leave-one-file-out split, measured by `python -m bench diagnose` (bench/diagnose.md), not pinned here."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import harness.diagnose as cli
from tests.conftest import compose_config

AUTHORS = ("authors_3.0", "authors_3.1", "authors_h1.0")


@pytest.fixture(scope="module")
def payload(tmp_path_factory: pytest.TempPathFactory) -> dict:
    from conftest import SHARED_DATA

    folder = SHARED_DATA / "dfki_double_pendulum_c0"
    if not folder.is_dir():
        pytest.skip(f"real DFKI logs not found at {folder} (the project was cloned without ../shared)")
    out = tmp_path_factory.mktemp("dfki")
    files = [folder / f"trajectory_{n}.csv" for n in ("00", "02", "05", "12", "01")]
    cfg = compose_config(
        [
            "system=two_link",
            "data=dfki_double_pendulum",
            # the data config's own split and band (fit on 00, 02, 05, 12; validate on 01, 5 Hz): only the
            # folder is overridden, so the test reads ../shared wherever it runs from
            f"data.path=[{','.join(str(f) for f in files)}]",
            f"output_dir={out}",
        ],
        config_name="diagnose",
    )
    result = cli.run(cfg)
    assert json.loads((Path(out) / "diagnosis.json").read_text())["system"] == "two_link"
    return result


@pytest.mark.slow
def test_every_model_is_reported_on_the_validation_files(payload: dict) -> None:
    assert [Path(p["source"]).name for p in payload["split"]["validation"]] == ["trajectory_01.csv"]
    train = sorted(Path(p["source"]).name for p in payload["split"]["train"])
    assert train == [f"trajectory_{n}.csv" for n in ("00", "02", "05", "12")]
    assert payload["info"]["band_hz"] == 5.0
    for model in ("nominal", "rigid_body_refit", "calibrated", *AUTHORS):
        m = payload["models"][model]
        assert set(m["torque_rms"]) == {"shoulder", "elbow"}
        assert set(m["simulation_error"]) == {"shoulder", "elbow"}
    assert payload["verdict"] in ("explained", "unexplained_structure")
    if payload["verdict"] == "unexplained_structure":
        assert payload["remaining"], "what remains must be described"


@pytest.mark.slow
def test_real_data_names_friction(payload: dict) -> None:
    shapes = ("coulomb_friction", "smooth_coulomb_friction")  # one frictionloss per joint, ideal or a ramp
    named = {f.get("joint") for f in payload["findings"] if f["effect"] in shapes}
    assert named == {"shoulder", "elbow"}
    for f in payload["findings"]:
        if f["effect"] in shapes:  # the authors' cf * pi / 2 is 0.146 and 0.123 N m
            assert 0.08 < f["value"] < 0.2


@pytest.mark.slow
def test_the_elbows_friction_law_has_its_viscous_part(payload: dict) -> None:
    """Once the elbow's frictionloss is named its viscous part is tried first: on these four files it lowers the
    error of each file held out in turn, beats the frictionloss's ramps, and is named with a positive value (the
    authors' model 3.0 writes b2 = 0.001 N m s/rad). Scored after the rigid-body refit, as before, it was not
    named and the held-out elbow RMS was 0.0772 N m (authors 3.0: 0.0709)."""
    (vis,) = [f for f in payload["findings"] if (f["effect"], f.get("joint")) == ("viscous_friction", "elbow")]
    assert 0 < vis["value"] < 0.03 and vis["at_bound"] is None, vis
    assert all(g > 0 for g in vis["fold_gains"]), vis["fold_gains"]
    assert payload["models"]["calibrated"]["torque_rms"]["elbow"] < 0.074


@pytest.mark.slow
def test_calibrated_beats_the_nominal_mjcf_on_every_joint(payload: dict) -> None:
    models = payload["models"]
    for joint in ("shoulder", "elbow"):
        assert models["calibrated"]["torque_rms"][joint] < models["nominal"]["torque_rms"][joint]
        assert models["calibrated"]["simulation_error"][joint] < models["nominal"]["simulation_error"][joint]


@pytest.mark.slow
def test_no_finding_on_real_data_is_outside_its_physical_range(payload: dict) -> None:
    for f in payload["findings"]:
        for p in f["parameters"]:
            assert p["at_bound"] is not None or p["std"] is not None
        if f["effect"] == "time_delay":
            assert 0 <= f["value"] <= 0.02, f
        if f["effect"] == "torque_gain":
            assert 0.7 <= f["value"] <= 1.3, f


@pytest.mark.slow
def test_offset_like_rigid_body_columns_left_at_nominal_are_reported(payload: dict) -> None:
    """On these four files the lateral first moments act as shoulder offsets that do not carry over to the
    held-out files (tests/test_diagnose_offset_like.py has the mechanism on simulated records): the rigid-body
    finding leaves them at nominal, does not list them among its fitted parameters, and a note says why."""
    rigid = [f for f in payload["findings"] if f["effect"] == "rigid_body"]
    assert rigid, [f["effect"] for f in payload["findings"]]
    held = rigid[0]["held_nominal"]
    assert held == ["d(MX1)", "d(MX2)"]
    assert not set(held) & {p["name"] for p in rigid[0]["parameters"]}
    assert any("not refitted" in n and "d(MX1)" in n for n in payload["notes"]), payload["notes"]
    assert "rigid_body" in cli._summary(payload) and "(d(MX1), d(MX2) nominal)" in cli._summary(payload)


def test_c1_config_reads_the_rebuild_with_the_same_nominal_model(shared_data: Path) -> None:
    """design C.1 is diagnosed against `two_link` (the same documented design); its config reads every shared
    file, holds one out by name and carries the lab's models for this build."""
    from omegaconf import OmegaConf

    from dynamics.plant import load_plant
    from envs.measured import read_many

    cfg = compose_config(["system=two_link", "data=dfki_double_pendulum_c1"], config_name="diagnose")
    paths = cli.data_paths(cfg)  # relative to the data config's own folder, wherever the test runs
    folder = shared_data / "dfki_double_pendulum_c1"
    assert sorted(p.name for p in paths) == sorted(p.name for p in folder.glob("*.csv"))
    assert set(cfg.data.validation) <= {p.name for p in paths}
    assert cfg.system.name == "two_link" and cli._band_hz(cfg) == 5.0
    data = read_many(paths, load_plant("two_link"), columns=OmegaConf.to_container(cfg.data.columns))  # type: ignore[arg-type]
    assert all(d.n_samples > 2500 for d in data)
    refs = cli.reference_models("auto", paths)
    assert {"authors_1.0", "authors_2.0"} <= set(refs)


@pytest.mark.slow
def test_the_validation_file_is_inside_the_training_motion_and_its_error_is_model_error(payload: dict) -> None:
    """trajectory_01 swings within what 00, 02, 05 and 12 covered: nothing is named outside the training motion.
    The calibrated prediction's std from the parameters' uncertainty is a small part of its validation error:
    what remains is model error, not estimation noise (measured 0.015 / 0.010 against 0.087 / 0.052 N m)."""
    assert payload["info"]["outside_training"] == []
    assert not any("outside the training motion" in n for n in payload["notes"])
    for joint, std in payload["info"]["prediction_std"].items():
        assert 0 < std < 0.5 * payload["models"]["calibrated"]["torque_rms"][joint]


@pytest.mark.parametrize(
    ("data_config", "folder"),
    [("dfki_double_pendulum", "dfki_double_pendulum_c0"), ("dfki_double_pendulum_c1", "dfki_double_pendulum_c1")],
)
def test_the_swing_ups_clipped_command_is_named_on_the_logged_rows(
    shared_data: Path, data_config: str, folder: str
) -> None:
    """C.0's swing-up (trajectory_12, ~616 Hz, jittery) commands the 8 N m limit on both joints, a row or two at a
    time, again and again; the reader resamples the file, which blurs that plateau, so the anomaly is found on
    the rows as logged. No other shared file of either session has an anomaly (every joint moves, no torque is
    stuck at zero or clipped)."""
    from omegaconf import OmegaConf

    from dynamics.plant import load_plant
    from envs.measured import read_many
    from identify.diagnose.anomalies import find_anomalies

    cfg = compose_config(["system=two_link", f"data={data_config}"], config_name="diagnose")
    files = sorted((shared_data / folder).glob("*.csv"))
    data = read_many(files, load_plant("two_link"), columns=OmegaConf.to_container(cfg.data.columns))  # type: ignore[arg-type]
    found = {(Path(a.source).name, a.kind, a.joint, a.detail.get("commanded")) for a in find_anomalies(data)}
    if folder.endswith("c0"):
        swing = next(d for d in data if d.source.endswith("trajectory_12.csv"))
        assert "logged_tau_cmd" in swing.meta and len(swing.meta["logged_tau_cmd"]) != swing.n_samples
        assert found == {
            ("trajectory_12.csv", "torque_saturated", "shoulder", 1.0),
            ("trajectory_12.csv", "torque_saturated", "elbow", 1.0),
        }
        clips = {a.joint: a.detail for a in find_anomalies([swing])}
        assert {j: (d["level_Nm"], d["episodes"], d["longest_run"]) for j, d in clips.items()} == {
            "shoulder": (8.0, 8.0, 2.0),
            "elbow": (8.0, 12.0, 2.0),
        }
    else:
        assert found == set()


def test_c1s_changing_zeros_come_with_the_start_pose_hint(shared_data: Path) -> None:
    """On C.1's default split the four training files' mean shoulder residuals differ (a zero that changes between
    files), and every file starts at the same angles and ends elsewhere: the note says so beside the options. At the
    state cut-off `sysid-diagnose` resolves for this data config (`derivative_options`: 5 Hz, the judging band)."""
    import numpy as np
    from omegaconf import OmegaConf

    from dynamics.plant import load_plant
    from envs.measured import read_many
    from identify.diagnose import diagnose

    cfg = compose_config(["system=two_link", "data=dfki_double_pendulum_c1"], config_name="diagnose")
    plant = load_plant("two_link")
    data = read_many(cli.data_paths(cfg), plant, columns=OmegaConf.to_container(cfg.data.columns))  # type: ignore[arg-type]
    held = [d for d in data if Path(d.source).name in cfg.data.validation]
    train = [d for d in data if all(d is not h for h in held)]
    options = cli.derivative_options(cfg)
    dg = diagnose(plant, train, held, rng=np.random.default_rng(0), derivative_options=options, band_hz=5.0)
    (note,) = [n for n in dg.notes if n.startswith("shoulder: the training records' mean torque residuals")]
    assert "diagnose.record_joint_offsets=true" in note
    assert "every training record starts at the same angles (to 0.01 rad) and ends elsewhere" in note


@pytest.mark.slow
@pytest.mark.parametrize(("held_out", "ramp"), [("20230629-143339.csv", 0.1), ("20230629-144115.csv", None)])
def test_c1s_elbow_friction_below_sliding_speed_is_a_ramp_where_a_file_holds_it_at_zero_torque(
    shared_data: Path, tmp_path: Path, held_out: str, ramp: float | None
) -> None:
    """C.1's 20230629-144115 commands the elbow zero torque throughout: it sticks for up to 0.7 s at a time while
    the drive reads ~0. Where that file is among the training records, the elbow's friction below sliding speed
    (rows the final fit leaves out) is written as a 0.1 rad/s ramp, chosen on those rows, and the held-out file's
    elbow is predicted better than with the narrow shape (judged as bench/diagnose.py judges: the model's MuJoCo
    inverse dynamics on 5 Hz zero-phase states against the 5 Hz torque). Held out itself, no training file holds
    the elbow so, no ramp lowers the training error by the margin asked, and the friction stays narrow."""
    import mujoco
    import numpy as np
    from omegaconf import OmegaConf

    from bench.diagnose import _judged_states, widened
    from dynamics.friction import friction_parameters, ideal_friction_speed
    from dynamics.plant import load_plant
    from envs.measured import read_measured
    from identify.diagnose.calibrate import mjcf_measured_torque

    folder = shared_data / "dfki_double_pendulum_c1"
    files = sorted(folder.glob("*.csv"))
    cfg = compose_config(
        [
            "system=two_link",
            "data=dfki_double_pendulum_c1",
            f"data.path=[{','.join(str(f) for f in files)}]",
            f"data.validation=[{held_out}]",
            "diagnose.final_fit=false",
            f"output_dir={tmp_path}",
        ],
        config_name="diagnose",
    )
    cli.run(cfg)
    payload = json.loads((tmp_path / "diagnosis.json").read_text())
    info = payload["info"]["slow_friction_ramps"]
    said = [n for n in payload["notes"] if "friction below sliding speed" in n]
    model = mujoco.MjModel.from_xml_path(str(tmp_path / "two_link_calibrated.xml"))
    speed = friction_parameters(model)[0]
    if ramp is None:
        assert info == {} and said == []
        assert np.all(speed < 0.01)  # the narrow shape MuJoCo simulates stably
        return
    assert set(info) == {"elbow"}
    assert len(said) == 1 and said[0].startswith("elbow: its friction below sliding speed is written as a ramp of 0.1")
    assert info["elbow"]["ramp_speed"] == ramp
    assert info["elbow"]["training_rms_ramp"] ** 2 < 0.9 * info["elbow"]["training_rms_before"] ** 2
    assert speed[1] == pytest.approx(ramp, rel=1e-6) and speed[0] < 0.01

    # the same MJCF with the elbow's friction MuJoCo's narrowest stable ramp again, as the fit wrote it before
    narrow = widened(
        model, ideal_friction_speed(model.dof_frictionloss[1], model.dof_invweight0[1], model.opt.timestep)
    )
    columns = OmegaConf.to_container(cfg.data.columns)
    data = read_measured(folder / held_out, load_plant("two_link"), columns=columns)  # type: ignore[arg-type]
    states, measured = _judged_states(data)

    def elbow_rms(m: mujoco.MjModel) -> float:
        pred = mjcf_measured_torque(m, data.time, states.q, states.dq, states.ddq)[states.valid]
        return float(np.sqrt(np.mean((measured[:, 1] - pred[:, 1]) ** 2)))

    assert elbow_rms(model) < elbow_rms(narrow)

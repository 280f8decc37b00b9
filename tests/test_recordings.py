"""The recordings read back from their .rrd: panel names with units, one colour per role, the camera framed
on the whole robot, named z bars with the 2-std band, the diagnosis residuals equal to its table, every
validation record in its own named tab, and the sweep report's bars named by job with thresholds drawn."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from test_diagnose import simulate

import harness.diagnose as diagnose_cli
from dynamics.plant import load_plant
from envs.dataset import write_csv
from envs.effects import HiddenEffect
from harness.record import ROLE_COLORS, parameter_entity
from harness.report import THRESHOLDS
from harness.report import main as report_main
from harness.robot3d import _reach
from harness.run import run
from tests.conftest import compose_config, rgba, rrd_blueprint, rrd_components

SHORT = ["system=pendulum", "system.periods=1", "validation.periods=1"]


def _views(blueprint: dict[str, dict[str, list]]) -> dict[str, dict[str, list]]:
    """View display name -> its blueprint entity's components, merged with its property entities."""
    out = {}
    for path, comps in blueprint.items():
        if path.startswith("/view/") and "ViewBlueprint:display_name" in comps:
            props = {k: v for p, c in blueprint.items() if p.startswith(path + "/") for k, v in c.items()}
            out[comps["ViewBlueprint:display_name"][0][0]] = {**comps, **props}
    return out


def _color(data: dict[str, dict[str, list]], entity: str) -> tuple[int, int, int]:
    return rgba(data[entity]["SeriesLines:colors"][0][0])[:3]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("run")
    run(compose_config(SHORT), output_dir=out)
    return out


def test_run_recording_panels_carry_units_and_split_q_from_dq(run_dir: Path) -> None:
    views = _views(rrd_blueprint(run_dir / "recording.rrd"))
    for title in ("swing: torque [N m]", "swing: residual [N m]", "swing: q [rad]", "swing: dq [rad/s]"):
        assert title in views, sorted(views)
    assert views["swing: q [rad]"]["ViewBlueprint:space_origin"][0][0] == "/joints/swing/q"
    assert views["swing: dq [rad/s]"]["ViewBlueprint:space_origin"][0][0] == "/joints/swing/dq"
    for name, view in views.items():
        if view["ViewBlueprint:class_identifier"][0][0] in ("TimeSeries", "BarChart"):
            assert "[" in name and name.endswith("]"), f"panel {name!r} has no unit"
            assert view["PlotLegend:visible"][0][0] is True


def test_run_recording_has_one_colour_per_role_and_draws_the_limits(run_dir: Path) -> None:
    data = rrd_components(run_dir / "recording.rrd")
    results = json.loads((run_dir / "results.json").read_text())
    j = "/joints/swing"
    assert _color(data, f"{j}/tau/measured") == ROLE_COLORS["measured"]
    assert _color(data, f"{j}/q/measured") == ROLE_COLORS["measured"]
    assert _color(data, f"{j}/dq/measured") == ROLE_COLORS["measured"]
    assert _color(data, f"{j}/tau/model") == ROLE_COLORS["model"]
    assert _color(data, f"{j}/residual/model") == ROLE_COLORS["model"]
    assert len(set(ROLE_COLORS.values())) == len(ROLE_COLORS)
    # the joint limits and the noise band, drawn in the reference colour at the values of results.json
    limits = results["excitation"]["limits"]
    for entity, value in (
        (f"{j}/q/limit_q_min_plus", limits["q_min"][0]),
        (f"{j}/q/limit_q_max_plus", limits["q_max"][0]),
        (f"{j}/dq/limit_dq_max_plus", limits["dq_max"][0]),
        (f"{j}/dq/limit_dq_max_minus", -limits["dq_max"][0]),
        (f"{j}/residual/noise_plus", 2 * results["validation"]["noise_std"]["swing"]),
    ):
        assert _color(data, entity) == ROLE_COLORS["reference"], entity
        values = np.concatenate(data[entity]["Scalars:scalars"])
        assert values == pytest.approx(value), entity
    # every series is named in the legend with its unit
    for entity, comps in data.items():
        if entity.startswith("/joints/") and "SeriesLines:names" in comps:
            assert comps["SeriesLines:names"][0][0].endswith("]"), entity


def test_run_recording_z_bars_are_named_with_the_two_std_band(run_dir: Path) -> None:
    data = rrd_components(run_dir / "recording.rrd")
    results = json.loads((run_dir / "results.json").read_text())
    params = results["base_parameters"]
    for i, p in enumerate(params):
        entity = f"/parameters/z/{parameter_entity(i, p['name'])}"
        assert entity in data, (entity, sorted(e for e in data if e.startswith("/parameters/z")))
        assert _bar_value(data[entity]) == pytest.approx(p["z"])
        assert rgba(data[entity]["BarChart:color"][0][0])[:3] == ROLE_COLORS["model"]
    band = data["/parameters/z/band_plus_2_std"]
    assert band["BarChart:widths"][0] == [float(len(params))]  # under every bar
    assert _bar_value(band) == 2.0
    assert _bar_value(data["/parameters/z/band_minus_2_std"]) == -2.0
    assert rgba(band["BarChart:color"][0][0])[:3] == ROLE_COLORS["reference"]


def test_run_recording_camera_frames_the_whole_robot_with_mount_and_axes(run_dir: Path) -> None:
    blueprint = rrd_blueprint(run_dir / "recording.rrd")
    view = _views(blueprint)["robot replay (measured motion)"]
    eye = np.array(view["EyeControls3D:position"][0][0])
    target = np.array(view["EyeControls3D:look_target"][0][0])
    assert view["EyeControls3D:eye_up"][0][0] == [0.0, 0.0, 1.0]
    plant = load_plant("pendulum")
    lo, hi = _reach(plant, np.linspace(-1, 1, 21)[:, None] * plant.mj_model.jnt_range[:, 1][None, :])
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    assert np.all(target >= lo - 1e-9) and np.all(target <= hi + 1e-9)  # it looks at the robot
    half_angle = math.degrees(math.atan(radius / float(np.linalg.norm(eye - target))))
    assert 12.0 < half_angle < 30.0, half_angle  # the swept sphere fits in rerun's view and fills most of it
    data = rrd_components(run_dir / "recording.rrd")
    assert "Arrows3D:vectors" in data["/robot/world_axes"]
    assert data["/robot/world_axes"]["Arrows3D:labels"][0] == ["x", "y", "z"]
    assert "Boxes3D:half_sizes" in data["/robot/mount"]
    assert blueprint["/blueprint_panel"]["PanelBlueprint:state"][0] == [2]  # collapsed


@pytest.fixture(scope="module")
def diagnosis_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A pendulum with hidden viscous friction, diagnosed on one training and two validation files in a band,
    its simulation error on 10 of their windows."""
    folder = tmp_path_factory.mktemp("diag")
    _, train, val_a = simulate("pendulum", [HiddenEffect("viscous_friction", "swing", 0.01)], 2, folder)
    _, _, val_b = simulate("pendulum", [HiddenEffect("viscous_friction", "swing", 0.01)], 3, folder)
    paths = [folder / "train.csv", folder / "val_a.csv", folder / "val_b.csv"]
    for data, path in zip((train, val_a, val_b), paths, strict=True):
        write_csv(data, path)
    out = folder / "out"
    cfg = compose_config(
        [
            "system=pendulum",
            f"data.path=[{','.join(str(p) for p in paths)}]",
            "data.validation=[val_a.csv,val_b.csv]",
            "diagnose.band_hz=4",
            f"output_dir={out}",
            "diagnose.references=null",
            "diagnose.max_windows=10",  # fewer than the records hold: the header says which are shown
        ],
        config_name="diagnose",
    )
    diagnose_cli.run(cfg)
    return out


def test_diagnosis_residual_rms_equals_the_table(diagnosis_dir: Path) -> None:
    data = rrd_components(diagnosis_dir / "diagnosis.rrd")
    payload = json.loads((diagnosis_dir / "diagnosis.json").read_text())
    for model in ("nominal", "calibrated"):
        table = payload["models"][model]["torque_rms"]["swing"]
        parts = [
            np.concatenate(comps["Scalars:scalars"])
            for entity, comps in data.items()
            if entity.endswith(f"/joints/swing/residual/{model}") and "Scalars:scalars" in comps
        ]
        assert len(parts) == 2  # both validation records
        residual = np.concatenate(parts)
        assert float(np.sqrt(np.mean(residual**2))) == pytest.approx(table, rel=0.01), model
    assert payload["models"]["calibrated"]["torque_rms"]["swing"] < payload["models"]["nominal"]["torque_rms"]["swing"]


def test_diagnosis_recording_names_every_record_the_band_and_the_criterion(diagnosis_dir: Path) -> None:
    blueprint = rrd_blueprint(diagnosis_dir / "diagnosis.rrd")
    names = {
        c["ContainerBlueprint:display_name"][0][0]
        for p, c in blueprint.items()
        if p.startswith("/container/") and "ContainerBlueprint:display_name" in c
    }
    assert {"val_a.csv", "val_b.csv"} <= names, names
    views = _views(blueprint)
    assert "swing: residual, 0-4 Hz band [N m]" in views
    assert "val_a.csv: measured arm, simulated ghosts" in views
    data = rrd_components(diagnosis_dir / "diagnosis.rrd")
    findings = data["/findings"]["TextDocument:text"][0][0]
    assert "**data set:** csv: train.csv, val_a.csv, val_b.csv" in findings
    assert "**verdict: explained**: at least one effect passed the selection" in findings
    assert "BIC drop > 10" in findings
    windows = json.loads((diagnosis_dir / "diagnosis.json").read_text())["info"]["simulation_windows"]
    assert windows["simulated"] == 10 < windows["of"]
    assert f"(10 of the {windows['of']} windows, spread evenly over the records" in findings
    root = "/validation/0_val_a/joints/swing"
    assert _color(data, f"{root}/tau/measured") == ROLE_COLORS["measured"]
    assert _color(data, f"{root}/tau/nominal") == ROLE_COLORS["nominal"]
    assert _color(data, f"{root}/tau/calibrated") == ROLE_COLORS["model"]
    assert _color(data, f"{root}/q/simulated_calibrated") == ROLE_COLORS["model"]
    # the ghosts of the simulated arms, translucent in their role's colour, moving beside the measured arm
    for ghost, role in (("nominal_ghost", "nominal"), ("calibrated_ghost", "model")):
        geoms = [c for p, c in data.items() if p.startswith(f"/validation/0_val_a/robot/{ghost}/") and "geom" in p]
        assert geoms, ghost
        colour = rgba(_first_colour(geoms[0]))
        assert colour[:3] == ROLE_COLORS[role] and colour[3] < 255
        assert any(
            p.startswith(f"/validation/0_val_a/robot/{ghost}/") and "Transform3D:translation" in c
            for p, c in data.items()
        )


def _first_colour(components: dict[str, list]) -> int:
    key = next(k for k in components if k.endswith(":colors"))
    return int(components[key][0][0])


def test_report_recording_names_bars_by_job_and_draws_thresholds(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    for k, seed in enumerate((0, 1)):
        run(compose_config([*SHORT, "record=none", f"seed={seed}"]), output_dir=sweep / f"{k}_pendulum")
    assert report_main([str(sweep)]) == 0
    data = rrd_components(sweep / "report.rrd")
    for job in ("0_pendulum", "1_pendulum"):
        assert f"/runs/max_abs_z/{job}" in data
        results = json.loads((sweep / job / "results.json").read_text())
        ratio = results["validation"]["torque_rms"]["swing"] / results["validation"]["noise_std"]["swing"]
        assert _bar_value(data[f"/runs/val_rms_over_noise/{job}_swing"]) == pytest.approx(ratio)
    assert _bar_value(data["/runs/max_abs_z/threshold_3"]) == THRESHOLDS["max_abs_z"] == 3.0
    assert _bar_value(data["/runs/val_rms_over_noise/threshold_1.2"]) == THRESHOLDS["val_rms_over_noise"] == 1.2
    blueprint = rrd_blueprint(sweep / "report.rrd")
    assert blueprint["/blueprint_panel"]["PanelBlueprint:state"][0] == [2]
    assert blueprint["/selection_panel"]["PanelBlueprint:state"][0] == [2]
    views = _views(blueprint)
    assert "validation torque RMS / sensor noise std, per joint [1]" in views
    assert "max |z| over base parameters [1]" in views


def _bar_value(components: dict[str, list]) -> float:
    """The one bar's height: the first row's tensor's first value."""
    return float(components["BarChart:values"][0][0]["buffer"][0])

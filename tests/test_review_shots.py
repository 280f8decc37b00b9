"""The recordings in a real browser: rerun's web viewer in headless Chromium (where Chromium is installed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_diagnose import simulate

import harness.diagnose as diagnose_cli
from envs.dataset import write_csv
from envs.effects import HiddenEffect
from harness.record import ROLE_COLORS
from harness.run import run
from tests.conftest import compose_config
from tools.review_shots import chromium_path, read_png, screenshot

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        chromium_path() is None, reason="no Chromium on PATH to render rerun's web viewer (apt-get install chromium)"
    ),
]


def _pixels_near(image: np.ndarray, rgb: tuple[int, int, int], tol: int = 12) -> int:
    return int(np.all(np.abs(image.astype(int) - np.array(rgb)) <= tol, axis=2).sum())


def test_run_recording_renders_in_the_web_viewer(tmp_path: Path) -> None:
    out = tmp_path / "run"
    run(compose_config(["system=pendulum", "system.periods=1", "validation.periods=1"]), output_dir=out)
    shot = screenshot(out / "recording.rrd", tmp_path / "recording.png", wait_s=60.0)
    image = read_png(shot.png)
    assert image.shape[0] > 600 and image.shape[1] > 1200
    # not blank: the viewer drew panels, text and plots (a loading screen is one flat colour with a line of text)
    assert image.reshape(-1, 3).std(axis=0).max() > 20
    assert len(np.unique(image.reshape(-1, 3)[::7], axis=0)) > 500
    # the viewer loaded this recording: its served file is named, and its series are drawn in the role colours
    assert str(out / "recording.rrd") in shot.server_log
    for role in ("model", "reference"):
        assert _pixels_near(image, ROLE_COLORS[role]) > 300, f"no {role} curve in the screenshot {shot.png}"


def test_diagnosis_recording_renders_in_the_web_viewer(tmp_path: Path) -> None:
    folder = tmp_path / "data"
    folder.mkdir()
    _, train, validation = simulate("pendulum", [HiddenEffect("viscous_friction", "swing", 0.01)], 2, folder)
    paths = [folder / "train.csv", folder / "validation.csv"]
    write_csv(train, paths[0])
    write_csv(validation, paths[1])
    out = tmp_path / "diagnosis"
    listed = ",".join(str(p) for p in paths)
    overrides = ["system=pendulum", f"data.path=[{listed}]", f"output_dir={out}", "diagnose.references=null"]
    diagnose_cli.run(compose_config(overrides, config_name="diagnose"))
    shot = screenshot(out / "diagnosis.rrd", tmp_path / "diagnosis.png", wait_s=60.0)
    image = read_png(shot.png)
    assert image.reshape(-1, 3).std(axis=0).max() > 20
    assert str(out / "diagnosis.rrd") in shot.server_log
    for role in ("nominal", "model"):  # the nominal and calibrated curves and ghosts are drawn
        assert _pixels_near(image, ROLE_COLORS[role]) > 300, f"no {role} colour in the screenshot {shot.png}"

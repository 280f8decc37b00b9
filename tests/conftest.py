"""Shared fixtures: composing the Hydra config as `sysid-run` does, and the shared data folder."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

from harness.setup import CONF_DIR

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def compose_config(
    overrides: list[str] | None = None, config_name: str = "config", *, config_dir: Path | None = None
) -> DictConfig:
    """The config `sysid-run` would see with these command-line overrides (and a user's config folder)."""
    extra = [f"hydra.searchpath=[file://{Path(config_dir).resolve()}]"] if config_dir is not None else []
    with initialize_config_dir(str(CONF_DIR), version_base=None):
        return compose(config_name, overrides=[*(overrides or []), *extra])


@pytest.fixture
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data folder {SHARED_DATA} is absent (the project was cloned without ../shared)")
    return SHARED_DATA


def rrd_rows(path: Path) -> dict[str, int]:
    """Entity path -> number of rows logged, read back from an .rrd file with rerun's own reader."""
    from rerun.chunk import RrdReader

    rows: dict[str, int] = {}
    for chunk in RrdReader(str(path)).store().stream().to_chunks():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    return rows


def rrd_has_blueprint(path: Path) -> bool:
    from rerun.chunk import RrdReader

    return bool(RrdReader(str(path)).blueprints())

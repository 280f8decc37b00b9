"""Shared fixtures: composing the Hydra config as `sysid-run` does, and the shared data folder."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

from harness.setup import CONF_DIR

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
SHARED_ROBOTS = SHARED_DATA.parent / "robots"  # Menagerie arms without meshes


def compose_config(
    overrides: list[str] | None = None, config_name: str = "config", *, config_dir: Path | None = None
) -> DictConfig:
    """The config `sysid-run` would see with these command-line overrides (and a user's config folder)."""
    extra = [f"hydra.searchpath=[file://{Path(config_dir).resolve()}]"] if config_dir is not None else []
    with initialize_config_dir(str(CONF_DIR), version_base=None):
        return compose(config_name, overrides=[*(overrides or []), *extra])


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The long tests (marked `slow`) run first: under `pytest -n 2` the 3 M-row diagnosis (2.4 min), collected
    near the end, ran alone on one core while the other sat idle."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


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


def _components(store) -> dict[str, dict[str, list]]:  # type: ignore[no-untyped-def]
    """Entity path -> component -> every value logged (in chunk order), for one store of an .rrd."""
    out: dict[str, dict[str, list]] = {}
    for chunk in store.stream().to_chunks():
        batch = chunk.to_record_batch()
        entity = out.setdefault(chunk.entity_path, {})
        for field in batch.schema:
            if field.metadata and field.metadata.get(b"rerun:kind") == b"data":
                entity.setdefault(field.name, []).extend(batch.column(field.name).to_pylist())
    return out


def rrd_components(path: Path) -> dict[str, dict[str, list]]:
    """The recording's logged data: entity path -> component (`Scalars:scalars`, `SeriesLines:colors`, ...)
    -> the values of every row."""
    from rerun.chunk import RrdReader

    return _components(RrdReader(str(path)).store())


def rrd_blueprint(path: Path) -> dict[str, dict[str, list]]:
    """The recording's blueprint as entity path (`/view/<id>`, `/container/<id>`, `/blueprint_panel`, ...) ->
    component (`ViewBlueprint:display_name`, `EyeControls3D:position`, ...) -> values."""
    from rerun.chunk import RrdReader

    reader = RrdReader(str(path))
    return _components(reader.store(store=reader.blueprints()[0]))


def rgba(packed: int) -> tuple[int, int, int, int]:
    """rerun's packed 0xRRGGBBAA colour as (r, g, b, a)."""
    return ((packed >> 24) & 255, (packed >> 16) & 255, (packed >> 8) & 255, packed & 255)

"""Every config composes, and each choice in it names something the code knows."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from dynamics.plant import load_plant
from excitation.registry import EXCITATIONS
from harness.setup import CONF_DIR
from identify.estimators import ESTIMATORS
from tests.conftest import compose_config

REPO = Path(__file__).resolve().parents[1]


def _options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))


@pytest.mark.parametrize("system", [s for s in _options("system") if s != "auto"])
def test_every_system_config_composes_and_loads(system: str) -> None:
    cfg = compose_config([f"system={system}"])
    plant = load_plant(cfg.system.mjcf)
    assert cfg.system.name == plant.name
    assert len(cfg.system.sensor.sigma_tau) == plant.nv


@pytest.mark.parametrize("group", ["estimator", "excitation", "noise", "record"])
def test_every_option_of_a_group_composes_and_passes_the_checks(group: str) -> None:
    """Each shipped option is accepted by the checks `sysid-run` makes before it runs (`estimator=ols`, whose
    `options: {}` is an empty mapping, was refused as not being one)."""
    from harness.validate import validate_run_config

    known = {"estimator": ESTIMATORS, "excitation": EXCITATIONS}.get(group)
    for option in _options(group):
        cfg = compose_config([f"{group}={option}"])
        if known is not None:
            assert cfg[group].name in known, (group, option)
        validate_run_config(cfg)


def test_slurm_launcher_config_composes() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "harness.run", "hydra/launcher=slurm", "hydra.launcher.partition=cpu", "--cfg", "hydra"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "SlurmLauncher" in proc.stdout and "partition: cpu" in proc.stdout


def test_a_robots_torque_resolution_is_its_smallest_torque_scale_over_2_to_the_11(tmp_path: Path) -> None:
    """It was never above 1/2048 N m: the minimum took 1 N m as one of the scales."""
    from omegaconf import OmegaConf

    from dynamics.plant import plant_from_xml
    from harness.defaults import resolve_system, torque_scale

    xml = """<mujoco model="gantry"><compiler angle="radian"/><worldbody><body name="a"><joint name="x" type="slide"
      axis="1 0 0" range="-0.5 0.5"/><geom type="box" size="0.05 0.05 0.05" mass="2"/><body name="b">
      <joint name="r" axis="0 0 1" range="-2 2"/><geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02" mass="0.5"/>
      </body></body></worldbody><actuator><motor joint="x" ctrlrange="-20 20"/><motor joint="r" ctrlrange="-5 5"/>
      </actuator></mujoco>"""
    plant = plant_from_xml(xml, "gantry", tmp_path)
    auto = OmegaConf.load(CONF_DIR / "system" / "auto.yaml")
    system, assumed = resolve_system(auto, plant)
    assert list(torque_scale(plant)) == [20.0, 5.0]
    assert system.sensor.tau_resolution == assumed["sensor.tau_resolution"] == pytest.approx(5.0 / 2**11, rel=1e-3)

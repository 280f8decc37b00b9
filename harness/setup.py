"""One place that turns a config into objects: sensors, limits, the experiment, designs and their simulation.

`sysid-run`, `sysid-diagnose`, the benchmarks and the tests build what a config describes through these
functions instead of rebuilding it by hand.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import DictConfig, OmegaConf, open_dict
from omegaconf.errors import OmegaConfBaseException

from dynamics.base import BaseParameters, base_parameters
from dynamics.errors import InfeasibleExcitationError, ModelError
from dynamics.plant import SYSTEMS, Plant, load_plant
from dynamics.regressor import ParameterModel
from envs.dataset import Dataset
from envs.sensors import SensorModel
from envs.simulate import simulate_open_loop, simulate_tracking
from excitation.fourier import FourierDesign
from excitation.limits import Limits, limits_for
from excitation.registry import design_excitation
from harness.defaults import resolve_system
from harness.progress import Progress
from harness.validate import ConfigError, check_system_name

__all__ = [
    "CONF_DIR",
    "Experiment",
    "design_from_config",
    "experiment_from_config",
    "limits_from_config",
    "sensor_from_config",
    "simulate_design",
    "with_auto_system",
    "with_model_defaults",
]

# absolute, so that the entry points find the configs wherever they are called from
CONF_DIR = Path(__file__).resolve().parent.parent / "conf"


def _plain(value: Any) -> float | list[float]:
    """A config scalar or list as plain Python floats."""
    return [float(v) for v in value] if OmegaConf.is_list(value) else float(value)


def with_auto_system(overrides: Sequence[str]) -> list[str]:
    """The command line's overrides with `system=auto` put first where they name a robot by path.

    `system.mjcf=<path>` without a `system=` choice names a robot with no system config of its own: its system
    node is `conf/system/auto.yaml` (every null taken from the model, `harness.defaults`), so that every key of
    that file can be overridden on the same line (`system.limits.clearance_m=0.05`). A built-in system's name
    (`system.mjcf=two_link`), or a sweep over them only, keeps the default system config.
    """
    out = list(overrides)
    keys = {o.split("=", 1)[0].lstrip("+~") for o in out if "=" in o}
    mjcf = [o.split("=", 1)[1] for o in out if o.split("=", 1)[0].lstrip("+~") == "system.mjcf" and "=" in o]
    if not mjcf or "system" in keys or all(v in SYSTEMS for v in mjcf[-1].split(",")):
        return out
    return ["system=auto", *out]


def _config_folders() -> list[Path]:
    """The folders configs are read from: Hydra's file search path (with --config-dir), else conf/."""
    from hydra.core.hydra_config import HydraConfig

    if HydraConfig.initialized():
        sources = HydraConfig.get().runtime.config_sources
        return [Path(s.path) for s in sources if s.schema == "file"]
    return [CONF_DIR]


def as_strings(raw: Any) -> list[str]:
    """A config value that is one item or a list of them, as a list of strings."""
    return [str(p) for p in (list(raw) if OmegaConf.is_list(raw) or isinstance(raw, list) else [raw])]


def own_config_folder(group: str, name: str, key: str, value: Any) -> Path | None:
    """The folder of the config file `<group>/<name>.yaml` that Hydra reads (the first on the search path), where
    its own `key` is `value` (the value in use, unresolved or resolved): there a relative path in it is relative
    to. None where the value is not that file's (given on the command line, to the current directory) or there
    is no such file."""
    for folder in _config_folders():
        candidate = folder / group / f"{name}.yaml"
        if not candidate.is_file():
            continue
        loaded = OmegaConf.load(candidate)
        raw = OmegaConf.to_container(loaded, resolve=False).get(key)  # type: ignore[union-attr]
        try:  # an interpolation within the file (an environment variable) resolves; one to another group does not
            own = OmegaConf.select(loaded, key)
            own = OmegaConf.to_container(own, resolve=True) if OmegaConf.is_config(own) else own
        except OmegaConfBaseException:
            own = raw
        mine = value
        if OmegaConf.is_config(value):
            mine = OmegaConf.to_container(value, resolve=False)
        matches = own not in (None, "???") and (
            as_strings(own) == as_strings(value) or as_strings(raw) == as_strings(mine)
        )
        return candidate.parent if matches else None
    return None


def _system_choice(cfg: DictConfig) -> str | None:
    """The system config chosen (Hydra's choice of the group, else the system's own name)."""
    from hydra.core.hydra_config import HydraConfig

    if HydraConfig.initialized():
        choice = HydraConfig.get().runtime.choices.get("system")
        if choice:
            return str(choice)
    name = cfg.system.get("name")
    return str(name) if name else None


def _model_path(value: str, folder: Path | None) -> str:
    """`system.mjcf` as a path or name to load: a relative path written in a system config file is relative to
    that file's `folder` (as a data config's paths are to its own), one given on the command line (`folder`
    None) to the current directory; a built-in system's name stays a name."""
    p = Path(value).expanduser()
    return str(p if p.is_absolute() or not p.suffix or folder is None else (folder / p).resolve())


def load_system(cfg: DictConfig) -> Plant:
    """The plant of `system.mjcf` (`_model_path`), named `system.name` where that is set (on the command line, or
    in a system config beside that config's own model: `system=two_link system.mjcf=other.xml` keeps the
    config's name for its own model, and the model given names itself).

    Raises:
        ConfigError: the value names no model (an unknown system, a missing file or folder, a log): the key named.
        ModelError: the model itself cannot be used (MuJoCo rejects it, unsupported joints, ...).
    """
    if OmegaConf.is_missing(cfg.system, "mjcf"):  # system=auto (a user's config) without its model
        raise ConfigError(
            "system.mjcf is not set: give the robot's model, e.g. system.mjcf=robot.xml (an MJCF, or a URDF), or "
            f"a built-in system such as system=two_link ({', '.join(SYSTEMS)})"
        )
    name = cfg.system.get("name")
    if name is not None:
        check_system_name(str(name))
    choice = _system_choice(cfg)
    folder = own_config_folder("system", choice, "mjcf", cfg.system.mjcf) if choice is not None else None
    if name is not None and choice is not None and folder is None:  # the model is not the config's own
        if own_config_folder("system", choice, "name", name) is not None:  # ... and the name is the config's
            name = None
    path = _model_path(str(cfg.system.mjcf), folder)
    try:
        plant = load_plant(path)
    except ModelError:
        raise
    except ValueError as err:  # mjcf_path: what the value names is no model file
        where = f" (relative to {Path.cwd()})" if Path(path).suffix and not Path(path).is_absolute() else ""
        raise ConfigError(f"system.mjcf: {err}{where}") from None
    return plant if name is None or str(name) == plant.name else dataclasses.replace(plant, name=str(name))


def with_model_defaults(cfg: DictConfig, plant: Plant) -> DictConfig:
    """`cfg` with every null of its system node filled from the model; prints what it assumed."""
    system, assumed = resolve_system(cfg.system, plant)
    renamed = system.get("name") != plant.name  # a built-in config's own name, for another model given instead
    if renamed:
        system.name = plant.name
    if not assumed and not renamed:
        return cfg
    if assumed:
        print(f"system settings taken from the model {plant.source or plant.path} (set any to override it):")
        for key, value in assumed.items():
            print(f"  system.{key}={value}")
        print("and what the model itself bounds (edit the model to change it):")
        for line in model_limits(plant):
            print(f"  {line}")
    out = cfg.copy()
    with open_dict(out):
        out.system = system
    return out


def model_limits(plant: Plant) -> list[str]:
    """What the model itself bounds (no config key: edit the model to change them), one line each: the joint
    ranges (with a limit's margin, inside which MuJoCo's limit force acts) and the actuators' torque limits."""
    margin = plant.mj_model.jnt_margin

    def joint_range(j: int) -> str:
        lo, hi = plant.q_range[j]
        if not (np.isfinite(lo) and np.isfinite(hi)):
            return f"{plant.joint_names[j]} unlimited"
        extra = f" (margin {margin[j]:.4g})" if margin[j] else ""
        return f"{plant.joint_names[j]} [{lo:.4g}, {hi:.4g}] {plant.position_units[j]}{extra}"

    def torque(j: int) -> str:
        if not plant.actuated[j]:
            return f"{plant.joint_names[j]} unactuated"
        limit = float(plant.tau_limit[j])
        value = f"{limit:.4g} {plant.torque_units[j]}" if np.isfinite(limit) else "unlimited"
        return f"{plant.joint_names[j]} {value}"

    return [
        "joint ranges (the model's): " + ", ".join(joint_range(j) for j in range(plant.nv)),
        "torque limits (the model's): " + ", ".join(torque(j) for j in range(plant.nv)),
    ]


def limits_from_config(system: DictConfig, plant: Plant) -> Limits:
    """The limits of a system config (its `limits` node) for `plant`."""
    lim = system.limits
    return limits_for(
        plant,
        velocity=_plain(lim.velocity),
        acceleration=_plain(lim.acceleration),
        range_margin=float(lim.range_margin),
        torque_margin=float(lim.torque_margin),
        clearance_m=None if lim.get("clearance_m") is None else float(lim.clearance_m),
    )


def sensor_from_config(cfg: DictConfig, plant: Plant) -> SensorModel:
    """The sensor model of a system config scaled by the noise config."""
    sigma_tau = np.broadcast_to(np.asarray(cfg.system.sensor.sigma_tau, dtype=float), (plant.nv,))
    return SensorModel(
        sample_rate_hz=float(cfg.system.sensor.sample_rate_hz),
        sigma_q=float(cfg.noise.sigma_q),
        q_resolution=float(cfg.noise.q_resolution),
        sigma_tau=sigma_tau * float(cfg.noise.tau_scale),
        tau_resolution=float(cfg.system.sensor.tau_resolution) * float(cfg.noise.tau_scale),
    )


def simulate_design(
    plant: Plant,
    design: FourierDesign,
    cfg: DictConfig,
    sensor: SensorModel,
    rng: np.random.Generator,
    periods: float,
    *,
    nominal: Plant | None = None,
) -> Dataset:
    """Simulate `periods` periods of a design: tracked (position design) or applied open loop (torque design).

    `nominal` is the model the tracking controller's feedforward and gains come from (None: `plant`).
    """
    duration = periods * design.period_s
    if cfg.system.torque_driven:
        return simulate_open_loop(plant, design.torque, duration_s=duration, sensor=sensor, rng=rng)
    return simulate_tracking(
        plant,
        design,
        duration_s=duration,
        sensor=sensor,
        rng=rng,
        nominal=nominal,
        bandwidth_hz=float(cfg.system.controller.bandwidth_hz),
        hard_friction=bool(cfg.system.get("hard_friction", False)),
        servo_feedforward=bool(OmegaConf.select(cfg, "system.controller.servo_feedforward", default=True)),
    )


@dataclass(frozen=True)
class Experiment:
    """What a system config sets up: the plant, its limits, the parameters to identify and the sensors."""

    plant: Plant
    limits: Limits
    model: ParameterModel
    base: BaseParameters
    sensor: SensorModel


def experiment_from_config(cfg: DictConfig, rng: np.random.Generator, *, plant: Plant | None = None) -> Experiment:
    """The plant, limits, parameter model (with its base parameters, found with `rng`) and sensor of `cfg`."""
    plant = plant or load_system(cfg)
    limits = limits_from_config(cfg.system, plant)
    model = ParameterModel(plant, tuple(cfg.system.effects))
    return Experiment(plant, limits, model, base_parameters(model, rng), sensor_from_config(cfg, plant))


def design_from_config(
    cfg: DictConfig, exp: Experiment, name: str, rng: np.random.Generator, *, progress: Progress | None = None
) -> FourierDesign:
    """The excitation `name` for the experiment; the config's options apply to the configured design only."""
    options = OmegaConf.to_container(cfg.excitation.options, resolve=True) if name == cfg.excitation.name else {}
    try:
        return design_excitation(
            name,
            exp.plant,
            exp.limits,
            model=exp.model,
            harmonics=int(cfg.excitation.harmonics),
            base_freq_hz=float(cfg.system.base_freq_hz),
            torque_driven=bool(cfg.system.torque_driven),
            rng=rng,
            progress=progress,
            **options,  # type: ignore[arg-type]
        )
    except InfeasibleExcitationError as err:
        if err.bound not in LIMIT_SETTINGS:
            raise
        raise InfeasibleExcitationError(
            f"{err}; that bound comes from {LIMIT_SETTINGS[err.bound]}; relax it, or lower system.base_freq_hz "
            "(the same motion, slower)",
            bound=err.bound,
        ) from err


# the setting behind each kind of bound that `limits_from_config` builds
LIMIT_SETTINGS = {
    "q": "the model's joint ranges (and position servos' ctrlrange) less system.limits.range_margin",
    "dq": "system.limits.velocity (and velocity servos' ctrlrange)",
    "ddq": "system.limits.acceleration",
    "tau": "the actuators' force limits times system.limits.torque_margin",
    "clearance": "system.limits.clearance_m",
}

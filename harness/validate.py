"""Config checks made before any computation: every value's type and range, joint counts against the model.

A mistake in a config is found here, named by its key (`excitation.harmonics`, `system.sensor.sigma_tau`),
and reported as one `ConfigError` line before the first second of work; the entry points turn it into
exit status 2. `check_group_overrides` does the same for a config-group value typed wrong on the command
line (`system=tow_link`, also inside a sweep), before Hydra composes anything.
"""

from __future__ import annotations

import inspect
import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import mujoco
from omegaconf import DictConfig, ListConfig, OmegaConf

from dynamics.plant import Plant

__all__ = [
    "MAX_HARMONICS",
    "ConfigError",
    "check_command_line",
    "check_driven",
    "check_group_overrides",
    "check_system",
    "flag_set_by",
    "validate_diagnose_config",
    "validate_run_config",
]

# The largest Fourier design supported: it has 2 * harmonics * nv coefficients and SLSQP's cost grows with
# their cube; 1000 harmonics used 10.5 GB without progress in 6 minutes. The sampling rule in
# `_check_harmonics` usually binds first.
MAX_HARMONICS = 50


class ConfigError(ValueError):
    """A config value of the wrong type, out of range, or inconsistent with the model; names the key."""


def _value(cfg: DictConfig, key: str) -> Any:
    if _missing(cfg, key):
        raise ConfigError(f"{key} is not set (it is mandatory): give it on the command line, e.g. {key}=...")
    try:
        return OmegaConf.select(cfg, key, throw_on_missing=True)
    except Exception as err:  # interpolation or resolution errors: name the key
        raise ConfigError(f"{key}: cannot be resolved: {err}") from None


def _missing(cfg: DictConfig, key: str) -> bool:
    parent, _, leaf = key.rpartition(".")
    node = OmegaConf.select(cfg, parent) if parent else cfg
    try:
        return isinstance(node, DictConfig) and OmegaConf.is_missing(node, leaf)
    except Exception:  # no such key
        return False


def _number(
    cfg: DictConfig,
    key: str,
    *,
    integer: bool = False,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    optional: bool = False,
) -> float | None:
    """The value at `key` as a number within [low, high] (`low_open`: (low, ...; `high_open`: ..., high));
    names the key if not."""
    raw = _value(cfg, key)
    if raw is None and optional:
        return None
    kind = "an integer" if integer else "a number"
    if isinstance(raw, bool) or not isinstance(raw, int | float) or (integer and not isinstance(raw, int)):
        raise ConfigError(f"{key} must be {kind}, got {raw!r}")
    value = float(raw)
    if not math.isfinite(value):
        raise ConfigError(f"{key} must be a finite number, got {raw!r}")
    if low is not None and (value < low or (low_open and value == low)):
        raise ConfigError(f"{key} must be {'>' if low_open else '>='} {low:g}, got {raw!r}")
    if high is not None and (value > high or (high_open and value == high)):
        raise ConfigError(f"{key} must be {'<' if high_open else '<='} {high:g}, got {raw!r}")
    return value


def _flag(cfg: DictConfig, key: str) -> None:
    raw = _value(cfg, key)
    if not isinstance(raw, bool):
        raise ConfigError(f"{key} must be true or false, got {raw!r}")


def _choice(cfg: DictConfig, key: str, valid: Sequence[str]) -> str:
    raw = _value(cfg, key)
    if raw not in valid:
        label = key.removesuffix(".name")
        where = "" if label == key else f" (set by {key})"
        raise ConfigError(f"unknown {label} {raw!r}; valid choices: {', '.join(sorted(valid))}{where}")
    return str(raw)


def _per_joint(cfg: DictConfig, key: str, plant: Plant, *, low: float, low_open: bool) -> None:
    """A scalar, or one value per joint of `plant`, each within range (null: left to the model)."""
    raw = _value(cfg, key)
    if raw is None:
        return
    values = list(raw) if isinstance(raw, ListConfig) else [raw]
    if isinstance(raw, ListConfig) and len(values) != plant.nv:
        raise ConfigError(
            f"{key} has {len(values)} value(s) but {plant.name} has {plant.nv} joint(s) "
            f"({', '.join(plant.joint_names)}): give one value per joint, or a single number (0.02, not [0.02]) for all"
        )
    for i, v in enumerate(values):
        where = f"{key}[{i}] ({plant.joint_names[i]})" if isinstance(raw, ListConfig) else key
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(float(v)):
            raise ConfigError(f"{where} must be a finite number, got {v!r}")
        if float(v) < low or (low_open and float(v) == low):
            raise ConfigError(f"{where} must be {'>' if low_open else '>='} {low:g}, got {v!r}")


def check_system(cfg: DictConfig, plant: Plant) -> None:
    """The `system` group's values against the model: per-joint lists have one value per joint."""
    _per_joint(cfg, "system.limits.velocity", plant, low=0.0, low_open=True)
    _per_joint(cfg, "system.limits.acceleration", plant, low=0.0, low_open=True)
    _per_joint(cfg, "system.sensor.sigma_tau", plant, low=0.0, low_open=False)
    effects = _value(cfg, "system.effects")
    if not isinstance(effects, ListConfig):
        raise ConfigError(f"system.effects must be a list of effect names, got {effects!r}")
    unlimited = [a for a in plant.actuation.actuators if not math.isfinite(a.torque_limit)]
    if unlimited and _value(cfg, "system.torque_driven") is True:
        a = unlimited[0]  # an open-loop torque design is sized by the torque limits; tracking needs none
        raise ConfigError(
            f"{plant.path}: actuator {a.name!r} on joint {plant.joint_names[a.joint]!r} has no torque limit (no "
            "ctrlrange, forcerange or actuatorfrcrange), and system.torque_driven=true (the model has unactuated "
            "joints) excites it by open-loop torque, whose size that limit sets: give it a ctrlrange ('-5 5')"
        )


def _check_estimator(cfg: DictConfig) -> None:
    from identify.estimators import ESTIMATORS, OPTION_RANGES

    name = _choice(cfg, "estimator.name", list(ESTIMATORS))
    options = _value(cfg, "estimator.options")
    if options is None:
        return  # none given: the estimator's own defaults
    if not isinstance(options, DictConfig):  # an empty mapping (`options: {}`, ols) is one too
        raise ConfigError(f"estimator.options must be a mapping of option names to values, got {options!r}")
    params = list(inspect.signature(ESTIMATORS[name]).parameters.values())[1:]
    accepted = {p.name: p for p in params if p.kind == inspect.Parameter.KEYWORD_ONLY}
    for key in (str(k) for k in options):
        if key not in accepted:
            valid = ", ".join(sorted(accepted)) or "none"
            raise ConfigError(
                f"estimator.options.{key} is not an option of estimator {name!r} (options: {valid}); "
                f"options of another estimator left over? use estimator={name} to take its own defaults"
            )
        default = accepted[key].default
        value = options[key]
        if isinstance(default, bool) and not isinstance(value, bool):
            raise ConfigError(f"estimator.options.{key} must be true or false, got {value!r}")
        if isinstance(default, int | float) and not isinstance(default, bool):
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ConfigError(f"estimator.options.{key} must be a number, got {value!r}")
            if isinstance(default, int) and not isinstance(value, int):
                raise ConfigError(f"estimator.options.{key} must be an integer, got {value!r}")
        domain = OPTION_RANGES.get(name, {}).get(key)
        if domain is None or (value is None and default is None):
            continue
        if isinstance(value, bool) or not isinstance(value, int | float) or not domain.contains(float(value)):
            raise ConfigError(
                f"estimator.options.{key} of estimator {name!r} must be {domain.describe()}"
                f"{' (or null)' if default is None else ''}, got {value!r}"
            )


MAX_RECORD_ROWS = 2_000_000  # samples in one simulated record (a 7-DoF regressor of 2e6 rows is ~8 GB)


def _check_harmonics(cfg: DictConfig) -> None:
    """1 <= harmonics <= MAX_HARMONICS, and the top harmonic slow enough for the sampling: the derivative filter
    cuts at 10 x the top harmonic, which must stay below the Nyquist frequency."""
    h = int(_number(cfg, "excitation.harmonics", integer=True, low=1) or 0)
    f0 = float(_number(cfg, "system.base_freq_hz", low=0.0, low_open=True) or 0.0)
    fs = float(_number(cfg, "system.sensor.sample_rate_hz", low=0.0, low_open=True) or 0.0)
    by_sampling = int(fs / 2.0 / (10.0 * f0))
    if by_sampling < 1:
        raise ConfigError(
            f"system.base_freq_hz must be <= {fs / 20.0:g} at system.sensor.sample_rate_hz={fs:g}, got {f0:g}: "
            f"the derivative filter cuts at 10 x the top harmonic, which must stay below the Nyquist frequency "
            f"{fs / 2:g} Hz"
        )
    limit = min(MAX_HARMONICS, by_sampling)
    if h > limit:
        why = (
            f"the design would have {2 * h} coefficients per joint; at most {MAX_HARMONICS} harmonics are supported"
            if limit == MAX_HARMONICS
            else f"at {f0:g} Hz the top harmonic needs a derivative cut-off of {10 * h * f0:g} Hz, above the "
            f"Nyquist frequency {fs / 2:g} Hz of system.sensor.sample_rate_hz"
        )
        raise ConfigError(f"excitation.harmonics must be between 1 and {limit}, got {h}: {why}")


def _check_differences_cutoff(cfg: DictConfig, cutoff: float | None, fs: float) -> None:
    """Refuse a cut-off above an eighth of the rate where the states are differences: identify.cutoff_hz with
    `butterworth`, and the IV estimator's reference_cutoff_hz where it has no period (it then filters)."""
    from identify.derivatives import differences_cutoff_problem

    checked = [("identify.cutoff_hz", cutoff, OmegaConf.select(cfg, "identify.derivatives") == "butterworth")]
    if OmegaConf.select(cfg, "estimator.name") == "iv":
        reference = OmegaConf.select(cfg, "estimator.options.reference_cutoff_hz")
        by_differences = OmegaConf.select(cfg, "estimator.options.period_s") is None
        checked.append(("estimator.options.reference_cutoff_hz", reference, by_differences))
    for key, value, differences in checked:
        if value is None or not differences:
            continue
        problem = differences_cutoff_problem(float(value), fs, f"system.sensor.sample_rate_hz={fs:g}")
        if problem:
            raise ConfigError(
                f"{key}={problem}; lower it"
                + (" (or set identify.derivatives=spectral or kalman)" if key == "identify.cutoff_hz" else "")
            )


def check_driven(plant: Plant) -> None:
    """Refuse, for a simulated run, a model none of whose joints an actuator drives (nothing could excite it), or
    with an actuator that gives torque of one sign only (a ctrlrange "0 20", a zero gain).

    Raises:
        ConfigError: naming the model (and the actuator) and how to fix it.
    """
    for a in plant.actuation.actuators:  # before the count of driven joints, which a gear 0 leaves out
        if a.gear == 0:
            raise ConfigError(
                f"{plant.path}: actuator {a.name!r} on joint {plant.joint_names[a.joint]!r} has gear 0: it applies no "
                "torque to the joint, so nothing can excite it: give it a non-zero gear (1 for a direct drive)"
            )
    if not any(bool(a) for a in plant.actuated):
        first = plant.joint_names[0]
        unnamed = mujoco.mj_id2name(plant.mj_model, mujoco.mjtObj.mjOBJ_JOINT, 0) is None  # the harness's name for it
        raise ConfigError(
            f"{plant.path}: no joint of {plant.name} is driven (the model has no <actuator> on its joints), so "
            "nothing can excite it: add a motor per joint, e.g. "
            + (f"name the first joint (<joint name='{first}' ...>) and add " if unnamed else "")
            + f"<actuator><motor joint='{first}' ctrlrange='-5 5'/></actuator>"
        )
    for a in plant.actuation.actuators:
        if a.gain == 0:  # whatever its ranges (none: an infinite limit), its ctrl moves nothing
            raise ConfigError(
                f"{plant.path}: actuator {a.name!r} on joint {plant.joint_names[a.joint]!r} has gain 0 (gainprm): "
                "its control applies no torque, so nothing can excite the joint: give it a non-zero gain"
            )
        if a.torque_limit > 0:
            continue
        ctrl = "unlimited" if a.ctrl_range is None else f"[{a.ctrl_range[0]:g}, {a.ctrl_range[1]:g}]"
        raise ConfigError(
            f"{plant.path}: actuator {a.name!r} can drive joint {plant.joint_names[a.joint]!r} one way only "
            f"(gain {a.gain:g}, gear {a.gear:g}, ctrlrange {ctrl}, its forcerange and the joint's actuatorfrcrange "
            "leave no torque of both signs), but an excitation swings each joint both ways: give it a range "
            "about zero (ctrlrange='-5 5') and a non-zero gain"
        )


def validate_run_config(cfg: DictConfig, plant: Plant | None = None) -> None:
    """Check a `sysid-run` config before any work; `plant` (the system's model) enables the joint-count checks.

    Raises:
        ConfigError: the first wrong value, named by its key.
    """
    from excitation.registry import EXCITATIONS
    from identify.derivatives import DERIVATIVES

    _number(cfg, "seed", integer=True, low=0)
    _flag(cfg, "overwrite")
    _choice(cfg, "excitation.name", list(EXCITATIONS))
    _choice(cfg, "identify.derivatives", list(DERIVATIVES))
    _choice(cfg, "record.kind", ["none", "rerun"])
    _check_estimator(cfg)
    _check_harmonics(cfg)
    _number(cfg, "system.periods", low=0.0, low_open=True)
    _number(cfg, "validation.periods", low=0.0, low_open=True)
    fs = float(_value(cfg, "system.sensor.sample_rate_hz"))
    for key in ("system.periods", "validation.periods"):  # the record's length, before anything is allocated
        rows = float(_value(cfg, key)) / float(_value(cfg, "system.base_freq_hz")) * fs
        if rows > MAX_RECORD_ROWS:
            raise ConfigError(
                f"{key}={_value(cfg, key)} at system.base_freq_hz={_value(cfg, 'system.base_freq_hz')} and "
                f"system.sensor.sample_rate_hz={fs:g} makes a record of {rows:.3g} samples; at most "
                f"{MAX_RECORD_ROWS:.0e} are simulated (memory): lower {key} or the sample rate"
            )
    cutoff = _number(cfg, "identify.cutoff_hz", low=0.0, low_open=True, high=fs / 2.0, high_open=True, optional=True)
    _check_differences_cutoff(cfg, cutoff, fs)
    _number(cfg, "system.limits.range_margin", low=0.0, high=0.49)
    if OmegaConf.select(cfg, "system.limits.clearance_m") is not None:
        _number(cfg, "system.limits.clearance_m", low=0.0)
    _number(cfg, "system.limits.torque_margin", low=0.0, low_open=True, high=1.0)
    _number(cfg, "system.sensor.tau_resolution", low=0.0)
    _number(cfg, "system.controller.bandwidth_hz", low=0.0, low_open=True, high=fs / 2.0, high_open=True)
    _number(cfg, "noise.sigma_q", low=0.0)
    _number(cfg, "noise.q_resolution", low=0.0)
    _number(cfg, "noise.tau_scale", low=0.0)
    _flag(cfg, "system.torque_driven")
    if OmegaConf.select(cfg, "system.controller.servo_feedforward") is not None:
        _flag(cfg, "system.controller.servo_feedforward")
    options = _value(cfg, "excitation.options")
    if options is not None and not isinstance(options, DictConfig):
        raise ConfigError(f"excitation.options must be a mapping, got {options!r}")
    if plant is not None:
        check_system(cfg, plant)


# derivative methods for measured records: `spectral` keeps an excitation's harmonics (it needs whole periods of a
# known one), `simulator` reads the simulator's own accelerations and `given` a record's own dq and ddq: a log in
# the measured-data format holds no accelerations
MEASURED_DERIVATIVES = ("butterworth", "kalman")


def validate_diagnose_config(cfg: DictConfig) -> None:
    """Check a `sysid-diagnose` config before any file is read.

    Raises:
        ConfigError: the first wrong value, named by its key.
    """
    if _missing(cfg, "data.path"):
        raise ConfigError(
            "data.path is not set: give the CSV file(s) to diagnose, e.g. data.path=run.csv or "
            "data.path='[a.csv,b.csv]', or a data config such as data=dfki_double_pendulum"
        )
    raw = _value(cfg, "data.path")
    items = list(raw) if isinstance(raw, ListConfig) else [raw]
    if not items or any(not isinstance(p, str) or not p.strip() for p in items):
        raise ConfigError(f"data.path must be a file path or a list of them, got {raw!r}")
    _number(cfg, "seed", integer=True, low=0)
    _flag(cfg, "overwrite")
    for group in ("data", "diagnose"):  # `diagnose=foo` replaces the whole mapping: every key below reads None
        node = OmegaConf.select(cfg, group)
        if not isinstance(node, DictConfig):
            raise ConfigError(
                f"{group} must be a mapping of settings (e.g. {group}.<key>=...), got {node!r}; set its keys one by one"
            )
    validation = OmegaConf.select(cfg, "data.validation")
    names = list(validation) if isinstance(validation, ListConfig) else [validation]
    if validation is not None and (not names or any(not _file_name(v) for v in names)):
        raise ConfigError(
            "data.validation must name the held-out file(s) (data.validation=b.csv or '[b.csv,c.csv]'), or be null "
            f"to hold out the last files (data.validation_fraction of them), got {validation!r}"
        )
    twice = sorted({str(v) for v in names if names.count(v) > 1}) if validation is not None else []
    if twice:
        raise ConfigError(f"data.validation names {twice[0]!r} more than once; name each held-out file once")
    columns = OmegaConf.select(cfg, "data.columns")
    if columns is not None and not isinstance(columns, DictConfig):
        raise ConfigError(
            f"data.columns must map the harness's names to the file's columns (e.g. {{q_shoulder: pos1}}) or be "
            f"null, got {columns!r}"
        )
    _number(cfg, "diagnose.cutoff_hz", low=0.0, low_open=True, optional=True)
    _number(cfg, "diagnose.band_hz", low=0.0, low_open=True, optional=True)
    _number(cfg, "data.band_hz", low=0.0, low_open=True, optional=True)
    _number(cfg, "data.cutoff_hz", low=0.0, low_open=True, optional=True)
    _number(cfg, "data.tau_lead_s", low=0.0, optional=True)
    _number(cfg, "diagnose.window_s", low=0.0, low_open=True)
    _number(cfg, "diagnose.max_rows", integer=True, low=1000, optional=True)
    _number(cfg, "diagnose.max_windows", integer=True, low=1, optional=True)
    if _value(cfg, "diagnose.derivatives") == "given":  # a choice of derive_states, not of a CSV log
        raise ConfigError(
            "diagnose.derivatives=given reads the states' rates from the data, and a log in the measured-data format "
            "holds no accelerations (its columns: time, q_, dq_, tau_, tau_cmd_): choose "
            f"{' or '.join(MEASURED_DERIVATIVES)}"
        )
    _choice(cfg, "diagnose.derivatives", MEASURED_DERIVATIVES)
    effects = _value(cfg, "diagnose.effects")
    if not isinstance(effects, ListConfig) or not all(isinstance(e, str) for e in effects):
        raise ConfigError(
            f"diagnose.effects must be a list of effect names, e.g. diagnose.effects=[armature,viscous_friction], "
            f"got {effects!r}"
        )
    from identify.diagnose import CANDIDATE_EFFECTS, SelectionOptions  # the core's own names and checks

    unknown_effects = [e for e in effects if e not in CANDIDATE_EFFECTS]
    if unknown_effects:
        valid = ", ".join(sorted(CANDIDATE_EFFECTS))
        raise ConfigError(f"diagnose.effects: unknown effect(s) {unknown_effects}; valid choices: {valid}")
    refs = _value(cfg, "diagnose.references")
    paths = isinstance(refs, ListConfig) and all(isinstance(r, str) for r in refs)
    if not (refs is None or isinstance(refs, str) or paths):
        raise ConfigError(f"diagnose.references must be auto, null, a yml path or a list of them, got {refs!r}")
    selection = _value(cfg, "diagnose.selection")
    if not isinstance(selection, DictConfig):
        raise ConfigError(f"diagnose.selection must be a mapping of the selection's thresholds, got {selection!r}")
    unknown = sorted(set(selection) - set(SelectionOptions.__dataclass_fields__))
    if unknown:
        valid = ", ".join(sorted(SelectionOptions.__dataclass_fields__))
        raise ConfigError(f"diagnose.selection.{unknown[0]} is not a threshold of the selection; valid keys: {valid}")
    try:
        SelectionOptions(**OmegaConf.to_container(selection, resolve=True))  # type: ignore[arg-type]
    except ValueError as err:
        raise ConfigError(f"diagnose.selection.{err}") from None
    _number(cfg, "data.validation_fraction", low=0.0, low_open=True, high=0.9)
    _number(cfg, "data.min_samples", integer=True, low=2)
    _number(cfg, "data.max_speed", low=0.0, low_open=True, optional=True)
    keys = (
        "data.repair",
        "data.resample",
        "diagnose.record_offsets",
        "data.record_offsets",
        "diagnose.record_joint_offsets",
        "data.record_joint_offsets",
        "diagnose.check_torque_signs",
        "diagnose.final_fit",
        "diagnose.recording",
        "system.hard_friction",
    )
    for key in keys:
        if OmegaConf.select(cfg, key) is not None:
            _flag(cfg, key)
    steps = OmegaConf.select(cfg, "diagnose.mujoco_steps")
    if steps is not None and not isinstance(steps, bool):
        raise ConfigError(
            f"diagnose.mujoco_steps must be true, false or null (null: decided from the data), got {steps!r}"
        )
    nuisances = [k for k in (flag_set_by(cfg, "record_offsets"), flag_set_by(cfg, "record_joint_offsets")) if k]
    if len(nuisances) == 2:
        raise ConfigError(
            f"{nuisances[0]} and {nuisances[1]} are both true: a torque zero and an angle zero per file are nearly "
            "the same column on motions about one pose (on C.1's logs they traded -1.1 N m against -0.38 rad); "
            "set the one the sensors call for"
        )


def _file_name(value: Any) -> bool:
    """A file named on the command line: a non-empty string, or a stem that Hydra read as an integer (`01`)."""
    return (isinstance(value, str) and bool(value.strip())) or (isinstance(value, int) and not isinstance(value, bool))


def flag_set_by(cfg: DictConfig, name: str) -> str | None:
    """The key that makes the flag `name` true: `diagnose.<name>` when set (not null), else the data config's
    `data.<name>` (a property of the logs); None where it is false or unset."""
    for where in ("diagnose", "data"):
        value = OmegaConf.select(cfg, f"{where}.{name}")
        if value is not None:
            return f"{where}.{name}" if bool(value) else None
    return None


_OVERRIDE = re.compile(r"^[+~]{0,2}([A-Za-z_][\w/.]*)(@[\w.]+)?=(.*)$")


def _sweep_values(text: str) -> list[str] | None:
    """The plain values of an override (`a`, `a,b`, `choice(a,b)`); None when it is a function or glob."""
    text = text.strip()
    match = re.fullmatch(r"choice\((.*)\)", text)
    if match:
        text = match.group(1)
    if any(ch in text for ch in "()[]{}$*'\"") or not text:
        return None
    return [v.strip() for v in text.split(",") if v.strip()]


def user_config_dirs(argv: Sequence[str]) -> list[Path]:
    """Config folders a command line adds: `--config-dir DIR` (or `-cd DIR`, `--config-dir=DIR`) and
    `hydra.searchpath=[file://DIR, ...]`."""
    out: list[Path] = []
    for i, arg in enumerate(argv):
        if arg in ("--config-dir", "-cd") and i + 1 < len(argv):
            out.append(Path(argv[i + 1]).expanduser())
        elif arg.startswith("--config-dir="):
            out.append(Path(arg.split("=", 1)[1]).expanduser())
        elif arg.startswith("hydra.searchpath="):
            for item in arg.split("=", 1)[1].strip("[]").split(","):
                item = item.strip().strip("'\"")
                if item.startswith("file://"):
                    out.append(Path(item.removeprefix("file://")).expanduser())
    return out


def check_group_overrides(argv: Sequence[str], conf_dir: Path) -> None:
    """Refuse a command-line value of one of our config groups (`system=...`, `estimator=...`) that names no
    config, listing the valid choices, before Hydra composes a config or a sweep starts a job.

    Groups under `hydra/` are left to Hydra (its launchers come from plugins); a value that is a path
    (`system=/abs/robot.yaml`) or a sweep function is left to Hydra too.

    Raises:
        ConfigError: the first unknown group value.
    """
    folders = [conf_dir, *user_config_dirs(argv)]
    groups = {p.name for f in folders if f.is_dir() for p in f.iterdir() if p.is_dir() and p.name != "hydra"}
    for arg in argv:
        match = _OVERRIDE.match(arg)
        if not match or arg.startswith("~"):
            continue
        group = match.group(1)
        if group not in groups:
            continue
        values = _sweep_values(match.group(3))
        if values is None:
            continue
        valid = sorted({p.stem for f in folders for p in (f / group).glob("*.yaml")})
        for value in values:
            sweep = f" (in the sweep {arg})" if len(values) > 1 else ""
            if value == "null":  # Hydra raises a bare ValueError: every group of ours needs a choice
                raise ConfigError(
                    f"{group}=null{sweep}: {group} needs one of its configs; valid choices: {', '.join(valid)}"
                )
            if value not in valid and "/" not in value:
                raise ConfigError(f"unknown {group} {value!r}{sweep}; valid choices: {', '.join(valid)}")


def _first_job(overrides: list[str]) -> list[str]:
    """A sweep's overrides with each sweep (`a,b`, `range(..)`, `choice(..)`) at its first value: what the
    first job composes. The keys are every job's, so an unknown key or a malformed override shows here."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    out = []
    for o in OverridesParser.create().parse_overrides(overrides):
        if o.is_sweep_override():
            first = next(iter(o.sweep_string_iterator()), None)
            out.append(f"{o.get_key_element()}={first}" if first is not None else o.input_line or "")
        else:
            out.append(o.input_line or "")
    return out


# a system's name names output files and Hydra's run folder: no folder separator, not hidden, no control character
_PLAIN_NAME = re.compile(r"[^/\\\x00-\x1f.][^/\\\x00-\x1f]*")


def check_system_name(name: str) -> None:
    """Raises ConfigError where `name` (`system.name`) is not a plain name for output files."""
    if not _PLAIN_NAME.fullmatch(name):
        raise ConfigError(
            f"system.name={name!r}: it names the outputs (<name>_calibrated.xml, the system in the results, the run "
            "folder), so it is a plain name: no '/' or '\\', not beginning with '.'; null takes the model file's"
        )


def check_command_line(argv: Sequence[str], conf_dir: Path, config_name: str) -> None:
    """Everything about a command line that can be checked before Hydra runs it: the config-group values (all
    of a sweep's), and for a single run that the overrides compose (an unknown key, a malformed value), so that
    these mistakes get one line and exit status 2 instead of Hydra's several lines and status 1.

    Raises:
        ConfigError: the first problem found.
    """
    check_group_overrides(argv, conf_dir)
    for a in argv:  # before Hydra makes the run folder it names (outputs/${system.name}/...)
        option, _, given = a.partition("=")
        if option.lstrip("+") == "hydra.launcher.n_jobs" and given.strip().lstrip("-").isdigit() and int(given) == 0:
            raise ConfigError(  # joblib's own error came after Hydra had written the sweep's multirun.yaml
                "hydra.launcher.n_jobs=0: the number of jobs run at once; give 1 or more (-1: one per core)"
            )
        if option.lstrip("+") == "system.name" and given not in ("null", ""):
            for name in given.split(",") if "-m" in argv or "--multirun" in argv else [given]:
                check_system_name(name.strip("'\""))
    overrides = [a for a in argv if a not in ("-m", "--multirun")]
    if any(a.startswith("-") for a in overrides):  # --help, --cfg, --config-dir ...: left to Hydra
        return
    from hydra import compose, initialize_config_dir
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    try:
        if len(overrides) < len(argv):  # a sweep: its first job's overrides stand for all (same keys)
            overrides = _first_job(overrides)
        with initialize_config_dir(str(conf_dir), version_base=None):
            compose(config_name, overrides=overrides, return_hydra_config=True)
            added = [o for o in overrides if o.startswith("+")]  # `+key` and `++key` (adds it where absent)
            if added:  # each new key against the config the other overrides make (or the groups alone)
                try:
                    base = compose(config_name, overrides=[o for o in overrides if o not in added])
                except (HydraException, OmegaConfBaseException):
                    base = compose(config_name, overrides=_group_choices(overrides, conf_dir))
                for o in added:
                    plus = "++" if o.startswith("++") else "+"
                    _check_added_key(base, o[len(plus) :].split("=", 1)[0], plus)
    except ConfigError:
        raise
    except (HydraException, OmegaConfBaseException, ValueError) as err:  # ValueError: Hydra's own, for some values
        lines = [
            ln.strip()
            for ln in str(err).splitlines()
            if ln.strip() and not ln.startswith("See https") and not ln.startswith("To append to your config")
        ]
        cause = err.__cause__
        if isinstance(cause, OmegaConfBaseException):
            lines.append(str(cause).splitlines()[0])
        key = next((o.split("=", 1)[0].lstrip("+~") for o in overrides if f"'{o.split('=', 1)[0]}'" in str(err)), None)
        if key is not None:
            try:
                with initialize_config_dir(str(conf_dir), version_base=None):
                    hint = _close_key(compose(config_name, overrides=_group_choices(overrides, conf_dir)), key)
            except (HydraException, OmegaConfBaseException):  # a group choice that is itself wrong: no hint
                hint = None
            if hint:
                lines.append(f"did you mean {hint}?")
        tilde = next((o for o in overrides if "=" in o and o.split("=", 1)[1].startswith("~")), None)
        if tilde is not None:  # Hydra's grammar reads a bare ~ as an operator; a quoted value is a plain string
            key, value = tilde.split("=", 1)
            lines.append(f"a value that begins with ~ must be quoted: {key}='{value}'")
        second = "mismatched input '='" in str(err)
        equal = next((o for o in overrides if second and "=" in o and "=" in o.split("=", 1)[1].strip("'\"")), None)
        if equal is not None:  # a file name with = in it (run=3.csv): Hydra reads the second = as its own
            key, value = equal.split("=", 1)
            lines.append(f"a value with = in it must be quoted: {key}='{value}'")
        raise ConfigError("; ".join(lines) or type(err).__name__) from None


def _group_choices(overrides: list[str], conf_dir: Path) -> list[str]:
    """The overrides that choose a config group's option (`data=dfki_double_pendulum`, a folder of `conf_dir`):
    the keys a hint can name."""
    return [o for o in overrides if "=" in o and o[0] not in "+~" and (conf_dir / o.split("=", 1)[0]).is_dir()]


# mappings whose keys are the user's own names (a file's columns): a new key there is not a typo of a sibling
_FREE_KEYS = ("data.columns",)
# names people reach for that no spelling distance finds: (the mapping, the name) -> the key that is read
_SYNONYMS = {
    **{("system", k): "mjcf" for k in ("path", "file", "model", "xml", "urdf")},
    **{("data", k): "path" for k in ("file", "files", "csv")},
}


def _close_key(cfg: DictConfig, key: str) -> str | None:
    """The existing key `key` most likely meant: its first part that `cfg` lacks, replaced by the closest
    sibling name (None where no sibling is close, or the part sits in a free mapping)."""
    import difflib

    parts = key.split(".")
    node: Any = cfg
    for i, part in enumerate(parts):
        if not isinstance(node, DictConfig):
            return None
        if part not in node.keys():  # `in node` is False for a value still missing (`???`)
            if ".".join(parts[:i]) in _FREE_KEYS:
                return None
            synonym = _SYNONYMS.get((".".join(parts[:i]), part))
            if synonym is not None and synonym in node.keys():
                return ".".join([*parts[:i], synonym, *parts[i + 1 :]])
            match = difflib.get_close_matches(part, [str(k) for k in node.keys()], n=1, cutoff=0.75)
            return ".".join([*parts[:i], match[0], *parts[i + 1 :]]) if match else None
        if i == len(parts) - 1:
            return None  # it exists (reading it would raise where its value is still missing)
        node = node[part]
    return None


def _check_added_key(cfg: DictConfig, key: str, plus: str = "+") -> None:
    """A `+key=value` (or `++key=value`, which adds the key where it is absent) whose new key is a near-miss of
    an existing one (`+system.limts.velocity`, which Hydra's own error suggests for a misspelled key) would be
    carried along and never read: refused, naming the key. `plus`: the override's prefix, `+` or `++`."""
    hint = _close_key(cfg, key)
    if hint:
        raise ConfigError(
            f"{plus}{key}: no such key is read; did you mean {hint}? ({plus} adds a new key and nothing reads it)"
        )

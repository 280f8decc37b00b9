"""`sysid-diagnose`: the discrepancy analysis of DESIGN.md on measured data.

`run(cfg)` reads the data (`envs.measured`), splits it (by file, or a contiguous time block of one file),
runs `identify.diagnose.diagnose` and writes `diagnosis.json`, `diagnosis.rrd` and `<system>_calibrated.xml`
into the Hydra run directory (or `cfg.output_dir` outside Hydra). With `diagnose.final_fit` (the default) the
diagnosis is run once more on every record, the validation ones included, and writes
`<system>_calibrated_all.xml`: the model for new data of the robot (a fit on more files of a session predicts a
file it never saw better: `bench/diagnose.md`, "More files"); its own figures are in-sample, so the held-out gain
reported stays the training fit's. Nothing is written until the analysis has finished, and a failure while
writing removes what was written: a run directory holds all of its outputs or none.
"""

from __future__ import annotations

import dataclasses
import glob
import json
import re
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, replace
from functools import partial
from pathlib import Path
from typing import Any

import hydra
import numpy as np
from omegaconf import DictConfig, OmegaConf

from dynamics.base import base_parameters
from dynamics.errors import DataError
from dynamics.plant import Plant, as_simulated
from dynamics.regressor import ParameterModel
from envs.dataset import Dataset, atomic_write
from envs.measured import read_many
from envs.split import names_file, split_train_validation
from harness.results import run_job, to_jsonable, write_json
from harness.rundir import RunFolder, RunFolderError, check_output_override, claim, kept_on_failure
from harness.setup import CONF_DIR, as_strings, load_system, own_config_folder, with_auto_system, with_model_defaults
from harness.validate import ConfigError, check_command_line, flag_set_by, validate_diagnose_config
from identify.derivatives import (
    derive_states,
    differences_cutoff_limit_hz,
    differences_cutoff_problem,
    excitation_bandwidth_hz,
    reduce_record,
    reduction_factor,
)
from identify.diagnose import (
    Diagnosis,
    ReferenceModel,
    SelectionOptions,
    author_accel,
    author_torque,
    diagnose,
    find_anomalies,
    load_author_model,
    with_found_lead,
)
from identify.diagnose.anomalies import still_joints
from identify.diagnose.candidates import MAX_DELAY_S
from identify.diagnose.residuals import noise_floor
from identify.diagnose.state_noise import check_full_rate_state_noise
from identify.excitation_check import check_excitation

__all__ = ["CONF_DIR", "data_paths", "main", "record_joint_offsets", "record_offsets", "reference_models", "run"]


def _output_dir(cfg: DictConfig) -> Path:
    if cfg.get("output_dir"):
        return Path(cfg.output_dir)
    from hydra.core.hydra_config import HydraConfig

    return Path(HydraConfig.get().runtime.output_dir)


def reference_models(spec: Any, data_paths: list[Path]) -> dict[str, ReferenceModel]:
    """The authors' identified models to compare with: `auto` (authors_identified/*.yml beside the first data
    file, none if absent), None, a yml path or a list of them."""
    if spec is None:
        return {}
    if spec == "auto":
        folder = data_paths[0].parent / "authors_identified"
        files = sorted(folder.glob("*.yml")) if folder.is_dir() else []
    else:
        files = [Path(p) for p in as_strings(spec)]
    out: dict[str, ReferenceModel] = {}
    for f in files:
        try:
            p = load_author_model(f)
        except DataError as err:
            found = " (found beside the data: diagnose.references=auto)" if spec == "auto" else ""
            raise DataError(f"{err}{found}; diagnose.references=null compares with none") from None
        name = "authors_" + re.sub(r"^design_.*?_model_", "", f.stem)  # design_C.1_model_2.0 -> authors_2.0
        out[name] = ReferenceModel(torque=partial(author_torque, p), accel=partial(author_accel, p))
    return out


def _data_config_folder(cfg: DictConfig) -> Path | None:
    """The folder of the data config file whose own `path` is the one in use (None: given on the command line)."""
    name = cfg.data.get("name")
    return own_config_folder("data", str(name), "path", cfg.data.path) if name else None


def data_paths(cfg: DictConfig) -> list[Path]:
    """The data files; a data config's relative paths are relative to that config's own folder, a path given on
    the command line to the current directory. A pattern (`logs/*.csv`) stands for its files in name order; a
    file that exists under the name as written (`run[1].csv`) is that file, not a pattern."""
    folder = _data_config_folder(cfg)
    out: list[Path] = []
    for item in as_strings(cfg.data.path):
        p = Path(item).expanduser()
        p = p if p.is_absolute() or folder is None else (folder / p).resolve()
        if glob.has_magic(str(p)) and not p.exists():  # a pattern (logs/*.csv): its files, in name order
            found = sorted(Path(f) for f in glob.glob(str(p)) if Path(f).is_file())
            if not found:
                raise DataError(f"{p}: the pattern matches no file")
            out += found
        else:
            out.append(p)
    return out


def _with_torque_lead(datasets: list[Dataset], lead: float) -> list[Dataset]:
    """The records with `data.tau_lead_s` set: the torque logged at row k acted over an interval centred `lead`
    later: half a sample where a controller logs its command at the start of a zero-order hold; a few
    milliseconds where the column is a command the drive applies later (its current loop's lag) or the angles are
    reported later than the torque (a bus's latency).

    Raises:
        ConfigError: a lead above `MAX_DELAY_S` and of a sample or more of some file (no held torque, drive's lag
            or bus's latency: a time column of another clock). Under a sample any lead is a held torque's offset.
    """
    if lead == 0:
        return datasets
    for d in datasets:
        if lead > MAX_DELAY_S and lead >= d.dt:
            raise ConfigError(
                f"data.tau_lead_s={lead:g} s is above {MAX_DELAY_S * 1e3:g} ms and a sample or more ({d.dt:g} s) of "
                f"{d.source}: a held torque's offset (under a sample), a drive's lag behind a commanded torque or "
                "angles reported late are a few ms; a longer offset is a time column of another clock: check the "
                "files' time columns"
            )
    return [dataclasses.replace(d, tau_lead_s=lead) for d in datasets]


SLOW_LOG_HZ = 100.0  # a joint log sampled slower than this may be timed in ms: said where its rate is refused


def _check_filters(cfg: DictConfig, datasets: list[Dataset]) -> None:
    """Refuse a filter frequency at or above the Nyquist frequency of the slowest file, or below
    `MIN_FILTER_CYCLES` cycles over the shortest one, or a re-start window shorter than `MIN_WINDOW_SAMPLES` of its
    samples or longer than the shortest file (known once read). The state cut-off against the differences' limit:
    `_capped_cutoff`."""
    slowest = max(datasets, key=lambda d: d.dt)
    shortest = min(datasets, key=lambda d: float(d.time[-1] - d.time[0]))
    span = float(shortest.time[-1] - shortest.time[0])
    nyquist = 0.5 / slowest.dt
    lowest = MIN_FILTER_CYCLES / span
    for name, value in (state_cutoff(cfg), _setting(cfg, "band_hz") or ("data.band_hz", None)):
        if value is not None and float(value) >= nyquist:
            unit = (  # a log timed in ms (a few kHz) reads as a few Hz
                f"; or check that its time column is in seconds (timed in milliseconds, it would be sampled at "
                f"{2e3 * nyquist:g} Hz)"
                if 2 * nyquist < SLOW_LOG_HZ
                else ""
            )
            raise ConfigError(
                f"{name}={float(value):g} Hz is not below the Nyquist frequency {nyquist:g} Hz of "
                f"{slowest.source} (sampled at {2 * nyquist:g} Hz){unit}"
            )
        if value is not None and float(value) < lowest:
            raise ConfigError(
                f"{name}={float(value):g} Hz is below {MIN_FILTER_CYCLES} cycles over {shortest.source} "
                f"({span:.4g} s: {lowest:.3g} Hz): a low-pass that slow leaves "
                "nothing of the motion to compare or differentiate; raise it (a few times the motion's frequencies), "
                "or check that the time column is in seconds (a log timed in minutes lasts a sixtieth as long)"
            )
    window = float(cfg.diagnose.window_s)
    if window < MIN_WINDOW_SAMPLES * slowest.dt * (1 - 1e-9):  # 0.25 s is 5 samples at 20 Hz, not fewer
        raise ConfigError(
            f"diagnose.window_s={window:g} s is shorter than {MIN_WINDOW_SAMPLES} samples of {slowest.source} "
            f"({MIN_WINDOW_SAMPLES * slowest.dt:.3g} s at {1 / slowest.dt:g} Hz): a re-started simulation needs "
            "some steps to show an error"
        )
    if window > span:
        raise ConfigError(
            f"diagnose.window_s={window:g} s is longer than {shortest.source} ({span:.4g} s): the simulation "
            "error re-starts the simulation every window of each validation file; shorten it"
        )


def _capped_cutoff(cfg: DictConfig, options: dict[str, float], datasets: list[Dataset]) -> tuple[dict[str, float], str]:
    """`options` against the differences' limit of the slowest file (`differences_cutoff_problem`, where the states
    are differences): `diagnose.cutoff_hz`, set for these files, is refused above it (on clean data the diagnosis
    then names effects that are not there); the data config's (`data.cutoff_hz`, conf/data/csv.yaml's 10 Hz on a
    log of any rate) is lowered to it, with the note that says so ("" where nothing is)."""
    name, value = state_cutoff(cfg)
    slowest = max(datasets, key=lambda d: d.dt)
    fs = 1.0 / slowest.dt
    if value is None or cfg.diagnose.get("derivatives", "butterworth") != "butterworth":
        return options, ""
    problem = differences_cutoff_problem(float(value), fs, f"the {fs:g} Hz sampling of {slowest.source}")
    if problem is None:
        return options, ""
    if name == "diagnose.cutoff_hz":
        raise ConfigError(f"{name}={problem}; lower it")
    top = differences_cutoff_limit_hz(fs)
    return {**options, "cutoff_hz": top}, f"{name}={problem}: the states are filtered at {top:g} Hz"


MIN_WINDOW_SAMPLES = 5  # the shortest re-start window of the simulation error, in samples of the slowest file
MIN_FILTER_CYCLES = 5  # the slowest state filter or analysis band: this many of its cycles over the shortest file


def _setting(cfg: DictConfig, name: str) -> tuple[str, float | None] | None:
    """The key that sets the filter frequency `name` [Hz], and its value: `diagnose.<name>` when set (not null), else
    the data config's `<name>` where it has the key (a property of the logs; its null has a meaning of its own);
    None where neither does."""
    if cfg.diagnose.get(name) is not None:
        return f"diagnose.{name}", float(cfg.diagnose[name])
    if name in cfg.data:
        value = cfg.data[name]
        return f"data.{name}", None if value is None else float(value)
    return None


def _band_hz(cfg: DictConfig) -> float | None:
    """The analysis band [Hz]: `diagnose.band_hz` when set, else the data config's `band_hz` (a property of the
    hardware the logs come from, such as the DFKI arm's structural vibration), else None (no band)."""
    return (_setting(cfg, "band_hz") or ("", None))[1]


DEFAULT_CUTOFF_HZ = 10.0  # the state filter's cut-off where neither diagnose.cutoff_hz nor the data config sets one


def state_cutoff(cfg: DictConfig) -> tuple[str, float | None]:
    """The key that sets the Butterworth cut-off of the angles before they are differentiated, and that cut-off
    [Hz]: `diagnose.cutoff_hz` when set; else the data config's `cutoff_hz` (the state filter the logs' models are
    judged with, such as the DFKI arm's 5 Hz; null there: 4 x the excitation's bandwidth); else
    `DEFAULT_CUTOFF_HZ`."""
    return _setting(cfg, "cutoff_hz") or ("diagnose.cutoff_hz", DEFAULT_CUTOFF_HZ)


def derivative_options(cfg: DictConfig) -> dict[str, float]:
    """The options of `derive_states` that sysid-diagnose uses: the `state_cutoff` where one is set (none: the
    cut-off derived from each record's excitation)."""
    cutoff = state_cutoff(cfg)[1]
    return {"cutoff_hz": cutoff} if cutoff is not None else {}


def _hard_friction(cfg: DictConfig) -> bool:
    """Whether the logs come from `sysid-run`'s Coulomb simulation of each frictionloss (`system.hard_friction`,
    false in conf/diagnose.yaml whatever the system config says): else the MJCF is read as MuJoCo applies it."""
    return bool(cfg.system.get("hard_friction", False))


def record_offsets(cfg: DictConfig) -> bool:
    """Whether a torque offset per training file is fitted as a nuisance: `diagnose.record_offsets` when set,
    else the data config's `record_offsets` (a property of the sensor, such as drivers whose torque estimate is
    zeroed anew at every power-up), else False."""
    return flag_set_by(cfg, "record_offsets") is not None


def record_joint_offsets(cfg: DictConfig) -> bool:
    """Whether an angle offset per training file is fitted as a nuisance (encoders zeroed wherever the arm rested
    when each file began): `diagnose.record_joint_offsets` when set, else the data config's, else False."""
    return flag_set_by(cfg, "record_joint_offsets") is not None


def _mjcf_names(system: str) -> tuple[str, str]:
    """The calibrated MJCFs' file names of a system: fitted on the training records, and on every record
    (`final_fit`)."""
    return f"{system}_calibrated.xml", f"{system}_calibrated_all.xml"


def _previous_mjcf_names(folder: Path, plant: Plant) -> tuple[str, ...]:
    """The calibrated MJCFs of a finished diagnosis of another system in `folder` (named by its diagnosis.json's
    `system`): an overwrite retires them with the rest, so that no other run's model is left beside the new one."""
    try:
        name = json.loads((folder / "diagnosis.json").read_text()).get("system")
    except (OSError, ValueError, AttributeError):  # none, unreadable, or not a diagnosis: nothing of ours to retire
        return ()
    if not isinstance(name, str) or name == plant.name or not name or Path(name).name != name:
        return ()
    return _mjcf_names(name)


def run(cfg: DictConfig) -> dict[str, Any]:
    """Diagnose `cfg.system` on `cfg.data`; returns diagnosis.json's content.

    The config is checked first (`harness.validate`), then the run folder is claimed
    (`harness.rundir.claim`: writable, not in use, no finished diagnosis unless `overwrite=true`).
    """
    validate_diagnose_config(cfg)
    plant = as_simulated(load_system(cfg), _hard_friction(cfg))  # the nominal MJCF as the logs' simulator ran it
    cfg = with_model_defaults(cfg, plant)
    previous = _previous_mjcf_names(_output_dir(cfg), plant)
    outputs = ("diagnosis.rrd", *previous, *_mjcf_names(plant.name), "diagnosis.json")
    try:
        logs: list[Path] | None = data_paths(cfg)
    except DataError:  # raised again where the logs are read, in the claimed folder
        logs = None
    inputs = [plant.source or plant.path, *(logs or [])]
    writes = [n for n in outputs if n not in previous]
    with claim(
        _output_dir(cfg), outputs=outputs, overwrite=bool(cfg.overwrite), inputs=inputs, writes=writes
    ) as folder:
        return _run(cfg, plant, folder, logs)


def _run(cfg: DictConfig, plant: Plant, folder: RunFolder, paths: list[Path] | None) -> dict[str, Any]:
    opts = cfg.diagnose
    out = folder.path
    paths = data_paths(cfg) if paths is None else paths  # None: finding them failed before the folder was claimed
    columns = OmegaConf.to_container(cfg.data.columns) if cfg.data.get("columns") is not None else None
    stage = _stages()
    stage(f"reading {len(paths)} file(s)")
    datasets = read_many(
        paths,
        plant,
        columns=columns,  # type: ignore[arg-type]
        repair=bool(cfg.data.get("repair", True)),
        resample=bool(cfg.data.get("resample", True)),
        max_speed=cfg.data.get("max_speed"),
        min_samples=int(cfg.data.get("min_samples", 50)),
    )
    datasets = _with_torque_lead(datasets, float(cfg.data.get("tau_lead_s") or 0.0))
    _check_filters(cfg, datasets)
    repairs = {  # per file: what the reader repaired (the first 100 rows of each kind)
        d.source: [{**asdict(r), "rows": list(r.rows[:100])} for r in d.meta.get("repairs", ())] for d in datasets
    }
    for d in datasets:  # said as they are made, not only in diagnosis.json
        for r in d.meta.get("repairs", ()):
            stage(f"repaired {Path(d.source).name}: {r.message}")
    ignored = {d.source: [str(c) for c in d.meta.get("ignored_columns", ())] for d in datasets}
    derivatives = str(opts.derivatives)
    options, capped = _capped_cutoff(cfg, derivative_options(cfg), datasets)
    if capped:
        stage(capped)
    # at the full rate: thinning would blur a stuck or clipped torque
    anomalies = find_anomalies(datasets, plant.hinge, plant.q_range, plant.limit_margin)
    validation = cfg.data.get("validation")
    datasets, excluded = _without_stuck_torques(datasets, anomalies, as_strings(validation) if validation else [])
    if excluded:
        stage(f"left out (a torque stuck at zero): {'; '.join(excluded)}")
    reduced = _reduce(plant, datasets, derivatives, options, cfg, stage)
    if reduced is not None:
        datasets, derivatives, options = reduced
    split = split_train_validation(
        datasets,
        validation_fraction=float(cfg.data.get("validation_fraction", 0.3)),
        validation=as_strings(validation) if validation is not None else None,
        min_samples=int(cfg.data.get("min_samples", 50)),
    )
    references = reference_models(
        OmegaConf.to_container(opts.references) if OmegaConf.is_list(opts.references) else opts.references, paths
    )
    if references and plant.nv != 2:  # the references are the DFKI double pendulum's two-joint model form
        if opts.references != "auto":
            raise ConfigError(
                f"diagnose.references: the reference models are of the two-joint DFKI double pendulum's form, and "
                f"{plant.name} has {plant.nv} joint(s); diagnose.references=null compares with none"
            )
        references = {}  # auto: found beside another robot's data, they do not apply
    stage(
        f"diagnosing {sum(d.n_samples for d in split.train)} training and "
        f"{sum(d.n_samples for d in split.validation)} validation rows"
    )
    if "rigid_body" in opts.effects:
        _check_training_excitation(plant, split.train, tuple(cfg.system.effects), derivatives, options)
    fit = partial(
        diagnose,
        plant,
        effects=tuple(opts.effects),
        derivatives=derivatives,
        derivative_options=options,
        anomalies=anomalies,
        selection=SelectionOptions(**OmegaConf.to_container(opts.selection, resolve=True)),  # type: ignore[arg-type]
        window_s=float(opts.window_s),
        max_windows=None if opts.get("max_windows") is None else int(opts.max_windows),
        band_hz=_band_hz(cfg),
        record_offsets=record_offsets(cfg),
        record_joint_offsets=record_joint_offsets(cfg),
        check_torque_signs=bool(opts.get("check_torque_signs", True)),
        hard_friction=_hard_friction(cfg),
        mujoco_steps=opts.get("mujoco_steps"),
    )
    known = cfg.data.get("tau_lead_s") is not None  # declared; else found from the data

    def run_diagnosis(train: Sequence[Dataset], **kwargs: Any) -> Diagnosis:  # each fit from the same seed
        rng = np.random.default_rng(int(cfg.seed))
        return with_found_lead(partial(fit, **kwargs), train, split.validation, rng, known=known)

    result = run_diagnosis(split.train, references=references)
    mjcf_name, final_name = _mjcf_names(plant.name)
    payload = result.to_dict(mjcf_name=mjcf_name)
    final: Diagnosis | None = None
    if bool(opts.get("final_fit", True)):
        stage(f"fitting the same diagnosis on every record ({sum(d.n_samples for d in datasets)} rows)")
        final = run_diagnosis(datasets, check_torque_signs=False)  # the same records the first fit checked
        payload["final_fit"] = _final_fit_entry(final, final_name, datasets)
    if capped:
        payload["notes"] = [*payload.get("notes", []), capped]
    payload["seed"] = int(cfg.seed)
    payload["units"] = _units(plant)
    payload["split"] = split.describe()
    payload["repairs"] = repairs
    payload["ignored_columns"] = ignored  # columns of each file the reader did not use
    if excluded:
        payload["excluded"] = excluded
    if reduced is not None:
        payload["reduced"] = {d.source: d.meta["reduced"] for d in datasets}
    payload["config"] = OmegaConf.to_container(cfg, resolve=True)
    stage("writing the outputs")
    dataset = f"{cfg.data.get('name', 'csv')}: {', '.join(p.name for p in paths)}"
    with folder.staged() as staging:
        _write_outputs(
            staging,
            plant,
            result,
            payload,
            mjcf_name,
            record=bool(opts.get("recording", True)),
            dataset=dataset,
            final=final,
        )
    stage("done")
    print(_summary(payload))
    print(f"outputs in {out}")
    return to_jsonable(payload)


def _without_stuck_torques(
    datasets: list[Dataset], anomalies: list[Any], validation: list[str]
) -> tuple[list[Dataset], list[str]]:
    """The files whose torque is stuck at zero on some joint are left out of the fit (a zero reading there is
    no measurement; fitted, it would be explained as a huge effect); an error when no file is left, or when
    `validation` (data.validation's names) names one of them.

    Returns:
        The files kept, and what was left out and why (one line per file).
    """
    stuck: dict[str, list[str]] = {}
    for a in anomalies:
        if a.kind == "torque_stuck_at_zero":
            stuck.setdefault(a.source, []).append(f"{a.joint} ({a.detail['zero_fraction']:.0%} of rows exactly 0)")
    if not stuck:
        return datasets, []
    lines = [f"{Path(src).name}: torque of {', '.join(j)}" for src, j in stuck.items()]
    kept = [d for d in datasets if d.source not in stuck]
    for src, joints in stuck.items():
        if any(names_file(name, src) for name in validation):
            raise DataError(
                f"{src}: torque of {', '.join(joints)}: stuck at zero (the sensor is off, or the column is not "
                "logged), so the file is left out, and data.validation names it: validate on another file"
            )
    if not kept:
        raise DataError(
            f"{'; '.join(lines)}: the torque is stuck at zero (the sensor is off, or the column is not logged), "
            "so there is nothing to fit; check the torque column(s) of these file(s)"
        )
    return kept, lines


def _reduce(
    plant: Plant,
    datasets: list[Dataset],
    method: str,
    options: dict[str, Any],
    cfg: DictConfig,
    stage: Callable[[str], None],
) -> tuple[list[Dataset], str, dict[str, Any]] | None:
    """Long logs thinned to `diagnose.max_rows` (states derived at the full rate first); None when they fit.
    Each log's angle noise is checked against the model torque at the full rate first
    (`check_full_rate_state_noise`): the thinned, 'given' states no longer show it.

    The kept rate never falls below 2.5 x the larger of the analysis band and twice the motion's own bandwidth
    (`excitation_bandwidth_hz`), so the thinned states and torques keep everything the motion excites.

    Returns:
        The reduced records, and the derivative method and options that read their states ('given').
    """
    limit = cfg.diagnose.get("max_rows")
    total = sum(d.n_samples for d in datasets)
    if limit is None or total <= int(limit) or method in ("simulator", "given"):
        return None
    band = float(_band_hz(cfg) or 0.0)
    out = []
    for i in range(len(datasets)):
        # measured dq is not needed once states are derived from q: it goes now, the rest of the record after it
        data, datasets[i] = replace(datasets[i], dq=None), None  # type: ignore[call-overload]
        fs = 1.0 / data.dt
        # the motion's bandwidth from (at most) its first 2^20 rows: a spectrum of the whole log is ~10x its memory
        keep_hz = max(band, 2.0 * excitation_bandwidth_hz(data.q[: 1 << 20], fs))
        k = reduction_factor(total, fs, max_rows=int(limit), band_hz=keep_hz)
        if k > 1:
            check_full_rate_state_noise(plant, data, method, options, band_hz=_band_hz(cfg))
        stage(
            f"{Path(data.source).name}: {data.n_samples} rows at {fs:.4g} Hz; states at the full rate, then every "
            f"{k}th row ({fs / k:.4g} Hz; states and torque anti-aliased at {fs / k / 2.5:.3g} Hz, the motion "
            f"spans {keep_hz / 2:.3g} Hz)"
        )
        reduced = reduce_record(data, method, k, **options)
        if k > 1:  # the anti-aliased torque hides its noise from the third differences: read it at the full rate
            reduced.meta["reduced"]["noise_floor"] = noise_floor(data.tau).tolist()
        out.append(reduced)
        del data
    return out, "given", {}


def _stages() -> Callable[[str], None]:
    """Progress lines on stderr: each stage as it starts, with the time since the run began."""
    start = time.perf_counter()

    def stage(message: str) -> None:
        print(f"[sysid-diagnose] {time.perf_counter() - start:6.1f} s  {message}", file=sys.stderr, flush=True)

    return stage


def _check_training_excitation(
    plant: Plant, train: tuple[Dataset, ...], effects: tuple[str, ...], method: str, options: dict[str, Any]
) -> None:
    """Refuse training data that do not excite the rigid-body (and configured effect) base parameters the
    refit will estimate: nothing is fitted on such data silently."""
    model = ParameterModel(plant, effects)
    base = base_parameters(model, np.random.default_rng(0))
    blocks = []
    for data in train:
        states = derive_states(data, method, **options)
        rows = states.valid
        blocks.append(base.columns(model.regressor(states.q[rows], states.dq[rows], states.ddq[rows])))
    files = ", ".join(Path(d.source).name for d in train)
    try:
        check_excitation(np.concatenate(blocks), names=base.names, source=files)
    except DataError as err:
        still = set.intersection(*(set(still_joints(d, plant.hinge)) for d in train))
        if not still:
            raise
        joints = sorted(still)
        spans = ", ".join(
            f"q_{plant.joint_names[j]} spans at most {max(float(np.ptp(d.q[:, j])) for d in train):.3g} "
            f"{'rad' if plant.hinge[j] else 'm'}"
            for j in joints
        )
        named = " and ".join(repr(plant.joint_names[j]) for j in joints)
        who, move, it = ("joint", "moves", "it") if len(joints) == 1 else ("joints", "move", "they")
        raise DataError(
            f"{files}: {who} {named} never {move} in any training file ({spans}; a frozen or unplugged encoder, or "
            f"a joint held still), so {str(err).removeprefix(files + ': ')}: give a file in which {it} "
            f"{'moves' if len(joints) == 1 else 'move'}"
        ) from None


def _write_outputs(
    out: Path,
    plant: Plant,
    result: Diagnosis,
    payload: dict[str, Any],
    mjcf_name: str,
    *,
    record: bool,
    dataset: str = "",
    final: Diagnosis | None = None,
) -> None:
    """The recording, the calibrated MJCF (and `final`'s, fitted on every record), then diagnosis.json (its
    presence means a finished run), into `out`: the run folder's staging folder (`RunFolder.staged`), which
    removes them all if one fails."""
    if record:
        from harness.record import record_diagnosis  # rerun (and pyarrow) only when recording: ~60 MB less memory

        record_diagnosis(
            out / "diagnosis.rrd", plant, result, _findings_markdown(result, _units(plant)), dataset=dataset
        )
    atomic_write(out / mjcf_name, lambda f: f.write(result.calibrated_xml))
    if final is not None:
        atomic_write(out / _mjcf_names(plant.name)[1], lambda f: f.write(final.calibrated_xml))
    write_json(out / "diagnosis.json", payload)


def _final_fit_entry(final: Diagnosis, mjcf_name: str, datasets: Sequence[Dataset]) -> dict[str, Any]:
    """diagnosis.json's `final_fit`: the diagnosis run again on every record (the validation ones included)."""
    return {
        "mjcf": mjcf_name,
        "records": [d.source for d in datasets],
        "findings": [{"name": f.name, "value": f.value, "std": f.std, "unit": f.unit} for f in final.findings],
        # each record's own zeros where they were fitted as nuisances (diagnose.record_offsets / record_joint_offsets)
        "record_offsets": final.info["record_offsets"],
        "record_joint_offsets": final.info["record_joint_offsets"],
        # whether every record, read together, is a log of MuJoCo's own steps (`diagnose.mujoco_steps`)
        "mujoco_steps": final.info["mujoco_steps"],
        "note": (
            "the same diagnosis fitted on every record, the validation ones included: the model for new data of "
            "this robot. Its figures would be in-sample, so none is reported; the gain on data the fit never saw "
            "is the training fit's (models.calibrated)"
        ),
    }


def _units(plant: Plant) -> dict[str, dict[str, str]]:
    """Per joint: the unit of its torque (`torque`: N m on a hinge, N on a slide) and of its angle (`angle`)."""
    return {
        j: {"torque": torque, "angle": angle}
        for j, torque, angle in zip(plant.joint_names, plant.torque_units, plant.position_units, strict=True)
    }


def _findings_markdown(result: Diagnosis, units: dict[str, dict[str, str]]) -> str:
    lines = [f"**verdict: {result.verdict}** ({result.verdict_reason})", ""]
    lines += [f"- anomaly: {a['kind']} {a['joint']} in {Path(a['source']).name}" for a in result.anomalies]
    lines += [
        "",
        "| effect (or confounded alternatives) | where | value | std | unit | bound |",
        "|---|---|---:|---:|---|---|",
    ]
    for f in result.findings:
        std = f"{f.std:.2g}" if np.isfinite(f.std) else "-"  # none at a bound
        lines.append(f"| {f.name} | {f.target} | {f.value:.5g} | {std} | {f.unit} | {f.at_bound or ''} |")
    lines += [
        "",
        "| model | joint | torque RMS | on the torques judged | simulation error |",
        "|---|---|---:|---:|---:|",
    ]
    for model, m in result.models.items():
        for j, v in m["torque_rms"].items():
            sim = m.get("simulation_error", {}).get(j)
            u = units[j]
            err = "-" if sim is None else f"{sim:.4g} {u['angle']}"
            judged = m.get("torque_rms_judged", {}).get(j)
            judged_text = "-" if judged is None or not np.isfinite(judged) else f"{judged:.4g} {u['torque']}"
            lines.append(f"| {model} | {j} | {v:.4g} {u['torque']} | {judged_text} | {err} |")
    angles = result.info.get("record_joint_offsets", [])
    if angles:  # nuisances: each training record's encoder zero, not part of the calibrated model
        lines += [
            "",
            "| training record | " + " | ".join(result.joint_names) + " |",
            "|---|" + "---:|" * len(result.joint_names),
        ]
        for r in angles:
            cells = [
                "-" if not np.isfinite(r[j]) else f"{r[j]:.4g} ± {r['std'][j]:.2g} {units[j]['angle']}"
                for j in result.joint_names
            ]
            lines.append(f"| {Path(r['source']).name} (angle offset) | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _summary(payload: dict[str, Any]) -> str:
    lines = [f"{payload['system']}: {payload['verdict']} ({payload.get('verdict_reason', '')})"]
    for a in payload.get("anomalies", []):
        lines.append(f"  anomaly: {a['kind']} {a['joint']} in {Path(a['source']).name}")
    for f in payload["findings"]:
        where = f.get("joint") or f.get("body") or ""
        finite = f["std"] is not None and np.isfinite(f["std"])
        std = f" +- {f['std']:.2g}" if finite else ""  # a value at its bound has none
        bound = f" (at its {f['at_bound']} bound{'' if finite else ', no std'})" if f.get("at_bound") else ""
        alts = "".join(  # an alternative the finding absorbs carries the value it takes in the same fit
            f" or {c['effect']} {c['target']}".rstrip()
            + (f" ({c['value']:.4g} +- {c['std']:.2g})" if "value" in c else "")
            for c in f.get("confounded_with", [])
        )
        held = f" ({', '.join(f['held_nominal'])} nominal)" if f.get("held_nominal") else ""
        value = "-" if f["value"] is None else f"{f['value']:.5g}"  # None: not finite (JSON has no inf)
        lines.append(f"  {f['effect']:17s} {where:10s} {value}{std} {f['unit']}{bound}{alts}{held}")
    if "final_fit" in payload:
        ff = payload["final_fit"]
        names = ", ".join(f["name"] for f in ff["findings"]) or "none"
        lines.append(f"  fitted on every record ({len(ff['records'])}): {ff['mjcf']}, the model for new data ({names})")
    for d in payload.get("info", {}).get("outside_training", []):
        share = max(d["share_outside_by_angle"], d["share_outside_by_speed"])
        lines.append(
            f"  outside the training motion: {d['joint']} in {Path(d['source']).name} ({share:.0%} of its rows)"
        )
    units = payload.get("units", {})

    def unit(j: str, kind: str) -> str:
        return str(units.get(j, {}).get(kind, "N m" if kind == "torque" else "rad"))

    for model, m in payload["models"].items():
        tau = ", ".join(f"{j} {v:.4f} {unit(j, 'torque')}" for j, v in m["torque_rms"].items())
        sim = ", ".join(f"{j} {v:.4f} {unit(j, 'angle')}" for j, v in m.get("simulation_error", {}).items())
        lines.append(f"  {model:18s} torque RMS: {tau}; simulation error: {sim or '-'}")
        if "torque_rms_judged" in m:
            judged = ", ".join(
                f"{j} {v:.4f} {unit(j, 'torque')}" if v is not None and np.isfinite(v) else f"{j} - (none judged)"
                for j, v in m["torque_rms_judged"].items()
            )
            lines.append(f"  {'':18s} on the torques the verdict judges: {judged}")
    spread = payload.get("info", {}).get("prediction_std")
    if spread and any(v > 0 for v in spread.values()):  # no effect found: nothing was fitted
        std = ", ".join(f"{j} {v:.4f} {unit(j, 'torque')}" for j, v in spread.items())
        lines.append(f"  {'':18s} calibrated prediction std from the parameters' uncertainty: {std}")
    return "\n".join(lines)


@hydra.main(config_path=str(CONF_DIR), config_name="diagnose", version_base=None)
def _hydra_main(cfg: DictConfig) -> None:
    run_job(run, cfg)


def main() -> None:
    """Console entry point `sysid-diagnose`: config-group values are checked before Hydra starts."""
    sys.argv[1:] = with_auto_system(sys.argv[1:])
    try:
        check_command_line(sys.argv[1:], CONF_DIR, "diagnose")
        check_output_override(sys.argv[1:], ("diagnosis.json", "diagnosis.rrd"))
    except (ConfigError, RunFolderError) as err:
        print(f"sysid-diagnose: error: {err}", file=sys.stderr)
        raise SystemExit(2) from None
    with kept_on_failure(sys.argv[1:], ("diagnosis.json",)):  # written last: a finished diagnosis
        _hydra_main()


if __name__ == "__main__":
    main()

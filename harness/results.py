"""Writing results (atomic JSON, the terminal summary table) and running one job with its failure record."""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import signal
import sys
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from omegaconf.errors import OmegaConfBaseException

from envs.dataset import atomic_write
from harness.rundir import RESULTS_FILES, terminate_as_exit

__all__ = [
    "USER_ERRORS",
    "describe_failure",
    "one_line",
    "record_failure",
    "run_job",
    "summary_table",
    "to_jsonable",
    "write_json",
]


def to_jsonable(value: Any) -> Any:
    """numpy scalars and arrays to plain Python; non-finite floats to None (JSON has no NaN)."""
    if isinstance(value, dict):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_jsonable(value.tolist())
    if isinstance(value, np.generic):
        return to_jsonable(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    return value


def write_json(path: Path, payload: dict[str, Any]) -> None:
    """Write `payload` as JSON atomically: readers see the old file or the whole new one, never half."""
    text = json.dumps(to_jsonable(payload), indent=2, allow_nan=False)
    atomic_write(Path(path), lambda f: f.write(text + "\n"))


# why a simulated motion leaves the design it tracks
_WHY_IT_LAGS = (
    "a servo lags its target, an actuator saturates, or the physics step is too coarse for the tracking loop: "
    "check the MJCF's ctrlrange, forcerange and timestep"
)


def summary_table(results: dict[str, Any]) -> str:
    """A readable table of the base parameters and the validation for the terminal."""
    rows = [("base parameter", "true", "estimate", "std", "rel.err", "z")]
    for p in results["base_parameters"]:
        rel = "-" if p["rel_error"] is None else f"{p['rel_error']:+.2%}"
        std = "-" if p["std"] is None else f"{p['std']:.2g}"
        z = "-" if p["z"] is None else f"{p['z']:+.2f}"
        rows.append((p["name"], f"{p['true']:.6g}", f"{p['estimate']:.6g}", std, rel, z))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = [
        "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths, strict=True)))
        for r in rows
    ]
    lines.insert(1, "-" * len(lines[0]))
    ex = results["excitation"]
    val = results["validation"]
    lines.append("")
    lines.append(
        f"excitation {ex['name']}: cond(X'X) = {ex['cond_XtX']:.4g} (column-normalised {ex['cond_W_colnorm']:.4g}), "
        f"{ex['harmonics']} harmonics, period {ex['period_s']:g} s, limits {'hold' if ex['limits_ok'] else 'BROKEN'}"
        + ("" if ex.get("simulated", {}).get("holds", True) else " on the design, not in the motion that ran")
    )
    sim = ex.get("simulated")
    if sim is not None and not sim["holds"]:
        track = sim.get("tracking_error_max", {})
        worst = max(track, key=lambda j: track[j]) if track else None
        lines.append(
            f"WARNING: the simulated motion breaks the limits the design keeps: {sim['worst']}"
            + (f"; largest tracking error {track[worst]:.3g} rad ({worst})" if worst else "")
            + f": the motion that ran is not the design ({_WHY_IT_LAGS}); the data hold the motion that ran"
        )
    for joint, miss in (sim or {}).get("not_following", {}).items():
        lines.append(
            f"WARNING: joint {joint} did not follow the design: up to {miss['error']:.3g} from its designed angles, "
            f"whose swing is {miss['swing']:.3g} either way (rad, or m for a slide): held in its friction, or its "
            "controller too weak for it (system.controller.bandwidth_hz); its data say little of its parameters"
        )
    poor = ex.get("poorly_excited", {})
    if poor.get("directions"):
        lines.append(
            f"WARNING: {poor['directions']} direction(s) of the base parameters are poorly excited (column-normalised "
            f"cond > {poor['cond_threshold']:g}): {', '.join(poor['weakest'])} (weakest {poor['weakest_direction']}); "
            "their estimates rest on the prior, if any, and their stds are large: use more periods or an optimised "
            "excitation"
        )
    val_sim = val.get("simulated")
    if val_sim is not None and not val_sim["holds"]:
        lines.append(
            f"WARNING: the validation motion that ran breaks the limits: {val_sim['worst']}: the validation torque "
            f"RMS below is judged where the model was not identified ({_WHY_IT_LAGS}); it says less of the "
            "parameters than the identification's stds"
        )
    for joint, rms in val["torque_rms"].items():
        unit = val.get("unit", {}).get(joint, "N m")  # a slide joint's is a force
        noise = val["noise_std"][joint]
        lines.append(f"validation {joint}: torque RMS {rms:.4g} {unit} (sensor noise std {noise:.4g})")
    lines.append("timing: " + ", ".join(f"{k} {v:.2f} s" for k, v in results["timing_s"].items()))
    return "\n".join(lines)


USER_ERRORS: tuple[type[BaseException], ...] = (ValueError, OSError, OmegaConfBaseException)
"""Errors that come from the input or the machine (a config value, a file, the disk), not from a bug: one line
on stderr and exit status 2, no traceback. Any other exception is a bug and keeps its traceback."""


def one_line(err: BaseException) -> str:
    """The error as one line: its message's lines joined (a multi-file data error lists each file)."""
    text = "; ".join(line.strip() for line in str(err).splitlines() if line.strip())
    if isinstance(err, OSError) and err.filename is not None:
        text = f"{err.filename}: {err.strerror or text}"
    return text or type(err).__name__


def as_interrupt(err: BaseException) -> BaseException:
    """`err`, or the Ctrl-C it stands for: NumPy turns a KeyboardInterrupt raised while it converts a sequence into
    `ValueError: setting an array element with a sequence`, the interrupt left in its context."""
    seen: BaseException | None = err
    while seen is not None:
        if isinstance(seen, KeyboardInterrupt):
            return seen
        seen = seen.__cause__ or seen.__context__
    return err


def describe_failure(err: BaseException) -> str:
    """What failed, for failure.json and the log: SIGTERM, an interrupt, or the exception's one line."""
    if isinstance(err, SystemExit) and isinstance(err.code, int) and err.code > 128:
        return f"terminated by {signal.Signals(err.code - 128).name}"
    if isinstance(err, KeyboardInterrupt):
        return "interrupted (Ctrl-C)"
    return f"{type(err).__name__}: {one_line(err)}"


def _log_to_files(message: str, level: int = logging.ERROR) -> None:
    """Log `message` to the job's log files only (Hydra's `<job>.log`): the terminal gets one line, not two."""
    record = logging.LogRecord("sysid", level, __file__, 0, message, None, None)
    raising, logging.raiseExceptions = logging.raiseExceptions, False  # a full disk: no "Logging error" dump
    try:
        for handler in logging.getLogger().handlers:
            if isinstance(handler, logging.FileHandler):
                handler.handle(record)
    finally:
        logging.raiseExceptions = raising


def record_failure(out: Path, err: BaseException, *, with_traceback: bool = True, own_folder: bool = False) -> str:
    """Write `failure.json` into the run folder `out` (unless the folder is not this run's: another run holds it,
    or it holds a finished run's results and is not `own_folder`) and log the error; returns the one-line
    description. `own_folder`: a sweep's job folder, whose results (if any) are an earlier run's that this one, with
    overwrite=true, failed to replace: the failure is recorded beside them, and the sweep counts the job failed
    (`rundir.failed_since_results`)."""
    from harness.rundir import RunFolderError

    message = describe_failure(err)
    _log_to_files(message)
    earlier = any((out / name).exists() for name in RESULTS_FILES)
    if isinstance(err, RunFolderError) or (earlier and not own_folder):
        return message
    error = f"{message} (the results here are an earlier run's)" if earlier else message
    payload = {"error": error, "traceback": traceback.format_exc() if with_traceback else None}
    with contextlib.suppress(OSError):  # the folder may be the very thing that failed
        if out.is_dir():
            write_json(out / "failure.json", payload)
    return message


def run_job(work: Callable[[Any], Any], cfg: Any) -> Any:
    """Run one Hydra job.

    A single run that fails writes `failure.json` (the error and its traceback) into its folder and logs it;
    bad input, a bad config or an unusable disk (`USER_ERRORS`) prints one line and exits with status 2, Ctrl-C
    prints one line and exits with status 130 (as a shell reports SIGINT), any other exception propagates with
    its traceback. SIGTERM ends the run through its clean-up code.

    Inside a sweep (`-m`) each job runs in a child process of its own (see `harness.sweep`): a job that
    raises, or whose process is killed (SIGKILL, the out-of-memory killer), is recorded in `failure.json` and
    the sweep goes on with the other jobs; the sweep's exit status says whether any failed.
    """
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    hydra_cfg = HydraConfig.get()
    out = Path(hydra_cfg.runtime.output_dir)
    # MuJoCo's warnings (an unstable simulation) go to the job's log: the code that meets one says it on the one
    # error line; printed by MuJoCo as well, they came before it on stderr
    mujoco.set_mju_user_warning(lambda text: _log_to_files(f"MuJoCo: {text}", logging.WARNING))
    if hydra_cfg.mode == RunMode.MULTIRUN:
        from harness.sweep import run_isolated

        return run_isolated(work, cfg, out, label=f"job {hydra_cfg.job.num}")
    job = hydra_cfg.job.name
    with terminate_as_exit():
        # a folder's log is appended to: a run after a failed one in the same folder says that it started and
        # finished, beside the failure it follows (the log read as a failure next to the new results)
        _log_to_files(f"{job} started (pid {os.getpid()})", logging.INFO)
        try:
            result = work(cfg)
        except BaseException as raised:
            err = as_interrupt(raised)
            message = record_failure(out, err)
            if isinstance(err, USER_ERRORS):
                print(f"{hydra_cfg.job.name}: error: {one_line(err)}", file=sys.stderr)
                raise SystemExit(2) from None
            if isinstance(err, SystemExit | KeyboardInterrupt):
                print(f"{hydra_cfg.job.name}: {message}", file=sys.stderr)
            if isinstance(err, KeyboardInterrupt):  # the user's own stop: the line above, no traceback
                raise SystemExit(130) from None
            raise
        _log_to_files(f"{job} finished: outputs in {out}", logging.INFO)
        return result

"""Writing results: atomic JSON and the terminal summary table."""

from __future__ import annotations

import json
import math
import sys
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from envs.dataset import atomic_write

__all__ = ["run_job", "summary_table", "to_jsonable", "write_json"]


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
    )
    for joint, rms in val["torque_rms"].items():
        lines.append(f"validation {joint}: torque RMS {rms:.4g} N m (sensor noise std {val['noise_std'][joint]:.4g})")
    lines.append("timing: " + ", ".join(f"{k} {v:.2f} s" for k, v in results["timing_s"].items()))
    return "\n".join(lines)


def run_job(work: Callable[[Any], Any], cfg: Any) -> Any:
    """Run one Hydra job.

    Inside a sweep (`-m`) a failure is written to `failure.json` in the job's folder and the sweep goes on with
    the other jobs. A single run that fails on bad input prints one clear line and exits with status 2;
    any other exception propagates with its traceback.
    """
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    hydra_cfg = HydraConfig.get()
    if hydra_cfg.mode != RunMode.MULTIRUN:
        try:
            return work(cfg)
        except ValueError as err:  # bad input or an impossible request (SysIdError subclasses included)
            print(f"{hydra_cfg.job.name}: error: {err}", file=sys.stderr)
            raise SystemExit(2) from err
    try:
        return work(cfg)
    except Exception as err:
        out = Path(hydra_cfg.runtime.output_dir)
        message = f"{type(err).__name__}: {err}"
        write_json(out / "failure.json", {"error": message, "traceback": traceback.format_exc()})
        print(f"job {hydra_cfg.job.num} failed: {message}", file=sys.stderr)
        return None

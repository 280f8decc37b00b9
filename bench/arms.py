"""Real arms, one row each: every MuJoCo Menagerie arm in ../shared/robots/ and the example-robot-data UR5 URDF,
each run as `sysid-run system.mjcf=<file>` with nothing else (the full default loop).

Per arm: cond(X'X) raw and column-normalised, the optimiser's time (wall and CPU), the finite-difference
SLSQP baseline's time from the same start where it finishes within `FD_BUDGET_S` (else "> budget"),
identification time, max |z|, the worst validation RMS over the sensor noise, limits and clearance of the design,
and of the motion that ran (`excitation.simulated`: the worst bound's use and the largest tracking error).

Writes bench/arms.json and bench/arms.md. Re-run: `.venv/bin/python -m bench arms` (from the repository root).
"""

from __future__ import annotations

import json
import tempfile
import time
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import OmegaConf

import excitation.optimise as optimise
from dynamics.plant import load_plant
from harness.run import run
from harness.setup import design_from_config, experiment_from_config, with_auto_system, with_model_defaults
from tests.conftest import compose_config

HERE = Path(__file__).resolve().parent
ROBOTS = HERE.parent.parent / "shared" / "robots"
URDF = "cmeel.prefix/share/example-robot-data/robots/ur_description/urdf/ur5_robot.urdf"
FD_BUDGET_S = 300.0
# the finite-difference baseline is run on the 7-DoF arm the issue names (each run costs up to the budget)
FD_ARMS = ("panda_nohand.xml",)


class _OutOfTime(Exception):
    pass


def _models() -> list[Path]:
    out = sorted(ROBOTS.glob("*.xml")) if ROBOTS.is_dir() else []
    try:
        urdf = Path(str(metadata.distribution("example-robot-data").locate_file(URDF)))
        out += [urdf] if urdf.is_file() else []
    except metadata.PackageNotFoundError:
        print("example-robot-data is not installed: the URDF row is left out")
    return out


def _one_start(overrides: list[str], gradient: str) -> dict[str, Any]:
    """Time one optimisation from the default start with `gradient` (analytic or finite_difference); the
    finite-difference baseline is stopped from inside SLSQP once FD_BUDGET_S is spent."""
    cfg = compose_config(with_auto_system(overrides))
    cfg = with_model_defaults(cfg, load_plant(cfg.system.mjcf))
    exp = experiment_from_config(cfg, np.random.default_rng(0))
    OmegaConf.update(cfg, "excitation.options.gradient", gradient)
    OmegaConf.update(cfg, "excitation.options.starts", 1)
    start, cpu = time.perf_counter(), time.process_time()
    original = optimise.design_criterion

    def budgeted(*args: Any, **kwargs: Any) -> Any:
        if time.perf_counter() - start > FD_BUDGET_S:
            raise _OutOfTime
        return original(*args, **kwargs)

    optimise.design_criterion = budgeted  # type: ignore[attr-defined]
    try:
        design_from_config(cfg, exp, "optimised", np.random.default_rng(1))
        finished = True
    except _OutOfTime:
        finished = False
    finally:
        optimise.design_criterion = original  # type: ignore[attr-defined]
    return {"finished": finished, "wall_s": time.perf_counter() - start, "cpu_s": time.process_time() - cpu}


def main() -> None:
    rows = []
    for model in _models():
        overrides = [f"system.mjcf={model}", "record=none"]
        cfg = compose_config(with_auto_system(overrides))
        cpu = time.process_time()
        with tempfile.TemporaryDirectory() as tmp:
            r = run(cfg, output_dir=Path(tmp))
        total_cpu = time.process_time() - cpu
        noise = r["validation"]["noise_std"]
        ratio = max(v / noise[j] for j, v in r["validation"]["torque_rms"].items() if noise[j] > 0)
        row = {
            "arm": model.name,
            "dof": len(noise),
            "cond_XtX": r["excitation"]["cond_XtX"],
            "cond_W_colnorm": r["excitation"]["cond_W_colnorm"],
            "excitation_wall_s": r["timing_s"]["excitation"],
            "identification_wall_s": r["timing_s"]["identification"],
            "run_cpu_s": total_cpu,
            "max_abs_z": r["max_abs_z"],
            "validation_rms_over_noise": ratio,
            "limits_ok": r["excitation"]["limits_ok"],
            "clearance": r["excitation"]["clearance"],
            "simulated": r["excitation"]["simulated"],
            "single_start": _one_start(overrides, "analytic"),
            "finite_difference": _one_start(overrides, "finite_difference") if model.name in FD_ARMS else None,
        }
        rows.append(row)
        print(json.dumps(row), flush=True)
    (HERE / "arms.json").write_text(json.dumps(rows, indent=2) + "\n")
    lines = [
        f"Each arm run as `sysid-run system.mjcf=<file>` (4 optimisation starts); optimiser and baseline from one "
        f"start, the baseline stopped at {FD_BUDGET_S:.0f} s. Times are wall / CPU [s] on this machine.",
        "",
        "| arm | DoF | cond(XᵀX) | cond col-norm | design, 4 starts [s] | 1 start: analytic [s] "
        "| 1 start: FD-SLSQP [s] "
        "| identification [s] | max abs z | validation RMS / noise (worst joint) | limits | clearance [m] "
        "| motion that ran: worst bound | largest tracking error [rad] |",
        "|---|---:|---:|---:|---:|---|---|---:|---:|---:|---|---|---|---:|",
    ]
    for r in rows:
        fd = r["finite_difference"]
        if fd is None:
            fd_text = "not run"
        else:
            fd_text = f"{fd['wall_s']:.1f} / {fd['cpu_s']:.1f}" if fd["finished"] else f"> {FD_BUDGET_S:.0f} (stopped)"
        one = r["single_start"]
        clear = r["clearance"]
        clear_text = f"{clear['min_distance_m']:.3f} >= {clear['required_m']}" if clear else "n/a"
        sim = r["simulated"]
        sim_text = ("" if sim["holds"] else "BROKEN: ") + sim["worst"]
        track = max(sim["tracking_error_max"].values())
        lines.append(
            f"| {r['arm']} | {r['dof']} | {r['cond_XtX']:.4g} | {r['cond_W_colnorm']:.3g} | "
            f"{r['excitation_wall_s']:.1f} | {one['wall_s']:.1f} / {one['cpu_s']:.1f} | {fd_text} | "
            f"{r['identification_wall_s']:.1f} | {r['max_abs_z']:.2f} | {r['validation_rms_over_noise']:.3f} | "
            f"{'hold' if r['limits_ok'] else 'BROKEN'} | {clear_text} | {sim_text} | {track:.4f} |"
        )
    (HERE / "arms.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

"""Excitation design per system: optimised cond against random feasible designs, the column-norm bound, and
the analytic-gradient optimiser against plain SLSQP with finite-difference gradients from the same starts.

Writes bench/excitation.json and bench/excitation.md. Re-run: `make bench` or
`.venv/bin/python -m bench excitation` (from the repository root: this module's name shadows the package
when run as a script).
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import OmegaConf

from dynamics.base import BaseParameters, base_parameters
from dynamics.errors import SysIdError
from dynamics.plant import MJCF_DIR, load_plant
from dynamics.regressor import ParameterModel
from excitation.designs import grid, random_design
from excitation.fourier import FourierDesign
from excitation.limits import Limits
from excitation.optimise import assess_design, optimise_excitation
from harness.setup import CONF_DIR, limits_from_config

HERE = Path(__file__).resolve().parent
SYSTEMS = ("pendulum", "two_link", "wheel_pendulum", "arm3")
SEED = 0


def _setup(system: str) -> tuple[Any, Any, Limits, ParameterModel, BaseParameters]:
    cfg = OmegaConf.load(CONF_DIR / "system" / f"{system}.yaml")
    plant = load_plant(cfg.mjcf)

    limits = limits_from_config(cfg, plant)
    model = ParameterModel(plant, tuple(cfg.effects))
    return cfg, plant, limits, model, base_parameters(model, np.random.default_rng(SEED))


def _column_bound(design: FourierDesign, model: ParameterModel, base: BaseParameters) -> float:
    """Largest over smallest column norm of the stacked base regressor: a lower bound of raw cond(W)."""
    W = base.columns(model.regressor(*design.evaluate(grid(design, 1000))))
    norms = np.linalg.norm(W.reshape(-1, W.shape[-1]), axis=0)
    return float(norms.max() / norms.min())


def bench_system(system: str, *, n_random: int = 100) -> dict[str, Any]:
    """Every number of the table for one system (see the module's docstring)."""
    cfg, plant, limits, model, base = _setup(system)
    exc = OmegaConf.load(CONF_DIR / "excitation" / "optimised.yaml")
    options: dict[str, Any] = OmegaConf.to_container(exc.options)  # type: ignore[assignment]
    options["periods"] = float(cfg.periods)
    torque_driven = bool(cfg.torque_driven)
    kw: dict[str, Any] = {
        "model": model,
        "base": base,
        "harmonics": int(exc.harmonics),
        "base_freq_hz": float(cfg.base_freq_hz),
        "torque_driven": torque_driven,
    }
    cpu = time.process_time()
    opt = optimise_excitation(plant, limits, rng=np.random.default_rng(SEED), **kw, **options)
    cpu_s = time.process_time() - cpu
    row: dict[str, Any] = {
        "system": system,
        "harmonics": int(exc.harmonics),
        "criterion": opt.criterion,
        "starts": int(options["starts"]),
        "cond_XtX": opt.cond_XtX,
        "cond_W_colnorm": opt.cond_W_colnorm,
        "limits_ok": opt.limits_ok,
        "limit_ratios": opt.ratios,
        "time_s": opt.wall_s,
        "cpu_s": cpu_s,
        "start_conds": list(opt.start_conds),
        "final_conds": list(opt.final_conds),
    }
    W_bound = None
    if not torque_driven:
        W_bound = _column_bound(opt.design, model, base)
    row["cond_W"] = float(np.sqrt(opt.cond_XtX))
    row["cond_W_lower_bound"] = W_bound

    start = time.perf_counter()
    rng = np.random.default_rng(SEED + 1)
    conds = []
    for _ in range(n_random):
        d = random_design(plant, limits, rng=rng, **{k: kw[k] for k in ("harmonics", "base_freq_hz", "torque_driven")})
        conds.append(assess_design(plant, limits, d, model=model, base=base, torque_driven=torque_driven)[0])
    row["random"] = {
        "n": n_random,
        "median_cond_XtX": float(np.median(conds)),
        "min_cond_XtX": float(np.min(conds)),
        "time_s": time.perf_counter() - start,
    }
    row["ratio_to_random_median"] = opt.cond_XtX / row["random"]["median_cond_XtX"]

    if not torque_driven:  # the evolution strategy of torque designs has no finite-difference twin
        cpu = time.process_time()
        fd = optimise_excitation(
            plant, limits, rng=np.random.default_rng(SEED), **kw, **{**options, "gradient": "finite_difference"}
        )
        fd_cpu_s = time.process_time() - cpu
        row["finite_difference"] = {
            "cond_XtX": fd.cond_XtX,
            "time_s": fd.wall_s,
            "cpu_s": fd_cpu_s,
            "limits_ok": fd.limits_ok,
            "speedup": fd.wall_s / opt.wall_s,
            "speedup_cpu": fd_cpu_s / cpu_s,
            "cond_ratio": opt.cond_XtX / fd.cond_XtX,
            "evaluations": fd.evaluations,
        }
    row["evaluations"] = opt.evaluations
    return row


def _markdown(rows: list[dict[str, Any]], machine: str) -> str:
    ok = [r for r in rows if "error" not in r] or [{"criterion": "?", "harmonics": "?", "starts": "?"}]
    lines = [
        f"Excitation design (criterion {ok[0]['criterion']}, {ok[0]['harmonics']} harmonics, {ok[0]['starts']} starts, "
        f"limits from the system configs; {machine}).",
        "",
        "| system | optimised cond(XᵀX) | random median (n) | ratio | cond(W) / column-norm bound | limits "
        "| time [s] (CPU) | FD-SLSQP cond(XᵀX) | FD time [s] (CPU) | speed-up wall (CPU) | cond ratio |",
        "|---|---:|---:|---:|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['system']} | {r['error']} |" + " |" * 10)
            continue
        fd = r.get("finite_difference")
        bound = "n/a" if r["cond_W_lower_bound"] is None else f"{r['cond_W']:.4g} / {r['cond_W_lower_bound']:.4g}"
        fd_cols = (
            f"{fd['cond_XtX']:.4g} | {fd['time_s']:.2f} ({fd['cpu_s']:.2f}) | {fd['speedup']:.1f}x "
            f"({fd['speedup_cpu']:.1f}x) | {fd['cond_ratio']:.3f}"
            if fd
            else "n/a | n/a | n/a | n/a"
        )
        lines.append(
            f"| {r['system']} | {r['cond_XtX']:.4g} | {r['random']['median_cond_XtX']:.4g} ({r['random']['n']}) "
            f"| {r['ratio_to_random_median']:.3f} | {bound} | {'hold' if r['limits_ok'] else 'BROKEN'} "
            f"| {r['time_s']:.2f} ({r['cpu_s']:.2f}) | {fd_cols} |"
        )
    lines += [
        "",
        "ratio: optimised over the random median (target <= 0.2; cond(XᵀX) >= 1 makes it unreachable where the",
        "random median is below 5). Column-norm bound: largest over smallest column norm, a lower bound of raw",
        "cond(W) = sqrt(cond(XᵀX)). Speed-up and cond ratio: the finite-difference baseline (plain SLSQP, the same",
        "starts, constraints and criterion) over the analytic-gradient optimiser, in wall time and in this",
        "process's CPU time (which other load on the machine does not inflate). Torque-driven systems are",
        "optimised by an evolution strategy on batched rollouts, with no finite-difference twin.",
    ]
    return "\n".join(lines) + "\n"


def main(n_random: int = 100) -> list[dict[str, Any]]:
    """Benchmark every system with an MJCF and a config; write bench/excitation.json and .md."""
    rows = []
    for system in SYSTEMS:
        if not (MJCF_DIR / f"{system}.xml").is_file() or not (CONF_DIR / "system" / f"{system}.yaml").is_file():
            continue
        try:
            rows.append(bench_system(system, n_random=n_random))
        except SysIdError as err:  # a system the harness cannot condition: say why in the table
            rows.append({"system": system, "error": f"{type(err).__name__}: {err}"})
        print(json.dumps({k: rows[-1].get(k) for k in ("system", "cond_XtX", "ratio_to_random_median", "time_s")}))
    threads = os.environ.get("OPENBLAS_NUM_THREADS", "default")
    machine = f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, BLAS threads {threads}"
    (HERE / "excitation.json").write_text(json.dumps({"machine": machine, "systems": rows}, indent=2) + "\n")
    md = _markdown(rows, machine)
    (HERE / "excitation.md").write_text(md)
    print(md)
    return rows


if __name__ == "__main__":
    main()

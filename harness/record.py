"""Rerun recordings of a run: time series per joint, parameters against truth, excitation and convergence.

Only this module (and the other harness entry points) import rerun; the numerical core returns plain results.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from dynamics.plant import Plant
from envs.dataset import atomic_write
from harness.robot3d import log_robot

__all__ = ["log_joint_series", "run_blueprint", "save_recording"]


FLUSH_TIMEOUT_S = 120.0  # the longest wait for rerun's encoder to hand over a recording's bytes


def save_recording(path: Path, app_id: str, fill: Callable[[rr.RecordingStream], None]) -> None:
    """Create a recording, let `fill` log into it, and write the finished file to `path` (never half-written).

    The recording is encoded into memory and written by `atomic_write`, not by rerun's file sink: on a full
    disk that sink's flush waits forever (and so does `disconnect`), while a plain write fails at once with
    `OSError` (ENOSPC), and the wait for the encoder is bounded by `FLUSH_TIMEOUT_S`.
    """
    rec = rr.RecordingStream(app_id)
    stream = rr.binary_stream(recording=rec)
    fill(rec)
    data = stream.read(flush=True, flush_timeout_sec=FLUSH_TIMEOUT_S)
    atomic_write(Path(path), lambda f: f.write(data or b""), binary=True)


def log_joint_series(rec: rr.RecordingStream, entity: str, time: np.ndarray, values: np.ndarray) -> None:
    """One scalar series against the `time` timeline (seconds), sent in a single batch."""
    rec.send_columns(
        entity,
        indexes=[rr.TimeColumn("time", duration=np.asarray(time, dtype=float))],
        columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=float)),
    )


def run_blueprint(joint_names: tuple[str, ...], *, with_history: bool) -> rrb.Blueprint:
    """Layout of a run recording: per-joint torque and motion, parameters, excitation, convergence."""
    joint_views = [
        rrb.Vertical(
            rrb.TimeSeriesView(origin=f"/joints/{j}/tau", name=f"{j}: torque measured vs predicted"),
            rrb.TimeSeriesView(origin=f"/joints/{j}/motion", name=f"{j}: q, dq"),
        )
        for j in joint_names
    ]
    side: list[Any] = [
        rrb.TextDocumentView(origin="/parameters/table", name="parameters vs truth"),
        rrb.BarChartView(origin="/parameters/z", name="z = error / std"),
        rrb.TextDocumentView(origin="/excitation", name="excitation"),
    ]
    if with_history:
        side.append(rrb.TimeSeriesView(origin="/estimator/history", name="estimate over time"))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="/robot", name="robot replay"),
            rrb.Horizontal(*joint_views),
            rrb.Vertical(*side),
            column_shares=[2, 3, 2],
        ),
        collapse_panels=True,
    )


def record_run(path: Path, plant: Plant, results: dict[str, Any], series: dict[str, Any]) -> None:
    """Write the run recording.

    Args:
        plant: the simulated robot, replayed in 3D along the measured motion.
        results: the results dictionary (parameters, excitation summary).
        series: `time` (N,), `joint_names`, and per-joint arrays (N, nv): `q`, `dq`, `tau_measured`,
            `tau_predicted`; optional `history` {"time": (T,), "beta": (T, r)}.
    """
    names = tuple(series["joint_names"])
    history = series.get("history")

    def fill(rec: rr.RecordingStream) -> None:
        rec.send_blueprint(run_blueprint(names, with_history=history is not None))
        t = series["time"]
        log_robot(rec, plant, t, series["q"])
        for j, name in enumerate(names):
            log_joint_series(rec, f"joints/{name}/tau/measured", t, series["tau_measured"][:, j])
            log_joint_series(rec, f"joints/{name}/tau/predicted", t, series["tau_predicted"][:, j])
            log_joint_series(rec, f"joints/{name}/motion/q", t, series["q"][:, j])
            log_joint_series(rec, f"joints/{name}/motion/dq", t, series["dq"][:, j])
        params = results["base_parameters"]
        rec.log(
            "parameters/table", rr.TextDocument(_parameter_markdown(params), media_type="text/markdown"), static=True
        )
        rec.log("parameters/z", rr.BarChart(np.array([p["z"] or 0.0 for p in params], dtype=float)), static=True)
        rec.log(
            "excitation",
            rr.TextDocument(_excitation_markdown(results["excitation"]), media_type="text/markdown"),
            static=True,
        )
        if history is not None:
            for i, pname in enumerate(results["estimate_names"]):
                log_joint_series(rec, f"estimator/history/{i}_{_safe(pname)}", history["time"], history["beta"][:, i])

    save_recording(path, "sysid-run", fill)


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name).strip("_")


def _parameter_markdown(params: list[dict[str, Any]]) -> str:
    lines = ["| base parameter | true | estimate | std | z |", "|---|---:|---:|---:|---:|"]
    for p in params:
        lines.append(f"| {p['name']} | {p['true']:.6g} | {p['estimate']:.6g} | {p['std']:.2g} | {p['z']:+.2f} |")
    return "\n".join(lines)


def _excitation_markdown(ex: dict[str, Any]) -> str:
    lines = [f"**{ex['name']}**: {ex['harmonics']} harmonics, period {ex['period_s']:g} s", ""]
    lines.append(f"- cond(XᵀX) = {ex['cond_XtX']:.4g}; column-normalised cond(W) = {ex['cond_W_colnorm']:.4g}")
    lines.append(
        f"- limits {'hold' if ex['limits_ok'] else 'are broken'}: "
        + ", ".join(f"{k} {v:.2f}" for k, v in ex["limit_ratios"].items())
    )
    return "\n".join(lines)


def diagnosis_blueprint(joint_names: tuple[str, ...]) -> rrb.Blueprint:
    """Layout of a diagnosis recording: per joint, torque (measured, nominal, calibrated), the residuals and
    the re-started simulations against the measured angle; the robot; the findings."""
    joint_views = [
        rrb.Vertical(
            rrb.TimeSeriesView(origin=f"/joints/{j}/tau", name=f"{j}: torque measured / nominal / calibrated"),
            rrb.TimeSeriesView(origin=f"/joints/{j}/residual", name=f"{j}: residual (measured - model)"),
            rrb.TimeSeriesView(origin=f"/joints/{j}/q", name=f"{j}: q measured vs re-started simulation"),
        )
        for j in joint_names
    ]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial3DView(origin="/robot", name="measured motion"),
                rrb.TextDocumentView(origin="/findings", name="findings and models"),
            ),
            rrb.Horizontal(*joint_views),
            column_shares=[2, 3],
        ),
        collapse_panels=True,
    )


def record_diagnosis(path: Path, plant: Plant, result: Any, findings_markdown: str) -> None:
    """Write the diagnosis recording from a `Diagnosis`'s series (time, torques, residuals, simulations)."""
    s = result.series
    names = tuple(s["joint_names"])

    def fill(rec: rr.RecordingStream) -> None:
        rec.send_blueprint(diagnosis_blueprint(names))
        t, ts = s["time"], s["sim_time"]
        log_robot(rec, plant, t, s["q_measured"])
        for j, name in enumerate(names):
            for kind in ("measured", "nominal", "calibrated"):
                log_joint_series(rec, f"joints/{name}/tau/{kind}", t, s[f"tau_{kind}"][:, j])
            for kind in ("nominal", "calibrated"):
                log_joint_series(
                    rec, f"joints/{name}/residual/{kind}", t, s["tau_measured"][:, j] - s[f"tau_{kind}"][:, j]
                )
            log_joint_series(rec, f"joints/{name}/q/measured", t, s["q_measured"][:, j])
            log_joint_series(rec, f"joints/{name}/q/simulated_nominal", ts, s["q_nominal"][:, j])
            log_joint_series(rec, f"joints/{name}/q/simulated_calibrated", ts, s["q_calibrated"][:, j])
        rec.log("findings", rr.TextDocument(findings_markdown, media_type="text/markdown"), static=True)

    save_recording(path, "sysid-diagnose", fill)

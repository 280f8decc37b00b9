"""Rerun recordings of a run and of a diagnosis, laid out so that a reader sees what they show at a glance.

One colour per role in every panel of every recording (`ROLE_COLORS`): the measurement, the nominal model,
the identified or calibrated model and a reference (truth, joint limits, noise floor, thresholds). Every
series is named (the legend), every panel title carries its unit, q and dq are in separate panels with the
joint limits drawn, and the 3D view opens framed on the whole robot with its mount and the world axes.

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
from harness.robot3d import camera, log_robot, log_scene

__all__ = [
    "ROLE_COLORS",
    "diagnosis_blueprint",
    "log_joint_series",
    "parameter_entity",
    "record_diagnosis",
    "record_run",
    "recording_bytes",
    "run_blueprint",
    "save_recording",
    "style_series",
]

# Okabe-Ito colours (distinct for colour-blind readers); measured is a mid grey, drawn widest, so that it reads
# on the viewer's light and dark themes alike and stays visible around a model line that fits it to the noise.
ROLE_COLORS: dict[str, tuple[int, int, int]] = {
    "measured": (120, 120, 120),
    "nominal": (230, 159, 0),
    "model": (86, 180, 233),
    "reference": (204, 121, 167),
}
_WIDTH = {"measured": 2.5, "nominal": 1.5, "model": 1.5, "reference": 1.0}
_GHOST_ALPHA = 110


FLUSH_TIMEOUT_S = 120.0  # the longest wait for rerun's encoder to hand over a recording's bytes


def recording_bytes(app_id: str, fill: Callable[[rr.RecordingStream], None]) -> bytes:
    """Create a recording, let `fill` log into it, and return the finished .rrd file's bytes, encoded in memory
    (the wait for the encoder bounded by `FLUSH_TIMEOUT_S`)."""
    rec = rr.RecordingStream(app_id)
    stream = rr.binary_stream(recording=rec)
    fill(rec)
    return stream.read(flush=True, flush_timeout_sec=FLUSH_TIMEOUT_S) or b""


def save_recording(path: Path, app_id: str, fill: Callable[[rr.RecordingStream], None]) -> None:
    """`recording_bytes` written to `path` (never half-written).

    The recording is encoded into memory and written by `atomic_write`, not by rerun's file sink: on a full
    disk that sink's flush waits forever (and so does `disconnect`), while a plain write fails at once with
    `OSError` (ENOSPC).
    """
    data = recording_bytes(app_id, fill)
    atomic_write(Path(path), lambda f: f.write(data), binary=True)


def log_joint_series(rec: rr.RecordingStream, entity: str, time: np.ndarray, values: np.ndarray) -> None:
    """One scalar series against the `time` timeline (seconds), sent in a single batch."""
    rec.send_columns(
        entity,
        indexes=[rr.TimeColumn("time", duration=np.asarray(time, dtype=float))],
        columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=float)),
    )


def style_series(rec: rr.RecordingStream, entity: str, role: str, name: str) -> None:
    """The series at `entity` drawn in `role`'s colour and named `name` in the legend."""
    if role not in ROLE_COLORS:
        raise ValueError(f"unknown role {role!r}; valid roles: {', '.join(ROLE_COLORS)}")
    rec.log(entity, rr.SeriesLines(colors=[ROLE_COLORS[role]], widths=[_WIDTH[role]], names=[name]), static=True)


def _series(rec: rr.RecordingStream, entity: str, time: np.ndarray, values: np.ndarray, role: str, name: str) -> None:
    style_series(rec, entity, role, name)
    log_joint_series(rec, entity, time, values)


def _level(rec: rr.RecordingStream, entity: str, time: np.ndarray, value: float | None, name: str) -> None:
    """A horizontal reference line at `value` over the span of `time` (nothing when the value is unbounded)."""
    if value is None or not np.isfinite(value):
        return
    _series(rec, entity, np.array([time[0], time[-1]]), np.array([value, value]), "reference", name)


def _legend_view(origin: str, name: str) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(
        origin=origin,
        name=name,
        plot_legend=rrb.PlotLegend(corner=rrb.Corner2D.LeftTop, visible=True),
    )


def _robot_view(origin: str, name: str, eye: dict[str, list[float]]) -> rrb.Spatial3DView:
    return rrb.Spatial3DView(
        origin=origin,
        name=name,
        eye_controls=rrb.EyeControls3D(
            kind=rrb.Eye3DKind.Orbital,
            position=eye["position"],
            look_target=eye["look_target"],
            eye_up=eye["eye_up"],
        ),
        line_grid=rrb.LineGrid3D(visible=True),
    )


def run_blueprint(
    joint_names: tuple[str, ...], *, with_history: bool, eye: dict[str, list[float]] | None = None
) -> rrb.Blueprint:
    """Layout of a run recording: the robot; per joint torque, residual, q and dq; parameters, excitation."""
    joint_views = [
        rrb.Vertical(
            _legend_view(f"/joints/{j}/tau", f"{j}: torque [N m]"),
            _legend_view(f"/joints/{j}/residual", f"{j}: residual [N m]"),
            _legend_view(f"/joints/{j}/q", f"{j}: q [rad]"),
            _legend_view(f"/joints/{j}/dq", f"{j}: dq [rad/s]"),
        )
        for j in joint_names
    ]
    side: list[Any] = [
        rrb.TextDocumentView(origin="/parameters/table", name="base parameters vs truth"),
        rrb.BarChartView(
            origin="/parameters/z",
            name="z = (estimate - truth) / std [1]",
            plot_legend=rrb.PlotLegend(corner=rrb.Corner2D.RightTop, visible=True),
        ),
        rrb.TextDocumentView(origin="/excitation", name="excitation"),
    ]
    if with_history:
        side.append(_legend_view("/estimator/history", "estimate over time [SI]"))
    robot = _robot_view("/robot", "robot replay (measured motion)", eye or _DEFAULT_EYE)
    return rrb.Blueprint(
        rrb.Horizontal(robot, rrb.Horizontal(*joint_views), rrb.Vertical(*side), column_shares=[2, 3, 2]),
        collapse_panels=True,
    )


_DEFAULT_EYE = {"position": [0.0, -2.0, 1.0], "look_target": [0.0, 0.0, 0.0], "eye_up": [0.0, 0.0, 1.0]}


def record_run(path: Path, plant: Plant, results: dict[str, Any], series: dict[str, Any]) -> None:
    """Write the run recording.

    Args:
        plant: the simulated robot, replayed in 3D along the measured motion.
        results: the results dictionary (parameters, excitation summary with its limits, validation noise std).
        series: `time` (N,), `joint_names`, and per-joint arrays (N, nv): `q`, `dq`, `tau_measured`,
            `tau_predicted`; optional `history` {"time": (T,), "beta": (T, r)}.
    """
    names = tuple(series["joint_names"])
    history = series.get("history")
    limits = results["excitation"].get("limits", {})
    noise = results.get("validation", {}).get("noise_std", {})

    def fill(rec: rr.RecordingStream) -> None:
        t, q = series["time"], series["q"]
        eye = camera(plant, q)
        rec.send_blueprint(run_blueprint(names, with_history=history is not None, eye=eye))
        log_scene(rec, plant, q)
        log_robot(rec, plant, t, q, entity="robot/measured", rgba=(*ROLE_COLORS["measured"], 255))
        for j, name in enumerate(names):
            base = f"joints/{name}"
            measured, predicted = series["tau_measured"][:, j], series["tau_predicted"][:, j]
            _series(rec, f"{base}/tau/measured", t, measured, "measured", "measured [N m]")
            _series(rec, f"{base}/tau/model", t, predicted, "model", "identified model [N m]")
            _series(rec, f"{base}/residual/model", t, measured - predicted, "model", "measured - model [N m]")
            sigma = noise.get(name)
            if sigma:
                _level(rec, f"{base}/residual/noise_plus", t, 2.0 * sigma, "+2 sensor noise std [N m]")
                _level(rec, f"{base}/residual/noise_minus", t, -2.0 * sigma, "-2 sensor noise std [N m]")
            _series(rec, f"{base}/q/measured", t, q[:, j], "measured", "q measured [rad]")
            _series(rec, f"{base}/dq/measured", t, series["dq"][:, j], "measured", "dq measured [rad/s]")
            for key, sign, label, unit, panel in (
                ("q_min", 1.0, "q min", "rad", "q"),
                ("q_max", 1.0, "q max", "rad", "q"),
                ("dq_max", 1.0, "+dq limit", "rad/s", "dq"),
                ("dq_max", -1.0, "-dq limit", "rad/s", "dq"),
            ):
                values = limits.get(key)
                if values is not None and values[j] is not None:
                    suffix = "minus" if sign < 0 else "plus"
                    _level(rec, f"{base}/{panel}/limit_{key}_{suffix}", t, sign * values[j], f"{label} [{unit}]")
        _log_parameters(rec, results["base_parameters"])
        rec.log(
            "excitation",
            rr.TextDocument(_excitation_markdown(results["excitation"]), media_type="text/markdown"),
            static=True,
        )
        if history is not None:
            for i, pname in enumerate(results["estimate_names"]):
                entity = f"estimator/history/{i}_{_safe(pname)}"
                rec.log(entity, rr.SeriesLines(names=[pname]), static=True)
                log_joint_series(rec, entity, history["time"], history["beta"][:, i])

    save_recording(path, "sysid-run", fill)


def _log_parameters(rec: rr.RecordingStream, params: list[dict[str, Any]]) -> None:
    """The table, and one named bar per base parameter (its z) over the reference band |z| <= 2."""
    rec.log("parameters/table", rr.TextDocument(_parameter_markdown(params), media_type="text/markdown"), static=True)
    # rerun draws a bar from its abscissa to abscissa + width: bar i spans [i, i + 0.7], the band all of them
    n = len(params)
    band = (*ROLE_COLORS["reference"], 70)
    for sign, label in ((1.0, "band_plus_2_std"), (-1.0, "band_minus_2_std")):
        rec.log(
            f"parameters/z/{label}",
            rr.BarChart([2.0 * sign], abscissa=[-0.15], widths=[float(n)], color=band),
            static=True,
        )
    for i, p in enumerate(params):
        z = p["z"] if p["z"] is not None else 0.0
        rec.log(
            f"parameters/z/{parameter_entity(i, p['name'])}",
            rr.BarChart([float(z)], abscissa=[float(i)], widths=[0.7], color=ROLE_COLORS["model"]),
            static=True,
        )


def parameter_entity(index: int, name: str) -> str:
    """The z bar's entity name (the legend's label) of base parameter `index` named `name`: `p3_YY1_0.04m2_Ia1`."""
    text = name.replace(" ", "").replace("+", "_").replace("*", "").replace("-", "_minus_")
    return f"p{index}_" + "".join(c if c.isalnum() or c in "._" else "_" for c in text).strip("_")


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name).strip("_")


def _parameter_markdown(params: list[dict[str, Any]]) -> str:
    lines = ["| # | base parameter | true | estimate | std | z |", "|---:|---|---:|---:|---:|---:|"]
    for i, p in enumerate(params):
        z = "-" if p["z"] is None else f"{p['z']:+.2f}"
        std = "-" if p["std"] is None else f"{p['std']:.2g}"
        lines.append(f"| {i} | {p['name']} | {p['true']:.6g} | {p['estimate']:.6g} | {std} | {z} |")
    lines += ["", "Bars: z of each parameter, p# numbered as here; shaded: the |z| <= 2 band."]
    return "\n".join(lines)


def _excitation_markdown(ex: dict[str, Any]) -> str:
    lines = [f"**{ex['name']}**: {ex['harmonics']} harmonics, period {ex['period_s']:g} s", ""]
    lines.append(f"- cond(XᵀX) = {ex['cond_XtX']:.4g}; column-normalised cond(W) = {ex['cond_W_colnorm']:.4g}")
    lines.append(
        f"- limits {'hold' if ex['limits_ok'] else 'are broken'} (largest use of each bound, 1 = at the bound): "
        + ", ".join(f"{k} {v:.2f}" for k, v in ex["limit_ratios"].items())
    )
    return "\n".join(lines)


def _record_key(i: int, source: str) -> str:
    return f"{i}_{_safe(Path(source).stem) or 'record'}"


def diagnosis_blueprint(
    joint_names: tuple[str, ...],
    records: list[tuple[str, str]],
    *,
    band: str,
    eyes: list[dict[str, list[float]]] | None = None,
) -> rrb.Blueprint:
    """Layout of a diagnosis recording: one tab per validation record (named by its file) with the measured
    motion and the ghosts of the simulated nominal and calibrated arms, and per joint the torques, the
    residuals in the analysis band and the re-started simulations against the measured angle; the findings
    beside.

    Args:
        records: (entity key, display name) per validation record.
        band: how the torques are compared, for the titles ("0-4 Hz band", "unfiltered").
        eyes: the 3D camera per record.
    """
    tabs = []
    for k, (key, label) in enumerate(records):
        root = f"/validation/{key}"
        joint_views = [
            rrb.Vertical(
                _legend_view(f"{root}/joints/{j}/tau", f"{j}: torque, {band} [N m]"),
                _legend_view(f"{root}/joints/{j}/residual", f"{j}: residual, {band} [N m]"),
                _legend_view(f"{root}/joints/{j}/q", f"{j}: q, re-started sims [rad]"),
            )
            for j in joint_names
        ]
        eye = eyes[k] if eyes else _DEFAULT_EYE
        tabs.append(
            rrb.Horizontal(
                _robot_view(f"{root}/robot", f"{label}: measured arm, simulated ghosts", eye),
                rrb.Horizontal(*joint_views),
                column_shares=[2, 3],
                name=label,
            )
        )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Tabs(*tabs, active_tab=0, name="validation records"),
            rrb.TextDocumentView(origin="/findings", name="findings and models"),
            column_shares=[5, 2],
        ),
        collapse_panels=True,
    )


_CRITERIA = {
    "explained": (
        "at least one effect passed the selection on the training records: BIC drop > {bic_margin:g}, "
        "held-out MSE gain >= {min_gain:g} (>= {min_gain_records:g} across records), |z| >= {min_z:g}; where each "
        "of 3+ records held out in turn gains >= {min_gain_records:g}, any BIC drop (none for the viscous part of a "
        "frictionloss just named, which must beat the frictionloss's other shapes) and |z| >= {min_z_records:g}"
    ),
    "unexplained_structure": (
        "no effect passed the selection, yet the nominal residual on the validation records is not white "
        "(structure above the noise floor that no candidate explains)"
    ),
    "no_discrepancy": (
        "no effect passed the selection and the nominal residual on the validation records is white at the noise floor"
    ),
}


def _criterion(verdict: str, selection: dict[str, Any]) -> str:
    template = _CRITERIA.get(verdict)
    if template is None:
        return "(no criterion recorded for this verdict)"
    try:
        return template.format(**selection)
    except (KeyError, ValueError):
        return template.split(":")[0]


def _windows_note(windows: dict | None) -> str:
    """The end of the header's sentence on the re-started simulations: which of their windows are shown."""
    if not windows or windows["simulated"] >= windows["of"]:
        return "."
    return (
        f" ({windows['simulated']} of the {windows['of']} windows, spread evenly over the records: "
        "`diagnose.max_windows`; the gaps between them are not simulated)."
    )


def _band_label(band_hz: float | None) -> str:
    return f"0-{band_hz:g} Hz band" if band_hz is not None else "unfiltered"


def record_diagnosis(
    path: Path, plant: Plant, result: Any, findings_markdown: str, *, dataset: str = "", calibrated: Plant | None = None
) -> None:
    """Write the diagnosis recording from a `Diagnosis`'s validation series.

    The torques and residuals plotted are those the table's torque RMS is computed from (measured and model
    torque, both in the analysis band, record by record), so the recording and diagnosis.json agree.

    Args:
        plant: the nominal robot (the measured arm and the nominal ghost are drawn with it).
        result: the `Diagnosis`; its `series["records"]` holds one dict per validation record.
        findings_markdown: the findings and model table.
        dataset: the data set's name for the findings panel (the data config's name and files).
        calibrated: the calibrated robot for its ghost (the nominal geometry when None: a calibration changes
            dynamics, not shapes).
    """
    s = result.series
    names = tuple(s["joint_names"])
    band = _band_label(s.get("band_hz"))
    records = [(_record_key(i, r["source"]), Path(r["source"]).name) for i, r in enumerate(s["records"])]
    selection = dict(result.info.get("selection", {}))
    header = [
        f"**data set:** {dataset or ', '.join(label for _, label in records)}",
        f"**validation records:** {', '.join(label for _, label in records)} (one tab each)",
        f"**verdict: {result.verdict}**: {_criterion(result.verdict, selection)}",
        f"**why, on these data:** {result.verdict_reason or '(not recorded)'}",
        f"Torques and residuals are compared in the {band}, as in the table below; the q panels re-start the "
        f"simulations from the measured state every {result.info.get('window_s', 0.25):g} s"
        + _windows_note(result.info.get("simulation_windows")),
    ]
    body = "\n".join(ln for ln in findings_markdown.splitlines() if not ln.startswith("**verdict"))
    ghost_plant = calibrated or plant

    def fill(rec: rr.RecordingStream) -> None:
        eyes = [camera(plant, r["q_measured"]) for r in s["records"]]
        rec.send_blueprint(diagnosis_blueprint(names, records, band=band, eyes=eyes))
        for (
            (key, _),
            r,
        ) in zip(records, s["records"], strict=True):
            root = f"validation/{key}"
            t, ts = r["time"], r["sim_time"]
            log_scene(rec, plant, r["q_measured"], entity=f"{root}/robot")
            log_robot(
                rec,
                plant,
                r["q_time"],
                r["q_measured"],
                entity=f"{root}/robot/measured",
                rgba=(*ROLE_COLORS["measured"], 255),
            )
            log_robot(
                rec,
                plant,
                ts,
                r["q_nominal"],
                entity=f"{root}/robot/nominal_ghost",
                rgba=(*ROLE_COLORS["nominal"], _GHOST_ALPHA),
            )
            log_robot(
                rec,
                ghost_plant,
                ts,
                r["q_calibrated"],
                entity=f"{root}/robot/calibrated_ghost",
                rgba=(*ROLE_COLORS["model"], _GHOST_ALPHA),
            )
            for j, name in enumerate(names):
                base = f"{root}/joints/{name}"
                meas = r["tau_measured"][:, j]
                _series(rec, f"{base}/tau/measured", t, meas, "measured", "measured [N m]")
                _series(rec, f"{base}/tau/nominal", t, r["tau_nominal"][:, j], "nominal", "nominal MJCF [N m]")
                _series(rec, f"{base}/tau/calibrated", t, r["tau_calibrated"][:, j], "model", "calibrated [N m]")
                _series(
                    rec,
                    f"{base}/residual/nominal",
                    t,
                    meas - r["tau_nominal"][:, j],
                    "nominal",
                    "measured - nominal [N m]",
                )
                _series(
                    rec,
                    f"{base}/residual/calibrated",
                    t,
                    meas - r["tau_calibrated"][:, j],
                    "model",
                    "measured - calibrated [N m]",
                )
                floor = result.noise_floor.get(name)
                if floor:
                    _level(rec, f"{base}/residual/noise_plus", t, float(floor), "+noise floor [N m]")
                    _level(rec, f"{base}/residual/noise_minus", t, -float(floor), "-noise floor [N m]")
                _series(rec, f"{base}/q/measured", r["q_time"], r["q_measured"][:, j], "measured", "measured [rad]")
                _series(rec, f"{base}/q/simulated_nominal", ts, r["q_nominal"][:, j], "nominal", "nominal sim [rad]")
                _series(
                    rec, f"{base}/q/simulated_calibrated", ts, r["q_calibrated"][:, j], "model", "calibrated sim [rad]"
                )
        text = "\n\n".join(header) + "\n\n" + body.strip("\n")
        rec.log("findings", rr.TextDocument(text, media_type="text/markdown"), static=True)

    save_recording(path, "sysid-diagnose", fill)

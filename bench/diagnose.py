"""The discrepancy diagnosis benchmarked: hidden effects on simulated data, and real logs file by file.

1. **Hidden effects** (`hidden_effect_table`; `several_records_table` for three training records, with
   effects the same in every record or a torque zero that changes between them): data from the independent generator of
   `identify.diagnose.testbed` (its own MuJoCo stepping loop, PD control and multi-sine excitation, not
   `envs.simulate`) with one effect hidden in the plant or the sensor, diagnosed against the clean MJCF
   on a held-out record of another excitation: what is named first, its value against the truth, the
   verdict and the validation torque RMS before and after. `arm_effect_table` does the same on four Menagerie
   arms of ../shared/robots/ (the UR5e, the Panda, the Kinova Gen3 and the xArm7, driven by torque) over seeds 0-3, and
   counts how often the stds cover the truth. `servo_log_table` logs the same arms through their own servos at
   MuJoCo's own step, as MuJoCo users write logs (positions and actuator force at each step).
   `pinocchio_table` makes every record with a plant that owes nothing to MuJoCo either: the model as
   Pinocchio's own MJCF parser reads it, integrated by RK4 of its articulated-body algorithm under a PD loop with
   gravity feed-forward tracking chirps (every built-in system and three Menagerie arms, seeds 0-3).
   `lab_model_table` does it with a generator that owes nothing to MuJoCo: the DFKI lab's own analytic model
   (their equations and identified parameters, or the nominal MJCF's numbers in their form) integrated by SciPy
   under open-loop sinusoidal torques.
2. **Real logs, leave one file out** (`lofo_table`): for each DFKI session (design C.0 and its rebuild C.1)
   every one of the shared files is held out in turn; the diagnosis is fitted on the other four and its
   calibrated MJCF is judged on the held-out file by inverse dynamics through MuJoCo
   (`identify.diagnose.calibrate.mjcf_measured_torque`) with zero-phase 5 Hz filtering (4th-order
   Butterworth, forward-backward, of the joint angles before differentiation and of the measured torque),
   against the lab's identified models evaluated on the same states. Every split is reported; none is
   chosen. A second table low-passes every model's torque as well (both sides filtered, as the diagnosis
   fits), the other reading of "zero-phase 5 Hz filtering". Each calibrated MJCF is also judged with its
   friction rewritten as wider ramps (`widened`, `RAMPS`): how much each reading depends on the friction's
   shape near zero speed. Another judges the calibrated MJCF's joint torque from MuJoCo's `mj_inverse` alone
   (`mujoco_only`: `qfrc_inverse`, without the actuators' gain and bias or the file's `sysid_*` custom
   numerics). A last reading gives every model the held-out file's own angle zero (`_angle_zeroed`,
   found on that file): the encoders are zeroed wherever each file began, and what a model loses with it known
   is not the zero. `moving` judges each joint only on the rows where it moves (`_moving_rows`): where it rests
   or turns round its inverse dynamics is a set within +-Fc, not a value. Each reading is also pooled over every
   held-out row of a session (`cross_validated`: each file held out once, weighed by its judged rows), the
   session's leave-one-file-out RMS, against each lab model's on the same rows.
3. **What the shared files allow** (`lab_form`): the lab's own model form (`authors.author_regressor`: rigid
   body, rotor inertia through the gear, viscous and atan Coulomb friction) refitted by least squares in the
   judging band, on the same states as the judge, (a) on the other files of the split and (b) on all of the
   session's shared files, the held-out one included (an in-sample bound, not a validation). The lab fitted its
   models on the whole session (fourteen files for C.0), the held-out file among them; where even (b) loses
   to the lab's model on a joint, no fit to these files with one parameter set for all of them reaches the
   lab's number there, and the split is a statement about the data, not about the diagnosis. The diagnosis
   itself is fitted on all of the session's files as well (`calibrated_all`, one calibrated MJCF judged on each
   file): its own in-sample bound.
4. **More files** (`three_files`): each split fitted again on every three of its four training files, judged on
   the same held-out file: whether a fit on more files predicts a file it never saw better (why `sysid-diagnose`
   also writes `<system>_calibrated_all.xml`, the diagnosis run on every record).
5. **An angle zero per file** (`angle_zeros_markdown`): every split fitted again with an angle offset per training
   file as a nuisance (`ANGLE_ZEROS`: the logs' encoders are zeroed at each file's start, where the arm rested),
   against the default fit and the lab's best, with each file's offset as the fit on every file finds it.

Writes bench/diagnose.json and bench/diagnose.md. Re-run: `python -m bench diagnose`
(`python -m bench.diagnose lofo`, `hidden`, `arms`, `servos` or `lab` for one part).
`python -m bench.diagnose lofo KEY=VALUE ...` runs the splits with Hydra overrides of the diagnosis (such as
`diagnose.record_offsets=true`) and prints the summary only, writing nothing.
"""

from __future__ import annotations

import copy
import json
import sys
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from scipy import optimize, signal

from bench._coverage import SHARED_ROBOTS as ROBOTS
from dynamics.friction import friction_solver
from dynamics.plant import load_plant
from dynamics.torque import inverse_dynamics
from envs.dataset import Dataset
from envs.measured import read_many
from harness.diagnose import derivative_options, record_joint_offsets, record_offsets
from harness.setup import CONF_DIR
from identify.derivatives import States, derive_states
from identify.diagnose import SelectionOptions, author_torque, diagnose, load_author_model, with_found_lead
from identify.diagnose.authors import author_regressor
from identify.diagnose.calibrate import mjcf_measured_torque
from identify.diagnose.diagnosis import SLIDING_FRACTION

HERE = Path(__file__).resolve().parent
SHARED = HERE.parents[1] / "shared" / "data"
JUDGE_HZ = 5.0  # zero-phase low-pass of the judged signals [Hz]
RAMPS = (0.03, 0.1, 0.3)  # friction ramp widths the calibrated models are also judged with [rad/s]
ANGLE_ZERO_STEP = 0.05  # [rad] first step of the search for a judged file's own angle zero
# session -> (data config, folder, the lab's models to beat: the best of them per joint)
SESSIONS = {
    "C.0": ("dfki_double_pendulum", "dfki_double_pendulum_c0", ("3.0",)),
    "C.1": ("dfki_double_pendulum_c1", "dfki_double_pendulum_c1", ("1.0", "2.0")),
}


def _lowpass(x: np.ndarray, fs: float) -> np.ndarray:
    sos = signal.butter(4, JUDGE_HZ, fs=fs, output="sos")
    return signal.sosfiltfilt(sos, x, axis=0)


def _judged_states(data: Dataset) -> tuple[States, np.ndarray]:
    """(States from the 5 Hz zero-phase filter of the angles, on every row; the measured torque filtered alike,
    (N_valid, nv), on the rows the filter trusts, `states.valid`)."""
    states = derive_states(data, "butterworth", cutoff_hz=JUDGE_HZ)
    return states, _lowpass(data.tau, 1.0 / data.dt)[states.valid]


def _judged(data: Dataset) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What every model is judged on: time (N,), q, dq, ddq and the measured torque (`_judged_states`), each
    (N, nv), on the rows the filter trusts."""
    states, measured = _judged_states(data)
    rows = states.valid
    return data.time[rows], states.q[rows], states.dq[rows], states.ddq[rows], measured


def widened(model: mujoco.MjModel, speed: float) -> mujoco.MjModel:
    """A copy of `model` whose every joint friction is MuJoCo's ramp Fc sat(dq / speed) (`dynamics.friction`),
    its Fc unchanged: how much the judged RMS depends on the friction's shape near zero speed."""
    out = copy.deepcopy(model)
    for j in np.flatnonzero(out.dof_frictionloss > 0):
        solref, solimp, _ = friction_solver(
            float(out.dof_frictionloss[j]), speed, float(out.dof_invweight0[j]), float(out.opt.timestep)
        )
        out.dof_solref[j], out.dof_solimp[j] = solref, solimp
    return out


def _angle_zeroed(
    predict: Callable[[np.ndarray], np.ndarray], q: np.ndarray, measured: np.ndarray, rows: np.ndarray
) -> tuple[list[float], list[float]]:
    """A model given the judged file's own angle zero: the constant (nv,) shift d of its angles [rad] (true =
    reported + d) that minimises the model's squared torque error over every joint, found on the file itself.
    `predict(q)`: the model's (N, nv) torque at angles q. Returns the (nv,) RMS [N m] at that shift, and d."""

    def cost(d: np.ndarray) -> float:
        return float(np.sum((measured - predict(q + d)[rows]) ** 2))

    start = np.zeros(q.shape[1])
    simplex = np.vstack([start, np.diag(np.full(q.shape[1], ANGLE_ZERO_STEP))])
    d = optimize.minimize(
        cost, start, method="Nelder-Mead", options={"initial_simplex": simplex, "xatol": 1e-4, "fatol": 1e-9}
    ).x
    return np.sqrt(np.mean((measured - predict(q + d)[rows]) ** 2, axis=0)).tolist(), d.tolist()


def judge(
    xml_path: Path,
    authors: dict[str, dict[str, float]],
    data: Dataset,
    ramps: tuple[float, ...] = (),
    *,
    angle_zero: bool = False,
) -> dict[str, dict[str, Any]]:
    """Per reading, per model: (nv,) torque RMS [N m] on `data` in the 5 Hz judging band. `torque_rms`: each model
    evaluated unfiltered on the filtered states; `both_filtered`: its torque low-passed as well (as the diagnosis
    fits); `demeaned`: the first reading's error with its own mean over the file taken out (what is left once a
    torque zero of the file's own is allowed); `angle_zeroed`, with `angle_zero` (else empty): the first reading
    with the file's own angle zero given to each model (`_angle_zeroed`), per model [RMS, shift]; `mujoco_only`:
    the first reading with the calibrated MJCF's joint torque from MuJoCo's `mj_inverse` alone
    (`inverse_dynamics`: `qfrc_inverse`, without the actuators' gain and bias or the file's `sysid_*` custom
    numerics: no torque sensor offset or gain, delay or custom friction law); `moving`: the first reading on each
    joint's `_moving_rows` only (plus `moving_share`, (nv,) the share of the rows each joint keeps); `rows`: the
    number of rows judged (those the filter trusts), by which a file weighs in a session's pooled RMS. `ramps`: also
    the calibrated model with its friction `widened` to each of these widths [rad/s] (`calibrated_ramp_<width>`),
    in the first two readings."""
    states, measured = _judged_states(data)
    rows, fs = states.valid, 1.0 / data.dt
    model = mujoco.MjModel.from_xml_path(str(xml_path))
    predictors: dict[str, Callable[[np.ndarray], np.ndarray]] = {
        "calibrated": lambda q: mjcf_measured_torque(model, data.time, q, states.dq, states.ddq)
    }
    for name, p in authors.items():
        predictors[name] = lambda q, p=p: author_torque(p, q, states.dq, states.ddq)  # type: ignore[misc]
    preds = {k: f(states.q) for k, f in predictors.items()}
    for speed in ramps:
        preds[f"calibrated_ramp_{speed:g}"] = mjcf_measured_torque(
            widened(model, speed), data.time, states.q, states.dq, states.ddq
        )
    zeroed = {k: list(_angle_zeroed(f, states.q, measured, rows)) for k, f in predictors.items() if angle_zero}

    def rms(pred: dict[str, np.ndarray]) -> dict[str, list[float]]:
        return {k: np.sqrt(np.mean((measured - v[rows]) ** 2, axis=0)).tolist() for k, v in pred.items()}

    native = {
        **{k: v for k, v in preds.items() if k in authors},
        "calibrated": inverse_dynamics(model, states.q, states.dq, states.ddq),
    }
    moving = _moving_rows(states.dq[rows])
    return {
        "torque_rms": rms(preds),
        "both_filtered": rms({k: _lowpass(v, fs) for k, v in preds.items()}),
        "demeaned": {k: np.std(measured - v[rows], axis=0).tolist() for k, v in preds.items()},
        "angle_zeroed": zeroed,
        "mujoco_only": rms(native),
        "moving": {
            k: [float(np.sqrt(np.mean((measured[m, j] - v[rows][m, j]) ** 2))) for j, m in enumerate(moving.T)]
            for k, v in preds.items()
            if k in authors or k == "calibrated"
        },
        "moving_share": moving.mean(axis=0).tolist(),
        "rows": len(measured),
    }


def _moving_rows(dq: np.ndarray) -> np.ndarray:
    """(N, nv) True where a joint moves faster than `SLIDING_FRACTION` of its RMS speed in the file (the
    diagnosis's own rule, `identify.diagnose.diagnosis._slow_rows`). Slower, it rests or turns round: its friction
    is anywhere within +-Fc and the inverse dynamics is a set, not a value; on a joint commanded zero torque the
    drive's current-based torque is 0 there whatever holds the link."""
    return np.abs(dq) > SLIDING_FRACTION * np.sqrt(np.mean(dq**2, axis=0))


def lab_form(datasets: list[Dataset], p: dict[str, float]) -> dict[str, list[list[float]]]:
    """The lab's model form refitted on the shared files (see the module docstring, part 3).

    Args:
        datasets: the session's files.
        p: one of the lab's parameter sets (for the fixed l1, g, gr).

    Returns:
        `others`: per file, (nv,) torque RMS [N m] of the form fitted on the other files; `all`: the same
        fitted once on every file, that one included; `self`: fitted on that file alone (the best the form does
        on it: a floor no fit of the form to other data goes below). In the judging band, equal weight per sample.
    """
    judged = [_judged(d) for d in datasets]
    Y = [author_regressor(q, dq, ddq, l1=p["l1"], g=p["g"], gr=p["gr"]) for _, q, dq, ddq, _ in judged]
    tau = [j[4] for j in judged]

    def fit(rows: list[int]) -> np.ndarray:
        A = np.concatenate([Y[i].reshape(-1, Y[i].shape[2]) for i in rows])
        b = np.concatenate([tau[i].reshape(-1) for i in rows])
        return np.linalg.lstsq(A, b, rcond=None)[0]  # type: ignore[no-any-return]

    def rms(k: int, coef: np.ndarray) -> list[float]:
        return np.sqrt(np.mean((tau[k] - Y[k] @ coef) ** 2, axis=0)).tolist()  # type: ignore[no-any-return]

    every = fit(list(range(len(datasets))))
    return {
        "others": [rms(k, fit([i for i in range(len(datasets)) if i != k])) for k in range(len(datasets))],
        "all": [rms(k, every) for k in range(len(datasets))],
        "self": [rms(k, fit([k])) for k in range(len(datasets))],
    }


def _session_config(data_config: str, overrides: tuple[str, ...] = ()) -> Any:
    with initialize_config_dir(str(CONF_DIR), version_base=None):
        return compose("diagnose", overrides=["system=two_link", f"data={data_config}", *overrides])


def lofo_table(session: str, overrides: tuple[str, ...] = (), *, fewer_files: bool = True) -> dict[str, Any]:
    """Every leave-one-file-out split of the session's shared files (see the module docstring), with the
    diagnosis configured by conf/diagnose.yaml and the session's data config, plus Hydra `overrides`.
    `fewer_files`: also fit each split on every three of its four training files (`three_files`, judged on the
    same held-out file), which tells whether a fit on more files predicts a file it never saw better."""
    data_config, folder, best_of = SESSIONS[session]
    cfg = _session_config(data_config, overrides)
    plant = load_plant("two_link")
    files = sorted((SHARED / folder).glob("*.csv"))
    columns = OmegaConf.to_container(cfg.data.columns)
    datasets = read_many(files, plant, columns=columns)  # type: ignore[arg-type]
    authors = {
        f"authors_{v}": load_author_model(SHARED / folder / "authors_identified" / f"design_{session}_model_{v}.yml")
        for v in best_of
    }
    opts = cfg.diagnose
    nominal_xml = plant.path
    refit = lab_form(datasets, next(iter(authors.values())))

    def run(train: list[Dataset], validation: list[Dataset]) -> Any:
        fit = partial(
            diagnose,
            plant,
            effects=tuple(opts.effects),
            derivatives=str(opts.derivatives),
            derivative_options=derivative_options(cfg),  # as sysid-diagnose resolves them (the data config's)
            selection=SelectionOptions(**OmegaConf.to_container(opts.selection)),  # type: ignore[arg-type]
            band_hz=float(cfg.data.band_hz),
            window_s=float(opts.window_s),
            record_offsets=record_offsets(cfg),  # as sysid-diagnose resolves them (the data config's, here)
            record_joint_offsets=record_joint_offsets(cfg),
        )
        known = cfg.data.get("tau_lead_s") is not None  # as sysid-diagnose: else found from the data
        return with_found_lead(fit, train, validation, np.random.default_rng(0), known=known)

    def judged_on(dg: Any, held: Dataset) -> list[float]:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "calibrated.xml"
            path.write_text(dg.calibrated_xml)
            return judge(path, {}, held)["torque_rms"]["calibrated"]

    in_sample = run(datasets, datasets[:1])  # the diagnosis fitted on every file: its in-sample bound
    calibrated_all = [judged_on(in_sample, d) for d in datasets]
    splits = []
    for k, held in enumerate(datasets):
        train = [d for i, d in enumerate(datasets) if i != k]
        start = time.perf_counter()
        dg = run(train, [held])
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "calibrated.xml"
            path.write_text(dg.calibrated_xml)
            judged = judge(path, authors, held, RAMPS, angle_zero=True)
        rms, both, zeroed = judged["torque_rms"], judged["both_filtered"], judged["angle_zeroed"]
        rms["nominal"] = judge(nominal_xml, {}, held)["torque_rms"]["calibrated"]
        rms["lab_form_others"], rms["lab_form_all"] = refit["others"][k], refit["all"][k]
        rms["lab_form_self"] = refit["self"][k]
        rms["calibrated_all"] = calibrated_all[k]
        three = [judged_on(run([d for d in train if d is not t], [held]), held) for t in train] if fewer_files else []
        best = np.min([rms[a] for a in authors], axis=0)
        splits.append(
            {
                "held_out": Path(held.source).name,
                "torque_rms": rms,
                "best_authors": best.tolist(),
                "wins": _at_most(rms["calibrated"], best),
                "both_filtered": both,
                "mujoco_only": judged["mujoco_only"],
                "moving": judged["moving"],
                "moving_share": judged["moving_share"],
                "judged_rows": judged["rows"],
                "demeaned": {k: v for k, v in judged["demeaned"].items() if k == "calibrated" or k in authors},
                "angle_zeroed": {k: v[0] for k, v in zeroed.items()},
                "angle_zero_shift": {k: v[1] for k, v in zeroed.items()},
                "wins_both_filtered": _at_most(both["calibrated"], np.min([both[a] for a in authors], axis=0)),
                "reachable_in_sample": _at_most(rms["lab_form_all"], best),
                "calibrated_in_sample": _at_most(rms["calibrated_all"], best),
                "three_files": three,
                "verdict": dg.verdict,
                "outside_training": [
                    {
                        "joint": d["joint"],
                        "share": max(d["share_outside_by_angle"], d["share_outside_by_speed"]),
                        "angle": d["validation_angle"],
                        "train_angle": d["train_angle"],
                    }
                    for d in dg.info["outside_training"]
                ],
                "prediction_std": list(dg.info["prediction_std"].values()),
                "diagnosis_band_rms": list(dg.models["calibrated"]["torque_rms"].values()),
                "findings": [
                    f.name + (f" ({', '.join(f.held_nominal)} nominal)" if f.held_nominal else "") for f in dg.findings
                ],
                "seconds": time.perf_counter() - start,
            }
        )
        print(session, splits[-1]["held_out"], json.dumps(rms), splits[-1]["wins"], flush=True)
    return {
        "session": session,
        "authors": list(authors),
        "joints": list(plant.joint_names),
        "splits": splits,
        "record_joint_offsets": [  # each file's angle zero where fitted, named by the file
            {**r, "source": Path(r["source"]).name} for r in in_sample.info["record_joint_offsets"]
        ],
    }


def _at_most(values: Any, best: Any) -> list[bool]:
    """Per joint: whether a model's RMS is at most the best lab model's (both (nv,))."""
    return [bool(c <= b) for c, b in zip(values, best, strict=True)]


def _yes_no(flags: list[bool]) -> str:
    return " / ".join("yes" if w else "**no**" for w in flags)


def _reading_markdown(table: dict[str, Any], key: str, intro: str) -> list[str]:
    """The splits of `table` in another reading `key` of each split (per model, (nv,) RMS): the calibrated model and
    the lab's, and whether the calibrated one is at most the best of the lab's on each joint; where the splits
    carry `<key>_share` ((nv,) the share of the rows the reading keeps), a column with it."""
    a = table["authors"]
    share = all(f"{key}_share" in s for s in table["splits"])
    lines = [
        "",
        f"The same splits of {table['session']} with {intro}:",
        "",
        "| held out | calibrated | "
        + " | ".join(a)
        + " | calibrated <= best lab model |"
        + (" rows kept |" if share else ""),
        "|" + "---|" * (3 + len(a) + share),
    ]
    for s in table["splits"]:
        r = s[key]
        cells = [f"{r[m][0]:.4f} / {r[m][1]:.4f}" for m in ("calibrated", *a)]
        best = np.min([r[m] for m in a], axis=0)
        kept = " " + " / ".join(f"{x:.0%}" for x in s[f"{key}_share"]) + " |" if share else ""
        lines.append(
            f"| {s['held_out']} | " + " | ".join(cells) + f" | {_yes_no(_at_most(r['calibrated'], best))} |" + kept
        )
    return lines


def _lofo_markdown(table: dict[str, Any]) -> str:
    a = table["authors"]
    head = "| held out | nominal | calibrated | " + " | ".join(a) + " | calibrated <= best lab model | findings |"
    lines = [
        f"### Design {table['session']}: torque RMS shoulder / elbow [N m], 5 Hz zero-phase band",
        "",
        head,
        "|" + "---|" * (5 + len(a)),
    ]
    for s in table["splits"]:
        r = s["torque_rms"]
        cells = [f"{r[m][0]:.4f} / {r[m][1]:.4f}" for m in ("nominal", "calibrated", *a)]
        lines.append(
            f"| {s['held_out']} | " + " | ".join(cells) + f" | {_yes_no(s['wins'])} | {', '.join(s['findings'])} |"
        )
    for key, intro in (
        (
            "both_filtered",
            "each model's torque low-passed too (both sides filtered, the other reading of the judging band)",
        ),
        (
            "demeaned",
            "each model's error less its own mean over the held-out file (a torque zero of that file's own allowed to "
            "every model): how much of a loss is the file's zero",
        ),
        (
            "mujoco_only",
            "the calibrated MJCF's joint torque from MuJoCo's `mj_inverse` alone (inertials, armature, damping, "
            "stiffness, frictionloss), without the actuators' gain and bias or any `sysid_*` custom numeric (a "
            "torque sensor's offset, a load-dependent friction, a delay): what `qfrc_inverse` says without this "
            "harness; equal to the first reading on a split whose calibrated MJCF has none of them",
        ),
        (
            "angle_zeroed",
            "each model given the held-out file's own angle zero (the constant shift of its angles that fits that "
            "model best, found on the file itself; `angle_zero_shift` in the JSON): what is left once the file's "
            "encoder zero is known, which no model fitted on other files can know",
        ),
        (
            "moving",
            "each joint judged only on the rows where it moves faster than a tenth of its RMS speed in the file "
            "(`_moving_rows`, the diagnosis's own slow-row rule): slower, it rests or turns round, its friction is "
            "anywhere within +-Fc and the inverse dynamics is a set, not a value; on a joint commanded zero torque "
            "the drive's current-based torque is 0 there whatever holds the link",
        ),
    ):
        if all(key in s for s in table["splits"]):
            lines += _reading_markdown(table, key, intro)
    if all("prediction_std" in s for s in table["splits"]):
        lines += [
            "",
            f"What the diagnosis itself says about each held-out file of {table['session']}: where it leaves the "
            "training motion (share of its rows at positions or speeds the training files never reach), and the "
            "calibrated prediction's std from the parameters' uncertainty against its error (both in the "
            "diagnosis's own band and states):",
            "",
            "| held out | outside the training motion | prediction std | calibrated RMS | verdict |",
            "|---|---|---|---|---|",
        ]
        for s in table["splits"]:
            out = (
                ", ".join(
                    f"{o['joint']} {o['share']:.0%} ({o['angle'][0]:.3g} to {o['angle'][1]:.3g} rad; training "
                    f"{o['train_angle'][0]:.3g} to {o['train_angle'][1]:.3g})"
                    for o in s["outside_training"]
                )
                or "-"
            )
            std, rms = (" / ".join(f"{v:.4f}" for v in s[k]) for k in ("prediction_std", "diagnosis_band_rms"))
            lines.append(f"| {s['held_out']} | {out} | {std} | {rms} | {s['verdict']} |")
    if all("calibrated_all" in s["torque_rms"] for s in table["splits"]):
        lines += [
            "",
            f"In-sample bounds on the shared files of {table['session']}: the lab's model form refitted (least squares "
            "in the same band, on the judge's states) on the other files and on all of them, the held-out one "
            "included, and on that file alone (the least the form leaves there, a floor for any fit of it to other "
            "data); and the diagnosis itself fitted on all of them (one calibrated MJCF judged on each file). "
            "Where a fit that has seen the file still loses to the lab's model, the split is out of reach of that "
            "model and its objective on these files, not a matter of generalisation.",
            "",
            "| held out | best lab model | lab form, other files | lab form, all files | <= lab | "
            "calibrated, all files | <= lab | lab form, this file alone |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for s in table["splits"]:
            r = s["torque_rms"]
            cells = [f"{x[0]:.4f} / {x[1]:.4f}" for x in (s["best_authors"], r["lab_form_others"], r["lab_form_all"])]
            alone = r.get("lab_form_self")
            alone_cell = f"{alone[0]:.4f} / {alone[1]:.4f}" if alone else "-"
            lines.append(
                f"| {s['held_out']} | " + " | ".join(cells) + f" | {_yes_no(s['reachable_in_sample'])} | "
                f"{r['calibrated_all'][0]:.4f} / {r['calibrated_all'][1]:.4f} | {_yes_no(s['calibrated_in_sample'])} | "
                f"{alone_cell} |"
            )
    return "\n".join(lines)


def _totals(tables: dict[str, dict[str, Any]], reading: str, model: str) -> tuple[float, int, int, int]:
    """Over every split of `tables`, in `reading` (`torque_rms`, `both_filtered`, `mujoco_only`, `angle_zeroed` or
    `moving`):
    the sum of `model`'s held-out RMS over the joints, the joints and the splits (every joint) where it is at most
    the best lab model, and the number of joints."""
    total, joints, splits, n = 0.0, 0, 0, 0
    for t in tables.values():
        for s in t["splits"]:
            rms = np.asarray(s[reading][model])
            won = rms <= np.min([s[reading][a] for a in t["authors"]], axis=0)
            total, joints, splits, n = (
                total + rms.sum(),
                joints + int(won.sum()),
                splits + bool(won.all()),
                n + rms.size,
            )
    return total, joints, splits, n


POOLED_READINGS = ("torque_rms", "both_filtered", "mujoco_only", "angle_zeroed", "moving")  # pooled per session


def cross_validated(table: dict[str, Any], reading: str) -> dict[str, np.ndarray] | None:
    """Per model judged in `reading` (the calibrated MJCF and each lab model): (nv,) its RMS over every held-out
    row of every split of `table`, each file held out once (the session's leave-one-file-out RMS: what the issue's
    "torque RMS on other files of the session" is over all of them), each split weighed by its judged rows (in
    `moving`, the rows each joint keeps). None for tables whose splits do not carry their row counts."""
    splits = table["splits"]
    if not all("judged_rows" in s and reading in s for s in splits):
        return None
    weights = np.array([np.full(len(table["joints"]), s["judged_rows"], float) for s in splits])
    if reading == "moving":
        weights = weights * np.array([s["moving_share"] for s in splits])
    out = {}
    for m in ["calibrated", *table["authors"]]:
        rms = np.array([s[reading][m] for s in splits], float)
        w = np.where(np.isfinite(rms), weights, 0.0)  # a joint with no rows kept in a split (NaN) weighs nothing
        out[m] = np.sqrt(np.sum(w * np.nan_to_num(rms) ** 2, axis=0) / w.sum(axis=0))
    return out


def _pooled(tables: dict[str, dict[str, Any]]) -> list[tuple[dict[str, Any], str, dict[str, np.ndarray], np.ndarray]]:
    """(table, reading, its `cross_validated` RMS per model, the better lab model's (nv,)) for every session and
    pooled reading; empty where a table lacks row counts."""
    out = []
    for t in tables.values():
        for reading in POOLED_READINGS:
            pooled = cross_validated(t, reading)
            if pooled is None:
                return []
            out.append((t, reading, pooled, np.min([pooled[a] for a in t["authors"]], axis=0)))
    return out


def cross_validated_markdown(tables: dict[str, dict[str, Any]]) -> str:
    """Per session and pooled reading: the cross-validated RMS of the calibrated MJCF and of each lab model, and
    whether the calibrated one is at most the better lab model on each joint; empty where a table lacks row
    counts."""
    lines = []
    for t, reading, pooled, best in _pooled(tables):
        labs = "; ".join(f"{a}: " + " / ".join(f"{v:.4f}" for v in pooled[a]) for a in t["authors"])
        cal, lab = (" / ".join(f"{v:.4f}" for v in x) for x in (pooled["calibrated"], best))
        won = _yes_no(_at_most(pooled["calibrated"], best))
        lines.append(f"| {t['session']} | {reading} | {cal} | {labs} | {lab} | {won} |")
    if not lines:
        return ""
    head = "| session | reading | calibrated | lab models | better lab model | calibrated <= it |"
    return "\n".join([head, "|---|---|---|---|---|---|", *lines])


def lofo_summary(tables: dict[str, dict[str, Any]]) -> str:
    """One line per judging reading: the sum of the held-out RMS over every split and joint, the joints and the
    splits (both joints) at most the lab's best model."""
    n_splits = sum(len(t["splits"]) for t in tables.values())
    lines = []
    every = [s for t in tables.values() for s in t["splits"]]
    for reading in ("torque_rms", "both_filtered", "mujoco_only", "angle_zeroed", "moving"):
        if not all(reading in s for s in every):
            continue  # tables from before the reading was judged
        total, joints, splits, n = _totals(tables, reading, "calibrated")
        won = f"{joints} of {n} joints and {splits} of {n_splits} splits"
        lines.append(f"{reading}: sum {total:.4f} N m, {won} <= the lab's best")
    pooled = _pooled(tables)
    if pooled:
        won = dict.fromkeys(POOLED_READINGS, 0)
        for _, reading, rms, best in pooled:
            won[reading] += sum(_at_most(rms["calibrated"], best))
        n_pooled = sum(len(t["joints"]) for t in tables.values())
        lines.append(
            "cross-validated (every held-out row of a session, each file held out once): "
            + ", ".join(f"{r} {won[r]} of {n_pooled}" for r in POOLED_READINGS)
            + " joints <= the better lab model"
        )
    if all("calibrated_all" in s["torque_rms"] for t in tables.values() for s in t["splits"]):
        total, joints, splits, n = _totals(tables, "torque_rms", "calibrated_all")
        won = f"{joints} of {n} joints and {splits} of {n_splits} files"
        lines.append(f"in-sample bound (fitted on every file): sum {total:.4f} N m, {won} <= the lab's best")
    return "\n".join(lines)


def fewer_files_markdown(tables: dict[str, dict[str, Any]]) -> str:
    """Per split: the held-out RMS of the fit on its four training files against the fits on every three of them
    (their mean and range), and how often the four-file fit is below the three-file mean."""
    splits = [(t["session"], s) for t in tables.values() for s in t["splits"]]
    if not all(s.get("three_files") for _, s in splits):
        return ""
    lines = [
        "| session | held out | fitted on four files | on three: mean | on three: range |",
        "|---|---|---|---|---|",
    ]
    below = n = 0
    for session, s in splits:
        four, three = np.asarray(s["torque_rms"]["calibrated"]), np.asarray(s["three_files"])
        mean = three.mean(axis=0)
        below += int(np.count_nonzero(four < mean))
        n += four.size
        span = " / ".join(f"{a:.4f}-{b:.4f}" for a, b in zip(three.min(axis=0), three.max(axis=0), strict=True))
        cells = [" / ".join(f"{v:.4f}" for v in x) for x in (four, mean)]
        lines.append(f"| {session} | {s['held_out']} | {cells[0]} | {cells[1]} | {span} |")
    return "\n".join([*lines, "", f"The four-file fit is below the three-file mean on {below} of {n} joint-splits."])


def ramp_markdown(tables: dict[str, dict[str, Any]]) -> str:
    """Every split's calibrated MJCF judged again with its friction `widened` to each of `RAMPS`: the sum of the
    held-out RMS over every split and joint and the joints at most the lab's best model, in both readings."""
    splits = [s for t in tables.values() for s in t["splits"]]
    if not all(f"calibrated_ramp_{v:g}" in s["torque_rms"] for s in splits for v in RAMPS):
        return ""  # tables from before the ramps were judged
    lines = [
        "| friction of the calibrated MJCF | sum [N m] | joints <= lab | both filtered: sum [N m] | joints <= lab |",
        "|---|---:|---:|---:|---:|",
    ]
    for key, label in [
        ("calibrated", "as fitted (ideal ramp)"),
        *((f"calibrated_ramp_{v:g}", f"ramp {v:g} rad/s") for v in RAMPS),
    ]:
        cells = []
        for reading in ("torque_rms", "both_filtered"):
            total, won, _, n = _totals(tables, reading, key)
            cells += [f"{total:.4f}", f"{won} of {n}"]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


PARTS = ("hidden", "arms", "servos", "pinocchio", "lab", "lofo")  # what `python -m bench diagnose` runs
ANGLE_ZEROS = ("diagnose.record_joint_offsets=true",)  # the splits run again with an angle offset per file


def angle_zeros_markdown(tables: dict[str, dict[str, Any]], defaults: dict[str, dict[str, Any]]) -> str:
    """The splits fitted with an angle offset per training file (`ANGLE_ZEROS`): each file's offset as the fit on
    every file finds it, and every split's held-out RMS against the lab's best and the default fit's (`defaults`,
    the same splits' tables without the option)."""
    lines = [
        "| session | file | its angle offset, fit on every file [rad] | held out: calibrated | default | best lab "
        "model | <= lab |",
        "|---|---|---|---|---|---|---|",
    ]
    for session, t in tables.items():
        offsets = {Path(r["source"]).name: r for r in t["record_joint_offsets"]}
        for s, d in zip(t["splits"], defaults[session]["splits"], strict=True):
            r = offsets[s["held_out"]]
            angle = " / ".join(f"{r[j]:+.3f} ± {r['std'][j]:.3f}" for j in t["joints"])
            cells = [
                " / ".join(f"{v:.4f}" for v in x)
                for x in (s["torque_rms"]["calibrated"], d["torque_rms"]["calibrated"], s["best_authors"])
            ]
            lines.append(
                f"| {session} | {s['held_out']} | {angle} | {cells[0]} | {cells[1]} | {cells[2]} | "
                f"{_yes_no(s['wins'])} |"
            )
    return "\n".join([*lines, "", *(f"- {line}" for line in lofo_summary(tables).split("\n"))])


# the lab's parameter sets that `lab` runs as the plant (identify.diagnose.testbed.lab_model_table)
LAB_MODELS = {
    f"{session} model {v}": (folder, f"design_{session}_model_{v}.yml")
    for session, folder, versions in (
        ("C.0", "dfki_double_pendulum_c0", ("3.0", "h1.0")),
        ("C.1", "dfki_double_pendulum_c1", ("1.0", "2.0")),
    )
    for v in versions
}


def main(parts: tuple[str, ...] = PARTS) -> None:
    """`parts`: `hidden`, `arms`, `lab` and/or `lofo`, and any `key=value` Hydra overrides of the diagnosis
    (conf/diagnose.yaml): with overrides the leave-one-file-out splits are run and summarised on stdout, and no
    file is written (the tables in bench/ stay those of the defaults)."""
    overrides = tuple(p for p in parts if "=" in p)
    if overrides and any(p in parts for p in ("hidden", "arms", "servos", "pinocchio", "lab")):
        raise SystemExit("overrides apply to the real-data splits only: run `python -m bench.diagnose lofo KEY=VALUE`")
    if overrides:
        if not SHARED.is_dir():
            raise SystemExit(f"the real-data splits need {SHARED}, which is absent")
        print(lofo_summary({s: lofo_table(s, overrides, fewer_files=False) for s in SESSIONS}))
        return
    out_json = HERE / "diagnose.json"
    result: dict[str, Any] = json.loads(out_json.read_text()) if out_json.exists() else {}
    if "lofo" in parts:
        if not SHARED.is_dir():
            print(f"skipping the real-data tables: {SHARED} is absent")
        else:
            result["lofo"] = {s: lofo_table(s) for s in SESSIONS}
            result["lofo_angle_zeros"] = {s: lofo_table(s, ANGLE_ZEROS, fewer_files=False) for s in SESSIONS}
    if "hidden" in parts:
        from identify.diagnose.testbed import hidden_effect_table, several_records_table

        result["hidden"] = hidden_effect_table()
        result["several_records"] = several_records_table()
    if "lab" in parts:
        from identify.diagnose.testbed import lab_model_table

        if not SHARED.is_dir():
            print(f"skipping the lab-model table: {SHARED} is absent")
        else:
            models = {k: SHARED / folder / "authors_identified" / name for k, (folder, name) in LAB_MODELS.items()}
            result["lab_model"] = lab_model_table(models)
    from identify.diagnose.testbed import arm_effect_table, pinocchio_table

    for part, key, table, what in (
        ("arms", "arms_hidden", arm_effect_table, "the Menagerie arms' table"),
        ("pinocchio", "pinocchio", pinocchio_table, "the Pinocchio plant's table"),
    ):
        if part not in parts:
            continue
        if not ROBOTS.is_dir():
            print(f"skipping {what}: {ROBOTS} is absent")
        else:
            with tempfile.TemporaryDirectory() as tmp:  # the arms driven by torque are written there
                result[key] = table(ROBOTS, tmp)
    if "servos" in parts:
        from identify.diagnose.testbed import servo_log_table

        if not ROBOTS.is_dir():
            print(f"skipping the Menagerie servos' table: {ROBOTS} is absent")
        else:
            result["servo_logs"] = servo_log_table(ROBOTS)
    out_json.write_text(json.dumps(result, indent=1))
    md = ["# Discrepancy diagnosis", "", "Written by `python -m bench diagnose` (see bench/diagnose.py).", ""]
    if "hidden" in result:
        from identify.diagnose.testbed import hidden_markdown

        md += ["## Hidden effects (independent generator)", "", hidden_markdown(result["hidden"]), ""]
    if "several_records" in result:
        from identify.diagnose.testbed import several_markdown

        md += [
            "## Several training records (independent generator)",
            "",
            "Three 6 s training records and a 4 s validation record, each its own multi-sine; `changing`: a torque "
            "zero that differs between the records is named (`info.changing_offsets`) and the verdict is "
            "`unexplained_structure`.",
            "",
            several_markdown(result["several_records"]),
            "",
        ]
    if "arms_hidden" in result:
        from identify.diagnose.testbed import hidden_markdown

        md += [
            "## Hidden effects on Menagerie arms (independent generator)",
            "",
            "The UR5e, the Panda, the Kinova Gen3 (continuous joints 1, 3, 5, 7) and the xArm7 (frictionloss 1 N m "
            "on every joint at MuJoCo's default solver parameters) of ../shared/robots/, their position servos "
            "replaced by motors of the same force limits (`identify.diagnose.testbed.torque_driven`), excited and "
            "measured by the testbed's own loop (`ARMS`: PD tracking of a multi-sine about a pose clear of the "
            "limits, RK4) with one effect hidden; "
            "the table is seed 0, the closing line counts seeds 0-3.",
            "",
            hidden_markdown(result["arms_hidden"]),
            "",
        ]
    if "pinocchio" in result:
        from identify.diagnose.testbed import hidden_markdown

        md += [
            "## A plant without MuJoCo: Pinocchio's articulated-body algorithm (independent generator)",
            "",
            "Every record made by `identify.diagnose.testbed.pinocchio_rollout`: the model as Pinocchio's own MJCF "
            "parser reads it (its inverse dynamics checked against MuJoCo's, not the harness's Pinocchio twin), "
            "integrated by a fixed-step RK4 at 4 kHz with the file's damping, frictionloss (as a Coulomb friction "
            "F tanh(dq / 0.01 rad/s), hardware's shape, not MuJoCo's soft ramp) and stiffness as plain forces; a "
            "PD loop at 1 kHz on the noisy, quantised angles with the gravity torque as feed-forward, tracking a "
            "chirp and two sines per joint; 500 Hz logs of the angles and the held commands. The built-in systems "
            "and three Menagerie arms driven by torque (`PINOCCHIO_ARMS`). Last, the xArm7 clean, with hardware's "
            "friction 1 N m tanh(dq / 0.05) on every joint at a 40 kHz step (its light last link asks for it): its "
            "MJCF's frictionloss, a ramp 7.7 rad/s wide on joint 7 at MuJoCo's default solver parameters, is the "
            "discrepancy, to be named as that joint's friction in a narrower shape (`friction_ramp`) at 1 N m. The "
            "table is seed 0, the closing line counts seeds 0-3.",
            "",
            hidden_markdown(result["pinocchio"]),
            "",
        ]
    if "servo_logs" in result:
        from identify.diagnose.testbed import servo_log_markdown

        md += [
            "## Menagerie arms through their own servos, logged as MuJoCo users log them",
            "",
            "The same four arms as they come (their position servos, integrator and step: implicitfast at 2 ms), "
            "and clean logs of the iiwa14 and the SO-ARM100 (MuJoCo's default Euler, which takes nothing of its "
            "servos implicitly: nothing to read), each given a multi-sine about a pose clear of its limits as its "
            "servos' targets and logged at every step as MuJoCo users write a log: the positions before the step "
            "and the actuator force of it (`identify.diagnose.testbed.servo_log`, 10 s to train on, 5 s to "
            "validate, 500 Hz). MuJoCo's integrator takes the servos' kv and the joint damping at the end of each "
            "step: an inertia h (kv + D / 2) in such a log (0.9 kg m^2 on the Panda's joints 1 and 2), and its "
            "friction ramps see the solver's acceleration, h M^-1 (kv + D) ddq beside the joints' own "
            "(`dynamics.stepping`). The diagnosis reads that from the data (`diagnose.mujoco_steps`, null by "
            "default): the first seed's reading and value, the verdicts of seeds 0-1. Each arm is logged clean "
            "with the positions after each step too (a loop that logs `d.qpos` once `mj_step` returns, beside the "
            "force of that step): its torque is one step behind its row, which the reading finds and undoes. The "
            "SO-ARM100's Euler step adds no inertia, so nothing tells its log from a robot's: there the one-step "
            "delay is named (1.93 ms on Wrist_Pitch for 2 ms, seed 0) with a note that it is the model's physics "
            "step and that `diagnose.mujoco_steps=true` reads the log a step earlier (`no_discrepancy` then, "
            "`tests/test_mujoco_steps.py`). The hidden effects on the "
            "xArm7 (frictionloss 1 N m on every joint, a ramp 7.7 rad/s wide on joint 7) are not named: a hidden "
            "armature moves that coupling, and the log is then not read as MuJoCo's steps at all; in the viscous "
            "and gain cases the right effect is chosen (joint 4's viscous friction at 0.4748 for 0.5, seed 0) beside "
            "time delays and armatures on joints 4 to 7 that raise the held-out error, and all of them are dropped.",
            "",
            servo_log_markdown(result["servo_logs"]),
            "",
        ]
    if "lab_model" in result:
        from identify.diagnose.testbed import lab_markdown

        md += [
            "## The DFKI lab's analytic model as the plant (a generator without MuJoCo)",
            "",
            "`identify.diagnose.testbed.lab_rollout`: the lab's own equations of the double pendulum integrated by "
            "SciPy under open-loop torques A1 sin(w t), A2 cos(w t) (three 10 s records to train on, a fourth to "
            "validate), quantised as the drivers' CAN frames; the plant is the nominal MJCF's own numbers in that "
            "form (clean) or one of the lab's identified parameter sets. Their friction is cf atan(100 dq) + b dq: "
            "its truth here is the Coulomb level cf pi / 2 and b. The error column is the calibrated MJCF's torque "
            "against the plant's on the exact validation states (seed 0).",
            "",
            lab_markdown(result["lab_model"]),
            "",
        ]
    for table in result.get("lofo", {}).values():
        md += [_lofo_markdown(table), ""]
    if "lofo" in result:
        md += [
            "Every split of both sessions:",
            "",
            *(f"- {line}" for line in lofo_summary(result["lofo"]).split("\n")),
            "",
        ]
        pooled = cross_validated_markdown(result["lofo"])
        if pooled:
            md += [
                "Each session over every held-out row (each file held out once, weighed by its judged rows; in "
                "`moving`, by the rows each joint keeps): the leave-one-file-out torque RMS of the calibrated MJCF, "
                "the session's cross-validated error on files the fit never saw, against each lab model's on the "
                "same rows and the better of them per joint. The lab's models were fitted on their whole sessions, "
                "these files among them.",
                "",
                pooled,
                "",
            ]
        fewer = fewer_files_markdown(result["lofo"])
        if fewer:
            md += [
                "### More files",
                "",
                "Each split fitted again on every three of its four training files and judged on the same held-out "
                "file (5 Hz band, as above): whether a fit on more files of a session predicts a file it never saw "
                "better. It is why `sysid-diagnose` also writes `<system>_calibrated_all.xml`, the diagnosis run "
                "on every record (`diagnose.final_fit`): the model for new data of the robot.",
                "",
                fewer,
                "",
            ]
        if "lofo_angle_zeros" in result:
            md += [
                "### An angle zero per file",
                "",
                "Every shared file of both sessions starts at 0.0002 rad on both joints, and ends where the motion "
                "left the arm: the drivers' encoders are zeroed at each start, where friction held the arm, not where "
                "it hangs. The same splits fitted with an angle offset per training file as a nuisance "
                "(`diagnose.record_joint_offsets=true`; the calibrated MJCF carries none of them, the held-out "
                "file's own is unknown to it). The offsets are each file's as the diagnosis fitted on every file "
                "finds them; on motions about the bottom a shoulder torque zero per file looks the same "
                "(opposite shoulder / elbow pairs), and the swing-up tells them apart. The option is off by default, "
                "on these logs too: the held-out files carry their own offsets, which no model predicts, and the "
                "splits say which reading is better.",
                "",
                angle_zeros_markdown(result["lofo_angle_zeros"], result["lofo"]),
                "",
            ]
        ramps = ramp_markdown(result["lofo"])
        if ramps:
            md += [
                "The same calibrated MJCFs judged with each joint's friction rewritten as a wider ramp Fc sat(dq / vt) "
                "(its Fc unchanged; `widened`): how much the judged RMS depends on the friction's shape near zero "
                "speed. A wider ramp looks better where the model is judged unfiltered against the filtered torque "
                "(a torque step cannot match a 5 Hz low-passed one) and not where both sides are filtered. The "
                "calibrated file widens a joint's friction only where the training records' rows the fit left out "
                "(sticking, turning round) ask for it (`slow_friction_ramps` in the diagnosis JSON; on these "
                "splits C.1's elbow at 0.1 rad/s wherever 20230629-144115, which commands it zero torque, is among "
                "the training files): a wide ramp lets a joint creep under a load it should hold in simulation.",
                "",
                ramps,
                "",
            ]
    (HERE / "diagnose.md").write_text("\n".join(md))


if __name__ == "__main__":
    main(tuple(sys.argv[1:]) or PARTS)

"""`sysid-run`: excitation design -> MuJoCo simulation -> identification -> truth comparison -> validation.

`run(cfg)` does the work and is what tests call; `main` is the thin Hydra wrapper.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import hydra
import numpy as np
from omegaconf import DictConfig, OmegaConf

from dynamics.base import BaseParameters
from dynamics.errors import ModelError
from dynamics.plant import Plant
from dynamics.prior import Prior, PriorSpec, make_prior
from dynamics.regressor import ParameterModel
from envs.dataset import Dataset, atomic_write, write_csv
from excitation.criteria import conditioning
from excitation.designs import grid
from excitation.fourier import FourierDesign
from excitation.limits import Limits
from excitation.optimise import position_limit_ratios
from harness.progress import printer
from harness.results import run_job, summary_table, write_json
from harness.rundir import RunFolder, RunFolderError, check_output_override, claim, kept_on_failure
from harness.setup import (
    CONF_DIR,
    design_from_config,
    experiment_from_config,
    load_system,
    simulate_design,
    with_auto_system,
    with_model_defaults,
)
from harness.validate import ConfigError, check_command_line, check_driven, validate_run_config
from identify.compare import compare_with_truth, linear_combination, predict_torque, torque_rms
from identify.derivatives import States, derive_states, differences_cutoff_limit_hz
from identify.derived import DERIVED
from identify.diagnose.diagnosis import SLIDING_FRACTION
from identify.estimators import estimate
from identify.excitation_check import MAX_COND, excitation_report
from identify.problem import Estimate, Problem, build_problem

__all__ = ["main", "run"]

# in writing order: results.json marks a finished run; model.xml only for a URDF (the MJCF MuJoCo compiled from it)
OUTPUTS = ("data.csv", "model.xml", "recording.rrd", "results.json")


@contextmanager
def _timed(timing: dict[str, float], stage: str) -> Iterator[None]:
    start = time.perf_counter()
    yield
    timing[stage] = timing.get(stage, 0.0) + time.perf_counter() - start


def limit_ratios(plant: Plant, design: FourierDesign, limits: Limits, data: Dataset, torque_driven: bool) -> dict:
    """Worst use of each bound: on a dense grid of the design (position designs) or the simulated motion."""
    if torque_driven:
        return limits.ratios(data.meta["q_true"], data.meta["dq_true"], data.ddq, data.meta["tau_applied"])
    return position_limit_ratios(plant, design, limits, grid(design, 4000))


# the simulated motion may use a bound this much beyond the design before it counts as leaving the limits: the
# tracking loop's error (feedforward from the prior, not the truth) adds a few per mille to a design at its bound
SIMULATED_MARGIN = 0.05
# the start-up the check of the simulated motion leaves out [s]: the simulation starts in the design's state, and
# a servo (which has no velocity feed-forward) brakes that initial speed at its force range for a few samples
# (57,000 rad/s^2 in the first sample of the Gen3's wrist); six time constants of the 4 Hz tracking loop
SETTLE_S = 0.25
# a joint whose largest distance from the designed angles exceeds this share of its designed swing (half the
# peak-to-peak) did not follow the design: stuck in its friction, or its controller too weak for it
FOLLOW_SHARE = 0.5


def simulated_motion(design: FourierDesign, limits: Limits, data: Dataset, torque_driven: bool) -> dict[str, Any]:
    """What the simulation really did against the limits, after the first `SETTLE_S`: each bound's worst use by
    the simulated motion (`ratios`), each joint's largest distance from the design's angles
    (`tracking_error_max`, position designs) and whether every bound held within `SIMULATED_MARGIN` (`holds`),
    with the worst one named (`worst`).

    Raises:
        ModelError: the motion pressed geoms together or a joint against its range limit: contact and limit
            forces are in the torque and no model has them.
    """

    def seen(e: dict[str, Any]) -> str:  # where an unmodelled force showed, from a simulator's report entry
        return f"in {e['samples']} of {data.n_samples} samples (first at t = {e['first_t_s']:.3f} s"

    contacts = data.meta.get("contacts", [])
    if contacts:
        c = contacts[0]
        always = c["samples"] == data.n_samples  # from the start pose on: they overlap wherever the arm goes
        apart = (
            "they touch in every sample, from the start pose on, wherever the arm goes (geoms that overlap in the "
            'model itself: a body between them, such as a gimbal without geoms, or <flag filterparent="disable"/> '
            "keeps MuJoCo from leaving out the pair of a parent and its child; or a link resting on the floor): no "
            "clearance keeps them apart; take "
            'them out of collision (contype="0" conaffinity="0", or an <exclude> of the two bodies)'
            if always
            else "keep them apart (a larger system.limits.clearance_m, which covers the floor plane and the collision "
            "geoms fixed to the world; a link without collision geoms only of the floor and the other links) or "
            'take them out of collision (contype="0" conaffinity="0")'
        )
        raise ModelError(
            f"the simulated motion presses geom {c['geoms'][0]} against {c['geoms'][1]} {seen(c)}; "
            f"{len(contacts)} pair(s) in all): contact forces enter the torque and no model has them; {apart}"
        )
    stops = data.meta.get("limits", [])
    if stops:
        s = stops[0]
        tracking = ""
        if not torque_driven and s["joint"] in data.joint_names:  # how far the tracked joint left its design
            j = data.joint_names.index(s["joint"])
            error = float(np.max(np.abs(data.meta["q_true"][:, j] - design.evaluate(data.time)[0][:, j])))
            tracking = f", its tracking error up to {error:.3g} {'rad' if s['unit'] == 'N m' else 'm'}"
        raise ModelError(
            f"the simulated motion presses joint {s['joint']!r} against its range limit {seen(s)}, up to "
            f"{s['max_force']:.3g} {s['unit']}{tracking}; {len(stops)} joint(s) in all): the limit's force enters the "
            "torque and no model has it; keep the motion further inside the range (a larger "
            "system.limits.range_margin, or, where the tracking error reaches the stop, a faster tracking loop: a "
            "larger system.controller.bandwidth_hz for a motor, a stiffer kp for a position servo, which tracks "
            "with its own gains) or widen the range (and any limit margin)"
        )
    assert data.ddq is not None  # a simulated dataset has the simulator's accelerations
    rows = data.time >= data.time[0] + min(SETTLE_S, 0.5 * float(data.time[-1] - data.time[0]))
    q, dq, ddq, tau = (x[rows] for x in (data.meta["q_true"], data.meta["dq_true"], data.ddq, data.meta["tau_applied"]))
    ratios = limits.ratios(q, dq, ddq, tau)
    out: dict[str, Any] = {"ratios": ratios, "from_s": float(data.time[rows][0] - data.time[0])}
    if not torque_driven:
        target = design.evaluate(data.time[rows])[0]
        err = np.abs(q - target).max(axis=0)
        out["tracking_error_max"] = dict(zip(limits.joint_names, err.tolist(), strict=True))
        swing = 0.5 * (target.max(axis=0) - target.min(axis=0))
        out["not_following"] = {
            name: {"error": float(e), "swing": float(w)}
            for name, e, w in zip(limits.joint_names, err, swing, strict=True)
            if e > FOLLOW_SHARE * w
        }
    key = limits.binding_key(ratios)
    out["holds"] = bool(ratios[key] <= 1.0 + SIMULATED_MARGIN)
    if key == "clearance" and limits.clearance is not None:  # its ratio is the bound over the distance kept
        kept = limits.clearance.clearance_m / ratios[key] if np.isfinite(ratios[key]) else 0.0
        out["worst"] = f"{limits.binding(ratios)}: {kept:.3g} m at the closest"
    else:
        per_joint = limits.joint_ratios(q, dq, ddq, tau)[key]
        j = int(np.argmax(per_joint))
        out["worst"] = f"{key}[{limits.joint_names[j]}] at {per_joint[j]:.3g} x its bound"
    return out


# the least default cut-off where Coulomb friction is fitted [Hz]: each reversal steps the friction torque by
# 2 Fc, and the acceleration by that over the inertia; a low-pass spreads the step over ~1 / cut-off, where
# the regressor's Fc sign(dq) has none of it. At 5 Hz the SO-ARM100's Fc2 and Fc3 came out at z +1.7 to +2.0
# on average over seeds 0-5 (max |z| up to 4.25); at 15 Hz -0.3 and +0.1, validation RMS unchanged
COULOMB_MIN_CUTOFF_HZ = 15.0


def _derivative_options(cfg: DictConfig, design: FourierDesign) -> dict[str, Any]:
    """Options of the derivative method: the cut-off (config, or 10 x the highest harmonic, >= 5 Hz, and
    >= `COULOMB_MIN_CUTOFF_HZ` where Coulomb friction is fitted; for `butterworth` at most an eighth of the rate,
    `differences_cutoff_limit_hz`, still a few times the top harmonic, which `validate` keeps below Nyquist) and,
    for the spectral method, the excitation's period (it keeps only the excitation's harmonics)."""
    method = cfg.identify.derivatives
    if method == "simulator":
        return {}
    cutoff = cfg.identify.cutoff_hz
    if cutoff is None:
        cutoff = max(10.0 * design.harmonics * design.base_freq_hz, 5.0)
        if "coulomb_friction" in (cfg.system.get("effects") or []):
            cutoff = max(cutoff, COULOMB_MIN_CUTOFF_HZ)
        if method == "butterworth":  # where the differences are accurate: a slow log (a coarse physics step)
            cutoff = min(cutoff, differences_cutoff_limit_hz(float(cfg.system.sensor.sample_rate_hz)))
    options: dict[str, Any] = {"cutoff_hz": float(cutoff)}
    if method == "spectral":
        options["period_s"] = design.period_s
    return options


def _identify(
    cfg: DictConfig, data: Dataset, model: ParameterModel, base: BaseParameters, design: FourierDesign, prior: Prior
) -> tuple[Estimate, Problem]:
    states = _sliding(cfg, model, derive_states(data, cfg.identify.derivatives, **_derivative_options(cfg, design)))
    problem = build_problem(data, states, model, base, prior=prior.theta)
    options = OmegaConf.to_container(cfg.estimator.options, resolve=True)
    return estimate(cfg.estimator.name, problem, **options), problem  # type: ignore[arg-type]


# fewest rows the sliding rule may keep before the run is refused (and the key named)
MIN_SLIDING_ROWS = 50


def _sliding(cfg: DictConfig, model: ParameterModel, states: States) -> States:
    """`states` trusting only the rows where every joint moves faster than `system.friction_min_speed` when the
    model has Coulomb columns: a sticking joint's friction is anywhere within +-Fc, not the column's Fc sign(dq),
    and such rows would bias Fc low (and show up in the validation as misfit the sliding model cannot have).

    A slide is held to `SLIDING_FRACTION` of its RMS speed instead where that is the smaller: its speed is in
    m/s, and the bound would leave no row of a short slide moving at centimetres per second.

    Raises:
        ConfigError: under `MIN_SLIDING_ROWS` rows would be kept (none left a validation RMS of NaN).
    """
    speed = cfg.system.get("friction_min_speed")
    if speed is None or "coulomb_friction" not in model.effects:
        return states
    rms = np.sqrt(np.mean(states.dq[states.valid] ** 2, axis=0))
    bound = np.where(model.plant.hinge, float(speed), np.minimum(float(speed), SLIDING_FRACTION * rms))
    moving = np.all(np.abs(states.dq) > bound, axis=1)
    kept, trusted = int(np.sum(states.valid & moving)), int(np.sum(states.valid))
    if kept < MIN_SLIDING_ROWS:
        raise ConfigError(
            f"system.friction_min_speed={speed}: only {kept} of {trusted} samples have every joint moving faster "
            f"(per joint: {', '.join(f'{n} {b:.4g}' for n, b in zip(model.plant.joint_names, bound, strict=True))}); "
            "lower it, or null to keep every sample"
        )
    return dataclasses.replace(states, valid=states.valid & moving)


def run(cfg: DictConfig, output_dir: Path | None = None) -> dict[str, Any]:
    """The whole loop for `cfg.system`; writes data.csv, recording.rrd and results.json (last) into `output_dir`.

    The config is checked first (`harness.validate`), then the folder is claimed for this run
    (`harness.rundir.claim`: writable, not in use, no finished run unless `overwrite=true`).

    Raises:
        ConfigError: a config value is wrong (named by its key).
        RunFolderError: the output folder cannot be used.
    """
    loaded = load_system(cfg)
    check_driven(loaded)
    cfg = with_model_defaults(cfg, loaded)
    validate_run_config(cfg, loaded)
    out = Path(output_dir) if output_dir is not None else _hydra_output_dir()
    # model.xml, a URDF's compiled MJCF, is retired by any run (no other robot's model left beside the results),
    # except where it is the model this run reads
    writes = [n for n in OUTPUTS if n != "model.xml" or loaded.source is not None]
    with claim(
        out, outputs=OUTPUTS, overwrite=bool(cfg.overwrite), inputs=[loaded.source or loaded.path], writes=writes
    ) as folder:
        return _run(cfg, folder, loaded)


def _run(cfg: DictConfig, folder: RunFolder, loaded: Plant) -> dict[str, Any]:
    out = folder.path
    timing: dict[str, float] = {}
    rng_design, rng_noise, rng_base, rng_val, rng_prior = np.random.default_rng(int(cfg.seed)).spawn(5)
    with _timed(timing, "setup"):
        exp = experiment_from_config(cfg, rng_base, plant=loaded)
        plant, limits, model, base, sensor = exp.plant, exp.limits, exp.model, exp.base, exp.sensor
        # the MJCF is the simulated truth: design limits, feedforward and fits use the prior model instead
        prior = make_prior(model, PriorSpec.from_dict(dict(cfg.prior)), rng_prior, simulated=True)
        nominal = dataclasses.replace(exp, plant=prior.plant)
    with _timed(timing, "excitation"):
        design = design_from_config(cfg, nominal, cfg.excitation.name, rng_design, progress=printer("excitation"))
    with _timed(timing, "simulation"):
        data = simulate_design(plant, design, cfg, sensor, rng_noise, float(cfg.system.periods), nominal=prior.plant)
        motion = simulated_motion(design, limits, data, bool(cfg.system.torque_driven))
    with _timed(timing, "identification"):
        est, problem = _identify(cfg, data, model, base, design, prior)
        beta_true = base.project(model.truth())
        comparison = compare_with_truth(est, beta_true)
        derived = _derived(plant, base, est)
    with _timed(timing, "validation"):
        val_design = design_from_config(cfg, nominal, "random", rng_val)
        val_data = simulate_design(
            plant, val_design, cfg, sensor, rng_val, float(cfg.validation.periods), nominal=prior.plant
        )
        val_motion = simulated_motion(val_design, limits, val_data, bool(cfg.system.torque_driven))
        val_states = _sliding(
            cfg, model, derive_states(val_data, cfg.identify.derivatives, **_derivative_options(cfg, val_design))
        )
        rows = val_states.valid
        val_pred = predict_torque(model, base, est.beta, val_states.q[rows], val_states.dq[rows], val_states.ddq[rows])
        val_rms = torque_rms(val_pred, val_data.tau[rows], plant.joint_names)
    cond_xtx, cond_colnorm = conditioning(problem.W)
    excited = excitation_report(problem.W, names=list(problem.names))
    ratios = limit_ratios(plant, design, limits, data, bool(cfg.system.torque_driven))
    noise_std = np.sqrt(np.asarray(sensor.sigma_tau) ** 2 + sensor.tau_resolution**2 / 12.0) * plant.actuated
    results: dict[str, Any] = {
        "system": plant.name,
        "seed": int(cfg.seed),
        "estimator": est.estimator,
        "excitation": {
            "name": cfg.excitation.name,
            "cond_XtX": cond_xtx,
            "cond_W_colnorm": cond_colnorm,
            "poorly_excited": {  # directions the data hardly move: their estimates rest on the prior, if any
                "directions": excited.poorly_excited,
                "cond_threshold": MAX_COND,
                "weakest": list(excited.weakest) if excited.poorly_excited else [],
                "weakest_direction": excited.weakest_direction if excited.poorly_excited else "",
            },
            "harmonics": design.harmonics,
            "base_freq_hz": design.base_freq_hz,
            "period_s": design.period_s,
            "limits_ok": bool(max(ratios.values()) <= 1.0 + 1e-9),  # the design's; `simulated`: the motion's
            "limit_ratios": ratios,
            "simulated": motion,  # the motion that ran: the tracking loop or the physics may not follow the design
            "limits": limits.to_dict(),
            "clearance": None
            if limits.clearance is None
            else {
                "required_m": limits.clearance.clearance_m,
                "min_distance_m": limits.clearance.clearance_m / ratios["clearance"]
                if ratios["clearance"] > 0
                else None,
                "holds": bool(ratios["clearance"] <= 1.0),
                "shapes": len(limits.clearance.shapes),
                "pairs_checked": len(limits.clearance.pairs),
            },
            "coefficients": {"a": design.a, "b": design.b, "q0": design.q0},
        },
        "prior": prior.summary(model.truth()),
        "covariance": est.diagnostics.get("covariance", {"method": "none", "reason": "the estimator defines none"}),
        "base_parameters": [c.to_dict() for c in comparison],
        "estimate_names": list(est.names),
        "max_abs_z": float(max(abs(c.z) for c in comparison)),
        "derived": derived,
        "residual_std": dict(zip(plant.joint_names, est.sigma.tolist(), strict=True)),
        # the states the fit used: the method and the options it ran with (the cut-off the rule chose)
        "derivatives": {"method": str(cfg.identify.derivatives), **_derivative_options(cfg, design)},
        "validation": {
            "torque_rms": val_rms,
            "noise_std": dict(zip(plant.joint_names, noise_std.tolist(), strict=True)),
            "unit": dict(zip(plant.joint_names, plant.torque_units, strict=True)),
            "samples": int(rows.sum()),
            "simulated": val_motion,
        },
        "data": {
            "samples": data.n_samples,
            "duration_s": float(data.time[-1] - data.time[0]),
            "saturated_fraction": data.meta["saturated_fraction"],
            # data.csv has no field for it: give it to sysid-diagnose as data.tau_lead_s
            "tau_lead_s": data.tau_lead_s,
        },
        "timing_s": timing,
        "config": OmegaConf.to_container(cfg, resolve=True),
        "overrides": _overrides(),
    }
    with folder.staged() as staging:
        _write_outputs(staging, cfg, results, data, problem, est)
    print(summary_table(results))
    print(f"outputs in {out}")
    return results


def _derived(plant: Plant, base: BaseParameters, est: Estimate) -> list[dict[str, Any]]:
    model = Path(plant.path).stem  # the built-in model's, whatever system.name calls it
    if model not in DERIVED:
        return []
    out = []
    for name, (c, unit) in DERIVED[model](plant).items():
        c_full = np.zeros(base.K.shape[1])
        c_full[: len(c)] = c
        value, std = linear_combination(base, est, c_full)
        true = float(c @ plant.theta)
        out.append(
            {
                "name": name,
                "unit": unit,
                "true": true,
                "estimate": value,
                "std": std,
                "z": (value - true) / std if std > 0 else None,
            }
        )
    return out


def _write_outputs(out: Path, cfg: DictConfig, results: dict, data: Dataset, problem: Problem, est: Estimate) -> None:
    """data.csv and recording.rrd first, results.json last: a results file means a finished run."""
    write_csv(data, out / "data.csv")
    plant = problem.model.plant
    if plant.source is not None:  # a URDF: the MJCF that MuJoCo compiled from it, and that was used
        text = plant.path.read_text()
        atomic_write(out / "model.xml", lambda f: f.write(text))
    if cfg.record.kind == "rerun":
        from harness.record import record_run

        rows = problem.rows
        predicted = np.einsum("knr,r->kn", problem.W, est.beta)
        series = {
            "time": data.time[rows],
            "joint_names": data.joint_names,
            "q": problem.states.q[rows],
            "dq": problem.states.dq[rows],
            "tau_measured": data.tau[rows],
            "tau_predicted": predicted,
            "history": est.diagnostics.get("history"),
        }
        record_run(out / "recording.rrd", problem.model.plant, results, series)
    write_json(out / "results.json", results)


def _overrides() -> list[str]:
    """This run's command-line overrides (kept in results.json: another run's .hydra/ cannot mix with them)."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return []
    return [str(o) for o in HydraConfig.get().overrides.task]


def _hydra_output_dir() -> Path:
    from hydra.core.hydra_config import HydraConfig

    return Path(HydraConfig.get().runtime.output_dir)


@hydra.main(config_path=str(CONF_DIR), config_name="config", version_base=None)
def _hydra_main(cfg: DictConfig) -> None:
    run_job(run, cfg)


def main() -> None:
    """Console entry point `sysid-run`: config-group values are checked (all of a sweep's) before Hydra starts."""
    sys.argv[1:] = with_auto_system(sys.argv[1:])
    try:
        check_command_line(sys.argv[1:], CONF_DIR, "config")
        # model.xml may be the model an MJCF's run reads (`claim` tells): a finished run is told by its other outputs
        check_output_override(sys.argv[1:], tuple(n for n in OUTPUTS if n != "model.xml"))
    except (ConfigError, RunFolderError) as err:
        print(f"sysid-run: error: {err}", file=sys.stderr)
        raise SystemExit(2) from None
    with kept_on_failure(sys.argv[1:], OUTPUTS):
        _hydra_main()


if __name__ == "__main__":
    main()

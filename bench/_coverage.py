"""Coverage study: does every reported std cover the truth as often as it claims?

For one system the motion is designed and simulated once, with the *prior* model (`dynamics.prior`, the truth
perturbed as a CAD model is wrong) for the design's torque limits and the tracking controller's feedforward
and gains, and the truth in MuJoCo. Every seed then measures it again with the residuals real data have:

- torque noise band-limited by a driver filter (2nd-order Butterworth at `noise_cutoff_hz`, scaled to keep
  each joint's std), with a different std on each joint, plus the torque quantisation;
- encoder noise and quantisation on q, with velocities and accelerations derived by the harness's
  Butterworth rule (errors in the regressor: errors in variables).

Each estimator runs through the registry (`identify.estimators.estimate`) on the problem that carries the
prior; z = (estimate - truth) / std over seeds and base parameters should follow N(0, 1). The Cramer-Rao
bound used for the RMS error is (X' S^-1 X)^-1 on the exact regressor X with S each joint's noise variance
(the white-noise bound of the same variance).

Not a benchmark on its own (the leading underscore keeps it out of `python -m bench`): `bench/estimators.py`
prints the full table and `tests/test_coverage.py` runs a fast variant.
"""

from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path
from typing import Any, NamedTuple

import mujoco
import numpy as np
from omegaconf import OmegaConf
from scipy import signal

from dynamics.base import BaseParameters, base_parameters
from dynamics.plant import Plant, load_plant, plant_from_xml
from dynamics.prior import Prior, PriorSpec, make_prior
from dynamics.regressor import ParameterModel
from envs.dataset import Dataset
from envs.sensors import SensorModel, quantise
from envs.simulate import simulate_tracking
from excitation.limits import limits_for
from excitation.registry import design_excitation
from harness.setup import CONF_DIR
from identify.derivatives import derive_states
from identify.estimators import estimate
from identify.problem import build_problem

__all__ = [
    "ARM7",
    "CoverageCase",
    "coverage_case",
    "coverage_runs",
    "coverage_summary",
    "motor_variant",
    "noisy_measurement",
]

SHARED_ROBOTS = Path(__file__).resolve().parents[2] / "shared" / "robots"
ARM7 = "panda"  # the 7-DoF arm of the study: ../shared/robots/panda_nohand.xml with motors
_ARM7_FILE = "panda_nohand.xml"


class CoverageCase(NamedTuple):
    name: str
    plant: Plant
    model: ParameterModel
    base: BaseParameters
    prior: Prior
    clean: Dataset
    sigma_tau: np.ndarray
    tau_resolution: float
    sigma_q: float
    q_resolution: float
    cutoff_hz: float
    noise_cutoff_hz: float


def motor_variant(path: Path, directory: Path) -> Plant:
    """The arm at `path` with every position servo replaced by a torque motor (gain 1, its force range).

    Contacts are switched off (the rigid-body regressor models none) and the integrator is explicit Euler
    with damping explicit too, so that the sampled motion is the one the joint torques and the model's
    damping produce (MuJoCo's implicit damping would shift the accelerations by h D / M).
    """
    spec = mujoco.MjSpec.from_file(str(path))
    for act in spec.actuators:
        limit = float(np.max(np.abs(act.forcerange))) if act.forcelimited or np.any(act.forcerange) else 100.0
        act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        act.gainprm = np.r_[1.0, np.zeros(len(act.gainprm) - 1)]
        act.biastype = mujoco.mjtBias.mjBIAS_NONE
        act.biasprm = np.zeros(len(act.biasprm))
        act.ctrllimited = True
        act.ctrlrange = np.array([-limit, limit])
        act.forcelimited = True
        act.forcerange = np.array([-limit, limit])
    spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    spec.option.timestep = 0.0005
    return plant_from_xml(spec.to_xml(), f"{path.stem}_motors", directory)


def _system(name: str, directory: Path) -> tuple[Plant, dict[str, Any]]:
    """The plant and the settings (effects, limits, sensor, controller) of a built-in system or the 7-DoF arm."""
    if name == ARM7:
        path = SHARED_ROBOTS / _ARM7_FILE
        if not path.is_file():
            raise FileNotFoundError(f"{path} is absent (the project was cloned without ../shared)")
        plant = motor_variant(path, directory)
        settings = {
            "effects": ["armature", "viscous_friction"],
            "velocity": 1.5,
            "acceleration": 8.0,
            "base_freq_hz": 0.1,
            "periods": 3.0,
            "sample_rate_hz": 500.0,
            "sigma_tau": [0.2, 0.2, 0.2, 0.2, 0.05, 0.05, 0.05],  # [N m] joint torque sensors, small on the wrist
            "tau_resolution": 0.01,
            "bandwidth_hz": 4.0,
        }
        return plant, settings
    cfg = OmegaConf.load(CONF_DIR / "system" / f"{name}.yaml")
    plant = load_plant(cfg.mjcf)
    settings = {
        "effects": list(cfg.effects),
        "velocity": OmegaConf.to_object(cfg.limits.velocity)
        if OmegaConf.is_list(cfg.limits.velocity)
        else float(cfg.limits.velocity),
        "acceleration": OmegaConf.to_object(cfg.limits.acceleration)
        if OmegaConf.is_list(cfg.limits.acceleration)
        else float(cfg.limits.acceleration),
        "base_freq_hz": float(cfg.base_freq_hz),
        "periods": float(cfg.periods),
        "sample_rate_hz": float(cfg.sensor.sample_rate_hz),
        "sigma_tau": OmegaConf.to_object(cfg.sensor.sigma_tau)
        if OmegaConf.is_list(cfg.sensor.sigma_tau)
        else float(cfg.sensor.sigma_tau),
        "tau_resolution": float(cfg.sensor.tau_resolution),
        "bandwidth_hz": float(cfg.controller.bandwidth_hz),
    }
    return plant, settings


def coverage_case(
    name: str,
    *,
    periods: float | None = None,
    noise_cutoff_hz: float = 10.0,
    sigma_q: float = 1.7e-5,
    q_resolution: float = 2 * np.pi / 2**18,
    directory: Path | None = None,
) -> CoverageCase:
    """Design and simulate system `name` once (noise-free) under the prior model's feedforward.

    Args:
        name: a built-in system ("pendulum", "two_link", "arm3") or `ARM7`.
        periods: excitation periods simulated (None: the system's own).
        noise_cutoff_hz: corner of the driver filter that band-limits the torque noise [Hz].
        sigma_q, q_resolution: encoder noise std and step [rad].
        directory: where the 7-DoF arm's motor variant is written (None: a temporary folder).
    """
    directory = directory or Path(tempfile.mkdtemp(prefix="sysid_coverage_"))
    plant, s = _system(name, directory)
    model = ParameterModel(plant, tuple(s["effects"]))
    base = base_parameters(model, np.random.default_rng(0))
    prior = make_prior(model, PriorSpec(seed=12), np.random.default_rng(0), simulated=True)
    limits = limits_for(prior.plant, velocity=s["velocity"], acceleration=s["acceleration"])
    design = design_excitation(
        "random",
        prior.plant,
        limits,
        model=model,
        harmonics=5,
        base_freq_hz=s["base_freq_hz"],
        torque_driven=False,
        rng=np.random.default_rng(3),
    )
    quiet = SensorModel(sample_rate_hz=s["sample_rate_hz"])
    length = float(periods if periods is not None else s["periods"])
    clean = simulate_tracking(
        plant,
        design,
        duration_s=length * design.period_s,
        sensor=quiet,
        rng=np.random.default_rng(0),
        nominal=prior.plant,
        bandwidth_hz=s["bandwidth_hz"],
    )
    sigma = np.broadcast_to(np.asarray(s["sigma_tau"], float), (plant.nv,)).copy()
    # joints with different noise: the system's level scaled from 0.5x to 2x along the chain
    sigma *= np.linspace(0.5, 2.0, plant.nv) if plant.nv > 1 else 1.0
    cutoff = max(10.0 * design.harmonics * design.base_freq_hz, 5.0)
    return CoverageCase(
        name,
        plant,
        model,
        base,
        prior,
        clean,
        sigma,
        s["tau_resolution"],
        sigma_q,
        q_resolution,
        cutoff,
        noise_cutoff_hz,
    )


def _band_limited(rng: np.random.Generator, shape: tuple[int, int], cutoff_hz: float, fs: float) -> np.ndarray:
    """Unit-variance noise low-passed by a 2nd-order Butterworth at cutoff_hz (causal, as a driver's filter)."""
    b, a = signal.butter(2, cutoff_hz, fs=fs)
    gain = float(np.sqrt(np.sum(signal.lfilter(b, a, np.r_[1.0, np.zeros(4095)]) ** 2)))
    white = rng.normal(size=(shape[0] + 2000, shape[1]))
    return signal.lfilter(b, a, white, axis=0)[2000:] / gain


def noisy_measurement(c: CoverageCase, rng: np.random.Generator) -> Dataset:
    """One measurement of the case's motion: band-limited per-joint torque noise, encoder noise, quantisation."""
    data = c.clean
    fs = 1.0 / data.dt
    noise = _band_limited(rng, data.tau.shape, c.noise_cutoff_hz, fs) * c.sigma_tau
    tau = np.where(c.plant.actuated, quantise(data.meta["tau_applied"] + noise, c.tau_resolution), 0.0)
    q = SensorModel(sigma_q=c.sigma_q, q_resolution=c.q_resolution).measure_q(data.meta["q_true"], rng)
    return dataclasses.replace(data, q=q, tau=tau)


def coverage_runs(c: CoverageCase, estimators: tuple[str, ...], seeds: list[int]) -> dict[str, dict[str, Any]]:
    """z-scores and errors of each estimator over the seeds.

    Returns:
        estimator -> {"z": (k, r) (NaN where no std), "err": (k, r), "reason": why no std (or ""),
        "covariance": the last run's covariance description, "rows": (N,) rows used}.
    """
    truth = c.base.project(c.model.truth())
    out: dict[str, dict[str, Any]] = {n: {"z": [], "err": [], "reason": "", "covariance": {}} for n in estimators}
    rows = None
    for seed in seeds:
        data = noisy_measurement(c, np.random.default_rng([seed, 7919]))
        states = derive_states(data, "butterworth", cutoff_hz=c.cutoff_hz)
        problem = build_problem(data, states, c.model, c.base, prior=c.prior.theta)
        rows = problem.rows
        for name in estimators:
            est = estimate(name, problem)
            err = est.beta - truth
            out[name]["err"].append(err)
            out[name]["z"].append(err / est.std)
            info = est.diagnostics.get("covariance", {})
            out[name]["covariance"] = info
            if est.cov is None:
                out[name]["reason"] = info.get("reason", "no covariance")
    for v in out.values():
        v["z"], v["err"], v["rows"] = np.array(v["z"]), np.array(v["err"]), rows
    return out


def crlb(c: CoverageCase, rows: np.ndarray) -> np.ndarray:
    """(r, r) (X' S^-1 X)^-1 on the exact regressor X, S each joint's torque noise variance."""
    exact = build_problem(c.clean, derive_states(c.clean, "simulator"), c.model, c.base).W[rows]
    var = c.sigma_tau**2 + c.tau_resolution**2 / 12.0
    return np.linalg.inv(np.einsum("knr,n,kns->rs", exact, 1.0 / var, exact))


def coverage_summary(c: CoverageCase, name: str, run: dict[str, Any]) -> dict[str, Any]:
    """Pooled statistics of one estimator's z-scores over the seeds where it reported a std.

    std(z) is the RMS of z about 0 (a bias counts against it), pooled over seeds and base parameters;
    `std_z_90` is its 90 % interval with the seeds resampled (None with one seed).
    """
    z, err = run["z"], run["err"]
    bound = crlb(c, run["rows"])
    mahal = np.einsum("kr,rs,ks->k", err, np.linalg.inv(bound), err) / err.shape[1]
    reported = np.all(np.isfinite(z), axis=1)
    zr = z[reported]
    some = bool(np.any(reported))
    band = None
    if some and len(zr) > 1:
        # the seeds resampled with replacement (a seed's parameters stay together: they share its noise)
        picks = np.random.default_rng(0).integers(0, len(zr), size=(2000, len(zr)))
        boot = np.sqrt(np.mean(zr[picks] ** 2, axis=(1, 2)))
        band = [float(np.quantile(boot, 0.05)), float(np.quantile(boot, 0.95))]
    return {
        "system": c.name,
        "estimator": name,
        "seeds": int(len(z)),
        "parameters": int(z.shape[1]),
        "reported_fraction": float(np.mean(reported)),
        "std_z": float(np.sqrt(np.mean(zr**2))) if some else None,
        "std_z_90": band,
        "mean_z": float(np.mean(zr)) if some else None,
        "max_abs_z": float(np.max(np.abs(zr))) if some else None,
        "frac_abs_z_gt_3": float(np.mean(np.abs(zr) > 3.0)) if some else None,
        "rms_error_crlb_units": float(np.sqrt(np.mean(mahal))),
        "covariance": {k: v for k, v in run["covariance"].items() if k != "reason"},
        "no_std_reason": run["reason"],
    }

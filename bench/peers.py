"""The harness against a peer tool, MuJoCo's own `mujoco.sysid`, on the same simulated data.

Per system: one identification record (the harness's excitation, "optimised" where that design exists,
tracked in MuJoCo and measured by the system's sensor model) and one validation record (a fresh random
design, another seed). Both tools get the same measured angles and torques, nothing else:

- the harness: Butterworth-filtered states (`CUTOFF_HZ`), base regressor (Pinocchio), weighted least
  squares. Linear: it needs no starting point.
- `mujoco.sysid`: MuJoCo rollouts driven open loop by the measured torque (held over each sample), each
  `CHUNK_S` long and started from the same filtered measured state; residual = measured minus simulated
  joint angles; parameters = each body's pseudo-inertia (physically consistent, `body_inertia_param`
  defaults) and each joint's armature where the harness identifies it; MuJoCo's least-squares optimiser,
  started from the MJCF with every mass, centre of mass, rotational inertia and armature scaled by its own
  random factor in `START_SPREAD` (fixed seed).

Each answer is mapped to the harness's base parameters (beta = K theta, theta read from the identified
MjModel) and scored by the same code: error against the MJCF truth (also in units of the WLS standard
deviation), validation torque RMS on the fresh record, and simulation error (joint angles after restarting
from the filtered measured state every `SIM_WINDOW_S` under the measured torque, integrated alike for
every row). Wall time covers each tool's work from the measured record to its answer (filtering included).

Writes bench/peers.json and bench/peers.md. Re-run: `make bench` or `.venv/bin/python -m bench peers`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

from dynamics.base import BaseParameters
from dynamics.plant import Plant
from dynamics.regressor import ParameterModel
from envs.dataset import Dataset
from excitation.registry import EXCITATIONS
from harness.setup import CONF_DIR, design_from_config, experiment_from_config, simulate_design
from identify.compare import predict_torque, torque_rms
from identify.derivatives import States, derive_states
from identify.diagnose.simulation_error import ode_stepper, simulation_error
from identify.estimators import estimate
from identify.problem import build_problem

HERE = Path(__file__).resolve().parent
SYSTEMS = ("two_link", "pendulum")
SEED = 0
CUTOFF_HZ = 5.0  # Butterworth cut-off of the filtered states both tools use [Hz]
START_SPREAD = (0.7, 1.3)  # the perturbed start: each inertial quantity times a factor drawn from this range
CHUNK_S = 0.5  # mujoco.sysid: length of each open-loop rollout [s] (of 0.25/0.5/1/2 s, 0.5 s fitted best)
MAX_ITERS = 50  # mujoco.sysid: optimiser iterations at most
SIM_WINDOW_S = 0.25  # simulation error: restart window [s]
INSTALL_HINT = "install the bench extras: .venv/bin/python -m pip install -e '.[dev,bench]'"


def sysid_available() -> bool:
    """Whether `mujoco.sysid` imports with its optional dependencies (it hides them when they are missing)."""
    from mujoco import sysid

    return hasattr(sysid, "optimize")


@dataclass(frozen=True)
class Case:
    """One system's shared data: the plant, its parameter model, the two records, the validation states.

    Attributes:
        data: the identification record (both tools fit it).
        val_data: the validation record (neither tool sees it).
        val_states: filtered validation states at the instant each torque row belongs to (torque RMS).
        val_start_states: filtered validation states at the sample instants (restarts of the simulation).
        settings: how the records were made.
    """

    system: str
    plant: Plant
    model: ParameterModel
    base: BaseParameters
    data: Dataset
    val_data: Dataset
    val_states: States
    val_start_states: States
    settings: dict[str, Any]


@dataclass(frozen=True)
class ToolResult:
    """A tool's identified base parameters, its wall and CPU time (all threads) [s], tool-specific facts."""

    tool: str
    beta: np.ndarray
    wall_s: float
    cpu_s: float
    info: dict[str, Any]


def _states(data: Dataset, *, at_samples: bool = False) -> States:
    """Filtered states; at the torque's instant (regressor) or at the sample instants (simulation starts)."""
    source = dataclasses.replace(data, tau_lead_s=0.0) if at_samples else data
    return derive_states(source, "butterworth", cutoff_hz=CUTOFF_HZ)


def _compose(system: str) -> DictConfig:
    excitation = (
        "optimised"
        if "optimised" in EXCITATIONS and (CONF_DIR / "excitation" / "optimised.yaml").is_file()
        else "default"
    )
    with initialize_config_dir(str(CONF_DIR), version_base=None):
        return compose("config", [f"system={system}", f"excitation={excitation}", "record=none", f"seed={SEED}"])


def make_case(system: str, *, periods: float | None = None, val_periods: float | None = None) -> Case:
    """Simulate the identification record and a validation record (random design) as `sysid-run` does.

    Args:
        periods, val_periods: record lengths in periods of each design (None: the system config's).
    """
    cfg = _compose(system)
    rng_design, rng_noise, rng_base, rng_val = np.random.default_rng(SEED).spawn(4)
    exp = experiment_from_config(cfg, rng_base)
    plant, model, base, sensor = exp.plant, exp.model, exp.base, exp.sensor
    design = design_from_config(cfg, exp, cfg.excitation.name, rng_design)
    periods = float(cfg.system.periods) if periods is None else periods
    data = simulate_design(plant, design, cfg, sensor, rng_noise, periods)
    val_design = design_from_config(cfg, exp, "random", rng_val)
    val_periods = float(cfg.validation.periods) if val_periods is None else val_periods
    val_data = simulate_design(plant, val_design, cfg, sensor, rng_val, val_periods)
    return Case(
        system=system,
        plant=plant,
        model=model,
        base=base,
        data=data,
        val_data=val_data,
        val_states=_states(val_data),
        val_start_states=_states(val_data, at_samples=True),
        settings={
            "seed": SEED,
            "excitation": cfg.excitation.name,
            "harmonics": design.harmonics,
            "period_s": design.period_s,
            "drive": "open-loop torque" if cfg.system.torque_driven else "tracking (PD + feedforward)",
            "identification_s": data.n_samples * data.dt,
            "validation_s": val_data.n_samples * val_data.dt,
            "sample_rate_hz": float(sensor.sample_rate_hz),
            "sigma_q_rad": float(sensor.sigma_q),
            "q_resolution_rad": float(sensor.q_resolution),
            "sigma_tau_Nm": np.atleast_1d(sensor.sigma_tau).tolist(),
            "tau_resolution_Nm": float(sensor.tau_resolution),
            "effects": list(cfg.system.effects),
            "cutoff_hz": CUTOFF_HZ,
        },
    )


# --- the shared starting model ------------------------------------------------------------------------


def perturbed_spec(case: Case, rng: np.random.Generator) -> mujoco.MjSpec:
    """The MJCF with each moving body's mass, centre of mass and rotational inertia, and each joint's
    armature (where identified), scaled by its own factor drawn uniformly from `START_SPREAD`."""
    spec = mujoco.MjSpec.from_file(str(case.plant.path))
    lo, hi = START_SPREAD
    for name in case.plant.body_names:
        body = spec.body(name)
        body.mass *= rng.uniform(lo, hi)
        body.ipos = body.ipos * rng.uniform(lo, hi)
        if np.all(np.isfinite(body.fullinertia)):
            body.fullinertia = body.fullinertia * rng.uniform(lo, hi)
        else:
            body.inertia = body.inertia * rng.uniform(lo, hi)
    if "armature" in case.model.effects:
        for name in case.plant.joint_names:
            spec.joint(name).armature *= rng.uniform(lo, hi)
    return spec


def theta_of(case: Case, m: mujoco.MjModel) -> np.ndarray:
    """(p,) a compiled model's parameters in the harness's order: 10 per body (Pinocchio's order, about the
    body frame's origin, which load_plant requires to be the joint's), then the effect columns."""
    parts = []
    for name in case.plant.body_names:
        b = m.body(name).id
        mass, c = float(m.body_mass[b]), m.body_ipos[b]
        flat = np.empty(9)
        mujoco.mju_quat2Mat(flat, m.body_iquat[b])
        rot = flat.reshape(3, 3)
        i_o = rot @ np.diag(m.body_inertia[b]) @ rot.T + mass * (c @ c * np.eye(3) - np.outer(c, c))
        parts.append([mass, *(mass * c), i_o[0, 0], i_o[0, 1], i_o[1, 1], i_o[0, 2], i_o[1, 2], i_o[2, 2]])
    theta = [np.concatenate(parts)]
    dofs = [int(m.joint(n).dofadr[0]) for n in case.plant.joint_names]
    for effect in case.model.effects:
        if effect != "armature":
            raise ValueError(f"the peer comparison maps only the armature effect, not {effect!r}")
        theta.append(m.dof_armature[dofs])
    return np.concatenate(theta)


# --- the two tools -----------------------------------------------------------------------------------


def run_harness(case: Case) -> ToolResult:
    """The harness's weighted least squares on the base regressor of the filtered states."""
    start, cpu = time.perf_counter(), time.process_time()
    est = estimate("wls", build_problem(case.data, _states(case.data), case.model, case.base))
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    return ToolResult("harness (WLS)", est.beta, wall, cpu, {"std": est.std.tolist()})


def _pseudo_inertia_modifier(body_name: str) -> Callable[[mujoco.MjSpec, Any], None]:
    """Write a pseudo-inertia parameter into the spec as sysid's default modifier does, but compilably.

    mujoco.sysid 4.0.0's default (`apply_body_theta_inertia`) marks the full inertia with iquat = NaN and a
    zero diagonal, which MuJoCo 4.0.0's compiler rejects ("mass and inertia of moving bodies must be larger
    than mjMINVAL"); with a unit iquat it takes the full inertia. Same parameterisation
    (`sysid.model_modifier.pi_from_theta`), same bounds.
    """
    from mujoco import sysid

    def modify(spec: mujoco.MjSpec, param: Any) -> None:
        pi = sysid.model_modifier.pi_from_theta(param.value)
        mass, com = float(pi[0]), pi[1:4] / pi[0]
        s = sysid.model_modifier.skew(com)
        i_com = pi[4:].reshape(3, 3) + mass * s @ s  # about the body origin -> about the centre of mass
        body = spec.body(body_name)
        body.explicitinertial = True
        body.mass, body.ipos = mass, com
        body.inertia, body.iquat = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]
        body.fullinertia = [i_com[0, 0], i_com[1, 1], i_com[2, 2], i_com[0, 1], i_com[0, 2], i_com[1, 2]]

    return modify


def _sysid_parameters(case: Case, spec: mujoco.MjSpec, m0: mujoco.MjModel) -> Any:
    from mujoco import sysid

    params = sysid.ParameterDict()
    for name in case.plant.body_names:
        modifier = _pseudo_inertia_modifier(name)
        params.add(sysid.body_inertia_param(spec, m0, name, inertia_type=sysid.InertiaType.Pseudo, modifier=modifier))
    if "armature" in case.model.effects:
        for name in case.plant.joint_names:
            a0 = float(m0.joint(name).armature[0])

            def set_armature(s: mujoco.MjSpec, p: Any, joint: str = name) -> None:
                s.joint(joint).armature = p.value[0]

            params.add(sysid.Parameter(f"{name}_armature", a0, 0.1 * a0, 10.0 * a0, modifier=set_armature))
    return params


def _chunks(valid: np.ndarray, n: int) -> list[tuple[int, int]]:
    """Row ranges [k0, k0 + n) of whole chunks inside the rows the filter trusts."""
    rows = np.flatnonzero(valid)
    return [(k, k + n) for k in range(int(rows[0]), int(rows[-1]) - n + 2, n)]


def run_sysid(case: Case, spec: mujoco.MjSpec, *, chunk_s: float = CHUNK_S, max_iters: int = MAX_ITERS) -> ToolResult:
    """`mujoco.sysid` from the start model `spec` on the identification record, restarting every `chunk_s`."""
    from mujoco import sysid

    if not sysid_available():
        raise ImportError(f"mujoco.sysid's optional dependencies are missing; {INSTALL_HINT}")
    logging.getLogger("absl").setLevel(logging.ERROR)  # one warning per chunk: the model has no sensors
    start, cpu = time.perf_counter(), time.process_time()
    data, states = case.data, _states(case.data, at_samples=True)
    m0 = spec.compile()
    params = _sysid_parameters(case, spec, m0)
    act = np.array([int(m0.jnt_dofadr[m0.actuator_trnid[a, 0]]) for a in range(m0.nu)])
    # observe the joint-position states: rollout's sensor rows are computed before each step, so a jointpos
    # sensor would trail its time stamp by one physics step
    observed = [f"{name}_qpos" for name in case.plant.joint_names]
    controls, observations, initial = [], [], []
    for k0, k1 in _chunks(states.valid, int(round(chunk_s / data.dt))):
        t = data.time[k0:k1] - data.time[k0]  # each chunk is its own rollout from t = 0
        ctrl = data.tau[k0:k1][:, act] / m0.actuator_gear[:, 0]
        # the torque is held over each sample interval: hand sysid that hold at the physics rate
        controls.append(sysid.TimeSeries(t, ctrl).resample(target_dt=float(m0.opt.timestep), method="zoh"))
        observations.append(sysid.TimeSeries.from_names(t, data.q[k0:k1], m0, names=observed))
        initial.append(sysid.create_initial_state(m0, states.q[k0], states.dq[k0]))
    names = [f"chunk{i}" for i in range(len(controls))]
    sequences = sysid.ModelSequences(
        case.system, spec, names, initial, controls, observations, allow_missing_sensors=True
    )
    residual_fn = sysid.build_residual_fn(models_sequences=[sequences])
    log = io.StringIO()
    with contextlib.redirect_stdout(log):  # the mujoco backend prints every iteration; keep its summary
        opt, _ = sysid.optimize(
            initial_params=params, residual_fn=residual_fn, optimizer="mujoco", verbose=False, max_iters=max_iters
        )
    identified = sysid.apply_param_modifiers(opt, spec.copy())
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    summary = [line for line in log.getvalue().splitlines() if line.startswith("Terminated")]
    x, (lo, hi) = opt.as_vector(), opt.get_bounds()
    at_bound = int(np.sum(np.minimum(x - lo, hi - x) <= 1e-3 * (hi - lo)))
    info = {
        "chunks": len(controls),
        "chunk_s": chunk_s,
        "max_iters": max_iters,
        "optimizer": summary,
        "parameters": int(x.size),
        "parameters_at_bound": at_bound,
    }
    return ToolResult("mujoco.sysid", case.base.project(theta_of(case, identified)), wall, cpu, info)


# --- scoring ---------------------------------------------------------------------------------------


def _accel(case: Case, beta: np.ndarray) -> Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]:
    """Forward dynamics of a base-parameter model, M(q) ddq = tau - h(q, dq), from its regressor."""
    nv = case.plant.nv
    unit = np.eye(nv)

    def accel(q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> np.ndarray:
        zero = np.zeros_like(q)
        # one regressor call: h(q, dq), then g(q) and M e_i + g(q) for every i
        qs = np.concatenate([q] * (nv + 2))
        dqs = np.concatenate([dq] + [zero] * (nv + 1))
        ddqs = np.concatenate([zero, zero] + [np.broadcast_to(unit[i], q.shape) for i in range(nv)])
        out = predict_torque(case.model, case.base, beta, qs, dqs, ddqs).reshape(nv + 2, len(q), nv)
        mass = np.moveaxis(out[2:] - out[1], 0, 2)  # (B, nv, nv), column i = M e_i
        return np.linalg.solve(mass, (tau - out[0])[..., None])[..., 0]

    return accel


def score(case: Case, beta: np.ndarray, wls_std: np.ndarray) -> dict[str, Any]:
    """Errors against the truth, validation torque RMS and simulation error of base parameters `beta`.

    Args:
        wls_std: (r,) the harness's WLS standard deviations, the common yardstick for the errors.
    """
    truth = case.base.project(case.model.truth())
    err = beta - truth
    nonzero = np.abs(truth) > 1e-9 * max(float(np.max(np.abs(truth))), 1.0)
    rel = np.where(nonzero, err / np.where(nonzero, np.abs(truth), 1.0), np.nan)
    vs, rows = case.val_states, case.val_states.valid
    pred = predict_torque(case.model, case.base, beta, vs.q[rows], vs.dq[rows], vs.ddq[rows])
    st, ok = case.val_start_states, case.val_start_states.valid
    sim = simulation_error(
        ode_stepper(_accel(case, beta), dt=float(case.plant.mj_model.opt.timestep)),
        case.val_data.time[ok],
        st.q[ok],
        st.dq[ok],
        case.val_data.tau[ok],
        window_s=SIM_WINDOW_S,
    )
    names = case.plant.joint_names
    return {
        "beta": beta.tolist(),
        "abs_error": err.tolist(),
        "rel_error": [None if np.isnan(r) else float(r) for r in rel],
        "error_over_wls_std": (err / wls_std).tolist(),
        "max_abs_rel_error": float(np.nanmax(np.abs(rel))),
        "max_abs_error_over_wls_std": float(np.max(np.abs(err / wls_std))),
        "validation_torque_rms": torque_rms(pred, case.val_data.tau[rows], names),
        "simulation_error_rad": dict(zip(names, sim.rms.tolist(), strict=True)),
    }


def compare(
    system: str,
    *,
    periods: float | None = None,
    val_periods: float | None = None,
    chunk_s: float = CHUNK_S,
    max_iters: int = MAX_ITERS,
) -> dict[str, Any]:
    """Both tools on one system's shared data, scored alike, with the truth and the start as reference rows."""
    case = make_case(system, periods=periods, val_periods=val_periods)
    spec = perturbed_spec(case, np.random.default_rng(SEED))
    start_beta = case.base.project(theta_of(case, spec.compile()))
    truth = case.base.project(case.model.truth())
    harness = run_harness(case)
    peer = run_sysid(case, spec, chunk_s=chunk_s, max_iters=max_iters)
    std = np.asarray(harness.info["std"])
    rows = [
        {"tool": "MJCF truth (reference)", "wall_s": None, "cpu_s": None, **score(case, truth, std)},
        {"tool": "perturbed start (reference)", "wall_s": None, "cpu_s": None, **score(case, start_beta, std)},
    ]
    for t in (harness, peer):
        rows.append({"tool": t.tool, "wall_s": t.wall_s, "cpu_s": t.cpu_s, "info": t.info, **score(case, t.beta, std)})
    sysid_params = "pseudo-inertia per body (body_inertia_param defaults: mass x[0.1, 10], COM +-0.5 m, ...)"
    if "armature" in case.model.effects:
        sysid_params += " + armature per joint in [0.1, 10] x start"
    return {
        "system": system,
        "settings": {
            **case.settings,
            "start_spread": list(START_SPREAD),
            "sysid": {"chunk_s": chunk_s, "max_iters": max_iters, "optimizer": "mujoco", "parameters": sysid_params},
            "simulation_window_s": SIM_WINDOW_S,
            "simulation_integrator": "semi-implicit Euler at the MJCF timestep, base-parameter dynamics",
        },
        "base_names": list(case.base.names),
        "truth": truth.tolist(),
        "rows": rows,
    }


def _markdown(results: list[dict[str, Any]]) -> str:
    lines = [
        "Harness (linear WLS) vs `mujoco.sysid` (rollout fit) on the same simulated records; "
        "re-run: `.venv/bin/python -m bench peers`.",
        "",
    ]
    for r in results:
        s = r["settings"]
        lines += [
            f"### {r['system']}",
            "",
            f"Identification: {s['identification_s']:g} s of the `{s['excitation']}` design ({s['drive']}), "
            f"validation: {s['validation_s']:g} s of a random design; {s['sample_rate_hz']:g} Hz, "
            f"sigma_tau {s['sigma_tau_Nm']} N m, sigma_q {s['sigma_q_rad']:g} rad; filter {s['cutoff_hz']:g} Hz; "
            f"sysid: {s['sysid']['chunk_s']:g} s rollouts, at most {s['sysid']['max_iters']} iterations, "
            f"start = MJCF x U{tuple(s['start_spread'])} per quantity (seed {s['seed']}).",
            "",
            "| tool | wall / CPU [s] | max abs rel. error | max abs error / WLS std "
            "| validation torque RMS [N m] | simulation error, 0.25 s restarts [rad] |",
            "|---|---:|---:|---:|---|---|",
        ]
        for row in r["rows"]:
            wall = "-" if row["wall_s"] is None else f"{row['wall_s']:.2f} / {row['cpu_s']:.2f}"
            val = ", ".join(f"{j} {v:.4g}" for j, v in row["validation_torque_rms"].items())
            sim = ", ".join(f"{j} {v:.3g}" for j, v in row["simulation_error_rad"].items())
            lines.append(
                f"| {row['tool']} | {wall} | {row['max_abs_rel_error']:.2e} | "
                f"{row['max_abs_error_over_wls_std']:.3g} | {val} | {sim} |"
            )
        tools = [row for row in r["rows"] if row["wall_s"] is not None]
        lines += [
            "",
            "| base parameter | truth | " + " | ".join(f"{t['tool']} (error / WLS std)" for t in tools) + " |",
        ]
        lines += ["|---|---:|" + "---:|" * len(tools)]
        for i, name in enumerate(r["base_names"]):
            cells = " | ".join(f"{t['beta'][i]:.6g} ({t['error_over_wls_std'][i]:+.2f})" for t in tools)
            lines.append(f"| {name} | {r['truth'][i]:.6g} | {cells} |")
        lines.append("")
    lines += [
        "Notes: both tools fit the same record (filter edges trimmed); the harness's WLS std is the common "
        "yardstick of the errors (it is the harness's own uncertainty, not a bound on a rollout fit). "
        "mujoco.sysid observes the joint-position states (its rollout's jointpos sensor rows trail their time "
        "stamps by one physics step) and sets the pseudo-inertia through its own `pi_from_theta` with a unit "
        "iquat (4.0.0's default modifier writes iquat = NaN, which MuJoCo 4.0.0 rejects). Simulation error: "
        "every row integrated by the same base-parameter dynamics. Wall times are of a shared 2-core machine; "
        "CPU time counts every thread.",
        "",
    ]
    return "\n".join(lines)


def main() -> None:
    results = [compare(system) for system in SYSTEMS]
    (HERE / "peers.json").write_text(json.dumps(results, indent=2) + "\n")
    text = _markdown(results)
    (HERE / "peers.md").write_text(text)
    print(text)

"""Estimators side by side: the maths of each, and their statistics against the Cramer-Rao bound.

The motion does not depend on the sensor noise, so each system is simulated once (noise-free) and measured
again for every Monte-Carlo run.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
from omegaconf import OmegaConf

from dynamics.base import BaseParameters, base_parameters
from dynamics.inertia import body_and_jacobian, body_from_log_cholesky, log_cholesky_from_body, pseudo_inertia
from dynamics.plant import Plant, load_plant
from dynamics.prior import PriorSpec, make_prior
from dynamics.regressor import ParameterModel
from envs.dataset import Dataset
from envs.sensors import SensorModel
from excitation.fourier import FourierDesign
from excitation.limits import limits_for
from excitation.registry import design_excitation
from harness.setup import CONF_DIR, simulate_design
from identify.compare import predict_torque
from identify.derivatives import States, derive_states
from identify.estimators import ESTIMATORS, estimate
from identify.estimators.signals import filtered_model
from identify.problem import Problem, build_problem
from tests.conftest import compose_config


class Case(NamedTuple):
    plant: Plant
    model: ParameterModel
    base: BaseParameters
    design: FourierDesign
    clean: Dataset
    sigma_tau: np.ndarray
    tau_resolution: float


@functools.cache
def case(system: str, periods: float | None = None, scale: float = 1.0, seconds: float | None = None) -> Case:
    """One noise-free simulation of the system's default design (optionally shrunk or shortened)."""
    cfg = compose_config([f"system={system}"])
    plant = load_plant(cfg.system.mjcf)
    model = ParameterModel(plant, tuple(cfg.system.effects))
    base = base_parameters(model, np.random.default_rng(0))
    limits = limits_for(plant, velocity=cfg.system.limits.velocity, acceleration=cfg.system.limits.acceleration)
    design = design_excitation(
        "default",
        plant,
        limits,
        model=model,
        harmonics=5,
        base_freq_hz=float(cfg.system.base_freq_hz),
        torque_driven=False,
        rng=np.random.default_rng(0),
    )
    if scale != 1.0:
        design = design.scaled(scale)
    length = float(periods or cfg.system.periods) if seconds is None else seconds / design.period_s
    quiet = SensorModel(sample_rate_hz=float(cfg.system.sensor.sample_rate_hz))
    clean = simulate_design(plant, design, cfg, quiet, np.random.default_rng(0), length)
    sigma_tau = np.broadcast_to(np.asarray(cfg.system.sensor.sigma_tau, float), (plant.nv,)).copy()
    return Case(plant, model, base, design, clean, sigma_tau, float(cfg.system.sensor.tau_resolution))


def measure(c: Case, rng: np.random.Generator, *, sigma_q: float = 0.0, q_resolution: float = 0.0) -> Dataset:
    sensor = SensorModel(
        sigma_q=sigma_q, q_resolution=q_resolution, sigma_tau=c.sigma_tau, tau_resolution=c.tau_resolution
    )
    return dataclasses.replace(
        c.clean,
        q=sensor.measure_q(c.clean.meta["q_true"], rng),
        tau=sensor.measure_tau(c.clean.meta["tau_applied"], c.plant.actuated, rng),
    )


def crlb(c: Case, rows: np.ndarray) -> np.ndarray:
    """(r,) Cramer-Rao bound of each base parameter: diag (X' S^-1 X)^-1, X the exact regressor on `rows`."""
    exact = build_problem(c.clean, derive_states(c.clean, "simulator"), c.model, c.base).W[rows]
    var = c.sigma_tau**2 + c.tau_resolution**2 / 12.0
    return np.diag(np.linalg.inv(np.einsum("knr,n,kns->rs", exact, 1.0 / var, exact)))


def rel_errors(names: tuple[str, ...], beta: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """|error| / |truth|; a parameter whose truth is 0 is compared with the largest of its kind (MX with MZ)."""
    out = np.empty(len(beta))
    for i, name in enumerate(names):
        scale = (
            abs(truth[i])
            if abs(truth[i]) > 1e-12
            else max(abs(truth[j]) for j, other in enumerate(names) if other[0] == name[0])
        )
        out[i] = abs(beta[i] - truth[i]) / scale
    return out


# --- the acceleration-free model and the physical parametrisation ---------------------------------------


def test_filtered_model_holds_exactly_on_analytic_states() -> None:
    c = case("two_link", periods=1)
    t = c.clean.time
    q, dq, ddq = c.design.evaluate(t)
    beta = c.base.project(c.model.truth())
    exact = c.base.columns(c.model.regressor(q, dq, ddq))
    data = dataclasses.replace(c.clean, tau=exact @ beta, tau_lead_s=0.0)
    problem = build_problem(data, States(q, dq, ddq, np.ones(len(t), bool)), c.model, c.base)
    fm = filtered_model(problem, omega=20.0)
    predicted = np.einsum("knr,r->kn", fm.psi[fm.settled], beta)
    # no acceleration entered psi, yet it reproduces the filtered torque (Tustin's error is O(dt^2))
    assert np.max(np.abs(predicted - fm.y[fm.settled])) < 1e-5 * np.max(np.abs(fm.y))


def test_log_cholesky_covers_consistent_bodies_and_its_jacobian_is_exact() -> None:
    plant = load_plant("two_link")
    for j in range(plant.nv):
        body = plant.theta[10 * j : 10 * j + 10]
        np.testing.assert_allclose(body_from_log_cholesky(log_cholesky_from_body(body)), body, atol=1e-12)
    rng = np.random.default_rng(0)
    for _ in range(20):
        x = rng.normal(size=10)
        assert np.linalg.eigvalsh(pseudo_inertia(body_from_log_cholesky(x)))[0] > 0
        _, jac = body_and_jacobian(x)
        numeric = np.column_stack(
            [(body_from_log_cholesky(x + 1e-6 * e) - body_from_log_cholesky(x - 1e-6 * e)) / 2e-6 for e in np.eye(10)]
        )
        np.testing.assert_allclose(jac, numeric, atol=1e-6 * max(1.0, np.abs(numeric).max()))


# --- noise-free convergence -----------------------------------------------------------------------------


@pytest.mark.parametrize("system", ["pendulum", "two_link"])
@pytest.mark.parametrize("name", ["filtered", "rls", "gradient", "energy"])
def test_acceleration_free_estimators_converge_on_noise_free_data(system: str, name: str) -> None:
    c = case(system)
    problem = build_problem(c.clean, derive_states(c.clean, "butterworth"), c.model, c.base)
    est = estimate(name, problem)
    err = rel_errors(c.base.names, est.beta, c.base.project(c.model.truth()))
    assert np.all(err <= 0.02), dict(zip(c.base.names, err.round(4), strict=True))
    if name in ("rls", "gradient"):
        history = est.diagnostics["history"]
        assert history["beta"].shape == (len(history["time"]), len(c.base.names))
        assert np.all(np.diff(history["time"]) > 0)
    if name == "rls":
        P = est.diagnostics["P"]
        assert np.allclose(P, P.T, rtol=0, atol=1e-12 * np.abs(P).max())
        assert np.linalg.eigvalsh(P)[0] > 0
        assert np.all(est.diagnostics["history"]["min_eig_P"] > 0)


# --- statistics against the Cramer-Rao bound -------------------------------------------------------------


@pytest.mark.parametrize("name", ["ols", pytest.param("wls", marks=pytest.mark.slow)])
def test_registry_least_squares_on_the_exact_regressor_reaches_the_cramer_rao_bound(name: str) -> None:
    # the project's estimator through the registry (not a hand-written lstsq), on exact states and white noise
    c = case("two_link", periods=1)
    exact = derive_states(c.clean, "simulator")
    sensor = SensorModel(sigma_tau=c.sigma_tau, tau_resolution=c.tau_resolution)
    rng = np.random.default_rng(2024)
    runs = 200
    problem = build_problem(c.clean, exact, c.model, c.base)  # the regressor once; the noise changes per run
    betas, stds = [], []
    for _ in range(runs):
        tau = sensor.measure_tau(c.clean.meta["tau_applied"], c.plant.actuated, rng)
        est = estimate(name, dataclasses.replace(problem, y=tau[problem.rows]))
        betas.append(est.beta)
        stds.append(est.std)
    bound = crlb(c, exact.valid)
    ratio = np.var(np.array(betas), axis=0, ddof=1) / bound
    assert np.all((ratio >= 0.7) & (ratio <= 1.3)), dict(zip(c.base.names, ratio.round(3), strict=True))
    # and its own std says so: the reported variance is the bound (white noise: the HAC lag stays short)
    reported = np.mean(np.array(stds) ** 2, axis=0) / bound
    assert np.all((reported >= 0.85) & (reported <= 1.2)), dict(zip(c.base.names, reported.round(3), strict=True))


def test_wls_covariance_uses_the_weights_that_produced_the_estimate() -> None:
    c = case("two_link", periods=1)
    exact = derive_states(c.clean, "simulator")
    sensor = SensorModel(sigma_tau=c.sigma_tau * np.array([0.3, 3.0]), tau_resolution=0.0)
    data = dataclasses.replace(
        c.clean, tau=sensor.measure_tau(c.clean.meta["tau_applied"], c.plant.actuated, np.random.default_rng(3))
    )
    problem = build_problem(data, exact, c.model, c.base)
    est = estimate("wls", problem, iterations=1)
    # one iteration: the weights come from the OLS residuals; the covariance must be that fit's sandwich
    from identify.estimators.covariance import sandwich, score
    from identify.estimators.least_squares import _joint_sigma, _solve, safe_sigma

    W, y = problem.W, problem.y
    actuated = np.asarray(data.actuated, bool)
    weight = 1.0 / safe_sigma(_joint_sigma(W, y, _solve(W, y, np.ones(2))), actuated) ** 2
    np.testing.assert_allclose(est.beta, _solve(W, y, weight), rtol=1e-12)
    resid = y - np.einsum("knr,r->kn", W, est.beta)
    bread = np.linalg.inv(np.einsum("knr,n,kns->rs", W, weight, W))
    expected, _ = sandwich(bread, score(W, resid, weight))
    np.testing.assert_allclose(est.cov, expected, rtol=1e-10)


@pytest.mark.slow
def test_derivatives_from_q_leave_ols_wls_iv_unbiased_and_near_the_bound() -> None:
    c = case("pendulum")
    truth = c.base.project(c.model.truth())
    runs = 40
    betas: dict[str, list[np.ndarray]] = {"ols": [], "wls": [], "iv": []}
    prior = make_prior(c.model, PriorSpec(), np.random.default_rng(0), simulated=True)
    for seed in range(runs):
        data = measure(c, np.random.default_rng(seed), sigma_q=1.7e-5, q_resolution=2.4e-5)
        states = derive_states(data, "butterworth", cutoff_hz=10.0)
        problem = build_problem(data, states, c.model, c.base, prior=prior.theta)
        for name in betas:
            betas[name].append(estimate(name, problem).beta)
    bound = crlb(c, states.valid)
    for name, values in betas.items():
        B = np.array(values)
        std = B.std(axis=0, ddof=1)
        bias = B.mean(axis=0) - truth
        # the benchmark (500 runs) checks |bias| <= 0.5 std and var/CRLB <= 1.5; 40 runs leave room for chance
        assert np.all(np.abs(bias) <= (0.5 + 3.0 / np.sqrt(runs)) * std), (name, bias / std)
        assert np.all(std**2 / bound <= 2.0), (name, std**2 / bound)


@pytest.mark.slow
def test_iv_beats_ols_when_noisy_positions_pass_the_filter() -> None:
    # sigma_q = 1.7e-4 rad through a 20 Hz cut-off: the regressor's errors bias least squares, not IV
    c = case("pendulum")
    truth = c.base.project(c.model.truth())
    sq_err = {"ols": 0.0, "iv": 0.0}
    for seed in range(12):
        data = measure(c, np.random.default_rng(100 + seed), sigma_q=1.7e-4, q_resolution=9.6e-5)
        problem = build_problem(data, derive_states(data, "butterworth", cutoff_hz=20.0), c.model, c.base)
        for name in sq_err:
            sq_err[name] += float(np.sum((estimate(name, problem).beta - truth) ** 2))
    assert sq_err["iv"] < 0.5 * sq_err["ols"], sq_err


# --- physical consistency on poorly excited data ---------------------------------------------------------


def _two_link_certainly_inconsistent(base: BaseParameters, beta: np.ndarray) -> bool:
    """A certificate that no physical two-link arm has these base parameters.

    Link 2's inertia about its axis bounds its mass from below, YY2 >= (MX2^2 + MZ2^2) / m2 (Cauchy-Schwarz),
    while `YY1 + l1^2 m2 + Ia1` bounds it from above (YY1, Ia1 >= 0); a negative inertia fails at once.
    """
    b = dict(zip(base.names, beta, strict=True))
    inertia1 = next(n for n in base.names if n.startswith("YY1"))
    l1_sq = base.K[base.names.index(inertia1), 10]  # the coefficient of m2
    if min(b["YY2"], b[inertia1], b["Ia2"]) <= 0:
        return True
    return bool((b["MX2"] ** 2 + b["MZ2"] ** 2) / b["YY2"] > b[inertia1] / l1_sq)


def test_physical_stays_consistent_where_ols_does_not_and_predicts_better() -> None:
    short = case("two_link", scale=0.05, seconds=2.0)  # 2 s of motions at a twentieth of the design's size
    data = measure(short, np.random.default_rng(0), sigma_q=1.7e-5, q_resolution=2.4e-5)
    problem = build_problem(data, derive_states(data, "butterworth", cutoff_hz=20.0), short.model, short.base)
    prior = make_prior(short.model, PriorSpec(seed=0), np.random.default_rng(0), simulated=True)
    ols = estimate("ols", problem)
    phys = estimate("physical", dataclasses.replace(problem, prior=prior.theta))
    theta = phys.diagnostics["theta"]
    assert min(phys.diagnostics["min_pseudo_inertia_eig"]) > 0
    assert np.all(theta[10 * short.plant.nv :] >= 0)  # rotor inertias
    np.testing.assert_allclose(short.base.K @ theta, phys.beta, rtol=1e-12, atol=1e-15)
    assert not _two_link_certainly_inconsistent(short.base, phys.beta)
    assert _two_link_certainly_inconsistent(short.base, ols.beta), dict(zip(short.base.names, ols.beta, strict=True))
    full = case("two_link")  # validation: the full design, never seen by the fit
    exact = derive_states(full.clean, "simulator")

    def rms(beta: np.ndarray) -> float:
        predicted = predict_torque(full.model, full.base, beta, exact.q, exact.dq, exact.ddq)
        return float(np.sqrt(np.mean((predicted - full.clean.meta["tau_applied"]) ** 2)))

    assert rms(phys.beta) < 0.8 * rms(ols.beta), (rms(phys.beta), rms(ols.beta))


# --- registry and configs --------------------------------------------------------------------------------


def _small_problem() -> Problem:
    c = case("pendulum", periods=1)
    data = measure(c, np.random.default_rng(5), sigma_q=1.7e-5, q_resolution=2.4e-5)
    prior = make_prior(c.model, PriorSpec(), np.random.default_rng(5), simulated=True)
    return build_problem(data, derive_states(data, "butterworth"), c.model, c.base, prior=prior.theta)


def test_physical_refuses_to_run_without_a_prior() -> None:
    problem = dataclasses.replace(_small_problem(), prior=None)
    with pytest.raises(ValueError, match="needs a prior model"):
        estimate("physical", problem)


@pytest.mark.parametrize("path", sorted((CONF_DIR / "estimator").glob("*.yaml")), ids=lambda p: Path(p).stem)
def test_every_estimator_config_names_a_registered_estimator_and_runs(path: Path) -> None:
    cfg = OmegaConf.to_container(OmegaConf.load(path))
    assert isinstance(cfg, dict) and cfg["name"] in ESTIMATORS
    est = estimate(cfg["name"], _small_problem(), **(cfg.get("options") or {}))
    assert est.estimator == cfg["name"]
    assert np.all(np.isfinite(est.beta)) and est.sigma.shape == (1,)
    assert est.cov is None or np.all(np.linalg.eigvalsh(0.5 * (est.cov + est.cov.T)) > -1e-12)


def test_unknown_estimator_lists_the_valid_names() -> None:
    with pytest.raises(ValueError, match=", ".join(sorted(ESTIMATORS))):
        estimate("kalman", _small_problem())

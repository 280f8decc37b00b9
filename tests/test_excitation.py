"""Optimised excitation: criterion gradients, limits on a denser grid, cond against random designs, errors."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from omegaconf import OmegaConf

from dynamics.base import BaseParameters, base_parameters
from dynamics.errors import InfeasibleExcitationError
from dynamics.plant import Plant, load_plant
from dynamics.regressor import ParameterModel
from dynamics.torque import inverse_dynamics, joint_torque
from envs.sensors import SensorModel
from envs.simulate import simulate_tracking
from excitation.criteria import CRITERIA, conditioning, criterion, design_criterion
from excitation.designs import default_design, grid, random_design
from excitation.fourier import FourierDesign
from excitation.limits import Limits, limits_for
from excitation.optimise import (
    OptimisedExcitation,
    _PositionProblem,
    assess_design,
    optimise_excitation,
)
from excitation.registry import EXCITATIONS, design_excitation
from harness.setup import CONF_DIR, limits_from_config
from identify.derivatives import derive_states
from identify.estimators import estimate
from identify.problem import build_problem

POSITION_SYSTEMS = [
    name
    for name in sorted(p.stem for p in (CONF_DIR / "system").glob("*.yaml"))
    if name != "auto" and not OmegaConf.load(CONF_DIR / "system" / f"{name}.yaml").torque_driven
]


@cache
def _setup(system: str, effects: tuple[str, ...] | None = None) -> tuple[Plant, Limits, ParameterModel, BaseParameters]:
    """Plant, limits, model and base parameters as `sysid-run` builds them from the system's config."""
    cfg = OmegaConf.load(CONF_DIR / "system" / f"{system}.yaml")
    plant = load_plant(cfg.mjcf)
    limits = limits_from_config(cfg, plant)
    model = ParameterModel(plant, tuple(cfg.effects) if effects is None else effects)
    return plant, limits, model, base_parameters(model, np.random.default_rng(0))


def _f0(system: str) -> float:
    return float(OmegaConf.load(CONF_DIR / "system" / f"{system}.yaml").base_freq_hz)


@cache
def _optimised(system: str, harmonics: int = 5) -> OptimisedExcitation:
    plant, limits, model, base = _setup(system)
    return optimise_excitation(
        plant,
        limits,
        model=model,
        base=base,
        harmonics=harmonics,
        base_freq_hz=_f0(system),
        rng=np.random.default_rng(1),
        torque_driven=plant.name == "wheel_pendulum",
    )


def _fd(f, x: np.ndarray, h: float) -> np.ndarray:  # type: ignore[no-untyped-def]
    cols = []
    for i in range(len(x)):
        e = np.zeros_like(x)
        e[i] = h
        cols.append((np.asarray(f(x + e)) - np.asarray(f(x - e))) / (2 * h))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("name", sorted(CRITERIA))
@pytest.mark.parametrize("sharpness", [None, 20.0])
def test_criterion_gradient_matches_finite_differences(name: str, sharpness: float | None) -> None:
    # friction and armature columns are part of the conditioned regressor
    plant, limits, model, base = _setup("two_link", ("armature", "viscous_friction", "coulomb_friction"))
    design = default_design(plant, limits, harmonics=3, base_freq_hz=0.1)
    t = grid(design, 40)

    def value(x: np.ndarray) -> float:
        d = FourierDesign.from_vector(x, n_joints=2, harmonics=3, base_freq_hz=0.1)
        return design_criterion(name, d, model, base, t, sharpness=sharpness, gradient=False)[0]

    j, g = design_criterion(name, design, model, base, t, sharpness=sharpness)
    assert g is not None and np.isfinite(j)
    np.testing.assert_allclose(g, _fd(value, design.to_vector(), 1e-6), rtol=1e-5, atol=1e-6 * np.abs(g).max())


def test_smooth_cond_bounds_the_true_cond_and_report_uses_the_true_one() -> None:
    A = np.random.default_rng(0).normal(size=(60, 5)) * [1, 2, 3, 4, 50]
    exact = criterion("cond", A)[0]
    smooth = criterion("cond", A, sharpness=20.0)[0]
    assert exact == pytest.approx(np.log(np.linalg.cond(A)))
    assert exact <= smooth <= exact + 2 * np.log(5) / 20
    assert conditioning(A)[0] == pytest.approx(np.linalg.cond(A) ** 2)


def test_unknown_names_list_the_valid_ones() -> None:
    with pytest.raises(ValueError, match="cond, cond_colnorm, logdet"):
        criterion("trace", np.eye(3))
    plant, limits, model, _ = _setup("pendulum")
    kw = {"model": model, "harmonics": 3, "base_freq_hz": 0.2, "rng": np.random.default_rng(0)}
    with pytest.raises(ValueError, match="cond, cond_colnorm, logdet"):
        optimise_excitation(plant, limits, criterion="trace", **kw)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="analytic, finite_difference"):
        optimise_excitation(plant, limits, gradient="exact", **kw)  # type: ignore[arg-type]


def test_nominal_torque_matches_mujoco_and_its_derivatives() -> None:
    plant = _setup("two_link")[0]
    rng = np.random.default_rng(2)
    q, dq, ddq = (rng.normal(size=(5, 2)) for _ in range(3))
    tau, D = joint_torque(plant, q, dq, ddq, derivatives=True)
    assert D is not None
    np.testing.assert_allclose(tau, inverse_dynamics(plant, q, dq, ddq), atol=1e-10)
    for k in range(5):
        state = [q[k], dq[k], ddq[k]]
        for d in range(3):

            def torque(x: np.ndarray, d: int = d, state: list = state) -> np.ndarray:
                args = [s[None] for s in state]
                args[d] = x[None]
                return joint_torque(plant, *args)[0][0]

            np.testing.assert_allclose(D[d, k], _fd(torque, state[d], 1e-6), atol=1e-7)


def test_limit_constraint_jacobian_matches_finite_differences() -> None:
    plant, limits, model, base = _setup("two_link")
    problem = _PositionProblem(
        plant,
        limits,
        model,
        base,
        harmonics=3,
        base_freq_hz=0.1,
        criterion="cond",
        sharpness=20.0,
        criterion_points=50,
        limit_points=50,
        margin=0.01,
    )
    x = default_design(plant, limits, harmonics=3, base_freq_hz=0.1).to_vector()
    J = problem.constraints_jacobian(x)
    np.testing.assert_allclose(J, _fd(problem.constraints, x, 1e-6), atol=1e-6 * np.abs(J).max())


@pytest.mark.parametrize("system", POSITION_SYSTEMS)
def test_optimised_cond_beats_random_designs_and_limits_hold_10x_denser(system: str) -> None:
    plant, limits, model, base = _setup(system)
    result = _optimised(system)
    # the dense check uses MuJoCo's inverse dynamics, not the optimiser's nominal torque
    n_opt = len(grid(result.design, 100))  # the limit grid optimised on (limit_points = 100)
    t = grid(result.design, 10 * n_opt)
    q, dq, ddq = result.design.evaluate(t)
    ratios = limits.ratios(q, dq, ddq, inverse_dynamics(plant, q, dq, ddq))
    assert max(ratios.values()) <= 1.0, ratios
    assert result.limits_ok and result.ratios["q"] > 0.5  # it moves, within the limits
    rng = np.random.default_rng(7)
    conds = []
    for _ in range(100):
        d = random_design(plant, limits, harmonics=5, base_freq_hz=_f0(system), rng=rng)
        conds.append(conditioning(base.columns(model.regressor(*d.evaluate(grid(d, 200)))))[0])
    median = float(np.median(conds))
    if median >= 5.0:
        assert result.cond_XtX <= 0.2 * median, (result.cond_XtX, median)
    else:
        # cond(X'X) >= 1: when random designs are already within 5x of the bound, ask for 10% of it
        assert result.cond_XtX <= 1.1, (result.cond_XtX, median)


@pytest.mark.slow
def test_wheel_pendulum_torque_design_beats_random_and_holds_every_physics_step() -> None:
    plant, limits, model, base = _setup("wheel_pendulum")
    result = _optimised("wheel_pendulum")
    # the search checks every 10th physics step; the result every step (a grid 10x denser)
    cond, _, ratios = assess_design(plant, limits, result.design, model=model, base=base, torque_driven=True)
    assert max(ratios.values()) <= 1.0, ratios
    assert ratios["q"] > 0.2  # the pendulum swings: candidates are filled to their limits, not shrunk
    assert cond == pytest.approx(result.cond_XtX)
    rng = np.random.default_rng(7)
    conds = []
    for _ in range(5):
        d = random_design(plant, limits, harmonics=5, base_freq_hz=0.2, rng=rng, torque_driven=True)
        conds.append(assess_design(plant, limits, d, model=model, base=base, torque_driven=True)[0])
    assert result.cond_XtX <= 0.2 * float(np.median(conds)), (result.cond_XtX, conds)


def test_at_rest_option_starts_and_ends_at_rest() -> None:
    plant, limits, model, base = _setup("pendulum")
    result = optimise_excitation(
        plant,
        limits,
        model=model,
        base=base,
        harmonics=4,
        base_freq_hz=0.2,
        rng=np.random.default_rng(0),
        starts=2,
        at_rest=True,
    )
    _, dq, ddq = result.design.evaluate(np.array([0.0, result.design.period_s]))
    np.testing.assert_allclose(dq, 0.0, atol=1e-6)
    np.testing.assert_allclose(ddq, 0.0, atol=1e-5)
    assert result.limits_ok and result.cond_XtX < min(result.start_conds)


def test_impossible_limits_raise_naming_the_binding_constraint() -> None:
    plant, _, model, base = _setup("two_link")
    limits = limits_for(plant, velocity=8.0, acceleration=1e-4)  # no useful motion at 0.1 Hz
    with pytest.raises(InfeasibleExcitationError, match="binding constraint ddq"):
        optimise_excitation(
            plant, limits, model=model, base=base, harmonics=5, base_freq_hz=0.1, rng=np.random.default_rng(0)
        )


def test_registry_and_config_select_the_optimised_design() -> None:
    assert sorted(EXCITATIONS) == ["default", "optimised", "random"]
    cfg = OmegaConf.load(CONF_DIR / "excitation" / "optimised.yaml")
    assert cfg.name == "optimised"
    plant, limits, model, _ = _setup("pendulum")
    options = OmegaConf.to_container(cfg.options)
    options.update(starts=1)  # type: ignore[union-attr]
    design = design_excitation(
        "optimised",
        plant,
        limits,
        model=model,
        harmonics=int(cfg.harmonics),
        base_freq_hz=0.2,
        torque_driven=False,
        rng=np.random.default_rng(0),
        **options,  # type: ignore[arg-type]
    )
    assert isinstance(design, FourierDesign) and design.harmonics == cfg.harmonics


@pytest.mark.parametrize("name", ["cond_colnorm", "logdet"])
def test_other_criteria_improve_their_own_value(name: str) -> None:
    plant, limits, model, base = _setup("two_link")
    result = optimise_excitation(
        plant,
        limits,
        model=model,
        base=base,
        harmonics=3,
        base_freq_hz=0.1,
        rng=np.random.default_rng(0),
        starts=1,
        criterion=name,
    )
    start = default_design(plant, limits, harmonics=3, base_freq_hz=0.1)
    t = grid(start, 100)
    before = design_criterion(name, start, model, base, t, gradient=False)[0]
    after = design_criterion(name, result.design, model, base, t, gradient=False)[0]
    assert after < before - 0.1 and result.limits_ok


def _std(plant: Plant, model: ParameterModel, base: BaseParameters, design: FourierDesign) -> np.ndarray:
    sensor = SensorModel(sample_rate_hz=500, sigma_tau=np.array([0.02, 0.02]), tau_resolution=0.00586)
    data = simulate_tracking(plant, design, duration_s=3 * design.period_s, sensor=sensor, rng=np.random.default_rng(3))
    return estimate("ols", build_problem(data, derive_states(data, "simulator"), model, base)).std


def test_optimised_design_identifies_with_smaller_std_than_random_ones() -> None:
    plant, limits, model, base = _setup("two_link")
    std_opt = _std(plant, model, base, _optimised("two_link").design)
    rng = np.random.default_rng(11)
    std_rand = [
        _std(plant, model, base, random_design(plant, limits, harmonics=5, base_freq_hz=0.1, rng=rng)) for _ in range(3)
    ]
    # the mean standard deviation over the base parameters, against the median of the random designs'
    ratio = np.mean(std_opt) / np.median([np.mean(s) for s in std_rand])
    assert ratio < 0.5, ratio
    # per parameter it is better on average too (the gravity parameters gain least: random designs of
    # the arm already sweep whole turns, and g bounds their columns)
    assert np.mean(std_opt / np.median(std_rand, axis=0)) < 0.8


def test_a_slide_with_no_room_is_refused_in_metres(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The refusal gave a slide's motion in rad."""
    from dynamics.plant import plant_from_xml

    xml = """<mujoco model="lift"><worldbody><body name="carriage"><joint name="lift" type="slide" axis="0 0 1"
      range="-0.005 0.005"/><geom type="box" size="0.05 0.05 0.05" mass="2"/></body></worldbody>
      <actuator><motor joint="lift" ctrlrange="-100 100"/></actuator></mujoco>"""
    plant = plant_from_xml(xml, "lift", tmp_path)
    limits = limits_for(plant, velocity=0.5, acceleration=5.0, range_margin=0.0)
    with pytest.raises(InfeasibleExcitationError, match=r"the limits allow at most 0\.00\d+ m of motion \(< 0\.02\)"):
        default_design(plant, limits, harmonics=3, base_freq_hz=0.2)


@pytest.mark.parametrize("stroke", [0.04, 0.2])  # a gripper's finger; a SCARA's lift
def test_a_short_slide_does_not_hold_the_hinges_to_its_stroke(tmp_path, stroke: float) -> None:  # type: ignore[no-untyped-def]
    """One factor for every joint held two hinges of +-2 rad to the slide's few centimetres (the 4 cm finger
    was refused: at most 0.018 of motion); ranges in metres and in radians do not compare."""
    from dynamics.plant import plant_from_xml

    def arm(slide: bool) -> str:
        finger = f"""<body name="finger" pos="0 0 -0.2"><joint name="f" type="slide" axis="1 0 0" range="0 {stroke}"/>
          <inertial pos="0 0 -0.02" mass="0.05" diaginertia="1e-5 1e-5 1e-5"/></body>"""
        return f"""<mujoco model="arm"><compiler angle="radian"/><worldbody><body name="l1" pos="0 0 0.5">
          <joint name="j1" axis="0 1 0" range="-2 2"/><inertial pos="0 0 -0.1" mass="1" diaginertia="0.01 0.01 0.002"/>
          <body name="l2" pos="0 0 -0.2"><joint name="j2" axis="0 1 0" range="-2 2"/>
          <inertial pos="0 0 -0.1" mass="0.5" diaginertia="0.005 0.005 0.001"/>{finger if slide else ""}</body></body>
          </worldbody><actuator><motor joint="j1" ctrlrange="-10 10"/><motor joint="j2" ctrlrange="-5 5"/>
          {'<motor joint="f" ctrlrange="-20 20"/>' if slide else ""}</actuator></mujoco>"""

    designs = {}
    for slide in (False, True):
        plant = plant_from_xml(arm(slide), f"arm_{slide}", tmp_path)
        limits = limits_for(plant, velocity=3.0, acceleration=30.0, range_margin=0.05)
        designs[slide] = (default_design(plant, limits, harmonics=5, base_freq_hz=0.2), limits)
    hinges = np.abs(designs[False][0].a[:2]).sum(axis=1)
    with_slide, limits = designs[True]
    np.testing.assert_allclose(np.abs(with_slide.a[:2]).sum(axis=1), hinges, rtol=1e-6)  # as without the finger
    q = with_slide.evaluate(grid(with_slide, 4000))[0]
    assert np.ptp(q[:, 0]) > 0.5 and np.all(q >= limits.q_min - 1e-9) and np.all(q <= limits.q_max + 1e-9)
    assert np.ptp(q[:, 2]) > 0.5 * stroke  # the finger moves over its own stroke

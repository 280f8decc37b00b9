"""Optimised excitation: the Fourier design with the best-conditioned regressor that the limits allow.

Position designs (fully actuated systems) are optimised by SLSQP from several starts (the default design
and random ones drawn from `rng`), with the criterion's analytic gradient (`excitation.criteria`). The
limits are constraints on a time grid: joint range, speed and acceleration are linear in the coefficients;
the torque comes from the nominal model (Pinocchio's RNEA with the MJCF's armature, damping and stiffness)
with its analytic derivatives. The result is checked on a grid ten times denser and, should a peak fall
between the grid's points, shrunk until every limit holds there.

Torque designs (underactuated systems) drive the actuated joints open loop; the motion, and with it the
regressor, comes from simulating the nominal model from rest. Their criterion is evaluated on batched
rollouts (`mujoco.rollout`) and improved by an evolution strategy whose populations are rolled out together
(derivative-free: the motion's sensitivity would need the whole rollout differentiated). Each candidate is
scaled to its limits, as random designs are, and the result is checked at every physics step.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize

from dynamics.base import BaseParameters, base_parameters
from dynamics.clearance import Clearance
from dynamics.errors import InfeasibleExcitationError, RankDeficientError
from dynamics.plant import Plant
from dynamics.regressor import ParameterModel
from dynamics.torque import joint_torque
from excitation.criteria import CRITERIA, conditioning, design_criterion
from excitation.criteria import criterion as evaluate_criterion
from excitation.designs import default_design, fit_to_limits, grid, random_design
from excitation.fourier import FourierDesign
from excitation.limits import Limits
from excitation.torque_search import CHECK_DENSITY, TorqueSearch, check_columns, cond_xtx, raw_torque_shape

__all__ = [
    "GRADIENTS",
    "OptimisedExcitation",
    "assess_design",
    "optimise_excitation",
    "position_limit_ratios",
    "within_clearance",
]

GRADIENTS = ("analytic", "finite_difference")


@dataclass(frozen=True)
class OptimisedExcitation:
    """An optimised design and the numbers that describe it.

    Attributes:
        design: the optimised Fourier design (joint motion, or drive torque when torque driven).
        criterion: the criterion's name.
        cond_XtX: cond(X'X) of the stacked base regressor on the check grid (raw).
        cond_W_colnorm: cond(W) with unit-norm columns on the check grid.
        ratios: worst use of each bound (`q`, `dq`, `ddq`, `tau`) on the check grid; <= 1 holds.
        start_conds: (starts,) cond(X'X) of each start before optimisation.
        final_conds: (starts,) cond(X'X) of each start after optimisation.
        wall_s: optimisation wall time [s].
        evaluations: criterion evaluations (gradients included) over every start.
    """

    design: FourierDesign
    criterion: str
    cond_XtX: float
    cond_W_colnorm: float
    ratios: dict[str, float]
    start_conds: tuple[float, ...]
    final_conds: tuple[float, ...]
    wall_s: float
    evaluations: int
    options: dict = field(default_factory=dict)

    @property
    def limits_ok(self) -> bool:
        return max(self.ratios.values()) <= 1.0


def position_limit_ratios(plant: Plant, design: FourierDesign, limits: Limits, t: np.ndarray) -> dict[str, float]:
    """Worst use of each bound by a position design on the times `t` [s] (torque of the nominal model)."""
    q, dq, ddq = design.evaluate(t)
    return limits.ratios(q, dq, ddq, joint_torque(plant, q, dq, ddq)[0])


def assess_design(
    plant: Plant,
    limits: Limits,
    design: FourierDesign,
    *,
    model: ParameterModel,
    base: BaseParameters,
    torque_driven: bool = False,
    periods: float = 3.0,
    points_per_period: int = 1000,
) -> tuple[float, float, dict[str, float]]:
    """cond(X'X), column-normalised cond(W) and the worst use of each bound of any design.

    A position design is sampled at `points_per_period` per period (torque of the nominal model); a torque
    design is simulated from rest for `periods` periods and checked at every physics step.
    """
    if torque_driven:
        search = TorqueSearch(
            plant, limits, model, base, criterion="cond", periods=periods, margin=0.0, criterion_points=100
        )
        ratios, W = search.check(design)
    else:
        t = grid(design, points_per_period)
        ratios = position_limit_ratios(plant, design, limits, t)
        W = base.columns(model.regressor(*design.evaluate(t)))
    return (*conditioning(W), ratios)


def optimise_excitation(
    plant: Plant,
    limits: Limits,
    *,
    model: ParameterModel,
    harmonics: int,
    base_freq_hz: float,
    rng: np.random.Generator,
    criterion: str = "cond",
    starts: int = 4,
    at_rest: bool = False,
    torque_driven: bool = False,
    gradient: str = "analytic",
    sharpness: float | None = 20.0,
    criterion_points: int = 100,
    limit_points: int = 100,
    margin: float = 0.01,
    max_iter: int = 100,
    periods: float = 3.0,
    generations: int = 8,
    population: int = 8,
    fill_limits: bool = True,
    base: BaseParameters | None = None,
    progress: Callable[[float, str], None] | None = None,
) -> OptimisedExcitation:
    """The design of `harmonics` harmonics of `base_freq_hz` that minimises `criterion` within `limits`.

    Args:
        model: the parameters to identify; its base regressor (effect columns included) is conditioned.
        rng: draws the random starts (and the evolution strategy's samples for torque designs).
        criterion: a key of `excitation.criteria.CRITERIA`.
        starts: optimisations run; the first starts from the default design, the others from random ones.
        at_rest: start and end every period at rest (dq = ddq = 0 at t = 0; position designs only).
        torque_driven: design an open-loop drive torque (underactuated systems).
        gradient: `analytic` (chain rule) or `finite_difference` (SciPy's, the baseline benchmarked against).
        sharpness: p of the smooth cond bound minimised (None: the exact, non-smooth cond).
        criterion_points, limit_points: samples per period of the criterion's and the limits' grids.
        margin: fraction of each bound kept free while optimising (the result is re-checked without it).
        max_iter: SLSQP iterations per start.
        periods: simulated periods from rest for a torque design (as long as the identification data).
        generations, population: evolution strategy for torque designs.
        fill_limits: torque designs: scale every candidate until its most used bound is (nearly) met, as the
            random and default designs are; otherwise raw cond favours barely moving (its velocity-squared
            columns shrink fastest).
        base: the model's base parameters (found with `rng` when not given).
        progress: called as progress(fraction done, message) after each start or generation.

    Raises:
        ValueError: unknown criterion or gradient (the message lists the valid ones).
        InfeasibleExcitationError: the limits leave no useful motion (the message names the binding bound).
        RankDeficientError: a base parameter's regressor column vanishes on every trajectory.
    """
    if criterion not in CRITERIA:
        raise ValueError(f"unknown excitation criterion {criterion!r}; valid choices: {', '.join(sorted(CRITERIA))}")
    if gradient not in GRADIENTS:
        raise ValueError(f"unknown gradient {gradient!r}; valid choices: {', '.join(GRADIENTS)}")
    if starts < 1:
        raise ValueError(f"starts must be >= 1, got {starts}")
    base = base if base is not None else base_parameters(model, rng.spawn(1)[0])
    options = {"criterion": criterion, "starts": starts, "at_rest": at_rest, "gradient": gradient}
    clock = time.perf_counter()
    check_points = 0  # torque designs are checked at every physics step
    if torque_driven:
        search = TorqueSearch(
            plant,
            limits,
            model,
            base,
            criterion=criterion,
            periods=periods,
            margin=margin,
            criterion_points=criterion_points,
            fill=fill_limits,
        )
        shapes = [raw_torque_shape(plant, harmonics, base_freq_hz, None if i == 0 else rng) for i in range(starts)]
        design, start_j, final_j = search.run(
            shapes, rng, generations=generations, population=population, progress=progress
        )
        evaluations = search.evaluations
    else:
        problem = _PositionProblem(
            plant,
            limits,
            model,
            base,
            harmonics=harmonics,
            base_freq_hz=base_freq_hz,
            criterion=criterion,
            sharpness=sharpness,
            criterion_points=criterion_points,
            limit_points=limit_points,
            margin=margin,
        )
        shapes = _position_starts(plant, limits, problem, rng, starts, at_rest)
        design, start_j, final_j = problem.run(
            shapes, at_rest=at_rest, gradient=gradient, max_iter=max_iter, progress=progress
        )
        evaluations = problem.evaluations
        check_points = CHECK_DENSITY * len(problem.t_lim)
    wall_s = time.perf_counter() - clock
    cond_xtx, cond_colnorm, ratios = assess_design(
        plant,
        limits,
        design,
        model=model,
        base=base,
        torque_driven=torque_driven,
        periods=periods,
        points_per_period=check_points,
    )
    return OptimisedExcitation(
        design=design,
        criterion=criterion,
        cond_XtX=cond_xtx,
        cond_W_colnorm=cond_colnorm,
        ratios=ratios,
        start_conds=tuple(start_j),
        final_conds=tuple(final_j),
        wall_s=wall_s,
        evaluations=evaluations,
        options=options,
    )


class _PositionProblem:
    """SLSQP over x = [a, b, q0] with the limits as ratios r on a grid: |r| <= bound, as bound^2 - r^2 >= 0."""

    def __init__(
        self,
        plant: Plant,
        limits: Limits,
        model: ParameterModel,
        base: BaseParameters,
        *,
        harmonics: int,
        base_freq_hz: float,
        criterion: str,
        sharpness: float | None,
        criterion_points: int,
        limit_points: int,
        margin: float,
    ) -> None:
        self.plant, self.limits, self.model, self.base = plant, limits, model, base
        self.n, self.H, self.f0 = plant.nv, harmonics, base_freq_hz
        self.criterion, self.sharpness, self.bound = criterion, sharpness, 1.0 - margin
        shape = FourierDesign(
            base_freq_hz, np.zeros((self.n, harmonics)), np.zeros((self.n, harmonics)), np.zeros(self.n)
        )
        self.t_crit, self.t_lim = grid(shape, criterion_points), grid(shape, limit_points)
        self.B = np.stack(shape.basis(self.t_lim))  # (3, N, 2H): q - q0, dq, ddq
        self.P, self.c, self.scale = self._linear_rows()
        self.act = np.flatnonzero(np.isfinite(limits.tau_max))
        # clearance on every other point of the limits' grid (the result is checked densely afterwards)
        self.clear_rows = slice(None, None, 2) if limits.clearance is not None else slice(0, 0)
        self.evaluations = 0
        self._cache: tuple[bytes, np.ndarray, np.ndarray] | None = None
        self._clear_cache: tuple[bytes, np.ndarray, np.ndarray] | None = None

    def design(self, x: np.ndarray) -> FourierDesign:
        return FourierDesign.from_vector(x, n_joints=self.n, harmonics=self.H, base_freq_hz=self.f0)

    def _columns(self, j: int) -> tuple[np.ndarray, np.ndarray, int]:
        nH = self.n * self.H
        a = j * self.H + np.arange(self.H)
        return a, nH + a, 2 * nH + j

    def _linear_rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rows P, centres c and half-widths s with ratio = (P x - c) / s for q, dq and ddq of every joint."""
        lim, nx = self.limits, 2 * self.n * self.H + self.n
        finite = np.isfinite(lim.q_min) & np.isfinite(lim.q_max)
        rows, centres, scales = [], [], []
        for j in range(self.n):
            a, b, q0 = self._columns(j)
            for d, (c, s) in enumerate(
                [
                    (0.5 * (lim.q_max[j] + lim.q_min[j]), 0.5 * (lim.q_max[j] - lim.q_min[j]))
                    if finite[j]
                    else (0.0, 0.0),
                    (0.0, lim.dq_max[j]),
                    (0.0, lim.ddq_max[j]),
                ]
            ):
                if d == 0 and not finite[j]:
                    continue
                P = np.zeros((self.B.shape[1], nx))
                P[:, a], P[:, b] = self.B[d][:, : self.H], self.B[d][:, self.H :]
                P[:, q0] = 1.0 if d == 0 else 0.0
                rows.append(P)
                centres.append(np.full(len(P), c))
                scales.append(np.full(len(P), s))
        return np.vstack(rows), np.concatenate(centres), np.concatenate(scales)

    def _ratios(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every constrained ratio (linear rows, then torque of the actuated joints) and its Jacobian."""
        key = x.tobytes()
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1], self._cache[2]
        q, dq, ddq = self.design(x).evaluate(self.t_lim)
        tau, D = joint_torque(self.plant, q, dq, ddq, derivatives=True)
        assert D is not None
        J_ab = np.einsum("dkji,dkh->kjih", D, self.B)  # (N, nv, nv, 2H)
        N = len(self.t_lim)
        J_tau = np.concatenate(
            [J_ab[..., : self.H].reshape(N, self.n, -1), J_ab[..., self.H :].reshape(N, self.n, -1), D[0]], axis=2
        )
        tau_max = self.limits.tau_max[self.act]
        r = np.concatenate([(self.P @ x - self.c) / self.scale, (tau[:, self.act] / tau_max).ravel()])
        J = np.vstack([self.P / self.scale[:, None], (J_tau[:, self.act] / tau_max[:, None]).reshape(-1, len(x))])
        self._cache = (key, r, J)
        return r, J

    def _clearance(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rows d / clearance - 1 / bound >= 0 (d the smooth smallest distance) on the clearance grid, and
        their Jacobian: the distance's gradient in q chained through q's linear map from x."""
        key = x.tobytes()
        if self._clear_cache is not None and self._clear_cache[0] == key:
            return self._clear_cache[1], self._clear_cache[2]
        clearance = self.limits.clearance
        if clearance is None:
            return np.zeros(0), np.zeros((0, len(x)))
        t = self.t_lim[self.clear_rows]
        q = self.design(x).evaluate(t)[0]
        d, g = clearance.smooth_distance(q)  # (K,), (K, n)
        B0 = self.B[0][self.clear_rows]  # (K, 2H)
        K = len(t)
        J = (
            np.concatenate(
                [
                    (g[:, :, None] * B0[:, None, : self.H]).reshape(K, -1),
                    (g[:, :, None] * B0[:, None, self.H :]).reshape(K, -1),
                    g,
                ],
                axis=1,
            )
            / clearance.clearance_m
        )
        c = d / clearance.clearance_m - 1.0 / self.bound
        self._clear_cache = (key, c, J)
        return c, J

    def constraints(self, x: np.ndarray) -> np.ndarray:
        """bound^2 - r^2 >= 0: both sides of every bound in one row (half the rows of a QP subproblem); then
        the clearance rows."""
        r = self._ratios(x)[0]
        return np.concatenate([self.bound**2 - r**2, self._clearance(x)[0]])

    def constraints_jacobian(self, x: np.ndarray) -> np.ndarray:
        r, J = self._ratios(x)
        return np.vstack([-2.0 * r[:, None] * J, self._clearance(x)[1]])

    def objective(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        self.evaluations += 1
        value, g = design_criterion(
            self.criterion, self.design(x), self.model, self.base, self.t_crit, sharpness=self.sharpness
        )
        assert g is not None
        return value, g

    def objective_value(self, x: np.ndarray) -> float:
        self.evaluations += 1
        return design_criterion(
            self.criterion,
            self.design(x),
            self.model,
            self.base,
            self.t_crit,
            sharpness=self.sharpness,
            gradient=False,
        )[0]

    def rest_rows(self) -> np.ndarray:
        """(2n, nx) E with E x = (dq(0), ddq(0)) of every joint."""
        E = np.zeros((2 * self.n, 2 * self.n * self.H + self.n))
        wl = 2 * np.pi * self.f0 * np.arange(1, self.H + 1)
        for j in range(self.n):
            a, b, _ = self._columns(j)
            E[j, a], E[self.n + j, b] = 1.0, wl
        return E

    def exact(self, design: FourierDesign) -> tuple[float, float]:
        """The criterion (exact, not smoothed) and cond(X'X) on the criterion's grid."""
        q, dq, ddq = design.evaluate(self.t_crit)
        A = self.base.columns(self.model.regressor(q, dq, ddq))
        A = A.reshape(-1, A.shape[-1])
        check_columns(A, self.base, self.plant)
        return evaluate_criterion(self.criterion, A)[0], cond_xtx(A)

    def solve(self, x0: np.ndarray, *, at_rest: bool, gradient: str, max_iter: int) -> np.ndarray:
        analytic = gradient == "analytic"
        ineq: dict = {"type": "ineq", "fun": self.constraints}
        constraints = [ineq]
        if analytic:
            ineq["jac"] = self.constraints_jacobian
        if at_rest:
            E = self.rest_rows()
            eq: dict = {"type": "eq", "fun": lambda x: E @ x}
            if analytic:
                eq["jac"] = lambda x: E
            constraints.append(eq)
        res = minimize(
            self.objective if analytic else self.objective_value,
            x0,
            jac=True if analytic else None,
            method="SLSQP",
            constraints=constraints,
            options={"maxiter": max_iter, "ftol": 1e-4},
        )
        return np.asarray(res.x)

    def run(
        self,
        shapes: list[FourierDesign],
        *,
        at_rest: bool,
        gradient: str,
        max_iter: int,
        progress: Callable[[float, str], None] | None = None,
    ) -> tuple[FourierDesign, list[float], list[float]]:
        """Optimise from every start; the best result that holds the limits on the dense grid wins."""
        t_check = grid(shapes[0], CHECK_DENSITY * len(self.t_lim))
        best: tuple[float, FourierDesign] | None = None
        failure: Exception = InfeasibleExcitationError("no start")
        start_j: list[float] = []
        final_j: list[float] = []
        for i, shape in enumerate(shapes):
            if progress is not None:
                done = f", best cond {min(final_j):.4g}" if final_j else ""
                progress(i / len(shapes), f"start {i + 1}/{len(shapes)}{done}")
            start_j.append(self.exact(shape)[1])
            x = self.solve(shape.to_vector(), at_rest=at_rest, gradient=gradient, max_iter=max_iter)
            try:
                design = _shrink_into_limits(self.plant, self.design(x), self.limits, t_check)
            except InfeasibleExcitationError:
                # SLSQP left the feasible set for good (offsets out of range or in collision): keep the start,
                # shrunk into the limits it may break (clearance, which the start's scaling does not check)
                try:
                    design = _shrink_into_limits(self.plant, shape, self.limits, t_check)
                    value, cond = self.exact(design)
                except (InfeasibleExcitationError, RankDeficientError) as err:
                    failure = err  # shrunk this far, the start no longer excites every base parameter
                    final_j.append(float("inf"))
                    continue
            else:
                value, cond = self.exact(design)
            final_j.append(cond)
            if best is None or value < best[0]:
                best = (value, design)
        if best is None:
            raise failure
        if progress is not None:
            progress(1.0, f"{len(shapes)} starts, best cond {min(final_j):.4g}")
        return best[1], start_j, final_j


_CLEARANCE_MARGIN = 0.005


def _shrink_into_limits(plant: Plant, design: FourierDesign, limits: Limits, t: np.ndarray) -> FourierDesign:
    """The design, its amplitudes shrunk (offsets kept) until every bound holds on the times `t`.

    Raises:
        InfeasibleExcitationError: even the offsets alone break a bound (named in the message).
    """

    def worst(s: float) -> tuple[float, dict[str, float]]:
        ratios = position_limit_ratios(plant, design.scaled(s), limits, t)
        if "clearance" in ratios:  # keep 0.5 % in hand for the denser check after (on a different grid)
            ratios["clearance"] *= 1.0 + _CLEARANCE_MARGIN
        return max(ratios.values()), ratios

    if worst(1.0)[0] <= 1.0:
        return design
    rest, ratios = worst(0.0)
    if rest > 1.0:
        raise limits.infeasible(f"the optimised offsets q0 = {design.q0} break a limit at rest", ratios)
    lo, hi = 0.0, 1.0
    for _ in range(20):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if worst(mid)[0] <= 1.0 else (lo, mid)
    return design.scaled(lo)


def within_clearance(plant: Plant, limits: Limits, design: FourierDesign) -> FourierDesign:
    """A position design kept clear of the floor and of the arm itself (for the default and random designs,
    which are scaled to every other limit): where it breaks the clearance it is moved about an open pose
    (`_open_pose`) and scaled again to the limits, then shrunk until the clearance holds on the check grid.

    Raises:
        InfeasibleExcitationError: even the offsets alone break the clearance (named in the message).
    """
    if limits.clearance is None:
        return design
    t = grid(design, CHECK_DENSITY * 100)
    if limits.clearance.ratio(design.evaluate(t)[0]) > 1.0:
        q0 = _open_pose(limits.clearance, limits, design.q0)
        design = fit_to_limits(plant, FourierDesign(design.base_freq_hz, design.a, design.b, q0), limits)
    return _shrink_into_limits(plant, design, limits, t)


_OPEN_LENGTH_M = 0.1
_OPEN_ROOM = 0.2  # share of each finite joint range an open pose keeps free at both ends


def _open_pose(clearance: Clearance, limits: Limits, q: np.ndarray, *, steps: int = 40) -> np.ndarray:
    """A pose near `q` (nv,) with room around it: a projected ascent (into the ranges) of the soft minimum of
    every distance with a long smoothing length (`_OPEN_LENGTH_M`), so that every near pair and floor
    distance pushes, not only the nearest."""
    # the pose keeps a share of each finite range on both sides: the motion about it needs room (a pose on a
    # range's end, where a short slide's range puts a 0.2 step, leaves nothing to scale the design into)
    width = np.where(np.isfinite(limits.q_max - limits.q_min), limits.q_max - limits.q_min, 0.0)
    lo, hi = limits.q_min + _OPEN_ROOM * width, limits.q_max - _OPEN_ROOM * width
    q = np.clip(q, lo, hi)
    d, g = clearance.smooth_distance(q[None], temperature_m=_OPEN_LENGTH_M)
    step = 0.2
    for _ in range(steps):
        norm = float(np.linalg.norm(g[0]))
        if norm == 0 or step < 1e-3:
            break
        trial = np.clip(q + step * g[0] / norm, lo, hi)
        d_t, g_t = clearance.smooth_distance(trial[None], temperature_m=_OPEN_LENGTH_M)
        if d_t[0] > d[0]:
            q, d, g = trial, d_t, g_t
        else:
            step *= 0.5
    return q


def _position_starts(
    plant: Plant, limits: Limits, problem: _PositionProblem, rng: np.random.Generator, starts: int, at_rest: bool
) -> list[FourierDesign]:
    """The default design and `starts - 1` random ones, each scaled into the limits (and brought to rest).

    They move about the ranges' middle unless the default design breaks the clearance there (an arm
    stretched out above the floor): then about an open pose (`_open_pose`), so that SLSQP starts near the
    clearance it has to keep.
    """
    H, f0 = problem.H, problem.f0
    q0 = None
    first = default_design(plant, limits, harmonics=H, base_freq_hz=f0)
    if limits.clearance is not None and limits.clearance.ratio(first.evaluate(problem.t_lim)[0]) > 1.0:
        q0 = _open_pose(limits.clearance, limits, first.q0)
        first = default_design(plant, limits, harmonics=H, base_freq_hz=f0, q0=q0)
    shapes = [first]
    shapes += [random_design(plant, limits, harmonics=H, base_freq_hz=f0, rng=rng, q0=q0) for _ in range(starts - 1)]
    if not at_rest:
        return shapes
    E = problem.rest_rows()
    out = []
    for shape in shapes:
        x = shape.to_vector()
        x = x - np.linalg.pinv(E) @ (E @ x)  # the nearest coefficients with dq(0) = ddq(0) = 0
        out.append(fit_to_limits(plant, problem.design(x), limits))
    return out

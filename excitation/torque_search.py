"""Excitation of torque-driven (underactuated) systems: an evolution strategy over batched MuJoCo rollouts.

The criterion is evaluated on simulated motion of the nominal model from rest, so the design is a drive
torque, not a trajectory; there is no analytic gradient, and `mujoco.rollout` runs each population at once.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import mujoco
import numpy as np
from mujoco import rollout

from dynamics.base import BaseParameters
from dynamics.errors import InfeasibleExcitationError, RankDeficientError
from dynamics.plant import Plant
from dynamics.regressor import ParameterModel
from excitation.criteria import conditioning
from excitation.criteria import criterion as evaluate_criterion
from excitation.designs import default_shape, grid, on_actuated, random_shape, torque_model
from excitation.fourier import FourierDesign
from excitation.limits import Limits

__all__ = ["CHECK_DENSITY", "TorqueSearch", "check_columns", "cond_xtx", "raw_torque_shape"]

CHECK_DENSITY = 10  # the result is verified on a grid this many times denser than the one optimised on


def cond_xtx(A: np.ndarray) -> float:
    return conditioning(A)[0]


def check_columns(A: np.ndarray, base: BaseParameters, plant: Plant) -> None:
    """Fail early on a base regressor with a vanishing column: no trajectory can condition it."""
    norms = np.linalg.norm(A, axis=0)
    dead = [base.names[i] for i in np.flatnonzero(norms <= 1e-9 * norms.max())]
    if dead:
        raise RankDeficientError(
            f"{plant.name}: the base regressor's columns of {dead} vanish on the trajectory (norms "
            f"{norms.min():.3g} of at most {norms.max():.3g}); the base parameters keep an unidentifiable parameter"
        )


def raw_torque_shape(
    plant: Plant, harmonics: int, base_freq_hz: float, rng: np.random.Generator | None
) -> FourierDesign:
    """A torque shape on the actuated joints: the default shape (rng None) or a random one, unscaled."""
    zero = np.zeros(plant.nv)
    if rng is None:
        return on_actuated(plant, default_shape(plant.nv, harmonics, base_freq_hz, zero))
    return on_actuated(plant, random_shape(plant.nv, harmonics, base_freq_hz, zero, rng))


class TorqueSearch:
    """Evolution strategy over the drive-torque coefficients; each population is rolled out in one batch.

    Candidates are capped at the torque bound and, with `fill`, scaled until their most used bound is met;
    the motion's bounds (range, speed, acceleration) are checked on every tenth physics step while searching
    (with the margin) and on every step at the end.
    """

    _LIMIT_STRIDE = CHECK_DENSITY

    def __init__(
        self,
        plant: Plant,
        limits: Limits,
        model: ParameterModel,
        base: BaseParameters,
        *,
        criterion: str,
        periods: float,
        margin: float,
        criterion_points: int,
        fill: bool = False,
    ) -> None:
        self.plant, self.limits, self.model, self.base = plant, limits, model, base
        self.fill = fill
        self.criterion, self.periods, self.bound = criterion, periods, 1.0 - margin
        self.criterion_points = criterion_points
        self.mj = m = torque_model(plant)
        self.dt = float(m.opt.timestep)
        self.act = np.flatnonzero(plant.actuated)
        self.act_joint = np.array([int(m.jnt_dofadr[m.actuator_trnid[a, 0]]) for a in range(m.nu)], dtype=int)
        self.datas = [mujoco.MjData(m) for _ in range(min(2, os.cpu_count() or 1))]
        self.evaluations = 0

    def _rollout(self, designs: list[FourierDesign]) -> tuple[np.ndarray, ...]:
        """q, dq, ddq, tau: each (batch, nstep, nv), from rest, at every physics step (`torque_model`)."""
        m = self.mj
        nstep = int(round(self.periods * designs[0].period_s / self.dt)) + 1
        t = np.arange(nstep) * self.dt
        tau = np.stack([d.torque(t) for d in designs])
        control = tau[:, :, self.act_joint] / m.actuator_gear[:, 0]
        spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        data = mujoco.MjData(m)
        state0 = np.empty(mujoco.mj_stateSize(m, spec))
        mujoco.mj_getState(m, data, state0, spec)
        states, _ = rollout.rollout(m, self.datas, state0[None, :], control)
        q, dq = states[:, :, 1 : 1 + m.nq], states[:, :, 1 + m.nq : 1 + m.nq + m.nv]
        ddq = np.diff(dq, axis=1) / self.dt
        return q[:, :-1], dq[:, :-1], ddq, tau[:, 1:]

    def _stride(self, design: FourierDesign) -> int:
        return max(1, int(round(design.period_s / self.dt / self.criterion_points)))

    def score(
        self, designs: list[FourierDesign], *, limit_stride: int, bound: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, float]]]:
        """Criterion, cond(X'X), bound violation (0 where every bound holds) and ratios of each design."""
        q, dq, ddq, tau = self._rollout(designs)
        cs, ls = self._stride(designs[0]), limit_stride
        values, conds, violation, all_ratios = [], [], [], []
        for b in range(len(designs)):
            ratios = self.limits.ratios(q[b, ::ls], dq[b, ::ls], ddq[b, ::ls], tau[b, ::ls])
            A = self.base.columns(self.model.regressor(q[b, ::cs], dq[b, ::cs], ddq[b, ::cs]))
            A = A.reshape(-1, A.shape[-1])
            check_columns(A, self.base, self.plant)
            values.append(evaluate_criterion(self.criterion, A)[0])
            conds.append(cond_xtx(A))
            violation.append(max(0.0, max(ratios.values()) - bound))
            all_ratios.append(ratios)
        self.evaluations += len(designs)
        return np.array(values), np.array(conds), np.array(violation), all_ratios

    def _to_torque_bound(self, design: FourierDesign, *, grow: bool = False) -> FourierDesign:
        """Scaled down (or, with `grow`, up) until the peak drive torque meets the bound."""
        peak = np.max(np.abs(design.torque(grid(design, 2000))), axis=0)[self.act]
        if not np.any(peak > 0):
            return design
        s = float(np.min(self.bound * self.limits.tau_max[self.act] / np.maximum(peak, 1e-300)))
        return design.scaled(s if grow else min(1.0, s))

    def _vector(self, design: FourierDesign) -> np.ndarray:
        return np.concatenate([design.a[self.act].ravel(), design.b[self.act].ravel()])

    def _design(self, z: np.ndarray, like: FourierDesign) -> FourierDesign:
        a, b = np.zeros_like(like.a), np.zeros_like(like.b)
        k = len(self.act) * like.harmonics
        a[self.act], b[self.act] = z[:k].reshape(len(self.act), -1), z[k:].reshape(len(self.act), -1)
        return FourierDesign(like.base_freq_hz, a, b, like.q0)

    def _filled(self, designs: list[FourierDesign]) -> list[FourierDesign]:
        """Each design scaled so that its most used bound is just met (one batched rollout; the response is
        close to linear in the amplitude, and what is not is caught by the scoring rollout)."""
        viol = self.score(designs, limit_stride=self._LIMIT_STRIDE, bound=0.0)[2]
        return [
            self._to_torque_bound(d.scaled(0.97 * self.bound / max(v, 1e-12)))
            for d, v in zip(designs, viol, strict=True)
        ]

    def _starts(self, shapes: list[FourierDesign]) -> tuple[FourierDesign, float, list[float]]:
        """Each shape filled to the limits (or at the torque bound and five halvings), rolled out together."""
        fractions = 0.5 ** np.arange(1 if self.fill else 6)
        cands = [self._to_torque_bound(s, grow=True).scaled(float(f)) for s in shapes for f in fractions]
        if self.fill:
            cands = self._filled(cands)
        values, conds, viol, ratios = self.score(cands, limit_stride=self._LIMIT_STRIDE, bound=self.bound)
        ok = viol == 0
        if not ok.any():
            still = self.score([shapes[0].scaled(0.0)], limit_stride=self._LIMIT_STRIDE, bound=self.bound)[3][0]
            # with no torque at all it leaves its range (or hits itself), past the bound itself: no speed bound is to
            # blame
            if max(still.get("q", 0.0), still.get("clearance", 0.0)) > 1.0:
                passive = [self.plant.joint_names[j] for j in np.flatnonzero(~np.asarray(self.plant.actuated))]
                left = "joint range" if still.get("q", 0.0) > 1.0 else "clearance"
                why, cure = (
                    (f"with a joint no actuator drives ({', '.join(passive)}) the arm", "give every joint an actuator")
                    if passive  # else every joint has one, and the arm was asked to be driven open loop
                    else (
                        "driven by torque (system.torque_driven=true), the arm",
                        "set system.torque_driven=false",
                    )
                )
                raise InfeasibleExcitationError(
                    f"{why} is excited by open-loop torque, not tracked, and no drive torque kept the motion within "
                    f"the limits; with none at all it leaves its {left} from its start pose: it does not hold itself "
                    f"up; {cure} so that the arm is tracked, or give a start pose in which it hangs at rest"
                )
            worst = ratios[int(np.argmin(viol))]
            scaled = "scaled to the limits" if self.fill else f"down to {fractions[-1]:.3g} x the torque bound"
            uses = {k: round(v, 3) for k, v in worst.items()}
            raise self.limits.infeasible(
                f"no drive torque {scaled} keeps the simulated motion within the limits",
                worst,
                f" (worst use of each bound: {uses})",
            )
        best = int(np.argmin(np.where(ok, values, np.inf)))
        per_start = np.where(ok, conds, np.inf).reshape(len(shapes), len(fractions)).min(axis=1)
        return cands[best], float(values[best]), per_start.tolist()

    def run(
        self,
        shapes: list[FourierDesign],
        rng: np.random.Generator,
        *,
        generations: int,
        population: int,
        progress: Callable[[float, str], None] | None = None,
    ) -> tuple[FourierDesign, list[float], list[float]]:
        """Search from the best start; returns the best design, each start's cond and the final cond."""
        best, best_value, start_conds = self._starts(shapes)
        mean, sigma = self._vector(best), 0.3
        elite = max(1, population // 4)
        for generation in range(generations):
            if progress is not None:
                progress(generation / generations, f"generation {generation + 1}/{generations}, best {best_value:.4g}")
            scale = sigma * np.sqrt(np.mean(mean**2))
            cands = [
                self._to_torque_bound(self._design(mean + scale * rng.normal(size=mean.shape), best))
                for _ in range(population)
            ]
            if self.fill:
                cands = self._filled(cands)
            values, _, viol, _ = self.score(cands, limit_stride=self._LIMIT_STRIDE, bound=self.bound)
            order = np.lexsort((values, viol))
            if viol[order[0]] == 0 and values[order[0]] < best_value:
                best, best_value, sigma = cands[order[0]], float(values[order[0]]), sigma * 1.3
            else:
                sigma *= 0.7
            mean = np.mean([self._vector(cands[i]) for i in order[:elite]], axis=0)
        best = self._verified(best)
        if progress is not None:
            progress(1.0, f"{generations} generations, best {best_value:.4g}")
        _, conds, _, ratios = self.score([best], limit_stride=1, bound=1.0)
        if not np.isfinite(best_value):  # the criterion the search minimised (raw cond(X'X) depends on units)
            # every design the limits allow moves the arm too little to excite the base parameters; a run on such
            # data fitted noise and exited 0 (a hanging chain with a passive middle joint: XX2 = 2e10 +- 4e10, a
            # validation torque RMS of 4e5 N m against 0.1 N m of noise)
            raise self.limits.infeasible(
                "no open-loop drive torque within the limits moves the arm enough to excite every base parameter "
                "(cond(X'X) is infinite for every design tried: scaled down to meet the limits, the torque leaves "
                "the arm nearly still)",
                ratios[0],
                "; drive every joint by an actuator so that it is tracked (not driven open loop), or widen the bound",
            )
        return best, start_conds, [float(conds[0])]

    def _verified(self, design: FourierDesign) -> FourierDesign:
        """The design, shrunk where needed until every bound holds on every physics step."""
        if self.score([design], limit_stride=1, bound=1.0)[2][0] == 0:
            return design
        fractions = 0.98 ** np.arange(1, 17)
        cands = [design.scaled(float(f)) for f in fractions]
        _, _, viol, ratios = self.score(cands, limit_stride=1, bound=1.0)
        ok = np.flatnonzero(viol == 0)
        if ok.size == 0:
            raise self.limits.infeasible(
                f"the optimised drive torque breaks a limit on the dense grid even at {fractions[-1]:.2f} x its "
                "amplitude",
                ratios[-1],
            )
        return cands[int(ok[0])]

    def check(self, design: FourierDesign) -> tuple[dict[str, float], np.ndarray]:
        """Ratios on every physics step and the stacked base regressor of the design's rollout."""
        q, dq, ddq, tau = self._rollout([design])
        cs = self._stride(design)
        ratios = self.limits.ratios(q[0], dq[0], ddq[0], tau[0])
        return ratios, self.base.columns(self.model.regressor(q[0, ::cs], dq[0, ::cs], ddq[0, ::cs]))

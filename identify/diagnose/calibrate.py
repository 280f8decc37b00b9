"""The extended model: the nominal MJCF plus the effects found, written in MuJoCo's own attributes.

Mapping (what each finding becomes in `<system>_calibrated.xml`):
    armature, viscous_friction     joint `armature`, `damping` (added to the nominal values)
    coulomb_friction               joint `frictionloss` = the fitted Coulomb torque Fc (1:1), with
                                   `solreffriction` / `solimpfriction` that make MuJoCo's friction the ramp
                                   Fc sat((dq + lead ddq) / vt) closest to Fc sign(dq) that the model's step
                                   simulates stably (`dynamics.friction.ideal_friction_speed`); MuJoCo's
                                   default parameters would turn it over at dq = -ddq / 105, well before a
                                   reversal, over a ramp of metres per second on a light joint. Its variant
                                   `mujoco` (`candidates.SOFT_FRICTION`) is that default shape, fitted as
                                   such: the frictionloss alone, the joint's solver parameters left as they are
    smooth_coulomb_friction        the same with the fitted ramp width vt (and the lead stability asks for);
    friction_ramp                  the fitted Fc in place of the nominal frictionloss, in the narrower shape
                                   found (ideal as above, or the ramp of width vt), whatever the joint's own
                                   solver parameters were
                                   `frictionloss_mapping` measures how closely MuJoCo's inverse dynamics follows
                                   the declared shape along the validation motion
    joint_stiffness                joint `stiffness`, `springref`
    payload, rigid_body            the bodies' `inertial` (mass, pos, fullinertia) from the corrected standard
                                   parameters
    joint_offset                   joint `ref` (the joint value of the model's pose): MuJoCo's qpos is then
                                   the measured angle
    torque_offset, torque_gain     the sensor: a `numeric` sysid_torque_sensor_<joint> [gain, offset] (the
                                   reported torque is gain x the applied one + offset), read back by
                                   `mjcf_measured_torque`; and a motor (ctrl a torque, not a set point) becomes
                                   `general` with gainprm = 1/gain and biasprm = -offset/gain (both over its
                                   gear and nominal gain): driven by the measured torque as ctrl, it applies
                                   the true one. A servo's ctrl is a set point: its simulation needs neither
    rotor_coupling                 the off-diagonal inertia rho = Ir gr between joint j and its ancestors (rotor
                                   on the parent link) has no joint attribute; it is written exactly as rho
                                   about the axis added to the child body's inertia, rho taken from the parent
                                   body's and from joint j's armature (the mass matrix then gains rho on
                                   M[ancestor, j] only), and recorded as a `numeric` sysid_rotor_coupling_<joint>
    time_delay                     no MuJoCo counterpart (the measured torque lags the applied one, so the
                                   applied torque lies ahead of the log): a `numeric` sysid_time_delay_<joint>

Effects of quasi-direct-drive actuators that MuJoCo has no attribute for are written as documented `numeric`
custom elements, named sysid_<effect>_<joint>, with their parameters (SI units), read back by
`mjcf_measured_torque` (and by anyone who adds them as a `qfrc_applied` in a simulation loop):
    cogging                        [n, a, b]: tau += a sin(n q) + b cos(n q) (n cycles per revolution of q)
    stribeck_friction              [Fs, vs]: tau += Fs sign(dq) exp(-(dq / vs)^2)
    load_friction                  [mu]: tau += mu |tau_j| sign(dq_j), tau_j the joint's torque without it
    backlash                       [b]: the link angle is q - (b / 2) sign(dq) (lost motion b, in contact)
    joint_elasticity               [k]: the link angle is q - tau_j / k (motor-side encoder, compliant gear)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import mujoco
import numpy as np

from dynamics.friction import (
    applied_friction_parameters,
    friction_enabled,
    friction_shape,
    friction_solver,
    ideal_friction_speed,
    kept_ramp,
)
from dynamics.inertia import (
    from_pseudo_inertia,
    is_consistent,
    pseudo_inertia,
    repair_body,
    transform_parameters,
)
from dynamics.mjcf import write_inertial
from dynamics.plant import Plant, load_spec, movable_xml, own_body_parameters
from dynamics.regressor import rigid_body_regressor
from dynamics.sampling import random_states
from dynamics.torque import inverse_dynamics, joint_torque
from identify.diagnose.candidates import IDEAL, SOFT_FRICTION, rotor_chain
from identify.diagnose.select import Step
from identify.diagnose.statistics import LinearFit

__all__ = [
    "CUSTOM_EFFECTS",
    "Extension",
    "applied_from_measured",
    "calibrated_xml",
    "consistent_parameters",
    "custom_torque",
    "extension_from_fit",
    "frictionloss_mapping",
    "mjcf_measured_torque",
    "predict_measured_torque",
    "torque_sensor",
]


def _zeros(n: int) -> np.ndarray:
    return np.zeros(n)


@dataclass(frozen=True)
class Extension:
    """Corrections to the nominal model, each (nv,) unless stated.

    Attributes:
        armature, damping, frictionloss, stiffness: added to the MJCF's joint values [SI].
        springref: new spring rest angles [rad] (the nominal ones where no stiffness was found).
        theta_delta: (10 nv,) change of the standard inertial parameters.
        joint_offset: reported minus true angle [rad].
        torque_offset: reported torque at zero applied torque [N m].
        torque_gain: reported over applied torque [1].
        delay_s: the reported torque lags the applied one by this much [s].
        rotor_coupling: off-diagonal rotor inertia between joint j and its ancestors [kg m^2] (already
            folded into theta_delta and armature; kept to be reported).
        custom: effects with no MuJoCo attribute, as (effect, joint index, parameters) (see the module
            docstring for each effect's parameters).
        friction_speed: (nv,) ramp width of each joint's friction where a smooth Coulomb shape was fitted
            [rad/s]; 0: ideal Coulomb. `calibrated_xml` replaces it by the width it writes.
        soft_friction: (nv,) True where the fitted Coulomb friction is MuJoCo's own frictionloss at the joint's
            solver parameters (`candidates.SOFT_FRICTION`): written without solreffriction / solimpfriction.
        narrowed: (nv,) True where the nominal frictionloss was found to act in a narrower shape than the ramp
            its solver parameters make (`friction_ramp`): written in that shape (`friction_speed`; 0: ideal),
            not in the joint's own ramp, even where its level is unchanged.
    """

    armature: np.ndarray
    damping: np.ndarray
    frictionloss: np.ndarray
    stiffness: np.ndarray
    springref: np.ndarray
    theta_delta: np.ndarray
    joint_offset: np.ndarray
    torque_offset: np.ndarray
    torque_gain: np.ndarray
    delay_s: np.ndarray
    rotor_coupling: np.ndarray = field(default_factory=lambda: np.zeros(0))
    notes: list[str] = field(default_factory=list)
    custom: list[tuple[str, int, tuple[float, ...]]] = field(default_factory=list)
    friction_speed: np.ndarray = field(default_factory=lambda: np.zeros(0))
    soft_friction: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    narrowed: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    def __post_init__(self) -> None:
        if self.friction_speed.size == 0:  # no shape given: every joint's friction ideal
            object.__setattr__(self, "friction_speed", np.zeros(len(self.armature)))
        if self.soft_friction.size == 0:
            object.__setattr__(self, "soft_friction", np.zeros(len(self.armature), bool))
        if self.narrowed.size == 0:
            object.__setattr__(self, "narrowed", np.zeros(len(self.armature), bool))

    @classmethod
    def none(cls, plant: Plant) -> Extension:
        n = plant.nv
        return cls(
            armature=_zeros(n),
            damping=_zeros(n),
            frictionloss=_zeros(n),
            stiffness=_zeros(n),
            springref=plant.springref.copy(),
            theta_delta=_zeros(10 * n),
            joint_offset=_zeros(n),
            torque_offset=_zeros(n),
            torque_gain=np.ones(n),
            delay_s=_zeros(n),
            rotor_coupling=_zeros(n),
            friction_speed=_zeros(n),
        )


def extension_from_fit(
    plant: Plant,
    steps: list[Step],
    fit: LinearFit,
    base_independent: np.ndarray,
    *,
    record_offsets: np.ndarray | None = None,
    nuisance: int | None = None,
) -> Extension:
    """Turn the chosen candidates' coefficients into model corrections.

    Args:
        fit: coefficients of the nuisance columns, then of the steps' columns.
        record_offsets: (n_records, nv) per-record torque offsets fitted as nuisance; their mean becomes the
            model's torque offset.
        nuisance: how many nuisance coefficients come first (None: those of `record_offsets`, one per record and
            actuated joint). Other nuisances (an angle offset per record) leave the model as it is.
    """
    ext = Extension.none(plant)
    offset = 0
    if record_offsets is not None and record_offsets.size:
        ext.torque_offset[:] = np.nanmean(record_offsets, axis=0)  # NaN: a record whose torque was not fitted
        offset = int(np.count_nonzero(plant.actuated)) * len(record_offsets)
    if nuisance is not None:
        if nuisance < offset:
            raise ValueError(f"nuisance={nuisance} is fewer than the {offset} record offsets' coefficients")
        offset = nuisance
    names = list(plant.joint_names)
    for s in steps:
        c = s.candidate
        coef = fit.coef[offset : offset + len(s.kept)]
        offset += len(s.kept)
        full = np.zeros(len(c.parameter_names))
        full[s.kept] = coef
        if c.effect == "payload":
            b = plant.body_names.index(c.target)
            symbols = ("m", "MX", "MY", "MZ", "XX", "XY", "YY", "XZ", "YZ", "ZZ")
            for name, value in zip(c.parameter_names, full, strict=True):
                ext.theta_delta[10 * b + symbols.index(name[1 : -len(str(b + 1))])] += value
            continue
        if c.effect == "rigid_body":
            ext.theta_delta[base_independent] += full
            continue
        j = names.index(c.target)
        custom = _custom_parameters(c.effect, c.variant, full)
        if custom is not None:
            if custom:
                ext.custom.append((c.effect, j, custom))
            continue
        if c.effect == "rotor_coupling":
            _add_rotor_coupling(plant, ext, j, float(full[0]))
            continue
        if c.effect == "smooth_coulomb_friction":
            ext.frictionloss[j] += full[0]
            ext.friction_speed[j] = float(c.variant)
            continue
        if c.effect == "friction_ramp":  # the joint's friction in a narrower shape, at the level fitted
            if not c.holds(float(full[0])):
                continue  # no friction at all: the final fit drops such a step, and no column made at it holds it
            ext.frictionloss[j] += full[0] - plant.frictionloss[j]
            ext.friction_speed[j] = 0.0 if c.variant == IDEAL else float(c.variant)
            ext.narrowed[j] = True
            continue
        if c.effect == "coulomb_friction" and c.variant == SOFT_FRICTION:
            ext.frictionloss[j] += full[0]
            ext.soft_friction[j] = True
            continue
        if c.effect == "joint_stiffness":
            k_total = plant.stiffness[j] + full[0]
            ext.stiffness[j] += full[0]
            if k_total != 0:
                ext.springref[j] = plant.springref[j] - full[1] / k_total
            continue
        target = {
            "armature": ext.armature,
            "viscous_friction": ext.damping,
            "coulomb_friction": ext.frictionloss,
            "joint_offset": ext.joint_offset,
            "torque_offset": ext.torque_offset,
            "time_delay": ext.delay_s,
        }.get(c.effect)
        if c.effect == "torque_gain":
            ext.torque_gain[j] = 1.0 + full[0]
        elif target is not None:
            target[j] += full[0]
    return ext


CUSTOM_EFFECTS = (
    "backlash",
    "cogging",
    "joint_elasticity",
    "load_friction",
    "stribeck_friction",
)
# custom numerics of earlier versions that a MuJoCo attribute now holds: a file that has one is refused
RETIRED_EFFECTS = {"smooth_coulomb_friction": "a frictionloss ramp (re-run the diagnosis to rewrite the file)"}


def _custom_parameters(effect: str, variant: str, coef: np.ndarray) -> tuple[float, ...] | None:
    """The numeric's parameters of a custom effect from its fitted coefficients; None for other effects,
    () when the fit leaves nothing to write (a rigid transmission)."""
    if effect not in CUSTOM_EFFECTS:
        return None
    if effect == "cogging":
        return (float(variant), float(coef[0]), float(coef[1]))
    if effect == "stribeck_friction":
        return (float(coef[0]), float(variant))
    if effect == "backlash":
        return (2.0 * float(coef[0]),)
    if effect == "joint_elasticity":
        return (1.0 / float(coef[0]),) if coef[0] > 0 else ()
    return (float(coef[0]),)


def custom_torque(
    custom: list[tuple[str, int, tuple[float, ...]]],
    evaluate: Callable[[np.ndarray], np.ndarray],
    q: np.ndarray,
    dq: np.ndarray,
) -> np.ndarray:
    """(N, nv) the applied joint torque with the custom effects (see the module docstring) [N m].

    Args:
        custom: (effect, joint, parameters) entries.
        evaluate: link angles (N, nv) -> the model's joint torque (N, nv) at them (velocities and
            accelerations fixed by the caller).
        q, dq: (N, nv) reported joint angles and velocities [rad, rad/s].
    """
    base = evaluate(q)
    q_link = q.copy()
    for effect, j, p in custom:
        if effect == "backlash":
            q_link[:, j] -= 0.5 * p[0] * np.sign(dq[:, j])
        elif effect == "joint_elasticity":
            q_link[:, j] -= base[:, j] / p[0]
    tau = evaluate(q_link) if np.any(q_link != q) else base.copy()
    for effect, j, p in custom:
        if effect == "cogging":
            tau[:, j] += p[1] * np.sin(p[0] * q[:, j]) + p[2] * np.cos(p[0] * q[:, j])
        elif effect == "stribeck_friction":
            tau[:, j] += p[0] * np.sign(dq[:, j]) * np.exp(-((dq[:, j] / p[1]) ** 2))
        elif effect == "load_friction":
            tau[:, j] += p[0] * np.abs(base[:, j]) * np.sign(dq[:, j])
    return tau


def _add_rotor_coupling(plant: Plant, ext: Extension, j: int, rho: float) -> None:
    """M[i, j] += rho for joint j's ancestors i, in inertials and armature (see the module docstring)."""
    chain = rotor_chain(plant, j)
    assert chain is not None, "rotor_coupling is only a candidate where rotor_chain holds"
    m, parent = plant.mj_model, chain[1]
    for body, joint, sign in ((j, j, 1.0), (parent, parent, -1.0)):
        a = np.asarray(m.jnt_axis[joint], dtype=float)
        outer = sign * rho * np.outer(a, a)
        # INERTIAL_SYMBOLS order: XX, XY, YY, XZ, YZ, ZZ after m, MX, MY, MZ
        ext.theta_delta[10 * body + 4 : 10 * body + 10] += [
            outer[0, 0],
            outer[0, 1],
            outer[1, 1],
            outer[0, 2],
            outer[1, 2],
            outer[2, 2],
        ]
    ext.armature[j] -= rho
    ext.rotor_coupling[j] += rho


def consistent_parameters(
    plant: Plant, theta: np.ndarray, metric: np.ndarray, notes: list[str], *, nominal: np.ndarray | None = None
) -> np.ndarray:
    """Physically consistent standard parameters that predict the training torques like `theta` does.

    A fit of base parameters can leave a body with no physical realisation (negative mass, an inertia
    about the centre of mass that is not positive definite), which an MJCF cannot hold. The parameters are
    then chosen to minimise

        || metric (theta' - theta) ||^2 + mu^2 || theta' - nominal ||^2,    J_b(theta') >= eps_b 1 for every body,

    the change of the predicted training torques plus a weak pull (mu = 1e-4 ||metric||) towards the nominal
    values that settles the directions the data do not see, with every body's pseudo-inertia J_b positive
    definite (Wensing, Kim and Slotine 2017) by a margin eps_b = a + b tr(Sigma_b) (the body's second moments)
    (`CONSISTENT_MARGIN`: twice the margin `is_consistent` asks, so that no repair follows). The problem is
    convex (a quadratic over linear matrix inequalities) and is solved to its optimum by a log-det barrier
    method (`_barrier_solve`). A log-Cholesky parametrisation, as before, never converged on these problems:
    the optimum lies on the boundary of the consistent set, where its coordinates run off to infinity (2000
    evaluations of scipy's least_squares on a 7-DoF arm, seconds each, and still moving). A consistent
    `theta` is returned unchanged.

    Args:
        plant: the nominal model.
        theta: (10 nv,) corrected standard parameters.
        nominal: (10 nv,) the anchor of the weak pull (default: `plant.theta`).
        metric: (k, 10 nv) with ||metric d|| the (weighted) training torque change of a parameter change d
            (the R factor of the stacked rigid-body regressor).
        notes: receives what was changed.
    """
    bodies = np.flatnonzero(plant.carries_body)

    def consistent(x: np.ndarray) -> bool:
        return all(is_consistent(x[10 * b : 10 * b + 10]) for b in bodies)

    if consistent(theta):
        return theta
    anchor = plant.theta if nominal is None else nominal
    fixed, converged = _barrier_solve(theta, metric, anchor, bodies, (theta, anchor))
    if not consistent(fixed):  # a body grown past the margin's scale
        fixed, converged = _barrier_solve(theta, metric, anchor, bodies, (theta, anchor, fixed))
    change = float(np.linalg.norm(metric @ (fixed - theta)) / max(float(np.linalg.norm(metric @ theta)), 1e-300))
    notes.append(
        "the fitted inertials had no physical realisation; the nearest consistent ones are written "
        f"(relative change of the predicted training torques {change:.2%})"
        + ("" if converged else "; the projection stopped before its tolerance (60 x 100 Newton steps)")
    )
    return fixed


CONSISTENT_MARGIN = (1e-7, 1e-5)  # pseudo-inertia kept >= (a + b tr Sigma_b) 1, Sigma_b its second moments
_GAP = 1e-10  # the barrier method stops within this share of the objective of the optimum
_PSEUDO = np.stack([pseudo_inertia(e).ravel() for e in np.eye(10)], axis=1)  # (16, 10): theta_b -> vec J_b


def _moment_scale(scales: tuple[np.ndarray, ...], k: int) -> float:
    """[kg m^2] the largest trace of body k's second moments (J's upper 3 x 3) among the parameter vectors."""
    return max(float(np.trace(pseudo_inertia(v[10 * k : 10 * k + 10])[:3, :3])) for v in scales)


def _newton_step(H: np.ndarray, g: np.ndarray) -> np.ndarray:
    """H^-1 g for a positive definite H whose scales span many decades near the boundary (the barrier's
    curvature grows as 1 / distance^2): Jacobi-scaled Cholesky; least squares where even that fails; the scaled
    gradient where LAPACK's SVD does not converge either (as gesdd did on a UR5e refit's 1e-22 .. 8e5 entries),
    which the line search still turns into a decrease."""
    d = 1.0 / np.sqrt(np.maximum(np.abs(np.diag(H)), 1e-300))
    scaled = H * d[:, None] * d[None, :]
    try:
        chol = np.linalg.cholesky(scaled)
        return d * np.linalg.solve(chol.T, np.linalg.solve(chol, d * g))  # type: ignore[no-any-return]
    except np.linalg.LinAlgError:
        pass
    try:
        step = d * np.linalg.lstsq(scaled, d * g, rcond=None)[0]
    except np.linalg.LinAlgError:
        return d * d * g  # type: ignore[no-any-return]
    return step if np.all(np.isfinite(step)) and float(g @ step) > 0 else d * d * g  # type: ignore[no-any-return]


def _barrier_solve(
    theta: np.ndarray, metric: np.ndarray, anchor: np.ndarray, bodies: np.ndarray, scales: tuple[np.ndarray, ...]
) -> tuple[np.ndarray, bool]:
    """The minimiser of `consistent_parameters`'s problem over the blocks of `bodies` (10 nv,), and whether it
    converged: Newton steps on the objective minus t sum_b log det(J_b - eps_b 1), t shrinking tenfold until the
    duality gap 4 t (bodies) is below `_GAP` of the objective (Boyd and Vandenberghe, ch. 11). Every other block
    (a joint that carries no body, whose values no MJCF holds) keeps `theta`'s values. Each margin eps_b scales
    with the body's second moments in `scales` (parameter vectors: the fit, the anchor, a previous solution)."""
    n = len(theta)
    a, b = CONSISTENT_MARGIN
    # the margin in the body's second moments Sigma = J's upper 3 x 3 (their trace bounds any two principal
    # moments about the centre of mass, whose sums is_consistent compares with a margin of 1e-7 + 1e-5 of them)
    eps = {int(k): a + b * _moment_scale(scales, int(k)) for k in bodies}
    free = np.concatenate([np.arange(10 * k, 10 * k + 10) for k in eps]) if eps else np.zeros(0, int)
    mu = 1e-4 * float(np.linalg.norm(metric, 2))
    x = theta.copy()
    x[free] = anchor[free]
    for k, e in eps.items():  # a start strictly inside: the nominal body, lifted where it is not
        cut = slice(10 * k, 10 * k + 10)
        w, V = np.linalg.eigh(pseudo_inertia(x[cut]))
        if w[0] <= 2 * e:
            x[cut] = from_pseudo_inertia((V * np.maximum(w, 2 * e)) @ V.T)
    A = metric[:, free]
    Q = A.T @ A + mu**2 * np.eye(len(free))
    q = A.T @ (A @ theta[free]) + mu**2 * anchor[free]  # the held blocks are theta's: they add nothing

    def objective(y: np.ndarray) -> float:  # as sums of squares: the expanded quadratic cancels to round-off
        return float(np.sum((metric @ (y - theta)) ** 2) + mu**2 * np.sum((y[free] - anchor[free]) ** 2))

    def factors(y: np.ndarray) -> list[np.ndarray] | None:  # Cholesky of each J_b - eps_b 1; None outside
        out = []
        for k, e in eps.items():
            try:
                out.append(np.linalg.cholesky(pseudo_inertia(y[10 * k : 10 * k + 10]) - e * np.eye(4)))
            except np.linalg.LinAlgError:
                return None
        return out

    def barrier(chol: list[np.ndarray]) -> float:  # -sum log det(J_b - eps_b 1) from its factors
        return -2.0 * sum(float(np.sum(np.log(np.diag(c)))) for c in chol)

    m = 4 * len(eps)
    t = max(objective(x), 1e-300) / max(m, 1)
    floor = 1e-14 * max(objective(x), 1e-300)  # the objective's scale where the optimum's is zero
    converged = False
    chol, fx = factors(x), objective(x)  # of the current point: each accepted step's, from its line search
    assert chol is not None  # the start is strictly inside, and every accepted step stays inside
    for _ in range(60):  # outer steps, t tenfold smaller each
        for _ in range(100):  # Newton steps at this t
            g, H = 2.0 * (Q @ x[free] - q), 2.0 * Q
            for i, c in enumerate(chol):
                inv = np.linalg.solve(c.T, np.linalg.solve(c, np.eye(4)))
                cut = slice(10 * i, 10 * i + 10)
                g[cut] -= t * _PSEUDO.T @ inv.ravel()
                H[cut, cut] += t * _PSEUDO.T @ np.kron(inv, inv) @ _PSEUDO
            dx = np.zeros(n)
            dx[free] = -_newton_step(H, g)
            decrement = float(-g @ dx[free])
            if decrement <= 2 * _GAP * max(fx, floor):
                break
            here, step = fx + t * barrier(chol), 1.0
            while step > 1e-6:  # backtracking: stay inside and decrease enough
                y = x + step * dx
                inside = factors(y)
                if inside is not None:
                    fy = objective(y)
                    if fy + t * barrier(inside) <= here - 0.25 * step * decrement:
                        break
                step *= 0.5
            if step <= 1e-6:  # no decrease left to resolve in floating point: centred as well as it can be
                break
            assert inside is not None
            x, chol, fx = y, inside, fy
        if m * t <= _GAP * max(fx, floor):
            converged = True
            break
        t *= 0.1
    return x, converged


def _generic_regressor(plant: Plant, n: int = 200) -> np.ndarray:
    """(n nv, 10 nv) the rigid-body regressor stacked over random states (the same states on every call)."""
    return rigid_body_regressor(plant, *random_states(plant, np.random.default_rng(0), n)).reshape(n * plant.nv, -1)


def _generic_metric(W: np.ndarray, n: int) -> np.ndarray:
    """(10 nv, 10 nv) R of the stacked regressor W of n states: ||R d|| is the torque change of a change d."""
    return np.linalg.qr(W, mode="r") / np.sqrt(n)  # type: ignore[no-any-return]


def _unobservable(W: np.ndarray) -> np.ndarray:
    """(10 nv,) True for standard parameters that never change a joint torque (zero column of W)."""
    norms = np.linalg.norm(W, axis=0)
    return norms <= 1e-9 * max(float(norms.max()), 1e-300)


def _angle_unit(spec: mujoco.MjSpec, plant: Plant, j: int) -> float:
    """Radians per unit of joint j's angles in the MJCF text (degrees where the compiler says so)."""
    return float(np.pi / 180.0) if plant.hinge[j] and spec.compiler.degree else 1.0


def calibrated_xml(plant: Plant, ext: Extension, *, metric: np.ndarray | None = None, comment: str = "") -> str:
    """The nominal MJCF with the corrections, as MJCF text (see the module docstring for the mapping).

    Args:
        plant: the nominal model.
        ext: the corrections.
        metric: (k, 10 nv) training-torque metric used to make corrected inertials physically consistent
            with the least change of the predicted torques (see `consistent_parameters`); None uses the torques
            at random states (the least change of the model's predictions anywhere).
        comment: a line for the file's header comment.
    """
    spec = load_spec(plant.path)
    spec.compiler.balanceinertia = True  # a safety net for the six digits the MJCF text keeps
    for j, name in enumerate(plant.joint_names):
        joint = spec.joint(name)
        armature = plant.armature[j] + ext.armature[j]
        if armature < 0:
            ext.notes.append(f"{name}: armature {armature:.4g} kg m^2 < 0 after the corrections; set to 0")
        joint.armature = float(max(armature, 0.0))
        m0 = plant.mj_model  # the file's own values (the plant's are 0 where an <option><flag> disables them)
        damping = np.array(joint.damping, dtype=float)
        damping[0] = float(m0.dof_damping[j]) + ext.damping[j]
        joint.damping = damping
        friction = float(m0.dof_frictionloss[j]) + ext.frictionloss[j]
        if friction < 0:
            ext.notes.append(f"{name}: fitted Coulomb friction {friction:.4g} N m < 0; frictionloss set to 0")
        joint.frictionloss = float(max(friction, 0.0))
        stiffness = np.array(joint.stiffness, dtype=float)
        stiffness[0] = float(m0.jnt_stiffness[j]) + ext.stiffness[j]
        joint.stiffness = stiffness
        unit = _angle_unit(spec, plant, j)
        joint.springref = float(ext.springref[j]) / unit
        joint.ref = float(joint.ref + ext.joint_offset[j] / unit)
    own = own_body_parameters(plant)
    corrected = own + ext.theta_delta
    if np.any(ext.theta_delta):
        n = 200
        W = _generic_regressor(plant, n)
        if metric is None:
            metric = _generic_metric(W, n)
        corrected = consistent_parameters(plant, corrected, metric, ext.notes, nominal=own)
        free = _unobservable(W)
        corrected = np.concatenate(
            [
                repair_body(
                    corrected[10 * b : 10 * b + 10], own[10 * b : 10 * b + 10], free[10 * b : 10 * b + 10], ext.notes, n
                )
                if plant.carries_body[b]
                else corrected[10 * b : 10 * b + 10]
                for b, n in enumerate(plant.body_names)
            ]
        )
    for j in range(plant.nv):
        delta = corrected[10 * j : 10 * j + 10] - own[10 * j : 10 * j + 10]
        if not np.any(delta):
            continue
        if plant.carries_body[j]:
            body = transform_parameters(corrected[10 * j : 10 * j + 10], np.linalg.inv(plant.joint_from_body[j]))
            write_inertial(spec, plant.body_names[j], body)
        else:
            ext.notes.append(
                f"{plant.joint_names[j]}: an inertial change on a joint that carries no body of its own cannot be "
                "written to the MJCF; left out"
            )
    m = plant.mj_model
    for a in range(m.nu):
        j = int(m.jnt_dofadr[m.actuator_trnid[a, 0]])
        gain, off = float(ext.torque_gain[j]), float(ext.torque_offset[j])
        if gain == 1.0 and off == 0.0:
            continue
        numeric = spec.add_numeric()  # what the sensor reports of the applied torque, for any actuator
        numeric.name = f"sysid_torque_sensor_{plant.joint_names[j]}"
        numeric.data = [gain, off]
        if plant.actuation.actuators[a].state_dependent:
            continue  # a servo's ctrl is a set point: the sensor's gain and offset do not enter its simulation
        act = spec.actuators[a]
        own_bias = float(m.actuator_biasprm[a, 0]) if m.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_AFFINE else 0.0
        act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        act.gainprm[0] = float(m.actuator_gainprm[a, 0]) / gain
        act.biastype = mujoco.mjtBias.mjBIAS_AFFINE  # the actuator's own constant force kept, the offset's added
        act.biasprm[0] = (own_bias - off / float(m.actuator_gear[a, 0])) / gain
    for j, name in enumerate(plant.joint_names):
        if ext.rotor_coupling.size and ext.rotor_coupling[j] != 0:
            numeric = spec.add_numeric()
            numeric.name = f"sysid_rotor_coupling_{name}"
            numeric.data = [float(ext.rotor_coupling[j])]
        if ext.delay_s[j] != 0:
            numeric = spec.add_numeric()
            numeric.name = f"sysid_time_delay_{name}"
            numeric.data = [float(ext.delay_s[j])]
    for effect, j, params in ext.custom:
        numeric = spec.add_numeric()
        numeric.name = f"sysid_{effect}_{plant.joint_names[j]}"
        numeric.data = [float(v) for v in params]
    _write_friction_shapes(spec, plant, ext)
    spec.compile()
    header = "<!-- Calibrated by sysid-diagnose (see identify/diagnose/calibrate.py for the mapping)."
    text = header + ("\n     " + comment.replace("--", "-") if comment else "") + " -->\n"
    return text + movable_xml(spec, plant.path)


def _write_friction_shapes(spec: mujoco.MjSpec, plant: Plant, ext: Extension) -> None:
    """Every joint whose friction the fit changed gets the solver parameters that make MuJoCo apply the fitted
    shape (`dynamics.friction`); `ext.friction_speed` records the ramp width written. A joint whose friction
    the fit left as it was, read as the ramp MuJoCo applies (`dynamics.plant.with_applied_friction`), keeps that
    ramp where a fitted inertia moves its `dof_invweight0` (with MuJoCo's default solver parameters the ramp's
    width goes with it)."""
    changed = [j for j in range(plant.nv) if ext.frictionloss[j] != 0 or ext.friction_speed[j] > 0 or ext.narrowed[j]]
    kept = [j for j in range(plant.nv) if j not in changed and plant.friction_speed[j] > 0]
    if not changed and not kept:
        return
    m = spec.compile()  # the inverse inertias of the calibrated model (its inertials and joint refs)
    # MuJoCo's ramp goes with dof_invweight0: where a fitted inertia moved it, the ramp is written as such
    moved = ~np.isclose(m.dof_invweight0, plant.mj_model.dof_invweight0, rtol=1e-9, atol=0.0)
    for j in kept:
        if not moved[j]:
            continue
        invweight = float(m.dof_invweight0[j])
        joint = spec.joint(plant.joint_names[j])
        joint.solref_friction, joint.solimp_friction, _ = kept_ramp(
            float(m.dof_frictionloss[j]), plant.friction_speed[j], plant.friction_lead[j], invweight, m.opt.timestep
        )
    if not changed:
        return
    if not friction_enabled(m):
        ext.notes.append(
            "the model's <option><flag> disables frictionloss (or every constraint): the fitted friction is written "
            "but MuJoCo does not apply it until the flag is enabled"
        )
    step = float(m.opt.timestep)
    # MuJoCo's own shape (`candidates.SOFT_FRICTION`): its width per unit Fc and lead at the nominal model
    soft_speed, soft_lead = applied_friction_parameters(plant.mj_model, np.ones(plant.nv))
    for j in changed:
        name = plant.joint_names[j]
        fc, invweight = float(m.dof_frictionloss[j]), float(m.dof_invweight0[j])
        if fc <= 0:
            ext.friction_speed[j] = 0.0
            continue
        joint = spec.joint(name)
        if ext.soft_friction[j]:  # MuJoCo's own shape at the joint's solver parameters, as fitted
            ext.friction_speed[j] = float(soft_speed[j]) * fc
            if moved[j]:
                joint.solref_friction, joint.solimp_friction, ext.friction_speed[j] = kept_ramp(
                    fc, ext.friction_speed[j], float(soft_lead[j]), invweight, step
                )
            continue
        if ext.friction_speed[j] <= 0 and plant.friction_speed[j] > 0 and not ext.narrowed[j]:  # its own ramp
            solref, solimp, ext.friction_speed[j] = kept_ramp(
                fc, plant.friction_speed[j], plant.friction_lead[j], invweight, step
            )
        else:  # the fitted ramp, or the ideal shape
            if ext.friction_speed[j] <= 0:
                ext.friction_speed[j] = ideal_friction_speed(fc, invweight, step)
            solref, solimp, ext.friction_speed[j] = friction_solver(fc, float(ext.friction_speed[j]), invweight, step)
        joint.solref_friction, joint.solimp_friction = solref, solimp


def predict_measured_torque(
    calibrated: Plant, ext: Extension, time: np.ndarray, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray
) -> np.ndarray:
    """(N, nv) torque the calibrated model says the sensor reports [N m]: gain, offset and delay applied exactly.

    `calibrated` carries the joint offsets as `ref`, so q is the measured angle.
    """
    tau = custom_torque(ext.custom, lambda x: joint_torque(calibrated, x, dq, ddq)[0], q, dq)
    out = tau.copy()
    for j in range(calibrated.nv):
        if ext.delay_s[j] != 0:
            out[:, j] = np.interp(time - ext.delay_s[j], time, tau[:, j])
    out = out * ext.torque_gain + ext.torque_offset
    return np.where(calibrated.actuated, out, tau)


def _numeric(model: mujoco.MjModel, name: str) -> np.ndarray | None:
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, name)
    if i < 0:
        return None
    adr, size = int(model.numeric_adr[i]), int(model.numeric_size[i])
    return np.array(model.numeric_data[adr : adr + size])


def mjcf_measured_torque(
    model: mujoco.MjModel, time: np.ndarray, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray
) -> np.ndarray:
    """(N, nv) the torque a calibrated MJCF says the sensor reports, read from the file alone [N m].

    MuJoCo's inverse dynamics (`mj_inverse`: inertia, armature, damping, stiffness, frictionloss as MuJoCo
    applies it), plus the documented `sysid_*` custom numerics MuJoCo has no attribute for (see the module
    docstring), delayed by `sysid_time_delay_<joint>`, then as the sensor reports it (`torque_sensor`: gain x
    torque + offset). The joint torque the actuator applies, whatever its gear, gain and constant force
    (`tau_<joint>` of the measured-data format). This is how the benchmark judges a calibrated file without
    any of the diagnosis's own objects.

    Args:
        model: the compiled calibrated MJCF.
        time: (N,) sample times [s]; q, dq, ddq: (N, nv) joint states [rad, rad/s, rad/s^2].

    Raises:
        ValueError: the file holds a custom numeric of an earlier version (`RETIRED_EFFECTS`).
    """
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, k) for k in range(model.njnt)]
    for effect, now in RETIRED_EFFECTS.items():
        old = [n for n in names if _numeric(model, f"sysid_{effect}_{n}") is not None]
        if old:
            raise ValueError(f"numeric sysid_{effect}_{old[0]}: written by an earlier version; it is now {now}")
    custom = []
    for j, name in enumerate(names):
        for effect in CUSTOM_EFFECTS:
            params = _numeric(model, f"sysid_{effect}_{name}")
            if params is not None:
                custom.append((effect, j, tuple(float(v) for v in params)))
    applied = custom_torque(custom, lambda x: inverse_dynamics(model, x, dq, ddq), q, dq)
    out = applied.copy()
    for j, name in enumerate(names):
        delay = _numeric(model, f"sysid_time_delay_{name}")
        if delay is not None and delay[0] != 0:
            out[:, j] = np.interp(time - float(delay[0]), time, applied[:, j])
    gain, offset = torque_sensor(model)
    return out * gain + offset


def torque_sensor(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """(nv,) gain and (nv,) offset of each joint's torque sensor in a calibrated MJCF: reported = gain x applied
    + offset, from its `sysid_torque_sensor_<joint>` numerics (1 and 0 where it has none)."""
    gain, offset = np.ones(model.nv), np.zeros(model.nv)
    for j in range(model.njnt):
        sensor = _numeric(model, f"sysid_torque_sensor_{mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j)}")
        if sensor is not None:
            gain[int(model.jnt_dofadr[j])], offset[int(model.jnt_dofadr[j])] = sensor[0], sensor[1]
    return gain, offset


def applied_from_measured(ext: Extension, time: np.ndarray, tau_measured: np.ndarray) -> np.ndarray:
    """(N, nv) the measured torque advanced by the delay (the input of the calibrated MJCF's actuators)."""
    out = tau_measured.copy()
    for j in range(tau_measured.shape[1]):
        if ext.delay_s[j] != 0:
            out[:, j] = np.interp(time + ext.delay_s[j], time, tau_measured[:, j])
    return out


def frictionloss_mapping(
    calibrated: Plant, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray
) -> dict[str, dict[str, float]]:
    """How MuJoCo's constraint-based frictionloss compares with the shape the model declares for it.

    The friction force MuJoCo's inverse dynamics produces (with and without the joints' frictionloss, along the
    given motion) is compared with Fc shape(dq, ddq) on every joint that has friction: the ramp
    Fc sat((dq + lead ddq) / vt) where the joint declares one (`dynamics.friction`), the ideal Fc sign(dq)
    otherwise.

    Returns:
        Per joint: `frictionloss` Fc [N m], `declared_speed` vt [rad/s] (0: ideal), `declared_lead` [s],
        `rms_difference` [N m], `relative` (rms / Fc), `saturated_fraction`
        (share of samples where MuJoCo's force is within 5 % of Fc) and `transition_speed` [rad/s] (the speed
        below which MuJoCo's force falls under 90 % of Fc, a 90th percentile over such samples).
    """
    m = calibrated.mj_model
    if not np.any(m.dof_frictionloss > 0):
        return {}
    m0 = mujoco.MjModel.from_xml_path(str(calibrated.path))
    m0.dof_frictionloss[:] = 0.0
    with_f, without = inverse_dynamics(m, q, dq, ddq), inverse_dynamics(m0, q, dq, ddq)
    declared = friction_shape(dq, ddq, calibrated.friction_speed, calibrated.friction_lead)
    out: dict[str, dict[str, float]] = {}
    for j, name in enumerate(calibrated.joint_names):
        fc = float(m.dof_frictionloss[j])
        if fc <= 0:
            continue
        f_mj = with_f[:, j] - without[:, j]
        ideal = fc * declared[:, j]
        under = np.abs(f_mj) < 0.9 * fc
        out[name] = {
            "frictionloss": fc,
            "declared_speed": float(calibrated.friction_speed[j]),
            "declared_lead": float(calibrated.friction_lead[j]),
            "rms_difference": float(np.sqrt(np.mean((f_mj - ideal) ** 2))),
            "relative": float(np.sqrt(np.mean((f_mj - ideal) ** 2)) / fc),
            "saturated_fraction": float(np.mean(np.abs(np.abs(f_mj) - fc) < 0.05 * fc)),
            "transition_speed": float(np.percentile(np.abs(dq[under, j]), 90)) if np.any(under) else 0.0,
        }
    return out

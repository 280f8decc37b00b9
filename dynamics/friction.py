"""MuJoCo's `frictionloss` as a declared friction shape: Fc sat((dq + lead ddq) / vt).

MuJoCo applies a joint's `frictionloss` Fc through a soft constraint. In inverse dynamics (`mj_inverse`, how a
calibrated MJCF is judged against logged torque) the friction force it produces is exactly

    f = Fc clip((dq + ddq / B) / vt, -1, 1),   vt = R Fc / B,   R = (1 - d) / d * invweight0

with B the constraint's reference damping (2 / (dmax timeconst) for a positive `solref`, -solref[1] / dmax for
the direct form), d its impedance at zero violation (`solimp[0]`) and invweight0 the dof's inverse inertia at
the model's reference pose (`dof_invweight0`). With MuJoCo's defaults (solref 0.02 1, solimp 0.9 0.95) the
friction leads the velocity by 1 / B = 9.5 ms, so it turns over well before a fast joint reverses, over a
ramp vt that reaches metres per second on a light wrist. `friction_solver` writes the direct form for a given
Fc and vt, with B as large as stability allows; `friction_parameters` reads vt and the lead 1 / B back.

Forward simulation integrates the constraint's damping explicitly, at the rate A B Fc / (B vt + A Fc)
(A = invweight0): it is stable (rate x timestep <= 1) when vt >= A Fc timestep (`min_friction_speed`) for any
B, and for a narrower ramp when B <= A Fc / (A Fc timestep - vt) (about 1 / timestep), the price being a lead
of at least one step. `ideal_friction_speed` picks the ramp that comes closest to the ideal Coulomb term.

`applied_friction_parameters` reads vt and the lead MuJoCo applies for any solver parameters (MuJoCo's defaults
among them; a positive time constant is clamped to two physics steps as MuJoCo does unless `refsafe` is
disabled). `friction_parameters` reads only a declared ramp (the direct form `friction_solver` writes): a dof with
other parameters has vt = 0 there, and the identification's torque model treats its friction as the ideal Coulomb
term Fc sign(dq) it stands for (and `system.hard_friction` simulates it as such). The diagnosis, which judges the
MJCF as MuJoCo simulates it, reads every frictionloss as applied (`dynamics.plant.with_applied_friction`).
"""

from __future__ import annotations

import mujoco
import numpy as np

__all__ = [
    "applied_friction_parameters",
    "declared_ramp",
    "friction_enabled",
    "friction_parameters",
    "friction_shape",
    "friction_solver",
    "ideal_friction",
    "ideal_friction_speed",
    "kept_ramp",
    "min_friction_speed",
    "ramp_solver",
]

_MIN_IMPEDANCE = 2e-4  # impedance d of a written ramp stays within these (MuJoCo clamps to [1e-4, 0.9999])
_MAX_IMPEDANCE = 0.999
_RAMP_DAMPING = 1e5  # B vt [rad/s^2] of a written ramp where stability allows: a lead of vt / 1e5 s
# [rad/s^2] at which `ideal_friction_speed` weighs the lead against the width: a reversal of a 1 rad swing at
# 1.6 Hz (the DFKI logs' sinusoids), where a lead of one 2 ms step shifts the turnover by 0.2 rad/s
_REVERSAL_ACCELERATION = 100.0


def friction_shape(dq: np.ndarray, ddq: np.ndarray, speed: np.ndarray, lead: np.ndarray) -> np.ndarray:
    """(N, nv) the declared friction shape per unit `frictionloss`: sat((dq + lead ddq) / vt), sign(dq) where
    vt = 0.

    Args:
        dq, ddq: (N, nv) joint velocities and accelerations [rad/s, rad/s^2].
        speed: (nv,) ramp widths vt [rad/s]; lead: (nv,) leads 1 / B [s] (`friction_parameters`).
    """
    dq = np.asarray(dq, dtype=float)
    speed = np.asarray(speed, dtype=float)
    ramp = np.clip((dq + np.asarray(lead) * np.asarray(ddq)) / np.where(speed > 0, speed, 1.0), -1.0, 1.0)
    return np.where(speed > 0, ramp, np.sign(dq))


def ideal_friction(frictionloss: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """(nv,) True where a dof's frictionloss is the ideal Coulomb term Fc sign(dq) (Fc > 0, no declared ramp:
    `friction_parameters` gives it vt = 0)."""
    return (np.asarray(frictionloss) > 0) & (np.asarray(speed) == 0)  # type: ignore[no-any-return]


def friction_enabled(m: mujoco.MjModel) -> bool:
    """False where the model's <option><flag> disables frictionloss (or every constraint): MuJoCo then applies
    no dry friction at all."""
    off = int(mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS) | int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    return not m.opt.disableflags & off


def applied_friction_parameters(
    m: mujoco.MjModel, frictionloss: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """((nv,) ramp width vt [rad/s], (nv,) lead 1 / B [s]) of the friction MuJoCo applies for each dof's
    frictionloss, whatever its solver parameters (see the module docstring); both 0 where a dof has none.
    `frictionloss` (nv,): the widths for these values of Fc at the dofs' own solver parameters instead of the
    model's (the shape a frictionloss the model lacks would take there).

    B is 2 / (dmax timeconst) for a positive `solref` (timeconst at least two physics steps unless `refsafe` is
    disabled) and -solref[1] / dmax for the direct form; vt = (1 - d) / d invweight0 Fc / B with d the impedance
    at zero violation, solimp[0]; both impedances clamped to [1e-4, 0.9999] as MuJoCo clamps them. As MuJoCo
    does: a solref of mixed signs is its default (0.02, 1), and a solimp of no width has d = (dmin + dmax) / 2
    (`<flag override="enable">` overrides contacts only, not a dof's friction).
    """
    speed, lead = np.zeros(m.nv), np.zeros(m.nv)
    refsafe = not m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_REFSAFE)
    for j in range(m.nv):
        fc = float(m.dof_frictionloss[j] if frictionloss is None else frictionloss[j])
        if fc <= 0:
            continue
        ref, imp = m.dof_solref[j], m.dof_solimp[j]
        if (ref[0] > 0) != (ref[1] > 0):  # a mixed sign: MuJoCo warns and takes its default
            ref = np.array([0.02, 1.0])
        dmax = float(np.clip(imp[1], 1e-4, 0.9999))
        # the impedance at zero violation: dmin, or the mean of both where the transition has no width
        d = float(np.clip(imp[0] if imp[2] > 1e-15 else 0.5 * (imp[0] + imp[1]), 1e-4, 0.9999))
        if ref[0] > 0:
            timeconst = max(float(ref[0]), 2.0 * float(m.opt.timestep)) if refsafe else float(ref[0])
            damping = 2.0 / (dmax * timeconst)
        else:
            damping = -float(ref[1]) / dmax
        if damping <= 0:
            continue  # no damping: MuJoCo's friction is then no ramp of the velocity
        speed[j] = (1.0 - d) / d * float(m.dof_invweight0[j]) * fc / damping
        lead[j] = 1.0 / damping
    return speed, lead


def declared_ramp(m: mujoco.MjModel) -> np.ndarray:
    """(nv,) True where a dof's frictionloss has the direct-form parameters `friction_solver` writes (solref[0] = 0,
    solref[1] < 0, solimp[0] = solimp[1]): a ramp the model declares."""
    ref, imp = m.dof_solref, m.dof_solimp
    return (m.dof_frictionloss > 0) & (ref[:, 0] == 0) & (ref[:, 1] < 0) & (imp[:, 0] == imp[:, 1])  # type: ignore[no-any-return]


def friction_parameters(m: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """((nv,) ramp width vt [rad/s], (nv,) lead 1 / B [s]) of each dof's frictionloss where it is a declared ramp
    (`declared_ramp`), as MuJoCo applies it; both 0 elsewhere (read as the ideal Coulomb term)."""
    speed, lead = applied_friction_parameters(m)
    declared = declared_ramp(m)
    return np.where(declared, speed, 0.0), np.where(declared, lead, 0.0)


def min_friction_speed(frictionloss: float, invweight0: float, timestep: float) -> float:
    """Narrowest ramp [rad/s] that forward simulation at `timestep` integrates stably with any lead."""
    return float(invweight0 * frictionloss * timestep)


def _narrowest(a: float, timestep: float) -> float:
    """Narrowest ramp [rad/s] whose damping-limited impedance stays <= `_MAX_IMPEDANCE` (a = A Fc): below it the
    stable B and the impedance bound cannot both hold."""
    return a * timestep * (1.0 - _MAX_IMPEDANCE)


def _damping(a: float, speed: float, timestep: float) -> float:
    """The largest B for a ramp vt within stability, the impedance floor and `_RAMP_DAMPING` (a = A Fc)."""
    b = min(_RAMP_DAMPING, a * (1.0 - _MIN_IMPEDANCE) / _MIN_IMPEDANCE) / speed
    if speed < a * timestep:
        b = min(b, a / (a * timestep - speed))
    return b


def friction_solver(
    frictionloss: float, speed: float, invweight0: float, timestep: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """(solreffriction (2,), solimpfriction (5,), the width written [rad/s]) that make MuJoCo's frictionloss Fc
    the ramp Fc sat((dq + ddq / B) / vt), B as large as stable forward simulation allows (see the module
    docstring). A width narrower than the step and MuJoCo's impedance bound allow (A Fc timestep / 1000) is
    widened to that.

    Args:
        frictionloss: Fc [N m] (> 0).
        speed: vt [rad/s] (> 0).
        invweight0: the dof's `dof_invweight0` in the compiled model.
        timestep: the model's physics step [s].

    Raises:
        ValueError: a non-positive Fc, vt, invweight0 or timestep.
    """
    if min(frictionloss, speed, invweight0, timestep) <= 0:
        raise ValueError(
            f"friction_solver needs Fc, vt, invweight0, timestep > 0, got {frictionloss}, {speed}, {invweight0}, "
            f"{timestep}"
        )
    a = invweight0 * frictionloss
    speed = max(speed, _narrowest(a, timestep))
    return (*_direct_form(a, speed, _damping(a, speed, timestep)), speed)


def _direct_form(a: float, speed: float, damping: float) -> tuple[np.ndarray, np.ndarray]:
    """(solref, solimp) of the direct form whose ramp is `speed` wide with reference damping B = `damping`
    (a = invweight0 Fc): the impedance d with R = B vt / Fc, i.e. d = a / (a + B vt)."""
    d = a / (a + damping * speed)
    return np.array([0.0, -damping * d]), np.array([d, d, 0.001, 0.5, 2.0])


def ramp_solver(
    frictionloss: float, speed: float, lead: float, invweight0: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """(solreffriction (2,), solimpfriction (5,)) of the direct form that makes MuJoCo's frictionloss Fc exactly
    the ramp Fc sat((dq + lead ddq) / vt) at this `invweight0` (no stability check: `friction_solver` picks the
    lead for forward simulation); None where the impedance it needs is outside MuJoCo's bounds. Keeps a joint's
    friction as it was where a change of its inertia would move `dof_invweight0`, and with it the ramp of
    MuJoCo's defaults."""
    solref, solimp = _direct_form(invweight0 * frictionloss, speed, 1.0 / lead)
    return (solref, solimp) if _MIN_IMPEDANCE / 2 <= solimp[0] <= 0.9999 else None


def kept_ramp(
    frictionloss: float, speed: float, lead: float, invweight0: float, timestep: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """(solreffriction, solimpfriction, the width written) that keep a joint's ramp of width `speed` and lead
    `lead` at this `invweight0`: exactly (`ramp_solver`) where MuJoCo's impedance bounds allow it, else the same
    width with the lead stable forward simulation allows (`friction_solver`)."""
    exact = ramp_solver(frictionloss, speed, lead, invweight0)
    return (*exact, speed) if exact is not None else friction_solver(frictionloss, speed, invweight0, timestep)


def ideal_friction_speed(frictionloss: float, invweight0: float, timestep: float) -> float:
    """The ramp width [rad/s] written for an ideal Coulomb friction: the one whose transition, its width plus the
    lead at `_REVERSAL_ACCELERATION`, is narrowest within stable forward simulation. Where A Fc timestep is
    large (a heavy friction on a light joint at a coarse step) even that is wide: A Fc timestep / 1000 at least."""
    a = invweight0 * frictionloss
    top = max(min_friction_speed(frictionloss, invweight0, timestep), 1e-6)
    grid = np.geomspace(max(_narrowest(a, timestep), top * 1e-6), top, 61)
    width = [v + _REVERSAL_ACCELERATION / _damping(a, float(v), timestep) for v in grid]
    return float(grid[int(np.argmin(width))])

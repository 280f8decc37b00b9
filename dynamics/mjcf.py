"""Editing a model's MJCF through MjSpec: the one writer of body inertials (calibration, hidden payloads)."""

from __future__ import annotations

import mujoco
import numpy as np

from dynamics.inertia import is_consistent, mass_com_inertia

__all__ = ["write_inertial"]


def write_inertial(spec: mujoco.MjSpec, body_name: str, params: np.ndarray) -> None:
    """Give body `body_name` the inertial `params` (10,), in the body's frame, whatever form the file used.

    Written as mass, centre, principal moments and their axes (`diaginertia` + `quat`, MuJoCo's own form);
    any `fullinertia` or alternative orientation of the original is cleared, and the body's inertial becomes
    explicit (so geoms no longer decide it).

    Raises:
        ValueError: unknown body, or parameters that are not physically consistent (MuJoCo would refuse them).
    """
    body = spec.body(body_name)
    if body is None:
        raise ValueError(f"unknown body {body_name!r} in the MJCF")
    if not is_consistent(params):
        raise ValueError(f"body {body_name!r}: the inertial parameters are not physically consistent: {params}")
    if (
        spec.compiler.inertiafromgeom == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE
        or spec.compiler.settotalmass > 0
    ):
        _freeze_geom_inertials(spec)  # else the compiler replaces (or rescales) what is written here
    m, c, inertia = mass_com_inertia(params)
    moments, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0:
        axes[:, 0] = -axes[:, 0]
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, axes.reshape(-1))
    _set_inertial(body, m, c, quat, moments)


def _set_inertial(body: mujoco.MjsBody, mass: float, ipos: np.ndarray, iquat: np.ndarray, moments: np.ndarray) -> None:
    """`body`'s explicit inertial in MuJoCo's own form (`diaginertia` + `quat`), any other form cleared."""
    body.mass, body.ipos, body.iquat, body.inertia = mass, ipos, iquat, moments
    body.fullinertia = np.array([np.nan, 0.0, 0.0, 0.0, 0.0, 0.0])  # MjSpec's "not given"
    body.ialt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT
    body.explicitinertial = True


def _freeze_geom_inertials(spec: mujoco.MjSpec) -> None:
    """Under `<compiler inertiafromgeom="true">` MuJoCo computes every body's inertial from its geoms, an explicit
    `<inertial>` included: one written would be ignored; under `settotalmass` it rescales every mass, a written one
    included. Every body's inertial is written as the model compiles it now, and the compiler switched to
    `inertiafromgeom="auto"` (geoms decide only where a body has no inertial) without a total mass, so that the
    model is the same and an inertial written afterwards is the one compiled."""
    model = spec.compile()
    bodies = list(spec.bodies)  # in the compiled order, the world first
    if len(bodies) != model.nbody:
        raise ValueError(f"the MJCF's {len(bodies)} bodies do not match the {model.nbody} it compiles to")
    for b in range(1, model.nbody):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b)
        body = spec.body(name) if name else bodies[b]
        _set_inertial(
            body,
            float(model.body_mass[b]),
            model.body_ipos[b].copy(),
            model.body_iquat[b].copy(),
            model.body_inertia[b].copy(),
        )
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_AUTO
    spec.compiler.settotalmass = -1.0

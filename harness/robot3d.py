"""The robot in 3D for rerun: MuJoCo's geoms as rerun primitives, moved by per-sample body transforms."""

from __future__ import annotations

import mujoco
import numpy as np
import rerun as rr

from dynamics.plant import Plant

__all__ = ["body_poses", "log_robot"]


def _xyzw(wxyz: np.ndarray) -> np.ndarray:
    return np.asarray(wxyz)[..., [1, 2, 3, 0]]


def body_poses(plant: Plant, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World positions (N, nbody, 3) and orientations (N, nbody, 4, wxyz) of every body at each q (N, nq)."""
    m = plant.mj_model
    d = mujoco.MjData(m)
    pos = np.empty((len(q), m.nbody, 3))
    quat = np.empty((len(q), m.nbody, 4))
    for k in range(len(q)):
        d.qpos[:] = q[k]
        mujoco.mj_kinematics(m, d)
        pos[k], quat[k] = d.xpos, d.xquat
    return pos, quat


def _log_geoms(rec: rr.RecordingStream, plant: Plant, body: int, entity: str) -> None:
    """The geoms of one body, static, in the body's frame."""
    m = plant.mj_model
    for g in np.flatnonzero(m.geom_bodyid == body):
        size, pos, quat = m.geom_size[g], m.geom_pos[g], _xyzw(m.geom_quat[g])
        color = (np.clip(m.geom_rgba[g], 0, 1) * 255).astype(np.uint8)
        kind = m.geom_type[g]
        path = f"{entity}/geom_{g}"
        shape: rr.AsComponents
        if kind == mujoco.mjtGeom.mjGEOM_BOX:
            shape = rr.Boxes3D(half_sizes=[size], centers=[pos], quaternions=[quat], colors=[color], fill_mode="solid")
        elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
            shape = rr.Ellipsoids3D(radii=[size[0]], centers=[pos], colors=[color], fill_mode="solid")
        elif kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
            shape = rr.Ellipsoids3D(
                half_sizes=[size], centers=[pos], quaternions=[quat], colors=[color], fill_mode="solid"
            )
        elif kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
            shape = rr.Cylinders3D(
                lengths=[2 * size[1]],
                radii=[size[0]],
                centers=[pos],
                quaternions=[quat],
                colors=[color],
                fill_mode="solid",
            )
        elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, m.geom_quat[g])
            start = pos - rot.reshape(3, 3)[:, 2] * size[1]  # rerun's capsule starts at its translation
            shape = rr.Capsules3D(
                lengths=[2 * size[1]], radii=[size[0]], translations=[start], quaternions=[quat], colors=[color]
            )
        else:
            continue  # planes, meshes, height fields: not drawn
        rec.log(path, shape, static=True)


def log_robot(
    rec: rr.RecordingStream,
    plant: Plant,
    time: np.ndarray,
    q: np.ndarray,
    *,
    entity: str = "robot",
    rate_hz: float = 50.0,
) -> None:
    """Log the robot's geometry once and its bodies' poses along `q` (N, nq), thinned to about `rate_hz`."""
    step = max(1, int(round(1.0 / (rate_hz * float(np.median(np.diff(time)))))))
    t, qs = time[::step], q[::step]
    pos, quat = body_poses(plant, qs)
    for body in range(1, plant.mj_model.nbody):
        name = mujoco.mj_id2name(plant.mj_model, mujoco.mjtObj.mjOBJ_BODY, body) or f"body{body}"
        path = f"{entity}/{name}"
        _log_geoms(rec, plant, body, path)
        rec.send_columns(
            path,
            indexes=[rr.TimeColumn("time", duration=t)],
            columns=rr.Transform3D.columns(translation=pos[:, body], quaternion=_xyzw(quat[:, body])),
        )

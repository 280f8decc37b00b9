"""The robot in 3D for rerun: MuJoCo's geoms as rerun primitives, moved by per-sample body transforms."""

from __future__ import annotations

import mujoco
import numpy as np
import rerun as rr

from dynamics.plant import Plant

__all__ = ["body_poses", "camera", "log_robot", "log_scene"]


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


def _log_geoms(
    rec: rr.RecordingStream, plant: Plant, body: int, entity: str, rgba: tuple[int, ...] | None = None
) -> None:
    """The geoms of one body, static, in the body's frame; in `rgba` when given, else the MJCF's colours."""
    m = plant.mj_model
    for g in np.flatnonzero(m.geom_bodyid == body):
        size, pos, quat = m.geom_size[g], m.geom_pos[g], _xyzw(m.geom_quat[g])
        if rgba is not None:
            color = np.asarray(rgba, dtype=np.uint8)
        else:
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
    rgba: tuple[int, ...] | None = None,
) -> None:
    """Log the robot's geometry once and its bodies' poses along `q` (N, nq), thinned to about `rate_hz`.

    Args:
        rgba: one colour (RGBA, 0-255) for every geom, such as a role's colour (a translucent one draws a
            ghost); None keeps the MJCF's colours.
    """
    keep = np.all(np.isfinite(q), axis=1)
    time, q = np.asarray(time)[keep], np.asarray(q)[keep]
    step = max(1, int(round(1.0 / (rate_hz * float(np.median(np.diff(time)))))))
    t, qs = time[::step], q[::step]
    pos, quat = body_poses(plant, qs)
    for body in range(1, plant.mj_model.nbody):
        name = mujoco.mj_id2name(plant.mj_model, mujoco.mjtObj.mjOBJ_BODY, body) or f"body{body}"
        path = f"{entity}/{name}"
        _log_geoms(rec, plant, body, path, rgba)
        rec.send_columns(
            path,
            indexes=[rr.TimeColumn("time", duration=t)],
            columns=rr.Transform3D.columns(translation=pos[:, body], quaternion=_xyzw(quat[:, body])),
        )


def _reach(plant: Plant, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lowest and highest world corner (3,) of everything the robot sweeps along `q` (N, nq), base included."""
    m = plant.mj_model
    d = mujoco.MjData(m)
    lo, hi = np.zeros(3), np.zeros(3)
    for k in np.linspace(0, len(q) - 1, min(len(q), 200)).astype(int):
        d.qpos[:] = q[k]
        mujoco.mj_kinematics(m, d)
        for g in range(m.ngeom):
            if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
                continue
            r = float(m.geom_rbound[g]) if m.geom_rbound[g] > 0 else float(np.max(m.geom_size[g]))
            lo = np.minimum(lo, d.geom_xpos[g] - r)
            hi = np.maximum(hi, d.geom_xpos[g] + r)
    return lo, hi


def camera(plant: Plant, q: np.ndarray) -> dict[str, list[float]]:
    """Where the 3D view's eye goes to frame the whole robot over its motion `q` (N, nq).

    A planar robot (every hinge axis parallel at the start) is seen square to its plane of motion, from
    slightly above; any other from an oblique corner. The eye stands far enough back that the sphere
    around everything the robot sweeps fills most of the view.

    Returns:
        `position`, `look_target` and `eye_up` (world frame, m), for `rerun.blueprint.EyeControls3D`.
    """
    m = plant.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = q[0]
    mujoco.mj_kinematics(m, d)
    hinges = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    axes = np.array([d.xaxis[j] for j in hinges]) if hinges else np.zeros((0, 3))
    up = np.array([0.0, 0.0, 1.0])
    planar = len(axes) > 0 and all(abs(float(a @ axes[0])) > 0.999 for a in axes)
    if planar and abs(float(axes[0] @ up)) < 0.9:
        view = -axes[0] + 0.35 * up  # square to the plane of motion, from slightly above
    else:
        view = np.array([1.0, -1.2, 0.9])
    view /= np.linalg.norm(view)
    lo, hi = _reach(plant, q)
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 0.05)
    eye = centre + view * radius * 2.0
    return {"position": eye.tolist(), "look_target": centre.tolist(), "eye_up": up.tolist()}


def log_scene(rec: rr.RecordingStream, plant: Plant, q: np.ndarray, *, entity: str = "robot") -> None:
    """The world's frame under the robot: z up, the world axes (x red, y green, z blue) and the mount.

    The axes are as long as half the robot's reach; the mount is a dark plate at the world origin where
    the robot's base is fixed.
    """
    lo, hi = _reach(plant, q)
    size = max(float(np.max(hi - lo)), 0.1)
    rec.log(entity, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log(
        f"{entity}/world_axes",
        rr.Arrows3D(
            vectors=np.eye(3) * 0.3 * size,
            origins=np.zeros((3, 3)),
            colors=[(230, 60, 60), (60, 200, 60), (70, 110, 255)],
            radii=0.006 * size,
            labels=["x", "y", "z"],
            show_labels=True,
        ),
        static=True,
    )
    rec.log(
        f"{entity}/mount",
        rr.Boxes3D(
            half_sizes=[[0.08 * size, 0.08 * size, 0.02 * size]],
            centers=[[0.0, 0.0, -0.02 * size]],
            colors=[(90, 90, 100)],
            fill_mode="solid",
            labels=["base"],
            show_labels=False,
        ),
        static=True,
    )

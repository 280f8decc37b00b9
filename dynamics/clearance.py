"""Clearance of an arm from itself, from the floor and from what stands fixed in its world along a motion.

Shapes: the model's own collision geometry (geoms with a nonzero `contype` or `conaffinity`, or in a `<pair>`)
where it has some, and for every moving body without any, a capsule from its frame to each child's frame (to its
own centre of mass for a leaf) of radius `FALLBACK_RADIUS_M`. Distances: MuJoCo's `mj_geomDistance` between
collision geoms, a closed form between capsules. Floors: the model's collision planes fixed to the world (a floor,
a table top, a wall: each an infinite plane, as MuJoCo collides with it), or the world plane z = 0 where it has
none; every moving shape is kept above each that MuJoCo's contact filter would check it against (as for pairs,
below; a fallback capsule against every plane that collides with anything). Obstacles: the other collision geoms
fixed to the world (a table, a pedestal, a wall box), each against the moving bodies' collision geoms (a body that
has none, only its fallback capsule, is not checked against them).

Pairs are those MuJoCo's contact filter would check: not shapes on the same or adjacent bodies (parent and child),
not pairs of bodies a `<contact><exclude>` names, not geoms whose contype / conaffinity bitmasks never meet; a
`<contact><pair>` of the model is checked whatever those filters say (its geoms are collision geoms here even with
zero bitmasks). Pairs that can never be apart are left out: pairs (or floor checks) already closer than the
clearance at a reference pose (links built to touch, the first link on its base): the model's `home` keyframe, its
qpos0 and the middle of the joint ranges (where designs are centred).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from dynamics.plant import Plant

__all__ = ["FALLBACK_RADIUS_M", "Clearance", "clearance_for"]

FALLBACK_RADIUS_M = 0.03


@dataclass(frozen=True)
class _Shape:
    body: int
    geom: int  # -1 for a fallback capsule
    ends: tuple[np.ndarray, np.ndarray]  # capsule end points in the body frame
    radius: float
    fixed: bool = False  # an obstacle fixed to the world


@dataclass(frozen=True)
class _Plane:
    """A floor: the half-space n . (x - point) >= 0 in the world frame (`normal` unit length)."""

    point: np.ndarray
    normal: np.ndarray
    geom: int = -1  # the model's plane geom (-1: the default floor z = 0)
    body: int = 0


_FLOOR = _Plane(np.zeros(3), np.array([0.0, 0.0, 1.0]))  # the world plane z = 0 where the model has no floor


def _segment_closest(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The closest points c1 on segments p1-q1 and c2 on p2-q2, each (N, 3) from segments each (N, 3)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = np.sum(d1 * d1, axis=1), np.sum(d2 * d2, axis=1)
    f, c, b = np.sum(d2 * r, axis=1), np.sum(d1 * r, axis=1), np.sum(d1 * d2, axis=1)
    denom = a * e - b * b
    s = np.where(denom > 1e-12, np.clip((b * f - c * e) / np.where(denom > 1e-12, denom, 1.0), 0, 1), 0.0)
    t = np.where(e > 1e-12, (b * s + f) / np.where(e > 1e-12, e, 1.0), 0.0)
    s = np.where(
        t < 0,
        np.clip(-c / np.where(a > 1e-12, a, 1.0), 0, 1),
        np.where(t > 1, np.clip((b - c) / np.where(a > 1e-12, a, 1.0), 0, 1), s),
    )
    t = np.clip(t, 0, 1)
    return p1 + d1 * s[:, None], p2 + d2 * t[:, None]


def _segment_distance(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """(N,) shortest distance between segments p1-q1 and p2-q2, each (N, 3)."""
    c1, c2 = _segment_closest(p1, q1, p2, q2)
    return np.linalg.norm(c1 - c2, axis=1)


class Clearance:
    """The smallest distance between an arm's non-adjacent links and to the floor, along joint angles."""

    def __init__(
        self,
        plant: Plant,
        shapes: list[_Shape],
        q_ref: np.ndarray,
        clearance_m: float,
        planes: tuple[_Plane, ...] = (_FLOOR,),
    ) -> None:
        """`q_ref` (nv,) or (k, nv): the reference pose(s); pairs closer than the clearance at any are left out.
        `planes`: the floors every moving shape is kept above."""
        self.plant, self.shapes, self.clearance_m, self.planes = plant, shapes, float(clearance_m), planes
        m = plant.mj_model
        parent, weld = m.body_parentid, m.body_weldid
        filter_parent = not m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_FILTERPARENT)

        def adjacent(a: int, b: int) -> bool:
            """One rigid body, or a moving body and its moving parent, through any jointless bodies between (as
            MuJoCo's contact filter reads them: a link and the world or a static body it hangs from are checked)."""
            wa, wb = int(weld[a]), int(weld[b])
            if wa == wb:
                return True
            if not filter_parent or wa == 0 or wb == 0:
                return False
            return int(weld[parent[wa]]) == wb or int(weld[parent[wb]]) == wa

        excluded = {
            (int(b1), int(b2)) for b1, b2 in zip(m.exclude_signature >> 16, m.exclude_signature & 0xFFFF, strict=True)
        }
        explicit = {frozenset((int(g1), int(g2))) for g1, g2 in zip(m.pair_geom1, m.pair_geom2, strict=True)}

        def masked(g1: int, g2: int) -> bool:
            """Two collision geoms whose contype / conaffinity bitmasks never let MuJoCo bring them into contact."""
            ct, ca = m.geom_contype, m.geom_conaffinity
            return not (int(ct[g1]) & int(ca[g2]) or int(ct[g2]) & int(ca[g1]))

        candidates = []
        for i, si in enumerate(shapes):
            for j in range(i + 1, len(shapes)):
                sj = shapes[j]
                a, b = si.body, sj.body
                if (si.fixed or sj.fixed) and (si.fixed == sj.fixed or min(si.geom, sj.geom) < 0):
                    continue  # an obstacle against the moving collision geoms only
                if frozenset((si.geom, sj.geom)) in explicit:
                    candidates.append((i, j))  # a <pair> of the model: MuJoCo checks it whatever the filters say
                    continue
                # a base built to touch its first link drops out at the reference poses
                if adjacent(a, b) or (a, b) in excluded or (b, a) in excluded:
                    continue
                if min(si.geom, sj.geom) >= 0 and masked(si.geom, sj.geom):
                    continue
                candidates.append((i, j))
        self.pairs = candidates

        def on_floor(shape: _Shape, plane: _Plane) -> bool:
            """Whether MuJoCo's contact filter would check a moving shape against a floor plane: the default floor
            always; a model's plane as a geom pair (a `<pair>` always, else not excluded and the bitmasks meeting;
            a plane in `<pair>`s only, against its paired geoms alone; a fallback capsule against a plane that
            collides with anything)."""
            if plane.geom < 0:
                return True
            if shape.geom >= 0 and frozenset((shape.geom, plane.geom)) in explicit:
                return True
            if (shape.body, plane.body) in excluded or (plane.body, shape.body) in excluded:
                return False
            if shape.geom < 0:
                return bool(m.geom_contype[plane.geom] or m.geom_conaffinity[plane.geom])
            return not masked(shape.geom, plane.geom)

        # (shape, plane) floor checks
        self.floor = [
            (k, f)
            for k, shape in enumerate(shapes)
            if not shape.fixed
            for f, plane in enumerate(planes)
            if on_floor(shape, plane)
        ]
        pair_d, floor_d = self._distances(np.atleast_2d(q_ref))
        self.pairs = [p for p, d in zip(self.pairs, pair_d.min(axis=0), strict=True) if d > clearance_m]
        self.floor = [k for k, d in zip(self.floor, floor_d.min(axis=0), strict=True) if d > clearance_m]

    def _distances(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m = self.plant.mj_model
        d = mujoco.MjData(m)
        n = len(q)
        ends = np.empty((len(self.shapes), 2, n, 3))
        pair_d = np.empty((n, len(self.pairs)))
        floor_d = np.empty((n, len(self.floor)))
        geoms = [(k, i, j) for k, (i, j) in enumerate(self.pairs) if min(self.shapes[i].geom, self.shapes[j].geom) >= 0]
        for s in range(n):
            d.qpos[:] = q[s]
            mujoco.mj_kinematics(m, d)
            for k, shape in enumerate(self.shapes):
                R, p = d.xmat[shape.body].reshape(3, 3), d.xpos[shape.body]
                ends[k, 0, s], ends[k, 1, s] = p + R @ shape.ends[0], p + R @ shape.ends[1]
            for k, i, j in geoms:
                pair_d[s, k] = mujoco.mj_geomDistance(m, d, self.shapes[i].geom, self.shapes[j].geom, 10.0, None)
        for k, (i, j) in enumerate(self.pairs):
            if min(self.shapes[i].geom, self.shapes[j].geom) >= 0:
                continue
            si, sj = self.shapes[i], self.shapes[j]
            seg = _segment_distance(ends[i, 0], ends[i, 1], ends[j, 0], ends[j, 1])
            pair_d[:, k] = seg - si.radius - sj.radius
        checked, point, normal = self._floor_checks()
        height = np.einsum("kena,ka->ken", ends[checked] - point[:, None, None, :], normal)  # each end point's
        floor_d[:] = (height.min(axis=1) - np.array([self.shapes[i].radius for i in checked])[:, None]).T
        return pair_d, floor_d

    def _floor_checks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The floor checks as arrays: (k,) shape index, (k, 3) a point of its plane and (k, 3) its unit normal."""
        shape = np.array([i for i, _ in self.floor], dtype=int)
        point = np.array([self.planes[f].point for _, f in self.floor]).reshape(-1, 3)
        normal = np.array([self.planes[f].normal for _, f in self.floor]).reshape(-1, 3)
        return shape, point, normal

    def min_distance(self, q: np.ndarray, *, max_points: int = 1000) -> float:
        """Smallest distance [m] over the samples q (N, nv): every k-th sample, k the smallest stride that leaves
        at most `max_points` (so a grid and the same grid 4x denser are checked on the same samples)."""
        if not self.pairs and not self.floor:
            return float("inf")
        q = np.atleast_2d(q)
        q = q[:: int(np.ceil(len(q) / max_points))]
        pair_d, floor_d = self._distances(q)
        return float(min(pair_d.min(initial=np.inf), floor_d.min(initial=np.inf)))

    def ratio(self, q: np.ndarray) -> float:
        """clearance / smallest distance: <= 1 where the clearance holds (inf once links touch)."""
        dist = self.min_distance(q)
        return float(self.clearance_m / dist) if dist > 0 else float("inf")

    def smooth_distance(self, q: np.ndarray, *, temperature_m: float = 0.005) -> tuple[np.ndarray, np.ndarray]:
        """A smooth lower bound of the smallest distance at each pose, and its gradient in the joint angles.

        The soft minimum -T log(sum_k exp(-d_k / T)) over every checked pair and floor distance d_k (at most
        T log(count) below the true minimum, so a constraint on it is conservative). Each d_k's gradient is
        that of the distance between its two witness points held fixed on their bodies (exact where the
        witness points are unique): u . (J_2 - J_1) with u the unit vector from the first to the second.

        Args:
            q: (N, nv) joint angles [rad].
            temperature_m: T [m], the soft minimum's smoothing length.

        Returns:
            d: (N,) soft-minimum distance [m].
            grad: (N, nv) its gradient [m/rad].
        """
        q = np.atleast_2d(q)
        n, nv = q.shape
        out_d, out_g = np.full(n, np.inf), np.zeros((n, nv))
        if not self.pairs and not self.floor:
            return out_d, out_g
        m = self.plant.mj_model
        data = mujoco.MjData(m)
        is_geo = np.array([min(self.shapes[i].geom, self.shapes[j].geom) >= 0 for i, j in self.pairs], dtype=bool)
        pi = np.array([i for i, _ in self.pairs], dtype=int)
        pj = np.array([j for _, j in self.pairs], dtype=int)
        ci, cj, gi, gj = pi[~is_geo], pj[~is_geo], pi[is_geo], pj[is_geo]
        geoms = np.array([s.geom for s in self.shapes], dtype=int)
        bodies = np.array([s.body for s in self.shapes], dtype=int)
        local = np.array([s.ends for s in self.shapes]).reshape(-1, 2, 3)  # (shapes, 2, 3) in the body frame
        radii = np.array([s.radius for s in self.shapes])
        floor, point, normal = self._floor_checks()
        fromto = np.empty(6)
        jac1, jac2 = np.empty((3, nv)), np.empty((3, nv))
        distmax = self.clearance_m + 20 * temperature_m  # farther pairs weigh < exp(-20) in the soft minimum
        for s in range(n):
            data.qpos[:] = q[s]
            mujoco.mj_kinematics(m, data)
            mujoco.mj_comPos(m, data)  # mj_jac needs cdof and subtree_com
            R, p = data.xmat[bodies].reshape(-1, 3, 3), data.xpos[bodies]
            ends = p[:, None, :] + np.einsum("kab,keb->kea", R, local)  # (shapes, 2, 3) in the world
            c1, c2 = _segment_closest(ends[ci, 0], ends[ci, 1], ends[cj, 0], ends[cj, 1])
            gap = np.linalg.norm(c2 - c1, axis=1)
            d_cap = gap - radii[ci] - radii[cj]
            d_geo = np.array(
                [
                    mujoco.mj_geomDistance(m, data, int(a), int(b), distmax, None)
                    for a, b in zip(geoms[gi], geoms[gj], strict=True)
                ]
            )
            heights = np.einsum("kea,ka->ke", ends[floor] - point[:, None, :], normal)  # (checks, 2)
            low = np.argmin(heights, axis=1)
            floor_pts = ends[floor, low]
            d_floor = heights[np.arange(len(floor)), low] - radii[floor]
            dk = np.concatenate([d_cap, d_geo, d_floor])
            lowest = float(dk.min())
            w = np.exp(-(dk - lowest) / temperature_m)
            total = float(w.sum())
            out_d[s] = lowest - temperature_m * np.log(total)
            nc, ng = len(ci), len(gi)
            beyond = np.zeros(len(dk), dtype=bool)
            beyond[nc : nc + ng] = d_geo >= distmax  # reported as distmax, no witness points: gradient zero
            for k in np.flatnonzero((w / total > 1e-6) & ~beyond):
                if k < nc:  # capsule pair: witness points on the segments (the radii are constant)
                    b1, p1, b2, p2 = bodies[ci[k]], c1[k], bodies[cj[k]], c2[k]
                    u = (p2 - p1) / max(float(gap[k]), 1e-12)
                elif k < nc + ng:  # collision geoms: MuJoCo's witness points
                    a, b = int(geoms[gi[k - nc]]), int(geoms[gj[k - nc]])
                    dist = mujoco.mj_geomDistance(m, data, a, b, distmax, fromto)
                    if dist == 0:
                        continue
                    b1, p1, b2, p2 = bodies[gi[k - nc]], fromto[:3].copy(), bodies[gj[k - nc]], fromto[3:].copy()
                    v = p2 - p1
                    u = np.sign(dist) * v / max(float(np.linalg.norm(v)), 1e-12)
                else:  # floor: the shape's lowest end point moving along the plane's normal
                    f = k - nc - ng
                    b1, p1, b2, p2, u = bodies[floor[f]], floor_pts[f], -1, p, -normal[f]
                mujoco.mj_jac(m, data, jac1, None, p1, int(b1))
                g = -u @ jac1
                if b2 >= 0:
                    mujoco.mj_jac(m, data, jac2, None, p2, int(b2))
                    g = g + u @ jac2
                out_g[s] += (w[k] / total) * g
        return out_d, out_g


def _geom_capsule(m: mujoco.MjModel, g: int) -> tuple[tuple[np.ndarray, np.ndarray], float]:
    """A capsule around geom g in its body frame (exact for spheres and capsules, bounding otherwise)."""
    flat = np.empty(9)
    mujoco.mju_quat2Mat(flat, m.geom_quat[g])
    R = flat.reshape(3, 3)
    pos, size = m.geom_pos[g], m.geom_size[g]
    kind = int(m.geom_type[g])
    if kind in (int(mujoco.mjtGeom.mjGEOM_CAPSULE), int(mujoco.mjtGeom.mjGEOM_CYLINDER)):
        axis = R[:, 2] * size[1]
        return (pos - axis, pos + axis), float(size[0])
    return (pos.copy(), pos.copy()), float(m.geom_rbound[g])


def clearance_for(plant: Plant, clearance_m: float, q_ref: np.ndarray) -> Clearance:
    """The clearance check of a plant (see the module docstring), referenced to the pose q_ref (nv,)."""
    m = plant.mj_model
    moving = {int(b) for b in range(1, m.nbody) if m.body_weldid[b] != 0}
    paired = {int(g) for g in (*m.pair_geom1, *m.pair_geom2)}
    colliding = [g for g in range(m.ngeom) if m.geom_contype[g] or m.geom_conaffinity[g] or g in paired]
    shapes = [_Shape(int(m.geom_bodyid[g]), g, *_geom_capsule(m, g)) for g in colliding if m.geom_bodyid[g] in moving]
    covered = {s.body for s in shapes}
    plane = int(mujoco.mjtGeom.mjGEOM_PLANE)
    shapes += [  # the obstacles: fixed to the world (planes are floors, checked as such)
        _Shape(int(m.geom_bodyid[g]), g, *_geom_capsule(m, g), fixed=True)
        for g in colliding
        if m.geom_bodyid[g] not in moving and int(m.geom_type[g]) != plane
    ]
    floors = [g for g in colliding if m.geom_bodyid[g] not in moving and int(m.geom_type[g]) == plane]
    data = mujoco.MjData(m)
    mujoco.mj_kinematics(m, data)  # where the world's planes are (they do not move with q)
    planes = tuple(
        _Plane(data.geom_xpos[g].copy(), data.geom_xmat[g].reshape(3, 3)[:, 2].copy(), g, int(m.geom_bodyid[g]))
        for g in floors
    ) or (_FLOOR,)
    for b in sorted(moving - covered):
        children = [c for c in range(1, m.nbody) if m.body_parentid[c] == b]
        targets = [m.body_pos[c].copy() for c in children] or [m.body_ipos[b].copy()]
        for target in targets:
            if np.linalg.norm(target) > 1e-6:
                shapes.append(_Shape(b, -1, (np.zeros(3), target), FALLBACK_RADIUS_M))
    return Clearance(plant, shapes, q_ref, clearance_m, planes)

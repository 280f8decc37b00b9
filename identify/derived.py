"""Physical quantities that are linear in the standard parameters (the thesis's J, m l, wheel inertia).

Each quantity is a vector c over the standard parameters, computed from the plant's kinematics at q = 0,
so no model number is written twice; `compare.linear_combination` turns it into an estimate and std.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pinocchio as pin

from dynamics.inertia import transform_parameters
from dynamics.plant import Plant

__all__ = ["DERIVED", "first_moment_along", "inertia_about_joint_axis"]


def _placements(plant: Plant) -> list[pin.SE3]:
    """Placement of every joint frame in the first joint's frame at q = 0."""
    pm = plant.pin_model
    data = pm.createData()
    pin.forwardKinematics(pm, data, pin.neutral(pm))
    root = data.oMi[1]
    return [root.actInv(data.oMi[i]) for i in range(1, pm.njoints)]


def _moved(params: np.ndarray, placement: pin.SE3) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, first moment (3,) and inertia (3, 3) at the first joint's origin, from one body's 10 parameters."""
    moved = transform_parameters(params, placement.homogeneous)
    xx, xy, yy, xz, yz, zz = moved[4:]
    return float(moved[0]), moved[1:4], np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def _linear_in_params(plant: Plant, fn: Callable[[float, np.ndarray, np.ndarray, int], float]) -> np.ndarray:
    """Vector c with c @ theta == sum over bodies k of fn(mass, first moment, inertia at the root, k)."""
    places = _placements(plant)
    c = np.zeros(10 * plant.nv)
    for k in range(plant.nv):
        for i in range(10):
            c[10 * k + i] = fn(*_moved(np.eye(10)[i], places[k]), k)
    return c


def inertia_about_joint_axis(plant: Plant, bodies: list[int]) -> np.ndarray:
    """c such that c @ theta is the inertia of `bodies` about the first joint's axis, at q = 0 [kg m^2]."""
    axis = np.asarray(plant.mj_model.jnt_axis[0], dtype=float)
    return _linear_in_params(plant, lambda m, h, inertia, k: float(axis @ inertia @ axis) if k in bodies else 0.0)


def first_moment_along(plant: Plant, direction: np.ndarray) -> np.ndarray:
    """c such that c @ theta is sum_k m_k c_k . direction in the first joint's frame at q = 0 [kg m]."""
    return _linear_in_params(plant, lambda m, h, inertia, k: float(direction @ h))


def _wheel_pendulum(plant: Plant) -> dict[str, tuple[np.ndarray, str]]:
    """The thesis's section 5.3: J = J_p + m_p l_p^2 + m_r l_r^2, m l = m_p l_p + m_r l_r, and J_wheel."""
    down = np.array([0.0, 0.0, -1.0])
    wheel_own = np.zeros(10 * plant.nv)
    wheel_own[10 * 1 + 6] = 1.0  # YY of the wheel about its own (y) axis
    total = inertia_about_joint_axis(plant, [0, 1])
    return {
        "J": (total - wheel_own, "kg m^2"),
        "ml": (first_moment_along(plant, down), "kg m"),
        "J_wheel": (wheel_own, "kg m^2"),
    }


DERIVED: dict[str, Callable[[Plant], dict[str, tuple[np.ndarray, str]]]] = {"wheel_pendulum": _wheel_pendulum}

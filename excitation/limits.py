"""Limits an excitation must respect: joint range (MJCF), speed and acceleration (config), torque (MJCF)."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from dynamics.actuators import two_sided
from dynamics.clearance import Clearance, clearance_for
from dynamics.errors import InfeasibleExcitationError, ModelError
from dynamics.plant import Plant

__all__ = ["Limits", "limits_for"]


@dataclass(frozen=True)
class Limits:
    """Per-joint bounds, each (n,); +-inf where a bound does not apply.

    Attributes:
        q_min, q_max: joint range [rad], already shrunk by the safety margin.
        dq_max: speed bound [rad/s].
        ddq_max: acceleration bound [rad/s^2].
        tau_max: torque bound [N m] (the actuator's limit times the torque margin; inf where unactuated).
        joint_names: names used in messages.
        clearance: the smallest distance kept between non-adjacent links and to the floor, or None.
    """

    q_min: np.ndarray
    q_max: np.ndarray
    dq_max: np.ndarray
    ddq_max: np.ndarray
    tau_max: np.ndarray
    joint_names: tuple[str, ...]
    clearance: Clearance | None = None

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        for name in ("q_min", "q_max", "dq_max", "ddq_max", "tau_max"):
            if np.shape(getattr(self, name)) != (n,):
                raise ValueError(f"limit {name} has shape {np.shape(getattr(self, name))}, expected ({n},)")
        if np.any(self.q_min >= self.q_max):
            raise ValueError(f"empty joint range: q_min {self.q_min} >= q_max {self.q_max}")
        for name in ("dq_max", "ddq_max", "tau_max"):
            if np.any(getattr(self, name) <= 0):
                raise ValueError(f"limit {name} must be > 0, got {getattr(self, name)}")

    def ratios(
        self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray | None = None, tau: np.ndarray | None = None
    ) -> dict[str, float]:
        """Worst use of each bound over the samples (<= 1 means it holds): keys `q`, `dq`, `ddq`, `tau`.

        For `q` the ratio is the worst excursion from the range's centre over the half-range, with an
        out-of-range sample giving > 1 (an unlimited joint gives 0).
        """
        out = {k: float(v.max()) for k, v in self.joint_ratios(q, dq, ddq, tau).items()}
        if self.clearance is not None:
            out["clearance"] = self.clearance.ratio(q)
        return out

    def joint_ratios(
        self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray | None = None, tau: np.ndarray | None = None
    ) -> dict[str, np.ndarray]:
        """Each joint's worst use (nv,) of each joint bound over the samples (N, nv): as `ratios`, by joint."""
        finite = np.isfinite(self.q_min) & np.isfinite(self.q_max)
        center = np.where(finite, 0.5 * (np.where(finite, self.q_min, 0) + np.where(finite, self.q_max, 0)), 0.0)
        half = 0.5 * (self.q_max - self.q_min)
        out = {"q": np.max(np.abs(q - center) / half, axis=0), "dq": np.max(np.abs(dq) / self.dq_max, axis=0)}
        if ddq is not None:
            out["ddq"] = np.max(np.abs(ddq) / self.ddq_max, axis=0)
        if tau is not None:
            out["tau"] = np.max(np.abs(tau) / self.tau_max, axis=0)
        return out

    @staticmethod
    def binding_key(ratios: dict[str, float]) -> str:
        """The kind of the most used bound (`q`, `dq`, `ddq`, `tau` or `clearance`)."""
        return max(ratios, key=lambda k: ratios[k])

    def binding(self, ratios: dict[str, float]) -> str:
        """A readable name of the most used bound, e.g. `dq (bound shoulder 8, elbow 8 rad/s)`."""
        key = self.binding_key(ratios)
        if key == "clearance" and self.clearance is not None:
            at_least = f"at least {self.clearance.clearance_m:.3g} m"
            return f"clearance ({at_least} between links, to the floor and to fixed geoms)"
        units = {"q": "rad", "dq": "rad/s", "ddq": "rad/s^2", "tau": "N m"}
        bound = {"q": self.q_max, "dq": self.dq_max, "ddq": self.ddq_max, "tau": self.tau_max}[key]
        per_joint = ", ".join(f"{j} {b:.4g}" for j, b in zip(self.joint_names, bound, strict=True))
        return f"{key} (bound {per_joint} {units[key]})"

    def infeasible(self, what: str, ratios: dict[str, float], then: str = "") -> InfeasibleExcitationError:
        """The error for `what` failed, naming the most used bound of `ratios` (and carrying its kind)."""
        return InfeasibleExcitationError(
            f"{what}: binding constraint {self.binding(ratios)}{then}", bound=self.binding_key(ratios)
        )

    def to_dict(self) -> dict[str, list[float]]:
        def clean(a: np.ndarray) -> list[float]:
            return [float(x) if np.isfinite(x) else None for x in a]  # type: ignore[misc]

        out: dict = {k: clean(getattr(self, k)) for k in ("q_min", "q_max", "dq_max", "ddq_max", "tau_max")}
        if self.clearance is not None:
            out["clearance_m"] = self.clearance.clearance_m
        return out


def limits_for(
    plant: Plant,
    *,
    velocity: float | list[float],
    acceleration: float | list[float],
    range_margin: float = 0.05,
    torque_margin: float = 0.9,
    clearance_m: float | None = None,
) -> Limits:
    """Limits from the MJCF (range, actuator torque, a servo's ctrlrange) and the config (speed, acceleration).

    A position servo's ctrlrange (over its gear) narrows its joint's range and a velocity servo's its speed:
    the servo clamps its target there, so a design beyond it would not be the motion that runs. A joint limit's
    `margin` narrows the range too: MuJoCo's limit force acts that far inside each end.

    Args:
        velocity: speed bound per joint (or one for all) [rad/s].
        acceleration: acceleration bound per joint (or one for all) [rad/s^2].
        range_margin: fraction of each finite joint range kept free at both ends.
        torque_margin: fraction of the actuator's torque limit the nominal model may use.
        clearance_m: smallest distance kept between non-adjacent links and to the floor [m] (None: unchecked),
            referenced to the model's `home` keyframe, qpos0 and range middles to leave out pairs built to touch.
    """
    n = plant.nv
    lo, hi = plant.q_range[:, 0].copy(), plant.q_range[:, 1].copy()
    # a limit's margin: MuJoCo's limit force acts within that distance of the range's end; a negative one lets the
    # joint past its range, which the design does not use
    margin = plant.limit_margin
    if np.any(2 * margin >= hi - lo):
        j = int(np.argmax(2 * margin - (hi - lo)))
        raise ModelError(
            f"{plant.path}: joint {plant.joint_names[j]!r}'s limit margin {margin[j]:.4g} leaves no free range "
            f"inside [{lo[j]:.4g}, {hi[j]:.4g}]: MuJoCo's limit force acts within the margin of each end"
        )
    lo, hi = lo + margin, hi - margin
    dq_max = np.broadcast_to(np.asarray(velocity, dtype=float), (n,)).copy()
    for a in plant.actuation.actuators:  # a servo's ctrlrange clamps its target: the joint goes no further
        if a.ctrl_range is None or not a.is_servo:
            continue
        reach = np.sort(a.ctrl_range / a.gear)
        if a.kind == "position":
            lo[a.joint], hi[a.joint] = max(lo[a.joint], reach[0]), min(hi[a.joint], reach[1])
        else:
            dq_max[a.joint] = min(dq_max[a.joint], two_sided(reach))
    finite = np.isfinite(lo) & np.isfinite(hi)
    shrink = range_margin * (hi - lo)
    lo[finite] += shrink[finite]
    hi[finite] -= shrink[finite]
    tau = np.where(plant.actuated, plant.tau_limit * torque_margin, np.inf)
    return Limits(
        q_min=lo,
        q_max=hi,
        dq_max=dq_max,
        ddq_max=np.broadcast_to(np.asarray(acceleration, dtype=float), (n,)).copy(),
        tau_max=tau,
        joint_names=plant.joint_names,
        clearance=None if clearance_m is None else clearance_for(plant, clearance_m, _reference_poses(plant, lo, hi)),
    )


def _reference_poses(plant: Plant, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(k, nv) the model's `home` keyframe (where it has one), its qpos0 and the middle of the joint ranges."""
    m = plant.mj_model
    key = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, "home")
    middle = np.where(np.isfinite(lo) & np.isfinite(hi), 0.5 * (np.nan_to_num(lo) + np.nan_to_num(hi)), 0.0)
    poses = [m.qpos0.copy(), middle] + ([m.key_qpos[key].copy()] if key >= 0 else [])
    return np.clip(np.array(poses), plant.q_range[:, 0], plant.q_range[:, 1])

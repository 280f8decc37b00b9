"""System settings taken from the model, for a robot that has no system config of its own.

`conf/system/auto.yaml` lists the keys; each null is filled here from the model, and the run prints what it
assumed. The defaults are stated, not tuned per robot:

- effects: the effect columns the model declares (armature, damping -> viscous_friction,
  frictionloss -> coulomb_friction, stiffness -> joint_stiffness);
- torque_driven: true when some joint has no actuator;
- velocity: the URDF's velocity limit where given, else `DEFAULT_VELOCITY`; acceleration `DEFAULT_ACCELERATION`;
- sample rate: the fastest rate <= `MAX_SAMPLE_RATE_HZ` that is a whole number of physics steps;
- torque noise: `NOISE_FRACTION` of each joint's torque scale (its actuator limit, or twice the largest torque
  it needs at random states within the default speed and acceleration where the actuator has none);
  resolution: the smallest scale over 2^11.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from omegaconf import DictConfig, OmegaConf

from dynamics.plant import Plant
from dynamics.sampling import random_states
from dynamics.torque import joint_torque
from dynamics.urdf import is_urdf, urdf_velocity_limits

__all__ = [
    "DEFAULT_ACCELERATION",
    "DEFAULT_VELOCITY",
    "MAX_SAMPLE_RATE_HZ",
    "NOISE_FRACTION",
    "declared_effects",
    "resolve_system",
    "torque_scale",
]

DEFAULT_VELOCITY = 1.5  # [rad/s]
DEFAULT_ACCELERATION = 8.0  # [rad/s^2]
MAX_SAMPLE_RATE_HZ = 500.0
NOISE_FRACTION = 0.005


def declared_effects(plant: Plant) -> list[str]:
    """The effect columns for what the model declares on any joint."""
    declared = {
        "armature": plant.armature,
        "viscous_friction": plant.damping,
        "coulomb_friction": plant.frictionloss,
        "joint_stiffness": plant.stiffness,
    }
    return [name for name, values in declared.items() if np.any(values > 0)]


def torque_scale(plant: Plant) -> np.ndarray:
    """(nv,) each joint's torque scale [N m]: its actuator limit, or twice the largest torque it needs at random
    states within the default speed and acceleration (gravity alone leaves a vertical axis at zero)."""
    rng = np.random.default_rng(0)
    q = random_states(plant, rng, 200)[0]
    dq = rng.uniform(-DEFAULT_VELOCITY, DEFAULT_VELOCITY, q.shape)
    ddq = rng.uniform(-DEFAULT_ACCELERATION, DEFAULT_ACCELERATION, q.shape)
    needed = np.max(np.abs(joint_torque(plant, q, dq, ddq, coulomb=False)[0]), axis=0)
    scale = np.where(np.isfinite(plant.tau_limit), plant.tau_limit, 2.0 * needed)
    return np.where(scale > 0, scale, 1.0)


def _sample_rate(plant: Plant) -> float:
    dt = float(plant.mj_model.opt.timestep)
    steps = int(np.ceil((1.0 / MAX_SAMPLE_RATE_HZ) / dt - 1e-9))
    return 1.0 / (max(steps, 1) * dt)


def _velocity(plant: Plant) -> float | list[float]:
    source = plant.source or plant.path
    if is_urdf(source):
        given = urdf_velocity_limits(source)
        if given:
            return [float(given.get(name, DEFAULT_VELOCITY)) for name in plant.joint_names]
    return DEFAULT_VELOCITY


def _rounded(values: np.ndarray) -> list[float]:
    return [float(f"{v:.3g}") for v in values]


def resolve_system(system: DictConfig, plant: Plant) -> tuple[DictConfig, dict[str, Any]]:
    """The system config with every null filled from the model, and what was assumed (key -> value)."""
    out = OmegaConf.create(OmegaConf.to_container(system, resolve=True))
    scale = torque_scale(plant)
    fill: dict[str, Any] = {
        "name": plant.name,
        "torque_driven": not bool(np.all(plant.actuated)),
        "effects": declared_effects(plant),
        "limits.velocity": _velocity(plant),
        "limits.acceleration": DEFAULT_ACCELERATION,
        "sensor.sample_rate_hz": _sample_rate(plant),
        "sensor.sigma_tau": _rounded(NOISE_FRACTION * scale * plant.actuated),
        "sensor.tau_resolution": float(f"{float(np.min(scale[plant.actuated])) / 2**11:.3g}")
        if any(plant.actuated)
        else 0.0,
    }
    assumed: dict[str, Any] = {}
    for key, value in fill.items():
        if OmegaConf.select(out, key, default=None) is None:
            OmegaConf.update(out, key, value, force_add=True)
            assumed[key] = value
    return out, assumed  # type: ignore[return-value]

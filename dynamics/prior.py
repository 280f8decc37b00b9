"""The prior (nominal) model: what a user believes about the robot before identifying it.

Everything that needs a model before the data have spoken takes it from here: the pull of a regularised or
physically consistent fit (`identify.estimators.physical`), the feedforward and gains of the tracking
controller, and the torque limits an excitation design is checked against.

- On real data the prior is the user's nominal MJCF (`kind="mjcf"`).
- In simulation the MJCF *is* the truth, so the prior is the truth perturbed the way a CAD model is wrong
  (`kind="perturbed"`): every body's mass scaled by a factor in 1 +- `mass_rel`, its centre of mass moved by
  up to `com_m` along each axis, its rotational inertia about the centre of mass scaled in each principal
  direction by up to +- `inertia_rel` (through the second moments of the mass distribution, so the body stays
  physically consistent), rotor inertia (armature) scaled by up to +- `armature_rel`, and friction unknown
  (damping and frictionloss 0). It is never the truth itself: a zero spread is refused.

The perturbed prior is a compiled MuJoCo model (built through `MjSpec` from the truth's compiled inertials),
so it serves as a `Plant` for feedforward and limits, and its standard parameters are a physically
consistent prior `theta` in the identification model's order.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from dynamics.errors import ModelError, one_line
from dynamics.plant import Plant, load_plant, load_spec, plant_from_model
from dynamics.regressor import ParameterModel

__all__ = ["PRIOR_KINDS", "Prior", "PriorSpec", "make_prior", "perturbed_plant"]

PRIOR_KINDS = ("mjcf", "perturbed")


@dataclass(frozen=True)
class PriorSpec:
    """How the prior is made.

    Attributes:
        kind: "perturbed" (truth perturbed as a CAD model is wrong; simulation) or "mjcf" (a nominal MJCF).
        mass_rel: each body's mass is scaled by 1 + u mass_rel, u uniform in [-1, 1].
        com_m: each coordinate of each body's centre of mass moves by u com_m [m].
        inertia_rel: each principal second moment about the centre of mass is scaled by 1 + u inertia_rel.
        armature_rel: each joint's rotor inertia is scaled by 1 + u armature_rel.
        mjcf: kind "mjcf": path of the nominal MJCF; None: the system's own MJCF (real data only, where
            the MJCF is the user's nominal model and not the truth).
        seed: seed of the perturbation (kind "perturbed"); None: drawn from the run's generator.
    """

    kind: str = "perturbed"
    mass_rel: float = 0.2
    com_m: float = 0.01
    inertia_rel: float = 0.3
    armature_rel: float = 0.3
    mjcf: str | None = None
    seed: int | None = None

    def __post_init__(self) -> None:
        if self.kind not in PRIOR_KINDS:
            raise ValueError(f"unknown prior kind {self.kind!r}; valid choices: {', '.join(PRIOR_KINDS)}")
        for name in ("mass_rel", "inertia_rel", "armature_rel"):
            value = getattr(self, name)
            if not 0.0 <= value < 1.0:
                raise ValueError(f"prior.{name} must be in [0, 1), got {value}")
        if self.com_m < 0:
            raise ValueError(f"prior.com_m must be >= 0 m, got {self.com_m}")
        if self.kind == "perturbed" and max(self.mass_rel, self.com_m, self.inertia_rel) == 0:
            raise ValueError(
                "a perturbed prior with zero spread is the truth itself; give prior.mass_rel, prior.com_m or "
                "prior.inertia_rel > 0 (or prior.kind=mjcf with a nominal MJCF)"
            )

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> PriorSpec:
        """From a config node; unknown keys are refused with the valid ones."""
        valid = set(cls.__dataclass_fields__)
        unknown = sorted(set(values) - valid)
        if unknown:
            raise ValueError(f"unknown prior key(s) {unknown}; valid keys: {', '.join(sorted(valid))}")
        return cls(**values)

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass(frozen=True, eq=False)
class Prior:
    """The prior model of one identification.

    Attributes:
        spec: how it was made.
        plant: the prior as a plant (feedforward, gains, torque limits).
        theta: (p,) its standard parameters in the identification model's order (friction 0 when unknown).
        seed: the perturbation's seed (None for kind "mjcf").
    """

    spec: PriorSpec
    plant: Plant
    theta: np.ndarray
    seed: int | None

    def summary(self, truth: np.ndarray) -> dict[str, Any]:
        """What results.json records: the spec, the seed and how far the prior is from `truth` (p,)."""
        nv = self.plant.nv
        mass_err = [float(self.theta[10 * j] / truth[10 * j] - 1.0) if truth[10 * j] > 0 else None for j in range(nv)]
        return {
            **self.spec.to_dict(),
            "seed": self.seed,
            # the MJCF a prior of kind "mjcf" was read from; a perturbed prior is compiled in memory, never written
            "path": str(self.plant.path) if self.spec.kind == "mjcf" else None,
            "mass_rel_error": mass_err,
            "is_truth": bool(np.array_equal(self.theta, truth)),
        }


def _principal_scaled(inertia: np.ndarray, factors: np.ndarray) -> np.ndarray:
    """Principal moments with the second moments s_i = (tr I)/2 - I_i scaled by `factors` (all stay >= 0)."""
    second = np.clip(0.5 * np.sum(inertia) - inertia, 0.0, None) * factors
    return np.sum(second) - second


def perturbed_plant(plant: Plant, spec: PriorSpec, rng: np.random.Generator, *, path: Path | None = None) -> Plant:
    """The truth's compiled model with every body's inertials and every joint's armature perturbed.

    Kinematics, actuators and limits are untouched (the regressor's columns are the same); damping and
    frictionloss are set to 0 (friction unknown).

    Args:
        plant: the truth.
        spec: the spreads.
        rng: draws the perturbation.
        path: the path the prior's plant reports (default: `<truth stem>_prior.xml` beside the truth).
    """
    m = plant.mj_model
    spec_ = load_spec(plant.path)
    spec_.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    by_name = {b.name: b for b in spec_.bodies}
    for b in range(1, m.nbody):
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b)
        body = by_name.get(name) if name else spec_.bodies[b]
        if body is None:
            raise ModelError(f"{plant.path}: body {name!r} of the compiled model is not in its MjSpec")
        mass = float(m.body_mass[b])
        u = rng.uniform(-1.0, 1.0, size=7)
        body.explicitinertial = True
        body.fullinertia = np.full(6, np.nan)
        body.iquat = m.body_iquat[b].copy()
        if mass <= 0:
            body.mass, body.ipos, body.inertia = 0.0, m.body_ipos[b].copy(), np.zeros(3)
            continue
        body.mass = mass * (1.0 + spec.mass_rel * u[0])
        body.ipos = m.body_ipos[b] + spec.com_m * u[1:4]
        body.inertia = _principal_scaled(m.body_inertia[b].copy(), 1.0 + spec.inertia_rel * u[4:7])
    for joint in spec_.joints:
        joint.armature = float(joint.armature) * (1.0 + spec.armature_rel * rng.uniform(-1.0, 1.0))
        joint.damping = np.zeros(3)
        joint.frictionloss = 0.0
    try:
        compiled = spec_.compile()
    except ValueError as err:
        raise ModelError(f"{plant.path}: the perturbed prior does not compile: {one_line(err)}") from err
    target = path or plant.path.with_name(f"{plant.path.stem}_prior.xml")
    return plant_from_model(target, compiled)


def make_prior(model: ParameterModel, spec: PriorSpec, rng: np.random.Generator, *, simulated: bool) -> Prior:
    """The prior of `model`'s plant.

    Args:
        model: the identification model (its plant is the truth in simulation, the nominal on real data).
        spec: the prior's kind and spreads.
        rng: draws the perturbation's seed when `spec.seed` is None.
        simulated: True when `model.plant` is the simulated truth: a prior of kind "mjcf" must then name a
            different MJCF (the system's own would be the truth).

    Raises:
        ValueError: a prior that would be the truth, or a nominal MJCF whose joints differ from the plant's.
    """
    if spec.kind == "perturbed":
        seed = int(spec.seed) if spec.seed is not None else int(rng.integers(2**31))
        plant = perturbed_plant(model.plant, spec, np.random.default_rng(seed))
    else:
        seed = None
        if spec.mjcf is None:
            if simulated:
                raise ValueError(
                    "prior.kind=mjcf without prior.mjcf uses the system's MJCF, which is the simulated truth; "
                    "give prior.mjcf=<nominal.xml> or use prior.kind=perturbed"
                )
            plant = model.plant
        else:
            try:
                plant = load_plant(spec.mjcf)
            except ValueError as err:  # ModelError too: the key named, as system.mjcf's are
                raise type(err)(f"prior.mjcf: {err}") from None
            if plant.joint_names != model.plant.joint_names:
                raise ValueError(
                    f"prior.mjcf {spec.mjcf}: joints {list(plant.joint_names)} differ from the system's "
                    f"{list(model.plant.joint_names)}"
                )
    theta = ParameterModel(plant, model.effects).truth()
    if simulated and np.array_equal(theta, model.truth()):
        raise ValueError("the prior equals the simulated truth; widen the prior's spread or give another MJCF")
    return Prior(spec, plant, theta, seed)

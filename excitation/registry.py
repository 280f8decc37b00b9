"""Excitation designs chosen by name; the default and random position designs keep the clearance too (the
validation motion is a random design run on the same robot)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from dynamics.plant import Plant
from dynamics.regressor import ParameterModel
from excitation.designs import default_design, random_design
from excitation.fourier import FourierDesign
from excitation.limits import Limits
from excitation.optimise import optimise_excitation, within_clearance

__all__ = ["EXCITATIONS", "design_excitation"]


def _default(plant: Plant, limits: Limits, *, harmonics: int, base_freq_hz: float, torque_driven: bool, **_: Any):  # type: ignore[no-untyped-def]
    design = default_design(plant, limits, harmonics=harmonics, base_freq_hz=base_freq_hz, torque_driven=torque_driven)
    return design if torque_driven else within_clearance(plant, limits, design)


def _random(  # type: ignore[no-untyped-def]
    plant: Plant,
    limits: Limits,
    *,
    harmonics: int,
    base_freq_hz: float,
    torque_driven: bool,
    rng: np.random.Generator,
    **_: Any,
):
    design = random_design(
        plant, limits, harmonics=harmonics, base_freq_hz=base_freq_hz, rng=rng, torque_driven=torque_driven
    )
    return design if torque_driven else within_clearance(plant, limits, design)


def _optimised(plant: Plant, limits: Limits, **kwargs: Any) -> FourierDesign:
    return optimise_excitation(plant, limits, **kwargs).design


EXCITATIONS: dict[str, Callable[..., FourierDesign]] = {"default": _default, "optimised": _optimised, "random": _random}


def design_excitation(
    name: str,
    plant: Plant,
    limits: Limits,
    *,
    model: ParameterModel,
    harmonics: int,
    base_freq_hz: float,
    torque_driven: bool,
    rng: np.random.Generator,
    **options: Any,
) -> FourierDesign:
    """The excitation called `name` (see `EXCITATIONS`) for `plant` within `limits`.

    Args:
        model: the parameters the data must identify (a criterion conditions their regressor).
        harmonics, base_freq_hz: the Fourier family.
        torque_driven: design a drive torque (underactuated systems) instead of joint positions.
        rng: randomness (random designs, multi-start).
        options: design-specific settings from the config.

    Raises:
        ValueError: unknown name (the message lists the valid ones).
    """
    if name not in EXCITATIONS:
        raise ValueError(f"unknown excitation {name!r}; valid choices: {', '.join(sorted(EXCITATIONS))}")
    return EXCITATIONS[name](
        plant,
        limits,
        model=model,
        harmonics=harmonics,
        base_freq_hz=base_freq_hz,
        torque_driven=torque_driven,
        rng=rng,
        **options,
    )

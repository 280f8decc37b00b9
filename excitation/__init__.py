"""Excitation design: Fourier trajectories, limits, conditioning criteria and their optimisation."""

from __future__ import annotations

from excitation.criteria import CRITERIA, conditioning, criterion, design_criterion, regressor_derivatives
from excitation.designs import default_design, fit_to_limits, grid, random_design, torque_rollout
from excitation.fourier import FourierDesign
from excitation.limits import Limits, limits_for
from excitation.optimise import (
    GRADIENTS,
    OptimisedExcitation,
    assess_design,
    optimise_excitation,
    position_limit_ratios,
)
from excitation.registry import EXCITATIONS, design_excitation

__all__ = [
    "CRITERIA",
    "EXCITATIONS",
    "GRADIENTS",
    "FourierDesign",
    "Limits",
    "OptimisedExcitation",
    "assess_design",
    "conditioning",
    "criterion",
    "default_design",
    "design_criterion",
    "design_excitation",
    "fit_to_limits",
    "grid",
    "limits_for",
    "optimise_excitation",
    "position_limit_ratios",
    "random_design",
    "regressor_derivatives",
    "torque_rollout",
]

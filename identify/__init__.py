"""Identification: regressors, base parameters, derivatives, estimators and comparison with the truth."""

from __future__ import annotations

from identify.compare import (
    ParameterComparison,
    compare_with_truth,
    linear_combination,
    predict_torque,
    torque_rms,
)
from identify.derivatives import DERIVATIVES, States, derive_states, excitation_bandwidth_hz
from identify.derived import DERIVED, first_moment_along, inertia_about_joint_axis
from identify.estimators import ESTIMATORS, estimate
from identify.excitation_check import ExcitationCheck, check_excitation
from identify.problem import Estimate, Problem, build_problem

__all__ = [
    "DERIVATIVES",
    "DERIVED",
    "ESTIMATORS",
    "Estimate",
    "ExcitationCheck",
    "ParameterComparison",
    "Problem",
    "States",
    "build_problem",
    "check_excitation",
    "compare_with_truth",
    "derive_states",
    "estimate",
    "excitation_bandwidth_hz",
    "first_moment_along",
    "inertia_about_joint_axis",
    "linear_combination",
    "predict_torque",
    "torque_rms",
]

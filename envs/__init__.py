"""Plants from MJCF, sensors, simulation and datasets (measured or simulated)."""

from __future__ import annotations

from envs.dataset import Dataset, write_csv
from envs.effects import HIDDEN_EFFECTS, MJCF_EFFECTS, SENSOR_EFFECTS, HiddenEffect, apply_effects
from envs.errors import (
    DataError,
    InfeasibleExcitationError,
    ModelError,
    RankDeficientError,
    SysIdError,
)
from envs.excitation_check import ExcitationCheck, check_excitation
from envs.measured import Repair, read_many, read_measured
from envs.plant import MJCF_DIR, SYSTEMS, Plant, load_plant, mjcf_path
from envs.sensors import SensorModel, quantise
from envs.simulate import Reference, inverse_dynamics, simulate_open_loop, simulate_tracking
from envs.split import Split, split_train_validation

__all__ = [
    "HIDDEN_EFFECTS",
    "MJCF_DIR",
    "MJCF_EFFECTS",
    "SENSOR_EFFECTS",
    "SYSTEMS",
    "DataError",
    "Dataset",
    "ExcitationCheck",
    "HiddenEffect",
    "InfeasibleExcitationError",
    "ModelError",
    "Plant",
    "RankDeficientError",
    "Reference",
    "Repair",
    "SensorModel",
    "Split",
    "SysIdError",
    "apply_effects",
    "check_excitation",
    "inverse_dynamics",
    "load_plant",
    "mjcf_path",
    "quantise",
    "read_many",
    "read_measured",
    "simulate_open_loop",
    "simulate_tracking",
    "split_train_validation",
    "write_csv",
]

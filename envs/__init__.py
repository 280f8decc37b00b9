"""Simulation, sensors, hidden effects and data I/O (measured or simulated datasets)."""

from __future__ import annotations

from envs.dataset import Dataset, write_csv
from envs.effects import HIDDEN_EFFECTS, MJCF_EFFECTS, SENSOR_EFFECTS, HiddenEffect, apply_effects
from envs.measured import Repair, read_many, read_measured
from envs.sensors import SensorModel, quantise
from envs.simulate import Reference, simulate_open_loop, simulate_tracking
from envs.split import Split, split_train_validation

__all__ = [
    "HIDDEN_EFFECTS",
    "MJCF_EFFECTS",
    "SENSOR_EFFECTS",
    "Dataset",
    "HiddenEffect",
    "Reference",
    "Repair",
    "SensorModel",
    "Split",
    "apply_effects",
    "quantise",
    "read_many",
    "read_measured",
    "simulate_open_loop",
    "simulate_tracking",
    "split_train_validation",
    "write_csv",
]

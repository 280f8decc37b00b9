"""Model discrepancy: what the nominal MJCF gets wrong on measured data, the named cause, the calibrated
model and the gain on held-out data (DESIGN.md question 4)."""

from __future__ import annotations

from dynamics.torque import joint_torque
from identify.diagnose.anomalies import Anomaly, find_anomalies
from identify.diagnose.authors import author_accel, author_torque, load_author_model
from identify.diagnose.calibrate import Extension, calibrated_xml, frictionloss_mapping, predict_measured_torque
from identify.diagnose.candidates import CANDIDATE_EFFECTS, Candidate, Signals, candidates
from identify.diagnose.diagnosis import DEFAULT_EFFECTS, Diagnosis, Finding, ReferenceModel, diagnose, with_found_lead
from identify.diagnose.residuals import analyse_residual, noise_floor, whiteness
from identify.diagnose.select import SelectionOptions, select_effects
from identify.diagnose.simulation_error import SimulationError, simulation_error

__all__ = [
    "CANDIDATE_EFFECTS",
    "DEFAULT_EFFECTS",
    "Anomaly",
    "Candidate",
    "Diagnosis",
    "Extension",
    "Finding",
    "ReferenceModel",
    "SelectionOptions",
    "Signals",
    "SimulationError",
    "analyse_residual",
    "author_accel",
    "author_torque",
    "calibrated_xml",
    "candidates",
    "diagnose",
    "find_anomalies",
    "frictionloss_mapping",
    "joint_torque",
    "load_author_model",
    "noise_floor",
    "predict_measured_torque",
    "select_effects",
    "simulation_error",
    "whiteness",
    "with_found_lead",
]

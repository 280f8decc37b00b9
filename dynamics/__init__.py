"""The model layer: the robot exactly as MuJoCo compiles it, its Pinocchio twin, regressor, torque and inertia.

`excitation/` and `identify/` build on this package; it imports neither of them.
"""

from __future__ import annotations

from dynamics.base import BaseParameters, base_parameters
from dynamics.errors import (
    DataError,
    InfeasibleExcitationError,
    ModelError,
    RankDeficientError,
    SysIdError,
)
from dynamics.inertia import (
    body_from_log_cholesky,
    from_mass_com_inertia,
    from_pseudo_inertia,
    is_consistent,
    log_cholesky_from_body,
    mass_com_inertia,
    pseudo_inertia,
    repair_body,
    transform_parameters,
)
from dynamics.mjcf import write_inertial
from dynamics.plant import (
    INERTIAL_SYMBOLS,
    MJCF_DIR,
    SYSTEMS,
    Plant,
    body_parameters,
    check_against_mujoco,
    load_plant,
    mjcf_path,
    own_body_parameters,
    plant_from_model,
    plant_from_xml,
)
from dynamics.regressor import EFFECT_COLUMNS, ParameterModel, rigid_body_regressor
from dynamics.sampling import independent_columns, random_states
from dynamics.torque import inverse_dynamics, joint_torque, torque_jacobian_q

__all__ = [
    "EFFECT_COLUMNS",
    "INERTIAL_SYMBOLS",
    "MJCF_DIR",
    "SYSTEMS",
    "BaseParameters",
    "DataError",
    "InfeasibleExcitationError",
    "ModelError",
    "ParameterModel",
    "Plant",
    "RankDeficientError",
    "SysIdError",
    "base_parameters",
    "body_from_log_cholesky",
    "body_parameters",
    "check_against_mujoco",
    "from_mass_com_inertia",
    "from_pseudo_inertia",
    "independent_columns",
    "inverse_dynamics",
    "is_consistent",
    "joint_torque",
    "load_plant",
    "log_cholesky_from_body",
    "mass_com_inertia",
    "mjcf_path",
    "own_body_parameters",
    "plant_from_model",
    "plant_from_xml",
    "pseudo_inertia",
    "random_states",
    "repair_body",
    "rigid_body_regressor",
    "torque_jacobian_q",
    "transform_parameters",
    "write_inertial",
]

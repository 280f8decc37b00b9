"""The calibrated MJCF is the user's MJCF edited through MjSpec: it loads, is physically valid and can be the
nominal of another diagnosis, whatever inertial form the user wrote (geoms, `diaginertia` + `quat`)."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from dynamics.base import base_parameters
from dynamics.inertia import is_consistent
from dynamics.plant import Plant, load_plant, own_body_parameters, plant_from_xml
from dynamics.regressor import ParameterModel
from envs.effects import HiddenEffect, apply_effects
from envs.sensors import SensorModel
from envs.simulate import simulate_tracking
from excitation.designs import default_design, random_design
from excitation.limits import limits_for
from identify.diagnose import diagnose
from identify.diagnose.calibrate import Extension, calibrated_xml

_TWO_LINK = """<mujoco model="{name}">
  <compiler angle="radian"/>
  <option timestep="0.001"/>
  <worldbody>
    <body name="upper" pos="0 0 1">
      <joint name="shoulder" type="hinge" axis="0 1 0" range="-3 3" armature="0.002"/>
      {inertial1}
      <geom type="capsule" fromto="0 0 0 0 0 -0.2" size="0.02" density="1500"/>
      <body name="lower" pos="0 0 -0.2">
        <joint name="elbow" type="hinge" axis="0 1 0" range="-3 3" armature="0.002"/>
        {inertial2}
        <geom type="capsule" fromto="0 0 0 0 0 -0.25" size="0.015" density="1500"/>
        <geom type="sphere" pos="0 0 -0.25" size="0.03" density="3000"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="shoulder" ctrlrange="-8 8"/>
    <motor joint="elbow" ctrlrange="-8 8"/>
  </actuator>
</mujoco>
"""

FORMS = {
    "geom_inertia": {"inertial1": "", "inertial2": ""},
    "diaginertia_quat": {
        "inertial1": '<inertial pos="0 0.01 -0.1" quat="0.96 0.1 0.2 0.15" mass="0.5" '
        'diaginertia="0.003 0.0028 4e-4"/>',
        "inertial2": '<inertial pos="0 0 -0.2" quat="0.9 0 0.3 0.3" mass="0.4" diaginertia="0.0025 0.0024 2e-4"/>',
    },
}

_SENSOR = SensorModel(
    500.0, sigma_q=1.7e-5, q_resolution=2.4e-5, sigma_tau=np.array([0.02, 0.02]), tau_resolution=0.006
)


def _plant(form: str, tmp_path: Path) -> Plant:
    path = tmp_path / f"{form}.xml"
    path.write_text(_TWO_LINK.format(name=form, **FORMS[form]))
    return load_plant(path)


def _data(nominal: Plant, hidden: Plant, sensor: SensorModel, seed: int):  # type: ignore[no-untyped-def]
    limits = limits_for(nominal, velocity=6.0, acceleration=40.0, range_margin=0.05, torque_margin=0.9)
    rng_train, rng_val, rng_design = np.random.default_rng(seed).spawn(3)
    train_design = default_design(nominal, limits, harmonics=5, base_freq_hz=0.2, torque_driven=False)
    val_design = random_design(nominal, limits, harmonics=5, base_freq_hz=0.2, rng=rng_design, torque_driven=False)
    train = simulate_tracking(hidden, train_design, duration_s=10.0, sensor=sensor, rng=rng_train, nominal=nominal)
    val = simulate_tracking(hidden, val_design, duration_s=5.0, sensor=sensor, rng=rng_val, nominal=nominal)
    return train, val


def _diagnose(nominal: Plant, train, val):  # type: ignore[no-untyped-def]
    return diagnose(nominal, [train], [val], rng=np.random.default_rng(0), derivative_options={"cutoff_hz": 10.0})


@pytest.mark.parametrize("form", sorted(FORMS))
def test_diagnose_calibrate_and_diagnose_again(form: str, tmp_path: Path) -> None:
    nominal = _plant(form, tmp_path)
    assert nominal.theta[0] > 0.1 and nominal.theta[10] > 0.1  # geom inertia is read, not massless
    truth = HiddenEffect("payload", "lower", 0.15, position=(0.0, 0.0, -0.25))
    hidden, sensor = apply_effects(nominal, [truth], sensor=_SENSOR, directory=tmp_path / "hidden")
    assert hidden.mj_model.body_mass[2] == pytest.approx(nominal.mj_model.body_mass[2] + 0.15)
    train, val = _data(nominal, hidden, sensor, seed=3)

    first = _diagnose(nominal, train, val)
    before = first.models["nominal"]["torque_rms"]
    after = first.models["calibrated"]["torque_rms"]
    assert after["elbow"] < 0.5 * before["elbow"], (before, after)

    calibrated = plant_from_xml(first.calibrated_xml, f"{form}_calibrated", tmp_path / "calibrated")
    # loads (the load check passed) and every body is physically consistent
    own = own_body_parameters(calibrated)
    assert all(is_consistent(own[10 * j : 10 * j + 10]) for j in range(calibrated.nv))

    second = _diagnose(calibrated, train, val)
    again = second.models["nominal"]["torque_rms"]
    for joint in again:  # the calibrated model, as a nominal, predicts as well as it did as the calibration
        assert again[joint] <= 1.05 * after[joint] + 1e-4, (again, after)
    assert second.verdict == "no_discrepancy", [f.to_dict() for f in second.findings]
    # and its own calibrated MJCF loads again: the chain can go on
    plant_from_xml(second.calibrated_xml, f"{form}_calibrated2", tmp_path / "calibrated2")


@pytest.mark.parametrize("seed", range(3))
def test_a_rigid_body_refit_of_arm3_writes_a_valid_inertia(seed: int, tmp_path: Path) -> None:
    """A refit changes only base parameters; whatever the unobserved directions, the written inertials are valid."""
    plant = load_plant("arm3")
    model = ParameterModel(plant)
    base = base_parameters(model, np.random.default_rng(0))
    rng = np.random.default_rng(seed)
    # a base-parameter change of 30 % with the rest of theta left as the least-norm solution (what a refit does)
    beta = base.project(plant.theta)
    delta_beta = 0.3 * beta * rng.normal(size=beta.shape)
    theta_delta = np.linalg.lstsq(base.K, delta_beta, rcond=None)[0]
    ext = Extension.none(plant)
    ext.theta_delta[:] = theta_delta
    xml = calibrated_xml(plant, ext)
    spec = mujoco.MjSpec.from_string(xml)
    spec.compiler.balanceinertia = False  # no compiler repair: the written values themselves must be valid
    spec.compile()
    refit = plant_from_xml(xml, f"arm3_refit_{seed}", tmp_path)
    m = refit.mj_model
    for b in range(1, m.nbody):  # as MuJoCo compiled them: positive, and A + B >= C
        moments = np.sort(m.body_inertia[b])
        assert m.body_mass[b] > 0 and moments[0] > 0 and moments[0] + moments[1] >= moments[2]
    assert "fullinertia" not in xml  # one consistent form: diaginertia + quat

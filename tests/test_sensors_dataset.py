"""Sensor model and dataset: noise, quantisation, delay, saturation, CSV round trip and validation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dynamics.errors import DataError
from dynamics.plant import load_plant
from envs.dataset import Dataset, write_csv
from envs.sensors import SensorModel, quantise
from envs.simulate import simulate_open_loop


def test_quantisation_and_noise_statistics() -> None:
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, size=(20000, 2))
    q = quantise(x, 0.01)
    np.testing.assert_allclose(q / 0.01, np.round(q / 0.01), atol=1e-9)
    assert np.std(q - x) == pytest.approx(0.01 / np.sqrt(12), rel=0.05)
    sensor = SensorModel(sigma_q=1e-3, sigma_tau=np.array([0.0, 0.05]))
    assert np.std(sensor.measure_q(x, rng) - x) == pytest.approx(1e-3, rel=0.05)
    tau = sensor.measure_tau(x, np.array([False, True]), rng)
    assert np.all(tau[:, 0] == 0)  # unactuated: known to be zero
    assert np.std(tau[:, 1] - x[:, 1]) == pytest.approx(0.05, rel=0.05)


def test_measured_torque_is_the_applied_torque_delayed_and_saturated() -> None:
    plant = load_plant("pendulum")
    step = 0.05
    sensor = SensorModel(sample_rate_hz=500, delay_s=step)

    def torque(t: np.ndarray) -> np.ndarray:
        return np.where(t >= 0.5, 5.0, 0.0)[:, None]  # beyond the 2.5 N m actuator limit

    data = simulate_open_loop(plant, torque, duration_s=1.0, sensor=sensor, rng=np.random.default_rng(0))
    applied = data.meta["tau_applied"][:, 0]
    assert applied.max() == pytest.approx(2.5)  # saturated by ctrlrange
    assert data.meta["saturated_fraction"][0] == pytest.approx(0.5, abs=0.01)
    first = np.flatnonzero(data.tau[:, 0] > 1e-9)[0]  # before: round-off of the Coriolis step correction
    assert data.time[first] == pytest.approx(0.5 + step, abs=1e-9)


def test_csv_round_trip_and_atomic_replace(tmp_path: Path) -> None:
    plant = load_plant("wheel_pendulum")
    data = simulate_open_loop(
        plant,
        lambda t: np.column_stack([0 * t, 0.1 * np.sin(t)]),
        duration_s=0.2,
        sensor=SensorModel(),
        rng=np.random.default_rng(0),
    )
    path = tmp_path / "data.csv"
    write_csv(data, path)
    table = np.genfromtxt(path, delimiter=",", names=True)
    assert table.dtype.names == (
        "time",
        "q_pendulum",
        "q_wheel",
        "tau_wheel",
        "tau_cmd_wheel",
        "ddq_pendulum",
        "ddq_wheel",
    )
    np.testing.assert_allclose(table["q_wheel"], data.q[:, 1], rtol=1e-9, atol=1e-12)
    assert not list(tmp_path.glob(".*"))


@pytest.mark.parametrize(
    ("time", "message"),
    [(np.array([0.0, 0.1, 0.1]), "not strictly increasing at row 2"), (np.array([0.0]), "at least|>= 2")],
)
def test_dataset_refuses_bad_time(time: np.ndarray, message: str) -> None:
    n = len(time)
    with pytest.raises(DataError, match=message):
        Dataset(time=time, q=np.zeros((n, 1)), tau=np.zeros((n, 1)), joint_names=("j",), actuated=np.ones(1, bool))


def test_dataset_names_the_bad_shape() -> None:
    with pytest.raises(DataError, match=r"tau has shape \(3, 2\), expected \(3, 1\)"):
        Dataset(
            time=np.arange(3.0), q=np.zeros((3, 1)), tau=np.zeros((3, 2)), joint_names=("j",), actuated=np.ones(1, bool)
        )


def test_a_simulation_that_mujoco_resets_is_refused_naming_the_joint(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """MuJoCo resets a diverging state to qpos0 and goes on, so every value stays finite and the record would be
    silently wrong: a joint spring that RK4 cannot hold at the step (1e4 N m/rad on 1e-4 kg m^2, 2 ms) is refused,
    naming the time, the dof and its joint."""
    from dynamics.errors import ModelError

    monkeypatch.chdir(tmp_path)  # MuJoCo writes its warning to MUJOCO_LOG.TXT in the working directory
    xml = tmp_path / "stiff.xml"
    xml.write_text(
        '<mujoco><option integrator="RK4" timestep="0.002" gravity="0 0 0"/><worldbody><body name="b">'
        '<joint name="spin" type="hinge" axis="0 0 1" stiffness="1e4"/>'
        '<inertial pos="0 0 0" mass="0.1" diaginertia="1e-4 1e-4 1e-4"/></body></worldbody>'
        '<actuator><motor name="m" joint="spin" ctrlrange="-1 1"/></actuator></mujoco>'
    )
    plant = load_plant(xml)

    def torque(t: np.ndarray) -> np.ndarray:
        return np.sin(10 * t)[:, None]

    with pytest.raises(ModelError, match=r"stiff: simulation diverged at t = .* dof 0 \(spin\) and reset the state"):
        simulate_open_loop(plant, torque, duration_s=1.0, sensor=SensorModel(500.0), rng=np.random.default_rng(0))

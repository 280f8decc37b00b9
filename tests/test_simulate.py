"""The simulator: the physics step it chooses for stiff servos, the clamped-servo fallback, the servo setpoints
evaluated a chunk at a time, and the saturation it reports (the ctrl and force clamp, never the integrator's
implicit-damping correction)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
from scipy import signal

import envs.simulate as simulate
from dynamics.plant import Plant, load_plant, plant_from_xml
from dynamics.torque import inverse_dynamics
from envs.sensors import SensorModel
from envs.simulate import simulate_open_loop, simulate_tracking
from identify.derivatives import derive_states

ROBOTS = Path(__file__).resolve().parents[2] / "shared" / "robots"
needs_robots = pytest.mark.skipif(not ROBOTS.is_dir(), reason="../shared/robots/ is not beside the project")

# a 0.21 kg m^2 upper arm swinging in gravity and a 1e-4 kg m^2 wrist rolling about the link: the wrist's servo
# (kp 800, kv 80, as the xarm7's) has kv / M = 8e5 1/s and a spring sqrt(kp / M) of 2828 1/s
_ARM = """<mujoco model="{name}"><option integrator="{integrator}" timestep="0.002">{flag}</option>
  <worldbody><body name="upper"><joint name="j0" axis="0 1 0" damping="{d0}"/>
    <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.03" mass="1"/>
    <body name="wrist" pos="0 0 -0.3"><joint name="j1" axis="0 0 1" damping="{d1}"/>
      <geom type="cylinder" size="0.01 0.02" mass="2"/></body></body></worldbody>
  <actuator>{actuators}</actuator></mujoco>"""
_SERVOS = (
    '<position joint="j0" kp="200" kv="20" forcerange="-{f0} {f0}"/>'
    '<position joint="j1" kp="800" kv="80" forcerange="-20 20"/>'
)
# position servos without a damper of their own: under RK4 the held setpoint made their force a sawtooth in each
# step, kp gear^2 dq h / 2 below the law at the step's start on average
_STIFF_SERVOS = '<position joint="j0" kp="200" forcerange="-50 50"/><position joint="j1" kp="800" forcerange="-20 20"/>'
_MOTORS = '<motor joint="j0" ctrlrange="-5 5"/><motor joint="j1" ctrlrange="-1 1"/>'


def _arm(
    tmp_path: Path,
    *,
    integrator: str = "implicitfast",
    actuators: str = _SERVOS.format(f0=50),
    d0: float = 0.0,
    d1: float = 0.0,
    eulerdamp: bool = True,
) -> Plant:
    flag = "" if eulerdamp else '<flag eulerdamp="disable"/>'
    xml = _ARM.format(name="arm", integrator=integrator, flag=flag, d0=d0, d1=d1, actuators=actuators)
    return plant_from_xml(xml, "arm", tmp_path)


class _Waves:
    """q = q0 + a (1 - cos w t) (zero speed at t = 0) or q0 + a sin w t, per joint; records its calls' sizes."""

    def __init__(self, q0: np.ndarray, amplitude: np.ndarray, *, freq_hz: float = 0.5, sine: bool = False) -> None:
        self.q0, self.a, self.w, self.sine = q0, amplitude, 2 * np.pi * freq_hz, sine
        self.calls: list[int] = []

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        self.calls.append(len(t))
        wt = self.w * t[:, None]
        if self.sine:
            return self.q0 + self.a * np.sin(wt), self.a * self.w * np.cos(wt), -self.a * self.w**2 * np.sin(wt)
        return self.q0 + self.a * (1 - np.cos(wt)), self.a * self.w * np.sin(wt), self.a * self.w**2 * np.cos(wt)


def _track(plant: Plant, reference: _Waves, duration_s: float = 0.4, **kwargs):  # type: ignore[no-untyped-def]
    return simulate_tracking(
        plant,
        reference,
        duration_s=duration_s,
        sensor=SensorModel(sample_rate_hz=500),
        rng=np.random.default_rng(0),
        **kwargs,
    )


def _substeps(plant: Plant, regulated: np.ndarray | None = None) -> int:
    m = simulate._servo_resolved(plant, np.zeros(plant.nv), regulated)
    return round(plant.mj_model.opt.timestep / m.opt.timestep)


def _wrist_inertia(plant: Plant) -> float:
    m, d = plant.mj_model, mujoco.MjData(plant.mj_model)
    mujoco.mj_forward(m, d)
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    return float(full[1, 1])


@pytest.mark.parametrize(
    ("integrator", "eulerdamp", "explicit_damping"),
    [
        ("implicitfast", True, 0.0),  # kv and d implicit: only the spring sqrt(kp / M) is resolved
        ("implicit", True, 0.0),
        ("Euler", True, 80.0),  # Euler takes the joint damping implicitly, not the actuator's kv
        ("Euler", False, 85.0),
        ("RK4", True, 85.0),
    ],
)
def test_the_physics_step_resolves_only_what_the_integrator_takes_explicitly(
    tmp_path: Path, integrator: str, eulerdamp: bool, explicit_damping: float
) -> None:
    plant = _arm(tmp_path, integrator=integrator, d1=5.0, eulerdamp=eulerdamp)
    inertia, h = _wrist_inertia(plant), plant.mj_model.opt.timestep
    rate = max(math.sqrt(800.0 / inertia), explicit_damping / inertia)
    assert _substeps(plant) == math.ceil(rate * h / simulate._MAX_RATE_STEP)
    if explicit_damping == 0:
        assert _substeps(plant) == 12  # not the 3400 that (kv + d) / M would ask for


@needs_robots
@pytest.mark.parametrize(("arm", "substeps"), [("xarm7_nohand", 10), ("iiwa14", 6), ("panda_nohand", 1), ("ur5e", 1)])
def test_menagerie_servo_arms_get_a_step_for_their_springs_not_their_implicit_dampers(arm: str, substeps: int) -> None:
    """The xarm7 took 2347 physics steps per 2 ms sample (4.7 M mj_step calls and 3.8 GB for a short run)."""
    assert _substeps(load_plant(ROBOTS / f"{arm}.xml")) == substeps


def test_a_clamped_servo_is_simulated_at_the_step_that_resolves_its_damper(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A position servo given the bare reference (no feedforward) pulls towards zero speed: started at 0.94 rad/s,
    the wrist's -kv dq exceeds its 20 N m range, and while clamped its damper is explicit (MuJoCo drops a clamped
    actuator's velocity derivative). At the spring's step (1/6 ms, kv h / M = 133) it ran away, clamped for good
    at 6.25 rad/s (the xarm7's wrist in a harness run: 5.7 rad/s and a torque RMS of 167 N m on held-out data)."""
    plant = _arm(tmp_path, d1=2.0)
    reference = _Waves(np.zeros(2), np.array([0.0, 0.3]), sine=True)
    data = _track(plant, reference, duration_s=0.1, servo_feedforward=False)
    assert np.abs(data.meta["dq_true"][:, 1]).max() < 1.0  # the reference's largest speed is 0.94 rad/s
    assert data.meta["refined_samples"][:1] == [0] and len(data.meta["refined_samples"]) <= 3
    assert np.all(np.abs(data.meta["tau_applied"]) <= plant.tau_limit * (1 + 1e-9))  # no kv term beyond it
    assert data.meta["saturated_fraction"][1] <= 0.05

    resolved = simulate._servo_resolved

    def everywhere(plant: Plant, q0: np.ndarray, regulated: np.ndarray | None = None) -> mujoco.MjModel:
        fine = simulate._Clamp.of(plant, q0, resolved(plant, q0, regulated), regulated)  # the finer step throughout
        assert fine is not None
        return fine.model

    monkeypatch.setattr(simulate, "_servo_resolved", everywhere)
    truth = _track(plant, reference, duration_s=0.1, servo_feedforward=False)
    assert truth.meta["refined_samples"] == []
    np.testing.assert_allclose(data.meta["q_true"], truth.meta["q_true"], atol=2e-4)


def test_servo_setpoints_are_evaluated_a_chunk_at_a_time(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    plant = _arm(tmp_path)
    whole = _Waves(np.zeros(2), np.array([0.2, 0.3]))
    expected = _track(plant, whole)
    assert max(whole.calls[1:]) == len(expected.time) * 12  # one call for every physics step of the run
    monkeypatch.setattr(simulate, "_SETPOINTS_PER_CALL", 30)
    chunked = _Waves(np.zeros(2), np.array([0.2, 0.3]))
    data = _track(plant, chunked)
    assert chunked.calls[0] == len(data.time) and max(chunked.calls[1:]) <= 30  # the first: the sample times
    np.testing.assert_array_equal(data.meta["q_true"], expected.meta["q_true"])
    np.testing.assert_array_equal(data.meta["tau_applied"], expected.meta["tau_applied"])


def test_an_implicit_servo_arm_inside_its_ranges_is_never_saturated(tmp_path: Path) -> None:
    """Implicitfast with kv and joint damping: the reported torque differs from the clamped command by the
    implicit-damping correction at every sample, which counted as saturation (a fraction of 1.0)."""
    plant = _arm(tmp_path, d0=1.0, d1=0.5)
    data = _track(plant, _Waves(np.zeros(2), np.array([0.2, 0.3])))
    assert np.abs(data.meta["tau_applied"] - data.tau_cmd).max() > 1e-6  # the correction is there
    assert data.meta["saturated_fraction"] == [0.0, 0.0]


def test_a_servo_beyond_its_force_range_is_saturated_part_of_the_time(tmp_path: Path) -> None:
    plant = _arm(tmp_path, actuators=_SERVOS.format(f0=2))  # gravity needs up to 2.9 N m on j0
    data = _track(plant, _Waves(np.zeros(2), np.array([0.2, 0.3])), duration_s=1.0)
    fraction = data.meta["saturated_fraction"]
    assert 0.05 < fraction[0] < 0.95 and fraction[1] == 0.0
    clamped = np.abs(data.tau_cmd[:, 0]) > 2.0  # a clamped servo's kv is no implicit term there: nothing added
    np.testing.assert_allclose(np.abs(data.meta["tau_applied"][clamped, 0]), 2.0, rtol=1e-12)


@pytest.mark.parametrize("over", [False, True])
def test_joint_damping_under_euler_is_no_saturation(tmp_path: Path, over: bool) -> None:
    """Euler takes joint damping implicitly: with damping on j0 its fraction read 1.0 without any clamp."""
    plant = _arm(tmp_path, integrator="Euler", actuators=_MOTORS, d0=2.0)

    def torque(t: np.ndarray) -> np.ndarray:
        return np.column_stack([(8.0 if over else 2.0) * np.sin(2 * np.pi * t), 0.5 * np.sin(3 * t)])

    data = simulate_open_loop(
        plant, torque, duration_s=1.0, sensor=SensorModel(sample_rate_hz=500), rng=np.random.default_rng(0)
    )
    fraction = data.meta["saturated_fraction"]
    assert fraction[1] == 0.0
    if over:  # |8 sin| > 5 for 57 % of the time
        assert fraction[0] == pytest.approx(1 - 2 * np.arcsin(5 / 8) / np.pi, abs=0.01)
    else:
        assert fraction[0] == 0.0


@needs_robots
def test_a_menagerie_arm_tracking_inside_its_ranges_is_never_saturated() -> None:
    """The Panda (implicitfast, kv 200-450, joint damping 1) reported [1.0] * 7 at a torque ratio of 0.3."""
    plant = load_plant(ROBOTS / "panda_nohand.xml")
    home = np.array([0.0, 0.0, 0.0, -1.57, 0.0, 1.57, -0.785])
    data = _track(plant, _Waves(home, np.full(7, 0.1)), duration_s=0.5)
    assert np.abs(data.tau_cmd).max(axis=0).max() > 1.0  # it does hold the arm up
    assert data.meta["saturated_fraction"] == [0.0] * 7


_TWO_LINK = Path(__file__).resolve().parents[1] / "mjcf" / "two_link.xml"


def test_the_tracking_loop_is_stable_at_a_coarse_sample_rate(tmp_path: Path) -> None:
    """The two-link arm at a 5 ms step, sampled (and controlled) at 200 Hz: PD gains from the mass matrix's
    diagonal fell into a limit cycle at the Nyquist rate once the arm stretched out; gains shaped by the whole
    matrix track it."""
    xml = _TWO_LINK.read_text().replace('timestep="0.0005"', 'timestep="0.005"')
    plant = plant_from_xml(xml, "coarse", tmp_path)
    reference = _Waves(np.zeros(2), np.array([0.6, 0.9]), freq_hz=0.1, sine=True)
    data = simulate_tracking(
        plant, reference, duration_s=12.0, sensor=SensorModel(sample_rate_hz=200), rng=np.random.default_rng(0)
    )
    q_ref, _, ddq_ref = reference.evaluate(data.time)
    assert np.abs(data.meta["q_true"] - q_ref).max() < 0.01  # diagonal gains: 0.089 rad
    assert np.abs(data.ddq).max() < 3.0 * np.abs(ddq_ref).max()  # diagonal gains: 1878 against 0.36 rad/s^2


def test_contacts_are_reported_by_geom_pair(tmp_path: Path) -> None:
    """A link swinging into a world-fixed block (tracked here without a design that keeps clear of it): the pair
    is named with its bodies, with the samples it pressed in and when it first did."""
    xml = """<mujoco model="bump"><option timestep="0.002"/><worldbody>
      <geom name="block" type="box" pos="0.25 0 -0.25" size="0.05 0.05 0.05"/>
      <body name="arm"><joint name="j0" axis="0 1 0"/>
        <geom name="rod" type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02" mass="1"/></body></worldbody>
      <actuator><motor joint="j0" ctrlrange="-20 20"/></actuator></mujoco>"""
    plant = plant_from_xml(xml, "bump", tmp_path)
    data = _track(plant, _Waves(np.zeros(1), np.array([-0.6])), duration_s=1.0)
    contacts = data.meta["contacts"]
    assert [c["geoms"] for c in contacts] == [["block (world)", "rod (arm)"]]
    assert 0 < contacts[0]["samples"] < data.n_samples and contacts[0]["first_t_s"] > 0.1
    free = _track(plant, _Waves(np.zeros(1), np.array([0.6])), duration_s=1.0)  # it swings the other way
    assert free.meta["contacts"] == []


def _filtered_mismatch(plant: Plant, data) -> np.ndarray:  # type: ignore[no-untyped-def]
    """(nv,) RMS of inverse dynamics on Butterworth states of the noise-free positions minus the torque through
    the same zero-phase filter: what a perfect model leaves on these data, in the harness's own states."""
    clean = dataclasses.replace(data, q=data.meta["q_true"], tau=data.meta["tau_applied"])
    states = derive_states(clean, "butterworth", cutoff_hz=10.0)
    sos = signal.butter(4, 10.0, fs=1.0 / data.dt, output="sos")
    # derive_states moves the states to the torque's instant (`tau_lead_s`); the torque stays
    tau = signal.sosfiltfilt(sos, data.meta["tau_applied"], axis=0)
    rows = np.flatnonzero(states.valid)[100:-100]  # and 0.2 s more at each end, clear of the filters' edges
    error = inverse_dynamics(plant, states.q[rows], states.dq[rows], states.ddq[rows]) - tau[rows]
    return np.sqrt(np.mean(error**2, axis=0))


@pytest.mark.parametrize(
    ("integrator", "eulerdamp", "actuators"),
    [
        ("implicitfast", True, _SERVOS.format(f0=50)),
        ("implicit", True, _SERVOS.format(f0=50)),
        # Euler takes the servo's kv explicitly: kv 80 on the light wrist took 3200 physics steps per sample (a
        # minute); kv 8 keeps the explicit damper at a tenth of the steps
        ("Euler", True, _SERVOS.format(f0=50).replace('kv="80"', 'kv="8"')),
        ("Euler", False, _MOTORS),
        ("RK4", True, _MOTORS),
        ("RK4", True, _STIFF_SERVOS),  # (RK4 with _SERVOS, 0.0058 before, takes a minute: kv 80 is explicit there)
        ("implicitfast", True, _MOTORS),
    ],
)
def test_the_data_are_those_of_the_continuous_robot_at_the_sampled_positions(
    tmp_path: Path, integrator: str, eulerdamp: bool, actuators: str
) -> None:
    """MuJoCo's semi-implicit step moves the positions by the step's end velocity: a zero-phase derivative of
    the sampled positions gives the step's mean velocity, while the step's dampers act at its end (or start)
    and its Coriolis torque at its start. The torque was consistent with the start velocity only, and the
    Panda's d = 1 dampers at h = 2 ms came out as -0.001 kg m^2 of armature on every joint (its wrist
    armatures at z = -3 over seeds). Now inverse dynamics holds to round-off on the exact states and, on the
    filtered positions, what is left is the filter's (the ur5e's shoulder under its servos: 4.4e-3 -> 2.6e-5 N m).
    Under RK4 a servo's setpoint held over the step made its force a sawtooth there: 0.58 of the stiff wrist's
    torque RMS was left, and `sysid-run` gave a position servo's viscous friction at z 600; the setpoint is now
    the target at the step's middle."""
    plant = _arm(tmp_path, integrator=integrator, actuators=actuators, d0=1.0, d1=0.05, eulerdamp=eulerdamp)
    if actuators == _MOTORS:

        def torque(t: np.ndarray) -> np.ndarray:
            return np.column_stack([2.0 * np.sin(2 * np.pi * 0.7 * t) + 1.0, 0.02 * np.sin(2 * np.pi * 1.1 * t)])

        data = simulate_open_loop(
            plant, torque, duration_s=3.0, sensor=SensorModel(sample_rate_hz=500), rng=np.random.default_rng(0)
        )
    else:
        data = _track(plant, _Waves(np.zeros(2), np.array([0.6, 0.8]), freq_hz=0.7, sine=True), duration_s=3.0)
    exact = inverse_dynamics(plant, data.meta["q_true"], data.meta["dq_true"], data.ddq) - data.meta["tau_applied"]
    scale = np.sqrt(np.mean(data.meta["tau_applied"] ** 2, axis=0))
    assert np.abs(exact).max() < 1e-9
    scale = np.sqrt(np.mean(data.meta["tau_applied"] ** 2, axis=0))
    # what is left is the filter's own (a zero-phase low-pass of a nonlinear torque): 3e-4 of the torque RMS
    # on j0 under every integrator. Before: 3.7e-4 on the implicit servos' wrist, 1.5e-3 to 6.9e-3 with motors
    relative = _filtered_mismatch(plant, data) / scale
    assert np.all(relative < 1.2e-3), relative
    if integrator.startswith("implicit"):
        assert relative[1] < 1e-4, relative


@needs_robots
def test_a_menagerie_arms_data_hold_its_inverse_dynamics_on_filtered_positions() -> None:
    """The Panda at h = 2 ms with d = 1 dampers and kv 200-450 servos: inverse dynamics on Butterworth states of
    the noise-free positions left 2.9e-3 to 6.2e-3 N m RMS on every joint over 4 s of these waves (a -d h / 2
    armature, half-step-old Coriolis torque); now 4e-6 to 4e-5 N m, the filter's own share."""
    plant = load_plant(ROBOTS / "panda_nohand.xml")
    home = np.array([0.0, 0.0, 0.0, -1.57, 0.0, 1.57, -0.785])
    data = _track(plant, _Waves(home, np.full(7, 0.3), freq_hz=0.4), duration_s=3.0)
    left = _filtered_mismatch(plant, data)
    assert np.all(left < 2e-4), left


@pytest.mark.parametrize("integrator", ["Euler", "implicitfast", "RK4"])
@pytest.mark.parametrize("kind", ["general", "servo"])
def test_an_actuator_whose_force_follows_the_state_holds_its_torque_like_a_motor(
    tmp_path: Path, integrator: str, kind: str
) -> None:
    """A `general` actuator whose force depends on the joint's angle and speed (b1, b2) is driven by a joint
    torque held over the sample, as a motor is. With its ctrl held over the sample its force drifted with the
    state inside the sample (and inside RK4's stages) while the torque logged was the sample's first, and
    sysid-run gave a gear-3 joint's viscous friction as 0.258 +- 0.004 for 0.05 (z 53). Now the arm moves as the
    plain-motor arm at the same physics step under the same torques, and logs the same torques. So does a servo
    asked for an open-loop torque through its setpoint (under RK4 inverse dynamics on its filtered states left
    0.93 of a stiff servo's torque RMS)."""
    general = (
        '<general joint="j0" gear="3" gainprm="0.5" biastype="affine" biasprm="0.3 -25 -1.5" ctrlrange="-1e3 1e3"/>'
        '<general joint="j1" gear="1" gainprm="2" biastype="affine" biasprm="0 -20 -0.05" ctrlrange="-1e3 1e3"/>'
    )
    servos = _STIFF_SERVOS.replace("forcerange", 'ctrlrange="-100 100" forcerange')
    biased = _arm(tmp_path / kind, actuators=general if kind == "general" else servos, integrator=integrator)
    split = _substeps(biased)
    # the b1 spring splits the step where a ctrl limit can bring its law in: several physics steps in a sample
    assert split > 1
    xml = _ARM.format(
        name="arm", integrator=integrator, flag="", d0=0.0, d1=0.0, actuators='<motor joint="j0"/><motor joint="j1"/>'
    ).replace('timestep="0.002"', f'timestep="{0.002 / split!r}"')
    plain = plant_from_xml(xml, "arm", tmp_path / "motor")

    def torque(t: np.ndarray) -> np.ndarray:
        return np.column_stack([2.0 * np.sin(2 * np.pi * 0.7 * t) + 1.0, 0.002 * np.sin(2 * np.pi * 1.1 * t)])

    sensor = SensorModel(sample_rate_hz=500)
    runs = [
        simulate_open_loop(p, torque, duration_s=2.0, sensor=sensor, rng=np.random.default_rng(0))
        for p in (biased, plain)
    ]
    assert np.abs(runs[0].meta["q_true"] - runs[1].meta["q_true"]).max() < 1e-9
    assert np.abs(runs[0].tau - runs[1].tau).max() < 1e-9
    assert runs[0].tau_lead_s == runs[1].tau_lead_s  # a held torque's instant
    assert runs[0].meta["saturated_fraction"] == [0.0, 0.0]
    exact = inverse_dynamics(biased, runs[0].meta["q_true"], runs[0].meta["dq_true"], runs[0].ddq)
    assert np.abs(exact - runs[0].meta["tau_applied"]).max() < 1e-9


def test_a_general_actuator_at_its_ctrl_limit_applies_its_own_law(tmp_path: Path) -> None:
    """Past its ctrl range the actuator cannot hold the torque asked: its force is gain x the limit plus its bias,
    which follows the state (a spring of b1 gear^2 here), and the sample is saturated, not held at a spring of the
    sample's angle (a held bias sampled a stiff spring at the sample rate and shook a light joint at 90 x its
    acceleration bound)."""
    general = '<general joint="j0" gear="3" gainprm="2" biastype="affine" biasprm="0 -25 0" ctrlrange="-1 1"/>'
    arm = _arm(tmp_path, actuators=general + '<motor joint="j1"/>', integrator="Euler")

    def torque(t: np.ndarray) -> np.ndarray:  # 3 x (2 x 1) = 6 N m at most through the ctrl: beyond it at times
        return np.column_stack([9.0 * np.sin(2 * np.pi * 0.5 * t), np.zeros_like(t)])

    data = simulate_open_loop(
        arm, torque, duration_s=2.0, sensor=SensorModel(sample_rate_hz=500), rng=np.random.default_rng(0)
    )
    q, dq = data.meta["q_true"][:, 0], data.meta["dq_true"][:, 0]
    law = 3.0 * (2.0 * np.sign(torque(data.time)[:, 0]) - 25.0 * 3.0 * q)  # at the limit, the actuator's own law
    at_limit = np.abs(torque(data.time)[:, 0] / 3.0 + 75.0 * q) > 2.0 + 1e-6
    assert 0.1 < at_limit.mean() < 0.9 and data.meta["saturated_fraction"][0] > 0.1
    np.testing.assert_allclose(data.meta["tau_applied"][at_limit, 0], law[at_limit], atol=0.1)
    assert np.all(np.isfinite(dq)) and np.abs(dq).max() < 50.0


def test_an_actuator_driven_as_a_motor_without_a_ctrl_range_does_not_split_the_step(tmp_path: Path) -> None:
    """An actuator whose force is set from the sample's torque at every physics step (`_holding`) applies its own
    law only at its ctrl limit: without a ctrl range, never, and its spring and damper ask for no finer step. An
    open-loop servo arm took 3200 physics steps per 2 ms sample for them (kv 80 on the light wrist), under
    implicitfast too, where its tracking takes 12 (1 s of motion: 34.8 s); a ctrl range brings the law, and the
    split, back."""
    plant = _arm(tmp_path / "free", actuators=_SERVOS.format(f0=50), integrator="Euler")
    regulated = simulate._state_dependent(plant, servos=True)
    assert regulated.all() and _substeps(plant) > 100  # tracking: the servos' own law, kv 80 explicit
    assert _substeps(plant, regulated) == 1
    limited_servos = _SERVOS.format(f0=50).replace("/>", ' ctrlrange="-3 3"/>')
    limited = _arm(tmp_path / "limited", actuators=limited_servos, integrator="Euler")
    assert _substeps(limited, regulated) == _substeps(limited) > 1

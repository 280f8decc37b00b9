"""What the simulation really did against the limits the design keeps: a one-sided or narrow actuator range is
taken into the limits (or refused), the simulated motion is checked against them, and contacts are refused."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from dynamics.errors import ModelError
from dynamics.plant import plant_from_xml
from envs.sensors import SensorModel
from envs.simulate import simulate_open_loop, simulate_tracking
from excitation.limits import limits_for
from harness.results import summary_table
from harness.run import simulated_motion
from harness.validate import ConfigError, check_driven

_ONE = """<mujoco model="{name}"><compiler angle="radian"/><option timestep="0.002"/><worldbody>{world}
  <body name="arm"><joint name="j0" axis="0 1 0" range="-2 2"/>
    <geom name="rod" type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02" mass="1"/></body></worldbody>
  <actuator>{actuator}</actuator></mujoco>"""


def _plant(tmp_path: Path, actuator: str, world: str = "", name: str = "one"):  # type: ignore[no-untyped-def]
    return plant_from_xml(_ONE.format(name=name, world=world, actuator=actuator), name, tmp_path)


class _Swing:
    """q = a sin(w t) about zero."""

    def __init__(self, a: float, freq_hz: float = 0.5) -> None:
        self.a, self.w = a, 2 * np.pi * freq_hz

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        wt = self.w * t[:, None]
        return self.a * np.sin(wt), self.a * self.w * np.cos(wt), -self.a * self.w**2 * np.sin(wt)


def _track(plant, reference: _Swing, duration_s: float = 2.0):  # type: ignore[no-untyped-def]
    sensor = SensorModel(sample_rate_hz=500)
    return simulate_tracking(plant, reference, duration_s=duration_s, sensor=sensor, rng=np.random.default_rng(0))


@pytest.mark.parametrize(
    ("actuator", "limit"),
    [
        ('<motor joint="j0" ctrlrange="-5 20"/>', 5.0),  # the smaller side: a symmetric bound of 20 broke it
        ('<motor joint="j0" ctrlrange="-20 20" gear="-2"/>', 40.0),
        ('<motor joint="j0" forcelimited="true" forcerange="-3 8"/>', 3.0),
        ('<general joint="j0" gainprm="2" ctrlrange="-1 4"/>', 2.0),
    ],
)
def test_the_torque_limit_is_what_the_actuator_gives_both_ways(tmp_path: Path, actuator: str, limit: float) -> None:
    plant = _plant(tmp_path, actuator)
    assert plant.tau_limit[0] == pytest.approx(limit)
    check_driven(plant)


@pytest.mark.parametrize(
    ("actuator", "message"),
    [
        ('<motor name="lift" joint="j0" ctrlrange="0 20"/>', r"actuator 'lift' can drive joint 'j0' one way only"),
        ('<motor name="lift" joint="j0" forcelimited="true" forcerange="-8 0"/>', r"'lift' can drive joint 'j0' one"),
        ('<general name="lift" joint="j0" gainprm="0" ctrlrange="-1 1"/>', r"'lift' on joint 'j0' has gain 0"),
        ('<motor name="lift" joint="j0" gear="0" ctrlrange="-1 1"/>', r"'lift' on joint 'j0' has gear 0: it applies"),
        # no range at all: an unlimited torque, and the ctrl still moves nothing (the run went on to NaN controls)
        ('<general name="lift" joint="j0" gainprm="0" biastype="affine" biasprm="0.5 0 0"/>', r"'lift' .* has gain 0"),
    ],
)
def test_an_actuator_that_cannot_drive_both_ways_is_refused_by_name(
    tmp_path: Path, actuator: str, message: str
) -> None:
    plant = _plant(tmp_path, actuator)
    with pytest.raises(ConfigError, match=message):
        check_driven(plant)


def test_a_servos_ctrlrange_narrows_the_range_and_speed_the_design_may_use(tmp_path: Path) -> None:
    """A position servo clamps its target to ctrlrange / gear, a velocity servo its speed: a design over the
    joint's own range (+-2 rad) ran as a motion clipped at +-0.5 rad, and the limits said they held."""
    position = _plant(tmp_path, '<position joint="j0" kp="50" ctrlrange="-1 0.6" gear="2"/>', name="pos")
    limits = limits_for(position, velocity=3.0, acceleration=10.0, range_margin=0.0)
    assert (limits.q_min[0], limits.q_max[0]) == pytest.approx((-0.5, 0.3))
    velocity = _plant(tmp_path, '<velocity joint="j0" kv="5" ctrlrange="-4 1"/>', name="vel")
    limits = limits_for(velocity, velocity=3.0, acceleration=10.0, range_margin=0.0)
    assert limits.dq_max[0] == pytest.approx(1.0) and (limits.q_min[0], limits.q_max[0]) == (-2.0, 2.0)


def test_a_motion_that_breaks_the_limits_is_named_and_flagged(tmp_path: Path) -> None:
    """A swing that needs more torque than the motor has: the motion that ran lags the design, and the check
    of the simulated motion names the broken bound where the design's own check held."""
    plant = _plant(tmp_path, '<motor joint="j0" ctrlrange="-0.8 0.8"/>')  # gravity alone needs 1.4 N m at 1.2 rad
    limits = limits_for(plant, velocity=20.0, acceleration=100.0, range_margin=0.0)
    reference = _Swing(1.2)
    data = _track(plant, reference)
    motion = simulated_motion(reference, limits, data, torque_driven=False)  # type: ignore[arg-type]
    assert not motion["holds"] and re.match(r"(q|dq|ddq|tau)\[j0\] at [\d.]+ x its bound", motion["worst"])
    assert motion["tracking_error_max"]["j0"] > 0.1
    held = simulated_motion(_Swing(0.2), limits, _track(plant, _Swing(0.2)), torque_driven=False)  # type: ignore[arg-type]
    assert held["holds"] and held["tracking_error_max"]["j0"] < 0.01
    results = _results(motion)
    assert f"WARNING: the simulated motion breaks the limits the design keeps: {motion['worst']}" in summary_table(
        results
    )
    assert "limits hold on the design, not in the motion that ran" in summary_table(results)
    assert "WARNING: the simulated motion" not in summary_table(_results(held))
    assert "limits hold\n" in summary_table(_results(held))
    # the validation's own motion (another design, as a position-servo arm's lags): warned of too
    validated = _results(held)
    validated["validation"]["simulated"] = motion
    assert f"WARNING: the validation motion that ran breaks the limits: {motion['worst']}" in summary_table(validated)
    validated["validation"]["simulated"] = held
    assert "WARNING" not in summary_table(validated)


def test_a_joint_that_does_not_follow_the_design_is_warned_of(tmp_path: Path) -> None:
    """A dry friction the nominal model does not know and its controller's gains cannot break: the joint barely
    moves, stays inside every limit (so `holds`), and was reported as a good run (a 5 g finger held 1.57 rad off
    its design). Now `not_following` names it, and the summary warns."""
    actuator = '<motor joint="j0" ctrlrange="-20 20"/>'
    nominal = _plant(tmp_path, actuator, name="free")
    stuck = plant_from_xml(
        _ONE.format(name="stuck", world="", actuator=actuator).replace(
            'range="-2 2"', 'range="-2 2" frictionloss="12"'
        ),
        "stuck",
        tmp_path,
    )
    limits = limits_for(nominal, velocity=20.0, acceleration=100.0, range_margin=0.0)
    reference = _Swing(0.5)
    sensor = SensorModel(sample_rate_hz=500)
    data = simulate_tracking(
        stuck, reference, duration_s=2.0, sensor=sensor, rng=np.random.default_rng(0), nominal=nominal
    )
    motion = simulated_motion(reference, limits, data, torque_driven=False)  # type: ignore[arg-type]
    assert motion["holds"]  # nothing broken: it does not move
    miss = motion["not_following"]["j0"]
    assert miss["swing"] == pytest.approx(0.5, rel=0.01) and miss["error"] > 0.25
    assert "WARNING: joint j0 did not follow the design: up to" in summary_table(_results(motion))
    followed = simulated_motion(reference, limits, _track(nominal, reference), torque_driven=False)  # type: ignore[arg-type]
    assert followed["not_following"] == {}
    assert "did not follow" not in summary_table(_results(followed))


def test_a_motion_that_presses_geoms_together_is_refused_by_name(tmp_path: Path) -> None:
    """A link swinging into a world-fixed block: the contact force would be fitted as inertia and friction."""
    plant = _plant(
        tmp_path,
        '<motor joint="j0" ctrlrange="-20 20"/>',
        world='<geom name="block" type="box" pos="-0.25 0 -0.25" size="0.05 0.05 0.05"/>',
    )
    limits = limits_for(plant, velocity=20.0, acceleration=100.0, range_margin=0.0)
    reference = _Swing(1.0)
    with pytest.raises(ModelError, match=r"presses geom block \(world\) against rod \(arm\) in \d+ of 1000 samples"):
        simulated_motion(reference, limits, _track(plant, reference), torque_driven=False)  # type: ignore[arg-type]


def test_a_pair_that_overlaps_in_every_sample_is_counted_once_a_sample_and_no_clearance_is_advised(
    tmp_path: Path,
) -> None:
    """A box on the arm inside a box fixed at the pivot: box-box contact has up to 8 points, and the pair was
    reported pressing in 4000 of 1000 samples (15003 of 15000 on a gimbal arm), with a larger clearance_m advised,
    which cannot part geoms that overlap wherever the arm goes."""
    xml = _ONE.format(
        name="hub",
        world='<geom name="hub" type="box" pos="0 0 0" size="0.04 0.04 0.04"/>',
        actuator='<motor joint="j0" ctrlrange="-20 20"/>',
    )
    xml = xml.replace('mass="1"/>', 'mass="1"/><geom name="block" type="box" pos="0 0 -0.03" size="0.03 0.03 0.03"/>')
    plant = plant_from_xml(xml, "hub", tmp_path)
    data = _track(plant, _Swing(0.5))
    assert {tuple(c["geoms"]): c["samples"] for c in data.meta["contacts"]} == {
        ("hub (world)", "block (arm)"): 1000,
        ("hub (world)", "rod (arm)"): 1000,
    }
    limits = limits_for(plant, velocity=20.0, acceleration=100.0, range_margin=0.0)
    with pytest.raises(ModelError, match=r"in 1000 of 1000 samples .* they touch in every sample") as err:
        simulated_motion(_Swing(0.5), limits, data, torque_driven=False)  # type: ignore[arg-type]
    assert "clearance_m" not in str(err.value)


def test_a_motion_that_presses_a_joint_against_its_range_limit_is_refused_by_name(tmp_path: Path) -> None:
    """A swing of 1.2 rad on a joint whose limit force acts from 0.5 rad on (range +-1.5, margin 1): the stop's
    force would be fitted as inertia and gravity."""
    xml = _ONE.format(name="stop", world="", actuator='<motor joint="j0" ctrlrange="-20 20"/>')
    plant = plant_from_xml(xml.replace('range="-2 2"', 'range="-1.5 1.5" margin="1"'), "stop", tmp_path)
    limits = limits_for(plant, velocity=20.0, acceleration=100.0, range_margin=0.0)
    reference = _Swing(1.2)
    data = _track(plant, reference)
    stop = data.meta["limits"][0]
    assert stop["joint"] == "j0" and stop["samples"] > 100 and stop["max_force"] > 0.1
    with pytest.raises(ModelError, match=r"presses joint 'j0' against its range limit in \d+ of 1000 samples") as err:
        simulated_motion(reference, limits, data, torque_driven=False)  # type: ignore[arg-type]
    # the key that makes the loop faster is named (a user who guessed controller.bandwidth_hz got "Key 'controller'
    # is not in struct"), with how far the joint left its design
    assert "its tracking error up to " in str(err.value) and "larger system.controller.bandwidth_hz" in str(err.value)
    free = _track(plant, _Swing(0.3))  # inside the margin's free range: no limit force
    assert free.meta["limits"] == []
    simulated_motion(_Swing(0.3), limits, free, torque_driven=False)  # type: ignore[arg-type]


def test_a_limit_margin_narrows_the_range_the_design_may_use(tmp_path: Path) -> None:
    """MuJoCo's limit force acts within `margin` of each end: the design keeps to the range inside it (and the
    range margin's share of that), and a margin that leaves nothing is refused by name."""
    xml = _ONE.format(name="margin", world="", actuator='<motor joint="j0" ctrlrange="-20 20"/>')
    plant = plant_from_xml(xml.replace('range="-2 2"', 'range="-2 2" margin="0.5"'), "margin", tmp_path)
    limits = limits_for(plant, velocity=20.0, acceleration=100.0, range_margin=0.1)
    assert limits.q_min[0] == pytest.approx(-1.5 + 0.3) and limits.q_max[0] == pytest.approx(1.5 - 0.3)
    wide = plant_from_xml(xml.replace('range="-2 2"', 'range="-2 2" margin="2"'), "wide", tmp_path)
    with pytest.raises(ModelError, match=r"joint 'j0'.s limit margin 2 leaves no free range inside \[-2, 2\]"):
        limits_for(wide, velocity=20.0, acceleration=100.0)


def _results(motion: dict) -> dict:
    """The parts of a run's results the summary table reads."""
    return {
        "system": "one",
        "seed": 0,
        "estimator": "ols",
        "base_parameters": [{"name": "m", "true": 1.0, "estimate": 1.0, "std": 0.1, "rel_error": 0.0, "z": 0.0}],
        "excitation": {
            "name": "default",
            "cond_XtX": 1.0,
            "cond_W_colnorm": 1.0,
            "harmonics": 5,
            "period_s": 10.0,
            "limits_ok": True,
            "simulated": motion,
        },
        "validation": {"torque_rms": {"j0": 0.1}, "noise_std": {"j0": 0.01}},
        "timing_s": {"setup": 0.1},
    }


def test_a_broken_clearance_says_the_distance_kept(tmp_path: Path) -> None:
    """Its ratio is the bound over the distance: "at 1.19 x its bound" read as more room than asked. A
    horizontal rod 15 cm above the floor (z = 0) swings by 0.3 rad: its 2 cm thick tip comes within
    0.15 - 0.3 sin(0.3) - 0.02 = 0.041 m of it, where 0.1 m are asked."""
    xml = """<mujoco model="low"><compiler angle="radian"/><option timestep="0.002"/><worldbody>
      <body name="arm" pos="0 0 0.15"><joint name="j0" axis="0 1 0" range="-2 2"/>
        <geom name="rod" type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" mass="1"/></body></worldbody>
      <actuator><motor joint="j0" ctrlrange="-20 20"/></actuator></mujoco>"""
    plant = plant_from_xml(xml, "low", tmp_path)
    limits = limits_for(plant, velocity=20.0, acceleration=100.0, range_margin=0.0, clearance_m=0.1)
    motion = simulated_motion(_Swing(0.3), limits, _track(plant, _Swing(0.3)), torque_driven=False)  # type: ignore[arg-type]
    assert not motion["holds"]
    kept = re.search(
        r"^clearance \(at least 0\.1 m between links, to the floor and to fixed geoms\): ([\d.]+) m at the closest$",
        motion["worst"],
    )
    assert kept is not None and float(kept.group(1)) == pytest.approx(0.041, abs=0.003), motion["worst"]


_SERVO_ARM = """<mujoco model="servo_arm"><compiler angle="radian"/><worldbody>
  <body name="l1" pos="0 0 1"><joint name="j1" axis="0 1 0" range="-1.5 1.5" damping="0.1"/>
    <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.03"/>
    <body name="l2" pos="0 0 -0.3"><joint name="j2" axis="0 1 0" range="-1.5 1.5" damping="0.05"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.25" size="0.025"/>
      <body name="l3" pos="0 0 -0.25"><joint name="j3" axis="0 1 0" range="-1.5 1.5" damping="0.02"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.2" size="0.02"/></body></body></body></worldbody>
  <actuator><position joint="j1" kp="20" kv="1" ctrlrange="-1.5 1.5" forcerange="-4 4"/>
    <position joint="j3" kp="5" kv="0.2" ctrlrange="-1.5 1.5" forcerange="-1 1"/></actuator></mujoco>"""


def test_a_torque_design_for_servos_is_sized_on_the_motion_the_servos_give(tmp_path: Path) -> None:
    """An arm with a passive joint is excited by open-loop torque; its position servos apply a torque through
    their own law (`ctrl_for_torque`), but the design's amplitude search rolled the design out with the torque
    as their ctrl, a target angle: it saw j3 swing 0.05 rad where the run swung 0.22, and the run broke its
    bounds with j3's servo at its force range on half the samples. The search's motion is now the run's."""
    from excitation.designs import default_design, torque_rollout

    plant = plant_from_xml(_SERVO_ARM, "servo_arm", tmp_path)
    limits = limits_for(plant, velocity=20.0, acceleration=200.0, range_margin=0.05)
    design = default_design(plant, limits, harmonics=5, base_freq_hz=0.1, torque_driven=True)
    q_search = torque_rollout(plant, [design], periods=1.0)[0][0]
    sensor = SensorModel(1.0 / float(plant.mj_model.opt.timestep))  # noiseless, one sample per physics step
    data = simulate_open_loop(plant, design.torque, duration_s=10.0, sensor=sensor, rng=np.random.default_rng(0))
    n = min(len(q_search), data.n_samples)
    assert np.max(np.abs(data.q[:n] - q_search[:n])) < 0.01 * np.ptp(data.q[:n], axis=0).max()
    ratios = limits.ratios(data.q, np.gradient(data.q, data.time, axis=0))
    assert max(ratios.values()) <= 1.0, ratios


def test_a_torque_design_for_strong_motors_on_a_light_arm_is_found_below_a_sixteenth_of_their_limit(
    tmp_path: Path,
) -> None:
    """Motors of 30 and 10 N m on a light arm with a passive joint: a sixteenth of their torque still spun it
    beyond 1.5 rad/s (the default speed bound of a model brought by path), and the run was refused although a
    smaller amplitude keeps every bound. The search now goes on to 1/256 and 1/4096 of the limit."""
    from excitation.designs import default_design, torque_rollout

    xml = _SERVO_ARM.replace(
        '<position joint="j1" kp="20" kv="1" ctrlrange="-1.5 1.5" forcerange="-4 4"/>',
        '<motor joint="j1" ctrlrange="-30 30"/>',
    ).replace(
        '<position joint="j3" kp="5" kv="0.2" ctrlrange="-1.5 1.5" forcerange="-1 1"/>',
        '<motor joint="j3" ctrlrange="-10 10"/>',
    )
    plant = plant_from_xml(xml, "strong", tmp_path)
    limits = limits_for(plant, velocity=1.5, acceleration=8.0, range_margin=0.05)
    design = default_design(plant, limits, harmonics=5, base_freq_hz=0.1, torque_driven=True)
    peak = np.max(np.abs(design.torque(np.linspace(0.0, design.period_s, 2001))), axis=0)
    assert peak[0] < 30.0 / 16  # below the first batch
    q, dq = torque_rollout(plant, [design], periods=3.0)
    assert max(limits.ratios(q[0], dq[0]).values()) <= 1.0

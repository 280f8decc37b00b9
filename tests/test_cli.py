"""`sysid-run`: its outputs follow DESIGN.md's contract and bad choices fail early and clearly."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hydra.errors import HydraException, MissingConfigException
from omegaconf.errors import OmegaConfBaseException

from dynamics.errors import InfeasibleExcitationError
from harness.run import run
from harness.validate import ConfigError
from tests.conftest import compose_config, rrd_has_blueprint, rrd_rows

REPO = Path(__file__).resolve().parents[1]


def _check_schema(results: dict) -> None:
    assert isinstance(results["system"], str)
    ex = results["excitation"]
    for key, kind in (("cond_XtX", float), ("cond_W_colnorm", float), ("harmonics", int), ("period_s", float)):
        assert isinstance(ex[key], kind), key
    assert isinstance(ex["limits_ok"], bool)
    assert results["base_parameters"], "no base parameters"
    for p in results["base_parameters"]:
        assert set(p) >= {"name", "true", "estimate", "std", "rel_error"}
        assert isinstance(p["name"], str) and isinstance(p["estimate"], float) and isinstance(p["std"], float)
    rms = results["validation"]["torque_rms"]
    assert rms and all(isinstance(v, float) for v in rms.values())
    assert results["timing_s"] and all(isinstance(v, float) for v in results["timing_s"].values())
    assert isinstance(results["seed"], int)


def test_console_script_writes_the_contracted_outputs(tmp_path: Path) -> None:
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "harness.run", "system=pendulum", "seed=3", f"hydra.run.dir={out}"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = json.loads((out / "results.json").read_text())
    _check_schema(results)
    assert results["system"] == "pendulum" and results["seed"] == 3
    assert "base parameter" in proc.stdout  # the terminal summary
    header = (out / "data.csv").read_text().splitlines()[0].split(",")
    assert header[:2] == ["time", "q_swing"] and "tau_swing" in header
    # what data.csv cannot say: its motor torque is held over the sample after its row (sysid-diagnose's
    # data.tau_lead_s), half a sample less half the semi-implicit step
    period = 1.0 / results["config"]["system"]["sensor"]["sample_rate_hz"]
    assert 0 < results["data"]["tau_lead_s"] < 0.5 * period
    rows = rrd_rows(out / "recording.rrd")
    n = len((out / "data.csv").read_text().splitlines()) - 1
    assert 0.8 * n < rows["/joints/swing/tau/measured"] <= n  # filter edges trimmed
    assert rows["/joints/swing/tau/model"] == rows["/joints/swing/tau/measured"]
    assert rows["/parameters/table"] == 1
    assert rows["/robot/measured/pendulum"] > 10  # the 3D replay: one pose per replayed sample
    assert rrd_has_blueprint(out / "recording.rrd")


def test_unknown_system_lists_the_valid_ones() -> None:
    with pytest.raises(MissingConfigException, match=r"(?s)system.*two_link.*wheel_pendulum"):
        compose_config(["system=three_link"])


def test_unknown_estimator_group_lists_the_valid_ones() -> None:
    with pytest.raises(MissingConfigException, match=r"(?s)estimator.*ols.*wls"):
        compose_config(["estimator=kalman_magic"])


def test_a_model_path_that_names_no_model_is_refused_by_its_key(tmp_path: Path) -> None:
    """A folder (or a log) given as the model: the refusal names system.mjcf, as every config error names its key."""
    (tmp_path / "robot").mkdir()
    cfg = compose_config(["record=none", f"system.mjcf={tmp_path / 'robot'}"])
    with pytest.raises(ConfigError, match=r"^system\.mjcf: model path is a directory, not a file: .*robot"):
        run(cfg, output_dir=tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_an_open_loop_run_of_a_motor_without_a_torque_limit_is_refused_by_name(tmp_path: Path) -> None:
    """A passive joint makes the run open loop (system.torque_driven from the model), and its design is sized by
    the motors' torque limits: one without any went on to infinite amplitudes, NaN controls and a misleading
    "columns vanish" error. Tracked (every joint driven), no limit is needed and none is asked for."""
    link = '<geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.03"/>'
    arm = (
        '<mujoco model="loose"><compiler angle="radian"/><worldbody><body pos="0 0 1"><joint name="j1" axis="0 1 0" '
        f'range="-1.5 1.5"/>{link}<body pos="0 0 -0.3"><joint name="j2" axis="0 1 0" range="-1.5 1.5" '
        f'damping="0.05"/>{link}</body></body></worldbody><actuator>{{motors}}</actuator></mujoco>'
    )
    (tmp_path / "loose.xml").write_text(arm.format(motors='<motor name="m1" joint="j1"/>'))
    cfg = compose_config(["record=none", "system=auto", f"system.mjcf={tmp_path / 'loose.xml'}"])
    with pytest.raises(ConfigError, match=r"actuator 'm1' on joint 'j1' has no torque limit .* give it a ctrlrange"):
        run(cfg, output_dir=tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_unknown_estimator_name_fails_before_any_work(tmp_path: Path) -> None:
    cfg = compose_config(["record=none", "estimator.name=magic"])
    with pytest.raises(ValueError, match=r"unknown estimator 'magic'; valid choices: .*ols.*wls"):
        run(cfg, output_dir=tmp_path)
    assert not any(tmp_path.iterdir())


def test_malformed_override_is_refused() -> None:
    with pytest.raises((HydraException, OmegaConfBaseException), match="no viable alternative"):
        compose_config(["system.limits.velocity=[1,"])


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        # Hydra raised a bare ValueError with a traceback ("Config group override must be a string or a list")
        (["system=null"], r"system=null: system needs one of its configs; valid choices: arm3, auto, pendulum"),
        (["-m", "estimator=ols,null"], r"estimator=null \(in the sweep estimator=ols,null\): estimator needs one"),
        # ++ adds a key where it is absent: a misspelled one was carried along and never read
        (["++validation.period=2"], r"\+\+validation\.period: no such key is read; did you mean validation\.periods"),
    ],
)
def test_a_group_set_to_null_or_a_misspelled_forced_key_is_named(argv: list[str], message: str) -> None:
    from harness.validate import check_command_line

    with pytest.raises(ConfigError, match=message):
        check_command_line(argv, REPO / "conf", "config")
    check_command_line(["++validation.periods=2"], REPO / "conf", "config")  # an existing key: accepted


URDF_ARM = """<?xml version="1.0"?>
<robot name="arm">
  <link name="base"/>
  <link name="l1">
    <inertial><origin xyz="0 0 -0.1"/><mass value="1"/>
      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
  </link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="10" velocity="5"/></joint>
</robot>
"""


def test_model_xml_is_an_output_never_overwritten_silently_nor_left_behind(tmp_path: Path) -> None:
    """A URDF run wrote model.xml over a file of that name without overwrite=true, and a later run of another
    system with overwrite=true left that robot's model.xml beside its own results."""
    from harness.rundir import RunFolderError

    urdf = tmp_path / "arm.urdf"
    urdf.write_text(URDF_ARM)
    out = tmp_path / "run"
    out.mkdir()
    (out / "model.xml").write_text("<mujoco model='mine'/>")
    with pytest.raises(RunFolderError, match=r"already holds model\.xml"):
        run(compose_config(["record=none", "system=auto", f"system.mjcf={urdf}"]), output_dir=out)
    assert (out / "model.xml").read_text() == "<mujoco model='mine'/>"
    run(compose_config(["record=none", "system=auto", f"system.mjcf={urdf}", "overwrite=true"]), output_dir=out)
    assert "Compiled by MuJoCo from arm.urdf" in (out / "model.xml").read_text()
    run(compose_config(["record=none", "system=pendulum", "overwrite=true"]), output_dir=out)
    assert sorted(p.name for p in out.iterdir()) == ["data.csv", "results.json"]


def test_a_urdf_saved_as_xml_is_read_as_a_urdf(tmp_path: Path) -> None:
    """A URDF whose file is called .xml: MuJoCo compiled it as it is, without the motors a URDF gets at its effort
    limits, and the run was refused with advice to add motors to an MJCF. Its root element tells it."""
    from dynamics.errors import ModelError
    from dynamics.plant import load_plant
    from dynamics.urdf import is_urdf

    path = tmp_path / "arm.xml"
    path.write_text(URDF_ARM)
    plant = load_plant(path)
    assert plant.source == path and plant.mj_model.nu == 1
    assert np.isclose(float(plant.tau_limit[0]), 10.0)  # the URDF's effort limit
    assert not is_urdf(REPO / "mjcf" / "pendulum.xml")
    (tmp_path / "broken.xml").write_text("<robot><link")
    with pytest.raises(ModelError, match=r"broken\.xml: not a readable URDF: unclosed token: line 1"):
        load_plant(tmp_path / "broken.xml")
    (tmp_path / "text.xml").write_text("not markup")
    assert not is_urdf(tmp_path / "text.xml")


def test_a_relative_model_path_in_a_users_system_config_is_relative_to_that_config(tmp_path: Path) -> None:
    """`mjcf: ../../models/arm.xml` in <dir>/system/arm.yaml was read against the working directory (a data
    config's paths are against its own folder), and the error named neither. Now the config's folder; a relative
    path on the command line stays against the working directory, and its error says so."""
    from harness.init import main

    (tmp_path / "models").mkdir()
    model = tmp_path / "models" / "arm.xml"
    shutil.copy(REPO / "mjcf" / "pendulum.xml", model)
    config = tmp_path / "conf" / "system" / "arm.yaml"
    assert main([str(model), "--out", str(config)]) == 0
    text = config.read_text()
    config.write_text(text.replace(f"mjcf: {model}", "mjcf: ../../models/arm.xml", 1))
    assert "mjcf: ../../models/arm.xml" in config.read_text()

    def sysid_run(*args: str) -> subprocess.CompletedProcess:
        command = [sys.executable, "-m", "harness.run", *args]
        return subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=300, check=False)

    user = ("--config-dir", str(tmp_path / "conf"), "record=none")
    proc = sysid_run(*user, "system=arm", f"hydra.run.dir={tmp_path}/run")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads((tmp_path / "run" / "results.json").read_text())["system"] == "arm"
    # a path built by interpolation from another key of the config, which the file alone cannot resolve
    interpolated = f"mjcf: {tmp_path}/models/${{system.name}}.xml"
    config.with_name("arm2.yaml").write_text(text.replace(f"mjcf: {model}", interpolated))
    proc = sysid_run(*user, "system=arm2", f"hydra.run.dir={tmp_path}/run3")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads((tmp_path / "run3" / "results.json").read_text())["system"] == "arm"
    proc = sysid_run("record=none", "system.mjcf=models/arm.xml", f"hydra.run.dir={tmp_path / 'run2'}")
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1].endswith(f"model file not found: models/arm.xml (relative to {REPO})")


def test_system_name_names_the_outputs_and_must_be_a_plain_name(tmp_path: Path) -> None:
    """`system.name` was read and then ignored: the results (and a diagnosis's calibrated MJCF) still carried the
    model file's name, whatever the config said. Now it names them; one with a folder in it is refused by its key
    before anything is written."""
    from harness.validate import ConfigError

    results = run(compose_config(["record=none", "system=pendulum", "system.name=bench_pendulum"]), output_dir=tmp_path)
    assert results["system"] == "bench_pendulum"
    for bad in ("my/arm", "../escaped", ".hidden"):
        out = tmp_path / bad.replace("/", "_")
        with pytest.raises(ConfigError, match=r"system\.name=.*it names the outputs .* so it is a plain name"):
            run(compose_config(["record=none", "system=pendulum", f"system.name={bad}"]), output_dir=out)
        assert not out.exists()
    # a built-in config's own name is its own model's: another model given in its place names itself
    from harness.setup import load_system

    other = REPO / "mjcf" / "pendulum.xml"
    assert load_system(compose_config(["system=two_link", f"system.mjcf={other}"])).name == "pendulum"
    assert load_system(compose_config(["system=two_link", f"system.mjcf={other}", "system.name=mine"])).name == "mine"


@pytest.mark.parametrize("config_name", ["config", "diagnose"])
def test_a_users_system_config_without_its_model_asks_for_system_mjcf(config_name: str) -> None:
    """`system=auto` left without `system.mjcf` was refused in OmegaConf's words ("Missing mandatory value:
    system.mjcf; full_key: system.mjcf; object_type=dict"); both commands now say what to give."""
    from harness.setup import load_system
    from harness.validate import ConfigError

    extra = ["data.path=run.csv"] if config_name == "diagnose" else []
    cfg = compose_config(["system=auto", *extra], config_name=config_name)
    with pytest.raises(ConfigError, match=r"^system\.mjcf is not set: give the robot's model, e\.g\. system\.mjcf="):
        load_system(cfg)


def test_the_iv_estimators_derived_reference_stays_where_differences_are_accurate(tmp_path: Path) -> None:
    """IV filters its reference at twice the motion's bandwidth, at most 0.4 of the rate: on noise-free pendulum
    data that was 125 Hz at 500 Hz, which the differences' limit (an eighth of the rate) then refused with a
    DataError naming no key (review of 809af9b). Without a period it now stops at that limit."""
    results = run(compose_config(["record=none", "system=pendulum", "estimator=iv", "noise=none"]), output_dir=tmp_path)
    assert results["estimator"] == "iv"  # noise-free: no z to judge


def test_failed_run_leaves_no_results(tmp_path: Path) -> None:
    # an acceleration bound too small for any motion: the excitation cannot be designed
    cfg = compose_config(["record=none", "system=pendulum", "system.limits.acceleration=1e-6"])
    with pytest.raises(ValueError, match="binding constraint"):
        run(cfg, output_dir=tmp_path)
    assert not (tmp_path / "results.json").exists()


def test_an_open_loop_design_that_leaves_the_arm_still_is_refused_not_fitted(tmp_path: Path) -> None:
    """A hanging chain whose middle joint has no actuator, driven open loop: every torque the limits allow was
    scaled down until the arm barely moved (|q| < 7e-5 rad), the search reported cond inf, and the run fitted
    noise and exited 0 (XX2 = 2e10 +- 4e10, validation RMS 4e5 N m against 0.1 N m of noise). Refused now."""
    model = tmp_path / "passive_middle.xml"
    model.write_text(
        '<mujoco model="passive_middle"><compiler angle="radian"/><worldbody><body name="l1" pos="0 0 0.6">'
        '<joint name="j1" axis="0 0 1" range="-2 2"/><geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>'
        '<body name="l2" pos="0.3 0 0"><joint name="j2" axis="0 1 0" range="-2 2" damping="0.05"/>'
        '<geom type="capsule" fromto="0 0 0 0 0 -0.25" size="0.025"/><body name="l3" pos="0 0 -0.25">'
        '<joint name="j3" axis="0 1 0" range="-2 2"/><geom type="capsule" fromto="0 0 0 0 0 -0.2" size="0.02"/>'
        '</body></body></body></worldbody><actuator><motor joint="j1" ctrlrange="-20 20"/>'
        '<motor joint="j3" ctrlrange="-10 10"/></actuator></mujoco>'
    )
    out = tmp_path / "run"
    with pytest.raises(InfeasibleExcitationError, match=r"moves the arm enough to excite .*cond\(X'X\) is infinite"):
        run(compose_config(["record=none", "system=auto", f"system.mjcf={model}"]), output_dir=out)
    assert not (out / "results.json").exists()


def test_an_arm_that_falls_with_a_passive_joint_is_told_why_not_to_relax_a_bound(tmp_path: Path) -> None:
    """The same chain held out horizontally: with no torque at all it falls from its start pose. The refusal said
    "binding constraint ddq ...; relax system.limits.acceleration, or lower system.base_freq_hz", which no value
    of either cured (acceleration 40, base_freq_hz 0.02 were tried). It now says the arm does not hold itself up
    and names the joint no actuator drives."""
    model = tmp_path / "passive_out.xml"
    model.write_text(
        '<mujoco model="passive_out"><compiler angle="radian"/><worldbody><body name="l1" pos="0 0 0.6">'
        '<joint name="j1" axis="0 0 1" range="-2 2"/><geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>'
        '<body name="l2" pos="0.3 0 0"><joint name="j2" axis="0 1 0" range="-2 2" damping="0.05"/>'
        '<geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.025"/><body name="l3" pos="0.25 0 0">'
        '<joint name="j3" axis="0 1 0" range="-2 2"/><geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02"/>'
        '</body></body></body></worldbody><actuator><motor joint="j1" ctrlrange="-20 20"/>'
        '<motor joint="j3" ctrlrange="-10 10"/></actuator></mujoco>'
    )
    with pytest.raises(
        InfeasibleExcitationError, match=r"no actuator drives \(j2\) .*it does not hold itself up"
    ) as err:
        run(compose_config(["record=none", "system=auto", f"system.mjcf={model}"]), output_dir=tmp_path / "run")
    assert err.value.bound is None and "relax" not in str(err.value)
    # every joint actuated, but asked to be driven open loop: the cure is tracking it, not more actuators
    both = model.read_text().replace('<motor joint="j3"', '<motor joint="j2" ctrlrange="-10 10"/><motor joint="j3"')
    model.write_text(both)
    overrides = ["record=none", "system=auto", f"system.mjcf={model}", "system.torque_driven=true"]
    with pytest.raises(
        InfeasibleExcitationError, match=r"^driven by torque \(system\.torque_driven=true\), .* set system"
    ):
        run(compose_config(overrides), output_dir=tmp_path / "run2")


def test_an_open_loop_design_no_torque_can_keep_names_its_bound_and_setting(tmp_path: Path) -> None:
    # the wheel pendulum's unactuated joint may not move faster than 0.01 rad/s: the torque search fails, and
    # says which bound and which key set it (it used to say "down to 1 x the torque bound" after filling)
    cfg = compose_config(["record=none", "system=wheel_pendulum", "system.limits.velocity=[0.01,150]"])
    with pytest.raises(InfeasibleExcitationError) as err:
        run(cfg, output_dir=tmp_path)
    message = str(err.value)
    assert "binding constraint dq (bound pendulum 0.01, wheel 150 rad/s)" in message
    assert "scaled to the limits" in message and "comes from system.limits.velocity" in message
    assert err.value.bound == "dq" and not (tmp_path / "results.json").exists()


def test_results_json_is_replaced_whole(tmp_path: Path) -> None:
    (tmp_path / "results.json").write_text('{"old": true}')
    run(compose_config(["record=none", "system=pendulum", "overwrite=true"]), output_dir=tmp_path)
    results = json.loads((tmp_path / "results.json").read_text())
    _check_schema(results)
    assert not list(tmp_path.glob(".*.tmp"))


def test_the_derivative_cut_off_rises_where_coulomb_friction_is_fitted() -> None:
    """A reversal steps the friction torque by 2 Fc; a 5 Hz low-pass spreads the acceleration's step over 0.2 s
    where the regressor's Fc sign(dq) has none of it (SO-ARM100 Fc2, Fc3: z +1.7 to +2.0 over seeds 0-5, then
    -0.3 and +0.1 at 15 Hz). A cut-off the config sets is kept as it is."""
    from excitation.fourier import FourierDesign
    from harness.run import COULOMB_MIN_CUTOFF_HZ, _derivative_options

    design = FourierDesign(0.1, np.zeros((2, 5)), np.zeros((2, 5)), np.zeros(2))
    plain = compose_config(["system=two_link"])
    dry = compose_config(["system=two_link", "system.effects=[armature,coulomb_friction]"])
    fixed = compose_config(["system=two_link", "system.effects=[coulomb_friction]", "identify.cutoff_hz=7"])
    assert _derivative_options(plain, design)["cutoff_hz"] == 5.0
    assert _derivative_options(dry, design)["cutoff_hz"] == COULOMB_MIN_CUTOFF_HZ == 15.0
    assert _derivative_options(fixed, design)["cutoff_hz"] == 7.0


@pytest.mark.parametrize(
    ("argv", "config", "message"),
    [
        (["system.path=/tmp/arm.xml"], "config", r"Key 'path' is not in struct; did you mean system\.mjcf\?"),
        (["system.urdf=/tmp/arm.urdf"], "config", r"did you mean system\.mjcf\?"),
        (["data.file=/tmp/log.csv"], "diagnose", r"Key 'file' is not in struct; did you mean data\.path\?"),
    ],
)
def test_the_names_people_reach_for_point_to_the_key_that_is_read(argv: list[str], config: str, message: str) -> None:
    """No spelling distance takes `system.path` to `system.mjcf` (or `data.file` to `data.path`, a value still
    missing there): the refusal names the key anyway."""
    from harness.validate import check_command_line

    with pytest.raises(ConfigError, match=message):
        check_command_line(argv, REPO / "conf", config)


def test_a_required_key_set_with_the_force_prefix_is_accepted() -> None:
    """`++data.path=` was refused with "did you mean data.path?": a value still missing (`???`) is not `in` its
    mapping for OmegaConf, so the key read as absent and as its own nearest neighbour."""
    from harness.validate import check_command_line

    check_command_line(["system=two_link", "data=csv", "++data.path=log.csv"], REPO / "conf", "diagnose")
    check_command_line(["system=auto", "++system.mjcf=mjcf/two_link.xml"], REPO / "conf", "config")


def test_a_sliding_rule_that_keeps_too_few_rows_names_each_joints_bound() -> None:
    """The refusal listed the bounds as a bare list, with no joint names (a URDF's three planar joints)."""
    from omegaconf import OmegaConf

    from dynamics.plant import load_plant
    from dynamics.regressor import ParameterModel
    from harness.run import _sliding
    from identify.derivatives import States

    plant = load_plant("two_link")
    n = 200
    slow = np.full((n, plant.nv), 0.001)
    states = States(np.zeros((n, plant.nv)), slow, np.zeros((n, plant.nv)), np.ones(n, bool))
    cfg = OmegaConf.create({"system": {"friction_min_speed": 0.05}})
    with pytest.raises(ConfigError, match=r"per joint: shoulder 0\.05, elbow 0\.05\)"):
        _sliding(cfg, ParameterModel(plant, ("coulomb_friction",)), states)

"""Issue 13: no silent garbage, no lost or mixed runs, one-line errors. One block per numbered problem.

Faults are injected for real where the machine allows it (SIGKILL and SIGTERM sent to the job's process, a
tiny or read-only tmpfs mounted as root) and through a patched writer otherwise.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from dynamics.errors import DataError
from dynamics.plant import load_plant
from envs.dataset import atomic_write, scratch_folder, write_csv
from envs.measured import read_measured
from harness import report
from harness.record import save_recording
from harness.run import run
from harness.rundir import LOCK_NAME, RunFolderError, claim, terminate_as_exit
from harness.setup import with_auto_system, with_model_defaults
from harness.validate import ConfigError, check_command_line, check_group_overrides, validate_run_config
from tests.conftest import compose_config

REPO = Path(__file__).resolve().parents[1]
CONF = REPO / "conf"


def _cli(*args: str, module: str = "harness.run", timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", module, *args], cwd=REPO, capture_output=True, text=True, timeout=timeout, check=False
    )


def _one_line_error(proc: subprocess.CompletedProcess, *needles: str) -> None:
    """Exit status 2, no traceback, and the last stderr line names the problem."""
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-2000:]
    last = proc.stderr.strip().splitlines()[-1]
    for needle in needles:
        assert needle in last, last


def _wait_for_lock(folder: Path, timeout_s: float = 120) -> int:
    """The pid written in `folder`'s lock file once a run holds it (the run creates the file, locks it and then
    writes its pid: a read in between finds it empty)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with contextlib.suppress(OSError, ValueError, IndexError):
            return int((folder / LOCK_NAME).read_text().split()[0])
        time.sleep(0.05)
    raise AssertionError(f"no run took the lock of {folder}")


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished pendulum run (results.json, data.csv) made under umask 022."""
    out = tmp_path_factory.mktemp("finished")
    old = os.umask(0o022)
    try:
        run(compose_config(["record=none", "system=pendulum"]), output_dir=out)
    finally:
        os.umask(old)
    return out


def _mount_tmpfs(target: Path, *options: str) -> bool:
    target.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        return False
    proc = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", ",".join(options), "tmpfs", str(target)], capture_output=True, check=False
    )
    return proc.returncode == 0


@contextlib.contextmanager
def _tmpfs(target: Path, *options: str) -> Iterator[Path]:
    if not _mount_tmpfs(target, *options):
        pytest.skip("mounting a tmpfs needs root with CAP_SYS_ADMIN; the patched-writer test covers the same path")
    try:
        yield target
    finally:
        subprocess.run(["umount", "-l", str(target)], capture_output=True, check=False)


# 1. spikes in q on a file without dq ---------------------------------------------------------------------------


def _spiked_csv(path: Path, fraction: float, *, n: int = 3000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A pendulum record at 500 Hz without dq, with isolated spikes of 0.3-0.6 rad in `fraction` of its rows."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 500.0
    q = 0.8 * np.sin(2 * np.pi * 0.3 * t) + 0.3 * np.sin(2 * np.pi * 1.1 * t + 0.4)
    q_meas = q + 1e-5 * rng.standard_normal(n)
    k = round(fraction * n)
    candidates = np.arange(20, n - 20, 3)  # isolated: never two spikes within two rows
    rows = np.sort(rng.choice(candidates, size=k, replace=False))
    q_meas[rows] += rng.choice([-1, 1], size=k) * rng.uniform(0.3, 0.6, size=k)
    tau = 0.3 * np.sin(q) + 0.01 * rng.standard_normal(n)
    np.savetxt(path, np.column_stack([t, q_meas, tau]), delimiter=",", header="time,q_swing,tau_swing", comments="")
    return rows, q


@pytest.mark.parametrize("fraction", [0.0067, 0.0099])
def test_spikes_in_q_without_dq_are_repaired_with_a_report(tmp_path: Path, fraction: float) -> None:
    rows, q_clean = _spiked_csv(tmp_path / "spiked.csv", fraction)
    data = read_measured(tmp_path / "spiked.csv", load_plant("pendulum"))
    glitches = [r for r in data.meta["repairs"] if r.kind == "glitch"]
    assert len(glitches) == 1 and set(glitches[0].rows) == set(rows.tolist())
    assert f"{len(rows)} glitch(es)" in glitches[0].message
    assert np.max(np.abs(data.q[:, 0] - q_clean)) < 1e-3  # the spikes are gone, the motion is kept


def test_spikes_past_the_stated_fraction_are_refused(tmp_path: Path) -> None:
    _spiked_csv(tmp_path / "spiked.csv", 0.02)
    with pytest.raises(DataError, match=r"spiked\.csv: column 'q_swing' has 60 glitch samples .* more than 1%"):
        read_measured(tmp_path / "spiked.csv", load_plant("pendulum"))


# 2. a run folder belongs to one run ----------------------------------------------------------------------------


def test_a_concurrent_run_into_the_same_folder_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "shared"
    args = ["system=wheel_pendulum", "record=none", f"hydra.run.dir={out}"]
    first = subprocess.Popen(
        [sys.executable, "-m", "harness.run", *args, "seed=1"],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        pid = _wait_for_lock(out)
        second = _cli(*args, "seed=2")
        _one_line_error(second, "in use by another run", f"pid {pid}")
    finally:
        _, err = first.communicate(timeout=300)
    assert first.returncode == 0, err[-2000:]
    assert "seed=1" in (out / ".hydra" / "overrides.yaml").read_text()  # the refused run wrote nothing here
    results = json.loads((out / "results.json").read_text())
    assert results["seed"] == 1 and "seed=1" in results["overrides"]
    (row,) = report.report_rows(report.collect(tmp_path))
    assert "seed=1" in row["overrides"] and "seed=2" not in row["overrides"]  # the run's own, not .hydra's
    assert not (out / LOCK_NAME).exists()


def test_a_folder_holding_a_users_results_is_refused_without_overwrite(tmp_path: Path) -> None:
    (tmp_path / "results.json").write_text('{"mine": true}')
    (tmp_path / "data.csv").write_text("time,q\n0,0\n")
    with pytest.raises(RunFolderError, match=r"already holds data\.csv, results\.json .*overwrite=true"):
        run(compose_config(["record=none", "system=pendulum"]), output_dir=tmp_path)
    assert (tmp_path / "results.json").read_text() == '{"mine": true}'
    assert (tmp_path / "data.csv").read_text() == "time,q\n0,0\n"
    for key in ("hydra.run.dir", "++hydra.run.dir"):  # Hydra's force-add form sets the folder as well
        proc = _cli("system=pendulum", "record=none", f"{key}={tmp_path}")
        _one_line_error(proc, "already holds", "overwrite=true")
    assert (tmp_path / "results.json").read_text() == '{"mine": true}'
    assert not (tmp_path / ".hydra").exists()  # refused before Hydra wrote its files into the folder
    assert not (tmp_path / "failure.json").exists()  # the folder is not this run's: nothing added to it


@pytest.mark.parametrize(
    ("args", "allowed"),
    [
        (["overwrite=true"], True),
        (["overwrite=True"], True),
        (["++overwrite=TRUE"], True),
        (["+overwrite=true"], True),
        (["overwrite=true", "overwrite=false"], False),  # the last setting counts, as in Hydra
        (["overwrite=false"], False),
        (["overwrite_x=true"], False),
        ([], False),
    ],
)
def test_overwrite_is_read_as_hydra_reads_it(tmp_path: Path, args: list[str], allowed: bool) -> None:
    """`overwrite=True` and `++overwrite=true` were refused with "pass overwrite=true": the check matched the
    literal text, while Hydra reads any case and the `+`/`++` forms."""
    from harness.rundir import check_output_override

    (tmp_path / "results.json").write_text('{"mine": true}')
    argv = ["system=pendulum", f"hydra.run.dir={tmp_path}", *args]
    if allowed:
        check_output_override(argv, ("results.json",))
    else:
        with pytest.raises(RunFolderError, match=r"already holds results\.json.*pass overwrite=true"):
            check_output_override(argv, ("results.json",))


def test_an_overwrite_that_fails_before_it_starts_leaves_the_finished_runs_record(tmp_path: Path) -> None:
    """overwrite=true with a value refused inside the run (after Hydra wrote its files): the finished run's
    results stayed, but its `.hydra/` config and log were the failed run's, which described other outputs."""
    out = tmp_path / "run"
    assert _cli("system=pendulum", "record=none", "system.periods=1", f"hydra.run.dir={out}").returncode == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    proc = _cli("system=pendulum", "record=none", "system.periods=-1", "overwrite=true", f"hydra.run.dir={out}")
    _one_line_error(proc, "system.periods must be > 0")
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before


def test_a_sweep_into_a_folder_of_finished_jobs_is_refused_before_hydra_writes(tmp_path: Path) -> None:
    """Hydra rewrote multirun.yaml and the old jobs' .hydra/ before each job refused its folder, and the sweep's
    summary then named the old jobs as this sweep's."""
    sweep = tmp_path / "sweep"
    (sweep / "0" / ".hydra").mkdir(parents=True)
    (sweep / "0" / "results.json").write_text('{"old": true}')
    (sweep / "0" / ".hydra" / "overrides.yaml").write_text("- seed=0\n")
    (sweep / "multirun.yaml").write_text("old: true\n")
    before = {p.relative_to(sweep): p.read_bytes() for p in sweep.rglob("*") if p.is_file()}
    for key in ("hydra.sweep.dir", "++hydra.sweep.dir"):
        proc = _cli("-m", "system=pendulum", "record=none", "seed=1,2", f"{key}={sweep}")
        _one_line_error(proc, f"sweep folder {sweep} already holds finished jobs (0/results.json)", "overwrite=true")
    assert {p.relative_to(sweep): p.read_bytes() for p in sweep.rglob("*") if p.is_file()} == before


def test_a_sweep_rerun_whose_job_fails_before_it_replaces_the_old_results_counts_it_failed(tmp_path: Path) -> None:
    """overwrite=true into a finished sweep, one job refused by a bad value before it could replace its folder's
    results: those stay (the earlier run's), but the sweep exited 0 and listed no failure, and the report read
    the old results as this job's."""
    sweep = tmp_path / "sweep"
    common = ("-m", "system=pendulum", "record=none", f"hydra.sweep.dir={sweep}")
    assert _cli(*common, "system.periods=1,2").returncode == 0
    old = (sweep / "1_pendulum" / "results.json").read_bytes()
    proc = _cli(*common, "system.periods=1,-1", "overwrite=true")
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert "1 of 2 job(s) failed" in proc.stderr and "system.periods must be > 0" in proc.stderr
    assert (sweep / "1_pendulum" / "results.json").read_bytes() == old  # nothing already written is lost
    failure = json.loads((sweep / "1_pendulum" / "failure.json").read_text())["error"]
    assert "system.periods must be > 0" in failure and "an earlier run's" in failure
    rows = {r["job"]: r for r in report.report_rows(report.collect(sweep))}
    assert rows["0_pendulum"]["status"] == "ok" and rows["1_pendulum"]["status"] == "failed"
    assert _cli(*common, "system.periods=1,2", "overwrite=true").returncode == 0  # replaced: the failure goes with it
    assert not (sweep / "1_pendulum" / "failure.json").exists()


def test_sweep_jobs_that_share_one_folder_fail_the_sweep(tmp_path: Path) -> None:
    """hydra.sweep.subdir=same: the second job found the first's results (refused, or with overwrite=true it
    replaced them), and the sweep exited 0 with one folder of results for two jobs."""
    sweep = tmp_path / "sweep"
    for extra in ((), ("overwrite=true",)):
        proc = _cli(
            "-m",
            "system=pendulum",
            "record=none",
            "seed=1,2",
            f"hydra.sweep.dir={sweep}",
            "hydra.sweep.subdir=same",
            *extra,
        )
        assert proc.returncode == 1, proc.stderr[-2000:]
        assert f"jobs 0, 1 shared the folder {(sweep / 'same').resolve()}" in proc.stderr, proc.stderr[-2000:]
    # a sweep whose jobs have folders of their own still exits 0: test_a_sweep_rerun_whose_job_fails_... checks it


@pytest.mark.parametrize(("tool", "foreign"), [("harness.run", "diagnosis.json"), ("harness.diagnose", "results.json")])
def test_a_folder_holding_the_other_tools_results_is_refused_even_with_overwrite(
    tmp_path: Path, tool: str, foreign: str
) -> None:
    """A sysid-run into a sysid-diagnose folder (or the reverse) would put its outputs beside the other's and
    replace the other's `.hydra/` record of its config."""
    (tmp_path / foreign).write_text('{"theirs": true}')
    (tmp_path / ".hydra").mkdir()
    (tmp_path / ".hydra" / "config.yaml").write_text("theirs: true\n")
    for extra in ((), ("overwrite=true",)):
        proc = _cli("system=pendulum", f"hydra.run.dir={tmp_path}", *extra, module=tool)
        _one_line_error(proc, f"holds {foreign}", "another tool")
    assert (tmp_path / foreign).read_text() == '{"theirs": true}'
    assert (tmp_path / ".hydra" / "config.yaml").read_text() == "theirs: true\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([foreign, ".hydra"])
    own = ("data.csv", "results.json") if foreign == "diagnosis.json" else ("diagnosis.json",)
    with pytest.raises(RunFolderError, match=f"holds {foreign}"), claim(tmp_path, outputs=own, overwrite=True):
        pass


def test_a_diverging_simulation_is_one_error_line_and_mujocos_warning_goes_to_the_log(tmp_path: Path) -> None:
    """A two-link arm at a 50 ms step diverges: MuJoCo printed its own "WARNING: Nan, Inf or huge value in QACC"
    and a blank line on stderr before the run's error line. The warning now goes to the job's log."""
    model = tmp_path / "coarse.xml"
    model.write_text(
        '<mujoco model="coarse"><compiler angle="radian"/><option timestep="0.05"/><worldbody>'
        '<body name="l1" pos="0 0 1"><joint name="j1" axis="0 1 0" range="-2 2" damping="0.01"/>'
        '<geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02" mass="0.5"/><body name="l2" pos="0 0 -0.3">'
        '<joint name="j2" axis="0 1 0" range="-2 2"/><geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02" '
        'mass="0.3"/></body></body></worldbody><actuator><motor joint="j1" ctrlrange="-5 5"/>'
        '<motor joint="j2" ctrlrange="-5 5"/></actuator></mujoco>'
    )
    out = tmp_path / "run"
    proc = _cli(f"system.mjcf={model}", f"hydra.run.dir={out}", "record=none")
    _one_line_error(proc, "coarse: simulation diverged at t = ", "lower the physics timestep")
    assert "WARNING" not in proc.stderr and "\n\n" not in proc.stderr, proc.stderr
    assert "MuJoCo: Nan, Inf or huge value in QACC" in (out / "sysid-run.log").read_text()


def test_a_model_named_like_an_output_in_the_run_folder_is_the_runs_input_and_is_kept(tmp_path: Path) -> None:
    """An MJCF called model.xml in the run folder (the name a URDF's run gives its compiled MJCF): sysid-run
    refused the folder as holding another run's model.xml, and with overwrite=true deleted the model it had just
    read (an MJCF's run writes no model.xml). Now it is the run's input: neither a finished run's output nor
    retired, first run and rerun alike."""
    model = tmp_path / "model.xml"
    shutil.copy(REPO / "mjcf" / "pendulum.xml", model)
    text = model.read_bytes()
    for extra in ((), ("overwrite=true",)):
        proc = _cli(f"system.mjcf={model}", f"hydra.run.dir={tmp_path}", "record=none", *extra)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert model.read_bytes() == text
        assert (tmp_path / "results.json").is_file()
    assert json.loads((tmp_path / "results.json").read_text())["config"]["system"]["mjcf"] == str(model)


def test_a_diagnosis_of_a_calibrated_mjcf_in_its_own_folder_keeps_it(finished_run: Path, tmp_path: Path) -> None:
    """Diagnosing again, into the same folder, with the calibrated MJCF an earlier diagnosis wrote there as the
    model: the rerun (overwrite=true) retired the earlier diagnosis's calibrated MJCFs, the model it had read
    among them, and deleted it. Now it stays as it was, beside the new diagnosis's own."""
    first = ("diagnose.recording=false", "diagnose.final_fit=false", f"data.path={finished_run / 'data.csv'}")
    proc = _cli("system=pendulum", f"hydra.run.dir={tmp_path}", *first, module="harness.diagnose")
    assert proc.returncode == 0, proc.stderr[-2000:]
    model = tmp_path / "pendulum_calibrated.xml"
    text = model.read_bytes()
    again = (f"system.mjcf={model}", f"hydra.run.dir={tmp_path}", "overwrite=true", *first)
    proc = _cli(*again, module="harness.diagnose")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert model.read_bytes() == text
    assert (tmp_path / "pendulum_calibrated_calibrated.xml").is_file()
    # named so that its own calibrated MJCF would be the model it reads: refused before any work
    proc = _cli(*again, "system.name=pendulum", module="harness.diagnose")
    _one_line_error(proc, "this run writes pendulum_calibrated.xml, and that file is its input", "system.name")
    assert model.read_bytes() == text


@pytest.mark.skipif(
    not (REPO.parent / "shared" / "data" / "dfki_double_pendulum_c1").is_dir(),
    reason="../shared/data/ is not beside the project (the DFKI lab's reference models)",
)
def test_reference_models_given_for_a_robot_they_do_not_fit_are_refused(finished_run: Path, tmp_path: Path) -> None:
    """The DFKI two-joint reference models named explicitly for a one-joint pendulum were dropped without a
    word; `auto` (found beside the data) still skips them, as they belong to another robot's logs."""
    model = REPO.parent / "shared" / "data" / "dfki_double_pendulum_c1" / "authors_identified"
    given = f"diagnose.references=[{model / 'design_C.1_model_1.0.yml'}]"
    data = f"data.path={finished_run / 'data.csv'}"
    proc = _cli("system=pendulum", data, given, f"hydra.run.dir={tmp_path}", module="harness.diagnose")
    _one_line_error(proc, "diagnose.references: the reference models are of the two-joint", "pendulum has 1 joint")
    assert not (tmp_path / "diagnosis.json").exists()


def test_a_run_that_would_write_over_its_input_is_refused_before_anything_is_replaced(tmp_path: Path) -> None:
    """`claim(inputs=...)`: an output the run writes that is the file it read is refused before any work; one
    that it only retires is kept, and if it writes it after all, the last guard refuses it when the outputs
    are put in place, the previous outputs as they were."""
    (tmp_path / "model.xml").write_text("<mujoco/>")
    (tmp_path / "results.json").write_text("{}")
    inputs, names = [tmp_path / "model.xml"], ("model.xml", "results.json")
    with pytest.raises(RunFolderError, match=r"this run writes model\.xml, and that file is its input"):
        with claim(tmp_path, outputs=names, overwrite=True, inputs=inputs):
            pass
    with claim(tmp_path, outputs=names, overwrite=True, inputs=inputs, writes=("results.json",)) as f:
        assert f.outputs == ("results.json",) and f.inputs == ("model.xml",)
        with pytest.raises(RunFolderError, match=r"would write model\.xml over the file it read"), f.staged() as stage:
            (stage / "model.xml").write_text("<mujoco><worldbody/></mujoco>")
            (stage / "results.json").write_text('{"new": 1}')
    assert (tmp_path / "model.xml").read_text() == "<mujoco/>"
    assert (tmp_path / "results.json").read_text() == "{}"


@pytest.mark.parametrize("stop", ["full_disk", "sigterm"])
def test_a_rerun_failing_or_stopped_while_writing_keeps_the_old_results_as_they_were(
    finished_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, stop: str
) -> None:
    """The previous outputs were removed before the new ones were written (the recording takes seconds): a rerun
    with overwrite=true stopped then, or failing on a full disk, left neither the old results nor new ones. The
    new outputs are now written into a staging folder and replace the old ones only once all are written."""
    out = tmp_path / "rerun"
    out.mkdir()
    old = {name: (finished_run / name).read_bytes() for name in ("results.json", "data.csv")}
    for name, data in old.items():
        (out / name).write_bytes(data)
    import harness.run as run_module

    def fail(path: Path, payload: dict) -> None:
        if stop == "sigterm":
            raise SystemExit(143)  # what `terminate_as_exit` makes of SIGTERM
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(run_module, "write_json", fail)
    with pytest.raises(OSError if stop == "full_disk" else SystemExit):
        run(compose_config(["record=none", "system=pendulum", "seed=5", "overwrite=true"]), output_dir=out)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == old  # nothing staged or half-written is left


def test_results_json_is_published_last(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every output is written into a staging folder first, results.json last; none is in the run folder before
    all are written; then they are renamed into place, results.json last."""
    import harness.run as run_module
    import harness.rundir as rundir_module

    seen: list[tuple[set[str], set[str]]] = []
    real = run_module.write_json

    def spy(path: Path, payload: dict) -> None:
        seen.append(({p.name for p in path.parent.iterdir()}, {p.name for p in tmp_path.iterdir()}))
        real(path, payload)

    published: list[str] = []
    real_replace = rundir_module.os.replace

    def replace(src: Path, dst: Path) -> None:  # (os.replace itself: every atomic write's too)
        if Path(src).parent.name.startswith(".staged.") and not Path(src).name.startswith("."):
            published.append(Path(dst).name)
        real_replace(src, dst)

    monkeypatch.setattr(run_module, "write_json", spy)
    monkeypatch.setattr(rundir_module.os, "replace", replace)
    run(compose_config(["system=pendulum"]), output_dir=tmp_path)
    assert len(seen) == 1 and seen[0][0] == {"data.csv", "recording.rrd"}
    assert {n for n in seen[0][1] if not n.startswith(".staged.")} == {LOCK_NAME}
    assert published == ["data.csv", "recording.rrd", "results.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv", "recording.rrd", "results.json"]


# 3. sweeps -----------------------------------------------------------------------------------------------------


def test_a_job_killed_by_sigkill_inside_a_joblib_sweep_is_recorded_and_the_others_finish(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "harness.run",
            "-m",
            "hydra/launcher=joblib",
            "hydra.launcher.n_jobs=2",
            f"hydra.sweep.dir={sweep}",
            "record=none",
            "system=wheel_pendulum,pendulum",
        ],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        pid = _wait_for_lock(sweep / "0_wheel_pendulum")
        os.kill(pid, signal.SIGKILL)  # as the out-of-memory killer would
    finally:
        _, err = proc.communicate(timeout=300)
    assert proc.returncode == 1, err[-3000:]
    assert "TerminatedWorkerError" not in err
    assert "1 of 2 job(s) failed" in err
    failure = json.loads((sweep / "0_wheel_pendulum" / "failure.json").read_text())
    assert "killed by SIGKILL" in failure["error"]
    assert (sweep / "1_pendulum" / "results.json").is_file()
    rows = {r["job"]: r for r in report.report_rows(report.collect(sweep))}
    assert rows["1_pendulum"]["status"] == "ok"
    assert rows["0_wheel_pendulum"]["status"] == "failed" and "SIGKILL" in rows["0_wheel_pendulum"]["error"]


def test_a_config_group_typo_in_a_sweep_lists_the_valid_choices_before_any_job(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    proc = _cli("-m", f"hydra.sweep.dir={sweep}", "record=none", "system=pendulum,tow_link")
    systems = ", ".join(sorted(p.stem for p in (CONF / "system").glob("*.yaml")))
    _one_line_error(proc, "unknown system 'tow_link'", f"valid choices: {systems}")
    assert not sweep.exists()
    with pytest.raises(
        ConfigError, match=r"unknown estimator 'wlss' \(in the sweep estimator=ols,wlss\); valid choices: .*ols.*wls"
    ):
        check_group_overrides(["estimator=ols,wlss"], CONF)
    check_group_overrides(["system=pendulum,two_link", "hydra/launcher=joblib", "seed=range(0,3)"], CONF)


# 4. a full disk does not hang ------------------------------------------------------------------------------------


def test_a_recording_on_a_full_disk_fails_at_once_and_leaves_nothing(tmp_path: Path) -> None:
    script = (
        "import numpy as np, rerun as rr, sys\n"
        "from harness.record import save_recording, log_joint_series\n"
        "t = np.arange(200000) * 1e-3\n"
        "try:\n"
        f"    save_recording('{tmp_path}/disk/r.rrd', 'x', lambda rec: log_joint_series(rec, 's', t, np.sin(t)))\n"
        "except OSError as err:\n"
        "    print('ENOSPC' if err.errno == 28 else err)\n"
    )
    with _tmpfs(tmp_path / "disk", "size=64k"):
        # a hang (rerun's own file sink waits forever on ENOSPC) fails the test through the timeout
        proc = subprocess.run(
            [sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=120, check=False
        )
        assert proc.stdout.strip() == "ENOSPC", proc.stderr[-2000:]
        assert not list((tmp_path / "disk").iterdir())


def test_a_run_on_a_full_disk_is_one_line_and_leaves_no_results(tmp_path: Path) -> None:
    with _tmpfs(tmp_path / "disk", "size=256k"):
        out = tmp_path / "disk" / "run"
        proc = _cli("system=pendulum", f"hydra.run.dir={out}")
        _one_line_error(proc, "No space left on device")
        assert not (out / "results.json").exists()
        assert not list(out.glob(".*.tmp"))


def test_save_recording_writes_a_readable_file_through_atomic_write(tmp_path: Path) -> None:
    from tests.conftest import rrd_rows

    def fill(rec) -> None:  # type: ignore[no-untyped-def]
        import rerun as rr

        rec.log("x", rr.Scalars(1.0))

    save_recording(tmp_path / "a.rrd", "t", fill)
    assert rrd_rows(tmp_path / "a.rrd")["/x"] == 1
    assert [p.name for p in tmp_path.iterdir()] == ["a.rrd"]


# 5. excitation.harmonics -------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ("0", "excitation.harmonics must be >= 1, got 0"),
        ("-3", "excitation.harmonics must be >= 1, got -3"),
        ("1000", "excitation.harmonics must be between 1 and 50, got 1000"),
        ("2.5", "excitation.harmonics must be an integer, got 2.5"),
        ("five", "excitation.harmonics must be an integer, got 'five'"),
    ],
)
def test_harmonics_are_checked_before_any_work(value: str, message: str) -> None:
    cfg = compose_config(["system=pendulum", f"excitation.harmonics={value}"])
    with pytest.raises(ConfigError, match=message.replace(".", r"\.")):
        validate_run_config(cfg, load_plant("pendulum"))


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("system.periods=1e9", "system.periods"),
        ("system.sensor.sample_rate_hz=1e9", "system.periods"),
        ("validation.periods=1e7", "validation.periods"),
    ],
)
def test_a_record_too_long_to_hold_is_refused_before_anything_is_allocated(override: str, key: str) -> None:
    cfg = compose_config(["system=pendulum", override])
    with pytest.raises(ConfigError, match=rf"{key}=.* makes a record of .* samples; at most 2e\+06"):
        validate_run_config(cfg, load_plant("pendulum"))


def test_the_runs_derived_state_cut_off_stays_where_differences_are_accurate() -> None:
    """10 x the top harmonic, at least 5 Hz: on a model stepped at 50 ms (20 Hz samples) that was 5 Hz, which the
    differences cannot follow (above an eighth of the rate they lose a fifth of the acceleration and more, and
    the filter now refuses such a cut-off); it is capped at 2.5 Hz, still 5 x the 0.5 Hz top harmonic."""
    from excitation.fourier import FourierDesign
    from harness.run import _derivative_options

    design = FourierDesign(0.1, np.zeros((1, 5)), np.zeros((1, 5)), np.zeros(1))
    for rate, cutoff in ((20.0, 2.5), (500.0, 5.0)):
        cfg = compose_config(["system=pendulum", f"system.sensor.sample_rate_hz={rate}"])
        assert _derivative_options(cfg, design)["cutoff_hz"] == pytest.approx(cutoff)


def test_harmonics_are_bounded_by_the_sampling() -> None:
    cfg = compose_config(["system=pendulum", "excitation.harmonics=30", "system.sensor.sample_rate_hz=20"])
    with pytest.raises(ConfigError, match=r"between 1 and .* Nyquist frequency 10 Hz"):
        validate_run_config(cfg, load_plant("pendulum"))
    validate_run_config(compose_config(["system=pendulum", "excitation.harmonics=8"]), load_plant("pendulum"))


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (
            ["system=pendulum", "system.base_freq_hz=300"],
            r"system\.base_freq_hz must be <= 25 at system\.sensor\.sample_rate_hz=500",
        ),
        (["system=pendulum", "identify.cutoff_hz=250"], r"identify\.cutoff_hz must be < 250, got 250"),
        (
            ["system=pendulum", "identify.cutoff_hz=100"],
            r"identify\.cutoff_hz=100 Hz is above 62\.5 Hz, an eighth of system\.sensor\.sample_rate_hz=500: ",
        ),
        (
            ["system=pendulum", "estimator=iv", "estimator.options.reference_cutoff_hz=100"],
            r"estimator\.options\.reference_cutoff_hz=100 Hz is above 62\.5 Hz, an eighth of ",
        ),
        (
            [f"system.mjcf={REPO / 'mjcf' / 'two_link.xml'}", "system.limits.clearance_m=-1"],
            r"system\.limits\.clearance_m must be >= 0, got -1",
        ),
        (
            [f"system.mjcf={REPO / 'mjcf' / 'two_link.xml'}", "system.controller.servo_feedforward=2"],
            r"system\.controller\.servo_feedforward must be true or false, got 2",
        ),
    ],
)
def test_a_value_out_of_its_range_is_named_by_its_key(overrides: list[str], message: str) -> None:
    """The frequency that breaks the sampling is named (not the harmonics it implies), a cut-off at the Nyquist
    frequency is refused here as the filter refuses it later, and a negative clearance is no clearance."""
    cfg = compose_config(with_auto_system(overrides))
    plant = load_plant(cfg.system.mjcf)
    with pytest.raises(ConfigError, match=message):
        validate_run_config(with_model_defaults(cfg, plant), plant)


# 6. sysid-report survives a corrupt job file -------------------------------------------------------------------


def test_report_survives_corrupt_job_files_and_names_them(finished_run: Path, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    good = tmp_path / "0_ok"
    good.mkdir()
    (good / "results.json").write_bytes((finished_run / "results.json").read_bytes())
    for i, content in enumerate([b'{"system": "pend', b"\x00\x01\x02binary", b"[1, 2]", b'{"system": "x"}']):
        job = tmp_path / f"{i + 1}_bad"
        job.mkdir()
        (job / "results.json").write_bytes(content)
    assert report.main([str(tmp_path)]) == 1  # written, and exit 1: jobs failed
    rows = {r["job"]: r for r in report.report_rows(report.collect(tmp_path))}
    assert rows["0_ok"]["status"] == "ok"
    for i in range(1, 5):
        row = rows[f"{i}_bad"]
        assert row["status"] == "failed" and f"{i}_bad/results.json" in row["error"], row
    md = (tmp_path / "report.md").read_text()
    assert "5 jobs, 1 ok, 4 failed" in md and "1_bad/results.json: unreadable or corrupt" in md
    assert "job 1_bad failed" in capsys.readouterr().err


# 7. tracebacks for common mistakes become one line, exit 2 ---------------------------------------------------------


def test_an_unknown_key_or_malformed_value_is_one_config_error() -> None:
    with pytest.raises(ConfigError, match=r"Could not override 'foo'.*Key 'foo' is not in struct"):
        check_command_line(["foo=1"], CONF, "config")
    with pytest.raises(ConfigError, match=r"no viable alternative at input '\[1,'$"):
        check_command_line(["system.limits.velocity=[1,"], CONF, "config")
    check_command_line(["system=arm3", "hydra.run.dir=/tmp/x", "-m", "seed=1,2"], CONF, "config")
    # ... in a sweep too: its first job's overrides are composed before any job starts
    for sweep in (["-m", "seed=1,2", "foo=1"], ["--multirun", "seed=range(0,3)", "estimator.options.bogus=2,3"]):
        with pytest.raises(ConfigError, match=r"Could not override '(foo|estimator.options.bogus)'"):
            check_command_line(sweep, CONF, "config")
    check_command_line(["-m", "system=pendulum,two_link", "excitation.harmonics=range(2,4)"], CONF, "config")
    # a home-folder path: Hydra's lexer stops at the ~ ("LexerNoViableAltException: data.path=~/x.csv; ^")
    with pytest.raises(ConfigError, match=r"a value that begins with ~ must be quoted: data\.path='~/x\.csv'$"):
        check_command_line(["system=two_link", "data.path=~/x.csv"], CONF, "diagnose")
    check_command_line(["system=two_link", "data.path='~/x.csv'"], CONF, "diagnose")
    # a file name with = in it: Hydra's parser alone said "mismatched input '=' expecting <EOF>", naming no key
    with pytest.raises(ConfigError, match=r"a value with = in it must be quoted: data\.path='/d/run=3\.csv'$"):
        check_command_line(["system=two_link", "data.path=/d/run=3.csv"], CONF, "diagnose")
    check_command_line(["system=two_link", "data.path='/d/run=3.csv'"], CONF, "diagnose")
    with pytest.raises(ConfigError, match=r"Could not override 'diagnose\.nokey'"):  # beside a deletion (no =)
        check_command_line(["~diagnose.window_s", "diagnose.nokey=1"], CONF, "diagnose")
    # a system name with a folder in it: refused before Hydra makes outputs/${system.name}/... (sweeps too)
    with pytest.raises(ConfigError, match=r"hydra\.launcher\.n_jobs=0: the number of jobs run at once"):
        check_command_line(["-m", "hydra/launcher=joblib", "hydra.launcher.n_jobs=0", "seed=0,1"], CONF, "config")
    for argv in (["system.name=../x"], ["-m", "seed=0,1", "system.name=ok,my/arm"]):
        with pytest.raises(ConfigError, match=r"system\.name='(\.\./x|my/arm)': it names the outputs"):
            check_command_line(argv, CONF, "config")


def test_a_misspelled_key_is_answered_with_the_key_meant_not_with_a_plus() -> None:
    """Hydra's own message for `system.limts.velocity=3` says to append it with `+`; the run then carried
    `+system.limts.velocity=3` along and never read it."""
    with pytest.raises(ConfigError, match=r"did you mean system\.limits\.velocity\?$") as err:
        check_command_line(["system.limts.velocity=3"], CONF, "config")
    assert "To append" not in str(err.value)
    with pytest.raises(
        ConfigError, match=r"\+system\.limts\.velocity: no such key is read; did you mean system\.limits"
    ):
        check_command_line(["+system.limts.velocity=3"], CONF, "config")
    with pytest.raises(ConfigError, match=r"did you mean diagnose\.selection\.min_gain\?"):
        check_command_line(["+diagnose.selection.min_gian=0.1"], CONF, "diagnose")
    check_command_line(["+data.columns.tau_elbw=x"], CONF, "diagnose")  # a file's column names are free
    check_command_line(["+system.notes=mine"], CONF, "config")  # a new key that misspells nothing is the user's
    check_command_line(["+diagnose.mine={a:1}", "diagnose.mine.a=2"], CONF, "diagnose")  # a key added, then set
    with pytest.raises(ConfigError, match=r"did you mean data\.band_hz\?"):  # a key of the data config chosen
        check_command_line(["data=dfki_double_pendulum", "data.band_hzz=3"], CONF, "diagnose")


def test_an_unknown_key_in_a_sweep_is_one_line_and_exit_2(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    proc = _cli("-m", f"hydra.sweep.dir={sweep}", "system=pendulum", "seed=0,1", "foo=1")
    _one_line_error(proc, "Could not override 'foo'")
    assert not sweep.exists()  # no job started


def test_no_data_path_is_one_line(tmp_path: Path) -> None:
    proc = _cli("system=pendulum", f"hydra.run.dir={tmp_path}", module="harness.diagnose")
    _one_line_error(proc, "data.path is not set")


def test_a_flipped_torque_column_of_a_real_log_is_one_line_and_writes_nothing(tmp_path: Path) -> None:
    from conftest import SHARED_DATA

    log = SHARED_DATA / "dfki_double_pendulum_c0" / "trajectory_01.csv"
    if not log.is_file():
        pytest.skip(f"real DFKI logs not found at {log.parent} (the project was cloned without ../shared)")
    out = tmp_path / "out"
    proc = _cli(
        "system=two_link",
        "data=dfki_double_pendulum",
        f"data.path=[{log},{log.with_name('trajectory_00.csv')}]",
        "++data.columns.tau_elbow={column:tau_meas2,scale:-1}",
        f"hydra.run.dir={out}",
        module="harness.diagnose",
    )
    _one_line_error(proc, "tau_elbow (the file's -1 * tau_meas2) runs against the torque", "sign looks flipped")
    assert not (out / "diagnosis.json").exists()
    # where the motion really needs the opposite torque, the user can say so and the diagnosis runs
    proc = _cli(
        "system=two_link",
        "data=dfki_double_pendulum",
        f"data.path=[{log},{log.with_name('trajectory_00.csv')}]",
        "++data.columns.tau_elbow={column:tau_meas2,scale:-1}",
        "diagnose.check_torque_signs=false",
        "diagnose.recording=false",
        f"hydra.run.dir={out}",
        module="harness.diagnose",
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (out / "diagnosis.json").is_file()


def test_estimator_options_of_another_estimator_are_one_line(tmp_path: Path) -> None:
    proc = _cli("system=pendulum", "estimator.name=ols", f"hydra.run.dir={tmp_path}")
    _one_line_error(proc, "estimator.options.iterations is not an option of estimator 'ols'")


@pytest.mark.parametrize(
    ("estimator", "option", "value", "needle"),
    [
        (
            "filtered",
            "omega",
            "-5",
            "estimator.options.omega of estimator 'filtered' must be a number > 0 rad/s, got -5",
        ),
        ("rls", "alpha", "1.5", "estimator.options.alpha of estimator 'rls' must be a number in (0, 1], got 1.5"),
        ("iv", "period_s", "abc", "estimator.options.period_s of estimator 'iv' must be a number > 0 s (or null)"),
        ("wls", "iterations", "0", "estimator.options.iterations of estimator 'wls' must be an integer >= 1, got 0"),
    ],
)
def test_an_estimator_option_out_of_its_range_is_one_line_before_anything_runs(
    tmp_path: Path, estimator: str, option: str, value: str, needle: str
) -> None:
    proc = _cli(
        "system=pendulum", f"estimator={estimator}", f"estimator.options.{option}={value}", f"hydra.run.dir={tmp_path}"
    )
    _one_line_error(proc, needle)
    assert "[excitation]" not in proc.stderr and not (tmp_path / "results.json").exists()  # refused before the design


def test_every_estimator_option_range_names_an_option_whose_default_it_holds() -> None:
    import inspect

    from identify.estimators import ESTIMATORS, OPTION_RANGES

    assert set(OPTION_RANGES) == set(ESTIMATORS)
    for name, ranges in OPTION_RANGES.items():
        params = inspect.signature(ESTIMATORS[name]).parameters
        for key, domain in ranges.items():
            default = params[key].default
            assert default is None or domain.contains(float(default)), (name, key, default)
        numeric = {
            k for k, p in params.items() if isinstance(p.default, int | float) and not isinstance(p.default, bool)
        }
        assert numeric <= set(ranges), (name, numeric - set(ranges))


def test_unreadable_file_names_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "locked.csv"
    path.write_text("time,q_swing,tau_swing\n0,0,0\n")
    if os.geteuid() != 0:
        path.chmod(0)
    else:  # root reads any file: inject the refusal the file system would give anyone else
        real_open = Path.open

        def refuse(self: Path, *args, **kwargs):  # type: ignore[no-untyped-def]
            if self == path:
                raise PermissionError(errno.EACCES, "Permission denied", str(self))
            return real_open(self, *args, **kwargs)

        monkeypatch.setattr(Path, "open", refuse)
    with pytest.raises(DataError, match=r"locked\.csv: cannot be read: permission denied"):
        read_measured(path, load_plant("pendulum"))


_HEADER = b"time,q_swing,tau_swing\n"


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (_HEADER + b"0,0\x00,0\n", rf"a binary file \(a NUL byte at byte {len(_HEADER) + 3}, line 2\)"),
        (bytes(range(256)) * 4, r"a binary file \(a NUL byte at byte 0, line 1\)"),
        (_HEADER + b"0,0,0\n1,0,caf\xe9\n", rf"not UTF-8 text \(byte 0xe9 at byte {len(_HEADER) + 13}, line 3\)"),
    ],
)
def test_binary_and_non_utf8_files_name_the_file_and_place(tmp_path: Path, content: bytes, message: str) -> None:
    (tmp_path / "bad.csv").write_bytes(content)
    with pytest.raises(DataError, match=r"bad\.csv: " + message):
        read_measured(tmp_path / "bad.csv", load_plant("pendulum"))


def test_a_read_only_run_folder_is_refused_before_any_work(tmp_path: Path) -> None:
    with _tmpfs(tmp_path / "ro", "ro", "size=64k"):
        proc = _cli("system=pendulum", "record=none", f"hydra.run.dir={tmp_path / 'ro' / 'run'}")
        _one_line_error(proc, "is not writable", "Read-only file system")


def test_a_full_disk_found_before_any_work(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import harness.rundir as rundir

    def full(*args, **kwargs):  # type: ignore[no-untyped-def]
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(rundir.os, "fsync", full)
    with pytest.raises(RunFolderError, match="is not writable: no space left on the device"):
        run(compose_config(["record=none", "system=pendulum"]), output_dir=tmp_path / "run")


# 8. outputs follow the umask -------------------------------------------------------------------------------------


def test_outputs_get_the_umasks_permissions(finished_run: Path, tmp_path: Path) -> None:
    for name in ("results.json", "data.csv"):
        assert stat.S_IMODE((finished_run / name).stat().st_mode) == 0o644, name
    old = os.umask(0o027)
    try:
        atomic_write(tmp_path / "x.json", lambda f: f.write("{}"))
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "x.json").stat().st_mode) == 0o640


# 9. messages that name the problem ---------------------------------------------------------------------------------


def test_time_in_milliseconds_is_named(tmp_path: Path) -> None:
    t = np.arange(500) * 2.0  # 2 ms steps written in ms
    table = np.column_stack([t, np.sin(t / 1000), np.cos(t / 1000)])
    np.savetxt(tmp_path / "ms.csv", table, delimiter=",", header="time,q_swing,tau_swing", comments="")
    with pytest.raises(DataError, match=r"ms\.csv: column 'time' .* time looks like milliseconds \(500 Hz then\)"):
        read_measured(tmp_path / "ms.csv", load_plant("pendulum"))


@pytest.mark.parametrize(
    ("data", "name", "given"),
    [
        ("csv", "t", "t"),  # data.columns null
        ("dfki_double_pendulum", "time [ms]", "time [ms]"),  # a config that maps time; a name Hydra must quote
        ("csv", "t", {"column": "t", "scale": 10.0, "offset": 5.0}),  # in tens of ms from 5: both take the factor
    ],
)
def test_the_time_unit_hint_is_an_override_that_works(tmp_path: Path, data: str, name: str, given: object) -> None:
    from omegaconf import OmegaConf

    t = np.arange(500) * 2.0  # 2 ms steps written in ms
    raw = (t - 5.0) / 10.0 if isinstance(given, dict) else t
    table = np.column_stack([raw, np.sin(t / 1000), np.cos(t / 1000), np.zeros(500), np.zeros(500)])
    path = tmp_path / "ms.csv"
    np.savetxt(path, table, delimiter=",", header=f"{name},q_shoulder,q_elbow,tau_shoulder,tau_elbow", comments="")
    plant = load_plant("two_link")
    columns = {"time": given, "q_shoulder": "q_shoulder", "q_elbow": "q_elbow"}
    columns |= {"tau_shoulder": "tau_shoulder", "tau_elbow": "tau_elbow"}
    with pytest.raises(DataError, match=r"command line: '([^']+)'") as err:
        read_measured(path, plant, columns=columns)
    override = re.search(r"command line: '([^']+)'", str(err.value)).group(1)  # type: ignore[union-attr]
    assert override.startswith("++data.columns.time={column:")
    cfg = compose_config(["system=two_link", f"data={data}", override], config_name="diagnose")
    mapped = OmegaConf.to_container(cfg.data.columns)["time"]  # type: ignore[index]
    assert mapped["column"] == name  # type: ignore[index]
    data_read = read_measured(path, plant, columns=columns | {"time": mapped})
    np.testing.assert_allclose(data_read.time, t / 1000, atol=1e-9)


def test_wrong_joint_count_in_a_system_config_is_named() -> None:
    cfg = compose_config(["system=two_link", "system.limits.velocity=[1,2,3]"])
    with pytest.raises(ConfigError, match=r"system\.limits\.velocity has 3 value\(s\) but two_link has 2 joint"):
        validate_run_config(cfg, load_plant("two_link"))


def test_a_directory_given_as_the_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="is a folder, not a file"):
        read_measured(tmp_path, load_plant("pendulum"))


def test_a_named_pipe_given_as_the_file_is_refused_not_waited_on(tmp_path: Path) -> None:
    fifo = tmp_path / "log.csv"
    os.mkfifo(fifo)  # opening it to read would block until a writer came
    with pytest.raises(DataError, match=r"log\.csv: is not a regular file"):
        read_measured(fifo, load_plant("pendulum"))


def test_seed_abc_names_the_key(tmp_path: Path) -> None:
    proc = _cli("system=pendulum", "seed=abc", f"hydra.run.dir={tmp_path}")
    _one_line_error(proc, "seed must be an integer, got 'abc'")


# 10. a record of why a run failed; clean-up on SIGTERM and after SIGKILL ----------------------------------------------


def test_a_failed_single_run_writes_failure_json_and_its_log(tmp_path: Path) -> None:
    proc = _cli("system=pendulum", "record=none", "system.limits.acceleration=1e-6", f"hydra.run.dir={tmp_path}")
    _one_line_error(proc, "binding constraint ddq")
    assert "that bound comes from system.limits.acceleration" in proc.stderr  # the setting to relax, by its key
    failure = json.loads((tmp_path / "failure.json").read_text())
    assert failure["error"].startswith("InfeasibleExcitationError: ") and "Traceback" in failure["traceback"]
    assert "binding constraint ddq" in (tmp_path / "sysid-run.log").read_text()


def _signalled_run(folder: Path, sig: int) -> tuple[int, str]:
    """(exit status, stderr) of a run into `folder` sent `sig` once it holds the folder's lock. The run starts with
    SIGINT and SIGTERM at their defaults and unblocked, as a terminal starts a command: a process that inherits
    SIGINT ignored (a shell's background job, or a test worker that some helper left so) never sees a Ctrl-C, and
    this is about how the run ends on one it does see."""
    reset = (
        "import os, signal, sys; [signal.signal(s, signal.SIG_DFL) for s in (signal.SIGINT, signal.SIGTERM)]; "
        "signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM}); "
        "os.execv(sys.executable, [sys.executable, '-m', 'harness.run', *sys.argv[1:]])"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", reset, "system=wheel_pendulum", "record=none", f"hydra.run.dir={folder}"],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    os.kill(_wait_for_lock(folder), sig)
    _, err = proc.communicate(timeout=120)
    return proc.returncode, err


def test_sigterm_ends_a_run_through_its_clean_up(tmp_path: Path) -> None:
    returncode, err = _signalled_run(tmp_path, signal.SIGTERM)
    assert returncode == 128 + signal.SIGTERM, err[-2000:]
    assert "terminated by SIGTERM" in err.strip().splitlines()[-1]
    assert json.loads((tmp_path / "failure.json").read_text())["error"] == "terminated by SIGTERM"
    assert not list(tmp_path.glob(".*.tmp")) and not (tmp_path / LOCK_NAME).exists()


def test_ctrl_c_ends_a_run_with_one_line_and_status_130(tmp_path: Path) -> None:
    """SIGINT (Ctrl-C) printed the line and then a KeyboardInterrupt traceback, and the process died by the
    signal."""
    inherited = (signal.getsignal(signal.SIGINT), signal.pthread_sigmask(signal.SIG_BLOCK, []))
    returncode, err = _signalled_run(tmp_path, signal.SIGINT)
    assert returncode == 130, (inherited, err[-2000:])
    assert "Traceback" not in err and "interrupted (Ctrl-C)" in err.strip().splitlines()[-1], err[-2000:]
    assert json.loads((tmp_path / "failure.json").read_text())["error"] == "interrupted (Ctrl-C)"
    assert not (tmp_path / LOCK_NAME).exists()


def test_a_ctrl_c_that_numpy_turned_into_a_value_error_is_read_as_ctrl_c() -> None:
    """Ctrl-C arriving while NumPy converts a sequence surfaces as `ValueError: setting an array element with a
    sequence`: the Ctrl-C test above once ended with that as a one-line error and status 2."""
    from harness.results import as_interrupt

    class Stopped:
        def __len__(self) -> int:
            return 2

        def __getitem__(self, i: int) -> float:
            raise KeyboardInterrupt

        def __float__(self) -> float:
            raise KeyboardInterrupt

    with pytest.raises(ValueError, match="setting an array element with a sequence") as caught:
        np.zeros(3)[0] = Stopped()  # type: ignore[call-overload]
    assert isinstance(as_interrupt(caught.value), KeyboardInterrupt)
    other = ValueError("a value error of its own")
    assert as_interrupt(other) is other


def test_sigterm_while_writing_removes_the_temporary_file(tmp_path: Path) -> None:
    def write(f) -> None:  # type: ignore[no-untyped-def]
        f.write("half")
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler raises here
        f.write(" and the rest")

    with pytest.raises(SystemExit) as exit_info, terminate_as_exit():
        atomic_write(tmp_path / "out.json", write)
    assert exit_info.value.code == 128 + signal.SIGTERM
    assert list(tmp_path.iterdir()) == []


def test_temporary_files_left_by_a_killed_run_are_removed_by_the_next(tmp_path: Path) -> None:
    (tmp_path / ".data.csv.x1y2.tmp").write_text("half")
    (tmp_path / "notes.txt").write_text("mine")
    with claim(tmp_path, outputs=("data.csv", "results.json"), overwrite=False):
        assert (tmp_path / LOCK_NAME).is_file()
        with pytest.raises(RunFolderError, match="in use by another run"), claim(tmp_path, outputs=(), overwrite=False):
            pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_scratch_folders_of_killed_processes_are_removed_by_the_next(tmp_path: Path) -> None:
    """SIGKILL leaves no chance to clean up: the diagnosis's scratch folder is named by its pid, and the next
    diagnosis removes the folders of pids that are gone (a live process's folder stays)."""
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    tmp = Path(tempfile.gettempdir())
    orphan, alive = tmp / f"sysid_diagnose_{dead.pid}_x1", tmp / f"sysid_diagnose_{os.getppid()}_x2"
    for folder in (orphan, alive):
        folder.mkdir(exist_ok=True)
        (folder / "two_link_calibrated.xml").write_text("<mujoco/>")
    try:
        with scratch_folder("sysid_diagnose_") as mine:
            assert mine.name.startswith(f"sysid_diagnose_{os.getpid()}_") and mine.is_dir()
        assert not mine.exists() and not orphan.exists() and alive.is_dir()
    finally:
        shutil.rmtree(orphan, ignore_errors=True)
        shutil.rmtree(alive, ignore_errors=True)


@pytest.fixture(scope="module")
def csv_pair(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Clean pendulum data: a training and a validation file."""
    from test_diagnose import simulate

    folder = tmp_path_factory.mktemp("pair")
    _, train, validation = simulate("pendulum", [], 2, folder)
    paths = [folder / "train.csv", folder / "validation.csv"]
    write_csv(train, paths[0])
    write_csv(validation, paths[1])
    return paths


def test_a_diagnosis_killed_with_sigkill_leaves_no_scratch_folder_after_the_next(
    csv_pair: list[Path], tmp_path: Path
) -> None:
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "harness.diagnose",
            "system=pendulum",
            f"data.path=[{csv_pair[0]},{csv_pair[1]}]",
            f"hydra.run.dir={tmp_path / 'killed'}",
        ],
        cwd=REPO,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    tmp = Path(tempfile.gettempdir())
    deadline = time.monotonic() + 120
    while not list(tmp.glob(f"sysid_diagnose_{proc.pid}_*")) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    seen = bool(list(tmp.glob(f"sysid_diagnose_{proc.pid}_*")))
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert seen, "the diagnosis ended before its scratch folder was seen"
    with scratch_folder("sysid_diagnose_"):
        pass
    assert not list(tmp.glob(f"sysid_diagnose_{proc.pid}_*"))


# 11. large files: memory scales with the file ----------------------------------------------------------------------


def test_reading_memory_stays_within_twice_the_file(tmp_path: Path) -> None:
    n = 300_000
    t = np.arange(n) / 500.0
    cols = [t, np.sin(t), np.cos(0.7 * t), np.cos(t), -0.7 * np.sin(0.7 * t), np.sin(2 * t), np.cos(3 * t)]
    path = tmp_path / "big.csv"
    header = "time,q_shoulder,q_elbow,dq_shoulder,dq_elbow,tau_shoulder,tau_elbow"
    np.savetxt(path, np.column_stack(cols), delimiter=",", header=header, comments="", fmt="%.10g")
    # ru_maxrss survives exec (this child would start with pytest's peak): read the peak from /proc instead,
    # resetting it (clear_refs 5) before the read
    script = (
        "from dynamics.plant import load_plant\n"
        "from envs.measured import read_measured\n"
        "def kb(field):\n"
        "    return next(int(ln.split()[1]) for ln in open('/proc/self/status') if ln.startswith(field + ':'))\n"
        "plant = load_plant('two_link')\n"
        "open('/proc/self/clear_refs', 'w').write('5')\n"
        "before = kb('VmRSS')\n"
        f"d = read_measured('{path}', plant)\n"
        "print(d.n_samples, (kb('VmHWM') - before) * 1024)\n"
    )
    if not Path("/proc/self/clear_refs").exists():
        pytest.skip("the peak memory of one stage is read from Linux's /proc/self (clear_refs, VmHWM)")
    proc = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, check=True)
    rows, grown = (int(v) for v in proc.stdout.split())
    assert rows == n
    assert 0.2 * path.stat().st_size < grown <= 2 * path.stat().st_size, (grown, path.stat().st_size)


@pytest.mark.slow
def test_a_whole_diagnosis_of_a_3m_row_file_stays_within_twice_the_file(tmp_path: Path) -> None:
    """sysid-diagnose on 3 M rows: read block by block, states at the full rate, then thinned to
    `diagnose.max_rows`; the peak memory above the loaded libraries stays within twice the file."""
    if not Path("/proc/self/clear_refs").exists():
        pytest.skip("the peak memory of one stage is read from Linux's /proc/self (clear_refs, VmHWM)")
    from bench.large_file import measure_diagnosis, write_file

    path = tmp_path / "large.csv"
    write_file(path, 3_000_000)
    m, err = measure_diagnosis(path, f"hydra.run.dir={tmp_path / 'out'}", "diagnose.recording=false")
    assert m["status"] == 0, err[-3000:]
    size_mb = path.stat().st_size / 2**20
    assert m["peak_mb"] <= 2 * size_mb, (m, size_mb)
    payload = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert payload["reduced"][str(path)]["factor"] > 1
    windows = payload["info"]["simulation_windows"]  # the simulation error on windows spread over the file
    assert windows["simulated"] <= 2000 < windows["of"], windows
    assert "every" in err and "states at the full rate" in err  # progress names the thinning


def test_a_run_after_a_failed_one_in_the_same_folder_says_in_the_log_that_it_finished(tmp_path: Path) -> None:
    """The folder's log is appended to, and a good run wrote nothing there: after a failed run and a good one in
    the same folder the log read as the failure, beside the new results."""
    broken = tmp_path / "broken.xml"
    broken.write_text("<mujoco><bad")
    out = tmp_path / "run"
    proc = _cli(f"system.mjcf={broken}", "record=none", f"hydra.run.dir={out}")
    _one_line_error(proc, "broken.xml", "MuJoCo cannot load it")
    assert (out / "failure.json").is_file()
    proc = _cli("system=pendulum", "record=none", f"hydra.run.dir={out}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = (out / "sysid-run.log").read_text().strip().splitlines()
    assert "ModelError" in "".join(lines) and not (out / "failure.json").exists()
    assert "sysid-run started (pid " in lines[-2]
    assert lines[-1].endswith(f"sysid-run finished: outputs in {out}")


def test_a_stop_while_the_outputs_are_published_waits_for_the_publish(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The previous outputs are retired and the staged ones renamed into place: a SIGTERM between the two had left
    neither (a review). The signal is now held until the publish is done, and the run then stops."""
    import harness.rundir as rundir_module
    from envs.dataset import atomic_write

    names = ("data.csv", "recording.rrd", "results.json")
    for name in names:
        (tmp_path / name).write_text("old")
    real = os.replace
    calls: list[str] = []

    def replace(src: Path, dst: Path) -> None:
        if Path(src).parent.name.startswith(".staged.") and not Path(src).name.startswith("."):
            calls.append(Path(dst).name)
            if len(calls) == 2:
                os.kill(os.getpid(), signal.SIGTERM)  # the scheduler stops the job between two renames
        real(src, dst)

    with terminate_as_exit(), claim(tmp_path, outputs=names, overwrite=True) as folder:
        with pytest.raises(SystemExit), folder.staged() as staging:
            for name in names:
                atomic_write(staging / name, lambda f: f.write("new"))
            monkeypatch.setattr(rundir_module.os, "replace", replace)
    monkeypatch.undo()
    assert calls == list(names)
    assert {p.name: p.read_text() for p in tmp_path.iterdir()} == dict.fromkeys(names, "new")


def _killed_while_staging(cfg: object) -> None:
    """A sweep job's work that is killed (SIGKILL: no clean-up of its own) while writing its staged outputs."""
    out = Path(str(cfg))
    staging = out / ".staged.abc.tmp"
    staging.mkdir()
    (staging / "data.csv").write_text("half")
    os.kill(os.getpid(), signal.SIGKILL)


def test_a_sweep_job_killed_while_staging_leaves_no_staging_folder(tmp_path: Path) -> None:
    """No later claim of a killed sweep job's folder comes to remove what it was writing (a review): the parent
    removes it when it records the death."""
    from harness.sweep import run_isolated

    run_isolated(_killed_while_staging, str(tmp_path), tmp_path, label="job 0")
    assert json.loads((tmp_path / "failure.json").read_text())["signal"] == "SIGKILL"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["failure.json"]

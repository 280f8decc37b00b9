"""Sweeps: parallel jobs through the joblib launcher, failures reported, and one table that matches the runs."""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

from harness.report import collect, main, report_rows
from tests.conftest import rrd_has_blueprint, rrd_rows

REPO = Path(__file__).resolve().parents[1]
# the parts of a sysid-run results.json the report reads
RESULTS = {
    "system": "pendulum",
    "estimator": "wls",
    "excitation": {"name": "optimised", "harmonics": 5, "cond_XtX": 2.0, "cond_W_colnorm": 1.5, "limits_ok": True},
    "base_parameters": [{"z": 0.5}],
    "validation": {"torque_rms": {"swing": 0.01}},
    "timing_s": {"setup": 0.1},
}


def _sweep(sweep: Path, *overrides: str, status: int = 0) -> subprocess.CompletedProcess:
    """`sysid-run -m` into `sweep` with the pendulum, no recordings, and these overrides; checks the exit status
    (1 when any job failed)."""
    cmd = [sys.executable, "-m", "harness.run", "-m", f"hydra.sweep.dir={sweep}", "system=pendulum", "record=none"]
    proc = subprocess.run([*cmd, *overrides], cwd=REPO, capture_output=True, text=True, timeout=600, check=False)
    assert proc.returncode == status, proc.stderr[-3000:]
    return proc


def test_two_job_sweep_and_its_report(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    _sweep(sweep, "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", "seed=0,1")
    assert main([str(sweep)]) == 0
    with (sweep / "report.csv").open() as f:
        table = {row["job"]: row for row in csv.DictReader(f)}
    assert len(table) == 2
    for job, row in table.items():
        results = json.loads((sweep / job / "results.json").read_text())
        assert row["status"] == "ok"
        assert float(row["cond_XtX"]) == results["excitation"]["cond_XtX"]
        assert float(row["val_rms_swing"]) == results["validation"]["torque_rms"]["swing"]
        assert f"seed={results['seed']}" in row["overrides"]
    assert "2 jobs, 2 ok, 0 failed" in (sweep / "report.md").read_text()
    assert all(rrd_rows(sweep / "report.rrd")[f"/runs/cond_XtX/{job}"] == 1 for job in table)  # a bar per job
    assert rrd_has_blueprint(sweep / "report.rrd")


def test_a_failed_job_is_reported_and_the_others_finish(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    proc = _sweep(sweep, "system.limits.acceleration=1e-6,60", status=1)
    assert "1 of 2 job(s) failed" in proc.stderr and "binding constraint ddq" in proc.stderr.splitlines()[-1]
    assert "Traceback" not in proc.stderr  # a bad-input failure is one line, in the job and at the end
    rows = {float(r["overrides"].split("acceleration=")[1]): r for r in report_rows(collect(sweep))}
    assert rows[60.0]["status"] == "ok"
    assert rows[1e-6]["status"] == "failed"
    assert "binding constraint ddq" in rows[1e-6]["error"]
    assert main([str(sweep)]) == 1  # sysid-report too says that a job failed
    assert "2 jobs, 1 ok, 1 failed" in (sweep / "report.md").read_text()


def test_report_of_a_missing_folder_is_a_clear_error(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    assert main([str(tmp_path / "nope")]) == 2
    assert "sweep folder not found" in capsys.readouterr().err
    (tmp_path / "a.csv").write_text("x\n")  # an existing file: said to be a file, not "not found"
    assert main([str(tmp_path / "a.csv")]) == 2
    assert "a.csv is a file, not a sweep folder" in capsys.readouterr().err


def test_a_run_without_stds_is_reported_ok_with_no_max_z(tmp_path: Path) -> None:
    """The gradient estimator gives no std, so every z is null: the report took max() of nothing and called
    the finished run failed ("incomplete or corrupt")."""
    sweep = tmp_path / "sweep"
    _sweep(sweep, "estimator=wls,gradient")
    assert main([str(sweep)]) == 0
    rows = {r["estimator"]: r for r in report_rows(collect(sweep))}
    assert rows["gradient"]["status"] == "ok" and rows["gradient"]["max_abs_z"] is None
    assert rows["wls"]["max_abs_z"] > 0


def test_a_killed_jobs_staging_folder_is_no_job_of_its_own(tmp_path: Path) -> None:
    """A job killed while publishing (SIGKILL: no clean-up) can leave its staging folder with a results file in
    it; the report's search of the sweep folder counted it as a job."""
    job = tmp_path / "0"
    (job / ".hydra").mkdir(parents=True)
    (job / "failure.json").write_text(json.dumps({"error": "killed"}))
    staged = job / ".staged.abc.tmp"
    staged.mkdir()
    (staged / "results.json").write_text("{}")
    assert [r["job"] for r in collect(tmp_path)] == ["0"]


def test_a_non_finite_number_in_a_jobs_file_fails_that_job(tmp_path: Path) -> None:
    """The tools write strict JSON; a results.json with NaN (edited, or written by another tool) was listed as
    an ok row showing `nan`."""
    for job, cond in (("0_ok", "2.0"), ("1_nan", "NaN")):
        (tmp_path / job / ".hydra").mkdir(parents=True)
        (tmp_path / job / "results.json").write_text(
            json.dumps(RESULTS).replace('"cond_XtX": 2.0', f'"cond_XtX": {cond}')
        )
    rows = {r["job"]: r for r in report_rows(collect(tmp_path))}
    assert rows["0_ok"]["status"] == "ok"
    assert (
        rows["1_nan"]["status"] == "failed"
        and rows["1_nan"]["error"] == "1_nan/results.json: cond_XtX is nan, not a finite number"
    )


def test_an_earlier_sweeps_jobs_left_in_the_folder_are_not_counted(tmp_path: Path) -> None:
    """A sweep of two jobs re-run into its folder with overwrite=true as a sweep of one left the earlier second
    job, and the report counted it as this sweep's ("2 jobs, 2 ok"). A job whose .hydra/ is older than the
    sweep's multirun.yaml is listed as left out."""
    import os

    for job, seed in (("0_pendulum", 5), ("1_pendulum", 1)):
        (tmp_path / job / ".hydra").mkdir(parents=True)
        (tmp_path / job / ".hydra" / "overrides.yaml").write_text(f"- system=pendulum\n- seed={seed}\n")
        (tmp_path / job / "results.json").write_text(json.dumps(RESULTS))
    (tmp_path / "multirun.yaml").write_text("hydra:\n  overrides:\n    task:\n    - system=pendulum\n    - seed=5\n")
    now = (tmp_path / "multirun.yaml").stat().st_mtime
    old = (now - 3600, now - 3600)
    os.utime(tmp_path / "1_pendulum" / ".hydra" / "overrides.yaml", old)  # the earlier sweep's
    os.utime(tmp_path / "0_pendulum" / ".hydra", old)  # a folder kept, its files rewritten by this sweep
    # a job whose files look older than multirun.yaml (a folder copied file by file) but whose overrides are the
    # sweep's is kept: the times alone do not make it an earlier sweep's
    copy = tmp_path.parent / f"{tmp_path.name}_copy"
    shutil.copytree(tmp_path, copy)
    os.utime(copy / "0_pendulum" / ".hydra" / "overrides.yaml", old)
    os.utime(copy / "multirun.yaml", (now, now))
    assert [r["status"] for r in collect(copy)] == ["ok", "stale"]  # 0_pendulum's seed=5 is the sweep's
    assert main([str(tmp_path)]) == 0
    text = (tmp_path / "report.md").read_text()
    assert "1 jobs, 1 ok, 0 failed" in text and "Left out, from an earlier sweep in this folder: 1_pendulum" in text
    with (tmp_path / "report.csv").open() as f:
        assert [row["job"] for row in csv.DictReader(f)] == ["0_pendulum"]


def _one_job_sweep(folder: Path) -> None:
    (folder / "0_pendulum" / ".hydra").mkdir(parents=True)
    (folder / "0_pendulum" / "results.json").write_text(json.dumps(RESULTS))


def test_a_report_file_sysid_report_did_not_write_is_never_replaced(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """sysid-report replaces its own report when run again, and nothing else: a report.md (or .csv, .rrd) of the
    user's in the sweep folder, or its own report.md edited since (notes added under the table), is left as it is,
    the run is refused with one line naming the file, and none of the three is written."""
    _one_job_sweep(tmp_path)
    assert main([str(tmp_path)]) == 0
    assert main([str(tmp_path)]) == 0  # its own report, replaced
    capsys.readouterr()
    edited = (tmp_path / "report.md").read_text() + "\nSeed 5 looks off: ask Ana.\n"
    (tmp_path / "report.md").write_text(edited)
    csv_before = (tmp_path / "report.csv").read_bytes()
    assert main([str(tmp_path)]) == 2
    (err,) = capsys.readouterr().err.strip().splitlines()
    assert f"{tmp_path / 'report.md'} was not written by sysid-report, or was changed since" in err
    assert (tmp_path / "report.md").read_text() == edited and (tmp_path / "report.csv").read_bytes() == csv_before

    for name in ("report.md", "report.csv", "report.rrd"):  # a file of the user's under each name
        sweep = tmp_path / f"mine_{name}"
        _one_job_sweep(sweep)
        (sweep / name).write_text("my own notes\n")
        assert main([str(sweep)]) == 2
        assert name in capsys.readouterr().err
        assert (sweep / name).read_text() == "my own notes\n"
        assert sorted(p.name for p in sweep.iterdir()) == ["0_pendulum", name]  # nothing else written


def test_a_report_written_before_the_manifest_is_still_replaced_and_one_with_notes_is_not(tmp_path: Path) -> None:
    """A sweep reported by a version without `.sysid_report.json`: a report.md that is its table and ends with the
    jobs line, a report.csv whose header starts job,overrides,status and a rerun recording are sysid-report's, and
    are replaced. The same report.md with the user's notes after the jobs line, or a report.csv of another header,
    is not; nor is anything where the manifest cannot be read."""
    _one_job_sweep(tmp_path)
    assert main([str(tmp_path)]) == 0
    manifest = tmp_path / ".sysid_report.json"
    manifest.unlink()
    (tmp_path / "report.csv").write_text("job,overrides,status\nold,,ok\n")
    assert main([str(tmp_path)]) == 0
    with (tmp_path / "report.csv").open() as f:
        assert [row["job"] for row in csv.DictReader(f)] == ["0_pendulum"]
    assert set(json.loads(manifest.read_text())) == {"report.md", "report.csv", "report.rrd"}

    manifest.unlink()
    noted = (tmp_path / "report.md").read_text() + "\nSeed 5 looks off.\n"
    (tmp_path / "report.md").write_text(noted)
    assert main([str(tmp_path)]) == 2
    assert (tmp_path / "report.md").read_text() == noted
    (tmp_path / "report.md").unlink()
    (tmp_path / "report.csv").write_text("run,score\n1,2\n")
    assert main([str(tmp_path)]) == 2
    assert (tmp_path / "report.csv").read_text() == "run,score\n1,2\n"

    (tmp_path / "report.csv").unlink()
    assert main([str(tmp_path)]) == 0
    manifest.write_text("{not json")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    assert main([str(tmp_path)]) == 2
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before


def test_a_report_cut_short_while_it_is_put_in_place_is_still_its_own(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The manifest accepts the old and the new version of each file before any is put in place: a run that
    dies after report.md is replaced (here the recording's rename fails) leaves a folder the next run replaces."""
    import os

    _one_job_sweep(tmp_path)
    assert main([str(tmp_path)]) == 0
    (tmp_path / "1_pendulum" / ".hydra").mkdir(parents=True)  # the sweep grew: every file changes
    (tmp_path / "1_pendulum" / "results.json").write_text(json.dumps(RESULTS))
    real_replace = os.replace

    def failing(src: object, dst: object) -> None:
        if str(dst).endswith("report.rrd"):
            raise OSError(28, "No space left on device", str(dst))
        real_replace(src, dst)  # type: ignore[arg-type]

    monkeypatch.setattr(os, "replace", failing)
    assert main([str(tmp_path)]) == 2
    assert "2 jobs, 2 ok, 0 failed" in (tmp_path / "report.md").read_text()  # the new report.md is in place
    assert not list(tmp_path.glob(".report.rrd.*"))  # no temporary file of the recording is left
    monkeypatch.setattr(os, "replace", real_replace)
    assert main([str(tmp_path)]) == 0
    assert set(json.loads((tmp_path / ".sysid_report.json").read_text())) == {"report.md", "report.csv", "report.rrd"}

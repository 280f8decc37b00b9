"""Sweeps on Ray (the `[ray]` extra): a 2-job sweep on a local Ray instance, and a killed job reported failed."""

from __future__ import annotations

import csv
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

from harness.report import collect, main, report_rows

REPO = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("hydra_plugins.hydra_ray_launcher") is None or importlib.util.find_spec("ray") is None,
    reason="the [ray] extra (hydra-ray-launcher, ray) is not installed: pip install -e '.[ray]'",
)


def _ray_sweep(sweep: Path, *overrides: str) -> subprocess.CompletedProcess:
    """`sysid-run -m` on a local Ray instance of 2 CPUs: short pendulum jobs, no recordings."""
    cmd = [
        sys.executable,
        "-m",
        "harness.run",
        "-m",
        "hydra/launcher=ray_local",
        "hydra.launcher.ray.init.num_cpus=2",
        f"hydra.sweep.dir={sweep}",
        "system=pendulum",
        "record=none",
        "system.periods=1",
        "validation.periods=1",
        *overrides,
    ]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    env.update(RAY_USAGE_STATS_ENABLED="0", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    return subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600, check=False)


def test_two_job_sweep_on_local_ray(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    proc = _ray_sweep(sweep, "seed=0,1")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Ray Launcher is launching 2 jobs" in proc.stderr + proc.stdout
    assert main([str(sweep)]) == 0
    with (sweep / "report.csv").open() as f:
        table = list(csv.DictReader(f))
    assert sorted(row["status"] for row in table) == ["ok", "ok"]
    assert sorted(row["overrides"].split("seed=")[1].split()[0] for row in table) == ["0", "1"]


def test_a_job_killed_under_ray_is_reported_failed(tmp_path: Path) -> None:
    # job 1's worker process is SIGKILLed once its folder exists, as the OOM killer or a scheduler would
    sweep = tmp_path / "sweep"
    proc = _ray_sweep(
        sweep, "seed=0,1", "+hydra.callbacks.kill._target_=tests.sweep_callbacks.KillJob", "+hydra.callbacks.kill.job=1"
    )
    assert proc.returncode != 0  # Ray does not re-run it (max_retries: 0) and the sweep says a job died
    assert "WorkerCrashedError" in proc.stderr or "died" in proc.stderr, proc.stderr[-3000:]
    rows = {r["job"]: r for r in report_rows(collect(sweep))}
    assert rows["0_pendulum"]["status"] == "ok"
    assert rows["1_pendulum"]["status"] == "failed"
    assert rows["1_pendulum"]["error"]
    assert main([str(sweep)]) == 1  # the report is written, and its status says a job failed
    assert "2 jobs, 1 ok, 1 failed" in (sweep / "report.md").read_text()

"""The README's five-minute tour, shortened: the same console scripts, smaller runs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tests.conftest import rrd_has_blueprint, rrd_rows

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
SHORT = ["system=pendulum", "system.periods=2", "validation.periods=1", "excitation.options.starts=1"]


def _script(name: str, *args: str) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run([str(BIN / name), *args], cwd=REPO, capture_output=True, text=True, timeout=600, check=False)
    assert proc.returncode == 0, f"{name} {' '.join(args)}\n{proc.stderr[-3000:]}"
    return proc


def test_tour(tmp_path: Path) -> None:
    # 1. design an excitation and identify; an estimator whose convergence the recording shows
    run_dir = tmp_path / "run"
    _script("sysid-run", *SHORT, f"hydra.run.dir={run_dir}")
    results = json.loads((run_dir / "results.json").read_text())
    assert results["excitation"]["name"] == "optimised" and results["excitation"]["limits_ok"]
    rls_dir = tmp_path / "rls"
    _script("sysid-run", *SHORT, "estimator=rls", f"hydra.run.dir={rls_dir}")
    assert any(e.startswith("/estimator/history/") for e in rrd_rows(rls_dir / "recording.rrd"))

    # 2. diagnose the simulated run's data (the nominal model is right there: nothing to name)
    diag_dir = tmp_path / "diagnose"
    _script("sysid-diagnose", "system=pendulum", f"data.path={run_dir / 'data.csv'}", f"hydra.run.dir={diag_dir}")
    diagnosis = json.loads((diag_dir / "diagnosis.json").read_text())
    assert diagnosis["verdict"] == "no_discrepancy", diagnosis["findings"]
    assert (diag_dir / "pendulum_calibrated.xml").is_file()

    # 3. a parallel sweep and its report
    sweep = tmp_path / "sweep"
    _script(
        "sysid-run",
        "-m",
        "hydra/launcher=joblib",
        "hydra.launcher.n_jobs=2",
        *SHORT,
        "record=none",
        "seed=0,1",
        f"hydra.sweep.dir={sweep}",
    )
    report = _script("sysid-report", str(sweep)).stdout
    assert "2 jobs, 2 ok, 0 failed" in report

    # 4. the recordings open with their layout
    for rrd in (run_dir / "recording.rrd", diag_dir / "diagnosis.rrd", sweep / "report.rrd"):
        assert rrd_has_blueprint(rrd), rrd

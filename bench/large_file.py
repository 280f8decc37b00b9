"""Reading a large measured file: CSV readers compared, and `read_measured`'s time and memory against file size.

Writes a 3 M-row two-link CSV (time, q, dq, tau per joint: the measured-data format) under the system's
temporary folder and reads it, each reader in a fresh process: numpy's `loadtxt` (what `envs.measured` uses),
pyarrow's CSV reader (installed with rerun-sdk), and polars where importable (not a dependency; set
`SYSID_BENCH_POLARS_PATH` to a folder holding it). Peak memory is the process's peak RSS during the read
less its RSS after the imports and the plant, i.e. what reading the file costs (Linux: /proc/self/status).

Writes bench/large_file.json and bench/large_file.md. Re-run: `.venv/bin/python -m bench large_file`.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
ROWS = 3_000_000

_READERS = {
    "numpy.loadtxt": "import numpy as np\nstart()\na = np.loadtxt(P, delimiter=',', skiprows=1, ndmin=2)\n",
    "pyarrow.csv": "import pyarrow.csv as pc\nstart()\nt = pc.read_csv(P)\na = [c.to_numpy() for c in t.columns]\n",
    "polars": "import polars as pl\nstart()\na = pl.read_csv(P).to_numpy()\n",
    "envs.measured.read_measured": (
        "from dynamics.plant import load_plant\nfrom envs.measured import read_measured\n"
        "plant = load_plant('two_link')\nstart()\nd = read_measured(P, plant)\n"
    ),
}

# ru_maxrss is not reset by exec (a child forked from a big parent starts with the parent's peak), so the peak
# is read from /proc: VmHWM after resetting it (clear_refs 5) at the start of the stage, less VmRSS then.
_PRELUDE = """
import sys, time
sys.path[:0] = [p for p in {extra!r} if p]
P = {path!r}
def _kb(field):
    for line in open("/proc/self/status"):
        if line.startswith(field + ":"):
            return int(line.split()[1])
_t = [0.0, 0]
_status = 0
def start():
    open("/proc/self/clear_refs", "w").write("5")
    _t[0] = time.perf_counter(); _t[1] = _kb("VmRSS")
"""
_EPILOGUE = """
import json
print(json.dumps({"s": time.perf_counter() - _t[0], "peak_mb": (_kb("VmHWM") - _t[1]) / 1024,
                  "total_mb": _kb("VmHWM") / 1024, "status": _status}))
"""
_DIAGNOSE = """
import harness.diagnose, identify.diagnose, dynamics.plant, scipy.signal, mujoco.rollout
dynamics.plant.load_plant("two_link")
sys.argv = ["sysid-diagnose", "system=two_link", "data.path=" + P, *{args!r}]
start()
try:
    harness.diagnose.main()
except SystemExit as e:
    _status = e.code or 0
"""


def write_file(path: Path, rows: int) -> None:
    """A two-link record at 500 Hz in the measured-data format, with dq, written in blocks: a slow motion and the
    torque the built-in `two_link` model needs for it (its equations in the DFKI lab's form, vectorised), with
    0.01 N m of noise. The diagnosis refuses a torque that does not follow the motion."""
    from dynamics.plant import load_plant
    from identify.diagnose.authors import author_torque
    from identify.diagnose.testbed import author_params_of

    params = author_params_of(load_plant("two_link"))
    header = "time,q_shoulder,q_elbow,dq_shoulder,dq_elbow,tau_shoulder,tau_elbow"
    rng = np.random.default_rng(0)
    with path.open("w") as f:
        f.write(header + "\n")
        for start in range(0, rows, 500_000):
            t = np.arange(start, min(rows, start + 500_000)) / 500.0
            q = np.column_stack([np.sin(0.5 * t), np.cos(0.3 * t)])
            dq = np.column_stack([0.5 * np.cos(0.5 * t), -0.3 * np.sin(0.3 * t)])
            ddq = np.column_stack([-0.25 * np.sin(0.5 * t), -0.09 * np.cos(0.3 * t)])
            tau = author_torque(params, q, dq, ddq) + 0.01 * rng.standard_normal(q.shape)
            np.savetxt(f, np.column_stack([t, q, dq, tau]), delimiter=",", fmt="%.10g")


def _stage(code: str, path: Path) -> subprocess.CompletedProcess:
    """Run `code` (which calls `start()` where the measured stage begins) in a fresh process; its last stdout
    line is the stage's {s, peak_mb, total_mb, status}."""
    extra = [str(REPO), os.environ.get("SYSID_BENCH_POLARS_PATH", "")]
    full = _PRELUDE.format(extra=extra, path=str(path)) + code + _EPILOGUE
    return subprocess.run([sys.executable, "-c", full], cwd=REPO, capture_output=True, text=True, check=False)


def measure(reader: str, path: Path) -> dict | None:
    """Time [s] and peak memory above the process's baseline [MB] of one reader, in a fresh process."""
    proc = _stage(_READERS[reader], path)
    if proc.returncode != 0:
        if "No module named" in proc.stderr:
            return None
        raise RuntimeError(f"{reader}: {proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def measure_diagnosis(path: Path, *args: str) -> tuple[dict, str]:
    """A whole `sysid-diagnose system=two_link data.path=<path> <args>` in a fresh process: its time [s], peak
    memory above the loaded libraries (`peak_mb`) and in all (`total_mb`) [MB], exit status, and its stderr.

    Raises:
        RuntimeError: the process died before it could report.
    """
    proc = _stage(_DIAGNOSE.format(args=list(args)), path)
    lines = proc.stdout.strip().splitlines()
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"sysid-diagnose of {path}: status {proc.returncode}: {proc.stderr[-2000:]}")
    return json.loads(lines[-1]), proc.stderr


def main() -> None:
    with tempfile.TemporaryDirectory(prefix="sysid_bench_large_") as tmp:
        path = Path(tmp) / "large.csv"
        write_file(path, ROWS)
        size_mb = path.stat().st_size / 2**20
        rows = []
        for reader in _READERS:
            m = measure(reader, path)
            rows.append({"reader": reader, "available": m is not None, **(m or {})})
    (HERE / "large_file.json").write_text(json.dumps({"rows": ROWS, "file_mb": size_mb, "readers": rows}, indent=2))
    md = [
        f"# Reading a {ROWS:,}-row, {size_mb:.0f} MB CSV (`python -m bench large_file`)",
        "",
        "| reader | time [s] | peak memory above baseline [MB] | x file size |",
        "|---|---:|---:|---:|",
    ]
    for r in rows:
        if r["available"]:
            md.append(f"| {r['reader']} | {r['s']:.2f} | {r['peak_mb']:.0f} | {r['peak_mb'] / size_mb:.2f} |")
        else:
            md.append(f"| {r['reader']} | not installed | - | - |")
    (HERE / "large_file.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()

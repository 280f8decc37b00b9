"""A trial of bad inputs and faults, tried as a new user would: how many are handled well.

Handled well: the exit status expected (2 for a user's mistake, 1 for a sweep with a failed job, 0 for data
that must be repaired with a report), no traceback, the last line on stderr naming the problem, and nothing
that was there before lost or changed. Each case runs the real console entry point in a subprocess.

Writes bench/reliability.json and bench/reliability.md. Re-run: `.venv/bin/python -m bench reliability`
(about five minutes on two cores). Cases that need root (a read-only or full tmpfs) are listed as skipped
where they cannot be set up.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from harness.rundir import terminate_as_exit

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
RUN, DIAGNOSE, REPORT = "harness.run", "harness.diagnose", "harness.report"
FAST = ("system=pendulum", "record=none")


@dataclass
class Case:
    """One bad input or fault. `args` may hold `{dir}` (the case's folder) and `{base}` (a finished run)."""

    name: str
    module: str
    args: tuple[str, ...]
    status: int = 2
    needles: tuple[str, ...] = ()
    prepare: Callable[[Path, Path], object] | None = None
    check: Callable[[Path, subprocess.CompletedProcess], str | None] | None = None
    keep: tuple[str, ...] = ()  # files under {dir} that must be unchanged afterwards
    needs_root: bool = False
    special: Callable[[Path, Path], tuple[bool, str]] | None = None
    result: dict = field(default_factory=dict)


def _py(module: str, *args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run(
        [sys.executable, "-m", module, *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
        env=env,
    )


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else "absent"


# data files made from the finished run's data.csv ------------------------------------------------------------------


def _table(base: Path) -> tuple[list[str], np.ndarray]:
    text = (base / "data.csv").read_text().splitlines()
    return text[0].split(","), np.loadtxt(base / "data.csv", delimiter=",", skiprows=1)


def _write(path: Path, header: list[str], table: np.ndarray) -> None:
    np.savetxt(path, table, delimiter=",", header=",".join(header), comments="", fmt="%.10g")


def _mutated(change: Callable[[list[str], np.ndarray], tuple[list[str], np.ndarray]]) -> Callable[[Path, Path], None]:
    def prepare(d: Path, base: Path) -> None:
        header, table = _table(base)
        _write(d / "data.csv", *change(header, table.copy()))

    return prepare


def _drop(header: list[str], table: np.ndarray, name: str) -> tuple[list[str], np.ndarray]:
    k = header.index(name)
    return [h for h in header if h != name], np.delete(table, k, axis=1)


def _raw(content: bytes) -> Callable[[Path, Path], None]:
    def prepare(d: Path, base: Path) -> None:
        (d / "data.csv").write_bytes(content)

    return prepare


def _spikes(fraction: float) -> Callable[[list[str], np.ndarray], tuple[list[str], np.ndarray]]:
    def change(header: list[str], table: np.ndarray) -> tuple[list[str], np.ndarray]:
        rng = np.random.default_rng(1)
        rows = rng.choice(np.arange(20, len(table) - 20, 3), size=round(fraction * len(table)), replace=False)
        table[rows, header.index("q_swing")] += rng.choice([-1, 1], size=len(rows)) * rng.uniform(0.3, 0.6, len(rows))
        return header, table

    return change


def _cell(row: int, col: str, value: str) -> Callable[[Path, Path], None]:
    def prepare(d: Path, base: Path) -> None:
        lines = (base / "data.csv").read_text().splitlines()
        header = lines[0].split(",")
        cells = lines[row + 1].split(",")
        cells[header.index(col)] = value
        lines[row + 1] = ",".join(cells)
        (d / "data.csv").write_text("\n".join(lines) + "\n")

    return prepare


def _user_files(d: Path, base: Path) -> None:
    (d / "out").mkdir()
    (d / "out" / "results.json").write_text('{"mine": true}\n')
    (d / "out" / "data.csv").write_text("time,q_swing,tau_swing\n0,0,0\n")


def _has_repair(kind: str) -> Callable[[Path, subprocess.CompletedProcess], str | None]:
    def check(d: Path, proc: subprocess.CompletedProcess) -> str | None:
        files = list((d / "out").glob("diagnosis.json"))
        if not files:
            return "no diagnosis.json"
        payload = json.loads(files[0].read_text())
        repairs = payload.get("repairs", {})
        if not any(r.get("kind") == kind for rs in repairs.values() for r in rs):
            return f"no {kind} repair reported: {repairs}"
        if payload.get("verdict") != "no_discrepancy":  # the data are the nominal model's own simulation
            return f"verdict {payload.get('verdict')} on repaired data: {[f['effect'] for f in payload['findings']]}"
        return None

    return check


def _corrupt_sweep(d: Path, base: Path) -> None:
    for i, content in enumerate([(base / "results.json").read_bytes(), b'{"system": "pend', b"\x00binary"]):
        (d / "sweep" / f"{i}_job").mkdir(parents=True)
        (d / "sweep" / f"{i}_job" / "results.json").write_bytes(content)


def _report_names(name: str) -> Callable[[Path, subprocess.CompletedProcess], str | None]:
    def check(d: Path, proc: subprocess.CompletedProcess) -> str | None:
        md = (d / "sweep" / "report.md").read_text() if (d / "sweep" / "report.md").is_file() else ""
        return None if name in md else f"report.md does not name {name}"

    return check


# cases needing processes in flight ----------------------------------------------------------------------------------


def _wait_lock(folder: Path, timeout_s: float = 120) -> int:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with contextlib.suppress(OSError, ValueError):
            return int((folder / ".sysid.lock").read_text().split()[0])
        time.sleep(0.05)
    raise TimeoutError(f"no lock in {folder}")


def _popen(*args: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.Popen(
        [sys.executable, "-m", *args], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
    )


def _concurrent(d: Path, base: Path) -> tuple[bool, str]:
    out = d / "out"
    first = _popen(RUN, "system=wheel_pendulum", "record=none", f"hydra.run.dir={out}", "seed=1")
    _wait_lock(out)
    second = _py(RUN, "system=wheel_pendulum", "record=none", f"hydra.run.dir={out}", "seed=2")
    first.communicate(timeout=600)
    seed = json.loads((out / "results.json").read_text())["seed"] if (out / "results.json").is_file() else None
    ok = first.returncode == 0 and second.returncode == 2 and seed == 1 and "in use" in second.stderr
    return ok, f"first {first.returncode}, second {second.returncode}: {_last(second.stderr)}; results seed {seed}"


def _sigterm(d: Path, base: Path) -> tuple[bool, str]:
    out = d / "out"
    proc = _popen(RUN, "system=wheel_pendulum", "record=none", f"hydra.run.dir={out}")
    os.kill(_wait_lock(out), signal.SIGTERM)
    _, err = proc.communicate(timeout=600)
    failure = (out / "failure.json").is_file()
    left = [p.name for p in out.glob(".*.tmp")] + ([".sysid.lock"] if (out / ".sysid.lock").exists() else [])
    ok = proc.returncode == 143 and failure and not left and "Traceback" not in err
    return ok, f"status {proc.returncode}, failure.json {failure}, left {left}: {_last(err)}"


def _sigkill_sweep(d: Path, base: Path) -> tuple[bool, str]:
    sweep = d / "sweep"
    proc = _popen(
        RUN,
        "-m",
        "hydra/launcher=joblib",
        "hydra.launcher.n_jobs=2",
        f"hydra.sweep.dir={sweep}",
        "record=none",
        "system=wheel_pendulum,pendulum",
    )
    os.kill(_wait_lock(sweep / "0_wheel_pendulum"), signal.SIGKILL)
    _, err = proc.communicate(timeout=600)
    recorded = (sweep / "0_wheel_pendulum" / "failure.json").is_file()
    other = (sweep / "1_pendulum" / "results.json").is_file()
    ok = proc.returncode == 1 and recorded and other and "TerminatedWorkerError" not in err
    return ok, f"status {proc.returncode}, failure recorded {recorded}, other job finished {other}: {_last(err)}"


def _text(edit: Callable[[str], str]) -> Callable[[Path, Path], None]:
    """Write the finished run's data.csv through a text edit."""

    def prepare(d: Path, base: Path) -> None:
        (d / "data.csv").write_text(edit((base / "data.csv").read_text()))

    return prepare


def _stuck(header: list[str], table: np.ndarray) -> tuple[list[str], np.ndarray]:
    table = table.copy()
    table[:, header.index("tau_swing")] = 0.0
    return header, table


def _model(xml: str) -> Callable[[Path, Path], None]:
    def prepare(d: Path, base: Path) -> None:
        (d / "robot.xml").write_text(xml)

    return prepare


def _report_after_failed_sweep(d: Path, base: Path) -> tuple[bool, str]:
    sweep = d / "sweep"
    _py(RUN, "-m", *FAST, f"hydra.sweep.dir={sweep}", "system.limits.acceleration=1e-6,60")
    proc = _py(REPORT, str(sweep))
    ok = proc.returncode == 1 and "failed" in _last(proc.stderr) and (sweep / "report.md").is_file()
    return ok, f"status {proc.returncode}, report written {(sweep / 'report.md').is_file()}: {_last(proc.stderr)}"


def _large_file(d: Path, base: Path) -> tuple[bool, str]:
    """sysid-diagnose on a 3 M-row file: the peak memory above the loaded libraries within 2x the file, and
    progress lines on stderr."""
    from bench.large_file import measure_diagnosis, write_file

    path = d / "large.csv"
    write_file(path, 3_000_000)
    try:
        m, err = measure_diagnosis(path, f"hydra.run.dir={d / 'out'}")
    except RuntimeError as e:
        return False, str(e)[-300:]
    size_mb = path.stat().st_size / 2**20
    progress = "states at the full rate" in err
    ok = m["status"] == 0 and m["peak_mb"] <= 2 * size_mb and progress
    return ok, (
        f"{size_mb:.0f} MB file: peak {m['peak_mb']:.0f} MB above the loaded libraries "
        f"({m['peak_mb'] / size_mb:.2f}x), {m['total_mb']:.0f} MB in all, {m['s']:.0f} s, progress lines {progress}"
    )


def _last(text: str) -> str:
    lines = text.strip().splitlines()
    return lines[-1] if lines else ""


def _cases() -> list[Case]:
    data = ("system=pendulum", "data.path={dir}/data.csv", "hydra.run.dir={dir}/out", "diagnose.recording=false")
    copy: Callable[[Path, Path], object] = lambda d, b: shutil.copy(b / "data.csv", d / "data.csv")  # noqa: E731
    out = ("hydra.run.dir={dir}/out",)
    c: list[Case] = []

    def run_case(name: str, *args: str, needles: tuple[str, ...] = (), **kw) -> None:  # type: ignore[no-untyped-def]
        c.append(Case(name, RUN, (*FAST, *out, *args), needles=needles, **kw))

    def data_case(name: str, prepare, *needles: str, system="pendulum", path="{dir}/data.csv", args=(), **kw) -> None:  # type: ignore[no-untyped-def]
        base_args = (f"system={system}", f"data.path={path}", *data[2:])
        c.append(Case(name, DIAGNOSE, (*base_args, *args), needles=needles, prepare=prepare, keep=("data.csv",), **kw))

    # config values
    run_case("seed=abc", "seed=abc", needles=("seed", "abc"))
    run_case("seed=-1", "seed=-1", needles=("seed",))
    run_case("seed=1.5", "seed=1.5", needles=("seed",))
    for h in ("0", "-3", "1000", "2.5", "many"):
        run_case(f"harmonics={h}", f"excitation.harmonics={h}", needles=("excitation.harmonics",))
    run_case("ols with wls options", "estimator.name=ols", needles=("estimator.options.iterations",))
    run_case("estimator.name=magic", "estimator.name=magic", needles=("estimator", "magic", "wls"))
    run_case("estimator group typo", "estimator=kalman", needles=("estimator", "kalman", "wls"))
    run_case("system group typo", "system=tow_link", needles=("tow_link", "two_link"))
    run_case("excitation group typo", "excitation=optimized", needles=("optimized", "optimised"))
    run_case("noise group typo", "noise=hgh", needles=("hgh", "high"))
    run_case("record group typo", "record=rrd", needles=("rrd", "rerun"))
    run_case(
        "sigma_tau 3 values, 2 joints",
        "system=two_link",
        "system.sensor.sigma_tau=[0.1,0.1,0.1]",
        needles=("system.sensor.sigma_tau", "2 joint"),
    )
    run_case(
        "velocity 3 values, 2 joints",
        "system=two_link",
        "system.limits.velocity=[1,2,3]",
        needles=("system.limits.velocity", "2 joint"),
    )
    run_case("velocity=-1", "system.limits.velocity=-1", needles=("system.limits.velocity",))
    run_case("velocity=abc", "system.limits.velocity=abc", needles=("system.limits.velocity",))
    run_case("periods=0", "system.periods=0", needles=("system.periods",))
    run_case("validation.periods=-1", "validation.periods=-1", needles=("validation.periods",))
    run_case("cutoff_hz=0", "identify.cutoff_hz=0", needles=("identify.cutoff_hz",))
    run_case("cutoff_hz above Nyquist", "identify.cutoff_hz=1000", needles=("identify.cutoff_hz",))
    run_case("derivatives=magic", "identify.derivatives=magic", needles=("magic", "butterworth"))
    run_case("base_freq_hz=0", "system.base_freq_hz=0", needles=("system.base_freq_hz",))
    run_case("sample_rate_hz=0", "system.sensor.sample_rate_hz=0", needles=("sample_rate_hz",))
    run_case("sigma_q=-1", "noise.sigma_q=-1", needles=("noise.sigma_q",))
    run_case("wls iterations=abc", "estimator.options.iterations=abc", needles=("estimator.options.iterations",))
    run_case("wls iterations=0", "estimator.options.iterations=0", needles=("iterations",))
    run_case("overwrite=maybe", "overwrite=maybe", needles=("overwrite",))
    run_case("torque_margin=2", "system.limits.torque_margin=2", needles=("system.limits.torque_margin",))
    run_case("range_margin=0.7", "system.limits.range_margin=0.7", needles=("system.limits.range_margin",))
    run_case(
        "infeasible limits",
        "system.limits.acceleration=1e-6",
        needles=("binding constraint",),
        check=lambda d, p: None if (d / "out" / "failure.json").is_file() else "no failure.json",
    )
    run_case("unknown key", "foo=1", needles=("foo",))
    run_case("malformed override", "system.limits.velocity=[1,", needles=("[1,",))
    run_case("missing system mjcf", "system.mjcf=/nonexistent/robot.xml", needles=("robot.xml",))
    c.append(
        Case(
            "sweep with a group typo",
            RUN,
            ("-m", *FAST, "hydra.sweep.dir={dir}/sweep", "system=pendulum,tow_link"),
            needles=("tow_link", "two_link"),
        )
    )
    c.append(
        Case(
            "sweep with a failed job",
            RUN,
            ("-m", *FAST, "hydra.sweep.dir={dir}/sweep", "system.limits.acceleration=1e-6,60"),
            status=1,
            needles=("binding constraint",),
        )
    )

    # data files (sysid-diagnose)
    c.append(Case("no data.path", DIAGNOSE, ("system=pendulum", "hydra.run.dir={dir}/out"), needles=("data.path",)))
    data_case("file does not exist", None, "no such file")
    data_case("directory as the file", lambda d, b: (d / "data.csv").mkdir(), "folder")
    data_case("empty file", _raw(b""), "empty")
    data_case("header only", _raw(b"time,q_swing,tau_swing\n"), "no data rows")
    data_case("NUL bytes", _raw(b"time,q_swing,tau_swing\n0,0\x00,0\n"), "binary")
    data_case("random binary", _raw(bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8))), "data.csv")
    data_case("latin-1 header", _raw("time,q_swing,tau_swing,température\n0,0,0,0\n".encode("latin-1")), "UTF-8")
    data_case("time in ms", _mutated(lambda h, t: (h, np.column_stack([t[:, 0] * 1e3, t[:, 1:]]))), "milliseconds")
    data_case("missing tau column", _mutated(lambda h, t: _drop(h, t, "tau_swing")), "missing column")
    data_case(
        "column of another system", _mutated(lambda h, t: ([*h, "q_elbow"], np.column_stack([t, t[:, 1]]))), "q_elbow"
    )
    data_case("NaN cell", _cell(100, "q_swing", "nan"), "row 100")
    data_case("text cell", _cell(100, "tau_swing", "abc"), "'abc'")
    data_case("ragged row", _cell(100, "tau_swing", "1,2"), "row 100")
    data_case("time goes backwards", _cell(100, "time", "0.0"), "backwards")
    data_case(
        "angles in degrees",
        _mutated(lambda h, t: (h, np.column_stack([t[:, :1], np.degrees(t[:, 1:2]), t[:, 2:]]))),
        "degrees",
    )
    data_case("too few rows", _mutated(lambda h, t: (h, t[:20])), "too little data")
    data_case("a long gap", _mutated(lambda h, t: (h, np.delete(t, np.s_[500:600], axis=0))), "gap")
    data_case("data of another system", copy, "missing column", system="two_link")
    data_case("same file twice", copy, "more than once", path="[{dir}/data.csv,{dir}/data.csv]")
    data_case("min_samples=abc", copy, "data.min_samples", args=("data.min_samples=abc",))
    data_case("validation_fraction=2", copy, "data.validation_fraction", args=("data.validation_fraction=2",))
    data_case("effect typo", copy, "frictoin", args=("diagnose.effects=[frictoin]",))
    data_case("max_speed=-1", copy, "data.max_speed", args=("data.max_speed=-1",))
    data_case("seed=abc (diagnose)", copy, "seed", args=("seed=abc",))
    for fraction in (0.0067, 0.0099):
        c.append(
            Case(
                f"spikes in q, {fraction:.2%} of rows",
                DIAGNOSE,
                data,
                status=0,  # a repair, reported
                prepare=_mutated(_spikes(fraction)),
                check=_has_repair("glitch"),
                keep=("data.csv",),
            )
        )
    data_case("spikes in q, 2% of rows", _mutated(_spikes(0.02)), "glitch samples", "1%")

    # run folders
    c.append(
        Case(
            "user's results.json and data.csv",
            RUN,
            (*FAST, *out),
            needles=("already holds", "overwrite"),
            prepare=_user_files,
            keep=("out/results.json", "out/data.csv"),
        )
    )
    c.append(
        Case(
            "run folder is a file",
            RUN,
            (*FAST, "hydra.run.dir={dir}/afile"),
            needles=("afile",),
            prepare=lambda d, b: (d / "afile").write_text("x"),
        )
    )
    c.append(
        Case(
            "read-only run folder",
            RUN,
            (*FAST, "hydra.run.dir={dir}/ro/out"),
            needles=("not writable",),
            needs_root=True,
            prepare=lambda d, b: _mount(d / "ro", "ro,size=64k"),
        )
    )
    c.append(
        Case(
            "full disk",
            RUN,
            ("system=pendulum", "hydra.run.dir={dir}/full/out"),
            needles=("No space left",),
            needs_root=True,
            prepare=lambda d, b: _mount(d / "full", "size=256k"),
        )
    )
    c.append(Case("concurrent runs into one folder", RUN, (), special=_concurrent))

    # reports
    c.append(Case("report of a missing folder", REPORT, ("{dir}/nope",), needles=("not found",)))
    c.append(Case("report of an empty folder", REPORT, ("{dir}",), needles=("no job folders",)))
    c.append(
        Case(
            "report with corrupt job files",
            REPORT,
            ("{dir}/sweep",),
            status=1,  # written, and the status says jobs failed
            prepare=_corrupt_sweep,
            check=_report_names("1_job/results.json"),
        )
    )

    c.append(Case("report after a sweep with a failed job", REPORT, (), special=_report_after_failed_sweep))

    # more config values and models (sysid-run)
    c.append(
        Case(
            "unknown key in a sweep",
            RUN,
            ("-m", *FAST, "hydra.sweep.dir={dir}/sweep", "seed=0,1", "foo=1"),
            needles=("foo",),
            check=lambda d, p: "a job started" if (d / "sweep").exists() else None,
        )
    )
    c.append(
        Case(
            "sweep where every job fails",
            RUN,
            ("-m", *FAST, "hydra.sweep.dir={dir}/sweep", "system.limits.acceleration=1e-6,2e-6"),
            status=1,
            needles=("binding constraint",),
        )
    )
    run_case("periods=1e9", "system.periods=1e9", needles=("system.periods", "samples"))
    run_case("sample_rate_hz=1e9", "system.sensor.sample_rate_hz=1e9", needles=("samples",))
    run_case("validation.periods=abc", "validation.periods=abc", needles=("validation.periods",))
    run_case("harmonics=null", "excitation.harmonics=null", needles=("excitation.harmonics",))
    run_case("seed=1e100", "seed=1e100", needles=("seed",))
    run_case("velocity 2 values, 1 joint", "system.limits.velocity=[1,2]", needles=("system.limits.velocity",))
    run_case("sigma_tau=-1", "system.sensor.sigma_tau=-1", needles=("system.sensor.sigma_tau",))
    run_case("cutoff_hz=abc", "identify.cutoff_hz=abc", needles=("identify.cutoff_hz",))
    run_case("wls iterations=-1", "estimator=wls", "estimator.options.iterations=-1", needles=("iterations",))
    run_case("a CSV as the model", "system.mjcf={base}/data.csv", needles=("data.csv",))
    run_case("a folder as the model", "system.mjcf={dir}", needles=("system",))
    run_case(
        "broken XML model",
        "system.mjcf={dir}/robot.xml",
        needles=("robot.xml", "cannot load"),
        prepare=_model("<mujoco><worldbody><body>"),
    )
    run_case(
        "model without joints",
        "system.mjcf={dir}/robot.xml",
        needles=("no joints",),
        prepare=_model('<mujoco><worldbody><body><geom size=".1"/></body></worldbody></mujoco>'),
    )
    run_case(
        "model without actuators",
        "system.mjcf={dir}/robot.xml",
        needles=("driven", "motor"),
        prepare=_model(
            '<mujoco><worldbody><body><joint name="j" axis="1 0 0"/><geom size=".1" pos="0 0 .2"/></body>'
            "</worldbody></mujoco>"
        ),
    )

    # more data files (sysid-diagnose)
    for name, edit in (
        ("semicolon-separated", lambda t: t.replace(",", ";")),
        ("tab-separated", lambda t: t.replace(",", "\t")),
        ("CRLF line ends", lambda t: t.replace("\n", "\r\n")),
        ("UTF-8 byte-order mark", lambda t: "\ufeff" + t),
        ("spaces after commas in the header", lambda t: t.replace(",", ", ", t.index("\n"))),
    ):
        c.append(Case(name, DIAGNOSE, data, status=0, prepare=_text(edit), keep=("data.csv",)))
    data_case("decimal commas", _text(lambda t: t.translate(str.maketrans(",.", ";,"))), "decimal comma")
    data_case("a comment line above the header", _text(lambda t: "# exported 2026-11-30\n" + t), "comment")
    data_case("torque stuck at zero", _mutated(_stuck), "stuck at zero")
    data_case(
        "joint that never moves",
        _mutated(lambda h, t: (h, np.column_stack([t[:, :1], 0 * t[:, 1:2] + 0.1, t[:, 2:]]))),
        "excite",
    )
    data_case("duplicate column name", _text(lambda t: t.replace("tau_cmd_swing", "tau_swing", 1)), "2 times")
    data_case("mapping to a missing column", copy, "'foo'", args=("+data.columns.tau_swing=foo",))
    data_case("unknown name in the mapping", copy, "bogus", args=("+data.columns.bogus=time",))
    data_case("pattern that matches no file", None, "matches no file", path="{dir}/nope_*.csv")
    c.append(
        Case(
            "a pattern for two files",
            DIAGNOSE,
            ("system=pendulum", "data.path={dir}/run_*.csv", *data[2:]),
            status=0,
            prepare=_halves,  # two different files (a copy of one file is refused: it cannot be fitted and validated)
        )
    )
    data_case("a folder in the list", copy, "folder", path="[{dir}/data.csv,{dir}]")
    data_case("max_rows=10", copy, "diagnose.max_rows", args=("diagnose.max_rows=10",))
    data_case("diagnose cutoff above Nyquist", copy, "cutoff_hz", args=("diagnose.cutoff_hz=1000",))
    data_case("band_hz=-1", copy, "diagnose.band_hz", args=("diagnose.band_hz=-1",))
    data_case("window_s=0", copy, "diagnose.window_s", args=("diagnose.window_s=0",))
    data_case("repair=maybe", copy, "data.repair", args=("data.repair=maybe",))
    c.append(Case("3 M-row file", DIAGNOSE, (), special=_large_file))

    # signals
    c.append(Case("SIGTERM during a run", RUN, (), special=_sigterm))
    c.append(Case("SIGKILL of a job in a joblib sweep", RUN, (), special=_sigkill_sweep))
    return c


def _mount(target: Path, options: str) -> None:
    target.mkdir(parents=True, exist_ok=True)
    subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(target)], check=True, capture_output=True)


def _judge(case: Case, d: Path, base: Path) -> dict:
    if case.needs_root and os.geteuid() != 0:
        return {"case": case.name, "verdict": "skipped", "why": "needs root to mount a tmpfs"}
    try:
        if case.prepare is not None:
            case.prepare(d, base)
    except (OSError, subprocess.CalledProcessError) as err:
        return {"case": case.name, "verdict": "skipped", "why": f"cannot set up: {err}"}
    if case.special is not None:
        ok, why = case.special(d, base)
        return {"case": case.name, "verdict": "well" if ok else "badly", "why": why}
    before = {k: _digest(d / k) for k in case.keep}
    args = [a.replace("{dir}", str(d)).replace("{base}", str(base)) for a in case.args]
    proc = _py(case.module, *args)
    last = _last(proc.stderr)
    problems = []
    if proc.returncode != case.status:
        problems.append(f"status {proc.returncode}, expected {case.status}")
    if "Traceback" in proc.stderr:
        problems.append("traceback")
    problems += [f"last line lacks {n!r}" for n in case.needles if n not in last]
    problems += [f"{k} changed" for k in case.keep if _digest(d / k) != before[k]]
    trouble = case.check(d, proc) if case.check is not None else None
    if trouble:
        problems.append(trouble)
    verdict = "well" if not problems else ("partly" if proc.returncode == case.status else "badly")
    return {"case": case.name, "verdict": verdict, "status": proc.returncode, "last_line": last, "why": problems}


def _halves(d: Path, b: Path) -> None:
    """run_1.csv and run_2.csv: the first and the second half of the base run's data.csv."""
    header, *rows = (b / "data.csv").read_text().splitlines()
    half = len(rows) // 2
    for i, part in ((1, rows[:half]), (2, rows[half:])):
        (d / f"run_{i}.csv").write_text("\n".join([header, *part]) + "\n")


def main() -> None:
    with terminate_as_exit(), tempfile.TemporaryDirectory(prefix="sysid_trial_") as tmp:  # SIGTERM: unmount, remove
        root = Path(tmp)
        base = root / "base"
        proc = _py(RUN, *FAST, f"hydra.run.dir={base}")
        if proc.returncode != 0:
            raise RuntimeError(f"the reference run failed: {proc.stderr[-2000:]}")
        cases = _cases()
        folders = []
        for i, _ in enumerate(cases):
            folders.append(root / f"case{i:03d}")
            folders[-1].mkdir()
        try:
            with ThreadPoolExecutor(2) as pool:
                rows = list(pool.map(lambda cd: _judge(cd[0], cd[1], base), zip(cases, folders, strict=True)))
        finally:
            for f in folders:
                for sub in ("ro", "full"):
                    if (f / sub).is_dir():
                        subprocess.run(["umount", "-l", str(f / sub)], capture_output=True, check=False)
    counts = {v: sum(r["verdict"] == v for r in rows) for v in ("well", "partly", "badly", "skipped")}
    (HERE / "reliability.json").write_text(json.dumps({"counts": counts, "cases": rows}, indent=2) + "\n")
    md = [
        "# Reliability trial (`python -m bench reliability`)",
        "",
        f"{len(rows)} cases: {counts['well']} handled well, {counts['partly']} partly, {counts['badly']} badly, "
        f"{counts['skipped']} skipped.",
        "",
        "| case | verdict | exit | last line on stderr / why |",
        "|---|---|---:|---|",
    ]
    for r in rows:
        detail = str(r.get("last_line") or r.get("why") or "")
        if r["verdict"] != "well" and r.get("last_line"):
            detail = f"{r['why']}: {r['last_line']}"
        md.append(f"| {r['case']} | {r['verdict']} | {r.get('status', '')} | {str(detail).replace('|', '/')[:220]} |")
    (HERE / "reliability.md").write_text("\n".join(md) + "\n")
    print("\n".join(md[:3]))


if __name__ == "__main__":
    main()

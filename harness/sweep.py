"""Sweeps that survive their jobs: one process per job, every failure recorded, a non-zero exit when any failed.

`run_isolated` runs one job of a Hydra multirun in a forked child process: a job that raises writes
`failure.json`; a job whose process dies (SIGKILL, the out-of-memory killer, a crash in native code) is
recorded by the parent, and the launcher's worker lives on to run the jobs still pending (without this, one
killed joblib worker ends the whole sweep with `TerminatedWorkerError`). The child volunteers to the
out-of-memory killer first (`oom_score_adj` 1000), so that the job, not the worker, is the one killed.

`SweepStatus` (a Hydra callback, set in the configs' `hydra.callbacks`) prints which jobs failed when the sweep
ends and makes its exit status 1 if any did, or if jobs shared one folder (a `hydra.sweep.subdir` that does not
tell them apart: each job's files overwrote the other's, and one folder of results stood for several jobs). Each
job notes its folder in the sweep's `.sysid_jobs/` as it starts (`JOBS_DIR`), in whatever process runs it.
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import os
import shutil
import signal
import sys
import traceback
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import Any

from hydra.experimental.callback import Callback
from hydra.types import RunMode
from omegaconf import DictConfig

from harness.rundir import RESULTS_FILES, clean_stale_temporaries, failed_since_results

__all__ = ["JOBS_DIR", "SweepStatus", "failed_jobs", "run_isolated", "shared_folders"]

JOBS_DIR = ".sysid_jobs"  # in a sweep folder: a file per job, named by its number, holding the job's folder


def _child(work: Callable[[Any], Any], cfg: Any, out: Path, label: str) -> None:
    from harness.results import USER_ERRORS, as_interrupt, one_line, record_failure
    from harness.rundir import terminate_as_exit

    with contextlib.suppress(OSError):
        Path("/proc/self/oom_score_adj").write_text("1000")
    code = 0
    with terminate_as_exit():
        try:
            work(cfg)
        except BaseException as raised:
            err = as_interrupt(raised)
            message = record_failure(out, err, own_folder=True)
            shown = one_line(err) if isinstance(err, USER_ERRORS) else message
            print(f"{label} failed: {shown}", file=sys.stderr)
            if not isinstance(err, (*USER_ERRORS, SystemExit, KeyboardInterrupt)):
                traceback.print_exc()
            code = 2 if isinstance(err, USER_ERRORS) else 1
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def run_isolated(work: Callable[[Any], Any], cfg: Any, out: Path, *, label: str) -> None:
    """Run `work(cfg)` in a forked child; record a death by signal in `out/failure.json`. Returns None."""
    from harness.results import write_json

    proc = multiprocessing.get_context("fork").Process(target=_child, args=(work, cfg, out, label))
    proc.start()

    def forward(signum: int, frame: FrameType | None) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.kill(proc.pid or 0, signum)

    try:
        previous = signal.signal(signal.SIGTERM, forward)
    except ValueError:  # not the main thread
        previous = None
    try:
        proc.join()
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    code = proc.exitcode
    if code is not None and code < 0:
        name = signal.Signals(-code).name
        why = " (the out-of-memory killer, or killed by hand)" if name == "SIGKILL" else ""
        message = f"the job's process (pid {proc.pid}) was killed by {name}{why}"
        with contextlib.suppress(OSError):
            out.mkdir(parents=True, exist_ok=True)
            write_json(out / "failure.json", {"error": message, "signal": name, "traceback": None})
            clean_stale_temporaries(out)  # what it was writing when it died (no claim of that folder comes again)
        print(f"{label} failed: {message}", file=sys.stderr)
    elif code and not (out / "failure.json").exists() and not any((out / n).exists() for n in RESULTS_FILES):
        with contextlib.suppress(OSError):
            write_json(out / "failure.json", {"error": f"the job's process exited with status {code}"})


def failed_jobs(sweep: Path) -> list[tuple[str, str]]:
    """(job folder, error) for every job of `sweep` (a folder with `.hydra/`) that has no results file."""
    out = []
    for job in sorted(p.parent for p in Path(sweep).rglob(".hydra")):
        if any((job / n).is_file() for n in RESULTS_FILES) and not failed_since_results(job):
            continue
        error = "no output and no failure record"
        with contextlib.suppress(OSError, ValueError, KeyError, TypeError):
            error = str(json.loads((job / "failure.json").read_text())["error"])
        out.append((str(job.relative_to(sweep)), error))
    return out


def shared_folders(sweep: Path) -> dict[str, list[int]]:
    """The job folders of `sweep` that more than one job of its last run wrote into: folder -> job numbers."""
    by_folder: dict[str, list[int]] = {}
    for note in sorted(Path(sweep, JOBS_DIR).glob("*")):
        with contextlib.suppress(OSError, ValueError):
            by_folder.setdefault(note.read_text().strip(), []).append(int(note.name))
    return {folder: sorted(jobs) for folder, jobs in by_folder.items() if len(jobs) > 1}


class SweepStatus(Callback):
    """At the end of a multirun: list the failed jobs, and the jobs that shared a folder, and exit with status 1 if
    there are any."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        shutil.rmtree(Path(str(config.hydra.sweep.dir), JOBS_DIR), ignore_errors=True)  # an earlier sweep's notes

    def on_job_start(self, config: DictConfig, **kwargs: Any) -> None:
        if config.hydra.mode != RunMode.MULTIRUN:
            return
        notes = Path(str(config.hydra.sweep.dir), JOBS_DIR)
        with contextlib.suppress(OSError):  # a note that cannot be written only leaves the check blind
            notes.mkdir(parents=True, exist_ok=True)
            (notes / str(config.hydra.job.num)).write_text(str(Path(str(config.hydra.runtime.output_dir)).resolve()))

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        sweep = Path(str(config.hydra.sweep.dir))
        failed, shared = failed_jobs(sweep), shared_folders(sweep)
        if not failed and not shared:
            return
        name = config.hydra.job.name
        if failed:
            total = sum(1 for _ in sweep.rglob(".hydra"))
            print(f"{name}: {len(failed)} of {total} job(s) failed in {sweep}:", file=sys.stderr)
            for job, error in failed:
                print(f"  {job}: {error}", file=sys.stderr)
        for folder, jobs in shared.items():
            print(
                f"{name}: jobs {', '.join(map(str, jobs))} shared the folder {folder} (hydra.sweep.subdir gives them "
                "one): each overwrote the other's files; put ${hydra.job.num} in the subdir",
                file=sys.stderr,
            )
        raise SystemExit(1)

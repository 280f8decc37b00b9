"""A run folder belongs to one run: a lock while it runs, no silent overwrite, and clean-up on SIGTERM.

`claim(folder, outputs=..., overwrite=...)` is entered before any computation:

- the folder is created and checked writable (a read-only folder or a full disk fails here, not after
  minutes of work);
- an exclusive `fcntl` lock on `.sysid.lock` (which holds the owner's pid, and is removed at the end) is taken;
  a second run into the same folder is refused while the first holds it, and the lock goes with the process
  however it ends;
- a folder that already holds outputs of a finished run (a user's `results.json`, `data.csv`, ...) is refused
  unless `overwrite` is true, and one that holds another tool's results (`RESULTS_FILES`: a `sysid-run`'s
  results.json in a `sysid-diagnose` folder, or the reverse) is refused always: the two would share one
  `.hydra/` record of their config;
- temporary files that a killed run left (`.<name>.*.tmp`) are removed.

`RunFolder.staged()` gives a hidden folder to write the new outputs into; only once they are all written does
`RunFolder.retire()` remove the previous run's outputs (results file first) and the new ones take their place, so
that a rerun that fails or is stopped while writing neither leaves the old results beside new data nor loses them.
`terminate_as_exit()` turns SIGTERM into `SystemExit`, so that every `finally` and temporary-file clean-up
runs when a scheduler stops the job.
"""

from __future__ import annotations

import errno
import fcntl
import os
import shutil
import signal
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import FrameType

__all__ = [
    "LOCK_NAME",
    "RESULTS_FILES",
    "STAGING_PREFIX",
    "RunFolder",
    "RunFolderError",
    "check_output_override",
    "claim",
    "clean_stale_temporaries",
    "kept_on_failure",
    "terminate_as_exit",
]

LOCK_NAME = ".sysid.lock"
STAGING_PREFIX = ".staged."  # the folder a run writes its outputs into before they replace the previous ones
RESULTS_FILES = ("results.json", "diagnosis.json")  # what marks a finished run of each tool (sysid-run, -diagnose)


def failed_since_results(folder: Path) -> bool:
    """Whether the last run in `folder` failed after its results were written: a `failure.json` at least as new as
    each results file there (a job of a sweep re-run with overwrite=true that failed before it could replace the
    earlier run's results: those are not this sweep's)."""
    failure = folder / "failure.json"
    results = [folder / n for n in RESULTS_FILES if (folder / n).is_file()]
    if not failure.is_file() or not results:
        return False
    return all(failure.stat().st_mtime_ns >= r.stat().st_mtime_ns for r in results)


class RunFolderError(ValueError):
    """The run folder cannot be used: not writable, in use by another run, or holding a finished run."""


@dataclass(frozen=True)
class RunFolder:
    """A claimed run folder and the outputs its run writes (the results file last)."""

    path: Path
    outputs: tuple[str, ...]
    inputs: tuple[str, ...] = ()  # files in the folder that this run reads: never retired, never replaced

    def retire(self) -> None:
        """Remove the previous outputs (the results file, the last of `outputs`, first) and any failure record."""
        for name in (*reversed(self.outputs), "failure.json"):
            (self.path / name).unlink(missing_ok=True)

    @contextmanager
    def staged(self) -> Iterator[Path]:
        """A hidden folder inside the run folder to write the new outputs into. When the block ends normally the
        previous outputs are retired and the new ones renamed into place (the results file last, each rename
        atomic); when it fails, or the run is stopped while writing, the staged files go and the previous
        outputs stay as they were (a kill that leaves the staging folder: the next `claim` removes it). Writing
        took seconds (the recording) after the previous results had been removed: a run stopped then lost them."""
        stage = Path(tempfile.mkdtemp(dir=self.path, prefix=STAGING_PREFIX, suffix=".tmp"))
        try:
            yield stage
            clash = sorted(p.name for p in stage.iterdir() if p.name in self.inputs)
            if clash:
                raise RunFolderError(
                    f"run folder {self.path}: this run would write {clash[0]} over the file it read as its input; "
                    "copy the input elsewhere or choose another folder"
                )
            with _signals_held():  # a stop between the retiring and the renames would leave neither old nor new
                self.retire()
                results = self.outputs[-1]
                for name in [*sorted(p.name for p in stage.iterdir() if p.name != results), results]:
                    if (stage / name).exists():
                        os.replace(stage / name, self.path / name)
        finally:
            shutil.rmtree(stage, ignore_errors=True)


@contextmanager
def _signals_held() -> Iterator[None]:
    """SIGTERM and SIGINT held back within the block and raised again when it ends, to the handlers then in place
    (the Python handlers, which run in the main thread: a thread's signal mask does not hold a signal another
    thread of the process may take). Outside the main thread, nothing is held."""
    caught: list[int] = []

    def hold(signum: int, frame: FrameType | None) -> None:
        caught.append(signum)

    try:
        previous = {s: signal.signal(s, hold) for s in (signal.SIGTERM, signal.SIGINT)}
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        for signum in dict.fromkeys(caught):
            signal.raise_signal(signum)


def _check_writable(folder: Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".sysid_write_probe.{os.getpid()}.tmp"
        with probe.open("wb") as f:
            f.write(b"\0" * 4096)  # a full disk refuses a block, not always an empty file
            f.flush()
            os.fsync(f.fileno())
        probe.unlink()
    except OSError as err:
        reason = "no space left on the device" if err.errno == errno.ENOSPC else (err.strerror or str(err))
        raise RunFolderError(f"run folder {folder} is not writable: {reason}") from None


def check_output_override(argv: Sequence[str], outputs: Sequence[str] = ()) -> None:
    """Before Hydra starts: the run (or sweep) folder of a command line, or the folder it would be made in, is
    writable, not in use by another run, and (a single run's folder) holds none of `outputs` unless the command
    line says `overwrite=true`. Hydra writes its `.hydra/` files and log there before any of our code runs: it
    would fail with a traceback, or replace a finished run's `.hydra/` before `claim` could refuse the folder.

    Raises:
        RunFolderError: the folder (or its nearest existing parent) is not writable, is locked, or holds a run.
    """
    key, value = _folder_override(argv)
    target = Path(value.split("${", 1)[0] or ".") if value is not None else Path.cwd()
    folder = target.absolute()
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise RunFolderError(f"run folder {target}: {folder} is a file, not a folder")
    try:
        with tempfile.TemporaryFile(dir=folder) as f:
            f.write(b"\0" * 4096)
            f.flush()
            os.fsync(f.fileno())
    except OSError as err:
        reason = "no space left on the device" if err.errno == errno.ENOSPC else (err.strerror or str(err))
        where = "" if folder == target.absolute() else f" (it would be made in {folder})"
        raise RunFolderError(f"run folder {target} is not writable{where}: {reason}") from None
    if value is not None and target.is_dir() and key == "hydra.run.dir=":
        if (target / LOCK_NAME).exists():
            os.close(_lock(target / LOCK_NAME, target))  # raises while another run holds it
        _refuse_held(target, outputs, _overwrite(argv))
    if value is not None and target.is_dir() and key == "hydra.sweep.dir=" and not _overwrite(argv):
        # Hydra rewrites multirun.yaml and each job folder's .hydra/ before any job could refuse its folder
        done = sorted(str(p.relative_to(target)) for name in RESULTS_FILES for p in target.glob(f"*/{name}"))
        if done:
            raise RunFolderError(
                f"sweep folder {target} already holds finished jobs ({', '.join(done[:3])}"
                f"{', ...' if len(done) > 3 else ''}); pass overwrite=true to replace them, or choose another "
                "hydra.sweep.dir"
            )


def _overwrite(argv: Sequence[str]) -> bool:
    """Whether a command line sets `overwrite` true, as Hydra reads it: `overwrite=true` in any case (`True`,
    `TRUE`), also as `+overwrite=` or `++overwrite=`; the last setting counts."""
    value = _last_setting(argv, "overwrite=")
    return value is not None and value.strip().lower() == "true"


def _folder_override(argv: Sequence[str]) -> tuple[str, str | None]:
    """The folder key of a command line (`hydra.sweep.dir=` with -m, else `hydra.run.dir=`) and its last value
    there (None where the command line does not set it)."""
    key = "hydra.sweep.dir=" if ("-m" in argv or "--multirun" in argv) else "hydra.run.dir="
    return key, _last_setting(argv, key)


def _last_setting(argv: Sequence[str], key: str) -> str | None:
    """The value a command line gives `key` (with its "="), as Hydra reads it: the last setting counts, and
    `+key=` and `++key=` set it too; None where it is not set."""
    values = [a.split("=", 1)[1] for a in argv if a.lstrip("+").startswith(key)]
    return values[-1] if values else None


def _refuse_held(folder: Path, outputs: Sequence[str], overwrite: bool) -> None:
    """Raises RunFolderError where `folder` holds another tool's results, or `outputs` of a finished run and not
    `overwrite`."""
    foreign = [name for name in RESULTS_FILES if name not in outputs and (folder / name).exists()]
    if foreign:
        raise RunFolderError(
            f"run folder {folder} holds {foreign[0]}, the results of another tool's run: choose another folder "
            "(overwrite=true does not apply to it)"
        )
    present = [name for name in outputs if (folder / name).exists()]
    if present and not overwrite:
        raise RunFolderError(
            f"run folder {folder} already holds {', '.join(present)} of another run; "
            "pass overwrite=true to replace them, or choose another folder"
        )


def clean_stale_temporaries(folder: Path) -> list[str]:
    """Remove what a killed run left in `folder`: its staging folder and its temporary files (`.<name>.*.tmp`);
    returns their names."""
    removed = []
    for p in folder.glob(f"{STAGING_PREFIX}*.tmp"):  # the staged outputs of a run killed while writing them
        if p.is_dir():
            shutil.rmtree(p, ignore_errors=True)
            removed.append(p.name)
    for p in folder.glob(".*.tmp"):
        if p.is_file():
            p.unlink(missing_ok=True)
            removed.append(p.name)
    return removed


@contextmanager
def claim(
    folder: Path,
    *,
    outputs: Sequence[str],
    overwrite: bool,
    inputs: Sequence[Path] = (),
    writes: Sequence[str] | None = None,
) -> Iterator[RunFolder]:
    """Hold `folder` for one run (see the module docstring); released when the block ends.

    Args:
        folder: the run folder (created if absent).
        outputs: the files the run writes, in writing order; the last one is the results file that marks a
            finished run.
        overwrite: allow replacing the outputs of a finished run.
        inputs: the files the run reads (its model, its logs). One that lies in `folder` under the name of an
            output (a model called model.xml, a calibrated MJCF of an earlier diagnosis there) is the user's input,
            not a finished run's output: it neither counts as one nor is retired, and a run that would write
            over it is refused: here where it is among `writes`, else when its outputs are put in place.
        writes: the outputs this run certainly writes (None: all of `outputs`; the others it only retires).

    Raises:
        RunFolderError: not writable, locked by another run, or holding outputs and `overwrite` is false.
    """
    folder = Path(folder)
    _check_writable(folder)
    lock = folder / LOCK_NAME
    fd = _lock(lock, folder)
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        read = _inputs_among(folder, outputs, inputs)
        clash = [name for name in read if name in (outputs if writes is None else writes)]
        if clash:
            raise RunFolderError(
                f"run folder {folder}: this run writes {clash[0]}, and that file is its input; copy the input "
                "elsewhere or choose another folder (or, for sysid-diagnose, another system.name)"
            )
        own = tuple(name for name in outputs if name not in read)
        _refuse_held(folder, own, overwrite)
        clean_stale_temporaries(folder)
        yield RunFolder(folder, own, read)
    finally:
        lock.unlink(missing_ok=True)  # while still holding it: a later run finds no stale file
        os.close(fd)  # closing releases the lock


def _inputs_among(folder: Path, outputs: Sequence[str], inputs: Sequence[Path]) -> tuple[str, ...]:
    """The names of `outputs` whose file in `folder` is one of `inputs` (the same file, however named)."""
    read = [Path(p) for p in inputs if Path(p).is_file()]
    out = []
    for name in outputs:
        path = folder / name
        if path.is_file() and any(os.path.samefile(path, p) for p in read):
            out.append(name)
    return tuple(out)


def _lock(lock: Path, folder: Path) -> int:
    """An open descriptor holding the exclusive lock on `lock` (the file at that path, not an unlinked one)."""
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = os.pread(fd, 64, 0).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise RunFolderError(
                f"run folder {folder} is in use by another run (pid {owner}); wait for it or choose another folder"
            ) from None
        try:
            same = os.stat(lock).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)  # the holder removed the file between our open and our lock: try the new one


@contextmanager
def terminate_as_exit() -> Iterator[None]:
    """Within the block, SIGTERM raises `SystemExit(143)` in the main thread (clean-up code then runs)."""

    def handler(signum: int, frame: FrameType | None) -> None:
        raise SystemExit(128 + signum)

    try:
        previous = signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextmanager
def kept_on_failure(argv: Sequence[str], outputs: Sequence[str]) -> Iterator[None]:
    """Around Hydra's run of a command line with `overwrite=true` into a folder that holds a finished run (its
    last output): Hydra replaces the folder's `.hydra/` files and log before the run starts, so a run that then
    fails would leave the old outputs beside the new, failed run's config. Where the old last output is still
    there after a failure, the `.hydra/` files and logs are put back as they were (new ones removed)."""
    key, value = _folder_override(argv)
    target = Path(value) if value is not None and key == "hydra.run.dir=" else None
    if target is None or not _overwrite(argv) or not outputs or not (target / outputs[-1]).is_file():
        yield
        return
    last_path = target / outputs[-1]
    last = last_path.read_bytes()

    def record() -> list[Path]:  # what Hydra writes into the folder before the run
        return [p for p in [*target.glob(".hydra/*"), *target.glob("*.log")] if p.is_file()]

    kept = {p: p.read_bytes() for p in record()}
    try:
        yield
    except BaseException as err:
        failed = not isinstance(err, SystemExit) or err.code not in (0, None)
        if failed and last_path.is_file() and last_path.read_bytes() == last:
            for p in record():
                if p not in kept:
                    p.unlink()
            for p, data in kept.items():
                p.write_bytes(data)
        raise

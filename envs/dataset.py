"""Measured (or simulated) joint data, and its CSV form (the measured-data format of DESIGN.md)."""

from __future__ import annotations

import csv
import io
import os
import re
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dynamics.errors import DataError

__all__ = ["Dataset", "atomic_write", "scratch_folder", "write_csv"]


@dataclass(frozen=True)
class Dataset:
    """Joint data on one time grid.

    Attributes:
        time: (N,) strictly increasing sample times [s].
        q: (N, nv) joint angles [rad].
        tau: (N, nv) measured joint torque [N m]; zero (known exactly) on unactuated joints.
        joint_names: (nv,) joint names as in the MJCF.
        actuated: (nv,) True where the joint is driven (its torque column is a measurement).
        dq: (N, nv) joint velocities [rad/s], or None when not measured.
        ddq: (N, nv) joint accelerations [rad/s^2]: only the simulator knows them exactly; None otherwise.
        tau_cmd: (N, nv) commanded torque [N m] where it differs from the measured one, or None.
        source: where the data came from (a file path or "simulation"), used in error messages.
        tau_lead_s: the torque reported at row k acted over an interval centred at time[k] + tau_lead_s [s]:
            half a sample for a zero-order-hold controller whose command is logged at the start of its
            interval (the simulator's case), 0 for a torque sampled at the instant, a few ms for a command the
            drive applies later (its current loop's lag) or angles reported late. Derivative filters evaluate
            the states at that time, so that states and torque describe the same instant.
        meta: free-form facts about how the data was made (seed, sensor, saturation, ...).
    """

    time: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    joint_names: tuple[str, ...]
    actuated: np.ndarray
    dq: np.ndarray | None = None
    ddq: np.ndarray | None = None
    tau_cmd: np.ndarray | None = None
    source: str = "simulation"
    tau_lead_s: float = 0.0
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n, nv = len(self.time), len(self.joint_names)
        if self.time.ndim != 1 or n < 2:
            raise DataError(f"{self.source}: time must be a 1-D array of >= 2 samples, got shape {self.time.shape}")
        for name in ("q", "tau", "dq", "ddq", "tau_cmd"):
            value = getattr(self, name)
            if value is not None and value.shape != (n, nv):
                raise DataError(f"{self.source}: {name} has shape {value.shape}, expected ({n}, {nv})")
        if np.asarray(self.actuated).shape != (nv,):
            raise DataError(f"{self.source}: actuated has shape {np.shape(self.actuated)}, expected ({nv},)")
        steps = np.diff(self.time)
        if np.any(steps <= 0):
            row = int(np.argmax(steps <= 0)) + 1
            raise DataError(f"{self.source}: column 'time' is not strictly increasing at row {row}")

    @property
    def n_samples(self) -> int:
        return len(self.time)

    @property
    def dt(self) -> float:
        """Median sample interval [s]."""
        return float(np.median(np.diff(self.time)))

    def slice(self, start: int, stop: int) -> Dataset:
        """Rows [start, stop) as a new dataset."""
        rows = slice(start, stop)

        def cut(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[rows]

        return Dataset(
            time=self.time[rows],
            q=self.q[rows],
            tau=self.tau[rows],
            joint_names=self.joint_names,
            actuated=self.actuated,
            dq=cut(self.dq),
            ddq=cut(self.ddq),
            tau_cmd=cut(self.tau_cmd),
            source=self.source,
            tau_lead_s=self.tau_lead_s,
            meta=self.meta,
        )


def write_csv(dataset: Dataset, path: Path) -> None:
    """Write a dataset in the measured-data format, atomically (a reader never sees half a file).

    Columns: `time`, `q_<joint>`, `dq_<joint>` (when known), `tau_<joint>` (actuated joints),
    `tau_cmd_<joint>` (when known, actuated joints) and `ddq_<joint>` (simulated data only).
    """
    names = dataset.joint_names
    act = [j for j, a in enumerate(dataset.actuated) if a]
    columns = [("time", dataset.time)]
    columns += [(f"q_{n}", dataset.q[:, j]) for j, n in enumerate(names)]
    if dataset.dq is not None:
        columns += [(f"dq_{n}", dataset.dq[:, j]) for j, n in enumerate(names)]
    columns += [(f"tau_{names[j]}", dataset.tau[:, j]) for j in act]
    if dataset.tau_cmd is not None:
        columns += [(f"tau_cmd_{names[j]}", dataset.tau_cmd[:, j]) for j in act]
    if dataset.ddq is not None:
        columns += [(f"ddq_{n}", dataset.ddq[:, j]) for j, n in enumerate(names)]
    table = np.column_stack([c for _, c in columns])
    buffer = io.StringIO()  # a joint name with a comma or a quote is quoted as CSV asks
    csv.writer(buffer, lineterminator="").writerow([n for n, _ in columns])
    header = buffer.getvalue()
    atomic_write(path, lambda f: np.savetxt(f, table, delimiter=",", header=header, comments="", fmt="%.10g"))


def _umask() -> int:
    """The process's umask, read without changing it where Linux allows (os.umask sets it to read it)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write(path: Path, write, *, binary: bool = False) -> None:  # type: ignore[no-untyped-def]
    """Write through `write(file)` into a temporary file beside `path`, then rename it into place.

    The file gets the permissions any new file gets under the process's umask (0644 under the usual 022), not
    the temporary file's private 0600: others on a shared file system can read the results.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, "wb" if binary else "w") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())  # the data reach the disk before the name does (a crash leaves old or new)
        os.replace(tmp, path)
    except OSError as err:
        Path(tmp).unlink(missing_ok=True)
        if err.filename is None and err.errno is not None:  # a write error names no file: name ours
            raise OSError(err.errno, err.strerror, str(path)) from err
        raise
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: alive
        return True
    return True


def _remove_orphans(prefix: str) -> None:
    """Remove `<prefix><pid>_*` folders in the temporary folder whose process is gone (a SIGKILL, an OOM kill
    or a power cut gives a process no chance to clean up; the next one does)."""
    pattern = re.compile(re.escape(prefix) + r"(\d+)_")
    for p in Path(tempfile.gettempdir()).glob(f"{prefix}*"):
        match = pattern.match(p.name)
        if match and p.is_dir() and not _alive(int(match.group(1))):
            shutil.rmtree(p, ignore_errors=True)


@contextmanager
def scratch_folder(prefix: str) -> Iterator[Path]:
    """A private temporary folder `<prefix><pid>_*`, removed on exit; the folders of killed processes with
    the same prefix are removed on entry."""
    _remove_orphans(prefix)
    with tempfile.TemporaryDirectory(prefix=f"{prefix}{os.getpid()}_") as tmp:
        yield Path(tmp)

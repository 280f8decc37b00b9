"""Measured joint data from CSV files: column mapping, input checks and repairs.

`read_measured` reads one CSV with a header row (the measured-data format of DESIGN.md, or any other layout
through a column mapping) into a `Dataset` of a plant's joints. The file may be gzip-compressed, UTF-8 or UTF-16
(with or without a byte-order mark) or UTF-32 text, with any line ends; cells may be quoted, and the columns not
used are not converted (they may hold text). Every message names the file, the column (the file's name, then
ours) and the row: `row k` counts data rows from 0, `line` is the line of the file (the header is line 1).
Nothing questionable reaches a fit silently:

- refused with `DataError`: missing or unknown columns, cells that are not numbers, NaN or inf, time that
  goes backwards or repeats, a gap in the sampling too long to interpolate, angles that look like degrees (or
  a velocity column that disagrees with the angle's own rate), a jump that no velocity allows and that is
  neither a whole turn nor an isolated glitch, too many glitches, and too few rows;
- repaired and reported in `dataset.meta["repairs"]` (a tuple of `Repair`): irregular start-up rows (dropped),
  encoder wrap-arounds (unwrapped by the whole turn), isolated glitches of at most `_GLITCH_MAX_RUN` samples
  (re-interpolated from the good samples around them), torque spikes far outside the column's own range
  (`_torque_spikes`: interpolated from their neighbours), and irregular or jittery sampling (interpolated onto a
  uniform grid at the median step, which the derivative filters need). `repair=False` turns the glitches and
  spikes into refusals, `resample=False` the resampling.

`identify.excitation_check.check_excitation` tells whether a regressor built from the data excites every
parameter asked for; `envs.split.split_train_validation` holds data out by file or by a block of time.
"""

from __future__ import annotations

import codecs
import contextvars
import csv
import gzip
import hashlib
import json
import re
import warnings
import zlib
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from decimal import ROUND_FLOOR, Decimal, InvalidOperation
from functools import cached_property, partial
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.ndimage import median_filter

from dynamics.errors import DataError
from dynamics.plant import Plant
from envs.dataset import Dataset

__all__ = ["Repair", "read_many", "read_measured"]

_REGULAR_TOL = 0.01  # a step within 1 % of the median step is regular (identify.derivatives asks for this)
_STARTUP_TOL = 0.25  # leading steps off the median by more than 25 % are the logger's start-up
_STARTUP_MAX_FRACTION = 0.05  # ... as long as they are a few rows; otherwise the sampling is irregular
_MAX_GAP_STEPS = 10.0  # a gap of more than 10 median steps is not interpolated across
_GLITCH_MAX_RUN = 5  # a glitch is at most 5 consecutive samples off track
_MAX_WRAP_TURNS = 2  # an encoder wrap-around is at most two whole turns between samples
_GLITCH_MAX_FRACTION = 0.01  # more glitch samples than 1 % of the rows: the sensor is not trusted
_SPIKE_WINDOW = 4 * _GLITCH_MAX_RUN + 1  # running median [samples] a torque spike is measured from (a run of
# up to twice the longest glitch moves it not at all)
_SPIKE_FACTOR = 10.0  # a torque spike departs from it by 10 x the column's 99th-percentile excursion
_MIN_JUMP = 0.02  # [rad] (or [m]) a step smaller than this is never called a jump
_DEGREE = np.pi / 180.0
_MILLIMETRE = 1e-3  # [m]
_MIN_SAMPLE_RATE_HZ = 5.0  # slower sampling is a time column in other units (ms, us) or not joint data
_MAX_SAMPLE_RATE_HZ = 1e5
_RATE_WINDOW = 2 * _GLITCH_MAX_RUN + 1  # steps in the running median that bounds the speed without dq
_SNIFF_BYTES = 1 << 16
_UTF16_SNIFF_BYTES = 1024  # UTF-16 without a byte-order mark is told by its NULs over this many first bytes
_GZIP_MAGIC = b"\x1f\x8b"
_GZIP_ERRORS = (EOFError, gzip.BadGzipFile, zlib.error)
_ENCODINGS = (  # byte-order mark, its codec without the mark, the codec that reads the file (and skips it)
    (codecs.BOM_UTF32_LE, "utf-32-le", "utf-32"),  # before UTF-16: its mark begins with UTF-16 LE's
    (codecs.BOM_UTF32_BE, "utf-32-be", "utf-32"),
    (codecs.BOM_UTF16_LE, "utf-16-le", "utf-16"),
    (codecs.BOM_UTF16_BE, "utf-16-be", "utf-16"),
    (codecs.BOM_UTF8, "utf-8", "utf-8-sig"),
)
_MARKUP = (  # a tag in the first 64 KiB of a file that begins with '<': what the file is
    ("<mujoco", "XML, a MuJoCo model (MJCF)"),
    ("<robot", "XML, a URDF robot model"),
    ("<html", "HTML, a web page"),
)
_BLOCK_ROWS = 200_000  # rows read at a time: a block of a wide file is a few tens of MB
_FORMAT_PREFIXES = ("q_", "dq_", "ddq_", "tau_cmd_", "tau_")


class _RowLines:
    """The line of each data row of a file being read, found only when a message asks (`_line`): blank lines,
    skipped by the reader, shift them from row + 2."""

    def __init__(self, file: _TextFile, rows: int) -> None:
        self.file, self.rows = file, rows

    @cached_property
    def lines(self) -> np.ndarray | None:
        return _row_lines(self.file, self.rows)

    def line(self, row: int) -> int:
        return row + 2 if self.lines is None else int(self.lines[row])


# the rows' lines of the file being read (`read_measured` sets it for its checks)
_ROW_LINES: contextvars.ContextVar[_RowLines | None] = contextvars.ContextVar("_ROW_LINES", default=None)
_TORQUE_LIMIT_FACTOR = 10.0  # a torque whose 99th-percentile size is this many times the actuator's limit is in
# other units (mN m, N cm) or another column: a motor's peak torque is a few times its rated one, not ten
_MAX_TORQUE = 1e6  # [N m] (or [N]): no robot joint carries more; the bound where an actuator has no limit
_RANGE_TOL = 0.05  # [rad] (or [m] x 0.1): beyond its range by more, a hinge logged whole turns off is turned back
_RANGE_FAR = 0.5  # [rad] (or [m] x 0.1): beyond its range by more, an angle is refused: a hard stop's soft
# contact lets a joint in a little (MuJoCo's own default limit, 0.2 rad at an impact at speed), never this far


@dataclass(frozen=True)
class Repair:
    """One repair made while reading a file, recorded in `dataset.meta["repairs"]`.

    Attributes:
        kind: `startup_trim`, `wrap`, `glitch`, `edge_glitch`, `whole_turns`, `torque_spike` or `resample`.
        column: the file's column (and ours) that was repaired, or `time`.
        rows: data rows of the file (0-based) where it applies: the first rows of each event.
        message: what was found and what was done, in words.
    """

    kind: str
    column: str
    rows: tuple[int, ...]
    message: str


@dataclass(frozen=True)
class _Column:
    name: str  # the file's column
    index: int
    scale: float = 1.0
    offset: float = 0.0


def read_measured(
    path: str | Path,
    plant: Plant,
    *,
    columns: Mapping[str, Any] | None = None,
    repair: bool = True,
    resample: bool = True,
    max_speed: float | None = None,
    min_samples: int = 50,
) -> Dataset:
    """Read one CSV file of joint data into a dataset of `plant`'s joints, checking and repairing it.

    Args:
        path: CSV file with a header row (or such a file gzip-compressed, whatever its name).
        plant: the system the data belong to; its joint names and actuators decide the columns needed:
            `time`, `q_<joint>` for every joint, `tau_<joint>` for every actuated joint, and optionally
            `dq_<joint>` (all joints) and `tau_cmd_<joint>` (all actuated joints).
        columns: None for the measured-data format (the file uses those names; `ddq_<joint>` is accepted and
            ignored, other unrelated columns are ignored and listed in `meta["ignored_columns"]`). Otherwise a
            map from our names to the file's column names, each value a name or `{column, scale, offset}`
            (ours = scale * file + offset, e.g. scale 0.0174533 for degrees, -1 for a flipped sign); our names
            left out are looked up under their own name.
        repair: unwrap encoder wrap-arounds and interpolate isolated glitches (reported); False refuses them.
        resample: interpolate irregular sampling onto a uniform grid at the median step (reported); False
            refuses it.
        max_speed: fastest physically possible joint speed [rad/s]; None estimates a bound from the data
            (3 x the 99.9th percentile of |dq|, or of the angle's own rate after a running median over 11
            steps when dq is absent, which glitches cannot move).
        min_samples: fewest rows accepted, before and after repairs.

    Returns:
        Dataset with `time` (N,) [s] on a uniform grid; `q` [rad], `tau` [N m] and the optional `dq` [rad/s]
        and `tau_cmd` [N m], each (N, nv); zero torque on unactuated joints; `source` the path; `meta` with `repairs`
        (tuple of `Repair`), `columns` (ours -> the file's column, with any scale and offset),
        `ignored_columns`, `rows_read`, `sample_rate_hz`, `time_origin_s` (a time column in Unix time, 1e6 s
        or more on its first row, is read less the whole seconds of that row, exactly: `time` + `time_origin_s`
        is the file's time; 0 for other files).

    Raises:
        DataError: a check failed; the message names the file, column and row.
    """
    path = Path(path)
    src = str(path)
    file = _text_file(path)
    header, delimiter = _read_header(file)
    if columns is None and all(_is_number(h) for h in header):  # a mapping may name numbered columns ("0", "1")
        raise DataError(
            f"{path}: line 1 holds numbers ({', '.join(header[:3])}{', ...' if len(header) > 3 else ''}), not "
            "column names: the file has no header row; add one naming its columns (time, q_<joint>, tau_<joint>, ...)"
        )
    sources, ignored = _resolve_columns(plant, header, columns, src)
    labels = _labels(sources)
    arrays, values, rows_read, time_origin = _read_body(file, header, delimiter, sources, labels, plant)
    with _lines_of(file, rows_read):  # every message below names a row by its own line of the file
        _check_length(rows_read, max(min_samples, 2), src, "rows")  # first: the checks below need a time step
        _check_finite(values, labels, src)
        t = values["time"]
        _check_time(t, sources["time"], labels["time"], src)
        names = plant.joint_names
        del values
        start = _startup_rows(t)
        # first: a gap reads as a wrong scale below
        _check_gaps(t[start:], np.arange(start, len(t)), labels["time"], src)
        _check_angle_units(plant, t, arrays, labels, src)
        _check_torque_units(plant, arrays, labels, sources, src)

        rows = np.arange(len(t))
        repairs: list[Repair] = []
        if start:
            steps = np.diff(t[: start + 1]) * 1e3
            repairs.append(
                Repair(
                    "startup_trim",
                    "time",
                    tuple(range(start)),
                    f"dropped the first {start} rows (t < {t[start]:.6g} s): start-up steps of {steps.min():.3g}-"
                    f"{steps.max():.3g} ms against the median {np.median(np.diff(t)) * 1e3:.4g} ms",
                )
            )
            t, rows, arrays = t[start:], rows[start:], _cut(arrays, start, len(t))

        head, tail = 0, 0
        q = arrays["q"]
        assert q is not None
        for j, n in enumerate(names):
            dq = arrays["dq"]
            with np.errstate(over="ignore", invalid="ignore"):  # a glitch near the largest double overflows its steps
                fixed, found, h, tl = _repair_joint(
                    t,
                    q[:, j],
                    None if dq is None else dq[:, j],
                    max_speed=max_speed,
                    label=labels[f"q_{n}"],
                    rows=rows,
                    src=src,
                    repair=repair,
                )
            q[:, j] = fixed
            repairs += found
            head, tail = max(head, h), max(tail, tl)
        arrays["q"] = q
        if head or tail:
            t, rows, arrays = t[head : len(t) - tail], rows[head : len(t) - tail], _cut(arrays, head, len(t) - tail)
        repairs += _fit_joint_ranges(t, arrays["q"], plant, labels=labels, rows=rows, src=src, repair=repair)

        for key in ("tau", "tau_cmd"):
            torque = arrays[key]
            if torque is None:
                continue
            for j, n in enumerate(names):
                label = labels.get(f"{key}_{n}")
                if label is not None:
                    torque[:, j], found = _torque_spikes(
                        t, torque[:, j], label=label, rows=rows, src=src, repair=repair
                    )
                    repairs += found
        logged = {k: arrays[k] for k in ("tau", "tau_cmd")}  # the torques as logged, before any resampling
        t, arrays, resampled = _regularise(t, arrays, rows, resample=resample, label=labels["time"], src=src)
        if resampled is not None:
            repairs.append(resampled)
        _check_length(len(t), min_samples, src, "rows left after the repairs")
        meta = {
            "repairs": tuple(repairs),
            "columns": {name: _describe(c) for name, c in sources.items()},
            "ignored_columns": tuple(ignored),
            "rows_read": rows_read,
            "sample_rate_hz": float(1.0 / np.median(np.diff(t))),
            "time_origin_s": time_origin,
        }
        if resampled is not None:  # interpolation blurs a torque's plateau at a limit: keep the logged values
            meta.update({f"logged_{k}": v.copy() for k, v in logged.items() if v is not None})
        q_out, tau_out = arrays["q"], arrays["tau"]
        assert q_out is not None and tau_out is not None
        return Dataset(
            time=t,
            q=q_out,
            tau=tau_out,
            joint_names=names,
            actuated=np.asarray(plant.actuated, bool),
            dq=arrays["dq"],
            tau_cmd=arrays["tau_cmd"],
            source=src,
            meta=meta,
        )


@contextmanager
def _lines_of(file: _TextFile, rows: int) -> Iterator[None]:
    """Within it, `_line` gives the lines of `file`'s `rows` data rows."""
    token = _ROW_LINES.set(_RowLines(file, rows))
    try:
        yield
    finally:
        _ROW_LINES.reset(token)


def _line(row: int) -> int:
    """The line of the file that data row `row` of the file being read is on (the header is line 1)."""
    lines = _ROW_LINES.get()
    return row + 2 if lines is None else lines.line(row)


def _row_lines(file: _TextFile, rows: int) -> np.ndarray | None:
    """(rows,) the line of each data row where the file has blank lines among its rows (skipped by the reader);
    None where it has none (each row on line row + 2). A pass or two over the file: for a message only."""
    if _line_count(file) - 1 == rows:
        return None
    lines = []
    with file.open() as f:  # the lines as `_read_body` reads them
        f.readline()
        for number, text in enumerate(f, start=2):
            if text.rstrip("\r\n"):
                lines.append(number)
    return np.array(lines[:rows]) if len(lines) >= rows else None


def read_many(
    paths: str | Path | Sequence[str | Path],
    plant: Plant,
    *,
    columns: Mapping[str, Any] | None = None,
    repair: bool = True,
    resample: bool = True,
    max_speed: float | None = None,
    min_samples: int = 50,
) -> list[Dataset]:
    """Read one file or several with `read_measured`, in the order given.

    Every file is checked before anything is returned, and the problems of all files are reported together.

    Raises:
        ValueError: no path given.
        DataError: a file listed twice (or two files of the same content), or any file failing a check (one line
            per file).
    """
    items = [paths] if isinstance(paths, str | Path) else list(paths)
    if not items:
        raise ValueError("no data file given (data.path is empty)")
    seen = [Path(p).resolve() for p in items]
    twice = sorted({str(p) for p in seen if seen.count(p) > 1})
    if twice:
        raise DataError(f"file(s) listed more than once (a file cannot be both fitted and validated on): {twice}")
    if len(items) > 1:  # a mapping that does not fit the plant is named once, not once per file
        _mapping_specs(plant, columns, f"data.columns (shared by all {len(items)} files)")
    datasets, errors = [], []
    for p in items:
        try:
            datasets.append(
                read_measured(
                    p,
                    plant,
                    columns=columns,
                    repair=repair,
                    resample=resample,
                    max_speed=max_speed,
                    min_samples=min_samples,
                )
            )
        except DataError as err:
            errors.append((str(Path(p)), str(err)))
    if errors:
        raise DataError(_join_errors(errors))
    first: dict[str, Path] = {}  # among files that read: two empty ones are refused for what they are
    for path, data in zip(seen, datasets, strict=True):
        # the samples read, not the bytes: a gzip copy, other line endings or another number format are copies too
        digest = _data_digest(data)
        if digest in first:
            raise DataError(
                f"{path} holds the same samples as {first[digest]} (a copy?): a file cannot be both fitted and "
                "validated on"
            )
        first[digest] = path
    return datasets


def _join_errors(errors: list[tuple[str, str]]) -> str:
    """One line per problem, in the order given: files whose messages differ only in the path that begins them
    (the same header, the same mapping) are named together before the message, once."""
    grouped: dict[tuple[bool, str], list[str]] = {}  # (begins with its path, the message after it) -> paths
    for path, message in errors:
        prefix = f"{path}: "
        named = message.startswith(prefix)
        grouped.setdefault((named, message.removeprefix(prefix)), []).append(path)
    lines = []
    for (named, text), paths in grouped.items():
        if not named:  # a message of its own form: as it is, once per file
            lines += [text] * len(paths)
        else:
            lines.append(f"{paths[0] if len(paths) == 1 else f'{len(paths)} files, ' + ', '.join(paths)}: {text}")
    return "\n".join(lines)


@dataclass(frozen=True)
class _TextFile:
    """How a data file is read as text: gzip-compressed or not, and its encoding (a Python codec)."""

    path: Path
    compressed: bool
    encoding: str  # utf-8-sig (a byte-order mark or none), utf-16 or utf-32 (after their byte-order mark), or
    # utf-16-le / utf-16-be (no mark)

    @contextmanager
    def open(self, newline: str | None = "") -> Iterator[TextIO]:
        """The file as text; `newline=""` splits lines at LF, CR LF and CR alike and leaves them as they are.

        Raises:
            DataError: a byte that is not text in the encoding, or a compressed stream that is cut or corrupt.
        """
        try:
            if self.compressed:
                f: TextIO = gzip.open(self.path, "rt", encoding=self.encoding, newline=newline)
            else:
                f = self.path.open(encoding=self.encoding, newline=newline)
            with f:
                yield f
        except UnicodeDecodeError as err:
            name = self.encoding.removesuffix("-sig").upper()
            raise DataError(
                f"{self.path}: not {name} text ({err.reason} at byte {err.start} of a block): save it as UTF-8"
            ) from None
        except _GZIP_ERRORS as err:
            raise _bad_gzip(self.path, err) from None


def _data_digest(data: Dataset) -> str:
    """SHA-256 of a dataset's samples as read: its angles and torques (not its times: a copy whose clock starts
    elsewhere is the same motion)."""
    h = hashlib.sha256()
    for a in (data.q, data.tau):
        h.update(np.ascontiguousarray(a, dtype=float).tobytes())
    return h.hexdigest()


def _text_file(path: Path) -> _TextFile:
    """How to read `path` as text: gzip is decompressed, UTF-16 and UTF-32 are decoded after their byte-order
    mark (UTF-16 without one is told by its NUL bytes, `_utf16_without_bom`). Anything else than a readable text
    file is refused, saying what it is (folder, binary, not UTF-8)."""
    if path.is_dir():
        raise DataError(f"{path}: is a folder, not a file; give the CSV file inside it")
    if not path.exists():
        raise DataError(f"{path}: no such file")
    if not path.is_file():  # a named pipe or a device would block the reader, or never end
        raise DataError(f"{path}: is not a regular file (a pipe, socket or device); give a CSV file")
    try:
        with path.open("rb") as f:
            head = f.read(_SNIFF_BYTES)
        compressed = head.startswith(_GZIP_MAGIC)
        if compressed:
            with gzip.open(path, "rb") as g:
                head = g.read(_SNIFF_BYTES)
    except PermissionError:
        raise DataError(f"{path}: cannot be read: permission denied") from None
    except _GZIP_ERRORS as err:  # BadGzipFile is an OSError: caught first
        raise _bad_gzip(path, err) from None
    except OSError as err:
        raise DataError(f"{path}: cannot be read: {err.strerror or err}") from None
    bom, bare, encoding = next((e for e in _ENCODINGS if head.startswith(e[0])), (b"", "utf-8", "utf-8-sig"))
    if not bom and b"\0" in head:  # UTF-16 saved without its byte-order mark: read in the order its NULs show
        bare = encoding = _utf16_without_bom(head) or bare
    if bare == "utf-8":  # NUL bytes are text in UTF-16 and UTF-32, in UTF-8 a binary file
        nul = head.find(b"\0")
        if nul >= 0:
            line = head[:nul].count(b"\n") + 1
            raise DataError(f"{path}: a binary file (a NUL byte at byte {nul}, line {line}), not CSV text")
    try:  # a character cut at the end of the sniffed block is left pending, not refused
        codecs.getincrementaldecoder(bare)().decode(head[len(bom) :], final=len(head) < _SNIFF_BYTES)
    except UnicodeDecodeError as err:
        raise _not_text(path, head, len(bom) + err.start, bare) from None
    return _TextFile(path, compressed, encoding)


def _utf16_without_bom(head: bytes) -> str | None:
    """`utf-16-le` or `utf-16-be` when the first bytes are UTF-16 text without a byte-order mark: no NUL at the
    even (little-endian) or odd (big-endian) bytes, NULs at most of the others (CSV is mostly ASCII; a `τ` or
    `°` in a header is not), and the sample decodes to printable text and line ends; None otherwise (a binary
    file: int16 samples of 1 to 255 have the NULs, not the text)."""
    sample = head[: min(len(head), _UTF16_SNIFF_BYTES) // 2 * 2]
    if len(sample) < 4:
        return None
    even, odd = sample[0::2], sample[1::2]
    for codec, high, low in (("utf-16-le", odd, even), ("utf-16-be", even, odd)):
        if b"\0" in low or high.count(0) < 0.5 * len(high):
            continue
        text = sample.decode(codec, errors="replace")
        if all(c.isprintable() or c in "\r\n\t" for c in text):
            return codec
    return None


def _bad_gzip(path: Path, err: Exception) -> DataError:
    return DataError(f"{path}: a gzip-compressed file that cannot be decompressed (cut short or corrupt): {err}")


def _not_text(path: Path, data: bytes, at: int, encoding: str) -> DataError:
    line = data[:at].count(b"\n") + 1
    return DataError(
        f"{path}: not {encoding.upper()} text (byte 0x{data[at]:02x} at byte {at}, line {line}); save the file as "
        "UTF-8 (or plain ASCII) CSV"
    )


def _read_header(file: _TextFile) -> tuple[list[str], str]:
    """The column names of line 1, and the delimiter they are separated by (a comma; a semicolon or a tab as
    spreadsheets export them are read too)."""
    path = file.path
    with file.open() as f:
        first = f.readline()
        rest = f.read(1 << 16) if not first.strip() or first.lstrip().startswith("<") else ""
    start = (first + rest).lstrip()
    if start.startswith("<"):  # a model or a web page, not a table: "separated by spaces" would mislead
        kind = next((k for tag, k in _MARKUP if tag in start.lower()), "XML or HTML (markup)")
        raise DataError(
            f"{path}: not CSV but {kind}: it begins with {start.splitlines()[0][:40]!r}; data.path takes CSV logs "
            "(a model is given as system.mjcf)"
        )
    if not first.strip():
        if rest.strip():
            raise DataError(
                f"{path}: line 1 is blank; the header row of column names must be line 1: remove the blank lines "
                "above it"
            )
        raise DataError(f"{path}: the file is empty; a header row of column names is expected on line 1")
    if first.lstrip().startswith("#"):
        raise DataError(
            f"{path}: line 1 is a comment ({first.strip()[:40]!r}); the header row of column names must be line 1: "
            "remove the comment lines above it"
        )
    if first.strip().lower().startswith("sep=") and len(first.strip()) <= 5:
        raise DataError(
            f"{path}: line 1 is a spreadsheet's delimiter line ({first.strip()!r}); the header row of column names "
            "must be line 1: remove that line"
        )
    delimiter = max((",", ";", "\t"), key=first.count)
    try:
        header = [h.strip() for h in next(csv.reader([first], delimiter=delimiter), [])]
    except csv.Error as err:
        raise DataError(f"{path}: the header row (line 1) cannot be read as CSV text: {err}") from None
    if not header or header == [""]:
        raise DataError(f"{path}: the file is empty; a header row of column names is expected on line 1")
    return header, delimiter


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _line_count(file: _TextFile) -> int:
    """Lines of the file (LF, CR LF or CR ended), the last one counted without its end too: an upper bound on
    its data rows + 1."""
    count, last = 0, "\n"
    with file.open(newline=None) as f:  # universal newlines: every line ends in "\n" here
        while block := f.read(1 << 22):
            count += block.count("\n")
            last = block[-1]
    return count + (last != "\n")


def _data_lines(lines: Iterable[str], n_fields: int, delimiter: str, path: Path) -> Iterator[str]:
    """The data rows of the lines after the header (line 2 on), one line each: blank lines are skipped.

    Only a line with another number of delimiters than the header's, or with a double quote, is split as CSV
    to count its fields; the others go on as they are (this runs once per line of a long file).

    Raises:
        DataError: a row with another number of fields than the header, or with a double quote left open (which
            would swallow the lines after it).
    """
    blank = 0
    for line, text in enumerate(lines, start=2):
        if text.count(delimiter) != n_fields - 1 or '"' in text:
            if not text.rstrip("\r\n"):  # as numpy's reader: a line of spaces is a row of one field
                blank += 1
                continue
            row = line - 2 - blank
            if text.count('"') % 2:
                raise DataError(
                    f'{path}: row {row} (line {line}) has an unmatched double quote ("); a quoted cell must end on '
                    "its own line"
                )
            fields = len(next(csv.reader([text], delimiter=delimiter)))
            if fields != n_fields:
                raise DataError(f"{path}: row {row} (line {line}) has {fields} fields; the header has {n_fields}")
        yield text


def _read_body(
    file: _TextFile,
    header: list[str],
    delimiter: str,
    sources: dict[str, _Column],
    labels: dict[str, str],
    plant: Plant,
) -> tuple[dict[str, np.ndarray | None], dict[str, np.ndarray], int, float]:
    """The used columns, read block by block (numpy's C reader) straight into the (N, nv) arrays of the dataset:
    memory is the dataset itself plus one block, whatever the file's length. The other columns are not converted
    (they may hold text); quoted numbers are read.

    Returns:
        arrays: q, dq, tau, tau_cmd ((N, nv); dq and tau_cmd None when absent).
        values: each used column by our name, as a view into `arrays`.
        rows: the data rows read.
        time_origin: what the time column was read relative to [s] (`_time_origin`; 0 for most files).
    """
    path = file.path
    names, nv, act = plant.joint_names, plant.nv, [j for j in range(plant.nv) if plant.actuated[j]]
    for keys in ([f"dq_{n}" for n in names], [f"tau_cmd_{names[j]}" for j in act]):
        present = [k in sources for k in keys]
        if any(present) and not all(present):
            lacking = [k for k, p in zip(keys, present, strict=True) if not p]
            raise DataError(f"{path}: missing column(s) {', '.join(lacking)}: give them for every joint or for none")
    capacity = max(_line_count(file) - 1, 1)
    arrays: dict[str, np.ndarray | None] = {
        "time": np.empty(capacity),
        "q": np.empty((capacity, nv)),
        "dq": np.empty((capacity, nv)) if f"dq_{names[0]}" in sources else None,
        "tau": np.zeros((capacity, nv)),
        "tau_cmd": np.zeros((capacity, nv)) if act and f"tau_cmd_{names[act[0]]}" in sources else None,
    }
    where: dict[str, tuple[str, int | None]] = {"time": ("time", None)}
    for j, joint in enumerate(names):
        where[f"q_{joint}"], where[f"dq_{joint}"] = ("q", j), ("dq", j)
        where[f"tau_{joint}"], where[f"tau_cmd_{joint}"] = ("tau", j), ("tau_cmd", j)

    def target(name: str) -> np.ndarray:
        block, j = where[name]
        out = arrays[block]
        assert out is not None
        return out if j is None else out[:, j]

    usecols = sorted({c.index for c in sources.values()})
    position = {index: k for k, index in enumerate(usecols)}  # a file column's place in the table read
    origin = _time_origin(file, delimiter, sources["time"].index)
    shift = float(origin) * sources["time"].scale  # [s] what the time read is relative to
    if origin and abs(sources["time"].offset + shift) < TIME_ORIGIN_S:
        # a mapped offset that already takes the origin out (offset -1.7e9): ours = scale * file + offset holds,
        # as scale * (file - origin) + (offset + scale * origin), the large terms cancelling exactly
        sources = {**sources, "time": replace(sources["time"], offset=sources["time"].offset + shift)}
        shift = 0.0
    # a time far from 0 (Unix time, 1.7e9 s) read as a double keeps 2.4e-7 s of it: read relative to its origin
    converters: dict[int | str, Callable[[str], float]] | None = (
        {sources["time"].index: partial(_relative, origin)} if origin else None
    )
    # every column converted: numpy checks each row's field count itself, and a quote left open can only swallow
    # lines into a cell that is then no number, so the lines need no check on the way (10-20 % of the time)
    every = len(usecols) == len(header)
    n = 0
    with file.open() as f:
        f.readline()
        lines = f if every else _data_lines(f, len(header), delimiter, path)
        while True:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", UserWarning)  # the empty read after the last block
                    table = np.loadtxt(
                        lines,
                        delimiter=delimiter,
                        ndmin=2,
                        max_rows=_BLOCK_ROWS,
                        comments=None,
                        usecols=None if every else usecols,
                        quotechar='"',
                        converters=converters,
                    )
            except (DataError, UnicodeDecodeError):  # both ValueErrors: from the lines, not from a cell
                raise
            except ValueError as err:
                _locate_bad_cell(file, len(header), delimiter, sources, labels)
                raise DataError(f"{path}: cannot read the rows as numbers: {err}") from err
            if table.shape[0] == 0:
                break
            if table.shape[1] != len(usecols):  # every column converted, and the rows have another number of them
                _locate_bad_cell(file, len(header), delimiter, sources, labels)
                raise DataError(f"{path}: rows have {table.shape[1]} fields but the header names {len(header)} columns")
            m = min(len(table), capacity - n)
            for name, c in sources.items():
                target(name)[n : n + m] = _scaled(table[:m, position[c.index]], c)
            n += m
            if m < len(table) or len(table) < _BLOCK_ROWS:
                break
    if n == 0:
        raise DataError(f"{path}: no data rows after the header")
    arrays.update({k: None if v is None else v[:n] for k, v in arrays.items()})
    values = {name: target(name) for name in sources}
    del arrays["time"]  # in `values`; the rest are the dataset's blocks
    return arrays, values, n, shift


TIME_ORIGIN_S = 1e6  # [s] a first time stamp this far from 0 is read relative to its whole part (`_time_origin`)


def _time_origin(file: _TextFile, delimiter: str, index: int) -> Decimal:
    """The whole part of the first row's time stamp where it is `TIME_ORIGIN_S` or more (Unix time: a double
    resolves 1.7e9 s to 2.4e-7 s, 1e-4 of a 500 Hz step, which moves the derivatives' grid); 0 otherwise, or where
    that cell is no number (the reader then names it)."""
    with file.open() as f:
        f.readline()
        for text in f:
            if not text.strip():
                continue
            cells = next(csv.reader([text], delimiter=delimiter), [])
            try:
                first = Decimal(cells[index].strip())
            except (IndexError, InvalidOperation):
                return Decimal(0)
            if not first.is_finite() or abs(first) < TIME_ORIGIN_S:
                return Decimal(0)
            return first.to_integral_value(rounding=ROUND_FLOOR)
    return Decimal(0)


def _relative(origin: Decimal, text: str) -> float:
    """A time cell less `origin`, exactly in decimal, then as a double."""
    try:
        return float(Decimal(text.strip()) - origin)
    except InvalidOperation:
        raise ValueError(f"could not convert string to float: {text!r}") from None


def _locate_bad_cell(
    file: _TextFile, n_fields: int, delimiter: str, sources: dict[str, _Column], labels: dict[str, str]
) -> None:
    """Raise a `DataError` naming the first row numpy's reader could not take, if any: one with another number of
    fields than the header (or a quote left open), or a cell of a used column that is not a number."""
    used = sorted((c.index, name) for name, c in sources.items())
    line = 1

    def numbered(f: TextIO) -> Iterator[str]:  # `line` is the line of the row last read
        nonlocal line
        for text in f:
            line += 1
            yield text

    with file.open() as f:
        f.readline()
        rows = csv.reader(_data_lines(numbered(f), n_fields, delimiter, file.path), delimiter=delimiter)
        for row, cells in enumerate(rows):
            for index, name in used:
                try:
                    # Python reads 1_0 as 10, and digits of other scripts (Arabic-Indic, full-width) as numbers;
                    # numpy's reader (and a CSV) does not
                    if "_" in cells[index] or not cells[index].isascii():
                        raise ValueError(cells[index])
                    float(cells[index])
                except ValueError:
                    raise DataError(
                        f"{file.path}: {labels[name]}, row {row} (line {line}): {cells[index]!r} is not a number"
                        f"{_cell_hint(cells[index], name, delimiter)}"
                    ) from None


def _cell_hint(cell: str, name: str, delimiter: str) -> str:
    """Why a cell may not be a number: a decimal comma, or a date or clock time in the time column."""
    if "," in cell and delimiter != "," and cell.replace(",", ".", 1).replace(".", "", 1).strip("+-").isdigit():
        return " (a decimal comma? write numbers with a decimal point)"
    if not cell.isascii() and any(c.isdigit() for c in cell):
        return " (digits of another script? write the ASCII digits 0-9)"
    if name == "time" and re.search(r"\d[-:/]\d", cell):
        return (
            " (a date or clock time? the harness expects time in seconds as a number: convert the time stamps to "
            "seconds, e.g. since the first row)"
        )
    return ""


def _labels(sources: dict[str, _Column]) -> dict[str, str]:
    """How messages name each used column: the file's name, then ours where they differ."""
    return {name: f"column '{c.name}'" + (f" ({name})" if c.name != name else "") for name, c in sources.items()}


def _targets(plant: Plant) -> dict[str, bool]:
    """Our column names for `plant`, each with whether it is required."""
    out = {"time": True}
    for n in plant.joint_names:
        out[f"q_{n}"] = True
        out[f"dq_{n}"] = False
    for j, n in enumerate(plant.joint_names):
        if plant.actuated[j]:
            out[f"tau_{n}"] = True
            out[f"tau_cmd_{n}"] = False
    return out


def _resolve_columns(
    plant: Plant, header: list[str], columns: Mapping[str, Any] | None, src: str
) -> tuple[dict[str, _Column], list[str]]:
    targets = _targets(plant)
    where = {h: i for i, h in enumerate(header)}
    listing = f"its columns are: {', '.join(header)}"
    spec = _mapping_specs(plant, columns, src)
    for key in targets:
        if key not in spec and key in where:
            spec[key] = (key, 1.0, 0.0)
    missing = [k for k, required in targets.items() if required and k not in spec]
    if missing and len(header) == 1 and len(header[0].split()) > 1:  # one column whose name is the whole header
        raise DataError(
            f"{src}: the header row is one column, {header[0][:60]!r}: the file seems separated by spaces; save it "
            "with commas (or semicolons, or tabs) between the columns"
        )
    if missing:
        raise DataError(
            f"{src}: missing column(s) {', '.join(missing)} (needed for {plant.name}); {listing}"
            f"{_suggested_mapping(plant, header, spec)}"
        )
    out: dict[str, _Column] = {}
    for key, (name, scale, offset) in spec.items():
        if name not in where:
            raise DataError(f"{src}: column '{name}' (mapped to {key}) is not in the file; {listing}")
        if header.count(name) > 1:
            raise DataError(f"{src}: column '{name}' (for {key}) appears {header.count(name)} times in the header")
        out[key] = _Column(name, where[name], scale, offset)
    by_column: dict[str, list[str]] = {}
    for key, c in out.items():  # a joint's torque and its command may share a column (a log of commands only)
        by_column.setdefault(c.name, []).append(
            "tau_" + key.removeprefix("tau_cmd_") if key.startswith("tau_cmd_") else key
        )
    for name, keys in by_column.items():
        if len(set(keys)) > 1:
            mapped = [k for k, c in out.items() if c.name == name]
            raise DataError(f"{src}: column '{name}' is mapped to {', '.join(mapped)}: each needs its own column")
    used = {c.name for c in out.values()}
    ignored = [h for h in header if h not in used]
    if columns is None:
        ddq = {f"ddq_{n}" for n in plant.joint_names}
        stray = [h for h in ignored if h not in ddq and h.startswith(_FORMAT_PREFIXES)]
        if stray:
            passive = {
                f"{p}{n}"
                for p in ("tau_", "tau_cmd_")
                for j, n in enumerate(plant.joint_names)
                if not plant.actuated[j]
            }
            why = (
                "a torque of a joint no actuator drives in this model: data of another build, or a column to leave "
                "out (a data.columns mapping reads only the columns it names)"
                if set(stray) <= passive
                else "a typo, or data of another system?"
            )
            raise DataError(
                f"{src}: unknown column(s) {', '.join(stray)}: {plant.name} has the joints "
                f"{', '.join(plant.joint_names)} (actuated: "
                f"{', '.join(n for j, n in enumerate(plant.joint_names) if plant.actuated[j]) or 'none'}); {why}"
            )
    return out, ignored


# Column names of other logs (ROS joint_states exports, drivers' logs, Franka's tau_J, the DFKI pos_meas1): the word
# that says what a column holds, words that say it is not the measurement, and words that prefer a column
_KIND_WORDS = {
    "q": {"q", "pos", "position", "positions", "qpos", "angle", "angles", "theta"},
    "dq": {"dq", "qd", "qdot", "vel", "velocity", "velocities", "qvel", "omega", "speed"},
    "tau": {"tau", "torque", "torques", "effort", "efforts", "trq"},
    "time": {"time", "t", "timestamp", "stamp", "sec", "secs", "seconds"},
}
_COMMAND_WORDS = {"cmd", "command", "commanded", "con"}  # a torque sent, not measured: tau_cmd
_NOT_MEASURED_WORDS = {  # set points, limits, other torques, accelerations ('q_d': Franka's desired q)
    *"des desired ref reference target goal set setpoint fric ext err error max min limit offset d dd ddq acc".split(),
    *_COMMAND_WORDS,
}
_MEASURED_WORDS = {"meas", "measured", "msr", "actual", "act", "j"}


def _words(name: str) -> list[str]:
    """A column name split into lower-case words and numbers: 'pos_meas1' -> pos, meas, 1; 'q[0]' -> q, 0."""
    return re.findall(r"[a-z]+|[0-9]+", re.sub(r"([a-z])([A-Z])", r"\1_\2", name).lower())


def _guess_columns(plant: Plant, header: list[str]) -> dict[str, str]:
    """Our names -> the file's columns, guessed from the column names alone: a word for the quantity (`_KIND_WORDS`)
    and either a joint's name or a number that counts the joints (0 or 1 based, in the model's joint order; torques
    may count the actuated joints only). Columns of set points and commands are not measurements; among two
    candidates a 'meas'/'actual' one is taken. A key that no column or several fit is left out."""
    joints = list(plant.joint_names)
    act = [n for j, n in enumerate(joints) if plant.actuated[j]]
    joint_words = {n: [w for w in _words(n) if w != "joint"] for n in joints}
    nameable = [n for n in joints if any(w.isalpha() for w in joint_words[n])]  # 'joint1' is counted, not named
    found: dict[str, list[tuple[bool, str]]] = {}
    numbered: dict[str, dict[int, list[tuple[bool, str]]]] = {}
    for column in header:
        words = _words(column)
        present = set(words)
        command, measured = bool(_COMMAND_WORDS & present), bool(_MEASURED_WORDS & present)
        for kind, vocabulary in _KIND_WORDS.items():
            if not vocabulary & present:
                continue
            if kind == "time":
                if len(words) == 1 or present <= vocabulary | {"s", "sec"}:
                    found.setdefault("time", []).append((True, column))
                continue
            if command and kind == "tau":
                kind = "tau_cmd"
            elif _NOT_MEASURED_WORDS & present - _MEASURED_WORDS:
                continue
            named = [n for n in nameable if all(w in words for w in joint_words[n])]
            if len(named) == 1:
                found.setdefault(f"{kind}_{named[0]}", []).append((measured, column))
            elif not named:
                numbers = [int(w) for w in words if w.isdigit()]
                if len(numbers) == 1:
                    numbered.setdefault(kind, {}).setdefault(numbers[0], []).append((measured, column))
    for kind, by_number in numbered.items():
        order = sorted(by_number)
        names = act if kind.startswith("tau") and len(order) == len(act) else joints
        if len(order) == len(names) and order in (list(range(len(names))), list(range(1, len(names) + 1))):
            for number, name in zip(order, names, strict=True):
                found.setdefault(f"{kind}_{name}", []).extend(by_number[number])
    out = {}
    for key, candidates in found.items():
        preferred = [c for m, c in candidates if m] if len(candidates) > 1 else [c for _, c in candidates]
        if len(preferred) == 1:
            out[key] = preferred[0]
    return out


def _suggested_mapping(plant: Plant, header: list[str], spec: Mapping[str, tuple[str, float, float]]) -> str:
    """A column mapping for the command line guessed from the file's column names (`_guess_columns`), when it
    names a column for every required name the file lacks; '' otherwise."""
    guess = {k: c for k, c in _guess_columns(plant, header).items() if k not in spec}
    targets = _targets(plant)
    lacking = [k for k, required in targets.items() if required and k not in spec]
    if not lacking or any(k not in guess for k in lacking) or len(set(guess.values())) < len(guess):
        return ""
    mapping = {k: guess[k] for k in targets if k in guess}
    for prefix in ("dq_", "tau_cmd_"):
        keys = [k for k in targets if k.startswith(prefix)]
        if not all(k in mapping or k in spec for k in keys):
            mapping = {k: v for k, v in mapping.items() if not k.startswith(prefix)}
    packed = ",".join(f"{k}:{json.dumps(c)}" for k, c in mapping.items())
    return f"; the column names suggest the mapping (check it) '++data.columns={{{packed}}}'"


def _mapping_specs(plant: Plant, columns: Mapping[str, Any] | None, src: str) -> dict[str, tuple[str, float, float]]:
    """The column mapping checked against `plant` (whatever the file): ours -> (the file's column, scale, offset).

    Raises:
        DataError: a name that is not one of `plant`'s, or a value that is not a column name or
            `{column, scale, offset}`; `src` begins the message.
    """
    targets = _targets(plant)
    unknown = [repr(k) for k in columns or {} if k not in targets]
    if unknown:
        raise DataError(
            f"{src}: unknown name{'s' if len(unknown) > 1 else ''} {', '.join(unknown)} in the column mapping; for "
            f"{plant.name} the names are: {', '.join(targets)} (a typo, or a mapping for another system?)"
        )
    return {str(key): _column_spec(key, value, src) for key, value in (columns or {}).items()}


def _scaled(x: np.ndarray, c: _Column) -> np.ndarray:
    """ours = scale * file + offset; a view of the table (no copy) when there is nothing to convert."""
    if c.scale == 1.0 and c.offset == 0.0:
        return x
    return c.scale * x + c.offset


def _describe(c: _Column) -> str:
    scaled = c.name if c.scale == 1.0 else f"{c.scale:.9g} * {c.name}"
    return scaled if c.offset == 0.0 else f"{scaled} + {c.offset:.9g}"


def _column_spec(key: str, value: Any, src: str) -> tuple[str, float, float]:
    if isinstance(value, str):
        return value, 1.0, 0.0
    if isinstance(value, Mapping) and "column" in value and set(value) <= {"column", "scale", "offset"}:
        numbers = []
        for part, default in (("scale", 1.0), ("offset", 0.0)):
            raw = value.get(part, default)
            try:
                number = float(raw) if not isinstance(raw, bool) else float("nan")
            except (TypeError, ValueError):
                number = float("nan")
            if not np.isfinite(number) or (part == "scale" and number == 0):
                need = "a finite nonzero number" if part == "scale" else "a finite number"
                raise DataError(f"{src}: the {part} of {key}'s mapping must be {need}, got {raw!r}")
            numbers.append(number)
        return str(value["column"]), numbers[0], numbers[1]
    raise DataError(f"{src}: the mapping of {key} must be a column name or {{column, scale, offset}}, got {value!r}")


def _check_finite(values: dict[str, np.ndarray], labels: dict[str, str], src: str) -> None:
    for name, x in values.items():
        bad = np.flatnonzero(~np.isfinite(x))
        if bad.size:
            k = int(bad[0])
            more = f" (and {bad.size - 1} more rows)" if bad.size > 1 else ""
            raise DataError(f"{src}: {labels[name]}, row {k} (line {_line(k)}): {x[k]} is not a finite number{more}")


def _check_time(t: np.ndarray, column: _Column, label: str, src: str) -> None:
    steps = np.diff(t)
    _check_time_unit(t, float(np.median(steps)), column, label, src)
    back = np.flatnonzero(steps < 0)
    same = np.flatnonzero(steps == 0)
    if back.size and (not same.size or back[0] < same[0]):
        k = int(back[0]) + 1
        raise DataError(
            f"{src}: {label} goes backwards at row {k} (line {_line(k)}): {t[k]:.9g} s after {t[k - 1]:.9g} s; "
            "time must be strictly increasing (concatenated or unsorted logs?)"
        )
    if same.size:
        k = int(same[0]) + 1
        rounded = ""
        positive = steps[steps > 0]
        grid = positive / positive.min() if positive.size else positive
        if same.size > 0.5 * len(steps) and positive.size and np.allclose(grid, np.round(grid), rtol=0, atol=1e-6):
            # most rows repeat a stamp, and the stamps move by whole steps of a coarser grid: rounded when written
            rounded = (
                f"; most rows repeat a time stamp, which moves in steps of {positive.min():.3g} s: the "
                "time was written with too few decimals to tell the rows apart; write it with more"
            )
        raise DataError(
            f"{src}: {label} repeats {t[k]:.9g} s at rows {k - 1} and {k} (lines {_line(k - 1)} and {_line(k)}); "
            f"time must be strictly increasing ({same.size} duplicate time stamp(s) in all){rounded}"
        )


def _check_time_unit(t: np.ndarray, step: float, column: _Column, label: str, src: str) -> None:
    """Refuse sampling slower than `_MIN_SAMPLE_RATE_HZ`: no joint log is that slow, a time in ms or us is, and so is
    a sample index (0, 1, 2, ...). The hint gives the mapping as a command-line override."""
    if not step > 0 or 1.0 / step >= _MIN_SAMPLE_RATE_HZ * (1 - 1e-9):  # a 0.2 s step is 5 Hz, not slower
        return
    if step == 1.0 and t[0] == np.round(t[0]) and np.all(np.diff(t) == 1.0):
        raise DataError(
            f"{src}: {label} counts {', '.join(f'{v:.0f}' for v in t[:3])}, ... (consecutive integers on all {len(t)} "
            "rows): a sample index or counter, not a time in seconds; give the time in seconds as data.columns.time, "
            f"or scale the counter by the sampling period, e.g. at 500 Hz {_mapping_hint(column, 'time', 0.002)}"
        )
    guesses = [(unit, f) for unit, f in (("milliseconds", 1e-3), ("microseconds", 1e-6), ("nanoseconds", 1e-9))]
    likely = [(unit, f) for unit, f in guesses if _MIN_SAMPLE_RATE_HZ <= 1.0 / (step * f) <= _MAX_SAMPLE_RATE_HZ]
    hint = "; the harness expects time in seconds"
    if likely:
        unit, f = likely[0]
        hint = (
            f": time looks like {unit} ({1.0 / (step * f):.4g} Hz then); the harness expects seconds: map it with "
            f"{_mapping_hint(column, 'time', f)}"
        )
    raise DataError(
        f"{src}: {label} steps by a median {step:.6g} per row, {1.0 / step:.4g} Hz sampling if in seconds, "
        f"slower than any joint log ({_MIN_SAMPLE_RATE_HZ:g} Hz at least){hint}"
    )


def _check_length(n: int, min_samples: int, src: str, what: str) -> None:
    if n < min_samples:
        raise DataError(
            f"{src}: too little data: {n} {what}, at least {min_samples} are needed (the least is data.min_samples)"
        )


def _check_angle_units(
    plant: Plant, t: np.ndarray, arrays: dict[str, np.ndarray | None], labels: dict[str, str], src: str
) -> None:
    """Refuse hinge angles that look like degrees, or a velocity column that is not the angle's rate."""
    q, dq = arrays["q"], arrays["dq"]
    assert q is not None
    for j, n in enumerate(plant.joint_names):
        if not plant.hinge[j]:
            continue
        lq = labels[f"q_{n}"]
        if dq is not None:
            ratio = _rate_ratio(t, q[:, j], dq[:, j])
            if ratio is not None and not 0.7 <= ratio <= 1.4:
                ldq = labels[f"dq_{n}"]
                if not np.isfinite(ratio):
                    raise DataError(
                        f"{src}: {ldq} stays near zero while {lq} moves (rows 0-{len(t) - 1}): a stuck velocity "
                        "column; without velocities (remove or rename every dq_ column: they are given for every "
                        "joint or none) they are derived from the angles"
                    )
                if abs(ratio * _DEGREE - 1) < 0.25:
                    why = f"{lq} looks like degrees (180/pi = 57.3); the harness expects radians"
                elif abs(ratio / _DEGREE - 1) < 0.25:
                    why = f"{ldq} looks like degrees per second (pi/180 = 0.0175); the harness expects rad/s"
                elif abs(ratio + 1) < 0.3:
                    why = f"{ldq} has the opposite sign of the angle's rate"
                else:
                    why = "one of the two has a wrong scale, or they belong to different joints"
                raise DataError(
                    f"{src}: {lq} changes {ratio:.4g} times as much as the time integral of {ldq} over the same "
                    f"intervals (rows 0-{len(t) - 1}): {why}. Give a scale in the column mapping to convert"
                )
        lo, hi = plant.q_range[j]
        x_lo, x_hi = float(q[:, j].min()), float(q[:, j].max())
        # far outside the range (not a turn or two beyond it, as a wrap-around would be) but inside it as degrees
        far = max(abs(x_lo), abs(x_hi)) > 3.0 * max(abs(lo), abs(hi))
        if np.isfinite(lo) and np.isfinite(hi) and far and lo <= x_lo * _DEGREE and x_hi * _DEGREE <= hi:
            k = int(np.argmax(np.abs(q[:, j])))
            turns = [n for n in range(-4, 5) if n and lo <= x_lo + 2 * np.pi * n and x_hi + 2 * np.pi * n <= hi]
            other = (  # an encoder zero whole turns off fits too: both readings are named
                f", or lies {-turns[0]:+d} whole turn(s) off its zero (then give the offset {2 * np.pi * turns[0]:.6g})"
                if turns
                else ""
            )
            raise DataError(
                f"{src}: {lq} spans [{x_lo:.4g}, {x_hi:.4g}] (row {k}, line {_line(k)}: {q[k, j]:.4g}), far beyond "
                f"the joint range [{lo:.4g}, {hi:.4g}] rad of {plant.name}, and inside it when read as degrees: the "
                f"angle looks like degrees (then give the scale {_DEGREE:.6g}){other}; the harness expects radians"
            )


def _mapping_hint(column: _Column, ours: str, factor: float) -> str:
    """The column mapping that multiplies `column` by `factor`, as a command-line override (`++` adds the key or
    replaces it, whether the data config maps columns or not). Ours = f (scale file + offset): the mapping's scale
    and offset both take the factor."""
    terms = [("column", json.dumps(column.name)), ("scale", f"{column.scale * factor:g}")]
    terms += [("offset", f"{column.offset * factor:g}")] if column.offset else []
    spaced = ", ".join(f"{k}: {v}" for k, v in terms)
    packed = ",".join(f"{k}:{v}" for k, v in terms)
    return f"{{{spaced}}} as data.columns.{ours} (on the command line: '++data.columns.{ours}={{{packed}}}')"


def _check_torque_units(
    plant: Plant, arrays: dict[str, np.ndarray | None], labels: dict[str, str], sources: dict[str, _Column], src: str
) -> None:
    """Refuse a torque column far beyond what its actuator can give: a torque in mN m or N cm, or another
    column, would otherwise be fitted as links of hundreds of kilograms."""
    for key in ("tau", "tau_cmd"):
        x = arrays[key]
        if x is None:
            continue
        for j, n in enumerate(plant.joint_names):
            ours = f"{key}_{n}"
            if ours not in labels or not plant.actuated[j]:
                continue
            size = np.abs(x[:, j])
            typical = float(np.percentile(size, 99.0))
            limit = float(plant.tau_limit[j])
            limited = bool(np.isfinite(limit) and limit > 0)
            bound = _TORQUE_LIMIT_FACTOR * limit if limited else _MAX_TORQUE
            if typical <= bound:
                continue
            unit = plant.torque_units[j]
            k = int(np.argmax(size))
            against = (
                f"{typical / limit:.3g} times the actuator limit {limit:.4g} {unit} of {plant.name}"
                if limited
                else f"beyond any robot joint ({_MAX_TORQUE:g} {unit})"
            )
            units = [(prefix, f) for prefix, f in (("m", 1e-3), ("c", 1e-2)) if typical * f <= bound]
            if units:
                prefix, f = units[0]
                hint = (
                    f"it looks like {prefix}{unit} ({1 / f:g} per {unit}); the harness expects {unit}: map it with "
                    f"{_mapping_hint(sources[ours], ours, f)}"
                )
            else:
                hint = "a wrong unit or another column? Give a scale in the column mapping"
            raise DataError(
                f"{src}: {labels[ours]} is {typical:.4g} {unit} or more on 1 % of the rows (row {k}, line {_line(k)}: "
                f"{x[k, j]:.4g}), {against}; {hint}"
            )


def _fit_joint_ranges(
    t: np.ndarray,
    q: np.ndarray | None,
    plant: Plant,
    *,
    labels: dict[str, str],
    rows: np.ndarray,
    src: str,
    repair: bool,
) -> list[Repair]:
    """Bring a hinge logged a whole number of turns off back into its joint range (reported), or refuse an angle
    far outside the range: the model's limit would stop the simulated joint there, and every simulated error
    after it would be the limit's, not the model's. A little beyond the range is a joint pressed into its stop."""
    assert q is not None
    repairs = []
    for j, n in enumerate(plant.joint_names):
        lo, hi = (float(v) for v in plant.q_range[j])
        if not (np.isfinite(lo) and np.isfinite(hi)):
            continue
        x = q[:, j]
        unit = 1.0 if plant.hinge[j] else 0.1

        def outside(y: np.ndarray, tol: float, lo: float = lo, hi: float = hi) -> np.ndarray:
            return np.flatnonzero((y < lo - tol) | (y > hi + tol))

        bad = outside(x, _RANGE_TOL * unit)
        if not bad.size:
            continue
        label = labels[f"q_{n}"]
        turns = [k for k in range(-4, 5) if k and plant.hinge[j] and not outside(x + 2 * np.pi * k, _RANGE_TOL).size]
        if turns and repair:
            k = turns[0]
            q[:, j] = x + 2 * np.pi * k
            repairs.append(
                Repair(
                    "whole_turns",
                    label,
                    (int(rows[0]),),
                    f"{label}: added {k:+d} x 2 pi to every row: as logged it lies outside the joint range "
                    f"[{lo:.4g}, {hi:.4g}] rad on {bad.size} of {len(x)} rows, and inside it {abs(k)} turn(s) "
                    "over (an encoder zero a whole turn off)",
                )
            )
            continue
        bad = outside(x, _RANGE_FAR * unit)
        if not bad.size:
            continue
        k = int(bad[np.argmax(np.maximum(lo - x[bad], x[bad] - hi))])
        unit_name = "rad" if plant.hinge[j] else "m"
        # an angle in degrees, a slide's position in millimetres: inside the range once converted
        guess, factor = ("degrees", _DEGREE) if plant.hinge[j] else ("millimetres", _MILLIMETRE)
        converts = lo <= float(x.min()) * factor and float(x.max()) * factor <= hi
        why = (
            f"it fits {turns[0]:+d} whole turn(s) over; not repaired (repair=False)"
            if turns
            else f"widen the joint's range in the MJCF, or correct the {'angle' if plant.hinge[j] else 'position'}'s "
            "zero with an offset in the column mapping"
            + (f"; read as {guess} it lies inside the range: if it is, give the scale {factor:.6g}" if converts else "")
        )
        raise DataError(
            f"{src}: {label} leaves the joint range [{lo:.4g}, {hi:.4g}] {unit_name} of {plant.name} by more than "
            f"{_RANGE_FAR * unit:g} {unit_name} on {bad.size} of "
            f"{len(x)} rows (the farthest row {rows[k]}, line {_line(rows[k])}, t = {t[k]:.6g} s: {x[k]:.4g}); the "
            f"model's limit would stop it there: {why}"
        )
    return repairs


def _rate_ratio(t: np.ndarray, x: np.ndarray, v: np.ndarray) -> float | None:
    """Median ratio of the angle's increments to the integral of the velocity over windows of ~0.05 s.

    None when the joint moves too little for the ratio to mean anything; inf when the angle moves and the
    velocity's integral stays within a tenth of it (a velocity column stuck at zero).
    """
    h = float(np.median(np.diff(t)))
    w = int(min(max(3, round(0.05 / h)), len(t) // 4))
    if w < 1:
        return None
    with np.errstate(over="ignore", invalid="ignore"):  # a glitch near the largest double (repaired later)
        integral = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
        dx, di = x[w:] - x[:-w], integral[w:] - integral[:-w]
        big = np.abs(di) >= max(0.25 * np.abs(di).max(), 0.02)
        if big.sum() < 10:
            # the angle as it moves, before the repairs: unwrapped, and a running median through its glitches
            smooth = median_filter(np.unwrap(np.nan_to_num(x)), size=min(2 * _GLITCH_MAX_RUN + 1, len(x)))
            ds = smooth[w:] - smooth[:-w]
            moving = np.abs(ds) >= max(0.25 * np.abs(ds).max(), 0.02)
            if moving.mean() >= 0.1 and np.all(np.abs(di[moving]) < 0.1 * np.abs(ds[moving])):
                return float("inf")
            return None
        return float(np.median(dx[big] / di[big]))


def _startup_rows(t: np.ndarray) -> int:
    """Leading rows whose steps are far off the median, when they are only a few."""
    steps = np.diff(t)
    off = np.abs(steps / np.median(steps) - 1.0) > _STARTUP_TOL
    if not off[0] or off.all():
        return 0
    first_regular = int(np.argmin(off))
    return first_regular if first_regular <= _STARTUP_MAX_FRACTION * len(t) else 0


def _cut(arrays: dict[str, np.ndarray | None], start: int, stop: int) -> dict[str, np.ndarray | None]:
    return {k: None if a is None else a[start:stop] for k, a in arrays.items()}


def _running_rate(steps: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """An angle's rate |step| / dt after a running median over `_RATE_WINDOW` steps: a glitch of up to
    `_GLITCH_MAX_RUN` samples moves two steps of a window, which cannot move its median."""
    return median_filter(np.abs(steps) / dt, size=min(_RATE_WINDOW, len(steps)), mode="nearest")  # type: ignore[no-any-return]


def _check_max_speed(
    steps: np.ndarray, dt: np.ndarray, max_speed: float, noise: float, *, label: str, src: str
) -> None:
    """Refuse a `max_speed` the angle's own sustained rate exceeds (`_running_rate`, which glitches cannot move,
    at its 99th percentile, less what its noise adds): the fastest the joint can move cannot be slower than it
    moves. `steps`, `dt`: (N - 1,) the angle's steps and their intervals."""
    if not len(steps):
        return
    rate = _running_rate(steps, dt)
    sustained = float(np.percentile(rate, 99.0)) - 3.0 * np.sqrt(2.0) * noise / float(np.median(dt))
    if sustained > 1.05 * max_speed:
        raise DataError(
            f"{src}: {label} moves at {sustained:.3g} rad/s (m/s on a slide; 99th percentile of its rate), faster than "
            f"max_speed={max_speed:g} (data.max_speed), the fastest the joint can move: raise it, or leave it null "
            "to bound the jumps called glitches from the data"
        )


def _repair_joint(
    t: np.ndarray,
    x: np.ndarray,
    v: np.ndarray | None,
    *,
    max_speed: float | None,
    label: str,
    rows: np.ndarray,
    src: str,
    repair: bool,
) -> tuple[np.ndarray, list[Repair], int, int]:
    """Find the steps of one angle that no velocity allows, and unwrap, interpolate, trim or refuse them.

    Returns:
        The repaired angle, the repairs, and the rows to drop at the head and at the tail.
    """
    n = len(x)
    dt_eff = np.diff(t)
    np.maximum(dt_eff, np.median(dt_eff), out=dt_eff)  # timestamps jitter; the motion does not go faster for it
    s = np.diff(x)
    # the statistics below work in place on their own temporaries (a long log's copies add up otherwise)
    if max_speed is not None:
        speed = float(max_speed)
    elif v is not None:
        speed = 3.0 * float(np.percentile(np.abs(v), 99.9, overwrite_input=True))
    else:
        # the angle's own running rate, so the glitches cannot set the bound that finds them (a percentile of the
        # raw steps could: 1 % of glitch rows is 2 % of the steps, and the 99th percentile was then a glitch's)
        rate = _running_rate(s, dt_eff)
        speed = 3.0 * float(np.percentile(rate, 99.9, overwrite_input=True))
        del rate
    noise = 0.0
    if n > 2:
        d2 = np.diff(x, 2)
        d2 -= np.median(d2)
        noise = 1.4826 * float(np.median(np.abs(d2, out=d2), overwrite_input=True)) / np.sqrt(6.0)
        del d2
    # a step of a count or one more is no jump, however coarse the encoder: where most steps are 0 the noise (a
    # median) and the running rate are 0, and each count read as a slip no velocity allows
    moved = np.abs(s[s != 0])
    resolution = float(moved.min()) if moved.size >= max(10, 0.01 * len(s)) else 0.0
    if resolution and np.mean(moved < 1.5 * resolution) < 0.5:  # the count is most of the steps, or no count
        resolution = 0.0
    floor = max(_MIN_JUMP, 10.0 * noise, 2.5 * resolution)
    if max_speed is not None:
        _check_max_speed(s, dt_eff, float(max_speed), noise, label=label, src=src)
    bound = np.multiply(dt_eff, speed, out=dt_eff)
    bound += floor
    flagged = np.flatnonzero(np.abs(s) > bound)
    if not flagged.size:
        return x, [], 0, 0
    dt = np.diff(t)

    def at(k: int) -> str:
        lines = f"{_line(rows[k])}-{_line(rows[k + 1])}"
        return f"between rows {rows[k]} and {rows[k + 1]} (lines {lines}, t = {t[k + 1]:.6g} s)"

    if not repair:
        k = int(flagged[0])
        turn = " (about a whole turn: an encoder wrap-around?)" if abs(abs(s[k]) - 2 * np.pi) <= bound[k] else ""
        raise DataError(
            f"{src}: {label} jumps by {s[k]:.4g} {at(k)}{turn}, more than any velocity allows ({bound[k]:.3g} at "
            f"{speed:.3g} rad/s); {flagged.size} such step(s) in all. Not repaired (repair=False)"
        )
    ok = np.abs(s) <= bound
    rate = np.where(ok, s / dt, np.nan)
    step_fix = np.zeros(n - 1)
    wraps: list[int] = []
    runs: list[tuple[int, int]] = []  # glitch rows [a, b]
    head, tail = 0, 0
    i = 0
    while i < flagged.size:
        k = int(flagged[i])
        near = rate[max(0, k - 5) : k + 6]
        r = float(np.nanmedian(near)) if np.isfinite(near).any() else 0.0
        jump = s[k] - r * dt[k]
        turns = round(jump / (2 * np.pi))
        # a wrap-around is a turn or two (a value 1e17 off is a multiple of 2 pi to within its rounding)
        if 0 < abs(turns) <= _MAX_WRAP_TURNS and abs(jump - 2 * np.pi * turns) <= bound[k]:
            step_fix[k] = -2 * np.pi * turns
            wraps.append(k)
            i += 1
            continue
        back = [
            int(e)
            for e in flagged[i + 1 :]
            if e - k <= _GLITCH_MAX_RUN
            and abs(x[e + 1] + step_fix[k:e].sum() - x[k] - r * (t[e + 1] - t[k])) <= speed * (t[e + 1] - t[k]) + floor
        ]
        if back:
            runs.append((k + 1, back[0]))
            i = int(np.searchsorted(flagged, back[0], side="right"))
        elif k < _GLITCH_MAX_RUN:
            head, i = k + 1, i + 1
        elif k >= n - 1 - _GLITCH_MAX_RUN:
            tail, i = n - 1 - k, flagged.size
        else:
            raise DataError(
                f"{src}: {label} jumps by {s[k]:.4g} {at(k)} and stays there: faster than any velocity allows "
                f"({bound[k]:.3g} at {speed:.3g} rad/s), not a whole turn (wrap-around), and not a glitch that "
                f"returns within {_GLITCH_MAX_RUN} samples. An encoder slip, or two records joined?"
            )
    n_bad = sum(b - a + 1 for a, b in runs) + head + tail
    if n_bad > max(1, _GLITCH_MAX_FRACTION * n):
        first = ", ".join(str(rows[a]) for a, _ in runs[:5])
        raise DataError(
            f"{src}: {label} has {n_bad} glitch samples (first at rows {first}), more than "
            f"{_GLITCH_MAX_FRACTION:.0%} of its {n} rows: the sensor is not trusted and nothing was repaired"
        )
    fixed = x + np.concatenate([[0.0], np.cumsum(step_fix)])
    good = np.ones(n, bool)
    for a, b in runs:
        good[a : b + 1] = False
    good[:head] = False
    good[n - tail :] = False
    for a, b in runs:
        window = np.flatnonzero(good[max(0, a - 8) : b + 9]) + max(0, a - 8)
        fixed[a : b + 1] = CubicSpline(t[window], fixed[window])(t[a : b + 1])
    out: list[Repair] = []
    if wraps:
        out.append(
            Repair(
                "wrap",
                label,
                tuple(int(rows[k + 1]) for k in wraps),
                f"{label}: unwrapped {len(wraps)} encoder wrap-around(s) (jumps of a whole turn, 2 pi rad) at rows "
                f"{', '.join(str(rows[k + 1]) for k in wraps[:10])}",
            )
        )
    if runs:
        biggest = max(float(np.max(np.abs(x[a : b + 1] - fixed[a : b + 1]))) for a, b in runs)
        out.append(
            Repair(
                "glitch",
                label,
                tuple(int(rows[a]) for a, _ in runs),
                f"{label}: re-interpolated {len(runs)} glitch(es) of {sum(b - a + 1 for a, b in runs)} sample(s) in "
                f"all (off track by up to {biggest:.3g}) at rows {', '.join(str(rows[a]) for a, _ in runs[:10])}",
            )
        )
    if head or tail:
        edge = [int(r) for r in rows[:head]] + [int(r) for r in rows[n - tail :]]
        out.append(
            Repair(
                "edge_glitch",
                label,
                tuple(edge),
                f"{label}: dropped {len(edge)} row(s) at the record's edge that jump off track: rows {edge[:10]}",
            )
        )
    return fixed, out, head, tail


def _torque_spikes(
    t: np.ndarray, x: np.ndarray, *, label: str, rows: np.ndarray, src: str, repair: bool
) -> tuple[np.ndarray, list[Repair]]:
    """Find the samples of one torque column far outside its own range, and interpolate or refuse them.

    A sample is a spike where it departs from the running median of `_SPIKE_WINDOW` samples by more than
    `_SPIKE_FACTOR` times the column's 99th-percentile excursion from its median (plus `_SPIKE_FACTOR` times its
    sample-to-sample noise): a logging or transmission glitch, not a torque the joint could carry and release
    within a sample. Runs of at most `_GLITCH_MAX_RUN` such samples are re-interpolated from their neighbours
    (`repair`), or refused, as is a longer run or more than `_GLITCH_MAX_FRACTION` of the rows.
    """
    n = len(x)
    if n < _SPIKE_WINDOW:
        return x, []
    centre = float(np.median(x))
    reach = float(np.percentile(np.abs(x - centre), 99.0))
    if float(np.ptp(x)) <= _SPIKE_FACTOR * reach:
        return x, []  # no sample departs from a running median by more than the column's span: nothing to find
    local = x - median_filter(x, size=_SPIKE_WINDOW, mode="nearest")
    noise = 1.4826 * float(np.median(np.abs(local - np.median(local))))
    steps = np.abs(np.diff(x))
    step = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 0.0  # its quantum, or its pulses' height
    bad = np.abs(local) > _SPIKE_FACTOR * max(reach + noise, step) + 1e-12
    if not bad.any():
        return x, []
    edges = np.diff(np.concatenate([[0], bad.astype(np.int8), [0]]))
    runs = list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1, strict=True))
    k = int(runs[0][0])
    where = f"row {rows[k]} (line {_line(rows[k])}, t = {t[k]:.6g} s)"
    what = f"{label} is {x[k]:.4g} at {where}, far outside its own range ({centre:.4g} +- {reach:.3g} for 99 % of rows)"
    longest = max(b - a + 1 for a, b in runs)
    if not repair:
        raise DataError(f"{src}: {what}; {len(runs)} such spike(s) in all. Not repaired (repair=False)")
    if longest > _GLITCH_MAX_RUN or bad.sum() > max(1, _GLITCH_MAX_FRACTION * n):
        raise DataError(
            f"{src}: {what}; {int(bad.sum())} such samples in {len(runs)} run(s), the longest {longest}: more "
            f"than isolated glitches of up to {_GLITCH_MAX_RUN} samples, so nothing was repaired"
        )
    good = ~bad
    fixed = x.copy()
    fixed[bad] = np.interp(t[bad], t[good], x[good])
    listed = ", ".join(str(rows[a]) for a, _ in runs[:10])
    return fixed, [
        Repair(
            "torque_spike",
            label,
            tuple(int(rows[a]) for a, _ in runs),
            f"{label}: re-interpolated {len(runs)} spike(s) of {int(bad.sum())} sample(s) in all (up to "
            f"{float(np.max(np.abs(x[bad] - fixed[bad]))):.4g} off its neighbours) at rows {listed}",
        )
    ]


def _where(rows: np.ndarray, k: int) -> str:
    """The file position of the sample after step k."""
    return f"row {rows[k + 1]} (line {_line(rows[k + 1])})"


def _check_gaps(t: np.ndarray, rows: np.ndarray, label: str, src: str) -> None:
    """Refuse a gap in the sampling longer than `_MAX_GAP_STEPS` median steps (nothing can be interpolated across
    it); `rows`: the file row of each sample."""
    steps = np.diff(t)
    h = float(np.median(steps))
    gaps = np.flatnonzero(steps > _MAX_GAP_STEPS * h)
    if gaps.size:
        k = int(gaps[0])
        raise DataError(
            f"{src}: {label} has a gap of {steps[k] * 1e3:.4g} ms before {_where(rows, k)} ({steps[k] / h:.1f} times "
            f"the median step of {h * 1e3:.4g} ms; {gaps.size} such gap(s)): too long to interpolate across. Split "
            "the file there"
        )


def _regularise(
    t: np.ndarray, arrays: dict[str, np.ndarray | None], rows: np.ndarray, *, resample: bool, label: str, src: str
) -> tuple[np.ndarray, dict[str, np.ndarray | None], Repair | None]:
    """Interpolate irregular sampling onto a uniform grid at the median step (or refuse it)."""
    steps = np.diff(t)
    h = float(np.median(steps))
    dev = np.abs(steps / h - 1.0)
    if dev.max() <= _REGULAR_TOL:
        return t, arrays, None
    worst = int(np.argmax(dev))
    irregular = int(np.sum(dev > _REGULAR_TOL))  # no gap among them: `read_measured` ran `_check_gaps` first
    summary = (
        f"{irregular} of {len(steps)} steps differ from the median {h * 1e3:.4g} ms by more than "
        f"{_REGULAR_TOL:.0%} (the largest, {steps[worst] * 1e3:.4g} ms, before {_where(rows, worst)})"
    )
    if not resample:
        raise DataError(f"{src}: {label} is irregularly sampled: {summary}. Pass resample=True to interpolate it")
    grid = t[0] + h * np.arange(int(np.floor((t[-1] - t[0]) / h + 1e-9)) + 1)
    out: dict[str, np.ndarray | None] = {}
    for key, a in arrays.items():
        if a is None:
            out[key] = None
        elif key == "q":
            out[key] = CubicSpline(t, a, axis=0)(grid)  # smooth motion: keeps the accelerations linear loses
        else:
            out[key] = np.column_stack([np.interp(grid, t, a[:, j]) for j in range(a.shape[1])])
    message = (
        f"{summary}: resampled onto a uniform {1 / h:.4g} Hz grid ({len(t)} -> {len(grid)} rows), angles by cubic "
        "spline, velocities and torques linearly"
    )
    return grid, out, Repair("resample", "time", (int(rows[worst + 1]),), message)

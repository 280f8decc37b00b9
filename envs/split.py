"""Training and validation data that share no sample: held out by file, or by a contiguous block of time
for a single record, never by random samples (neighbouring samples are strongly correlated)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dynamics.errors import DataError
from envs.dataset import Dataset

__all__ = ["Split", "names_file", "split_train_validation"]


@dataclass(frozen=True)
class Split:
    """Training and validation data that share no sample.

    Attributes:
        train: datasets the fit may use.
        validation: datasets it never sees.
        by: `file` (whole files held out) or `time_block` (the last part of a single record held out).
    """

    train: tuple[Dataset, ...]
    validation: tuple[Dataset, ...]
    by: str

    def describe(self) -> dict[str, Any]:
        """JSON-ready summary: `by`, and per part the source, first and last time [s] and sample count."""

        def part(datasets: tuple[Dataset, ...]) -> list[dict[str, Any]]:
            return [
                {"source": d.source, "t_start": float(d.time[0]), "t_end": float(d.time[-1]), "n_samples": d.n_samples}
                for d in datasets
            ]

        return {"by": self.by, "train": part(self.train), "validation": part(self.validation)}


def names_file(name: object, source: str) -> bool:
    """Whether a file's name as `data.validation` gives it (its path, file name or stem) is the file `source`."""
    return str(name) in (source, Path(source).name, Path(source).stem)


def split_train_validation(
    datasets: Sequence[Dataset],
    *,
    validation_fraction: float = 0.3,
    validation: Sequence[str] | None = None,
    min_samples: int = 50,
) -> Split:
    """Hold data out for validation: whole files when there are two or more, else the end of the record.

    Args:
        datasets: one dataset per file, in order.
        validation: files to hold out, by name, stem or path (two or more files only); None holds out the last
            round(validation_fraction x files) of them, at least one, leaving at least one to train on.
        validation_fraction: share held out when `validation` is None: of the files, or, for a single file,
            of its samples, taken as one contiguous block at its end (the fit's samples all come before).
        min_samples: fewest samples in each block of a single file.

    Raises:
        ValueError: a fraction outside (0, 1), no dataset, or `validation` naming a file not given.
        DataError: a single record too short to split.
    """
    if not datasets:
        raise ValueError("no dataset to split")
    if not 0.0 < validation_fraction < 1.0:
        raise ValueError(f"validation_fraction must lie in (0, 1), got {validation_fraction}")
    if len(datasets) == 1:
        data = datasets[0]
        if validation:
            raise ValueError(
                f"validation names {[str(v) for v in validation]} but only one file was read "
                f"({Path(data.source).name}): a single file's validation data are its last block (validation_fraction "
                "of its samples), so leave validation unset (data.validation=null), or give the held-out files too"
            )
        cut = int(round(data.n_samples * (1.0 - validation_fraction)))
        short = min(cut, data.n_samples - cut)
        if short < min_samples:
            fix = (
                f"data.validation_fraction {validation_fraction:g} holds {data.n_samples - cut} out; give a fraction "
                f"between {min_samples / data.n_samples:.2g} and {min(0.9, 1 - min_samples / data.n_samples):.2g} "
                "(0.9 at most), or more data"
                if 2 * min_samples <= data.n_samples
                else "give more data"
            )
            raise DataError(
                f"{data.source}: {data.n_samples} samples are too few to split into a training and a validation "
                f"block of at least {min_samples} samples each (data.min_samples): {fix}"
            )
        return Split((data.slice(0, cut),), (data.slice(cut, data.n_samples),), "time_block")
    if validation is None:
        n_val = min(len(datasets) - 1, max(1, int(round(validation_fraction * len(datasets)))))
        held = set(range(len(datasets) - n_val, len(datasets)))
    else:
        held = set()
        for name in validation:
            hits = [i for i, d in enumerate(datasets) if names_file(name, d.source)]
            if not hits:
                given = ", ".join(Path(d.source).name for d in datasets)
                raise ValueError(
                    f"validation file {name!r} is not among the files read: {given}; name one of them "
                    "(data.validation=<file>), or data.validation=null to hold out the last files"
                )
            exact = [i for i in hits if datasets[i].source == str(name)]
            if len(hits) > 1 and not exact:
                raise ValueError(
                    f"validation file {name!r} names {len(hits)} of the files read "
                    f"({', '.join(datasets[i].source for i in hits)}): give the full path of the one to hold out"
                )
            held.update(exact or hits)
        if len(held) == len(datasets):
            raise ValueError("every file is held out for validation: none is left to fit on")
    train = tuple(d for i, d in enumerate(datasets) if i not in held)
    return Split(train, tuple(d for i, d in enumerate(datasets) if i in held), "file")

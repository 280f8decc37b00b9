"""The project's exception hierarchy: domain failures that a caller may want to catch as one."""

from __future__ import annotations

__all__ = [
    "DataError",
    "InfeasibleExcitationError",
    "ModelError",
    "RankDeficientError",
    "SysIdError",
    "one_line",
]


class SysIdError(Exception):
    """Base class of every domain failure raised by the harness."""


class ModelError(SysIdError, ValueError):
    """An MJCF model the harness cannot use (unsupported joint type, mismatched parsers, ...)."""


class DataError(SysIdError, ValueError):
    """Measured or simulated data that cannot be used as it is (bad columns, NaN, time order, ...)."""


class InfeasibleExcitationError(SysIdError, ValueError):
    """No trajectory meets the limits; the message names the binding constraint.

    Attributes:
        bound: the kind of that bound (`q`, `dq`, `ddq`, `tau` or `clearance`), or None where not known; a
            caller that built the limits from its own settings names the setting from it.
    """

    def __init__(self, message: str, *, bound: str | None = None) -> None:
        super().__init__(message)
        self.bound = bound


class RankDeficientError(SysIdError, ValueError):
    """The regressor does not excite the parameters that were asked for."""


def one_line(err: Exception) -> str:
    """A library's error on one line (MuJoCo's compile errors take three: the error, the element, a note)."""
    return "; ".join(line.strip() for line in str(err).splitlines() if line.strip())

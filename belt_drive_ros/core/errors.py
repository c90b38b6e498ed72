"""Error hierarchy of belt_drive_ros: every error derives from :class:`BeltDriveError` and from the built-in that
fits it (callers may catch either); messages name the offending field, method or value and, where one exists, the fix.
Values are quoted in messages through :func:`short`, checked as numbers through :func:`real` / :func:`plain_number`.
"""

from __future__ import annotations

from collections.abc import Mapping
from numbers import Real
from typing import Any, Callable

#: longest quoted value in an error message [characters]
QUOTE_LIMIT = 60
#: largest integer a file may hold (beyond, floats overflow and no setting means anything)
MAX_INT = 2**63


class BeltDriveError(Exception):
    """Base class of every error raised by belt_drive_ros."""


class ParameterError(BeltDriveError, ValueError):
    """A model parameter is missing, unknown, non-finite or out of range: ``field`` names it (the paper's
    symbol, e.g. ``"r_3"``), ``detail`` says what is wrong."""

    def __init__(self, field: str, message: str):
        self.field = field
        self.detail = message
        super().__init__(f"{field}: {message}")


class SceneError(BeltDriveError, ValueError):
    """A scene file or scene mapping is malformed (names the key path)."""


class InputError(SceneError):
    """A file from outside refused before its content is used (:mod:`belt_drive_ros.io.inputs`)."""


class IntegratorError(BeltDriveError, ValueError):
    """Unknown integrator name or invalid integrator option."""


class UnstableStepError(BeltDriveError, ValueError):
    """A fixed-step method would be unstable at the requested step (raised before the run starts,
    :mod:`belt_drive_ros.core.stability`)."""


class SimulationDivergedError(BeltDriveError, ArithmeticError):
    """The state became non-finite or left its physical envelope during a run."""


class OutputError(BeltDriveError, OSError):
    """Writing an output failed (disk full, I/O error; nothing partial is left): a failed run (exit 1), not bad input."""


# ------------------------------------------------------------------ values in messages
def short(value: Any, limit: int = QUOTE_LIMIT) -> str:
    """``repr(value)`` cut to ``limit`` characters; a container of more than 8 items summarised by type and length
    before any ``repr`` is built (a huge value never becomes a huge string)."""
    if isinstance(value, (list, tuple, dict, set)) and len(value) > 8:
        return f"<{type(value).__name__} of {len(value)} items>"
    if isinstance(value, (str, bytes)) and len(value) > 4 * limit:
        value = value[: 4 * limit]
        text = repr(value)
        return text[:limit] + f"... ({type(value).__name__}, truncated)"
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


def unknown_key(data: Mapping, known) -> str | None:
    """The first key of ``data`` not in ``known`` (keys as text cut to 60 characters, sorted), or None: what every
    "unknown key" message names."""
    unknown = sorted(str(k)[:60] for k in set(data) - set(known))
    return unknown[0] if unknown else None


def real(value: Any) -> int | float | None:
    """``value`` as a Python ``int`` or ``float`` if it is a real number (numpy scalars as their Python value), else
    None: booleans, arrays, strings, ``Decimal`` ... are not numbers here."""
    if isinstance(value, (int, float)):
        return None if isinstance(value, bool) else value
    if isinstance(value, Real) and hasattr(value, "item") and type(value).__name__ != "bool":
        value = value.item()  # numpy's scalars (registered as numbers.Real) as Python numbers
        return value if isinstance(value, (int, float)) and not isinstance(value, bool) else None
    return None


def plain_number(value: Any, refuse: Callable[[str], Exception]) -> int | float:
    """``value`` as a Python number (:func:`real`), else ``refuse(what is wrong)`` raised: not a number, or an
    integer beyond 2^63 (no float holds it; the text of a 5000-digit one even exceeds Python's int-to-str limit)."""
    number = real(value)
    if number is None:
        raise refuse(f"must be a number, got {type(value).__name__} {short(value)}")
    if isinstance(number, int) and abs(number) > MAX_INT:
        raise refuse("must be finite, got an integer beyond 2^63")
    return number

"""A campaign file's values checked with their key named (``campaign/spec.py``): a string is not a number nor a
boolean, a boolean is not a number, ``2.7`` is not a count, ``.inf`` and ``.nan`` are not finite; errors are one
line (:class:`~belt_drive_ros.core.errors.InputError` unless the caller names its own)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from ..core.errors import MAX_INT, real, short
from ..io.inputs import InputError


def _refuse(error, key: str, expected: str, value: Any):
    return error(f"{key}: must be {expected}, got {type(value).__name__} {short(value)}")


def number(
    value: Any, key: str, *, low: float | None = None, high: float | None = None, integer: bool = False,
    error: type[Exception] = InputError,
) -> float | int:  # fmt: skip
    """``value`` as a finite number in ``[low, high]`` (an ``int`` when ``integer``), else ``error`` naming ``key``.

    Booleans and strings are refused (``'2e4'`` is text, ``true`` is not 1);
    with ``integer`` a float is taken only when whole (``1e3`` is 1000,
    ``2.7`` is refused, never truncated).
    """
    given, value = value, real(value)
    if value is None:
        raise _refuse(error, key, "a whole number" if integer else "a number", given)
    if isinstance(value, float) and not math.isfinite(value):
        raise _refuse(error, key, "a finite number", value)
    if integer:
        if isinstance(value, float):
            if not value.is_integer():
                raise _refuse(error, key, "a whole number", value)
            value = int(value)
    elif isinstance(value, int) and abs(value) > MAX_INT:  # (no float holds it as written; a finite float passes)
        raise error(f"{key}: must be a finite number, got an integer beyond 2^63")
    else:
        value = float(value)
    if (low is not None and value < low) or (high is not None and value > high):
        lo = "-inf" if low is None else f"{low:g}"
        hi = "inf" if high is None else f"{high:g}"
        raise error(f"{key}: {value:g} is outside [{lo}, {hi}]")
    return value


def boolean(value: Any, key: str, error: type[Exception] = InputError) -> bool:
    """``value`` if it is ``true`` or ``false`` (a string such as ``'false'`` is refused), else ``error``."""
    if not isinstance(value, bool):
        raise _refuse(error, key, "true or false", value)
    return value


def text(value: Any, key: str, error: type[Exception] = InputError) -> str:
    """``value`` if it is a string, else ``error`` naming ``key``."""
    if not isinstance(value, str):
        raise _refuse(error, key, "a string", value)
    return value


def mapping(value: Any, key: str, error: type[Exception] = InputError, *, empty: dict | None = None) -> dict:
    """``value`` as a dict; ``None`` (the key given empty) is ``empty`` when that is given, else ``error``."""
    if value is None and empty is not None:
        return dict(empty)
    if not isinstance(value, Mapping):
        raise _refuse(error, key, "a mapping (key: value)", value)
    return dict(value)


def sequence(value: Any, key: str, error: type[Exception] = InputError, *, nonempty: bool = False) -> list:
    """``value`` as a list (a YAML sequence), non-empty if asked, else ``error`` naming ``key``."""
    if not isinstance(value, (list, tuple)):
        raise _refuse(error, key, "a non-empty list" if nonempty else "a list", value)
    if nonempty and not value:
        raise error(f"{key}: must be a non-empty list, got []")
    return list(value)

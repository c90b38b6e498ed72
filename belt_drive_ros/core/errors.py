"""Error hierarchy of belt_drive_ros: every error derives from :class:`BeltDriveError` and from the built-in that
fits it (callers may catch either); messages name the offending field, method or value and, where one exists, the fix.
"""

from __future__ import annotations


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
    """A file from outside refused before its content is used (:mod:`belt_drive_ros.core.inputs`)."""


class IntegratorError(BeltDriveError, ValueError):
    """Unknown integrator name or invalid integrator option."""


class UnstableStepError(BeltDriveError, ValueError):
    """A fixed-step method would be unstable at the requested step (raised before the run starts,
    :mod:`belt_drive_ros.core.stability`)."""


class SimulationDivergedError(BeltDriveError, ArithmeticError):
    """The state became non-finite or left its physical envelope during a run."""


class OutputError(BeltDriveError, OSError):
    """Writing an output failed (disk full, I/O error; nothing partial is left): a failed run (exit 1), not bad input."""

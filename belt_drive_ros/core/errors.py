"""Error hierarchy of belt_drive_ros.

Every error derives from :class:`BeltDriveError` and from the built-in that
fits it, so callers may catch either. Messages name the offending field,
method or value and, where one exists, the fix.
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
    """A file from outside is refused before its content is used.

    Not a regular file, too large, not UTF-8, or YAML with aliases, anchors,
    duplicate keys or too deep nesting (:mod:`belt_drive_ros.core.inputs`).
    """


class IntegratorError(BeltDriveError, ValueError):
    """Unknown integrator name or invalid integrator option."""


class UnstableStepError(BeltDriveError, ValueError):
    """A fixed-step method would be unstable at the requested step.

    Raised *before* a run starts by :mod:`belt_drive_ros.core.stability`; the
    message names the method, the step, ``h*omega_n``, the method's boundary,
    a stable step and an unconditionally stable method.
    """


class SimulationDivergedError(BeltDriveError, ArithmeticError):
    """The state became non-finite or left its physical envelope during a run."""


class OutputError(BeltDriveError, OSError):
    """Writing an output failed (disk full, I/O error); nothing partial is left behind.

    A *failed run* (exit code 1 on the command line), unlike the input errors.
    """

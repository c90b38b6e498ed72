"""Torque profiles as data: the arrays the compiled kernel reads (numpy only, no numba here).

A profile (:mod:`~belt_drive_ros.core.sources`) encodes itself as rows of a
small program (:class:`ProfileData`):

* ``kinds`` (R,) int64: one of the codes below per row; row 0 is evaluated;
* ``params`` (R, :data:`WIDTH`) float64: the row's numbers (layout per code below);
* ``tx``, ``ty`` (K,) float64: every table of the profile, end to end (a row
  holds its table's offset and length in ``params``).

One compiled dispatcher (:func:`belt_drive_ros.core.kernel_profiles.profile_torque`)
evaluates any profile from these four arrays: the kernel compiles once per
installed version, never per scene (the arrays' types never change). A new
kind is one code here, one ``encode`` method and one branch in the kernel.

Row layouts (``p`` = ``params[row]``; ``t`` [s], ``angle`` [rad], ``speed`` [rad/s], torques [N m]):

=============  ==============================================================================
code           torque
=============  ==============================================================================
CONSTANT       ``p0``
STEP           ``p1 if t >= p2 else p0``
RAMP           ``p0 + clip((t - p2) / p4, 0, 1) * p1`` (``p3`` = end time; written as the branches)
SINE           ``p0 + p1 sin(p2 t + p3)``
TABLE_LINEAR   ``interp(t, tx[o:o+n], ty[o:o+n])``, ``o, n = p0, p1``
TABLE_HELD     zero-order hold of ``ty`` at ``t`` (``tx`` the switching times)
TABLE_HELD_NS  the same at ``rint(t 1e9)`` with ``tx`` in whole nanoseconds (a recording)
ENGINE         base(``p0`` mode: 0 ``p1``; 1 ``clip(p1 + p2 (p3 - speed), 0, p4)``; 2 ``p4``)
               ``+ sum_k A_k sin(k (p5 (p6 angle) + p7))``, ``A = ty[p9:p9+p10]``; faded by ``p8``
MOTOR_LINE     ``p0 (1 - speed / p1)``, faded by ``p2``
MOTOR_CURVE    ``interp(speed, tx[o:o+n], ty[o:o+n])``, ``o, n = p0, p1``, faded by ``p2``
POLYNOMIAL     ``p0 + p1 speed + p2 speed |speed|`` (zero terms dropped)
COMPRESSOR     ``p0 + p1 speed + sum_k A_k sin(k (p2 angle + p3))``, ``A = ty[p5:p5+p6]``; faded by ``p4``
SCHEDULE       row ``p2`` if ``tx[j] <= t < ty[j]`` for a period ``j`` in ``[p0, p0 + p1)``, else row ``p3``
=============  ==============================================================================

"faded by T" (T > 0): the torque times ``0 if t < 0, 1 if t > T, else t / T``;
T = 0: no fade. Terms with a zero coefficient are dropped (not added as
zeros), as the profiles' formulas write them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: the kinds' codes: module constants, which a numba kernel that imports them reads as compile-time constants
#: (``torque(CONSTANT, ...)`` compiles to that kind's branch alone, as a literal 0 would)
CONSTANT, STEP, RAMP, SINE = 0, 1, 2, 3
TABLE_LINEAR, TABLE_HELD, TABLE_HELD_NS = 4, 5, 6
ENGINE, MOTOR_LINE, MOTOR_CURVE, POLYNOMIAL, COMPRESSOR, SCHEDULE = 7, 8, 9, 10, 11, 12
#: status codes of :func:`~belt_drive_ros.core.kernel.linear_steps`: all steps done; the last state written
#: diverged; the last state written is the first past the guard; the implicit stage of the next step did not converge
OK, DIVERGED, GUARDED, NOT_CONVERGED = 0, 1, 2, 3
#: numbers per row of ``params``
WIDTH = 12
#: per kind, the column of ``params`` holding a table's offset into ``tx``/``ty``, and the columns holding row indices
TABLE_COLUMN = {TABLE_LINEAR: 0, TABLE_HELD: 0, TABLE_HELD_NS: 0, MOTOR_CURVE: 0, ENGINE: 9, COMPRESSOR: 5, SCHEDULE: 0}
ROW_COLUMNS = {SCHEDULE: (2, 3)}
#: code -> name (for messages and docs)
KIND_NAMES = {
    CONSTANT: "constant", STEP: "step", RAMP: "ramp", SINE: "sine", TABLE_LINEAR: "table (linear)",
    TABLE_HELD: "table (previous)", TABLE_HELD_NS: "recorded table", ENGINE: "engine", MOTOR_LINE: "motor (line)",
    MOTOR_CURVE: "motor (curve)", POLYNOMIAL: "polynomial", COMPRESSOR: "compressor", SCHEDULE: "schedule",
}  # fmt: skip


@dataclass(frozen=True, eq=False)
class ProfileData:
    """A profile's program for the kernel (see the module docstring); arrays C-contiguous.

    ``params`` is writable on purpose: :class:`~belt_drive_ros.core.sources.HeldTorque`
    (the node's sampled drive torque) sets ``params[0, 0]`` at each tick and the
    kernel reads the new value at its next call.
    """

    kinds: np.ndarray
    params: np.ndarray
    tx: np.ndarray
    ty: np.ndarray


class ProfileBuilder:
    """Collects rows and tables while profiles encode themselves (nested ones: a schedule's parts)."""

    def __init__(self):
        self.kinds: list[int] = []
        self.rows: list[list[float]] = []
        #: the tables as float64 arrays end to end (a recording's samples are never Python floats); ``size`` entries
        self.tx: list[np.ndarray] = []
        self.ty: list[np.ndarray] = []
        self.size = 0

    def row(self, kind: int, *values: float) -> int:
        """Append a row of ``kind`` with ``values`` (at most :data:`WIDTH`); returns its index."""
        if len(values) > WIDTH:
            raise ValueError(f"profile row of kind {kind}: {len(values)} numbers, at most {WIDTH}")
        self.kinds.append(int(kind))
        self.rows.append([float(v) for v in values] + [0.0] * (WIDTH - len(values)))
        return len(self.kinds) - 1

    def reserve(self) -> int:
        """Index of a row filled in later by :meth:`fill` (a schedule is row 0, its parts after it)."""
        return self.row(CONSTANT)

    def fill(self, index: int, kind: int, *values: float) -> None:
        self.kinds[index] = int(kind)
        self.rows[index] = [float(v) for v in values] + [0.0] * (WIDTH - len(values))

    def table(self, xs, ys) -> tuple[int, int]:
        """Append a table; returns ``(offset, length)`` into ``tx``/``ty``."""
        xs = np.asarray(xs, dtype=np.float64).ravel()
        ys = np.asarray(ys, dtype=np.float64).ravel()
        offset = self.size
        self.tx.append(xs)
        self.ty.append(ys)
        self.size += xs.size
        return offset, xs.size

    def build(self) -> ProfileData:
        tx = np.concatenate(self.tx) if self.size else np.zeros(1)
        ty = np.concatenate(self.ty) if self.size else np.zeros(1)
        return ProfileData(np.array(self.kinds, dtype=np.int64), np.array(self.rows, dtype=np.float64).reshape(-1, WIDTH), tx, ty)


def stack(datas) -> tuple[ProfileData, np.ndarray]:
    """Several profiles as one program: rows and tables end to end, each row's table offset and row indices
    moved by its profile's start. Returns the stacked data and each profile's first row (P,) int64
    (:func:`~belt_drive_ros.core.kernel_profiles.profile_torque_at` evaluates profile p from its first row)."""
    builder, starts = ProfileBuilder(), []
    for d in datas:
        rows, tables = len(builder.kinds), builder.size
        starts.append(rows)
        for kind, values in zip(d.kinds.tolist(), d.params.tolist()):
            if kind in TABLE_COLUMN:
                values[TABLE_COLUMN[kind]] += tables
            for c in ROW_COLUMNS.get(kind, ()):
                values[c] += rows
            builder.row(kind, *values)
        builder.table(d.tx, d.ty)
    return builder.build(), np.array(starts, dtype=np.int64)

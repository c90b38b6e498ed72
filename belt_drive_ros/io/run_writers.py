"""Writers that take a run window by window (:mod:`belt_drive_ros.core.stream`).

Each writes into an open file of :func:`belt_drive_ros.io.atomic.atomic_output`
(or a bag folder), takes windows with :meth:`add`, starts over on
:meth:`restart` (an ``auto`` run that turned out to slip) and is finished
by :meth:`close`. :class:`Decimator` keeps every ``N``-th sample of a run
for a plot, the one output that needs the whole run at once.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..core.fidelity import ModelChoice
from ..core.scene import Scene
from ..core.simulate import CSV_COLUMNS, SLIP_CSV_COLUMNS, SLIP_MODELS, SimResult
from .bag_folder import bag_files_in as _bag_files, remove_bag_folder

__all__ = ["CsvWindows", "Decimator", "McapWindows", "RunSummary"]

#: MCAP chunk size of a streamed run [bytes]: one chunk index entry (~1 KB) stays in memory per chunk
STREAM_CHUNK = 2 << 20


class CsvWindows:
    """CSV of a streamed run: the header of :meth:`SimResult.to_csv`, then each window's rows as they come."""

    def __init__(self, handle):
        self.handle = handle
        self.columns = None

    def add(self, window: SimResult) -> None:
        if self.columns is None:
            self.columns = CSV_COLUMNS + (SLIP_CSV_COLUMNS if window.model in SLIP_MODELS else ())
            self.handle.write(",".join(self.columns) + "\n")
        np.savetxt(self.handle, window.table(self.columns), delimiter=",", fmt="%.12g")

    def restart(self) -> None:
        self.handle.seek(0)
        self.handle.truncate()
        self.columns = None

    def close(self) -> None:
        """Nothing to finish (the atomic output flushes and renames)."""


class McapWindows:
    """MCAP (or rosbag2 bag folder) of a streamed run through :class:`~belt_drive_ros.io.recording.ResultMcapWriter`.

    ``target`` is the open binary file of an atomic output, or the bag
    folder's path with ``bag_folder=True``; ``options`` go to the writer
    (start time, split limits ...). The scene record is written at the end
    with the sample count.

    Windows after the first are written by a thread of their own
    (``background=True``, the default) while the caller computes the next
    one: the compiled kernel and numpy's array loops release the GIL, so
    simulation and writing overlap. At most one window waits; windows are
    written in order (the same bytes as writing them in the caller). A
    failure of the writing thread is raised by the next :meth:`add` or by
    :meth:`close`. ``write_cpu`` is the CPU time [s] spent writing, in
    whichever thread.
    """

    def __init__(self, target, bag_folder: bool = False, force: bool = False, background: bool = True, **options):
        self.target, self.bag_folder, self.force, self.options = target, bag_folder, force, options
        self.writer = None
        self.counts: dict = {}
        self.background = bool(background)
        self.write_cpu = 0.0
        self._thread = None
        self._queue = None
        self._error: BaseException | None = None
        self._stop = False

    def add(self, window: SimResult) -> None:
        self._raise()
        if self.writer is None:
            from .recording import ResultMcapWriter

            # a bag of someone else's that the writer will refuse (no --force) is never removed below
            theirs = self.bag_folder and not self.force and bool(_bag_files(self.target))
            try:
                self.writer = ResultMcapWriter(self.target, window, force=self.force, bag_folder=self.bag_folder,
                                               chunk_size=STREAM_CHUNK, **self.options)
            except KeyboardInterrupt:  # (Terminated too) while the first file was begun: abort() cannot see it
                if self.bag_folder and not theirs:
                    remove_bag_folder(self.target)
                raise
            self._write(window)
            return
        if not self.background:
            self._write(window)
            return
        if self._thread is None:
            import queue
            import threading

            self._queue, self._stop = queue.Queue(maxsize=1), False
            self._thread = threading.Thread(target=self._work, name="mcap-windows", daemon=True)
            self._thread.start()
        self._queue.put(window)

    def _write(self, window: SimResult) -> None:
        start = time.thread_time()
        try:
            self.writer.write(window)
        finally:
            self.write_cpu += time.thread_time() - start

    def _work(self) -> None:
        """The writing thread: windows in order until None; after a failure (or :meth:`abort`) it only drains."""
        while True:
            window = self._queue.get()
            if window is None:
                return
            if self._error is None and not self._stop:
                try:
                    self._write(window)
                except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
                    self._error = exc

    def _join(self) -> None:
        """Wait until every window handed over is written (or skipped after a failure); the thread ends."""
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join()
            self._thread = self._queue = None

    def _raise(self) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            raise error

    def restart(self) -> None:
        self._join()
        self._error = None
        if self.writer is not None:
            self.writer.abort()
            self.writer = None
        if self.bag_folder:
            remove_bag_folder(self.target)
            self.force = True
        else:
            self.target.seek(0)
            self.target.truncate()

    def close(self) -> dict:
        self._join()
        self._raise()
        if self.writer is not None:
            self.counts = self.writer.close()
        return self.counts

    def abort(self) -> None:
        """After a failure or an interruption: no partial output is left (a bag folder's files are removed)."""
        self._stop = True  # the thread finishes the window it writes, skips the one waiting
        self._join()
        self._error = None
        if self.writer is not None:
            self.writer.abort()
            self.writer = None
            if self.bag_folder:
                remove_bag_folder(self.target)


class Decimator:
    """Every ``every``-th sample of a run (counted across windows) as one :class:`SimResult`, for plots."""

    def __init__(self, every: int = 1):
        if int(every) < 1:
            raise ValueError(f"every must be >= 1, got {every}")
        self.every = int(every)
        self.restart()

    def restart(self) -> None:
        self.seen = 0
        self.parts: list = []
        self.last: SimResult | None = None

    def add(self, window: SimResult) -> None:
        index = np.arange((-self.seen) % self.every, len(window.time), self.every)
        self.seen += len(window.time)
        self.last = window
        if index.size:
            self.parts.append((window.time[index], window.states[index], window.inputs[index],
                               {k: np.asarray(v)[index] for k, v in window.outputs.items()},
                               {k: np.asarray(v)[index] for k, v in window.energy.items()}))

    def result(self) -> SimResult:
        """The kept samples as one run (scene, model, method and choice of the last window)."""
        w = self.last
        cat = np.concatenate
        return SimResult(
            scene=w.scene, model=w.model, method=w.method, dt=w.dt,
            time=cat([p[0] for p in self.parts]), states=cat([p[1] for p in self.parts]),
            inputs=cat([p[2] for p in self.parts]),
            outputs={k: cat([p[3][k] for p in self.parts]) for k in self.parts[0][3]},
            choice=w.choice, stability=w.stability,
            energy={k: cat([p[4][k] for p in self.parts]) for k in self.parts[0][4]},
        )


@dataclass
class RunSummary:
    """What the run's summary needs, accumulated window by window (or from one whole run).

    ``final`` holds each output's last value; ``peak_deflection`` the largest
    |relative deflection| [rad] (a reverse-driven belt's too); ``slip_samples``/``samples`` the fraction of
    samples the belt slips (or slackens); ``onsets`` the slip phases;
    ``peak_slip_speed`` the largest |slip speed| [m/s].
    """

    scene: Scene | None = None
    model: str = ""
    method: str = ""
    dt: float = math.nan
    choice: ModelChoice | None = None
    method_choice: object = None
    stability: object = None
    accuracy: object = None
    wall_time: float = 0.0
    t_start: float = math.nan
    t_end: float = math.nan
    samples: int = 0
    slip_samples: float = 0.0
    onsets: int = 0
    peak_deflection: float = 0.0
    peak_slip_speed: float = 0.0
    final: dict = field(default_factory=dict)

    def add(self, window: SimResult) -> "RunSummary":
        """Take in the next window of the run; returns ``self``."""
        if not self.samples:
            self.scene, self.t_start = window.scene, float(window.time[0])
        self.model, self.method, self.dt = window.model, window.method, window.dt
        self.choice, self.stability = window.choice, window.stability
        self.accuracy = getattr(window, "accuracy", None)
        self.method_choice = getattr(window, "method_choice", None)
        self.wall_time += window.wall_time
        self.t_end = float(window.time[-1])
        o = window.outputs
        self.samples += len(window.time)
        self.slip_samples += float(np.sum(o["slip"]))
        self.onsets += sum(1 for e in window.events if e[0] == "onset")
        self.peak_deflection = max(self.peak_deflection, float(np.max(np.abs(o["relative_deflection"]))))
        if "slip_speed" in o:
            self.peak_slip_speed = max(self.peak_slip_speed, float(np.max(np.abs(o["slip_speed"]))))
        self.final = {name: float(np.asarray(values)[-1]) for name, values in o.items()}
        return self

    @property
    def slip_fraction(self) -> float:
        """Fraction of samples with the belt slipping (or slack, linear models) [-]."""
        return self.slip_samples / self.samples if self.samples else 0.0

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return (self.t_end - self.t_start) / self.wall_time if self.wall_time > 0 else math.inf

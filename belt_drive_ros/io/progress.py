"""A small progress bar on stderr for runs that take longer than a moment."""

from __future__ import annotations

import sys
import time


class ProgressBar:
    """Callable ``bar(fraction)``; draws only after ``delay`` s and only on a terminal or when forced."""

    def __init__(self, label: str, delay: float = 0.5, stream=None, force: bool = False, width: int = 30):
        self.label, self.delay, self.width = label, delay, width
        self.stream = stream or sys.stderr
        self.enabled = force or getattr(self.stream, "isatty", lambda: False)()
        self.start = time.perf_counter()
        self.drawn = False

    def __call__(self, fraction: float) -> None:
        if not self.enabled:
            return
        elapsed = time.perf_counter() - self.start
        if elapsed < self.delay and fraction < 1.0:
            return
        if fraction >= 1.0 and not self.drawn:
            return
        filled = int(self.width * min(max(fraction, 0.0), 1.0))
        eta = elapsed / fraction - elapsed if fraction > 0 else float("nan")
        self.stream.write(
            f"\r{self.label} [{'#' * filled}{'.' * (self.width - filled)}] {100 * fraction:5.1f}% "
            f"{elapsed:5.1f}s eta {eta:4.1f}s"
        )
        if fraction >= 1.0:
            self.stream.write("\n")
        self.stream.flush()
        self.drawn = True

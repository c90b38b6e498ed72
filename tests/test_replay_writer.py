"""Writing a streamed run to MCAP while the next window is simulated (issue 20: the replay's wall time).

:class:`~belt_drive_ros.io.run_writers.McapWindows` hands every window after
the first to a thread of its own; the file must be the one written in the
caller's thread, byte for byte, and a failure of that thread must reach the
caller (no hang, no half-written file left to look complete).
"""

from __future__ import annotations

import io

import pytest

from belt_drive_ros.core.stream import stream
from belt_drive_ros.io import recording
from belt_drive_ros.io.bags import reference_scene
from belt_drive_ros.io.recording import BagWriteError
from belt_drive_ros.io.run_writers import McapWindows


def _windows():
    scene = reference_scene("engine_idle").with_overrides(model="flexible", duration=0.3, dt=1e-3)
    return list(stream(scene, window_steps=40))


def _write(windows, background: bool) -> bytes:
    buf = io.BytesIO()
    sink = McapWindows(buf, start_time_ns=0, background=background)
    for window in windows:
        sink.add(window)
    counts = sink.close()
    assert counts["/joint_states"] == sum(len(w.time) for w in windows)
    return buf.getvalue()


def test_windows_written_by_the_thread_are_the_callers_bytes():
    windows = _windows()
    assert len(windows) >= 7  # several windows wait for the thread
    assert _write(windows, background=True) == _write(windows, background=False)


def test_a_failure_of_the_writing_thread_reaches_the_caller(monkeypatch):
    windows = _windows()
    plain = recording.ResultMcapWriter.write
    calls = []

    def failing(self, window):
        calls.append(window)
        if len(calls) == 3:
            raise BagWriteError("out.mcap: No space left on device")
        plain(self, window)

    monkeypatch.setattr(recording.ResultMcapWriter, "write", failing)
    sink = McapWindows(io.BytesIO(), start_time_ns=0)
    with pytest.raises(BagWriteError, match="No space left"):
        for window in windows:  # raised by a later add, or at the latest by close
            sink.add(window)
        sink.close()
    sink.abort()  # what sim does after a failure: returns, the thread is gone
    assert sink._thread is None
    assert len(calls) <= 4  # the thread stopped writing after the failure (at most the window waiting was taken)


def test_abort_skips_the_window_waiting():
    windows = _windows()
    sink = McapWindows(io.BytesIO(), start_time_ns=0)
    for window in windows[:4]:
        sink.add(window)
    sink.abort()
    assert sink._thread is None and sink.writer is None

"""A recording's memory is bounded by its split (issue 13: ~250 KB/min growth while recording).

The MCAP writer keeps one chunk index per chunk until the file is finished
(the summary section needs them); a recorder closes a chunk every 0.25 s
of log time, so an unsplit recording grows by ~1 KiB per second. Measured
with tracemalloc on the writer the node uses
(:func:`belt_drive_ros.ros.recorder.open_writer`), at 1 kHz on two topics
over a minute of log time: the growth between the first and the second
half minute with a split every 5 s is a small fraction of the unsplit growth,
and it reads back whole.
"""

from __future__ import annotations

import tracemalloc

import numpy as np

from msg_tools import read_topic

from belt_drive_ros.io.recording import encode_float64
from belt_drive_ros.ros.recorder import open_writer

TOPICS = ("/a", "/c")
RATE_NS = 1_000_000  # 1 kHz


def _write(writer, start_tick: int, ticks: int) -> None:
    payloads = encode_float64(np.arange(start_tick, start_tick + ticks, dtype=float))
    for k, data in enumerate(payloads):
        t = (start_tick + k) * RATE_NS
        for topic in TOPICS:
            writer.write_raw(topic, "std_msgs/msg/Float64", data, t)


def _growth(path, **split) -> int:
    """Traced bytes added by the second half minute of log time (after the first)."""
    writer = open_writer(path, **split)
    tracemalloc.start()
    try:
        _write(writer, 0, 30_000)
        first = tracemalloc.get_traced_memory()[0]
        _write(writer, 30_000, 30_000)
        second = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
        writer.finish()
    return second - first


def test_split_recording_memory_stays_flat_where_one_file_grows(tmp_path):
    whole = _growth(tmp_path / "one.mcap")
    split = _growth(tmp_path / "split", max_bag_duration=5.0)
    assert whole > 120 * 200  # 120 chunk indexes in 30 s, a few hundred bytes each
    assert split < whole / 4, (split, whole)
    print(f"growth over 30 s of log time: one file {whole} B, split every 5 s {split} B")
    files = sorted(p.name for p in (tmp_path / "split").iterdir())
    assert len(files) == 13 and "metadata.yaml" in files  # 12 files of 5 s
    for path in (tmp_path / "one.mcap", tmp_path / "split"):
        data = read_topic(path, "/c").data
        np.testing.assert_array_equal(data, np.arange(60_000, dtype=float))

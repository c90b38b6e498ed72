"""A recording's memory is bounded by its split (issue 13: ~250 KB/min growth while recording).

The MCAP writer keeps one chunk index per chunk until the file is finished
(the summary section needs them); a recorder closes a chunk every 0.25 s
of log time, so an unsplit recording grows by ~1 KiB per second. Measured
with tracemalloc on the writer the node uses
(:func:`belt_drive_ros.ros.recorder.open_writer`), at 1 kHz on two topics
over 30 s of log time: the growth between the first and the second
15 s with a split every 5 s is a small fraction of the unsplit growth,
and it reads back whole. A finished split file gives malloc's freed pages back
(``release_free_heap``, glibc ``malloc_trim``), once per file, never fatally.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

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


HALF = 15_000  # ticks (15 s of log time) before and while the growth is measured


def _growth(path, **split) -> int:
    """Traced bytes added by the second 15 s of log time (after the first)."""
    writer = open_writer(path, **split)
    tracemalloc.start()
    try:
        _write(writer, 0, HALF)
        first = tracemalloc.get_traced_memory()[0]
        _write(writer, HALF, HALF)
        second = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
        writer.finish()
    return second - first


def test_split_recording_memory_stays_flat_where_one_file_grows(tmp_path):
    whole = _growth(tmp_path / "one.mcap")
    split = _growth(tmp_path / "split", max_bag_duration=5.0)
    assert whole > 60 * 200  # 60 chunk indexes in 15 s, a few hundred bytes each
    assert split < whole / 4, (split, whole)
    print(f"growth over 15 s of log time: one file {whole} B, split every 5 s {split} B")
    files = sorted(p.name for p in (tmp_path / "split").iterdir())
    assert len(files) == 7 and "metadata.yaml" in files  # 6 files of 5 s
    for path in (tmp_path / "one.mcap", tmp_path / "split"):
        data = read_topic(path, "/c").data
        np.testing.assert_array_equal(data, np.arange(2 * HALF, dtype=float))


def _recorder_growth(tmp_path, ros_domain_id, ticks: int, **split) -> tuple[int, int]:
    """(traced bytes added by the recorder over the last ``ticks`` ticks after as many warm-up ticks,
    number of files written): a real rclpy node (never spun) and :class:`NodeRecorder` fed
    ``record_tick`` / ``record_input`` directly, log time 1 ms per tick."""
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node

    from belt_drive_ros.ros.recorder import NodeRecorder

    context = Context()
    rclpy.init(args=[], context=context, domain_id=ros_domain_id)
    node = Node("memory_probe", context=context)
    path = tmp_path / ("split" if split else "one.mcap")
    recorder = NodeRecorder(node, str(path), topics=[
        "drive_torque", "drive_torque_applied", "joint_states", "shaft_speed", "load_torque", "belt_torque",
        "relative_deflection"], flush_interval_s=0.25, **split)
    joints = [0.1 * j for j in range(12)]
    floats = (1.0, 2.0, 3.0, 4.0)

    def run(start: int, n: int) -> None:
        for k in range(start, start + n):
            now = 10**9 + k * 1_000_000
            recorder.record_input(2.0, now)
            recorder.record_tick(now, joints, floats, 2.0)

    try:
        tracemalloc.start()  # from the start: what the window frees of the warm-up's is subtracted
        try:
            run(0, ticks)
            recorder.writer.flush()  # as the flush timer does: both measurements between chunks
            before = tracemalloc.get_traced_memory()[0]
            run(ticks, ticks)
            recorder.writer.flush()
            grown = tracemalloc.get_traced_memory()[0] - before
        finally:
            tracemalloc.stop()
        assert recorder.error is None and recorder.message_count == 2 * ticks * 7
    finally:
        recorder.close()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    files = len(list(path.glob("*.mcap"))) if split else 1
    return grown, files


@pytest.mark.ros
def test_recorder_python_memory_does_not_grow_per_tick(tmp_path, ros_domain_id):
    """The node's recorder (record_tick and record_input, 7 messages a tick) keeps nothing per tick:
    over 10,000 ticks after 10,000 of warm-up, split every 2 s, the traced memory grows by less
    than 2 bytes per tick, where one list entry kept per tick would be 8 and one object ~50. What
    does grow is per finished file (its entry for metadata.yaml, a few hundred bytes: ~60 an hour
    with the node's 60 s splits) and one-time caches; the open file's chunk indexes are measured
    at the same phase (right after a flush, at the same offset into a 2 s file) both times.
    Unsplit (4,000 ticks after as many), the growth is the chunk indexes the file keeps for its summary
    (~ticks/250 of them)."""
    ticks = 10_000
    split, files = _recorder_growth(tmp_path, ros_domain_id, ticks, max_bag_duration=2.0)
    assert files == 2 * ticks // 2000  # 40 s of log time in 2 s files
    assert split < 2 * ticks, f"recorder grew {split} B over {ticks} ticks ({split / ticks:.2f} B/tick)"
    # the chunk index per chunk is the same from 8 chunks on (measured 852-889 B over 2,000-10,000 ticks):
    # 4,000 ticks (16 chunks) measure it, at a third of the traced ticks' cost
    unsplit = 4_000
    whole, _ = _recorder_growth(tmp_path, ros_domain_id, unsplit)
    chunks = unsplit / 250  # a chunk every 0.25 s of log time
    per_chunk = whole / chunks
    print(f"recorder growth over {ticks} ticks: split {split} B ({split / ticks:.2f} B/tick); over {unsplit} ticks one file "
          f"{whole} B = {per_chunk:.0f} B per chunk index ({per_chunk * 4 * 3600 / 2**20:.1f} MiB per hour)")
    assert 200 < per_chunk < 8000  # the summary's chunk index per chunk: inherent to one unsplit file


def test_release_free_heap_gives_freed_pages_back_and_never_raises(monkeypatch):
    """glibc ``malloc_trim(0)`` after a split file is finished: freed memory goes back to the
    system (fragmented free pages: every other 64 KiB block freed); elsewhere a no-op."""
    import platform

    from belt_drive_ros.ros import recorder

    blocks = [bytearray(64 * 1024 - 64) for _ in range(400)]  # ~25 MiB below the mmap threshold
    del blocks[::2]
    if platform.libc_ver()[0] == "glibc":
        assert recorder.release_free_heap() is True
    monkeypatch.setattr(recorder, "_MALLOC_TRIM", None)
    monkeypatch.setattr(platform, "libc_ver", lambda *a, **k: ("musl", "1.2"))
    assert recorder.release_free_heap() is False
    del blocks


def test_the_recorder_trims_the_heap_once_per_finished_split_file(monkeypatch):
    from belt_drive_ros.ros import recorder

    calls = []
    monkeypatch.setattr(recorder, "release_free_heap", lambda: calls.append(1) or True)

    class Node:
        def get_clock(self):
            return None

    class SplitWriter:  # the part of Ros2BagWriter the flush timer looks at
        path = "bag"
        files = ["bag/bag_0.mcap"]

        def flush(self):
            pass

    writer = SplitWriter()
    rec = recorder.TopicRecorder(Node(), writer, flush_period=None)
    rec._on_flush_timer()
    assert calls == []  # the first file is still open
    writer.files = ["bag/bag_0.mcap", "bag/bag_1.mcap"]
    rec._on_flush_timer()
    rec._on_flush_timer()
    assert calls == [1] and rec.heap_trims == 1
    writer.files = writer.files + ["bag/bag_2.mcap"]
    rec._on_flush_timer()
    assert calls == [1, 1]

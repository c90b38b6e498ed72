"""A bag folder written in blocks (``Ros2BagWriter(blocks=True).write_block``) holds the messages that writing
them one by one (``write_raw``) gives, split into the same files by duration, and by size at chunk granularity.
Read back with the ``mcap`` library's reader (not ours)."""

from __future__ import annotations

import os
import struct

import numpy as np
import pytest
from mcap.reader import make_reader

from msg_tools.bagdir import Ros2BagWriter, bag_files

FLOAT64 = "std_msgs/msg/Float64"
LATCHED = "/robot_description"
TOPICS = [("/a", FLOAT64), ("/b", FLOAT64)]


def _payload(values: np.ndarray) -> np.ndarray:
    """(n, 12) CDR of std_msgs/Float64 messages: little-endian header, 4 bytes padding, the double."""
    out = np.zeros((values.size, 12), dtype=np.uint8)
    out[:, 0:4] = np.frombuffer(b"\x00\x01\x00\x00", dtype=np.uint8)
    out[:, 4:12] = values.astype("<f8").view(np.uint8).reshape(-1, 8)
    return out


def _steps(seed: int, n: int) -> tuple[np.ndarray, list]:
    """``n`` steps at 1 ms from 5 ns: their times [ns] and a random Float64 payload per topic (seeded)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1_000_000 + 5
    return t, [_payload(rng.normal(size=t.size)) for _ in TOPICS]


def _write(folder, blocks: bool, steps: int, **split):
    """Three blocks of ``steps`` steps of both topics at 1 ms, a latched message between the first two."""
    rng = np.random.default_rng(7)
    with Ros2BagWriter(folder, force=True, blocks=blocks, chunk_size=4096, **split) as w:
        w.add_topic(LATCHED, FLOAT64)
        w.latch(LATCHED)
        for k in range(3):
            t = (np.arange(steps) + k * steps) * 1_000_000 + 5
            payloads = [_payload(rng.normal(size=steps)) for _ in TOPICS]
            if k == 1:
                w.write_raw(LATCHED, FLOAT64, bytes(_payload(np.array([42.0]))[0]), int(t[0]))
            if blocks:
                w.write_block(TOPICS, t, payloads)
            else:
                for i, ti in enumerate(t.tolist()):
                    for (topic, type_name), p in zip(TOPICS, payloads):
                        w.write_raw(topic, type_name, p[i].tobytes(), ti)
    return [_messages(f) for f in bag_files(folder)]


def _messages(path) -> list:
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, m.publish_time, m.sequence, bytes(m.data))
                for _, c, m in make_reader(f).iter_messages(log_time_order=False)]


def test_split_by_duration_gives_the_same_files_and_messages(tmp_path):
    raw = _write(tmp_path / "raw", False, 700, max_bag_duration=0.25)
    block = _write(tmp_path / "block", True, 700, max_bag_duration=0.25)
    assert len(raw) == 9 and [len(f) for f in block] == [len(f) for f in raw]
    for a, b in zip(raw, block):
        assert sorted(a) == sorted(b)  # (within a file, one step's topics in either order)
    assert (tmp_path / "raw" / "metadata.yaml").read_text().replace("raw", "block") == \
           (tmp_path / "block" / "metadata.yaml").read_text()
    latched = 700 * 1_000_000 + 5  # (written at the second block's first step)
    for f in block:  # each file begun after it starts with it
        first = min(m[1] for m in f)
        if first > latched:
            assert [m[1] for m in f if m[0] == LATCHED] == [first]


def test_split_by_size_keeps_every_message_in_order_and_each_file_full(tmp_path):
    limit = 20_000
    raw = _write(tmp_path / "raw", False, 2000, max_bag_size=limit)
    block = _write(tmp_path / "block", True, 2000, max_bag_size=limit)
    assert len(block) >= 3 and abs(len(block) - len(raw)) <= 1
    sizes = [os.path.getsize(p) for p in bag_files(tmp_path / "block")]
    raw_sizes = [os.path.getsize(p) for p in bag_files(tmp_path / "raw")]
    assert min(sizes[:-1]) >= limit and sizes[-1] > 0 and max(sizes) <= max(raw_sizes) + 2 * 4096
    # (a message's sequence counts within its file: the files split at other steps)
    payload = [m[:3] + m[4:] for f in block for m in f if m[0] != LATCHED]
    expected = [m[:3] + m[4:] for f in raw for m in f if m[0] != LATCHED]
    assert sorted(payload, key=lambda m: (m[1], m[0])) == sorted(expected, key=lambda m: (m[1], m[0]))
    assert [m[1] for m in payload] == sorted(m[1] for m in payload)  # across files, in time order
    value = struct.pack("<d", 42.0)
    begun_after = [f for f in block if min(m[1] for m in f) > 2000 * 1_000_000 + 5]  # (the latched message's time)
    assert len(begun_after) >= 2
    for f in begun_after:  # each starts with the latched message
        first = min(m[1] for m in f)
        assert [(m[1], m[4][4:]) for m in f if m[0] == LATCHED] == [(first, value)]


def test_write_block_needs_a_block_writer(tmp_path):
    with Ros2BagWriter(tmp_path / "x", force=True) as w:
        with pytest.raises(TypeError, match="blocks=True"):
            w.write_block(TOPICS, np.array([1]), [_payload(np.ones(1))] * 2)


def test_split_by_size_with_the_default_chunk_size_checks_after_each_chunk(tmp_path):
    """No ``chunk_size`` given (``write_result_mcap(..., max_bag_size=N)``): the files' chunks are the writer's
    default 128 KiB, and the size is checked after each of them, not after 1 MiB's worth (files ~4x the limit)."""
    limit, chunk = 200_000, 128 * 1024
    rng = np.random.default_rng(3)
    t = np.arange(20_000) * 1_000_000
    with Ros2BagWriter(tmp_path / "bag", force=True, blocks=True, max_bag_size=limit) as w:
        w.write_block(TOPICS, t, [_payload(rng.normal(size=t.size)) for _ in TOPICS])
    sizes = [os.path.getsize(p) for p in bag_files(tmp_path / "bag")]
    assert len(sizes) >= 3 and all(limit <= s <= limit + chunk + 4096 for s in sizes[:-1]), sizes
    assert sum(len(_messages(f)) for f in bag_files(tmp_path / "bag")) == 2 * t.size


def _one_step_runs(folder, blocks: bool, t, payloads, **split) -> None:
    """A recorded message on /raw just before each step, each step's samples a one-step block (or its messages)."""
    with Ros2BagWriter(folder, force=True, blocks=blocks, chunk_size=4096, **split) as w:
        for k, tk in enumerate(t.tolist()):
            w.write_raw("/raw", FLOAT64, bytes(_payload(np.array([float(k)]))[0]), tk - 1)
            if blocks:
                w.write_block(TOPICS, t[k : k + 1], [p[k : k + 1] for p in payloads])
            else:
                for (topic, type_name), p in zip(TOPICS, payloads):
                    w.write_raw(topic, type_name, p[k].tobytes(), tk)


def test_one_step_blocks_between_passed_through_messages_split_as_message_by_message(tmp_path):
    """A re-simulation into a bag folder: a recorded message at every step, the samples as one-step blocks
    between them; the same files and messages as writing all one by one, and as few chunks."""
    t, payloads = _steps(5, 900)
    files = {}
    for blocks in (False, True):
        folder = tmp_path / str(blocks)
        _one_step_runs(folder, blocks, t, payloads, max_bag_duration=0.25)
        files[blocks] = bag_files(folder)
    assert [sorted(_messages(f)) for f in files[True]] == [sorted(_messages(f)) for f in files[False]]
    for a, b in zip(files[False], files[True]):
        with open(a, "rb") as fa, open(b, "rb") as fb:
            chunks = [make_reader(f).get_summary().statistics.chunk_count for f in (fa, fb)]
        assert chunks[1] <= chunks[0] + 1, chunks


def test_a_latched_topic_written_in_blocks_starts_each_file_with_its_message_before_the_split(tmp_path):
    """A block that spans several files: each new file repeats the latched topic's message of the step before it,
    as writing one by one does (not the one before the block)."""
    t, payloads = _steps(9, 1000)
    files = {}
    for blocks in (False, True):
        folder = tmp_path / str(blocks)
        with Ros2BagWriter(folder, force=True, blocks=blocks, chunk_size=4096, max_bag_duration=0.3) as w:
            w.latch("/a")
            for a, b in ((0, 10), (10, t.size)):  # (a first block: the latched topic has a message before the next)
                if blocks:
                    w.write_block(TOPICS, t[a:b], [p[a:b] for p in payloads])
                else:
                    for k in range(a, b):
                        for (topic, type_name), p in zip(TOPICS, payloads):
                            w.write_raw(topic, type_name, p[k].tobytes(), int(t[k]))
        files[blocks] = [sorted(_messages(f)) for f in bag_files(folder)]
    assert len(files[False]) == 4 and files[True] == files[False]


def test_one_step_blocks_split_by_size_stay_in_few_chunks_and_files(tmp_path):
    """The same with max_bag_size: a one-step block that joined the open chunk is not flushed as a chunk of its
    own to learn the file's size (a chunk per step: twice the files, each ~50x the chunks)."""
    t, payloads = _steps(6, 3000)
    chunks, messages = {}, {}
    for blocks in (False, True):
        folder = tmp_path / str(blocks)
        _one_step_runs(folder, blocks, t, payloads, max_bag_size=40_000)
        chunks[blocks] = []
        for f in bag_files(folder):
            with open(f, "rb") as fh:
                chunks[blocks].append(make_reader(fh).get_summary().statistics.chunk_count)
        messages[blocks] = sorted(m[:3] + m[4:] for f in bag_files(folder) for m in _messages(f))
    assert messages[True] == messages[False]
    assert len(chunks[False]) >= 3 and abs(len(chunks[True]) - len(chunks[False])) <= 1, chunks
    assert sum(chunks[True]) <= sum(chunks[False]) + len(chunks[True]), chunks


@pytest.mark.parametrize("stride", [1, 3, 5])
def test_a_run_between_passed_through_messages_gives_the_same_messages_message_by_message_or_in_blocks(
        tmp_path, monkeypatch, stride):
    """A re-simulation passes a recorded message through every few steps: runs of up to ``recording.SHORT_RUN``
    steps between them are written message by message (cheaper there), longer ones as blocks. Both give the same
    messages (times, sequence numbers, bytes) in a file and in a bag folder as writing every run in blocks."""
    import dataclasses

    from belt_drive_ros.core.simulate import simulate
    from belt_drive_ros.io import recording
    from belt_drive_ros.io.cdr_encoders import encode_float64
    from belt_drive_ros.io.scenes import load_scene

    run = simulate(dataclasses.replace(load_scene("paper"), duration=0.2, dt=0.001, method="exact"))
    start = 1_000_000_000
    t_ns = np.round(run.time[::stride] * 1e9).astype(np.int64) + start - 1
    passthrough = [("/raw", FLOAT64, "", None, list(zip(t_ns.tolist(), encode_float64(np.arange(t_ns.size)))))]
    read, usual = {}, recording.SHORT_RUN
    for short in (usual, 0):
        monkeypatch.setattr(recording, "SHORT_RUN", short)
        for folder in (False, True):
            out = tmp_path / f"{short}_{folder}" / ("bag" if folder else "run.mcap")
            out.parent.mkdir()
            recording.write_result_mcap(run, out, bag_folder=folder, passthrough=passthrough, start_time_ns=start)
            files = bag_files(out) if folder else [out]
            read[short, folder] = sorted(m for f in files for m in _messages(f))
    assert usual >= 3 and len(read[0, False]) == 7 * run.time.size + t_ns.size + 1
    assert read[usual, False] == read[0, False] == read[usual, True] == read[0, True]


def test_a_block_of_no_topics_writes_nothing_as_message_by_message_does(tmp_path):
    """``write_block([], t, [])``: no messages, as writing them one by one (nothing) gives; it divided by zero
    (the step's bytes), in a bag folder and (after noting the block's times as the file's) in a single file."""
    from msg_tools.block_writer import BlockMcapWriter

    with Ros2BagWriter(tmp_path / "x", force=True, blocks=True, max_bag_size=10_000) as w:
        w.write_block([], np.array([1, 2, 3]), [])
        w.write_raw("/a", FLOAT64, bytes(_payload(np.ones(1))[0]), 7)
    with BlockMcapWriter(tmp_path / "y.mcap", force=True) as w:
        w.write_block([], np.array([1, 2, 3]), [])
        w.write_raw("/a", FLOAT64, bytes(_payload(np.ones(1))[0]), 7)
    for path in bag_files(tmp_path / "x") + [tmp_path / "y.mcap"]:
        assert [m[:2] for m in _messages(path)] == [("/a", 7)]
        with open(path, "rb") as f:
            stats = make_reader(f).get_summary().statistics
        assert (stats.message_start_time, stats.message_end_time) == (7, 7)


def test_a_block_whose_times_go_back_is_refused(tmp_path):
    """A block's times must be ascending (files split by searching them; a file's statistics take their first
    and last): out of order, the file said it began at its last time and ended at its first (start > end) and a
    bag folder split at the wrong step. Refused now, with nothing written."""
    from msg_tools.block_writer import BlockMcapWriter

    t = np.array([5, 3, 1])
    with Ros2BagWriter(tmp_path / "x", force=True, blocks=True, max_bag_duration=1e-9) as w:
        with pytest.raises(ValueError, match="ascending"):
            w.write_block(TOPICS, t, [_payload(np.ones(3))] * 2)
        assert w.message_count == 0 and len(w.files) == 1
    with BlockMcapWriter(tmp_path / "y.mcap", force=True) as w:
        with pytest.raises(ValueError, match="ascending"):
            w.write_block(TOPICS, t, [_payload(np.ones(3))] * 2)
        assert w.message_count == 0


@pytest.mark.parametrize("rows", [3, 8])
@pytest.mark.parametrize("split", [{}, {"max_bag_duration": 2e-9}])
def test_a_block_whose_payload_rows_are_not_its_steps_is_refused_with_nothing_written(tmp_path, rows, split):
    """A payload of more rows than the block's times was taken silently (its first rows written, the rest
    dropped) where BlockMcapWriter.write_block refuses it; one of fewer rows, in a folder split by duration,
    had the block's first pieces written before the refusal. Refused up front now, as a single file does."""
    with Ros2BagWriter(tmp_path / "x", force=True, blocks=True, **split) as w:
        with pytest.raises(ValueError, match=r"payload must be \(5, >= 4\) bytes"):
            w.write_block(TOPICS, np.arange(5), [_payload(np.ones(5)), _payload(np.ones(rows))])
        with pytest.raises(ValueError, match=r"payload must be \(5, >= 4\) bytes"):
            w.write_block(TOPICS[:1], np.arange(5), [np.zeros(5, dtype=np.uint8)])  # (1-D: an IndexError before)
        assert w.message_count == 0


@pytest.mark.parametrize("count", [1, 3])
def test_a_block_with_a_payload_count_other_than_its_topics_is_refused_by_name(tmp_path, count):
    """One payload per topic: fewer or more were refused by a message about the writer's internals ("no field
    of name s1", "... t2"). Both writers refuse it now naming the counts, with nothing written."""
    from msg_tools.block_writer import BlockMcapWriter

    payloads = [_payload(np.ones(5))] * count
    with Ros2BagWriter(tmp_path / "x", force=True, blocks=True) as w:
        with pytest.raises(ValueError, match=f"2 topics need as many payloads, got {count}"):
            w.write_block(TOPICS, np.arange(5), payloads)
        assert w.message_count == 0
    with BlockMcapWriter(tmp_path / "y.mcap", force=True) as w:
        with pytest.raises(ValueError, match=f"2 topics need as many payloads, got {count}"):
            w.write_block(TOPICS, np.arange(5), payloads)
        assert w.message_count == 0

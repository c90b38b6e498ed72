"""BlockMcapWriter: blocks of fixed-size messages give the file the per-message writer gives,
as the mcap library (indexed and linear reads, CRCs checked), mcap_ros2's decoder and
msg_tools.read_topic see it (decoded values compared, no ROS)."""

import io

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory

from belt_drive_ros.io.recording import float64_rows, joint_state_rows
from msg_tools import Ros2McapWriter, read_topic
from msg_tools.block_writer import BlockMcapWriter
from msg_tools.writer import encode

TOPICS = [("/drive_torque", "std_msgs/msg/Float64"), ("/joint_states", "sensor_msgs/msg/JointState"),
          ("/shaft_speed", "std_msgs/msg/Float64")]


def _payloads(t_ns, seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(t_ns.size, 4))
    return [float64_rows(x[:, 0]), joint_state_rows(t_ns, x, 2 * x, -x), float64_rows(x[:, 1])]


def _write(writer_class, target, blocks, **options):
    """Metadata, a single message, then the blocks, a single message between the first two, a last one."""
    with writer_class(target, **options) as w:
        w.add_metadata("scene", {"name": "test"})
        for topic, type_name in TOPICS:
            w.add_topic(topic, type_name)
        w.write("/note", "std_msgs/msg/String", {"data": "start"}, 5)
        for i, (t_ns, payloads) in enumerate(blocks):
            if hasattr(w, "write_block"):
                w.write_block(TOPICS, t_ns, payloads)
            else:
                for k, t in enumerate(t_ns.tolist()):
                    for (topic, type_name), p in zip(TOPICS, payloads):
                        w.write_raw(topic, type_name, p[k].tobytes(), t)
            if i == 0:
                w.write("/note", "std_msgs/msg/String", {"data": "between"}, int(t_ns[-1]))
        w.write("/note", "std_msgs/msg/String", {"data": "end"}, int(blocks[-1][0][-1]) + 1)
    return w


def _messages(data: bytes, indexed: bool):
    """(topic, sequence, log time, publish time, decoded message as a tuple) in the reader's order."""
    reader = make_reader(io.BytesIO(data), decoder_factories=[DecoderFactory()], validate_crcs=True)
    if indexed:
        it = reader.iter_decoded_messages(log_time_order=False)
    else:
        it = ((None, c, m, None) for _, c, m in _linear(data))
    out = []
    for _, channel, message, decoded in it:
        if decoded is None:
            decoded = DecoderFactory().decoder_for("cdr", reader.get_summary().schemas[channel.schema_id])(message.data)
        value = getattr(decoded, "data", None)
        if value is None:
            value = (decoded.header.stamp.sec, decoded.header.stamp.nanosec, tuple(decoded.name),
                     tuple(decoded.position), tuple(decoded.velocity), tuple(decoded.effort))
        out.append((channel.topic, message.sequence, message.log_time, message.publish_time, value))
    return out


def _linear(data: bytes):
    """Every message by a linear scan of the records (chunks decompressed, CRCs checked)."""
    from mcap.records import Channel, Message

    channels = {}
    for record in StreamReader(io.BytesIO(data), skip_magic=False, validate_crcs=True).records:
        if isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            yield None, channels[record.channel_id], record


@pytest.mark.parametrize("chunk_size", [1024, 64 * 1024])
def test_blocks_read_as_the_per_message_writers_file(chunk_size):
    t1 = 1_000_000_000 + np.arange(700, dtype=np.int64) * 1_000_000
    t2 = t1[-1] + 1_000_000 + np.arange(333, dtype=np.int64) * 1_000_000
    blocks = [(t1, _payloads(t1, 1)), (t2, _payloads(t2, 2))]
    files = {}
    for cls in (Ros2McapWriter, BlockMcapWriter):
        buf = io.BytesIO()
        _write(cls, buf, blocks, chunk_size=chunk_size, flush_interval_s=None)
        files[cls] = buf.getvalue()
    for indexed in (True, False):
        expected = _messages(files[Ros2McapWriter], indexed)
        got = _messages(files[BlockMcapWriter], indexed)
        assert len(got) == 3 + 3 * (700 + 333)
        assert got == expected
    summary = make_reader(io.BytesIO(files[BlockMcapWriter])).get_summary()
    stats = summary.statistics
    assert stats.message_count == 3 + 3 * 1033
    assert stats.message_start_time == 5 and stats.message_end_time == int(t2[-1]) + 1
    assert sorted(stats.channel_message_counts.values()) == [3, 1033, 1033, 1033]
    assert len(summary.chunk_indexes) == stats.chunk_count > (1 if chunk_size == 1024 else 0)
    assert [m.name for m in summary.metadata_indexes] == ["scene", "rosbag2"]
    # msg_tools' own reader: the columns, vectorized
    for topic, column in (("/drive_torque", 0), ("/shaft_speed", 1)):
        data = read_topic(io.BytesIO(files[BlockMcapWriter]), topic)
        values = np.concatenate([np.random.default_rng(s).normal(size=(n, 4))[:, column] for s, n in ((1, 700), (2, 333))])
        np.testing.assert_array_equal(np.asarray(data["data"]), values)


def test_block_payloads_are_the_encoder_bytes():
    """Each message of a block is byte for byte its payload row (the CDR encoders' output)."""
    t = np.arange(50, dtype=np.int64) * 1_000_000
    payloads = _payloads(t, 3)
    buf = io.BytesIO()
    with BlockMcapWriter(buf) as w:
        w.write_block(TOPICS, t, payloads)
    rows = {topic: p for (topic, _), p in zip(TOPICS, payloads)}
    seen = {topic: 0 for topic in rows}
    for _, channel, message in make_reader(io.BytesIO(buf.getvalue())).iter_messages():
        k = seen[channel.topic]
        assert message.data == rows[channel.topic][k].tobytes()
        assert message.log_time == message.publish_time == int(t[k])
        assert message.sequence == k + 1
        seen[channel.topic] += 1
    assert payloads[0][7].tobytes() == encode("std_msgs/msg/Float64", {"data": float(np.frombuffer(payloads[0][7][4:], "<f8")[0])})


def test_bad_blocks_are_refused():
    with BlockMcapWriter(io.BytesIO()) as w:
        t = np.arange(3, dtype=np.int64)
        with pytest.raises(ValueError, match="payload"):
            w.write_block(TOPICS[:1], t, [np.zeros((2, 12), np.uint8)])
        with pytest.raises(ValueError, match=">= 0"):
            w.write_block(TOPICS[:1], t - 5, [np.zeros((3, 12), np.uint8)])


def test_fixed_messages_write_only_their_fields_into_the_reused_block():
    """Blocks of FixedMessages (templates kept in the writer's reused block, only the fields written) give
    the same file as their bytes: blocks growing, shrinking, and a block of another layout between."""
    from belt_drive_ros.io.recording import float64_messages, joint_state_messages
    from msg_tools.block_writer import FixedMessages

    def fixed(t_ns, seed):
        x = np.random.default_rng(seed).normal(size=(t_ns.size, 4))
        return [float64_messages(x[:, 0]), joint_state_messages(t_ns, x, 2 * x, -x), float64_messages(x[:, 1])]

    sizes, start, plan = [50, 120, 30, 200, 10], 1_000_000_000, []
    for i, n in enumerate(sizes):
        t = start + np.arange(n, dtype=np.int64) * 1_000_000
        start = int(t[-1]) + 1_000_000
        topics = TOPICS if i != 2 else TOPICS[::-1]  # another layout: the block's constants are written again
        payloads = fixed(t, i) if i != 2 else fixed(t, i)[::-1]
        plan.append((topics, t, payloads))
    files = {}
    for kind in ("messages", "bytes", "fixed"):
        buf = io.BytesIO()
        with (Ros2McapWriter if kind == "messages" else BlockMcapWriter)(buf, chunk_size=4096, flush_interval_s=None) as w:
            for topic, type_name in TOPICS:
                w.add_topic(topic, type_name)
            for topics, t, payloads in plan:
                if kind == "messages":  # the reference: message by message
                    rows = [p.rows() for p in payloads]
                    for k, stamp in enumerate(t.tolist()):
                        for (topic, type_name), r in zip(topics, rows):
                            w.write_raw(topic, type_name, r[k].tobytes(), stamp)
                else:
                    w.write_block(topics, t, [p.rows() for p in payloads] if kind == "bytes" else payloads)
        files[kind] = buf.getvalue()
    assert all(isinstance(p, FixedMessages) for p in plan[0][2])
    assert files["fixed"] == files["bytes"]
    expected = _messages(files["messages"], indexed=True)
    assert len(expected) == 3 * sum(sizes)
    assert _messages(files["fixed"], indexed=True) == expected
    from msg_tools.scan import Scan  # the data section's CRC (combined from the chunks' own) as a reader checks it

    for kind in ("messages", "fixed"):
        assert Scan(files[kind], kind).run().data_crc == "ok"


def test_crc32_combine_is_the_crc_of_the_joined_bytes():
    """The data section's CRC is combined from each chunk's (computed in the worker threads): zlib's
    crc32_combine, written out, equals the CRC of the joined bytes (empty parts and megabytes included)."""
    import os
    import zlib

    from msg_tools.block_writer import crc32_combine

    rng = np.random.default_rng(5)
    for n1, n2 in [(0, 0), (0, 7), (7, 0), (1, 1), (3, 100_000), (2_000_000, 1_048_577)] + [
            tuple(rng.integers(0, 5000, 2)) for _ in range(50)]:
        a, b = os.urandom(int(n1)), os.urandom(int(n2))
        assert crc32_combine(zlib.crc32(a), zlib.crc32(b), len(b)) == zlib.crc32(a + b)


def test_packed_chunk_indexes_are_the_mcap_librarys_records():
    """The summary's chunk index records, packed in one pass, are the bytes ``mcap.records.ChunkIndex`` writes
    (any number of message index entries per chunk, 64-bit fields at their extremes)."""
    from mcap.data_stream import RecordBuilder
    from mcap.records import ChunkIndex

    from msg_tools.block_writer import BlockRecords

    records = BlockRecords(io.BytesIO())
    records._chunk_compression = "zstd"
    rng = np.random.default_rng(1)
    expected = RecordBuilder()
    for k in range(40):
        fields = [int(v) for v in rng.integers(0, 2**63, size=7, dtype=np.uint64)] if k else [2**64 - 1] * 7
        pairs = {int(c): int(rng.integers(0, 2**63)) for c in rng.choice(2**16, size=k % 9, replace=False)}
        records._chunks.extend(fields + [len(pairs)])
        for channel, offset in pairs.items():
            records._chunk_pairs.extend((channel, offset))
        start, end, at, length, index_length, compressed, size = fields
        ChunkIndex(message_start_time=start, message_end_time=end, chunk_start_offset=at, chunk_length=length,
                   message_index_offsets=pairs, message_index_length=index_length, compression="zstd",
                   compressed_size=compressed, uncompressed_size=size).write(expected)
    assert records.chunk_index_records() == expected.end()


@pytest.mark.parametrize("flush_interval_s", [None, 0.05])
def test_short_blocks_between_single_messages_join_the_open_chunk(flush_interval_s):
    """A re-simulation passes a recorded message through at every step: its samples come as blocks of one step
    between single messages. They go into the open chunk as single messages do (closed by size, or log time),
    not a chunk each (a file ~2.3x as large, written ~2x slower); read back as the per-message writer's file."""
    t = 1_000_000_000 + np.arange(600, dtype=np.int64) * 1_000_000
    payloads = _payloads(t, 4)
    files = {}
    for cls in (Ros2McapWriter, BlockMcapWriter):
        buf = io.BytesIO()
        with cls(buf, chunk_size=16 * 1024, flush_interval_s=flush_interval_s) as w:
            for topic, type_name in TOPICS:
                w.add_topic(topic, type_name)
            for k in range(t.size):
                w.write("/note", "std_msgs/msg/String", {"data": f"step {k}"}, int(t[k]) - 1)
                if cls is BlockMcapWriter:
                    w.write_block(TOPICS, t[k : k + 1], [p[k : k + 1] for p in payloads])
                else:
                    for (topic, type_name), p in zip(TOPICS, payloads):
                        w.write_raw(topic, type_name, p[k].tobytes(), int(t[k]))
        files[cls] = buf.getvalue()
    for indexed in (True, False):
        assert _messages(files[BlockMcapWriter], indexed) == _messages(files[Ros2McapWriter], indexed)
    chunks = {cls: make_reader(io.BytesIO(data)).get_summary().statistics.chunk_count for cls, data in files.items()}
    assert chunks[BlockMcapWriter] <= chunks[Ros2McapWriter] + 1, chunks
    assert len(files[BlockMcapWriter]) < 1.2 * len(files[Ros2McapWriter])


def test_a_chunk_spans_the_times_of_the_short_block_it_began_with():
    """A short block joined the open chunk, then the clock jumped back: the next block's first chunk holds both,
    and its start and end times (what an indexed reader seeks by) take in every one of its messages."""
    early = np.arange(10, 400, dtype=np.int64) * 1_000_000
    late = np.array([900_000_000])
    buf = io.BytesIO()
    with BlockMcapWriter(buf, chunk_size=64 * 1024, flush_interval_s=None) as w:
        w.write_block(TOPICS, late, _payloads(late, 5))
        w.write_block(TOPICS, early, _payloads(early, 6))
    reader = make_reader(io.BytesIO(buf.getvalue()))
    chunks = reader.get_summary().chunk_indexes
    assert chunks and min(c.message_start_time for c in chunks) == int(early[0])
    assert max(c.message_end_time for c in chunks) == int(late[0])
    times = sorted(m.log_time for _, _, m in reader.iter_messages(log_time_order=True))
    assert times == sorted([int(late[0])] * 3 + early.tolist() * 3)

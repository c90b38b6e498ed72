"""msg_tools.reader: vectorized decoding against mcap_ros2, tolerant reading of
truncated files, clear errors for bad input (no ROS needed)."""

import io
import struct
import warnings

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from msg_tools._cdr import decoder_for

from msg_tools import (
    read_bag,
    BagNotFoundError,
    CorruptBagError,
    DecodeError,
    RecoveredBagWarning,
    Ros2McapWriter,
    TopicNotFoundError,
    list_topics,
    read_topic,
    read_topics,
    summary,
)
from msg_tools.schemas import schema_text
from msg_tools.writer import encode

RNG = np.random.default_rng(20240611)


def _decoder(type_name):
    return decoder_for(type_name, schema_text(type_name))


def _bits(a):
    return np.asarray(a, dtype=np.float64).view(np.int64)


def _bag(messages, **kwargs):
    """messages: iterable of (topic, type, cdr bytes, log time ns)."""
    buf = io.BytesIO()
    with Ros2McapWriter(buf, **kwargs) as w:
        for topic, type_name, data, t in messages:
            w.write_raw(topic, type_name, data, t)
    return buf.getvalue()


# ------------------------------------------------------------------ Float64
def test_float64_vectorized_equals_mcap_ros2_bitwise():
    values = np.concatenate([
        RNG.normal(scale=1e3, size=3000),
        [0.0, -0.0, np.inf, -np.inf, np.nan, 5e-324, np.finfo(float).max],
    ])
    payloads = [encode("std_msgs/msg/Float64", {"data": float(v)}) for v in values]
    raw = _bag(("/torque", "std_msgs/msg/Float64", p, i) for i, p in enumerate(payloads))
    data = read_topic(raw, "/torque")
    assert data.decoder == "vectorized"
    reference = [_decoder("std_msgs/msg/Float64")(p).data for p in payloads]
    np.testing.assert_array_equal(_bits(data.data), _bits(reference))
    np.testing.assert_array_equal(data.log_time_ns, np.arange(len(values)))


def test_float64_big_endian_and_mixed_encapsulation():
    values = RNG.normal(size=200)
    payloads = [
        (b"\x00\x00\x00\x00" + struct.pack(">d", v)) if i % 3 else
        (b"\x00\x01\x00\x00" + struct.pack("<d", v))
        for i, v in enumerate(values)
    ]
    reference = [_decoder("std_msgs/msg/Float64")(p).data for p in payloads]
    np.testing.assert_array_equal(reference, values)  # mcap_ros2 agrees on the layout
    raw = _bag(("/x", "std_msgs/msg/Float64", p, i) for i, p in enumerate(payloads))
    np.testing.assert_array_equal(read_topic(raw, "/x").data, values)
    all_be = _bag(("/x", "std_msgs/msg/Float64", b"\x00\x00\x00\x00" + struct.pack(">d", v), i)
                  for i, v in enumerate(values))
    np.testing.assert_array_equal(read_topic(all_be, "/x").data, values)


def test_out_of_order_and_padded_payloads_are_sorted_by_log_time():
    times = RNG.permutation(500)
    values = times * 0.25
    # every third payload carries 4 trailing padding bytes (other length)
    payloads = [encode("std_msgs/msg/Float64", {"data": v}) + (b"\0" * 4 if i % 3 == 0 else b"")
                for i, v in enumerate(values)]
    for raw in (
        _bag(("/x", "std_msgs/msg/Float64", p, int(t)) for p, t in zip(payloads, times)),
        _bag(("/x", "std_msgs/msg/Float64", encode("std_msgs/msg/Float64", {"data": v}), int(t))
             for v, t in zip(values, times)),
    ):
        data = read_topic(raw, "/x")
        np.testing.assert_array_equal(data.log_time_ns, np.arange(500))
        np.testing.assert_array_equal(data.data, np.arange(500) * 0.25)


def test_float64_unsupported_encapsulation_is_rejected_clearly():
    raw = _bag([("/x", "std_msgs/msg/Float64", b"\x00\x03\x00\x00" + struct.pack("<d", 1.0), 0)])
    with pytest.raises(DecodeError) as info:
        read_topic(raw, "/x")
    text = str(info.value)
    assert "/x" in text and "0x0003" in text and "\n" not in text


# --------------------------------------------------------------- JointState
def _js(names, n_pos, n_vel, n_eff, t_ns, frame="base_link"):
    return {
        "header": {"stamp": {"sec": t_ns // 10**9, "nanosec": t_ns % 10**9}, "frame_id": frame},
        "name": names,
        "position": RNG.normal(size=n_pos).tolist(),
        "velocity": RNG.normal(size=n_vel).tolist(),
        "effort": RNG.normal(size=n_eff).tolist(),
    }


def _check_against_mcap_ros2(data, payloads):
    decode = _decoder("sensor_msgs/msg/JointState")
    for i, p in enumerate(payloads):
        ref = decode(p)
        assert data.stamp_ns[i] == ref.header.stamp.sec * 10**9 + ref.header.stamp.nanosec
        for fname in ("position", "velocity", "effort"):
            expected = np.full(len(data.names), np.nan)
            for name, value in zip(ref.name, getattr(ref, fname)):
                expected[data.names.index(name)] = value
            np.testing.assert_array_equal(_bits(getattr(data, fname)[i]), _bits(expected))


def test_joint_state_vectorized_equals_mcap_ros2():
    names = ["crank", "alternator", "water_pump", "ac_compressor"]
    msgs = [_js(names, 4, 4, 4, 1_700_000_000_123_456_789 + i * 1_000_000) for i in range(500)]
    payloads = [encode("sensor_msgs/msg/JointState", m) for m in msgs]
    raw = _bag(("/joint_states", "sensor_msgs/msg/JointState", p, i) for i, p in enumerate(payloads))
    data = read_topic(raw, "/joint_states")
    assert data.decoder == "vectorized"
    assert data.names == names and data.position.shape == (500, 4)
    _check_against_mcap_ros2(data, payloads)
    np.testing.assert_allclose(data.stamp, data.stamp_ns * 1e-9, rtol=1e-15)


def test_joint_state_empty_effort_is_nan_and_still_vectorized():
    payloads = [encode("sensor_msgs/msg/JointState", _js(["a", "bb"], 2, 2, 0, i)) for i in range(50)]
    data = read_topic(_bag(("/js", "sensor_msgs/msg/JointState", p, i) for i, p in enumerate(payloads)), "/js")
    assert data.decoder == "vectorized"
    assert np.isnan(data.effort).all() and not np.isnan(data.velocity).any()
    _check_against_mcap_ros2(data, payloads)


def test_joint_state_ignores_uninitialised_padding_bytes():
    # DDS (rclpy) leaves alignment padding and trailing bytes uninitialised
    payloads = []
    for i in range(100):
        p = bytearray(encode("sensor_msgs/msg/JointState", _js(["a", "bcd"], 2, 2, 2, i, frame="ab")))
        p[19] = RNG.integers(256)  # padding after "ab\0"
        p += bytes(RNG.integers(0, 256, size=4, dtype=np.uint8))  # trailing garbage
        payloads.append(bytes(p))
    data = read_topic(_bag(("/js", "sensor_msgs/msg/JointState", p, i) for i, p in enumerate(payloads)), "/js")
    assert data.decoder == "vectorized"
    _check_against_mcap_ros2(data, payloads)


def test_joint_state_varying_joints_falls_back_to_mcap_ros2():
    layouts = [(["a", "b"], 2, 2, 2), (["a", "b", "c"], 3, 3, 0), (["c"], 1, 0, 1), (["b", "a"], 2, 2, 2)]
    payloads = [encode("sensor_msgs/msg/JointState", _js(*layouts[i % 4], i)) for i in range(80)]
    data = read_topic(_bag(("/js", "sensor_msgs/msg/JointState", p, i) for i, p in enumerate(payloads)), "/js")
    assert data.decoder == "mcap_ros2"
    assert data.names == ["a", "b", "c"]
    _check_against_mcap_ros2(data, payloads)


def test_joint_state_same_length_different_names_is_not_mixed_up():
    payloads = [encode("sensor_msgs/msg/JointState", _js(["ab"] if i % 2 else ["cd"], 1, 1, 1, i))
                for i in range(20)]
    assert len({len(p) for p in payloads}) == 1
    data = read_topic(_bag(("/js", "sensor_msgs/msg/JointState", p, i) for i, p in enumerate(payloads)), "/js")
    assert data.decoder == "mcap_ros2" and data.names == ["cd", "ab"]
    _check_against_mcap_ros2(data, payloads)


def test_generic_types_decode_to_objects_and_numeric_fields():
    raw = _bag(
        [("/clock", "rosgraph_msgs/msg/Clock", encode("rosgraph_msgs/msg/Clock", {"clock": {"sec": 4, "nanosec": 5}}), 1),
         ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray",
          encode("diagnostic_msgs/msg/DiagnosticArray", {"status": [{"level": 2, "name": "belt"}]}), 2),
         ("/note", "std_msgs/msg/String", encode("std_msgs/msg/String", {"data": "hi"}), 3)]
    )
    topics = read_topics(raw)
    assert topics["/clock"].messages[0].clock.nanosec == 5
    assert topics["/diagnostics"].messages[0].status[0].name == "belt"
    assert topics["/note"].messages[0].data == "hi"
    assert topics["/clock"].fields == {}  # time stamps are not signals


# ---------------------------------------------------------------- summary
def test_summary_counts_rates_and_metadata():
    buf = io.BytesIO()
    with Ros2McapWriter(buf) as w:
        w.add_metadata("scene", {"name": "idle"})
        for i in range(101):
            w.write("/a", "std_msgs/msg/Float64", {"data": 1.0}, 5_000_000_000 + i * 10_000_000)
        w.write("/b", "std_msgs/msg/String", {"data": "x"}, 5_000_000_000)
    s = summary(buf.getvalue())
    assert s.complete and s.profile == "ros2" and s.message_count == 102
    a = {t.topic: t for t in s.topics}["/a"]
    assert (a.type_name, a.message_count, a.message_encoding, a.schema_encoding) == (
        "std_msgs/msg/Float64", 101, "cdr", "ros2msg")
    assert a.start_ns == 5_000_000_000 and a.end_ns == 6_000_000_000
    assert a.duration_s == pytest.approx(1.0) and a.frequency_hz == pytest.approx(100.0)
    assert s.duration_s == pytest.approx(1.0)
    assert s.metadata_dict("scene") == {"name": "idle"}
    assert "serialized_metadata" in s.metadata_dict("rosbag2")
    assert [t.topic for t in list_topics(buf.getvalue())] == ["/a", "/b"]


# ------------------------------------------------------------- truncation
def _long_bag():
    buf = io.BytesIO()
    with Ros2McapWriter(buf, flush_interval_s=0.05) as w:
        for i in range(1000):
            t = i * 1_000_000
            w.write("/x", "std_msgs/msg/Float64", {"data": float(i)}, t)
            w.write("/js", "sensor_msgs/msg/JointState", _js(["a", "b"], 2, 2, 2, t), t)
    return buf.getvalue()


@pytest.mark.parametrize("fraction", [0.05, 0.3, 0.5, 0.77, 0.95])
def test_truncated_file_reads_up_to_last_complete_chunk(fraction):
    raw = _long_bag()
    cut = int(len(raw) * fraction)
    chunks = make_reader(io.BytesIO(raw)).get_summary().chunk_indexes
    complete = [c for c in chunks if c.chunk_start_offset + c.chunk_length <= cut]
    last_time = max((c.message_end_time for c in complete), default=-1)
    expected = sum(1 for i in range(1000) if i * 1_000_000 <= last_time)
    with pytest.warns(RecoveredBagWarning) as record:
        data = read_topic(raw[:cut], "/x")
    assert not data.complete and data.stop_reason
    assert len(data) == expected
    np.testing.assert_array_equal(data.data, np.arange(expected, dtype=float))
    # total over all topics, counted with the mcap library in the complete chunks
    chunk_records = [r for r in StreamReader(io.BytesIO(raw), emit_chunks=True).records
                     if isinstance(r, Chunk)][: len(complete)]
    total = sum(isinstance(m, Message) for c in chunk_records for m in breakup_chunk(c))
    assert f"recovered {total} messages in {len(complete)} complete chunks" in str(record[0].message)


def test_file_cut_inside_header_has_no_messages():
    raw = _long_bag()
    with pytest.warns(RecoveredBagWarning):
        s = summary(raw[:30])
    assert not s.complete and s.message_count == 0 and s.topics == []


def test_corrupted_chunk_in_a_finished_file_is_damage():
    """The file has a summary, so a chunk that fails its check is damage, not a cut-off end."""
    raw = bytearray(_long_bag())
    chunks = make_reader(io.BytesIO(bytes(raw))).get_summary().chunk_indexes
    third = chunks[2]
    raw[third.chunk_start_offset + third.chunk_length - 20] ^= 0xFF
    with pytest.raises(CorruptBagError, match="damaged: the data stops early .*chunk"):
        read_topic(bytes(raw), "/x")
    bag = read_bag(bytes(raw), ["/x"], allow_damaged=True)  # what is before the damage
    assert bag.damage and not bag.complete
    data = bag.topics["/x"]
    assert len(data) == sum(1 for i in range(1000) if i * 1_000_000 <= chunks[1].message_end_time)


# ------------------------------------------------------------------ errors
def test_missing_file(tmp_path):
    with pytest.raises(BagNotFoundError) as info:
        read_topic(tmp_path / "nope.mcap", "/x")
    assert isinstance(info.value, FileNotFoundError) and "nope.mcap" in str(info.value)


@pytest.mark.parametrize("content", [b"", b"hello world, not a bag at all", bytes(range(256)) * 4])
def test_garbage_is_corrupt_bag_error(tmp_path, content):
    path = tmp_path / "garbage.mcap"
    path.write_bytes(content)
    with pytest.raises(CorruptBagError) as info:
        summary(path)
    assert isinstance(info.value, ValueError)
    assert "garbage.mcap" in str(info.value) and "\n" not in str(info.value)


def test_unknown_topic_lists_available_topics():
    raw = _bag([("/x", "std_msgs/msg/Float64", encode("std_msgs/msg/Float64", {"data": 1.0}), 0)])
    with pytest.raises(TopicNotFoundError) as info:
        read_topic(raw, "/joint_states")
    assert isinstance(info.value, KeyError)
    assert str(info.value) == "topic '/joint_states' not found in <bytes> (topics: /x)"


def test_directory_with_one_bag_is_accepted(tmp_path):
    (tmp_path / "run_0.mcap").write_bytes(
        _bag([("/x", "std_msgs/msg/Float64", encode("std_msgs/msg/Float64", {"data": 2.0}), 0)])
    )
    assert read_topic(tmp_path, "x").data.tolist() == [2.0]


def test_complete_file_gives_no_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_topic(_long_bag(), "/x").complete


def test_chunks_of_equal_size_messages_are_read_whole_and_as_record_by_record(monkeypatch):
    """A chunk of message records all of one size (a torque recording) is taken in array operations:
    the same times, payloads and values as the record walk, interleaved channels and a chunk of mixed
    sizes (walked) included; the fast path is taken for the uniform chunks."""
    from msg_tools import scan

    n = 3000
    values = RNG.normal(size=n)
    messages = []
    for k in range(n):  # two Float64 topics interleaved, one out of order; a String now and then (other size)
        messages.append(("/drive_torque", "std_msgs/msg/Float64", encode("std_msgs/msg/Float64", {"data": values[k]}), 1000 * k + 7))
        messages.append(("/other", "std_msgs/msg/Float64", encode("std_msgs/msg/Float64", {"data": -values[k]}), 1000 * k))
        if k == 2500:
            messages.append(("/note", "std_msgs/msg/String", encode("std_msgs/msg/String", {"data": "x"}), 1000 * k))
    messages[10], messages[12] = messages[12], messages[10]
    data = _bag(messages, chunk_size=4096)
    taken = []
    fast = scan.Scan._uniform_messages

    def spy(self, records):
        taken.append(fast(self, records))
        return taken[-1]

    monkeypatch.setattr(scan.Scan, "_uniform_messages", spy)
    whole = read_bag(data, ["/drive_torque", "/other", "/note"])
    assert sum(taken) >= 5 and not all(taken)  # uniform chunks whole, the chunk with the String walked
    monkeypatch.setattr(scan.Scan, "_uniform_messages", lambda self, records: False)
    walked = read_bag(data, ["/drive_torque", "/other", "/note"])
    for topic in ("/drive_torque", "/other"):
        a, b = whole.topics[topic], walked.topics[topic]
        assert np.array_equal(a.log_time_ns, b.log_time_ns) and np.array_equal(a.publish_time_ns, b.publish_time_ns)
        assert np.array_equal(_bits(a.data), _bits(b.data))
    assert np.array_equal(_bits(whole.topics["/drive_torque"].data), _bits(values))
    assert whole.topics["/note"].messages[0].data == "x"


def test_tf_of_one_layout_is_decoded_from_the_bytes_as_the_generic_decoder_names_it(tmp_path, monkeypatch):
    """Every recording's /tf was decoded message by message into objects (a 39 MB file: 2.3 GB and 40 s to
    compare). Messages of one layout are read straight from the bytes: the same fields, names and floats as the
    generic decoder's; a /tf whose layout varies still goes the generic way."""
    import numpy as np

    from belt_drive_ros.cli import main
    from msg_tools import decode, read_topic

    rec = tmp_path / "run.mcap"
    assert main(["sim", "paper", "--duration", "0.2", "--method", "etd4", "--out", str(rec)]) == 0
    fast = read_topic(rec, "/tf")
    assert fast.decoder == "vectorized" and len(fast.fields) == 4 * 7
    monkeypatch.setattr(decode, "_decode_tf_vectorized", lambda datas: None)
    slow = read_topic(rec, "/tf")
    assert slow.decoder == "mcap_ros2" and list(slow.fields) == list(fast.fields)
    for key in fast.fields:
        np.testing.assert_array_equal(fast.fields[key], slow.fields[key])

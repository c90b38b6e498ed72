"""Ros2McapWriter: rosbag2 conventions seen by the mcap library's own reader,
round trips, overwrite protection, write errors and crash safety (no ROS)."""

import errno
import io
import os
import signal
import struct
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from msg_tools import (
    MsgToolsError,
    OverwriteError,
    Ros2McapWriter,
    UnknownMessageTypeError,
    WriteError,
    read_topic,
    summary,
)
from msg_tools.writer import encode

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

JOINTS = ["crank", "alternator", "water_pump"]


def _joint_state(i, t_ns):
    return {
        "header": {"stamp": {"sec": t_ns // 10**9, "nanosec": t_ns % 10**9}, "frame_id": "base"},
        "name": JOINTS,
        "position": [0.1 * i, 0.2 * i, 0.3 * i],
        "velocity": [10.0 + i, 20.0, 30.0],
        "effort": [1.0, -2.0, 0.5 * i],
    }


def _write_sample(target, n=50, **kwargs):
    with Ros2McapWriter(target, **kwargs) as w:
        w.add_metadata("scene", {"name": "engine_idle", "k": "1000.0"})
        for i in range(n):
            t = 1_000_000_000 + i * 1_000_000
            w.write("/drive_torque", "std_msgs/msg/Float64", {"data": 0.5 * i}, t)
            w.write("/joint_states", "sensor_msgs/msg/JointState", _joint_state(i, t), t,
                    publish_time_ns=t - 100)
        w.write("/clock", "rosgraph_msgs/msg/Clock", {"clock": {"sec": 1}}, 1_000_000_000,
                qos="clock")
        w.write("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray",
                {"status": [{"level": 1, "name": "belt", "message": "slip"}]}, 1_000_000_000,
                qos="diagnostics")
    return w


def test_independent_reader_sees_ros2_conventions():
    buf = io.BytesIO()
    _write_sample(buf)
    reader = make_reader(io.BytesIO(buf.getvalue()), decoder_factories=[DecoderFactory()])
    header = reader.get_header()
    assert header.profile == "ros2"
    assert "msg_tools" in header.library
    s = reader.get_summary()
    assert s is not None, "summary section missing"
    assert s.statistics.message_count == 102
    assert {sc.encoding for sc in s.schemas.values()} == {"ros2msg"}
    assert {sc.name for sc in s.schemas.values()} == {
        "std_msgs/msg/Float64", "sensor_msgs/msg/JointState", "rosgraph_msgs/msg/Clock",
        "diagnostic_msgs/msg/DiagnosticArray",
    }
    assert len(s.channels) == 4
    for channel in s.channels.values():
        assert channel.message_encoding == "cdr"
        qos = yaml.safe_load(channel.metadata["offered_qos_profiles"])
        assert isinstance(qos, list) and qos[0]["history"] == "keep_last"
        assert channel.metadata["topic_type_hash"].startswith("RIHS01_")
    by_topic = {c.topic: c for c in s.channels.values()}
    assert yaml.safe_load(by_topic["/clock"].metadata["offered_qos_profiles"])[0][
        "reliability"] == "best_effort"
    assert s.chunk_indexes and {ci.compression for ci in s.chunk_indexes} == {"zstd"}

    records = {m.name: m.metadata for m in reader.iter_metadata()}
    assert records["scene"] == {"name": "engine_idle", "k": "1000.0"}
    bag = yaml.safe_load(records["rosbag2"]["serialized_metadata"])
    assert bag["version"] == 9 and bag["storage_identifier"] == "mcap"
    assert bag["ros_distro"] == "jazzy"
    assert bag["message_count"] == 102
    assert bag["starting_time"]["nanoseconds_since_epoch"] == 1_000_000_000
    assert bag["duration"]["nanoseconds"] == 49_000_000
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in bag["topics_with_message_count"]}
    assert counts == {"/drive_torque": 50, "/joint_states": 50, "/clock": 1, "/diagnostics": 1}
    for t in bag["topics_with_message_count"]:
        meta = t["topic_metadata"]
        assert meta["serialization_format"] == "cdr"
        assert isinstance(meta["offered_qos_profiles"], list)
        assert meta["type_description_hash"].startswith("RIHS01_")

    decoded = [(c.topic, m.log_time, m.publish_time, msg)
               for _, c, m, msg in reader.iter_decoded_messages(topics=["/joint_states"])]
    assert len(decoded) == 50
    topic, log_time, publish_time, msg = decoded[7]
    assert (log_time, publish_time) == (1_007_000_000, 1_006_999_900)
    assert list(msg.name) == JOINTS and msg.position[2] == pytest.approx(2.1)
    assert msg.header.stamp.sec == 1 and msg.header.stamp.nanosec == 7_000_000


def test_round_trip_file_and_bytesio_equal(tmp_path):
    path = tmp_path / "run.mcap"
    _write_sample(path)
    (tmp_path / "again").mkdir()
    _write_sample(tmp_path / "again" / "run.mcap")
    assert path.read_bytes() == (tmp_path / "again" / "run.mcap").read_bytes(), (
        "writer output is not deterministic"
    )
    buf = io.BytesIO()
    _write_sample(buf)
    for source in (path, str(path), buf.getvalue(), io.BytesIO(buf.getvalue())):
        torque = read_topic(source, "/drive_torque")
        np.testing.assert_array_equal(torque.data, 0.5 * np.arange(50))
        np.testing.assert_array_equal(torque.log_time_ns, 1_000_000_000 + 1_000_000 * np.arange(50))
        js = read_topic(source, "joint_states")
        assert js.names == JOINTS
        np.testing.assert_allclose(js.position[:, 1], 0.2 * np.arange(50), rtol=0, atol=0)
        np.testing.assert_array_equal(js.publish_time_ns, js.log_time_ns - 100)


def test_write_raw_keeps_bytes_exactly():
    # a payload with non-zero option bytes and trailing padding, as DDS may deliver
    payload = b"\x00\x01\xab\xcd" + struct.pack("<d", 2.5) + b"\x77\x02\x78\x03"
    buf = io.BytesIO()
    with Ros2McapWriter(buf) as w:
        w.write_raw("/drive_torque", "std_msgs/msg/Float64", payload, 5, publish_time_ns=3)
    (_, _, message), = list(make_reader(io.BytesIO(buf.getvalue())).iter_messages())
    assert message.data == payload
    assert (message.log_time, message.publish_time) == (5, 3)
    assert read_topic(buf.getvalue(), "/drive_torque").data.tolist() == [2.5]


def test_encode_matches_mcap_ros2_writer_bytes():
    from mcap_ros2.writer import Writer as Ros2Writer

    from msg_tools.schemas import schema_text

    buf = io.BytesIO()
    ros2 = Ros2Writer(buf)
    schema = ros2.register_msgdef("sensor_msgs/msg/JointState", schema_text("sensor_msgs/msg/JointState"))
    ros2.write_message("/js", schema, _joint_state(3, 10), log_time=10)
    ros2.finish()
    (_, _, reference), = list(make_reader(io.BytesIO(buf.getvalue())).iter_messages())
    assert encode("sensor_msgs/msg/JointState", _joint_state(3, 10)) == reference.data
    assert encode("std_msgs/msg/Float64", {"data": np.float64(1.5)}) == (
        b"\x00\x01\x00\x00" + struct.pack("<d", 1.5)
    )


def test_overwrite_refused_without_force(tmp_path):
    path = tmp_path / "run.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(OverwriteError) as info:
        Ros2McapWriter(path)
    assert isinstance(info.value, FileExistsError)
    assert str(path) in str(info.value) and "--force" in str(info.value)
    assert path.read_bytes() == b"precious"
    with Ros2McapWriter(path, force=True) as w:
        w.write("/x", "std_msgs/msg/Float64", {"data": 1.0}, 0)
    assert read_topic(path, "/x").data.tolist() == [1.0]


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
def test_disk_full_raises_write_error_then_stops():
    with pytest.raises(WriteError) as info:
        Ros2McapWriter("/dev/full", force=True)
    assert info.value.errno == errno.ENOSPC
    assert "/dev/full" in str(info.value) and "No space left" in str(info.value)
    assert isinstance(info.value, OSError) and "\n" not in str(info.value)


class _FillingDisk(io.BytesIO):
    """A stream that runs out of space after ``capacity`` bytes."""

    def __init__(self, capacity):
        super().__init__()
        self.capacity = capacity

    def write(self, data):
        if self.tell() + len(data) > self.capacity:
            raise OSError(errno.ENOSPC, "No space left on device")
        return super().write(data)


def test_write_error_mid_recording_is_reported_and_writer_stops():
    disk = _FillingDisk(capacity=20_000)
    w = Ros2McapWriter(disk, chunk_size=4096)
    with pytest.raises(WriteError) as info:
        for i in range(10_000):
            w.write("/x", "std_msgs/msg/Float64", {"data": float(i)}, i * 1_000_000)
    assert info.value.errno == errno.ENOSPC and w.failed
    assert str(info.value) == "cannot write <stream>: No space left on device"
    with pytest.raises(WriteError, match="earlier error"):
        w.write("/x", "std_msgs/msg/Float64", {"data": 0.0}, 0)
    w.finish()  # only closes; does not raise again
    # what reached the disk reads like a killed recording
    with pytest.warns(Warning, match="incomplete"):
        data = read_topic(disk.getvalue(), "/x")
    assert len(data) > 0
    np.testing.assert_array_equal(data.data, np.arange(len(data), dtype=float))


def test_missing_directory_is_write_error(tmp_path):
    with pytest.raises(WriteError) as info:
        Ros2McapWriter(tmp_path / "no" / "such" / "dir.mcap")
    assert info.value.errno == errno.ENOENT and "dir.mcap" in str(info.value)


def test_context_manager_finishes_on_exception(tmp_path):
    path = tmp_path / "run.mcap"
    with pytest.raises(RuntimeError, match="boom"):
        with Ros2McapWriter(path) as w:
            w.write("/x", "std_msgs/msg/Float64", {"data": 3.0}, 7)
            raise RuntimeError("boom")
    info = summary(path)
    assert info.complete and info.message_count == 1
    assert "rosbag2" in [name for name, _ in info.metadata]


def test_usage_errors_are_precise():
    w = Ros2McapWriter(io.BytesIO())
    w.write("/x", "std_msgs/msg/Float64", {"data": 1.0}, 0)
    with pytest.raises(MsgToolsError, match="/x already has type std_msgs/msg/Float64"):
        w.write("/x", "std_msgs/msg/String", {"data": "a"}, 1)
    with pytest.raises(UnknownMessageTypeError, match="foo_msgs/msg/Bar"):
        w.write_raw("/cmd", "foo_msgs/msg/Bar", b"\x00\x01\x00\x00", 0)
    with pytest.raises(ValueError, match="reserved"):
        w.add_metadata("rosbag2", {})
    with pytest.raises(TypeError, match="'k'"):
        w.add_metadata("scene", {"k": 1.0})
    with pytest.raises(ValueError, match="encapsulation"):
        w.write_raw("/x", "std_msgs/msg/Float64", b"\x00", 0)
    w.finish()
    with pytest.raises(MsgToolsError, match="finished"):
        w.write("/x", "std_msgs/msg/Float64", {"data": 1.0}, 0)


def test_register_custom_type():
    buf = io.BytesIO()
    with Ros2McapWriter(buf) as w:
        w.register_type("belt_msgs/msg/Span", "float64 tension\nfloat64 slip\n")
        w.write("/span", "belt_msgs/msg/Span", {"tension": 350.0, "slip": 0.01}, 0)
    data = read_topic(buf.getvalue(), "/span")
    assert data.decoder == "mcap_ros2"
    assert data.tension.tolist() == [350.0] and data.slip.tolist() == [0.01]


def test_chunks_close_every_flush_interval_of_log_time():
    buf = io.BytesIO()
    topics = [f"/t{k}" for k in range(6)]
    with Ros2McapWriter(buf, flush_interval_s=0.25, chunk_size=64 * 1024) as w:
        for i in range(2000):  # 2 s at 1 kHz on 6 topics
            for topic in topics:
                w.write("/" + topic.strip("/"), "std_msgs/msg/Float64", {"data": float(i)}, i * 1_000_000)
    indexes = make_reader(io.BytesIO(buf.getvalue())).get_summary().chunk_indexes
    spans = [(ci.message_end_time - ci.message_start_time) * 1e-9 for ci in indexes]
    assert len(indexes) >= 8
    assert max(spans) <= 0.25 + 1e-9


CHILD = textwrap.dedent(
    """
    import os, sys, time
    sys.path.insert(0, {repo!r})
    from msg_tools import Ros2McapWriter
    w = Ros2McapWriter({path!r}, flush_interval_s=0.25)
    i = 0
    while True:
        t = i * 1_000_000  # 1 kHz log time
        for k in range(6):
            w.write("/t%d" % k, "std_msgs/msg/Float64", {{"data": float(i)}}, t)
        i += 1
        if i == {stop}:
            os._exit(0)  # like SIGKILL: no finish(), Python buffers lost
        if i == 300:
            print("ready", flush=True)
    """
)


def test_killed_writer_loses_at_most_the_open_chunk(tmp_path):
    path = tmp_path / "killed.mcap"
    stop = 3000  # 3 s of 6 topics at 1 kHz
    subprocess.run([sys.executable, "-c", CHILD.format(repo=REPO, path=str(path), stop=stop)],
                   check=True, timeout=60)
    with pytest.warns(Warning, match="incomplete"):
        data = read_topic(path, "/t3")
    assert not data.complete
    # recovered a gap-free prefix, and lost at most 0.25 s (+1 sample) of data
    np.testing.assert_array_equal(data.data, np.arange(len(data), dtype=float))
    assert len(data) >= stop - 251, f"lost {stop - len(data)} of {stop} samples"


def test_sigkill_during_recording_leaves_readable_file(tmp_path):
    path = tmp_path / "sigkill.mcap"
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD.format(repo=REPO, path=str(path), stop=-1)],
        stdout=subprocess.PIPE, text=True,
    )
    try:
        assert child.stdout.readline().strip() == "ready"
        deadline = time.monotonic() + 20
        while os.path.getsize(path) < 60_000 and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=10)
    assert child.returncode == -signal.SIGKILL
    with pytest.warns(Warning, match=r"recovered \d+ messages"):
        info = summary(path)
    assert not info.complete and info.message_count > 0
    with pytest.warns(Warning):
        data = read_topic(path, "/t0")
    assert len(data) > 250
    np.testing.assert_array_equal(data.data, np.arange(len(data), dtype=float))

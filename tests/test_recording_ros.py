"""Live recording with ROS 2: NodeRecorder on a running node, and `belt-drive record` under signals.

The files are checked with the ``mcap`` library's own reader and
``mcap_ros2``'s decoder (not project code). rclpy leaves CDR padding
uninitialised, so JointState is compared by decoded values; Float64 has no
padding, so its recorded bytes must equal ``mcap_ros2``'s encoding.
"""

import contextlib
import errno
import io
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from msg_tools import RecoveredBagWarning, encode, read_topic, summary
from msg_tools.cli import main as msg_tools
from msg_tools.qos import parse_offered_qos_yaml

pytestmark = pytest.mark.ros

NODE_TOPICS = {"/drive_torque", "/drive_torque_applied", "/joint_states", "/shaft_speed", "/load_torque", "/belt_torque",
               "/relative_deflection", "/tf", "/diagnostics", "/clock"}
#: the slipping model's topics (truck_compressor runs on it: auto goes on to slipping)
SLIP_TOPICS = {"/span_force_tight", "/span_force_slack", "/friction_use", "/slip", "/slip_speed", "/elastic_deflection",
               "/slip_angle"}


def _spin_until(executor, predicate, timeout=10.0):
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        executor.spin_once(timeout_sec=0.005)


@pytest.fixture
def harness(ros_domain_id):
    from belt_drive_ros.ros.harness import BeltDriveHarness

    with BeltDriveHarness(scene="truck_compressor", domain_id=ros_domain_id) as h:
        yield h


def _drive(h, recorder, steps=150):
    """Lockstep: torque then 1 ms of /clock, ``steps`` times; wait until the recorder has everything."""
    _spin_until(h.executor, lambda: all(n >= 1 for n in recorder.publisher_counts().values()))
    before = h.node.counters["published"]
    for k in range(steps):
        h.publish_torque(20.0 + 10.0 * np.sin(k / 9.0))
        h.advance(0.001)
    published = h.node.counters["published"] - before
    _spin_until(h.executor, lambda: recorder.writer.topic_counts().get("/relative_deflection", 0) >= published)
    h.node.publish_diagnostics()
    _spin_until(h.executor, lambda: recorder.writer.topic_counts().get("/diagnostics", 0) >= 1)
    return published



@contextlib.contextmanager
def _recorder_and_torque_publisher(record_args, domain_id):
    """``belt-drive record --topics /drive_torque *record_args`` in a child process, and a reliable
    Float64 publisher on ``/drive_torque`` in a private rclpy context on the same domain: yields
    ``(proc, pub)``; the recorder is killed if still running and the context shut down on exit."""
    import rclpy
    from rclpy.context import Context
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64

    from belt_drive_ros.ros import environment as ros_env

    cmd = [os.path.join(os.path.dirname(sys.executable), "belt-drive"), "record", "--topics", "/drive_torque",
           *record_args]
    proc = subprocess.Popen(cmd, env=ros_env.child_environment(domain_id), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    try:
        node = rclpy.create_node("record_probe", context=ctx)
        yield proc, node.create_publisher(Float64, "/drive_torque",
                                          QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    finally:
        if proc.poll() is None:
            proc.kill()
        rclpy.try_shutdown(context=ctx)

def test_node_recording_is_rosbag2_mcap_written_from_the_tick(harness, tmp_path):
    from belt_drive_ros.io.torque_bag import scene_from_bag
    from belt_drive_ros.ros.recorder import NodeRecorder

    h = harness
    path = tmp_path / "node.mcap"
    recorder = NodeRecorder(h.node, path)
    h.node.recorder = recorder  # the node calls record_input/record_tick and close() on destroy
    published = _drive(h, recorder)
    recorder.close()
    assert not recorder.failed and recorder.status.startswith("closed")

    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header, info = reader.get_header(), reader.get_summary()
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        messages = list(reader.iter_decoded_messages())
    assert header.profile == "ros2"
    assert {s.encoding for s in info.schemas.values()} == {"ros2msg"}
    channels = {c.topic: c for c in info.channels.values()}
    assert h.node.settings.model.name == "slipping"
    assert set(channels) == NODE_TOPICS | SLIP_TOPICS
    for channel in channels.values():
        assert channel.message_encoding == "cdr"
        assert parse_offered_qos_yaml(channel.metadata["offered_qos_profiles"])
    (speed_qos,) = parse_offered_qos_yaml(channels["/shaft_speed"].metadata["offered_qos_profiles"])
    # what discovery tells about the node's publisher (history/depth are not in it, as in ros2 bag record)
    assert (speed_qos.reliability, speed_qos.durability) == ("reliable", "transient_local")  # OUTPUT_QOS offers
    assert "rosbag2" in metadata and "units" in metadata and "parameters" in metadata
    assert metadata["scene"]["source"] == "node" and metadata["scene"]["drive_source"] == "topic"
    assert yaml.safe_load(metadata["scene"]["yaml"])["drive"] == {
        "type": "recorded", "bag": "", "topic": "/drive_torque_applied", "interpolation": "previous"}
    assert metadata["parameters"]["use_sim_time"] == "true"

    by_topic = {}
    for _schema, channel, message, decoded in messages:
        by_topic.setdefault(channel.topic, []).append((message, decoded))
    assert len(by_topic["/joint_states"]) == published == len(by_topic["/drive_torque_applied"])
    assert len(by_topic["/drive_torque"]) == 150  # as received
    # Float64: the recorded bytes are exactly mcap_ros2's encoding of the decoded value
    for message, decoded in by_topic["/shaft_speed"] + by_topic["/drive_torque"] + by_topic["/drive_torque_applied"]:
        assert message.data == encode("std_msgs/msg/Float64", {"data": decoded.data})
    # decoded by mcap_ros2 == what the harness's own subscriber received
    out = {k: v[-published:] for k, v in h.outputs().items()}  # the ticks while recording
    speed = np.array([d.data for _m, d in by_topic["/shaft_speed"]])
    np.testing.assert_array_equal(speed, out["shaft_speed"])
    js = [d for _m, d in by_topic["/joint_states"]]
    assert list(js[0].name) == ["wheel_M", "wheel_1", "wheel_2", "wheel_3"]
    np.testing.assert_array_equal([j.velocity[0] for j in js], out["omega_M"])
    np.testing.assert_array_equal([j.effort[0] for j in js], out["drive_torque"])
    # log time = the tick time exactly (written from the tick, no DDS round trip); also the applied torque
    stamps = np.array([j.header.stamp.sec * 10**9 + j.header.stamp.nanosec for j in js])
    np.testing.assert_array_equal([m.log_time for m, _d in by_topic["/joint_states"]], stamps)
    np.testing.assert_array_equal([m.log_time for m, _d in by_topic["/drive_torque_applied"]], stamps)
    np.testing.assert_array_equal([d.data for _m, d in by_topic["/drive_torque_applied"]], out["drive_torque"])
    # msg_tools' vectorized reader agrees with mcap_ros2
    np.testing.assert_array_equal(read_topic(path, "/joint_states").velocity[:, 0], [j.velocity[0] for j in js])
    # self-describing: the scene comes back, driven by the recorded torque
    scene = scene_from_bag(path)
    assert scene.params == h.node.settings.params and scene.model == h.node.settings.model.name
    assert scene.drive.values.size == published


class _DiskFullAfter(io.BytesIO):
    """A file that takes ``limit`` bytes, then fails like a full disk."""

    def __init__(self, limit):
        super().__init__()
        self.limit = limit

    def write(self, b):
        if self.tell() + len(b) > self.limit:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return super().write(b)


def test_write_error_stops_recording_not_the_node(harness):
    from belt_drive_ros.ros.recorder import NodeRecorder

    h = harness
    recorder = NodeRecorder(h.node, _DiskFullAfter(16 * 1024), flush_interval_s=0.01, chunk_size=1024)
    h.node.recorder = recorder
    for k in range(200):
        h.publish_torque(10.0)
        h.advance(0.001)
        if recorder.failed:
            break
    assert recorder.failed
    assert recorder.error.errno == errno.ENOSPC
    assert "No space left on device" in recorder.status and recorder.status.startswith("FAILED")
    ticks = h.node.counters["published"]
    h.advance(0.05)  # the node keeps simulating and publishing
    assert h.node.counters["published"] == ticks + 50 and h.node.counters["divergences"] == 0
    recorder.close()  # no exception: the file keeps what it had up to its last complete chunk
    h.node.recorder = None


def test_existing_file_refused(harness, tmp_path):
    from belt_drive_ros.io.recording import BagExistsError
    from belt_drive_ros.ros.recorder import NodeRecorder

    path = tmp_path / "keep.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(BagExistsError, match="pass --force"):
        NodeRecorder(harness.node, path)
    assert path.read_bytes() == b"precious"
    assert harness.node.count_subscribers("/shaft_speed") == 1  # nothing left behind (the harness's probe)


def test_a_split_node_recording_takes_the_bag_folder_lock(harness, tmp_path):
    """A node recording split into a bag folder holds the folder's lock (as ``belt-drive sim --bag-folder`` and
    ``belt-drive record`` do) until it is closed: a second recorder into the folder is refused naming this pid,
    before it looks at the folder; the lock file goes with the close."""
    from belt_drive_ros.io.recording import BagWriteError
    from belt_drive_ros.ros.recorder import NodeRecorder

    folder, lock = tmp_path / "bag", tmp_path / ".bag.lock"
    first = NodeRecorder(harness.node, folder, max_bag_duration=1.0)
    try:
        assert lock.read_text() == f"{os.getpid()}\n"
        with pytest.raises(BagWriteError) as info:
            NodeRecorder(harness.node, folder, max_bag_duration=1.0, force=True)
        assert str(info.value).startswith(f"{folder}: another run (pid {os.getpid()}) is writing this bag folder")
    finally:
        first.close()
    assert (folder / "metadata.yaml").is_file() and not lock.exists()
    NodeRecorder(harness.node, folder, max_bag_duration=1.0, force=True).close()  # released: the next one writes


# ---------------------------------------------------------- belt-drive record
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL])
def test_record_command_under_signals(tmp_path, ros_domain_id, sig):
    import rclpy
    from rclpy.context import Context
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64

    from belt_drive_ros.ros import environment as ros_env

    path = tmp_path / "rec.mcap"
    env = ros_env.child_environment(ros_domain_id)  # UDP only: a killed child leaves no shared memory
    topics = [] if sig == signal.SIGINT else ["--topics", "/drive_torque"]  # SIGINT: discover all
    cmd = [os.path.join(os.path.dirname(sys.executable), "belt-drive"), "record", "--out", str(path), *topics]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain_id)
    sent = 0
    try:
        node = rclpy.create_node("record_probe", context=ctx)
        pub = node.create_publisher(Float64, "/drive_torque", QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        deadline = time.monotonic() + 20
        while pub.get_subscription_count() < 1:
            assert time.monotonic() < deadline and proc.poll() is None, proc.stderr.read() if proc.poll() else "no match"
            time.sleep(0.02)
        time.sleep(0.2)  # let the recorder's side of discovery complete too
        for _ in range(3):  # ~0.75 s at 400 Hz: several 0.25 s chunks are on disk
            for _ in range(100):
                pub.publish(Float64(data=float(sent)))
                sent += 1
                time.sleep(0.0025)
        while path.stat().st_size < 200 and time.monotonic() < deadline:  # a chunk was flushed
            time.sleep(0.05)
        time.sleep(0.3)
        shm = ros_env.shared_memory_of(proc.pid)
        proc.send_signal(sig)
        code = proc.wait(timeout=20)
        stderr = proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
        rclpy.try_shutdown(context=ctx)

    if sig == signal.SIGKILL:
        assert code == -signal.SIGKILL
        with pytest.warns(RecoveredBagWarning):
            data = read_topic(path, "/drive_torque")
        assert not data.complete
        assert 0 < len(data) <= sent
        np.testing.assert_array_equal(data.data, np.arange(len(data)))  # in order, none missing
        assert msg_tools(["info", str(path)]) == 1  # readable, reported INCOMPLETE (data lost: exit 1)
        # Fast DDS keeps using shared memory under ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (even with
        # FASTDDS_BUILTIN_TRANSPORTS=UDPv4): clean up what the killed recorder left behind
        orphans = ros_env.remove_orphan_segments(shm)
        assert orphans, "expected the killed recorder's own Fast DDS segment"
        left = orphans & set(os.listdir("/dev/shm"))
        assert not left, f"shared memory of the killed recorder still in /dev/shm: {sorted(left)}"
    else:
        assert code == 0, stderr
        assert "Traceback" not in stderr
        with open(path, "rb") as f:
            reader = make_reader(f)
            assert reader.get_summary() is not None  # finalized: summary section written
            assert any(m.name == "rosbag2" for m in reader.iter_metadata())
        data = read_topic(path, "/drive_torque")
        assert data.complete
        np.testing.assert_array_equal(data.data, np.arange(sent))  # lossless
        assert summary(path).topics[0].offered_qos_profiles  # the probe's publisher QoS


def test_record_command_refuses_to_overwrite(tmp_path, capsys):
    from belt_drive_ros.cli import main

    path = tmp_path / "keep.mcap"
    path.write_bytes(b"precious")
    assert main(["record", "--out", str(path), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{path} exists; pass --force to overwrite it" in err[0]
    assert path.read_bytes() == b"precious"


def test_record_command_splits_into_a_bag_folder(tmp_path, ros_domain_id, capsys):
    """``belt-drive record --max-bag-duration`` writes NAME/NAME_i.mcap + metadata.yaml, losslessly;
    a split onto a ``.mcap`` name or a negative limit is refused in one line (exit 2)."""
    import yaml
    from std_msgs.msg import Float64

    from belt_drive_ros.cli import main

    for argv, what in ((["--out", str(tmp_path / "x.mcap"), "--max-bag-duration", "1"], "--out: "),
                       (["--out", str(tmp_path / "x"), "--max-bag-size", "-5"], "--max-bag-size: must be >= 0"),
                       (["--out", str(tmp_path / "x"), "--max-bag-duration", "nan"], "--max-bag-duration: must be")):
        assert main(["record", *argv, "--duration", "0.1"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("belt-drive: error: " + what), err
    assert not (tmp_path / "x").exists() and not (tmp_path / "x.mcap").exists()

    folder = tmp_path / "rec"
    sent = 0
    with _recorder_and_torque_publisher(["--out", str(folder), "--max-bag-duration", "0.2"], ros_domain_id) as (proc, pub):
        deadline = time.monotonic() + 20
        while pub.get_subscription_count() < 1:
            assert time.monotonic() < deadline and proc.poll() is None, proc.stderr.read() if proc.poll() else "no match"
            time.sleep(0.02)
        time.sleep(0.2)
        # a second recorder into the folder is refused as a second sim --bag-folder is: exit 1, the holder named
        assert main(["record", "--out", str(folder), "--max-bag-duration", "0.2", "--force", "--duration", "0.1"]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"belt-drive: error: --out {folder}: another run (pid {proc.pid}) "
                                                   "is writing this bag folder"), err
        for _ in range(300):  # ~0.75 s at 400 Hz: about four 0.2 s files
            pub.publish(Float64(data=float(sent)))
            sent += 1
            time.sleep(0.0025)
        time.sleep(0.3)
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=20)
        stderr = proc.stderr.read()
    assert code == 0 and "Traceback" not in stderr, stderr
    assert not (tmp_path / ".rec.lock").exists()  # the lock's file goes with the recorder
    meta = yaml.safe_load((folder / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert len(meta["relative_file_paths"]) >= 3 and meta["message_count"] == sent
    data = read_topic(folder, "/drive_torque")
    np.testing.assert_array_equal(data.data, np.arange(sent))  # every message once, in order, across the files
    assert msg_tools(["info", str(folder)]) == 0


def test_record_duration_ends_by_itself_with_exit_0(tmp_path, ros_domain_id):
    """``belt-drive record --duration S`` is a normal end: the file is finished, exit 0 (not 1)."""
    from std_msgs.msg import Float64

    from msg_tools import read_topic

    path = tmp_path / "timed.mcap"
    sent = 0
    # 8 s: long enough for discovery on a loaded machine
    with _recorder_and_torque_publisher(["--out", str(path), "--duration", "8"], ros_domain_id) as (proc, pub):
        deadline = time.monotonic() + 60
        while proc.poll() is None:  # publish until the recorder stops by itself
            assert time.monotonic() < deadline, "belt-drive record --duration 8 did not end"
            pub.publish(Float64(data=float(sent)))
            sent += 1
            time.sleep(0.005)
        code = proc.wait(timeout=20)
        out, err = proc.stdout.read(), proc.stderr.read()
    assert code == 0, err
    assert "Traceback" not in err and out.startswith(f"wrote {path}: ")
    data = read_topic(path, "/drive_torque").data  # a finished file with what arrived
    assert data.size > 0 and np.all(np.diff(data) > 0)

"""Offline recording (write_result_mcap, scene metadata) read back by independent tools; no ROS needed.

The independent reader is the ``mcap`` library's own (``make_reader``) with
``mcap_ros2``'s decoder, not msg_tools.
"""

import io
import os
import subprocess
import sys

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from belt_drive_ros.cli import main as belt_drive
from belt_drive_ros.io.recording import (
    JOINT_NAMES,
    TOPIC_TYPES,
    BagExistsError,
    BagReadError,
    BagWriteError,
    encode_float64,
    encode_joint_states,
    write_result_mcap,
)
from belt_drive_ros.io.torque_bag import scene_from_bag, scene_with_torque_bag
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.core.simulate import simulate
from belt_drive_ros.io.urdf import urdf_from_params
from msg_tools import encode, read_bag, read_topic
from msg_tools.cli import main as msg_tools
from msg_tools.qos import parse_offered_qos_yaml

OUTPUT_TOPICS = ["/drive_torque", "/joint_states", "/tf", "/shaft_speed", "/load_torque", "/belt_torque",
                 "/relative_deflection"]


@pytest.fixture(scope="module")
def run():
    """A short flexible run with a closed-loop drive (0.3 s, 1 kHz output)."""
    return simulate(load_scene("truck_compressor").with_overrides(duration=0.3))


@pytest.fixture(scope="module")
def bag(run, tmp_path_factory):
    path = tmp_path_factory.mktemp("offline") / "run.mcap"
    write_result_mcap(run, path, start_time_ns=0)  # times = simulated time (default: wall time, tested below)
    return path


def _independent(path):
    """Everything the mcap library sees: header, summary, metadata, decoded messages."""
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        summary = reader.get_summary()
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        messages = [(ch.topic, msg.log_time, msg.publish_time, msg.data, decoded)
                    for _schema, ch, msg, decoded in reader.iter_decoded_messages()]
    return header, summary, metadata, messages


def test_independent_reader_sees_rosbag2_layout(bag, run):
    header, summary, metadata, messages = _independent(bag)
    assert header.profile == "ros2"
    assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    assert {s.name for s in summary.schemas.values()} == {"std_msgs/msg/Float64", "sensor_msgs/msg/JointState",
                                                           "std_msgs/msg/String", "tf2_msgs/msg/TFMessage"}
    channels = {c.topic: c for c in summary.channels.values()}
    assert sorted(channels) == sorted(OUTPUT_TOPICS + ["/robot_description"])
    for topic, channel in channels.items():
        assert channel.message_encoding == "cdr"
        (qos,) = parse_offered_qos_yaml(channel.metadata["offered_qos_profiles"])
        assert qos.reliability == "reliable" and qos.history == "keep_last"
        # the URDF is latched as robot_state_publisher latches it; the signals are volatile
        assert (qos.durability, qos.depth) == (("transient_local", 1) if topic == "/robot_description" else ("volatile", 10))
    assert {ci.compression for ci in summary.chunk_indexes} == {"zstd"}
    stride = round(1.0 / (run.scene.output_rate * run.dt))  # steps per output sample
    n = (run.time.size - 1) // stride + 1
    assert summary.statistics.message_count == len(OUTPUT_TOPICS) * n + 1  # and one robot_description
    # rosbag2 metadata: what `ros2 bag info` shows
    bag_meta = yaml.safe_load(metadata["rosbag2"]["serialized_metadata"])
    assert bag_meta["version"] == 9 and bag_meta["storage_identifier"] == "mcap"
    assert bag_meta["message_count"] == len(OUTPUT_TOPICS) * n + 1
    assert {t["topic_metadata"]["name"] for t in bag_meta["topics_with_message_count"]} == set(OUTPUT_TOPICS) | {
        "/robot_description"}
    # self-describing: scene, parameters, units
    scene = metadata["scene"]
    assert scene["source"] == "offline" and scene["model"] == run.model == "flexible"
    assert scene["method"] == run.method and float(scene["dt"]) == run.dt
    stored = yaml.safe_load(scene["yaml"])
    assert stored["params"] == run.scene.params.to_dict() and stored["drive"]["type"] == "engine"
    assert float(metadata["parameters"]["k"]) == run.scene.params.k
    assert metadata["units"]["/shaft_speed"] == "rad/s" and metadata["units"]["/drive_torque"] == "N*m"
    # messages: sim time, decoded values = the run's outputs, node layout of JointState
    speed = [(log, pub, m.data) for topic, log, pub, _raw, m in messages if topic == "/shaft_speed"]
    times = np.array([s[0] for s in speed])
    np.testing.assert_array_equal(times, np.arange(n) * 1_000_000)
    assert all(log == pub for log, pub, _ in speed)
    np.testing.assert_array_equal([s[2] for s in speed], run.outputs["omega_M"][::stride])
    js = [m for topic, _l, _p, _r, m in messages if topic == "/joint_states"]
    assert list(js[7].name) == list(JOINT_NAMES)
    assert js[7].header.stamp.nanosec == 7_000_000
    o = {k: v[::stride][7] for k, v in run.outputs.items()}
    assert list(js[7].position) == [o["phi_M"], o["phi_1"], o["phi_2"], o["phi_3"]]
    assert list(js[7].velocity) == [o["omega_M"], o["omega_1"], o["omega_2"], o["omega_3"]]
    assert list(js[7].effort) == [o["drive_torque"], 0.0, 0.0, -o["load_torque"]]
    # the drive's URDF first (at the start time), then the node's order at each time: drive_torque,
    # joint_states, /tf, then the Float64 outputs
    assert [topic for topic, *_ in messages[:8]] == ["/robot_description"] + OUTPUT_TOPICS
    assert messages[0][1] == 0 and messages[0][4].data == urdf_from_params(run.scene.params)


def test_same_run_gives_byte_identical_file(run, tmp_path):
    paths = [tmp_path / d / "golden.mcap" for d in ("a", "b")]
    for path in paths:
        path.parent.mkdir()
        write_result_mcap(run, path, start_time_ns=1_767_225_600_000_000_000)
    assert paths[0].read_bytes() == paths[1].read_bytes()


def test_offline_run_is_stamped_with_the_wall_time_of_the_run_by_default(run, tmp_path):
    import time

    before = time.time_ns()
    write_result_mcap(run, tmp_path / "now.mcap")
    after = time.time_ns()
    data = read_topic(tmp_path / "now.mcap", "/joint_states")
    assert before <= data.log_time_ns[0] <= after
    np.testing.assert_array_equal(data.stamp_ns, data.log_time_ns)  # header stamps follow
    write_result_mcap(run, tmp_path / "zero.mcap", start_time_ns=0)
    zero = read_topic(tmp_path / "zero.mcap", "/joint_states")
    assert zero.log_time_ns[0] == round(run.time[0] * 1e9)
    # the same sample times, shifted by the start
    np.testing.assert_array_equal(data.log_time_ns - zero.log_time_ns, data.log_time_ns[0] - zero.log_time_ns[0])


def test_offline_run_in_rosbag2_folder_layout_split_by_duration(run, tmp_path):
    """NAME/NAME_k.mcap + metadata.yaml as rosbag2 Jazzy writes it: rosbags reads it, msg-tools too."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    from msg_tools.bagdir import bag_files
    from msg_tools.cli import main as msg_tools_main

    folder = tmp_path / "run"
    single = tmp_path / "single.mcap"
    start = 1_767_225_600_000_000_000
    write_result_mcap(run, single, start_time_ns=start)
    counts = write_result_mcap(run, folder, start_time_ns=start, max_bag_duration=0.1)
    files = bag_files(folder)
    assert len(files) >= 3 and [os.path.basename(f) for f in files] == [f"run_{k}.mcap" for k in range(len(files))]
    assert (folder / "metadata.yaml").is_file()
    whole = read_bag(single)
    split = read_bag(folder)
    for topic, data in whole.topics.items():
        if topic == "/robot_description":  # latched: repeated at the start of every file
            from msg_tools import summary

            starts = [summary(f).start_ns for f in files]
            np.testing.assert_array_equal(split.topics[topic].log_time_ns, starts)
            continue
        np.testing.assert_array_equal(split.topics[topic].log_time_ns, data.log_time_ns)
        for key, values in data.fields.items():
            np.testing.assert_array_equal(split.topics[topic].fields[key], values)
    store = get_typestore(Stores.ROS2_JAZZY)
    expected = {t: len(files) if t == "/robot_description" else len(d) for t, d in whole.topics.items()}
    with Reader(folder) as reader:
        assert reader.message_count == sum(counts.values()) == sum(expected.values())
        assert {c.topic: c.msgcount for c in reader.connections} == expected == counts
        assert reader.start_time == start + round(run.time[0] * 1e9)
        speeds = [store.deserialize_cdr(raw, c.msgtype).data for c, _t, raw in reader.messages()
                  if c.topic == "/shaft_speed"]
    np.testing.assert_array_equal(speeds, whole.topics["/shaft_speed"].data)
    for verb in (["info", str(folder)], ["export", str(folder), "--topic", "/shaft_speed", "--out", str(tmp_path / "s.csv")],
                 ["compare", str(folder), str(single)]):
        assert msg_tools_main(verb) == 0, verb


def test_fast_encoders_equal_mcap_ros2_encoding():
    rng = np.random.default_rng(3)
    values = np.concatenate([[0.0, -0.0, np.inf, -np.inf, 1e-310, np.pi * 1e12], rng.normal(size=50)])
    assert encode_float64(values) == [encode("std_msgs/msg/Float64", {"data": v}) for v in values]
    n = 40
    stamps = np.sort(rng.integers(0, 4 * 10**9, size=n))
    pos, vel, eff = (rng.normal(scale=100, size=(n, 4)) for _ in range(3))
    fast = encode_joint_states(stamps, pos, vel, eff)
    for k in range(n):
        ref = encode("sensor_msgs/msg/JointState", {
            "header": {"stamp": {"sec": int(stamps[k] // 10**9), "nanosec": int(stamps[k] % 10**9)}, "frame_id": ""},
            "name": list(JOINT_NAMES), "position": pos[k], "velocity": vel[k], "effort": eff[k],
        })
        assert fast[k] == ref


def test_joint_state_encoder_matches_the_batch_encoder_and_reads_back_in_rclpy():
    """The node publishes these bytes as its joint_states (rclpy's publish of a serialized message):
    they must be the batch encoder's and what rclpy deserializes to the same message."""
    from rclpy import serialization
    from sensor_msgs.msg import JointState

    from belt_drive_ros.io.recording import JointStateEncoder

    rng = np.random.default_rng(3)
    encoder = JointStateEncoder(len(JOINT_NAMES))
    for stamp in (0, 1, 999_999_999, 1_763_916_000_123_456_789):
        values = rng.normal(scale=100, size=12).tolist()
        data = encoder.encode(stamp, values)
        assert data == encode_joint_states([stamp], *(np.array(values[k:k + 4])[None, :] for k in (0, 4, 8)))[0]
        msg = serialization.deserialize_message(data, JointState)
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == divmod(stamp, 10**9)
        assert msg.header.frame_id == "" and list(msg.name) == list(JOINT_NAMES)
        assert list(msg.position) + list(msg.velocity) + list(msg.effort) == values


def test_joint_names_and_topics_match_the_node():
    node = pytest.importorskip("belt_drive_ros.ros.node")
    assert tuple(node.JOINT_NAMES) == JOINT_NAMES
    assert set(node.OUTPUT_TOPICS) < set(TOPIC_TYPES)


def test_scene_round_trips_through_the_bag(bag, run):
    scene = scene_from_bag(bag)
    assert scene == run.scene.with_overrides(model="flexible")
    assert simulate(scene).outputs["omega_M"].tolist() == run.outputs["omega_M"].tolist()


def test_torque_bag_reference_resolves_and_is_checked(bag, run, tmp_path):
    replayed = simulate(scene_with_torque_bag(run.scene, bag))
    out = tmp_path / "replayed.mcap"
    write_result_mcap(replayed, out)
    meta = yaml.safe_load(_independent(out)[2]["scene"]["yaml"])
    assert meta["drive"]["type"] == "recorded" and meta["drive"]["bag"] == "run.mcap"
    assert meta["drive"]["samples"] == 301 and "times" not in meta["drive"]  # a reference, not the samples
    with pytest.raises(BagReadError, match="not next to it"):
        scene_from_bag(out)  # run.mcap lives in another folder
    scene = scene_from_bag(out, torque_bag=bag)
    assert scene.drive == replayed.scene.drive and scene.duration == pytest.approx(0.3)
    (tmp_path / "run.mcap").write_bytes(bag.read_bytes()[:-10] + b"0123456789")
    with pytest.raises(BagReadError, match="sha256 differs"):
        scene_from_bag(out)


def test_existing_file_is_never_replaced_without_force(run, tmp_path):
    path = tmp_path / "keep.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(BagExistsError, match="pass --force") as info:
        write_result_mcap(run, path)
    assert isinstance(info.value, FileExistsError)
    assert path.read_bytes() == b"precious"
    write_result_mcap(run, path, force=True)
    assert read_topic(path, "/shaft_speed").complete


def test_write_error_is_one_clear_line(run, tmp_path):
    with pytest.raises(BagWriteError) as info:
        write_result_mcap(run, tmp_path / "missing_dir" / "x.mcap")
    assert "missing_dir" in str(info.value) and "\n" not in str(info.value)

    class FullDisk(io.BytesIO):
        """Takes the first 4 KiB, then the disk is full."""

        def write(self, b):
            if self.tell() + len(b) > 4096:
                raise OSError(28, "No space left on device")
            return super().write(b)

    with pytest.raises(BagWriteError, match="No space left on device") as info:
        write_result_mcap(run, FullDisk())
    assert info.value.errno == 28


# ------------------------------------------------- bad files at the command line
def _corrupt(tmp_path, good):
    data = good.read_bytes()
    files = {
        "garbage": b"this is not an MCAP file at all" * 10,
        "empty": b"",
        "magic_only": data[:8],
        "cut_in_header": data[:20],
    }
    out = {}
    for name, blob in files.items():
        out[name] = tmp_path / f"{name}.mcap"
        out[name].write_bytes(blob)
    return out


def test_corrupt_and_truncated_files_one_line_error_in_process(bag, tmp_path, capsys):
    for name, path in _corrupt(tmp_path, bag).items():
        assert belt_drive(["sim", "paper", "--torque-bag", str(path), "--quiet"]) == 2, name
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("belt-drive: error: ") and str(path) in err[0], (name, err)
        code = msg_tools(["info", str(path)])
        err = capsys.readouterr().err.strip().splitlines()
        if name in ("garbage", "empty"):
            assert code == 2 and len(err) == 1 and err[0].startswith("msg-tools: error: "), (name, err)
        else:  # a valid start, cut off: reported as an incomplete bag with 0 messages
            assert code == 1 and len(err) == 1 and err[0].startswith("msg-tools: warning: "), (name, err)


def test_file_cut_mid_data_reads_up_to_last_chunk(bag, tmp_path, capsys):
    data = bag.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.warns(UserWarning, match="last complete chunk"):
        scene = scene_with_torque_bag(load_scene("truck_compressor"), cut)
    assert 0.0 < scene.duration < 0.3
    assert msg_tools(["info", str(cut)]) == 1  # readable, reported INCOMPLETE: data lost
    assert "INCOMPLETE" in capsys.readouterr().out


def test_no_traceback_from_the_console_scripts(bag, tmp_path):
    """The installed entry points (as a user runs them) print one line and exit 2."""
    garbage = _corrupt(tmp_path, bag)["garbage"]
    bindir = os.path.dirname(sys.executable)
    for cmd in (
        [os.path.join(bindir, "belt-drive"), "sim", "paper", "--torque-bag", str(garbage), "--quiet"],
        [os.path.join(bindir, "msg-tools"), "compare", str(garbage), str(bag)],
    ):
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2, (cmd, proc.stderr)
        assert len(lines) == 1 and "Traceback" not in proc.stderr and "error:" in lines[0], proc.stderr


@pytest.mark.parametrize("dt, rate, note", [
    (0.005, 150.0, True),    # 200 Hz steps: 150 Hz is no whole number of steps -> every step, said
    (0.005, 100.0, False),   # every second step
    (0.005, 200.0, False),   # every step
    (0.005, 1000.0, False),  # above the step rate: every step by design
    (5e-4, 333.0, True),
])  # fmt: skip
def test_an_output_rate_that_is_no_whole_number_of_steps_is_said(dt, rate, note, tmp_path, capsys):
    """The message rate falls back to every step where the step rate divided by a whole number is not it: `sim`
    says so in one line when it writes an MCAP (before: the file's topics at 200 Hz, nothing said)."""
    from belt_drive_ros.io.recording import output_rate_note

    line = output_rate_note(dt, rate)
    assert bool(line) == note
    if note:
        assert line == (f"note: output_rate {rate:g} Hz is not the step rate {1 / dt:g} Hz divided by a whole number: "
                        f"the recording has a message at every step ({1 / dt:g} Hz)")
        scene = tmp_path / "s.yaml"
        data = load_scene("paper").to_dict()
        data.update(duration=0.2, dt=dt, output_rate=rate)
        scene.write_text(yaml.safe_dump(data))
        assert belt_drive(["sim", str(scene), "--quiet", "--out", str(tmp_path / "s.mcap")]) == 0
        assert line in capsys.readouterr().out

"""The node records itself when given ``record_path`` (issue 4 wired into issue 3's node).

Checked with the independent ``mcap`` reader (not project code) and against
the outputs the harness received; a runtime change of ``record_path`` is
rejected with a reason, and an existing file is never overwritten.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from mcap.reader import make_reader

from msg_tools import read_topic

from belt_drive_ros.io.recording import SLIP_FLOAT_OUTPUTS

pytestmark = pytest.mark.ros


def test_node_records_its_run_when_given_record_path(tmp_path, ros_domain_id):
    from belt_drive_ros.ros.harness import BeltDriveHarness

    bag = tmp_path / "run.mcap"
    with BeltDriveHarness(scene="paper", model="flexible", method="exact", domain_id=ros_domain_id,
                          record_path=str(bag)) as h:  # fmt: skip
        h.publish_torque(6.0)
        h.advance(0.2)
        rejected = h.set_parameters(record_path=str(tmp_path / "elsewhere.mcap"))
        assert not rejected.successful and "record_path" in rejected.reason
        h.advance(0.1)
        out = h.outputs()
        recording = h.diagnostics()["simulation"]["values"]["recording"]
        assert "recording" in recording and str(bag) in recording
    # finalized on close: an independent reader sees a complete ros2 bag with a summary
    with open(bag, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count > 0
        topics = {c.topic for c in summary.channels.values()}
        assert {"/shaft_speed", "/relative_deflection", "/joint_states", "/drive_torque"} <= topics
        assert all("offered_qos_profiles" in c.metadata for c in summary.channels.values())
        names = {m.name for m in reader.iter_metadata()}
        assert "rosbag2" in names
    # what was recorded is what the harness received (decoded values, not bytes: CDR padding)
    speed = read_topic(bag, "/shaft_speed").data
    n = min(speed.size, out["shaft_speed"].size)
    assert n > 250
    np.testing.assert_array_equal(speed[-n:], out["shaft_speed"][-n:])
    assert np.all(np.isfinite(speed))


def test_existing_record_path_refuses_the_start_unless_overwrite_is_set(tmp_path, ros_domain_id):
    """Asked to record onto an existing file, the node does not start (it never runs unrecorded);
    ``record_overwrite`` (``belt-drive node --force``) replaces the file."""
    from belt_drive_ros.ros.harness import BeltDriveHarness
    from belt_drive_ros.ros.parameter_schema import NodeConfigError

    bag = tmp_path / "keep.mcap"
    bag.write_bytes(b"precious")
    with pytest.raises(NodeConfigError) as info:
        with BeltDriveHarness(scene="paper", domain_id=ros_domain_id, record_path=str(bag)):
            pass
    assert str(info.value) == f"record_path: {bag} exists; set record_overwrite:=true to overwrite it"
    assert bag.read_bytes() == b"precious"
    with pytest.raises(NodeConfigError, match="record_path: .*"):  # cannot be created: refused as well
        with BeltDriveHarness(scene="paper", domain_id=ros_domain_id, record_path=str(tmp_path / "no" / "x.mcap")):
            pass
    with BeltDriveHarness(scene="paper", domain_id=ros_domain_id, record_path=str(bag), record_overwrite=True,
                          input_timeout=0.0) as h:
        h.advance(0.01)
        assert "recording" in h.diagnostics()["simulation"]["values"]["recording"]
        rejected = h.set_parameters(record_overwrite=False)
        assert not rejected.successful and rejected.reason == "Trying to set a read-only parameter: record_overwrite."
    assert read_topic(bag, "/shaft_speed").data.size == 11


def test_split_recording_is_a_rosbag2_folder_every_verb_reads(tmp_path, ros_domain_id):
    """max_bag_duration splits into NAME/NAME_i.mcap + metadata.yaml; the folder holds every tick
    once, msg-tools info/export/compare read it without damage warnings, and it re-simulates
    bit for bit."""
    import io
    import yaml
    from contextlib import redirect_stderr, redirect_stdout

    from msg_tools import cli as msg_cli

    from belt_drive_ros.core.simulate import simulate
    from belt_drive_ros.io.torque_bag import scene_from_bag
    from belt_drive_ros.ros.harness import BeltDriveHarness
    from belt_drive_ros.ros.parameter_schema import NodeConfigError

    with pytest.raises(NodeConfigError, match="record_path: .*bag folder"):
        with BeltDriveHarness(domain_id=ros_domain_id, record_path=str(tmp_path / "x.mcap"), max_bag_duration=1.0):
            pass
    folder = tmp_path / "run"
    with BeltDriveHarness(scene="paper", domain_id=ros_domain_id, record_path=str(folder), max_bag_duration=0.05,
                          input_timeout=0.0) as h:
        for value in (6.0, 12.0, -3.0):
            h.publish_torque(value)
            h.advance(0.1)
        out = h.outputs()
        substeps = h.node.settings.substeps
    files = sorted(p.name for p in folder.iterdir())
    assert "metadata.yaml" in files
    meta = yaml.safe_load((folder / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["relative_file_paths"] == [f"run_{i}.mcap" for i in range(len(meta["relative_file_paths"]))]
    assert 5 <= len(meta["relative_file_paths"]) <= 8  # 0.3 s in 0.05 s files
    assert set(files) == set(meta["relative_file_paths"]) | {"metadata.yaml"}
    speed = read_topic(folder, "/shaft_speed")
    assert speed.data.size == out["shaft_speed"].size == 301 and np.all(np.diff(speed.log_time_ns) > 0)
    np.testing.assert_array_equal(speed.data, out["shaft_speed"])
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    assert counts["/shaft_speed"] == 301 and counts["/drive_torque_applied"] == 301
    for argv in (["info", str(folder)], ["export", str(folder), "--topic", "/shaft_speed", "-o", str(tmp_path / "s.csv")],
                 ["compare", str(folder), str(folder)],
                 ["plot", str(folder), "--topics", "/shaft_speed", "--out", str(tmp_path / "s.png")]):
        stdout, stderr = io.StringIO(), io.StringIO()
        with redirect_stdout(stdout), redirect_stderr(stderr):
            code = msg_cli.main(argv)
        assert code == 0, (argv, stdout.getvalue(), stderr.getvalue())
        assert "damage" not in stderr.getvalue().lower() and "warning" not in stderr.getvalue().lower(), argv
    assert (tmp_path / "s.csv").read_text().count("\n") == 302  # header + every tick across the files
    assert (tmp_path / "s.png").read_bytes()[:4] == b"\x89PNG"
    result = simulate(scene_from_bag(folder))
    o = np.asarray(result.outputs["omega_M"])[::substeps]
    assert np.array_equal(speed.data, o[: speed.data.size]) and o.size == speed.data.size
    check_split_folder(folder, "/robot_description")


def check_split_folder(folder, latched, printed_total=None, first_at_start=True):
    """A split bag folder as the mcap library and rosbags read it: every file starts with ``latched``
    (one message, at the file's first log time; in the first file anywhere unless ``first_at_start``), and ``metadata.yaml`` states exactly what they hold
    (per file, per topic, in total; ``printed_total`` too when given)."""
    import collections

    import yaml
    from rosbags.rosbag2 import Reader

    meta = yaml.safe_load((folder / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    per_topic = collections.Counter()
    assert len(meta["files"]) >= 2
    for k, entry in enumerate(meta["files"]):
        with open(folder / entry["path"], "rb") as f:
            messages = [(c.topic, m.log_time) for _, c, m in make_reader(f).iter_messages(log_time_order=True)]
        start = entry["starting_time"]["nanoseconds_since_epoch"]
        times = [t for topic, t in messages if topic == latched]
        assert messages[0][1] == start and len(times) == 1, entry["path"]
        if k or first_at_start:  # (a recorder's first file has it when DDS delivers it)
            assert times == [start], entry["path"]
        assert len(messages) == entry["message_count"], entry["path"]
        per_topic.update(topic for topic, _ in messages)
    stated = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    assert stated == dict(per_topic) and meta["message_count"] == sum(per_topic.values())
    with Reader(folder) as reader:  # rosbags: from metadata.yaml, and message by message
        assert reader.message_count == meta["message_count"]
        assert {c.topic: c.msgcount for c in reader.connections} == stated
        assert sum(1 for _ in reader.messages()) == meta["message_count"]
    if printed_total is not None:
        assert printed_total == meta["message_count"]


# ------------------------------------------------------------ exact replay
#: per case: node parameters and the torque sequence [(value, ticks to advance after it)]
REPLAY_CASES = {
    "plain": ({}, [(6.0, 40), (12.0, 37), (-3.0, 23)]),
    "nonfinite_rejected": ({}, [(6.0, 30), (float("nan"), 20), (9.0, 10), (float("inf"), 25), (-2.0, 15)]),
    "clamped": ({"torque_limit": 5.0}, [(3.0, 20), (100.0, 30), (-7.5, 30), (4.0, 20)]),
    "beyond_bound_rejected": ({}, [(6.0, 20), (1e9, 30), (-4.0, 20)]),
    "timeout_zero": ({"input_timeout": 0.02, "timeout_behavior": "zero"}, [(8.0, 50), (3.0, 60)]),
    "timeout_hold": ({"input_timeout": 0.02, "timeout_behavior": "hold"}, [(8.0, 50), (3.0, 60)]),
    # a belt at a tenth of its preload (Q_max ~ 68 N) and +/-300 N m at the motor: stick-slip events inside ticks
    "slips": ({"F_0": 53.5}, [(6.0, 20), (300.0, 30), (-300.0, 30), (6.0, 30)]),
}


@pytest.mark.parametrize("case", sorted(REPLAY_CASES))
def test_recording_resimulates_to_the_recorded_outputs_bit_for_bit(tmp_path, ros_domain_id, case):
    """scene_from_bag + simulate() of a node recording gives every recorded output exactly.

    The node records the torque it applied at each tick (after NaN
    rejection, the bound, the limit and the input timeout) on
    ``/drive_torque_applied``; the scene metadata points the re-simulation
    at it. The raw ``/drive_torque`` keeps what was received.
    """
    from belt_drive_ros.core.simulate import simulate
    from belt_drive_ros.io.torque_bag import scene_from_bag
    from belt_drive_ros.ros.harness import BeltDriveHarness

    params, sequence = REPLAY_CASES[case]
    params = {"input_timeout": 0.0, **params}
    bag = tmp_path / f"{case}.mcap"
    with BeltDriveHarness(scene="truck_compressor", domain_id=ros_domain_id, record_path=str(bag), **params) as h:
        for value, ticks in sequence:
            h.publish_torque(value)
            h.advance(ticks * 0.001)
        substeps = h.node.settings.substeps
        counters = dict(h.node.counters)
    if case == "nonfinite_rejected":
        assert counters["rejected_nonfinite"] == 2
    elif case == "clamped":
        assert counters["clamped"] == 2
    elif case == "beyond_bound_rejected":
        assert counters["rejected_bound"] == 1
    elif case.startswith("timeout"):
        assert counters["timeouts"] == 2
    raw = read_topic(bag, "/drive_torque").data
    assert raw.size == len(sequence)
    np.testing.assert_array_equal(raw, [v for v, _ in sequence])  # as received, NaN and all
    applied = read_topic(bag, "/drive_torque_applied")
    assert np.all(np.isfinite(applied.data)) and applied.data.size == sum(t for _, t in sequence) + 1

    result = simulate(scene_from_bag(bag))
    js = read_topic(bag, "/joint_states")
    n = js.stamp_ns.size
    assert n == applied.data.size and result.time.size == (n - 1) * substeps + 1
    grid = slice(0, None, substeps)
    np.testing.assert_allclose(result.time[grid], (js.stamp_ns - js.stamp_ns[0]) / 1e9, rtol=0, atol=1e-12)
    o = {k: np.asarray(v)[grid] for k, v in result.outputs.items()}
    for j, wheel in enumerate(("M", "1", "2", "3")):
        assert np.array_equal(js.position[:, j], o[f"phi_{wheel}"]), f"phi_{wheel}"
        assert np.array_equal(js.velocity[:, j], o[f"omega_{wheel}"]), f"omega_{wheel}"
    assert np.array_equal(js.effort[:, 0], o["drive_torque"])
    assert np.array_equal(js.effort[:, 3], -o["load_torque"])
    for topic, signal in (("shaft_speed", "omega_M"), ("load_torque", "load_torque"),
                          ("belt_torque", "belt_torque"), ("relative_deflection", "relative_deflection")):
        assert np.array_equal(read_topic(bag, f"/{topic}").data, o[signal]), topic
    assert result.model == "slipping"  # truck_compressor: auto goes on to slipping; its topics re-simulate too
    for topic, signal in SLIP_FLOAT_OUTPUTS:
        assert np.array_equal(read_topic(bag, f"/{topic}").data, np.asarray(o[signal], dtype=float)), topic
    if case == "slips":
        assert len(result.events) >= 2 and np.any(read_topic(bag, "/slip").data == 1.0)
    if case == "clamped":
        assert set(np.unique(js.effort[:, 0])) <= {0.0, 3.0, 5.0, -5.0, 4.0}
    if case == "timeout_zero":
        assert np.any(js.effort[:, 0] == 0.0) and js.effort[-1, 0] == 0.0


def test_sim_time_recording_stamps_latched_and_early_messages_at_the_first_clock(tmp_path, ros_domain_id):
    """With use_sim_time, what the node records before its first /clock (the latched
    robot_description, a torque received, a /diagnostics published while it waits) is stamped
    at the run's first /clock time, not at 0: the file spans the run, not 56 years."""
    from msg_tools import summary

    from belt_drive_ros.ros.harness import BeltDriveHarness

    start = 1_767_225_600.0  # 2026-01-01, as `belt-drive replay --clock` of a shipped bag starts
    bag = tmp_path / "sim.mcap"
    with BeltDriveHarness(scene="paper", domain_id=ros_domain_id, record_path=str(bag), start_time=start,
                          input_timeout=0.0) as h:
        h.publish_torque(5.0)
        h.advance(0.2)
        h.node.publish_diagnostics()
        h.advance(0.05)
    info = summary(bag)
    start_ns = int(start * 1e9)
    assert info.start_ns == start_ns and info.end_ns == start_ns + 250_000_000, (info.start_ns, info.end_ns)
    described = read_topic(bag, "/robot_description")
    assert described.log_time_ns.tolist() == [start_ns]
    with open(bag, "rb") as f:  # first message of the file (log-time order): the URDF, at the first /clock
        first = next(make_reader(f).iter_messages(log_time_order=True))
    assert first[1].topic == "/robot_description" and first[2].log_time == start_ns


def test_recorder_holds_messages_until_the_first_clock_and_bounds_what_it_holds():
    """TopicRecorder on simulated time: messages at time 0 before any /clock wait for the first
    time of the run (a later message's, or run_started's, 0 included), and at most MAX_HELD_BYTES wait."""
    import io
    from types import SimpleNamespace

    from msg_tools import Ros2McapWriter

    from belt_drive_ros.ros import recorder as rec

    class Clock:
        ros_time_is_active = True

    def make():
        node = SimpleNamespace(get_clock=Clock, get_publishers_info_by_topic=lambda topic: [],
                               get_logger=lambda: SimpleNamespace(error=print))
        return rec.TopicRecorder(node, Ros2McapWriter(io.BytesIO()), flush_period=None)

    data = b"\x00\x01\x00\x00" + b"\x00" * 8
    r = make()
    r.write("/a", "std_msgs/msg/Float64", data, 0)
    r.write("/b", "std_msgs/msg/Float64", data, 0)
    assert r.writer.message_count == 0
    r.write("/a", "std_msgs/msg/Float64", data, 7_000)
    assert r.writer.message_count == 3 and r.writer.time_range_ns == (7_000, 7_000)
    r.write("/a", "std_msgs/msg/Float64", data, 0)  # after the start, time 0 is a time like any other
    assert r.writer.message_count == 4

    r = make()
    r.write("/a", "std_msgs/msg/Float64", data, 0)
    r.run_started(0)  # a run whose /clock starts at 0
    assert r.writer.message_count == 1 and r.writer.time_range_ns == (0, 0)

    r = make()
    big = b"\x00\x01\x00\x00" + b"\x00" * (rec.MAX_HELD_BYTES // 3)
    for _ in range(5):
        r.write("/s", "std_msgs/msg/String", big, 0)
    assert r.held_dropped == 3
    r.close()  # never a /clock: what is held is written at 0
    assert r.writer.message_count == 2


def test_node_recording_resimulates_from_the_command_line(tmp_path, ros_domain_id, capsys):
    """A node recording with a NaN the node rejected: `belt-drive sim rec.mcap --out re.mcap` re-simulates it
    from its own scene record and `msg-tools compare rec.mcap re.mcap` passes (every output within 1e-9 of
    its peak); `belt-drive sim SCENE --torque-bag rec.mcap` takes /drive_torque_applied and says so."""
    from msg_tools import compare
    from msg_tools.cli import main as msg_tools

    from belt_drive_ros.cli import main as belt_drive
    from belt_drive_ros.ros.harness import BeltDriveHarness

    rec = tmp_path / "rec.mcap"
    with BeltDriveHarness(scene="truck_compressor", domain_id=ros_domain_id, record_path=str(rec),
                          input_timeout=0.0) as h:
        for value, ticks in ((6.0, 30), (float("nan"), 20), (9.0, 25), (-2.0, 15)):
            h.publish_torque(value)
            h.advance(ticks * 0.001)
        assert h.node.counters["rejected_nonfinite"] == 1
    assert np.isnan(read_topic(rec, "/drive_torque").data).sum() == 1
    capsys.readouterr()
    re = tmp_path / "re.mcap"
    assert belt_drive(["sim", str(rec), "--out", str(re), "--quiet"]) == 0
    said = capsys.readouterr().out
    assert f"re-simulating {rec}" in said and "drive torque: /drive_torque_applied" in said
    assert msg_tools(["compare", str(rec), str(re)]) == 0, capsys.readouterr().out
    capsys.readouterr()
    report = compare(rec, re, rtol=0.0, atol=0.0)  # the outputs themselves: equal to 1e-9 of each peak
    by_name = {s.name: s for s in report.signals}
    for name in ("shaft_speed/data", "belt_torque/data", "relative_deflection/data", "joint_states/position[wheel_3]",
                 "drive_torque_applied/data", "slip_speed/data"):
        recorded = read_topic(rec, "/" + name.split("/")[0])
        peak = np.nanmax(np.abs(recorded.position if "position" in name else recorded.data))
        assert by_name[name].n_compared == 91 and by_name[name].worst_abs_error <= 1e-9 * peak, by_name[name]
    # the re-simulation re-simulated (an offline recording of the node's topics): the same file's outputs exactly
    re2 = tmp_path / "re2.mcap"
    assert belt_drive(["sim", str(re), "--out", str(re2), "--quiet"]) == 0
    capsys.readouterr()
    assert msg_tools(["compare", str(re), str(re2), "--rtol", "0", "--atol", "0", "--time-base", "absolute"]) == 0
    # SCENE --torque-bag rec.mcap: the applied torque, not the raw one with its NaN
    other = tmp_path / "other.mcap"
    assert belt_drive(["sim", "truck_compressor", "--torque-bag", str(rec), "--out", str(other), "--quiet"]) == 0
    said = capsys.readouterr().out
    assert "torque from /drive_torque_applied" in said
    np.testing.assert_array_equal(np.unique(read_topic(other, "/drive_torque").data), [-2.0, 0.0, 6.0, 9.0])


@pytest.mark.parametrize("event", ["reset", "parameter", "clock back"])
def test_a_recording_whose_run_restarted_or_changed_is_refused_by_name(tmp_path, ros_domain_id, capsys, event):
    """`belt-drive sim REC.mcap` repeats one run from one start with one set of parameters. A recording with a
    `~/reset`, a runtime change of a run parameter (k) or a /clock that jumped back (a restart) is refused in one
    line naming the event and its time (before: exit 0 and a re-simulation that no longer matched the recording).
    The same node without the event re-simulates as before."""
    from belt_drive_ros.cli import main as belt_drive
    from belt_drive_ros.ros.harness import BeltDriveHarness

    rec = tmp_path / "rec.mcap"
    with BeltDriveHarness(scene="paper", domain_id=ros_domain_id, record_path=str(rec), input_timeout=0.0) as h:
        h.publish_torque(5.0)
        h.advance(0.2)
        if event == "reset":
            h.reset()
        elif event == "parameter":
            assert h.set_parameters(k=1.0e4).successful
        else:
            h._step_clock(h._clock_ns - 100_000_000)  # /clock 0.1 s back: the node restarts there
        h.advance(0.1)
    capsys.readouterr()
    assert belt_drive(["sim", str(rec), "--out", str(tmp_path / "re.mcap"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    expected = {"reset": r"the node restarted from the initial state \(~/reset", "parameter": "parameter k changed",
                "clock back": r"the node restarted from the initial state \(clock jumped back\)"}[event]
    assert len(err) == 1 and re.search(rf"cannot re-simulate: {expected}.* at t = 0\.\d+ s of the recording", err[0]), err


def test_a_recording_driven_by_the_scene_re_simulates_its_whole_span(tmp_path, ros_domain_id, capsys):
    """drive_source scene and a node that runs past the scene's duration (it keeps ticking): the re-simulation
    covers the recorded ticks, from the first to the last, on their time stamps, and compare passes (before: the
    scene's duration, stamped with the wall time)."""
    import yaml

    from msg_tools.cli import main as msg_tools

    from belt_drive_ros.cli import main as belt_drive
    from belt_drive_ros.io.scenes import load_scene
    from belt_drive_ros.ros.harness import BeltDriveHarness

    short = tmp_path / "short.yaml"
    data = load_scene("paper").to_dict()
    data["duration"] = 0.1
    short.write_text(yaml.safe_dump(data))
    rec = tmp_path / "rec.mcap"
    with BeltDriveHarness(scene=str(short), domain_id=ros_domain_id, record_path=str(rec), drive_source="scene") as h:
        h.advance(0.3)
    capsys.readouterr()
    re_ = tmp_path / "re.mcap"
    assert belt_drive(["sim", str(rec), "--out", str(re_), "--quiet"]) == 0
    recorded, again = read_topic(rec, "/joint_states"), read_topic(re_, "/joint_states")
    assert len(recorded) == len(again) > 250
    np.testing.assert_array_equal(again.log_time_ns, recorded.log_time_ns)
    assert msg_tools(["compare", str(rec), str(re_)]) == 0, capsys.readouterr().out


def test_a_recording_across_a_forward_clock_jump_re_simulates_on_its_own_ticks(tmp_path, ros_domain_id, capsys):
    """/clock jumps 0.3 s ahead (on the tick grid): the node integrates the stretch in one go and publishes at the new
    time only. The re-simulation writes the recording's own ticks, so compare passes (before: every tick of the jump
    too, and compare failed on 'a gap of 0.3 s'); the values are the recording's bit for bit."""
    from msg_tools.cli import main as msg_tools

    from belt_drive_ros.cli import main as belt_drive
    from belt_drive_ros.ros.harness import BeltDriveHarness

    rec = tmp_path / "rec.mcap"
    with BeltDriveHarness(scene="paper", domain_id=ros_domain_id, record_path=str(rec), input_timeout=0.0) as h:
        h.publish_torque(5.0)
        h.advance(0.1)
        h._step_clock(h._clock_ns + 300_000_000)  # one /clock 0.3 s on
        h.publish_torque(3.0)
        h.advance(0.1)
    recorded = read_topic(rec, "/joint_states")
    assert np.diff(recorded.log_time_ns).max() == 300_000_000  # the jump is in the recording
    capsys.readouterr()
    re_ = tmp_path / "re.mcap"
    assert belt_drive(["sim", str(rec), "--out", str(re_), "--quiet"]) == 0
    again = read_topic(re_, "/joint_states")
    np.testing.assert_array_equal(again.log_time_ns, recorded.log_time_ns)
    np.testing.assert_array_equal(again.position, recorded.position)
    assert msg_tools(["compare", str(rec), str(re_)]) == 0, capsys.readouterr().out


def test_a_recording_with_two_torques_in_one_clock_period_re_simulates_and_compares(tmp_path, ros_domain_id, capsys):
    """Two drive torques received within one /clock period are logged at one time (the raw input, as rosbag2 logs
    it); the re-simulation passes that topic through as recorded, and compare pairs the duplicate stamps both files
    have in order (before: 'duplicate time stamps in A', exit 1, every computed signal equal)."""
    from msg_tools.cli import main as msg_tools

    from belt_drive_ros.cli import main as belt_drive
    from belt_drive_ros.ros.harness import BeltDriveHarness

    rec = tmp_path / "rec.mcap"
    with BeltDriveHarness(scene="paper", domain_id=ros_domain_id, record_path=str(rec), input_timeout=0.0) as h:
        h.publish_torque(5.0)
        h.publish_torque(6.0)  # the same /clock period: one log time
        h.advance(0.05)
        h.publish_torque(2.0)
        h.publish_torque(3.0)
        h.advance(0.05)
    raw = read_topic(rec, "/drive_torque")
    assert (np.diff(raw.log_time_ns) == 0).sum() == 2  # the duplicates are in the recording
    capsys.readouterr()
    re_ = tmp_path / "re.mcap"
    assert belt_drive(["sim", str(rec), "--out", str(re_), "--quiet"]) == 0
    assert msg_tools(["compare", str(rec), str(re_)]) == 0, capsys.readouterr().out


def test_a_publish_clock_recording_has_one_time_base(tmp_path, ros_domain_id):
    """With ``publish_clock`` the node's outputs are logged at its simulated time (from 0); ``/clock`` and
    ``/diagnostics`` reach its recorder through subscriptions and were logged at the node's clock, the system's: one
    file 56 years long, every chunk spanning both times. Now every message is on the simulated time base: each
    ``/clock`` logged at its arrival, just after the time it carries; the file as long as the run."""
    from belt_drive_ros.ros.harness import BeltDriveHarness

    bag = tmp_path / "run.mcap"
    with BeltDriveHarness(scene="paper", domain_id=ros_domain_id, use_sim_time=False, publish_clock=True,
                          real_time_factor=1.0, input_timeout=0.0, record_path=str(bag)) as h:  # fmt: skip
        h._spin_until(lambda: h.node.timing.sim_ns >= 1_500_000_000, "1.5 s of simulated time")  # /diagnostics: 1 Hz wall
        end_ns = h.node.timing.sim_ns
    from mcap_ros2.decoder import DecoderFactory

    with open(bag, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        stats = reader.get_summary().statistics
        logged = {}
        for _, channel, message, decoded in reader.iter_decoded_messages():
            logged.setdefault(channel.topic, []).append((message.log_time, decoded))
    assert {"/clock", "/diagnostics", "/shaft_speed"} <= set(logged)
    assert 0 <= stats.message_start_time <= stats.message_end_time <= end_ns + 10**9  # the run's length, not decades
    # each /clock logged when its subscription received it, on the time it carries (the node went on meanwhile)
    # (the lag is delivery, its size the machine's load: bounded by the run, the old time base was decades off)
    lag = [log_time - (msg.clock.sec * 10**9 + msg.clock.nanosec) for log_time, msg in logged["/clock"]]
    assert min(lag) >= 0 and max(lag) <= end_ns


def test_a_recording_whose_clock_stopped_between_ticks_is_refused_not_resimulated_short(tmp_path, ros_domain_id, capsys):
    """A /clock every 1.5 ms (a time master at its own rate): the node integrates to each clock time and publishes
    there; the re-simulation wrote only the samples on the 1 ms grid (half of them, the rest equal), and compare in
    one order passed. Now it says so and writes nothing."""
    from belt_drive_ros.cli import main
    from belt_drive_ros.ros.harness import BeltDriveHarness

    rec = tmp_path / "run.mcap"
    with BeltDriveHarness(scene="paper", model="flexible", method="etd4", domain_id=ros_domain_id,
                          input_timeout=0.0, record_path=str(rec)) as h:  # fmt: skip
        h.publish_torque(6.0)
        h.advance(0.03, step=0.0015)
    out = tmp_path / "re.mcap"
    assert main(["sim", str(rec), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "cannot re-simulate: 10 of 21 ticks lie off the node's 1 ms tick grid (the first at t = 0.0015 s" in err, err
    assert not out.exists()


def test_a_recording_whose_substeps_split_no_tick_evenly_is_refused_not_resimulated_short(tmp_path, ros_domain_id,
                                                                                           capsys):
    """substeps=7 at 1 kHz: the node steps 7 x 142857 ns and 1 ns per tick; the re-simulation stepped dt evenly, off
    the ticks, and wrote 2 of the 31 ticks (compare then failed on every signal). Now it says so and writes nothing."""
    from belt_drive_ros.cli import main
    from belt_drive_ros.ros.harness import BeltDriveHarness

    rec = tmp_path / "run.mcap"
    with BeltDriveHarness(scene="paper", model="flexible", method="exact", substeps=7, domain_id=ros_domain_id,
                          input_timeout=0.0, record_path=str(rec)) as h:  # fmt: skip
        assert h.node.settings.dt_ns == 142857
        h.publish_torque(6.0)
        h.advance(0.03)
    out = tmp_path / "re.mcap"
    assert main(["sim", str(rec), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "cannot re-simulate: the node split each 1 ms tick into steps of 142857 ns and a last one of 1 ns" in err, err
    assert len(err.strip().splitlines()) == 1 and not out.exists()

"""A long torque bag replayed offline (issue 20): read a page at a time, the same run bit for bit, memory flat.

``belt-drive sim SCENE --torque-bag BAG --out OUT`` of a run that streams reads
the bag's drive torque a page at a time (:class:`~belt_drive_ros.io.torque_bag.PagedTorque`):
the windows, the guards' rigid survey and probes read the pages of their
times. The windows equal those of the drive read whole, and the peak memory
does not grow with the bag's length.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from belt_drive_ros.benchmarks.recording import make_torque_bag
from belt_drive_ros.cli import main
from belt_drive_ros.commands import sim as sim_command
from belt_drive_ros.core import accuracy_probes
from belt_drive_ros.core import stream as stream_module
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.core.stream import stream
from belt_drive_ros.io import run_writers
from belt_drive_ros.io.torque_bag import PASS_CHUNKS, PagedTorque, paged_torque_bag, scene_with_torque_bag
from belt_drive_ros.io.recording import BagReadError, float64_rows
from msg_tools.block_writer import BlockMcapWriter
from msg_tools.chunked import topic_chunks
from test_stream import _peak_bytes

SCENE = Path(__file__).resolve().parents[1] / "bags" / "engine_idle.yaml"


def _windows(scene, window_steps):
    return [w for w in stream(scene, window_steps=window_steps)]


def _same_windows(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert np.array_equal(x.time, y.time) and np.array_equal(x.states, y.states)
        assert np.array_equal(x.inputs, y.inputs)
        for name in x.outputs:
            assert np.array_equal(x.outputs[name], y.outputs[name]), name
        for name in x.energy:
            assert np.array_equal(x.energy[name], y.energy[name]), name
    # the guards' figures and verdicts (the last window carries the report: the guard runs beside the windows)
    assert a[-1].accuracy is not None and repr(a[-1].accuracy) == repr(b[-1].accuracy)


@pytest.mark.parametrize("model", ["flexible", "rigid"])
def test_a_paged_bag_runs_the_windows_of_the_whole_bag_bit_for_bit(tmp_path, monkeypatch, model):
    """Windows of 700 steps, the survey in pieces of 900 and bag chunks of ~1,500 messages: pages, pieces
    and chunks end at different times, the run and the accuracy report are the whole bag's."""
    monkeypatch.setattr(accuracy_probes, "SURVEY_CHUNK", 900)
    bag = tmp_path / "torque.mcap"
    make_torque_bag(bag, 0.1, chunk_size=64 << 10)
    base = load_scene(str(SCENE)).with_overrides(model=model, dt=1e-3)
    whole, paged = scene_with_torque_bag(base, bag), paged_torque_bag(base, bag)
    assert isinstance(paged.drive, PagedTorque) and paged.duration == whole.duration
    assert paged.drive.reference() == whole.drive.reference()
    _same_windows(_windows(whole, 700), _windows(paged, 700))


def test_the_slipping_model_pages_the_bag_and_runs_the_windows_of_the_whole_bag_bit_for_bit(tmp_path, monkeypatch):
    """The slipping run steps each window on the page of its times (its hybrid stepper holds its torque's
    table): with friction low enough that the belt sticks and slips hundreds of times, the windows, their
    events and the guards' report are those of the bag read whole."""
    import dataclasses

    monkeypatch.setattr(accuracy_probes, "SURVEY_CHUNK", 900)
    bag = tmp_path / "torque.mcap"
    make_torque_bag(bag, 0.1, chunk_size=64 << 10)
    base = load_scene(str(SCENE)).with_overrides(model="slipping", dt=1e-3)
    base = dataclasses.replace(base, params=dataclasses.replace(base.params, mu=0.15))
    whole, paged = scene_with_torque_bag(base, bag), paged_torque_bag(base, bag)
    a, b = _windows(whole, 700), _windows(paged, 700)
    assert all(isinstance(w.scene.drive, PagedTorque) for w in b)
    assert sum(len(w.events) for w in a) > 100 and [w.events for w in a] == [w.events for w in b]
    _same_windows(a, b)


def test_equal_times_across_chunks_and_uneven_spacing_page_as_the_whole_bag(tmp_path):
    """Messages at equal times (the later wins) across a chunk's seam, uneven spacing off the step grid."""
    rng = np.random.default_rng(3)
    # 1,500 messages in chunks of 4 KiB: the 16 chunks of 6,000 in 16 KiB (the seam at the same chunk), a quarter
    # of the run (each off-grid sample is a partial step: the run's cost); windows of 400 steps: as many windows
    n, block = 1500, 750
    times = np.cumsum(rng.integers(300_000, 1_700_000, size=n)).astype(np.int64)
    times[block - 1] = times[block] = times[block + 1]  # a run of equal times over the seam of two blocks
    values = 40.0 + 30.0 * np.sin(np.arange(n) * 0.05) + rng.normal(size=n)
    bag = tmp_path / "uneven.mcap"
    with BlockMcapWriter(bag, chunk_size=4 << 10) as w:
        for a in range(0, n, block):
            w.write_block([("/drive_torque", "std_msgs/msg/Float64")], times[a : a + block],
                          [float64_rows(values[a : a + block])])
    base = load_scene(str(SCENE)).with_overrides(model="flexible", dt=1e-3)
    whole, paged = scene_with_torque_bag(base, bag), paged_torque_bag(base, bag)
    assert paged is not None and paged.drive.samples == whole.drive.times.size
    chunks, _ = topic_chunks(bag, "/drive_torque")
    assert len(chunks) >= 2 * PASS_CHUNKS  # the pass that opens the bag takes two goes
    chunks.close()
    _same_windows(_windows(whole, 400), _windows(paged, 400))


def test_a_namespaced_torque_beside_another_topic_in_the_same_chunks_pages_as_the_whole_bag(tmp_path):
    """Chunks holding two topics (a node recording's): the torque's records are picked out of each."""
    n = 5000
    times = np.arange(n, dtype=np.int64) * 1_000_000 + 7
    torque = 40.0 + 30.0 * np.sin(np.arange(n) * 0.03)
    bag = tmp_path / "node.mcap"
    with BlockMcapWriter(bag, chunk_size=16 << 10) as w:
        for a in range(0, n, 1000):
            w.write_block([("/truck/drive_torque", "std_msgs/msg/Float64"), ("/truck/shaft_speed", "std_msgs/msg/Float64")],
                          times[a : a + 1000], [float64_rows(torque[a : a + 1000]), float64_rows(-torque[a : a + 1000])])
    base = load_scene(str(SCENE)).with_overrides(model="flexible", dt=1e-3)
    whole, paged = scene_with_torque_bag(base, bag), paged_torque_bag(base, bag)
    assert isinstance(paged.drive, PagedTorque) and paged.drive.topic == "/truck/drive_torque"
    assert paged.drive.reference() == whole.drive.reference()
    _same_windows(_windows(whole, 900), _windows(paged, 900))


def test_a_bag_cut_off_or_damaged_is_read_whole(tmp_path):
    bag = tmp_path / "torque.mcap"
    make_torque_bag(bag, 0.05, chunk_size=16 << 10)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(bag.read_bytes()[: bag.stat().st_size // 2])
    base = load_scene(str(SCENE))
    assert paged_torque_bag(base, cut) is None  # no summary section: the whole read recovers what it can
    damaged = tmp_path / "damaged.mcap"
    data = bytearray(bag.read_bytes())
    chunks, _ = topic_chunks(bag, "/drive_torque")
    at, length = chunks._offsets[1]
    chunks.close()
    data[at + length // 2 : at + length // 2 + 64] = bytes(64)  # inside a chunk's data; the summary is sound
    damaged.write_bytes(bytes(data))
    assert paged_torque_bag(base, damaged) is None  # the whole read says what is wrong, in one line
    with pytest.raises(BagReadError, match="damaged.mcap"):
        scene_with_torque_bag(base, damaged)


def test_a_chunk_damaged_where_the_opening_pass_decodes_ahead_is_read_whole(tmp_path):
    """The pass that opens a bag has the next chunks decoded by a thread of its own: a damaged one there is what
    one damaged in the pass's own group is (the whole read says what is wrong), the thread ends, the file is shut."""
    import threading

    bag = tmp_path / "torque.mcap"
    make_torque_bag(bag, 0.25, chunk_size=16 << 10)
    chunks, _ = topic_chunks(bag, "/drive_torque")
    assert len(chunks) > 3 * PASS_CHUNKS
    base = load_scene(str(SCENE))
    for k in (PASS_CHUNKS + 1, 2 * PASS_CHUNKS + 3, len(chunks) - 1):  # each decoded ahead of the pass
        at, length = chunks._offsets[k]
        data = bytearray(bag.read_bytes())
        data[at + length // 2 : at + length // 2 + 64] = bytes(64)
        damaged = tmp_path / f"damaged{k}.mcap"
        damaged.write_bytes(bytes(data))
        assert paged_torque_bag(base, damaged) is None, k
        with pytest.raises(BagReadError, match=damaged.name):
            scene_with_torque_bag(base, damaged)
    chunks.close()
    assert not [t for t in threading.enumerate() if t.name.startswith("bag-pass")]
    paged, whole = paged_torque_bag(base, bag), scene_with_torque_bag(base, bag)
    assert paged.drive.samples == whole.drive.times.size and paged.drive.sha256 == whole.drive.sha256
    assert paged.drive.read_cpu > 0.0  # every chunk's decoding counted, in whichever thread
    page = paged.drive.page(3.0, 9.0)
    keep = (whole.drive.times >= page.times[0]) & (whole.drive.times <= page.times[-1])
    assert np.array_equal(page.times, whole.drive.times[keep]) and np.array_equal(page.values, whole.drive.values[keep])


#: the long bag [min]: the peak of a run with its guard and writer threads beside it varies by ~+-0.7 MB from run
#: to run (per extra sample -4 to 16 B over 45,000 samples with a 1-minute bag, the same code): 2 minutes put
#: 105,000 samples under that noise, while the whole-read design's ~58 B a sample stays far above the bound
LONG_MINUTES = 2.0


def test_replay_memory_does_not_grow_with_the_bag(tmp_path, monkeypatch):
    """A bag 4x longer peaks at about the same memory: under 16 B per extra bag sample (measured ~6 B,
    most of it the output file's chunk indexes: 64 KiB chunks here), where reading the bag whole held
    ~58 B per sample (its times and values, the kernel's table, the breakpoints: measured on the code
    before the pages, which fails this). Windows and survey pieces of 2,000 steps make both runs many
    windows; a first, untraced run loads what a process loads once."""
    monkeypatch.setattr(sim_command, "STREAM_ABOVE", 0)
    monkeypatch.setattr(stream_module, "WINDOW_STEPS", 2000)
    monkeypatch.setattr(accuracy_probes, "SURVEY_CHUNK", 2000)
    monkeypatch.setattr(run_writers, "STREAM_CHUNK", 64 << 10)
    bags = {}
    for name, minutes in (("warm", 0.1), ("short", 0.25), ("long", LONG_MINUTES)):
        bags[name] = tmp_path / f"{name}_torque.mcap"
        make_torque_bag(bags[name], minutes, chunk_size=64 << 10)

    def run(name: str) -> list:
        return ["sim", str(SCENE), "--model", "flexible", "--torque-bag", str(bags[name]), "--quiet", "--force",
                "--start-time", "0", "--out", str(tmp_path / f"{name}.mcap")]

    assert main(run("warm")) == 0
    short = _peak_bytes(run("short"))
    long = _peak_bytes(run("long"))
    per_sample = (long - short) / ((LONG_MINUTES - 0.25) * 60_000)
    assert per_sample < 16, (short, long, per_sample)


def test_a_topic_whose_channels_carry_two_types_is_not_paged(tmp_path):
    """/drive_torque in two channels, Float64 then String (whose 12-byte CDR is as long as a Float64's): the paged
    read checked the first channel's type only and read the strings' bytes as torques (8.6e-307 N m, exit 0, on a
    bag long enough to stream). Now it leaves such a topic to the whole read, which refuses it by name."""
    import struct

    from mcap.writer import Writer

    bag = tmp_path / "mixed.mcap"
    with open(bag, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="test")
        s1 = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data\n")
        s2 = w.register_schema("std_msgs/msg/String", "ros2msg", b"string data\n")
        a, b = w.register_channel("/drive_torque", "cdr", s1), w.register_channel("/drive_torque", "cdr", s2)
        for i in range(4000):
            t = 10**18 + i * 10**6
            data = (b"\x00\x01\x00\x00" + struct.pack("<I", 4) + b"abc\x00" if i >= 2000
                    else b"\x00\x01\x00\x00" + struct.pack("<d", 5.0 + i * 1e-3))
            w.add_message(b if i >= 2000 else a, log_time=t, publish_time=t, data=data, sequence=i)
        w.finish()
    base = load_scene(str(SCENE)).with_overrides(dt=1e-3)
    assert paged_torque_bag(base, bag) is None  # the whole read decides
    with pytest.raises(BagReadError, match="carry different message types"):
        scene_with_torque_bag(base, bag)

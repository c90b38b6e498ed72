"""A network recording written a block of samples at a time (io/network_bag.py's NetworkBagWriter).

The writer keeps BLOCK_SAMPLES samples and writes them as one block. Checks
on its bytes, read back with the mcap library: every sample of every output
is there once, in time order per topic, each message the bytes the node
publishes (``encode_float64``, the joint_states and /tf encoders); a time
going back (the node restarts after a clock jump) starts a new block; inputs
written between samples are kept; ``flush`` puts the kept samples into the
file (a reader of the unfinished file sees them) and ``close`` the rest.
"""

from __future__ import annotations

import numpy as np

from belt_drive_ros.io.scenes import load_network
from belt_drive_ros.io.cdr_encoders import encode_float64
from belt_drive_ros.io.network_bag import BLOCK_SAMPLES, NetworkBagWriter, NetworkLayout, network_record, scene_text


def _messages(path) -> dict:
    """topic -> [(log time, bytes)] in file order, read as a stream (no summary needed); every message of a
    chunk lies inside the chunk's time range (which indexed readers trust)."""
    from mcap.stream_reader import StreamReader, breakup_chunk

    from mcap.exceptions import EndOfFile

    def records(f):  # an unfinished file ends after its last complete record
        reader = StreamReader(f, emit_chunks=True).records
        while True:
            try:
                yield next(reader)
            except (StopIteration, EndOfFile):
                return

    topics, out = {}, {}
    with open(path, "rb") as f:
        for record in records(f):
            kind = type(record).__name__
            if kind == "Channel":
                topics[record.id] = record.topic
            elif kind == "Chunk":
                for inner in breakup_chunk(record, validate_crc=True):
                    if type(inner).__name__ == "Channel":
                        topics[inner.id] = inner.topic
                    elif type(inner).__name__ == "Message":
                        assert record.message_start_time <= inner.log_time <= record.message_end_time
                        out.setdefault(topics[inner.channel_id], []).append((inner.log_time, bytes(inner.data)))
            elif kind == "Message":
                out.setdefault(topics[record.channel_id], []).append((record.log_time, bytes(record.data)))
    return out


def test_blocks_hold_every_sample_as_published_bytes_across_a_clock_jump(tmp_path):
    scene = load_network("fead_i4")
    layout = NetworkLayout(scene)
    record = network_record(scene, scene_text("fead_i4"), method=scene.method, dt=scene.dt, tick_ns=1_000_000,
                            source="node", drive_source="topic")
    path = tmp_path / "rec.mcap"
    writer = NetworkBagWriter(path, layout, record)
    rng = np.random.default_rng(3)
    times = [1_000_000 * k for k in range(1, 41)] + [1_000_000 * k for k in range(10, 40)]  # back to 10 ms at 41
    samples = []
    joint_enc, tf_enc = layout.joint_encoder(), layout.tf_encoder()
    nj = len(layout.joints)
    for j, t in enumerate(times):
        joints, floats = rng.normal(size=3 * nj).tolist(), rng.normal(size=len(layout.floats)).tolist()
        floats[0] = -0.0 if j == 5 else floats[0]
        writer.write_sample(t, joints, floats)
        samples.append((t, joint_enc.encode(t, joints), tf_enc.encode(t, joints[:nj]), encode_float64(np.array(floats))))
        if j == 7:
            writer.write_input("drive_torque", 3.5, t + 1)
        if j == 29:  # a flush mid-run: what was kept is in the file now, before close
            writer.flush()
            seen = _messages(path)
            assert [t for t, _ in seen["/joint_states"]] == times[:30]
    writer.close()
    assert len(times) % BLOCK_SAMPLES  # a part block at the end, written by close
    got = _messages(path)
    assert [t for t, _ in got["/joint_states"]] == times  # every sample once, per topic in the order written
    assert [d for _, d in got["/joint_states"]] == [s[1] for s in samples]
    assert [d for _, d in got["/tf"]] == [s[2] for s in samples]
    for k, (topic, _) in enumerate(layout.floats):
        assert [d for _, d in got["/" + topic]] == [s[3][k] for s in samples], topic
    assert got["/drive_torque"] == [(times[7] + 1, encode_float64(np.array([3.5]))[0])]
    from mcap.reader import make_reader

    with open(path, "rb") as f:  # the summary's counts agree
        stats = make_reader(f).get_summary().statistics
    assert stats.message_count == 1 + len(times) * (2 + len(layout.floats)) + 1

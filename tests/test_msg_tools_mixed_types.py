"""A topic recorded on channels of different message types: one clear error naming the types, not a decoding
error of the first type's layout; channels of one type (publishers with different QoS) stay one topic."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from mcap.writer import Writer

from belt_drive_ros.cli import main
from msg_tools.errors import DecodeError
from msg_tools.reader import read_topic

_FLOAT64 = b"\x00\x01\x00\x00"  # (CDR little-endian encapsulation)


def _bag(path, second_type: str) -> None:
    """/drive_torque as two channels: Float64 100 N m every ms, and every 10 ms a ``second_type`` message (a String
    "x", or a Float64 of 50 N m on a channel with other metadata)."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="test")
        s1 = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
        c1 = w.register_channel("/drive_torque", "cdr", s1, metadata={"offered_qos_profiles": ""})
        if second_type == "String":
            s2 = w.register_schema("std_msgs/msg/String", "ros2msg", b"string data")
            second = _FLOAT64 + struct.pack("<I", 2) + b"x\x00"
        else:
            s2, second = s1, _FLOAT64 + struct.pack("<d", 50.0)
        c2 = w.register_channel("/drive_torque", "cdr", s2, metadata={"other": "qos"})
        for i in range(200):
            t = i * 1_000_000
            w.add_message(c1, log_time=t, publish_time=t, data=_FLOAT64 + struct.pack("<d", 100.0))
            if i % 10 == 0:
                w.add_message(c2, log_time=t + 1, publish_time=t + 1, data=second)
        w.finish()


def test_a_topic_of_two_types_is_refused_naming_both(tmp_path, capsys):
    """Before: '/drive_torque (std_msgs/msg/Float64): message 1 has 10 bytes, needs 12' (the String read as a
    Float64), from the reader and from ``sim --torque-bag``."""
    bag = tmp_path / "mixed.mcap"
    _bag(bag, "String")
    with pytest.raises(DecodeError, match=r"2 channels carry different message types \(std_msgs/msg/Float64, "
                                          r"std_msgs/msg/String\)"):
        read_topic(bag, "/drive_torque")
    status = main(["sim", "paper", "--torque-bag", str(bag), "--duration", "0.1", "--quiet",
                   "--out", str(tmp_path / "out.mcap")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1, err
    assert "different message types" in err[0] and "std_msgs/msg/String" in err[0], err
    assert not (tmp_path / "out.mcap").exists()


def test_channels_of_one_type_are_one_topic(tmp_path):
    bag = tmp_path / "two_channels.mcap"
    _bag(bag, "Float64")
    data = read_topic(bag, "/drive_torque")
    assert data.fields["data"].size == 220
    assert np.count_nonzero(data.fields["data"] == 50.0) == 20
    assert np.all(np.diff(data.log_time_ns) >= 0)

"""Pins the one private mcap_ros2 function msg_tools uses (``serialize_dynamic``, in msg_tools._cdr).

Exact bytes of known messages (little endian, encapsulation ``00 01 00 00``,
zero padding), and the round trip through the public decoder.
"""

from msg_tools import _cdr, schemas


def test_float64_bytes():
    enc = _cdr.encoder_for("std_msgs/msg/Float64", schemas.schema_text("std_msgs/msg/Float64"))
    assert bytes(enc({"data": 1.5})) == bytes.fromhex("00010000" + "000000000000f83f")


def test_joint_state_bytes_zero_padding_and_round_trip():
    from types import SimpleNamespace as NS

    text = schemas.schema_text("sensor_msgs/msg/JointState")
    msg = NS(header=NS(stamp=NS(sec=1, nanosec=2), frame_id=""), name=["a"], position=[0.5],
             velocity=[], effort=[])
    data = bytes(_cdr.encoder_for("sensor_msgs/msg/JointState", text)(msg))
    expected = bytes.fromhex(
        "00010000"            # encapsulation: CDR little endian
        "01000000" "02000000"  # stamp sec, nanosec
        "01000000" "00"        # frame_id: length 1 (the NUL), "\0"
        "000000"               # padding to 4
        "01000000" "02000000" "6100"  # name: 1 string "a\0"
        "0000"                 # padding to 4
        "01000000"             # position: 1 double (offset 32 after the header: aligned to 8)
        "000000000000e03f"     # 0.5
        "00000000" "00000000"  # velocity, effort: empty
    )
    assert data == expected
    back = _cdr.decoder_for("sensor_msgs/msg/JointState", text)(data)
    assert back.header.stamp.sec == 1 and back.name == ["a"] and list(back.position) == [0.5]

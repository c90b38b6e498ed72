"""CDR encoders of the recorded messages, without rclpy (see :mod:`belt_drive_ros.io.recording`).

Byte-identical to :func:`msg_tools.encode` (zero padding, as ``mcap_ros2``
encodes), built from templates: long runs and node ticks pack only the
stamps and the doubles.
"""

from __future__ import annotations

import math
import struct
from typing import List, Sequence, Tuple

import numpy as np

from .bag_layout import JOINT_NAMES, JOINT_STATE, STRING, TF_MESSAGE

_F64_HEADER = b"\x00\x01\x00\x00"


def stamp_words(stamp_ns: np.ndarray) -> np.ndarray:
    """``builtin_interfaces/Time`` of each time ``stamp_ns`` [ns] as one little-endian ``uint64`` whose bytes are the
    CDR of the stamp (``sec`` int32, then ``nanosec`` uint32): a message's stamp is then one 8-byte field to write,
    not two (the same bytes as writing ``sec`` and ``nanosec`` apart)."""
    sec, nanosec = np.divmod(np.asarray(stamp_ns, dtype=np.int64), 1_000_000_000)
    words = np.empty(sec.size, dtype=[("sec", "<i4"), ("nanosec", "<u4")])
    words["sec"], words["nanosec"] = sec, nanosec
    return words.view("<u8")


def float64_messages(values: np.ndarray):
    """CDR of ``std_msgs/Float64`` for each value (header ``00 01 00 00`` little endian, then the IEEE
    double) as :class:`msg_tools.block_writer.FixedMessages`."""
    from msg_tools.block_writer import FixedMessages

    raw = np.ascontiguousarray(values, dtype="<f8").reshape(-1)
    return FixedMessages(_F64_HEADER + bytes(8), {"data": ("<f8", 4)}, {"data": raw})


def float64_rows(values: np.ndarray) -> np.ndarray:
    """:func:`float64_messages` as the rows of an ``(n, 12)`` uint8 array."""
    return float64_messages(values).rows()


def encode_float64(values: np.ndarray) -> List[bytes]:
    """CDR of ``std_msgs/Float64`` for each value, as ``mcap_ros2`` encodes it.

    Header ``00 01 00 00`` (little endian) then the IEEE double; byte-identical
    to :func:`msg_tools.encode` (a test checks), ~50x faster for long runs.
    """
    raw = np.ascontiguousarray(values, dtype="<f8").tobytes()
    return [_F64_HEADER + raw[i : i + 8] for i in range(0, len(raw), 8)]


class JointStateEncoder:
    """CDR of the node's ``sensor_msgs/JointState`` for one tick, without rclpy.

    The bytes of :func:`encode_joint_states` (zero padding, as ``mcap_ros2``
    encodes), from a template built once: per tick only the stamp and the
    twelve doubles are packed in (~2.5 us). The node publishes these bytes
    as its ``joint_states`` (rclpy's ``Publisher.publish`` takes a serialized
    message) and records the same bytes: converting a ``JointState`` object
    to its C struct and serializing it cost the node's tick ~30 us. Fast CDR
    leaves its padding bytes uninitialised where this writes zeros; every
    CDR reader skips them (a test deserializes these bytes with rclpy).
    """

    def __init__(self, joints: int = 4, names: Sequence[str] | None = None):
        names = JOINT_NAMES if names is None else tuple(names)  # a belt network: its pulleys and the arm
        joints = len(names)
        self._template, self._offsets = _joint_state_layout(names, "")
        first, second, third = self._offsets
        gap = second - first - 8 * joints  # the length field, and CDR's zero padding to 8 bytes
        if gap not in (4, 8) or third - second - 8 * joints != gap:
            raise RuntimeError("JointState template: the arrays are not consecutive sequences")
        # the stamp, then the three arrays with the length fields (and padding) between them: two packs per message
        between = "I" + "x" * (gap - 4)
        self._arrays = struct.Struct(f"<{joints}d{between}{joints}d{between}{joints}d")
        self._joints = joints
        self._stamp = struct.Struct("<iI")

    @property
    def layout(self) -> tuple[bytes, tuple[int, int, int]]:
        """(template, offsets): the message's bytes and the byte offsets of its positions, velocities and
        efforts (the stamp at bytes 4-12), for a writer of its own (the node's compiled tick)."""
        return self._template, tuple(self._offsets)

    def encode(self, stamp_ns: int, values) -> bytes:
        """``values`` = position, velocity, effort of the joints, concatenated."""
        buf = bytearray(self._template)
        self._stamp.pack_into(buf, 4, *divmod(stamp_ns, 1_000_000_000))
        j = self._joints
        self._arrays.pack_into(buf, self._offsets[0], *values[:j], j, *values[j : 2 * j], j, *values[2 * j :])
        return bytes(buf)



class TfEncoder:
    """CDR of ``tf2_msgs/TFMessage`` for the drive's wheels at their joint angles, without rclpy.

    One ``geometry_msgs/TransformStamped`` per wheel joint, as
    ``robot_state_publisher`` publishes a continuous joint: parent
    ``base_link``, child ``<joint>_link`` (the links of
    :func:`~belt_drive_ros.io.urdf.urdf_from_params`), translation the joint
    origin ``(x, y, 0)`` [m], rotation the joint angle ``q`` [rad] about the
    joint axis ``(0, 0, s)`` (``s = +/-1``): the quaternion
    ``(x, y, z, w) = (0, 0, s sin(q/2), cos(q/2))``. Every transform is
    stamped with the tick's time.

    The bytes come from a template encoded once (:func:`msg_tools.encode`):
    per message only the stamps and the ``z, w`` of each rotation are packed
    in. ``params`` fix the joint origins (a new encoder when the radii change).
    ``frames`` instead gives them directly, one ``(joint, parent link, x, y, sign)``
    per joint (a belt network: the tensioner pulley hangs on its arm's link).
    """

    def __init__(self, params, joints: Sequence[str] = JOINT_NAMES, frames: Sequence[tuple] | None = None):
        import msg_tools

        if frames is None:
            from .urdf import drive_layout

            wheels = drive_layout(params).wheels
            frames = [(j, "base_link", wheels[j][0], wheels[j][1], wheels[j][2]) for j in joints]
        parents = {f[0]: f[1] for f in frames}
        wheels = {f[0]: (f[2], f[3], f[4]) for f in frames}
        self.joints = tuple(f[0] for f in frames)
        self.signs = np.array([wheels[j][2] for j in self.joints], dtype=float)
        n = len(self.joints)
        sec_marks = [0x5A5A0000 + k for k in range(n)]
        nsec_marks = [0x3C3C0000 + k for k in range(n)]
        rot_marks = np.arange(1, 2 * n + 1, dtype=float).reshape(n, 2) * 1e300 / 7.0  # (z, w) per wheel
        transforms = [{
            "header": {"stamp": {"sec": sec_marks[k], "nanosec": nsec_marks[k]}, "frame_id": parents[joint]},
            "child_frame_id": f"{joint}_link",
            "transform": {"translation": {"x": float(wheels[joint][0]), "y": float(wheels[joint][1]), "z": 0.0},
                          "rotation": {"x": 0.0, "y": 0.0, "z": float(rot_marks[k, 0]), "w": float(rot_marks[k, 1])}},
        } for k, joint in enumerate(self.joints)]
        template = msg_tools.encode(TF_MESSAGE, {"transforms": transforms})

        def find(packed: bytes) -> int:
            offset = template.find(packed)
            if offset < 0 or template.find(packed, offset + 1) >= 0:
                raise RuntimeError("TFMessage template: a field is not found exactly once")
            return offset

        self._stamps = [find(struct.pack("<iI", sec_marks[k], nsec_marks[k])) for k in range(n)]
        self._rotations = [find(struct.pack("<2d", *rot_marks[k])) for k in range(n)]
        self._template = template
        self._stamp, self._rotation = struct.Struct("<iI"), struct.Struct("<2d")
        self._sign_list = [float(v) for v in self.signs]

    def quaternions(self, angles) -> np.ndarray:
        """``(z, w)`` of each wheel's rotation for joint angles ``angles`` [rad] (last axis: the wheels)."""
        half = 0.5 * np.asarray(angles, dtype=float)
        return np.stack([self.signs * np.sin(half), np.cos(half)], axis=-1)

    def encode(self, stamp_ns: int, angles) -> bytes:
        """The message at ``stamp_ns`` [ns] for the wheels' joint angles ``angles`` [rad] (a node's tick:
        plain floats, no numpy)."""
        buf = bytearray(self._template)
        sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
        pack_stamp, pack_rotation, sin, cos = self._stamp.pack_into, self._rotation.pack_into, math.sin, math.cos
        for stamp, rotation, sign, angle in zip(self._stamps, self._rotations, self._sign_list, angles):
            half = 0.5 * angle
            pack_stamp(buf, stamp, sec, nsec)
            pack_rotation(buf, rotation, sign * sin(half), cos(half))
        return bytes(buf)

    def messages(self, stamp_ns: np.ndarray, angles: np.ndarray):
        """The messages at ``stamp_ns`` (n,) [ns] for ``angles`` (n, wheels) [rad] as
        :class:`msg_tools.block_writer.FixedMessages`."""
        from msg_tools.block_writer import FixedMessages

        stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
        angles = np.asarray(angles, dtype=float).reshape(stamp_ns.size, len(self._stamps))
        fields, values = {}, {}
        stamps = stamp_words(stamp_ns)  # (every transform carries the tick's stamp: one array for all)
        for k, (stamp, rotation, sign) in enumerate(zip(self._stamps, self._rotations, self._sign_list)):
            # (z, w) of wheel k as :meth:`quaternions` gives them (the same floats), one (n, 2) array per wheel
            q = np.empty((stamp_ns.size, 2))
            half = np.multiply(angles[:, k], 0.5, out=q[:, 1])
            np.multiply(np.sin(half), sign, out=q[:, 0])
            np.cos(half, out=q[:, 1])
            fields.update({f"stamp{k}": ("<u8", stamp), f"q{k}": (("<f8", 2), rotation)})
            values.update({f"stamp{k}": stamps, f"q{k}": q})
        return FixedMessages(self._template, fields, values)

    def rows(self, stamp_ns: np.ndarray, angles: np.ndarray) -> np.ndarray:
        """One message per row of an ``(n, size)`` uint8 array: ``stamp_ns`` (n,) [ns], ``angles`` (n, wheels) [rad]."""
        return self.messages(stamp_ns, angles).rows()

    def encode_many(self, stamp_ns: np.ndarray, angles: np.ndarray) -> List[bytes]:
        """The messages of :meth:`rows`, one ``bytes`` each."""
        return [row.tobytes() for row in self.rows(stamp_ns, angles)]


def encode_robot_description(params) -> Tuple[str, bytes]:
    """The drive's URDF for ``params`` (:func:`~belt_drive_ros.io.urdf.urdf_from_params`) and its
    ``std_msgs/String`` CDR (as ``mcap_ros2`` and rclpy encode it)."""
    import msg_tools

    from .urdf import urdf_from_params

    urdf = urdf_from_params(params)
    return urdf, msg_tools.encode(STRING, {"data": urdf})


_JOINT_LAYOUTS: dict = {}


def _joint_state_layout(names: Sequence[str], frame_id: str) -> Tuple[bytes, List[int]]:
    """(template, offsets): the CDR of a ``sensor_msgs/JointState`` with ``names`` and as many
    positions, velocities and efforts, encoded once by :func:`msg_tools.encode` (zero padding), and the
    byte offsets of its three double arrays (the stamp is at bytes 4-12)."""
    key = (tuple(names), frame_id)
    layout = _JOINT_LAYOUTS.get(key)
    if layout is None:
        from msg_tools import encode

        joints = len(names)
        marks = np.arange(1, 3 * joints + 1, dtype=float).reshape(3, joints) * 1e300 / 7.0  # cannot occur elsewhere
        template = encode(JOINT_STATE, {
            "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": frame_id},
            "name": list(names), "position": marks[0], "velocity": marks[1], "effort": marks[2],
        })
        offsets = []
        for group in marks:  # position, velocity, effort: each a contiguous CDR sequence
            packed = np.ascontiguousarray(group, dtype="<f8").tobytes()
            offset = template.find(packed)
            if offset < 0 or template.find(packed, offset + 1) >= 0:
                raise RuntimeError("JointState template: an array is not found exactly once")
            offsets.append(offset)
        layout = _JOINT_LAYOUTS[key] = (template, offsets)
    return layout


def joint_state_messages(stamp_ns: np.ndarray, position: np.ndarray, velocity: np.ndarray, effort: np.ndarray,
                         names: Sequence[str] = JOINT_NAMES, frame_id: str = ""):
    """CDR of ``sensor_msgs/JointState`` messages as :class:`msg_tools.block_writer.FixedMessages`.

    The layout of a JointState with fixed names and array sizes does not
    change from message to message: one message encoded with
    :func:`msg_tools.encode` (zero padding) is the template, and the stamps
    and values are written into copies of it. Each message is byte-identical to
    encoding it with :func:`msg_tools.encode` (a test checks).

    Parameters
    ----------
    stamp_ns : (N,) int
        ``header.stamp`` [ns].
    position, velocity, effort : (N, J) float
        One column per joint of ``names``.
    """
    from msg_tools.block_writer import FixedMessages

    stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
    n, joints = len(stamp_ns), len(names)
    template, offsets = _joint_state_layout(names, frame_id)
    return FixedMessages(template, {"stamp": ("<u8", 4), "position": (("<f8", joints), offsets[0]),
                                    "velocity": (("<f8", joints), offsets[1]), "effort": (("<f8", joints), offsets[2])},
                         {"stamp": stamp_words(stamp_ns),
                          **{name: np.asarray(values, dtype=float).reshape(n, joints)
                             for name, values in (("position", position), ("velocity", velocity), ("effort", effort))}})


def joint_state_rows(stamp_ns: np.ndarray, position: np.ndarray, velocity: np.ndarray, effort: np.ndarray,
                     names: Sequence[str] = JOINT_NAMES, frame_id: str = "") -> np.ndarray:
    """:func:`joint_state_messages` as the rows of an ``(N, size)`` uint8 array."""
    return joint_state_messages(stamp_ns, position, velocity, effort, names, frame_id).rows()


def encode_joint_states(stamp_ns: np.ndarray, position: np.ndarray, velocity: np.ndarray,
                        effort: np.ndarray, names: Sequence[str] = JOINT_NAMES,
                        frame_id: str = "") -> List[bytes]:
    """The messages of :func:`joint_state_rows`, one ``bytes`` each."""
    return [row.tobytes() for row in joint_state_rows(stamp_ns, position, velocity, effort, names, frame_id)]

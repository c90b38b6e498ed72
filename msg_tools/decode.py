"""Decode the CDR payloads of one topic into numpy arrays (CDR = XCDR1, as ROS 2 Jazzy's default middleware writes).

* ``std_msgs/msg/Float64`` -- vectorized: payload = 4-byte encapsulation header
  (``00 01`` little endian, ``00 00`` big endian, 2 option bytes) + float64;
* ``sensor_msgs/msg/JointState`` -- vectorized when every message has the same
  length, frame id, joint names and array sizes (the common case of a fixed
  robot); otherwise decoded message by message with ``mcap_ros2``;
* any other type -- decoded with ``mcap_ros2`` into a list of objects, plus
  arrays of their numeric fields.

:func:`build_topic` turns the payloads a :class:`~msg_tools.scan.Scan`
collected for one topic into a :class:`~msg_tools.results.TopicData`.
"""

from __future__ import annotations

import struct
from array import array
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Dict, Iterable, List, Optional, Sequence, Tuple

import numpy as np

from . import schemas as _schemas
from .errors import DecodeError
from .results import TopicData

if TYPE_CHECKING:
    from .scan import Scan, SchemaRecord

__all__ = ["FLOAT64", "JOINT_STATE", "Payloads", "build_topic", "decode_float64", "joint_layout"]

FLOAT64 = "std_msgs/msg/Float64"
JOINT_STATE = "sensor_msgs/msg/JointState"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"


class Payloads:
    """Serialized messages of one topic, in log-time order.

    Parameters
    ----------
    blob : bytes-like
        Payloads back to back (file order).
    starts, ends : numpy.ndarray of int64
        Byte range of each payload in ``blob``, already in log-time order.
    """

    def __init__(self, blob: Any, starts: np.ndarray, ends: np.ndarray):
        self.blob = blob
        self.starts = starts
        self.ends = ends
        self.lengths = ends - starts

    def __len__(self) -> int:
        return int(self.starts.shape[0])

    def __getitem__(self, i: int) -> bytes:
        return bytes(self.blob[int(self.starts[i]) : int(self.ends[i])])

    def __iter__(self):  # type: ignore[no-untyped-def]
        for a, b in zip(self.starts.tolist(), self.ends.tolist()):
            yield bytes(self.blob[a:b])

    def fixed_length(self) -> Optional[int]:
        """The common payload length, or None if lengths differ."""
        if len(self) == 0:
            return None
        first = int(self.lengths[0])
        return first if bool(np.all(self.lengths == first)) else None

    def matrix(self, width: int) -> np.ndarray:
        """(N, width) uint8 matrix of the first ``width`` bytes of each payload."""
        n = len(self)
        flat = np.frombuffer(self.blob, dtype=np.uint8)
        length = self.fixed_length()
        if length is not None and flat.size == n * length:
            rows = flat.reshape(n, length)  # every payload is one row
            order = self.starts // length
            if bool(np.all(order == np.arange(n))):
                return rows[:, :width]  # a view, no copy
            return rows[order, :width]
        out = np.empty((n, width), dtype=np.uint8)
        columns = np.arange(width)
        for a in range(0, n, 65536):  # bounded temporary index arrays
            index = self.starts[a : a + 65536, None] + columns[None, :]
            out[a : a + 65536] = flat[index]
        return out



def _kinds(headers: np.ndarray, topic: str, type_name: str) -> np.ndarray:
    """Return a bool array ``little_endian`` from (N, 2) encapsulation id bytes."""
    if headers.size == 0:
        return np.zeros(0, dtype=bool)
    bad = (headers[:, 0] != 0) | (headers[:, 1] > 1)
    if bad.any():
        i = int(np.argmax(bad))
        if headers[i, 0] == 0x28 and headers[i, 1] == 0xB5:  # zstd's magic number 0xFD2FB528, little endian
            raise DecodeError(
                f"{topic} ({type_name}): message {i} is zstd-compressed data, not CDR (a bag recorded with "
                "rosbag2's compression_mode message): not read here; write an uncompressed copy first (e.g. "
                "'ros2 bag convert')")
        raise DecodeError(
            f"{topic} ({type_name}): message {i} has CDR encapsulation "
            f"0x{headers[i, 0]:02x}{headers[i, 1]:02x}; only plain CDR "
            "(0x0000 big endian, 0x0001 little endian) is supported"
        )
    return headers[:, 1] == 1


def decode_float64(datas: Sequence[bytes], topic: str = "?") -> np.ndarray:
    """Vectorized decode of ``std_msgs/msg/Float64`` payloads.

    Parameters
    ----------
    datas : sequence of bytes
        Serialized messages (encapsulation header + 8-byte float).
    topic : str
        For error messages.

    Returns
    -------
    numpy.ndarray of float64, shape (N,)
    """
    if not isinstance(datas, Payloads):
        blob = b"".join(datas)
        ends = np.cumsum([len(d) for d in datas], dtype=np.int64)
        datas = Payloads(blob, ends - np.array([len(d) for d in datas], dtype=np.int64), ends)
    n = len(datas)
    if n == 0:
        return np.zeros(0)
    if int(datas.lengths.min()) < 12:
        i = int(np.argmin(datas.lengths))
        raise DecodeError(
            f"{topic} (std_msgs/msg/Float64): message {i} has {int(datas.lengths[i])} bytes, "
            "needs 12"
        )
    raw = datas.matrix(12)
    little = _kinds(raw[:, 0:2], topic, FLOAT64)
    values = np.empty(n, dtype=np.float64)
    payload = np.ascontiguousarray(raw[:, 4:12])
    if little.all():
        values[:] = payload.view("<f8").ravel()
    elif not little.any():
        values[:] = payload.view(">f8").ravel()
    else:
        values[little] = payload[little].view("<f8").ravel()
        values[~little] = payload[~little].view(">f8").ravel()
    return values


class _Cursor:
    """Minimal XCDR1 reader for the JointState layout (alignment from payload start)."""

    def __init__(self, data: bytes):
        self.data = data
        self.little = data[1] == 1
        self.pos = 4
        self.e = "<" if self.little else ">"

    def align(self, n: int) -> None:
        rel = self.pos - 4
        self.pos += (-rel) % n

    def u32(self) -> int:
        self.align(4)
        (v,) = struct.unpack_from(self.e + "I", self.data, self.pos)
        self.pos += 4
        return v

    def string(self) -> Tuple[str, int, int]:
        """Return the string and the (start, end) byte range of length + characters."""
        self.align(4)
        start = self.pos
        n = self.u32()
        if self.pos + n > len(self.data):
            raise DecodeError("string runs past the end of the message")
        raw = self.data[self.pos : self.pos + n]
        self.pos += n
        text = raw[:-1].decode("utf-8") if n else ""
        return text, start, self.pos


@dataclass
class _JointLayout:
    length: int
    little: bool
    frame_id: str
    names: List[str]
    arrays: Dict[str, Tuple[int, int]]  # field -> (data offset, count)
    meaningful: np.ndarray  # byte columns that must be equal in every message


def joint_layout(data: bytes) -> _JointLayout:
    """Parse the structure of one JointState message (sizes, offsets, names)."""
    if len(data) < 12 or data[0] != 0 or data[1] > 1:
        raise DecodeError("not plain CDR")
    cur = _Cursor(data)
    mask = np.zeros(len(data), dtype=bool)
    mask[0:2] = True  # encapsulation id
    cur.pos = 4 + 8  # header.stamp (sec, nanosec)
    frame_id, a, b = cur.string()
    mask[a:b] = True
    cur.align(4)
    mask[cur.pos : cur.pos + 4] = True
    count = cur.u32()
    names: List[str] = []
    for _ in range(count):
        name, a, b = cur.string()
        mask[a:b] = True
        names.append(name)
    arrays: Dict[str, Tuple[int, int]] = {}
    for fname in ("position", "velocity", "effort"):
        cur.align(4)
        mask[cur.pos : cur.pos + 4] = True
        n = cur.u32()
        if n:
            cur.align(8)
        arrays[fname] = (cur.pos, n)
        cur.pos += 8 * n
        if cur.pos > len(data):
            raise DecodeError(f"{fname} array runs past the end of the message")
    return _JointLayout(len(data), cur.little, frame_id, names, arrays, mask)


def _same_layout(raw: np.ndarray, meaningful: np.ndarray) -> bool:
    """Whether every row of ``raw`` (N, length) has the first row's bytes where ``meaningful`` (the layout's counts
    and strings: not the values, nor the padding rclpy leaves uninitialised) is True; checked in bounded blocks."""
    cols = np.flatnonzero(meaningful)
    reference = raw[0, cols]
    for block in range(0, raw.shape[0], 65536):  # bounded temporary memory
        if not (raw[block : block + 65536, cols] == reference).all():
            return False
    return True


def _decode_joint_state_vectorized(datas: "Payloads") -> Optional[Dict[str, Any]]:
    """Return decoded JointState arrays, or None if the messages differ in layout."""
    n = len(datas)
    try:
        layout = joint_layout(datas[0])
    except (DecodeError, struct.error, UnicodeDecodeError):
        return None
    length = layout.length
    if datas.fixed_length() != length:
        return None
    raw = datas.matrix(length)
    if not _same_layout(raw, layout.meaningful):
        return None
    e = "<" if layout.little else ">"
    stamp_bytes = np.ascontiguousarray(raw[:, 4:12])
    sec = stamp_bytes[:, 0:4].copy().view(e + "i4").ravel().astype(np.int64)
    nsec = stamp_bytes[:, 4:8].copy().view(e + "u4").ravel().astype(np.int64)
    joints = len(layout.names)
    out: Dict[str, Any] = {
        "stamp_ns": sec * 1_000_000_000 + nsec,
        "names": layout.names,
        "frame_id": layout.frame_id,
    }
    for fname, (offset, count) in layout.arrays.items():
        values = np.full((n, joints), np.nan)
        if count:
            block = np.ascontiguousarray(raw[:, offset : offset + 8 * count])
            decoded = block.view(e + "f8").reshape(n, count).astype(np.float64)
            k = min(count, joints)
            values[:, :k] = decoded[:, :k]
        out[fname] = values
    return out


class LazyMessages:
    """Message objects decoded when read (``data.messages[k]``, iteration): the payloads are kept, not the objects
    (for a topic the vectorized decoders read, whose objects would take ~55x the bytes)."""

    def __init__(self, payloads: List[bytes], decoder: Callable[[bytes], Any]):
        self._payloads, self._decoder = payloads, decoder

    def __len__(self) -> int:
        return len(self._payloads)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return LazyMessages(self._payloads[k], self._decoder)
        return self._decoder(self._payloads[k])

    def __iter__(self):
        return (self._decoder(p) for p in self._payloads)

    def reordered(self, order) -> "LazyMessages":
        return LazyMessages([self._payloads[int(i)] for i in order], self._decoder)

    @staticmethod
    def joined(parts: List["LazyMessages"]) -> "LazyMessages":
        return LazyMessages([p for part in parts for p in part._payloads], parts[0]._decoder)


#: the numeric leaves of a TransformStamped's transform, in the order the generic decoder names them
_TF_LEAVES = tuple(f"transform.{part}.{axis}" for part, axes in (("translation", "xyz"), ("rotation", "xyzw"))
                   for axis in axes)


def _decode_tf_vectorized(datas: "Payloads") -> Optional[Dict[str, np.ndarray]]:
    """The fields of ``tf2_msgs/TFMessage`` messages of one layout (the same frames in the same order, every message
    the same length: a recorder's, a robot_state_publisher's) as arrays, by the generic decoder's names
    (``transforms[CHILD].transform.translation.x`` ...), read straight from the bytes; None where the layout varies
    (the generic decoder reads those). Decoding each message into objects took ~55x the file's size in memory."""
    try:
        first = datas[0]
        if len(first) < 8 or first[0] != 0 or first[1] > 1:
            return None
        cur = _Cursor(first)
        mask = np.zeros(len(first), dtype=bool)
        mask[0:2] = True
        mask[4:8] = True  # the sequence's length
        count = cur.u32()
        offsets: Dict[str, int] = {}
        for _ in range(count):
            cur.align(4)
            cur.pos += 8  # header.stamp: sec, nanosec (not compared: the generic decoder leaves times out)
            for _string in range(2):  # header.frame_id, child_frame_id
                text, a, b = cur.string()
                mask[a:b] = True
            child = text
            cur.align(8)
            if not child or cur.pos + 56 > len(first) or f"transforms[{child}].{_TF_LEAVES[0]}" in offsets:
                return None  # (no label, or a frame twice: the generic decoder's rules)
            for k, leaf in enumerate(_TF_LEAVES):
                offsets[f"transforms[{child}].{leaf}"] = cur.pos + 8 * k
            cur.pos += 56
    except (DecodeError, struct.error, UnicodeDecodeError, IndexError):
        return None
    length = len(first)
    if datas.fixed_length() != length or cur.pos != length:
        return None
    raw = datas.matrix(length)
    if not _same_layout(raw, mask):
        return None
    e = "<" if cur.little else ">"
    return {key: np.ascontiguousarray(raw[:, at : at + 8]).view(e + "f8").ravel().astype(np.float64)
            for key, at in offsets.items()}


def _decode_joint_state_objects(objs: Sequence[Any]) -> Dict[str, Any]:
    """Build JointState arrays from decoded messages; joints = union of names."""
    names: List[str] = []
    index: Dict[str, int] = {}
    for msg in objs:
        for name in msg.name:
            if name not in index:
                index[name] = len(names)
                names.append(name)
    n, joints = len(objs), len(names)
    out: Dict[str, Any] = {"names": names, "frame_id": objs[0].header.frame_id if objs else ""}
    stamp_ns = np.empty(n, dtype=np.int64)
    arrays = {f: np.full((n, joints), np.nan) for f in ("position", "velocity", "effort")}
    for i, msg in enumerate(objs):
        stamp_ns[i] = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
        cols = [index[name] for name in msg.name]
        for fname, values in arrays.items():
            seq = list(getattr(msg, fname))
            k = min(len(seq), len(cols))
            if k:
                values[i, cols[:k]] = seq[:k]
    out["stamp_ns"] = stamp_ns
    out.update(arrays)
    return out


def _decoder_for(type_name: str, schema: Optional[SchemaRecord]) -> Callable[[bytes], Any]:
    from ._cdr import decoder_for

    if schema is not None and schema.encoding == "ros2msg" and schema.data:
        text = schema.data.decode("utf-8")
    else:
        text = _schemas.schema_text(type_name)
    try:
        return decoder_for(type_name, text)
    except Exception as exc:  # noqa: BLE001 - parser errors of many kinds
        raise DecodeError(f"cannot build a decoder for {type_name}: {exc}") from None


def _decode_objects(datas: Iterable[bytes], type_name: str, schema: Optional[SchemaRecord], topic: str) -> List[Any]:
    decoder = _decoder_for(type_name, schema)
    out = []
    for i, data in enumerate(datas):
        try:
            out.append(decoder(data))
        except Exception as exc:  # noqa: BLE001 - struct/index errors on bad payloads
            raise DecodeError(f"{topic} ({type_name}): message {i} cannot be decoded ({exc})") from None
    return out


def _is_time(obj: Any) -> bool:
    slots = getattr(obj, "__slots__", ())
    return tuple(slots) == ("sec", "nanosec")


def _numeric_leaves(obj: Any, prefix: str = "") -> Dict[str, Any]:
    """Return numeric leaf fields of a decoded message by dotted path.

    ``builtin_interfaces/Time`` fields (time stamps) and strings are skipped;
    numeric arrays are kept as tuples; an array of messages gives each element's
    leaves under ``path[label]``, the label its ``child_frame_id`` where it has
    one (a ``tf2_msgs/TFMessage``'s transforms: ``transforms[wheel_M_link].
    transform.rotation.w``), else its index.
    """
    out: Dict[str, Any] = {}
    for name in getattr(obj, "__slots__", ()):
        value = getattr(obj, name)
        path = f"{prefix}{name}"
        if isinstance(value, bool):
            out[path] = float(value)
        elif isinstance(value, (int, float)):
            out[path] = float(value)
        elif isinstance(value, (list, tuple, array)) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
        ):
            if len(value):
                out[path] = tuple(float(v) for v in value)
        elif isinstance(value, (bytes, bytearray)):
            continue
        elif isinstance(value, (list, tuple)) and value and all(hasattr(v, "__slots__") for v in value):
            for k, item in enumerate(value):
                label = getattr(item, "child_frame_id", None)
                out.update(_numeric_leaves(item, f"{path}[{label if isinstance(label, str) and label else k}]."))
        elif hasattr(value, "__slots__") and not _is_time(value):
            out.update(_numeric_leaves(value, path + "."))
    return out


def _generic_fields(objs: Sequence[Any]) -> Tuple[Dict[str, np.ndarray], set]:
    """``(fields, sparse)``: each numeric leaf of the messages as an array over them, in order of first appearance;
    a leaf some messages lack is NaN there, an array leaf whose length varies NaN-padded, both named in ``sparse``
    (only the leaves every message had were kept: a ``/tf`` of one transform per message, its frames alternating,
    had none, and compare skipped it)."""
    if not objs:
        return {}, set()
    leaves = [_numeric_leaves(m) for m in objs]
    keys: Dict[str, None] = {}
    for item in leaves:
        keys.update(dict.fromkeys(item))
    out: Dict[str, np.ndarray] = {}
    sparse: set = set()
    for key in keys:
        values = [item.get(key) for item in leaves]
        lengths = {len(v) for v in values if isinstance(v, tuple)}
        if lengths:  # an array leaf: (N, longest), NaN where shorter or absent
            width = max(lengths)
            column = np.full((len(values), width), np.nan)
            for k, v in enumerate(values):
                if isinstance(v, tuple):
                    column[k, : len(v)] = v
            if len(lengths) > 1 or any(not isinstance(v, tuple) for v in values):
                sparse.add(key)
        else:
            column = np.array([np.nan if v is None else v for v in values], dtype=np.float64)
            if any(v is None for v in values):
                sparse.add(key)
        out[key] = column
    return out, sparse



def _type_name(scan: Scan, cid: int) -> str:
    """The message type of channel ``cid`` of ``scan``, normalized where it can be ("" without a schema)."""
    schema = scan.schemas.get(scan.channels[cid].schema_id)
    type_name = schema.name if schema is not None else ""
    if type_name:
        try:
            type_name = _schemas.normalize_type_name(type_name)
        except ValueError:
            pass
    return type_name


def _build(scan: Scan, channel_ids: List[int], topic: str) -> TopicData:
    channel = scan.channels[channel_ids[0]]
    schema = scan.schemas.get(channel.schema_id)
    type_name = _type_name(scan, channel_ids[0])
    types = {_type_name(scan, cid) for cid in channel_ids[1:]} - {type_name}
    if types:  # (channels of one type, e.g. publishers with different QoS, are one topic's messages)
        raise DecodeError(
            f"{topic}: its {len(channel_ids)} channels carry different message types "
            f"({', '.join(sorted(types | {type_name}, key=str))}): one topic must have one type"
        )
    accs = [scan.accs[cid] for cid in channel_ids]
    blob: Any = accs[0].blob if len(accs) == 1 else bytearray()
    if len(accs) == 1:  # the scan's own arrays, viewed below (not copied: a long recording's times are held once)
        logs, pubs, ends = accs[0].log, accs[0].pub, accs[0].ends
    else:
        logs, pubs, ends = array("q"), array("q"), array("q")
        for acc in accs:
            logs.extend(acc.log)
            pubs.extend(acc.pub)
            shift = len(blob)
            ends.extend(e + shift for e in acc.ends)
            blob += acc.blob or b""
    log_ns = np.frombuffer(logs, dtype=np.int64) if len(logs) else np.zeros(0, np.int64)
    pub_ns = np.frombuffer(pubs, dtype=np.int64) if len(pubs) else np.zeros(0, np.int64)
    end_arr = np.frombuffer(ends, dtype=np.int64) if len(ends) else np.zeros(0, np.int64)
    start_arr = np.concatenate([[0], end_arr[:-1]]).astype(np.int64) if len(end_arr) else end_arr
    if log_ns.size > 1 and np.any(np.diff(log_ns) < 0):
        order = np.argsort(log_ns, kind="stable")
        log_ns, pub_ns = log_ns[order], pub_ns[order]
        start_arr, end_arr = start_arr[order], end_arr[order]
    datas = Payloads(blob if blob is not None else b"", start_arr, end_arr)
    data = TopicData(
        topic=channel.topic,
        type_name=type_name,
        log_time_ns=log_ns,
        publish_time_ns=pub_ns,
        complete=scan.complete,
        stop_reason=scan.stop_reason,
    )
    if len(datas) == 0:
        if type_name == FLOAT64:
            data.fields["data"] = np.zeros(0)
        return data
    if channel.message_encoding != "cdr":
        raise DecodeError(
            f"{topic}: message encoding {channel.message_encoding!r} is not supported (only cdr)"
        )
    if type_name == FLOAT64:
        data.fields["data"] = decode_float64(datas, topic)
        data.decoder = "vectorized"
    elif type_name == JOINT_STATE:
        decoded = _decode_joint_state_vectorized(datas)
        data.decoder = "vectorized"
        if decoded is None:
            objs = _decode_objects(datas, type_name, schema, topic)
            decoded = _decode_joint_state_objects(objs)
            data.decoder = "mcap_ros2"
        data.names = list(decoded.pop("names"))
        data.fields["stamp_ns"] = decoded["stamp_ns"]
        data.fields["stamp"] = decoded["stamp_ns"].astype(np.float64) * 1e-9
        for fname in ("position", "velocity", "effort"):
            data.fields[fname] = decoded[fname]
    elif type_name == TF_MESSAGE and (tf := _decode_tf_vectorized(datas)) is not None:
        data.fields.update(tf)
        data.messages = LazyMessages(list(datas), _decoder_for(type_name, schema))  # (objects when read)
        data.decoder = "vectorized"
    else:
        if not type_name:
            raise DecodeError(f"{topic}: channel has no schema; cannot decode")
        objs = _decode_objects(datas, type_name, schema, topic)
        data.messages = objs
        fields, data.sparse = _generic_fields(objs)
        data.fields.update(fields)
        data.decoder = "mcap_ros2"
    return data


def build_topic(scan: Scan, cids: List[int], topic: str, keep: bool) -> TopicData:
    """``topic`` (its channels ``cids``) of ``scan`` as arrays.

    A topic that cannot be decoded raises :class:`DecodeError`, or with
    ``keep`` comes back with its times, ``decoder="failed"`` and the reason
    in ``decode_error``.
    """
    try:
        return _build(scan, cids, topic)
    except DecodeError as exc:
        if not keep:
            raise
        channel = scan.channels[cids[0]]
        schema = scan.schemas.get(channel.schema_id)
        logs = array("q")
        for cid in cids:
            logs.extend(scan.accs[cid].log)
        times = np.sort(np.frombuffer(logs, dtype=np.int64)) if len(logs) else np.zeros(0, np.int64)
        return TopicData(
            topic=channel.topic,
            type_name=schema.name if schema else "",
            log_time_ns=times,
            publish_time_ns=times.copy(),
            decoder="failed",
            complete=scan.complete,
            stop_reason=scan.stop_reason,
            decode_error=str(exc),
        )

"""Read ROS 2 MCAP files into numpy arrays, tolerating files cut off mid-write.

The reader walks the records of the data section in file order with a small
MCAP parser of its own (record layout from the MCAP specification,
``website/docs/spec/index.md`` in foxglove/mcap). It does not need the summary
section, so it reads files whose writer was killed: it stops at the first
incomplete record, keeps every complete chunk before it and issues a
:class:`~msg_tools.errors.RecoveredBagWarning` saying how many messages it
recovered.

Decoding (CDR, XCDR1 as used by ROS 2 Jazzy's default middleware):

* ``std_msgs/msg/Float64`` -- vectorized: payload = 4-byte encapsulation header
  (``00 01`` little endian, ``00 00`` big endian, 2 option bytes) + float64;
* ``sensor_msgs/msg/JointState`` -- vectorized when every message has the same
  length, frame id, joint names and array sizes (the common case of a fixed
  robot); otherwise decoded message by message with ``mcap_ros2``;
* any other type -- decoded with ``mcap_ros2`` into a list of objects, plus
  arrays of their numeric fields.
"""

from __future__ import annotations

import mmap
import os
import struct
import warnings
import zlib
from array import array
from dataclasses import dataclass, field
from typing import IO, Any, Callable, Dict, Iterable, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import index as _index
from . import schemas as _schemas
from .errors import (
    BagNotFoundError,
    CorruptBagError,
    DecodeError,
    RecoveredBagWarning,
    TopicNotFoundError,
)

__all__ = [
    "Bag",
    "BagSummary",
    "TopicData",
    "TopicInfo",
    "list_topics",
    "read_bag",
    "read_topic",
    "read_topics",
    "summary",
]

Source = Union[str, "os.PathLike[str]", bytes, bytearray, memoryview, IO[bytes]]

MAGIC = b"\x89MCAP0\r\n"

# opcodes (MCAP specification)
_HEADER, _FOOTER, _SCHEMA, _CHANNEL, _MESSAGE, _CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
_METADATA, _DATA_END = 0x0C, 0x0F
_STATISTICS, _CHUNK_INDEX = 0x0B, 0x08

_u16 = struct.Struct("<H").unpack_from
_u32 = struct.Struct("<I").unpack_from
_u64 = struct.Struct("<Q").unpack_from
_rec_head = struct.Struct("<BQ").unpack_from  # opcode, length
_msg_head = struct.Struct("<HIQQ").unpack_from  # channel id, sequence, log time, publish time

#: largest uncompressed chunk accepted [bytes]; writers close chunks far below this
#: (rosbag2: 768 KiB by default, msg_tools: 128 KiB); a larger claim is damage
MAX_CHUNK_BYTES = 1 << 31

FLOAT64 = "std_msgs/msg/Float64"
JOINT_STATE = "sensor_msgs/msg/JointState"


# --------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------
@dataclass
class TopicData:
    """Messages of one topic as arrays.

    Attributes
    ----------
    topic : str
        Topic name as stored in the bag.
    type_name : str
        ROS 2 type, e.g. ``"sensor_msgs/msg/JointState"``.
    log_time_ns : numpy.ndarray of int64, shape (N,)
        Receive times [ns], sorted.
    publish_time_ns : numpy.ndarray of int64, shape (N,)
        Send times [ns].
    fields : dict of str to numpy.ndarray
        Decoded values. ``Float64``: ``data`` (N,). ``JointState``: ``stamp``
        (N,) [s], ``stamp_ns`` (N,) int64 [ns], ``position``/``velocity``/
        ``effort`` (N, J) (NaN where a message has no value). Other types: the
        numeric fields found in every message, by dotted path.
    names : list of str
        Joint names (columns of the JointState arrays); empty for other types.
    messages : list or None
        Decoded message objects for types without a vectorized decoder.
    decoder : str
        ``"vectorized"``, ``"mcap_ros2"``, ``"none"`` (no messages) or
        ``"failed"`` (see ``decode_error``).
    complete : bool
        False if the file was cut off (writer killed); see ``stop_reason``.
    stop_reason : str
        Why reading stopped early ("" if the file is complete).
    decode_error : str
        Why decoding failed, when :func:`read_bag` was asked to keep going.
    """

    topic: str
    type_name: str
    log_time_ns: np.ndarray
    publish_time_ns: np.ndarray
    fields: Dict[str, np.ndarray] = field(default_factory=dict)
    names: List[str] = field(default_factory=list)
    messages: Optional[List[Any]] = None
    decoder: str = "none"
    complete: bool = True
    stop_reason: str = ""
    decode_error: str = ""

    def __len__(self) -> int:
        return int(self.log_time_ns.shape[0])

    def __getattr__(self, name: str) -> np.ndarray:
        fields = self.__dict__.get("fields", {})
        if name in fields:
            return fields[name]
        raise AttributeError(
            f"{type(self).__name__} of {self.__dict__.get('topic', '?')} has no field {name!r}; "
            f"fields: {', '.join(fields) or 'none'}"
        )

    def __getitem__(self, name: str) -> np.ndarray:
        return getattr(self, name)

    @property
    def log_time_s(self) -> np.ndarray:
        """Receive times [s] (float64)."""
        return self.log_time_ns.astype(np.float64) * 1e-9


@dataclass
class TopicInfo:
    """One topic of a bag as listed by :func:`list_topics`.

    Attributes
    ----------
    topic, type_name : str
        Name and ROS 2 type.
    message_count : int
        Messages read.
    start_ns, end_ns : int or None
        First and last log time [ns].
    duration_s : float
        ``end - start`` [s].
    frequency_hz : float
        Mean rate ``(count - 1) / duration`` [Hz] (0 if undefined).
    message_encoding, schema_encoding : str
        ``"cdr"`` and ``"ros2msg"`` for ROS 2 bags.
    offered_qos_profiles : str
        The channel's QoS YAML ("" if absent).
    """

    topic: str
    type_name: str
    message_count: int
    start_ns: Optional[int]
    end_ns: Optional[int]
    duration_s: float
    frequency_hz: float
    message_encoding: str
    schema_encoding: str
    offered_qos_profiles: str = ""



def merged_metadata(metadata: List[Tuple[str, Dict[str, str]]], name: str) -> Dict[str, str]:
    """Merged key/values of all metadata records called ``name`` (later records win)."""
    merged: Dict[str, str] = {}
    for record_name, values in metadata:
        if record_name == name:
            merged.update(values)
    return merged


@dataclass
class BagSummary:
    """What :func:`summary` finds in a bag.

    Attributes
    ----------
    path : str
        File read.
    size_bytes : int
        File size [bytes].
    profile, library : str
        MCAP header fields.
    topics : list of TopicInfo
        In channel order.
    metadata : list of (str, dict)
        Metadata records in file order: name and key/value strings.
    message_count : int
        Messages read.
    start_ns, end_ns : int or None
        First and last log time [ns].
    duration_s : float
        [s].
    chunk_count : int
        Complete chunks read.
    compression : list of str
        Chunk compressions used (``"zstd"``, ``""`` for none, ...).
    complete : bool
        False if the file was cut off; ``stop_reason`` says where.
    stop_reason : str
        "" for a complete file.
    damage : list of str
        Where the data disagrees with the file's summary section (a chunk
        missing, duplicated or corrupt); empty for a sound file.
    from_summary : bool
        True when read from the summary section alone (no scan of the data).
    """

    path: str
    size_bytes: int
    profile: str
    library: str
    topics: List[TopicInfo]
    metadata: List[Tuple[str, Dict[str, str]]]
    message_count: int
    start_ns: Optional[int]
    end_ns: Optional[int]
    duration_s: float
    chunk_count: int
    compression: List[str]
    complete: bool
    stop_reason: str
    damage: List[str] = field(default_factory=list)
    from_summary: bool = False

    def metadata_dict(self, name: str) -> Dict[str, str]:
        """Return the merged key/values of all metadata records called ``name``."""
        return merged_metadata(self.metadata, name)


# --------------------------------------------------------------------------
# low-level record scan
# --------------------------------------------------------------------------
@dataclass
class _Schema:
    id: int
    name: str
    encoding: str
    data: bytes


@dataclass
class _Channel:
    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: Dict[str, str]


class _Acc:
    """Per-channel accumulator of times and (optionally) payloads.

    Payloads are appended to one ``bytearray`` with their end offsets, which
    keeps memory near the payload size and lets fixed-size messages be viewed
    as an (N, L) byte matrix without copying.
    """

    __slots__ = ("log", "pub", "blob", "ends")

    def __init__(self, keep_data: bool):
        self.log = array("q")
        self.pub = array("q")
        self.blob: Optional[bytearray] = bytearray() if keep_data else None
        self.ends = array("q")


class _Payloads:
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


def _read_str(buf: Any, off: int) -> Tuple[str, int]:
    (n,) = _u32(buf, off)
    off += 4
    return bytes(buf[off : off + n]).decode("utf-8"), off + n


def _read_map(buf: Any, off: int) -> Tuple[Dict[str, str], int]:
    (n,) = _u32(buf, off)
    off += 4
    end = off + n
    out: Dict[str, str] = {}
    while off < end:
        key, off = _read_str(buf, off)
        value, off = _read_str(buf, off)
        out[key] = value
    if off != end:
        raise ValueError("map length mismatch")
    return out, end


class _Scan:
    """Walk an MCAP byte buffer record by record, tolerating truncation.

    Parameters
    ----------
    buf : bytes-like
        Whole file.
    name : str
        File name for messages.
    want : callable(topic) -> bool, optional
        Channels whose topic passes are accumulated (all if None).
    keep_data : bool
        Keep message payloads (else only times).
    """

    def __init__(
        self,
        buf: Any,
        name: str,
        want: Optional[Callable[[str], bool]] = None,
        keep_data: bool = True,
    ):
        self.buf = buf
        self.name = name
        self.want = want
        self.keep_data = keep_data
        self.profile = ""
        self.library = ""
        self.schemas: Dict[int, _Schema] = {}
        self.channels: Dict[int, _Channel] = {}
        self.accs: Dict[int, _Acc] = {}
        self.metadata: List[Tuple[str, Dict[str, str]]] = []
        self.chunk_count = 0
        self.compression: List[str] = []
        self.complete = False
        self.stop_reason = ""
        self.message_count = 0
        self.bytes_read = 0
        self.data_crc = "none"  # the data section's CRC: "ok", "bad" or "none" (not written)
        self.damage: List[str] = []

    # -- records ----------------------------------------------------------
    def _schema(self, body: Any) -> None:
        (sid,) = _u16(body, 0)
        name, off = _read_str(body, 2)
        encoding, off = _read_str(body, off)
        (n,) = _u32(body, off)
        data = bytes(body[off + 4 : off + 4 + n])
        if sid != 0:
            self.schemas[sid] = _Schema(sid, name, encoding, data)

    def _channel(self, body: Any) -> None:
        cid, sid = struct.unpack_from("<HH", body, 0)
        topic, off = _read_str(body, 4)
        encoding, off = _read_str(body, off)
        meta, _ = _read_map(body, off)
        if cid not in self.channels:
            self.channels[cid] = _Channel(cid, sid, topic, encoding, meta)
            if self.want is None or self.want(topic):
                self.accs[cid] = _Acc(self.keep_data)

    def _message(self, buf: Any, start: int, end: int) -> None:
        cid, _seq, log_time, pub_time = _msg_head(buf, start)
        acc = self.accs.get(cid)
        self.message_count += 1
        if acc is not None:
            acc.log.append(log_time)
            acc.pub.append(pub_time)
            if acc.blob is not None:
                acc.blob += buf[start + 22 : end]
                acc.ends.append(len(acc.blob))

    def _chunk(self, body: Any, at: int) -> None:
        (uncompressed_size,) = _u64(body, 16)
        (crc,) = _u32(body, 24)
        compression, off = _read_str(body, 28)
        (n,) = _u64(body, off)
        off += 8
        payload = body[off : off + n]
        if uncompressed_size > MAX_CHUNK_BYTES:
            raise _Stop(f"chunk at byte {at} claims {uncompressed_size} bytes uncompressed "
                        f"(more than {MAX_CHUNK_BYTES}); damaged")
        if compression == "":
            records = payload
        elif compression == "zstd":
            import zstandard

            try:
                records = zstandard.ZstdDecompressor().decompress(
                    bytes(payload), max_output_size=uncompressed_size
                )
            except (zstandard.ZstdError, OverflowError, MemoryError, ValueError) as exc:
                raise _Stop(f"zstd chunk at byte {at} cannot be decompressed ({exc})") from None
        elif compression == "lz4":
            try:
                import lz4.frame  # type: ignore
            except ImportError:
                raise CorruptBagError(
                    f"{self.name}: chunk compressed with lz4, but the 'lz4' package is not installed"
                ) from None
            try:
                records = lz4.frame.decompress(bytes(payload))
            except (RuntimeError, ValueError, OverflowError, MemoryError) as exc:
                raise _Stop(f"lz4 chunk at byte {at} cannot be decompressed ({exc})") from None
        else:
            raise CorruptBagError(
                f"{self.name}: chunk at byte {at} uses unsupported compression {compression!r}"
            )
        if len(records) != uncompressed_size:
            raise _Stop(f"chunk at byte {at} has {len(records)} bytes, header says {uncompressed_size}")
        if crc != 0 and zlib.crc32(records) != crc:
            raise _Stop(f"chunk at byte {at} fails its CRC check")
        if compression not in self.compression:
            self.compression.append(compression)
        # check the record structure of the whole chunk before using any of it
        items: List[Tuple[int, int, int]] = []
        pos, size = 0, len(records)
        while pos < size:
            if pos + 9 > size:
                raise _Stop(f"chunk at byte {at} ends inside a record header")
            opcode, length = _rec_head(records, pos)
            start, end = pos + 9, pos + 9 + length
            if end > size:
                raise _Stop(f"chunk at byte {at} has a record longer than the chunk")
            items.append((opcode, start, end))
            pos = end
        for opcode, start, end in items:
            if opcode == _MESSAGE:
                self._message(records, start, end)
            elif opcode == _SCHEMA:
                self._schema(memoryview(records)[start:end])
            elif opcode == _CHANNEL:
                self._channel(memoryview(records)[start:end])
        self.chunk_count += 1

    # -- driver -----------------------------------------------------------
    def run(self) -> "_Scan":
        buf = self.buf
        size = len(buf)
        if size == 0:
            raise CorruptBagError(f"{self.name}: file is empty (0 bytes), not an MCAP file")
        head = bytes(buf[:8])
        if head != MAGIC:
            if len(head) < 8 and MAGIC.startswith(head):
                self.stop_reason = f"file ends after {size} bytes, inside the MCAP magic"
                return self
            raise CorruptBagError(f"{self.name}: not an MCAP file (starts with {head!r})")
        pos = 8
        try:
            while True:
                if pos + 9 > size:
                    raise _Stop(
                        "file ends without a footer" if pos == size
                        else f"file ends inside a record header at byte {pos}"
                    )
                opcode, length = _rec_head(buf, pos)
                start, end = pos + 9, pos + 9 + length
                if end > size:
                    raise _Stop(
                        f"record (opcode 0x{opcode:02x}) at byte {pos} needs {length} bytes, "
                        f"only {size - start} left"
                    )
                try:
                    self._record(opcode, buf, start, end, pos)
                except CorruptBagError:
                    raise
                except (struct.error, ValueError, UnicodeDecodeError, IndexError) as exc:
                    if pos == 8:
                        raise CorruptBagError(
                            f"{self.name}: first record cannot be parsed ({exc}); not an MCAP file?"
                        ) from None
                    raise _Stop(f"record (opcode 0x{opcode:02x}) at byte {pos} is malformed ({exc})")
                if opcode == _DATA_END:
                    (crc,) = _u32(buf, start) if length >= 4 else (0,)
                    # the data section's CRC (0: not computed): bytes before this record
                    self.data_crc = "none" if crc == 0 else ("ok" if zlib.crc32(buf[:pos]) == crc else "bad")
                pos = end
                self.bytes_read = pos
                if opcode == _DATA_END:
                    self.complete = True
                    return self
                if opcode == _FOOTER:
                    self.complete = True
                    return self
        except _Stop as stop:
            self.stop_reason = str(stop)
            return self

    def _record(self, opcode: int, buf: Any, start: int, end: int, at: int) -> None:
        if opcode == _CHUNK:
            self._chunk(memoryview(buf)[start:end], at)
        elif opcode == _MESSAGE:
            self._message(buf, start, end)
        elif opcode == _SCHEMA:
            self._schema(memoryview(buf)[start:end])
        elif opcode == _CHANNEL:
            self._channel(memoryview(buf)[start:end])
        elif opcode == _METADATA:
            body = memoryview(buf)[start:end]
            name, off = _read_str(body, 0)
            values, _ = _read_map(body, off)
            self.metadata.append((name, values))
        elif opcode == _HEADER:
            body = memoryview(buf)[start:end]
            self.profile, off = _read_str(body, 0)
            self.library, _ = _read_str(body, off)
        elif at == 8:
            raise ValueError(f"first record has opcode 0x{opcode:02x}, expected a header (0x01)")


class _Stop(Exception):
    """Internal: reading stops here; everything before is kept."""


class _Source:
    """Open a path, bytes or stream as one bytes-like buffer."""

    def __init__(self, source: Source):
        self._mmap: Optional[mmap.mmap] = None
        self._file: Optional[IO[bytes]] = None
        self.path: Optional[str] = None  # the file, when the source is one
        if isinstance(source, (bytes, bytearray, memoryview)):
            self.name = "<bytes>"
            self.buf: Any = source
        elif isinstance(source, (str, os.PathLike)):
            path = os.fspath(source)
            self.name = path
            if not os.path.exists(path):
                raise BagNotFoundError(path)
            if os.path.isdir(path):
                from .bagdir import bag_files

                found = bag_files(path)
                if len(found) != 1:
                    raise BagNotFoundError(
                        path, f"is a bag folder of {len(found)} files; read it with read_bag() "
                        "or one file at a time (msg_tools.bagdir.bag_files)"
                    )
                path = found[0]
                self.name = path
            try:
                self._file = open(path, "rb")
                self.path = path
                size = os.fstat(self._file.fileno()).st_size
                if size == 0:
                    self.buf = b""
                else:
                    self._mmap = mmap.mmap(self._file.fileno(), 0, access=mmap.ACCESS_READ)
                    self.buf = self._mmap
            except OSError as exc:
                self.close()
                raise CorruptBagError(f"cannot read {path}: {exc.strerror or exc}") from None
        elif hasattr(source, "read"):
            self.name = getattr(source, "name", "<stream>")
            if hasattr(source, "seek"):
                source.seek(0)
            self.buf = source.read()
        else:
            raise TypeError(f"cannot read a bag from {type(source).__name__}")

    @property
    def size(self) -> int:
        return len(self.buf)

    def close(self) -> None:
        if self._mmap is not None:
            try:
                self._mmap.close()
            except BufferError:  # a traceback still holds a view; the GC closes it
                pass
            self._mmap = None
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> "_Source":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _scan(source: Source, want: Optional[Callable[[str], bool]], keep_data: bool) -> Tuple[_Scan, int, str]:
    """Scan the data section; check what was read against the summary section.

    ``scan.damage`` lists where the data disagrees with a readable summary
    (the file was finished, so every difference is damage); a file without
    a readable summary is read up to its last complete chunk, with a
    :class:`RecoveredBagWarning` when it is incomplete.
    """
    with _Source(source) as src:
        scan = _Scan(src.buf, src.name, want=want, keep_data=keep_data).run()
        size, name = src.size, src.name
        indexed, reason = _index.read_summary(src.buf, path=src.path) if size else (None, "")
    scan.buf = None  # release the mapping
    scan.damage = []
    if indexed is not None:
        scan.damage = list(indexed.problems)
        if not scan.complete:
            scan.damage.insert(0, f"the data stops early ({scan.stop_reason})")
        elif scan.data_crc == "bad":
            scan.damage.insert(0, "the data section fails its CRC check")
        counts = {cid: len(acc.log) for cid, acc in scan.accs.items()}
        topics = {cid: ch.topic for cid, ch in scan.channels.items()}
        scan.damage += _index.count_problems(indexed, counts, topics)
    elif not scan.complete:
        warnings.warn(
            RecoveredBagWarning(
                f"{name} is incomplete ({scan.stop_reason}); recovered {scan.message_count} "
                f"messages in {scan.chunk_count} complete chunks"
            ),
            stacklevel=3,
        )
    elif scan.data_crc == "bad":  # finished file, summary unreadable, and the data fails its CRC
        scan.damage = ["the data section fails its CRC check"] + ([reason] if reason else [])
    elif reason:
        warnings.warn(RecoveredBagWarning(f"{name}: {reason}; read from the data section"), stacklevel=3)
    return scan, size, name


def damage_error(name: str, damage: List[str]) -> CorruptBagError:
    """The one-line error for a file whose data disagrees with its summary."""
    more = f" (and {len(damage) - 1} more problems)" if len(damage) > 1 else ""
    return CorruptBagError(f"{name} is damaged: {damage[0]}{more}")


# --------------------------------------------------------------------------
# CDR decoding
# --------------------------------------------------------------------------
def _kinds(headers: np.ndarray, topic: str, type_name: str) -> np.ndarray:
    """Return a bool array ``little_endian`` from (N, 2) encapsulation id bytes."""
    if headers.size == 0:
        return np.zeros(0, dtype=bool)
    bad = (headers[:, 0] != 0) | (headers[:, 1] > 1)
    if bad.any():
        i = int(np.argmax(bad))
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
    if not isinstance(datas, _Payloads):
        blob = b"".join(datas)
        ends = np.cumsum([len(d) for d in datas], dtype=np.int64)
        datas = _Payloads(blob, ends - np.array([len(d) for d in datas], dtype=np.int64), ends)
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


def _joint_layout(data: bytes) -> _JointLayout:
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


def _decode_joint_state_vectorized(datas: "_Payloads") -> Optional[Dict[str, Any]]:
    """Return decoded JointState arrays, or None if the messages differ in layout."""
    n = len(datas)
    try:
        layout = _joint_layout(datas[0])
    except (DecodeError, struct.error, UnicodeDecodeError):
        return None
    length = layout.length
    if datas.fixed_length() != length:
        return None
    raw = datas.matrix(length)
    cols = np.flatnonzero(layout.meaningful)
    reference = raw[0, cols]
    for block in range(0, n, 65536):  # bounded temporary memory
        if not (raw[block : block + 65536, cols] == reference).all():
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


def _decoder_for(type_name: str, schema: Optional[_Schema]) -> Callable[[bytes], Any]:
    from ._cdr import decoder_for

    if schema is not None and schema.encoding == "ros2msg" and schema.data:
        text = schema.data.decode("utf-8")
    else:
        text = _schemas.schema_text(type_name)
    try:
        return decoder_for(type_name, text)
    except Exception as exc:  # noqa: BLE001 - parser errors of many kinds
        raise DecodeError(f"cannot build a decoder for {type_name}: {exc}") from None


def _decode_objects(datas: Iterable[bytes], type_name: str, schema: Optional[_Schema], topic: str) -> List[Any]:
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
    numeric arrays are kept as tuples; arrays of messages are skipped.
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
        elif hasattr(value, "__slots__") and not _is_time(value):
            out.update(_numeric_leaves(value, path + "."))
    return out


def _generic_fields(objs: Sequence[Any]) -> Dict[str, np.ndarray]:
    if not objs:
        return {}
    leaves = [_numeric_leaves(m) for m in objs]
    common = set(leaves[0])
    for item in leaves[1:]:
        common &= set(item)
    out: Dict[str, np.ndarray] = {}
    for key in sorted(common, key=list(leaves[0]).index):
        values = [item[key] for item in leaves]
        if isinstance(values[0], tuple):
            if len({len(v) for v in values}) != 1:
                continue
            out[key] = np.asarray(values, dtype=np.float64)
        else:
            out[key] = np.asarray(values, dtype=np.float64)
    return out


def _topic_matcher(topics: Optional[Iterable[str]]) -> Optional[Callable[[str], bool]]:
    if topics is None:
        return None
    wanted = set()
    for t in topics:
        wanted.add(t)
        wanted.add(t if t.startswith("/") else "/" + t)
        wanted.add(t.lstrip("/"))
    return lambda topic: topic in wanted


def _resolve(topic: str, available: Sequence[str]) -> Optional[str]:
    if topic in available:
        return topic
    alt = "/" + topic if not topic.startswith("/") else topic.lstrip("/")
    return alt if alt in available else None


def _build(scan: _Scan, channel_ids: List[int], topic: str) -> TopicData:
    channel = scan.channels[channel_ids[0]]
    schema = scan.schemas.get(channel.schema_id)
    type_name = schema.name if schema is not None else ""
    if type_name:
        try:
            type_name = _schemas.normalize_type_name(type_name)
        except ValueError:
            pass
    logs, pubs, ends = array("q"), array("q"), array("q")
    accs = [scan.accs[cid] for cid in channel_ids]
    blob: Any = accs[0].blob if len(accs) == 1 else bytearray()
    for acc in accs:
        logs.extend(acc.log)
        pubs.extend(acc.pub)
        if len(accs) > 1:
            shift = len(blob)
            ends.extend(e + shift for e in acc.ends)
            blob += acc.blob or b""
        else:
            ends = acc.ends
    log_ns = np.frombuffer(logs, dtype=np.int64).copy() if len(logs) else np.zeros(0, np.int64)
    pub_ns = np.frombuffer(pubs, dtype=np.int64).copy() if len(pubs) else np.zeros(0, np.int64)
    end_arr = np.frombuffer(ends, dtype=np.int64).copy() if len(ends) else np.zeros(0, np.int64)
    start_arr = np.concatenate([[0], end_arr[:-1]]).astype(np.int64) if len(end_arr) else end_arr
    if log_ns.size > 1 and np.any(np.diff(log_ns) < 0):
        order = np.argsort(log_ns, kind="stable")
        log_ns, pub_ns = log_ns[order], pub_ns[order]
        start_arr, end_arr = start_arr[order], end_arr[order]
    datas = _Payloads(blob if blob is not None else b"", start_arr, end_arr)
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
    else:
        if not type_name:
            raise DecodeError(f"{topic}: channel has no schema; cannot decode")
        objs = _decode_objects(datas, type_name, schema, topic)
        data.messages = objs
        data.fields.update(_generic_fields(objs))
        data.decoder = "mcap_ros2"
    return data


def _build_or_keep(scan: _Scan, cids: List[int], topic: str, keep: bool) -> TopicData:
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


# --------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------
@dataclass
class Bag:
    """Topics of a bag read in one pass, with the bag's header and metadata.

    Attributes
    ----------
    path : str
        File read.
    profile, library : str
        MCAP header fields.
    metadata : list of (str, dict)
        Metadata records in file order.
    topics : dict of str to TopicData
        The topics read, keyed by their name in the bag.
    available : list of str
        Every topic in the bag.
    complete : bool
        False if the file was cut off.
    stop_reason : str
        Where reading stopped early ("" if complete).
    """

    path: str
    profile: str
    library: str
    metadata: List[Tuple[str, Dict[str, str]]]
    topics: Dict[str, TopicData]
    available: List[str]
    complete: bool
    stop_reason: str
    damage: List[str] = field(default_factory=list)

    def metadata_dict(self, name: str) -> Dict[str, str]:
        """Return the merged key/values of all metadata records called ``name``."""
        return merged_metadata(self.metadata, name)


def read_bag(
    source: Source,
    topics: Optional[Iterable[str]] = None,
    *,
    missing_ok: bool = False,
    keep_undecodable: bool = False,
    allow_damaged: bool = False,
) -> Bag:
    """Read topics (all by default) and the metadata records in one pass.

    Parameters and errors as :func:`read_topics`; with ``keep_undecodable``
    a topic whose messages cannot be decoded is returned with
    ``decoder="failed"`` and the reason in ``decode_error`` instead of raising.
    A file whose data disagrees with its own summary section (a chunk
    missing, duplicated or corrupt; message counts per channel differ)
    raises :class:`CorruptBagError` unless ``allow_damaged`` (then
    ``Bag.damage`` lists the problems).
    """
    topics = None if topics is None else list(topics)
    if isinstance(source, (str, os.PathLike)) and os.path.isdir(source):
        from .bagdir import bag_files, folder_damage

        files = bag_files(source)
        damage = folder_damage(source)
        if damage and not allow_damaged:
            raise damage_error(os.fspath(source), damage)
        if len(files) > 1:
            parts = [read_bag(f, topics, missing_ok=True, keep_undecodable=keep_undecodable,
                              allow_damaged=allow_damaged) for f in files]
            bag = _merge_bags(os.fspath(source), parts)
            bag.damage.extend(d for d in damage if d not in bag.damage)
            if topics is not None and not missing_ok:
                for topic in topics:
                    if _resolve(topic, bag.available) is None:
                        raise TopicNotFoundError(topic, bag.path, bag.available)
            return bag
    scan, _size, name = _scan(source, _topic_matcher(topics), keep_data=True)
    if scan.damage and not allow_damaged:
        raise damage_error(name, scan.damage)
    by_topic: Dict[str, List[int]] = {}
    for cid, channel in scan.channels.items():
        if cid in scan.accs:
            by_topic.setdefault(channel.topic, []).append(cid)
    available = sorted({c.topic for c in scan.channels.values()})
    if topics is not None and not missing_ok:
        for topic in topics:
            if _resolve(topic, available) is None:
                raise TopicNotFoundError(topic, name, available)
    return Bag(
        path=name,
        profile=scan.profile,
        library=scan.library,
        metadata=scan.metadata,
        topics={
            topic: _build_or_keep(scan, cids, topic, keep_undecodable)
            for topic, cids in by_topic.items()
        },
        available=available,
        complete=scan.complete,
        stop_reason=scan.stop_reason,
        damage=list(scan.damage),
    )


def _merge_topic(parts: List[TopicData]) -> TopicData:
    """One topic read from the consecutive files of a split bag, concatenated in time order."""
    first = next((p for p in parts if len(p)), parts[0])  # a file without its messages has no joints/fields
    failed = [p for p in parts if p.decode_error]
    merged = TopicData(
        topic=first.topic, type_name=first.type_name,
        log_time_ns=np.concatenate([p.log_time_ns for p in parts]),
        publish_time_ns=np.concatenate([p.publish_time_ns for p in parts]),
        names=list(first.names), decoder=first.decoder,
        complete=all(p.complete for p in parts),
        stop_reason="; ".join(p.stop_reason for p in parts if p.stop_reason),
        decode_error=failed[0].decode_error if failed else "",
    )
    if failed:
        merged.decoder = "failed"
        return merged
    if any(p.names != first.names or set(p.fields) != set(first.fields) for p in parts if len(p)):
        raise DecodeError(f"{first.topic}: the files of the split bag hold different joints or fields")
    for key in first.fields:
        merged.fields[key] = np.concatenate([p.fields[key] for p in parts if key in p.fields])
    if any(p.messages is not None for p in parts):
        merged.messages = [m for p in parts for m in (p.messages or [])]
    if merged.log_time_ns.size > 1 and np.any(np.diff(merged.log_time_ns) < 0):
        order = np.argsort(merged.log_time_ns, kind="stable")
        merged.log_time_ns, merged.publish_time_ns = merged.log_time_ns[order], merged.publish_time_ns[order]
        merged.fields = {k: v[order] for k, v in merged.fields.items()}
        if merged.messages is not None:
            merged.messages = [merged.messages[i] for i in order]
    return merged


def _merge_bags(name: str, parts: List["Bag"]) -> "Bag":
    """The files of a split bag as one :class:`Bag` (metadata records of the first file)."""
    by_topic: Dict[str, List[TopicData]] = {}
    for bag in parts:
        for topic, data in bag.topics.items():
            by_topic.setdefault(topic, []).append(data)
    return Bag(
        path=name, profile=parts[0].profile, library=parts[0].library, metadata=parts[0].metadata,
        topics={topic: _merge_topic(datas) for topic, datas in by_topic.items()},
        available=sorted({t for bag in parts for t in bag.available}),
        complete=all(b.complete for b in parts),
        stop_reason="; ".join(b.stop_reason for b in parts if b.stop_reason),
        damage=[d for b in parts for d in b.damage],
    )


def read_topics(
    source: Source, topics: Optional[Iterable[str]] = None, *, missing_ok: bool = False
) -> Dict[str, TopicData]:
    """Read several topics in one pass over the file.

    Parameters
    ----------
    source : path, bytes or binary stream
        The MCAP file.
    topics : iterable of str, optional
        Topics to read (a leading ``/`` may be omitted); all topics if None.
    missing_ok : bool
        Leave out requested topics that are not in the file instead of raising.

    Returns
    -------
    dict of str to TopicData
        Keyed by the topic name as stored in the bag.

    Raises
    ------
    BagNotFoundError, CorruptBagError, TopicNotFoundError, DecodeError
    """
    return read_bag(source, topics, missing_ok=missing_ok).topics


def read_topic(source: Source, topic: str) -> TopicData:
    """Read one topic of an MCAP file into numpy arrays.

    Parameters
    ----------
    source : path, bytes or binary stream
        The MCAP file. A file whose writer was killed is read up to its last
        complete chunk, with a :class:`~msg_tools.errors.RecoveredBagWarning`.
    topic : str
        Topic name (``"/joint_states"``; the leading ``/`` may be omitted).

    Returns
    -------
    TopicData

    Raises
    ------
    BagNotFoundError
        If the file does not exist.
    CorruptBagError
        If it is not an MCAP file.
    TopicNotFoundError
        If the topic is not in the file (the message lists the topics).

    Examples
    --------
    >>> js = read_topic("run.mcap", "/joint_states")        # doctest: +SKIP
    >>> js.position.shape, js.names                          # doctest: +SKIP
    ((5000, 3), ['crank', 'alternator', 'belt_span'])
    """
    result = read_topics(source, [topic])
    if not result:
        # the topic exists but none of its channels was accumulated (cannot happen)
        raise TopicNotFoundError(topic, getattr(source, "name", str(source)), [])
    return next(iter(result.values()))


def summary(source: Source) -> BagSummary:
    """Summarize a bag: header, topics with counts and rates, metadata records.

    A finished file is answered from its summary section, read with the mcap
    library (no data is read; the indexes are checked against the records
    they point at). A file without a readable summary (writer killed), or
    whose indexes do not match its records, is scanned record by record;
    ``damage`` then says what disagrees.
    """
    with _Source(source) as src:
        indexed, _reason = _index.read_summary(src.buf, path=src.path) if src.size else (None, "")
        size, name = src.size, src.name
    if indexed is not None and indexed.sound:
        return _summary_from_index(indexed, name, size)
    scan, size, name = _scan(source, None, keep_data=False)
    return _summary_from_scan(scan, name, size)


def _topic_info(topic: str, schema_name: str, schema_encoding: str, encoding: str, qos: str,
                count: int, start: Optional[int], end: Optional[int]) -> TopicInfo:
    duration = (end - start) * 1e-9 if count and start is not None and end is not None else 0.0
    return TopicInfo(
        topic=topic, type_name=schema_name, message_count=count, start_ns=start, end_ns=end,
        duration_s=duration,
        frequency_hz=(count - 1) / duration if count > 1 and duration > 0 else 0.0,
        message_encoding=encoding, schema_encoding=schema_encoding, offered_qos_profiles=qos,
    )


def _summary_from_index(indexed: "_index.IndexedSummary", name: str, size: int) -> BagSummary:
    s = indexed.summary
    stats = s.statistics
    merged: Dict[str, List[int]] = {}
    for cid, channel in s.channels.items():
        merged.setdefault(channel.topic, []).append(cid)
    topics: List[TopicInfo] = []
    for topic, cids in merged.items():
        channel = s.channels[cids[0]]
        schema = s.schemas.get(channel.schema_id)
        count = sum(stats.channel_message_counts.get(cid, 0) for cid in cids)
        times = [indexed.topic_times[cid] for cid in cids if cid in indexed.topic_times]
        if count and not times:  # no message indexes: the file's time range
            times = [(stats.message_start_time, stats.message_end_time)]
        start = min(t[0] for t in times) if count else None
        end = max(t[1] for t in times) if count else None
        topics.append(_topic_info(topic, schema.name if schema else "", schema.encoding if schema else "",
                                  channel.message_encoding, channel.metadata.get("offered_qos_profiles", ""),
                                  count, start, end))
    count = stats.message_count
    start_all = stats.message_start_time if count else None
    end_all = stats.message_end_time if count else None
    compression: List[str] = []
    for ci in s.chunk_indexes:
        if ci.compression not in compression:
            compression.append(ci.compression)
    return BagSummary(
        path=name, size_bytes=size, profile=indexed.profile, library=indexed.library,
        topics=topics, metadata=indexed.metadata, message_count=count,
        start_ns=start_all, end_ns=end_all,
        duration_s=((end_all - start_all) * 1e-9) if count else 0.0,  # type: ignore[operator]
        chunk_count=len(s.chunk_indexes), compression=compression,
        complete=True, stop_reason="", damage=[], from_summary=True,
    )


def _summary_from_scan(scan: _Scan, name: str, size: int) -> BagSummary:
    topics: List[TopicInfo] = []
    start_all: Optional[int] = None
    end_all: Optional[int] = None
    merged: Dict[str, List[int]] = {}
    for cid, channel in scan.channels.items():
        merged.setdefault(channel.topic, []).append(cid)
    for topic, cids in merged.items():
        channel = scan.channels[cids[0]]
        schema = scan.schemas.get(channel.schema_id)
        parts = [np.frombuffer(scan.accs[cid].log, dtype=np.int64) for cid in cids
                 if cid in scan.accs and len(scan.accs[cid].log)]
        logs = np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)
        count = int(logs.size)
        start = int(logs.min()) if count else None
        end = int(logs.max()) if count else None
        if start is not None:
            start_all = start if start_all is None else min(start_all, start)
            end_all = end if end_all is None else max(end_all, end)  # type: ignore[arg-type]
        topics.append(_topic_info(topic, schema.name if schema else "", schema.encoding if schema else "",
                                  channel.message_encoding, channel.metadata.get("offered_qos_profiles", ""),
                                  count, start, end))
    return BagSummary(
        path=name,
        size_bytes=size,
        profile=scan.profile,
        library=scan.library,
        topics=topics,
        metadata=scan.metadata,
        message_count=scan.message_count,
        start_ns=start_all,
        end_ns=end_all,
        duration_s=((end_all - start_all) * 1e-9) if start_all is not None else 0.0,  # type: ignore[operator]
        chunk_count=scan.chunk_count,
        compression=scan.compression,
        complete=scan.complete,
        stop_reason=scan.stop_reason,
        damage=list(scan.damage),
    )


def list_topics(source: Source) -> List[TopicInfo]:
    """Return the topics of a bag (see :class:`TopicInfo`)."""
    return summary(source).topics

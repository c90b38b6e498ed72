"""Scan an MCAP file record by record, tolerating files cut off mid-write.

:class:`Scan` walks the records of the data section in file order with a
small MCAP parser of its own (record layout from the MCAP specification,
``website/docs/spec/index.md`` in foxglove/mcap). It does not need the summary
section, so it reads files whose writer was killed: it stops at the first
incomplete record and keeps every complete chunk before it.
:func:`scan_source` runs it and checks what it read against the summary
section (:mod:`msg_tools.index`) when the file has a readable one: every
difference is then damage; a file without one that stops early gets a
:class:`~msg_tools.errors.RecoveredBagWarning` saying how many messages were
recovered.
"""

from __future__ import annotations

import mmap
import os
import stat
import struct
import threading
import warnings
import zlib
from array import array
from dataclasses import dataclass
from typing import IO, Any, Callable, Dict, List, Optional, Tuple, Union

from . import index as _index
from .errors import BagNotFoundError, CorruptBagError, RecoveredBagWarning
from .files import open_regular, regular_path

__all__ = ["MAGIC", "MAX_CHUNK_BYTES", "ChannelRecord", "SchemaRecord", "Scan", "Source", "SourceBuffer",
           "damage_error", "scan_source"]

Source = Union[str, "os.PathLike[str]", bytes, bytearray, memoryview, IO[bytes]]

MAGIC = b"\x89MCAP0\r\n"

# opcodes (MCAP specification)
_HEADER, _FOOTER, _SCHEMA, _CHANNEL, _MESSAGE, _CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
_METADATA, _DATA_END = 0x0C, 0x0F

_u16 = struct.Struct("<H").unpack_from
_u32 = struct.Struct("<I").unpack_from
_u64 = struct.Struct("<Q").unpack_from
_rec_head = struct.Struct("<BQ").unpack_from  # opcode, length
_msg_head = struct.Struct("<HIQQ").unpack_from  # channel id, sequence, log time, publish time
_rec_msg_head = struct.Struct("<BQHIQ").unpack_from  # opcode, length, channel id, sequence, log time

#: largest uncompressed chunk accepted [bytes]; writers close chunks far below this
#: (rosbag2: 768 KiB by default, msg_tools: 128 KiB); a larger claim is damage
MAX_CHUNK_BYTES = 1 << 31


@dataclass
class SchemaRecord:
    id: int
    name: str
    encoding: str
    data: bytes


@dataclass
class ChannelRecord:
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

    @property
    def count(self) -> int:
        return len(self.log)

    def span(self) -> Tuple[Optional[int], Optional[int]]:
        """First and last log time [ns] (None, None without messages)."""
        return (min(self.log), max(self.log)) if len(self.log) else (None, None)


class _Tally:
    """Per-channel message count and log-time range: constant memory whatever the file's length
    (what :func:`msg_tools.bag_summary.summary` needs from a scan)."""

    __slots__ = ("count", "first", "last")

    def __init__(self) -> None:
        self.count = 0
        self.first: Optional[int] = None
        self.last: Optional[int] = None

    def span(self) -> Tuple[Optional[int], Optional[int]]:
        return self.first, self.last



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



class Scan:
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
    keep_times : bool
        Keep every message's times (else, with ``keep_data`` False, only a
        count and the first and last log time per channel: bounded memory).
    """

    def __init__(
        self,
        buf: Any,
        name: str,
        want: Optional[Callable[[str], bool]] = None,
        keep_data: bool = True,
        keep_times: bool = True,
    ):
        self.buf = buf
        self.keep_times = keep_times or keep_data
        self.name = name
        self.want = want
        self.keep_data = keep_data
        self.profile = ""
        self.library = ""
        self.schemas: Dict[int, SchemaRecord] = {}
        self.channels: Dict[int, ChannelRecord] = {}
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
        self.checked_against_summary = False  # scan_source found a readable summary section
        self.recovered = ""  # what stopped the scan, when the chunk index read the rest (scan_source)

    # -- records ----------------------------------------------------------
    def _schema(self, body: Any) -> None:
        (sid,) = _u16(body, 0)
        name, off = _read_str(body, 2)
        encoding, off = _read_str(body, off)
        (n,) = _u32(body, off)
        data = bytes(body[off + 4 : off + 4 + n])
        if sid != 0:
            self.schemas[sid] = SchemaRecord(sid, name, encoding, data)

    def _channel(self, body: Any) -> None:
        cid, sid = struct.unpack_from("<HH", body, 0)
        topic, off = _read_str(body, 4)
        encoding, off = _read_str(body, off)
        meta, _ = _read_map(body, off)
        self._add_channel(cid, sid, topic, encoding, meta)

    def _add_channel(self, cid: int, sid: int, topic: str, encoding: str, meta: Dict[str, str]) -> None:
        if cid not in self.channels:
            self.channels[cid] = ChannelRecord(cid, sid, topic, encoding, meta)
            if self.want is None or self.want(topic):
                self.accs[cid] = _Acc(self.keep_data) if self.keep_times else _Tally()

    def _message(self, buf: Any, start: int, end: int) -> None:
        cid, _seq, log_time, pub_time = _msg_head(buf, start)
        acc = self.accs.get(cid)
        self.message_count += 1
        if acc is None:
            return
        if not self.keep_times:
            acc.count += 1
            if acc.first is None or log_time < acc.first:
                acc.first = log_time
            if acc.last is None or log_time > acc.last:
                acc.last = log_time
            return
        try:
            acc.log.append(log_time)
            acc.pub.append(pub_time)
        except OverflowError:  # (an int64 array: a time of 2^63 ns or later)
            raise CorruptBagError(f"{self.name}: a message at byte {start} is stamped {max(log_time, pub_time)} ns, "
                                  "beyond 2^63 ns (the year 2262)") from None
        if acc.blob is not None:
            acc.blob += buf[start + 22 : end]
            acc.ends.append(len(acc.blob))

    def _chunk(self, body: Any, at: int) -> None:
        records, compression = chunk_records(body, at, self.name)
        if compression not in self.compression:
            self.compression.append(compression)
        if not self.keep_times:
            self._tally_chunk(records, at)
            self.chunk_count += 1
            return
        if self._uniform_messages(records):
            self.chunk_count += 1
            return
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
            if opcode in (_MESSAGE, _SCHEMA, _CHANNEL):  # what a chunk may hold (message indexes are skipped)
                self._record(opcode, records, start, end, at)
        self.chunk_count += 1

    def _uniform_messages(self, records: Any) -> bool:
        """A chunk of message records all of one length (a recording of fixed-size messages, e.g. Float64),
        taken in whole-array operations instead of record by record; False (nothing taken) for any other
        (:func:`uniform_rows` checks the structure)."""
        import numpy as np

        rows = uniform_rows(records)
        if rows is None:
            return False
        length = rows.shape[1] - 9
        channel = rows[:, 9:11].copy().view("<u2")[:, 0]
        self.message_count += rows.shape[0]
        ids = np.unique(channel).tolist()
        for cid in ids:
            acc = self.accs.get(cid)
            if acc is None:
                continue
            mine = rows if len(ids) == 1 else rows[channel == cid]
            acc.log.frombytes(mine[:, 15:23].copy().view("<i8")[:, 0].astype(np.int64).tobytes())  # native order
            acc.pub.frombytes(mine[:, 23:31].copy().view("<i8")[:, 0].astype(np.int64).tobytes())
            if acc.blob is not None:
                payload = length - 22
                acc.blob += mine[:, 31:].tobytes()
                last = acc.ends[-1] if len(acc.ends) else 0
                acc.ends.frombytes((last + payload * np.arange(1, mine.shape[0] + 1, dtype=np.int64)).tobytes())
        return True

    def _tally_chunk(self, records: Any, at: int) -> None:
        """Count-only walk of a decompressed chunk (one ``unpack`` per message): the record
        structure of the whole chunk is checked before any of it is used, as in :meth:`_chunk`."""
        tallies: Dict[int, List[int]] = {}
        others: List[Tuple[int, int, int]] = []
        pos, size, n = 0, len(records), 0
        rec_head, msg_head = _rec_head, _rec_msg_head
        while pos < size:
            if pos + 9 > size:
                raise _Stop(f"chunk at byte {at} ends inside a record header")
            opcode, length = rec_head(records, pos)
            end = pos + 9 + length
            if end > size:
                raise _Stop(f"chunk at byte {at} has a record longer than the chunk")
            if opcode == _MESSAGE:
                if length < 22:
                    raise _Stop(f"chunk at byte {at} holds a message record of {length} bytes "
                                "(shorter than a message header)")
                cid, log_time = msg_head(records, pos)[2::2]
                tally = tallies.get(cid)
                if tally is None:
                    tallies[cid] = [1, log_time, log_time]
                else:
                    tally[0] += 1
                    if log_time < tally[1]:
                        tally[1] = log_time
                    elif log_time > tally[2]:
                        tally[2] = log_time
                n += 1
            elif opcode in (_SCHEMA, _CHANNEL):
                others.append((opcode, pos + 9, end))
            pos = end
        for opcode, start, end in others:
            self._record(opcode, records, start, end, at)
        self.message_count += n
        for cid, (count, first, last) in tallies.items():
            acc = self.accs.get(cid)
            if acc is None:
                continue
            acc.count += count
            acc.first = first if acc.first is None else min(acc.first, first)
            acc.last = last if acc.last is None else max(acc.last, last)

    # -- driver -----------------------------------------------------------
    def resume(self, summary: Any, metadata: List[Tuple[str, Dict[str, str]]]) -> int:
        """Read the chunks the summary section indexes that the scan did not reach; return how many.

        For a finished file whose scan stopped at a damaged record (a record
        length, the header): the chunk index (checked against the records by
        :mod:`msg_tools.index`) points past it. Schemas, channels and metadata
        records come from the summary. Raises :class:`_Stop` if an indexed
        chunk cannot be read (decompression, CRC, structure).
        """
        for sid, sc in summary.schemas.items():
            if sid != 0 and sid not in self.schemas:
                self.schemas[sid] = SchemaRecord(sid, sc.name, sc.encoding, bytes(sc.data))
        for cid, ch in summary.channels.items():
            self._add_channel(cid, ch.schema_id, ch.topic, ch.message_encoding, dict(ch.metadata))
        if len(metadata) > len(self.metadata):
            self.metadata = list(metadata)
        n = 0
        for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            at = ci.chunk_start_offset
            if at >= self.bytes_read:
                self._record(_CHUNK, self.buf, at + 9, at + ci.chunk_length, at)
                n += 1
        return n

    def run(self) -> "Scan":
        buf = self.buf
        size = len(buf)
        if size == 0:
            raise CorruptBagError(f"{self.name}: file is empty (0 bytes), not an MCAP file")
        head = bytes(buf[:8])
        if head != MAGIC:
            if len(head) < 8 and MAGIC.startswith(head):
                self.stop_reason = f"file ends after {size} bytes, inside the MCAP magic"
                return self
            if head.startswith(b"\x28\xb5\x2f\xfd"):  # zstd's magic number: a whole file compressed
                raise CorruptBagError(f"{self.name}: a zstd-compressed file, not MCAP (rosbag2's compression_mode "
                                      "file?): decompress it first ('zstd -d')")
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
                    self.data_crc = "none" if crc == 0 else ("ok" if _crc32(buf, pos) == crc else "bad")
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



_LOCAL = threading.local()  # each thread's zstd decompressor (a one-shot call resets it: reused chunk after chunk)


def _zstd_decompressor():
    """This thread's ``zstandard.ZstdDecompressor`` (made once per thread: an instance is not shared between
    threads; each ``decompress`` starts a new frame, so one that failed on a damaged chunk reads the next)."""
    decompressor = getattr(_LOCAL, "zstd", None)
    if decompressor is None:
        import zstandard

        decompressor = _LOCAL.zstd = zstandard.ZstdDecompressor()
    return decompressor


def chunk_records(body: Any, at: int, name: str) -> Tuple[Any, str]:
    """The records of the chunk record ``body`` (the bytes after its opcode and length) at byte ``at``,
    decompressed and CRC-checked, and its compression; :class:`_Stop` (or :class:`CorruptBagError`)
    when they cannot be read."""
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
            records = _zstd_decompressor().decompress(payload, max_output_size=uncompressed_size)
        except (zstandard.ZstdError, OverflowError, MemoryError, ValueError) as exc:
            raise _Stop(f"zstd chunk at byte {at} cannot be decompressed ({exc})") from None
    elif compression == "lz4":
        try:
            import lz4.frame  # type: ignore
        except ImportError:
            raise CorruptBagError(f"{name}: chunk compressed with lz4, but the 'lz4' package is not installed") from None
        try:
            records = lz4.frame.decompress(bytes(payload))
        except (RuntimeError, ValueError, OverflowError, MemoryError) as exc:
            raise _Stop(f"lz4 chunk at byte {at} cannot be decompressed ({exc})") from None
    else:
        raise CorruptBagError(f"{name}: chunk at byte {at} uses unsupported compression {compression!r}")
    if len(records) != uncompressed_size:
        raise _Stop(f"chunk at byte {at} has {len(records)} bytes, header says {uncompressed_size}")
    if crc != 0 and zlib.crc32(records) != crc:
        raise _Stop(f"chunk at byte {at} fails its CRC check")
    return records, compression


def uniform_rows(records: Any):
    """A chunk's records as an (N, 9 + length) uint8 matrix when they are all message records of one
    length (a recording of fixed-size messages, e.g. Float64), else None.

    The records then lie at a fixed stride: every opcode and length byte at its place in that stride
    is checked before any message is used, so the structure check is the record walk's."""
    import numpy as np

    size = len(records)
    if size < 9 + 22:
        return None
    opcode, length = _rec_head(records, 0)
    stride = 9 + length
    if opcode != _MESSAGE or length < 22 or size % stride:
        return None
    rows = np.frombuffer(records, dtype=np.uint8).reshape(size // stride, stride)
    if not (np.all(rows[:, 0] == _MESSAGE) and np.all(rows[:, 1:9].copy().view("<u8")[:, 0] == length)):
        return None
    return rows


def _crc32(buf: Any, end: int, step: int = 1 << 24) -> int:
    """CRC-32 of ``buf[:end]``, read in slices of ``step`` bytes (an mmap is never copied whole)."""
    crc = 0
    view = memoryview(buf)
    try:
        for at in range(0, end, step):
            crc = zlib.crc32(view[at:min(end, at + step)], crc)
    finally:
        view.release()
    return crc


class _Stop(Exception):
    """Internal: reading stops here; everything before is kept."""


class SourceBuffer:
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
            st = regular_path(path, folder=True)
            if stat.S_ISDIR(st.st_mode):
                from .bagdir import bag_files

                found = bag_files(path)
                if len(found) != 1:
                    raise BagNotFoundError(
                        path, f"is a bag folder of {len(found)} files; read it with read_bag() "
                        "or one file at a time (msg_tools.bagdir.bag_files)"
                    )
                path = found[0]
                self.name = path
            self._file = os.fdopen(open_regular(path), "rb")  # a FIFO would block open(): refused before it
            try:
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

    def __enter__(self) -> "SourceBuffer":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()



def scan_source(source: Source, want: Optional[Callable[[str], bool]], keep_data: bool,
                keep_times: bool = True) -> Tuple[Scan, int, str]:
    """Scan the data section; check what was read against the summary section.

    ``scan.damage`` lists where the data disagrees with a readable summary
    (the file was finished, so every difference is damage); a file without
    a readable summary is read up to its last complete chunk, with a
    :class:`RecoveredBagWarning` when it is incomplete.
    """
    with SourceBuffer(source) as src:
        scan = Scan(src.buf, src.name, want=want, keep_data=keep_data, keep_times=keep_times).run()
        size, name = src.size, src.name
        indexed, reason = _index.read_summary(src.buf, path=src.path) if size else (None, "")
        resumed = None
        if indexed is not None and not scan.complete and scan.stop_reason and _index.chunks_readable(indexed):
            try:  # a finished file damaged before its end: its chunk index reads what follows the damage
                resumed = scan.resume(indexed.summary, indexed.metadata)
            except _Stop:
                resumed = None
    scan.buf = None  # release the mapping
    scan.damage = []
    if indexed is not None:
        scan.checked_against_summary = True
        counts = {cid: acc.count for cid, acc in scan.accs.items()}
        topics = {cid: ch.topic for cid, ch in scan.channels.items()}
        if resumed is not None and not _index.count_problems(indexed, counts, topics, want):
            # every message the summary counts was read: the data is whole, the damage is said
            scan.recovered = "; ".join(indexed.problems + [
                f"the data stops early ({scan.stop_reason}); the {resumed} chunks after it read through "
                "the summary's chunk index"])
            scan.complete, scan.stop_reason = True, ""
            warnings.warn(RecoveredBagWarning(f"{name} is damaged but whole: {scan.recovered}; "
                                              f"{scan.message_count} messages, as the summary counts"), stacklevel=3)
            return scan, size, name
        scan.damage = list(indexed.problems)
        if not scan.complete:
            scan.damage.insert(0, f"the data stops early ({scan.stop_reason})")
        elif scan.data_crc == "bad":
            scan.damage.insert(0, "the data section fails its CRC check")
        scan.damage += _index.count_problems(indexed, counts, topics, want)
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
    elif reason.startswith("summary unreadable"):
        # the data section ends (Data End record) but the file's end does not read: the writer did not finish
        # (killed while writing the summary) or the end was cut off. Nothing checks the data: incomplete.
        scan.complete = False
        scan.stop_reason = f"its end is cut or damaged, {reason}; the data section reads to its Data End record"
        warnings.warn(RecoveredBagWarning(f"{name} is incomplete ({scan.stop_reason}); recovered "
                                          f"{scan.message_count} messages in {scan.chunk_count} complete chunks"),
                      stacklevel=3)
    elif reason:
        warnings.warn(RecoveredBagWarning(f"{name}: {reason}; read from the data section"), stacklevel=3)
    return scan, size, name



def damage_error(name: str, damage: List[str]) -> CorruptBagError:
    """The one-line error for a file whose data disagrees with its summary."""
    more = f" (and {len(damage) - 1} more problems)" if len(damage) > 1 else ""
    return CorruptBagError(f"{name} is damaged: {damage[0]}{more}")

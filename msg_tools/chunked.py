"""One topic of a finished MCAP file read a few chunks at a time (memory bounded by the chunks read, not the file).

:func:`topic_chunks` opens a file whose summary section is readable and sound
(its chunk index checked against the records, :mod:`msg_tools.index`) and
whose chunks holding the topic follow each other in time (each starts no
earlier than the one before ends: a recorder writing in receive order).
:meth:`ChunkedTopic.read` then decodes chunks ``i .. j - 1`` into a
:class:`~msg_tools.results.TopicData`, the same arrays :func:`msg_tools.read_topic`
holds for those messages (concatenated in file order, stably sorted by log
time). Any other file: None and the reason (read it whole instead).
"""

from __future__ import annotations

import os
from typing import List, Optional, Tuple

import numpy as np

from . import index as _index
from .decode import build_topic
from .errors import CorruptBagError
from .files import open_regular
from .results import TopicData
from .scan import _CHUNK, _MESSAGE, Scan, _Stop, SchemaRecord, SourceBuffer, chunk_records

__all__ = ["ChunkedTopic", "topic_chunks"]

#: a message record of a ``std_msgs/Float64`` (opcode, record length, channel, log time, then the CDR: its
#: encapsulation's first two bytes ``00 01``, little endian, two option bytes, the double): 9 + 22 + 12 bytes
_FLOAT64_RECORD = np.dtype({"names": ["opcode", "length", "channel", "log_time", "encapsulation", "value"],
                            "formats": ["u1", "<u8", "<u2", "<i8", "<u2", "<f8"], "offsets": [0, 1, 9, 15, 31, 35],
                            "itemsize": 9 + 22 + 12})


class ChunkedTopic:
    """The chunks of a file that hold one topic: ``starts``/``ends`` [ns] (the chunks' first and last
    message log times, int64, in file order); :meth:`read` decodes a run of them."""

    def __init__(self, path: str, summary, cids: List[int], topic: str, chunks: list):
        self.path, self.topic, self._cids, self._fd = path, topic, cids, None
        self._fd = open_regular(path)  # chunks are read with pread: a mapping would keep every page read resident
        self._offsets = [(int(c.chunk_start_offset), int(c.chunk_length)) for c in chunks]
        try:
            self.starts = np.array([int(c.message_start_time) for c in chunks], dtype=np.int64)
            self.ends = np.array([int(c.message_end_time) for c in chunks], dtype=np.int64)
        except OverflowError:
            self.close()
            raise CorruptBagError(f"{path}: {topic}'s messages are stamped beyond 2^63 ns (the year 2262)") from None
        self._summary = summary

    def __len__(self) -> int:
        return len(self._offsets)

    def read(self, i: int, j: int) -> TopicData:
        """The topic's messages in chunks ``i .. j - 1`` (file order)."""
        scan = Scan(b"", self.path, want=lambda topic: topic == self.topic, keep_data=True)
        for sid, sc in self._summary.schemas.items():
            if sid != 0:
                scan.schemas[sid] = SchemaRecord(sid, sc.name, sc.encoding, bytes(sc.data))
        for cid, ch in self._summary.channels.items():
            scan._add_channel(cid, ch.schema_id, ch.topic, ch.message_encoding, dict(ch.metadata))
        for at, length in self._offsets[i:j]:
            try:
                scan._record(_CHUNK, self._record(at, length), 9, length, at)
            except _Stop as exc:
                raise CorruptBagError(f"{self.path}: {exc}") from None
        scan.complete = True
        return build_topic(scan, self._cids, self.topic, False)

    def float64(self, k: int) -> Tuple[np.ndarray, np.ndarray]:
        """Log times [ns] (int64) and values of ``std_msgs/Float64`` messages in chunk ``k``: the arrays of
        :meth:`read` (stably sorted by log time), taken from the records' columns when the chunk holds only
        this topic's messages, all little-endian CDR of one length; else through :meth:`read`."""
        at, length = self._offsets[k]
        record = self._record(at, length)
        try:
            records = chunk_records(memoryview(record)[9:], at, self.path)[0]
        except _Stop as exc:
            raise CorruptBagError(f"{self.path}: {exc}") from None
        del record
        size = len(records)
        if size and size % _FLOAT64_RECORD.itemsize == 0:
            # every record at its place in the stride checked (a message, of this length, of this topic's
            # channels, little-endian CDR) before any value is used: the record walk's structure check
            rows = np.frombuffer(records, dtype=_FLOAT64_RECORD)
            channel = rows["channel"]
            if (np.all(rows["opcode"] == _MESSAGE) and np.all(rows["length"] == _FLOAT64_RECORD.itemsize - 9)
                    and np.all(rows["encapsulation"] == 0x0100)
                    and (np.all(channel == self._cids[0]) if len(self._cids) == 1 else np.all(np.isin(channel, self._cids)))):
                log = rows["log_time"].astype(np.int64)
                values = rows["value"].astype(np.float64)
                if log.size > 1 and np.any(log[1:] < log[:-1]):
                    order = np.argsort(log, kind="stable")
                    log, values = log[order], values[order]
                return log, values
        data = self.read(k, k + 1)
        return np.asarray(data.log_time_ns, dtype=np.int64), np.asarray(data.data, dtype=np.float64)

    def _record(self, at: int, length: int) -> bytes:
        record = os.pread(self._fd, length, at)
        if len(record) != length:
            raise CorruptBagError(f"{self.path}: chunk at byte {at} is cut off")
        return record

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __del__(self):
        self.close()


def topic_chunks(path, topic: str) -> Tuple[Optional[ChunkedTopic], str]:
    """:class:`ChunkedTopic` of ``topic`` in the file ``path``, or (None, why it must be read whole)."""
    if not isinstance(path, (str, os.PathLike)) or os.path.isdir(path):
        return None, "not a single file"
    with SourceBuffer(path) as src:
        indexed, reason = _index.read_summary(src.buf, path=src.path) if src.size else (None, "empty")
    try:
        if indexed is None or not indexed.sound or not _index.chunks_readable(indexed):
            raise LookupError(reason or "no sound summary section")
        summary = indexed.summary
        cids = sorted(cid for cid, ch in summary.channels.items() if ch.topic == topic)
        if not cids:
            raise LookupError(f"no channel {topic}")
        chunks = sorted((c for c in summary.chunk_indexes if any(cid in c.message_index_offsets for cid in cids)),
                        key=lambda c: c.chunk_start_offset)
        if not chunks:
            raise LookupError(f"no chunk holds {topic}")
        for a, b in zip(chunks, chunks[1:]):
            if b.message_start_time < a.message_end_time:
                raise LookupError("chunks overlap in time")
        return ChunkedTopic(os.fspath(path), summary, cids, topic, chunks), ""
    except LookupError as exc:
        return None, str(exc)

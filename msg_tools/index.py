"""The summary section of an MCAP file: read with the mcap library, checked against the file.

A finished file ends with a summary section (schemas, channels, statistics
with per-channel message counts, chunk and metadata indexes) that the mcap
library's seeking reader (:func:`mcap.reader.make_reader`,
``get_summary()``) reads from the footer without touching the data. This
module reads it that way, checks that the indexes agree with the records
they point at, and answers ``msg-tools info --summary-only`` from it; by
default ``info`` (and every reader) also scans the data record by record
(:mod:`msg_tools.scan`) and compares it with this summary.

Checks (cheap: one small read per chunk):

* every chunk index points at a chunk record of the indexed length, whose
  header carries the indexed start and end times;
* every message index offset of a chunk points at a message index record of
  that channel;
* the statistics agree with the indexes (chunk count, sum of per-channel
  counts).

A chunk removed from or duplicated in the data section moves every later
chunk, so the indexes no longer point at chunks: that is reported as
damage. Comparing the messages actually read with the per-channel counts
(:func:`count_problems`) catches what the indexes cannot.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional, Tuple

from .errors import NotAFileError
from .files import open_regular

__all__ = ["IndexedSummary", "chunks_readable", "count_problems", "read_summary"]

_CHUNK, _MESSAGE_INDEX = 0x06, 0x07
_rec_head = struct.Struct("<BQ").unpack_from
_u64 = struct.Struct("<Q").unpack_from
_u32 = struct.Struct("<I").unpack_from
_u16 = struct.Struct("<H").unpack_from


class _BufferStream:
    """A read-only, seekable file object over a bytes-like buffer (an mmap): reads never
    allocate more than what is left, whatever length a damaged record claims."""

    def __init__(self, buf: Any):
        self._buf = buf
        self._pos = 0

    def read(self, n: int = -1) -> bytes:
        end = len(self._buf) if n is None or n < 0 else min(len(self._buf), self._pos + n)
        data = bytes(self._buf[self._pos:end])
        self._pos = max(self._pos, end)
        return data

    def seek(self, offset: int, whence: int = 0) -> int:
        base = {0: 0, 1: self._pos, 2: len(self._buf)}[whence]
        pos = base + offset
        if pos < 0:
            raise ValueError(f"seek to byte {pos} before the start of the file")
        self._pos = pos
        return pos

    def tell(self) -> int:
        return self._pos

    def seekable(self) -> bool:
        return True

    def readable(self) -> bool:
        return True


@dataclass
class IndexedSummary:
    """What the summary section says, and whether the file agrees with it.

    Attributes
    ----------
    summary : mcap.summary.Summary
        As the mcap library read it.
    metadata : list of (str, dict)
        Metadata records, read through the metadata indexes.
    problems : list of str
        Where the indexes and the records disagree (empty for a sound file).
    topic_times : dict of int to (int, int)
        First and last log time [ns] of each channel, from the message
        indexes of its first and last chunks (chunk times if the file has no
        message indexes).
    """

    summary: Any
    profile: str = ""
    library: str = ""
    metadata: List[Tuple[str, Dict[str, str]]] = field(default_factory=list)
    problems: List[str] = field(default_factory=list)
    topic_times: Dict[int, Tuple[int, int]] = field(default_factory=dict)

    @property
    def sound(self) -> bool:
        return not self.problems


def read_summary(buf: Any, *, path: Optional[str] = None,
                 check: bool = True) -> Tuple[Optional[IndexedSummary], str]:
    """Read the summary section of the MCAP file in ``buf`` with the mcap library.

    Parameters
    ----------
    buf : bytes-like
        The whole file (an mmap for files): the checks read from it.
    path : str, optional
        The file itself: the library then reads through a buffered file
        object (fast); without it, through a view of ``buf``.
    check : bool
        Check the indexes against the records (:func:`_check`).

    Returns
    -------
    (IndexedSummary or None, str)
        None and the reason when the file has no readable summary (cut off,
        no footer, damaged summary section); the reason is "" for a file
        that was written without a summary.
    """
    import io

    from mcap.reader import SeekingReader

    if len(buf) < 8 + 9 + 20 + 8:
        return None, "file too short for a footer"
    try:
        stream: Any = os.fdopen(open_regular(path), "rb") if path else _BufferStream(buf)
    except (OSError, NotAFileError) as exc:
        return None, f"summary unreadable ({exc.strerror or exc})"
    try:
        # no record can be longer than the file: a damaged length fails at once, allocating nothing
        reader = SeekingReader(stream, record_size_limit=len(buf))
        summary = reader.get_summary()
        if summary is None:
            return None, ""
        if summary.statistics is None:
            return None, "summary section has no statistics record"
        metadata, metadata_problems = _metadata_records(buf, summary)
        try:
            header, header_problem = reader.get_header(), ""
        except Exception as exc:  # noqa: BLE001 - a damaged header record: the summary stands on its own
            header, header_problem = None, f"the header record cannot be read ({_first_line(exc)})"
    except Exception as exc:  # noqa: BLE001 - any parse error of a damaged or cut-off file
        return None, f"summary unreadable ({_first_line(exc)})"
    finally:
        if isinstance(stream, io.IOBase):
            stream.close()
    out = IndexedSummary(summary, header.profile if header else "", header.library if header else "", metadata)
    if check:
        out.problems = ([header_problem] if header_problem else []) + metadata_problems + _check(buf, summary)
    elif header_problem or metadata_problems:
        out.problems = ([header_problem] if header_problem else []) + metadata_problems
    out.topic_times = _topic_times(buf, summary, trust_message_indexes=not out.problems)
    return out, ""


def _first_line(exc: BaseException) -> str:
    text = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def chunks_readable(indexed: IndexedSummary) -> bool:
    """The chunk index can be followed: every problem found is the header record's or a metadata record's, not the
    indexes'."""
    return all(p.startswith(("the header record", "metadata record")) for p in indexed.problems)


def _metadata_records(buf: Any, summary: Any) -> Tuple[List[Tuple[str, Dict[str, str]]], List[str]]:
    """``(records, problems)``: each metadata record the metadata indexes point at, read on its own (one flipped byte
    in one made the whole summary unreadable: a finished file read as cut off, 0 messages), and what could not be."""
    from .scan import _read_map, _read_str

    records, problems = [], []
    for idx in summary.metadata_indexes:
        try:
            at, length = int(idx.offset), int(idx.length)
            if not (9 <= length and at + length <= len(buf)) or buf[at] != 0x0C:
                raise ValueError("no metadata record there")
            body = memoryview(buf)[at + 9 : at + length]
            name, off = _read_str(body, 0)
            values, _ = _read_map(body, off)
            records.append((name, values))
        except Exception as exc:  # noqa: BLE001 - a damaged record: said, the others kept
            problems.append(f"metadata record {str(idx.name)[:60]!r} at byte {idx.offset} cannot be read "
                            f"({_first_line(exc)})")
    return records, problems


def _summary_crc_ok(buf: Any) -> bool:
    """The footer's CRC of the summary section (0: not computed) matches the bytes."""
    import zlib

    size = len(buf)
    footer = size - 8 - 29  # footer record: opcode, length, summary_start, summary_offset_start, crc
    summary_start = _u64(buf, footer + 9)[0]
    (crc,) = _u32(buf, footer + 25)
    if crc == 0:
        return True
    begin = summary_start if summary_start else footer
    if not 0 < begin <= footer:
        return False
    return zlib.crc32(buf[begin:size - 8 - 4]) == crc


def _check(buf: Any, summary: Any) -> List[str]:
    problems: List[str] = []
    size = len(buf)
    if not _summary_crc_ok(buf):
        problems.append("the summary section fails its CRC check")
    stats = summary.statistics
    indexes = summary.chunk_indexes
    if stats.chunk_count != len(indexes) and indexes:  # (no chunk index at all is allowed: rosbag2's noChunkIndex)
        problems.append(f"statistics count {stats.chunk_count} chunks, the chunk index {len(indexes)}")
    total = sum(stats.channel_message_counts.values())
    if total != stats.message_count:
        problems.append(f"statistics count {stats.message_count} messages in all, {total} per channel")
    for k, ci in enumerate(indexes):
        at = ci.chunk_start_offset
        if at + 9 + 16 > size:
            problems.append(f"chunk {k} indexed at byte {at}, beyond the end of the file")
            continue
        opcode, length = _rec_head(buf, at)
        if opcode != _CHUNK or 9 + length != ci.chunk_length:
            problems.append(f"chunk {k} indexed at byte {at}, but no chunk of {ci.chunk_length} bytes is there")
            continue
        start, end = _u64(buf, at + 9)[0], _u64(buf, at + 17)[0]
        if (start, end) != (ci.message_start_time, ci.message_end_time):
            problems.append(f"chunk {k} at byte {at} holds other times than its index says")
            continue
        for cid, offset in ci.message_index_offsets.items():
            if offset + 11 > size or _rec_head(buf, offset)[0] != _MESSAGE_INDEX or _u16(buf, offset + 9)[0] != cid:
                problems.append(f"message index of channel {cid} for chunk {k} is not at byte {offset}")
                break
    return problems


def _message_index_times(buf: Any, offset: int) -> List[int]:
    """Log times in the message index record at ``offset`` (spec: channel id, array of (time, offset))."""
    (length,) = _u32(buf, offset + 11)
    start = offset + 15
    n = min(length, max(0, len(buf) - start)) // 16
    return [_u64(buf, start + 16 * i)[0] for i in range(n)]


def _topic_times(buf: Any, summary: Any, trust_message_indexes: bool) -> Dict[int, Tuple[int, int]]:
    """First and last log time of each channel, reading at most a few message index records."""
    out: Dict[int, Tuple[int, int]] = {}
    chunks = summary.chunk_indexes
    for cid in summary.statistics.channel_message_counts:
        having = [ci for ci in chunks if cid in ci.message_index_offsets] or []
        if not having:
            continue
        first = min(ci.message_start_time for ci in having)
        last = max(ci.message_end_time for ci in having)
        if trust_message_indexes:
            lo, hi = None, None
            for ci in sorted(having, key=lambda c: c.message_start_time):
                if lo is not None and ci.message_start_time >= lo:
                    break
                times = _message_index_times(buf, ci.message_index_offsets[cid])
                if times:
                    lo = min(times) if lo is None else min(lo, min(times))
            for ci in sorted(having, key=lambda c: c.message_end_time, reverse=True):
                if hi is not None and ci.message_end_time <= hi:
                    break
                times = _message_index_times(buf, ci.message_index_offsets[cid])
                if times:
                    hi = max(times) if hi is None else max(hi, max(times))
            first = lo if lo is not None else first
            last = hi if hi is not None else last
        out[cid] = (first, last)
    return out


def count_problems(indexed: IndexedSummary, counts: Dict[int, int], topics: Dict[int, str],
                   want: Optional[Callable[[str], bool]] = None) -> List[str]:
    """Channels whose messages read (``counts``) differ from the summary's per-channel counts,
    including channels the summary counts that the data never showed (``want``: the topics read)."""
    expected = indexed.summary.statistics.channel_message_counts
    channels = indexed.summary.channels
    out = []
    absent = {c for c, n in expected.items()
              if n and c not in counts and (want is None or (c in channels and want(channels[c].topic)))}
    for cid in sorted(set(counts) | absent):
        got, want = counts.get(cid, 0), expected.get(cid, 0)
        if got != want:
            name = topics.get(cid) or (channels[cid].topic if cid in channels else f"channel {cid}")
            out.append(f"{name} has {got} messages in the data, the summary says {want}")
    return out

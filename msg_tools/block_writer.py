"""Write long runs of fixed-size messages to MCAP a block at a time (numpy, no per-message Python).

:class:`BlockMcapWriter` is a :class:`~msg_tools.writer.Ros2McapWriter`
(same file layout, channels, metadata, rosbag2 record and summary) whose
records are written by :class:`BlockRecords` instead of ``mcap``'s
``Writer``, and which takes, besides single messages, a *block*:
:meth:`BlockMcapWriter.write_block` writes ``n`` time steps of ``T`` topics,
one message per topic and step, each topic's messages of one fixed size (an
``(n, size)`` byte array: CDR of messages with fixed-length strings and
arrays, as an offline run's outputs are). The message records of a block
are assembled as one byte array (a row per step: the ``T`` records in
topic order), cut into chunks of ``chunk_size`` bytes, and the chunks
compressed (zstd, lz4) and checksummed in worker threads (both release the
GIL) while the caller assembles the next chunk or computes the next block.
Each chunk is assembled in a buffer of its own (a few MiB, reused once its
chunk is written), so its records are still in the cache while their fields
are written, and memory holds at most :data:`MAX_IN_FLIGHT` chunks.

The MCAP written is the specification's (https://mcap.dev/spec): chunks
with their message index records, schema and channel records in the data
section, a data-section CRC, and a summary (schemas, channels, statistics,
chunk and metadata indexes, summary offsets). The non-message records are
``mcap.records``' own; the message, chunk and message-index records are
packed here with numpy, in the same byte layout.
"""

from __future__ import annotations

import struct
import threading
import zlib
from array import array
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from typing import Dict, List, Optional, Sequence

import numpy as np
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (DataEnd, Footer, Header, Metadata, MetadataIndex, Schema, Statistics,
                          SummaryOffset)
from mcap.records import Channel as ChannelRecord
from mcap.writer import MCAP0_MAGIC, CompressionType

from .writer import _MESSAGE_OVERHEAD, Ros2McapWriter

__all__ = ["BlockMcapWriter", "BlockRecords", "FixedMessages"]

#: zstd level of the block path: a fast level (negative: no entropy coding of literals). On an offline run's
#: records (rows of fixed-size messages, mostly constant bytes between the values) level -1 with a 128 KiB
#: window and a 8 K-entry hash table compresses ~1.3x as fast as level 1 for a file ~2 % larger; level 3
#: is ~2x slower again. Any zstd decoder reads it (the level is the compressor's choice only).
ZSTD_LEVEL = -1
#: window and hash table sizes (log2) of the block path's zstd (small: they stay in the cache)
ZSTD_WINDOW_LOG, ZSTD_HASH_LOG = 17, 13
_LOCAL = threading.local()  # each worker thread's zstd compressor (made once, reused chunk after chunk)
#: compressed chunks waiting to be written at most (bounds the memory of a long run)
MAX_IN_FLIGHT = 8
_CHUNK_HEAD = struct.Struct("<BQQQQI")  # opcode, record length, start, end, uncompressed size, CRC
_MESSAGE_HEAD = np.dtype([("opcode", "u1"), ("length", "<u8"), ("channel", "<u2"), ("sequence", "<u4"),
                          ("log_time", "<u8"), ("publish_time", "<u8")])
assert _MESSAGE_HEAD.itemsize == _MESSAGE_OVERHEAD


def _chunk_job(kind: CompressionType, data, start: int, end: int, index, message_index: bool) -> tuple:
    """A chunk as a worker thread makes it from its records ``data`` (messages of log times ``start`` ..
    ``end`` [ns]): ``(chunk record, its message index records, (channel, offset of its index record from the
    first), compression, CRC-32 of the two)``. ``index`` is ``{channel: (k, 2) [(log time, offset)]}`` or a
    function returning it (a block's, built here). The main thread then only writes them and combines the
    CRC into the data section's (:func:`crc32_combine`): nothing in a chunk depends on where it lands."""
    crc = zlib.crc32(data)
    if kind == CompressionType.ZSTD:
        out, name = _zstd().compress(data), "zstd"
    elif kind == CompressionType.LZ4:
        import lz4.frame

        out, name = lz4.frame.compress(data), "lz4"
    else:
        out, name = bytes(data), ""
    tail = struct.pack("<I", len(name)) + name.encode() + struct.pack("<Q", len(out))
    head = _CHUNK_HEAD.pack(Opcode.CHUNK, 8 + 8 + 8 + 4 + len(tail) + len(out), start, end, len(data), crc) + tail
    parts, places, at = [], [], 0
    if message_index:
        index = index() if callable(index) else index
        for channel in sorted(index):
            entries = np.ascontiguousarray(index[channel], dtype="<u8")
            parts += [struct.pack("<BQHI", Opcode.MESSAGE_INDEX, 2 + 4 + entries.nbytes, channel, entries.nbytes),
                      entries.tobytes()]
            places.append((channel, at))
            at += 15 + entries.nbytes
    records = b"".join(parts)
    return (head, out), records, places, name, zlib.crc32(records, zlib.crc32(out, zlib.crc32(head)))


def _zstd():
    """This thread's zstd compressor (:data:`ZSTD_LEVEL`, :data:`ZSTD_WINDOW_LOG`, :data:`ZSTD_HASH_LOG`)."""
    compressor = getattr(_LOCAL, "zstd", None)
    if compressor is None:
        import zstandard

        params = zstandard.ZstdCompressionParameters.from_level(ZSTD_LEVEL, window_log=ZSTD_WINDOW_LOG,
                                                                hash_log=ZSTD_HASH_LOG)
        compressor = _LOCAL.zstd = zstandard.ZstdCompressor(compression_params=params)
    return compressor


def _block_index(log_time: np.ndarray, base: int, row: int, channels: Sequence[int], offsets: Sequence[int],
                 head: Dict[int, list]) -> Dict[int, np.ndarray]:
    """The message index of a chunk of a block's rows: ``head`` (the open chunk's single messages, ``{channel:
    [(log time, offset)]}``) then, per channel, each row's ``log_time`` [ns] and the record's offset (``base``
    + ``row`` per row + the channel's offset in the row)."""
    m = log_time.size
    index = {ch: np.array(e, dtype="<u8").reshape(-1, 2) for ch, e in head.items()}
    starts = np.uint64(base) + np.arange(m, dtype=np.uint64) * np.uint64(row)
    for channel, offset in zip(channels, offsets):
        entries = np.empty((m, 2), dtype="<u8")
        entries[:, 0] = log_time
        entries[:, 1] = starts + np.uint64(offset)
        index[channel] = np.concatenate([index[channel], entries]) if channel in index else entries
    return index


_POLY = 0xEDB88320  # CRC-32 (zlib's), reflected


def _multmodp(a: int, b: int) -> int:
    """``a b`` modulo the CRC-32 polynomial (reflected bit order, as zlib's crc32.c; ``a`` nonzero)."""
    m, p = 1 << 31, 0
    while True:
        if a & m:
            p ^= b
            if not a & (m - 1):
                return p
        m >>= 1
        b = (b >> 1) ^ _POLY if b & 1 else b >> 1


def _x2n_table() -> list:
    p, table = 1 << 30, []  # x^1
    for _ in range(32):
        table.append(p)
        p = _multmodp(p, p)
    return table


_X2N = _x2n_table()


_TIMES: dict = {}  # k -> the four byte tables of the product by x^(8 2^k) (:func:`_times`)


def _times(k: int) -> tuple:
    """Tables of ``c -> c x^(8 2^k)`` modulo the polynomial: the product is linear in ``c``, so it is the XOR of
    one entry per byte of ``c`` (``tables[j][byte j of c]``), each entry the XOR of the products of its bits."""
    tables = _TIMES.get(k)
    if tables is None:
        bits = [_multmodp(_X2N[(k + 3) & 31], 1 << i) for i in range(32)]
        tables = []
        for j in range(4):
            table = [0] * 256
            for v in range(1, 256):
                low = v & -v
                table[v] = table[v ^ low] ^ bits[8 * j + low.bit_length() - 1]
            tables.append(table)
        tables = _TIMES[k] = tuple(tables)
    return tables


def crc32_combine(crc1: int, crc2: int, len2: int) -> int:
    """CRC-32 of ``A + B`` from ``crc1 = crc32(A)``, ``crc2 = crc32(B)`` and ``len(B)`` (zlib's crc32_combine:
    ``crc1`` times ``x^(8 len2)`` modulo the polynomial, plus ``crc2``; the product by each power of two of
    ``len2``'s bits through byte tables, :func:`_times`)."""
    c, k, n = int(crc1), 0, int(len2)
    while n and c:
        if n & 1:
            t0, t1, t2, t3 = _times(k)
            c = t0[c & 255] ^ t1[(c >> 8) & 255] ^ t2[(c >> 16) & 255] ^ t3[c >> 24]
        n >>= 1
        k += 1
    return c ^ crc2


class FixedMessages:
    """``n`` messages of one fixed-size layout: ``template`` (the CDR of one message) with ``fields``
    ``{name: (dtype, offset)}`` taking ``values[name]`` (one row per message).

    :meth:`rows` gives the ``(n, size)`` bytes. A block writer takes it instead of the bytes: its
    reused block holds the template from the previous block of the same layout, so only the fields
    are written (a ``JointState`` or ``TFMessage`` changes in a fifth of its bytes from step to step).
    """

    def __init__(self, template: bytes, fields: Dict[str, tuple], values: Dict[str, np.ndarray]):
        self.template, self.fields, self.values = bytes(template), dict(fields), dict(values)
        self.dtype = np.dtype({"names": list(self.fields), "formats": [f for f, _ in self.fields.values()],
                               "offsets": [o for _, o in self.fields.values()], "itemsize": len(self.template)})
        self.n = len(next(iter(self.values.values()))) if self.values else 0

    def __len__(self) -> int:
        return self.n

    @property
    def size(self) -> int:
        """Bytes per message."""
        return len(self.template)

    def __getitem__(self, key: slice) -> "FixedMessages":
        return FixedMessages(self.template, self.fields, {name: v[key] for name, v in self.values.items()})

    def write_into(self, view: np.ndarray) -> None:
        """The fields into ``view`` (``n`` messages of :attr:`dtype`, holding the template already)."""
        for name, values in self.values.items():
            view[name] = values

    def rows(self) -> np.ndarray:
        """The messages as the rows of an ``(n, size)`` uint8 array."""
        out = np.empty((self.n, self.size), dtype=np.uint8)
        out[...] = np.frombuffer(self.template, dtype=np.uint8)
        self.write_into(np.ndarray((self.n,), dtype=self.dtype, buffer=out, strides=(self.size,)))
        return out


class _Buffer:
    """A chunk's records being assembled or compressed: ``array`` (bytes), and the ``layout`` of the block
    whose constant bytes (record heads, FixedMessages' templates) its first ``ready`` rows hold already
    (kept while chunks of that layout follow: only the fields are written)."""

    __slots__ = ("array", "layout", "ready")

    def __init__(self, array: np.ndarray):
        self.array, self.layout, self.ready = array, (), 0


class BlockRecords:
    """The MCAP record writer behind :class:`BlockMcapWriter` (``mcap.writer.Writer``'s methods, plus blocks).

    Single messages go into an open chunk (closed by :meth:`flush`, by
    :meth:`add_block`, which writes it as the head of its first chunk, or
    when it reaches ``chunk_size``); schema and channel records go to the
    data section between chunks. Chunks are written in order; compression
    runs in a pool of two threads, at most :data:`MAX_IN_FLIGHT` chunks ahead
    of the file (a chunk's buffer is assembled again once it is written).
    """

    def __init__(self, stream, chunk_size: int = 1 << 20, compression: CompressionType = CompressionType.ZSTD,
                 index_types=None, enable_data_crcs: bool = True):
        from mcap.writer import IndexType

        self.stream = stream
        self.chunk_size = int(chunk_size)
        self.compression = compression
        self.message_index = index_types is None or bool(index_types & IndexType.MESSAGE)
        self.data_crcs = enable_data_crcs
        self.data_crc = 0
        self.schemas: Dict[int, Schema] = {}
        self.channels: Dict[int, ChannelRecord] = {}
        self.metadata_indexes: List[MetadataIndex] = []
        # the chunk indexes of the summary, compact (a long run has thousands): per chunk start, end, offset,
        # length, message index length, compressed and uncompressed size, and its (channel, offset) pairs
        self._chunks = array("Q")
        self._chunk_pairs = array("Q")
        self._chunk_compression = ""
        self.counts: Dict[int, int] = {}
        self.message_count = self.metadata_count = 0
        self.start_time: Optional[int] = None
        self.end_time = 0
        self._open = bytearray()  # records of the open chunk (single messages)
        self._open_index: Dict[int, list] = {}  # channel -> [(log time, offset)]
        self._pool: Optional[ThreadPoolExecutor] = None
        self._pending: deque = deque()
        # buffers of blocks' chunks whose chunk is written, to assemble the next ones in (:class:`_Buffer`)
        self._free: List[_Buffer] = []
        try:  # the file offset of the next record (counted from here on)
            self._offset = int(stream.tell())
        except (OSError, AttributeError, ValueError):
            self._offset = 0
        self._types: dict = {}  # a block layout's row types (:meth:`_row_types`)
        self._constants: dict = {}  # and its constant bytes

    # -------------------------------------------------------------- output
    def _emit(self, data) -> None:
        if self.data_crcs:
            self.data_crc = zlib.crc32(data, self.data_crc)
        self._put(data)

    def _put(self, data) -> None:
        """Write ``data`` (no CRC), counting the file offset (no ``tell`` per record)."""
        self.stream.write(data)
        self._offset += len(data)

    def _emit_record(self, record) -> None:
        builder = RecordBuilder()
        record.write(builder)
        self._emit(builder.end())

    def start(self, profile: str = "", library: str = "") -> None:
        self._emit(MCAP0_MAGIC)
        self._emit_record(Header(profile=profile, library=library))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema = Schema(id=len(self.schemas) + 1, name=name, encoding=encoding, data=data)
        self.schemas[schema.id] = schema
        self._write_pending(all_of_them=True)
        self._emit_record(schema)
        return schema.id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int, metadata: Dict[str, str]) -> int:
        channel = ChannelRecord(id=len(self.channels) + 1, topic=topic, message_encoding=message_encoding,
                                schema_id=schema_id, metadata=dict(metadata))
        self.channels[channel.id] = channel
        self._write_pending(all_of_them=True)
        self._emit_record(channel)
        return channel.id

    def add_metadata(self, name: str, data: Dict[str, str]) -> None:
        self._write_pending(all_of_them=True)
        builder = RecordBuilder()
        Metadata(name=name, metadata=data).write(builder)
        record = builder.end()
        self.metadata_indexes.append(MetadataIndex(offset=self._offset, length=len(record), name=name))
        self.metadata_count += 1
        self._emit(record)

    # ------------------------------------------------------------ messages
    def _times(self, first: int, last: int) -> None:
        self.start_time = first if self.start_time is None else min(self.start_time, first)
        self.end_time = max(self.end_time, last)

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0) -> None:
        self._open_index.setdefault(channel_id, []).append((log_time, len(self._open)))
        self._open += struct.pack("<BQHIQQ", Opcode.MESSAGE, 22 + len(data), channel_id, sequence, log_time,
                                  publish_time)
        self._open += data
        self.counts[channel_id] = self.counts.get(channel_id, 0) + 1
        self.message_count += 1
        self._times(log_time, log_time)
        if len(self._open) >= self.chunk_size:
            self._close_open()

    def _close_open(self) -> None:
        if self._open_index:
            index = {ch: np.array(entries, dtype="<u8").reshape(-1, 2) for ch, entries in self._open_index.items()}
            times = np.concatenate([e[:, 0] for e in index.values()])
            self._submit(bytes(self._open), int(times.min()), int(times.max()), index)
        self._open, self._open_index = bytearray(), {}

    def add_block(self, channels: Sequence[int], sequences: Sequence[int], log_time: np.ndarray,
                  payloads: Sequence[np.ndarray]) -> int:
        """``n`` steps of one message per channel: ``log_time`` (n,) [ns] (ascending; also the publish
        time), ``payloads[k]`` (n, size_k) uint8 (or :class:`FixedMessages`) the messages of ``channels[k]``, whose first sequence
        number is ``sequences[k]`` (then one more per step, modulo 2**32). Returns the bytes the block added to
        the open chunk (a short block that fits in its room joins it), 0 if it went into chunks of its own."""
        log_time = np.ascontiguousarray(log_time, dtype="<u8")
        n = log_time.size
        if not n:
            return 0
        sizes = [int(p.size if isinstance(p, FixedMessages) else p.shape[1]) for p in payloads]
        # one row per step: each channel's record (head fields, then the payload) at its offset
        row = sum(_MESSAGE_OVERHEAD + size for size in sizes)
        layout = (row, tuple((c, size, p.template if isinstance(p, FixedMessages) else None)
                             for c, size, p in zip(channels, sizes, payloads)))
        constant, variable, offsets = self._row_types(layout, payloads)
        for channel in channels:
            self.counts[channel] = self.counts.get(channel, 0) + n
        self.message_count += n * len(channels)
        self._times(int(log_time[0]), int(log_time[-1]))
        rows = max(1, self.chunk_size // row)
        # a short block (under a 16th of a chunk) that fits in the open chunk's room joins it, as single messages
        # do: one chunk of its own per short block (a re-simulation's passed-through message at every step cuts
        # the samples into blocks of one step) made a file ~2.3x the size, written ~2x slower than message by
        # message. A longer one is chunks of its own at once (a node recording's, ~one chunk: on disk as it comes)
        joins = n * row <= self.chunk_size // 16 and len(self._open) + n * row < self.chunk_size
        head_records, head_index = bytes(self._open), self._open_index
        self._open, self._open_index = bytearray(), {}
        # the variable bytes: (field, its values for the whole block as bytes, one np.void per row: a field of
        # several numbers is copied as one unit per row, much faster than numpy's sub-array copies)
        times = np.empty((n, 2), dtype="<u8")
        times[:, 0] = times[:, 1] = log_time  # log and publish time, the same in every record
        values = []
        for k, payload in enumerate(payloads):
            values.append((f"t{k}", times.view((np.void, 16)).reshape(n)))
            if isinstance(payload, FixedMessages):
                for name, (fmt, _) in payload.fields.items():
                    kind = np.dtype(fmt)
                    column = np.ascontiguousarray(payload.values[name], dtype=kind.base).reshape(n, -1)
                    values.append((f"p{k}.{name}", column.view((np.void, kind.itemsize)).reshape(n)))
            else:
                values.append((f"p{k}", payload.view((np.void, sizes[k])).reshape(n)))
        mask = np.uint64(0xFFFFFFFF)
        # chunk by chunk, each assembled in a buffer of its own (a chunk's records stay in the cache while
        # their fields are written) and compressed in a worker thread while the next one is assembled
        for a in range(0, n, rows):
            b = min(n, a + rows)
            m = b - a
            buffer = self._take(m * row)
            if buffer.layout != layout:
                buffer.layout, buffer.ready = layout, 0
            if buffer.ready < m:  # the constant bytes (record heads, FixedMessages' templates) of rows not written yet
                view = np.ndarray((m - buffer.ready,), dtype=constant, buffer=buffer.array, offset=buffer.ready * row)
                view[...] = self._constants[layout]
                buffer.ready = m
            view = np.ndarray((m,), dtype=variable, buffer=buffer.array)
            steps, numbers = np.arange(a, b, dtype=np.uint64), {}
            for k, first in enumerate(sequences):
                if first not in numbers:  # (every channel's, usually: one array)
                    numbers[first] = ((steps + np.uint64(first)) & mask).astype("<u4")
                view[f"s{k}"] = numbers[first]
            for name, column in values:
                view[name] = column[a:b]
            records = buffer.array[: m * row]
            if joins:  # (the whole block: a = 0, b = n)
                self._open = bytearray(head_records)
                self._open += records.data
                self._open_index = head_index
                starts = np.arange(m, dtype=np.uint64) * np.uint64(row) + np.uint64(len(head_records))
                for channel, offset in zip(channels, offsets):
                    entries = zip(log_time.tolist(), (starts + np.uint64(offset)).tolist())
                    self._open_index.setdefault(channel, []).extend(entries)
                self._free.append(buffer)  # (its rows copied)
                return m * row
            first, last = int(log_time[a]), int(log_time[b - 1])
            if head_records or head_index:  # the open chunk's messages come first
                records = np.concatenate([np.frombuffer(head_records, dtype=np.uint8), records])
                # (any of their times: short blocks joined them, and a clock that jumped back can follow)
                head_times = [t for e in head_index.values() for t, _ in e]
                first, last = min(first, *head_times), max(last, *head_times)
            # the chunk's message index: built by the worker thread
            index = partial(_block_index, log_time[a:b], len(head_records), row, channels, offsets, head_index)
            head_records, head_index = b"", {}
            self._submit(records, first, last, index, buffer)
        return 0

    def _row_types(self, layout: tuple, payloads) -> tuple:
        """(constant, variable, offsets) of a block's rows: the structured types of a row's constant bytes
        (each record's opcode, length and channel, each :class:`FixedMessages`' template) and of its variable
        fields (sequence ``s<k>``, log and publish time ``t<k>``, payload ``p<k>`` or its fields ``p<k>.<name>``),
        and each channel's record offset in the row. Built once per layout."""
        got = self._types.get(layout)
        if got is not None:
            return got
        row = layout[0]
        cn, cf, co, vn, vf, vo, offsets = [], [], [], [], [], [], []
        constants = []
        at = 0
        for k, ((channel, size, template), payload) in enumerate(zip(layout[1], payloads)):
            head = np.zeros(1, dtype=_MESSAGE_HEAD)
            head["opcode"], head["length"], head["channel"] = Opcode.MESSAGE, 22 + size, channel
            cn.append(f"h{k}"), cf.append((np.void, 11)), co.append(at)
            constants.append(head.view(np.uint8)[:11].tobytes())
            vn += [f"s{k}", f"t{k}"]
            vf += ["<u4", (np.void, 16)]
            vo += [at + 11, at + 15]
            if template is not None:
                cn.append(f"c{k}"), cf.append((np.void, size)), co.append(at + 31)
                constants.append(template)
                for name, (fmt, offset) in payload.fields.items():
                    vn.append(f"p{k}.{name}"), vf.append((np.void, np.dtype(fmt).itemsize)), vo.append(at + 31 + offset)
            else:
                vn.append(f"p{k}"), vf.append((np.void, size)), vo.append(at + 31)
            offsets.append(at)
            at += _MESSAGE_OVERHEAD + size
        constant = np.dtype({"names": cn, "formats": cf, "offsets": co, "itemsize": row})
        variable = np.dtype({"names": vn, "formats": vf, "offsets": vo, "itemsize": row})
        value = np.zeros(1, dtype=constant)
        for name, data in zip(cn, constants):
            value[name] = np.frombuffer(data, dtype=value.dtype[name])[0]
        self._constants[layout] = value[0]
        got = self._types[layout] = (constant, variable, offsets)
        return got

    def _take(self, size: int) -> "_Buffer":
        """A buffer of at least ``size`` bytes whose chunk is written (the oldest pending chunk is written
        first when :data:`MAX_IN_FLIGHT` are pending: memory holds at most that many chunks)."""
        while len(self._pending) >= MAX_IN_FLIGHT:
            self._write_oldest()
        free = self._free
        while free:
            buffer = free.pop()
            if buffer.array.size >= size:
                return buffer
        return _Buffer(np.empty(size, dtype=np.uint8))

    # -------------------------------------------------------------- chunks
    def _submit(self, records, start: int, end: int, index: Dict[int, np.ndarray], buffer=None) -> None:
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix="mcap-chunk")
        self._pending.append((self._pool.submit(_chunk_job, self.compression, records, start, end, index,
                                                self.message_index), buffer))
        self._write_pending(all_of_them=False)

    def _write_oldest(self) -> None:
        """Write the oldest pending chunk (waiting for its compression); its buffer is free again."""
        future, buffer = self._pending.popleft()
        self._write_chunk(*future.result())
        if buffer is not None:
            self._free.append(buffer)

    def _write_pending(self, all_of_them: bool) -> None:
        """Write the compressed chunks in order: those done (all with ``all_of_them``, waiting), and
        always enough that at most MAX_IN_FLIGHT stay."""
        pending = self._pending
        while pending and (all_of_them or len(pending) > MAX_IN_FLIGHT or pending[0][0].done()):
            self._write_oldest()

    def _write_chunk(self, chunk: tuple, index: bytes, places: list, compression: str, crc: int) -> None:
        """Write a chunk record and its message index records (:func:`_chunk_job`'s values; their CRC came
        from the worker: combined into the data section's, not computed again here)."""
        head, data = chunk
        offset = self._offset
        self._put(head)
        self._put(data)
        index_start = self._offset
        if index:
            self._put(index)
        if self.data_crcs:
            self.data_crc = crc32_combine(self.data_crc, crc, len(head) + len(data) + len(index))
        for channel, at in places:
            self._chunk_pairs.extend((channel, index_start + at))
        _, _, start, end, size, _ = _CHUNK_HEAD.unpack_from(head)
        self._chunks.extend((start, end, offset, index_start - offset, len(index), len(data), size, len(places)))
        self._chunk_compression = compression

    def chunk_index_records(self) -> bytes:
        """The chunk index records of the chunks written so far, packed (the layout of ``mcap.records.ChunkIndex``:
        a long run has thousands, which its record builder writes field by field at ~170 us each)."""
        name = self._chunk_compression.encode()
        tail = struct.Struct(f"<QI{len(name)}sQQ")
        parts, pairs = [], 0
        for k in range(0, len(self._chunks), 8):
            start, end, offset, length, index_length, compressed, size, n = self._chunks[k : k + 8]
            entries = b"".join(struct.pack("<HQ", self._chunk_pairs[pairs + 2 * j], self._chunk_pairs[pairs + 2 * j + 1])
                               for j in range(n))
            pairs += 2 * n
            body = (struct.pack("<QQQQI", start, end, offset, length, len(entries)) + entries
                    + tail.pack(index_length, len(name), name, compressed, size))
            parts += [struct.pack("<BQ", Opcode.CHUNK_INDEX, len(body)), body]
        return b"".join(parts)

    def flush(self) -> None:
        """Close the open chunk and write every chunk (waiting for their compression)."""
        self._close_open()
        self._write_pending(all_of_them=True)
        self.stream.flush()

    # --------------------------------------------------------------- finish
    def finish(self) -> None:
        """Write the last chunks, the data end and the summary (the stream stays open)."""
        try:
            self.flush()
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)
                self._pool = None
        self._emit_record(DataEnd(self.data_crc))
        summary_start = self._offset
        parts, offsets = [], []

        def group(opcode, records, packed=b""):
            builder = RecordBuilder()
            for record in records:
                record.write(builder)
            data = builder.end() + packed
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + sum(map(len, parts)),
                                         group_length=len(data)))
            parts.append(data)

        group(Opcode.SCHEMA, self.schemas.values())
        group(Opcode.CHANNEL, self.channels.values())
        group(Opcode.STATISTICS, [Statistics(
            message_count=self.message_count, schema_count=len(self.schemas), channel_count=len(self.channels),
            attachment_count=0, metadata_count=self.metadata_count, chunk_count=len(self._chunks) // 8,
            message_start_time=self.start_time or 0, message_end_time=self.end_time,
            channel_message_counts=dict(self.counts),
        )])
        group(Opcode.CHUNK_INDEX, [], self.chunk_index_records())
        group(Opcode.ATTACHMENT_INDEX, [])
        group(Opcode.METADATA_INDEX, self.metadata_indexes)
        summary_offset_start = summary_start + sum(map(len, parts))
        builder = RecordBuilder()
        for offset in offsets:
            offset.write(builder)
        summary = b"".join(parts) + builder.end()
        crc = zlib.crc32(summary)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start), crc)
        self.stream.write(summary)
        footer = RecordBuilder()
        Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc).write(footer)
        self.stream.write(footer.end())
        self.stream.write(MCAP0_MAGIC)


def checked_block(topics: Sequence[tuple], log_time_ns: np.ndarray, payloads: Sequence) -> list:
    """The payloads of a block of ``log_time_ns.size`` (> 0) steps as :meth:`BlockMcapWriter.write_block` writes
    them (uint8 arrays made contiguous, :class:`FixedMessages` as they are), after checking the block: times
    ``>= 0`` [ns] and ascending (a file's and a chunk's times are their first and last), one payload per topic, each
    ``(n, >= 4)`` bytes. A :class:`ValueError` names what is wrong."""
    n = log_time_ns.size
    if log_time_ns[0] < 0:
        raise ValueError(f"write_block: times must be >= 0 ns, got {int(log_time_ns[0])}")
    if n > 1 and bool((log_time_ns[1:] < log_time_ns[:-1]).any()):
        raise ValueError("write_block: times must be ascending")
    if len(payloads) != len(topics):
        raise ValueError(f"write_block: {len(topics)} topics need as many payloads, got {len(payloads)}")
    payloads = [p if isinstance(p, FixedMessages) else np.ascontiguousarray(p, dtype=np.uint8) for p in payloads]
    for (topic, _), p in zip(topics, payloads):
        shape = (len(p), p.size) if isinstance(p, FixedMessages) else p.shape
        if len(shape) != 2 or shape[0] != n or shape[1] < 4:
            raise ValueError(f"write_block: {topic}: payload must be ({n}, >= 4) bytes, got {shape}")
    return payloads


class BlockMcapWriter(Ros2McapWriter):
    """A :class:`~msg_tools.writer.Ros2McapWriter` that also writes blocks of fixed-size messages.

    Same arguments and file layout; :meth:`write_block` writes ``n`` steps of
    several topics at once (see the module docstring). ``flush_interval_s``
    closes chunks of single messages only, and of the short blocks (under a
    16th of a chunk) that joined them (a longer block's chunks are cut by size).
    """

    _records_class = BlockRecords

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._mcap.chunk_size = self._chunk_size  # a block's chunks: cut by size here

    def write_block(self, topics: Sequence[tuple], log_time_ns: np.ndarray, payloads: Sequence[np.ndarray]) -> bool:
        """``topics`` ``[(topic, type_name), ...]`` (declared with :meth:`add_topic` or here with the
        default QoS), ``log_time_ns`` (n,) ascending [ns] (also the publish time), ``payloads[k]``
        ``(n, size)`` uint8 (or :class:`FixedMessages`): the CDR of ``topics[k]``'s message at each time.
        True if the block joined the open chunk (short: see :meth:`BlockRecords.add_block`), False if it
        went into chunks of its own."""
        log_time_ns = np.asarray(log_time_ns, dtype=np.int64)
        n = log_time_ns.size
        if not n or not topics:  # (no messages: none one by one either)
            return False
        payloads = checked_block(topics, log_time_ns, payloads)
        with self._lock:
            self._check_writable()
            channels = [self._channel(topic, type_name, None) for topic, type_name in topics]
            try:
                joined = self._mcap.add_block([c.channel_id for c in channels],
                                              [(c.sequence + 1) & 0xFFFFFFFF for c in channels], log_time_ns, payloads)
            except OSError as exc:
                raise self._fail(exc) from exc
            for channel in channels:
                channel.sequence = (channel.sequence + n) & 0xFFFFFFFF
                channel.count += n
            self._message_count += n * len(channels)
            first, last = int(log_time_ns[0]), int(log_time_ns[-1])
            self._start_ns = first if self._start_ns is None else min(self._start_ns, first)
            self._end_ns = last if self._end_ns is None else max(self._end_ns, last)
            if joined:  # (the open chunk, closed by size or log time as for single messages)
                if self._chunk_t0_ns is None:
                    self._chunk_t0_ns = first
                self._after_message(last, joined - _MESSAGE_OVERHEAD)
            else:
                self._pending_bytes, self._chunk_t0_ns = 0, None  # the block closed the open chunk
        return bool(joined)

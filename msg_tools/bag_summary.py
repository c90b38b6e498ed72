"""Summarize a bag (header, topics with counts and rates, metadata records) without decoding it.

A finished file is answered from its summary section, read with the mcap
library's summary reader and checked against the records it points at
(:mod:`msg_tools.index`); a file without a readable or sound summary is
scanned record by record (:mod:`msg_tools.scan`), times only.
"""

from __future__ import annotations

from typing import Dict, List, Optional

from . import index as _index
from .results import BagSummary, TopicInfo
from .scan import Scan, Source, SourceBuffer, scan_source

__all__ = ["list_topics", "summary"]


def summary(source: Source, *, verify: bool = True) -> BagSummary:
    """Summarize a bag: header, topics with counts and rates, metadata records.

    With ``verify`` (default) the data section is scanned record by record
    (:func:`msg_tools.scan.scan_source`: record lengths, decompression, chunk
    CRCs, the data section's CRC) and checked against the summary section
    (chunk indexes pointing at their chunks, message counts per channel);
    ``damage`` lists every disagreement. The scan streams the file (an mmap,
    one chunk at a time) and keeps a count and a time range per channel, so
    its memory does not grow with the file.

    Without ``verify`` a finished file is answered from its summary section
    alone, read with the mcap library (fast; no data is read, only the
    indexes are checked against the records they point at): damage inside a
    chunk goes unseen. A file without a readable summary (writer killed), or
    whose indexes do not match its records, is scanned all the same.
    """
    if not verify:
        with SourceBuffer(source) as src:
            indexed, _reason = _index.read_summary(src.buf, path=src.path) if src.size else (None, "")
            size, name = src.size, src.name
        if indexed is not None and indexed.sound:
            return _summary_from_index(indexed, name, size)
    scan, size, name = scan_source(source, None, keep_data=False, keep_times=False)
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


def _summary_from_scan(scan: Scan, name: str, size: int) -> BagSummary:
    topics: List[TopicInfo] = []
    start_all: Optional[int] = None
    end_all: Optional[int] = None
    merged: Dict[str, List[int]] = {}
    for cid, channel in scan.channels.items():
        merged.setdefault(channel.topic, []).append(cid)
    for topic, cids in merged.items():
        channel = scan.channels[cids[0]]
        schema = scan.schemas.get(channel.schema_id)
        accs = [scan.accs[cid] for cid in cids if cid in scan.accs and scan.accs[cid].count]
        count = sum(acc.count for acc in accs)
        start = min(acc.span()[0] for acc in accs) if accs else None
        end = max(acc.span()[1] for acc in accs) if accs else None
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
        verified=scan.checked_against_summary,
        recovered=scan.recovered,
    )


def list_topics(source: Source, *, verify: bool = True) -> List[TopicInfo]:
    """Return the topics of a bag (see :class:`TopicInfo`; ``verify`` as :func:`summary`)."""
    return summary(source, verify=verify).topics

"""Read ROS 2 MCAP files into numpy arrays, tolerating files cut off mid-write: the public reader.

:func:`read_bag` (and :func:`read_topics`, :func:`read_topic` on it) reads the
wanted topics in one pass over a file, or over the files of a split bag
folder, and concatenates them in time order; :func:`summary` and
:func:`list_topics` describe a bag without decoding it. The work is done by:

* :mod:`msg_tools.scan` -- the record-by-record scan of the data section,
  recovery of cut-off files (up to the last complete chunk, with a
  :class:`~msg_tools.errors.RecoveredBagWarning`) and the check against the
  summary section (damage);
* :mod:`msg_tools.decode` -- vectorized CDR decoding (``Float64``,
  ``JointState``) and ``mcap_ros2`` for every other type;
* :mod:`msg_tools.bag_summary` -- summaries, from a count-only scan checked
  against the summary section, or (``verify=False``) from the summary section
  through the mcap library (:mod:`msg_tools.index`);
* :mod:`msg_tools.results` -- the dataclasses returned.
"""

from __future__ import annotations

import os
from typing import Callable, Dict, Iterable, List, Optional, Sequence

import numpy as np

from .bag_summary import list_topics, summary
from .decode import build_topic
from .errors import DecodeError, TopicNotFoundError
from .results import Bag, BagSummary, TopicData, TopicInfo
from .scan import Source, damage_error, scan_source

# importable from here as before the split (msg_tools.reader.FLOAT64, ...)
from .decode import FLOAT64, JOINT_STATE, decode_float64  # noqa: F401
from .results import merged_metadata  # noqa: F401
from .scan import MAGIC, MAX_CHUNK_BYTES  # noqa: F401

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
    scan, _size, name = scan_source(source, _topic_matcher(topics), keep_data=True)
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
            topic: build_topic(scan, cids, topic, keep_undecodable)
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
    generic = first.decoder == "mcap_ros2"  # (a type decoded message by message: its fields may differ by file)
    if any(p.names != first.names or (set(p.fields) != set(first.fields) and not generic) for p in parts if len(p)):
        raise DecodeError(f"{first.topic}: the files of the split bag hold different joints or fields")
    keys = dict.fromkeys(k for p in parts if len(p) for k in p.fields) if generic else dict.fromkeys(first.fields)
    merged.sparse = set().union(*(p.sparse for p in parts))
    for key in keys:
        shapes = {p.fields[key].shape[1:] for p in parts if len(p) and key in p.fields}
        width = max(shapes)
        if not (len(shapes) > 1 or any(len(p) and key not in p.fields for p in parts)):
            merged.fields[key] = np.concatenate([p.fields[key] for p in parts if key in p.fields])  # (its dtype kept)
            continue
        merged.sparse.add(key)  # a file without it, or narrower: NaN there
        pieces = []
        for p in parts:
            if not len(p) and key not in p.fields:
                continue
            column = p.fields.get(key)
            padded = np.full((len(p), *width), np.nan)
            if column is not None:
                padded[(slice(None), *(slice(0, n) for n in column.shape[1:]))] = column
            pieces.append(padded)
        merged.fields[key] = np.concatenate(pieces)
    from .decode import LazyMessages

    kept = [p.messages for p in parts if p.messages is not None]
    if kept and all(isinstance(m, LazyMessages) for m in kept):  # (still decoded when read)
        merged.messages = LazyMessages.joined(kept)
    elif kept:
        merged.messages = [m for p in parts for m in (p.messages or [])]
    if merged.log_time_ns.size > 1 and np.any(np.diff(merged.log_time_ns) < 0):
        order = np.argsort(merged.log_time_ns, kind="stable")
        merged.log_time_ns, merged.publish_time_ns = merged.log_time_ns[order], merged.publish_time_ns[order]
        merged.fields = {k: v[order] for k, v in merged.fields.items()}
        if isinstance(merged.messages, LazyMessages):
            merged.messages = merged.messages.reordered(order)
        elif merged.messages is not None:
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

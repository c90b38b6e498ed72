"""What the readers return: one topic as arrays, a bag's topics, a bag's summary.

Plain dataclasses, filled by :mod:`msg_tools.reader` (topics) and
:mod:`msg_tools.bag_summary` (summaries); nothing here reads a file.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Tuple

import numpy as np

__all__ = ["Bag", "BagSummary", "TICK_GAP_METADATA", "TopicData", "TopicInfo", "merged_metadata", "tick_gaps"]

#: the metadata records a belt_drive_ros node writes for each gap in its ticks (``start_ns``, ``end_ns``,
#: ``ticks_missed``, ``cause``, ``time_base``; see belt_drive_ros.ros.gaps)
TICK_GAP_METADATA = "tick_gap"


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
        numeric fields by dotted path; one that some messages lack (or an
        array whose length varies) is NaN there and named in ``sparse``.
    names : list of str
        Joint names (columns of the JointState arrays); empty for other types.
    messages : sequence or None
        Decoded message objects for types without a vectorized decoder, and
        for ``/tf`` (decoded when read there: ``messages[k]``, iteration).
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
    #: fields some messages lack (NaN there): a ``/tf`` of one transform per message, alternating frames; an
    #: array whose length varies (padded with NaN). Their samples are the messages that have them.
    sparse: set = field(default_factory=set)

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


def tick_gaps(metadata: List[Tuple[str, Dict[str, str]]]) -> List[Dict[str, str]]:
    """The :data:`TICK_GAP_METADATA` records, in file order, each once (a split bag's files repeat
    the records before them)."""
    seen, out = set(), []
    for name, values in metadata:
        key = tuple(sorted(values.items()))
        if name == TICK_GAP_METADATA and key not in seen:
            seen.add(key)
            out.append(dict(values))
    return out


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
    verified : bool
        True when the data was scanned and checked against a readable
        summary section (``damage`` then lists every disagreement).
    recovered : str
        Set when the data section is damaged before its end but every chunk was read through
        the summary's chunk index and the counts agree: what was damaged ("" otherwise).
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
    verified: bool = False
    recovered: str = ""

    def metadata_dict(self, name: str) -> Dict[str, str]:
        """Return the merged key/values of all metadata records called ``name``."""
        return merged_metadata(self.metadata, name)



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

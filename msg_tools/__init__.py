"""msg_tools: ROS-free reading, writing and comparison of ROS 2 MCAP recordings.

Files follow the rosbag2 ``mcap`` storage conventions (profile ``ros2``,
``ros2msg`` schemas, ``cdr`` messages, ``offered_qos_profiles`` per channel, a
``rosbag2`` metadata record), so they open in Foxglove and PlotJuggler and play
with ``ros2 bag play``. Nothing here imports rclpy.

Main entry points
-----------------
:class:`Ros2McapWriter`
    write messages (raw CDR or encoded from dicts) with crash-safe chunking.
:func:`read_topic`, :func:`read_topics`, :func:`read_bag`
    topics as numpy arrays; tolerant of files whose writer was killed.
:func:`summary`, :func:`list_topics`
    header, topics with counts and rates, metadata records; the data is
    scanned and checked against the summary section (``verify=False``: the
    summary section alone, unchecked).
:func:`compare`, :func:`compare_folders`
    signal-by-signal tolerance check of two recordings (or folders of them,
    pairwise); holes and duplicate stamps fail.
:class:`Ros2BagWriter`, :func:`bag_files`
    rosbag2's bag folder layout (``NAME/NAME_k.mcap`` + ``metadata.yaml``),
    split by size or duration; every reader accepts a folder.
``msg-tools``
    the command line (:mod:`msg_tools.cli`).
"""

from .bagdir import Ros2BagWriter, bag_files
from .compare import CompareReport, FolderReport, SignalResult, compare, compare_folders
from .errors import (
    BagNotFoundError,
    CorruptBagError,
    NotAFileError,
    DecodeError,
    MsgToolsError,
    OverwriteError,
    RecoveredBagWarning,
    TopicNotFoundError,
    UnknownMessageTypeError,
    WriteError,
)
from .qos import PRESETS as QOS_PRESETS
from .qos import QosProfile, offered_qos_yaml, parse_offered_qos_yaml
from .reader import (
    Bag,
    BagSummary,
    TopicData,
    TopicInfo,
    list_topics,
    read_bag,
    read_topic,
    read_topics,
    summary,
)
from .schemas import known_types, schema_text
from .writer import Ros2McapWriter, encode

__all__ = [
    "Bag",
    "BagNotFoundError",
    "BagSummary",
    "CompareReport",
    "FolderReport",
    "CorruptBagError",
    "NotAFileError",
    "DecodeError",
    "MsgToolsError",
    "OverwriteError",
    "QOS_PRESETS",
    "QosProfile",
    "RecoveredBagWarning",
    "Ros2BagWriter",
    "Ros2McapWriter",
    "SignalResult",
    "TopicData",
    "TopicInfo",
    "TopicNotFoundError",
    "UnknownMessageTypeError",
    "WriteError",
    "bag_files",
    "compare",
    "compare_folders",
    "encode",
    "known_types",
    "list_topics",
    "offered_qos_yaml",
    "parse_offered_qos_yaml",
    "read_bag",
    "read_topic",
    "read_topics",
    "schema_text",
    "summary",
]

"""Write rosbag2-compatible ROS 2 MCAP files without ROS.

The file layout follows what ``ros2 bag record -s mcap`` (Jazzy) writes, see
ros2/rosbag2 ``rosbag2_storage_mcap/src/mcap_storage.cpp``:

* header profile ``ros2``; schemas ``pkg/msg/Type`` with encoding ``ros2msg``
  (:mod:`msg_tools.schemas`); channels with message encoding ``cdr`` and
  metadata ``offered_qos_profiles`` (:mod:`msg_tools.qos`) and
  ``topic_type_hash``;
* messages: ``log_time`` = receive time [ns], ``publish_time`` = send time [ns];
* at :meth:`Ros2McapWriter.finish`, a metadata record ``rosbag2`` whose key
  ``serialized_metadata`` is the BagMetadata YAML (``update_metadata`` in
  mcap_storage.cpp, ``convert<BagMetadata>::encode`` in
  ``rosbag2_storage/include/rosbag2_storage/yaml.hpp``), then the MCAP summary
  (schemas, channels, statistics, chunk and metadata indexes).

Crash safety: messages go into zstd chunks that are closed, written and
flushed to the operating system whenever ``chunk_size`` bytes (uncompressed)
or ``flush_interval_s`` of log time have accumulated, so a writer killed with
SIGKILL loses at most the open chunk; :func:`msg_tools.reader.read_topic`
reads such a file up to its last complete chunk.
"""

from __future__ import annotations

import os
import threading
from importlib.metadata import PackageNotFoundError, version
from types import SimpleNamespace
from typing import IO, Any, Dict, List, Optional, Union

from mcap.writer import LIBRARY_IDENTIFIER as _MCAP_LIBRARY
from mcap.writer import CompressionType, IndexType
from mcap.writer import Writer as _McapWriter

from . import schemas as _schemas
from .errors import MsgToolsError, OverwriteError, WriteError
from .qos import QosLike, as_profiles, offered_qos_yaml

__all__ = ["Ros2McapWriter", "encode", "bag_metadata_yaml", "LIBRARY"]

try:
    _VERSION = version("belt-drive-ros")
except PackageNotFoundError:  # running from a source tree
    _VERSION = "0+unknown"

#: Library string written into the MCAP header.
LIBRARY = f"msg_tools/{_VERSION} (belt_drive_ros); {_MCAP_LIBRARY}"

#: rosbag2 BagMetadata version written (Jazzy: 9, QoS policies as strings).
BAG_METADATA_VERSION = 9

_COMPRESSION = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
    "": CompressionType.NONE,
}

# Message record: opcode (1) + length (8) + channel id (2) + sequence (4)
# + log time (8) + publish time (8) = 31 bytes before the payload.
_MESSAGE_OVERHEAD = 31

_encoders: Dict[str, Any] = {}


def _plain(value: Any) -> Any:
    """Prepare a message given as dicts for ``mcap_ros2``'s encoder.

    numpy arrays/scalars become Python lists/numbers. Dicts become
    ``SimpleNamespace`` objects: mcap_ros2 looks a missing field up with
    ``hasattr`` too, so a dict without a ``values`` field (``DiagnosticStatus``)
    would otherwise hand it the bound method ``dict.values``.
    """
    if isinstance(value, dict):
        return SimpleNamespace(**{str(key): _plain(item) for key, item in value.items()})
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    tolist = getattr(value, "tolist", None)
    if tolist is not None and type(value).__module__ == "numpy":
        return tolist()
    return value


def encode(type_name: str, message: Any, schema: Optional[str] = None) -> bytes:
    """Serialize ``message`` to CDR (little endian) with ``mcap_ros2``.

    Parameters
    ----------
    type_name : str
        ROS 2 type, e.g. ``"std_msgs/msg/Float64"``.
    message : dict or object
        Field values by name: a dict (nested dicts for nested messages; numpy
        arrays allowed), an rclpy message, or any object with the attributes.
        Missing fields take their default (0, ``""``, empty array).
    schema : str, optional
        Complete ``ros2msg`` text; by default :func:`msg_tools.schemas.schema_text`.

    Returns
    -------
    bytes
        4-byte encapsulation header ``00 01 00 00`` then the payload. The
        output is deterministic (padding bytes are zero).
    """
    from ._cdr import encoder_for

    full_name = _schemas.normalize_type_name(type_name)
    key = full_name if schema is None else f"{full_name}\0{schema}"
    encoder = _encoders.get(key)
    if encoder is None:
        text = schema if schema is not None else _schemas.schema_text(full_name)
        encoder = encoder_for(full_name, text)
        _encoders[key] = encoder
    try:
        return bytes(encoder(_plain(message)))
    except (ValueError, TypeError, AttributeError, KeyError) as exc:
        raise MsgToolsError(f"cannot encode {full_name} message: {exc}") from exc


def _yaml_str(text: str) -> str:
    """Quote ``text`` for YAML only if a plain scalar would change its meaning."""
    import json
    import re

    if text == "":
        return '""'
    plain = re.fullmatch(r"[A-Za-z_/.][A-Za-z0-9_/.\-]*", text) is not None
    if plain and text.lower() not in {"true", "false", "yes", "no", "on", "off", "null"}:
        return text
    return json.dumps(text)


def _indent(text: str, spaces: int) -> List[str]:
    pad = " " * spaces
    return [pad + line for line in text.splitlines()]


def bag_metadata_yaml(
    topics: List[Dict[str, Any]],
    *,
    starting_time_ns: int,
    duration_ns: int,
    message_count: int,
    relative_file_path: str = "",
    custom_data: Optional[Dict[str, str]] = None,
    ros_distro: str = "jazzy",
    files: Optional[List[Dict[str, Any]]] = None,
) -> str:
    """Return rosbag2 BagMetadata YAML (version 9) as ``YAML::Dump`` lays it out.

    Parameters
    ----------
    topics : list of dict
        One dict per topic with keys ``name``, ``type``, ``offered_qos_profiles``
        (the YAML of :func:`msg_tools.qos.offered_qos_yaml`),
        ``type_description_hash`` and ``message_count``.
    starting_time_ns : int
        Earliest log time [ns since epoch].
    duration_ns : int
        Latest minus earliest log time [ns].
    message_count : int
        Total number of messages.
    relative_file_path : str
        File name of the bag file (empty for streams).
    custom_data : dict of str to str, optional
        rosbag2 ``custom_data`` (``~`` when empty).
    ros_distro : str
        ROS distribution name.
    files : list of dict, optional
        Several files (a split recording): per file ``path`` (relative),
        ``starting_time_ns``, ``duration_ns``, ``message_count``; replaces
        ``relative_file_path``.
    """
    lines = [
        f"version: {BAG_METADATA_VERSION}",
        "storage_identifier: mcap",
        "duration:",
        f"  nanoseconds: {int(duration_ns)}",
        "starting_time:",
        f"  nanoseconds_since_epoch: {int(starting_time_ns)}",
        f"message_count: {int(message_count)}",
    ]
    if topics:
        lines.append("topics_with_message_count:")
        for topic in topics:
            lines += [
                "  - topic_metadata:",
                f"      name: {_yaml_str(topic['name'])}",
                f"      type: {_yaml_str(topic['type'])}",
                "      serialization_format: cdr",
            ]
            qos = topic["offered_qos_profiles"]
            if qos.strip() == "[]":
                lines.append("      offered_qos_profiles: []")
            else:
                lines.append("      offered_qos_profiles:")
                lines += _indent(qos, 8)
            lines += [
                f"      type_description_hash: {_yaml_str(topic.get('type_description_hash', ''))}",
                f"    message_count: {int(topic['message_count'])}",
            ]
    else:
        lines.append("topics_with_message_count: []")
    lines += ['compression_format: ""', 'compression_mode: ""']
    if files is None and relative_file_path:
        files = [{"path": relative_file_path, "starting_time_ns": starting_time_ns,
                  "duration_ns": duration_ns, "message_count": message_count}]
    if files:
        lines.append("relative_file_paths:")
        lines += [f"  - {_yaml_str(f['path'])}" for f in files]
        lines.append("files:")
        for f in files:
            lines += [
                f"  - path: {_yaml_str(f['path'])}",
                "    starting_time:",
                f"      nanoseconds_since_epoch: {int(f['starting_time_ns'])}",
                "    duration:",
                f"      nanoseconds: {int(f['duration_ns'])}",
                f"    message_count: {int(f['message_count'])}",
            ]
    else:
        lines += ["relative_file_paths: []", "files: []"]
    if custom_data:
        lines.append("custom_data:")
        lines += [f"  {_yaml_str(str(k))}: {_yaml_str(str(v))}" for k, v in custom_data.items()]
    else:
        lines.append("custom_data: ~")
    lines.append(f"ros_distro: {_yaml_str(ros_distro)}")
    return "\n".join(lines)


class _Channel:
    __slots__ = ("channel_id", "topic", "type_name", "qos_yaml", "type_hash", "count", "sequence")

    def __init__(self, channel_id: int, topic: str, type_name: str, qos_yaml: str, type_hash: str):
        self.channel_id = channel_id
        self.topic = topic
        self.type_name = type_name
        self.qos_yaml = qos_yaml
        self.type_hash = type_hash
        self.count = 0
        self.sequence = 0


class Ros2McapWriter:
    """Write ROS 2 messages to an MCAP file that rosbag2, Foxglove and PlotJuggler read.

    Parameters
    ----------
    output : str, os.PathLike or binary stream
        File to create, or a writable binary stream (e.g. ``io.BytesIO``;
        it is not closed by :meth:`finish`).
    force : bool
        Replace an existing file. Without it an existing file raises
        :class:`~msg_tools.errors.OverwriteError`.
    chunk_size : int
        Close the current chunk once it holds this many bytes (uncompressed).
        The default (128 KiB) is about 0.15 s of 6 topics at 1 kHz.
    compression : {"zstd", "lz4", "none"}
        Chunk compression.
    flush_interval_s : float or None
        Also close the chunk once its messages span this much log time [s], so
        a killed recorder loses at most about this much data. ``None`` disables.
    ros_distro : str
        Written into the ``rosbag2`` metadata.
    custom_data : dict of str to str, optional
        rosbag2 ``custom_data`` entries.
    message_index : bool
        Write a message index after each chunk (16 bytes per message, about
        half the file for small messages). rosbag2 needs it to read in
        receive-time order; without it, readers fall back to file order, which
        is time order for our files. Keep it for files that users open.

    Examples
    --------
    >>> import io
    >>> buf = io.BytesIO()
    >>> with Ros2McapWriter(buf) as w:
    ...     w.write("/drive_torque", "std_msgs/msg/Float64", {"data": 1.5}, log_time_ns=0)

    Notes
    -----
    Thread-safe: every public method holds an internal lock. After the first
    ``OSError`` the writer stops writing (``failed`` is True) and every further
    write raises :class:`~msg_tools.errors.WriteError`; :meth:`finish` then
    only closes the file, which stays readable up to its last complete chunk.
    """

    #: the MCAP record writer (``mcap``'s; :class:`msg_tools.block_writer.BlockMcapWriter` has its own)
    _records_class: Any = _McapWriter

    def __init__(
        self,
        output: Union[str, "os.PathLike[str]", IO[bytes]],
        *,
        force: bool = False,
        chunk_size: int = 128 * 1024,
        compression: str = "zstd",
        flush_interval_s: Optional[float] = 0.25,
        ros_distro: str = "jazzy",
        custom_data: Optional[Dict[str, str]] = None,
        message_index: bool = True,
    ):
        if compression not in _COMPRESSION:
            raise ValueError(
                f"unknown compression {compression!r}; expected one of zstd, lz4, none"
            )
        if int(chunk_size) < 1024:
            raise ValueError(f"chunk_size must be >= 1024 bytes, got {chunk_size}")
        if flush_interval_s is not None and not flush_interval_s > 0:
            raise ValueError(f"flush_interval_s must be > 0 s or None, got {flush_interval_s}")
        self._lock = threading.RLock()
        self._chunk_size = int(chunk_size)
        self._flush_interval_ns = (
            None if flush_interval_s is None else int(round(flush_interval_s * 1e9))
        )
        self._ros_distro = ros_distro
        self._custom_data = dict(custom_data or {})
        self._schema_ids: Dict[str, int] = {}
        self._extra_definitions: Dict[str, str] = {}
        self._channels: Dict[str, _Channel] = {}
        self._message_count = 0
        self._start_ns: Optional[int] = None
        self._end_ns: Optional[int] = None
        self._pending_bytes = 0
        self._chunk_t0_ns: Optional[int] = None
        self._finished = False
        self.error: Optional[WriteError] = None

        if isinstance(output, (str, os.PathLike)):
            self.path: Optional[str] = os.fspath(output)
            self._stream: IO[bytes] = self._open(self.path, force)
            self._owns_stream = True
        else:
            if not hasattr(output, "write"):
                raise TypeError(
                    f"output must be a path or a writable binary stream, got {type(output).__name__}"
                )
            self.path = None
            self._stream = output
            self._owns_stream = False
        self._name = self.path if self.path is not None else "<stream>"
        try:
            self._mcap = self._records_class(
                self._stream,
                chunk_size=2**62,  # chunks are closed by this class, see _after_message
                enable_data_crcs=True,  # DataEnd carries the data section's CRC: readers detect damage
                compression=_COMPRESSION[compression],
                index_types=IndexType.ALL if message_index else IndexType.ALL & ~IndexType.MESSAGE,
            )
            self._mcap.start(profile="ros2", library=LIBRARY)
            self._stream.flush()
        except OSError as exc:
            self._fail(exc, "write")
            raise self.error from exc  # type: ignore[misc]
        except Exception:
            if self._owns_stream:
                self._stream.close()
            raise

    # ------------------------------------------------------------------ setup
    @staticmethod
    def _open(path: str, force: bool) -> IO[bytes]:
        if os.path.isdir(path):
            raise WriteError(path, "is a directory", action="create")
        if os.path.lexists(path) and not force:
            raise OverwriteError(path)
        try:
            # "xb" makes the no-overwrite check atomic against a racing writer
            return open(path, "wb" if force else "xb")
        except FileExistsError:
            raise OverwriteError(path) from None
        except OSError as exc:
            raise WriteError(path, exc, action="create") from exc

    def __enter__(self) -> "Ros2McapWriter":
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.finish()
        else:
            # keep the original exception; still close the file properly
            try:
                self.finish()
            except Exception:  # noqa: BLE001 - the body's exception is the one to see
                pass

    # --------------------------------------------------------------- properties
    @property
    def failed(self) -> bool:
        """True after a write error; nothing more is written."""
        return self.error is not None

    @property
    def finished(self) -> bool:
        """True once :meth:`finish` has run."""
        return self._finished

    @property
    def message_count(self) -> int:
        """Messages written so far."""
        return self._message_count

    def topic_counts(self) -> Dict[str, int]:
        """Return the number of messages written per topic."""
        with self._lock:
            return {topic: ch.count for topic, ch in self._channels.items()}

    def topics_metadata(self) -> List[Dict[str, Any]]:
        """One dict per topic (name, type, offered_qos_profiles, type_description_hash,
        message_count), as :func:`bag_metadata_yaml` takes them."""
        with self._lock:
            return [
                {
                    "name": ch.topic,
                    "type": ch.type_name,
                    "offered_qos_profiles": ch.qos_yaml,
                    "type_description_hash": ch.type_hash,
                    "message_count": ch.count,
                }
                for ch in self._channels.values()
            ]

    @property
    def time_range_ns(self) -> "tuple[Optional[int], Optional[int]]":
        """(earliest, latest) log time written [ns]; (None, None) before the first message."""
        return self._start_ns, self._end_ns

    @property
    def bytes_written(self) -> int:
        """Bytes handed to the output so far (closed chunks; the open chunk is not counted)."""
        try:
            return int(self._stream.tell())
        except (OSError, ValueError):
            return 0

    # ------------------------------------------------------------------ errors
    def _fail(self, exc: BaseException, action: str = "write") -> WriteError:
        if self.error is None:
            self.error = WriteError(self._name, exc, action=action)
        return self.error

    def _check_writable(self) -> None:
        if self._finished:
            raise MsgToolsError(f"writer for {self._name} is finished; no more writes")
        if self.error is not None:
            raise WriteError(
                self._name, f"writer stopped after an earlier error ({self.error.strerror})"
            )

    # ----------------------------------------------------------------- schemas
    def register_type(self, type_name: str, msg_text: str) -> None:
        """Add the ``.msg`` text of a type that has no built-in definition.

        Parameters
        ----------
        type_name : str
            ``"pkg/msg/Type"``.
        msg_text : str
            Its ``.msg`` text (dependencies not built in must be registered too).
        """
        with self._lock:
            self._extra_definitions[_schemas.normalize_type_name(type_name)] = msg_text

    def _schema_id(self, type_name: str) -> int:
        schema_id = self._schema_ids.get(type_name)
        if schema_id is None:
            text = _schemas.schema_text(type_name, self._extra_definitions)
            schema_id = self._mcap.register_schema(type_name, "ros2msg", text.encode("utf-8"))
            self._schema_ids[type_name] = schema_id
        return schema_id

    def add_topic(self, topic: str, type_name: str, qos: Union[QosLike, List[QosLike], None] = None,
                  type_hash: Optional[str] = None) -> None:
        """Declare a topic (channel) before its first message.

        Parameters
        ----------
        topic : str
            Topic name, e.g. ``"/joint_states"``.
        type_name : str
            ROS 2 type of its messages.
        qos : preset name, QosProfile, dict, rclpy QoSProfile or list, optional
            Offered QoS written as ``offered_qos_profiles``; default ``"reliable"``.
            Only used when the channel is created (first call for the topic).
        type_hash : str, optional
            ``RIHS01_...`` hash of the type as discovery reports it (a live
            recorder passes the publishers'); default: computed from the
            definition (:func:`msg_tools.schemas.type_hash`). Written as the
            channel's ``topic_type_hash`` and the topic's
            ``type_description_hash``.

        Raises
        ------
        MsgToolsError
            If the topic already exists with another type.
        UnknownMessageTypeError
            If the type has no definition.
        """
        with self._lock:
            self._check_writable()
            self._channel(topic, type_name, qos, type_hash)

    def _channel(self, topic: str, type_name: str, qos: Any, type_hash: Optional[str] = None) -> _Channel:
        channel = self._channels.get(topic)
        full_type = _schemas.normalize_type_name(type_name)
        if channel is not None:
            if channel.type_name != full_type:
                raise MsgToolsError(
                    f"topic {topic} already has type {channel.type_name}, got {full_type}"
                )
            return channel
        if not isinstance(topic, str) or not topic:
            raise ValueError(f"topic must be a non-empty string, got {topic!r}")
        qos_yaml = offered_qos_yaml(as_profiles(qos))
        if not type_hash:
            type_hash = _schemas.type_hash(full_type, self._extra_definitions)
        try:
            schema_id = self._schema_id(full_type)
            channel_id = self._mcap.register_channel(
                topic=topic,
                message_encoding="cdr",
                schema_id=schema_id,
                metadata={
                    "offered_qos_profiles": qos_yaml,
                    "topic_type_hash": type_hash,
                },
            )
        except OSError as exc:
            raise self._fail(exc) from exc
        channel = _Channel(channel_id, topic, full_type, qos_yaml, type_hash)
        self._channels[topic] = channel
        return channel

    # ---------------------------------------------------------------- messages
    def write_raw(
        self,
        topic: str,
        type_name: str,
        cdr_bytes: Union[bytes, bytearray, memoryview],
        log_time_ns: int,
        publish_time_ns: Optional[int] = None,
        qos: Union[QosLike, List[QosLike], None] = None,
    ) -> None:
        """Write one already-serialized message, byte for byte.

        Parameters
        ----------
        topic : str
            Topic name.
        type_name : str
            ROS 2 type of the message.
        cdr_bytes : bytes-like
            Serialized message (encapsulation header + CDR), e.g. what an rclpy
            subscription created with ``raw=True`` delivers.
        log_time_ns : int
            Receive time [ns] (ROS time; sim time when ``use_sim_time``).
        publish_time_ns : int, optional
            Send time [ns]; defaults to ``log_time_ns``.
        qos : optional
            Offered QoS of the topic, used when its channel is created.

        Raises
        ------
        WriteError
            If the file cannot be written (the writer then stops writing).
        """
        data = bytes(cdr_bytes)
        if len(data) < 4:
            raise ValueError(
                f"message on {topic} has {len(data)} bytes; CDR needs a 4-byte encapsulation header"
            )
        log_time = int(log_time_ns)
        publish_time = log_time if publish_time_ns is None else int(publish_time_ns)
        if log_time < 0 or publish_time < 0:
            raise ValueError(
                f"message on {topic}: times must be >= 0 ns, got log={log_time} publish={publish_time}"
            )
        with self._lock:
            self._check_writable()
            channel = self._channel(topic, type_name, qos)
            channel.sequence = (channel.sequence + 1) & 0xFFFFFFFF
            try:
                self._mcap.add_message(
                    channel_id=channel.channel_id,
                    log_time=log_time,
                    data=data,
                    publish_time=publish_time,
                    sequence=channel.sequence,
                )
            except OSError as exc:
                raise self._fail(exc) from exc
            channel.count += 1
            self._message_count += 1
            self._start_ns = log_time if self._start_ns is None else min(self._start_ns, log_time)
            self._end_ns = log_time if self._end_ns is None else max(self._end_ns, log_time)
            self._after_message(log_time, len(data))

    def write(
        self,
        topic: str,
        type_name: str,
        message: Any,
        log_time_ns: int,
        publish_time_ns: Optional[int] = None,
        qos: Union[QosLike, List[QosLike], None] = None,
    ) -> None:
        """Encode ``message`` with ``mcap_ros2`` and write it.

        Deterministic: the same calls give a byte-identical file, which makes
        it suitable for golden files. Parameters as :meth:`write_raw`, with
        ``message`` a dict or object as accepted by :func:`encode`.
        """
        full_type = _schemas.normalize_type_name(type_name)
        if full_type in self._extra_definitions:
            schema = _schemas.schema_text(full_type, self._extra_definitions)
            data = encode(full_type, message, schema=schema)
        else:
            data = encode(full_type, message)
        self.write_raw(topic, full_type, data, log_time_ns, publish_time_ns, qos)

    def _after_message(self, log_time: int, size: int) -> None:
        self._pending_bytes += size + _MESSAGE_OVERHEAD
        if self._chunk_t0_ns is None:
            self._chunk_t0_ns = log_time
        too_big = self._pending_bytes >= self._chunk_size
        too_old = (
            self._flush_interval_ns is not None
            and log_time - self._chunk_t0_ns >= self._flush_interval_ns
        )
        if too_big or too_old:
            self._flush_locked()

    def _flush_locked(self) -> None:
        try:
            self._mcap.flush()  # closes the chunk, writes it and its index, flushes
        except OSError as exc:
            raise self._fail(exc) from exc
        self._pending_bytes = 0
        self._chunk_t0_ns = None

    def flush(self) -> None:
        """Close the current chunk and hand everything to the operating system.

        Call it from a wall-clock timer in a live recorder if messages may stop
        arriving, so the last messages do not wait in an open chunk.
        """
        with self._lock:
            self._check_writable()
            self._flush_locked()

    # ----------------------------------------------------------------- metadata
    def add_metadata(self, name: str, data: Dict[str, str]) -> None:
        """Write a metadata record (e.g. the scene and parameters of a run).

        Parameters
        ----------
        name : str
            Record name. ``"rosbag2"`` is reserved (written by :meth:`finish`).
        data : dict of str to str
            Key/value pairs; both must be strings.
        """
        if not isinstance(name, str) or not name:
            raise ValueError(f"metadata name must be a non-empty string, got {name!r}")
        if name == "rosbag2":
            raise ValueError("metadata name 'rosbag2' is reserved for the bag metadata")
        bad = [k for k, v in data.items() if not isinstance(k, str) or not isinstance(v, str)]
        if bad:
            raise TypeError(
                f"metadata {name!r}: keys and values must be str; not for key(s) {bad[:5]}"
            )
        with self._lock:
            self._check_writable()
            try:
                self._mcap.add_metadata(name, dict(data))
                self._stream.flush()
            except OSError as exc:
                raise self._fail(exc) from exc

    def bag_metadata(self) -> str:
        """Return the rosbag2 ``serialized_metadata`` YAML for what was written so far."""
        with self._lock:
            start = self._start_ns or 0
            duration = (self._end_ns - self._start_ns) if self._start_ns is not None else 0
            return bag_metadata_yaml(
                self.topics_metadata(),
                starting_time_ns=start,
                duration_ns=duration,
                message_count=self._message_count,
                relative_file_path=os.path.basename(self.path) if self.path else "",
                custom_data=self._custom_data,
                ros_distro=self._ros_distro,
            )

    # ------------------------------------------------------------------ finish
    def finish(self) -> None:
        """Write the ``rosbag2`` metadata and the summary, then close the file.

        Idempotent. After a write error it only closes the file (no summary):
        the file then reads like one whose writer was killed.

        Raises
        ------
        WriteError
            If the final records cannot be written.
        """
        with self._lock:
            if self._finished:
                return
            self._finished = True
            try:
                if self.error is None:
                    try:
                        self._mcap.add_metadata(
                            "rosbag2", {"serialized_metadata": self.bag_metadata()}
                        )
                        self._mcap.finish()
                        self._stream.flush()
                    except OSError as exc:
                        raise self._fail(exc, "finish") from exc
            finally:
                if self._owns_stream:
                    try:
                        self._stream.close()
                    except OSError as exc:
                        if self.error is None:
                            raise self._fail(exc, "close") from exc

"""rosbag2's directory layout: ``NAME/NAME_0.mcap``, ``NAME_1.mcap``, ... and ``NAME/metadata.yaml``.

``ros2 bag record -o NAME`` writes a folder: one MCAP file per split (by
size or duration, ``--max-bag-size`` / ``--max-bag-duration``) and
``metadata.yaml``, whose top key ``rosbag2_bagfile_information`` holds the
BagMetadata (version 9 in Jazzy; ``rosbag2_storage/src/rosbag2_storage/
metadata_io.cpp`` and ``yaml.hpp`` in ros2/rosbag2): storage id, duration,
start, message count, topics with counts, ``relative_file_paths`` and per
file its start, duration and count. rosbag2 tooling and rosbags' directory
reader open such a folder.

:class:`Ros2BagWriter` writes that layout with the interface of
:class:`~msg_tools.writer.Ros2McapWriter` and splits when asked.
:func:`bag_files` lists the files of a bag folder (or returns a single file)
for the reading side: every ``msg-tools`` verb accepts a folder.
"""

from __future__ import annotations

import contextlib
import os
import threading
from typing import IO, Any, ContextManager, Dict, List, Optional, Tuple, Union

from .errors import BagNotFoundError, CorruptBagError, MsgToolsError, OverwriteError, WriteError
from .writer import Ros2McapWriter, bag_metadata_yaml

__all__ = ["METADATA_FILE", "Ros2BagWriter", "bag_files", "folder_damage"]

METADATA_FILE = "metadata.yaml"


def bag_files(path: Union[str, "os.PathLike[str]"]) -> List[str]:
    """The MCAP files of a bag: ``[path]`` for a file; for a folder the files its
    ``metadata.yaml`` lists (``relative_file_paths``), else its ``*.mcap`` files by split index.

    Raises
    ------
    BagNotFoundError
        If the path does not exist, or is a folder without MCAP files.
    CorruptBagError
        If ``metadata.yaml`` is unreadable or lists a file that is missing.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise BagNotFoundError(path)
    if not os.path.isdir(path):
        return [path]
    meta = os.path.join(path, METADATA_FILE)
    info = _metadata(path)
    if info is not None:
        mode = str(info.get("compression_mode") or "").strip()
        if mode and mode.lower() != "none":  # rosbag2's own compression: whole files or each message's data
            raise CorruptBagError(
                f"{path}: compressed by rosbag2 (compression_mode {mode}, compression_format "
                f"{info.get('compression_format') or '?'}): not read here; write an uncompressed copy first (e.g. "
                "'ros2 bag convert'; an MCAP file's own chunk compression, rosbag2's default, is read)")
        relative = info.get("relative_file_paths")
        if relative is None:
            relative = []
        if not isinstance(relative, list) or not all(isinstance(p, str) and p for p in relative):
            raise CorruptBagError(f"{meta}: relative_file_paths is not a list of file names")
        for p in relative:  # the bag's own files: a path that leaves the folder is no part of it
            if os.path.isabs(p) or ".." in p.replace("\\", "/").split("/"):
                raise CorruptBagError(f"{meta}: relative_file_paths names {p!r}, outside the bag folder")
        files = [os.path.join(path, p) for p in relative]
        seen: set = set()
        for p, file in zip(relative, files):
            key = os.path.normpath(file)
            if key in seen:  # (read twice, a recording doubles its messages; msg-tools info called it overlapping)
                raise CorruptBagError(f"{meta}: relative_file_paths lists {p!r} twice")
            seen.add(key)
        for file in files:
            _check_regular(file, f"{meta} lists")
        if files:
            return files
    found = [f for f in os.listdir(path) if f.endswith(".mcap")]
    for name in found:
        _check_regular(os.path.join(path, name), "the folder holds")
    if not found:
        raise BagNotFoundError(path, "is a directory without .mcap files")

    def split_index(name: str) -> Tuple[int, str]:
        stem = name[: -len(".mcap")]
        tail = stem.rsplit("_", 1)[-1]
        return (int(tail) if tail.isdigit() else -1, name)

    return [os.path.join(path, f) for f in sorted(found, key=split_index)]


#: largest metadata.yaml read [bytes] (rosbag2 writes ~300 bytes per split file and topic)
METADATA_LIMIT = 16 * 2**20


def _metadata(path: str) -> Optional[Dict[str, Any]]:
    """The ``rosbag2_bagfile_information`` mapping of the folder's ``metadata.yaml``; None without one.

    Read through the package's bounded loader (``belt_drive_ros.io.inputs``:
    a regular UTF-8 file under :data:`METADATA_LIMIT`, YAML without aliases,
    anchors, deep nesting or duplicate keys), so a hostile file (a "billion
    laughs" of aliases, a FIFO, /dev/zero linked in) is refused in one line.
    """
    from belt_drive_ros.io.inputs import InputError, read_yaml

    meta = os.path.join(path, METADATA_FILE)
    if not os.path.lexists(meta):
        return None
    try:
        data = read_yaml(meta, "bag metadata", limit=METADATA_LIMIT)
    except InputError as exc:
        raise CorruptBagError(f"{exc}; not a rosbag2 metadata file") from None
    info = data.get("rosbag2_bagfile_information") if isinstance(data, dict) else None
    if not isinstance(info, dict):
        raise CorruptBagError(f"{meta}: not a rosbag2 metadata file (no rosbag2_bagfile_information mapping)")
    return info


def _check_regular(file: str, how: str) -> None:
    """Refuse (CorruptBagError) a bag file that is missing or not a regular file (a FIFO would block ``open``)."""
    import stat

    try:
        mode = os.stat(file).st_mode
    except OSError:
        raise CorruptBagError(f"{how} {file}, which does not exist") from None
    if not stat.S_ISREG(mode):
        raise CorruptBagError(f"{how} {file}, which is not a regular file (a FIFO, device or folder)")


def _listed_files(path: str) -> List[Dict[str, Any]]:
    """The ``files`` entries of a bag folder's ``metadata.yaml`` (path, start, duration, count); [] if none."""
    meta = os.path.join(path, METADATA_FILE)
    info = _metadata(path)
    if info is None:
        return []
    entries = info.get("files") or []
    if not isinstance(entries, list):
        raise CorruptBagError(f"{meta}: 'files' is not a list")
    out = []
    for entry in entries:
        try:
            out.append({
                "path": os.path.join(path, str(entry["path"])),
                "start": int(entry["starting_time"]["nanoseconds_since_epoch"]),
                "duration": int(entry["duration"]["nanoseconds"]),
                "count": int(entry["message_count"]),
            })
        except (KeyError, TypeError, ValueError, OverflowError):
            raise CorruptBagError(f"{meta}: a 'files' entry lacks path, starting_time, duration or message_count") from None
    return out


def folder_damage(path: Union[str, "os.PathLike[str]"], *, summaries: Optional[Dict[str, Any]] = None) -> List[str]:
    """What a bag folder's files disagree with: the per-file message count, start and duration
    its ``metadata.yaml`` states, and each other (two files holding the same span twice).

    Returns [] for a single file, a consistent folder, or a folder without
    ``metadata.yaml`` whose files do not repeat each other (a killed recorder's).
    ``summaries``: the files' :class:`BagSummary` by path when the caller has them
    (``msg-tools info``); otherwise each file's summary section is read
    (``verify=False``: its data is checked when it is read).
    """
    from .reader import summary

    path = os.fspath(path)
    if not os.path.isdir(path):
        return []
    files = bag_files(path)
    listed = {os.path.normpath(e["path"]): e for e in _listed_files(path)}
    damage: List[str] = []
    spans: Dict[Tuple[Any, Any, int], str] = {}
    timed: List[Tuple[int, int, str]] = []  # (start, end [ns], name) of each file with messages, in the files' order
    for file in files:
        s = summaries[file] if summaries and file in summaries else summary(file, verify=False)
        name = os.path.basename(file)
        damage.extend(f"{name}: {d}" for d in s.damage)
        span = (s.start_ns, s.end_ns, s.message_count)
        if s.message_count and span in spans:
            damage.append(f"{name} holds the same {s.message_count} messages as {spans[span]} (a file repeated)")
        spans.setdefault(span, name)
        if s.message_count and s.start_ns is not None and s.end_ns is not None:
            timed.append((s.start_ns, s.end_ns, name))
        entry = listed.get(os.path.normpath(file))
        if entry is None:
            continue
        start = s.start_ns if s.start_ns is not None else 0
        duration = (s.end_ns - s.start_ns) if s.start_ns is not None and s.end_ns is not None else 0
        if s.message_count != entry["count"]:
            damage.append(f"{name} holds {s.message_count} messages, {METADATA_FILE} says {entry['count']}")
        elif entry["count"] and (start, duration) != (entry["start"], entry["duration"]):
            damage.append(f"{name} spans {start} ns + {duration} ns, {METADATA_FILE} says "
                          f"{entry['start']} ns + {entry['duration']} ns")
    read = {os.path.normpath(f) for f in files}
    damage.extend(f"{METADATA_FILE} describes {os.path.basename(p)} in files:, which is not among the files it lists"
                  for p in listed if p not in read)
    # split files follow each other in time (a file begins where the last ended or later; the latched messages a new
    # file repeats are stamped with its first log time): two that overlap are no one recording's splits
    for (_, end_a, a), (start_b, _, b) in zip(timed, timed[1:]):
        if start_b < end_a:
            damage.append(f"{b} starts {(end_a - start_b) / 1e9:.6g} s before {a} ends: split files do not overlap")
    return damage


class Ros2BagWriter:
    """Write a rosbag2 bag folder, split by size or duration like ``ros2 bag record``.

    Parameters
    ----------
    folder : path
        Bag folder to create (``NAME``); files are ``NAME_0.mcap``, ``NAME_1.mcap``, ...
    force : bool
        Replace an existing folder's bag files and metadata.yaml.
    max_bag_size : int, optional
        Start a new file once the current one holds this many bytes
        (rosbag2 ``--max-bag-size``; checked as chunks are written). 0/None: no limit.
    max_bag_duration : float, optional
        Start a new file once the current one spans this much log time [s]
        (``--max-bag-duration``). 0/None: no limit.
    blocks : bool
        Write each file with :class:`~msg_tools.block_writer.BlockMcapWriter`
        (the same records), so that :meth:`write_block` writes many steps of
        several topics at once: a long offline run's files ~20x faster than
        message by message. Default False (the records of the ``mcap``
        library's writer, as a live recording's).
    hold : context manager, optional
        Held while the folder is written: entered before the folder is
        looked at, exited once :meth:`finish` has run (or the constructor
        failed); a folder lock (``belt_drive_ros.io.bag_folder.bag_folder_lock``:
        one writer per folder, a second refused naming the first's pid).
    **writer_options
        Passed to each :class:`~msg_tools.writer.Ros2McapWriter` (chunk_size,
        compression, flush_interval_s, ros_distro, custom_data, message_index).

    Notes
    -----
    Every file repeats the schemas, channels and metadata records written so
    far (the scene, parameters, units), so each file is self-describing.
    Latched topics (:meth:`latch`: a ``robot_description``, ``/tf_static``)
    are repeated too: each new file starts with the latest message of each,
    stamped with the file's first log time (as ROS 1's ``--repeat-latched``
    and rosbag2's ``--repeat-transient-local`` do), so one file alone shows
    the drive. Those copies are messages of their file: counted in its
    ``message_count`` and in ``metadata.yaml``, read by every reader.
    ``metadata.yaml`` is written by :meth:`finish`; a killed writer leaves
    the files without it, which :func:`bag_files` still reads.
    """

    def __init__(self, folder: Union[str, "os.PathLike[str]"], *, force: bool = False,
                 max_bag_size: Optional[int] = None, max_bag_duration: Optional[float] = None,
                 hold: Optional[ContextManager[Any]] = None, blocks: bool = False, **writer_options: Any):
        self._blocks = bool(blocks)
        self._hold = contextlib.ExitStack()
        if hold is not None:
            self._hold.enter_context(hold)
        try:
            self._start(folder, force, max_bag_size, max_bag_duration, writer_options)
        except BaseException:
            self._hold.close()
            raise

    def _start(self, folder, force: bool, max_bag_size: Optional[int], max_bag_duration: Optional[float],
               writer_options: Dict[str, Any]) -> None:
        self.folder = os.fspath(folder)
        if max_bag_size is not None and max_bag_size < 0:
            raise ValueError(f"max_bag_size must be >= 0 bytes, got {max_bag_size}")
        if max_bag_duration is not None and not max_bag_duration >= 0:
            raise ValueError(f"max_bag_duration must be >= 0 s, got {max_bag_duration}")
        self.max_bag_size = int(max_bag_size or 0)
        self.max_bag_duration_ns = int(round((max_bag_duration or 0) * 1e9))
        self._options = dict(writer_options)
        self._lock = threading.RLock()
        self.name = os.path.basename(os.path.normpath(self.folder))
        self._force = force
        if os.path.exists(self.folder) and not os.path.isdir(self.folder):
            raise WriteError(self.folder, "exists and is not a folder", action="create bag folder")
        if os.path.isdir(self.folder) and not force and any(
                f.endswith(".mcap") or f == METADATA_FILE for f in os.listdir(self.folder)):
            raise OverwriteError(self.folder)
        try:
            os.makedirs(self.folder, exist_ok=True)
            if force:  # a longer earlier recording's files would otherwise read as this one's
                for f in os.listdir(self.folder):
                    stem = f[: -len(".mcap")] if f.endswith(".mcap") else ""
                    if f == METADATA_FILE or (stem.startswith(self.name + "_")
                                              and stem[len(self.name) + 1:].isdigit()):
                        os.remove(os.path.join(self.folder, f))
        except OSError as exc:
            raise WriteError(self.folder, exc, action="create bag folder") from exc
        self._done: List[Dict[str, Any]] = []  # finished files: path, times, message count
        self._topic_meta: Dict[str, Dict[str, Any]] = {}  # per topic: its metadata, messages in finished files
        self._topics: Dict[str, Tuple[str, Any, Optional[str]]] = {}
        self._types: Dict[str, str] = {}
        self._metadata: List[Tuple[str, Dict[str, str]]] = []
        self._latched: Dict[str, Optional[Tuple[str, bytes]]] = {}  # topic -> (type, CDR) of its latest message
        self._finished = False
        self._current: Ros2McapWriter = self._open(0)

    # ---------------------------------------------------------------- files
    @property
    def path(self) -> str:
        """The bag folder."""
        return self.folder

    @property
    def files(self) -> List[str]:
        """Paths of the files written so far (the open one last)."""
        return [f["abs"] for f in self._done] + [self._current.path]  # type: ignore[list-item]

    def _open(self, index: int) -> Ros2McapWriter:
        path = os.path.join(self.folder, f"{self.name}_{index}.mcap")
        if self._blocks:
            from .block_writer import BlockMcapWriter

            writer: Ros2McapWriter = BlockMcapWriter(path, force=self._force, **self._options)
        else:
            writer = Ros2McapWriter(path, force=self._force, **self._options)
        for type_name, text in self._types.items():
            writer.register_type(type_name, text)
        for name, data in self._metadata:
            writer.add_metadata(name, data)
        for topic, (type_name, qos, type_hash) in self._topics.items():
            writer.add_topic(topic, type_name, qos, type_hash=type_hash)
        return writer

    def _split_if_due(self, log_time: int) -> None:
        w = self._current
        if not w.message_count:
            return
        start, _ = w.time_range_ns
        due = (self.max_bag_size and w.bytes_written >= self.max_bag_size) or (
            self.max_bag_duration_ns and start is not None and log_time - start >= self.max_bag_duration_ns)
        if due:
            self._close_current()
            self._current = self._open(len(self._done))
            for topic, latest in self._latched.items():  # each file starts with the latched topics
                if latest is not None:
                    self._current.write_raw(topic, latest[0], latest[1], log_time)

    def _close_current(self) -> None:
        w = self._current
        w.finish()
        start, end = w.time_range_ns
        # per file only its times and count; the topics' descriptions once, their counts summed
        # (a long split recording keeps a few hundred bytes per file, not every file's QoS texts)
        for t in w.topics_metadata():
            entry = self._topic_meta.setdefault(t["name"], dict(t, message_count=0))
            entry["message_count"] += t["message_count"]
        self._done.append({
            "abs": w.path, "path": os.path.basename(w.path or ""),
            "starting_time_ns": start or 0, "duration_ns": (end - start) if start is not None else 0,
            "message_count": w.message_count,
        })

    # -------------------------------------------------------- writer interface
    @property
    def error(self) -> Optional[WriteError]:
        return self._current.error

    @property
    def failed(self) -> bool:
        return self._current.failed

    @property
    def finished(self) -> bool:
        return self._finished

    @property
    def message_count(self) -> int:
        """Messages in every file (after :meth:`finish` the last file is among the finished ones)."""
        open_file = 0 if self._finished else self._current.message_count
        return sum(f["message_count"] for f in self._done) + open_file

    def topic_counts(self) -> Dict[str, int]:
        """Messages per topic in every file (equal to ``metadata.yaml`` once finished)."""
        counts: Dict[str, int] = {name: t["message_count"] for name, t in self._topic_meta.items()}
        if not self._finished:
            for topic, n in self._current.topic_counts().items():
                counts[topic] = counts.get(topic, 0) + n
        return counts

    def latch(self, topic: str) -> None:
        """Repeat ``topic``'s latest message at the start of every later file (see the class notes)."""
        with self._lock:
            self._latched.setdefault(topic, None)

    def register_type(self, type_name: str, msg_text: str) -> None:
        with self._lock:
            self._types[type_name] = msg_text
            self._current.register_type(type_name, msg_text)

    def add_topic(self, topic: str, type_name: str, qos: Any = None, type_hash: Optional[str] = None) -> None:
        with self._lock:
            self._current.add_topic(topic, type_name, qos, type_hash=type_hash)
            self._topics.setdefault(topic, (type_name, qos, type_hash))

    def add_metadata(self, name: str, data: Dict[str, str]) -> None:
        with self._lock:
            self._current.add_metadata(name, data)
            self._metadata.append((name, dict(data)))

    def write_raw(self, topic: str, type_name: str, cdr_bytes: Any, log_time_ns: int,
                  publish_time_ns: Optional[int] = None, qos: Any = None) -> None:
        with self._lock:
            self._split_if_due(int(log_time_ns))
            self._current.write_raw(topic, type_name, cdr_bytes, log_time_ns, publish_time_ns, qos)
            self._topics.setdefault(topic, (type_name, qos, None))
            if topic in self._latched:
                self._latched[topic] = (type_name, bytes(cdr_bytes))

    def write_block(self, topics: List[Tuple[str, str]], log_time_ns: Any, payloads: List[Any]) -> None:
        """``n`` steps of several topics at once, as
        :meth:`msg_tools.block_writer.BlockMcapWriter.write_block` takes them
        (a writer made with ``blocks=True``). The files split where writing
        the same messages one by one with :meth:`write_raw` would split them:
        by duration at the first step ``max_bag_duration`` or more after the
        file's first message (every topic of a step in the same file); by
        size once the file's chunks hold ``max_bag_size`` bytes, checked after
        each chunk's worth of steps (written at once, where a run without a
        size limit compresses chunks in other threads meanwhile; a short
        block that joined the open chunk is counted once that chunk closes,
        as single messages are). Each new
        file starts with the latched topics' latest message.
        """
        import numpy as np

        from .block_writer import FixedMessages, checked_block

        if not self._blocks:
            raise TypeError("write_block needs a bag writer made with blocks=True")
        t = np.asarray(log_time_ns, dtype=np.int64)
        n = int(t.size)
        if not n or not topics:  # (no messages: none one by one either)
            return
        # (up front, as the file's writer checks each piece: the times are searched to split, the pieces sliced)
        payloads = checked_block(topics, t, payloads)
        step_bytes = sum(p.size if isinstance(p, FixedMessages) else p.shape[1] for p in payloads)
        chunk = self._current._chunk_size  # (the files' chunk size: given, or Ros2McapWriter's default)
        piece = max(1, chunk // (step_bytes + 31 * len(topics)))  # (31: a message record's header)
        with self._lock:
            a = 0
            while a < n:
                self._split_if_due(int(t[a]))
                w = self._current
                b = n
                if self.max_bag_duration_ns:
                    start = w.time_range_ns[0] if w.message_count else int(t[a])
                    b = max(a + 1, int(np.searchsorted(t, start + self.max_bag_duration_ns, "left")))
                if self.max_bag_size:
                    b = min(b, a + piece)
                joined = w.write_block(topics, t[a:b], [p[a:b] for p in payloads])
                if self.max_bag_size and not joined:
                    w.flush()  # (its chunks written now, not compressed in flight: the file's size is known)
                for (topic, type_name), p in zip(topics, payloads):
                    self._topics.setdefault(topic, (type_name, None, None))
                    if topic in self._latched:  # (its message before the next file: the piece's last)
                        last = p[b - 1 : b]
                        last = last.rows() if isinstance(last, FixedMessages) else last
                        self._latched[topic] = (type_name, last[0].tobytes())
                a = b

    def write(self, topic: str, type_name: str, message: Any, log_time_ns: int,
              publish_time_ns: Optional[int] = None, qos: Any = None) -> None:
        from . import schemas
        from .writer import encode

        full_type = schemas.normalize_type_name(type_name)
        schema = schemas.schema_text(full_type, self._types) if self._types else None
        self.write_raw(topic, full_type, encode(full_type, message, schema=schema), log_time_ns, publish_time_ns, qos)

    def flush(self) -> None:
        with self._lock:
            self._current.flush()

    def metadata_yaml(self) -> str:
        """``metadata.yaml`` for the files finished so far (all of them after :meth:`finish`)."""
        files = list(self._done)
        topics = self._topic_meta
        starts = [f["starting_time_ns"] for f in files if f["message_count"]]
        ends = [f["starting_time_ns"] + f["duration_ns"] for f in files if f["message_count"]]
        start = min(starts) if starts else 0
        body = bag_metadata_yaml(
            list(topics.values()), starting_time_ns=start,
            duration_ns=(max(ends) - start) if ends else 0,
            message_count=sum(f["message_count"] for f in files),
            custom_data=self._options.get("custom_data"),
            ros_distro=self._options.get("ros_distro", "jazzy"), files=files,
        )
        return "rosbag2_bagfile_information:\n" + "\n".join("  " + ln for ln in body.splitlines()) + "\n"

    def finish(self) -> None:
        """Finish the open file and write ``metadata.yaml``, then let go of ``hold``. Idempotent."""
        with self._lock:
            if self._finished:
                return
            self._finished = True
            with self._hold:  # (released whether the files close or fail)
                failed = self._current.failed
                self._close_current()
                if failed:
                    return  # the files read like a killed recording's; no metadata.yaml
                path = os.path.join(self.folder, METADATA_FILE)
                try:
                    with open(path + ".tmp", "w", encoding="utf-8") as f:
                        f.write(self.metadata_yaml())
                    os.replace(path + ".tmp", path)
                except OSError as exc:
                    raise WriteError(path, exc) from exc

    def __enter__(self) -> "Ros2BagWriter":
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        try:
            self.finish()
        except MsgToolsError:
            if exc_type is None:
                raise

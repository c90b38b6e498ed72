"""Replay a recorded drive torque: offline through the model, or live on ROS 2.

Offline (no ROS, deterministic)
-------------------------------
:func:`scene_with_torque_bag` replaces a scene's drive by the recorded
``drive_torque`` of a bag, as a zero-order hold
(:class:`RecordedTorque`, a :class:`~belt_drive_ros.core.sources.Table` with
``interpolation='previous'``), which is how the node sees held messages:
the value of the latest message at or before ``t`` acts at ``t``. Times are
``log_time`` relative to the first message; the scene's duration becomes the
span of the recording unless given. ``belt-drive sim SCENE --torque-bag BAG
--out run.mcap`` is this plus :func:`~belt_drive_ros.io.recording.write_result_mcap`:
the same inputs give a byte-identical output file.

Live (``belt-drive replay``)
----------------------------
:func:`run_replay` publishes the recorded messages (as serialized
``Float64`` CDR, the recorded bytes for little-endian recordings) on the
recorded topic, with the recorded spacing divided by ``rate``, from
``start_offset`` seconds into the recording, optionally looping, and with
``clock=True`` publishes ``/clock`` as well: for every message first
``/clock`` = the message's time, then the message. A node with
``use_sim_time`` then ticks to that time with the torque it held so far,
and holds the new one for the next interval, which is exactly the
zero-order hold of the offline replay. Without back-pressure that needs the
node to keep up (its ``/clock`` subscription keeps only the latest sample);
``sync_topic`` (``--sync /joint_states``) makes it lockstep: before message
k the replay waits until the node published outputs stamped t_k, so the run
is deterministic however loaded the machine is, and as fast as the node
allows at a high ``rate``. Looping keeps ``/clock`` increasing
(each pass is shifted by the span plus one sample spacing).
:func:`replay_schedule` is the pure timing of all this (tested without ROS).
"""

from __future__ import annotations

import dataclasses
import math
import os
import threading
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Tuple

import numpy as np

from msg_tools.errors import MsgToolsError, RecoveredBagWarning

from ..core.errors import BeltDriveError, InputError
from .inputs import check_path, parse_yaml
from ..core.scene import RANGES, Scene
from .scenes import scene_from_mapping
from .bag_layout import SCENE_FORMAT
from .recording import RECORDED_DRIVE, SCENE_METADATA, BagReadError, _sha256, bag_error
from ..core.profile_data import TABLE_HELD_NS
from ..core.sources import TORQUE_MAX, Table, TorqueProfile
from . import is_recording  # noqa: F401 (defined without mcap, for the sim command's first look)

__all__ = [
    "is_recording",
    "scene_from_bag",
    "RecordedTorque",
    "TorqueRecording",
    "load_torque_recording",
    "scene_with_torque_bag",
    "PagedTorque",
    "paged_torque_bag",
    "torque_bag_scene",
]

FLOAT64 = "std_msgs/msg/Float64"
DEFAULT_TOPIC = "/drive_torque"


@dataclass(frozen=True, eq=False)
class RecordedTorque(Table):
    """A :class:`Table` (zero-order hold) that remembers the bag it came from.

    ``to_dict`` is a plain ``table`` (so ``Scene.to_dict`` round-trips);
    :meth:`reference` is the short form the recording metadata stores
    instead of the samples.
    """

    interpolation: str = "previous"
    source: str = ""
    topic: str = DEFAULT_TOPIC
    sha256: str = ""
    start_ns: int = 0

    def __post_init__(self):
        super().__post_init__()
        if self.interpolation != "previous":
            raise ValueError("RecordedTorque: interpolation must be 'previous' (zero-order hold)")
    def encode(self, builder):
        # The hold switches at whole nanoseconds: ``t`` is rounded to the nearest ns before the
        # lookup, so a step that starts at a message's time uses that message even when the
        # integrator's float time grid (dt * k) lands a rounding error below it. The switching
        # times are whole ns as floats (exact below 2**53 ns, 104 days; rint as the int64 round trip).
        offset, n = builder.table(np.rint(self.times * 1e9), self.values)
        return builder.row(TABLE_HELD_NS, offset, n)

    def left_of(self, t: float) -> float:
        # one nanosecond before t's nanosecond: the hold above rounds t to whole ns
        return (round(t * 1e9) - 1) / 1e9

    def left_of_array(self, t: np.ndarray) -> np.ndarray:
        """:meth:`left_of` of each time of ``t`` [s] (the same floats: rint rounds half to even as round)."""
        return (np.rint(np.asarray(t, dtype=np.float64) * 1e9) - 1.0) / 1e9

    def to_dict(self) -> Dict[str, Any]:
        return {
            "type": "table",
            "times": self.times.tolist(),
            "values": self.values.tolist(),
            "interpolation": self.interpolation,
        }

    def reference(self) -> Dict[str, Any]:
        """``{type: recorded, bag, topic, samples, start_ns, sha256, interpolation}``."""
        return {
            "type": RECORDED_DRIVE,
            "bag": self.source,
            "topic": self.topic,
            "samples": int(self.times.size),
            "start_ns": int(self.start_ns),
            "sha256": self.sha256,
            "interpolation": self.interpolation,
        }


@dataclass(frozen=True)
class TorqueRecording:
    """The ``drive_torque`` messages of a bag.

    Attributes
    ----------
    path : str
    topic : str
        Topic as stored.
    log_time_ns : (N,) int64
        Receive times [ns], sorted.
    values : (N,) float
        Torques [N m].
    payloads : list of bytes or None
        The serialized messages (for live replay).
    offered_qos : str
        The channel's ``offered_qos_profiles`` YAML.
    complete : bool
        False if the file was cut off (read up to its last complete chunk).
    """

    path: str
    topic: str
    log_time_ns: np.ndarray
    values: np.ndarray
    payloads: Optional[List[bytes]] = None
    offered_qos: str = ""
    complete: bool = True
    stop_reason: str = ""

    @property
    def span_ns(self) -> int:
        return int(self.log_time_ns[-1] - self.log_time_ns[0]) if self.log_time_ns.size else 0

    @property
    def period_ns(self) -> int:
        """Median spacing of the messages [ns] (0 for a single message)."""
        if self.log_time_ns.size < 2:
            return 0
        return int(np.median(np.diff(self.log_time_ns)))


def _damaged(data_bag, name: str) -> BagReadError:
    """The error of a recording cut off or damaged before any message of topic ``name`` could be read."""
    return BagReadError(f"{data_bag.path}: damaged or incomplete recording ({data_bag.stop_reason}): no {name} message "
                        f"could be read before the damage; 'msg-tools info {data_bag.path}' says what is missing")


def load_torque_recording(bag, topic: str = DEFAULT_TOPIC, *, keep_payloads: bool = False,
                          warn=None) -> TorqueRecording:
    """Read the drive torque of ``bag``.

    Parameters
    ----------
    bag : path
    topic : str
        ``/drive_torque`` by default; the leading ``/`` may be omitted, and a
        single Float64 topic ending in ``drive_torque`` (a namespaced node's)
        is found too.
    keep_payloads : bool
        Keep the serialized messages (live replay publishes them unchanged).
    warn : callable, optional
        Called with one line if the file was cut off (default: ``warnings.warn``).

    Raises
    ------
    BagReadError
        Missing file, not MCAP, topic absent, wrong type, no messages.
    """
    from msg_tools.errors import MsgToolsError, RecoveredBagWarning
    from msg_tools.reader import read_bag, summary

    name = topic if topic.startswith("/") else "/" + topic
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecoveredBagWarning)
        try:
            data_bag = read_bag(bag, [name], missing_ok=True)  # one pass over the file
            if name not in data_bag.available:
                base = name.rsplit("/", 1)[-1]
                candidates = [t for t in data_bag.available if t.endswith("/" + base)]
                if len(candidates) != 1:
                    if not data_bag.complete:  # cut off or damaged before the topic's channel: not a missing topic
                        raise _damaged(data_bag, name)
                    listing = ", ".join(data_bag.available) or "none"
                    pick = "; name one (belt-drive sim --torque-topic)" if len(candidates) > 1 else ""
                    raise BagReadError(f"{data_bag.path}: no topic {name} (topics: {listing}){pick}")
                name = candidates[0]
                data_bag = read_bag(bag, [name], missing_ok=True)
            offered = ""
            if keep_payloads:
                offered = next((t.offered_qos_profiles for t in summary(bag, verify=False).topics if t.topic == name), "")
        except MsgToolsError as exc:
            raise bag_error(exc) from None
    path = data_bag.path
    if name not in data_bag.topics or len(data_bag.topics[name]) == 0:
        if not data_bag.complete:  # cut off or damaged before any of its messages: not an empty topic
            raise _damaged(data_bag, name)
        raise BagReadError(f"{path}: topic {name} has no messages")
    data = data_bag.topics[name]
    if data.type_name != FLOAT64:
        raise BagReadError(f"{path}: topic {name} has type {data.type_name}, expected {FLOAT64}")
    values = np.asarray(data.data, dtype=float)
    if not np.all(np.isfinite(values)):
        bad = int(np.count_nonzero(~np.isfinite(values)))
        raise BagReadError(f"{path}: {bad} non-finite value(s) on {name}")
    if not np.all(np.abs(values) <= TORQUE_MAX):  # (a profile's plausible range: 1e300 N m diverged the run)
        bad = int(np.count_nonzero(np.abs(values) > TORQUE_MAX))
        raise BagReadError(f"{path}: {bad} value(s) on {name} beyond the plausible +-{TORQUE_MAX:g} N m")
    if not data.complete:
        text = (f"{path} was not finalized ({data.stop_reason}); "
                f"using the {len(data)} messages up to its last complete chunk")
        (warn or (lambda m: warnings.warn(m, RecoveredBagWarning, stacklevel=3)))(text)
    payloads = None
    if keep_payloads:
        from .recording import encode_float64

        # Float64 CDR has no padding: re-encoding gives the recorded bytes
        # (little endian, as every ROS 2 middleware writes them)
        payloads = encode_float64(values)
    return TorqueRecording(
        path=path,
        topic=name,
        log_time_ns=np.asarray(data.log_time_ns, dtype=np.int64),
        values=values,
        payloads=payloads,
        offered_qos=offered,
        complete=data.complete,
        stop_reason=data.stop_reason,
    )


def _zoh_table(times_ns: np.ndarray, values: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Strictly increasing times [s from the first] and values; at equal times the later message wins."""
    return _zoh_table_relative(times_ns - times_ns[0], values)


def _zoh_table_relative(rel: np.ndarray, values: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """:func:`_zoh_table` of times already relative to the first message [ns] (int64)."""
    last = np.ones(rel.size, dtype=bool)
    last[:-1] = rel[1:] != rel[:-1]
    if not last.all():  # (no copies of an hour's samples when no two share a time)
        rel, values = rel[last], values[last]
    times = rel.astype(np.float64)
    del rel
    times *= 1e-9  # the float product rel * 1e-9, in place
    return times, values


def scene_with_torque_bag(scene, bag, *, topic: str = DEFAULT_TOPIC, duration: Optional[float] = None,
                          warn=None):
    """``scene`` driven by the torque recorded in ``bag`` (zero-order hold).

    Parameters
    ----------
    scene : Scene
    bag : path
        MCAP with ``std_msgs/Float64`` messages on ``topic``.
    topic : str
        Default ``/drive_torque``.
    duration : float, optional
        Simulated time [s]; default the span from the first to the last
        message (the scene's own duration if the bag holds one message).
    warn : callable, optional
        Receives a one-line warning if the bag was cut off.

    Returns
    -------
    Scene
        With ``drive`` = :class:`RecordedTorque` (times relative to the first
        message; at equal times the later message wins) and the duration.
        Load, parameters, initial state, model and integrator are the scene's.

    Raises
    ------
    BagReadError
        If the bag cannot be read or has no usable torque (one line).
    """
    rec = load_torque_recording(bag, topic, warn=warn)
    times, values = _zoh_table(rec.log_time_ns, rec.values)
    if duration is None:
        duration = float(times[-1]) if times.size > 1 else scene.duration
        _check_span(rec.path, duration)
    if not (duration > 0 and math.isfinite(duration)):
        raise BagReadError(f"{rec.path}: duration must be > 0 s, got {duration!r}")
    drive = RecordedTorque(
        times=times,
        values=values,
        interpolation="previous",
        source=os.path.basename(rec.path),
        topic=rec.topic,
        sha256=_sha256(bag) if isinstance(bag, (str, os.PathLike)) else "",
        start_ns=int(rec.log_time_ns[0]),
    )
    dt = min(scene.dt, duration)
    description = _described(scene.description, os.path.basename(rec.path))
    return dataclasses.replace(scene, drive=drive, duration=float(duration), dt=dt, description=description)


def _described(description: str, source: str) -> str:
    """``description`` of a scene driven by the torque bag named ``source``: it says so once (a recording's own
    scene, re-simulated, already says it: each re-simulation said it once more)."""
    note = f"Drive torque recorded in {source}."
    return description if description.endswith(note) else f"{description} {note}".strip()


#: chunks decoded at a time by the pass that opens a :class:`PagedTorque`
PASS_CHUNKS = 8
#: decoded chunks a :class:`PagedTorque` keeps
CACHED_CHUNKS = 4
#: a gap [s] between two times asked of :meth:`PagedTorque.torque` that starts another page
PAGE_GAP = 1.0


class PagedTorque(TorqueProfile):
    """The drive torque of a bag as :class:`RecordedTorque` gives it, read from the file a page at a time.

    The same zero-order hold (times [s] relative to the first message, at
    equal times the later message wins), but no sample is held for the
    whole run: :meth:`page` returns a :class:`RecordedTorque` of the samples
    from the last one at or before ``t0`` to the first one at or after
    ``t1``, which gives every time in ``[t0, t1]`` the torque, the
    breakpoints and the kernel's table lookup of the whole recording
    (its times are the same floats). The core's stepper reads pages of its
    windows (:class:`~belt_drive_ros.core.stepper.Plant`); what asks for
    the whole table (:meth:`breakpoints`, :meth:`encode`, :meth:`to_dict`)
    gets it, read whole (:meth:`whole`). Made by :func:`paged_torque_bag`.
    """

    kind = "table"
    state_dependent = False
    uses_angle = False
    interpolation = "previous"
    left_of = RecordedTorque.left_of
    left_of_array = RecordedTorque.left_of_array

    def __init__(self, chunked, start_ns: int, samples: int, changes: bool, min_gap: float, bag, source: str,
                 topic: str, sha256: str):
        self._chunked, self.start_ns, self.samples = chunked, int(start_ns), int(samples)
        self._changes, self._min_gap = bool(changes), float(min_gap)
        self.longest_silence = (0.0, 0.0)  # (length, start) [s] of the longest stretch without a message
        self.last_time: Optional[float] = None  # [s] of the last message after the first (the opening pass's)
        self._bag, self.source, self.topic, self.sha256 = bag, source, topic, sha256
        # per thread (a run's guard reads pages beside its windows): ``last`` (t0, t1, page) of the last page
        # read, ``cache`` {chunk index: (log times, values)}, least recently used first
        self._local = threading.local()
        self._lock = threading.Lock()
        #: CPU time [s] spent decoding chunks, every thread's (the figure ``bench replay`` reports)
        self.read_cpu = 0.0
        self._ahead: Optional[dict] = None  # the opening pass's chunks decoded beside it (:meth:`_chunk`)

    def _mine(self):
        """This thread's ``last`` page and chunk ``cache`` (made on first use)."""
        local = self._local
        if not hasattr(local, "cache"):
            local.last, local.cache = None, {}
        return local

    @property
    def times(self):  # Table's interface (reference() reads times.size): the whole, read on use
        return self.whole().times

    @property
    def values(self):
        return self.whole().values

    def whole(self) -> RecordedTorque:
        """The whole recording as :func:`scene_with_torque_bag` reads it (every sample in memory)."""
        rec = load_torque_recording(self._bag, self.topic)
        times, values = _zoh_table(rec.log_time_ns, rec.values)
        return RecordedTorque(times=times, values=values, interpolation="previous", source=self.source,
                              topic=self.topic, sha256=self.sha256, start_ns=self.start_ns)

    def reference(self) -> Dict[str, Any]:
        """:meth:`RecordedTorque.reference`, without reading the samples."""
        return {"type": RECORDED_DRIVE, "bag": self.source, "topic": self.topic, "samples": self.samples,
                "start_ns": self.start_ns, "sha256": self.sha256, "interpolation": self.interpolation}

    def _decode(self, i: int, j: int) -> Tuple[np.ndarray, np.ndarray]:
        """Log times [ns from the first message] and values of chunks i .. j - 1, widened over seams where
        equal times continue (so a run of equal times is whole: its last message wins, as in the whole read)."""
        c = self._chunked
        while i > 0 and c.starts[i] == c.ends[i - 1]:
            i -= 1
        while j < len(c) and c.starts[j] == c.ends[j - 1]:
            j += 1
        parts = [self._chunk(k) for k in range(i, j)]  # in time order, each sorted: the whole read's order
        return (np.concatenate([p[0] for p in parts]) - self.start_ns if len(parts) > 1 else parts[0][0] - self.start_ns,
                np.concatenate([p[1] for p in parts]) if len(parts) > 1 else parts[0][1])

    def _decoded(self, k: int) -> Tuple[np.ndarray, np.ndarray]:
        """Log times [ns] and values of chunk ``k`` read from the file (its CPU time counted in :attr:`read_cpu`)."""
        start = time.thread_time()
        try:
            return self._chunked.float64(k)
        finally:
            with self._lock:
                self.read_cpu += time.thread_time() - start

    def _chunk(self, k: int) -> Tuple[np.ndarray, np.ndarray]:
        """Log times [ns] and values of chunk ``k``; the last :data:`CACHED_CHUNKS` are kept (consecutive
        pages share the chunk at their seam). The pass that opens the bag has the next chunks decoded beside it
        (``_ahead``: {chunk index: future}; one not started yet is decoded here)."""
        cache = self._mine().cache
        got = cache.pop(k, None)
        if got is None:
            ahead = self._ahead.pop(k, None) if self._ahead else None
            try:
                got = ahead.result() if ahead is not None and not ahead.cancel() else self._decoded(k)
            except MsgToolsError as exc:  # (the pass that opened the bag read every chunk)
                raise bag_error(exc) from None
            if len(cache) >= CACHED_CHUNKS:
                del cache[next(iter(cache))]
        cache[k] = got
        return got

    def page(self, t0: float, t1: float) -> RecordedTorque:
        """The samples that give the torque on ``[t0, t1]`` [s] (see the class)."""
        mine = self._mine()
        last = mine.last
        if last is not None and last[0] <= t0 and t1 <= last[1]:
            return last[2]
        c = self._chunked
        lo = self.start_ns + math.floor(t0 * 1e9) - 1
        hi = self.start_ns + math.ceil(t1 * 1e9) + 1
        i = max(0, int(np.searchsorted(c.starts, lo, side="right")) - 1)
        j = min(len(c), int(np.searchsorted(c.ends, hi, side="left")) + 1)
        times, values = _zoh_table_relative(*self._decode(i, j))
        a = max(0, int(np.searchsorted(times, t0, side="right")) - 1)
        b = min(times.size - 1, int(np.searchsorted(times, t1, side="left")))
        page = RecordedTorque(times=times[a : b + 1].copy(), values=values[a : b + 1].copy(), interpolation="previous",
                              source=self.source, topic=self.topic, sha256=self.sha256, start_ns=self.start_ns)
        mine.last = (t0, t1, page)
        return page

    def torque(self, t, angle=0.0, speed=0.0):
        """As the whole table's: times closer than :data:`PAGE_GAP` read from one page."""
        if not np.ndim(t):
            return self.page(float(t), float(t)).torque(t, angle, speed)
        t = np.asarray(t, dtype=float)
        ts, angles, speeds = np.broadcast_arrays(t, np.asarray(angle, dtype=float), np.asarray(speed, dtype=float))
        flat = ts.ravel()
        out = np.empty(flat.size)
        order = np.argsort(flat, kind="stable")
        s = flat[order]
        cuts = np.flatnonzero(np.diff(s) > PAGE_GAP) + 1 if s.size else []
        for part in np.split(order, cuts):
            if part.size:
                out[part] = self.page(float(flat[part].min()), float(flat[part].max())).torque(
                    flat[part], angles.ravel()[part], speeds.ravel()[part])
        return out.reshape(ts.shape)

    def scalar_torque(self):
        return lambda t, angle, speed: float(self.torque(t, angle, speed))

    def encode(self, builder):
        return self.whole().encode(builder)

    def breakpoints(self):
        return self.whole().breakpoints()

    def excitation_frequencies(self, speed):
        if self.samples < 2:
            return []
        if self._changes:
            return [(math.inf, "table with zero-order hold (step changes)")]
        return [(0.5 / self._min_gap, "table (Nyquist of its sample spacing)")]

    def to_dict(self) -> Dict[str, Any]:
        return self.whole().to_dict()

    def close(self) -> None:
        """Release the file (the profile reads no page after this)."""
        self._chunked.close()

    def __eq__(self, other):
        return other is self

    __hash__ = object.__hash__


def paged_torque_bag(scene, bag, *, topic: str = DEFAULT_TOPIC, duration: Optional[float] = None):
    """:func:`scene_with_torque_bag` with the drive a :class:`PagedTorque` (memory bounded by a page, not the
    bag), or None when the bag must be read whole (a folder, a file cut off or damaged, no chunk index,
    chunks out of time order, a topic the whole read would refuse or resolve otherwise)."""
    from msg_tools.chunked import topic_chunks

    from msg_tools import summary

    name = topic if topic.startswith("/") else "/" + topic
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RecoveredBagWarning)
            topics = [t.topic for t in summary(bag, verify=False).topics]
        if name not in topics:  # a namespaced node's single .../drive_torque, as the whole read finds it
            candidates = [t for t in topics if t.endswith("/" + name.rsplit("/", 1)[-1])]
            name = candidates[0] if len(candidates) == 1 else name
        chunked, _why = topic_chunks(bag, name)
    except (MsgToolsError, OSError):
        return None
    if chunked is None:
        return None
    drive = None
    try:
        for cid in chunked._cids:  # every channel of the topic (the whole read refuses a topic of mixed types)
            schema = chunked._summary.schemas.get(chunked._summary.channels[cid].schema_id)
            if schema is None or schema.name.replace("/msg/", "/") != FLOAT64.replace("/msg/", "/"):
                raise LookupError
        first = chunked.float64(0)[0]
        if not len(first):
            raise LookupError
        drive = PagedTorque(chunked, int(np.min(first)), 0, False, math.inf, bag, os.path.basename(os.fspath(bag)),
                            chunked.topic, "")
        # one pass: what the whole read checks (finite values) and knows (samples, last time, steps, spacing). A
        # thread of its own hashes the file, then decodes the next chunks while this one takes the current ones (zstd,
        # the CRC and the hash release the GIL): the same arrays, in the same order, on both cores
        pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="bag-pass")
        digest = pool.submit(_sha256, bag)
        drive._ahead = {}
        try:
            samples, changes, gap, last_t, last_v, silence = 0, False, math.inf, None, None, (0.0, 0.0)
            for k in range(0, len(chunked), PASS_CHUNKS):
                for a in range(k + PASS_CHUNKS, min(len(chunked), k + 2 * PASS_CHUNKS)):  # (at most two groups decoded)
                    if a not in drive._ahead:
                        drive._ahead[a] = pool.submit(drive._decoded, a)
                rel, raw = drive._decode(k, min(len(chunked), k + PASS_CHUNKS))
                if not np.all(np.abs(raw) <= TORQUE_MAX):  # (non-finite too: the whole read names what is wrong)
                    raise LookupError
                times, values = _zoh_table_relative(rel, raw)
                if last_t is not None:  # a widened read repeats what the last one took
                    keep = times > last_t
                    times, values = times[keep], values[keep]
                if not times.size:
                    continue
                if last_t is not None:
                    gap = min(gap, float(times[0] - last_t))
                    changes = changes or bool(values[0] != last_v)
                    silence = max(silence, (float(times[0] - last_t), last_t), key=lambda g: g[0])
                if times.size > 1:
                    spacing = np.diff(times)
                    gap = min(gap, float(np.min(spacing)))
                    j = int(np.argmax(spacing))
                    silence = max(silence, (float(spacing[j]), float(times[j])), key=lambda g: g[0])
                    changes = changes or bool(np.any(values[1:] != values[:-1]))
                samples += times.size
                last_t, last_v = float(times[-1]), float(values[-1])
            drive.sha256 = digest.result()
        finally:  # (before the file can be closed below)
            drive._ahead = None
            pool.shutdown(wait=True, cancel_futures=True)
    except (LookupError, MsgToolsError, BeltDriveError):  # the whole read says what is wrong in its own words
        chunked.close()
        return None
    drive.samples, drive._changes, drive._min_gap = samples, changes, gap
    drive.longest_silence, drive.last_time = silence, last_t
    end_s = last_t
    if duration is None:
        duration = end_s if samples > 1 else scene.duration
        if 0.0 < duration < RANGES["duration"][0]:  # (refused by _check_span: the file closed first)
            chunked.close()
            _check_span(bag, duration)
    if not (duration > 0 and math.isfinite(duration)):
        chunked.close()
        raise BagReadError(f"{bag}: duration must be > 0 s, got {duration!r}")
    dt = min(scene.dt, duration)
    description = _described(scene.description, drive.source)
    return dataclasses.replace(scene, drive=drive, duration=float(duration), dt=dt, description=description)


#: a stretch of a torque bag without a message is named before a run when longer than this [s] ...
SILENCE_NOTE_S = 1.0
#: ... and than this many of the bag's shortest message spacings (a bag of a few steps is held by design)
SILENCE_NOTE_SPACINGS = 1000.0


def silence_note(drive) -> str:
    """A line naming the longest stretch without a torque message of a recorded ``drive``
    (:class:`RecordedTorque` or :class:`PagedTorque`) when it is longer than :data:`SILENCE_NOTE_S` and
    :data:`SILENCE_NOTE_SPACINGS` of its shortest spacing: the drive holds the last torque through it, which
    a recording cut short or a publisher that stalled makes easy to miss; '' otherwise."""
    if isinstance(drive, PagedTorque) and drive.samples > 1:
        (length, start), spacing = drive.longest_silence, drive._min_gap
    elif isinstance(drive, RecordedTorque) and len(drive.times) > 1:
        steps = np.diff(drive.times)
        j = int(np.argmax(steps))
        length, start, spacing = float(steps[j]), float(drive.times[j]), float(np.min(steps))
    else:
        return ""
    if length > SILENCE_NOTE_S and length > SILENCE_NOTE_SPACINGS * spacing:
        return (f"note: {drive.source} has no torque message for {length:.6g} s (from {start:.6g} s after its first "
                "message): the drive holds the last torque through it")
    return ""


def tail_note(drive, duration: float) -> str:
    """A line when a run of ``duration`` [s] goes on past the last torque message of a recorded ``drive``
    (:class:`RecordedTorque` or :class:`PagedTorque`) by more than the recording's shortest spacing: the drive
    holds that last torque to the end, which a ``--duration`` longer than the bag makes easy to miss; '' otherwise."""
    if isinstance(drive, PagedTorque) and drive.last_time is not None:
        last, spacing = drive.last_time, drive._min_gap
    elif isinstance(drive, RecordedTorque) and len(drive.times):
        last = float(drive.times[-1])
        spacing = float(np.min(np.diff(drive.times))) if len(drive.times) > 1 else math.inf
    else:
        return ""
    tail = duration - last
    if tail > 0.0 and tail > min(spacing, SILENCE_NOTE_S):
        return (f"note: {drive.source}'s last torque message is at {last:.6g} s and the run lasts {duration:.6g} s: the "
                f"drive holds that torque for the last {tail:.6g} s")
    return ""


def torque_bag_scene(scene, bag, *, topic: str = DEFAULT_TOPIC, streamed=None, duration: Optional[float] = None):
    """``scene`` driven by the torque of ``bag``: :func:`paged_torque_bag` when ``streamed(scene)`` says the
    run streams in windows (:func:`~belt_drive_ros.core.stream.stream`) and the bag can be paged, else
    :func:`scene_with_torque_bag` (every sample in memory). ``duration`` [s]: the run's (default: the bag's span)."""
    if streamed is not None:
        paged = paged_torque_bag(scene, bag, topic=topic, duration=duration)
        if paged is not None:
            if streamed(paged):
                return paged
            paged.drive.close()
    return scene_with_torque_bag(scene, bag, topic=topic, duration=duration)


def _check_span(path, span: float) -> None:
    """Refuse a bag whose torque spans less than the shortest run, naming the bag (the scene's own check named the
    duration the caller may have set: ``duration: 9.99e-07 s is outside ...`` with ``--duration 0.5`` given)."""
    low = RANGES["duration"][0]
    if 0.0 < span < low:
        raise BagReadError(f"{path}: its torque spans {span:g} s, less than the shortest run ({low:g} s); give the "
                           "run's duration (belt-drive sim --duration)")


# --------------------------------------------------------- re-simulation
def _read_metadata(path) -> Tuple[Dict[str, str], str]:
    """``scene`` metadata of a bag and its path text; errors as :class:`BagReadError`.

    A split bag folder's last file holds every metadata record written
    (each file repeats those before it).
    """
    import warnings

    from msg_tools import bag_files, summary

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecoveredBagWarning)
        try:
            info = summary(bag_files(path)[-1], verify=False)
        except MsgToolsError as exc:
            raise bag_error(exc) from None
    return info.metadata_dict(SCENE_METADATA), os.fspath(path)


def scene_from_bag(path, *, torque_bag=None):
    """Rebuild the :class:`~belt_drive_ros.core.scene.Scene` stored in a recording.

    Parameters
    ----------
    path : path
        An MCAP file written by :func:`~belt_drive_ros.io.recording.write_result_mcap`, a
        :class:`~belt_drive_ros.ros.recorder.NodeRecorder` or ``belt-drive make-bags``.
    torque_bag : path, optional
        Where the recorded drive torque is, when the scene refers to one
        (``drive: {type: recorded, ...}``). By default the bag named in the
        reference, looked up next to ``path``; a node recording refers to its
        own ``drive_torque`` topic (``bag: ""``).

    Returns
    -------
    Scene
        With the model, integrator and step the run used; a recorded drive is
        the zero-order hold of the referenced bag's ``drive_torque``
        (:func:`scene_with_torque_bag`), over the stored
        duration.

    Raises
    ------
    BagReadError
        If the file has no ``scene`` record, the record is invalid, or the
        referenced torque bag is missing or has changed (sha256).
    """
    record, name = _read_metadata(path)
    if "yaml" not in record:
        raise BagReadError(f"{name}: no '{SCENE_METADATA}' metadata record; not written by belt_drive_ros")
    fmt = str(record.get("format", SCENE_FORMAT))
    if fmt != SCENE_FORMAT:  # (a later version's record may mean other things by the same keys)
        raise BagReadError(f"{name}: its '{SCENE_METADATA}' record is format {fmt[:60]!r}; this version reads "
                           f"{SCENE_FORMAT!r}")
    try:
        data = parse_yaml(record["yaml"], "scene metadata")
    except InputError as exc:
        raise BagReadError(f"{name}: {exc}") from None
    if not isinstance(data, dict):
        raise BagReadError(f"{name}: scene metadata is not a mapping")
    drive = data.get("drive")
    reference = drive if isinstance(drive, dict) and drive.get("type") == RECORDED_DRIVE else None
    if reference is not None:
        data = dict(data, drive=0.0)
    try:
        scene = scene_from_mapping(data)
    except (BeltDriveError, ValueError, TypeError) as exc:
        raise BagReadError(f"{name}: stored scene is invalid: {exc}") from None
    if reference is None:
        return scene
    source = torque_bag
    if source is None:
        ref = str(reference.get("bag", ""))
        source = path if ref in ("", "self") else os.path.join(os.path.dirname(os.fspath(path)), ref)
        if not os.path.exists(source):
            raise BagReadError(
                f"{name}: the drive torque was recorded in {ref}, which is not next to it "
                "(pass torque_bag=... / --torque-bag)"
            )
        try:  # (the stored name could be /dev/zero or a FIFO: hashing it never ended)
            check_path(source, "the recorded torque bag", folder=True)
        except InputError as exc:
            raise BagReadError(f"{name}: {exc}") from None
        expected = reference.get("sha256")
        if expected and ref not in ("", "self") and _sha256(source) != expected:
            raise BagReadError(
                f"{name}: {source} is not the torque bag this run used (sha256 differs); "
                "regenerate the pair or pass torque_bag=..."
            )
    # a node recording runs as long as it was recorded: its span; an offline run: its duration
    own = torque_bag is None and str(reference.get("bag", "")) in ("", "self")
    return scene_with_torque_bag(
        scene, source, topic=str(reference.get("topic", "/drive_torque")),
        duration=None if own else scene.duration,
    )

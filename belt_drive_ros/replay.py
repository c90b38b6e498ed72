"""Replay a recorded drive torque: offline through the model, or live on ROS 2.

Offline (no ROS, deterministic)
-------------------------------
:func:`scene_with_torque_bag` replaces a scene's drive by the recorded
``drive_torque`` of a bag, as a zero-order hold
(:class:`RecordedTorque`, a :class:`~belt_drive_ros.sources.Table` with
``interpolation='previous'``), which is how the node sees held messages:
the value of the latest message at or before ``t`` acts at ``t``. Times are
``log_time`` relative to the first message; the scene's duration becomes the
span of the recording unless given. ``belt-drive sim SCENE --torque-bag BAG
--out run.mcap`` is this plus :func:`~belt_drive_ros.recording.write_result_mcap`:
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
import warnings
from dataclasses import dataclass
from typing import Any, Dict, Iterator, List, Optional, Tuple

import numpy as np

from .recording import RECORDED_DRIVE, BagReadError, _sha256, bag_error
from .sources import Table

__all__ = [
    "RecordedTorque",
    "TorqueRecording",
    "load_torque_recording",
    "replay_schedule",
    "run_replay",
    "scene_with_torque_bag",
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
        object.__setattr__(self, "_times_ns", np.round(self.times * 1e9).astype(np.int64))

    # The hold switches at whole nanoseconds: ``t`` is rounded to the nearest
    # ns before the lookup, so a step that starts at a message's time uses
    # that message even when the integrator's float time grid (dt * k) lands
    # a rounding error below it.
    def torque(self, t, angle=0.0, speed=0.0):
        t_ns = np.rint(np.asarray(t, dtype=float) * 1e9).astype(np.int64)
        idx = np.clip(np.searchsorted(self._times_ns, t_ns, side="right") - 1, 0, self.times.size - 1)
        out = self.values[idx]
        return out if np.ndim(t) else float(out)

    __call__ = torque

    def scalar_torque(self):
        from bisect import bisect_right

        times_ns, values = self._times_ns.tolist(), self.values.tolist()
        last = len(times_ns) - 1

        def held(t, angle, speed):
            # values[clip(searchsorted(times_ns, round(t [ns]), 'right') - 1, 0, last)]
            j = bisect_right(times_ns, round(t * 1e9)) - 1
            return values[0 if j < 0 else last if j > last else j]

        return held

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
                    listing = ", ".join(data_bag.available) or "none"
                    raise BagReadError(f"{data_bag.path}: no topic {name} (topics: {listing})")
                name = candidates[0]
                data_bag = read_bag(bag, [name], missing_ok=True)
            offered = ""
            if keep_payloads:
                offered = next((t.offered_qos_profiles for t in summary(bag).topics if t.topic == name), "")
        except MsgToolsError as exc:
            raise bag_error(exc) from None
    path = data_bag.path
    if name not in data_bag.topics:
        raise BagReadError(f"{path}: topic {name} has no messages")
    data = data_bag.topics[name]
    if data.type_name != FLOAT64:
        raise BagReadError(f"{path}: topic {name} has type {data.type_name}, expected {FLOAT64}")
    if len(data) == 0:
        raise BagReadError(f"{path}: topic {name} has no messages")
    values = np.asarray(data.data, dtype=float)
    if not np.all(np.isfinite(values)):
        bad = int(np.count_nonzero(~np.isfinite(values)))
        raise BagReadError(f"{path}: {bad} non-finite value(s) on {name}")
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
    rel = times_ns - times_ns[0]
    last = np.ones(rel.size, dtype=bool)
    last[:-1] = rel[1:] != rel[:-1]
    return rel[last].astype(np.float64) * 1e-9, values[last]


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
    description = f"{scene.description} Drive torque recorded in {os.path.basename(rec.path)}.".strip()
    return dataclasses.replace(scene, drive=drive, duration=float(duration), dt=dt, description=description)


# ----------------------------------------------------------------- live
def replay_schedule(log_time_ns: np.ndarray, *, rate: float = 1.0, start_offset: float = 0.0,
                    loop: bool = False, max_loops: Optional[int] = None) -> Iterator[Tuple[float, int, int]]:
    """Timing of a live replay: ``(wall offset [s], clock [ns], message index)`` in order.

    Parameters
    ----------
    log_time_ns : (N,) int, sorted
        Recorded times.
    rate : float
        Playback speed (2: twice as fast); > 0.
    start_offset : float
        Skip the first ``start_offset`` seconds of the recording [s]; the
        first message at or after it is published at wall offset 0.
    loop : bool
        Repeat forever (or ``max_loops`` passes). Pass ``k`` is shifted by
        ``k * (span + period)`` on the clock, ``span`` = last - first
        published time and ``period`` = the median spacing, so ``/clock``
        keeps increasing.

    Returns
    -------
    iterator of (float, int, int)
        Wall-clock offset from the start of the replay [s], the ``/clock``
        value for the message [ns] (its recorded time, shifted per pass),
        and the index of the message in ``log_time_ns``.

    Raises
    ------
    ValueError
        At once (not on iteration) for a bad rate or an offset past the end.
    """
    if not (rate > 0 and math.isfinite(rate)):
        raise ValueError(f"rate must be a finite number > 0, got {rate!r}")
    if not (start_offset >= 0 and math.isfinite(start_offset)):
        raise ValueError(f"start offset must be >= 0 s, got {start_offset!r}")
    times = np.asarray(log_time_ns, dtype=np.int64)
    if times.size == 0:
        return iter(())
    begin = int(times[0]) + int(round(start_offset * 1e9))
    first = int(np.searchsorted(times, begin, side="left"))
    if first >= times.size:
        raise ValueError(
            f"start offset {start_offset:g} s is past the end of the recording ({(times[-1] - times[0]) / 1e9:g} s)"
        )
    return _schedule(times, first, rate, loop, max_loops)


def _schedule(times, first, rate, loop, max_loops):
    selected = times[first:]
    span = int(selected[-1] - selected[0])
    period = int(np.median(np.diff(selected))) if selected.size > 1 else 1_000_000
    shift = span + max(period, 1)
    passes = 0
    while True:
        base = passes * shift
        for k in range(first, times.size):
            clock = int(times[k]) + base
            yield (clock - int(selected[0])) / 1e9 / rate, clock, k
        passes += 1
        if not loop or (max_loops is not None and passes >= max_loops):
            return


def _rclpy_qos(offered_yaml: str):
    """rclpy QoS from the bag's offered profiles (first one), default reliable depth 10."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    from msg_tools.qos import parse_offered_qos_yaml

    try:
        profiles = parse_offered_qos_yaml(offered_yaml)
    except ValueError:
        profiles = []
    if not profiles:
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10)
    p = profiles[0]
    return QoSProfile(
        history=HistoryPolicy.KEEP_ALL if p.history == "keep_all" else HistoryPolicy.KEEP_LAST,
        depth=max(1, p.depth),
        reliability=ReliabilityPolicy.BEST_EFFORT if p.reliability == "best_effort" else ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if p.durability == "transient_local" else DurabilityPolicy.VOLATILE,
    )


def run_replay(bag, *, rate: float = 1.0, loop: bool = False, start_offset: float = 0.0,
               clock: bool = False, topic: str = DEFAULT_TOPIC, out_topic: Optional[str] = None,
               wait_subscribers: int = 0, wait_timeout: float = 10.0, delay: float = 0.0,
               sync_topic: Optional[str] = None, sync_timeout: float = 2.0, max_loops: Optional[int] = None,
               ros_args: Optional[List[str]] = None, should_stop=None, log=print) -> int:
    """Publish the recorded drive torque of ``bag`` on ROS 2 (see the module docstring).

    Parameters
    ----------
    bag : path
    rate, loop, start_offset : see :func:`replay_schedule`.
    clock : bool
        Also publish ``/clock`` (``rosgraph_msgs/Clock``) before each message.
    topic : str
        Topic to read from the bag.
    out_topic : str, optional
        Topic to publish on; default the recorded one (remap with ``--ros-args -r``).
    wait_subscribers : int
        Wait (up to ``wait_timeout`` s) until this many subscribers match the
        torque topic (and ``/clock``) before the first message.
    delay : float
        Wall seconds to wait before the first message (after the subscribers
        matched: discovery completes on the subscriber's side a little later,
        and what is published before is lost to it).
    sync_topic : str, optional
        Lockstep with ``clock``: after publishing ``/clock`` = t_k, wait (up
        to ``sync_timeout`` s) until a ``sensor_msgs/JointState`` stamped at
        or after t_k arrives on this topic (the node's ``joint_states``, i.e.
        it has ticked to t_k), and only then publish message k. The node then
        always ticks before it takes the next torque, so the run is the same
        however loaded the machine is (and runs as fast as the node allows
        when ``rate`` is high). Needs every message time to be a tick of the
        node (bag rate <= node rate, on its tick grid); ``/clock`` = 0 is
        not waited for (ROS reads it as "unset").
    ros_args : list of str, optional
        ROS arguments for the replay node (``--ros-args`` is prepended if absent).
    should_stop : callable, optional
        Polled between messages; True ends the replay (signal handlers set it).

    Returns
    -------
    int
        Messages published.
    """
    import time

    from . import ros_env

    rec = load_torque_recording(bag, topic, keep_payloads=True, warn=lambda m: log(f"warning: {m}"))
    schedule = replay_schedule(rec.log_time_ns, rate=rate, start_offset=start_offset, loop=loop,
                               max_loops=max_loops)
    ros_env.configure_environment()
    import rclpy
    from builtin_interfaces.msg import Time
    from rclpy.context import Context
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.signals import SignalHandlerOptions
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Float64

    args = list(ros_args or [])
    if args and args[0] != "--ros-args":
        args = ["--ros-args"] + args
    context = Context()
    rclpy.init(args=["belt-drive-replay"] + args, context=context,
               signal_handler_options=SignalHandlerOptions.NO)
    stop = should_stop or (lambda: False)
    published = late = 0
    node = None
    try:
        node = rclpy.create_node("torque_replay", context=context)
        pub = node.create_publisher(Float64, out_topic or rec.topic, _rclpy_qos(rec.offered_qos))
        clock_pub = None
        if clock:
            clock_pub = node.create_publisher(
                Clock, "/clock", QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                                            reliability=ReliabilityPolicy.RELIABLE))
        synced = {"stamp": -1}
        sync_executor = None
        if sync_topic:
            if clock_pub is None:
                raise ValueError("sync_topic needs clock=True (lockstep is on /clock)")
            from rclpy.executors import SingleThreadedExecutor
            from sensor_msgs.msg import JointState

            def on_sync(msg) -> None:
                stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                synced["stamp"] = max(synced["stamp"], stamp)

            sync_sub = node.create_subscription(JointState, sync_topic, on_sync, QoSProfile(
                history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE))
            sync_executor = SingleThreadedExecutor(context=context)
            sync_executor.add_node(node)
        if wait_subscribers > 0:
            publishers = [pub] + ([clock_pub] if clock_pub is not None else [])
            deadline = time.monotonic() + wait_timeout

            def matched() -> bool:
                if min(p.get_subscription_count() for p in publishers) < wait_subscribers:
                    return False
                return sync_executor is None or sync_sub.get_publisher_count() >= 1

            while not matched() and not stop():
                if time.monotonic() > deadline:
                    log(f"warning: {pub.get_subscription_count()} of {wait_subscribers} subscribers after "
                        f"{wait_timeout:g} s; starting anyway")
                    break
                time.sleep(0.01)
        end = time.monotonic() + max(0.0, delay)
        while time.monotonic() < end and not stop():
            time.sleep(0.01)
        log(f"replaying {rec.topic} of {rec.path} ({rec.log_time_ns.size} messages, "
            f"{rec.span_ns / 1e9:g} s) on {pub.topic_name} at rate {rate:g}"
            + (", looping" if loop else "") + (", publishing /clock" if clock else ""))
        payloads = rec.payloads
        clock_msg = Clock(clock=Time())
        start = time.monotonic()
        for offset, clock_ns, index in schedule:
            if stop():
                break
            while True:
                wait = start + offset - time.monotonic()
                if wait <= 0 or stop():
                    break
                time.sleep(min(wait, 0.05))
            if stop():
                break
            if clock_pub is not None:
                clock_msg.clock.sec, clock_msg.clock.nanosec = divmod(clock_ns, 1_000_000_000)
                clock_pub.publish(clock_msg)
                if sync_executor is not None and clock_ns > 0:
                    deadline = time.monotonic() + sync_timeout
                    resend = time.monotonic() + 0.05
                    while synced["stamp"] < clock_ns and not stop():
                        now = time.monotonic()
                        if now > deadline:
                            late += 1
                            break
                        if now > resend:  # a node takes /clock best effort: resend a lost sample
                            clock_pub.publish(clock_msg)
                            resend = now + 0.05
                        sync_executor.spin_once(timeout_sec=0.005)
            pub.publish(payloads[index])
            published += 1
        if late:
            log(f"warning: {late} time(s) no {sync_topic} stamped at the /clock time within "
                f"{sync_timeout:g} s (is each message time a tick of the node?)")
    finally:
        if sync_executor is not None:
            sync_executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
    return published

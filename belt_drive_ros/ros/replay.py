"""Live replay of a recorded drive torque on ROS 2 (``belt-drive replay``).

See :mod:`belt_drive_ros.io.torque_bag` for the offline replay and the
zero-order-hold convention both share. :func:`replay_schedule` is the pure
timing (tested without ROS); :func:`run_replay` publishes.
"""

from __future__ import annotations

import math
from typing import Iterator, List, Optional, Tuple

import numpy as np

from ..io.torque_bag import DEFAULT_TOPIC, load_torque_recording

__all__ = ["replay_schedule", "run_replay"]


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
        keeps increasing. A loop of a part that spans no time (one message,
        or all sharing one time stamp) has no period and is refused.

    Returns
    -------
    iterator of (float, int, int)
        Wall-clock offset from the start of the replay [s], the ``/clock``
        value for the message [ns] (its recorded time, shifted per pass),
        and the index of the message in ``log_time_ns``.

    Raises
    ------
    ValueError
        At once (not on iteration) for a bad rate, an offset past the end, or
        a loop of a part spanning no time.
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
    if loop and times[-1] == times[first]:
        count = times.size - first
        raise ValueError(
            f"cannot loop: the {count} message{'s' if count > 1 else ''} from offset {start_offset:g} s "
            f"{'share one time stamp' if count > 1 else 'is alone'}, so the replay spans no time (no loop period)"
        )
    if loop and (times[-1] - times[first]) / rate < LOOP_MIN_NS:  # (two messages 1 ns apart: 4.7 M a second)
        raise ValueError(
            f"cannot loop: the messages from offset {start_offset:g} s span {(times[-1] - times[first]) / 1e9:g} s, "
            f"a pass of {(times[-1] - times[first]) / rate / 1e6:.3g} ms at rate {rate:g}: under "
            f"{LOOP_MIN_NS / 1e6:g} ms a loop floods the topic")
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
        depth=max(1000, p.depth),  # a replay bursts: keep every unacknowledged sample (a recorded depth 1 would drop some)
        # always reliable: a replay must not lose samples, and a reliable writer serves best-effort readers too
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if p.durability == "transient_local" else DurabilityPolicy.VOLATILE,
    )


#: the shortest pass of a --loop replay [ns of wall time]: a shorter one publishes faster than any node ticks
LOOP_MIN_NS = 1_000_000
#: /clock ticks a --sync replay waits for its first answer before it gives up (each up to sync_timeout)
SYNC_TRIES = 3


class SyncNeverAnswered(RuntimeError):
    """A ``--sync`` replay whose sync topic never answered a /clock tick: the lockstep it asked for never held."""


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
        Also publish ``/clock`` (``rosgraph_msgs/Clock``) = the message's time
        right after each message: a node with ``use_sim_time`` that has taken
        the message in samples it at that tick, so it holds message k over
        [t_k, t_k+1), the zero-order hold of the offline replay.
    topic : str
        Topic to read from the bag.
    out_topic : str, optional
        Topic to publish on; default the recorded one (remap with ``--ros-args -r``). The command's ``--to``
        defaults to ``drive_torque``: the node's input, in the replay node's namespace.
    wait_subscribers : int
        Wait (up to ``wait_timeout`` s) until this many subscribers match the
        torque topic (and ``/clock``) before the first message.
    delay : float
        Wall seconds to wait before the first message (after the subscribers
        matched: discovery completes on the subscriber's side a little later,
        and what is published before is lost to it).
    sync_topic : str, optional
        Lockstep with ``clock``: after publishing message k and ``/clock`` =
        t_k, wait (up to ``sync_timeout`` s) until a ``sensor_msgs/JointState``
        stamped at or after t_k arrives on this topic (the node's
        ``joint_states``, i.e. it has ticked to t_k), and only then publish
        message k+1. The node then always ticks before it takes the next
        torque, so the run is the same however loaded the machine is (and
        runs as fast as the node allows when ``rate`` is high). Needs every
        message time to be a tick of the node (bag rate <= node rate, on its
        tick grid).
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

    from .executors import ros_session

    rec = load_torque_recording(bag, topic, keep_payloads=True, warn=lambda m: log(f"warning: {m}"))
    schedule = replay_schedule(rec.log_time_ns, rate=rate, start_offset=start_offset, loop=loop,
                               max_loops=max_loops)
    args = list(ros_args or [])
    if args and args[0] != "--ros-args":
        args = ["--ros-args"] + args
    with ros_session(["belt-drive-replay"] + args) as context:
        return _publish(rec, schedule, context, rate=rate, loop=loop, clock=clock, out_topic=out_topic,
                        wait_subscribers=wait_subscribers, wait_timeout=wait_timeout, delay=delay,
                        sync_topic=sync_topic, sync_timeout=sync_timeout, should_stop=should_stop, log=log)


def _publish(rec, schedule, context, *, rate, loop, clock, out_topic, wait_subscribers, wait_timeout, delay,
             sync_topic, sync_timeout, should_stop, log) -> int:
    """The replay loop of :func:`run_replay` on an initialised ``context``; returns the messages published."""
    import time

    import rclpy
    from builtin_interfaces.msg import Time
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Float64

    stop = should_stop or (lambda: False)
    published = late = missed = 0  # (missed: sync timeouts in a row)
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
            from sensor_msgs.msg import JointState

            from .executors import make_executor

            def on_sync(msg) -> None:
                stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                synced["stamp"] = max(synced["stamp"], stamp)

            sync_sub = node.create_subscription(JointState, sync_topic, on_sync, QoSProfile(
                history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE))
            sync_executor = make_executor(context, "single")
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
            pub.publish(payloads[index])
            published += 1
            if clock_pub is not None:
                clock_msg.clock.sec, clock_msg.clock.nanosec = divmod(clock_ns, 1_000_000_000)
                clock_pub.publish(clock_msg)
                if sync_executor is not None:
                    deadline = time.monotonic() + sync_timeout
                    resend = time.monotonic() + 0.05
                    while synced["stamp"] < clock_ns and not stop():
                        now = time.monotonic()
                        if now > deadline:
                            late += 1
                            missed += 1
                            if synced["stamp"] < 0 and late >= SYNC_TRIES:  # nothing ever answered: no lockstep
                                raise SyncNeverAnswered(
                                    f"--sync {sync_topic}: no sensor_msgs/JointState stamped at the /clock time in "
                                    f"{late} tries of {sync_timeout:g} s (is a node running on /clock, and is "
                                    f"{sync_topic} its joint_states?); published {published} message(s)")
                            if synced["stamp"] >= 0 and (sync_sub.get_publisher_count() == 0 or missed >= SYNC_TRIES):  # it answered, and
                                # stopped: its node ended (the rest would wait sync_timeout each, --loop for ever)
                                gone = sync_sub.get_publisher_count() == 0
                                raise SyncNeverAnswered(
                                    f"--sync {sync_topic}: " + ("no publisher any more (its node ended)" if gone else
                                                                 f"no answer to {missed} /clock times in a row")
                                    + f" at {clock_ns / 1e9:.9g} s; published {published} message(s)")
                            break
                        if now > resend:  # a node takes /clock best effort: resend a lost sample
                            clock_pub.publish(clock_msg)
                            resend = now + 0.05
                        sync_executor.spin_once(timeout_sec=0.005)
                    if synced["stamp"] >= clock_ns:
                        missed = 0
        from rclpy.duration import Duration

        for publisher in (pub, clock_pub):  # the last samples reach every reader before this process ends
            if publisher is not None:
                publisher.wait_for_all_acked(Duration(seconds=2.0))
        if late:
            log(f"warning: {late} time(s) no {sync_topic} stamped at the /clock time within "
                f"{sync_timeout:g} s (is each message time a tick of the node?)")
    finally:
        if sync_executor is not None:
            sync_executor.shutdown()
        if node is not None:
            node.destroy_node()
    return published

"""The node's drive-torque input: validation, limit, timeout, sample-and-hold (no rclpy).

:class:`DriveInput` takes every ``drive_torque`` message in constant time
(:meth:`~DriveInput.receive`: NaN/Inf rejected, ``torque_limit`` applied,
a value beyond the plausible ``torque_bound`` rejected, each counted)
and keeps the latest valid value. At each tick the node
*samples* it (:meth:`~DriveInput.sample`: the ``input_timeout`` rule
applied at the tick time) into :attr:`~DriveInput.applied`, the
zero-order hold the plant reads until the next tick::

    u_drive(t) = applied_k    for  t_k <= t < t_k+1

This is the sampling of a discrete-time controller (python-control's ZOH):
a message received between ticks k-1 and k acts from tick k on, and the
outputs published at t_k already show it (``joint_states`` effort of
``wheel_M``; the rigid model's belt torque). A recording of the sampled
values (``drive_torque_applied``, one per tick at t_k) therefore replays
offline as a table with ``interpolation: previous`` to the same numbers.

Two threads: the executor's input callback receives (:meth:`~DriveInput.receive`,
under :attr:`~DriveInput.lock`, which nothing holds longer than a hand-over),
and the tick *takes* what was received (:meth:`~DriveInput.take`, at the start
of the tick, before its compute) and samples only what it took. A message
received while a tick computes therefore acts from the next tick on, as one
received after the tick's start always has: its callback does not wait for
the tick to end.
"""

from __future__ import annotations

import math
import struct
import threading

from ..core.sources import HeldTorque

__all__ = ["DriveInput", "HeldTorque", "float64_value"]

#: a tick time no run reaches [ns] (DriveInput.until while nothing but a new message changes the sample)
NEVER = 2**62
INPUT_COUNTERS = ("received", "rejected_nonfinite", "rejected_bound", "clamped", "ignored", "timeouts")


def float64_value(data: bytes) -> float:
    """The value of a ``std_msgs/Float64`` from its serialized bytes (a raw subscription's message).

    Classic CDR: the 4-byte encapsulation header (``00 01``: little endian,
    ``00 00``: big endian, then two option bytes) and the IEEE double right
    after it. Any other encoding goes through rclpy's own deserialization.
    Read this way, the node's input callback builds no message object (the
    executor's conversion to a ``Float64`` cost ~10 us on the caches of a
    1 kHz node, with the GIL held).
    """
    if len(data) >= 12 and data[0] == 0 and data[1] in (0, 1):
        return struct.unpack_from("<d" if data[1] else ">d", data, 4)[0]
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Float64

    return deserialize_message(data, Float64).data


class DriveInput:
    """``drive_torque`` as the node takes it in (see the module docstring).

    Parameters
    ----------
    counters : dict
        Shared counter dict; the keys of :data:`INPUT_COUNTERS` are added.
    """

    def __init__(self, counters: dict):
        self.counters = counters
        for key in INPUT_COUNTERS:
            counters.setdefault(key, 0)
        #: held by :meth:`receive` and by :meth:`take`'s hand-over only (never through a tick's compute)
        self.lock = threading.Lock()
        #: latest valid message after the limit [N m] (received; the tick samples it once taken)
        self.latest = 0.0
        #: node time [ns] of the latest valid message (None: none yet)
        self.last_input_ns: int | None = None
        #: what the plant reads: the value sampled at the last tick [N m]
        self.applied = HeldTorque(0.0)
        #: the tick's side: the latest message and its time as the last :meth:`take` found them
        self.taken = 0.0
        self.taken_ns: int | None = None
        #: True while input_timeout has expired (the tick's side: set by :meth:`sample`, cleared by :meth:`take`)
        self.stale = False
        self._new = False  # a message received since the last take
        #: the last :meth:`sample`'s value [N m], and the tick time [ns] up to which a sample gives it again and
        #: changes nothing (no timeout to count or warn of; a take sets it back: -1)
        self.value, self.until = 0.0, -1

    def receive(self, value: float, now_ns: int, settings) -> bool:
        """Take one message (constant time); return True if it was accepted."""
        c = self.counters
        c["received"] += 1
        if not math.isfinite(value):
            c["rejected_nonfinite"] += 1
            return False
        if settings.drive_source != "topic":
            c["ignored"] += 1
            return False
        if abs(value) > settings.torque_bound:
            c["rejected_bound"] += 1
            return False
        limit = settings.torque_limit
        if limit > 0.0 and abs(value) > limit:
            value = math.copysign(limit, value)
            c["clamped"] += 1
        with self.lock:
            self.latest, self.last_input_ns, self._new = value, now_ns, True
        return True

    def take(self) -> bool:
        """The tick's hand-over (at its start, before its compute): the latest message received becomes the one
        :meth:`sample` reads; True if one came since the last take. Without one nothing is locked (the flag is
        set last, under the lock, by :meth:`receive`: a message whose receipt is not complete is the next take's)."""
        if not self._new:
            return False
        with self.lock:
            self.taken, self.taken_ns, self._new = self.latest, self.last_input_ns, False
        self.stale, self.until = False, -1
        return True

    def rebase(self, now_ns: int) -> None:
        """The run starts on a new time base at node time ``now_ns`` (its first tick, the first ``/clock``, a clock
        switched): a message received before counts as received there. Its stamp is of the clock before (simulated
        time 0 before the first ``/clock``, or the other clock), so its age on the new one means nothing: the run
        applies it from scene time 0, and ``input_timeout`` counts from there."""
        with self.lock:
            if self.last_input_ns is not None:
                self.last_input_ns = now_ns
            if self.taken_ns is not None:
                self.taken_ns = now_ns
        self.stale, self.until = False, -1

    def sample(self, now_ns: int, origin_ns: int, settings) -> tuple[float, str | None]:
        """The drive torque sampled at tick time ``now_ns`` [N m] (the timeout rule applied there): the message
        the last :meth:`take` handed over.

        Returns ``(value, warning)``: the caller holds ``value`` in
        :attr:`applied` once the interval before the tick is integrated;
        ``warning`` is one line when the input has just gone stale (the
        caller logs it), else None.
        """
        warning = None
        timeout = settings.input_timeout_ns
        until = NEVER  # stale stays stale until a take
        if settings.drive_source != "topic" or timeout <= 0:
            self.stale = False
        else:
            since = self.taken_ns if self.taken_ns is not None else origin_ns
            stale = now_ns - since > timeout
            if not stale:
                until = since + timeout
            if stale and not self.stale:
                self.counters["timeouts"] += 1
                what = "no drive_torque received" if self.taken_ns is None else "drive_torque stale"
                warning = f"{what} for {(now_ns - since) / 1e9:.3g} s > input_timeout: " + (
                    "holding the last value" if settings.timeout_behavior == "hold" else "drive torque set to 0"
                )
            self.stale = stale
        self.value = value = 0.0 if self.stale and settings.timeout_behavior == "zero" else self.taken
        self.until = until
        return value, warning

    def status(self, settings) -> tuple[bool, str]:
        """(warn, message) for the input diagnostic."""
        if settings.drive_source == "scene":
            return False, "drive from the scene's profile; drive_torque ignored"
        if self.stale:
            what = "no drive_torque received" if self.last_input_ns is None else "drive_torque stale"
            return True, what + (": holding last value" if settings.timeout_behavior == "hold" else ": torque set to 0")
        if self.last_input_ns is None:
            return False, "no drive_torque received yet: 0 N m"
        return False, "ok"

"""Re-simulating a recording from the command line (``belt-drive sim RECORDING --out re.mcap``).

:func:`resimulation` gathers what the command needs to write a file comparable with the recording: the
recording's own scene (:func:`~belt_drive_ros.io.torque_bag.scene_from_bag`), the time of its first sample, a
node recording's output rate, and every recorded topic the run does not compute, to be passed through as
recorded. It needs the whole recording: a file cut off or damaged is refused in one line naming it, before
its scene is rebuilt (:func:`_check_whole`), and the messages are read with every chunk's CRC checked
(:func:`_messages_of_whole`). :func:`torque_topic` says which topic ``--torque-bag`` reads from a bag.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Tuple

from msg_tools.errors import MsgToolsError, RecoveredBagWarning

from ..core.params import FIELD_DOCS
from .bag_layout import PARAMETERS_METADATA, restarts_of
from .recording import (
    APPLIED_TOPIC, FLOAT_OUTPUTS, ROBOT_DESCRIPTION, SCENE_METADATA, SLIP_FLOAT_OUTPUTS, TF_TOPIC, BagReadError, bag_error,
)  # fmt: skip
from .torque_bag import DEFAULT_TOPIC, RecordedTorque, scene_from_bag

__all__ = ["Resimulation", "resimulation", "torque_topic"]


def torque_topic(bag) -> Tuple[str, str]:
    """The torque topic ``--torque-bag`` reads from ``bag``, and a line saying why.

    A node recording holds ``drive_torque`` as received (a NaN the node
    rejected included) and ``drive_torque_applied``, the torque the node
    applied at each tick: the latter, when present, is what re-simulates
    the run. Otherwise ``/drive_torque`` (any namespace).
    """
    from msg_tools import bag_files, summary

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecoveredBagWarning)
        try:
            topics = [t.topic for t in summary(bag_files(bag)[-1], verify=False).topics]
        except MsgToolsError as exc:
            raise bag_error(exc) from None
    applied = [t for t in topics if t.rsplit("/", 1)[-1] == APPLIED_TOPIC]
    if len(applied) == 1:
        return applied[0], (f"torque from {applied[0]} (the torque the node applied at each tick; "
                            f"{DEFAULT_TOPIC} holds what it received)")
    return DEFAULT_TOPIC, ""


def _damaged(file, why: str) -> BagReadError:
    """The one-line refusal to re-simulate ``file``, a recording that is not whole, saying ``why``."""
    return BagReadError(f"{file}: cannot re-simulate a damaged or incomplete recording ({why}); "
                        f"'msg-tools info {file}' says what is missing")


def _check_whole(file):
    """``file``'s msg_tools summary; refused unless it is a whole MCAP file (its end written, no damage its summary
    section shows).

    Re-simulation passes every recorded topic through to the new file, so it
    needs all of them: a recording cut off mid-write (a killed writer, a
    truncated copy) reads only up to the cut, which :func:`scene_from_bag`
    tolerates (its scene and torque come first) but a pass-through must not.
    A RECOVERED file (damaged before its end, every chunk read through the
    summary's chunk index) is whole and passes.
    """
    from msg_tools import summary

    info = summary(file, verify=False)
    if not info.complete or info.damage:
        raise _damaged(file, info.stop_reason or "; ".join(info.damage))
    return info


def _messages_of_whole(file, topics=None):
    """``(schema, channel, message)`` of ``file`` in log-time order, via the mcap library's reader (``topics``: only
    those, reading only the chunks that hold them).

    The reader trusts the file's summary section: bytes damaged inside a
    file whose end is intact can surface as any error of its parsing (a
    record length past the end, text that is not UTF-8, a seek before the
    start, a chunk that does not decompress). Each is the one-line
    :func:`_damaged` refusal naming the file; an error of the disk itself
    (``EIO``, permissions) stays what it is.
    """
    import errno

    from mcap.reader import make_reader

    with open(file, "rb") as f:
        records = make_reader(f, validate_crcs=True).iter_messages(topics=topics, log_time_order=True)
        while True:
            try:
                item = next(records)
            except StopIteration:
                return
            except OSError as exc:
                if exc.errno != errno.EINVAL:
                    raise
                raise _damaged(file, f"a seek outside the file: {exc}") from None
            except Exception as exc:  # noqa: BLE001 - only the reader's parsing of the file's bytes is in here
                first = str(exc).splitlines()[0] if str(exc) else ""
                raise _damaged(file, f"{type(exc).__name__}: {first}"[:200]) from None
            yield item


#: node parameters whose change during a recording changes its run (a re-simulation holds one set throughout)
RUN_PARAMETERS = frozenset(FIELD_DOCS) | {"scene", "model", "method", "step_rate_hz", "substeps", "drive_source"}


def _one_run(info, file, start_ns: Optional[int]) -> None:
    """Refuse a node recording whose run a re-simulation cannot repeat: one that restarted from the initial state
    (``~/reset``, a clock that jumped back, a divergence, a new time base: its ``restart`` records after the first
    start) or had a run parameter changed at runtime (its ``parameters`` records after the first). The one line names
    the first such event, at its scene time where the recording's start is known."""
    events = []
    params = [values for name, values in info.metadata if name == PARAMETERS_METADATA]
    for values in params[1:]:
        changed = sorted(k for k in values if k in RUN_PARAMETERS)
        if changed and values.get("time_ns", "").lstrip("-").isdigit():
            events.append((int(values["time_ns"]), f"parameter {', '.join(changed)} changed"))
    events += [(t, f"the node restarted from the initial state ({cause})") for t, cause in restarts_of(info.metadata)
               if t is not None]
    if events:
        t, what = min(events)
        when = f"t = {(t - start_ns) / 1e9:.6g} s" if start_ns is not None else f"node time {t / 1e9:.9g} s"
        raise BagReadError(f"{file}: cannot re-simulate: {what} at {when} of the recording; 'belt-drive sim' repeats "
                           "one run from one start with one set of parameters")


def _rate(text: str) -> Optional[float]:
    """A scene record's ``output_rate`` [Hz] as a number, None when it is none (a finite number > 0)."""
    try:
        rate = float(text)
    except ValueError:
        return None
    return rate if math.isfinite(rate) and rate > 0 else None


@dataclass
class Resimulation:
    """What ``belt-drive sim RECORDING --out re.mcap`` needs to write a file comparable with the recording.

    ``scene``: the recording's own (:func:`scene_from_bag`); ``start_time_ns``:
    the time of its first sample (scene time 0); ``output_rate`` [Hz]: one
    sample per tick of a node recording, an offline one's rate as written (None: the scene's); ``namespace``:
    its topics'; ``drive_topic``: where the run's drive torque goes
    (``drive_torque_applied`` for a node recording, whose ``drive_torque`` is
    the raw input); ``passthrough``: the recorded topics the run does not
    compute (the raw ``drive_torque``, ``/clock``, ``/diagnostics``), copied
    as recorded: ``(topic, type, offered QoS YAML, type hash, [(log time, CDR)])``; ``stamps``: a node recording's
    tick times [ns] (its ``joint_states`` log times), the samples ``--out`` holds (None: every sample); ``topics``:
    an offline recording's topics of the run (relative names; None: every one).
    """

    scene: Any
    start_time_ns: Optional[int]
    output_rate: Optional[float]
    namespace: str
    drive_topic: str
    passthrough: List[tuple]
    stamps: Optional[Any] = None
    topics: Optional[List[str]] = None


def resimulation(path, computed=(), torque_bag=None) -> Resimulation:
    """The :class:`Resimulation` of the recording ``path`` (file or bag folder).

    ``computed``: topic names (relative) the re-simulation writes itself; every
    other topic of the recording is passed through. Types msg_tools has no
    definition of are left out. ``torque_bag``: as :func:`scene_from_bag`'s.
    """
    from msg_tools import bag_files, schemas

    with warnings.catch_warnings():  # a cut recording is refused first, before its scene is rebuilt
        warnings.simplefilter("ignore", RecoveredBagWarning)
        try:
            files = bag_files(path)
            infos = [_check_whole(file) for file in files]
            last = infos[-1]
        except MsgToolsError as exc:
            raise bag_error(exc) from None
    scene = scene_from_bag(path, torque_bag=torque_bag)
    record = last.metadata_dict(SCENE_METADATA)  # (the last file holds every metadata record written)
    drive = scene.drive
    start = int(drive.start_ns) if isinstance(drive, RecordedTorque) and drive.start_ns is not None else None
    namespace, drive_topic = "/", "drive_torque"
    if isinstance(drive, RecordedTorque) and drive.topic.rsplit("/", 1)[-1] == APPLIED_TOPIC:
        namespace = drive.topic.rsplit("/", 1)[0] or "/"
        drive_topic = APPLIED_TOPIC
    elif record.get("source") == "node":  # the node's own drive (the scene's): recorded as applied, in its namespace
        namespace = record.get("node", "/").rsplit("/", 1)[0] or "/"
        drive_topic = APPLIED_TOPIC
    topics = None
    if record.get("source") == "offline":  # written by write_result_mcap: the topics of the run it wrote
        every = {ROBOT_DESCRIPTION, "joint_states", TF_TOPIC.strip("/"), "drive_torque"} | {n for n, _ in FLOAT_OUTPUTS}
        ours = every | {drive_topic} | {name for name, _ in SLIP_FLOAT_OUTPUTS}  # (every model's, the slipping one's)
        run = [t for info in infos for t in info.topics if t.topic.rsplit("/", 1)[-1] in ours]
        bases = {"drive_torque" if b == drive_topic else b for b in (t.topic.rsplit("/", 1)[-1] for t in run)}
        if not every <= bases:  # a subset (write_result_mcap's topics=, by which the drive torque is drive_torque);
            topics = sorted(bases)  # else every topic of the run's model (a flexible recording run --model slipping)
        parents = {t.topic.rsplit("/", 1)[0] or "/" for t in run if t.topic != TF_TOPIC}  # (/tf is absolute)
        if drive_topic != APPLIED_TOPIC and len(parents) == 1:  # its namespace (/car1: the re-simulation wrote
            namespace = parents.pop()  # /shaft_speed ... and copied the recorded /car1/shaft_speed ... as they were)
        # its first sample is its scene time 0 (the --start-time it was written with): not the wall time of the
        # re-simulation, nor the first stamp of the torque bag that drove it. A topic's first time comes from the
        # message indexes, which no CRC covers: one earlier than the file's first message (its statistics, under
        # the summary's CRC) is a damaged index, not the run's start
        firsts = [t.start_ns for t in run if t.start_ns is not None]
        known = [info.start_ns for info in infos if info.start_ns is not None]
        start = max(min(firsts), min(known)) if firsts and known else min(firsts) if firsts else start
    if start is None and record.get("source") == "node" and record.get("drive_source") == "scene":
        # the node's own drive: the run is the recorded ticks, from the first to the last (not the scene's duration)
        ticks = [t for info in infos for t in info.topics if t.topic.rsplit("/", 1)[-1] == "joint_states" and t.start_ns is not None]
        if ticks:
            start, end = min(t.start_ns for t in ticks), max(t.end_ns for t in ticks)
            if end > start:
                scene = scene.with_overrides(duration=(end - start) / 1e9)
    _one_run(last, path, start)
    text = record.get("tick_ns", "")
    tick_ns = int(text) if text.strip().isdigit() and int(text) > 0 else None  # (a node's tick [ns], else None)
    dt = _rate(record.get("dt", ""))  # [s] (a finite number > 0, or None)
    step = round(dt * 1e9) if dt is not None else 0  # [ns]
    if record.get("source") == "node" and step > 0 and tick_ns is not None and tick_ns % step:
        # substeps that split no tick evenly (1 ms in 7): the node stepped whole-ns steps of dt and a last shorter
        # one per tick; the run offline steps dt evenly, off the ticks (only 2 of 131 samples were written).
        # Refused before any message is read
        raise BagReadError(
            f"{path}: cannot re-simulate: the node split each {tick_ns / 1e6:g} ms tick into steps of {step} ns "
            f"and a last one of {tick_ns % step} ns; 'belt-drive sim' repeats a run whose dt divides its tick")
    output_rate = 1e9 / tick_ns if tick_ns is not None else None
    if output_rate is None and record.get("source") == "offline":  # the rate it was written at (write_result_mcap's
        # output_rate, not always the scene's: at the scene's, 1 kHz, a 250 Hz recording had 4x the samples)
        output_rate = _rate(record.get("output_rate", ""))
    written = {name.strip("/") for name in computed} | {drive_topic}

    def relative(topic: str) -> str:
        return (topic[len(namespace):] if topic.startswith(namespace) else topic).strip("/")

    channels: Dict[str, list] = {}
    ticks: Optional[list] = [] if record.get("source") == "node" else None  # (a node's ticks: its joint_states)
    file = path
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecoveredBagWarning)
        try:
            for file, info in zip(files, infos):
                names = [t.topic for t in info.topics]
                joints = [t for t in names if relative(t) == "joint_states"]
                if ticks is not None and joints:  # (the node's ticks: joint_states' log times, read vectorized)
                    from msg_tools import read_topic

                    ticks.extend(int(t) for t in read_topic(file, joints[0]).log_time_ns)
                # only the topics passed through are read message by message (a re-simulation of a long
                # recording decoded every message to copy none: 21 s where the run took 1.4)
                copied = [t for t in names if relative(t) not in written and t.strip("/") not in written]
                if not copied:
                    continue
                for schema, channel, message in _messages_of_whole(file, copied):
                    entry = channels.get(channel.topic)
                    if entry is None:
                        type_name = schema.name if schema is not None else ""
                        if not schemas.type_hash(type_name):
                            continue  # no definition here: cannot be written
                        entry = channels[channel.topic] = [
                            channel.topic, type_name, channel.metadata.get("offered_qos_profiles", ""),
                            channel.metadata.get("topic_type_hash") or None, []]
                    entry[4].append((int(message.log_time), bytes(message.data)))
        except MsgToolsError as exc:
            raise bag_error(exc) from None
        except OSError as exc:  # the disk failed a read (EIO, a file gone): the input, not a write
            raise BagReadError(f"{file}: cannot read it ({exc.strerror or exc}); nothing written") from None
    import numpy as np

    if ticks and start is not None and tick_ns is not None:
        # a /clock that stopped between two ticks (a time master at 1.5 ms, a jump to an off-grid time): the node
        # integrated to it and published there; the run offline has samples on the grid only (half the ticks of a
        # 1.5 ms clock were left out, the rest equal): refused, not written short
        off = (np.asarray(ticks, dtype=np.int64) - start) % tick_ns != 0
        if off.any():
            first = ticks[int(np.argmax(off))]
            raise BagReadError(
                f"{path}: cannot re-simulate: {int(off.sum())} of {len(ticks)} ticks lie off the node's "
                f"{tick_ns / 1e6:g} ms tick grid (the first at t = {(first - start) / 1e9:.9g} s: its /clock stopped "
                "between two ticks); 'belt-drive sim' repeats a run whose ticks are on its grid")
    return Resimulation(scene, start, output_rate, namespace, drive_topic,
                        [tuple(entry) for entry in channels.values()],
                        np.array(ticks, dtype=np.int64) if ticks else None, topics)

"""Record runs to MCAP: live from a ROS 2 node, or offline from a :class:`SimResult`.

Both paths write the same rosbag2-compatible layout through
:class:`msg_tools.Ros2McapWriter` (profile ``ros2``, ``ros2msg`` schemas,
``cdr`` messages, ``offered_qos_profiles`` on every channel, a ``rosbag2``
metadata record, zstd chunks, a summary section), the same topics and the
same message layout as :class:`belt_drive_ros.ros.node.BeltDriveNode`:

=========================  ===========================  ======================
topic                      type                         content [unit]
=========================  ===========================  ======================
``/drive_torque``          ``std_msgs/msg/Float64``     torque on wheel M [N m]
``/joint_states``          ``sensor_msgs/msg/JointState`` wheels ``wheel_M, wheel_1,
                                                        wheel_2, wheel_3``:
                                                        position [rad], velocity
                                                        [rad/s], effort = external
                                                        torque [N m] (drive, 0, 0,
                                                        -load)
``/shaft_speed``           ``std_msgs/msg/Float64``     omega_M [rad/s]
``/load_torque``           ``std_msgs/msg/Float64``     load torque at wheel 3 [N m]
``/belt_torque``           ``std_msgs/msg/Float64``     belt torque on wheel 3 [N m]
``/relative_deflection``   ``std_msgs/msg/Float64``     ``i phi_M - phi_3`` [rad]
``/diagnostics``           ``diagnostic_msgs/msg/DiagnosticArray`` (live only)
``/clock``                 ``rosgraph_msgs/msg/Clock``  (live, when the node uses
                                                        or publishes sim time)
=========================  ===========================  ======================

Every file is self-describing: metadata records

* ``scene``: ``yaml`` (the scene as :func:`~belt_drive_ros.io.scenes.scene_yaml` writes it, with the
  model, integrator and step actually used; a drive recorded in a bag is
  stored as a reference ``{type: recorded, bag, topic, samples, sha256}``
  instead of its samples), ``name``, ``model``, ``method``, ``dt``,
  ``drive_source`` and ``source`` (``offline`` or ``node``);
* ``parameters``: the node's ROS parameters (live) or the model parameters
  (offline), values as text; a live recording appends one
  ``parameters`` record per accepted runtime change, with ``time_ns``;
* ``units``: SI unit of every topic (:mod:`msg_tools.units`).

:func:`belt_drive_ros.io.torque_bag.scene_from_bag` turns these back into a :class:`Scene`, so a recording
can be re-simulated offline.

Time stamps
-----------
*Live* (:class:`NodeRecorder`, ``belt-drive record``): ``log_time`` is the
receive time on the recording node's clock [ns]: ROS time, i.e. simulated
time when the node has ``use_sim_time`` (then ``0`` until the first
``/clock``). ``publish_time`` equals ``log_time``: the Jazzy wheels'
EventsExecutor cannot deliver the message info that carries the send time.
*Offline* (:func:`write_result_mcap`): both are the start time (default the
wall time of the run, as rosbag2 stamps a recording; ``start_time_ns`` sets
it) plus the simulated time of the sample; ``joint_states`` stamps carry the
same time.

Crash safety
------------
Chunks are closed every ``flush_interval_s`` of log time and, live, by a
wall-clock (steady) timer as well, so after SIGKILL the file reads up to its
last complete chunk (:func:`msg_tools.read_topic` tolerates the missing
summary). SIGINT/SIGTERM finalize (``belt-drive record`` and the node's
shutdown call :meth:`NodeRecorder.close`). An existing file is never
replaced unless ``force``. A write error (disk full, permission) stops the
recording, not the node: it is logged once, :attr:`NodeRecorder.failed`
turns True and :attr:`NodeRecorder.status` says why (for ``/diagnostics``).

This module never imports rclpy: the live recorders that use it are in
:mod:`belt_drive_ros.ros.recorder`.
"""

from __future__ import annotations

import math
import time
from typing import Any, Dict, Iterable, List, Mapping, Optional, Sequence

import numpy as np

from msg_tools.block_writer import BlockMcapWriter
from msg_tools.errors import MsgToolsError
from msg_tools.units import UNITS_METADATA

from ..core.scene import SLIP_MODELS
# the layout and the encoders live beside this module; their names stay importable from here
from .bag_layout import (  # noqa: F401 - re-exported
    APPLIED_TOPIC, CLOCK, DIAGNOSTIC_ARRAY, FLOAT64, FLOAT_OUTPUTS, JOINT_NAMES, JOINT_STATE, PARAMETERS_METADATA,
    RECORDED_DRIVE, ROBOT_DESCRIPTION, ROBOT_DESCRIPTION_QOS, SCENE_METADATA, SLIP_FLOAT_OUTPUTS, STRING, TF_MESSAGE,
    TF_QOS, TF_TOPIC, TOPIC_TYPES, TOPIC_UNITS, BagError, BagExistsError, BagReadError, BagWriteError, _absolute, _fmt,
    _scene_record, _sha256, bag_error, scene_mapping, units_metadata,
)  # fmt: skip
from .cdr_encoders import (  # noqa: F401 - re-exported
    _F64_HEADER, JointStateEncoder, TfEncoder, encode_float64, encode_joint_states, encode_robot_description,
    float64_messages, float64_rows, joint_state_messages, joint_state_rows,
)  # fmt: skip

__all__ = [
    "BagError",
    "BagExistsError",
    "BagReadError",
    "BagWriteError",
    "JOINT_NAMES",
    "JointStateEncoder",
    "TF_MESSAGE",
    "TF_TOPIC",
    "TOPIC_TYPES",
    "TfEncoder",
    "TOPIC_UNITS",
    "bag_error",
    "encode_float64",
    "encode_joint_states",
    "encode_robot_description",
    "output_rate_note",
    "output_stride",
    "scene_mapping",
    "write_result_mcap",
]


def _output_stride(result, output_rate: Optional[float]) -> int:
    """Samples of ``result`` per output message (1 if the rate does not divide the grid)."""
    rate = float(output_rate or result.scene.output_rate)
    if not rate > 0 or not math.isfinite(rate):
        raise ValueError(f"output_rate must be a finite number > 0 Hz, got {output_rate!r}")
    return output_stride(result.dt, rate)


def output_stride(dt: float, rate: float) -> int:
    """Steps of ``dt`` [s] per message at ``rate`` [Hz]: a whole number, else 1 (a message at every step; a single
    belt's and a network's MCAP alike)."""
    stride = int(round(1.0 / (rate * dt)))
    if stride < 1 or abs(stride * dt * rate - 1.0) > 1e-9:
        return 1
    return stride


def output_rate_note(dt: float, rate: float) -> str:
    """A line when the message rate ``rate`` [Hz] is below the step rate ``1 / dt`` but not that rate divided by a
    whole number: the recording then has a message at every step, not at ``rate``; '' otherwise (a rate at or above
    the step rate is every step by design: one message per step at most)."""
    if not (rate > 0 and math.isfinite(rate)) or rate * dt >= 1.0 - 1e-9 or output_stride(dt, rate) > 1:
        return ""
    return (f"note: output_rate {rate:g} Hz is not the step rate {1.0 / dt:g} Hz divided by a whole number: the "
            f"recording has a message at every step ({1.0 / dt:g} Hz)")


def parse_start_time(text: str) -> Optional[int]:
    """``--start-time``: ``now`` (None: the wall time when writing), seconds since the epoch,
    or an ISO 8601 date (UTC unless it names a zone); returns ns since the epoch."""
    import datetime

    import decimal

    text = str(text).strip()
    if text.lower() == "now":
        return None
    try:
        seconds = float(text)
        exact = decimal.Decimal(text) if math.isfinite(seconds) else None  # (float(text) * 1e9 is off by up to 128 ns)
    except (ValueError, decimal.InvalidOperation):
        try:
            when = datetime.datetime.fromisoformat(text.replace("Z", "+00:00"))
        except ValueError:
            raise ValueError(f"--start-time {text!r}: expected 'now', seconds since the epoch or an ISO 8601 date") from None
        if when.tzinfo is None:
            when = when.replace(tzinfo=datetime.timezone.utc)
        seconds = when.timestamp()
        exact = decimal.Decimal((when - datetime.datetime(1970, 1, 1, tzinfo=datetime.timezone.utc))
                                // datetime.timedelta(microseconds=1)) / 1_000_000
    if not (math.isfinite(seconds) and 0 <= seconds <= STAMP_MAX_S):
        raise ValueError(f"--start-time {text!r}: must be between 1970 and 2038-01-19T03:14:07Z (a ROS time stamp's "
                         "seconds are a 32-bit integer)")
    return int((exact * 1_000_000_000).to_integral_value(decimal.ROUND_HALF_EVEN))


#: the last second a ROS time stamp holds (builtin_interfaces/Time: int32 sec): 2038-01-19T03:14:07Z
STAMP_MAX_S = 2**31 - 1


def check_stamp_span(start_ns: Optional[int], duration: float) -> None:
    """Refuse (:class:`~belt_drive_ros.core.errors.ParameterError` of ``--start-time``, one line) a run from
    ``start_ns`` [ns since the epoch] over ``duration`` [s] whose last stamp a ROS time stamp cannot hold (its seconds
    wrapped to negative years); ``None``: the wall time, fine."""
    if start_ns is None:
        return
    end = start_ns / 1e9 + float(duration)
    if end >= STAMP_MAX_S + 1:
        from ..core.errors import ParameterError

        raise ParameterError("--start-time", f"the run's last sample would be stamped {end:.0f} s after 1970, past "
                             "2038-01-19T03:14:07Z, the last second a ROS time stamp holds (32-bit seconds)")


def write_result_mcap(result, path, force: bool = False, *, namespace: str = "/",
                      output_rate: Optional[float] = None, topics: Optional[Iterable[str]] = None,
                      compression: str = "zstd",
                      extra_metadata: Optional[Mapping[str, Mapping[str, str]]] = None,
                      start_time_ns: Optional[int] = None, bag_folder: bool = False,
                      max_bag_size: Optional[int] = None,
                      max_bag_duration: Optional[float] = None, drive_topic: str = "drive_torque",
                      passthrough: Sequence[tuple] = (), stamps: Optional[np.ndarray] = None) -> Dict[str, int]:
    """Write an offline run as a ROS 2 MCAP with the node's topics and layout.

    Parameters
    ----------
    result : SimResult
        From :func:`belt_drive_ros.core.simulate.simulate`.
    path : path or binary stream
        Output file (refused if it exists, unless ``force``).
    force : bool
        Replace an existing file.
    namespace : str
        Namespace of the topics (default ``/``: ``/shaft_speed`` ...).
    output_rate : float, optional
        Messages per second [Hz]; default the scene's ``output_rate`` (the
        node's publish rate). Samples are taken every ``round(1/(rate*dt))``
        integrator steps; all steps if that does not divide evenly. The run's
        last sample is written too where the duration is no whole number of
        those periods: the file ends where the run does.
    topics : iterable of str, optional
        Subset of ``robot_description``, ``drive_torque``, ``joint_states``,
        ``shaft_speed``, ``load_torque``, ``belt_torque``,
        ``relative_deflection`` (and the slipping model's outputs: none written for a run of another model) (default all).
        ``robot_description`` is one ``std_msgs/String`` message at the start:
        the drive's URDF from the scene's radii (:mod:`belt_drive_ros.io.urdf`),
        offered transient local like ``robot_state_publisher``'s, for
        Foxglove's 3D panel.
    compression : {"zstd", "lz4", "none"}
    extra_metadata : mapping of record name to str dict, optional
        Further metadata records.
    start_time_ns : int, optional
        Time stamp [ns since the epoch] of scene time 0. Default: the wall
        time of the call, as rosbag2 stamps a recording (viewers then show
        the day of the run, not 1970). Give a fixed value (0 included) for
        files that must be byte-identical run after run (golden files).
    bag_folder : bool
        Write rosbag2's folder layout (``path/NAME_0.mcap`` +
        ``path/metadata.yaml``, :class:`msg_tools.bagdir.Ros2BagWriter`)
        instead of one file; implied by the split limits.
    max_bag_size : int, optional
        Split into a new file once one holds this many bytes.
    max_bag_duration : float, optional
        Split into a new file once one spans this much time [s].
    drive_topic : str
        Topic of the run's drive torque (a re-simulated node recording:
        ``drive_torque_applied``, beside the recording's raw ``drive_torque``).
    passthrough : sequence of tuple
        Recorded topics copied as they are, ``(topic, type, offered QoS YAML,
        type hash, [(log time [ns], CDR bytes)])``, written in time order
        between the samples (:func:`~belt_drive_ros.io.resimulate.resimulation`).
    stamps : array of int, optional
        Write only the samples at these time stamps [ns] (a re-simulated node recording: its ticks, so a stretch
        the node integrated in one go, a /clock jump or a stall, has no samples here either).

    Returns
    -------
    dict
        Messages written per topic.

    Notes
    -----
    ``log_time``, ``publish_time`` and the ``joint_states`` stamps are
    ``start_time_ns`` + simulated time. Messages are encoded as ``mcap_ros2``
    encodes them (zero padding), so the same run with the same
    ``start_time_ns`` gives a byte-identical file (golden files).
    At each time the order is the node's: ``drive_torque``, ``joint_states``,
    then the Float64 outputs; ``robot_description`` comes first of all.

    Raises
    ------
    BagExistsError
        If ``path`` exists and ``force`` is False.
    BagWriteError
        If the file cannot be written.
    """
    stride = _output_stride(result, output_rate)
    n = len(result.time)
    count = len(range(0, n, stride)) + (1 if n and (n - 1) % stride else 0)  # (the run's last sample, off the stride)
    if stamps is not None and start_time_ns is not None:  # (the samples kept: the scene record says how many)
        times = np.round(np.asarray(result.time, dtype=float)[::stride] * 1e9).astype(np.int64) + int(start_time_ns)
        count = int(np.isin(times, stamps).sum())
    writer = ResultMcapWriter(path, result, force=force, namespace=namespace, output_rate=output_rate,
                              topics=topics, compression=compression, extra_metadata=extra_metadata,
                              start_time_ns=start_time_ns, bag_folder=bag_folder, max_bag_size=max_bag_size,
                              max_bag_duration=max_bag_duration, drive_topic=drive_topic, passthrough=passthrough,
                              samples=count if stamps is None or start_time_ns is not None else None, stamps=stamps)
    try:
        writer.write(result)
    except BaseException:
        writer.abort()
        raise
    return writer.close()


#: a run of at most this many samples between passed-through messages (a re-simulated node recording passes its
#: drive_torque through at every step) is written message by message: a block's fixed cost exceeds its messages'
#: own there. 10 s of paper at 1 ms into a file, a message passed through every k steps, s CPU as blocks / message
#: by message: k = 1: 1.21 / 0.62, 2: 0.62 / 0.42, 3: 0.43 / 0.34, 4: 0.39 / 0.33, 8: 0.20 / 0.27 (2026-11-28; a bag
#: folder the same)
SHORT_RUN = 4


class ResultMcapWriter:
    """The one writer of offline runs to MCAP: :func:`write_result_mcap` for a whole run, window by window for a streamed one.

    ``ResultMcapWriter(path, first_window, ...)`` opens the output (options as
    :func:`write_result_mcap`), :meth:`write` appends a window of the run
    (a :class:`~belt_drive_ros.core.simulate.SimResult` continuing the
    previous one, see :mod:`belt_drive_ros.core.stream`), :meth:`close`
    finishes the file and returns the messages per topic. Output samples are
    every ``stride``-th sample of the whole run, counted across windows, so a
    streamed run writes what the whole run would. With ``samples`` given (a
    whole run), the scene record goes first, as always; otherwise (a stream,
    whose length is known only at the end) it is written at :meth:`close`
    with the count. ``chunk_size`` [bytes] (default the writer's 128 KiB,
    closed every 0.25 s of log time) sets size-only chunks: the MCAP writer
    keeps one chunk index entry per chunk until it finishes, so a day-long
    stream uses a few MiB chunks to keep that small.
    """

    def __init__(self, path, result, force: bool = False, *, namespace: str = "/",
                 output_rate: Optional[float] = None, topics: Optional[Iterable[str]] = None,
                 compression: str = "zstd", extra_metadata: Optional[Mapping[str, Mapping[str, str]]] = None,
                 start_time_ns: Optional[int] = None, bag_folder: bool = False,
                 max_bag_size: Optional[int] = None, max_bag_duration: Optional[float] = None,
                 samples: Optional[int] = None, chunk_size: Optional[int] = None,
                 drive_topic: str = "drive_torque", passthrough: Sequence[tuple] = (),
                 stamps: Optional[np.ndarray] = None):
        self.float_outputs = FLOAT_OUTPUTS + tuple(o for o in SLIP_FLOAT_OUTPUTS if getattr(result, "model", "") in SLIP_MODELS)
        offline_topics = (ROBOT_DESCRIPTION, "drive_torque", "joint_states", TF_TOPIC.strip("/")) + tuple(
            name for name, _ in self.float_outputs)
        self.wanted = offline_topics if topics is None else tuple(t.strip("/") for t in topics)
        # (the slipping model's outputs are known topics of any run: a run of another model has none to write)
        unknown = sorted(set(self.wanted) - set(offline_topics) - {name for name, _ in SLIP_FLOAT_OUTPUTS})
        if unknown:
            raise ValueError(f"topics: unknown {', '.join(unknown)}; offline runs have {', '.join(offline_topics)}")
        self.stride = _output_stride(result, output_rate)
        self.stamps = None if stamps is None else np.unique(np.asarray(stamps, dtype=np.int64))  # (sorted)
        if start_time_ns is None:
            start_time_ns = time.time_ns()
        self.start_time_ns = int(start_time_ns)
        if self.start_time_ns < 0:
            raise ValueError(f"start_time_ns must be >= 0 ns since the epoch, got {start_time_ns}")
        if len(result.time) and result.time[0] < 0:
            raise ValueError(f"result starts at negative time {result.time[0]} s; MCAP times must be >= 0")
        self.namespace = namespace
        self.seen = 0  # samples of the run so far (all windows)
        self.samples = 0  # of them written
        self._tail = None  # (the latest window, the index of its last sample)
        scene = result.scene
        mapping = scene_mapping(scene, model=result.model, method=result.method, dt=result.dt)
        drive_source = "torque_bag" if isinstance(mapping.get("drive"), dict) and mapping["drive"].get("type") == RECORDED_DRIVE else "scene"
        self._record = lambda count: _scene_record(
            mapping, source="offline", drive_source=drive_source,
            extra={
                "model_choice": result.choice.reason if result.choice is not None else f"{result.model}: set explicitly",
                "method_choice": (result.method_choice.reason if getattr(result, "method_choice", None) is not None
                                  else f"{result.method}: set explicitly"),  # fmt: skip
                "output_rate": float(output_rate or scene.output_rate) if self.stride > 1 else 1.0 / result.dt,
                "samples": int(count),
            },
        )
        parameters = {name: _fmt(float(value)) for name, value in scene.params.to_dict().items()}
        parameters.update(model=result.model, method=result.method, dt=_fmt(float(result.dt)))
        self._deferred = samples is None
        # a long stream: fewer, larger chunks (the writer keeps one index entry per chunk until the end)
        chunking = {} if chunk_size is None else {"chunk_size": int(chunk_size), "flush_interval_s": None}
        try:
            if bag_folder or max_bag_size or max_bag_duration:
                from msg_tools.bagdir import Ros2BagWriter

                self.writer: Any = Ros2BagWriter(path, force=force, compression=compression,
                                                 max_bag_size=max_bag_size, max_bag_duration=max_bag_duration,
                                                 blocks=True, **chunking)
            else:
                self.writer = BlockMcapWriter(path, force=force, compression=compression, **chunking)
            w = self.writer
            if not self._deferred:
                w.add_metadata(SCENE_METADATA, self._record(samples))
            self.payload_topics = []
            if "drive_torque" in self.wanted:
                self.payload_topics.append((_absolute(drive_topic, namespace), FLOAT64, "drive_torque"))
            if "joint_states" in self.wanted:
                self.payload_topics.append((_absolute("joint_states", namespace), JOINT_STATE, None))
            if TF_TOPIC.strip("/") in self.wanted:  # /tf is absolute, as tf2 broadcasts it
                self.payload_topics.append((TF_TOPIC, TF_MESSAGE, TF_TOPIC))
                self._tf = TfEncoder(scene.params)
            for topic, signal in self.float_outputs:
                if topic in self.wanted:
                    self.payload_topics.append((_absolute(topic, namespace), FLOAT64, signal))
            w.add_metadata(PARAMETERS_METADATA, parameters)
            written = {topic for topic, _, _ in self.payload_topics}
            w.add_metadata(UNITS_METADATA, {
                key: unit for key, unit in units_metadata(namespace).items()
                if key in written or key.rsplit("/", 1)[0] in written
            })
            for extra_name, values in (extra_metadata or {}).items():
                w.add_metadata(extra_name, dict(values))
        except (MsgToolsError, OSError) as exc:
            raise bag_error(exc) from None
        self._params = scene.params
        self._topics_added = False
        # recorded messages copied as they are, in time order between the samples: (time, topic, type, CDR)
        self._passthrough = sorted(((t, topic, type_name, data) for topic, type_name, _, _, messages in passthrough
                                    for t, data in messages), key=lambda m: m[0])
        self._passthrough_qos = [(topic, type_name, qos, type_hash) for topic, type_name, qos, type_hash, _ in passthrough]
        self._next_passthrough = 0

    def _add_topics(self, t0_ns: Optional[int]) -> None:
        """Channels in the file's order: robot_description with its one message (at the first sample), then the signals."""
        w = self.writer
        if ROBOT_DESCRIPTION in self.wanted and t0_ns is not None:
            description = _absolute(ROBOT_DESCRIPTION, self.namespace)
            w.add_topic(description, STRING, ROBOT_DESCRIPTION_QOS)
            if hasattr(w, "latch"):  # a split run starts every file with it
                w.latch(description)
            w.write_raw(description, STRING, encode_robot_description(self._params)[1], t0_ns)
        for topic, type_name, _ in self.payload_topics:
            w.add_topic(topic, type_name, TF_QOS if topic == TF_TOPIC else "reliable")
        for topic, type_name, qos, type_hash in self._passthrough_qos:
            from msg_tools import parse_offered_qos_yaml

            try:
                profiles = parse_offered_qos_yaml(qos) if qos else "reliable"
            except ValueError:
                profiles = "reliable"
            w.add_topic(topic, type_name, profiles or "reliable", type_hash=type_hash)
        self._topics_added = True

    def _write_passthrough(self, until_ns: Optional[int]) -> None:
        """The passed-through messages up to ``until_ns`` (all with None)."""
        messages, k = self._passthrough, self._next_passthrough
        while k < len(messages) and (until_ns is None or messages[k][0] <= until_ns):
            t, topic, type_name, data = messages[k]
            self.writer.write_raw(topic, type_name, data, t)
            k += 1
        self._next_passthrough = k

    def write(self, result) -> None:
        """Append the window ``result`` (the samples after the previous window's last)."""
        n = len(result.time)
        first = (-self.seen) % self.stride
        self.seen += n
        if n:  # the run's last sample so far: written at close when it is off the stride (the run ends there)
            self._tail = (result, n - 1)
        self._write_samples(result, slice(first, n, self.stride), len(range(first, n, self.stride)))

    def _write_samples(self, result, index: slice, count: int) -> None:
        """The samples ``index`` (``count`` of them) of the window ``result``."""
        if not count:
            return
        t_ns = np.round(np.asarray(result.time, dtype=float)[index] * 1e9).astype(np.int64) + self.start_time_ns
        o = {name: np.asarray(values)[index] for name, values in result.outputs.items()}
        if self.stamps is not None:  # only the recording's own ticks
            keep = np.isin(t_ns, self.stamps)
            if not keep.all():
                t_ns, o, count = t_ns[keep], {name: v[keep] for name, v in o.items()}, int(keep.sum())
                if not count:
                    return
        self.samples += count
        payloads: list = []  # the messages of each topic (msg_tools.block_writer.FixedMessages)
        phi = None  # the joint angles (n, 4) [rad]: joint_states' positions and /tf's rotations (read only)
        for topic, type_name, signal in self.payload_topics:
            if signal is None:
                zeros = np.zeros(count)
                phi = np.column_stack([o["phi_M"], o["phi_1"], o["phi_2"], o["phi_3"]]) if phi is None else phi
                velocity = np.column_stack([o["omega_M"], o["omega_1"], o["omega_2"], o["omega_3"]])
                effort = np.column_stack([o["drive_torque"], zeros, zeros, -o["load_torque"]])
                payloads.append(joint_state_messages(t_ns, phi, velocity, effort))
            elif signal == TF_TOPIC:
                phi = np.column_stack([o["phi_M"], o["phi_1"], o["phi_2"], o["phi_3"]]) if phi is None else phi
                payloads.append(self._tf.messages(t_ns, phi))
            else:
                payloads.append(float64_messages(np.asarray(o[signal], dtype=float)))
        try:
            if not self._topics_added:
                self._add_topics(int(t_ns[0]))
            topics = [(topic, type_name) for topic, type_name, _ in self.payload_topics]
            passthrough = self._passthrough
            a = 0
            while a < t_ns.size:  # the samples up to the next passed-through message, as one block
                k = self._next_passthrough
                b = t_ns.size if k >= len(passthrough) else int(np.searchsorted(t_ns, passthrough[k][0], "left"))
                if b > a:
                    self._write_block(topics, t_ns[a:b], [p[a:b] for p in payloads])
                if b < t_ns.size:  # passed-through messages at or before t_ns[b] go before that sample
                    self._write_passthrough(int(t_ns[b]))
                a = b
        except (MsgToolsError, OSError) as exc:
            raise bag_error(exc) from None

    def _write_block(self, topics: list, t_ns: np.ndarray, payloads: List[np.ndarray]) -> None:
        """Samples ``t_ns`` [ns] of every topic as one block (:class:`msg_tools.block_writer.BlockMcapWriter`, or a
        bag folder's :class:`msg_tools.bagdir.Ros2BagWriter` made with ``blocks=True``, which splits it into files);
        a run of at most :data:`SHORT_RUN` steps message by message."""
        if t_ns.size > SHORT_RUN:
            self.writer.write_block(topics, t_ns, payloads)
            return
        write = self.writer.write_raw
        rows = [p.rows() if hasattr(p, "rows") else p for p in payloads]
        for k, t in enumerate(t_ns.tolist()):
            for (topic, type_name), r in zip(topics, rows):
                write(topic, type_name, r[k].tobytes(), t)

    def close(self) -> Dict[str, int]:
        """Finish the file (the scene record now, for a stream); returns messages per topic. The run's last sample
        is written when the stride passed it (a duration that is no whole number of output periods: the file ends
        where the run does, not up to a period before; a recording's own stamps excepted)."""
        if self._tail is not None and self.stamps is None and (self.seen - 1) % self.stride:
            result, last = self._tail
            self._write_samples(result, slice(last, last + 1), 1)
        self._tail = None
        try:
            if not self._topics_added:
                self._add_topics(None)
            self._write_passthrough(None)
            if self._deferred:
                self.writer.add_metadata(SCENE_METADATA, self._record(self.samples))
            counts = self.writer.topic_counts()
            self.writer.__exit__(None, None, None)
        except (MsgToolsError, OSError) as exc:
            raise bag_error(exc) from None
        return counts

    def abort(self) -> None:
        """Close after a failure (the file is not completed; :mod:`belt_drive_ros.io.atomic` removes it)."""
        try:
            self.writer.__exit__(RuntimeError, RuntimeError("aborted"), None)
        except Exception:  # noqa: BLE001 - the original error is the one to report
            pass

"""A belt network's topics, messages and recordings (no rclpy): one layout for the node and the offline run.

Topics (relative names, SI units; ``P`` a pulley's name, ``S`` a span's
``<from>_<to>``; every value ``std_msgs/Float64`` unless said):

====================================  ========================================================
topic                                 content [unit]
====================================  ========================================================
``drive_torque``                      input: torque on the driver (crank) [N m] (node: subscribed)
``P/load_torque``                     input: torque accessory P takes from the belt [N m] (node: subscribed)
``P/angle``, ``P/speed``              rotation [rad], speed [rad/s], positive moving the belt forward
``P/belt_torque``                     torque of the belt on P, ``r (T_leave - T_arrive)`` [N m]
``P/hub_load``                        P's bearing load |(T_i - w) e_i - (T_{i-1} - w) e_{i-1}|, w = m' v^2 [N]
``P/friction_use``                    ``|dT| / capstan limit`` [-] (1: P would start to slip)
``P/slip``, ``P/slip_speed``          1 while P slides, else 0 [-]; belt ahead of P's surface [m/s]
``spans/S/tension``                   span tension [N]
``spans/S/slack``                     1 while the span would go slack (``T < m' v^2``), else 0 [-]
``tensioner_arm/angle``               the arm's angle about its pivot [rad] (absolute, x axis = 0)
``joint_states``                      ``sensor_msgs/JointState``: every pulley, then ``tensioner_arm``
``/tf``                               ``tf2_msgs/TFMessage``: one transform per joint
``robot_description``                 ``std_msgs/String``: the layout's URDF (:mod:`.network_urdf`)
====================================  ========================================================

``joint_states``: position and velocity of each pulley, effort the
external torque along its positive rotation ``u_i`` [N m] (drive +, load
-); the arm's position is its angle from the installed one [rad] (the URDF
draws the installed layout at 0), its effort 0. The linear tier has no
slip: ``slip`` and ``slip_speed`` are 0 there (``friction_use`` says
where a pulley would slip).

A recording is self-describing: a metadata record ``network_scene`` holds
the scene's YAML text, the method, step and tick, and the node records,
besides what it received, the inputs it *applied*: ``drive_torque_applied``
and ``P/load_torque_applied`` once per tick while a value from the topic
was held (before a pulley's first message its profile acts). Those replay
the run exactly (``belt-drive sim REC.mcap``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from msg_tools.bagdir import bag_files
from msg_tools.block_writer import BlockMcapWriter
from msg_tools.errors import MsgToolsError
from msg_tools.units import UNITS_METADATA

from .bag_layout import (FLOAT64, JOINT_STATE, ROBOT_DESCRIPTION_QOS, STRING, TF_MESSAGE, TF_QOS, TF_TOPIC, _absolute,
                         _fmt, bag_error)
from .cdr_encoders import JointStateEncoder, TfEncoder, encode_float64, float64_rows

__all__ = ["NETWORK_METADATA", "NetworkLayout", "NetworkBagWriter", "read_network_recording", "scene_text",
           "write_network_mcap"]

#: metadata record of a network recording (the scene and how it was stepped)
NETWORK_METADATA = "network_scene"
DRIVE_TOPIC = "drive_torque"
APPLIED = "_applied"
ARM_JOINT = "tensioner_arm"
PULLEY_SIGNALS = (("angle", "rad"), ("speed", "rad/s"), ("belt_torque", "N*m"), ("hub_load", "N"),
                  ("friction_use", "1"), ("slip", "1"), ("slip_speed", "m/s"))
SPAN_SIGNALS = (("tension", "N"), ("slack", "1"))
#: samples a recording keeps before it writes them as one block (~0.1 MB of fead_i4's outputs: about one chunk,
#: what the message-by-message writer kept open too; a process killed outright loses at most these)
BLOCK_SAMPLES = 25
#: the rows of a one-sample run that NetworkLayout.values lays end to end (n values each; arm_angle last, one)
_SIGNAL_ROWS = ("angle", "speed", "belt_torque", "hub_load", "friction_use", "slip", "slip_speed", "tension", "slack",
                "arm_angle")


def scene_text(label: str) -> str:
    """The YAML text of a network scene, by shipped name or path (what a recording stores)."""
    from .inputs import read_text
    from .scenes import shipped_networks

    if str(label) in shipped_networks():
        return (resources.files("belt_drive_ros") / "scenes" / "networks" / f"{label}.yaml").read_text(encoding="utf-8")
    return read_text(Path(label), "scene file")


def scene_from_text(text: str, name: str):
    from .inputs import parse_yaml
    from ..core.network.scene import NetworkScene

    return NetworkScene.from_mapping(parse_yaml(text, f"network scene {name}"), name=name)


class NetworkLayout:
    """The topics, joints and frames of one network scene, and the messages of one sample.

    ``floats``: the Float64 output topics in publishing order, each ``(topic, (what, index))``;
    ``joints``: joint names; ``inputs``: ``[(topic, pulley index)]`` of the subscribed inputs.
    """

    def __init__(self, scene):
        from ..core.network.model import arm

        self.scene = scene
        P = scene.pulleys
        self.floats: List[Tuple[str, Tuple[str, int]]] = []
        for i, p in enumerate(P):
            self.floats += [(f"{p.name}/{what}", (what, i)) for what, _ in PULLEY_SIGNALS]
        for j, span in enumerate(scene.span_names()):
            self.floats += [(f"spans/{span}/{what}", (what, j)) for what, _ in SPAN_SIGNALS]
        self.units = {f"{p.name}/{what}": unit for p in P for what, unit in PULLEY_SIGNALS}
        self.units.update({f"spans/{s}/{what}": unit for s in scene.span_names() for what, unit in SPAN_SIGNALS})
        self.joints = [p.name for p in P]
        self.arm = None
        if scene.tensioner is not None:
            self.floats.append(("tensioner_arm/angle", ("arm_angle", 0)))
            self.units["tensioner_arm/angle"] = "rad"
            self.joints.append(ARM_JOINT)
            self.arm = arm(P, scene.tensioner)  # (pulley index, pivot, length, installed angle)
        self.inputs = [(DRIVE_TOPIC, scene.driver)] + [(f"{p.name}/load_torque", i) for i, p in enumerate(P)
                                                       if p.role == "accessory"]
        self.units.update({topic: "N*m" for topic, _ in self.inputs})
        self.units.update({topic + APPLIED: "N*m" for topic, _ in self.inputs})
        # values(): where each Float64 output sits in a one-sample run's rows laid end to end (n each, the arm's 1)
        n = len(P)
        at = {what: j * n for j, what in enumerate(_SIGNAL_ROWS)}
        self._gather = np.array([at[what] + i for _, (what, i) in self.floats], dtype=np.intp)
        self._zeros = np.zeros(n)

    # ----------------------------------------------------------------- frames
    def senses(self) -> List[float]:
        """Per pulley the sense of rotation about +z of a positive angle (+1 counter-clockwise), from the belt:
        at the tangent point ``a`` where the belt leaves along ``e``, ``omega z x (a - c) = v e``."""
        geo = self.scene.geometry
        out = []
        for i, p in enumerate(self.scene.pulleys):
            a = np.asarray(geo.leave[i]) - np.asarray(p.centre, dtype=float)
            e = geo.directions[i]
            out.append(1.0 if a[0] * e[1] - a[1] * e[0] > 0 else -1.0)
        return out

    def frames(self) -> List[tuple]:
        """``(joint, parent link, x, y, sense)`` of every joint (the tensioner pulley hangs on the arm's link)."""
        out = []
        t = self.arm[0] if self.arm else -1
        for i, (p, sense) in enumerate(zip(self.scene.pulleys, self.senses())):
            if i == t:
                _, _, length, angle = self.arm  # in the arm's link (at the pivot, not turned at 0)
                out.append((p.name, f"{ARM_JOINT}_link", length * math.cos(angle), length * math.sin(angle), sense))
            else:
                out.append((p.name, "base_link", float(p.centre[0]), float(p.centre[1]), sense))
        if self.arm:
            out.append((ARM_JOINT, "base_link", float(self.arm[1][0]), float(self.arm[1][1]), 1.0))
        return out

    def tf_encoder(self) -> TfEncoder:
        return TfEncoder(None, frames=self.frames())

    def joint_encoder(self) -> JointStateEncoder:
        return JointStateEncoder(names=self.joints)

    def urdf(self) -> str:
        from .network_urdf import network_urdf

        return network_urdf(self)

    # ---------------------------------------------------------------- samples
    def values(self, run, u) -> Tuple[list, list]:
        """``(joints, floats)`` of a one-sample run and its pulley torques ``u``: the JointState's position,
        velocity and effort concatenated, and the Float64 topics' values, as Python floats (one gather from the
        run's rows, in :attr:`floats`' order; a flag as 1.0 or 0.0)."""
        zeros = self._zeros
        rows = [run.angle[0], run.speed[0], run.belt_torque[0], run.hub_load[0], run.friction_use[0],
                zeros if getattr(run, "slip", None) is None else run.slip[0],
                zeros if getattr(run, "slip_speed", None) is None else run.slip_speed[0], run.tension[0],
                run.slack[0].astype(float), zeros[:1] if run.arm_angle is None else run.arm_angle[:1]]
        floats = np.concatenate(rows).take(self._gather).tolist()
        state = run.states[0].tolist()
        m = len(state) // 2
        return self.joint_values(state[:m], state[m:], np.asarray(u, dtype=float).tolist()), floats

    def joint_values(self, angle: list, speed: list, u: list) -> list:
        """The JointState's position, velocity and effort concatenated, as Python floats, of the absolute state's
        angles and speeds (m each: the pulleys', then the arm's; a run's ``states`` row split in two) and the
        pulley torques ``u`` [N m] (:meth:`~belt_drive_ros.ros.network_stepper.NetworkStepper.pulley_state`).

        The arm's position is its absolute angle less the installed one, ``(theta_a + theta_0) - theta_0``
        computed as the run's ``arm_angle`` gives it (bit for bit the recorded value)."""
        n = len(self.scene.pulleys)
        if not self.arm:
            return angle[:n] + speed[:n] + list(u)
        theta0 = self.arm[3]
        return angle[:n] + [(angle[n] + theta0) - theta0] + speed[:n] + [speed[n]] + list(u) + [0.0]


# ---------------------------------------------------------------------- writing
class NetworkBagWriter:
    """A network run or recording as a ROS 2 MCAP (profile ros2, cdr, offered QoS, zstd chunks).

    Channels in order: ``robot_description`` (one latched message at the first sample), ``joint_states``,
    ``/tf``, the Float64 outputs; inputs (``record_inputs``: received and applied) when first written.
    The outputs are kept for :data:`BLOCK_SAMPLES` samples and written as one block
    (:meth:`msg_tools.block_writer.BlockMcapWriter.write_block`: no message object or writer call per
    message; a split folder, ``max_bag_duration`` / ``max_bag_size``, takes them sample by sample); inputs
    are written as they come. :meth:`flush` and :meth:`close` write what is kept. ``output_qos``: the QoS the
    outputs' publishers offer, written as their channels' ``offered_qos_profiles`` (the node's: reliable, transient
    local, keep last 10; an offline run's default: reliable, volatile).

    A split folder is written under its lock (:func:`~belt_drive_ros.io.bag_folder.bag_folder_lock`, as the paper
    node's :func:`~belt_drive_ros.ros.recorder.open_writer` and ``belt-drive sim --bag-folder`` take it), held until
    :meth:`close`: a second writer into the folder is refused (:class:`~.recording.BagWriteError` "FOLDER: another
    run (pid N) is writing this bag folder ...") before it looks at the folder.
    """

    def __init__(self, path, layout: NetworkLayout, record: Dict[str, str], *, force: bool = False,
                 namespace: str = "/", compression: str = "zstd", max_bag_duration: float = 0.0,
                 max_bag_size: int = 0, output_qos="reliable"):
        self.layout = layout
        self._output_qos = output_qos
        self.namespace = namespace
        try:
            if max_bag_duration or max_bag_size:  # a rosbag2 folder split as the paper node's (every file self-describing)
                from msg_tools.bagdir import Ros2BagWriter

                from .bag_folder import bag_folder_lock

                # one writer per folder, as the paper node's and sim --bag-folder (the node names record_path)
                self.writer = Ros2BagWriter(path, force=force, compression=compression,
                                            max_bag_duration=max_bag_duration or None, max_bag_size=max_bag_size or None,
                                            hold=bag_folder_lock(path, ""))
            else:
                self.writer = BlockMcapWriter(path, force=force, compression=compression)
            self.writer.add_metadata(NETWORK_METADATA, record)
            units = {_absolute(t, namespace): u for t, u in layout.units.items()}
            for field, unit in (("position", "rad"), ("velocity", "rad/s"), ("effort", "N*m")):  # (as the drive's)
                units[_absolute(f"joint_states/{field}", namespace)] = unit
            self.writer.add_metadata(UNITS_METADATA, units)
        except (MsgToolsError, OSError) as exc:
            raise bag_error(exc) from None
        self._joint = layout.joint_encoder()
        self._tf = layout.tf_encoder()
        self._joint_topic = _absolute("joint_states", namespace)
        self._float_topics = [_absolute(t, namespace) for t, _ in layout.floats]
        self._block_topics = [(self._joint_topic, JOINT_STATE), (TF_TOPIC, TF_MESSAGE)] + [
            (t, FLOAT64) for t in self._float_topics]
        self._started = False
        self._inputs: set = set()
        # the samples kept for the next block: times, joint_states and /tf CDR (fixed sizes), Float64 values
        # (a split folder's writer takes messages one by one, each sample as it comes: its files split on time)
        self._block = BLOCK_SAMPLES if isinstance(self.writer, BlockMcapWriter) else 1
        self._kept = 0
        self._times = np.empty(BLOCK_SAMPLES, dtype=np.int64)
        self._values = np.empty((BLOCK_SAMPLES, len(self._float_topics)))
        self._cdr: list = [None, None]

    def _start(self, t_ns: int) -> None:
        w = self.writer
        description = _absolute("robot_description", self.namespace)
        w.add_topic(description, STRING, ROBOT_DESCRIPTION_QOS)
        if hasattr(w, "latch"):  # a split folder: every file starts with the layout's URDF
            w.latch(description)
        import msg_tools

        w.write_raw(description, STRING, msg_tools.encode(STRING, {"data": self.layout.urdf()}), t_ns)
        w.add_topic(self._joint_topic, JOINT_STATE, self._output_qos)
        w.add_topic(TF_TOPIC, TF_MESSAGE, TF_QOS)
        for topic in self._float_topics:
            w.add_topic(topic, FLOAT64, self._output_qos)
        self._started = True

    def write_sample(self, t_ns: int, joints: Sequence[float], floats: Sequence[float]) -> None:
        """One sample at ``t_ns`` [ns]: joint_states, /tf and every Float64 output (values in :attr:`NetworkLayout.floats`' order)."""
        n = len(self.layout.joints)
        self.write_tick(t_ns, self._joint.encode(t_ns, joints), self._tf.encode(t_ns, joints[:n]), floats)

    def write_tick(self, t_ns: int, joint_cdr: bytes, tf_cdr: bytes, floats: Sequence[float]) -> None:
        """One sample given as the joint_states and /tf CDR (the bytes the node publishes) and the Float64
        outputs' values (written as :func:`~.cdr_encoders.encode_float64` encodes them)."""
        try:
            if not self._started:
                self._start(t_ns)
            k = self._kept
            if k and (t_ns < self._times[k - 1] or len(joint_cdr) != self._cdr[0].shape[1]
                      or len(tf_cdr) != self._cdr[1].shape[1]):
                self._write_block()  # a block is in time order, its messages of one size each
                k = 0
            if not k and (self._cdr[0] is None or self._cdr[0].shape[1] != len(joint_cdr)
                          or self._cdr[1].shape[1] != len(tf_cdr)):
                self._cdr = [np.empty((BLOCK_SAMPLES, len(joint_cdr)), np.uint8),
                             np.empty((BLOCK_SAMPLES, len(tf_cdr)), np.uint8)]
            self._times[k] = t_ns
            self._cdr[0][k] = np.frombuffer(joint_cdr, np.uint8)
            self._cdr[1][k] = np.frombuffer(tf_cdr, np.uint8)
            self._values[k] = floats
            self._kept = k + 1
            if self._kept == self._block:
                self._write_block()
        except (MsgToolsError, OSError) as exc:
            raise bag_error(exc) from None

    def _write_block(self) -> None:
        k = self._kept
        if not k:
            return
        self._kept = 0
        per_topic = float64_rows(self._values[:k].T).reshape(len(self._float_topics), k, 12)  # topic by topic
        payloads = [self._cdr[0][:k], self._cdr[1][:k], *per_topic]
        if self._block > 1:
            self.writer.write_block(self._block_topics, self._times[:k], payloads)
            return
        for j in range(k):  # sample by sample, in the block's topic order
            for (topic, kind), rows in zip(self._block_topics, payloads):
                self.writer.write_raw(topic, kind, rows[j].tobytes(), int(self._times[j]))

    def write_input(self, topic: str, value: float, t_ns: int) -> None:
        """An input value (received, or ``..._applied`` at a tick) [N m]."""
        name = _absolute(topic, self.namespace)
        try:
            if name not in self._inputs:
                self.writer.add_topic(name, FLOAT64, "reliable")
                self._inputs.add(name)
            self.writer.write_raw(name, FLOAT64, encode_float64(np.array([value]))[0], t_ns)
        except (MsgToolsError, OSError) as exc:
            raise bag_error(exc) from None

    def add_metadata(self, name: str, data: Dict[str, str]) -> None:
        """A metadata record (the node's ``restart`` records: a re-simulation refuses a restarted run)."""
        try:
            self.writer.add_metadata(name, data)
        except (MsgToolsError, OSError) as exc:
            raise bag_error(exc) from None

    def flush(self) -> None:
        """Write the samples kept and flush the file."""
        try:
            self._write_block()
            self.writer.flush()
        except (MsgToolsError, OSError) as exc:
            raise bag_error(exc) from None

    def close(self) -> Dict[str, int]:
        try:
            self._write_block()
            counts = self.writer.topic_counts()
            self.writer.__exit__(None, None, None)
        except (MsgToolsError, OSError) as exc:
            raise bag_error(exc) from None
        return counts


def network_record(scene, text: str, *, method: str, dt: float, tick_ns: int, source: str,
                   drive_source: str, namespace: str = "/", tier: str = "") -> Dict[str, str]:
    """The ``network_scene`` metadata record (``tier``: the one the run stepped, which its re-simulation steps)."""
    return {"format": "belt_drive_ros network 1", "kind": "network", "name": scene.name, "yaml": text,
            "method": method, "dt": _fmt(float(dt)), "tick_ns": str(int(tick_ns)), "source": source,
            "drive_source": drive_source, "namespace": namespace, **({"tier": tier} if tier else {})}


def write_network_mcap(stepper, text: str, states, steps: Sequence[int], path, *, force: bool = False,
                       start_time_ns: int = 0, held: Optional[Sequence[Tuple[int, int, float]]] = None,
                       source: str = "offline", namespace: str = "/",
                       received: Sequence[Tuple[str, int, float]] = ()) -> Dict[str, int]:
    """Write a run's states ``(N, 2m)`` at the grid steps ``steps`` (``k dt``) as the node would publish them.

    Each sample's outputs come from the stepper's one-sample evaluation (the node's), so a node run and its
    offline twin give equal bytes. ``held``: ``(step, pulley, value)`` where a held input took effect (a
    re-simulated recording); they are written as ``..._applied`` at each written sample while in force.
    ``received``: a recording's inputs as received ``(relative topic, log time [ns], value)``, passed through.
    """
    scene = stepper.scene
    layout = NetworkLayout(scene)
    record = network_record(scene, text, method=stepper.method, dt=stepper.dt, tier=stepper.tier,
                            tick_ns=int(round((steps[1] - steps[0] if len(steps) > 1 else 1) * stepper.dt * 1e9)),
                            source=source, drive_source="recorded" if held else "scene", namespace=namespace)
    writer = NetworkBagWriter(path, layout, record, force=force, namespace=namespace)
    topic_of = {i: topic for topic, i in layout.inputs}
    changes = sorted(held or [])
    now: Dict[int, float] = {}
    c = 0
    try:
        for row, k in enumerate(steps):
            while c < len(changes) and changes[c][0] <= k:
                now[changes[c][1]] = changes[c][2]
                c += 1
            for i, value in now.items():
                stepper.hold(i, value)
            t_ns = start_time_ns + int(round(k * stepper.dt * 1e9))
            run, u = stepper.sample(k, states[row])
            joints, floats = layout.values(run, u)
            writer.write_sample(t_ns, joints, floats)
            for i, value in now.items():
                writer.write_input(topic_of[i] + APPLIED, value, t_ns)
        for topic, t_ns, value in received:  # the inputs as the node received them, passed through
            writer.write_input(topic, value, t_ns)
    except BaseException:
        try:
            writer.writer.__exit__(RuntimeError, RuntimeError("aborted"), None)
        except Exception:  # noqa: BLE001 - the original error is the one to report
            pass
        raise
    return writer.close()


# ---------------------------------------------------------------------- reading
@dataclass
class NetworkRecording:
    """What a network recording holds for its re-simulation."""

    scene: object
    text: str
    method: str
    dt: float
    tick_ns: int
    start_ns: int
    end_ns: int
    #: (step index, pulley index, value [N m]) where an applied input changed (at a tick)
    held: List[Tuple[int, int, float]]
    #: the ticks (index from the first) the recording has samples of: the node publishes a tick it integrated
    #: to; ticks it had to skip (a gap: the process starved) were integrated over, not published
    ticks: List[int]
    #: the node's namespace (its topics' prefix)
    namespace: str = "/"
    #: the inputs as received: (relative topic, log time [ns], value [N m]) (a re-simulation passes them through)
    received: List[Tuple[str, int, float]] = field(default_factory=list)
    #: the tier the run stepped ("" in a recording from before it was recorded: the scene's choice)
    tier: str = ""


def is_network_recording(path) -> bool:
    """Whether ``path`` is an MCAP file (or a split recording's bag folder) holding a ``network_scene`` record
    (also a file cut off mid-write)."""
    p = Path(str(path))
    try:
        if not ((p.suffix.lower() == ".mcap" and p.is_file()) or (p.is_dir() and any(p.glob("*.mcap")))):
            return False
    except OSError:  # a name the system refuses (too long, ...): not a recording; the scene loader says why
        return False
    try:
        for record in _records(p):
            if type(record).__name__ == "Metadata" and record.name == NETWORK_METADATA:
                return True
            if type(record).__name__ == "Message":  # the record comes before the first message
                return False
    except Exception:  # noqa: BLE001 - not readable: the recording path says why
        return False
    return False


def _records(path):
    """The file's records in order, read as a stream (no summary needed); a file cut off mid-write ends at
    its last complete record (a node killed while recording). A split recording's folder: its files in order."""
    from mcap.stream_reader import StreamReader

    for name in bag_files(path) if Path(str(path)).is_dir() else [path]:
        with open(name, "rb") as f:
            reader = StreamReader(f, record_size_limit=1 << 30).records
            while True:
                try:
                    record = next(reader)
                except StopIteration:
                    break
                except Exception:  # noqa: BLE001 - cut off or damaged here: what came before stands
                    break
                yield record


def read_network_recording(path) -> NetworkRecording:
    """The scene, step, tick and applied inputs of a network recording (:class:`BagReadError` naming the file).

    Read as a stream, so a recording cut off mid-write (the node killed) re-simulates up to its last
    complete sample."""
    from .bag_layout import BagReadError, restarts_of

    metadata: Dict[str, Dict[str, str]] = {}
    topics: Dict[int, str] = {}
    messages: List[Tuple[str, int, bytes]] = []
    records: List[Tuple[str, Dict[str, str]]] = []  # every metadata record in file order (the restarts among them)
    try:
        for record in _records(path):
            kind = type(record).__name__
            if kind == "Metadata":
                metadata[record.name] = dict(record.metadata)
                records.append((record.name, metadata[record.name]))
            elif kind == "Channel":
                topics[record.id] = record.topic
            elif kind == "Message":
                messages.append((topics.get(record.channel_id, ""), record.log_time, record.data))
        record = metadata[NETWORK_METADATA]
        scene = scene_from_text(record["yaml"], record["name"])
        layout = NetworkLayout(scene)
        namespace = record.get("namespace", "/")
        pulley_of = {_absolute(topic + APPLIED, namespace): i for topic, i in layout.inputs}
        received_of = {_absolute(topic, namespace): topic for topic, _ in layout.inputs}
        joint_states = _absolute("joint_states", namespace)
        dt, tick_ns = float(record["dt"]), int(record["tick_ns"])
    except BagReadError:
        raise
    except Exception as exc:  # noqa: BLE001 - damaged or foreign file: one line
        raise BagReadError(f"{path}: not a readable network recording ({type(exc).__name__}: {exc})") from None
    restarts = [(t or 0, cause) for t, cause in restarts_of(records)]  # (node time [ns], cause) after the first start
    written = [t for topic, t, _ in messages if topic == joint_states]
    back = next((k for k in range(1, len(written)) if written[k] <= written[k - 1]), None)
    if back is not None and not restarts:  # (a recording made before the node recorded its restarts)
        restarts.append((written[back], "clock jumped back"))
    if restarts:  # one run from one start: a restart's second run cannot be stepped on from the first
        t, cause = min(restarts)
        first = min(written) if written else t
        raise BagReadError(f"{path}: cannot re-simulate: the node restarted from the initial state ({cause}) at t = "
                           f"{(t - first) / 1e9:.6g} s of the recording; 'belt-drive sim' repeats one run from one start")
    messages.sort(key=lambda m: m[1])  # log time order (stable: a tick's order kept)
    times = [t for topic, t, _ in messages if topic == joint_states]
    applied = [(t, pulley_of[topic], float(np.frombuffer(data[4:12], "<f8")[0]))
               for topic, t, data in messages if topic in pulley_of]
    if not times:
        raise BagReadError(f"{path}: a network recording without samples (joint_states)")
    start = times[0]
    substeps = int(round(tick_ns * 1e-9 / dt))
    held, last = [], {}
    for t, i, value in applied:  # in steps: the value acts from its tick on
        if t > times[-1]:
            break  # applied at a tick whose sample was cut off
        k = int(round((t - start) / tick_ns)) * substeps
        if last.get(i) != value:
            held.append((k, i, value))
            last[i] = value
    ticks = [int(round((t - start) / tick_ns)) for t in times]
    received = [(received_of[topic], t, float(np.frombuffer(data[4:12], "<f8")[0]))
                for topic, t, data in messages if topic in received_of and len(data) >= 12]
    return NetworkRecording(scene, record["yaml"], record["method"], dt, tick_ns, start, times[-1], held, ticks,
                            namespace, received, record.get("tier", ""))


__all__ += ["NetworkRecording", "is_network_recording", "network_record", "scene_from_text"]

"""QoS profiles and the rosbag2 ``offered_qos_profiles`` YAML.

rosbag2 stores, per channel, the QoS profiles offered by the publishers of the
topic (MCAP channel metadata key ``offered_qos_profiles``, and again inside the
``rosbag2`` metadata record). ``ros2 bag play`` re-creates its publishers from
them, so a latched (transient_local) or best-effort topic replays as recorded.

Format (ROS 2 Jazzy, bag metadata version 9), from ros2/rosbag2
``rosbag2_storage/src/rosbag2_storage/qos.cpp`` (``convert<Rosbag2QoS>::encode``
and ``serialize_rclcpp_qos_vector``, which is ``YAML::Dump`` of a sequence):

* a YAML block sequence, one mapping per offering publisher, keys in the order
  history, depth, reliability, durability, deadline, lifespan, liveliness,
  liveliness_lease_duration, avoid_ros_namespace_conventions;
* since version 9 the policies are **strings** from ``rmw_qos_*_policy_to_str``
  (``keep_last``, ``reliable``, ``best_effort``, ``volatile``,
  ``transient_local``, ``automatic``, ...); version <= 8 bags (Humble, Iron)
  used the integer enum values, which :func:`parse_offered_qos_yaml` also reads;
* durations are mappings ``{sec: int, nsec: int}``; publishers that set no
  deadline/lifespan/lease are reported by the middleware as infinite,
  ``sec: 9223372036, nsec: 854775807`` (``RMW_DURATION_INFINITE``);
* ``YAML::Dump`` writes no trailing newline.

Reading (``rosbag2_storage_mcap/src/mcap_storage.cpp``, ``read_metadata``) parses
the channel key with the version found in the ``rosbag2`` metadata record, so a
file with string policies must carry ``version: 9`` there (our writer does).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Dict, Iterable, List, Sequence, Tuple, Union

__all__ = [
    "INFINITE",
    "PRESETS",
    "QosProfile",
    "offered_qos_yaml",
    "parse_offered_qos_yaml",
    "preset",
]

#: ``RMW_DURATION_INFINITE`` as (sec, nsec): what rmw reports for "not set".
INFINITE: Tuple[int, int] = (9223372036, 854775807)

HISTORY = ("system_default", "keep_last", "keep_all", "unknown")
RELIABILITY = ("system_default", "reliable", "best_effort", "unknown", "best_available")
DURABILITY = ("system_default", "transient_local", "volatile", "unknown", "best_available")
LIVELINESS = (
    "system_default", "automatic", "manual_by_node", "manual_by_topic", "unknown",
    "best_available",
)
# Position in each tuple = integer value of the rmw enum (rmw/types.h), used by
# metadata versions <= 8.


def _check(name: str, value: str, allowed: Sequence[str]) -> str:
    text = str(value).strip().lower()
    if text not in allowed:
        raise ValueError(f"invalid QoS {name} {value!r}; expected one of {', '.join(allowed)}")
    return text


def _duration(name: str, value: Any) -> Tuple[int, int]:
    """Return ``(sec, nsec)`` from a tuple, a ``{sec, nsec}`` dict or seconds."""
    if value is None:
        return INFINITE
    if isinstance(value, dict):
        sec, nsec = int(value["sec"]), int(value["nsec"])
    elif isinstance(value, (tuple, list)) and len(value) == 2:
        sec, nsec = int(value[0]), int(value[1])
    elif isinstance(value, (int, float)):
        if value < 0:
            raise ValueError(f"QoS {name} must be >= 0 s, got {value}")
        total_ns = int(round(float(value) * 1e9))
        sec, nsec = divmod(total_ns, 1_000_000_000)
    else:
        raise ValueError(f"QoS {name} must be (sec, nsec), {{sec, nsec}} or seconds, got {value!r}")
    if sec < 0 or not 0 <= nsec:
        raise ValueError(f"QoS {name} must be non-negative, got sec={sec} nsec={nsec}")
    return sec, nsec


@dataclass(frozen=True)
class QosProfile:
    """A publisher's offered QoS, with the policy names rosbag2 writes.

    Attributes
    ----------
    history : str
        ``"keep_last"``, ``"keep_all"``, ``"system_default"`` or ``"unknown"``.
    depth : int
        Queue depth [messages] for ``keep_last``.
    reliability : str
        ``"reliable"``, ``"best_effort"``, ...
    durability : str
        ``"volatile"`` or ``"transient_local"`` (latched), ...
    deadline, lifespan, liveliness_lease_duration : tuple of int
        ``(sec, nsec)``; :data:`INFINITE` when not set.
    liveliness : str
        ``"automatic"``, ``"manual_by_topic"``, ...
    avoid_ros_namespace_conventions : bool
        As in ``rmw_qos_profile_t``.
    """

    history: str = "keep_last"
    depth: int = 10
    reliability: str = "reliable"
    durability: str = "volatile"
    deadline: Tuple[int, int] = INFINITE
    lifespan: Tuple[int, int] = INFINITE
    liveliness: str = "automatic"
    liveliness_lease_duration: Tuple[int, int] = INFINITE
    avoid_ros_namespace_conventions: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "history", _check("history", self.history, HISTORY))
        object.__setattr__(
            self, "reliability", _check("reliability", self.reliability, RELIABILITY)
        )
        object.__setattr__(self, "durability", _check("durability", self.durability, DURABILITY))
        object.__setattr__(self, "liveliness", _check("liveliness", self.liveliness, LIVELINESS))
        depth = int(self.depth)
        if depth < 0:
            raise ValueError(f"QoS depth must be >= 0, got {self.depth}")
        object.__setattr__(self, "depth", depth)
        for name in ("deadline", "lifespan", "liveliness_lease_duration"):
            object.__setattr__(self, name, _duration(name, getattr(self, name)))
        object.__setattr__(
            self, "avoid_ros_namespace_conventions", bool(self.avoid_ros_namespace_conventions)
        )

    @classmethod
    def from_dict(cls, data: Dict[str, Any]) -> "QosProfile":
        """Build a profile from a mapping (string or integer policies)."""
        known = {f for f in cls.__dataclass_fields__}  # type: ignore[attr-defined]
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"unknown QoS keys {sorted(unknown)}; expected {sorted(known)}")
        values = dict(data)
        for key, table in (
            ("history", HISTORY),
            ("reliability", RELIABILITY),
            ("durability", DURABILITY),
            ("liveliness", LIVELINESS),
        ):
            if isinstance(values.get(key), int) and not isinstance(values.get(key), bool):
                index = values[key]
                if not 0 <= index < len(table):
                    raise ValueError(f"invalid integer QoS {key} {index}")
                values[key] = table[index]
        return cls(**values)

    @classmethod
    def from_rclpy(cls, profile: Any) -> "QosProfile":
        """Convert an ``rclpy.qos.QoSProfile`` (duck-typed; rclpy is not imported).

        Durations that are zero (``RMW_DURATION_UNSPECIFIED``, rclpy's default)
        are written as :data:`INFINITE`, which is what the middleware reports for
        them and what ``ros2 bag record`` stores.
        """

        def policy(value: Any) -> str:
            name = getattr(value, "name", value)
            return str(name).lower()

        def duration(value: Any) -> Tuple[int, int]:
            ns = getattr(value, "nanoseconds", None)
            if ns is None:
                return _duration("duration", value)
            if ns <= 0:
                return INFINITE
            return divmod(int(ns), 1_000_000_000)

        return cls(
            history=policy(profile.history),
            depth=int(profile.depth),
            reliability=policy(profile.reliability),
            durability=policy(profile.durability),
            deadline=duration(profile.deadline),
            lifespan=duration(profile.lifespan),
            liveliness=policy(profile.liveliness),
            liveliness_lease_duration=duration(profile.liveliness_lease_duration),
            avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
        )

    def to_yaml_item(self) -> str:
        """Return this profile as one item of the YAML sequence (yaml-cpp layout)."""

        def dur(name: str, value: Tuple[int, int]) -> List[str]:
            return [f"  {name}:", f"    sec: {value[0]}", f"    nsec: {value[1]}"]

        lines = [
            f"- history: {self.history}",
            f"  depth: {self.depth}",
            f"  reliability: {self.reliability}",
            f"  durability: {self.durability}",
            *dur("deadline", self.deadline),
            *dur("lifespan", self.lifespan),
            f"  liveliness: {self.liveliness}",
            *dur("liveliness_lease_duration", self.liveliness_lease_duration),
            f"  avoid_ros_namespace_conventions: {'true' if self.avoid_ros_namespace_conventions else 'false'}",
        ]
        return "\n".join(lines)


#: Named profiles. ``reliable`` is rclpy's default publisher (depth 10);
#: ``clock`` is ``rclcpp::ClockQoS`` (keep_last 1, best_effort), what
#: ``ros2 bag play --clock`` and simulators offer on ``/clock``; ``diagnostics``
#: is what diagnostic_updater publishers offer (reliable, volatile, depth 10);
#: ``transient_local`` is a latched topic (``/robot_description`` style);
#: ``sensor_data`` is ``qos_profile_sensor_data`` (best_effort, depth 5).
PRESETS: Dict[str, QosProfile] = {
    "reliable": QosProfile(),
    "best_effort": QosProfile(reliability="best_effort"),
    "sensor_data": QosProfile(depth=5, reliability="best_effort"),
    "clock": QosProfile(depth=1, reliability="best_effort"),
    "diagnostics": QosProfile(depth=10),
    "transient_local": QosProfile(depth=1, durability="transient_local"),
}


def preset(name: str, depth: int | None = None) -> QosProfile:
    """Return the named preset, optionally with another ``keep_last`` depth.

    Raises
    ------
    ValueError
        If ``name`` is not a preset; the message lists the presets.
    """
    try:
        profile = PRESETS[name]
    except KeyError:
        raise ValueError(
            f"unknown QoS preset {name!r}; presets: {', '.join(sorted(PRESETS))}"
        ) from None
    return profile if depth is None else replace(profile, depth=depth)


QosLike = Union[str, QosProfile, Dict[str, Any], Any]


def as_profiles(profile: Union[QosLike, Iterable[QosLike], None]) -> List[QosProfile]:
    """Normalise a preset name, profile, dict, rclpy profile or a list of them."""
    if profile is None:
        return [PRESETS["reliable"]]
    if isinstance(profile, (list, tuple)):
        out = [p for item in profile for p in as_profiles(item)]
        return out
    if isinstance(profile, QosProfile):
        return [profile]
    if isinstance(profile, str):
        return [preset(profile)]
    if isinstance(profile, dict):
        return [QosProfile.from_dict(profile)]
    if hasattr(profile, "reliability") and hasattr(profile, "durability"):
        return [QosProfile.from_rclpy(profile)]
    raise TypeError(f"cannot use {type(profile).__name__} as a QoS profile")


def offered_qos_yaml(profile: Union[QosLike, Iterable[QosLike], None] = None) -> str:
    """Return the rosbag2 (Jazzy) ``offered_qos_profiles`` YAML for a channel.

    Parameters
    ----------
    profile : str, QosProfile, dict, rclpy QoSProfile, or a list of them, optional
        The offered profile(s): one item per publisher. A string is a preset
        name (see :data:`PRESETS`). ``None`` means the ``reliable`` preset.
        An empty list gives ``"[]"`` (rosbag2 then uses its default offer).

    Returns
    -------
    str
        YAML block sequence without a trailing newline, e.g.::

            - history: keep_last
              depth: 10
              reliability: reliable
              durability: volatile
              deadline:
                sec: 9223372036
                nsec: 854775807
              ...
              avoid_ros_namespace_conventions: false
    """
    profiles = as_profiles(profile)
    if not profiles:
        return "[]"
    return "\n".join(p.to_yaml_item() for p in profiles)


def parse_offered_qos_yaml(text: str) -> List[QosProfile]:
    """Parse an ``offered_qos_profiles`` string (string or integer policies).

    Raises
    ------
    ValueError
        If the text is not a YAML list of QoS mappings.
    """
    # the package's bounded YAML loader (no aliases, bounded nesting): the text comes from a file
    from belt_drive_ros.io.inputs import InputError, parse_yaml

    if not text or not text.strip():
        return []
    try:
        data = parse_yaml(text, "offered_qos_profiles")
    except InputError as exc:
        raise ValueError(str(exc)) from None
    if data is None:
        return []
    if not isinstance(data, list) or not all(isinstance(item, dict) for item in data):
        raise ValueError("offered_qos_profiles must be a YAML list of mappings")
    return [QosProfile.from_dict(item) for item in data]

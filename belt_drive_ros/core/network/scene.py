"""Network scenes (``kind: network``, every key in ``docs/serpentine.md``): a serpentine belt around named pulleys
listed in the order the belt travels, counter-clockwise (:mod:`.geometry`), an optional tensioner arm; frozen,
validated, errors one line naming the pulley or key (read by :func:`belt_drive_ros.io.scenes.load_network`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Mapping

import numpy as np

from ..errors import SceneError, plain_number, real, short, unknown_key
from ..integrators import method_class
from ..sources import TorqueProfile, make_profile
from .geometry import Layout, layout

SIDES = {"inner": 1.0, "backside": -1.0}
#: most pulleys one belt network may have (an accessory drive has a dozen or so; the model's cost grows with the cube)
MAX_PULLEYS = 64
#: names a pulley may not take: the tensioner arm's joint and the URDF root (its topics, joint_states, /tf)
RESERVED_NAMES = ("tensioner_arm", "base_link")


def span_name(leaving: str, arriving: str) -> str:
    """The span from pulley ``leaving`` to pulley ``arriving`` as its topics and columns name it."""
    return f"{leaving}_{arriving}"
ROLES = ("driver", "accessory", "idler", "tensioner")
#: torque sign per role: a driver's profile drives the belt, an accessory's loads it
ROLE_SIGN = {"driver": 1.0, "accessory": -1.0}


def _number(where: str, value, low: float = 0.0, strict: bool = False, top: float = 1.0e9) -> float:
    value = float(plain_number(value, lambda text: SceneError(f"{where}: {text}")))
    if not math.isfinite(value):
        raise SceneError(f"{where}: must be finite, got {value!r}")
    if value < low or (strict and value == low):
        raise SceneError(f"{where}: must be {'>' if strict else '>='} {low:g}, got {value!r}")
    if value > top:
        raise SceneError(f"{where}: {value:g} is outside the plausible range (up to {top:g})")
    return value


def _point(where: str, value) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise SceneError(f"{where}: expected [x, y] in m, got {short(value)}")
    return (_number(f"{where}[0]", value[0], low=-1.0e3, top=1.0e3),  # (a drive within 1 km either way)
            _number(f"{where}[1]", value[1], low=-1.0e3, top=1.0e3))


def _keys(where: str, data, allowed: tuple, required: tuple) -> dict:
    if not isinstance(data, Mapping):
        raise SceneError(f"{where}: expected a mapping, got {type(data).__name__} {short(data)}")
    unknown = unknown_key(data, allowed)
    if unknown:
        raise SceneError(f"{where}.{unknown}: unknown key; known: {', '.join(allowed)}")
    missing = [k for k in required if k not in data]
    if missing:
        raise SceneError(f"{where}.{missing[0]}: missing")
    return dict(data)


@dataclass(frozen=True)
class Pulley:
    """One pulley: name, centre [m], radius [m], inertia [kg m^2], bearing damping [N m s/rad],
    side (+1 inner face, -1 backside), role, torque profile (driver: drive; accessory: load), friction coefficient."""

    name: str
    centre: tuple[float, float]
    radius: float
    inertia: float
    damping: float = 0.0
    side: float = 1.0
    role: str = "idler"
    torque: TorqueProfile | None = None
    mu: float = 0.5
    #: the pulley's speed over its drive shaft's (a gear train in front of the driver, :func:`reduce_gears`; the
    #: profile acts on the shaft): 1.0 without gears. ``inertia`` and ``damping`` are then the reduced ones.
    gear: float = 1.0

    @property
    def sign(self) -> float:
        """+1: the profile drives the belt (driver), -1: it loads it (accessory), 0: no torque."""
        return ROLE_SIGN.get(self.role, 0.0) if self.torque is not None else 0.0

    def load(self, t, angle=0.0, speed=0.0):
        """The torque on the pulley [N m], signed (+ drives the belt): ``sign Q(t, angle / gear, speed / gear) / gear``
        at its angle [rad] and speed [rad/s] (``Q`` the profile, on the drive shaft ahead of a gear train)."""
        g = self.gear
        if g == 1.0:
            return self.sign * self.torque.torque(t, angle, speed)
        return self.sign * self.torque.torque(t, angle / g, speed / g) / g


#: keys of one wheel of a driver's gear train
GEAR_KEYS = ("inertia", "damping", "ratio")


def reduce_gears(where: str, raw, inertia: float, damping: float) -> tuple[float, float, float]:
    """``(gear, inertia, damping)`` of a driver pulley behind a gear train ``raw`` (wheels from the drive shaft on,
    each ``inertia`` [kg m^2], ``damping`` [N m s/rad], ``ratio`` the next wheel's speed over this one's), reduced as
    the paper's model reduces wheels M, 1, 2 (``docs/serpentine.md``): ``G_k`` the product of the ratios from wheel k
    on, ``gear = G_0``, ``J = J_pulley + sum_k I_k / G_k^2``, ``b = b_pulley + sum_k b_k / G_k^2`` (no mesh loss)."""
    if not isinstance(raw, list) or not 1 <= len(raw) <= 8:
        raise SceneError(f"{where}: expected a list of 1 to 8 wheels from the drive shaft on, got {short(raw)}")
    wheels = []
    for k, item in enumerate(raw):
        w = f"{where}[{k}]"
        item = _keys(w, item, GEAR_KEYS, ("inertia", "ratio"))
        wheels.append((_number(f"{w}.inertia", item["inertia"], top=1.0e3), _number(f"{w}.damping", item.get("damping", 0.0), top=1.0e4),
                       _number(f"{w}.ratio", item["ratio"], strict=True, top=100.0)))
    G = 1.0
    for I_k, b_k, ratio in reversed(wheels):  # G_k = ratio_k G_(k+1), from the pulley back to the shaft
        G *= ratio
        inertia += I_k / G**2
        damping += b_k / G**2
    return G, inertia, damping


@dataclass(frozen=True)
class Belt:
    """Belt: axial stiffness EA [N], Kelvin-Voigt damping [N s] (span damping = damping / L_j [N s/m]),
    mass per length [kg/m], installed tension T_0 [N] (uniform, no load)."""

    EA: float
    damping: float
    mass_per_length: float
    installed_tension: float


@dataclass(frozen=True)
class Tensioner:
    """Tensioner arm: pulley (its name), pivot [m], arm inertia about the pivot [kg m^2] (pulley mass included),
    spring rate [N m/rad], damping [N m s/rad]; its length and installed angle come from the pulley's centre.
    ``preload`` [N m] is the spring torque at the installed angle (computed from T_0 when the scene gives T_0)."""

    pulley: str
    pivot: tuple[float, float]
    inertia: float
    spring_rate: float
    damping: float
    preload: float


@dataclass(frozen=True)
class Engine:
    """The engine: the pulley on its crankshaft (default: the driver), cylinders, strokes per cycle, and the
    crank's speed range [rad/s] (the Campbell axis). Firing order (pulses per crank revolution) = 2 cylinders / strokes."""

    cylinders: int = 4
    strokes: int = 4
    speed_range: tuple[float, float] = (70.0, 630.0)
    pulley: str = ""

    @property
    def firing_order(self) -> float:
        return self.cylinders * 2.0 / self.strokes


@dataclass(frozen=True)
class NetworkScene:
    """A belt network scene (SI units): pulleys in travel order, belt, optional tensioner, engine, run settings."""

    name: str
    description: str
    pulleys: tuple[Pulley, ...]
    belt: Belt
    tensioner: Tensioner | None
    engine: Engine
    initial_speed: float
    operating_speed: float
    duration: float
    dt: float
    method: str
    geometry: Layout

    def index(self, name: str) -> int:
        return [p.name for p in self.pulleys].index(name)

    @cached_property
    def driver(self) -> int:
        """Index of the driver pulley (found once per scene object: scenes are frozen)."""
        return [p.role for p in self.pulleys].index("driver")

    def span_names(self) -> list[str]:
        n = len(self.pulleys)
        return [span_name(self.pulleys[j].name, self.pulleys[(j + 1) % n].name) for j in range(n)]

    # ------------------------------------------------------------------ reading
    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], name: str = "custom") -> "NetworkScene":
        from .model import arm_terms  # the arm's equilibrium (model: the tensioner's equation)

        allowed = ("kind", "name", "description", "pulleys", "belt", "tensioner", "engine",
                   "initial_speed", "operating_speed", "duration", "dt", "method")
        data = _keys("scene", data, allowed, ("kind", "pulleys", "belt", "duration", "dt", "initial_speed"))
        if not isinstance(data["kind"], str) or data["kind"] != "network":
            raise SceneError(f"kind: must be 'network' for a belt network scene, got {short(data['kind'])}")
        raw = data["pulleys"]
        if not isinstance(raw, list) or len(raw) < 2:
            raise SceneError(f"pulleys: expected a list of at least 2 pulleys, got {short(raw)}")
        if len(raw) > MAX_PULLEYS:
            raise SceneError(f"pulleys: at most {MAX_PULLEYS} pulleys (an accessory drive has a dozen or so), got {len(raw)}")
        pulleys, names = [], []
        keys = ("name", "centre", "radius", "inertia", "damping", "side", "role", "torque", "mu", "gears")
        for k, item in enumerate(raw):
            label = item.get("name") if isinstance(item, Mapping) and isinstance(item.get("name"), str) else f"[{k}]"
            where = f"pulleys.{label}"
            item = _keys(where, item, keys, ("name", "centre", "radius", "inertia", "role"))
            pname = item["name"]
            if not isinstance(pname, str) or not pname.isascii() or not pname.replace("_", "").isalnum() \
                    or not pname[0].isalpha() or len(pname) > 64:
                raise SceneError(f"{where}.name: letters, digits and _ only (at most 64), starting with a letter, got {short(pname)}")
            if pname in names:
                raise SceneError(f"{where}: duplicate pulley name")
            if pname in RESERVED_NAMES:
                raise SceneError(f"{where}.name: {pname!r} names the tensioner arm's own joint and topics; call the pulley "
                                 "something else")
            names.append(pname)
            role = item["role"]
            if not isinstance(role, str) or role not in ROLES:
                raise SceneError(f"{where}.role: must be one of {', '.join(ROLES)}, got {short(role)}")
            side = item.get("side", "inner")
            if not isinstance(side, str) or side not in SIDES:
                raise SceneError(f"{where}.side: must be inner or backside, got {short(side)}")
            torque = item.get("torque")
            if torque is not None and role not in ROLE_SIGN:
                article = "an" if role[0] in "aeiou" else "a"
                raise SceneError(f"{where}.torque: {article} {role} carries no torque profile (driver or accessory only)")
            if role in ROLE_SIGN and torque is None:
                raise SceneError(f"{where}.torque: missing (a {role} states its {'drive' if role == 'driver' else 'load'} torque)")
            inertia = _number(f"{where}.inertia", item["inertia"], strict=True, top=1.0e3)
            damping = _number(f"{where}.damping", item.get("damping", 0.0), top=1.0e4)
            gear = 1.0
            if "gears" in item:
                if role != "driver":
                    raise SceneError(f"{where}.gears: only the driver has a gear train in front of it")
                gear, inertia, damping = reduce_gears(f"{where}.gears", item["gears"], inertia, damping)
            pulleys.append(Pulley(
                name=pname, centre=_point(f"{where}.centre", item["centre"]),
                radius=_number(f"{where}.radius", item["radius"], low=1.0e-4, top=10.0),  # (as the drive's r_3)
                inertia=inertia, damping=damping, gear=gear,
                side=SIDES[side], role=role,
                torque=None if torque is None else make_profile(torque, f"{where}.torque"),
                mu=_number(f"{where}.mu", item.get("mu", 0.5), strict=True, top=10.0),
            ))
        spans: dict = {}  # a span is named by its pulleys joined with _ (its topics, columns): each name once
        for j, p in enumerate(pulleys):
            q = pulleys[(j + 1) % len(pulleys)]
            other = spans.setdefault(span_name(p.name, q.name), (p.name, q.name))
            if other != (p.name, q.name):
                raise SceneError(f"pulleys: the spans {other[0]} -> {other[1]} and {p.name} -> {q.name} would both be "
                                 f"named {span_name(p.name, q.name)} (their topics and columns): rename a pulley")
        roles = [p.role for p in pulleys]
        if roles.count("driver") != 1:
            raise SceneError(f"pulleys: exactly one pulley has role driver, got {roles.count('driver')}")
        if roles.count("tensioner") > 1:
            raise SceneError("pulleys: at most one pulley has role tensioner")
        geo = layout(names, [p.centre for p in pulleys], [p.radius for p in pulleys], [p.side for p in pulleys])
        b = _keys("belt", data["belt"], ("EA", "damping", "mass_per_length", "installed_tension"), ("EA", "damping"))
        EA = _number("belt.EA", b["EA"], strict=True, top=1.0e9)
        damping = _number("belt.damping", b["damping"], top=1.0e6)
        mass = _number("belt.mass_per_length", b.get("mass_per_length", 0.0), top=100.0)
        tensioner = None
        T0 = b.get("installed_tension")
        if "tensioner" in roles:
            if "tensioner" not in data:
                raise SceneError(f"tensioner: missing (pulley {names[roles.index('tensioner')]} has role tensioner)")
            t = _keys("tensioner", data["tensioner"], ("pivot", "inertia", "spring_rate", "damping", "preload"),
                      ("pivot", "inertia", "spring_rate", "damping"))
            if (T0 is None) == ("preload" not in t):
                raise SceneError("belt.installed_tension: give either it or tensioner.preload (one gives the other)")
            pivot = _point("tensioner.pivot", t["pivot"])
            tp = pulleys[roles.index("tensioner")]
            if math.hypot(tp.centre[0] - pivot[0], tp.centre[1] - pivot[1]) <= 1e-6:
                raise SceneError(f"tensioner.pivot: coincides with the centre of pulley {tp.name} (arm length 0)")
            tensioner = Tensioner(pulley=tp.name, pivot=pivot,
                                  inertia=_number("tensioner.inertia", t["inertia"], strict=True, top=1.0e3),
                                  spring_rate=_number("tensioner.spring_rate", t["spring_rate"], strict=True, top=1.0e7),
                                  damping=_number("tensioner.damping", t["damping"], top=1.0e5), preload=0.0)
            # the spring torque [N m] (in +theta_a) holding the arm at its installed angle against a uniform tension
            # T_0 is P = T_0 sum_j g_j (the belt pulls on the arm with -sum_j T_j g_j): per N of T_0
            per_newton = float(np.sum(arm_terms(geo, pulleys, tensioner)[0]))
            if abs(per_newton) < 1e-9:
                raise SceneError(f"tensioner.pivot: the arm of {tp.name} does not move the belt at its installed angle "
                                 "(it swings along the belt)")
            if T0 is None:  # the spring's torque [N m] at the installed angle, in whichever sense tensions the belt
                T0 = _number("tensioner.preload", t["preload"], strict=True, top=1.0e5) / abs(per_newton)
            T0 = _number("belt.installed_tension", T0, strict=True, top=1.0e6)
            object.__setattr__(tensioner, "preload", T0 * per_newton)
        elif "tensioner" in data:
            raise SceneError("tensioner: given, but no pulley has role tensioner")
        if T0 is None:
            raise SceneError("belt.installed_tension: missing")
        T0 = _number("belt.installed_tension", T0, strict=True, top=1.0e6)
        e = _keys("engine", data.get("engine", {}), ("pulley", "cylinders", "strokes", "speed_range"), ())
        crank = e.get("pulley", names[roles.index("driver")])
        if not isinstance(crank, str) or crank not in names:
            raise SceneError(f"engine.pulley: must name a pulley ({', '.join(names)}), got {short(crank)}")
        rng = e.get("speed_range", [70.0, 630.0])
        if not isinstance(rng, (list, tuple)) or len(rng) != 2:
            raise SceneError(f"engine.speed_range: expected [low, high] in rad/s, got {short(rng)}")
        lo, hi = _number("engine.speed_range[0]", rng[0], strict=True), _number("engine.speed_range[1]", rng[1], strict=True)
        if hi <= lo:
            raise SceneError(f"engine.speed_range: high {hi:g} must exceed low {lo:g} rad/s")
        (cyl, given_cyl), (strokes, given_strokes) = ((real(v), v) for v in (e.get("cylinders", 4), e.get("strokes", 4)))
        if not isinstance(cyl, int) or not 1 <= cyl <= 32:
            raise SceneError(f"engine.cylinders: an integer 1..32, got {short(given_cyl)}")
        if strokes not in (2, 4):
            raise SceneError(f"engine.strokes: 2 or 4, got {short(given_strokes)}")
        method = data.get("method", "exact")
        try:
            method_class(method)
        except Exception as exc:  # noqa: BLE001 - the registry's own one-line message
            raise SceneError(f"method: {exc}") from None
        dt = _number("dt", data["dt"], strict=True, top=1.0)
        duration = _number("duration", data["duration"], strict=True, top=1.0e7)
        if duration / dt > 1.0e8:
            raise SceneError(f"dt: {dt:g} s over {duration:g} s is more than 1e8 steps")
        speed = _number("initial_speed", data["initial_speed"], low=-1.0e4, top=1.0e4)
        for key in ("name", "description"):  # (a mapping or bytes printed as the scene's name)
            if key in data and not isinstance(data[key], str):
                raise SceneError(f"{key}: expected text, got {type(data[key]).__name__} {short(data[key])}")
        return cls(
            name=str(data.get("name", name)), description=str(data.get("description", "")).strip(),
            pulleys=tuple(pulleys), belt=Belt(EA, damping, mass, T0), tensioner=tensioner,
            engine=Engine(cyl, strokes, (lo, hi), crank), initial_speed=speed,
            operating_speed=_number("operating_speed", data.get("operating_speed", speed), low=-1.0e4, top=1.0e4),
            duration=duration, dt=dt, method=method, geometry=geo,
        )


def run_steps(scene, duration: float | None, dt: float | None) -> tuple[float, float, int]:
    """``(duration [s], dt [s], steps)`` of a run (default the scene's duration and step), checked as the scene
    file's (:class:`SceneError`; also for a run shorter than one step)."""
    if not isinstance(scene, NetworkScene):
        raise SceneError(f"scene: expected a NetworkScene (load_network), got {type(scene).__name__}")
    duration = scene.duration if duration is None else _number("duration", duration, strict=True, top=1.0e7)
    dt = scene.dt if dt is None else _number("dt", dt, strict=True, top=1.0)
    if duration / dt > 1.0e8:
        raise SceneError(f"dt: {dt:g} s over {duration:g} s is more than 1e8 steps")
    steps = int(round(duration / dt))
    if steps < 1:
        raise SceneError(f"duration: {duration:g} s is shorter than one step of {dt:g} s")
    return duration, dt, steps


def warm_scene():
    """The two-pulley belt (driver and accessory, constant torques) the warm-ups of the network tiers step."""
    return NetworkScene.from_mapping({
        "kind": "network", "duration": 2e-3, "dt": 1e-3, "initial_speed": 1.0,
        "belt": {"EA": 1000.0, "damping": 0.1, "installed_tension": 10.0},
        "pulleys": [{"name": "a", "role": "driver", "centre": [0, 0], "radius": 0.05, "inertia": 1e-3, "torque": 0.1},
                    {"name": "b", "role": "accessory", "centre": [0.3, 0], "radius": 0.05, "inertia": 1e-3,
                     "torque": 0.1}]})  # fmt: skip



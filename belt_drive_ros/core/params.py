"""Frozen, validated parameters of the belt drive, named by the paper's symbols (Dizo et al., eq. 3-20; each
default explained in ``docs/model.md``), SI units. Kinematics: ``g = (r_M / R_1)(r_1 / R_2)``, ``phi_2 = g phi_M``
(gear train M -> 2); ``i = g r_2 / r_3``, ``phi_3 = i phi_M`` (rigid belt only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Mapping, NamedTuple

import numpy as np

from .errors import ParameterError, plain_number, short, unknown_key

#: field -> (unit, description); also the order of the YAML keys.
FIELD_DOCS: dict[str, tuple[str, str]] = {
    "I_M": ("kg m^2", "inertia of drive wheel M (engine/motor side, incl. its shaft)"),
    "I_1": ("kg m^2", "inertia of intermediate gear wheel 1 (may be 0)"),
    "I_2": ("kg m^2", "inertia of wheel 2 (gear + driving pulley, may be 0)"),
    "I_3": ("kg m^2", "inertia of loaded pulley 3 incl. the driven device"),
    "r_M": ("m", "pitch radius of the gear on wheel M"),
    "R_1": ("m", "pitch radius of wheel 1 meshing with M"),
    "r_1": ("m", "pitch radius of wheel 1 meshing with wheel 2"),
    "R_2": ("m", "pitch radius of wheel 2 meshing with wheel 1"),
    "r_2": ("m", "belt pulley radius on wheel 2"),
    "r_3": ("m", "belt pulley radius on wheel 3"),
    "k": ("N/m", "stiffness of one belt span (two spans act in parallel)"),
    "c": ("N s/m", "viscous damping of one belt span"),
    "b_M": ("N m s/rad", "bearing damping of wheel M"),
    "b_1": ("N m s/rad", "bearing damping of wheel 1"),
    "b_2": ("N m s/rad", "bearing damping of wheel 2"),
    "b_3": ("N m s/rad", "bearing damping of wheel 3"),
    "F_0": ("N", "belt installation (pre-)tension of each span"),
    "mu": ("1", "effective belt-pulley friction coefficient"),
    "wrap_angle": ("rad", "belt wrap angle on the pulley that slips first"),
    "groove_angle": ("rad", "included pulley groove angle alpha; pi (flat belt, default), ~0.70 (40 deg) for V and poly-V: mu_eff = mu / sin(alpha/2)"),
    "belt_mass": ("kg/m", "belt mass per length m' (centrifugal tension F_c = m' v^2); 0 (default): massless belt"),
}

#: optional fields and their defaults (the flat, massless belt), left out of to_dict() when at the default
OPTIONAL_DEFAULTS: dict[str, float] = {"groove_angle": math.pi, "belt_mass": 0.0}

#: largest plausible value of each field (SI units): past these no belt drive exists, and the
#: numbers only make the model meaningless (k = 1e300 N/m gives omega_n = inf); the node
#: advertises the same ranges
PLAUSIBLE_MAX: dict[str, float] = {
    "I_M": 1.0e3, "I_1": 1.0e3, "I_2": 1.0e3, "I_3": 1.0e3,
    "r_M": 10.0, "R_1": 10.0, "r_1": 10.0, "R_2": 10.0, "r_2": 10.0, "r_3": 10.0,
    "k": 1.0e10, "c": 1.0e7, "b_M": 1.0e4, "b_1": 1.0e4, "b_2": 1.0e4, "b_3": 1.0e4,
    "F_0": 1.0e7, "mu": 10.0, "wrap_angle": 2.0 * math.pi, "groove_angle": math.pi, "belt_mass": 100.0,
}

#: smallest plausible value of the fields that have one (SI units): below these the derived quantities leave the
#: floats (r_3 = 1e-300 m: a reduced inertia of 1e600; k = 5e-324 N/m: a belt mode of 0 Hz that divides; a groove of
#: 1e-20 rad: a capstan ratio e^(1e20)); a V-belt's groove is 30-40 deg (0.52-0.70 rad), a pulley's radius centimetres
PLAUSIBLE_MIN: dict[str, float] = {
    "r_M": 1.0e-4, "R_1": 1.0e-4, "r_1": 1.0e-4, "R_2": 1.0e-4, "r_2": 1.0e-4, "r_3": 1.0e-4,
    "k": 1.0, "groove_angle": 0.2,
}
#: span damping: none (0), or at least this [N s/m] (a tinier c makes the slip mode's creep k/c overflow)
C_MIN = 1.0e-6

_POSITIVE = ("I_M", "I_3", "r_M", "R_1", "r_1", "R_2", "r_2", "r_3", "k", "mu", "wrap_angle")
_NON_NEGATIVE = ("I_1", "I_2", "c", "b_M", "b_1", "b_2", "b_3", "F_0", "belt_mass")


def _unit(name: str) -> str:
    """`` UNIT`` of field ``name`` for a message (nothing for a pure number, unit "1")."""
    unit = FIELD_DOCS[name][0]
    return "" if unit == "1" else f" {unit}"


class Rule(NamedTuple):
    """One check of one field: its value must lie strictly between ``low`` and ``high`` (floats: a closed end is
    kept as the next float outward, an unbounded one as an infinity, so a rule refuses NaN and +-inf); ``text`` the
    error's detail, formatted with ``value``. Build one with :func:`rule`."""

    field: str
    low: float
    high: float
    text: str
    #: the ends as written (an unbounded side: an infinity), e.g. for a range a ROS parameter descriptor states
    written: tuple[float, float] = (-math.inf, math.inf)

    def holds(self, value):
        """Whether ``value`` lies inside: a float: a bool; an array: a bool per element."""
        return (self.low < value) & (value < self.high)

    def error(self, value: float) -> ParameterError:
        return ParameterError(self.field, self.text.format(value=value))


def rule(field: str, low: float | None, high: float | None, ends: str, text: str) -> Rule:
    """The :class:`Rule` that ``field`` lies in ``low .. high`` (None: unbounded), ``ends`` in interval notation:
    ``"(]"`` is ``low < value <= high``."""
    written = (-math.inf if low is None else float(low), math.inf if high is None else float(high))
    low = -math.inf if low is None else math.nextafter(low, -math.inf) if ends[0] == "[" else low
    high = math.inf if high is None else math.nextafter(high, math.inf) if ends[1] == "]" else high
    return Rule(field, float(low), float(high), text, written)


#: the constructor's checks (one table: :class:`BeltDriveParams` checks a value by it, :func:`valid_parameter_rows`
#: a column) in the order it applies them, its error the first one a value breaks: every field finite (declaration
#: order), the :data:`_POSITIVE` fields > 0, the :data:`_NON_NEGATIVE` ones >= 0, the wrap angle at most a full
#: turn, the groove angle in (0, pi]
RULES: tuple[Rule, ...] = (
    *(rule(name, None, None, "()", "must be finite, got {value!r}") for name in FIELD_DOCS),
    *(rule(name, 0.0, None, "()", f"must be > 0{_unit(name)}, got {{value!r}}") for name in _POSITIVE),
    *(rule(name, 0.0, None, "[)", f"must be >= 0{_unit(name)}, got {{value!r}}") for name in _NON_NEGATIVE),
    rule("wrap_angle", None, 2.0 * math.pi, "(]", "must be <= 2*pi rad, got {value!r}"),
    rule("groove_angle", 0.0, math.pi, "(]", "must be in (0, pi] rad (pi: flat belt), got {value!r}"),
)  # fmt: skip
def _plausible_text(name: str, top: float) -> str:
    """The detail of a value outside ``name``'s plausible range (the ends :data:`RULES` and the plausible ones give)."""
    low = PLAUSIBLE_MIN.get(name)
    start = f"[{low:g}" if low is not None else "(0" if name in _POSITIVE else "[0"
    if name == "c":
        start = f"0 (no span damping) or [{C_MIN:g}"
    return f"{{value:g}}{_unit(name)} is outside the plausible range {start}, {top:g}]{_unit(name)}"


#: :meth:`BeltDriveParams.check_plausible`'s checks, one per field of :data:`PLAUSIBLE_MAX` (its upper end), then one
#: per field of :data:`PLAUSIBLE_MIN` (its lower end), in their order; the span damping's gap (0, :data:`C_MIN`) is
#: :func:`damping_gap`'s
PLAUSIBLE_RULES: tuple[Rule, ...] = tuple(
    rule(name, None, top, "(]", _plausible_text(name, top)) for name, top in PLAUSIBLE_MAX.items()
) + tuple(
    rule(name, low, None, "[)", _plausible_text(name, PLAUSIBLE_MAX[name])) for name, low in PLAUSIBLE_MIN.items()
)  # fmt: skip


def damping_gap(c):
    """Whether span damping ``c`` [N s/m] (a float, or an array: per element) lies in the implausible gap between 0
    and :data:`C_MIN` (no damping and real damping are both plausible)."""
    return (0.0 < c) & (c < C_MIN)
_BOUNDS: dict = {}


def _bounds(rules: tuple) -> tuple:
    """``(field, low, high)`` per field that ``rules`` check, the strictest of its ends: a value keeps all of its
    field's rules iff ``low < value < high`` (one comparison per field where no value breaks a rule). Derived from
    the table it is given (a table changed or replaced is read anew)."""
    found = _BOUNDS.get(id(rules))
    if found is None or found[0] is not rules:
        ends: dict = {}
        for r in rules:
            low, high = ends.get(r.field, (-math.inf, math.inf))
            ends[r.field] = (max(low, r.low), min(high, r.high))
        if len(_BOUNDS) > 8:
            _BOUNDS.clear()
        found = _BOUNDS[id(rules)] = (rules, tuple((name, low, high) for name, (low, high) in ends.items()))
    return found[1]


def _check(values: dict, rules: tuple) -> None:
    """Raise the :class:`ParameterError` of the first of ``rules`` a value of ``values`` (field -> value, changed in
    place: a value not a float made one, at the first rule that reads it) breaks."""
    for name, low, high in _bounds(rules):
        value = values[name]
        if type(value) is not float or not low < value < high:
            break
    else:
        return  # (every value a float that keeps its rules: no rule walked)
    for r in rules:
        value = values[r.field]
        if type(value) is not float:  # (a field's first rule is its finiteness: the fields made floats in order)
            value = values[r.field] = float(plain_number(value, lambda text: ParameterError(r.field, text)))
        if not r.holds(value):
            raise r.error(value)


@dataclass(frozen=True)
class BeltDriveParams:
    """Physical parameters of the accessory belt drive (SI units; defaults: the ``truck_compressor`` scene's,
    justified in ``docs/model.md``). Construction refuses, with a :class:`ParameterError` naming the field, a value
    that is not a number or breaks one of :data:`RULES` (the first it breaks)."""

    I_M: float = 1.0
    I_1: float = 0.002
    I_2: float = 0.003
    I_3: float = 0.012
    r_M: float = 0.06
    R_1: float = 0.05
    r_1: float = 0.05
    R_2: float = 0.05
    r_2: float = 0.09
    r_3: float = 0.07
    k: float = 3.0e5
    c: float = 20.0
    b_M: float = 0.05
    b_1: float = 5.0e-4
    b_2: float = 5.0e-4
    b_3: float = 5.0e-3
    F_0: float = 535.0
    mu: float = 0.5
    wrap_angle: float = 3.0
    groove_angle: float = math.pi
    belt_mass: float = 0.0

    def __post_init__(self) -> None:
        _check(self.__dict__, RULES)

    # ------------------------------------------------------------------ mapping
    @classmethod
    def from_mapping(cls, data: Mapping[str, Any] | None) -> "BeltDriveParams":
        """Build from a mapping keyed by the paper's symbols; unknown keys are errors."""
        if data is not None and not isinstance(data, Mapping):
            raise ParameterError("params", f"expected a mapping of parameters, got {type(data).__name__} {short(data)}")
        data = dict(data or {})
        unknown = unknown_key(data, _FIELDS)
        if unknown:
            raise ParameterError(unknown, f"unknown parameter; known parameters are {', '.join(sorted(_FIELDS))}")
        return cls(**data)

    def to_dict(self) -> dict[str, float]:
        """Plain ``{symbol: value}`` mapping (YAML-ready, SI units); the optional fields (:data:`OPTIONAL_DEFAULTS`)
        only when they differ from the flat massless belt, so scenes and recordings without them read as before."""
        return {
            f.name: getattr(self, f.name)
            for f in fields(self)
            if not (f.name in OPTIONAL_DEFAULTS and getattr(self, f.name) == OPTIONAL_DEFAULTS[f.name])
        }

    def check_plausible(self) -> "BeltDriveParams":
        """``self`` if every field is within :data:`PLAUSIBLE_MAX`, else :class:`ParameterError` naming the range:
        for parameters from outside (the constructor alone admits idealised values such as ``F_0 = 1e9`` N)."""
        _check(self.__dict__, PLAUSIBLE_RULES)
        if damping_gap(self.c):
            raise ParameterError("c", _plausible_text("c", PLAUSIBLE_MAX["c"]).format(value=self.c))
        return self

    def field_values(self) -> dict[str, float]:
        """Every field ``{symbol: value}``, the optional ones included (e.g. to declare them all as node parameters)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def replace(self, **changes: Any) -> "BeltDriveParams":
        """Copy with ``changes`` applied, validated like the constructor."""
        for name in changes:
            if name not in FIELD_DOCS:
                raise ParameterError(name, "unknown parameter")
        values = {name: getattr(self, name) for name in _FIELDS}
        values.update(changes)
        return BeltDriveParams(**values)

    def replace_rows(self, columns: Mapping[str, Any], *, plausible: bool = False) -> list:
        """:meth:`replace` (then :meth:`check_plausible` when ``plausible``) of every row of ``columns`` (field ->
        (V,) array of numbers; the fields not given keep ``self``'s values), column-wise: one entry per row, the
        parameters of a row that passes, or the :class:`ParameterError` the scalar path raises for one that fails.

        The rows are checked by :func:`valid_parameter_rows` (:data:`RULES`, :data:`PLAUSIBLE_RULES`: numpy over all
        rows at once); the parameters of a row that passes are built from its floats without a second check, the only
        way this class is built unchecked. A row that fails is built by the scalar path, so its error names the first
        rule it breaks."""
        names = list(columns)
        for name in names:
            if name not in FIELD_DOCS:
                raise ParameterError(name, "unknown parameter")
        arrays = [np.asarray(columns[name]) for name in names]
        for name, values in zip(names, arrays):
            if values.ndim != 1 or values.dtype.kind not in "fiu" or len(values) != len(arrays[0]):
                raise ParameterError(name, f"expected a column of numbers as long as the others, got {values.dtype} "
                                     f"{values.shape}")  # fmt: skip
        arrays = [values.astype(float) for values in arrays]
        base = self.__dict__
        every = {name: np.array([base[name]]) for name in FIELD_DOCS}  # (the unchanged fields: (1,), broadcast)
        every.update(zip(names, arrays))
        ok = valid_parameter_rows(every, plausible=plausible).tolist() if names else []
        out = []
        for passed, row in zip(ok, zip(*(values.tolist() for values in arrays))):
            if passed:
                params = object.__new__(BeltDriveParams)  # (frozen: its __dict__ filled as the constructor fills it)
                params.__dict__.update(base)
                params.__dict__.update(zip(names, row))
            else:
                try:
                    params = self.replace(**dict(zip(names, row)))
                    if plausible:
                        params.check_plausible()
                except ParameterError as exc:
                    params = exc
            out.append(params)
        return out

    # ---------------------------------------------------------------- derived
    @property
    def gear_ratio(self) -> float:
        """g = (r_M/R_1)(r_1/R_2): angle of wheel 2 per angle of wheel M [-]."""
        return (self.r_M / self.R_1) * (self.r_1 / self.R_2)

    @property
    def ratio(self) -> float:
        """i = g r_2/r_3: angle of wheel 3 per angle of wheel M (rigid belt) [-]."""
        return self.gear_ratio * self.r_2 / self.r_3

    @property
    def inertia_drive_side(self) -> float:
        """I_f = I_M + I_1 (r_M/R_1)^2 + I_2 g^2, wheels M, 1, 2 reduced to M [kg m^2]."""
        return self.I_M + self.I_1 * (self.r_M / self.R_1) ** 2 + self.I_2 * self.gear_ratio**2

    @property
    def inertia_reduced(self) -> float:
        """I_red = I_f + I_3 i^2, all four wheels reduced to M (paper eq. 13) [kg m^2]."""
        return self.inertia_drive_side + self.I_3 * self.ratio**2

    @property
    def bearing_damping_drive_side(self) -> float:
        """b_f = b_M + b_1 (r_M/R_1)^2 + b_2 g^2, reduced to M [N m s/rad]."""
        return self.b_M + self.b_1 * (self.r_M / self.R_1) ** 2 + self.b_2 * self.gear_ratio**2

    @property
    def bearing_damping_reduced(self) -> float:
        """b_red = b_f + b_3 i^2, all bearings reduced to M [N m s/rad]."""
        return self.bearing_damping_drive_side + self.b_3 * self.ratio**2

    @property
    def belt_torsional_stiffness(self) -> float:
        """2 k r_3^2: belt torque at wheel 3 per rad of relative deflection [N m/rad]."""
        return 2.0 * self.k * self.r_3**2

    @property
    def belt_natural_frequency(self) -> float:
        """Undamped belt mode omega_n = sqrt(2k (r_2^2 g^2/I_f + r_3^2/I_3)) [rad/s]."""
        g = self.gear_ratio
        return math.sqrt(
            2.0 * self.k * (self.r_2**2 * g**2 / self.inertia_drive_side + self.r_3**2 / self.I_3)
        )

    @property
    def belt_damping_ratio(self) -> float:
        """Damping ratio of the belt mode from span damping c alone [-] (zeta = c omega_n / (2k))."""
        return self.c * self.belt_natural_frequency / (2.0 * self.k)

    @property
    def mu_effective(self) -> float:
        """mu_eff = mu / sin(alpha/2): friction of a belt wedged in a groove of angle alpha [-] (flat: mu)."""
        return self.mu / math.sin(0.5 * self.groove_angle)

    @property
    def capstan_ratio(self) -> float:
        """e^(mu_eff * wrap_angle): largest (F_tight - F_c)/(F_slack - F_c) before the belt slips [-]."""
        exponent = self.mu_effective * self.wrap_angle  # (past ~709 no float holds it: the belt never slips)
        return math.exp(exponent) if exponent < 709.0 else math.inf

    def friction_limit(self, omega_M=0.0):
        """Q_max = 2 (F_0 - F_c) tanh(mu_eff beta / 2) [N]: largest net force (tight - slack) friction transmits.

        From the capstan law (F_tight - F_c) = (F_slack - F_c) e^(mu_eff beta) with
        F_tight + F_slack = 2 F_0. Clipped at 0 when F_c exceeds F_0 (the belt lifts off).
        """
        if isinstance(omega_M, (int, float)):  # the scalar path of the event handling: no numpy
            return self.scalar_friction_limit()(omega_M)
        return friction_limit_array(self.F_0, self.r_2 * self.gear_ratio, self.belt_mass, self.capstan_factor, omega_M)

    @property
    def capstan_factor(self) -> float:
        """2 tanh(mu_eff beta / 2): Q_max per net span tension F_0 - F_c [-]."""
        return 2.0 * math.tanh(0.5 * self.mu_effective * self.wrap_angle)

    def scalar_friction_limit(self):
        """:meth:`friction_limit` [N] of one float ``omega_M`` [rad/s], the constants bound: ``max((F_0 - m' v^2) k_c, 0)``,
        ``v = r_2 g omega_M``, the operations of :func:`friction_limit_array` in the same order."""
        force, mass, speed, factor = float(self.F_0), float(self.belt_mass), self.r_2 * self.gear_ratio, self.capstan_factor

        def limit(omega_M):
            v = speed * omega_M
            return max((force - mass * v * v) * factor, 0.0)

        return limit


#: the fields in declaration order (validation walks them in this order)
_FIELDS = tuple(f.name for f in fields(BeltDriveParams))


def valid_parameter_rows(columns: Mapping[str, np.ndarray], *, plausible: bool = True) -> np.ndarray:
    """(V,) bool: whether each row of ``columns`` (field -> (V,) float array, or (1,) for a value every row shares;
    the fields not given pass) keeps :data:`RULES` (the constructor's checks) and, when ``plausible``,
    :data:`PLAUSIBLE_RULES` (:meth:`BeltDriveParams.check_plausible`'s), each field's by the bounds the scalar
    check compares a value with."""
    ok = np.ones(max((len(values) for values in columns.values()), default=0), dtype=bool)
    for rules in (RULES, PLAUSIBLE_RULES) if plausible else (RULES,):
        for name, low, high in _bounds(rules):
            values = columns.get(name)
            if values is not None:
                ok &= (low < values) & (values < high)
    if plausible and columns.get("c") is not None:
        ok &= ~damping_gap(columns["c"])
    return ok


class ParamColumns:
    """The fields of V (validated) :class:`BeltDriveParams` as (V,) float arrays, with their derived quantities:
    :class:`BeltDriveParams`' own properties on the columns, so column v is what ``params[v]`` computes (what
    :class:`~belt_drive_ros.core.model.ModelStack` is built from)."""

    gear_ratio = BeltDriveParams.gear_ratio
    ratio = BeltDriveParams.ratio
    inertia_drive_side = BeltDriveParams.inertia_drive_side
    inertia_reduced = BeltDriveParams.inertia_reduced
    bearing_damping_drive_side = BeltDriveParams.bearing_damping_drive_side
    bearing_damping_reduced = BeltDriveParams.bearing_damping_reduced
    belt_torsional_stiffness = BeltDriveParams.belt_torsional_stiffness

    def __init__(self, params=(), columns: dict | None = None):
        if columns is None:
            params = list(params)
            columns = {name: np.array([getattr(q, name) for q in params], dtype=float) for name in FIELD_DOCS}
        for name in FIELD_DOCS:
            setattr(self, name, columns[name])

    def __len__(self) -> int:
        return len(self.k)

    def subset(self, keep) -> "ParamColumns":
        """The columns of the variants ``keep`` (positions)."""
        return ParamColumns(columns={name: getattr(self, name)[keep] for name in FIELD_DOCS})


def centrifugal_tension(belt_speed_ratio, belt_mass, omega_M):
    """F_c = m' v^2 [N] at belt speed v = (r_2 g) omega_M [m/s]: the tension a belt of m' [kg/m] needs to run round its
    pulleys, which takes nothing from the pressure on them (floats or arrays that broadcast, per element)."""
    v = belt_speed_ratio * omega_M
    return belt_mass * v * v


def friction_limit_array(F_0, belt_speed_ratio, belt_mass, capstan_factor, omega_M):
    """Q_max = max((F_0 - m' v^2) 2 tanh(mu_eff beta / 2), 0) [N] at belt speed v = (r_2 g) omega_M, on arrays
    (of speeds, and of parameters: an ensemble's variants on the last axis), per element as for one run."""
    return np.maximum((F_0 - centrifugal_tension(belt_speed_ratio, belt_mass, omega_M)) * capstan_factor, 0.0)

"""A torque formula written once, as Python expression text, and the forms derived from it.

A profile states its torque as one expression in ``t`` [s], ``angle`` [rad]
and ``speed`` [rad/s] (:class:`Formula`). Three forms come from that text:

* the scalar closure ``f(t, angle, speed) -> float`` (:func:`scalar_function`):
  the text compiled as a ``lambda``, for the step loops on Python floats;
* the inlined source (:func:`render`): the same text with the argument names
  replaced, which :func:`~belt_drive_ros.core.integrators.compile_scalar_loop`
  writes into its generated loop instead of a call. Closure and loop compile
  the same operations in the same order, so they agree bit for bit;
* the array function (:func:`array_function`): the same syntax tree with
  ``a if c else b`` turned into ``where(c, a, b)``, ``and``/``or`` into
  ``&``/``|``, chained comparisons split, and each primitive replaced by its
  numpy twin (``math.sin`` -> ``np.sin``), for whole runs sampled at once.
  Equal to the closure to rounding (numpy's ``sin`` may differ in the last bit).

Names in the expression are the arguments, the primitives of :data:`PRIMITIVES`
(each with a scalar and an array implementation, tested against each other),
names bound by ``:=`` (a subexpression used twice), and the formula's
``constants``: a float is written into the text as its exact literal
(``repr``); an array or tuple (a table) is bound by name; another
:class:`~belt_drive_ros.core.sources.TorqueProfile` is bound as a call to its
own forms (a schedule's parts).

Generated source is registered with :mod:`linecache` (:func:`compile_source`),
so tracebacks and debuggers show its lines.
"""

from __future__ import annotations

import ast
import hashlib
import linecache
import math
from bisect import bisect_right
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

ARGUMENTS = ("t", "angle", "speed")


# ---------------------------------------------------------------- primitives
def _interp(x: float, xp, fp) -> float:
    """``np.interp`` for one float: linear between the points, held beyond the ends."""
    if x <= xp[0]:
        return fp[0]
    if x >= xp[-1]:
        return fp[-1]
    if x != x:  # NaN in, NaN out (as numpy)
        return x
    j = bisect_right(xp, x) - 1
    return (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j]) * (x - xp[j]) + fp[j]


def _held(x: float, xp, fp) -> float:
    """Zero-order hold: ``fp[clip(searchsorted(xp, x, 'right') - 1, 0, last)]`` for one float."""
    j = bisect_right(xp, x) - 1
    return fp[0 if j < 0 else len(fp) - 1 if j >= len(fp) else j]


def _held_array(x, xp, fp):
    idx = np.clip(np.searchsorted(xp, np.asarray(x, dtype=float), side="right") - 1, 0, len(fp) - 1)
    return np.asarray(fp)[idx]


def _held_ns(t: float, times_ns, fp) -> float:
    """Zero-order hold switching at whole nanoseconds: ``t`` is rounded to the nearest ns (half to even)."""
    return _held(round(t * 1e9), times_ns, fp)


def _held_ns_array(t, times_ns, fp):
    t_ns = np.rint(np.asarray(t, dtype=float) * 1e9).astype(np.int64)
    idx = np.clip(np.searchsorted(times_ns, t_ns, side="right") - 1, 0, len(fp) - 1)
    return np.asarray(fp)[idx]


#: name -> (scalar implementation, array implementation). The only functions a formula may call.
PRIMITIVES: dict[str, tuple[Callable, Callable]] = {
    "sin": (math.sin, np.sin),
    "cos": (math.cos, np.cos),
    "abs": (abs, np.abs),
    "interp": (_interp, np.interp),
    "held": (_held, _held_array),
    "held_ns": (_held_ns, _held_ns_array),
}
SCALAR_PRIMITIVES = {name: pair[0] for name, pair in PRIMITIVES.items()}
ARRAY_PRIMITIVES = {name: pair[1] for name, pair in PRIMITIVES.items()}


# ---------------------------------------------------------------- formulas
@dataclass(frozen=True, eq=False)
class Formula:
    """A torque [N m] as a Python expression in ``t``, ``angle``, ``speed``.

    Attributes
    ----------
    expression : the text, e.g. ``"mean + amplitude * sin(omega * t + phase)"``.
    constants : values of the other names in the text: floats (written in as
        exact literals), arrays/tuples (bound by name; lists for the scalar
        forms) and torque profiles (bound as a call ``name(t, angle, speed)``).
    """

    expression: str
    constants: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        tree = ast.parse(self.expression, mode="eval")
        names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
        bound = {n.target.id for n in ast.walk(tree) if isinstance(n, ast.NamedExpr)}
        unknown = names - set(ARGUMENTS) - set(PRIMITIVES) - set(self.constants) - bound
        if unknown:
            raise ValueError(f"formula {self.expression!r}: unknown name(s) {', '.join(sorted(unknown))}")
        object.__setattr__(self, "_tree", tree)
        object.__setattr__(self, "_bound", frozenset(bound))

    def reads(self, argument: str) -> bool:
        """True when the torque depends on ``argument`` (``t``, ``angle`` or ``speed``); cached per formula (immutable)."""
        cache = self.__dict__.setdefault("_reads_cache", {})
        if argument not in cache:
            cache[argument] = self._reads(argument)
        return cache[argument]

    def _reads(self, argument: str) -> bool:
        if any(isinstance(n, ast.Name) and n.id == argument for n in ast.walk(self._tree)):
            return True
        parts = [v for v in self.constants.values() if _is_profile(v)]
        flag = {"angle": "uses_angle", "speed": "state_dependent"}.get(argument)
        return flag is not None and any(getattr(p, flag) for p in parts) or (argument == "t" and bool(parts))

    def prefixed(self, prefix: str) -> "Formula":
        """The same formula with its constants and ``:=`` names prefixed (to nest it in another)."""
        rename = {name: prefix + name for name in (*self.constants, *self._bound)}
        tree = _Rename(rename).visit(_copy(self._tree))
        return Formula(ast.unparse(tree), {prefix + k: v for k, v in self.constants.items()})

    def key(self) -> tuple:
        """Hashable identity of the formula (text and constant values), for caches."""
        return (self.expression, tuple((k, _hashable(v)) for k, v in sorted(self.constants.items())))


def _hashable(value):
    if isinstance(value, np.ndarray):
        return ("array", value.dtype.str, value.shape, value.tobytes())
    if isinstance(value, (list, tuple)):
        return tuple(_hashable(v) for v in value)
    if isinstance(value, float) or isinstance(value, int):
        return value
    return ("object", id(value), value)  # a profile: held alive by the key itself


def _copy(tree):
    return ast.parse(ast.unparse(tree), mode="eval")


class _Rename(ast.NodeTransformer):
    """Replace names: by another name (str) or by an expression (ast node)."""

    def __init__(self, mapping: Mapping[str, Any]):
        self.mapping = mapping

    def visit_Name(self, node):
        new = self.mapping.get(node.id)
        if new is None:
            return node
        if isinstance(new, str):
            return ast.copy_location(ast.Name(new, node.ctx), node)
        return ast.copy_location(new, node)


def _literal(value: float) -> ast.expr:
    """Exact literal of a float (a negative one as -literal: same value, parenthesised by precedence)."""
    value = float(value)
    if math.copysign(1.0, value) < 0:
        return ast.UnaryOp(ast.USub(), ast.Constant(-value))
    return ast.Constant(value)


def render(
    formula: Formula, t: str = "t", angle: str = "angle", speed: str = "speed", prefix: str = "", array: bool = False
) -> tuple[str, dict]:
    """Source of ``formula`` with the arguments replaced by the expressions given, and its bindings.

    Floats become exact literals; the other constants and the ``:=`` names get
    ``prefix`` (two formulas inlined into one loop do not collide). Returns
    ``(source, bindings)``: the names the source needs besides the primitives.
    ``array=True``: the numpy form (see the module docstring). Memoized per formula.
    """
    memo = formula.__dict__.setdefault("_renders", {})
    key = (t, angle, speed, prefix, array)
    if key not in memo:
        memo[key] = _render(formula, t, angle, speed, prefix, array)
    source, bindings = memo[key]
    return source, dict(bindings)


def _render(formula: Formula, t: str, angle: str, speed: str, prefix: str, array: bool) -> tuple[str, dict]:
    mapping: dict[str, Any] = {name: ast.parse(value, mode="eval").body for name, value in zip(ARGUMENTS, (t, angle, speed))}
    bindings = {}
    for name, value in formula.constants.items():
        if isinstance(value, (float, int)) and not isinstance(value, bool):
            mapping[name] = _literal(value)
        else:
            mapping[name] = prefix + name
            bindings[prefix + name] = _bind(value, array)
    for name in formula._bound:
        mapping[name] = prefix + name
    tree = _Rename(mapping).visit(_copy(formula._tree))
    if array:
        tree = _ToArray().visit(tree)
    return ast.unparse(ast.fix_missing_locations(tree)), bindings


def _is_profile(value) -> bool:
    """A torque profile bound as a constant (a schedule's part): anything with ``torque`` and ``scalar_torque``."""
    return callable(getattr(value, "scalar_torque", None)) and callable(getattr(value, "torque", None))


def _bind(value, array: bool):
    if _is_profile(value):  # its own forms
        return value.torque if array else value.scalar_torque()
    if array:
        return np.asarray(value)
    return np.asarray(value).tolist() if isinstance(value, np.ndarray) else value


class _ToArray(ast.NodeTransformer):
    """Scalar syntax to numpy syntax: conditionals to where(), boolean operators to &/|."""

    def visit_IfExp(self, node):
        self.generic_visit(node)
        return ast.Call(ast.Name("where", ast.Load()), [node.test, node.body, node.orelse], [])

    def visit_BoolOp(self, node):
        self.generic_visit(node)
        op = ast.BitAnd() if isinstance(node.op, ast.And) else ast.BitOr()
        out = node.values[0]
        for value in node.values[1:]:
            out = ast.BinOp(out, op, value)
        return out

    def visit_Compare(self, node):
        self.generic_visit(node)
        if len(node.ops) == 1:
            return node
        left, parts = node.left, []
        for op, right in zip(node.ops, node.comparators):
            parts.append(ast.Compare(left, [op], [right]))
            left = right
        out = parts[0]
        for part in parts[1:]:
            out = ast.BinOp(out, ast.BitAnd(), part)
        return out


# ---------------------------------------------------------------- compiled forms
def compile_source(source: str, label: str, namespace: dict) -> dict:
    """``exec`` generated ``source`` in ``namespace``, registered with linecache under ``<label hash>``.

    Tracebacks and debuggers then show the generated lines. Returns the namespace.
    """
    digest = hashlib.sha1(source.encode()).hexdigest()[:10]
    filename = f"<{label} {digest}>"
    # mtime None: linecache.checkcache keeps the entry (there is no file to compare against)
    linecache.cache[filename] = (len(source), None, source.splitlines(True), filename)
    exec(compile(source, filename, "exec"), namespace)
    return namespace


def scalar_function(formula: Formula, label: str = "torque") -> Callable[[float, float, float], float]:
    """The closure ``f(t, angle, speed) -> float`` compiled from the formula's text."""
    body, bindings = render(formula)
    source = f"def torque(t, angle, speed):\n    return {body}\n"
    namespace = compile_source(source, f"{label} formula", {**SCALAR_PRIMITIVES, **bindings})
    fn = namespace["torque"]
    fn.__source__ = source
    return fn


def array_function(formula: Formula, label: str = "torque") -> Callable:
    """``f(t, angle, speed) -> ndarray`` evaluating the formula on broadcast numpy arrays."""
    body, bindings = render(formula, array=True)
    source = f"def torque(t, angle, speed):\n    return {body}\n"
    namespace = compile_source(source, f"{label} array formula", {**ARRAY_PRIMITIVES, "where": np.where, **bindings})
    return namespace["torque"]

"""A fixed-step method as data (:class:`StageScheme`) and the three ways it is run.

Every fixed-step method of the package on ``x' = A x + B u(t, x)`` is a
sequence of affine maps between torque samples (A is constant, so stage
sums collapse into fixed matrices). A method states that scheme once
(:meth:`~belt_drive_ros.core.integrators.FixedStepIntegrator.stage_scheme`);
this module derives from it

* :func:`step` -- one step on numpy arrays (the integrator protocol),
* :func:`linear_step` -- the one-step map ``x+ = Phi x + sum_j G_j u(t + c_j h)``
  for a torque of time only (vectorized open-loop runs, stability), and
* :func:`compile_scalar_loop` -- a generated Python loop on plain floats with
  the matrices as literals and the torque formulas inlined (the fast path).
"""

from __future__ import annotations

import linecache
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .errors import IntegratorError
from .formula import SCALAR_PRIMITIVES, compile_source, render

Inputs = Callable[[float, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class StageScheme:
    """A fixed-step method on x' = A x + B u(t, x) as affine maps between torque samples.

    With the stage torques ``U_i = u(t + nodes[i] h, X_i)`` (m values each)::

        X_i = stages[i] @ [x, U_0, ..., U_{i-1}]      (None: X_i = x)
        x+  = final @ [x, U_0, ..., U_{s-1}]          (final_base = j: [X_j, U_0, ...])

    Every method here has this form because A is constant: the Runge-Kutta
    stage sums collapse into fixed matrices, the exponential methods are
    already written so. ``implicit = (tol, max_iter)`` marks a method whose
    last stage is evaluated at x+ itself (the trapezoidal rule), solved by
    fixed-point iteration on U_{s-1} from the guess U_{s-2}, to ``tol``
    relative, at most ``max_iter`` sweeps. ``final_base = j`` starts the last
    map from stage j's state instead of x (etd2: x+ = a + G1 (U_1 - U_0), 16
    products instead of 32).
    """

    nodes: tuple
    stages: tuple
    final: np.ndarray
    implicit: tuple | None = None
    final_base: int | None = None


@dataclass(frozen=True)
class LinearStep:
    """One step of a method on x' = A x + B u(t): x+ = Phi x + sum_j gains[j] u(t + nodes[j] h)."""

    Phi: np.ndarray
    nodes: tuple
    gains: tuple


@dataclass(frozen=True)
class Guard:
    """A stop rule for a compiled loop: it stops after the first step whose end state has ``g(x) > 0``.

    ``g(x) = f(row . x) - (bound - quad (speed . x)^2)`` with ``f = abs`` when
    ``absolute`` else the identity. The slipping belt's switching functions
    have this form (``|Q| - Q_max(omega_M)`` with ``Q`` linear in the state and
    ``Q_max = 2 (F_0 - m' v^2) tanh(mu_eff beta / 2)``; ``-sigma s'`` with ``s'``
    linear), so a stick or slip phase runs in the compiled loop and only the
    step in which the switching function turns positive is redone with event
    location. The check costs a few multiply-adds per step.
    """

    row: tuple
    bound: float = 0.0
    absolute: bool = False
    speed: tuple | None = None
    quad: float = 0.0

    def value(self, x) -> float:
        """g(x) for one state (plain floats)."""
        v = sum(c * float(xi) for c, xi in zip(self.row, x))
        v = abs(v) if self.absolute else v
        bound = self.bound
        if self.speed is not None and self.quad:
            w = sum(c * float(xi) for c, xi in zip(self.speed, x))
            bound -= self.quad * w * w
        return v - bound

    def source(self, names) -> str:
        """The condition ``g(x) > 0`` as Python source on the state variables ``names``."""
        lhs = _linear_expression(self.row, names)
        lhs = f"abs({lhs})" if self.absolute else f"({lhs})"
        rhs = repr(float(self.bound))
        if self.speed is not None and self.quad:
            w = _linear_expression(self.speed, names)
            rhs = f"({rhs} - {float(self.quad)!r} * ({w}) * ({w}))"
        return f"{lhs} > {rhs}"


def not_converged(name: str, t: float, max_iter: int, dt: float) -> IntegratorError:
    """The error of an implicit stage whose fixed-point iteration failed (one message for every path)."""
    return IntegratorError(
        f"{name}: fixed-point iteration for the state-dependent torque did not converge "
        f"at t={t:.6g} s in {max_iter} sweeps; reduce dt (now {dt:g} s)"
    )


def affine(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``M @ v`` summed column by column from the left: ``((M[:, 0] v[0] + M[:, 1] v[1]) + ...)``.

    The order of the compiled loop's unrolled expressions
    (:func:`compile_scalar_loop`) and of the ensemble's per-variant sums
    (:mod:`~belt_drive_ros.core.ensemble`), so a step taken here, in the
    compiled loop or in an ensemble gives the same floats (a BLAS product may
    sum in another order). ``add.accumulate`` is sequential by definition.
    ``v`` may be a matrix (k, c): each column as a vector.
    """
    if np.ndim(v) == 2:
        return np.cumsum(M[:, :, None] * v[None, :, :], axis=1)[:, -1, :]
    return np.cumsum(M * v, axis=-1)[..., -1]


def step(scheme: StageScheme, dt: float, t: float, x: np.ndarray, inputs: Inputs, name: str = "method") -> np.ndarray:
    """One step of ``scheme`` (step ``dt`` [s]) from state ``x`` at time ``t`` [s] with torques ``inputs(t, x)`` [N m].

    Sums run column by column from the left (:func:`affine`), as in the compiled loop.
    """
    s = len(scheme.nodes)
    explicit = s - 1 if scheme.implicit else s
    states, U = [], []
    for i in range(explicit):
        M = scheme.stages[i]
        xi = x if M is None else affine(M, np.concatenate([x, *U]))
        states.append(xi)
        U.append(np.asarray(inputs(t + scheme.nodes[i] * dt if scheme.nodes[i] else t, xi), dtype=float))
    base = x if scheme.final_base is None else states[scheme.final_base]
    if not scheme.implicit:
        return affine(scheme.final, np.concatenate([base, *U]))
    tol, max_iter = scheme.implicit
    known = np.concatenate([base, *U])
    free = affine(scheme.final[:, : known.size], known)  # x+ without the implicit stage
    gain = scheme.final[:, known.size :]
    t_last = t + scheme.nodes[-1] * dt
    guess = U[-1]  # first guess: the previous stage's torque
    for _ in range(max_iter):
        u_new = np.asarray(inputs(t_last, free + affine(gain, guess)), dtype=float)
        if np.all(np.abs(u_new - guess) <= tol * (1.0 + np.abs(u_new))):
            return free + affine(gain, u_new)
        guess = u_new
    raise not_converged(name, t, max_iter, dt)


def linear_step(scheme: StageScheme, n: int) -> LinearStep:
    """The scheme's one-step map for a torque of time only: every U_i = u(t + c_i h) is then an input.

    ``x+ = final @ [base, U_0, ...]`` with ``base = x`` or stage j's affine
    state; samples at equal nodes merge, zero gains drop.
    """
    s = len(scheme.nodes)
    m = (scheme.final.shape[1] - n) // s
    full = np.zeros((n, n + m * s), dtype=scheme.final.dtype)
    full[:, n:] += scheme.final[:, n:]
    j = scheme.final_base
    if j is None or scheme.stages[j] is None:
        full[:, :n] += scheme.final[:, :n]
    else:
        full[:, : scheme.stages[j].shape[1]] += scheme.final[:, :n] @ scheme.stages[j]
    merged: dict[float, np.ndarray] = {}
    for i, c in enumerate(scheme.nodes):
        G = full[:, n + m * i : n + m * (i + 1)]
        merged[float(c)] = merged[float(c)] + G if float(c) in merged else G
    nodes = tuple(c for c in sorted(merged) if np.any(merged[c]))
    return LinearStep(full[:, :n].copy(), nodes, tuple(merged[c].copy() for c in nodes))


# ------------------------------------------------- compiled scalar loops
def _linear_expression(coefficients, names) -> str:
    """Source of sum_j c_j * names[j], dropping zero terms (floats printed exactly by repr)."""
    terms = []
    for c, v in zip(coefficients, names):
        c = float(c)
        if c == 0.0:
            continue
        terms.append(v if c == 1.0 else f"-{v}" if c == -1.0 else f"{c!r} * {v}")
    return " + ".join(terms) if terms else "0.0"


def compile_scalar_loop(
    scheme: StageScheme,
    wheel_map: np.ndarray,
    dt: float,
    name: str = "method",
    uses_angle: tuple = (True, True),
    formulas: tuple = (None, None),
    guard: Guard | None = None,
    extra: tuple = (),
) -> Callable:
    """Generate and compile a Python loop that runs ``scheme`` on plain floats.

    Per step, numpy spends ~1 us per call on a 4-vector, more than the
    arithmetic itself; a closed-loop run of the belt model makes ~10 such
    calls per step. The loop below unrolls every matrix-vector product into
    float arithmetic with the matrix entries as literals (zeros dropped) and
    inlines the torque profiles' formulas (:class:`~belt_drive_ros.core.formula.Formula`):
    10-20x faster than looping over :meth:`FixedStepIntegrator.step`
    on the shipped scenes (docs/performance.md), and equal to it to rounding
    (same maths, another summation order).

    Parameters
    ----------
    scheme : the method's :class:`StageScheme`.
    wheel_map : (4, n) matrix W with ``[phi_M, omega_M, phi_3, omega_3] = W x``;
        the drive torque sees (phi_M, omega_M), the load (phi_3, omega_3).
    dt : step h [s] (stage times are ``t + c_i h``, as in :meth:`step`).
    uses_angle : (drive, load): False when that torque ignores its angle
        argument (:attr:`~belt_drive_ros.core.sources.TorqueProfile.uses_angle`);
        then only the speeds of the intermediate stages are computed (the
        stages exist only to feed the torques) and the angle passed is 0.0.
    formulas : (drive, load): each torque's :class:`~belt_drive_ros.core.formula.Formula`
        (:meth:`~belt_drive_ros.core.sources.TorqueProfile.formula`), inlined
        instead of a call (a call costs about as much as 5 multiply-adds): the
        same text the profile's scalar closure is compiled from, so bitwise
        equal to it; or None to call ``drive``/``load``.
    guard : a :class:`Guard`: the loop also stops (a shorter list, the last
        state the one at which ``g > 0``) after the first step that ends with
        the guard positive.
    extra : inputs after the two torques that depend on the drive speed
        omega_M only, each ``f(speed, name) -> source`` of its value at the
        speed expression ``speed`` (``name``: a free variable name it may
        assign): the slipping belt's force ``sigma Q_max(omega_M)`` while a belt
        with mass slides. Not for implicit schemes.

    Returns
    -------
    ``loop(times, x, drive, load, limit) -> list`` integrating ``len(times) - 1``
    steps from state ``x`` (tuple) at ``times[0]`` with scalar torque
    functions ``drive(t, angle, speed)`` and ``load(...)``; returns the states
    after each step, flattened. Every 64 steps it checks that the state is
    finite and the speeds (second half of x) within ``limit``, and stops early
    (a shorter list) if not, for the caller to report. The generated source
    is the function's ``__source__`` attribute and is registered with
    :mod:`linecache`: tracebacks and debuggers show its lines.
    """
    W = np.asarray(wheel_map, dtype=float)
    bindings: dict = {}
    n = W.shape[1]
    s = len(scheme.nodes)
    m = (scheme.final.shape[1] - n) // s
    if W.shape[0] != 4 or m != 2 + len(extra) or scheme.final.shape != (n, n + m * s) or (extra and scheme.implicit):
        raise IntegratorError(f"{name}: scalar loop needs 4 wheel coordinates, 2 torques and its extra inputs (explicit)")
    xs = [f"x{r}" for r in range(n)]
    lines = [
        "def loop(times, x, drive, load, limit, abs=abs):",
        f'    """{name}: {n} states, {s} torque sample(s) per step (generated by compile_scalar_loop)."""',
        f"    {', '.join(xs)}, = x",
        "    out = []",
        "    extend = out.extend",
        "    for k in range(len(times) - 1):",
        "        t = times[k]",
    ]

    # Stages whose wheel coordinates share their part in x (etd4: a and b are both E2 x + P U) sum that part once:
    # the prefix is the same left-to-right sum the whole expression starts with, so the values are bit for bit the same.
    needed = [r for q in range(2) for r in ((2 * q, 2 * q + 1) if uses_angle[q] else (2 * q + 1,))]
    uses: dict = {}
    for i in range(s - 1 if scheme.implicit else s):
        if scheme.stages[i] is not None and scheme.final_base != i:
            rows = W @ scheme.stages[i]
            for r in needed:
                if np.any(rows[r, :n]) and np.any(rows[r, n:]):
                    key = (r, rows[r, :n].tobytes())
                    uses[key] = uses.get(key, 0) + 1
    prefixes = {key: f"p{j}" for j, key in enumerate(k for k, c in uses.items() if c > 1)}
    defined: set = set()
    times_at: dict = {}

    def wheel_expression(lines, wheel_rows, r, inputs):
        """Source of wheel coordinate ``wheel_rows[r] @ inputs``, its x part named once when stages share it."""
        key = (r, np.asarray(wheel_rows[r, :n]).tobytes()) if inputs[:n] == xs else None
        if key not in prefixes:
            return _linear_expression(wheel_rows[r], inputs)
        if key not in defined:
            lines.append(f"        {prefixes[key]} = {_linear_expression(wheel_rows[r, :n], xs)}")
            defined.add(key)
        return f"{prefixes[key]} + {_linear_expression(wheel_rows[r, n:], inputs[n:])}"

    def torques(i, wheel_rows, inputs, at):
        """Lines computing u{i}_0, u{i}_1 from the wheel coordinates ``wheel_rows @ inputs``."""
        if at == "t":
            lines = []
        elif at in times_at:  # stages at one time (etd4's two at t + h/2): one sum
            lines, at = [], times_at[at]
        else:
            lines = [f"        t{i} = {at}"]
            times_at[at] = f"t{i}"
            at = f"t{i}"
        speed = None
        for q, fn in enumerate(("drive", "load")):
            args = []
            for role, row in (("a", 2 * q), ("w", 2 * q + 1)):
                if role == "a" and not uses_angle[q]:
                    args.append("0.0")
                    continue
                expr = wheel_expression(lines, wheel_rows, row, inputs)
                if formulas[q] is not None and not expr.isidentifier():  # inlined: named once, used maybe twice
                    lines.append(f"        {role}{i}_{q} = {expr}")
                    expr = f"{role}{i}_{q}"
                args.append(expr)
            if q == 0:
                speed = args[1]
            if formulas[q] is None:
                call = f"{fn}({at}, {args[0]}, {args[1]})"
            else:
                call, names = render(formulas[q], at, args[0], args[1], prefix=f"{fn[0]}_")
                bindings.update(names)
            lines.append(f"        u{i}_{q} = {call}")
        lines += [f"        u{i}_{2 + e} = {source(speed, f'v{i}_{e}')}" for e, source in enumerate(extra)]
        return lines

    def at(c):
        return "t" if c == 0.0 else f"t + {float(c * dt)!r}"

    n_explicit = s - 1 if scheme.implicit else s
    for i in range(n_explicit):
        lines.append(f"        # stage {i}: torques at t + {scheme.nodes[i]:g} h")
        if scheme.stages[i] is None:
            lines += torques(i, W, xs, at(scheme.nodes[i]))
        elif scheme.final_base == i:  # the whole stage state is needed again at the end of the step
            state = [f"s{i}_{r}" for r in range(n)]
            inputs = xs + [f"u{j}_{q}" for j in range(i) for q in range(m)]
            lines += [f"        {state[r]} = {_linear_expression(scheme.stages[i][r], inputs)}" for r in range(n)]
            lines += torques(i, W, state, at(scheme.nodes[i]))
        else:  # only its wheel coordinates: W @ stage map, straight from x and the earlier torques
            inputs = xs + [f"u{j}_{q}" for j in range(i) for q in range(m)]
            lines += torques(i, W @ scheme.stages[i], inputs, at(scheme.nodes[i]))
    known = xs + [f"u{j}_{q}" for j in range(n_explicit) for q in range(m)]
    if scheme.implicit:
        tol, max_iter = scheme.implicit
        last = s - 1
        free = [f"f{r}" for r in range(n)]
        guess = [f"u{last}_{q}" for q in range(m)]
        lines += [f"        # free response Phi x + G u_0, then u_{last} = u(t + h, x+) by fixed point"]
        lines += [f"        {free[r]} = {_linear_expression(scheme.final[r, : len(known)], known)}" for r in range(n)]
        lines += [  # first guess: the torque at the step's start, as Trapezoidal.step
            f"        g0, g1 = u{last - 1}_0, u{last - 1}_1",
            f"        for _ in range({int(max_iter)}):",
        ]
        state = [f"y{r}" for r in range(n)]
        gain = scheme.final[:, len(known) :]
        lines += [f"            {state[r]} = {free[r]} + {_linear_expression(gain[r], ['g0', 'g1'])}" for r in range(n)]
        lines += ["    " + line for line in torques(last, W, state, at(scheme.nodes[last]))]
        lines += [
            f"            if abs({guess[0]} - g0) <= {tol!r} * (1.0 + abs({guess[0]})) and "
            f"abs({guess[1]} - g1) <= {tol!r} * (1.0 + abs({guess[1]})):",
            "                break",
            f"            g0, g1 = {guess[0]}, {guess[1]}",
            "        else:",
            "            _not_converged(t)",
        ]
        lines += [f"        x{r} = {free[r]} + {_linear_expression(gain[r], guess)}" for r in range(n)]
    else:
        base = "x"
        if scheme.final_base is not None and scheme.stages[scheme.final_base] is not None:
            base = f"s{scheme.final_base}"
            known = [f"{base}_{r}" for r in range(n)] + known[n:]
        lines.append(f"        # end of step: x+ = final @ [{base}, U_0, ...]")
        lines.append(f"        {', '.join(xs)} = " + ", ".join(_linear_expression(scheme.final[r], known) for r in range(n)))
    half = n // 2
    finite = " and ".join([f"abs(x{r}) <= limit" for r in range(half, n)] + [f"x{r} - x{r} == 0.0" for r in range(half)])
    lines += [
        f"        extend(({', '.join(xs)},))",
        *([f"        if {guard.source(xs)}:", "            break"] if guard is not None else []),
        f"        if k & 63 == 63 and not ({finite}):",
        "            break",
        "    return out",
    ]
    source = "\n".join(lines) + "\n"
    key = (source, name, dt, tuple(None if f is None else f.key() for f in formulas))  # extra inputs: in the source
    if key not in _COMPILED_LOOPS:
        if len(_COMPILED_LOOPS) >= 256:  # sweeps over many steps: keep the cache small
            for old in _COMPILED_LOOPS.values():
                linecache.cache.pop(old.__code__.co_filename, None)
            _COMPILED_LOOPS.clear()
        _COMPILED_LOOPS[key] = _compile_loop(source, scheme, dt, name, bindings)
    return _COMPILED_LOOPS[key]


#: generated loops by (source, method name, dt, formulas): a Simulator per run need not recompile (~0.5 ms).
_COMPILED_LOOPS: dict = {}


def _compile_loop(source: str, scheme: StageScheme, dt: float, name: str, bindings: dict) -> Callable:
    def _not_converged(t):
        raise not_converged(name, t, scheme.implicit[1], dt)

    namespace = {**SCALAR_PRIMITIVES, **bindings, "_not_converged": _not_converged}
    loop = compile_source(source, f"{name} scalar loop", namespace)["loop"]
    loop.__source__ = source
    return loop

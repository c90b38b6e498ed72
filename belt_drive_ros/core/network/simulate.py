"""A belt network's run (:func:`simulate`): the tier, the method, the guards, the compiled loop.

Tiers: ``flexible`` (every pulley and the tensioner arm), ``rigid`` (the belt inextensible: one DOF, the
driver's angle), ``slipping`` (stick or slip at every pulley, :mod:`.slip`), ``auto`` (:func:`choose_tier`'s
linear tier, then slipping when a pulley reaches its capstan limit in its run). The linear tiers step in the
kernel's linear loop (:class:`NetworkLoop`) with any fixed-step method; a method that would grow a mode at
the step is refused before the run (:func:`.model.check_step`), the run's accuracy estimated by step
doubling (:func:`accuracy`).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import replace

import numpy as np

from ..errors import IntegratorError, SceneError, SimulationDivergedError, UnstableStepError, short
from ..identity_cache import built_once
from ..profile_data import CONSTANT, DIVERGED, NOT_CONVERGED
from .model import NetworkModel, NetworkRun, arm_swing, check_step, grid_breakpoints, outputs, piece_of, stack_profiles, step_runs
from .scene import run_steps, warm_scene

TIERS = ("auto", "flexible", "rigid", "slipping")
#: auto: rigid when the belt's lowest mode is at least this many times the fastest excitation
RIGID_MARGIN = 10.0
#: accuracy guard: a run is accurate when its estimated error is at most this part of the peak tension change
ACCURACY = 1e-3
#: speed [rad/s] past which a run counts as diverged
LIMIT = 1.0e5


class NetworkLoop:
    """One tier's (``flexible`` or ``rigid``) matrices and one fixed-step method as the arrays of the kernel's
    linear loop (:func:`~belt_drive_ros.core.kernel.wheel_steps`, one wheel per driven pulley);
    ``loop(times, x, out, lo, hi)`` runs the steps."""

    def __init__(self, model: NetworkModel, tier: str, method: str, dt: float):
        from ..integrators import make_integrator, method_class
        from ..kernel_loop import KernelLoop, scheme_arrays

        scene = model.scene
        self.model, self.tier, self.method, self.dt = model, tier, method, float(dt)
        A, B_all = model.flexible_matrices() if tier == "flexible" else model.rigid_matrices()
        cls = method_class(method)
        if not cls.fixed_step:
            raise SceneError(f"method {method}: a belt network steps with a fixed-step method")
        self.active = [i for i, p in enumerate(scene.pulleys) if p.sign]
        signs = np.array([scene.pulleys[i].sign / scene.pulleys[i].gear for i in self.active])  # a gear train: Q / g
        B = B_all[:, self.active] * signs
        check_step(method, A, B, self.dt)
        scheme = make_integrator(method, A, B, self.dt).scheme
        n, P = A.shape[0], len(self.active)
        uses = np.array([bool(scene.pulleys[i].torque.uses_angle) for i in self.active], dtype=np.int64)
        # W: per active pulley the angle and speed of its drive shaft (the pulley's / gear) from the state; an angle
        # no profile reads is not computed (the kernel passes 0.0)
        W = np.zeros((2 * P, n))
        half = n // 2
        for p, i in enumerate(self.active):
            if tier == "rigid":
                W[2 * p, 0], W[2 * p + 1, 1] = model.ratios[i], model.ratios[i]
            elif i == scene.driver:
                W[2 * p, i], W[2 * p + 1, half + i] = 1.0, 1.0
            else:  # theta_i = rho_i theta_d - l_i
                W[2 * p, scene.driver], W[2 * p, i], W[2 * p + 1, half + i] = model.ratios[i], -1.0, 1.0
            W[2 * p : 2 * p + 2] /= scene.pulleys[i].gear
            if not uses[p]:
                W[2 * p] = 0.0
        if not KernelLoop.usable(scheme):
            raise SceneError(f"method {method}: its step matrices are complex for this network")
        self.A, self.B, self.scheme = A, B, scheme
        self.start, self.pk, self.pp, self.px, self.py = stack_profiles([(scene.pulleys[i].name, scene.pulleys[i].torque)
                                                                         for i in self.active])
        kinds, offsets, S, F, final_base, tol, max_iter = scheme_arrays(scheme, self.dt, W[None], P)
        self.args = (W[None], kinds, offsets, S[0], F, final_base, tol, max_iter, uses)
        self._none = (np.zeros((0, 5)), np.zeros(5 + 2 * n))  # no extra input, no guard

    def __call__(self, times, x, out, lo: float = -math.inf, hi: float = math.inf):
        from ..kernel import wheel_steps

        stacked = (self.pk, self.pp, self.px, self.py)  # both banks of the kernel: every profile from its start row
        return wheel_steps(times, x, out, lo, hi, LIMIT, *self.args, self.start, *stacked, *stacked, *self._none)

    def hold(self, pulley: int, value: float) -> None:
        """Pulley ``pulley``'s profile becomes the constant ``value`` [N m] (its profile's sign convention)."""
        row = self.start[self.active.index(pulley)]
        self.pk[row] = CONSTANT
        self.pp[row, 0] = float(value)

    def piece(self, h: float) -> NetworkLoop:
        """This loop for one step of ``h`` [s] (:func:`~.model.piece_of`)."""
        return piece_of(self, h, lambda h: NetworkLoop(self.model, self.tier, self.method, h), ("start", "pk", "pp", "px", "py"))

    def initial(self) -> np.ndarray:
        """The belt turning at the scene's ``initial_speed``, unstretched."""
        scene = self.model.scene
        if self.tier == "rigid":
            return np.array([0.0, float(scene.initial_speed)])
        m = self.model.M.shape[0]
        x = np.zeros(2 * m)
        x[m : m + len(scene.pulleys)] = self.model.speeds_at(scene.initial_speed)
        return x


# ---------------------------------------------------------------------- runs
def clamp(marks: list, left: list, t0: float, t1: float) -> tuple[float, float]:
    """``(lo, hi)`` [s]: the stage-time clamp of a run of whole steps from ``t0`` to ``t1`` between breakpoints
    (:func:`~.model.grid_breakpoints`' ``marks`` and ``left``): from the latest mark at or before ``t0`` to the
    left limit of the first mark at or after ``t1``."""
    i = bisect.bisect_right(marks, t0) - 1
    j = bisect.bisect_left(marks, t1)
    return (marks[i] if i >= 0 else -math.inf), (left[j] if j < len(marks) else math.inf)


def advance(loop: NetworkLoop, x, out, k0: int, k1: int) -> None:
    """Steps ``k0 .. k1-1`` (times ``k dt``) from state ``x`` at ``k0 dt``; the states after each into ``out[0 .. k1-k0-1]``.

    The one way time advances in a network (a whole run, the node's ticks): one kernel call per run of whole
    steps between torque breakpoints, its stage times clamped into the run's side of them; a step with
    breakpoints strictly inside split there, one call per piece (:func:`~.model.step_runs`).
    """
    dt = loop.dt
    marks, left, inside = grid_breakpoints(loop.model, dt)

    def call(piece, times, start, into):
        lo, hi = clamp(marks, left, times[0], times[-1])
        done, status, t = piece(times, start, into, lo, hi)
        if status == DIVERGED:
            raise SimulationDivergedError(f"{loop.model.scene.name}: the state became non-finite or too fast at "
                                          f"t = {t:.6g} s ({loop.tier} tier, {loop.method} at dt = {dt:g} s)")
        if status == NOT_CONVERGED:
            raise IntegratorError(f"{loop.method}: fixed-point iteration for the state-dependent torque did not "
                                  f"converge at t={t:.6g} s; reduce dt (now {dt:g} s)")

    start = np.array(x, dtype=float)
    grid = [k for k in (round(b / dt) for b in marks) if k * dt in marks]
    for a, e, edges in step_runs(inside, dt, k0, k1, grid):
        if edges is None:
            call(loop, np.arange(a, e + 1) * dt, start, out[a - k0 : e - k0])
        else:
            for p, q in zip(edges[:-1], edges[1:]):
                call(loop.piece(q - p), np.array([p, q]), start, out[a - k0 : a - k0 + 1])
                start = out[a - k0].copy()
        start = out[e - k0 - 1].copy()


def run_loop(loop: NetworkLoop, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """``(times, states)`` of ``steps`` steps from the scene's start."""
    x = loop.initial()
    out = np.empty((steps + 1, x.size))
    out[0] = x
    advance(loop, x, out[1:], 0, steps)
    return np.arange(steps + 1) * loop.dt, out


def rigid_outputs(loop: NetworkLoop, times, states, u=None) -> NetworkRun:
    """Outputs of a rigid run: every pulley at its speed ratio, the span tensions quasi-static (the torques each
    pulley's own equation needs, carried by the belt's static stretch), the arm at the equilibrium those tensions hold
    it at (:func:`~.model.arm_swing`; its speed 0.0: quasi-static).
    ``u`` (N, n): the signed pulley torques applied [N m] (default: the profiles')."""
    model, scene = loop.model, loop.model.scene
    rho, n, m = model.ratios, len(scene.pulleys), model.M.shape[0]
    if u is None:
        u = np.zeros((len(times), n))
        for i in loop.active:
            p = scene.pulleys[i]
            u[:, i] = p.load(times, rho[i] * states[:, 0] if p.torque.uses_angle else 0.0 * times,
                                               rho[i] * states[:, 1])
    A, B = model.rigid_matrices()
    accel = states @ A[1] + u @ B[1]
    J, b = np.diag(model.M)[:n], model.bearing_damping
    load = u - (J * rho) * accel[:, None] - (b * rho) * states[:, 1:2] * rho  # what the belt takes at each pulley
    S = model.__dict__.get("_rigid_map")
    if S is None:
        S = model.__dict__["_rigid_map"] = np.ascontiguousarray(model.rigid_tension_map().T)
    T = scene.belt.installed_tension + load @ S
    full = np.zeros((len(times), 2 * m))
    full[:, :n], full[:, m : m + n] = states[:, :1] * rho, states[:, 1:2] * rho
    if model.arm >= 0:
        full[:, model.arm] = arm_swing(model.rigid_arm_row(), states[:, 0], states[:, 1], u.T)
    return outputs(model, times, full, T)


def network_loop(model: NetworkModel, tier: str, method: str, dt: float) -> NetworkLoop:
    """The model's :class:`NetworkLoop` for ``(tier, method, dt)``, built once per model (read-only arrays;
    :meth:`NetworkLoop.hold` writes into its own copy, so a node builds its own loop)."""
    return built_once(model.__dict__.setdefault("_loops", {}), 8, (), lambda: NetworkLoop(model, tier, method, dt),
                      extra=(tier, method, float(dt)))


def model_of(scene) -> NetworkModel:
    """The scene's :class:`~.model.NetworkModel`, built once per scene object (scenes are frozen)."""
    found = scene.__dict__.get("_network_model")
    if found is None:
        found = NetworkModel.build(scene)
        object.__setattr__(scene, "_network_model", found)
    return found


def _run(model, tier, method, dt, steps, tensions_only=False):
    """The run's :class:`~.model.NetworkRun` (``tensions_only``: its span tensions (N+1, n) [N] only)."""
    loop = network_loop(model, tier, method, dt)
    times, states = run_loop(loop, steps)
    if tier == "rigid":
        run = rigid_outputs(loop, times, states)
        return run.tension if tensions_only else run
    T = model.run_tensions(states)
    return T if tensions_only else outputs(model, times, model.to_absolute(states), T)


def accuracy(model, tier, method, dt, steps, run) -> str:
    """Step doubling: the run against the same run at 2 dt (at dt / 2 where 2 dt is unstable, or where the run has
    fewer than 4 steps: a run of one or two steps at 2 dt says nothing); Richardson's estimate of the run's error on
    the span tensions, ``|T_h - T_2h| / (2^p - 1)`` (p the method's order)."""
    from ..integrators import method_class

    order = method_class(method).order
    if not order or steps < 1:
        return ""
    T0 = model.scene.belt.installed_tension

    def halved() -> float:
        fine = _run(model, tier, method, 0.5 * dt, 2 * steps, tensions_only=True)
        return float(np.max(np.abs(run.tension - fine[::2]))) * 2**order / (2**order - 1)

    if steps < 4:
        err = halved()
    else:
        try:
            coarse = _run(model, tier, method, 2.0 * dt, steps // 2, tensions_only=True)
            err = float(np.max(np.abs(run.tension[: 2 * (steps // 2) + 1 : 2] - coarse))) / (2**order - 1)
        except UnstableStepError:
            err = halved()
    # relative to the peak change, and at least to a millionth of the installed tension: an idle run's change is
    # rounding noise (3e-7 N), against which a 3.5e-9 N error read 1 % and INACCURATE
    scale = max(float(np.max(np.abs(run.tension - T0))), 1e-6 * T0)
    verdict = "accurate" if err <= ACCURACY * scale else "INACCURATE"
    text = f"{verdict}: estimated span tension error {err:.3g} N ({err / scale:.2g} of the peak change, step doubling)"
    if verdict != "accurate":
        text += f"; dt <= {dt * (ACCURACY * scale / err) ** (1.0 / order):.3g} s should be accurate"
    return text


def choose_tier(model: NetworkModel) -> tuple[str, str]:
    """``(tier, reason)`` of ``auto`` among the linear tiers: rigid when the belt's lowest mode is at least
    :data:`RIGID_MARGIN` times every excitation frequency of the profiles (at the pulleys' speeds), else flexible."""
    from .model import undamped_frequencies

    scene = model.scene
    lowest = model.__dict__.get("_lowest")
    if lowest is None:
        lowest = model.__dict__["_lowest"] = float(undamped_frequencies(model)[0])
    top, who = 0.0, None
    speed = max(abs(scene.initial_speed), abs(scene.operating_speed))
    rho = model.ratios
    for i, p in enumerate(scene.pulleys):
        if p.sign:
            for f, what in p.torque.excitation_frequencies(rho[i] * speed / p.gear):
                if f > top:
                    top, who = f, (p.name, what)
    if who is None or lowest >= RIGID_MARGIN * top:
        why = "nothing excites it" if who is None else f"{who[0]}'s {who[1]} reaches {top:.3g} Hz"
        return "rigid", f"rigid: the belt's lowest mode ({lowest:.3g} Hz) lies above {RIGID_MARGIN:g}x the excitation ({why})"
    return "flexible", (f"flexible: {who[0]}'s {who[1]} reaches {top:.3g} Hz, within {RIGID_MARGIN:g}x of the belt's "
                        f"lowest mode ({lowest:.3g} Hz)")


def _linear(scene, net: NetworkModel, model: str, method: str, dt: float, steps: int) -> tuple:
    """``(tier, reason, run, why)``: the linear tier ``model`` names (``auto``: :func:`choose_tier`'s) and its run;
    ``why``: ``auto``'s reason to go on to the slipping tier (a pulley reaches its capstan limit in that run) or None."""
    tier, reason = choose_tier(net) if model == "auto" else (model, f"{model}: asked for")
    run = _run(net, tier, method, dt, steps)
    onset = run.capstan_onset(scene) if model == "auto" else None
    why = None if onset is None else (f"slipping: {onset[0]} reaches the capstan limit at t = {onset[1]:.6g} s "
                                      f"(in the {tier} tier's run)")
    return tier, reason, run, why


def auto_tier(scene, method: str, dt: float) -> tuple[str, str]:
    """``(tier, reason)`` of ``model: auto`` for the scene's run (its duration, ``method``, ``dt`` [s]): the linear tier
    :func:`choose_tier` picks, or ``slipping`` when a pulley reaches its capstan limit in that tier's run (the
    node and the re-simulation of its recordings step the tier the offline run steps)."""
    steps = max(1, int(round(scene.duration / dt)))
    tier, reason, _, why = _linear(scene, model_of(scene), "auto", method, dt, steps)
    return ("slipping", why) if why else (tier, reason)


def run_slipping(model: NetworkModel, duration: float, dt: float, method: str | None = None) -> NetworkRun:
    """The slipping tier's run (:func:`.slip.simulate_slipping`) from the scene's start, every pulley sticking."""
    from .slip import simulate_slipping

    return simulate_slipping(model, model.scene, duration, dt, method)


def simulate(scene, duration: float | None = None, dt: float | None = None, method: str | None = None,
             model: str = "auto", check_accuracy: bool = True) -> NetworkRun:
    """Run a belt network scene from the belt turning at ``initial_speed`` unstretched, on tier ``model``
    (:data:`TIERS`) with a fixed-step ``method`` (default the scene's). The slipping tier steps the exact flow of
    each mode only: a ``method`` asked for by name that it cannot step is refused, the scene's own replaced by
    ``exact``. The run carries ``tier``, ``reason``, ``method`` and ``accuracy`` (a linear tier's step doubling).
    """
    if not isinstance(model, str) or model not in TIERS:
        raise SceneError(f"model: must be one of {', '.join(TIERS)} for a belt network, got {short(model)}")
    duration, dt, steps = run_steps(scene, duration, dt)  # (checks the scene's type first)
    net = model_of(scene)
    name = method or scene.method
    if model == "slipping":
        return replace(run_slipping(net, duration, dt, method), tier="slipping", reason="slipping: asked for",
                       method=method or "exact")
    tier, reason, run, why = _linear(scene, net, model, name, dt, steps)
    if why is not None:
        from .slip import METHODS

        if method is not None and method not in METHODS:  # asked for by name: never swapped for another silently
            raise SceneError(f"method {method}: the run slips ({why.removeprefix('slipping: ')}) and the slipping "
                             "tier steps the exact flow of each stick/slip mode only: use method exact, or model "
                             "flexible for the linear run (not valid past that time)")
        return replace(run_slipping(net, duration, dt), tier="slipping", reason=why, method="exact")
    verdict = accuracy(net, tier, name, dt, steps, run) if check_accuracy else ""
    return replace(run, tier=tier, reason=reason, method=name, accuracy=verdict)


def warm() -> None:
    """Compile (or load from the disk cache) the network loop: a two-pulley belt, one step of each tier."""
    simulate(warm_scene(), model="flexible", check_accuracy=False)

"""The slipping tier of a belt network: stick or slip at every pulley, at the capstan limit (derived in
``docs/model.md``, "Slip at every pulley of a network")::

    |T_i - T_{i-1}| <= f_i (T_i + T_{i-1} - 2 w),    f_i = tanh(mu_i beta_i / 2),  w = m' v^2
    delta_j = (r_{j+1} theta_{j+1} + s_{j+1}) - (r_j theta_j + s_j) + g_j theta_a

(``T_i`` [N] the span leaving pulley i, ``v`` [m/s] the belt speed at the driver, ``s_i`` [m] the belt's slip ahead
of pulley i's surface). State ``x = [q, q', s]``; a mode names per pulley ``sig_i``: 0 sticking (``s_i' = 0``) or
the direction ``+-1`` of ``s_i'`` while it slides, where ``T_i - T_{i-1} = sig_i f_i (T_i + T_{i-1} - 2 w)`` (with
``T_j = T_0 + k_j delta_j + c_j delta_j'``: linear in the sliding pulleys' ``s'``; undamped spans: in ``s``, put
back onto it after each step). Every mode is ``x' = A x + B u + c (T_0 - w)``, a step its exact flow with the
torques and ``w`` held; switches (stick -> slip at the limit, slip -> stick where ``s_i'`` crosses zero if the
stick mode's friction stays inside it) are located on that flow (:mod:`.slip_kernel`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SceneError, SimulationDivergedError
from ..profile_data import CONSTANT, WIDTH
from .model import NetworkModel, NetworkRun, grid_breakpoints, outputs, piece_of, stack_profiles, step_runs
from .scene import run_steps

#: modes kept with their step exponentials per run
CACHE_SLOTS = 8
#: event kind by (sliding before, sliding after)
_KINDS = {(False, True): "onset", (True, False): "restick", (True, True): "reversal"}
#: the one method of the slipping tier (zero-order hold: the exact flow of each mode)
METHODS = ("exact", "zoh")


@dataclass(frozen=True)
class SlipEvent:
    """A mode switch: time [s], pulley name, ``"onset"``, ``"restick"`` or ``"reversal"`` (the slip speed crossed
    zero where sticking would leave the limit at once: it slides on the other way), slip direction (+1: the belt
    runs ahead of the pulley surface, -1: behind it; the direction it had for a re-stick)."""

    time: float
    pulley: str
    kind: str
    direction: int


@dataclass(frozen=True)
class SlipNetworkRun(NetworkRun):
    """A slipping-tier run: :class:`~.model.NetworkRun` (states ``[q, q']``) plus, per sample and pulley,
    ``slip_state`` (0 stick, +-1 slip direction), ``slip_speed`` s' [m/s], ``slip_distance`` s [m],
    ``friction_work`` (the friction loss so far [J]), ``input_work`` (the work of its torque so far [J]),
    and the ``events`` in time order."""

    slip_state: np.ndarray | None = None
    slip_speed: np.ndarray | None = None
    slip_distance: np.ndarray | None = None
    friction_work: np.ndarray | None = None
    input_work: np.ndarray | None = None
    events: tuple = ()

    @property
    def slip(self) -> np.ndarray:
        """Per sample and pulley 1 while it slides, else 0 (the node's ``P/slip`` topic)."""
        return (self.slip_state != 0).astype(float)

    def first_slip(self):
        """The first ``onset`` event (:class:`SlipEvent`: time [s], pulley, kind, direction), or None."""
        return next((e for e in self.events if e.kind == "onset"), None)


class SlipArrays:
    """The kernel's constant arrays of one network model (SI units)."""

    def __init__(self, model: NetworkModel, dt: float):
        scene = model.scene
        self.model = model
        P = scene.pulleys
        self.n = n = len(P)
        self.m = m = model.M.shape[0]
        self.N = 2 * m + n
        belt = scene.belt
        self.a = np.ascontiguousarray(model.stretch, dtype=float)
        self.k = np.ascontiguousarray(model.k, dtype=float)
        self.c = np.ascontiguousarray(model.c, dtype=float)
        self.Minv = 1.0 / np.diag(model.M)
        # the arm's spring and geometric stiffness, bearing and arm damping: K and C without the spans
        self.Karm = np.zeros((m, m))
        self.Cb = np.diag([p.damping for p in P] + ([scene.tensioner.damping] if scene.tensioner else []))
        if model.arm >= 0:
            self.Karm[model.arm, model.arm] = scene.tensioner.spring_rate + model.geometric_stiffness(np.full(n, belt.installed_tension))
        self.f = np.tanh(0.5 * np.array([p.mu for p in P]) * scene.geometry.wraps)
        self.r = np.array([p.radius for p in P])
        self.sgn = np.array([p.sign / p.gear for p in P], dtype=float)  # a gear train: Q / gear on the pulley
        self.driver = int(scene.driver)
        damped = 1.0 if belt.damping > 0.0 else 0.0
        # then per pulley 1 / gear: the profile reads the drive shaft's angle and speed (the pulley's / gear)
        self.par = np.array([belt.installed_tension, belt.mass_per_length, float(dt), 1.0e5, damped, *[1.0 / p.gear for p in P]])
        # the profiles as the linear tiers stack them (pulley i's from row start[i]), then one constant row per
        # pulley: a held torque (:meth:`hold`) points the pulley there
        active = [i for i, p in enumerate(P) if p.sign]
        first, pk, pp, self.ptx, self.pty = stack_profiles([(P[i].name, P[i].torque) for i in active], "this profile has "
                                                           "no data form; the slipping tier runs compiled profiles only")
        self.start = np.zeros(n, dtype=np.int64)
        self.start[active] = first
        self.held_rows = pk.size + np.arange(n)
        self.pk = np.concatenate([pk, np.full(n, CONSTANT, dtype=np.int64)])
        self.pp = np.ascontiguousarray(np.concatenate([pp, np.zeros((n, WIDTH))]))
        self._profiles = (self.start.copy(), self.sgn.copy())
        self.model_gears = [p.gear for p in P]
        from .slip_kernel import LEVELS  # (imports numba: only where a run starts)

        K, N = CACHE_SLOTS, self.N
        self.cache = (np.full(K, -1, dtype=np.int64), np.full(K, -1, dtype=np.int64), np.zeros((K, N, N)), np.zeros((K, N)),
                      np.zeros((K, n, N)), np.zeros((K, n)), np.zeros((K, n, N)), np.zeros((K, n)), np.zeros((K, n, n)),
                      np.zeros((K, LEVELS + 1, N, N)), np.zeros((K, LEVELS + 1, N, N)))

    def hold(self, pulley: int, value: float | None, sign: float = 0.0) -> None:
        """Pulley ``pulley``'s torque becomes ``sign value`` [N m] from now on (``sign``: its role's, +1 driver, -1
        accessory); ``value`` None: back to its profile."""
        if value is None:
            self.start[pulley], self.sgn[pulley] = self._profiles[0][pulley], self._profiles[1][pulley]
            return
        row = self.held_rows[pulley]
        self.pp[row, 0] = float(value)
        self.start[pulley] = row
        self.sgn[pulley] = sign / self.model_gears[pulley]

    def piece(self, h: float) -> "SlipArrays":
        """These arrays for one step of ``h`` [s], their own step and exponentials (:func:`~.model.piece_of`)."""
        return piece_of(self, h, lambda h: SlipArrays(self.model, h), ("sgn", "pk", "pp", "ptx", "pty", "start"), CACHE_SLOTS)

    def plant(self):
        """The kernel's plant arguments, in :func:`~.slip_kernel.slip_steps`'s order."""
        return (self.par, self.Minv, self.Karm, self.Cb, self.a, self.k, self.c, self.f, self.r, self.sgn, self.driver,
                self.pk, self.pp, self.ptx, self.pty, self.start)


def slip_state(model: NetworkModel, arr: SlipArrays, speed: float = 0.0) -> np.ndarray:
    """A run's whole state between two calls of the kernel (:func:`advance_slipping`), one float vector
    ``[x (2m + n), mode (n), fresh (n), friction work (n), input work (n), tensions (n), slip speeds (n)]``:
    the belt turning at ``speed`` [rad/s] at the driver, unstretched, every pulley sticking."""
    n, m, N = arr.n, arr.m, arr.N
    state = np.zeros(N + 6 * n)
    x = state[:N]
    x[m : m + n] = model.speeds_at(speed)
    state[N + 4 * n : N + 5 * n] = model.tensions(x[:m], x[m : 2 * m]) + arr.k * (np.roll(x[2 * m :], -1) - x[2 * m :])
    return state


def advance_slipping(arr: SlipArrays, state, k0: int, k1: int, out=None, name: str = "", names=()) -> np.ndarray:
    """Steps ``k0 .. k1-1`` (times ``k dt``) of the slipping tier from ``state`` at ``k0 dt`` (:func:`slip_state`,
    updated in place); the one way its time advances (a whole run, the node's ticks: the kernel continues from
    the state bit for bit). ``out``: None, or ``(states, modes, tensions, slip speeds, friction work, input work)``
    with ``k1 - k0 + 1`` rows each (row j: after step ``k0 + j - 1``). Returns the events ``[time, pulley, old mode,
    new mode]`` of these steps. Raises :class:`SimulationDivergedError` (``name``, ``names``: the scene's and the
    pulleys' names for its message).
    """
    from . import slip_kernel as K

    n, N, dt = arr.n, arr.N, float(arr.par[2])
    x, wf, win = state[:N], state[N + 2 * n : N + 3 * n], state[N + 3 * n : N + 4 * n]
    sig = state[N : N + n].astype(np.int64)
    fresh = state[N + n : N + 2 * n] != 0.0
    out = slip_rows(k1 - k0 + 1, N, n) if out is None else out
    events = np.empty((2 * (K.MAX_SWITCHES + 1) * n + 256, 4))
    count = np.zeros(1, dtype=np.int64)

    def call(arrays, lo: int, hi: int, t0: float, base: int) -> None:
        """Steps ``lo .. hi-1`` of ``arrays`` (times ``t0 + k h``, h its step), samples from row ``base + 1`` on."""
        nonlocal events
        k = lo
        while k < hi:
            status, k_end = K.slip_steps(k, hi, t0, x, sig, *(o[base + k - lo :] for o in out), events, count,
                                         *arrays.plant(), *arrays.cache, wf, win, fresh)  # fmt: skip
            if status == K.OK:
                return
            if status == K.EVENTS_FULL:  # stopped before step k_end (x, sig as there): room for more, go on
                events = np.concatenate([events, np.empty_like(events)])
                k = k_end
                continue
            where = f"t = {t0 + k_end * float(arrays.par[2]):.6g} s"
            if status == K.CHATTER:
                who = [names[int(e[1])] for e in events[max(0, count[0] - 4) : count[0]]]
                raise SimulationDivergedError(f"{name}: more than {K.MAX_SWITCHES} stick/slip switches inside one step at {where} "
                                              f"({', '.join(dict.fromkeys(who)) or 'no pulley'}: chattering); reduce dt")
            if status == K.STUCK:
                who = names[int(events[count[0], 1])]
                raise SimulationDivergedError(f"{name}: at t = {events[count[0], 0]:.9g} s the slip speed on {who} reaches zero "
                                              "where it can neither stick (the friction it would need leaves the limit at once) "
                                              "nor slide on either way (several pulleys sliding on a loose belt); raise "
                                              "belt.installed_tension or give the belt damping")
            if status == K.ALL_SLIP:
                raise SimulationDivergedError(f"{name}: the belt slides on every pulley at once at {where} (a massless belt "
                                              "has no motion then: the capstan limits cannot all hold, or the sliding pulleys' "
                                              "equations are singular); raise belt.installed_tension")
            raise SimulationDivergedError(f"{name}: the state became non-finite or too fast at {where} (slipping tier at dt = {dt:g} s)")

    # a step with torque breakpoints strictly inside is split there (each piece the exact flow over its length,
    # the torques held from the piece's start), as the linear tiers split it
    for a, e, edges in step_runs(grid_breakpoints(arr.model, dt)[2], dt, k0, k1):
        if edges is None:
            call(arr, a, e, 0.0, a - k0)
        else:
            for p, q in zip(edges[:-1], edges[1:]):
                call(arr.piece(q - p), 0, 1, p, a - k0)
    if k1 > k0:
        state[N : N + n] = sig
        state[N + n : N + 2 * n] = fresh
        state[N + 4 * n : N + 5 * n] = out[2][k1 - k0]
        state[N + 5 * n :] = out[3][k1 - k0]
    return events[: count[0]]


def slip_rows(rows: int, N: int, n: int) -> tuple:
    """``rows`` empty samples of a slipping run: ``(states (N,), modes, tensions, slip speeds, friction work,
    input work)`` (n each per row), as :func:`advance_slipping` writes them."""
    return (np.empty((rows, N)), np.zeros((rows, n), dtype=np.int64), np.empty((rows, n)), np.zeros((rows, n)),
            np.zeros((rows, n)), np.zeros((rows, n)))


def slip_run(model: NetworkModel, time, states, modes, tensions, slip_speed, friction_work, input_work, events=()):
    """The :class:`SlipNetworkRun` of samples (rows) of a slipping run (``states`` (N, 2m + n))."""
    m, scene = model.M.shape[0], model.scene
    base = outputs(model, time, states[:, : 2 * m], tensions)
    names = [p.name for p in scene.pulleys]
    evs = tuple(SlipEvent(float(e[0]), names[int(e[1])], _KINDS[(e[2] != 0, e[3] != 0)], int(e[3] if e[3] != 0 else e[2]))
                for e in events)  # fmt: skip
    fields = {f: getattr(base, f) for f in NetworkRun.__dataclass_fields__}
    return SlipNetworkRun(**fields, slip_state=modes.astype(np.int8), slip_speed=slip_speed,
                          slip_distance=states[:, 2 * m :], friction_work=friction_work, input_work=input_work, events=evs)


def simulate_slipping(model: NetworkModel | None, scene, duration: float | None = None, dt: float | None = None,
                      method: str | None = None) -> SlipNetworkRun:
    """Run the slipping tier (``method``: ``exact``, its one method) from the belt turning at ``scene.initial_speed``
    unstretched, every pulley sticking; :class:`SimulationDivergedError` as :func:`advance_slipping` raises it."""
    model = NetworkModel.build(scene) if model is None else model
    if method is not None and method not in METHODS:
        raise SceneError(f"method: the slipping tier steps the exact flow of each stick/slip mode (exact); {method} is not available for it")
    _, dt, steps = run_steps(scene, duration, dt)
    arr = SlipArrays(model, dt)
    n, N = arr.n, arr.N
    state = slip_state(model, arr, scene.initial_speed)
    out = slip_rows(steps + 1, N, n)
    out[0][0] = state[:N]
    out[2][0] = state[N + 4 * n : N + 5 * n]
    events = advance_slipping(arr, state, 0, steps, out, scene.name, [p.name for p in scene.pulleys])
    states, modes, T, sd, wf, win = out
    return slip_run(model, np.arange(steps + 1) * dt, states, modes, T, sd, wf, win, events)


def warm() -> None:
    """Compile (or load from the disk cache) the slipping tier's kernel (one signature: any scene), on a two-pulley belt."""
    from .scene import warm_scene

    simulate_slipping(None, warm_scene())



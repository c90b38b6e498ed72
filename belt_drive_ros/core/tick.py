"""The node's common tick in one compiled call: whole grid steps, then every output at their end.

A 1 kHz tick of the linear models is one step of the kernel
(:func:`~belt_drive_ros.core.kernel.linear_steps`) and the sixteen outputs
of :data:`~belt_drive_ros.core.model.OUTPUT_UNITS` at the new state. Done in
Python that is ~25 calls of numpy on tiny arrays and as many interpreted
functions, whose cost on the caches a 1 ms sleep leaves is most of the tick.
:func:`linear_tick` does both in one ``@njit(cache=True, nogil=True)`` call
writing into buffers :class:`TickKernel` allocates once per stepper.

Bit for bit the operations of the reference path (the stepper's
:meth:`~belt_drive_ros.core.stepper.Stepper.advance`, then
:meth:`~belt_drive_ros.core.model._LinearModel.outputs` of one sample):

* grid times ``origin + dt * k`` (the float product and sum of ``Stepper._grid``);
* the torques at the tick time from the profiles' data
  (:func:`~belt_drive_ros.core.kernel.profile_torque`), at the wheel
  coordinates ``W x`` summed over the nonzero entries of ``W`` from the left
  (as :class:`~belt_drive_ros.core.stepper.Plant`'s scalar ``inputs``);
* ``y_j = (x_0 C_j0 + ... + x_{n-1} C_j,n-1) + (u_0 D_j0 + u_1 D_j1)``
  (``model._affine_sample``), then ``drive_torque, load_torque = u``;
* span forces and flags: ``half = 0.5 |T_b| / r_3``, ``F_tight = F_0 + half``,
  ``F_slack = F_0 - half``, slack ``F_slack <= 0``, slip ``slack or F_tight >
  F_slack capstan_ratio`` (:func:`~belt_drive_ros.core.model.span_forces`),
  the flags as 0.0/1.0.

A tick at which the held drive torque changes comes here too when it is one
grid step: the general path then clamps the step's torque times to
``[lo, hi]`` (``lo = t0`` after a jump at ``t0``, ``hi = left_of(t1)``
before one at ``t1``: the stepper's special step) and evaluates the outputs
at ``t1`` with the new value; the kernel takes the same clamps and writes
the new value into the held torque's data between the two (``drive``).
Ticks near a plant breakpoint, or a held-torque jump in a tick of several
steps, a kernel loop with extra inputs: the stepper as before.

The kernels also write the tick's ``joint_states`` message into a byte
buffer the caller lays out (:func:`write_joints`): the stamp and the twelve
doubles (positions, velocities, efforts) at the offsets it gives, so the
node publishes the bytes without building them in Python.
"""

from __future__ import annotations

import math

import numpy as np

from numba import njit

from .kernel import HEADER, SECTIONS, linear_steps, profile_torque
from .kernel_slip import KIND_NAMES, PHASE_SIZE, STICKING, hybrid_steps
from .slip import SLIP, STICK
from .slip_run import SlippingSimulator, SlipState, _kind_code
from .model import LINEAR_OUTPUTS, OUTPUT_UNITS

#: :attr:`TickKernel.y` holds OUTPUT_UNITS in order: the linear outputs first, then these four
_AFTER = ("span_force_tight", "span_force_slack", "slack", "slip")
assert tuple(OUTPUT_UNITS) == LINEAR_OUTPUTS + _AFTER
_N_SECTIONS = len(SECTIONS)


@njit(cache=True, nogil=True)
def _coordinate(rows, q, n, x):
    """Wheel coordinate ``q`` of ``x``: the nonzero entries of row q of W, summed from the left (Plant.inputs)."""
    count, j1 = 0, 0
    for j in range(n):
        if rows[q * n + j] != 0.0:
            count += 1
            j1 = j
    if count == 1:
        c = rows[q * n + j1]
        return x[j1] if c == 1.0 else c * x[j1]
    total = 0.0
    for j in range(n):
        c = rows[q * n + j]
        if c != 0.0:
            total = total + c * x[j]
    return total


@njit(cache=True, nogil=True)
def write_joints(y, msg, at, stamp):
    """The tick's ``joint_states`` into the message buffer ``msg`` (uint8, its size a multiple of 8, 8-byte aligned).

    ``at`` (floats holding whole numbers): the float64 index in ``msg`` of the
    positions, velocities and efforts (four each), then the uint32 index of
    the stamp's seconds (its nanoseconds follow). ``stamp`` [ns] >= 0. The
    joints ``wheel_M, wheel_1, wheel_2, wheel_3``: positions ``y[0], y[2],
    y[4], y[6]``, velocities ``y[1], y[3], y[5], y[7]``, efforts ``y[8], 0, 0,
    -y[9]`` (drive torque, minus the load torque) of :data:`~belt_drive_ros.core.model.OUTPUT_UNITS`.
    """
    f = msg.view(np.float64)
    w = msg.view(np.uint32)
    p, v, e, s = int(at[0]), int(at[1]), int(at[2]), int(at[3])
    for j in range(4):
        f[p + j] = y[2 * j]
        f[v + j] = y[2 * j + 1]
    f[e], f[e + 1], f[e + 2], f[e + 3] = y[8], 0.0, 0.0, -y[9]
    w[s] = stamp // 1000000000
    w[s + 1] = stamp % 1000000000


@njit(cache=True, nogil=True)
def linear_tick(k0, steps, x, out, lo, hi, drive, stamp, reals, ints, dp, lp, rows, y, msg):
    """``steps`` whole grid steps from grid index ``k0`` (state ``x``) into ``out``, then the outputs into ``y``
    and the ``joint_states`` message stamped ``stamp`` [ns] into ``msg`` (:func:`write_joints`).

    ``reals, ints, dp, lp``: the stepper's kernel loop
    (:class:`~belt_drive_ros.core.kernel_loop.KernelLoop`); ``rows`` packs
    ``[W (4 n), C (12 n), D (12 x 2), F_0, r_3, capstan_ratio, origin, dt, speed limit, message layout (4)]``
    (:class:`TickKernel`). ``lo, hi`` [s]: the torque times clamped to them
    (``-inf, inf``: none; the stepper's special step at a held-torque jump);
    ``drive``: NaN, or the held drive torque's new value [N m], written into
    ``dp[0, 0]`` (the held torque's data) after the steps, before the
    outputs. ``x`` may be a row of ``out`` (the kernel reads it before it
    writes). Returns ``(done, status, t)`` of the kernel; ``y``, ``msg`` and
    ``dp`` are written only when every step is done (status OK).
    """
    n = x.size
    d0 = 16 * n
    origin, dt, limit = rows[d0 + 27], rows[d0 + 28], rows[d0 + 29]
    times = np.empty(steps + 1)
    for j in range(steps + 1):
        times[j] = origin + dt * float(k0 + j)
    done, status, t = linear_steps(times, x, out, lo, hi, limit, reals, ints, dp, lp)
    if status != 0:
        return done, status, t
    if drive == drive:
        dp[0, 0] = drive
    xe = out[steps - 1]
    # the profiles' data inside the loop's arrays (the layout linear_steps unpacks)
    s = ints[1]
    at = ints[HEADER : HEADER + _N_SECTIONS + 1]
    k = HEADER + _N_SECTIONS + 1
    nd = dp.shape[0]
    dk, lk = ints[k + s : k + s + nd], ints[k + s + nd :]
    t1 = times[steps]
    # the coordinates' numbers as int64, not literals: a literal argument compiles a specialisation of its own
    q0, q1, q2, q3 = np.int64(0), np.int64(1), np.int64(2), np.int64(3)
    angle_M = _coordinate(rows, q0, n, xe) if ints[7] else 0.0
    angle_3 = _coordinate(rows, q2, n, xe) if ints[8] else 0.0
    u0 = profile_torque(dk, dp, reals[at[7] : at[8]], reals[at[8] : at[9]], t1, angle_M, _coordinate(rows, q1, n, xe))
    u1 = profile_torque(lk, lp, reals[at[9] : at[10]], reals[at[10] : at[11]], t1, angle_3, _coordinate(rows, q3, n, xe))
    c0 = 4 * n
    for j in range(12):  # the LINEAR_OUTPUTS
        a = xe[0] * rows[c0 + j * n]
        for q in range(1, n):
            a = a + xe[q] * rows[c0 + j * n + q]
        y[j] = a + (u0 * rows[d0 + 2 * j] + u1 * rows[d0 + 2 * j + 1])
    y[8], y[9] = u0, u1  # drive_torque, load_torque: the inputs themselves
    F_0, r_3, capstan = rows[d0 + 24], rows[d0 + 25], rows[d0 + 26]
    half = 0.5 * abs(y[10]) / r_3  # belt_torque
    tight = F_0 + half
    slack_force = F_0 - half
    slack = slack_force <= 0.0
    y[12], y[13] = tight, slack_force
    y[14] = 1.0 if slack else 0.0
    y[15] = 1.0 if slack or tight > slack_force * capstan else 0.0
    write_joints(y, msg, rows[d0 + 30 :], stamp)
    return done, status, t


def grid_step_ns(dt: float, origin: float) -> int:
    """The grid step [ns] when ``dt`` [s] is a whole number of nanoseconds and the grid starts at 0, else 0.

    Then a node time ``origin_ns + k step_ns`` is the grid time ``k dt`` (which
    the node's scene times snap to) without the general rounding.
    """
    step_ns = round(dt * 1e9)
    return step_ns if step_ns > 0 and step_ns / 1e9 == dt and origin == 0.0 else 0


def joints_message(template: bytes | None = None, offsets=None) -> tuple[np.ndarray, memoryview, list]:
    """``(msg, view, at)``: the buffer :func:`write_joints` writes a message into, the message's bytes
    in it (a view: ``bytes(view)`` copies them) and its layout ``at``.

    ``template``: the message's bytes, its stamp at bytes 4-12 (seconds, nanoseconds: little-endian
    int32, uint32) and its positions, velocities and efforts (four little-endian doubles each)
    at the byte ``offsets``, which must share one alignment (as CDR's sequences of doubles do).
    None: a scratch message of that shape.
    """
    if template is None:
        template, offsets = bytes(112), (12, 44, 76)
    shift = -offsets[0] % 8  # where the template starts in the buffer, so that its doubles are 8-byte aligned
    if any((shift + o) % 8 for o in offsets) or (shift + 4) % 4:
        raise ValueError("joint_states layout: its double arrays do not share one alignment")
    msg = np.zeros(-(-(shift + len(template)) // 8) * 8, dtype=np.uint8)
    msg[shift : shift + len(template)] = np.frombuffer(template, dtype=np.uint8)
    at = [float((shift + o) // 8) for o in offsets] + [float((shift + 4) // 4)]
    return msg, memoryview(msg)[shift : shift + len(template)], at


class TickKernel:
    """One stepper's tick as one compiled call: :meth:`step` advances its buffers, :attr:`y` holds the outputs.

    ``TickKernel.of(stepper)`` is None where the tick cannot be compiled
    (an adaptive method, a Python-only profile, extra inputs: the general
    path serves those ticks).
    """

    def __init__(self, stepper, limit: float):
        plant, loop = stepper.plant, stepper.loop
        model = plant.model
        n = model.A.shape[0]
        C, D = model.output_matrices()
        p = model.params
        msg, self.message, at = joints_message()
        self.rows = np.concatenate([np.ravel(plant.wheel_map), np.ravel(C), np.ravel(D),
                                    [p.F_0, p.r_3, p.capstan_ratio, stepper.origin, stepper.dt, limit], at]).astype(np.float64)
        #: the outputs of the last :meth:`step` [SI units, OUTPUT_UNITS order; slack/slip as 0.0/1.0]
        self.y = np.zeros(len(OUTPUT_UNITS))
        self.n, self.dt, self.origin = n, stepper.dt, stepper.origin
        self.step_ns = grid_step_ns(self.dt, stepper.origin)
        self._out = np.empty((1, n))
        self._loop = (loop.reals, loop.ints, loop._dp, loop._lp)
        self._args = (*self._loop, self.rows, self.y, msg)

    def set_message(self, template: bytes, offsets) -> None:
        """Write the ``joint_states`` of each :meth:`step` into ``template``'s layout (:func:`joints_message`);
        :attr:`message` then holds its bytes after a step."""
        msg, self.message, at = joints_message(template, offsets)
        self.rows[-4:] = at
        self._args = (*self._loop, self.rows, self.y, msg)

    @classmethod
    def of(cls, stepper, limit: float):
        """The tick kernel of ``stepper`` (divergence beyond ``limit`` [rad/s]), or None where it cannot run."""
        loop = getattr(stepper, "loop", None)
        if loop is None or stepper.plant.extra or stepper.guard is not None or not hasattr(stepper.plant.model, "C"):
            return None
        return cls(stepper, limit)

    def step(self, x: np.ndarray, k0: int, k1: int, lo: float = -math.inf, hi: float = math.inf,
             drive: float = math.nan, stamp: int = 0):
        """Whole grid steps k0 -> k1 from state ``x``: ``(states (k1 - k0, n), status)``; :attr:`y` at k1
        and :attr:`message` stamped ``stamp`` [ns] when OK (``lo``, ``hi``, ``drive``: :func:`linear_tick`'s).

        The states are written into a buffer kept for the next call (the
        last row is the next call's ``x``): a caller keeps them by copying.
        """
        out = self._out
        if out.shape[0] != k1 - k0:
            out = self._out = np.empty((k1 - k0, self.n))
        return out, linear_tick(k0, k1 - k0, x, out, lo, hi, drive, stamp, *self._args)[1]


# ------------------------------------------------------------------ the slipping belt
#: constants of the slipping model's outputs in :func:`slip_tick` (:meth:`SlipTickKernel` packs them in this order)
SLIP_CONSTANTS = ("ratio", "r_3", "a_1", "g", "F_0", "q_1", "q_2", "q_3", "rel_2", "rel_3", "c", "2k r_3", "2c",
                  "belt speed ratio", "belt_mass", "capstan_factor")  # fmt: skip


@njit(cache=True, nogil=True)
def slip_tick(k0, grid, knots, lo, hi, special, kind, xs, sigma5, x, dt, limit, out_y, out_mode, out_sigma, out_native, reals, ints,
              offsets, have, Yflex, Minv, Z, R, c, mats, guards, uses, dk, dp, dx, dy, lk, lp, lx, ly, events, consts,
              y, drive, stamp, msg):  # fmt: skip
    """The slipping belt's tick: :func:`~belt_drive_ros.core.kernel_slip.hybrid_steps` over
    ``grid.size - 1`` whole grid steps from grid index ``k0``, then every output of the slipping
    model at the last knot into ``y``.

    ``xs``: the phase coordinates of the hybrid state the steps start from, copied into the
    buffer ``x`` (zeros after them; ``sigma5``, unless NaN, at ``x[5]``: the stepwise phase's
    direction). ``grid``, ``knots``: buffers the grid times are written into; the other
    arguments up to ``events`` are the hybrid loop's (its call from step 0
    with no events recorded yet; ``lo``, ``hi``: each step's torque-time clamps, as
    :func:`linear_tick`'s); ``consts``: :data:`SLIP_CONSTANTS`, the grid's origin [s], then
    the message layout of :func:`write_joints`. ``drive``: NaN or the held drive torque's new
    value, written into ``dp[0, 0]`` after the steps when no mode switched in them; ``stamp``,
    ``msg``: the ``joint_states`` message (:func:`write_joints`). ``y``
    receives ``OUTPUT_UNITS + SLIP_OUTPUT_UNITS`` in order, the operations of
    :meth:`~belt_drive_ros.core.slip.SlippingBeltModel.outputs` on one sample
    (flags as 0.0/1.0), with ``u = [drive(t, phi_M, omega_M), load(t, phi_3, omega_3)]``
    at the last knot ``t`` (:meth:`~belt_drive_ros.core.slip_run.SlippingSimulator.inputs`).
    Returns the hybrid loop's ``(next step, status, kind, sigma, events)``;
    ``y`` is written only when the loop is done (status 0).
    """
    for j in range(x.size):
        x[j] = xs[j] if j < xs.size else 0.0
    if sigma5 == sigma5:
        x[5] = sigma5
    for j in range(grid.size):  # the grid times origin + dt k of Stepper._grid; the knots are them
        grid[j] = consts[16] + dt * float(k0 + j)
        knots[j] = grid[j]
    # k0 and n0 as int64 (the signature Python's calls compile), not literal zeros: a literal would compile the
    # whole hybrid loop (and its event step) a second time
    zero = np.int64(0)
    k1, status, kind, sigma, n_ev = hybrid_steps(grid, knots, lo, hi, special, zero, kind, x, dt, limit, out_y, out_mode,
                                                 out_sigma, out_native, reals, ints, offsets, have, Yflex, Minv, Z, R, c,
                                                 mats, guards, uses, dk, dp, dx, dy, lk, lp, lx, ly, events, zero)  # fmt: skip
    if status != 0:
        return k1, status, kind, sigma, n_ev
    if drive == drive and n_ev == 0:
        dp[0, 0] = drive
    slipping = kind > STICKING
    sg = sigma
    last = grid.size - 2
    y0, y1, y2, y3, y4 = out_y[last, 0], out_y[last, 1], out_y[last, 2], out_y[last, 3], out_y[last, 4]
    ratio, r_3, a1, g, F_0 = consts[0], consts[1], consts[2], consts[3], consts[4]
    t = knots[last + 1]
    phi_3 = ratio * y0 - y1 - y4 / r_3
    u0 = profile_torque(dk, dp, dx, dy, t, y0, y2)
    u1 = profile_torque(lk, lp, lx, ly, t, phi_3, y3)
    v = consts[13] * y2  # Q_max (scalar_friction_limit: Python's max(value, 0.0))
    qmax = (F_0 - consts[14] * v * v) * consts[15]
    if 0.0 > qmax:
        qmax = 0.0
    stick = consts[5] * y1 + consts[6] * y2 + consts[7] * y3
    Q = sg * qmax if slipping else stick
    speed = 0.0
    if slipping:
        rel = y2 * consts[8] + y3 * consts[9]
        speed = rel if consts[10] == 0.0 else rel - (Q - consts[11] * y1) / consts[12]
    slack_force = F_0 - 0.5 * Q
    tight = F_0 + 0.5 * Q
    slip_angle = y4 / r_3
    low = tight if tight < slack_force else slack_force  # Python's min(slack_force, tight)
    y[0], y[1], y[2], y[3], y[4], y[5] = y0, y2, a1 * y0, a1 * y2, g * y0, g * y2
    y[6], y[7], y[8], y[9], y[10], y[11] = phi_3, y3, u0, u1, r_3 * Q, y1 + slip_angle
    y[12], y[13] = tight, slack_force
    y[14] = 1.0 if low <= 0.0 else 0.0
    y[15] = 1.0 if slipping else 0.0
    y[16], y[17], y[18], y[19] = y1, slip_angle, y4, speed
    y[20] = Q / qmax if qmax > 0 else math.inf
    y[21] = qmax
    write_joints(y, msg, consts[17:], stamp)
    return k1, status, kind, sigma, n_ev


class SlipTickKernel:
    """A slipping engine's (:class:`~belt_drive_ros.core.slip_run.SlippingSimulator`) tick of whole steps as one
    compiled call (:func:`slip_tick`), its buffers allocated once; :attr:`y` holds the outputs."""

    def __init__(self, engine, limit: float):
        m, p = engine.model, engine.model.params
        q, rel = m._q, m.rel_row.tolist()
        self.consts = np.array([p.ratio, p.r_3, p.r_M / p.R_1, p.gear_ratio, p.F_0, q[1], q[2], q[3], rel[2], rel[3],
                                p.c, 2.0 * p.k * p.r_3, 2.0 * p.c, p.r_2 * p.gear_ratio, float(p.belt_mass),
                                p.capstan_factor, engine.origin], dtype=np.float64)  # fmt: skip
        self._msg, self.message, at = joints_message()
        self.consts = np.concatenate([self.consts, at])
        self.engine, self.dt, self.origin, self.limit = engine, engine.dt, engine.origin, limit
        self.step_ns = grid_step_ns(engine.dt, engine.origin)
        self.y = np.zeros(22)
        self.x = np.zeros(6)
        self.events = np.zeros((1024, 8))  # the hybrid loop wants room for a chattering step's switches
        self._buffers(1)
        self._built = -1  # how many phase steppers the engine had when its arrays were packed (see _pack)
        self._tail: tuple | None = None  # slip_tick's arguments from reals on (None: the engine cannot compile)
        self._state, self._code = None, 0  # the hybrid state the last advance returned, its kind code

    def _pack(self) -> None:
        """The engine's compiled arrays as :func:`slip_tick`'s trailing arguments (again whenever a phase's
        stepper was built since: the engine only adds them)."""
        compiled = self.engine._compiled()
        self._built = len(self.engine._steppers)
        if compiled is None:
            self._tail = None
            return
        have, reals, ints, offsets, Yflex, Minv, arrays = compiled
        self._tail = (reals, ints, offsets, have, Yflex, Minv, *arrays, self.events, self.consts, self.y)

    def _buffers(self, N: int) -> None:
        """The hybrid loop's arrays for ``N`` whole steps without clamps or splits."""
        self.N = N
        self.grid, self.knots = np.zeros(N + 1), np.zeros(N + 1)
        self.lo, self.hi, self.special = np.full(N, -math.inf), np.full(N, math.inf), np.zeros(N, dtype=np.int64)
        self.out_y, self.out_native = np.empty((N, 5)), np.empty((N, 6))
        self.out_mode, self.out_sigma = np.empty(N, dtype=np.int64), np.empty(N)

    def set_message(self, template: bytes, offsets) -> None:
        """As :meth:`TickKernel.set_message`."""
        self._msg, self.message, at = joints_message(template, offsets)
        self.consts[-4:] = at

    def advance(self, state, k0: int, k1: int, lo: float = -math.inf, hi: float = math.inf, drive: float = math.nan,
                stamp: int = 0):
        """The hybrid state after the whole grid steps k0 -> k1 from ``state`` (a
        :class:`~belt_drive_ros.core.slip_run.SlipState`), the outputs at t1 in :attr:`y` and
        :attr:`message` stamped ``stamp`` [ns]; ``lo`` clamps the first step's torque times, ``hi``
        the last one's, ``drive`` as :func:`slip_tick`'s. None when the step needs the engine's own
        :meth:`~belt_drive_ros.core.slip_run.SlippingSimulator.advance` (a mode switch in it, a
        failure: it redoes the step from ``state`` and reports them)."""
        if len(self.engine._steppers) != self._built:
            self._pack()
        if self._tail is None:
            return None
        if state is self._state:  # the usual tick: the state the last call returned (its own C array)
            code, xs = self._code, state.x
        else:
            code, xs = _kind_code(state), np.array(state.x, dtype=np.float64)
        if k1 - k0 != self.N:
            self._buffers(k1 - k0)
        clamped = lo != -math.inf or hi != math.inf
        if clamped:
            self.lo[0], self.hi[-1] = lo, hi
        k1, status, kind, sigma, n_ev = slip_tick(
            k0, self.grid, self.knots, self.lo, self.hi, self.special, code, xs,
            state.sigma if state.kind == "hybrid" else math.nan, self.x, self.dt, self.limit, self.out_y,
            self.out_mode, self.out_sigma, self.out_native, *self._tail, drive, stamp, self._msg,
        )  # fmt: skip
        if clamped:
            self.lo[0], self.hi[-1] = -math.inf, math.inf
        if status != 0 or n_ev:
            return None
        state = SlipState(STICK if kind <= STICKING else SLIP, float(sigma), KIND_NAMES[kind], self.x[: PHASE_SIZE[kind]].copy())
        self._state, self._code = state, kind  # (= _kind_code(state): the loop's code of that phase)
        return state

    def state_y(self) -> np.ndarray:
        """The slipping state ``y`` (5,) after the last :meth:`advance` (the engine's ``state_y`` of it)."""
        return self.out_y[-1].copy()


def warm() -> None:
    """Compile (or load from the disk cache) :func:`linear_tick` and :func:`slip_tick` with the one
    signature the node uses (``make install`` calls it through :func:`~belt_drive_ros.core.warm.warm`)."""
    from .model import FlexibleBeltModel
    from .params import BeltDriveParams
    from .sources import Constant
    from .stepper import Plant, Stepper

    params, torque = BeltDriveParams(), Constant(1.0)
    kernel = TickKernel.of(Stepper(Plant(FlexibleBeltModel(params), torque, torque), "exact", 1e-3), 1.0e5)
    kernel.step(np.zeros(4), 0, 1)
    engine = SlippingSimulator(params, torque, torque, "etd2", 1e-3, check_stability=False)
    SlipTickKernel(engine, 1.0e5).advance(engine.initial(np.zeros(5)), 0, 1)

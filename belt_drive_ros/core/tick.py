"""The node's common tick in one compiled call: whole grid steps, then every output at their end.

A 1 kHz tick of the linear models is one step of the kernel
(:func:`~belt_drive_ros.core.kernel.linear_steps`) and the sixteen outputs
of :data:`~belt_drive_ros.core.model.OUTPUT_UNITS` at the new state:
:func:`linear_tick` does both in one ``@njit(cache=True, nogil=True)`` call
writing into buffers :class:`TickKernel` allocates once per stepper.

Bit for bit the operations of the reference path (the stepper's
:meth:`~belt_drive_ros.core.stepper.Stepper.advance`, then
:meth:`~belt_drive_ros.core.model._LinearModel.outputs` of one sample):

* grid times ``origin + dt * k`` (the float product and sum of ``Stepper._grid``);
* the torques at the tick time from the profiles' data
  (:func:`~belt_drive_ros.core.kernel_profiles.profile_torque`), at the wheel
  coordinates ``W x`` summed over the nonzero entries of ``W`` from the left
  (as :class:`~belt_drive_ros.core.stepper.Plant`'s scalar ``inputs``);
* ``y_j = (x_0 C_j0 + ... + x_{n-1} C_j,n-1) + (u_0 D_j0 + u_1 D_j1)``
  (``model._affine_sample``), then ``drive_torque, load_torque = u``;
* span forces and flags: ``half = 0.5 |T_b| / r_3``, ``F_tight = F_0 + half``,
  ``F_slack = F_0 - half``, slack ``F_slack <= 0``, slip ``slack or F_tight - F_c >
  (F_slack - F_c) capstan_ratio`` with the centrifugal tension ``F_c = m' (r_2 g omega_M)^2``
  (none for a massless belt; :func:`~belt_drive_ros.core.model.span_forces`),
  the flags as 0.0/1.0.

A tick at which the held drive torque changes is compiled too when it is one
grid step (:func:`linear_tick`'s clamps); ticks near a plant breakpoint, a
held-torque jump in a tick of several steps, extra inputs: the stepper as before.

The kernels also write the tick's ``joint_states`` message (:func:`write_joints`): the node publishes its bytes.
"""

from __future__ import annotations

import ctypes
import math

import numpy as np

from numba import carray, njit
from numba.extending import overload

from .kernel import HEADER, SECTIONS, _doubles_at, doubles_view, linear_steps
from .kernel_hybrid import (FLEXIBLE, KIND_NAMES, MASS_DOWN, MASS_UP, PHASE_SIZE, SLIP_DOWN, SLIP_UP, STEPWISE,
                            STICKING, _flexible, _shift_angle, _to_y, hybrid_steps)
from .kernel_profiles import profile_torque
from .kernel_slip import MAX_SWITCHES
from .slip import SLIP, STICK
from .slip_run import SlippingSimulator, SlipState, _events, _kind_code
from .model import LINEAR_OUTPUTS, OUTPUT_UNITS

#: :attr:`TickKernel.y` holds OUTPUT_UNITS in order: the linear outputs first, then these four
_AFTER = ("span_force_tight", "span_force_slack", "slack", "slip")
assert tuple(OUTPUT_UNITS) == LINEAR_OUTPUTS + _AFTER


# ------------------------------------------------------------------ packed arguments
# numba's dispatcher converts every argument on every call, ~0.7-1.5 us per array on cold caches (15 arrays and
# scalars: 11 us, against 3.5 us of work): a tick's arrays go in one buffer (:class:`PackedArrays`), cut into views
# again in the kernels (the same types and layouts: the loops they call keep their one compiled signature).


@njit(cache=True, nogil=True, inline="always")  # no call of its own: its section numbers are literals
def _at(ints, j):
    return ints[4 * j], ints[4 * j + 1], ints[4 * j + 2], ints[4 * j + 3]


@njit(cache=True, nogil=True, inline="always")  # no call of its own: its section numbers are literals
def _f1(reals, ints, j):
    a, d0, _, _ = _at(ints, j)
    return reals[a : a + d0]


@njit(cache=True, nogil=True, inline="always")  # no call of its own: its section numbers are literals
def _f2(reals, ints, j):
    a, d0, d1, _ = _at(ints, j)
    return doubles_view(reals, a, (d0, d1))


@njit(cache=True, nogil=True, inline="always")  # no call of its own: its section numbers are literals
def _f3(reals, ints, j):
    a, d0, d1, d2 = _at(ints, j)
    return doubles_view(reals, a, (d0, d1, d2))


@njit(cache=True, nogil=True, inline="always")  # no call of its own: its section numbers are literals
def _i1(ints, j):
    a, d0, _, _ = _at(ints, j)
    return ints[a : a + d0]


@njit(cache=True, nogil=True, inline="always")  # no call of its own: its section numbers are literals
def _i2(ints, j):
    a, d0, d1, _ = _at(ints, j)
    return doubles_view(ints, a, (d0, d1))


class PackedArrays:
    """Named arrays in one float64 buffer ``reals`` (``ints``: its int64 view; ``views[name]``: each array's view).

    ``names``: ``(FLOATS, INTS)``, section ``j`` is ``FLOATS[j]`` (float64), then ``INTS[j - len(FLOATS)]``
    (int64); the buffer starts with ``(offset [8-byte words], d0, d1, d2)`` of every section, which the kernels'
    ``_f1, _f2, _f3, _i1, _i2`` read (``ints = reals.view(np.int64)``).
    """

    def __init__(self, names: tuple, floats: dict, ints: dict):
        FLOATS, INTS = names
        shapes = [np.shape(floats[name]) for name in FLOATS] + [np.shape(ints[name]) for name in INTS]
        if any(len(s) > 3 for s in shapes):
            raise ValueError("PackedArrays: at most three dimensions")
        sizes = [int(np.prod(s)) for s in shapes]
        nf = len(FLOATS)
        a = 4 * len(shapes)
        self.reals = np.zeros(a + sum(sizes))
        self.ints = self.reals.view(np.int64)
        self.views = {}
        for j, (name, shape, size) in enumerate(zip(FLOATS + INTS, shapes, sizes)):
            dims = tuple(shape) + (1,) * (3 - len(shape))
            self.ints[4 * j : 4 * j + 4] = (a, *dims)
            view = (self.reals if j < nf else self.ints)[a : a + size].reshape(shape)
            view[...] = floats[name] if j < nf else ints[name]
            self.views[name] = view
            a += size
        #: the buffer's address: what the tick kernels take (:func:`packed_at`); valid while this object lives
        self.address = self.reals.ctypes.data


# numba converts an int argument in a fraction of an array's time (on the caches a 1 ms sleep leaves, ~1 us against
# ~6 us: an array is type-checked by its fingerprint, then wrapped in a reference-counted record for the call and
# released after it): the ticks take their buffer's address and view the buffer there (numba's public extension
# API: an intrinsic for the address as a pointer, numba.carray for the array at it, not owned; the caller keeps the
# buffer alive through the call)


def packed_at(address: int) -> np.ndarray:
    """The float64 buffer of a :class:`PackedArrays` at ``address`` (its :attr:`~PackedArrays.address`), whole: its
    length from its table (the last section's offset and shape). Compiled: :func:`_doubles_at` and
    ``numba.carray``; interpreted (``NUMBA_DISABLE_JIT=1``): the same memory through ctypes."""
    words = ctypes.POINTER(ctypes.c_double)
    table = np.ctypeslib.as_array(ctypes.cast(address, ctypes.POINTER(ctypes.c_int64)), (4,))
    table = np.ctypeslib.as_array(ctypes.cast(address, ctypes.POINTER(ctypes.c_int64)), (int(table[0]),))
    a, d0, d1, d2 = (int(v) for v in table[-4:])
    return np.ctypeslib.as_array(ctypes.cast(address, words), (a + d0 * d1 * d2,))


@overload(packed_at, jit_options=dict(nogil=True))
def _packed_at(address):
    def impl(address):
        n = carray(_doubles_at(address), (1,)).view(np.int64)[0]  # 4 x the sections: the table's length
        table = carray(_doubles_at(address), (n,)).view(np.int64)
        return carray(_doubles_at(address), (table[n - 4] + table[n - 3] * table[n - 2] * table[n - 1],))

    return impl


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


#: the linear tick's packed sections (:class:`TickKernel`): the output rows, the kernel loop's ``reals``, load and drive
#: profiles, the state, the outputs, the ``joint_states`` message (its bytes as doubles), the clamps, room for the grid
#: times and states of up to ROOM steps; the loop's ``ints`` and the call's own: ``k0, steps, stamp, step_ns``
LINEAR_FLOATS = ("rows", "reals", "lp", "dp", "x", "y", "msg", "clamp", "times", "out")
LINEAR_INTS = ("ints", "io")
_ROWS, _REALS, _LP, _DP, _X, _Y, _MSG, _CLAMP, _TIMES, _OUT, _INTS, _IO = range(12)
#: grid steps per tick the buffers have room for (a tick of more allocates its times and states)
ROOM = 16
#: a done tick's flags, which its kernel returns negated (a failure: its status > 0): the outputs' ``slack`` and
#: ``slip`` set, the slipping model's outputs (:func:`slip_tick`, every tick); :func:`slip_tick` adds ``EVENT`` per
#: mode switch. The node counts its ticks by them without reading the outputs
SLACK, SLIPS, SLIPPING, EVENT = 1, 2, 4, 8


@njit(cache=True, nogil=True)
def linear_tick(address):
    """``steps`` whole grid steps from grid index ``k0`` of the state, then the outputs and the ``joint_states``
    message stamped ``stamp`` [ns] (:func:`write_joints`); returns the kernel's status (> 0), or when done minus the
    outputs' flags (:data:`SLACK`, :data:`SLIPS`; 0: neither).

    ``packed``: :class:`TickKernel`'s buffer (:data:`LINEAR_FLOATS`, :data:`LINEAR_INTS`) at ``address``, the one
    argument (numba converts every argument on every call: ~1 us per int and ~6 us per array on the caches a 1 ms
    sleep leaves; :func:`packed_at`).
    ``io = [k0, steps, stamp, step_ns]``; when the steps are done (status OK) the next tick's ``k0 + steps`` and
    ``stamp + steps step_ns`` [ns] are written into it: the usual tick writes nothing before the call. ``reals,
    ints, lp, dp`` (the drive profile's data, the held torque's copied in): the stepper's kernel loop
    (:class:`~belt_drive_ros.core.kernel_loop.KernelLoop`); ``rows`` packs ``[W (4 n), C (12 n), D (12 x 2), F_0,
    r_3, capstan_ratio, belt_mass, r_2 g, origin, dt, speed limit, message layout (4)]``; ``x`` (n,) the state, replaced by the new
    one; ``y`` the outputs. ``clamp``: ``lo, hi`` [s], the torque times clamped to them (``-inf, inf``: none; the
    stepper's special step at a held-torque jump: ``lo = t0`` after a jump at ``t0``, ``hi = left_of(t1)`` before
    one at ``t1``), and ``drive``: NaN, or the held drive torque's new value [N m], written into ``dp[0, 0]`` after
    the steps, before the outputs; read and set back to ``-inf, inf, NaN``. ``x``, ``y``, the message, ``dp`` and
    ``io`` are written only when every step is done.
    """
    packed = packed_at(address)
    table = packed.view(np.int64)
    rows, reals, ints, lp = _f1(packed, table, _ROWS), _f1(packed, table, _REALS), _i1(table, _INTS), _f2(packed, table, _LP)
    x, y, clamp, dp, io = _f1(packed, table, _X), _f1(packed, table, _Y), _f1(packed, table, _CLAMP), _f2(packed, table, _DP), _i1(table, _IO)
    k0, steps, stamp = io[0], io[1], io[2]
    lo, hi, drive = clamp[0], clamp[1], clamp[2]
    clamp[0], clamp[1], clamp[2] = -math.inf, math.inf, math.nan
    n = x.size
    d0 = 16 * n
    origin, dt, limit = rows[d0 + 29], rows[d0 + 30], rows[d0 + 31]
    if steps <= ROOM:  # (no allocation)
        times, out = _f1(packed, table, _TIMES)[: steps + 1], _f2(packed, table, _OUT)[:steps]
    else:
        times, out = np.empty(steps + 1), np.empty((steps, n))
    for j in range(steps + 1):
        times[j] = origin + dt * float(k0 + j)
    done, status, t = linear_steps(times, x, out, lo, hi, limit, reals, ints, dp, lp)
    if status != 0:
        return status
    if drive == drive:
        dp[0, 0] = drive
    xe = out[steps - 1]
    x[:] = xe
    io[0], io[2] = k0 + steps, stamp + steps * io[3]
    # the profiles' data inside the loop's arrays (the layout linear_steps unpacks)
    s = ints[1]
    at = ints[HEADER : HEADER + len(SECTIONS) + 1]
    k = HEADER + len(SECTIONS) + 1
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
    F_0, r_3, capstan, mass = rows[d0 + 24], rows[d0 + 25], rows[d0 + 26], rows[d0 + 27]
    half = 0.5 * abs(y[10]) / r_3  # belt_torque
    tight = F_0 + half
    slack_force = F_0 - half
    slack = slack_force <= 0.0
    y[12], y[13] = tight, slack_force
    if mass != 0.0:  # the centrifugal tension m' v^2 at v = r_2 g omega_M (params.centrifugal_tension)
        v = rows[d0 + 28] * y[1]
        F_c = mass * v * v
        slip = slack or tight - F_c > (slack_force - F_c) * capstan
    else:
        slip = slack or tight > slack_force * capstan
    y[14] = 1.0 if slack else 0.0
    y[15] = 1.0 if slip else 0.0
    write_joints(y, _f1(packed, table, _MSG).view(np.uint8), rows[d0 + 32 :], stamp)
    return -((SLACK if slack else 0) + (SLIPS if slip else 0))


def grid_step_ns(dt: float, origin: float) -> int:
    """The grid step [ns] when ``dt`` [s] is a whole number of nanoseconds and the grid starts at 0, else 0: then
    a node time ``origin_ns + k step_ns`` is the grid time ``k dt`` (which scene times snap to) with no rounding."""
    step_ns = round(dt * 1e9)
    return step_ns if step_ns > 0 and step_ns / 1e9 == dt and origin == 0.0 else 0


def joints_message(template: bytes | None = None, offsets=None) -> tuple[np.ndarray, slice, list]:
    """``(msg, where, at)``: the buffer :func:`write_joints` writes into, the message's bytes in it
    (``memoryview(msg)[where]``) and its layout ``at``. ``template``: the message's bytes, its stamp at bytes 4-12
    (little-endian int32 s, uint32 ns), its positions, velocities and efforts (four little-endian doubles each) at
    the byte ``offsets``, which share one alignment (as CDR's double sequences do); None: a scratch message.
    """
    if template is None:
        template, offsets = bytes(112), (12, 44, 76)
    shift = -offsets[0] % 8  # where the template starts in the buffer, so that its doubles are 8-byte aligned
    if any((shift + o) % 8 for o in offsets) or (shift + 4) % 4:
        raise ValueError("joint_states layout: its double arrays do not share one alignment")
    msg = np.zeros(-(-(shift + len(template)) // 8) * 8, dtype=np.uint8)
    msg[shift : shift + len(template)] = np.frombuffer(template, dtype=np.uint8)
    at = [float((shift + o) // 8) for o in offsets] + [float((shift + 4) // 4)]
    return msg, slice(shift, shift + len(template)), at


def load_compiled(kernel, args) -> None:
    """Load ``kernel``'s compiled code for ``args``' types now (numba's disk cache: 25-50 ms), not at a node's
    first tick."""
    if hasattr(kernel, "compile"):  # (not under NUMBA_DISABLE_JIT: a plain function)
        from numba import typeof

        kernel.compile(tuple(typeof(a) for a in args))


def _cells(a: np.ndarray) -> memoryview:
    """A C-contiguous float64 or int64 array's numbers as one flat memoryview: a Python number written into it
    costs a fraction of numpy's item assignment on cold caches."""
    return memoryview(a).cast("B").cast(a.dtype.char)


class TickKernel:
    """One stepper's tick as one compiled call: :meth:`step` advances :attr:`state`, :attr:`y` holds the outputs.

    The kernel loop's ``reals``, ``ints`` and both profiles' data are copied into the tick's buffer (the node's
    stepper never changes them, but for the held drive torque's value: a jump the kernel takes is written into the
    held torque's own array too, and a value set outside a tick is copied in by :meth:`drive_changed`).
    """

    def __init__(self, stepper, limit: float, message: tuple = ()):
        plant, loop = stepper.plant, stepper.loop
        model = plant.model
        n = model.A.shape[0]
        C, D = model.output_matrices()
        p = model.params
        msg, where, at = joints_message(*message)
        rows = np.concatenate([np.ravel(plant.wheel_map), np.ravel(C), np.ravel(D),
                               [p.F_0, p.r_3, p.capstan_ratio, p.belt_mass, p.r_2 * p.gear_ratio, stepper.origin,
                                stepper.dt, limit], at]).astype(np.float64)
        self.dt, self.origin = stepper.dt, stepper.origin
        self.step_ns = grid_step_ns(self.dt, stepper.origin)
        arrays = PackedArrays((LINEAR_FLOATS, LINEAR_INTS),
                              dict(rows=rows, reals=loop.reals, lp=loop._lp, dp=loop._dp, x=np.zeros(n),
                                   y=np.zeros(len(OUTPUT_UNITS)), msg=msg.view(np.float64),
                                   clamp=[-math.inf, math.inf, math.nan], times=np.zeros(ROOM + 1), out=np.zeros((ROOM, n))),
                              dict(ints=loop.ints, io=[0, 0, 0, self.step_ns]))  # fmt: skip
        views = arrays.views
        #: the outputs of the last :meth:`step` [SI units, OUTPUT_UNITS order; slack/slip as 0.0/1.0]
        self.y = views["y"]
        #: their flags (:data:`SLACK`, :data:`SLIPS`) after the last OK :meth:`step`
        self.flags = 0
        #: :attr:`y` as a memoryview (its ``tolist()``: the same floats as numpy's, ~2 us sooner on cold caches)
        self.values = memoryview(self.y)
        #: the state the last :meth:`step` reached (written again by the next one: a caller keeps it by copying)
        self.state = views["x"]
        #: the ``joint_states`` message of the last :meth:`step` (a view of its bytes)
        self.message = memoryview(views["msg"].view(np.uint8))[where]
        self._clamp, self._io = _cells(views["clamp"]), _cells(views["io"])
        #: the next call's clamps ``lo, hi, drive`` (:func:`linear_tick`'s; the kernel sets them back when it reads
        #: them): the node writes a plain tick's here (its :func:`linear_tick` call reads them; :meth:`step` writes all three)
        self.clamps = self._clamp
        self._drive, self._drive_copy = _cells(loop._dp), _cells(views["dp"])  # (the held torque's data, its copy)
        self._packed, self._address = arrays.reals, arrays.address  # (the kernel's argument: the buffer's address)
        load_compiled(linear_tick, (self._address,))

    @classmethod
    def of(cls, stepper, limit: float, message: tuple = ()):
        """The tick kernel of ``stepper`` (divergence beyond ``limit`` [rad/s]), or None where it cannot run;
        ``message``: ``(template, offsets)`` of the ``joint_states`` it writes (:func:`joints_message`; none: a
        scratch message)."""
        loop = getattr(stepper, "loop", None)
        if loop is None or stepper.plant.extra or stepper.guard is not None or not hasattr(stepper.plant.model, "C"):
            return None
        return cls(stepper, limit, message)

    def drive_changed(self) -> None:
        """The drive profile's data were written outside a tick (the held torque set): copied into the buffer."""
        self._drive_copy[:] = self._drive

    def step(self, x: np.ndarray, k0: int, k1: int, lo: float = -math.inf, hi: float = math.inf,
             drive: float = math.nan, stamp: int = 0) -> int:
        """Whole grid steps k0 -> k1 from state ``x``: the status; when OK the new state in :attr:`state`,
        :attr:`y` at k1 and :attr:`message` stamped ``stamp`` [ns] (``lo``, ``hi``, ``drive``:
        :func:`linear_tick`'s clamps; ``drive`` is written into the held torque's own data too). ``x`` is
        :attr:`state` on the usual tick (nothing copied)."""
        if x is not self.state:
            self.state[:] = x
        io = self._io
        io[0], io[1], io[2] = k0, k1 - k0, stamp
        clamp = self._clamp  # (all three: a plain tick's call may have left a clamp for the next, see clamps)
        clamp[0], clamp[1], clamp[2] = lo, hi, drive
        status = linear_tick(self._address)
        if status > 0:
            return status
        if drive == drive:
            self._drive[0] = drive
        self.flags = -status
        return 0


# ------------------------------------------------------------------ the slipping belt
#: constants of the slipping model's outputs in :func:`slip_tick` (:meth:`SlipTickKernel` packs them in this order)
SLIP_CONSTANTS = ("ratio", "r_3", "a_1", "g", "F_0", "q_1", "q_2", "q_3", "rel_2", "rel_3", "c", "2k r_3", "2c",
                  "belt speed ratio", "belt_mass", "capstan_factor")  # fmt: skip


#: mode switches a slipping tick takes itself (more: the engine redoes the tick)
EVENTS = 7
#: the slipping tick's sections (:class:`SlipTickKernel`): the hybrid loop's buffers of N steps, its phase state, the
#: engine's arrays (Z as pairs of doubles), outputs, message, the load's shifted numbers and the flexible state sticking
#: after slip, the drive profile's data (the held torque's copied in); ``fscalars``: ``lo, hi, drive, sigma5, dt,
#: limit, sigma``; ``iscalars``: the phase kind, how many of ``xs`` to start from (-1: ``x`` as it is), the call's
#: ``k0``, ``stamp`` [ns] and ``step_ns``
SLIP_FLOATS = ("grid", "knots", "lo", "hi", "out_y", "out_native", "out_sigma", "x", "xs", "reals", "Yflex", "Minv",
               "Z", "R", "c", "mats", "guards", "dx", "dy", "lp", "lx", "ly", "events", "consts", "y", "msg", "fscalars",
               "shifted", "flex", "dp")
SLIP_INTS = ("special", "out_mode", "ints", "offsets", "have", "uses", "dk", "lk", "iscalars")
(_GRID, _KNOTS, _SLO, _SHI, _OUT_Y, _OUT_NATIVE, _OUT_SIGMA, _SX, _SXS, _SREALS, _YFLEX, _MINV, _Z, _R, _C, _MATS,
 _GUARDS, _DX, _DY, _SLP, _LX, _LY, _EVENTS, _CONSTS, _SY, _SMSG, _FSCALARS, _SHIFTED, _FLEX, _SDP, _SPECIAL, _OUT_MODE,
 _SINTS, _OFFSETS, _HAVE, _USES, _DK, _LK, _ISCALARS) = range(len(SLIP_FLOATS) + len(SLIP_INTS))  # fmt: skip


@njit(cache=True, nogil=True)
def slip_tick(address):
    """The slipping belt's ``N`` whole grid steps of the buffers from grid index ``k0``, then every output
    of the slipping model at the last knot into ``y`` and the ``joint_states`` message stamped ``stamp`` [ns]
    (:func:`write_joints`). Returns ``-(n EVENT + flags)`` when done (the outputs' :data:`SLACK`, :data:`SLIPS`
    and always :data:`SLIPPING`), ``n`` events (mode switches) in the first rows of ``events``, and ``k0 + N``,
    ``stamp + N step_ns`` written into ``iscalars`` (the next tick's: the usual tick writes nothing before the
    call); else the hybrid loop's status (> 0): the buffers then hold the state the call started from.

    A tick whose steps cross no guard is the phase's linear loop alone (:func:`~.kernel.linear_steps`, stretch by
    stretch of equal clamps as :func:`~.kernel_hybrid.hybrid_steps` takes them; sticking after slip the flexible loop
    from ``Minv y``, the load's angle shifted by ``-s / r_3``; the same floats); any other runs ``hybrid_steps``
    from the start.

    ``packed``: :class:`SlipTickKernel`'s buffer (:data:`SLIP_FLOATS`, :data:`SLIP_INTS`) at ``address``, the one
    argument (:func:`linear_tick`'s reason); ``dp`` in it: the drive profile's data. The start: phase kind ``iscalars[0]``, its
    coordinates the first ``iscalars[1]`` of ``xs`` copied into ``x`` (-1: ``x`` as the last tick left
    it), zeros after them; ``sigma5`` (``fscalars[3]``), unless NaN, at ``x[5]`` (the stepwise phase's
    direction), ``fscalars[6]`` its sigma; ``xs`` keeps that ``x``. The sections up to ``events`` are the
    hybrid loop's arguments (``grid``, ``knots``: written with the grid times); ``lo``, ``hi``
    (``fscalars[0:2]``) clamp the first and the last step's torque times, ``drive`` (``fscalars[2]``)
    NaN or the held drive torque's new value written into ``dp[0, 0]`` after the steps, as
    :func:`linear_tick`'s, all three then set back. ``consts``: :data:`SLIP_CONSTANTS`, the grid's
    origin [s], the message layout. ``y``: ``OUTPUT_UNITS + SLIP_OUTPUT_UNITS``, the operations of
    :meth:`~belt_drive_ros.core.slip.SlippingBeltModel.outputs` on one sample (flags 0.0/1.0), ``u =
    [drive(t, phi_M, omega_M), load(t, phi_3, omega_3)]`` at the last knot ``t``. On 0, ``iscalars[0]``
    holds the new kind, ``x`` its coordinates, ``fscalars[6]`` its sigma and ``sigma5`` the same (NaN
    unless stepwise): the next call continues from it.
    """
    packed = packed_at(address)
    table = packed.view(np.int64)
    fs, js = _f1(packed, table, _FSCALARS), _i1(table, _ISCALARS)
    grid, knots, lo, hi = _f1(packed, table, _GRID), _f1(packed, table, _KNOTS), _f1(packed, table, _SLO), _f1(packed, table, _SHI)
    x, xs, consts, y = _f1(packed, table, _SX), _f1(packed, table, _SXS), _f1(packed, table, _CONSTS), _f1(packed, table, _SY)
    out_y = _f2(packed, table, _OUT_Y)
    kind, given, k0, stamp = js[0], js[1], js[2], js[3]
    dp = _f2(packed, table, _SDP)
    if given >= 0:
        for j in range(x.size):
            x[j] = xs[j] if j < given else 0.0
        js[1] = -1  # the next call continues from x (the caller gives a state again after a failure)
    else:
        for j in range(PHASE_SIZE[kind], x.size):
            x[j] = 0.0
    sigma5, drive, dt, limit = fs[3], fs[2], fs[4], fs[5]
    if sigma5 == sigma5:
        x[5] = sigma5
    for j in range(x.size):  # the state this call starts from, put back when the engine has to redo the steps
        xs[j] = x[j]
    N = grid.size - 1
    lo[0], hi[N - 1] = fs[0], fs[1]
    fs[0], fs[1], fs[2] = -math.inf, math.inf, math.nan
    for j in range(grid.size):  # the grid times origin + dt k of Stepper._grid; the knots are them
        grid[j] = consts[16] + dt * float(k0 + j)
        knots[j] = grid[j]
    dk, dx, dy = _i1(table, _DK), _f1(packed, table, _DX), _f1(packed, table, _DY)
    lk, lp, lx, ly = _i1(table, _LK), _f2(packed, table, _SLP), _f1(packed, table, _LX), _f1(packed, table, _LY)
    reals, ints, offsets, have = _f1(packed, table, _SREALS), _i1(table, _SINTS), _i2(table, _OFFSETS), _i1(table, _HAVE)
    sigma = 1.0 if kind == SLIP_UP or kind == MASS_UP else -1.0 if kind == SLIP_DOWN or kind == MASS_DOWN else 0.0
    status = n_ev = -1
    Yflex, Minv, c = _f2(packed, table, _YFLEX), _f2(packed, table, _MINV), _f1(packed, table, _C)
    uses = _i1(table, _USES)
    if kind != STEPWISE and have[kind] == 2:
        # the usual tick: the phase's linear loop alone, stretch by stretch of equal clamps (hybrid_steps' stretches),
        # its states in out_native's room (sticking after slip: hybrid_steps' flexible loop, the load shifted by the
        # slip s = y[4]); any guard, failure or missing phase: hybrid_steps below from the start
        loop = FLEXIBLE if kind == STICKING else kind
        n, r0, r1, i0, i1 = PHASE_SIZE[loop], offsets[loop, 0], offsets[loop, 1], offsets[loop, 2], offsets[loop, 3]
        room = packed[table[4 * _OUT_NATIVE] : table[4 * _OUT_NATIVE] + 6 * N]
        start, load, s = x[:n], lp, x[4]
        if kind == STICKING:
            start, load = _f1(packed, table, _FLEX), _shift_angle(lk, lp, _f2(packed, table, _SHIFTED), c, uses, s)
        k = status = n_ev = 0
        while k < N and status == 0:
            j = k + 1
            while j < N and lo[j] == lo[k] and hi[j] == hi[k]:
                j += 1
            states = doubles_view(room, 0, (j - k, n))
            if kind == STICKING:
                _flexible(x, Minv, start)
            _, status, _ = linear_steps(grid[k : j + 1], start, states, lo[k], hi[k], limit, reals[r0:r1],
                                        ints[i0:i1], dp, load)  # fmt: skip
            if kind == STICKING:  # y of the flexible state, the slip s kept
                _to_y(FLEXIBLE, states[j - k - 1], Yflex, x)
                x[4] = s
            else:
                x[:n] = states[j - k - 1]
            k = j
    if status != 0:  # k0 and n0 as int64, not literal zeros (a literal would compile the hybrid loop again)
        x[:] = xs
        zero = np.int64(0)
        _, status, kind, sigma, n_ev = hybrid_steps(
            grid, knots, lo, hi, _i1(table, _SPECIAL), zero, kind, x, dt, limit, out_y, _i1(table, _OUT_MODE),
            _f1(packed, table, _OUT_SIGMA), _f2(packed, table, _OUT_NATIVE), reals, ints, offsets, have, Yflex, Minv,
            _f3(packed, table, _Z).view(np.complex128), _f2(packed, table, _R), c, _f2(packed, table, _MATS),
            _f2(packed, table, _GUARDS), uses, dk, dp, dx, dy, lk, lp, lx, ly, _f2(packed, table, _EVENTS),
            zero)  # fmt: skip
    lo[0], hi[N - 1] = -math.inf, math.inf
    if status != 0:
        x[:] = xs
        return status
    _to_y(kind, x, Yflex, out_y[N - 1])  # the state's y (after a restick: Yflex Minv y)
    js[0] = kind
    fs[3] = sigma if kind == STEPWISE else math.nan  # the next call's sigma5 when it continues from this state
    fs[6] = sigma
    if drive == drive:
        dp[0, 0] = drive
    js[2], js[3] = k0 + N, stamp + N * js[4]
    slipping = kind > STICKING
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
    Q = sigma * qmax if slipping else stick
    speed = 0.0
    if slipping:
        rel = y2 * consts[8] + y3 * consts[9]
        speed = rel if consts[10] == 0.0 else rel - (Q - consts[11] * y1) / consts[12]
    half = 0.5 * abs(Q)  # (SlippingBeltModel.outputs: the tight span is the stretched one, either way)
    slack_force = F_0 - half
    tight = F_0 + half
    slip_angle = y4 / r_3
    low = tight if tight < slack_force else slack_force  # Python's min(slack_force, tight)
    y[0], y[1], y[2], y[3], y[4], y[5] = y0, y2, a1 * y0, a1 * y2, g * y0, g * y2
    y[6], y[7], y[8], y[9], y[10], y[11] = phi_3, y3, u0, u1, r_3 * Q, y1 + slip_angle
    y[12], y[13] = tight, slack_force
    y[14] = 1.0 if low <= 0.0 else 0.0
    y[15] = 1.0 if slipping else 0.0
    bits = SLIPPING + (SLACK if low <= 0.0 else 0) + (SLIPS if slipping else 0)
    y[16], y[17], y[18], y[19] = y1, slip_angle, y4, speed
    y[20] = Q / qmax if qmax > 0 else math.inf
    y[21] = qmax
    write_joints(y, _f1(packed, table, _SMSG).view(np.uint8), consts[17:], stamp)
    return -(n_ev * EVENT + bits)


class SlipTickKernel:
    """A slipping engine's (:class:`~belt_drive_ros.core.slip_run.SlippingSimulator`) tick of whole steps as one
    compiled call (:func:`slip_tick`), its buffers packed again when a phase's stepper was built or the steps
    per tick changed; :attr:`y` holds the outputs. The hybrid state stays in the buffers between ticks:
    :meth:`state` builds it as a :class:`~belt_drive_ros.core.slip_run.SlipState` when asked."""

    def __init__(self, engine, limit: float, message: tuple = ()):
        m, p = engine.model, engine.model.params
        q, rel = m._q, m.rel_row.tolist()
        self._msg, self._where, at = joints_message(*message)
        self.consts = np.array([p.ratio, p.r_3, p.r_M / p.R_1, p.gear_ratio, p.F_0, q[1], q[2], q[3], rel[2], rel[3],
                                p.c, 2.0 * p.k * p.r_3, 2.0 * p.c, p.r_2 * p.gear_ratio, float(p.belt_mass),
                                p.capstan_factor, engine.origin, *at], dtype=np.float64)  # fmt: skip
        self.engine, self.dt, self.origin, self.limit = engine, engine.dt, engine.origin, limit
        self.step_ns = grid_step_ns(engine.dt, engine.origin)
        self.y = np.zeros(22)
        #: the outputs' flags after the last done :meth:`advance` (:data:`SLIPPING` and
        #: :data:`SLACK`, :data:`SLIPS`)
        self.flags = SLIPPING
        self.values = memoryview(self.y)  # (as TickKernel.values)
        #: the slipping state ``y`` (5,) after the last :meth:`advance` (a view: the next one writes it again)
        self.end_y = np.zeros(5)
        self.message = None
        self.N = 1
        self._built = -1  # how many phase steppers the engine had when its arrays were packed (see _pack)
        self._packed: np.ndarray | None = None  # slip_tick's buffer (None: the engine cannot compile)
        self._pack(1)

    def _pack(self, N: int) -> None:
        """The engine's compiled arrays and the buffers of ``N`` whole steps without clamps or splits as
        :func:`slip_tick`'s buffers."""
        compiled = self.engine._compiled()
        self._built, self.N = len(self.engine._steppers), N
        if compiled is None:
            self._packed = None
            return
        have, reals, ints, offsets, Yflex, Minv, (Z, R, c, mats, guards, uses, dk, dp, dx, dy, lk, lp, lx, ly) = compiled
        arrays = PackedArrays(
            (SLIP_FLOATS, SLIP_INTS),
            dict(grid=np.zeros(N + 1), knots=np.zeros(N + 1), lo=np.full(N, -math.inf), hi=np.full(N, math.inf),
                 out_y=np.zeros((N, 5)), out_native=np.zeros((N, 6)), out_sigma=np.zeros(N), x=np.zeros(6),
                 xs=np.zeros(6), reals=reals, Yflex=Yflex, Minv=Minv, Z=Z.view(np.float64), R=R, c=c, mats=mats,
                 guards=guards, dx=dx, dy=dy, lp=lp, lx=lx, ly=ly,
                 # room for a chattering step's switches (the hybrid loop wants it) and EVENTS more (then the engine)
                 events=np.zeros((MAX_SWITCHES + 1 + EVENTS, 8)),
                 consts=self.consts, y=self.y, msg=self._msg.view(np.float64),
                 fscalars=[-math.inf, math.inf, math.nan, math.nan, self.dt, self.limit, 0.0], shifted=lp,
                 flex=np.zeros(4), dp=dp),
            dict(special=np.zeros(N, dtype=np.int64), out_mode=np.zeros(N, dtype=np.int64), ints=ints, offsets=offsets,
                 have=have, uses=uses, dk=dk, lk=lk, iscalars=[0, 0, 0, 0, self.step_ns]))  # fmt: skip
        views = arrays.views
        self.y, self._x, self._xs, self.end_y = views["y"], views["x"], views["xs"], views["out_y"][-1]
        self.values = memoryview(self.y)
        self._fs, self._js, self._events = views["fscalars"], views["iscalars"], views["events"]
        self._fcells, self._jcells = _cells(self._fs), _cells(self._js)
        #: the next call's clamps ``lo, hi, drive`` in its first three cells (:func:`slip_tick`'s ``fscalars``): the
        #: node writes a plain tick's here (its :func:`slip_tick` call reads them; :meth:`advance` writes all three)
        self.clamps = self._fcells
        self._drive, self._drive_copy = _cells(dp), _cells(views["dp"])  # (the held torque's data, its copy)
        self.message = memoryview(views["msg"].view(np.uint8))[self._where]
        self._packed, self._address = arrays.reals, arrays.address  # (the kernel's argument: the buffer's address)
        load_compiled(slip_tick, (self._address,))

    def drive_changed(self) -> None:
        """The drive profile's data were written outside a tick (the held torque set): copied into the buffer."""
        if self._packed is not None:
            self._drive_copy[:] = self._drive

    def advance(self, state, k0: int, k1: int, lo: float = -math.inf, hi: float = math.inf, drive: float = math.nan,
                stamp: int = 0) -> list | None:
        """The whole grid steps k0 -> k1 from ``state`` (a SlipState; None: the buffers' state), the outputs at
        t1 in :attr:`y`, :attr:`message` stamped ``stamp`` [ns]; ``lo``, ``hi``, ``drive``: :func:`slip_tick`'s.
        The mode switches in them when done (:class:`~belt_drive_ros.core.slip.Event`; an empty tuple: none);
        None when the engine's own ``advance`` must redo it from :meth:`state` (a failure, more than
        :data:`EVENTS` switches)."""
        # (only the engine's own advance, from a state object, builds a phase stepper: the usual tick needs no look)
        if k1 - k0 != self.N or state is not None and len(self.engine._steppers) != self._built:
            if state is None:
                state = self.state()
            self._pack(k1 - k0)
        if self._packed is None:
            return None
        js, fs = self._jcells, self._fcells
        if state is not None:  # else the usual tick: x holds the state the last call reached, iscalars its kind
            js[0], js[1] = _kind_code(state), len(state.x)
            self._xs[: len(state.x)] = state.x
            fs[3] = state.sigma if state.kind == "hybrid" else math.nan
            fs[6] = state.sigma
        js[2], js[3] = k0, stamp
        fs[0], fs[1], fs[2] = lo, hi, drive  # (all three: a clamp left for the next call, see clamps)
        done = slip_tick(self._address)
        if done > 0:
            return None
        if drive == drive:
            self._drive[0] = drive  # (the kernel wrote its copy)
        self.flags, n = -done & (EVENT - 1), -done // EVENT
        return _events(self._events[:n]) if n else ()

    def state(self) -> SlipState:
        """The hybrid state the buffers hold: the last :meth:`advance`'s (where it failed, the one it started from)."""
        kind = int(self._js[0])
        return SlipState(STICK if kind <= STICKING else SLIP, float(self._fs[6]), KIND_NAMES[kind],
                         self._x[: PHASE_SIZE[kind]].copy())


def warm() -> None:
    """Compile (or load from the disk cache) :func:`linear_tick` and :func:`slip_tick` with the one
    signature the node uses (``make install`` calls it through :func:`~belt_drive_ros.core.warm.warm`)."""
    from .model import FlexibleBeltModel
    from .params import BeltDriveParams
    from .sources import Constant
    from .stepper import Plant, Stepper

    params, torque = BeltDriveParams(), Constant(1.0)  # (a tick kernel loads its compiled code when built)
    TickKernel.of(Stepper(Plant(FlexibleBeltModel(params), torque, torque), "exact", 1e-3), 1.0e5)
    SlipTickKernel(SlippingSimulator(params, torque, torque, "etd2", 1e-3, check_stability=False), 1.0e5)

"""The arrays one plant and one fixed-step method hand to the compiled loop, built once.

:class:`KernelLoop` turns the method's StageScheme, the plant's wheel map,
both profiles' data, the extra input and a guard into the arrays of
:func:`belt_drive_ros.core.kernel.linear_steps`, and calls it with them.
"""

from __future__ import annotations

import math

import numpy as np

from .identity_cache import built_once
from .profile_data import DIVERGED, GUARDED, NOT_CONVERGED, OK  # noqa: F401 (re-exported for the stepper)


class FrictionForce:
    """The slipping belt's extra input ``sigma Q_max(omega_M)`` [N] as data for the kernel.

    ``Q_max = max((F_0 - m' v^2) k_c, 0)`` with ``v = r omega_M`` (``r`` = r_2
    times the gear ratio, ``k_c`` the capstan factor; see
    :meth:`~belt_drive_ros.core.params.BeltDriveParams.friction_limit`);
    :meth:`value` is the same operations in Python (the stepper's ``inputs``, which scipy's methods and the
    guards' probes call).
    """

    def __init__(self, sigma: float, params):
        self.row = np.array([float(sigma), float(params.F_0), float(params.belt_mass),
                             float(params.r_2 * params.gear_ratio), float(params.capstan_factor)])
        self.sigma, self._limit = float(sigma), params.scalar_friction_limit()

    def value(self, omega_M: float) -> float:
        return self.sigma * self._limit(omega_M)


def guard_array(guard, n: int) -> np.ndarray:
    """A :class:`~belt_drive_ros.core.stage_scheme.Guard` (or None) as the kernel's ``(5 + 2n,)`` array."""
    out = np.zeros(5 + 2 * n)
    if guard is None:
        return out
    out[0], out[1], out[2], out[3] = 1.0, float(bool(guard.absolute)), float(guard.bound), float(guard.quad)
    out[5 : 5 + n] = np.asarray(guard.row, dtype=float)
    if guard.speed is not None:
        out[4] = 1.0
        out[5 + n :] = np.asarray(guard.speed, dtype=float)
    return out


def scheme_arrays(scheme, dt: float, W, m: int):
    """A fixed-step method's :class:`~belt_drive_ros.core.stage_scheme.StageScheme` as the arrays of
    :func:`~belt_drive_ros.core.kernel.wheel_steps`: ``(kinds, offsets, S, F, final_base, tol, max_iter)``.

    ``W`` (V, 2P, n): the wheel map (V variants: the scheme's matrices carry the same leading axis, or none);
    ``m``: inputs per stage (P torques and the extras). ``S`` (V, s, max(2P, n), n + m s): stage i's map,
    zero-padded, as ``W @ map`` where only its wheel coordinates feed the torques (kind 1) or the map itself
    for the stage whose state starts the final map (kind 2; kind 0: the stage state is x);
    ``F`` (V, n, n + m s) the final map. ``dt`` (K,) steps: a scheme of K steps at once
    (:func:`~belt_drive_ros.core.integrators.stacked_scheme`, one plant's W), V = K and ``offsets`` (K, s).
    """
    n = W.shape[2]
    s = len(scheme.nodes)
    cols = n + m * s
    final = np.asarray(scheme.final, dtype=float)
    final = final if final.ndim == 3 else final[None]
    V = max(W.shape[0], final.shape[0])
    if final.shape[1:] != (n, cols):
        raise ValueError(f"kernel loop: the scheme's final map is {final.shape[1:]}, expected {(n, cols)}")
    rows = max(W.shape[1], n)
    kinds = np.zeros(s, dtype=np.int64)
    S = np.zeros((V, s, rows, cols))
    for i, M in enumerate(scheme.stages):
        if M is None or (scheme.implicit and i == s - 1):
            continue
        M = M if M.ndim == 3 else M[None]
        padded = np.zeros((M.shape[0], M.shape[1], cols))
        padded[:, :, : M.shape[2]] = M
        if scheme.final_base == i:
            kinds[i] = 2
        else:  # only the wheel coordinates feed the torques: W @ the stage map (matrix by matrix)
            kinds[i], padded = 1, W @ padded
        S[:, i, : padded.shape[1]] = padded
    if np.ndim(dt):  # c h of each step (the same product as a step's own)
        offsets = np.zeros((np.size(dt), s))
        for i, c in enumerate(scheme.nodes):
            if c:
                offsets[:, i] = c * np.asarray(dt, dtype=float)
    else:
        offsets = np.array([float(c * dt) if c else 0.0 for c in scheme.nodes])
    final_base = -1 if scheme.final_base is None else int(scheme.final_base)
    tol, max_iter = (float(scheme.implicit[0]), int(scheme.implicit[1])) if scheme.implicit else (0.0, 0)
    return kinds, offsets, S, final, final_base, tol, max_iter


#: a single plant's ``reals`` before the tables and its ``ints``, by (scheme, step, wheel map, extras, guard, profile
#: kinds and table sizes): numbers of the method and the plant only (a cached integrator's scheme is read-only),
#: so the guards' and the run's loops of one scene, and a repeated run, build them once
_OWN: dict = {}
_USABLE: dict = {}  # scheme -> its matrices are real
OWN_CACHE_SIZE = 256


class KernelLoop:
    """``loop(times, x, out, lo, hi) -> (done, status, t)``: :func:`~belt_drive_ros.core.kernel.linear_steps` for one plant.

    Parameters
    ----------
    scheme : the method's StageScheme; dt : its step [s] (stage times ``t + c_i dt``).
    wheel_map : (4, n); uses_angle : (drive, load) flags.
    drive, load : :class:`~belt_drive_ros.core.profile_data.ProfileData`.
    extra : tuple of :class:`FrictionForce` (the inputs after the two torques).
    guard : optional Guard.

    Variants: a scheme whose matrices carry a leading variant axis (V, ...)
    and a wheel map (V, 4, n) give ``reals`` of shape (V, R), one row per
    variant in the layout of one plant (the same operations build each row:
    row v is what the plant of variant v alone gets), for
    :func:`~belt_drive_ros.core.kernel_variants.variant_steps`; ``ints`` and
    the profiles are shared.
    """

    def __init__(self, scheme, dt: float, wheel_map, uses_angle, drive, load, extra=(), guard=None):
        from . import kernel

        self._steps, self._clamped, self._pieces = kernel.linear_steps, kernel.clamped_steps, kernel.piece_steps
        W = np.asarray(wheel_map, dtype=float)
        stacked = W.ndim == 3
        W = W if stacked else W[None]  # (V, 4, n)
        V, n = W.shape[0], W.shape[2]
        self.uses_angle = uses = np.array([bool(u) for u in uses_angle], dtype=np.int64)
        self.drive, self.load = drive, load
        d, l = drive, load
        tables = (d.tx, d.ty, l.tx, l.ty)
        guard_row = guard_array(guard, n)
        # the profiles' parameters stay their own arrays: a held torque's value written in place is read
        self._dp, self._lp = d.params, l.params
        #: the profiles' tables: after the plant's numbers in a single run's ``reals``, apart for variants (shared)
        self.tables = np.concatenate([np.ravel(a) for a in tables]).astype(np.float64)

        def build(scheme=scheme, dt=dt, guard_row=guard_row):  # (no reference to self: _own_of keeps it)
            kinds, offsets, S, final, final_base, tol, max_iter = scheme_arrays(scheme, dt, W, 2 + len(extra))
            extra_rows = np.array([e.row for e in extra], dtype=np.float64).reshape(len(extra), 5)
            sections = (W, offsets, S, final, np.array([tol]), extra_rows, guard_row, *tables)
            # per row (a variant's, or a step's of a stacked scheme of steps): W, S, F, and the offsets of steps
            rowwise = (True, offsets.ndim == 2, True, True, False, False, False)
            starts = np.cumsum([0] + [a[0].size if r else a.size for a, r in zip(sections, rowwise + (False,) * 4)])
            # the plant's and method's numbers (per variant, or step; one plant's in a row of its own); then the
            # profiles' tables (shared)
            R = max(V, S.shape[0])
            own = np.concatenate(
                [np.broadcast_to(a.reshape(a.shape[0], -1) if r else np.ravel(a), (R, a[0].size if r else a.size))
                 for a, r in zip(sections[:7], rowwise)], axis=1,
            ).astype(np.float64) if stacked or R > 1 else np.concatenate([np.ravel(a) for a in sections[:7]]).astype(np.float64)
            header = [n, kinds.size, len(extra), S.shape[2], S.shape[3], final_base, max_iter, *uses]
            return own, np.concatenate([header, starts, kinds, d.kinds, l.kinds]).astype(np.int64)

        self._own_of = None  # (scheme, dt) -> the unguarded own numbers of one plant (None: stacked, other extras)
        self._rows_of = None  # (a stacked scheme, its steps) -> those numbers as rows (:meth:`piece_rows`)
        self._piece = None  # the loop :meth:`piece` rewrites, made on first use
        if stacked or not all(isinstance(e, FrictionForce) for e in extra):
            own, self.ints = build()
            if stacked:
                self.reals = own
                return
        else:  # one plant: the method's and plant's numbers built once per scheme (a cached integrator's), read-only
            rows = np.array([e.row for e in extra], dtype=np.float64).reshape(len(extra), 5)
            key = (W.tobytes(), rows.tobytes(), self.uses_angle.tobytes(), d.kinds.tobytes(), l.kinds.tobytes(),
                   *(a.size for a in tables))  # fmt: skip
            own, ints = built_once(_OWN, OWN_CACHE_SIZE, (scheme,), build, (float(dt), guard_row.tobytes(), *key))
            self.ints = ints.copy()  # its own: the node's tick writes into a loop's ints
            unguarded = guard_array(None, n)

            def own_of(other, h):
                return built_once(_OWN, OWN_CACHE_SIZE, (other,), lambda: build(other, h, unguarded),
                                  (float(h), unguarded.tobytes(), *key))

            self._own_of, self._ints0 = own_of, ints
            self._rows_of = lambda other, steps: build(other, steps, unguarded)
        self.reals = np.concatenate([own, self.tables])
        self.tables = self.reals[own.size :]  # a view: a recording's samples held once

    def piece(self, scheme, dt: float):
        """The loop of this plant for ``scheme``, another step ``dt`` [s] of the same method (a partial step's), with
        no guard: one loop per loop, whose ``reals`` head is rewritten with that scheme's numbers on each call (the
        plant's tables are not copied again: a recording's hold ~16 bytes a sample), so use it before the next call.
        The same arrays as ``KernelLoop(scheme, dt, ...)`` of the plant (the same floats); None where that is not
        one layout (stacked variants, another extra input, a scheme of other stage kinds)."""
        if self._own_of is None:
            return None
        size = self.reals.size - self.tables.size
        # (scheme, its numbers or None) by the scheme's identity and step: the checks below made once per partial
        # step's integrator (the survey's and the windows' partial steps repeat theirs at every run)
        known = self.__dict__.setdefault("_piece_numbers", {})
        found = known.get((id(scheme), dt))
        if found is None or found[0] is not scheme:
            own = None
            if KernelLoop.usable(scheme):
                own, ints = self._own_of(scheme, dt)
                if own.size != size or not np.array_equal(ints, self._ints0):
                    own = None
            if len(known) >= OWN_CACHE_SIZE:
                known.clear()
            found = known[(id(scheme), dt)] = (scheme, own)
        own = found[1]
        if own is None:
            return None
        loop = self._piece
        if loop is None:
            loop = self._piece = object.__new__(KernelLoop)
            loop.__dict__.update(self.__dict__)
            loop._piece, loop._own_of = None, None
            loop.reals, loop.ints = self.reals.copy(), self._ints0.copy()
            loop.tables = loop.reals[size:]
        loop.reals[:size] = own
        return loop

    def piece_rows(self, scheme, steps):
        """The numbers of this plant's loop (unguarded) for ``scheme``, a stacked scheme of the method's ``steps`` [s]
        (:func:`~belt_drive_ros.core.integrators.stacked_scheme`), as (K, R) rows: row k the head of ``reals`` of
        :meth:`piece` ``(scheme_k, steps[k])`` (the same floats), for :meth:`pieces`; None where :meth:`piece`
        would be None."""
        if self._own_of is None or scheme is None or not KernelLoop.usable(scheme):
            return None
        rows, ints = self._rows_of(scheme, np.asarray(steps, dtype=float))
        if rows.ndim != 2 or rows.shape[1] != self.reals.size - self.tables.size or not np.array_equal(ints, self._ints0):
            return None
        return rows

    def pieces(self, times, x, out, sets, lo, hi, rows, limit: float = 1.0e5):
        """Steps ``times[k] -> times[k+1]`` of other lengths (the pieces of split steps), states into ``out[k]``, in one
        compiled call: step k with the method's numbers of row ``sets[k]`` of ``rows`` (:meth:`piece_rows`; row 0
        may be this loop's own head) and torque times clamped into ``[lo[k], hi[k]]``:
        :func:`~belt_drive_ros.core.kernel.piece_steps` (``(steps done, status, t)``)."""
        if not x.flags.writeable:  # (one signature, as __call__)
            x = x.copy()
        return self._pieces(times, x, out, sets, lo, hi, rows, limit, self.reals, self.ints, self._dp, self._lp)

    def __call__(self, times, x, out, lo: float = -math.inf, hi: float = math.inf, limit: float = 1.0e5):
        # numba types a read-only array apart: a writable copy keeps the kernel's one signature
        if not x.flags.writeable:
            x = x.copy()
        if not times.flags.writeable:
            times = times.copy()
        return self._steps(times, x, out, lo, hi, limit, self.reals, self.ints, self._dp, self._lp)

    def clamped(self, times, x, out, c0: int, c1: int, base: int, cells, lo, hi, ends, half: float, limit: float = 1.0e5):
        """Steps ``c0 .. c1 - 1`` of ``times`` with their clamps at breakpoints on the knots, in one compiled call:
        :func:`~belt_drive_ros.core.kernel.clamped_steps` (its arguments; ``(steps done, status, t)``)."""
        return self._clamped(times, x, out, c0, c1, base, cells, lo, hi, ends, half, limit, self.reals, self.ints,
                             self._dp, self._lp)  # fmt: skip

    @staticmethod
    def usable(scheme) -> bool:
        """Whether a scheme's matrices are real (the kernel's arrays are float64; read once per cached scheme)."""
        return built_once(_USABLE, OWN_CACHE_SIZE, (scheme,), lambda: not np.iscomplexobj(scheme.final)
                          and all(M is None or not np.iscomplexobj(M) for M in scheme.stages))


def _warm_loop(stacked: bool):
    """(a constant profile's data, a 2-state KernelLoop of it: one plant, or one variant of a stacked scheme)."""
    from .profile_data import CONSTANT, ProfileBuilder
    from .stage_scheme import StageScheme

    builder = ProfileBuilder()
    builder.row(CONSTANT, 1.0)
    data, n = builder.build(), 2
    final, W = np.hstack([np.eye(n), np.zeros((n, 2))]), np.vstack([np.eye(n), np.eye(n)])
    scheme = StageScheme((0.0,), (None,), final[None] if stacked else final)
    return data, KernelLoop(scheme, 1e-3, W[None] if stacked else W, (False, False), data, data)


def warm() -> None:
    """Compile (or load from the disk cache) the profile dispatcher, the linear loop and the outputs' affine map
    (:mod:`~belt_drive_ros.core.kernel_affine`) with the one signature runs use (:func:`belt_drive_ros.core.warm.warm`
    warms every kernel; the variant loop: :func:`warm_variants`)."""
    from . import kernel_affine
    from .kernel_profiles import profile_torque, profile_torque_array

    kernel_affine.warm()  # (a long run's outputs: model._affine)
    data, loop = _warm_loop(False)
    profile_torque(data.kinds, data.params, data.tx, data.ty, 0.0, 0.0, 0.0)
    one = np.zeros(1)
    profile_torque_array(data.kinds, data.params, data.tx, data.ty, one, one, one, np.empty(1))
    loop(np.array([0.0, 1e-3]), np.zeros(2), np.empty((1, 2)))
    none = np.zeros(0, dtype=np.int64)
    loop.clamped(np.array([0.0, 1e-3]), np.zeros(2), np.empty((1, 2)), 0, 1, 0, none, np.zeros(0), np.zeros(0),
                 np.zeros(1, dtype=np.int64), 5e-4)  # fmt: skip
    loop.pieces(np.array([0.0, 1e-3]), np.zeros(2), np.empty((1, 2)), np.zeros(1, dtype=np.int64), np.full(1, -math.inf),
                np.full(1, math.inf), loop.reals[None, : loop.reals.size - loop.tables.size].copy())  # fmt: skip


def warm_variants() -> None:
    """Compile (or load from the disk cache) the variant loop (it calls the linear loop's dispatcher
    ``_steps`` for variants it does not step as lanes: loaded from the cache where that is warm)."""
    from .kernel_variants import knot_torques, variant_steps

    data, ens = _warm_loop(True)
    variant_steps(np.array([0.0, 1e-3]), np.zeros((2, 2, 1)), 0, -math.inf, math.inf, 1.0e5, ens.reals, ens.tables,
                  ens.ints, data.params, data.params, np.zeros(1, dtype=np.int64))  # fmt: skip
    knot_torques(data.kinds, data.params, data.tx, data.ty, np.zeros(1), np.zeros((1, 1)), np.zeros((1, 1)), np.empty((1, 1)))

"""The linear (flexible) tier of a belt network: ``M q'' + C q' + K q = f(t, q, q')`` (derived in
``docs/serpentine.md``, "The model (linear tier)").

``q = [theta_0 .. theta_{n-1}, theta_a]``: each pulley's rotation [rad] (positive moves the belt forward) and the
tensioner arm's angle from its installed angle [rad]. Span j stretches by ``delta_j = a_j . q`` (``r_{j+1}
theta_{j+1} - r_j theta_j + g_j theta_a``, ``g_j = (dc_{j+1}/dtheta_a - dc_j/dtheta_a) . e_j``) and carries ``T_j = T_0
+ k_j delta_j + c_j delta_j'`` (``k_j = EA / L_j``, ``c_j = damping / L_j``)::

    M = diag(J_i, J_a)    K = sum_j k_j a_j a_j^T + (k_a + k_geo) e_a e_a^T    k_geo = sum_j T_j* dg_j/dtheta_a
    C = sum_j c_j a_j a_j^T + diag(b_i, c_a)          f_i = Q_i(t, theta_i, theta_i')

K is symmetric with one zero mode (the belt turning all pulleys, no stretch).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import SceneError, UnstableStepError
from ..identity_cache import built_once


# ---------------------------------------------------------------------- tensioner arm geometry
def arm(pulleys, tensioner) -> tuple[int, np.ndarray, float, float]:
    """``(index of the tensioner pulley, pivot [m], arm length L_a [m], installed arm angle theta_0 [rad])``."""
    t = [p.name for p in pulleys].index(tensioner.pulley)
    c = np.asarray(pulleys[t].centre, dtype=float)
    p = np.asarray(tensioner.pivot, dtype=float)
    return t, p, float(np.hypot(*(c - p))), float(math.atan2(c[1] - p[1], c[0] - p[0]))


def arm_terms(geo, pulleys, tensioner) -> tuple[np.ndarray, np.ndarray]:
    """``(g, dg)`` per span at the installed angle: ``g_j = d delta_j / d theta_a`` [m/rad] and ``dg_j/dtheta_a``
    [m/rad^2], non-zero for the two spans at the tensioner pulley only (arm ``La``: ``c_t' = La (-sin, cos)``,
    ``c_t'' = -La (cos, sin)``; the span turning at ``psi' = (d x d')/D^2 + dr (d . d') / (D^2 L)``)."""
    n = len(pulleys)
    t, _, La, th = arm(pulleys, tensioner)
    c1 = La * np.array([-math.sin(th), math.cos(th)])
    c2 = -La * np.array([math.cos(th), math.sin(th)])
    g, dg = np.zeros(n), np.zeros(n)
    rho = np.array([p.side * p.radius for p in pulleys])
    for j, sgn in (((t - 1) % n, 1.0), (t, -1.0)):  # arriving at t: d' = +c1; leaving t: d' = -c1
        k = (j + 1) % n
        d = np.asarray(pulleys[k].centre, dtype=float) - np.asarray(pulleys[j].centre, dtype=float)
        D2, dr, L = float(d @ d), rho[k] - rho[j], geo.lengths[j]
        e = geo.directions[j]
        nrm = np.array([-e[1], e[0]])
        dd = sgn * c1
        psi1 = (d[0] * dd[1] - d[1] * dd[0]) / D2 + dr * float(d @ dd) / (D2 * L)
        g[j] = float(dd @ e)
        dg[j] = float(sgn * c2 @ e) + float(dd @ nrm) * psi1
    return g, dg


def _times_rows(X, rows) -> np.ndarray:
    """``X @ rows.T`` for samples X (N, m) or one sample (m,), both operands C-contiguous (100x faster on a run)."""
    X = np.ascontiguousarray(X, dtype=float)
    return X @ np.ascontiguousarray(rows.T)


# ---------------------------------------------------------------------- the linear model
@dataclass(frozen=True)
class NetworkModel:
    """Matrices of the linear tier for one scene (see the module docstring).

    ``stretch`` (n_spans, m): rows ``a_j``; ``k``, ``c``: per-span stiffness [N/m] and damping [N s/m];
    ``M``, ``C``, ``K`` (m, m) with ``K`` excluding the arm's geometric stiffness (``k_geo`` per tension: :meth:`stiffness`);
    ``g``, ``dg``: the arm terms per span (zeros without a tensioner); ``arm``: index of theta_a or -1.
    """

    scene: object
    stretch: np.ndarray
    k: np.ndarray
    c: np.ndarray
    M: np.ndarray
    C: np.ndarray
    K_belt: np.ndarray
    g: np.ndarray
    dg: np.ndarray
    arm: int

    @classmethod
    def build(cls, scene) -> "NetworkModel":
        P, geo, n = scene.pulleys, scene.geometry, len(scene.pulleys)
        m = n + (1 if scene.tensioner else 0)
        a = np.zeros((n, m))
        for j in range(n):
            k = (j + 1) % n
            a[j, k] += P[k].radius
            a[j, j] -= P[j].radius
        g = dg = np.zeros(n)
        arm = -1
        if scene.tensioner:
            g, dg = arm_terms(geo, P, scene.tensioner)
            arm = n
            a[:, arm] = g
        kj = scene.belt.EA / geo.lengths
        cj = scene.belt.damping / geo.lengths
        M = np.diag([p.inertia for p in P] + ([scene.tensioner.inertia] if scene.tensioner else []))
        C = a.T @ (cj[:, None] * a) + np.diag([p.damping for p in P] + ([scene.tensioner.damping] if scene.tensioner else []))
        K = a.T @ (kj[:, None] * a)
        if scene.tensioner:
            K[arm, arm] += scene.tensioner.spring_rate
        model = cls(scene, a, kj, cj, M, C, K, g, dg, arm)
        model._check_arm_stable()
        return model

    def _check_arm_stable(self) -> None:
        """Refuse (:class:`SceneError`) a tensioner whose arm is unstable at its installed angle: the installed
        stiffness ``K + k_geo e_a e_a^T`` has a negative eigenvalue (the belt's geometric stiffness pulls the arm
        away faster than its spring and the belt hold it). Every tier ran it, and the step guard blamed the step."""
        if self.arm < 0:
            return
        K = self.stiffness()
        eig = np.linalg.eigvalsh(0.5 * (K + K.T))
        if eig[0] < -1e-9 * max(float(np.max(np.abs(eig))), 1e-300):
            k_geo = self.geometric_stiffness(np.full(len(self.k), self.scene.belt.installed_tension))
            raise SceneError(
                f"tensioner.spring_rate: the arm is unstable at its installed angle (the belt's geometric stiffness "
                f"{k_geo:.4g} N m/rad outweighs the spring's {self.scene.tensioner.spring_rate:g} N m/rad and the "
                "belt's stretch); a stiffer spring, a stiffer belt (belt.EA) or another arm geometry holds it")

    # ------------------------------------------------------------------ pieces
    def geometric_stiffness(self, tensions) -> float:
        """``k_geo = sum_j T_j dg_j/dtheta_a`` [N m/rad] at span tensions ``tensions`` [N] (0 without a tensioner)."""
        return float(np.dot(tensions, self.dg)) if self.arm >= 0 else 0.0

    def stiffness(self, tensions=None) -> np.ndarray:
        """K with the arm's geometric stiffness at ``tensions`` (default: the installed tension everywhere)."""
        K = self.K_belt.copy()
        if self.arm >= 0:
            T = np.full(len(self.k), self.scene.belt.installed_tension) if tensions is None else np.asarray(tensions)
            K[self.arm, self.arm] += self.geometric_stiffness(T)
        return K

    def tensions(self, q, qd) -> np.ndarray:
        """Span tensions [N] ``T_0 + k_j delta_j + c_j delta_j'`` for states ``q, qd`` ((m,) or (N, m))."""
        return (self.scene.belt.installed_tension + self.k * _times_rows(q, self.stretch)
                + self.c * _times_rows(qd, self.stretch))

    def speeds_at(self, driver_speed: float) -> np.ndarray:
        """Pulley speeds [rad/s] of the belt running without stretch: ``omega_i = omega_d r_d / r_i``."""
        P = self.scene.pulleys
        return np.array([driver_speed * P[self.scene.driver].radius / p.radius for p in P])

    def operating_loads(self, driver_speed: float, shift=0.0) -> np.ndarray:
        """Mean torque [N m] of each pulley's profile (signed: + drives the belt; idlers 0) over two revolutions at
        the scene's end, at the belt speed of ``driver_speed`` (each pulley's speed plus ``shift`` [rad/s])."""
        t = self.scene.duration
        w = self.speeds_at(driver_speed) + shift
        out = np.zeros(len(self.scene.pulleys))
        angles = np.linspace(0.0, 4.0 * math.pi, 64, endpoint=False)
        for i, p in enumerate(self.scene.pulleys):
            if p.sign:
                out[i] = float(np.mean(p.load(t, angles, w[i])))
        return out

    def load_damping(self, driver_speed: float) -> np.ndarray:
        """Per pulley ``-dQ_i/domega_i`` [N m s/rad] of the profiles at the operating speed (central difference)."""
        h = 1e-4 * np.maximum(1.0, np.abs(self.speeds_at(driver_speed)))
        return (self.operating_loads(driver_speed, -h) - self.operating_loads(driver_speed, h)) / (2.0 * h)

    # ------------------------------------------------------------------ statics
    def static(self, loads, iterations: int = 20, w: float = 0.0):
        """``(q, tensions [N], Q)``: the static state (least squares: no rigid turning) under constant pulley torques
        ``loads`` [N m] (signed; the driver's replaced by the one balancing the others, ``sum_i Q_i / r_i = 0``), the
        belt running with centrifugal tension ``w = m' v^2`` [N]. The arm's load is ``-sum_j (T_j - w) g_j`` (``w``
        adds ``w sum_j g_j`` to its force), its geometric stiffness iterated to ``T_j - w`` (``iterations = 1``: kept
        at T_0, the equilibrium of a run's equations; they differ by ``(T_j - T_0) dg_j/dtheta_a theta_a``).
        """
        P = self.scene.pulleys
        Q = np.asarray(loads, dtype=float).copy()
        d = self.scene.driver
        Q[d] = 0.0
        Q[d] = -P[d].radius * sum(Q[i] / P[i].radius for i in range(len(P)))
        f = np.zeros(self.M.shape[0])
        f[: len(P)] = Q
        if w and self.arm >= 0:
            f[self.arm] += w * float(np.sum(self.g))
        T = np.full(len(self.k), self.scene.belt.installed_tension)
        q = np.zeros_like(f)
        for _ in range(iterations):
            # K_lin q = f - (geometric preload change): the arm sees -sum_j (T_j - T_0) g_j through K_belt already;
            # the geometric term linearises sum_j (T_j - w) g_j(theta) about theta_0 with T_j at the current tensions
            q_new = np.linalg.lstsq(self.stiffness(T - w), f, rcond=None)[0]
            T_new = self.tensions(q_new, np.zeros_like(q_new))
            done = np.max(np.abs(T_new - T)) <= 1e-12 * max(1.0, np.max(np.abs(T_new)))
            q, T = q_new, T_new
            if done:
                break
        return q, T, Q

    def operating_point(self, driver_speed: float):
        """``(K, C, tensions)`` linearised at the operating speed: static tensions under the mean loads with the belt's
        centrifugal tension ``w = m' v^2`` at that speed (:meth:`static`), the arm's geometric stiffness at the
        tensions it feels (``T_j - w``), the profiles' speed slopes as damping."""
        w = self.scene.belt.mass_per_length * (driver_speed * self.scene.pulleys[self.scene.driver].radius) ** 2
        _, T, _ = self.static(self.operating_loads(driver_speed), w=w)
        C = self.C.copy()
        C[: len(self.scene.pulleys), : len(self.scene.pulleys)] += np.diag(self.load_damping(driver_speed))
        return self.stiffness(T - w), C, T

    # ------------------------------------------------------------------ first-order form
    def state_space(self, K=None, C=None):
        """``(A, B)`` of ``x = [q, q']`` in the pulleys' own angles, ``u`` the n pulley torques [N m] (modal analysis)."""
        return self._first_order(np.eye(self.M.shape[0]), self.stiffness() if K is None else K, self.C if C is None else C)

    def _first_order(self, E, K, C):
        """``(A, B)`` of ``x = [q, omega]`` with ``q' = E omega``, ``M omega' = u - C omega - K q``, ``u`` the n pulley
        torques [N m] (``M`` diagonal: ``M^-1`` row by row)."""
        m, n = self.M.shape[0], len(self.scene.pulleys)
        Minv = 1.0 / np.diag(self.M)
        A = np.zeros((2 * m, 2 * m))
        A[:m, m:] = E
        A[m:, :m] = -(Minv[:, None] * K)
        A[m:, m:] = -(Minv[:, None] * C)
        B = np.zeros((2 * m, n))
        B[m + np.arange(n), np.arange(n)] = Minv[:n]
        return A, B

    # ------------------------------------------------------------------ the run's coordinates
    @cached_property
    def ratios(self) -> np.ndarray:
        """Speed ratios ``rho_i = r_d / r_i`` [-]: pulley i turns rho_i times the driver with the belt unstretched."""
        r = np.array([p.radius for p in self.scene.pulleys])
        found = r[self.scene.driver] / r
        found.flags.writeable = False
        return found

    @property
    def lag_stretch(self) -> np.ndarray:
        """(n_spans, m) rows ``b_j``: span j's stretch in the run's coordinates, ``delta_j = b_j . q_run``.

        The run integrates the driver's angle, every other pulley's lag ``l_i = rho_i theta_d - theta_i`` [rad]
        (the paper's ``delta = i phi_M - phi_3``) and the arm's angle. Since ``r_i rho_i = r_d``,
        ``delta_j = r_j l_j - r_{j+1} l_{j+1} + g_j theta_a``: the driver's growing angle enters no stretch
        (its column is exactly zero), so the stretches keep their digits over a long run.
        """
        b = -self.stretch.copy()
        b[:, self.scene.driver] = 0.0
        if self.arm >= 0:
            b[:, self.arm] = self.g
        return b

    def flexible_matrices(self):
        """``(A, B)`` of the flexible tier in the run's state ``x = [theta_d, l_i (i != d), theta_a, omega_i, omega_a]``.

        ``q' = E omega`` (``l_i' = rho_i omega_d - omega_i``), ``M omega' = u - C omega - K_l q`` with
        ``K_l = sum_j k_j a_j b_j^T + (k_a + k_geo) e_a e_a^T`` (``k_geo`` at T_0), B = M^-1 per pulley torque.
        """
        n, m, d = len(self.scene.pulleys), self.M.shape[0], self.scene.driver
        E = np.eye(m)
        for i in range(n):
            if i != d:
                E[i, i], E[i, d] = -1.0, self.ratios[i]
        K = self.stretch.T @ (self.k[:, None] * self.lag_stretch)
        if self.arm >= 0:
            K[self.arm, self.arm] += self.scene.tensioner.spring_rate + self.geometric_stiffness(
                np.full(len(self.k), self.scene.belt.installed_tension))
        return self._first_order(E, K, self.C)

    def to_absolute(self, states) -> np.ndarray:
        """Run states (N, 2m) in the pulleys' own angles ``[theta, theta_a, omega, omega_a]`` (theta_i = rho_i theta_d - l_i)."""
        out = np.array(states, dtype=float)
        found = self.__dict__.get("_lags")
        if found is None:  # the driver and the ratios of the pulleys before and after it
            d, n = self.scene.driver, len(self.scene.pulleys)
            found = self.__dict__["_lags"] = (d, n, self.ratios[:d].copy(), self.ratios[d + 1 :].copy())
        d, n, before, after = found  # per element the loop over pulleys' operations (bit for bit)
        out[:, :d] = before * out[:, d : d + 1] - out[:, :d]
        out[:, d + 1 : n] = after * out[:, d : d + 1] - out[:, d + 1 : n]
        return out

    def run_tensions(self, states) -> np.ndarray:
        """Span tensions [N] ``T_0 + k_j (b_j . q) + c_j (a_j . omega)`` of flexible run states (N, 2m)."""
        m = self.M.shape[0]
        return (self.scene.belt.installed_tension + self.k * _times_rows(states[:, :m], self.lag_stretch)
                + self.c * _times_rows(states[:, m:], self.stretch))

    def rigid_matrices(self):
        """``(A, B)`` of the rigid tier, ``x = [theta_d, omega_d]``: ``J_red omega_d' = sum_i rho_i (u_i - b_i rho_i omega_d)``,
        ``J_red = sum_i J_i rho_i^2`` (an inextensible belt keeps its length: the arm's quasi-static swing,
        :meth:`rigid_arm_row`, has no inertia in it)."""
        rho = self.ratios
        n = len(rho)
        J, b = np.diag(self.M)[:n], self.bearing_damping
        J_red, b_red = float(np.sum(J * rho * rho)), float(np.sum(b * rho * rho))
        A = np.array([[0.0, 1.0], [0.0, -b_red / J_red]])
        B = np.zeros((2, n))
        B[1] = rho / J_red
        return A, B

    @property
    def bearing_damping(self) -> np.ndarray:
        """Per pulley its bearing damping b_i [N m s/rad]: ``C`` without the spans' damping (diagonal)."""
        n = len(self.scene.pulleys)
        return np.diag(self.C)[:n] - np.diag(self.stretch.T @ (self.c[:, None] * self.stretch))[:n]

    def rigid_tension_map(self) -> np.ndarray:
        """(n_spans, n) S: span tension changes ``T - T_0 = S Q`` [N] under balanced pulley torques Q [N m]
        (``sum_i rho_i Q_i = 0``): the belt's static stretch (K^+ Q), the arm at its equilibrium."""
        return self.k[:, None] * (self.stretch @ self._static_compliance())

    def _static_compliance(self) -> np.ndarray:
        """(m, n) ``K^+`` on unit pulley torques: the static displacement of every coordinate under each (the arm's
        row its swing), solved once per model (read-only) for :meth:`rigid_tension_map` and :meth:`rigid_arm_row`."""
        found = self.__dict__.get("_compliance")
        if found is None:
            m, n = self.M.shape[0], len(self.scene.pulleys)
            rhs = np.zeros((m, n))
            rhs[:n] = np.eye(n)
            found = np.linalg.lstsq(self.stiffness(), rhs, rcond=None)[0]
            found.flags.writeable = False
            self.__dict__["_compliance"] = found
        return found

    def rigid_arm_row(self) -> np.ndarray | None:
        """(n + 2,) c: the rigid tier's arm swing from its installed angle [rad] as :func:`arm_swing` forms it from
        ``x = [theta_d, omega_d]`` and the signed pulley torques u [N m], or None without a tensioner.

        The arm sits at the equilibrium the quasi-static tensions of :meth:`rigid_tension_map` hold it at: its
        swing is ``a . Q`` with ``a`` the arm's row of ``K^+`` and ``Q_i = u_i - J_i rho_i omega_d' - b_i rho_i^2
        omega_d`` what the belt takes at pulley i (``omega_d' = A_1 x + B_1 u``, :meth:`rigid_matrices`), i.e.
        ``c = [-(a.J rho) A_10, -(a.J rho) A_11 - a.(b rho^2), a_i - (a.J rho) B_1i]``."""
        if self.arm < 0:
            return None
        found = self.__dict__.get("_rigid_arm_row")
        if found is not None:
            return found
        n = len(self.scene.pulleys)
        a = self._static_compliance()[self.arm]
        rho, J, b = self.ratios, np.diag(self.M)[:n], self.bearing_damping
        A, B = self.rigid_matrices()
        inertia = float(a @ (J * rho))
        c = np.concatenate([[-inertia * A[1, 0], -inertia * A[1, 1] - float(a @ (b * rho * rho))], a - inertia * B[1]])
        c.flags.writeable = False
        self.__dict__["_rigid_arm_row"] = c
        return c


def arm_swing(c, theta, omega, u) -> np.ndarray | float:
    """The rigid tier's arm swing [rad] ``c_0 theta + c_1 omega + sum_i c_{2+i} u_i`` (``c``:
    :meth:`NetworkModel.rigid_arm_row`; ``u``: the pulley torques, a sequence of columns or floats), summed from the
    left from 0.0: on arrays or floats the same operations (the node's compiled tick sums them in this order too)."""
    s = 0.0 + c[0] * theta
    s = s + c[1] * omega
    for i, ui in enumerate(u):
        s = s + c[2 + i] * ui
    return s


# ---------------------------------------------------------------------- modes
@dataclass(frozen=True)
class Mode:
    """One vibration mode of eigenvalue ``s``: damped frequency ``Im(s) / 2 pi`` [Hz], ``natural`` = ``|s| / 2 pi``
    [Hz] (a one-degree-of-freedom mode's undamped natural frequency; with non-proportional damping the undamped
    eigenproblem's, :func:`undamped_frequencies`, differ a little), damping ratio ``-Re(s) / |s|``, shape.

    ``shape``: per coordinate the belt-direction amplitude (``r_i theta_i``, ``La theta_a``), largest = 1.
    """

    frequency: float
    natural: float
    damping_ratio: float
    shape: np.ndarray


def modes(model: NetworkModel, driver_speed: float | None = None) -> list[Mode]:
    """Oscillating modes at the operating point (eigenvalues of A with Im > 0), lowest first. The belt turning every
    pulley (K's zero mode) is none: undamped, its double zero eigenvalue comes out split by rounding to about
    ``+-sqrt(eps) |A|``, real or imaginary, so eigenvalues below ``1e-6 max |lambda|`` are left out."""
    speed = model.scene.operating_speed if driver_speed is None else driver_speed
    K, C, _ = model.operating_point(speed)
    A, _ = model.state_space(K, C)
    lam, vec = np.linalg.eig(A)
    tiny = 1e-6 * float(np.max(np.abs(lam)))
    m = model.M.shape[0]
    scene = model.scene
    scale = np.array([p.radius for p in scene.pulleys] + ([arm(scene.pulleys, scene.tensioner)[2]] if model.arm >= 0 else []))
    out = []
    for i in np.argsort(np.abs(lam)):
        if lam[i].imag <= 1e-9 * max(1.0, abs(lam[i])) or abs(lam[i]) <= tiny:
            continue
        v = vec[:m, i] * scale
        v = v / v[np.argmax(np.abs(v))]
        out.append(Mode(lam[i].imag / (2 * math.pi), abs(lam[i]) / (2 * math.pi), -lam[i].real / abs(lam[i]), v.real))
    return out


def undamped_frequencies(model: NetworkModel) -> np.ndarray:
    """Natural frequencies [Hz] of ``K v = w^2 M v`` (K at the installed tension; the zero mode left out), ascending."""
    K = model.stiffness()
    s = 1.0 / np.sqrt(np.diag(model.M))
    w2 = np.linalg.eigvalsh(s[:, None] * K * s[None, :])
    return np.sqrt(np.clip(np.sort(w2)[1:], 0.0, None)) / (2 * math.pi)


# ---------------------------------------------------------------------- runs
@dataclass(frozen=True)
class NetworkRun:
    """A run's outputs (SI): times (N,), per pulley angle/speed/belt torque/hub load and per span tension/slack flag
    (N, n), arm angle [rad] (absolute, N,) or None."""

    time: np.ndarray
    angle: np.ndarray
    speed: np.ndarray
    belt_torque: np.ndarray
    hub_load: np.ndarray
    tension: np.ndarray
    slack: np.ndarray
    arm_angle: np.ndarray | None
    states: np.ndarray
    friction_use: np.ndarray | None = None
    #: the tier that ran (flexible, rigid, slipping), why (``auto``), the method and the accuracy verdict
    tier: str = "flexible"
    reason: str = ""
    method: str = ""
    accuracy: str = ""

    def capstan_onset(self, scene):
        """``(pulley name, time [s], friction use)`` where a pulley's friction use first reaches 1, or None: in the first
        sample where any does, the pulley whose use crosses 1 first, at the crossing time interpolated linearly from the
        sample before (the largest use where the run starts beyond the limit); its use in that sample."""
        use = self.friction_use
        over = np.flatnonzero((use >= 1.0).any(axis=1))
        if not over.size:
            return None
        k = int(over[0])
        now = use[k]
        if k == 0:
            i = int(np.argmax(now))
            return scene.pulleys[i].name, float(self.time[0]), float(now[i])
        before, t0, t1 = use[k - 1], float(self.time[k - 1]), float(self.time[k])
        crossing = [(t0 + (1.0 - before[i]) / (now[i] - before[i]) * (t1 - t0), -now[i], i)
                    for i in np.flatnonzero(now >= 1.0)]  # (now > 1 > before there: the denominator is positive)
        t, _, i = min(crossing)
        return scene.pulleys[i].name, float(t), float(now[i])


def check_step(name: str, A, B, dt: float) -> None:
    """:class:`UnstableStepError` if the fixed-step method ``name`` grows a mode of ``x' = A x`` at step ``dt`` [s]
    (the core's stability guard, :func:`~belt_drive_ros.core.stability.check_step`), naming a stable step."""
    from ..stability import check_step as guard

    report = guard(A, B, name, dt)
    if not report.stable:
        stable = report.max_stable_dt
        hint = f"dt <= {stable:.3g} s is stable, or " if stable else ""
        raise UnstableStepError(f"method {name} at dt = {dt:g} s grows the {report.omega_n / (2 * math.pi):.4g} Hz mode "
                                f"(h omega = {report.h_omega_n:.3g}): {hint}use exact, etd2 or etd4")


def _friction_use(T, T_in, belt_speed, mass_per_length: float, factor) -> np.ndarray:
    """Per pulley ``|T_i - T_{i-1}| / ((T_i + T_{i-1} - 2 m' v^2) f_i)``, ``f_i = tanh(mu_i beta_i / 2)`` (``factor``),
    inf past lift-off: the capstan law ``(T_tight - m' v^2) = (T_slack - m' v^2) e^(mu beta)`` lets friction pass at
    most that tension difference, so a use of 1 is where the pulley starts to slip. ``T`` (..., n) [N] the spans
    leaving, ``T_in`` those arriving (``T`` rolled by one pulley), ``belt_speed`` (...) [m/s]."""
    v = np.asarray(belt_speed, dtype=float)[..., None]
    limit = np.maximum(T + T_in - 2.0 * mass_per_length * v * v, 0.0) * factor
    diff = np.abs(T - T_in)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(limit > 0.0, diff / np.where(limit > 0.0, limit, 1.0), np.where(diff > 0.0, np.inf, 0.0))


def operating_limits(model: NetworkModel, driver_speed: float) -> list[str]:
    """What makes the linearisation at ``driver_speed`` [rad/s] (:meth:`NetworkModel.operating_point`) invalid, one
    phrase each: a span whose static tension is below the centrifugal tension ``m' v^2`` (slack), a pulley whose static
    friction use is beyond 1 (it slips: :func:`_friction_use`). Empty where the belt holds."""
    r, prev, *_, factor, mass, d, _ = _output_terms(model)
    _, _, T = model.operating_point(driver_speed)
    v = driver_speed * r[d]
    w = mass * v * v
    spans, names = model.scene.span_names(), [p.name for p in model.scene.pulleys]
    out = [f"span {spans[j]} slack (static tension {T[j]:.4g} N)" for j in np.flatnonzero(T < w)]
    use = _friction_use(T[None, :], T[None, prev], np.array([v]), mass, factor)[0]
    out += [f"pulley {names[i]} beyond its capstan limit (static friction use {use[i]:.3g})" for i in np.flatnonzero(use > 1.0)]
    return out


def _output_terms(model: NetworkModel) -> tuple:
    """What :func:`outputs` takes from the scene, found once per model: radii, each pulley's arriving span, the
    span directions' components (leaving, arriving), ``tanh(mu beta / 2)``, m', the driver, the arm's installed angle."""
    found = model.__dict__.get("_output_terms")
    if found is None:
        scene, n = model.scene, len(model.scene.pulleys)
        e = np.asarray(scene.geometry.directions, dtype=float)
        e_in, c = np.roll(e, 1, axis=0), np.ascontiguousarray
        found = model.__dict__["_output_terms"] = (
            np.array([p.radius for p in scene.pulleys]), np.roll(np.arange(n), 1), c(e[:, 0]), c(e[:, 1]), c(e_in[:, 0]),
            c(e_in[:, 1]), np.tanh(0.5 * np.array([p.mu for p in scene.pulleys]) * scene.geometry.wraps),
            float(scene.belt.mass_per_length), scene.driver, arm(scene.pulleys, scene.tensioner)[3] if model.arm >= 0 else 0.0)
    return found


def outputs(model: NetworkModel, time, states, T) -> NetworkRun:
    """Per pulley and per span outputs from states ``[q, q']`` (N, 2m) and the tier's span tensions ``T`` (N, n) [N]."""
    r, prev, ex, ey, ex_in, ey_in, factor, mass, d, theta0 = _output_terms(model)
    m, n = model.M.shape[0], len(model.scene.pulleys)
    q, qd = states[:, :m], states[:, m:]
    T_in = T[:, prev]  # span i-1 arrives at pulley i
    torque = r * (T - T_in)
    v = qd[:, d] * r[d]
    w = (mass * v * v)[:, None]  # the centrifugal tension m' v^2: the belt presses on a pulley with T - w
    # |(T_i - w) e_i - (T_{i-1} - w) e_{i-1}| (directions fixed; a massless belt: the tensions themselves, bit for bit)
    hub = np.hypot((T - w) * ex - (T_in - w) * ex_in, (T - w) * ey - (T_in - w) * ey_in)
    slack = T < w
    angle = q[:, model.arm] + theta0 if model.arm >= 0 else None
    return NetworkRun(time, q[:, :n], qd[:, :n], torque, hub, T, slack, angle, states, _friction_use(T, T_in, v, mass, factor))


def stack_profiles(profiles, refused: str = "a profile without a data form cannot run in a network"):
    """``(start, kinds, params, tx, ty)``: the ``(name, profile)`` pairs' data as one program
    (:func:`~..profile_data.stack`); a profile without one is refused (``refused``: the message's end)."""
    from ..profile_data import stack

    data = []
    for name, profile in profiles:
        d = profile.data()
        if d is None:
            raise SceneError(f"pulleys.{name}.torque: {refused}")
        data.append(d)
    stacked, start = stack(data)
    return start, stacked.kinds, stacked.params, stacked.tx, stacked.ty


def grid_breakpoints(model: NetworkModel, dt: float) -> tuple[list, list, dict]:
    """``(marks, left, inside)`` of the profiles' breakpoints on the grid of step ``dt``: their times [s] (sorted; one
    on a knot as ``k dt``), per mark the latest time every profile still gives its value from the left
    (``TorqueProfile.left_of``), ``{step c: [marks strictly inside step c]}``."""
    found = model.__dict__.get("_grid_breakpoints", {}).get(dt)
    if found is None:
        profiles = [p.torque for p in model.scene.pulleys if p.sign]
        marks, inside = set(), {}
        for profile in profiles:
            for b in profile.breakpoints():
                if not (math.isfinite(b) and b > 0.0):
                    continue
                k = round(b / dt)
                if abs(k * dt - b) <= 1e-9 * dt:
                    marks.add(k * dt)
                else:
                    marks.add(float(b))
                    inside.setdefault(math.floor(b / dt), set()).add(float(b))
        marks = sorted(marks)
        left = [min(profile.left_of(b) for profile in profiles) for b in marks]
        found = (marks, left, {c: sorted(bs) for c, bs in inside.items()})
        model.__dict__.setdefault("_grid_breakpoints", {})[dt] = found
    return found


def piece_of(owner, h: float, build, shared: tuple, size: int = 8):
    """``build(h)``, ``owner``'s arrays for one step of ``h`` [s] (a piece of a step split at a breakpoint), sharing
    ``owner``'s attributes ``shared`` (its profile arrays: a held torque holds in the piece too); built once per h."""
    def make():
        found = build(h)
        for name in shared:
            setattr(found, name, getattr(owner, name))
        return found

    return built_once(owner.__dict__.setdefault("_pieces", {}), size, (), make, extra=(h,))


def step_runs(inside: dict, dt: float, k0: int, k1: int, knots=()):
    """Steps ``k0 .. k1-1`` of ``dt`` [s] as ``(a, e, edges)``: runs of whole steps ``a .. e-1`` (``edges`` None),
    also cut at the steps ``knots``, and each step ``a`` with breakpoints strictly inside (``inside`` of
    :func:`grid_breakpoints`) alone, ``edges`` its pieces' ends [s] (the step split there)."""
    split = [c for c in inside if k0 <= c < k1]
    cuts = sorted({k0, k1, *split, *(c + 1 for c in split if c + 1 < k1), *(k for k in knots if k0 < k < k1)})
    for a, e in zip(cuts[:-1], cuts[1:]):
        yield a, e, ([a * dt, *inside[a], (a + 1) * dt] if a in inside else None)

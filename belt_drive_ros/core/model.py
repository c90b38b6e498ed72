"""Rigid-belt (1 DOF) and flexible-belt (2 DOF) models of the accessory drive (derived in ``docs/model.md``).

Stateless linear systems ``x' = A x + B u``, ``y = C x + D u`` (:data:`LINEAR_OUTPUTS`), ``u = [drive_torque,
load_torque]`` [N m] (drive on wheel M, load opposing wheel 3). State order, written down once (read elsewhere
through ``wheel_coordinates``, ``wheel_map``, ``relative_deflection``; the slipping model adds the slip ``s``):

* flexible: ``x = [phi_M, delta, omega_M, omega_3]``  [rad, rad, rad/s, rad/s], ``delta = i phi_M - phi_3`` a state
  (it keeps its digits over long runs), ``phi_3`` an output
* rigid:    ``x = [phi_M, omega_M]``                  [rad, rad/s]

Equations of motion (the paper's eq. 18/20, errata corrected, plus span damping c and bearing damping b)::

    M q'' + C q' + K q = [M_drive, -M_load],   q = [phi_M, phi_3],   M = diag(I_f, I_3)
    K = 2k S,  C = 2c S + diag(b_f, b_3),      S = [[r_2^2 g^2, -r_2 r_3 g], [-r_2 r_3 g, r_3^2]]
    rigid:  I_red phi_M'' + b_red phi_M' = M_drive - i M_load

With ``r_2 g = i r_3`` the stiffness acts on delta alone; belt torque on wheel 3 ``T_b = 2 k r_3^2 delta + 2 c r_3^2
delta'``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .identity_cache import built_once
from .params import BeltDriveParams, centrifugal_tension

#: Names of the per-sample output signals, in CSV/plot order. SI units.
OUTPUT_UNITS: dict[str, str] = {
    "phi_M": "rad",
    "omega_M": "rad/s",
    "phi_1": "rad",
    "omega_1": "rad/s",
    "phi_2": "rad",
    "omega_2": "rad/s",
    "phi_3": "rad",
    "omega_3": "rad/s",
    "drive_torque": "N m",
    "load_torque": "N m",
    "belt_torque": "N m",
    "relative_deflection": "rad",
    "span_force_tight": "N",
    "span_force_slack": "N",
    "slack": "bool",
    "slip": "bool",
}

#: outputs linear in (x, u), the rows of the models' ``C`` and ``D`` (:meth:`_LinearModel.output_matrices`)
LINEAR_OUTPUTS = (
    "phi_M", "omega_M", "phi_1", "omega_1", "phi_2", "omega_2", "phi_3", "omega_3",
    "drive_torque", "load_torque", "belt_torque", "relative_deflection",
)  # fmt: skip
_BELT = LINEAR_OUTPUTS.index("belt_torque")


@dataclass(frozen=True)
class _LinearModel:
    """Common part of the two models: matrices built once from ``params``."""

    params: BeltDriveParams
    A: np.ndarray
    B: np.ndarray

    name: ClassVar[str] = ""
    n_states: ClassVar[int] = 0

    def _init(self, params, A, B, C, D) -> None:
        """Set the frozen fields (``C``, ``D`` with every row filled in: :func:`_output_rows`)."""
        object.__setattr__(self, "params", params)
        for name, value in (("A", A), ("B", B), ("C", C), ("D", D)):
            object.__setattr__(self, name, value)
        # C and D as rows of plain floats: the outputs of one sample (the node's tick) without numpy
        object.__setattr__(self, "_rows", tuple(zip(map(tuple, C.tolist()), map(tuple, D.tolist()))))

    # -- output maps --------------------------------------------------------
    def output_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """(C, D): the outputs :data:`LINEAR_OUTPUTS` are ``y = C x + D u`` (SI units)."""
        return self.C, self.D

    @property
    def _D_of_outputs(self) -> np.ndarray:
        """D with the rows of the drive and load torques +0.0 (:meth:`outputs` reads those two from u; built once)."""
        cached = self.__dict__.get("_d_outputs")
        if cached is None:
            cached = self.D.copy()
            cached[[LINEAR_OUTPUTS.index("drive_torque"), LINEAR_OUTPUTS.index("load_torque")]] = 0.0
            cached.flags.writeable = False
            object.__setattr__(self, "_d_outputs", cached)
        return cached

    @property
    def wheel_map(self) -> np.ndarray:
        """(4, n) matrix W with ``[phi_M, omega_M, phi_3, omega_3] = W x`` (what the torques see; built once, read-only)."""
        cached = self.__dict__.get("_wheel_map")
        if cached is None:
            cached = self.C[[LINEAR_OUTPUTS.index(name) for name in ("phi_M", "omega_M", "phi_3", "omega_3")]]
            cached.flags.writeable = False
            object.__setattr__(self, "_wheel_map", cached)
        return cached

    def wheel_coordinates(self, x: np.ndarray) -> tuple:
        """(phi_M, omega_M, phi_3, omega_3) of state(s) ``x`` (last axis = state)."""
        y = _affine(self.wheel_map, np.asarray(x, dtype=float))  # summed as the steppers sum (bit for bit)
        return y[..., 0], y[..., 1], y[..., 2], y[..., 3]

    def state_part(self, x: np.ndarray) -> np.ndarray:
        """``C x`` (N, O) of samples ``x`` (N, n), the wheel coordinates' rows (:data:`WHEEL_ROWS`) among them."""
        return _affine(self.C, np.asarray(x, dtype=float))

    def outputs(self, x: np.ndarray, u: np.ndarray, cx: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """All output signals of :data:`OUTPUT_UNITS` for samples ``x`` (N, n), ``u`` (N, 2): ``y = C x + D u``, then
        :meth:`span_forces`. One sample (``x`` (n,): the node's tick) gives plain floats and bools by the same
        operations in the same order (:func:`_affine_sample`: bit for bit). ``cx``: :meth:`state_part` of ``x``."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        if x.ndim == 1:
            values = _affine_sample(self._rows, x.tolist(), u.tolist())
            out = dict(zip(LINEAR_OUTPUTS, values))
            out["drive_torque"], out["load_torque"] = float(u[0]), float(u[1])  # the inputs themselves
        else:
            # the D rows of the two torques left out: those outputs are the inputs themselves, bit for bit
            y = _plus_affine(_affine(self.C, x) if cx is None else cx, self._D_of_outputs, u)
            out = {name: y[..., j] for j, name in enumerate(LINEAR_OUTPUTS)}
            out["drive_torque"], out["load_torque"] = u[..., 0], u[..., 1]
        tight, slack_force, slack, slip = self.span_forces(out["belt_torque"], out["omega_M"])
        out.update(span_force_tight=tight, span_force_slack=slack_force, slack=slack, slip=slip)
        return {name: out[name] for name in OUTPUT_UNITS}

    # -- helpers shared by both models --------------------------------------
    def total_energy(self, x: np.ndarray) -> np.ndarray:
        """E = T + V [J] (the rigid belt's V = 0)."""
        return self.kinetic_energy(x) + self.potential_energy(x)

    def span_forces(self, belt_torque: np.ndarray, omega_M) -> tuple:
        """Span forces and slack/slip flags from the belt torque at wheel 3 [N m] and the drive speed [rad/s] (the
        belt's centrifugal tension; none for a massless belt; :func:`span_forces`)."""
        p = self.params
        F_c = centrifugal_tension(p.r_2 * p.gear_ratio, p.belt_mass, omega_M) if p.belt_mass else 0.0
        return span_forces(p.F_0, p.r_3, p.capstan_ratio, belt_torque, F_c)


class FlexibleBeltModel(_LinearModel):
    """Two-degree-of-freedom model, an elastic, damped belt between wheels 2 and 3 (module docstring): M, K, C are
    :attr:`mass_matrix`, :attr:`stiffness_matrix`, :attr:`damping_matrix` (in ``q = [phi_M, phi_3]``)."""

    name: ClassVar[str] = "flexible"
    n_states: ClassVar[int] = 4

    def __init__(self, params: BeltDriveParams):
        m = flexible_matrices(params)
        self._init(params, m["A"], m["B"], m["C"], m["D"])
        object.__setattr__(self, "mass_matrix", m["mass"])
        object.__setattr__(self, "stiffness_matrix", m["stiffness"])
        object.__setattr__(self, "damping_matrix", m["damping"])

    @property
    def lagrange_map(self) -> np.ndarray:
        """(4, 4) T with ``[phi_M, phi_3, omega_M, omega_3] = T x`` (Lagrange's coordinates and speeds).

        T is its own inverse (``phi_3 = i phi_M - delta`` and ``delta = i phi_M - phi_3``),
        so ``T A T`` and ``T B`` are A and B in the coordinates of ``docs/model.md``.
        """
        T = np.eye(4)
        T[1, 0:2] = (self.params.ratio, -1.0)
        return T

    def relative_deflection(self, x: np.ndarray) -> np.ndarray:
        """delta = i phi_M - phi_3 [rad] (a state coordinate)."""
        return np.asarray(x, dtype=float)[..., 1]

    # -- energies -------------------------------------------------------------
    def kinetic_energy(self, x: np.ndarray) -> np.ndarray:
        """T = 1/2 q'^T M q' [J] (wheels M, 1, 2 via the gear ratios)."""
        return 0.5 * _quadratic(x[..., 2], x[..., 3], self.mass_matrix)

    def potential_energy(self, x: np.ndarray) -> np.ndarray:
        """V = 2 (1/2) k (r_2 phi_2 - r_3 phi_3)^2 = k r_3^2 delta^2 [J] (paper eq. 15; = 1/2 q^T K q)."""
        p = self.params
        return p.k * p.r_3**2 * np.asarray(x, dtype=float)[..., 1] ** 2

    def dissipation_power(self, x: np.ndarray) -> np.ndarray:
        """P_d = q'^T C q' = 2 D_D (Rayleigh) [W], power lost in belt and bearings."""
        return _quadratic(x[..., 2], x[..., 3], self.damping_matrix)

    def input_power(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """P_in = M_drive omega_M - M_load omega_3 [W]."""
        return u[..., 0] * x[..., 2] - u[..., 1] * x[..., 3]

    # -- conversions ----------------------------------------------------------
    def state_from_rigid(
        self, x_rigid: np.ndarray, load_torque: float = 0.0, drive_torque: float | None = None
    ) -> np.ndarray:
        """Flexible state with the rigid motion and the quasi-static belt deflection: the rigid model's own ``T_b /
        (2 k r_3^2)`` with ``drive_torque`` given (the torque that accelerates wheel 3 included: no belt transient when
        switching during a run-up), else the static ``M_L / (2 k r_3^2)``."""
        i = self.params.ratio
        phi, omega = float(x_rigid[0]), float(x_rigid[1])
        if drive_torque is None:
            delta = static_deflection(self.params, load_torque)
        else:
            rigid = make_model("rigid", self.params)
            tb = float(rigid.belt_torque(np.array([phi, omega]), np.array([drive_torque, load_torque])))
            delta = tb / self.params.belt_torsional_stiffness
        return np.array([phi, delta, omega, i * omega])


class RigidBeltModel(_LinearModel):
    """One-degree-of-freedom model (paper eq. 12-14, load reduced through i), ``x = [phi_M, omega_M]``, ``phi_3 = i
    phi_M``. Belt torque on wheel 3 from wheel 3's own equation, ``T_b = I_3 i phi_M'' + b_3 i omega_M + M_load``;
    the relative deflection reported is its quasi-static ``T_b / (2 k r_3^2)``."""

    name: ClassVar[str] = "rigid"
    n_states: ClassVar[int] = 2

    def __init__(self, params: BeltDriveParams):
        m = rigid_matrices(params)
        self._init(params, m["A"], m["B"], m["C"], m["D"])

    def belt_torque(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """T_b = I_3 i a_M + b_3 i omega_M + M_load [N m] (wheel 3's equation); one sample (x 1-D): a float."""
        if np.ndim(x) == 1:  # the operations of a run's rows on plain floats (_affine_sample)
            return _affine_sample(self._rows[_BELT : _BELT + 1], np.asarray(x, dtype=float).tolist(),
                                  np.asarray(u, dtype=float).tolist())[0]  # fmt: skip
        j = slice(_BELT, _BELT + 1)
        return (_affine(self.C[j], np.asarray(x, dtype=float)) + _affine(self.D[j], np.asarray(u, dtype=float)))[..., 0]

    def kinetic_energy(self, x: np.ndarray) -> np.ndarray:
        """T = 1/2 I_red omega_M^2 [J] (paper eq. 11)."""
        return 0.5 * self.params.inertia_reduced * x[..., 1] ** 2

    def potential_energy(self, x: np.ndarray) -> np.ndarray:
        """V = 0: a rigid belt stores no energy [J]."""
        return np.zeros_like(x[..., 0])

    def dissipation_power(self, x: np.ndarray) -> np.ndarray:
        """P_d = b_red omega_M^2 [W]."""
        return self.params.bearing_damping_reduced * x[..., 1] ** 2

    def input_power(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """P_in = (M_drive - i M_load) omega_M [W]."""
        return (u[..., 0] - self.params.ratio * u[..., 1]) * x[..., 1]

    def state_from_flexible(self, x_flex: np.ndarray) -> np.ndarray:
        """Rigid state [phi_M, omega_M] of a flexible state (drops the belt mode)."""
        return np.array([float(x_flex[0]), float(x_flex[2])])


def _lead(p) -> tuple:
    """Leading shape of parameters ``p``: () for one set (floats), (V,) for columns."""
    return np.shape(p.k)


def _column(value) -> np.ndarray:
    """A float or a (V,) column as an array that broadcasts against rows of the leading shape (..., 1)."""
    return np.asarray(value, dtype=float)[..., None]


def flexible_matrices(p) -> dict:
    """A, B, C, D (and the mass, stiffness, damping matrices) of :class:`FlexibleBeltModel` (module docstring).

    ``p``: one :class:`~belt_drive_ros.core.params.BeltDriveParams` (floats: matrices of one model) or a
    :class:`~belt_drive_ros.core.params.ParamColumns` ((V,) columns: stacks with a leading variant axis);
    the same operations per element either way, so a stack's matrices are each variant's own.
    """
    lead = _lead(p)
    g, i = p.gear_ratio, p.ratio
    I_f, b_f = p.inertia_drive_side, p.bearing_damping_drive_side
    # the belt's shape S: K = 2k S (symmetric PSD, erratum 1 fixed), belt damping 2c S
    s00, s01, s11 = p.r_2**2 * g**2, -p.r_2 * p.r_3 * g, p.r_3**2
    two_k, two_c = 2.0 * p.k, 2.0 * p.c
    d00, d01, d11 = two_c * s00 + b_f, two_c * s01 + 0.0, two_c * s11 + p.b_3  # C = 2c S + diag(b_f, b_3)
    m_f, m_3 = 1.0 / I_f, 1.0 / p.I_3  # M^-1 = diag(1/I_f, 1/I_3)
    A = np.zeros(lead + (4, 4))
    A[..., 0, 2] = 1.0  # phi_M' = omega_M
    A[..., 1, 2], A[..., 1, 3] = i, -1.0  # delta' = i omega_M - omega_3
    # K q = 2k r_3 [r_2 g delta, -r_3 delta]: the stiffness acts on delta alone (r_2 g = i r_3)
    kr = two_k * p.r_3
    A[..., 2, 1], A[..., 3, 1] = -(m_f * (kr * (p.r_2 * g))), -(m_3 * (kr * -p.r_3))
    # omega' = ... - M^-1 C omega + M^-1 [M_drive, -M_load]
    # (0 - x: a zero entry is +0, as the matrix product -M^-1 C gives it)
    A[..., 2, 2], A[..., 2, 3] = 0.0 - m_f * d00, 0.0 - m_f * d01
    A[..., 3, 2], A[..., 3, 3] = 0.0 - m_3 * d01, 0.0 - m_3 * d11
    B = np.zeros(lead + (4, 2))
    B[..., 2, 0] = 1.0 / I_f  # drive torque on M
    B[..., 3, 1] = -1.0 / p.I_3  # load torque opposes wheel 3 (erratum 2 fixed)
    C = np.zeros(lead + (len(LINEAR_OUTPUTS), 4))
    row = LINEAR_OUTPUTS.index
    C[..., row("phi_M"), 0] = C[..., row("omega_M"), 2] = C[..., row("omega_3"), 3] = 1.0
    C[..., row("phi_3"), 0], C[..., row("phi_3"), 1] = i, -1.0  # phi_3 = i phi_M - delta
    C[..., row("relative_deflection"), 1] = 1.0
    # T_b = 2 k r_3^2 delta + 2 c r_3^2 (i omega_M - omega_3)
    two_r2 = 2.0 * p.r_3**2
    belt = row("belt_torque")
    C[..., belt, 1], C[..., belt, 2], C[..., belt, 3] = two_r2 * p.k, two_r2 * (p.c * i), two_r2 * -p.c
    D = np.zeros(lead + (len(LINEAR_OUTPUTS), 2))
    _output_rows(p, C, D)
    out = {"A": A, "B": B, "C": C, "D": D}
    if not lead:  # one model: the matrices of its energies
        shape = np.array([[s00, s01], [s01, s11]])
        out.update(mass=np.diag([I_f, p.I_3]), stiffness=two_k * shape, damping=np.array([[d00, d01], [d01, d11]]))
    return out


def rigid_matrices(p) -> dict:
    """A, B, C, D of :class:`RigidBeltModel` for parameters ``p`` (one set or columns: see :func:`flexible_matrices`)."""
    lead = _lead(p)
    i, I_red = p.ratio, p.inertia_reduced
    A = np.zeros(lead + (2, 2))
    A[..., 0, 1] = 1.0
    A[..., 1, 1] = -p.bearing_damping_reduced / I_red
    B = np.zeros(lead + (2, 2))
    B[..., 1, 0], B[..., 1, 1] = 1.0 / I_red, -i / I_red
    C = np.zeros(lead + (len(LINEAR_OUTPUTS), 2))
    D = np.zeros(lead + (len(LINEAR_OUTPUTS), 2))
    row = LINEAR_OUTPUTS.index
    C[..., row("phi_M"), 0] = C[..., row("omega_M"), 1] = 1.0
    C[..., row("phi_3"), 0] = C[..., row("omega_3"), 1] = i
    # T_b = I_3 i a_M + b_3 i omega_M + M_load, a_M = the second row of A x + B u
    ii = _column(p.I_3 * i)
    belt, deflection = row("belt_torque"), row("relative_deflection")
    C[..., belt, :] = ii * A[..., 1, :] + np.stack(np.broadcast_arrays(0.0, p.b_3 * i), axis=-1)
    D[..., belt, :] = ii * B[..., 1, :] + np.array([0.0, 1.0])
    # quasi-static deflection T_b / (2 k r_3^2)
    stiffness = _column(p.belt_torsional_stiffness)
    C[..., deflection, :] = C[..., belt, :] / stiffness
    D[..., deflection, :] = D[..., belt, :] / stiffness
    _output_rows(p, C, D)
    return {"A": A, "B": B, "C": C, "D": D}


def _output_rows(p, C: np.ndarray, D: np.ndarray) -> None:
    """Fill the rows of C for wheels 1 and 2 from wheel M's (the gear ratios), and the input rows of D."""
    for wheel, ratio in (("1", p.r_M / p.R_1), ("2", p.gear_ratio)):
        r = _column(ratio)
        C[..., LINEAR_OUTPUTS.index("phi_" + wheel), :] = r * C[..., LINEAR_OUTPUTS.index("phi_M"), :]
        C[..., LINEAR_OUTPUTS.index("omega_" + wheel), :] = r * C[..., LINEAR_OUTPUTS.index("omega_M"), :]
    D[..., LINEAR_OUTPUTS.index("drive_torque"), 0] = 1.0
    D[..., LINEAR_OUTPUTS.index("load_torque"), 1] = 1.0


#: the rows of C that the torques see: [phi_M, omega_M, phi_3, omega_3] = W x (:attr:`_LinearModel.wheel_map`)
WHEEL_ROWS = tuple(LINEAR_OUTPUTS.index(name) for name in ("phi_M", "omega_M", "phi_3", "omega_3"))


class ModelStack:
    """V linear models of one kind (rigid or flexible) as stacked matrices: ``A`` (V, n, n), ``B`` (V, n, m), ``C``
    (V, O, n), ``D`` (V, O, m), ``W`` (V, 4, n) (the wheel map) are element for element those of ``make_model(kind,
    params[v])`` (:func:`flexible_matrices` / :func:`rigid_matrices` on :class:`~.params.ParamColumns` ``columns``),
    without a model object per variant; :meth:`model` builds variant v's when one is needed."""

    def __init__(self, kind: str, params, columns=None, matrices: dict | None = None):
        from .params import ParamColumns

        if kind not in ("rigid", "flexible"):
            raise ValueError(f"ModelStack: a linear model (rigid or flexible), got {kind!r}")
        self.name, self.params = kind, list(params)
        self.columns = columns if columns is not None else ParamColumns(self.params)
        if matrices is None:
            matrices = (flexible_matrices if kind == "flexible" else rigid_matrices)(self.columns)
        self.A, self.B, self.C, self.D = (matrices[k] for k in ("A", "B", "C", "D"))
        self.W = self.C[:, WHEEL_ROWS, :]
        self.n_states = self.A.shape[-1]
        self._models: dict = {}

    def __len__(self) -> int:
        return len(self.params)

    def model(self, v: int):
        """Variant v's model object (:func:`make_model`; built once)."""
        found = self._models.get(v)
        if found is None:
            found = self._models[v] = make_model(self.name, self.params[v])
        return found

    def subset(self, keep) -> "ModelStack":
        """The variants ``keep`` (positions), a new stack."""
        keep = list(keep)
        matrices = {k: getattr(self, k)[keep] for k in ("A", "B", "C", "D")}
        out = ModelStack(self.name, [self.params[v] for v in keep], self.columns.subset(keep), matrices)
        out._models = {j: self._models[v] for j, v in enumerate(keep) if v in self._models}
        return out


def _affine(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``x @ M.T`` summed column by column, elementwise: the same floats for one sample (the node's tick) as for a
    whole run (a BLAS product may sum in another order). A long run of float64 samples with several rows is one
    compiled pass (:func:`~belt_drive_ros.core.kernel_affine.affine_rows`, each row's samples in order; ~2x faster
    than numpy's outer products on 1,000 samples of 12 outputs): the same products and sums, returned as the
    transpose of ``(rows, samples)``.
    """
    if (M.shape[0] > 1 and x.size > 512 and x.dtype == np.float64 and M.dtype == np.float64
            and x.shape[-1] >= M.shape[1] >= 1):
        # (the kernel has no bounds checks: samples of fewer states than M has columns would be read past each
        # row and past the array's end; those take numpy's path below, which raises IndexError as a short run does)
        # (C-contiguous and writable: numba types a read-only array apart, the kernel keeps its one signature)
        M, samples = (a if a.flags.writeable and a.flags.c_contiguous else np.array(a, order="C")
                      for a in (M, x.reshape(-1, x.shape[-1])))
        out = np.empty((M.shape[0], samples.shape[0]))
        _affine_rows()(M, samples, out)
        return out.T.reshape(x.shape[:-1] + (M.shape[0],))
    y = x[..., 0, None] * M[:, 0]
    for k in range(1, M.shape[1]):
        y = y + x[..., k, None] * M[:, k]
    return y


#: the compiled kernels this module calls, imported at their first use (importing it imports no compiler)
_COMPILED: dict = {}


def _affine_rows():
    """:func:`~belt_drive_ros.core.kernel_affine.affine_rows` (imported at the first long run, then kept)."""
    found = _COMPILED.get("affine_rows")
    if found is None:
        from .kernel_affine import affine_rows

        found = _COMPILED["affine_rows"] = affine_rows
    return found


def _plus_affine(y: np.ndarray, M: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``y + _affine(M, u)``, the same floats, without multiplying the rows of M that are all +0.0 (most of D):
    each of those rows is ``u_0 0.0 + u_1 0.0 + ...``, one (N,) sum they share."""
    if np.signbit(M).any():  # (a -0.0 coefficient would flip a zero's sign)
        return y + _affine(M, u)
    rows = np.flatnonzero(M.any(axis=1))
    out = y + _affine(np.zeros((1, M.shape[1])), u)
    if rows.size:
        out[..., rows] = y[..., rows] + _affine(M[rows], u)
    return out


def _quadratic(w0: np.ndarray, w1: np.ndarray, S: np.ndarray) -> np.ndarray:
    """``w^T S w`` per sample for the speeds ``w = (w0, w1)``: the terms ``w_i S_ij w_j`` summed in index order
    (the floats of ``np.einsum("...i,ij,...j->...", w, S, w)``, without its general loop)."""
    return w0 * S[0, 0] * w0 + w0 * S[0, 1] * w1 + w1 * S[1, 0] * w0 + w1 * S[1, 1] * w1


def _affine_sample(rows, x: list, u: list) -> list:
    """``_affine(C, x) + _affine(D, u)`` of one sample on plain floats; ``rows`` = (C row, D row) pairs.

    Each output is ``((x_0 C_j0 + x_1 C_j1) + ...) + (u_0 D_j0 + u_1 D_j1)``: the operations :func:`_affine`
    applies to every sample of a run, in the same order (the same doubles, tested bit for bit), without numpy.
    """
    u0, u1 = u
    if len(x) == 4:  # the flexible model, written out (a third of the loop's time)
        x0, x1, x2, x3 = x
        return [x0 * c0 + x1 * c1 + x2 * c2 + x3 * c3 + (u0 * d0 + u1 * d1) for (c0, c1, c2, c3), (d0, d1) in rows]
    x0, x1 = x  # the rigid model
    return [x0 * c0 + x1 * c1 + (u0 * d0 + u1 * d1) for (c0, c1), (d0, d1) in rows]


def span_forces(F_0, r_3, capstan_ratio, belt_torque, centrifugal=0.0) -> tuple:
    """(F_tight, F_slack [N], slack, slip flags) from the belt torque [N m]: ``Q = T_b / r_3`` splits about the
    pre-tension, ``F_tight, F_slack = F_0 +- |Q|/2``; slack where ``F_slack <= 0`` (a span cannot push), slip past the
    capstan (Euler-Eytelwein) limit with the centrifugal tension ``F_c`` [N] (:func:`~belt_drive_ros.core.params.
    centrifugal_tension`) taken off both spans, ``F_tight - F_c > (F_slack - F_c) e^(mu_eff wrap)``: the belt torque
    past ``r_3 Q_max(omega_M)``, where the slipping model slips (a massless belt: ``F_c = 0``, ``F_tight > F_slack
    e^(mu_eff wrap)``). Either flag, the linear model is outside its validity. Arguments may be arrays that broadcast
    (an ensemble's variants on the last axis) or floats (one sample): the same operations per element."""
    half = 0.5 * abs(belt_torque) / r_3  # abs: np.abs on arrays, the float's own on one sample
    tight = F_0 + half
    slack_force = F_0 - half
    slack = slack_force <= 0.0
    slip = slack | (tight - centrifugal > (slack_force - centrifugal) * capstan_ratio)
    return tight, slack_force, slack, slip


def static_deflection(params: BeltDriveParams, load_torque: float) -> float:
    """Static relative deflection under a constant load: M_L / (2 k r_3^2) [rad]."""
    return load_torque / params.belt_torsional_stiffness


#: rigid and flexible models by (kind, parameter set): read-only once built (frozen, their matrices), so the model
#: choice, the guards and the run of one scene share one; the least recently used of more than 32 is dropped
_MODELS: dict = {}


def make_model(kind: str, params: BeltDriveParams):
    """Model by name: ``"rigid"``, ``"flexible"`` or ``"slipping"`` (:class:`~belt_drive_ros.core.slip.SlippingBeltModel`).

    A rigid or flexible model of one parameter set (the same object) is built once and shared."""
    if kind in ("rigid", "flexible"):
        build = RigidBeltModel if kind == "rigid" else FlexibleBeltModel
        return built_once(_MODELS, 32, (params,), lambda: build(params), extra=(kind,))
    if kind == "slipping":
        from .slip import SlippingBeltModel

        return SlippingBeltModel(params)
    raise ValueError(f"model: unknown model {kind!r}; choose 'rigid', 'flexible', 'slipping' or 'auto'")


"""Model no more than a scene needs: the ``auto`` choice between rigid, flexible and slipping (``docs/model.md``,
"Model no more than a scene needs"; the rule's error: ``docs/performance.md``, fidelity chart).

* **flexible** when an excitation frequency (at the operating speeds of a cheap rigid run) reaches
  ``FREQUENCY_RATIO_THRESHOLD f_n`` (amplification ``1 / |1 - (f/f_n)^2|``: ~1 % at 0.1) or a torque changes
  stepwise, the start included (:func:`start_mismatch`, from ``START_MISMATCH_THRESHOLD`` of the peak);
* **rigid** otherwise (the quasi-static deflection ``T_b / (2 k r_3^2)`` reported);
* **slipping** when the chosen linear run transmits ``|Q| = |T_b| / r_3`` beyond the capstan limit
  ``Q_max = 2 (F_0 - F_c) tanh(mu_eff beta / 2)`` at any time (the reason names the peak ratio and its time);
  a scene within the limit keeps its linear model and that run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .accuracy_probes import RigidSurvey, operating_run_step  # noqa: F401 - operating_run_step re-exported
from .model import make_model
from .stepper import Plant, Stepper, shared_plant

#: rigid is chosen while max(f_excitation) / f_n stays below this [-].
FREQUENCY_RATIO_THRESHOLD = 0.1
#: a start mismatch |T_qs(0) - T_b(0)| from this fraction of the rigid run's peak belt torque is a step [-]
#: (the free vibration it starts has that amplitude: ~1 %, the rigid error at FREQUENCY_RATIO_THRESHOLD).
START_MISMATCH_THRESHOLD = 0.01


class _Deferred:
    """Text formatted when first read: ``function(*arguments)`` (a module function and plain data, so it pickles),
    formatted once for every copy of a choice holding it."""

    __slots__ = ("function", "arguments", "text")

    def __init__(self, function, *arguments):
        self.function, self.arguments, self.text = function, arguments, None

    def __call__(self) -> str:
        if self.text is None:
            self.text = self.function(*self.arguments)
        return self.text


class _Text:
    """A frozen dataclass field whose text is given as it is or as a :class:`_Deferred`, formatted on its first read
    and kept: a caller that never reads it (a campaign reads only the model) never formats it. The same text either
    way; ``dataclasses.replace`` reads it, :func:`_replaced` does not."""

    def __set_name__(self, owner, name):
        self.slot = "_" + name

    def __get__(self, obj, owner=None):
        if obj is None:  # (no default value for the dataclass field)
            raise AttributeError(self.slot[1:])
        text = obj.__dict__[self.slot]
        if type(text) is _Deferred:
            text = obj.__dict__[self.slot] = text()
        return text

    def __set__(self, obj, value):
        obj.__dict__[self.slot] = value


@dataclass(frozen=True)
class ModelChoice:
    """Outcome of :func:`choose_model`: ``model`` (rigid, flexible or slipping) and ``reason`` (one sentence a person
    can check; formatted when first read); ``belt_frequency`` f_n [Hz]; ``excitations`` ((frequency [Hz], label), ...)
    at the estimated operating speeds; ``max_ratio`` their largest / f_n [-] (inf: a step change); ``output_rate``
    [Hz] outputs are consumed at; ``linear`` the frequency rule's tier; ``limit_ratio`` peak |Q| / Q_max of that
    linear run [-] and ``limit_time`` its time [s] (nan: not checked)."""

    model: str
    reason: str = _Text()  # type: ignore[assignment]  (the descriptor: a str, or a _Deferred formatted on first read)
    belt_frequency: float
    excitations: tuple
    max_ratio: float
    output_rate: float
    linear: str = ""
    limit_ratio: float = math.nan
    limit_time: float = math.nan


def _replaced(choice: ModelChoice, **changes) -> ModelChoice:
    """``dataclasses.replace(choice, **changes)`` without reading ``reason`` (a deferred one stays deferred)."""
    new = object.__new__(ModelChoice)
    new.__dict__.update(choice.__dict__)
    for name, value in changes.items():
        object.__setattr__(new, name, value)  # (the fields' own setting: the reason's through its descriptor)
    return new


def start_mismatch(scene, needed: float | None = None) -> tuple[float, float]:
    """(quasi-static belt torque the start needs, belt torque the initial state carries) [N m]: the rigid model's
    ``T_qs = I_3 i a_M + b_3 i omega_M + M_load`` at t = 0 (``needed``: when the caller has it, e.g. an ensemble's
    rigid estimate) and ``2 k r_3^2 delta_0 + 2 c r_3^2 delta_0'``; their difference is the step the belt sees."""
    p = scene.params
    if needed is None:
        rigid = make_model("rigid", p)
        x0 = scene.initial_state.vector("rigid", p.ratio)
        needed = float(rigid.belt_torque(x0, shared_plant(rigid, scene.drive, scene.load).inputs(0.0, x0)))
    init = scene.initial_state
    carried = p.belt_torsional_stiffness * init.relative_deflection + 2.0 * p.c * p.r_3**2 * init.relative_speed
    return needed, carried


def choose_model(
    scene, check_slip: bool = True, linear_run=None, speeds=None,
    linear: ModelChoice | None = None, start_torque: float | None = None, limit: tuple | None = None,
    survey: RigidSurvey | None = None, change_frequency: float | None = None,
) -> ModelChoice:
    """Rigid, flexible or slipping for ``scene``, with the reason (module docstring). ``check_slip``: go on to
    ``slipping`` past the capstan limit (False: the linear tiers only). What the caller has already (else computed
    here): ``linear_run`` ``f(model_name) -> (time, outputs)`` (``simulate`` keeps it as its result); ``speeds``
    (max |omega_M|, max |omega_3| [rad/s], max |belt torque| [N m]) of the rigid estimate; ``linear`` the frequency
    rule's choice; ``start_torque`` (:func:`start_mismatch`); ``limit`` (:func:`limit_exceedance`); ``survey``
    (the :class:`RigidSurvey` shared with the accuracy guard's probes); ``change_frequency`` the rigid estimate's
    :attr:`~RigidSurvey.change_frequency` [1/s] when the caller made its own estimate (a campaign's ensemble).
    """
    choice = linear if linear is not None else _linear_choice(scene, speeds, start_torque, survey, change_frequency)
    if choice.linear != choice.model:  # (the frequency rule's own choice names its tier already)
        choice = _replaced(choice, linear=choice.model)
    if not check_slip:
        return choice
    if limit is None:
        time, outputs = (linear_run or (lambda kind: _linear_outputs(scene, kind)))(choice.model)
        limit = limit_exceedance(scene.params, time, outputs)
    ratio, t_peak = limit
    choice = _replaced(choice, limit_ratio=ratio, limit_time=t_peak)
    if ratio <= 1.0:
        return choice
    reason = _Deferred(_slipping_reason, ratio, scene.params.friction_limit(0.0), t_peak, choice)
    return _replaced(choice, model="slipping", reason=reason)


def _slipping_reason(ratio: float, q_max: float, t_peak: float, linear: ModelChoice) -> str:
    """:func:`choose_model`'s reason past the capstan limit: peak |Q| / Q_max ``ratio``, ``q_max`` Q_max at rest [N],
    at ``t_peak`` [s] of the run on ``linear``'s model (its reason quoted)."""
    return (
        f"slipping: peak transmitted force {ratio:.2f} x the capstan limit "
        f"(Q_max = {q_max:.0f} N at rest) at t = {t_peak:.3g} s "
        f"in the {linear.model} run ({linear.reason})"
    )


def limit_exceedance(params, time, outputs) -> tuple[float, float]:
    """(peak |Q| / Q_max, its time [s]) of a rigid or flexible run's outputs: ``Q = T_b / r_3`` [N] the net force
    the belt transmits, ``Q_max(omega_M)`` the capstan limit (:meth:`~.params.BeltDriveParams.friction_limit`)."""
    belt = np.asarray(outputs["belt_torque"], dtype=float)
    omega = np.asarray(outputs["omega_M"], dtype=float)
    q_max = params.friction_limit(omega)
    ratio = friction_use(belt, params.r_3, q_max if q_max.shape == belt.shape else np.broadcast_to(q_max, belt.shape))
    k = int(np.argmax(ratio))
    return float(ratio[k]), float(time[k])


def friction_use(belt_torque, r_3, q_max):
    """|Q| / Q_max [-], ``Q = T_b / r_3`` (inf where Q_max = 0: lifted off); arrays broadcast (an ensemble's variants
    on the last axis, ``r_3`` and ``q_max`` per variant), the same operations per element as for one run."""
    q = np.abs(belt_torque) / r_3
    return np.divide(q, q_max, out=np.full(q.shape, np.inf), where=q_max > 0)


def _linear_outputs(scene, kind: str):
    """(time, outputs) of ``scene`` on the linear model ``kind`` with its method and step (``auto``: chosen for ``kind``)."""
    from .method_choice import resolve

    scene = resolve(scene, kind)[0]
    model = make_model(kind, scene.params)
    stepper = Stepper(Plant(model, scene.drive, scene.load), scene.method, scene.dt, scene.method_options)
    time, states = stepper.run(scene.initial_state.vector(kind, scene.params.ratio), 0.0, scene.duration)
    return time, model.outputs(states, stepper.plant.input_array(time, states))


#: the rigid run's belt-torque change over its swing (:attr:`RigidSurvey.change_frequency`) counts as an excitation
#: when it exceeds this many times the profiles' highest frequency (a sine at f changes at pi f over its swing)
CHANGE_FACTOR = 4.0


def _linear_choice(scene, speeds=None, start_torque=None, survey=None, change_frequency=None) -> ModelChoice:
    """Rigid or flexible for ``scene`` by the frequency rule, with the reason (``speeds``, ``start_torque``,
    ``survey``, ``change_frequency``: see :func:`choose_model`; without speeds the survey, default one run here,
    gives them)."""
    if speeds is None:
        survey = survey or RigidSurvey.of_scene(scene)
        speeds, start_torque = survey.speeds, survey.start_torque if start_torque is None else start_torque
    f_n = scene.params.belt_natural_frequency / (2.0 * math.pi)
    w_M, w_3, peak = speeds
    excitations = list(scene.drive.excitation_frequencies(w_M)) + list(scene.load.excitation_frequencies(w_3))
    needed, carried = start_mismatch(scene, start_torque)
    if abs(needed - carried) >= START_MISMATCH_THRESHOLD * peak and abs(needed - carried) > 0.0:
        excitations.append((math.inf, (
            f"the start (torques at t = 0 need {needed:.3g} N m of belt torque, the initial deflection "
            f"carries {carried:.3g} N m: a {abs(needed - carried) / peak:.0%} step of the peak; "
            f"the scene starts at its stated deflection, not the quasi-static one)"
        )))
    excitations = tuple(sorted(((float(f), label) for f, label in excitations), reverse=True))
    f_max = excitations[0][0] if excitations else 0.0
    if f_max < FREQUENCY_RATIO_THRESHOLD * f_n and (survey is not None or change_frequency is not None):
        # what the profiles' own frequencies miss: a torque that changes with the state (a motor curve cut off within
        # a few rad/s swings the belt torque in milliseconds as the speed passes it), from the rigid run
        try:
            f_change = change_frequency if change_frequency is not None else survey.change_frequency
        except Exception:  # noqa: BLE001 - a survey that diverged: the profiles' frequencies decide
            f_change = 0.0
        # (a harmonic of frequency f changes at pi f over its swing: only a change the profiles' frequencies cannot
        # explain counts, past CHANGE_FACTOR times the highest of them)
        if f_change >= FREQUENCY_RATIO_THRESHOLD * f_n and f_change > CHANGE_FACTOR * f_max:
            excitations = ((f_change, "the rigid run's fastest belt-torque change (max |dT/dt| over its swing, a "
                                      "torque that changes with the speed)"),) + excitations
            f_max = f_change
    ratio = f_max / f_n
    if math.isinf(f_max) or ratio >= FREQUENCY_RATIO_THRESHOLD:
        model = "flexible"
    else:
        model = "rigid"
    reason = _Deferred(_linear_reason, model, f_n, excitations, ratio, 0.5 * scene.output_rate)
    return ModelChoice(model, reason, f_n, excitations, ratio, scene.output_rate, linear=model)


def _linear_reason(model: str, f_n: float, excitations: tuple, ratio: float, nyquist: float) -> str:
    """The frequency rule's reason for ``model``: belt mode ``f_n`` [Hz], ``excitations`` (highest first), their
    largest over f_n ``ratio`` [-], the output Nyquist frequency ``nyquist`` [Hz] (:func:`_linear_choice`)."""
    f_max, label = excitations[0] if excitations else (0.0, "none")
    if model == "flexible" and math.isinf(f_max):
        reason = f"flexible: {label} excites the belt mode ({f_n:.1f} Hz) at every frequency"
        finite = [(f, lab) for f, lab in excitations if math.isfinite(f)]
        if finite:
            reason += f"; also {finite[0][1]} at {finite[0][0]:.1f} Hz ({finite[0][0] / f_n:.2f} of it)"
    elif model == "flexible":
        reason = (
            f"flexible: {label} at {f_max:.1f} Hz is {ratio:.2f} of the belt mode ({f_n:.1f} Hz), >= {FREQUENCY_RATIO_THRESHOLD:g}: "
            + (
                f"the belt resonance amplifies it by {1 / (1 - ratio**2):.2f}x"
                if ratio < 1.0
                else "at or above resonance the belt dynamics dominate"
            )
        )
    else:
        reason = (
            f"rigid: highest excitation {f_max:.3g} Hz ({label}) is {ratio:.3f} of the belt mode "
            f"({f_n:.1f} Hz), < {FREQUENCY_RATIO_THRESHOLD:g}: the belt stays quasi-static "
            f"(amplification {1 / (1 - ratio**2):.4f}); quasi-static deflection reported"
        )
        if f_n > nyquist:
            reason += f"; the belt mode is also above the output Nyquist frequency ({nyquist:.0f} Hz)"
    return reason

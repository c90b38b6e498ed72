"""Steps split by off-grid samples (a recording's jittered receive times): each piece's kernel loop is the stepper's
loop with that piece's numbers written into one buffer (``KernelLoop.piece``), not a loop of its own per piece length
holding another copy of the recording's table; the same arrays, so the same floats. A block of split steps is one
compiled call (``KernelLoop.pieces``), its pieces' numbers rows of one stacked scheme (``stacked_scheme``): the floats
of each split step stepped alone."""

import numpy as np
import pytest

from belt_drive_ros.core.kernel_loop import KernelLoop
from belt_drive_ros.core.model import make_model
from belt_drive_ros.core.simulate import Simulator
from belt_drive_ros.core.stage_scheme import Guard
from belt_drive_ros.core.stepper import Stepper
from belt_drive_ros.io.bags import reference_scene
from belt_drive_ros.io.torque_bag import RecordedTorque

METHODS = ["etd4", "exact", "rk4", "lawson5", "trapezoidal"]


def _jittered(n=400, rate=1000.0, jitter_ns=20_000):
    """An engine-like torque sampled at ``rate`` [Hz] with receive times off the step grid (whole ns, as a bag's)."""
    t_ns = np.round(np.arange(n) / rate * 1e9).astype(np.int64)
    t_ns[1:] += np.random.default_rng(7).integers(-jitter_ns, jitter_ns + 1, n - 1)
    t = t_ns * 1e-9
    return RecordedTorque(times=t, values=15.0 + 300.0 * np.sin(230.0 * t) + 90.0 * np.sin(460.0 * t))


def _stepper(method, model="flexible", dt=1e-3, cls=Stepper):
    scene = reference_scene("engine_idle")
    sim = Simulator(make_model(model, scene.params), _jittered(), scene.load, method, dt, check_stability=False)
    st = sim.stepper
    if cls is not Stepper:
        st = cls(st.plant, method, dt, st.method_options, st.origin)
    return st, scene.initial_state.vector(model, scene.params.ratio)


class _EachAlone(Stepper):
    """The stepper before blocks of split steps: each split step alone, a kernel call per piece."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._rows = None


class _LoopPerLength(_EachAlone):
    """The stepper before pieces shared one loop: a kernel loop of its own per piece length (built from scratch)."""

    def _loop_of(self, integrator):
        if integrator is self.integrator or self.loop is None:
            return self.loop
        return self.plant.kernel_loop(integrator)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("model", ["rigid", "flexible"])
def test_pieces_give_the_floats_of_a_loop_built_per_length(method, model):
    st, x0 = _stepper(method, model)
    ref, _ = _stepper(method, model, cls=_LoopPerLength)
    times, states = st.run(x0, 0.0, 0.35)
    assert len(st.split_steps) > 200  # the jitter splits most steps
    ref_times, ref_states = ref.run(x0, 0.0, 0.35)
    np.testing.assert_array_equal(times, ref_times)
    np.testing.assert_array_equal(states, ref_states)  # the same floats, not merely close
    a, b = 0.0123457, 0.3154321  # off the grid: partial steps at both ends too
    np.testing.assert_array_equal(st.advance(x0, a, b), ref.advance(x0, a, b))


@pytest.mark.parametrize("method", METHODS)
def test_a_piece_holds_the_arrays_of_its_own_loop(method):
    st, _ = _stepper(method)
    plant = st.plant
    guard = Guard(row=(0.0, 1.0, 0.0, 0.0), bound=1e9)
    guarded = plant.kernel_loop(st.integrator, guard)  # a guarded stepper's pieces are not guarded (as before)
    for h in (3.21e-4, 1e-3 - 3.21e-4, 7.77e-6):
        it = st._partial(h)
        own = plant.kernel_loop(it)
        for loop in (st.loop, guarded):
            piece = loop.piece(it.scheme, it.dt)
            np.testing.assert_array_equal(piece.reals, own.reals)
            np.testing.assert_array_equal(piece.ints, own.ints)
            assert piece.reals is loop.piece(st._partial(h / 2).scheme, h / 2).reals  # one buffer, rewritten
        assert not np.array_equal(guarded.reals, st.loop.reals)  # (the guard is in the parent's numbers)


def test_an_off_grid_run_keeps_no_loop_per_piece_length():
    """Before, every distinct piece length kept a kernel loop with a copy of the recording's table (up to 4096 per
    stepper, a page of a long bag each: a 10 s jittered 1 kHz bag streamed peaked at 862 MB, now 202 MB)."""
    st, x0 = _stepper("etd4", cls=_EachAlone)
    st.run(x0, 0.0, 0.35)
    assert len(st._partials) > 200  # distinct piece lengths, each an integrator of its own
    assert not st._loops
    table = st.loop.tables.size
    held = {id(loop.reals): loop.reals.size for loop in (st.loop, st.loop._piece)}
    assert sum(held.values()) < 3 * table  # the parent's and the one piece buffer


def test_stacked_variants_have_no_piece():
    from belt_drive_ros.core.stage_scheme import StageScheme
    from belt_drive_ros.core.profile_data import CONSTANT, ProfileBuilder

    builder = ProfileBuilder()
    builder.row(CONSTANT, 1.0)
    data, n = builder.build(), 2
    final, W = np.hstack([np.eye(n), np.zeros((n, 2))]), np.vstack([np.eye(n), np.eye(n)])
    loop = KernelLoop(StageScheme((0.0,), (None,), final[None]), 1e-3, W[None], (False, False), data, data)
    assert loop.piece(StageScheme((0.0,), (None,), final[None]), 5e-4) is None


def test_a_loop_with_its_piece_is_freed_without_the_cycle_collector():
    """A page's loop holds the page's table: it must go when its stepper goes, not at the next cyclic collection
    (a reference cycle through the loop's own-numbers builder kept every page of a streamed replay until then:
    tests/test_replay_memory.py's bound failed, 16.7-18.3 B per sample)."""
    import gc
    import weakref

    st, _ = _stepper("etd4")
    loop = st.plant.kernel_loop(st.integrator)
    it = st._partial(3.21e-4)
    assert loop.piece(it.scheme, it.dt) is not None
    ref = weakref.ref(loop)
    enabled = gc.isenabled()
    gc.disable()
    try:
        del loop
        assert ref() is None
    finally:
        if enabled:
            gc.enable()


@pytest.mark.parametrize("method", ["exact", "etd2", "etd4"])
def test_prepared_piece_matrices_are_the_floats_of_each_built_alone(method):
    """The pieces' integrators of a block of split steps get their matrix exponentials from one stacked call
    (``prepare``); each matrix must be what the one-step computation gives it alone, bit for bit, for lengths from
    a nanosecond to a whole step (Pade degrees and scalings differ across such a stack)."""
    from belt_drive_ros.core import integrators as I

    scene = reference_scene("engine_idle")
    model = make_model("flexible", scene.params)
    A, B = np.asarray(model.A, dtype=float), np.asarray(model.B, dtype=float)
    steps = np.concatenate([[1e-9, 2.5e-7, 1e-3], np.random.default_rng(3).uniform(1e-6, 1e-3, 200)])
    of = I._phi_blocks if method == "etd4" else I._expm_blocks
    I.method_class(method).prepare(A, B, steps)
    everyone = steps if method != "etd4" else np.concatenate([steps, 0.5 * steps])
    for h in everyone.tolist():
        held = of._ready.pop((tuple(I._key(a) for a in (A, B)), h))
        alone = of.of(A, B, h)
        assert len(held) == len(alone)
        for m, n in zip(held, alone):
            np.testing.assert_array_equal(m, n)


_EachAloneBase = _EachAlone


class _NothingPrepared(_EachAlone):
    """The stepper before pieces were prepared together: each piece's matrices computed alone."""

    def _prepare_pieces(self, plan, splits, start):
        return len(splits)


@pytest.mark.parametrize("method", ["exact", "etd4"])
def test_prepared_pieces_give_the_floats_of_pieces_built_alone(method, monkeypatch):
    from belt_drive_ros.core import integrators as I

    calls = []
    expm = I.expm_stack
    I._FIXED.clear()  # (what earlier tests built or readied for these lengths: not this test's calls)
    for of in (I._expm_blocks, I._phi_blocks):
        of._ready.clear()
        of._cached.cache_clear()
    monkeypatch.setattr(I, "expm_stack", lambda M: calls.append(np.shape(M)) or expm(M))
    ref, x0 = _stepper(method, cls=_NothingPrepared)
    ref_times, ref_states = ref.run(x0, 0.0, 0.35)
    alone = len(calls)
    assert alone > 200  # one exponential (etd4: two) per new piece length
    calls.clear()
    st, _ = _stepper(method, cls=_EachAloneBase)
    times, states = st.run(x0, 0.0, 0.35)
    assert len(st._partials) > 200 and len(calls) <= 4  # the pieces' lengths in one stacked call
    np.testing.assert_array_equal(times, ref_times)
    np.testing.assert_array_equal(states, ref_states)


STACKED = ["exact", "etd2", "etd4", "euler", "symplectic_euler", "rk4", "trapezoidal"]


@pytest.mark.parametrize("method", STACKED)
@pytest.mark.parametrize("model", ["rigid", "flexible"])
def test_a_stacked_scheme_is_the_floats_of_each_step_built_alone(method, model):
    """``stacked_scheme`` builds the matrices of many steps at once (exponentials, products and solves matrix by
    matrix): slice k must be the integrator of step k's scheme bit for bit, from a nanosecond to a whole step."""
    from belt_drive_ros.core.integrators import make_integrator, stacked_scheme

    scene = reference_scene("engine_idle")
    mdl = make_model(model, scene.params)
    steps = np.concatenate([[1e-9, 2.5e-7, 1e-3, 7.3e-4], np.random.default_rng(5).uniform(1e-6, 1e-3, 120)])
    stacked = stacked_scheme(method, mdl.A, mdl.B, steps)
    for k, h in enumerate(steps.tolist()):
        alone = make_integrator(method, mdl.A, mdl.B, h).scheme
        assert alone.nodes == stacked.nodes and alone.final_base == stacked.final_base
        assert alone.implicit == stacked.implicit
        for a, b in zip((*alone.stages, alone.final), (*stacked.stages, stacked.final)):
            assert (a is None) == (b is None)
            if a is not None:
                np.testing.assert_array_equal(np.asarray(b)[k], a)


def test_methods_not_built_so_have_no_stacked_scheme():
    from belt_drive_ros.core.integrators import stacked_scheme

    scene = reference_scene("engine_idle")
    mdl = make_model("flexible", scene.params)
    assert stacked_scheme("lawson5", mdl.A, mdl.B, [1e-4, 2e-4]) is None
    assert stacked_scheme("RK45", mdl.A, mdl.B, [1e-4, 2e-4]) is None


@pytest.mark.parametrize("method", ["exact", "etd4", "rk4", "trapezoidal", "symplectic_euler"])
@pytest.mark.parametrize("model", ["rigid", "flexible"])
def test_blocks_of_split_steps_give_the_floats_of_each_step_alone_in_few_calls(method, model, monkeypatch):
    """A jittered run's split steps in blocks, each one compiled call of all its pieces (a block's whole steps with
    them), their numbers from one stacked scheme per block: the floats of each split step stepped alone (a kernel
    call per piece, an integrator per piece length), for a run and for an advance off the grid."""
    ref, x0 = _stepper(method, model, cls=_EachAlone)
    ref_times, ref_states = ref.run(x0, 0.0, 0.35)
    st, _ = _stepper(method, model)
    calls = []
    pieces = KernelLoop.pieces
    monkeypatch.setattr(KernelLoop, "pieces", lambda self, *a: calls.append(a[0].size) or pieces(self, *a))
    times, states = st.run(x0, 0.0, 0.35)
    assert len(st.split_steps) > 200 and not st._partials  # no integrator per piece length
    assert 1 <= len(calls) <= 2 and sum(calls) > 2 * len(st.split_steps)  # every piece in a call or two
    np.testing.assert_array_equal(times, ref_times)
    np.testing.assert_array_equal(states, ref_states)  # the same floats, not merely close
    a, b = 0.0123457, 0.3154321  # off the grid: partial steps at both ends too
    np.testing.assert_array_equal(st.advance(x0, a, b), ref.advance(x0, a, b))


def test_a_block_that_diverges_stops_where_each_step_alone_stops():
    """A torque that blows the state up inside a block: the same error (time and state) as each split step alone."""
    from belt_drive_ros.core.errors import SimulationDivergedError

    scene = reference_scene("engine_idle")
    t = np.sort(np.r_[0.0, np.arange(1, 300) * 1e-3 + np.random.default_rng(2).uniform(-2e-5, 2e-5, 299)])
    drive = RecordedTorque(times=t, values=np.where(t > 0.2, 1e12, 20.0))
    messages = []
    for cls in (_EachAlone, Stepper):
        sim = Simulator(make_model("flexible", scene.params), drive, scene.load, "exact", 1e-3, check_stability=False)
        st = sim.stepper if cls is Stepper else cls(sim.stepper.plant, "exact", 1e-3)
        with pytest.raises(SimulationDivergedError) as err:
            st.run(scene.initial_state.vector("flexible", scene.params.ratio), 0.0, 0.29)
        messages.append(str(err.value))
    assert "t=0.20" in messages[0] and messages[0] == messages[1]


def test_blocks_add_no_compiled_specialisation():
    """Blocks of rigid and flexible, explicit and implicit runs, a run from a read-only state: one signature of
    ``piece_steps`` (the one ``kernel_loop.warm`` compiles; make install warms it)."""
    from belt_drive_ros.core import kernel, kernel_loop

    kernel_loop.warm()
    for method, model in (("exact", "rigid"), ("trapezoidal", "flexible")):
        st, x0 = _stepper(method, model)
        x0 = np.array(x0)
        x0.flags.writeable = False
        st.run(x0, 0.0, 0.05)
    assert len(kernel.piece_steps.signatures) == 1


@pytest.mark.parametrize("method", ["exact", "etd4"])
def test_a_partial_step_after_blocks_readies_no_integrator_for_the_steps_they_took(method, monkeypatch):
    """A run off the grid steps its split steps in blocks and its partial last step alone: that step readies the
    integrators of its own pieces at most, not the pieces of the split steps the blocks already took (a stacked
    exponential of every length of the run, held and never used); the same floats either way."""
    from belt_drive_ros.core import stepper as stepper_module

    readied = []
    prepare = stepper_module.prepare_integrators
    monkeypatch.setattr(stepper_module, "prepare_integrators",
                        lambda name, A, B, steps, **o: readied.append(len(steps)) or prepare(name, A, B, steps, **o))
    ref, x0 = _stepper(method, cls=_EachAlone)
    a, b = 0.0123457, 0.3154321  # off the grid: partial steps at both ends
    expected = ref.advance(x0, a, b)
    readied.clear()
    st, _ = _stepper(method)
    np.testing.assert_array_equal(st.advance(x0, a, b), expected)
    assert len(st.split_steps) > 200 and sum(readied) <= 8  # (the partial step's own pieces: a few)

"""The node's compiled common tick (core/tick.py) against the general path, bit for bit.

Two :class:`~belt_drive_ros.ros.simulation.NodeSimulation` of the same
settings tick in lockstep: one with its tick kernel (whole grid steps and
every output in one compiled call), one with it switched off (the stepper's
``advance`` or the slipping engine's, then the model's ``outputs``: what the
node did before and what ``belt-drive sim`` is compared with in test_node).
Every published value and the state must be the same floats at every tick,
through drive-torque changes (general ticks in between), plant breakpoints
and the slipping belt's mode switches (redone by the engine); and the
compiled tick must actually serve most ticks. One compiled specialisation per
kernel whatever the scene; ``NUMBA_DISABLE_JIT=1`` gives the same floats.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from belt_drive_ros.core import tick
from belt_drive_ros.ros.inputs import DriveInput
from belt_drive_ros.ros.parameter_schema import SceneCache, build_settings, default_values
from belt_drive_ros.ros.simulation import NodeSimulation


class _Log:
    def info(self, line):
        pass

    warn = error = info


def _pair(values: dict):
    scenes = SceneCache()
    full = {**default_values(scenes.get(values.get("scene", "paper"))), **values}
    sims = []
    for _ in range(2):
        counters: dict = {}
        drive = DriveInput(counters)
        sims.append(NodeSimulation(build_settings(full, scenes), drive, counters, _Log()))
    sims[1]._tick_kernel = None  # the general path
    return sims


def _sine_load_scene(folder) -> str:
    """paper with a load that depends on time (a sine): the scene where a step's torque times clamped at a
    held-torque jump give other floats than unclamped ones (paper's own load reads speed alone)."""
    from pathlib import Path

    import belt_drive_ros

    text = (Path(belt_drive_ros.__file__).parent / "scenes" / "paper.yaml").read_text()
    start = text.index("\nload:")
    end = text.index("\n", text.index("c2:", start))
    path = Path(folder) / "sine_load.yaml"
    path.write_text(text[:start] + "\nload:\n  type: sine\n  mean: 2.0\n  amplitude: 1.5\n  frequency: 7.0" + text[end:])
    return str(path)


def _lockstep(values: dict, ticks: int, torques=None):
    """(fast ticks, values of both per tick, states of both) of two simulations ticking together."""
    sims = _pair(values)
    tick_ns = sims[0].settings.tick_ns
    fast = 0
    rows = ([], [])
    for k in range(ticks):
        now = 10**9 + k * tick_ns
        for j, sim in enumerate(sims):
            if torques is not None and k in torques:
                sim.drive.receive(torques[k], now - 1, sim.settings)
            assert sim.advance_to(now)
            if j == 0:
                fast += sim._fresh_ns == now
            rows[j].append(sim.values(now) + list(sim.x))
    return fast, np.array(rows[0]), np.array(rows[1]), sims


def test_linear_tick_equals_the_general_path_bit_for_bit_through_torque_changes():
    torques = {k: 2.0 + 0.25 * (k % 7) for k in range(5, 600, 9)}  # a controller at ~110 Hz
    fast, a, b, _ = _lockstep({"drive_source": "topic"}, 600, torques)
    assert fast > 400  # the compiled tick served the ticks between changes
    assert a.shape == b.shape and np.array_equal(a, b)  # the same floats (flags 0.0/1.0 in both)
    assert np.all(np.isfinite(a)) and np.ptp(a[:, 1]) > 0.0  # the drive moved


def test_ticks_at_torque_changes_are_compiled_too_and_equal_the_general_path():
    # a change at tick k is a breakpoint at t_k (the step before ends there, clamped to its left) and
    # at t_k for the step after: the general path's special steps; the compiled tick takes the same clamps
    torques = {k: 1.0 + 0.5 * (k % 5) for k in range(3, 300, 2)}  # a change every other tick
    fast, a, b, sims = _lockstep({"drive_source": "topic"}, 300, torques)
    assert fast == 299  # every tick but the first (which starts the run)
    assert np.array_equal(a, b) and np.ptp(a[:, 8]) > 0.0  # drive torque (output 8) changed


def test_slipping_ticks_at_torque_changes_equal_the_engine():
    torques = {k: 40.0 + 15.0 * ((k // 7) % 7) for k in range(5, 1500, 7)}  # a change every 7th tick
    fast, a, b, sims = _lockstep({"scene": "truck_compressor", "model": "slipping", "drive_source": "topic"}, 1500,
                                 torques)
    assert np.array_equal(a, b)
    assert sims[0].slip_events == sims[1].slip_events
    # every tick without a mode switch is compiled, the change ticks among them (only a switch goes to the engine)
    assert fast + sims[0].counters["slip_events"] >= 1495 and fast > 1200  # (and the two ticks at the load's breakpoint)


@pytest.mark.parametrize("values, base, change, ticks", [({"drive_source": "topic"}, 2.0, 0.5, 400),
                                                         ({"scene": "sine load", "drive_source": "topic"}, 2.0, 0.5, 400),
                                                         ({"scene": "truck_compressor", "model": "slipping",
                                                           "drive_source": "topic"}, 40.0, 30.0, 1500)])
@pytest.mark.parametrize("every", [1, 2, 10])
def test_torque_change_ticks_are_plain_calls_with_their_clamps(values, base, change, ticks, every, monkeypatch,
                                                               tmp_path):
    # a new sample at a plain tick (the jump at its end) and the tick after one (the jump at its start) are the
    # kernel's one call with the clamps the general path's tick gives them, not that path (a change at every tick:
    # both at once): the same floats, and the general path only starts the run and takes a plant breakpoint's ticks
    general = []
    original = NodeSimulation._advance

    def counted(self, now_ns, sampled=None):
        if self._tick_kernel is not None:
            general.append(now_ns)
        return original(self, now_ns, sampled)

    monkeypatch.setattr(NodeSimulation, "_advance", counted)
    if values.get("scene") == "sine load":  # (a load of time: the clamps change its floats)
        values = {**values, "scene": _sine_load_scene(tmp_path)}
    torques = {k: base + change * ((k // every) % 4) for k in range(3, ticks, every)}
    fast, a, b, sims = _lockstep(values, ticks, torques)
    assert np.array_equal(a, b) and len(set(a[:, 8])) == 5  # 0 N m, then the four values
    assert sims[0].slip_events == sims[1].slip_events
    assert values.get("model") != "slipping" or sims[0].counters["slip_events"] > 20  # (mode switches among them)
    # every tick compiled but the first, and the two of each plant breakpoint (truck_compressor's load at 0.5 s); the
    # general path: the first two ticks (the run's start, no plain tick yet), the breakpoint's and the one after it
    near = sum(0.0 < b < ticks * 1e-3 for b in sims[0]._plant_breakpoints)
    assert fast == ticks - 1 - 2 * near
    assert len(general) == 2 + 3 * near


@pytest.mark.parametrize("values", [{"drive_source": "topic"},
                                    {"scene": "truck_compressor", "model": "slipping", "drive_source": "topic"}])
def test_joint_states_message_written_by_the_tick_equals_the_encoder(values):
    from belt_drive_ros.io.cdr_encoders import JointStateEncoder

    sims = _pair(values)
    sim, encoder = sims[0], JointStateEncoder(4)
    tick_ns = sim.settings.tick_ns
    written = 0
    for k in range(200):
        now = 1_700_000_000_123_000_000 + k * tick_ns
        if k % 9 == 4:
            sim.drive.receive(3.0 + k % 4, now - 1, sim.settings)
        sim.advance_to(now)
        v = sim.values(now)
        expected = encoder.encode(now, (v[0], v[2], v[4], v[6], v[1], v[3], v[5], v[7], v[8], 0.0, 0.0, -v[9]))
        message = sim.joint_message(now)
        if message is not None:
            written += 1
            assert message == expected
    assert written > 150


def test_linear_tick_with_substeps_and_the_scene_drive_across_its_breakpoints():
    # paper's scene drive ramps (a breakpoint at the ramp's end) and the step 4 substeps per tick
    fast, a, b, sims = _lockstep({"drive_source": "scene", "substeps": 4}, 400)
    assert sims[0]._plant_breakpoints and fast > 300
    assert np.array_equal(a, b)


def test_rigid_model_tick():
    fast, a, b, _ = _lockstep({"drive_source": "scene", "model": "rigid"}, 300)
    assert fast > 250 and np.array_equal(a, b)


def test_slipping_tick_equals_the_engine_bit_for_bit_through_mode_switches():
    fast, a, b, sims = _lockstep({"scene": "truck_compressor", "model": "slipping", "drive_source": "scene"}, 3000)
    assert sims[0].slip_events == sims[1].slip_events and len(sims[0].slip_events) > 0  # the belt slipped and re-stuck
    assert sims[0].counters["slip_events"] == sims[1].counters["slip_events"] > 20
    # the ticks with events are compiled too (located in the kernel; before, the engine redid each in Python):
    # all but the first and the two at each of the load's breakpoints (0.5 s and 2 s): 112 events, 2995 fast ticks
    assert fast >= 2995
    assert np.array_equal(a, b)
    assert np.any(a[:, 15] == 1.0) and np.any(a[:, 15] == 0.0)  # slipping and sticking ticks among them


def test_one_compiled_specialisation_per_tick_kernel():
    _lockstep({"drive_source": "topic"}, 5)
    _lockstep({"drive_source": "scene", "model": "rigid"}, 5)
    _lockstep({"scene": "truck_compressor", "model": "slipping", "drive_source": "scene"}, 5)
    assert len(tick.linear_tick.signatures) == 1
    assert len(tick.slip_tick.signatures) == 1


LOADED_AT_START = """
import sys
sys.path.insert(0, {tests!r})
from test_node_tick import _pair
from belt_drive_ros.core import tick
sims = [_pair(values)[0] for values in ({{"drive_source": "topic"}}, {{"scene": "truck_compressor", "model": "slipping"}})]
loaded = [len(tick.linear_tick.signatures), len(tick.slip_tick.signatures)]
for sim in sims:
    sim.advance_to(10**9)
    sim.advance_to(10**9 + sim.settings.tick_ns)
print(loaded, [len(tick.linear_tick.signatures), len(tick.slip_tick.signatures)])
"""


def test_the_node_loads_its_compiled_ticks_at_start_not_at_its_first_tick():
    # loading a tick kernel's compiled code from numba's disk cache took the first tick 25 ms (paper) and
    # 50 ms (truck_compressor): a fresh process has both loaded once the node's simulations exist
    code = LOADED_AT_START.format(tests=os.path.dirname(__file__))
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split("\n")[0] == "[1, 1] [1, 1]"


def test_the_tick_kernels_take_their_arrays_packed_in_one_buffer():
    # numba's dispatcher converts every argument on every call, ~1 us per int and ~6 us per array on the caches a
    # 1 ms sleep leaves: each tick passes its packed buffer's address, the held torque's data and the call's grid
    # index and stamp inside it (the ticks before passed 9 and 35 arrays, then 2 arrays and 2-3 ints)
    from numba import types

    _lockstep({"drive_source": "topic"}, 5)
    _lockstep({"scene": "truck_compressor", "model": "slipping", "drive_source": "topic"}, 5)
    for kernel in (tick.linear_tick, tick.slip_tick):
        (signature,) = kernel.signatures
        assert signature == (types.int64,)


def test_packed_at_views_the_buffer_at_its_address_compiled_and_interpreted():
    from numba import njit

    packed = tick.PackedArrays((("a", "b"), ("k",)), {"a": np.arange(6.0).reshape(2, 3), "b": [7.5]},
                               {"k": np.array([[-3, 4]], dtype=np.int64)})

    @njit
    def write(address):
        buffer = tick.packed_at(address)
        buffer[18] = -buffer[18]
        return buffer.size

    assert write(packed.address) == 21 and packed.views["b"][0] == -7.5  # compiled: the same memory, whole
    assert write.py_func(packed.address) == 21 and packed.views["b"][0] == 7.5  # NUMBA_DISABLE_JIT's path
    assert np.shares_memory(tick.packed_at(packed.address), packed.reals)


def test_packed_arrays_views_write_what_the_buffer_holds():
    packed = tick.PackedArrays((("a", "b"), ("k",)), {"a": np.arange(6.0).reshape(2, 3), "b": [7.5]}, {"k": np.array([[-3, 4]], dtype=np.int64)})
    views = packed.views
    assert views["a"].shape == (2, 3) and views["k"].dtype == np.int64 and views["k"].shape == (1, 2)
    assert np.shares_memory(packed.reals, packed.ints) and np.shares_memory(views["k"], packed.reals)
    table = packed.ints[:12].reshape(3, 4)  # (offset, d0, d1, d2) of a, b, k
    assert table.tolist() == [[12, 2, 3, 1], [18, 1, 1, 1], [19, 1, 2, 1]]
    views["b"][0] = -1.25
    views["k"][0, 1] = 9
    assert packed.reals[18] == -1.25 and packed.ints[20] == 9 and packed.reals[12:18].tolist() == list(range(6))


#: a child script's head: the hybrid loop's calls from the slipping tick counted (where the kernels run as Python)
COUNTED = """
import json, sys
import numpy as np
sys.path.insert(0, {tests!r})
from test_node_tick import _lockstep, _pair
from belt_drive_ros.core import tick
calls = []
hybrid_steps = tick.hybrid_steps
def counted(*args):
    calls.append(1)
    return hybrid_steps(*args)
tick.hybrid_steps = counted
"""
SCRIPT = COUNTED + """out = []
for values in ({{"drive_source": "topic"}}, {{"scene": "truck_compressor", "model": "slipping", "drive_source": "scene"}}):
    fast, a, b, sims = _lockstep(values, 120, {{k: 1.0 + k for k in range(3, 120, 11)}} if values.get("drive_source") == "topic" else None)
    out.append([fast, a.tolist()])
print(len(calls), sims[0].counters.get("slip_events", 0))
print(json.dumps(out))
"""


@pytest.mark.slow
def test_numba_disabled_gives_the_same_floats():
    # and the slipping tick without a mode switch steps the phase's linear loop alone: the hybrid loop (its
    # allocations and event code, the tick's cold cost) only for the ticks the guard fires in
    code = SCRIPT.format(tests=os.path.dirname(__file__))
    runs = {}
    for jit in ("0", "1"):
        done = subprocess.run([sys.executable, "-c", code], env=dict(os.environ, NUMBA_DISABLE_JIT=jit),
                              capture_output=True, text=True, timeout=900)
        assert done.returncode == 0, done.stderr[-2000:]
        *_, counts, floats = done.stdout.strip().splitlines()
        runs[jit] = json.loads(floats)
    assert runs["0"] == runs["1"] and runs["0"][0][0] > 60
    hybrid_calls, events = map(int, counts.split())  # (the NUMBA_DISABLE_JIT=1 run's)
    assert runs["1"][1][0] > 100 and hybrid_calls <= 2 * events + 2


def test_the_raw_drive_torque_input_reads_the_value_rclpy_reads():
    # the node subscribes to drive_torque raw (no Float64 object per message) and reads the double from the CDR bytes
    import struct

    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64

    from belt_drive_ros.ros.inputs import float64_value

    for value in (0.0, -0.0, 1.25, -3.5e-310, 1e300, float("inf"), float("-inf")):
        data = serialize_message(Float64(data=value))
        got = float64_value(data)
        assert struct.pack("<d", got) == struct.pack("<d", value)
        big = b"\x00\x00\x00\x00" + struct.pack(">d", value)  # a big-endian CDR writer's bytes
        assert struct.pack("<d", float64_value(big)) == struct.pack("<d", value)
    assert np.isnan(float64_value(serialize_message(Float64(data=float("nan")))))  # (then rejected and counted)


def test_the_slipping_tick_keeps_its_hybrid_state_in_the_kernel_between_ticks(monkeypatch):
    # no SlipState object (and no copies of x) per compiled tick: the state is built only when asked for
    built = []

    class Counted(tick.SlipState):
        def __init__(self, *args, **kwargs):
            built.append(1)
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(tick, "SlipState", Counted)
    sims = _pair({"scene": "truck_compressor", "model": "slipping", "drive_source": "topic"})
    sim = sims[0]
    tick_ns = sim.settings.tick_ns
    fast = 0
    for k in range(300):
        now = 10**9 + k * tick_ns
        if k % 10 == 5:
            sim.drive.receive(2.0 + k % 3, now - 1, sim.settings)
        sim.advance_to(now)
        fast += sim._fresh_ns == now
    assert fast > 250 and len(built) <= 300 - fast  # (a tick the engine redoes builds one)
    state = sim.hybrid  # built now, from the kernel's buffers
    assert len(built) <= 301 - fast and state.kind in ("flexible", "stick") and np.array_equal(sim.stepper.state_y(state), sim.x)


STICK_AFTER_SLIP = COUNTED + """sim = _pair({{"scene": "truck_compressor", "model": "slipping", "drive_source": "scene"}})[0]
engine, kernel = sim.stepper, sim._tick_kernel
k0, ticks = round({t0} / engine.dt), round({t1} / engine.dt) - round({t0} / engine.dt)  # one grid step a tick
events = []
state = engine.advance(engine.initial(sim.x), 0.0, engine.grid_time(k0), events=events)
assert state.kind == "stick" and state.x[4] != 0.0 and events, (state, events)  # sticking after a slip
reference, same, slips = state, True, 0
for k in range(k0, k0 + ticks):
    got = kernel.advance(state if k == k0 else None, k, k + 1)
    reference = engine.advance(reference, engine.grid_time(k), engine.grid_time(k + 1))
    same = same and got == () and np.array_equal(kernel.end_y, engine.state_y(reference))
    slips += reference.kind != "stick"
print(len(calls), ticks, slips, same, len(events))
"""


@pytest.mark.slow
def test_ticks_sticking_after_a_slip_run_the_flexible_loop_without_the_hybrid_loop():
    # a tick that sticks after a slip (the slip s fixed) steps the flexible loop with the load's angle shifted by
    # -s / r_3 inside slip_tick, as hybrid_steps does, with the same floats; before, every such tick (most of the
    # truck's ticks after its first slip) went through hybrid_steps
    # truck_compressor: its first slip 0.5046-0.5068 s, the next at 0.5300 s; ticks 0.508 -> 0.528 s stick after it
    code = STICK_AFTER_SLIP.format(tests=os.path.dirname(__file__), t0=0.508, t1=0.528)
    done = subprocess.run([sys.executable, "-c", code], env=dict(os.environ, NUMBA_DISABLE_JIT="1"),
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    calls, ticks, slips, same, events = done.stdout.split()
    assert int(events) >= 2 and int(slips) == 0 and same == "True"  # slipped and re-stuck before; sticks throughout
    assert int(ticks) >= 20 and int(calls) == 0  # (one a tick on the old code)


def test_ticks_after_general_ticks_that_changed_the_held_torque():
    # a held-torque change in a tick of several steps goes the general path, which sets the held torque itself;
    # the compiled ticks after it read their own copy of the drive's data: it must have the new value
    torques = {k: 2.0 + 0.5 * (k % 4) for k in range(4, 200, 6)}
    fast, a, b, sims = _lockstep({"drive_source": "topic", "substeps": 4}, 200, torques)
    assert np.array_equal(a, b) and np.ptp(a[:, 8]) > 0.0
    assert 100 < fast < 200 - len(torques) + 2  # the change ticks went the general path, most others compiled


@pytest.mark.parametrize("values", [{"drive_source": "topic"},
                                    {"scene": "truck_compressor", "model": "slipping", "drive_source": "topic"}])
def test_ticks_after_a_restart_that_took_a_new_torque(values):
    # ~/reset restarts the run at the last tick, which samples the drive torque there (held from scene time 0
    # on): the compiled ticks after it read the new value from their copy of the drive's data
    sims = _pair(values)
    tick_ns = sims[0].settings.tick_ns
    rows, fast = ([], []), 0
    for k in range(120):
        now = 10**9 + k * tick_ns
        for j, sim in enumerate(sims):
            if k % 30 == 29:
                sim.drive.receive(5.0 + k / 30, now - tick_ns // 2, sim.settings)
                sim.restart("test")
            assert sim.advance_to(now)
            fast += j == 0 and sim._fresh_ns == now
            rows[j].append(sim.values(now) + list(sim.x))
    a, b = np.array(rows[0]), np.array(rows[1])
    assert np.array_equal(a, b) and fast > 100 and len(set(a[:, 8])) == 5  # 0 N m, then four values held


def test_the_jump_ticks_float_below_is_plant_left_of_where_the_profiles_say_so():
    # a plain tick before a held-torque jump clamps at the float below t1 when every profile's left_of is that one
    # (TorqueProfile's, a schedule of such parts): the number Plant.left_of gives; any other profile asks Plant
    from belt_drive_ros.core.sources import Constant, Schedule
    from belt_drive_ros.ros.simulation import _left_is_below

    class Earlier(Constant):
        def left_of(self, t):
            return t - 1e-6

    assert _left_is_below(Constant(1.0)) and _left_is_below(Schedule(Constant(1.0), Constant(2.0), ((0.1, 0.2),)))
    assert not _left_is_below(Earlier(1.0)) and not _left_is_below(Schedule(Earlier(1.0), Constant(2.0), ((0.1, 0.2),)))
    for values in ({"drive_source": "topic"}, {"scene": "truck_compressor", "model": "slipping", "drive_source": "topic"},
                   {"scene": "bsg_start", "drive_source": "topic"}, {"scene": "e_motor_start", "drive_source": "topic"}):
        sim = _pair(values)[0]
        assert sim._below
        plant = (sim.stepper.stepper if values.get("model") == "slipping" else sim.stepper).plant
        for t in (1e-3, 0.5, 0.7 + 1e-3 * 3, 2.0, 123.456):
            assert plant.left_of(t) == np.nextafter(t, -np.inf)


@pytest.mark.parametrize("values", [{"scene": "sine load", "drive_source": "topic"},
                                    {"scene": "truck_compressor", "model": "slipping", "drive_source": "topic"}])
def test_a_clamp_left_for_the_next_plain_tick_never_reaches_a_restarted_run(values, tmp_path):
    # a jump taken at a plain tick leaves the next tick's clamp (lo = t1) in the kernel's cells; a restart before
    # that tick sends it the general way, whose call writes all three clamps: the same floats as the general path
    # (a load of time: a stale clamp would change them; the kernel call reading it comes two ticks on, after the
    # run's start near t = 0)
    if values["scene"] == "sine load":
        values = {**values, "scene": _sine_load_scene(tmp_path)}
    sims = _pair(values)
    tick_ns = sims[0].settings.tick_ns
    rows = ([], [])
    left = 0
    for k in range(90):
        now = 10**9 + k * tick_ns
        for j, sim in enumerate(sims):
            if k % 15 == 7:
                sim.drive.receive(20.0 + k / 3, now - 1, sim.settings)
            if k % 15 == 8:
                if j == 0:
                    left += sim._tick_kernel.clamps[0] != -np.inf  # (the jump at tick 7 left tick 8's clamp)
                sim.restart("test")
            assert sim.advance_to(now)
            rows[j].append(sim.values(now) + list(sim.x))
    a, b = np.array(rows[0]), np.array(rows[1])
    assert left == 6 and np.array_equal(a, b)


@pytest.mark.ros
@pytest.mark.parametrize("params", [(("drive_source", "topic"), ("input_timeout", 0.0)),
                                    (("scene", "truck_compressor"), ("model", "slipping"), ("drive_source", "topic"),
                                     ("input_timeout", 0.0))])
def test_the_nodes_usual_tick_is_the_simulations_plain_tick(params):
    # BeltDriveNode._tick takes a plain tick through NodeSimulation.plain_tick itself, not advance_to (the plain
    # path is written once, in the simulation): a node whose joint_states alone is read publishes, tick by tick
    # through torque changes every 7th tick, the bytes and values of a node on the general path (no tick kernel)
    import time

    from rclpy.parameter import Parameter

    from belt_drive_ros.ros.executors import ros_session
    from belt_drive_ros.ros.node import BeltDriveNode

    with ros_session() as ctx:
        over = [Parameter("tick_thread", value=False)] + [Parameter(k, value=v) for k, v in params]
        nodes = [BeltDriveNode(context=ctx, parameter_overrides=over) for _ in range(2)]
        try:
            nodes[1].sim._tick_kernel = None  # the general path: the stepper (or the engine), model.outputs
            for node in nodes:
                node.refresh_subscriber_counts()
                node._readers["joint_states"] = 1  # the usual tick: joint_states alone
                node._count_listeners()
            calls = {"advance_to": 0, "plain_tick": 0}
            sim = nodes[0].sim
            for name in calls:
                def counted(now_ns, _f=getattr(sim, name), _name=name):
                    calls[_name] += 1
                    return _f(now_ns)

                setattr(sim, name, counted)
            tick_ns = sim.settings.tick_ns
            t0 = time.time_ns() // tick_ns * tick_ns
            for k in range(300):
                now = t0 + k * tick_ns
                sent = []
                for node in nodes:
                    if k % 7 == 3:
                        node.drive.receive(5.0 + (k % 11), now - 1, node.sim.settings)
                    with node.timing.lock:
                        sent.append(node._tick(now, True))
                assert [data for _, data in sent[0]] == [data for _, data in sent[1]]
                assert list(nodes[0]._last[0]) == list(nodes[1]._last[0])
            assert nodes[0].counters == nodes[1].counters
            assert calls["plain_tick"] > 290 and calls["advance_to"] < 5
        finally:
            for node in nodes:
                node.destroy_node()


def test_the_linear_tick_flags_slip_with_the_belts_centrifugal_tension():
    # bsg_start's belt has mass: the compiled tick's slip flag takes m' v^2 off both spans as the model's outputs do
    fast, a, b, sims = _lockstep({"scene": "bsg_start", "model": "flexible", "drive_source": "scene"}, 400)
    assert sims[0].settings.params.belt_mass > 0.0 and fast > 300
    assert np.array_equal(a, b)
    slip = a[:, 15]  # OUTPUT_UNITS' slip (0.0/1.0)
    assert slip.max() == 1.0 and slip.min() == 0.0  # the breakaway flags slip, later ticks pass


class _Warnings(_Log):
    def __init__(self):
        self.lines = []

    def warn(self, line):
        self.lines.append(line)


def test_a_torque_received_before_the_first_clock_applies_from_scene_time_zero():
    """Sim time: a drive_torque arrives while the node clock is still 0 (no /clock yet), then /clock starts at 50 s.
    The run starts there and applies that torque from its first tick; input_timeout counts from the start, not from
    node time 0 (before: 'drive_torque stale for 50 s', torque set to 0 at once). It still times out later."""
    values = {"drive_source": "topic", "timeout_behavior": "zero", "input_timeout": 0.5}
    scenes = SceneCache()
    full = {**default_values(scenes.get("paper")), **values}
    counters: dict = {}
    log = _Warnings()
    sim = NodeSimulation(build_settings(full, scenes), DriveInput(counters), counters, log)
    sim.drive.receive(5.0, 0, sim.settings)  # node time 0: before the first /clock
    start = 50 * 10**9
    tick = sim.settings.tick_ns
    for k in range(400):  # 0.4 s of ticks: within the timeout from the start
        assert sim.advance_to(start + k * tick)
        assert sim.drive.applied.value == 5.0, k
    assert log.lines == [] and counters["timeouts"] == 0 and sim.x[2] > 0.0  # the motor turns
    for k in range(400, 700):  # past 0.5 s without a message: stale, torque 0, said once
        sim.advance_to(start + k * tick)
    assert sim.drive.applied.value == 0.0 and counters["timeouts"] == 1
    assert len(log.lines) == 1 and log.lines[0].startswith("drive_torque stale for 0.5")

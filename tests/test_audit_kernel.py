"""Issue 20's structural promises about the compiled kernel, checked from outside (an auditor's view).

* numba and llvmlite are pinned in constraints.txt, and those are the versions installed;
* the entry points that never step a model never import them (the real console scripts, their imports
  listed by ``-X importtime``);
* no code is generated anywhere in the packages (no ``exec``, ``eval``, ``compile()``, no code objects);
* every compiled function is ``cache=True, nogil=True``, and the tick kernels the node calls really run
  without the GIL (another thread keeps running Python during the call);
* the first runs after ``make install`` (a scene, a slipping scene, a torque bag, the node's ticks, an
  ensemble, a network) compile nothing: every kernel comes from the disk cache, one signature each.
"""

from __future__ import annotations

import ast
import json
import math
import os
import re
import subprocess
import sys
import textwrap
import threading
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = (ROOT / "belt_drive_ros", ROOT / "msg_tools")
BIN = Path(sys.executable).parent
#: the modules holding compiled functions (every module of the package importing numba)
KERNEL_MODULES = ("belt_drive_ros.core.kernel", "belt_drive_ros.core.kernel_profiles", "belt_drive_ros.core.kernel_slip",
                  "belt_drive_ros.core.kernel_hybrid", "belt_drive_ros.core.kernel_affine",
                  "belt_drive_ros.core.kernel_variants", "belt_drive_ros.core.tick", "belt_drive_ros.core.network.tick",
                  "belt_drive_ros.core.network.slip_kernel")


# ------------------------------------------------------------------ pins and lazy import
def test_numba_and_llvmlite_are_pinned_and_installed_as_pinned():
    pins = dict(re.findall(r"^([A-Za-z0-9_.-]+)==(\S+)\s*$", (ROOT / "constraints.txt").read_text(), re.M))
    for name in ("numba", "llvmlite"):
        assert name in pins, f"{name} is not pinned (==) in constraints.txt"
        assert version(name) == pins[name], (name, version(name), pins[name])


def test_every_module_importing_numba_is_a_listed_kernel_module():
    """The list above is complete: a new kernel module joins it (and the checks below)."""
    found = set()
    for path in (ROOT / "belt_drive_ros").rglob("*.py"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else (
                [node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0 else [])
            if any(n.split(".")[0] == "numba" for n in names):
                found.add(".".join(path.relative_to(ROOT).with_suffix("").parts))
    assert found == set(KERNEL_MODULES)


def _imported_by(argv: list[str]) -> set[str]:
    """Top-level module names a process imported (``-X importtime`` lists every import on stderr)."""
    env = dict(os.environ, PYTHONPROFILEIMPORTTIME="1")
    done = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    rows = [line.split("|")[-1] for line in done.stderr.splitlines() if line.startswith("import time:")]
    assert len(rows) > 20, done.stderr[-2000:]  # the listing is there
    return {row.strip().split(".")[0] for row in rows}


@pytest.mark.parametrize("argv", [
    [str(BIN / "belt-drive"), "--help"],
    [str(BIN / "belt-drive"), "scenes"],
    [str(BIN / "belt-drive"), "scenes", "paper"],
    [str(BIN / "msg-tools"), "--help"],
    [sys.executable, "-c", "import belt_drive_ros"],
], ids=["belt-drive --help", "belt-drive scenes", "belt-drive scenes paper", "msg-tools --help", "import belt_drive_ros"])
def test_entry_points_that_never_step_a_model_never_import_numba(argv):
    loaded = _imported_by(argv)
    assert "belt_drive_ros" in loaded or "msg_tools" in loaded
    assert not loaded & {"numba", "llvmlite"}


def test_a_run_from_the_console_script_imports_numba():
    """The check above sees numba where a run imports it (it is no check that cannot fail)."""
    assert {"numba", "llvmlite"} <= _imported_by([str(BIN / "belt-drive"), "sim", "paper", "--duration", "0.01", "--quiet"])


# ------------------------------------------------------------------ no code generation
#: calls that run or build code from text or from code objects
GENERATING = {"exec", "eval", "compile", "FunctionType", "CodeType", "LambdaType"}


def _code_generation(source: str) -> list[int]:
    """Line numbers of ``exec(...)``, ``eval(...)``, ``compile(...)`` (the builtin, not ``re.compile`` nor a numba
    dispatcher's ``compile(tuple(types))`` of a signature), ``builtins.exec``, ``types.FunctionType(...)`` /
    ``CodeType`` and ``__code__`` assignments in ``source``."""
    lines = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Call):
            f = node.func
            if isinstance(f, ast.Name) and f.id in GENERATING:
                lines.append(node.lineno)
            elif isinstance(f, ast.Attribute) and f.attr in GENERATING and not (
                    f.attr == "compile" and isinstance(f.value, ast.Name) and f.value.id in ("re", "regex")) and not (
                    f.attr == "compile" and len(node.args) == 1 and not node.keywords and _signature(node.args[0])):
                lines.append(node.lineno)
        elif isinstance(node, (ast.Assign, ast.AugAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            if any(isinstance(t, ast.Attribute) and t.attr == "__code__" for t in targets):
                lines.append(node.lineno)
    return sorted(lines)


def _signature(arg) -> bool:
    """A numba signature written out: a tuple display or ``tuple(...)``."""
    return isinstance(arg, ast.Tuple) or isinstance(arg, ast.Call) and isinstance(arg.func, ast.Name) and arg.func.id == "tuple"


def test_the_detector_finds_code_generation():
    source = textwrap.dedent("""
        import re, builtins, types
        re.compile("a+")
        exec("x = 1")
        code = compile("1 + 1", "<loop>", "eval")
        builtins.exec(code)
        f = types.FunctionType(code, {})
        f.__code__ = code
        eval("2")
        kernel.compile(tuple(typeof(a) for a in args))
        kernel.compile("x = 1")
    """)
    assert _code_generation(source) == [4, 5, 6, 7, 8, 9, 11]


def test_no_code_is_generated_anywhere_in_the_packages():
    found = [f"{path.relative_to(ROOT)}:{line}" for package in PACKAGES for path in sorted(package.rglob("*.py"))
             for line in _code_generation(path.read_text(encoding="utf-8"))]
    assert not found, "code generated from text: " + ", ".join(found)


# ------------------------------------------------------------------ compiled functions: options, the GIL
def _dispatchers():
    import importlib

    from numba.core.registry import CPUDispatcher

    out = {}
    for name in KERNEL_MODULES:
        module = importlib.import_module(name)
        for attr, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.py_func.__module__ == name:
                out[f"{name}.{attr}"] = value
    return out


def test_every_compiled_function_is_cached_and_releases_the_gil():
    from numba.core.caching import NullCache

    found = _dispatchers()
    assert len(found) > 40  # every @njit of the kernel modules
    assert [n for n, d in found.items() if not d.targetoptions.get("nogil")] == []
    assert [n for n, d in found.items() if isinstance(d._cache, NullCache)] == []


def _python_runs_during(call, seconds: float = 0.5) -> int:
    """Loops of this thread's Python counter that ran while another thread ran ``call()`` again and again for
    ``seconds`` (at least 4 times).

    The interpreter's forced switch is turned off meanwhile (a switch interval of 1000 s): the GIL changes
    hands only where it is released. A call that keeps it lets this thread run nothing until the other thread
    has ended (0 loops); a call that releases it lets the counter run through it (this thread lends the GIL
    back every 10,000 loops, for the other to return from its call). Half a second of calls: on a loaded
    machine this thread waits its turn for a core, which comes many times in that while."""
    done = []

    def worker():
        end, calls = time.perf_counter() + seconds, 0
        while calls < 4 or time.perf_counter() < end:
            call()
            calls += 1
        done.append(True)

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1000.0)
    try:
        thread = threading.Thread(target=worker)
        thread.start()
        count = 0
        while not done:
            count += 1
            if count % 10_000 == 0:
                time.sleep(0)
        thread.join()
    finally:
        sys.setswitchinterval(interval)
    return count


def test_the_gil_detector_sees_a_kernel_that_holds_it():
    from numba import njit

    def busy(n):
        s = 0.0
        for i in range(n):
            s += math.sqrt(i + s % 7.0)
        return s

    held, free = njit(nogil=False)(busy), njit(nogil=True)(busy)
    n = 3_000_000
    assert held(10) == free(10)  # compiled before the count
    assert _python_runs_during(lambda: held(n)) == 0
    assert _python_runs_during(lambda: free(n)) > 1000


def test_the_node_tick_kernels_run_without_the_gil():
    """The node's tick thread computes while the executor runs Python: linear and slipping ticks."""
    from belt_drive_ros.core.params import BeltDriveParams
    from belt_drive_ros.core.model import FlexibleBeltModel
    from belt_drive_ros.core.slip_run import SlippingSimulator
    from belt_drive_ros.core.sources import Constant
    from belt_drive_ros.core.stepper import Plant, Stepper
    from belt_drive_ros.core.tick import SlipTickKernel, TickKernel

    params, torque = BeltDriveParams(), Constant(1.0)
    linear = TickKernel.of(Stepper(Plant(FlexibleBeltModel(params), torque, torque), "exact", 1e-4), 1.0e5)
    steps = 400_000
    assert linear.step(np.zeros(4), 0, 1) == 0
    assert _python_runs_during(lambda: linear.step(linear.state, 0, steps)) > 1000
    engine = SlippingSimulator(params, torque, torque, "etd2", 1e-4, check_stability=False)
    slipping = SlipTickKernel(engine, 1.0e5)
    state = engine.initial(np.zeros(5))
    slipping.advance(state, 0, 1)
    assert _python_runs_during(lambda: slipping.advance(state, 0, 100_000)) > 1000


# ------------------------------------------------------------------ the first runs compile nothing
#: runs as ``make install`` leaves the cache (argv[1]: a scratch folder): the entry points of a scene, a
#: slipping scene, a network, a torque bag replayed offline and its recording re-simulated, the node's linear,
#: slipping and network ticks, an ensemble; then every compiled function's signatures and cache misses
FIRST_RUNS = """
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
bags = Path(sys.argv[2])
from belt_drive_ros.cli import main
for argv in (["sim", "paper"], ["sim", "truck_compressor"], ["sim", "bsg_start"], ["sim", "fead_i4", "--duration", "0.05"],
             ["sim", str(bags / "engine_idle.yaml"), "--torque-bag", str(bags / "engine_idle_torque.mcap"),
              "--out", str(out / "replay.mcap")],
             ["sim", str(out / "replay.mcap"), "--torque-bag", str(bags / "engine_idle_torque.mcap"),
              "--out", str(out / "again.mcap")]):
    assert main(argv + ["--quiet"]) == 0, argv
sys.path.insert(0, sys.argv[3])
from test_node_tick import _lockstep
fast, *_ = _lockstep({"drive_source": "topic"}, 20, {5: 3.0})
slipping, *_ = _lockstep({"scene": "truck_compressor", "model": "slipping", "drive_source": "scene"}, 20)
assert fast > 10 and slipping > 10, (fast, slipping)
from belt_drive_ros.io.scenes import load_network
from belt_drive_ros.ros.network_stepper import NetworkStepper
from test_network_stepper import three_ticks
scene = load_network("fead_i4")
three_ticks(scene, NetworkStepper(scene, tier="flexible"))
from belt_drive_ros.campaign.ensemble_run import simulate_many
from belt_drive_ros.io.scenes import load_scene
base = load_scene("paper")
scenes = [base.with_overrides(duration=0.2, params=base.params.replace(k=base.params.k * (1 + 0.01 * j))) for j in range(8)]
outcomes = list(simulate_many(scenes))
assert len(outcomes) == 8 and all(o.error is None and o.ensemble for o in outcomes), outcomes
from numba.core.registry import CPUDispatcher
import belt_drive_ros.core.kernel_variants
report = {}
for name, module in list(sys.modules.items()):
    if name.startswith("belt_drive_ros."):
        for attr, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.py_func.__module__ == name:
                stats = value.stats
                report[f"{name}.{attr}"] = [len(value.signatures), sum(stats.cache_misses.values()),
                                            sum(stats.cache_hits.values()), value._cache._cache_file._index_path]
print(json.dumps(report))
"""


@pytest.mark.slow
def test_the_first_runs_after_install_compile_nothing(tmp_path):
    """Every kernel these runs call comes from the disk cache ``make install`` warmed (numba's
    ``[cache] data saved`` would mean a compilation), with one signature: profiles are data."""
    env = dict(os.environ, NUMBA_DEBUG_CACHE="1")
    done = subprocess.run([sys.executable, "-c", FIRST_RUNS, str(tmp_path), str(ROOT / "bags"), str(ROOT / "tests")],
                          capture_output=True, text=True, env=env, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    saved = [line for line in done.stdout.splitlines() if line.startswith("[cache] data saved")]
    assert saved == [], "compiled after make install:\n" + "\n".join(saved)
    report = json.loads(done.stdout.strip().splitlines()[-1])
    used = {name: row for name, row in report.items() if row[0]}
    # the entry points these runs reach, each loaded from the cache (called from Python: a cache hit of its own)
    for name in ("core.kernel.linear_steps", "core.kernel.wheel_steps", "core.kernel_hybrid.hybrid_steps",
                 "core.tick.linear_tick", "core.tick.slip_tick", "core.network.tick.network_tick",
                 "core.kernel_variants.variant_steps"):
        assert used.get(f"belt_drive_ros.{name}", [0, 0, 0])[2] >= 1, (name, used.get(f"belt_drive_ros.{name}"))
    # one signature each, but the state loop: one per literal ``wide`` (kernel._explicit, kernel._explicit_wide)
    counts = {"belt_drive_ros.core.kernel._state_loop": (1, 2)}
    assert {name: row for name, row in used.items() if row[0] not in counts.get(name, (1,)) or row[1] != 0} == {}
    # ... and that cache entry is make install's, not one another test wrote while this one ran (pytest -n 2: the
    # other worker starts at once; a kernel make install missed, compiled and saved there within the first
    # seconds, was a cache hit here too). tests/conftest.py notes when the suite started.
    start = float(os.environ["BELT_DRIVE_SUITE_START"])
    late = {name: row[3] for name, row in used.items() if os.path.getmtime(row[3]) >= start}
    assert late == {}, "cache entries written during this test session, not by make install: " + ", ".join(late)
    # the torque bag's run, re-simulated from its recording (the bag passed: it is not next to the recording;
    # before, sim ignored --torque-bag for a recording and refused it, the message saying to pass --torque-bag)
    from msg_tools.cli import main as msg_tools

    assert msg_tools(["compare", str(tmp_path / "replay.mcap"), str(tmp_path / "again.mcap"), "--rtol", "0", "--atol", "0"]) == 0


def test_numba_disable_jit_runs_the_kernels_as_python_with_the_same_floats(tmp_path):
    """The interpreted-run tests (test_bench_fastpath, test_node_tick, test_ensemble, ...) compare a child run under
    ``NUMBA_DISABLE_JIT=1`` with a compiled one: that child does run every kernel as plain Python (were the
    variable not honoured, both runs compiled, they would pass comparing a run with itself)."""
    from belt_drive_ros.io.scenes import load_scene
    from belt_drive_ros.core.simulate import simulate

    code = textwrap.dedent(f"""
        import importlib, sys, types, numpy as np
        from numba.core.registry import CPUDispatcher
        modules = [importlib.import_module(m) for m in {KERNEL_MODULES!r}]
        compiled = [f"{{m.__name__}}.{{a}}" for m in modules for a, v in vars(m).items() if isinstance(v, CPUDispatcher)]
        assert compiled == [], compiled
        from belt_drive_ros.core import kernel
        assert isinstance(kernel.linear_steps, types.FunctionType)
        from belt_drive_ros.core.simulate import simulate
        from belt_drive_ros.io.scenes import load_scene
        np.save(sys.argv[1], simulate(load_scene("paper"), duration=0.05).states)
    """)
    path = tmp_path / "states.npy"
    done = subprocess.run([sys.executable, "-c", code, str(path)], env=dict(os.environ, NUMBA_DISABLE_JIT="1"),
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    compiled = simulate(load_scene("paper"), duration=0.05).states
    assert compiled.shape[0] > 10 and np.array_equal(np.load(path), compiled)


# ------------------------------------------------------------------ the drawing in docs/development.md
def _drawing() -> str:
    text = (ROOT / "docs" / "development.md").read_text(encoding="utf-8")
    section = text.split("## The compiled kernel: a parameter's path from scene to output", 1)[1]
    return section.split("```", 2)[1]


def test_the_drawing_of_a_parameters_path_names_what_the_code_has():
    """Every file the drawing names exists, and every function, class and constant it names is defined in the
    package (with its argument list where it gives one): a rename or a move makes the drawing fail here."""
    drawing = _drawing()
    files = set(re.findall(r"\b((?:core|io|ros)/[\w/]+\.py)\b", drawing))
    assert len(files) >= 6 and [f for f in files if not (ROOT / "belt_drive_ros" / f).is_file()] == []
    source = "\n".join(p.read_text(encoding="utf-8") for p in (ROOT / "belt_drive_ros").rglob("*.py"))
    names = set(re.findall(r"\b([A-Za-z_]\w*)\(", drawing)) | set(re.findall(r"\.(\w+)\(", drawing))
    names |= {n.rsplit(".", 1)[-1] for n in re.findall(r"(?:\.py: |-> )([A-Za-z_][\w.]*)", drawing)}
    names |= {"MOTOR_LINE", "StageScheme", "Stepper", "KernelLoop", "wheel_steps"}
    names -= {"core", "io", "py", "row", "U_i"}  # a path's parts, the drawing's words
    assert {"linear_steps", "load_scene", "make_profile", "profile_torque", "outputs"} <= names
    undefined = sorted(n for n in names if not re.search(rf"^\s*(?:def {n}\b|class {n}\b|(?:\w+\s*,\s*)*{n}\s*(?:,\s*\w+\s*)*(?::[^=\n]*)?=)", source, re.M))
    assert undefined == []
    signature = re.search(r"kernel\.linear_steps\(([^)]*)\)", drawing).group(1)
    assert re.search(rf"^def linear_steps\({re.escape(signature)}\):", source, re.M)

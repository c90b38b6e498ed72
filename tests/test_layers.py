"""The package's three layers, as the folders show them, and their import rules.

* ``belt_drive_ros.core``: numpy, scipy, numba and the standard library only (it reads no file);
  never ``io``, ``ros``, rclpy, mcap or msg_tools. numba is imported only where a run
  starts: ``belt-drive --help``, ``belt-drive scenes`` and ``msg-tools`` never load it.
* ``belt_drive_ros.io``: ROS-free input and output; may use core and msg_tools/mcap,
  never ``ros`` or rclpy.
* ``belt_drive_ros.ros``: the rclpy adapters; may use core and io.
* ``belt_drive_ros.campaign``: sweeps on Dask; may use core, io, msg_tools, pandas, dask; never ``ros``.
* No import circles between modules of the package (module level or inside functions).

The static checks read every ``import`` statement (also those inside functions)
with :mod:`ast`; the dynamic checks import in a fresh interpreter (this pytest
process has rclpy loaded by other tests already).
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "belt_drive_ros"
#: per layer: the package's own layers it may import, and the third-party top-level modules
MAY_IMPORT = {
    "core": ({"core"}, {"numpy", "scipy", "numba"}),
    "io": ({"core", "io"}, {"numpy", "scipy", "yaml", "mcap", "mcap_ros2", "msg_tools", "zstandard", "matplotlib"}),
    "campaign": ({"core", "io", "campaign"}, {"numpy", "scipy", "yaml", "msg_tools", "matplotlib", "pandas", "pyarrow",
                                                "dask", "distributed"}),
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path) -> list[tuple[str, int]]:
    """Absolute names of every module ``path`` imports (anywhere in the file), with line numbers."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            out.append((target, node.lineno))
            for alias in node.names:  # ``from . import x`` imports the submodule x
                candidate = f"{target}.{alias.name}"
                if (PACKAGE.parent / (candidate.replace(".", "/") + ".py")).exists():
                    out.append((candidate, node.lineno))
    return out


def _modules(layer: str) -> list[Path]:
    return sorted((PACKAGE / layer).rglob("*.py"))


def test_the_three_layers_exist():
    for layer in ("core", "io", "ros"):
        assert (PACKAGE / layer / "__init__.py").is_file(), layer
        assert len(_modules(layer)) > 1, layer


@pytest.mark.parametrize("layer", sorted(MAY_IMPORT))
def test_layer_imports_only_what_it_may(layer):
    own_layers, third_party = MAY_IMPORT[layer]
    stdlib = set(sys.stdlib_module_names)
    bad = []
    for path in _modules(layer):
        for target, line in _imports(path):
            parts = target.split(".")
            if parts[0] == "belt_drive_ros":
                ok = len(parts) > 1 and parts[1] in own_layers
            else:
                ok = parts[0] in stdlib or parts[0] in third_party
            if not ok:
                bad.append(f"{path.relative_to(PACKAGE.parent)}:{line} imports {target}")
    assert not bad, f"{layer} breaks its layer rule:\n" + "\n".join(bad)


def test_no_import_circles():
    paths = sorted(PACKAGE.rglob("*.py"))
    names = {_module_name(p) for p in paths}
    graph = {_module_name(p): {t for t, _ in _imports(p) if t in names and t != _module_name(p)} for p in paths}
    # a package's __init__ is not an edge target worth following (re-exports only)
    graph = {k: {t for t in v if not (PACKAGE.parent / t.replace(".", "/") / "__init__.py").exists()}
             for k, v in graph.items()}
    cycles, state, stack = [], {}, []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node)
    assert not cycles, "import circles:\n" + "\n".join(" -> ".join(c) for c in cycles)


#: core modules that touch files, and why: numba's disk cache of the kernels (its stamps, the kernels' sources)
READS_FILES = {"jit_cache.py"}
#: what reading a file looks like in a module (open, stat, read_text ... and the package's own readers)
FILE_READS = re.compile(r"(?<![\w.])open\(|\.(read_text|read_bytes|stat|lexists|listdir|scandir|open)\(|"
                        r"\b(read_yaml|parse_yaml|read_text|check_path|open_regular)\(")


def test_the_core_reads_no_file():
    """Scene files, campaign files and YAML are read in io (io/inputs.py, io/scenes.py): the core builds and checks
    from parsed mappings and arrays; it only lists the names of the shipped scenes."""
    found = [f"{path.relative_to(PACKAGE.parent)}:{n}: {line.strip()}"
             for path in _modules("core") if path.name not in READS_FILES
             for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
             if FILE_READS.search(line)]
    assert not found, "the core reads files:\n" + "\n".join(found)


def _loaded_after(code: str, prefixes: tuple[str, ...]) -> list[str]:
    probe = code + "\nimport sys\nprint(sorted(m for m in sys.modules if m.split('.')[0] in %r))" % (prefixes,)
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return eval(out.stdout.strip().splitlines()[-1])  # noqa: S307 - our own list literal


def test_core_runs_without_rclpy_or_mcap():
    code = "\n".join(f"import {_module_name(p)}" for p in _modules("core") if p.stem != "__init__")
    code += "\nfrom belt_drive_ros.core.simulate import simulate\nfrom belt_drive_ros.io.scenes import load_scene\n"
    code += "simulate(load_scene('paper'), duration=0.01)"
    assert _loaded_after(code, ("rclpy", "mcap", "mcap_ros2", "msg_tools")) == []


def test_io_runs_without_rclpy():
    code = "\n".join(f"import belt_drive_ros.io.{p.stem}" for p in _modules("io") if p.stem != "__init__")
    assert _loaded_after(code, ("rclpy",)) == []


@pytest.mark.parametrize("command", ["node", "source", "demo", "record", "replay", "sim"])
def test_command_modules_import_rclpy_only_when_run(command):
    assert _loaded_after(f"import belt_drive_ros.commands.{command}", ("rclpy",)) == []


def test_cli_parser_does_not_import_rclpy():
    assert _loaded_after("from belt_drive_ros.cli import build_parser\nbuild_parser()", ("rclpy",)) == []


def test_msg_tools_takes_only_the_bounded_loader_from_the_package():
    """msg_tools is a sibling package over io's stdlib+PyYAML loader (io.inputs), nothing else of belt_drive_ros:
    every YAML it reads from a file (metadata.yaml, rosbag2 and QoS metadata) goes through the same bounded loader."""
    allowed = {"belt_drive_ros.io.inputs"}
    used, bad = set(), []
    for path in sorted((PACKAGE.parent / "msg_tools").glob("*.py")):
        for target, line in _imports(path):
            if target.split(".")[0] == "belt_drive_ros":
                used.add(target)
                if target not in allowed:
                    bad.append(f"msg_tools/{path.name}:{line} imports {target}")
    assert not bad, "\n".join(bad)
    assert used == allowed
    code = "from belt_drive_ros.io.inputs import parse_yaml\nparse_yaml('a: 1')"
    assert _loaded_after(code, ("belt_drive_ros",)) == ["belt_drive_ros", "belt_drive_ros.core", "belt_drive_ros.core.errors",
                                                        "belt_drive_ros.io", "belt_drive_ros.io.inputs"]


@pytest.mark.parametrize("code", [
    "from belt_drive_ros.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass",
    "from belt_drive_ros.cli import main\nmain(['scenes'])",
    "from msg_tools.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass",
    "import belt_drive_ros.core.scene, belt_drive_ros.core.sources, belt_drive_ros.core.integrators",
], ids=["belt-drive --help", "belt-drive scenes", "msg-tools --help", "core imports"])
def test_numba_is_imported_only_where_a_run_starts(code):
    # numba (and llvmlite under it) costs ~0.3 s of import: commands that never step a model never pay it
    assert _loaded_after(code, ("numba", "llvmlite")) == []


def test_a_run_does_use_the_compiled_kernel():
    code = "from belt_drive_ros.core.simulate import simulate\nfrom belt_drive_ros.io.scenes import load_scene\n"
    code += "simulate(load_scene('paper'), duration=0.01)"
    assert "numba" in _loaded_after(code, ("numba",))


def test_a_plain_sim_of_a_scene_loads_no_recording_library(tmp_path):
    """``belt-drive sim paper`` reads no recording: mcap and msg_tools (~0.17 s of import) load only for a
    recording (the network-recording check once loaded them for every scene)."""
    code = "from belt_drive_ros.cli import main\nmain(['sim', 'paper', '--duration', '0.01', '--quiet'])"
    assert _loaded_after(code, ("mcap", "msg_tools", "mcap_ros2")) == []

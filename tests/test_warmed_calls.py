"""No Python code calls a kernel helper that only other kernels call (``inline="always"``): such a call compiles and
caches a specialisation of its own, which ``make install`` never warms (core/warm.py), so the first run after a
fresh install compiles it there (seconds) and writes a cache entry nobody else reads. Tests reach those helpers
through the warmed kernel that inlines them (``tests/test_kernel_slip.py``: the phi functions through the modal
flow) or through their ``py_func`` (plain Python)."""

from __future__ import annotations

import ast
from pathlib import Path

from test_audit_kernel import KERNEL_MODULES, _dispatchers

ROOT = Path(__file__).resolve().parents[1]


def _inline_only() -> dict[str, set[str]]:
    """Per kernel module (dotted name): its functions compiled only inlined into other kernels."""
    out: dict[str, set[str]] = {}
    for name, dispatcher in _dispatchers().items():
        module, attr = name.rsplit(".", 1)
        if dispatcher.targetoptions.get("inline") == "always":
            out.setdefault(module, set()).add(attr)
    return out


def _package_of(path: Path) -> str:
    """The dotted package a file of the repository belongs to ('' outside ``belt_drive_ros``)."""
    parts = path.resolve().relative_to(ROOT).parent.parts
    return ".".join(parts) if parts[:1] == ("belt_drive_ros",) else ""


def _calls_of(text: str, package: str, label: str, inline: dict[str, set[str]]) -> list[str]:
    """``label:line name`` of each call in the source ``text`` (of a module of ``package``) of a name of ``inline``:
    ``module.NAME(...)`` through a module imported by any alias, or ``NAME(...)`` imported from it."""
    tree = ast.parse(text)
    modules: dict[str, str] = {}  # alias -> kernel module
    names: dict[str, str] = {}  # local name -> "module.NAME"
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from the package, up level - 1
                up = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            for a in node.names:
                if f"{base}.{a.name}" in inline:
                    modules[a.asname or a.name] = f"{base}.{a.name}"
                elif a.name in inline.get(base, ()):
                    names[a.asname or a.name] = f"{base}.{a.name}"
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name in inline and a.asname:
                    modules[a.asname] = a.name
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) and f.value.id in modules \
                and f.attr in inline[modules[f.value.id]]:
            found.append(f"{label}:{node.lineno} {modules[f.value.id]}.{f.attr}")
        elif isinstance(f, ast.Name) and f.id in names:
            found.append(f"{label}:{node.lineno} {names[f.id]}")
    return found


def test_no_python_code_calls_an_inline_only_kernel_helper():
    inline = _inline_only()
    assert "_phis4" in inline["belt_drive_ros.core.kernel_slip"]  # (what the scan looks for is there)
    kernels = {ROOT / Path(*m.split(".")).with_suffix(".py") for m in KERNEL_MODULES}  # (their calls: compiled ones)
    files = sorted(set((ROOT / "tests").glob("*.py")) | set((ROOT / "belt_drive_ros").rglob("*.py")))
    found = [call for path in files if path not in kernels
             for call in _calls_of(path.read_text(encoding="utf-8"), _package_of(path), str(path.relative_to(ROOT)),
                                   inline)]
    assert found == [], "called from Python (a specialisation make install does not warm):\n" + "\n".join(found)


def test_the_scan_finds_such_a_call():
    """The check above can fail: each way of naming a helper is found (and a ``py_func`` call or a warmed
    kernel is not)."""
    inline = _inline_only()
    text = ("from belt_drive_ros.core import kernel_slip\nfrom belt_drive_ros.core import kernel_slip as ks\n"
            "from belt_drive_ros.core.kernel_slip import _phis4 as p4\n"
            "import belt_drive_ros.core.kernel_profiles as kp\n"
            "from ..kernel_profiles import polynomial\n"
            "kernel_slip._phis4(1j)\nks._phis4(1j)\np4(1j)\nkp.motor_line(1.0, 0.0, 0.0, 0.0, 0.0)\n"
            "polynomial(0.0, 0.0, 0.0, 1.0)\nkernel_slip._phis4.py_func(1j)\nkernel_slip.event_step()\n")
    found = _calls_of(text, "belt_drive_ros.core.network", "sample", inline)
    assert [f.split(" ")[1].rsplit(".", 1)[1] for f in found] == ["_phis4"] * 3 + ["motor_line", "polynomial"], found

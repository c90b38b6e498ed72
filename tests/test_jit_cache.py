"""The compiled kernels' disk cache follows their sources (core/jit_cache.py)."""

from __future__ import annotations

import shutil

from belt_drive_ros.core import jit_cache


def _copy_core(tmp_path, monkeypatch):
    core = tmp_path / "belt_drive_ros" / "core"
    shutil.copytree(jit_cache.CORE, core, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(jit_cache, "CORE", core)
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    return core


def _entries(core):
    """One cache entry per kernel file (index and data), as numba names them."""
    return {name + suffix: core / folder / "__pycache__" / f"{stem}.run-10.py312{suffix}"
            for name, folder, stem in (("kernel", ".", "kernel"), ("profiles", ".", "kernel_profiles"),
                                       ("variants", ".", "kernel_variants"), ("tick", ".", "tick"),
                                       ("network_slip", "network", "slip_kernel"))
            for suffix in (".nbi", ".1.nbc")}  # fmt: skip


def _make(entries):
    for entry in entries.values():
        entry.parent.mkdir(parents=True, exist_ok=True)
        entry.write_bytes(b"compiled")


def _gone(entries):
    return {name.split(".")[0] for name, entry in entries.items() if not entry.exists()}


def _edit(path):
    path.write_text(path.read_text() + "\n# edited\n")


def test_only_entries_built_from_an_edited_source_are_dropped(tmp_path, monkeypatch):
    core = _copy_core(tmp_path, monkeypatch)
    entries = _entries(core)
    _make(entries)
    assert jit_cache.refresh() is True  # no stamp yet: built from unknown sources
    assert not any(e.exists() for e in entries.values())
    _make(entries)
    assert jit_cache.refresh() is False and all(e.exists() for e in entries.values())
    # a leaf kernel file: its own entries only
    _edit(core / "kernel_variants.py")
    assert jit_cache.refresh() is True
    assert _gone(entries) == {"variants"}
    _make(entries)
    # a module the node's tick imports (not a kernel file itself): the tick's entries
    _edit(core / "slip_run.py")
    assert jit_cache.refresh() is True
    assert _gone(entries) == {"tick"}
    _make(entries)
    # the linear loop: its own entries and those of every file that imports it (not the profiles', which it imports)
    _edit(core / "kernel.py")
    assert jit_cache.refresh() is True
    assert _gone(entries) == {"kernel", "variants", "tick"}
    _make(entries)
    # the profiles every kernel reads: every entry, in both folders
    _edit(core / "kernel_profiles.py")
    assert jit_cache.refresh() is True and not any(e.exists() for e in entries.values())
    _make(entries)
    # a source no kernel imports: nothing
    _edit(core / "simulate.py")
    assert jit_cache.refresh() is False and all(e.exists() for e in entries.values())


def test_a_new_kernel_file_and_the_module_it_imports_are_followed(tmp_path, monkeypatch):
    """A kernel file added after the last check, importing a module added with it: an edit of that module
    drops the new file's entries (the quick check covers every source of the folder, not only the known ones)."""
    core = _copy_core(tmp_path, monkeypatch)
    jit_cache.refresh()
    (core / "helper_x.py").write_text("K = 1\n")
    (core / "kernel_x.py").write_text("from numba import njit\n\nfrom .helper_x import K\n")
    entry = core / "__pycache__" / "kernel_x.f-3.py312.nbi"
    jit_cache.refresh()
    entry.write_bytes(b"compiled")
    assert jit_cache.refresh() is False and entry.exists()
    (core / "helper_x.py").write_text("K = 2\n")
    assert jit_cache.refresh() is True and not entry.exists()


def test_entries_under_numba_cache_dir_are_handled(tmp_path, monkeypatch):
    core = _copy_core(tmp_path / "pkg", monkeypatch)
    user = tmp_path / "cache"
    mirrored = user / "site" / "belt_drive_ros" / "core" / "network"
    mirrored.mkdir(parents=True)
    (mirrored / "slip_kernel.run-5.py312.nbi").write_bytes(b"stale")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(user))
    assert jit_cache.refresh() is True
    assert not (mirrored / "slip_kernel.run-5.py312.nbi").exists()
    (mirrored / "slip_kernel.run-5.py312.nbi").write_bytes(b"fresh")
    assert jit_cache.refresh() is False and (mirrored / "slip_kernel.run-5.py312.nbi").exists()
    _edit(core / "network" / "slip_kernel.py")
    assert jit_cache.refresh() is True and not (mirrored / "slip_kernel.run-5.py312.nbi").exists()
    assert (core / "__pycache__" / jit_cache.STAMP).exists()


#: the modules of compiled kernels (every @njit function of the package is in one of them)
KERNEL_MODULES = ("kernel", "kernel_affine", "kernel_hybrid", "kernel_profiles", "kernel_slip", "kernel_variants",
                  "tick", "network.slip_kernel", "network.tick")


def _literal_parameters(fn) -> set[str]:
    """The parameters ``fn``'s body passes to ``numba.literally`` (a call, not a mention in a comment or docstring)."""
    import ast
    import inspect
    import textwrap

    tree = ast.parse(textwrap.dedent(inspect.getsource(fn)))
    return {c.args[0].id for c in ast.walk(tree) if isinstance(c, ast.Call) and isinstance(c.func, ast.Name)
            and c.func.id == "literally" and len(c.args) == 1 and isinstance(c.args[0], ast.Name)}


def test_the_literal_parameters_are_read_from_calls_only():
    def f(a, b, c):
        """literally(b) in a docstring"""
        literally(a)  # noqa: F821 (read, not run)
        return c  # literally(c) in a comment

    assert _literal_parameters(f) == {"a"}


def _literal_arguments(module_name: str) -> list[str]:
    """Calls from one compiled function to another, not inlined one, that pass an int or bool constant
    (a literal, or a module constant such as ``STICK``): numba types such an argument as ``Literal[int](0)``
    and compiles the callee once more for it, beside the signature Python's calls compile. A parameter the callee
    asks numba to make literal (``literally(name)``: one compiled copy per value, on purpose) is not counted."""
    import ast
    import importlib
    import inspect

    from numba.core.registry import CPUDispatcher

    module = importlib.import_module(f"belt_drive_ros.core.{module_name}")

    def dispatcher(name):
        obj = getattr(module, name, None)
        return obj if isinstance(obj, CPUDispatcher) else None

    def constant(node, local):
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            node = node.operand
        if isinstance(node, ast.Constant):
            return isinstance(node.value, (bool, int))
        if isinstance(node, ast.Name) and node.id not in local:
            return isinstance(getattr(module, node.id, None), (bool, int))
        return False

    found = []
    for fn in ast.parse(inspect.getsource(module)).body:
        if not isinstance(fn, ast.FunctionDef) or dispatcher(fn.name) is None:
            continue
        local = {a.arg for a in fn.args.args} | {n.id for n in ast.walk(fn) if isinstance(n, ast.Name)
                                                  and isinstance(n.ctx, ast.Store)}
        for call in (n for n in ast.walk(fn) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)):
            callee = dispatcher(call.func.id)
            if callee is None or callee.targetoptions.get("inline", "never") == "always":
                continue
            params = list(inspect.signature(callee.py_func).parameters)
            literal = _literal_parameters(callee.py_func)
            for k, arg in enumerate(call.args):
                if constant(arg, local) and not (k < len(params) and params[k] in literal):
                    found.append(f"{module_name}.py:{call.lineno} {fn.name} -> {call.func.id} argument {k}")
    return found


def test_compiled_calls_pass_no_literal_numbers_to_other_kernels():
    """A compiled caller passing ``0`` where Python's calls pass an int64 made ``make install`` compile the
    whole slipping hybrid loop and its event step twice (and a tick helper four times), and the cache
    hold both: each kernel is compiled once, with the one signature runs use."""
    found = [f for name in KERNEL_MODULES for f in _literal_arguments(name)]
    assert not found, "\n".join(found)

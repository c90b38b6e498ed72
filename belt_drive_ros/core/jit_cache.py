"""Keep numba's disk cache of the compiled kernels in step with their sources.

numba checks a cached function against its own file only, but a kernel holds what it took from the modules it
imports (a callee's machine code, an inlined helper, a constant). So each file's entries (``<file>.*.nbi``, ``*.nbc``
in ``core/__pycache__``, ``core/network/__pycache__`` or their mirror under ``NUMBA_CACHE_DIR``) are stamped with a
SHA-256 over the file and the package modules it imports at module level, transitively, and removed before any
kernel loads when that stamp changed. A folder we cannot write is left alone.
"""

from __future__ import annotations

import ast
import hashlib
import json
import os
from pathlib import Path

CORE = Path(__file__).resolve().parent
#: per folder: ``{"files": every source the entries were built from, "digest": of them all, "stamps": {file stem: digest}}``
STAMP = "kernels.json"


def _imports(path: Path) -> set[Path]:
    """The package's files ``path`` imports at module level (inside a top-level ``if``/``try`` too)."""
    package, found = CORE.parent, set()
    nodes = list(ast.parse(path.read_bytes()).body)
    while nodes:
        node = nodes.pop()
        if isinstance(node, (ast.If, ast.Try, ast.ExceptHandler)):
            nodes += [n for n in ast.iter_child_nodes(node) if isinstance(n, (ast.stmt, ast.ExceptHandler))]
        modules = [(0, a.name, ()) for a in node.names] if isinstance(node, ast.Import) else []
        if isinstance(node, ast.ImportFrom):
            modules = [(node.level, node.module or "", [a.name for a in node.names])]
        for level, module, names in modules:
            if level or module.split(".")[0] == package.name:
                target = (path.parents[level - 1] if level else package.parent).joinpath(*filter(None, module.split(".")))
                for t in [target, *(target / name for name in names)]:
                    found |= {f for f in (t.with_suffix(".py"), t / "__init__.py") if f.is_file()}
    return found


def _closure(path: Path) -> list[Path]:
    """``path`` and the package modules it imports at module level, transitively (sorted)."""
    seen, todo = set(), [path]
    while todo:
        f = todo.pop()
        if f not in seen:
            seen.add(f)
            todo += _imports(f) if f.is_file() else []
    return sorted(seen)


def _digest(files) -> str:
    h = hashlib.sha256()
    for f in files:
        h.update(str(f.relative_to(CORE.parent)).encode())
        h.update(f.read_bytes() if f.is_file() else b"")
    return h.hexdigest()


def _cache_folders() -> list[tuple[Path, Path]]:
    """(cache folder, the source folder its entries were built from)."""
    folders = [(CORE / "__pycache__", CORE), (CORE / "network" / "__pycache__", CORE / "network")]
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user and Path(user).is_dir():
        tail = ("belt_drive_ros", "core")
        for stamp in Path(user).rglob("*.nbi"):
            parts = stamp.parent.parts
            if parts[-2:] == tail or parts[-3:-1] == tail:
                folders.append((stamp.parent, CORE if parts[-2:] == tail else CORE / parts[-1]))
    return list(dict.fromkeys(folders))


def refresh() -> bool:
    """Drop cache entries built from other sources than today's; True when some were dropped."""
    dropped = False
    for folder, sources in _cache_folders():
        here = {str(p.relative_to(CORE.parent)) for p in sources.glob("*.py")}  # a new kernel file is seen at once
        try:
            old = json.loads((folder / STAMP).read_text())
            if _digest(CORE.parent / f for f in sorted(here | set(old["files"]))) == old["digest"]:
                continue  # not one file the entries were built from changed since the last check
        except (OSError, ValueError, KeyError, TypeError):
            old = {}
        entries = list(folder.glob("*.nbi")) + list(folder.glob("*.nbc"))
        stems = {e.name.split(".")[0] for e in entries} | {p.stem for p in sources.glob("*.py") if b"njit" in p.read_bytes()}
        closures = {s: _closure(sources / f"{s}.py") for s in stems}
        stamps = {s: _digest(files) for s, files in closures.items()}
        files = sorted(here | {str(f.relative_to(CORE.parent)) for c in closures.values() for f in c})
        try:
            for entry in entries:
                stem = entry.name.split(".")[0]
                if stamps[stem] != old.get("stamps", {}).get(stem):
                    entry.unlink()
                    dropped = True
            folder.mkdir(parents=True, exist_ok=True)
            digest = _digest(CORE.parent / f for f in files)
            (folder / STAMP).write_text(json.dumps({"files": files, "digest": digest, "stamps": stamps}))
        except OSError:
            continue  # a read-only install: numba itself then caches elsewhere
    return dropped

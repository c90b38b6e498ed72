"""Keep numba's disk cache of the compiled kernels in step with their sources.

numba checks a cached function against its own file only, but a kernel also
holds what it took from other modules when it compiled: a compiled callee's
machine code (every loop calls ``kernel.profile_torque``), an inlined helper's
body, a module constant. A kernel reaches another module only through a
module-level import, so each source file's entries (``<file>.*.nbi``,
``*.nbc``) are stamped with a SHA-256 over that file and every package module
it imports at module level, transitively. Before any kernel loads, the entries
whose stamp differs are removed: an edit of ``kernel_variants.py`` drops its
own entries, one of ``kernel.py`` those of every file importing it. Folders:
``core/__pycache__``, ``core/network/__pycache__`` or their mirror under
``NUMBA_CACHE_DIR``; a folder we cannot write is left alone.
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
    """The files of the package ``path`` imports at module level (inside a top-level ``if``/``try`` too)."""
    package, found = CORE.parent, set()
    nodes = list(ast.parse(path.read_bytes()).body)
    while nodes:
        node = nodes.pop()
        if isinstance(node, (ast.If, ast.Try)):
            nodes += [*node.body, *node.orelse, *getattr(node, "finalbody", ()), *(b for h in getattr(node, "handlers", ()) for b in h.body)]
        elif isinstance(node, ast.ImportFrom) and node.level:
            base = path.parent
            for _ in range(node.level - 1):
                base = base.parent
            base = base.joinpath(*node.module.split(".")) if node.module else base
            for name in [None] + [a.name for a in node.names]:
                target = base / name if name else base
                found |= {f for f in (target.with_suffix(".py"), target / "__init__.py") if f.is_file()}
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
            for name in (n for n in names if n.split(".")[0] == package.name):
                target = package.parent.joinpath(*name.split("."))
                found |= {f for f in (target.with_suffix(".py"), target / "__init__.py") if f.is_file()}
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
        try:
            old = json.loads((folder / STAMP).read_text())
            if _digest(CORE.parent / f for f in old["files"]) == old["digest"]:
                continue  # not one file the entries were built from changed since the last check
        except (OSError, ValueError, KeyError, TypeError):
            old = {}
        entries = list(folder.glob("*.nbi")) + list(folder.glob("*.nbc"))
        stems = {e.name.split(".")[0] for e in entries} | {p.stem for p in sources.glob("*.py") if b"njit" in p.read_bytes()}
        closures = {s: _closure(sources / f"{s}.py") for s in stems}
        stamps = {s: _digest(files) for s, files in closures.items()}
        files = sorted({str(f.relative_to(CORE.parent)) for c in closures.values() for f in c})
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

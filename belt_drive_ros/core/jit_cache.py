"""Keep numba's disk cache of the compiled kernels in step with their sources.

numba keys a cached function by its own source file, but a kernel that calls
a compiled function of another file (every loop calls ``kernel.profile_torque``)
carries that callee's machine code in its own entry: after an edit of
``kernel.py`` alone its callers' entries would still load the old callee.
This module fingerprints every kernel source together (SHA-256) and, when the
fingerprint changed, removes the cache entries (``*.nbi``, ``*.nbc``) of
``core/`` and ``core/network/`` (or those under ``NUMBA_CACHE_DIR`` for these
folders) before any kernel loads; a folder we cannot write is left alone.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

CORE = Path(__file__).resolve().parent
#: every file whose compiled functions are called from another file's kernel
SOURCES = ("kernel.py", "kernel_slip.py", "kernel_variants.py", "profile_data.py", "network/slip_kernel.py")  # fmt: skip
STAMP = "kernels.sha256"


def fingerprint() -> str:
    """SHA-256 over the kernels' sources, in the order of :data:`SOURCES`."""
    h = hashlib.sha256()
    for name in SOURCES:
        path = CORE / name
        h.update(name.encode())
        h.update(path.read_bytes() if path.exists() else b"")
    return h.hexdigest()


def _cache_folders() -> list[Path]:
    folders = [CORE / "__pycache__", CORE / "network" / "__pycache__"]
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user and Path(user).is_dir():
        tail = ("belt_drive_ros", "core")
        for stamp in Path(user).rglob("*.nbi"):
            parts = stamp.parent.parts
            if parts[-2:] == tail or parts[-3:-1] == tail:
                folders.append(stamp.parent)
    return list(dict.fromkeys(folders))


def refresh() -> bool:
    """Drop cache entries built from other kernel sources; True when some were dropped."""
    digest = fingerprint()
    dropped = False
    for folder in _cache_folders():
        stamp = folder / STAMP
        try:
            if stamp.read_text() == digest:
                continue
        except OSError:
            pass
        try:
            for entry in list(folder.glob("*.nbi")) + list(folder.glob("*.nbc")):
                entry.unlink()
                dropped = True
            folder.mkdir(parents=True, exist_ok=True)
            stamp.write_text(digest)
        except OSError:
            continue  # a read-only install: numba itself then caches elsewhere
    return dropped

"""The compiled kernels' disk cache follows their sources (core/jit_cache.py)."""

from __future__ import annotations

import shutil

from belt_drive_ros.core import jit_cache


def _copy_core(tmp_path, monkeypatch):
    core = tmp_path / "belt_drive_ros" / "core"
    for name in jit_cache.SOURCES:
        (core / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(jit_cache.CORE / name, core / name)
    monkeypatch.setattr(jit_cache, "CORE", core)
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    return core


def test_entries_built_from_other_sources_are_dropped_once(tmp_path, monkeypatch):
    core = _copy_core(tmp_path, monkeypatch)
    old = [core / "__pycache__" / "kernel_slip.hybrid_steps-100.py312.nbi",
           core / "network" / "__pycache__" / "kernel.network_steps-50.py312.nbc"]  # fmt: skip
    for entry in old:
        entry.parent.mkdir(parents=True, exist_ok=True)
        entry.write_bytes(b"stale")
    assert jit_cache.refresh() is True
    assert not any(entry.exists() for entry in old)
    assert (core / "__pycache__" / jit_cache.STAMP).read_text() == jit_cache.fingerprint()
    fresh = core / "__pycache__" / "kernel.linear_steps-10.py312.nbi"
    fresh.write_bytes(b"built from these sources")
    assert jit_cache.refresh() is False and fresh.exists()
    # an edit of the shared kernel alone invalidates its callers' entries in every folder
    (core / "kernel.py").write_text((core / "kernel.py").read_text() + "\n# edited\n")
    assert jit_cache.refresh() is True and not fresh.exists()


def test_entries_under_numba_cache_dir_are_handled(tmp_path, monkeypatch):
    core = _copy_core(tmp_path / "pkg", monkeypatch)
    user = tmp_path / "cache"
    mirrored = user / "site" / "belt_drive_ros" / "core" / "network"
    mirrored.mkdir(parents=True)
    (mirrored / "slip_kernel.run-5.py312.nbi").write_bytes(b"stale")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(user))
    assert jit_cache.refresh() is True
    assert not (mirrored / "slip_kernel.run-5.py312.nbi").exists()
    assert (mirrored / jit_cache.STAMP).read_text() == jit_cache.fingerprint()
    assert (core / "__pycache__" / jit_cache.STAMP).exists()

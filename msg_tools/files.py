"""The permission bits of a file written through a temporary file and renamed onto its path.

``tempfile.mkstemp`` creates files readable by their owner only (0o600); an
output renamed from one would keep that. :func:`output_mode` gives the mode
a plain ``open(path, "w")`` would have left: that of the file being replaced,
else 0o666 less the process's umask.
"""

from __future__ import annotations

import os
import stat

__all__ = ["output_mode"]


def output_mode(path: str | os.PathLike) -> int:
    """Permission bits for a new ``path``: those of the file it replaces, else 0o666 less the umask."""
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        mask = os.umask(0)
        os.umask(mask)
        return 0o666 & ~mask

"""One bounded cache of objects built from other objects, keyed by those objects' identity (models, plants,
steppers, slipping phases): an entry holds the objects it was built from, so their ids are not reused while it
lives, and a hit is checked with ``is``; the least recently used entry goes first. Entries are read-only: matrices, closures, profile data; never a state
or a verdict.
"""

from __future__ import annotations

from operator import is_
from typing import Callable


def built_once(cache: dict, size: int, objects: tuple, build: Callable, extra: tuple = (), keep=None):
    """``build()`` once per ``objects`` (by identity) and hashable ``extra``; kept in ``cache`` (at most ``size``
    entries, the least recently used dropped: a hit moves its entry to the end) unless ``keep(value)`` is false."""
    key = (*map(id, objects), *extra)
    hit = cache.get(key)
    if hit is not None and all(map(is_, hit[0], objects)):  # (map of a C function: no frame per object)
        cache.pop(key, None)  # (the end: the entry just used is the last one dropped)
        cache[key] = hit
        return hit[1]
    value = build()
    if keep is None or keep(value):
        if len(cache) >= size:  # (another thread may drop the same entry meanwhile)
            cache.pop(next(iter(cache), None), None)
        cache[key] = (objects, value)
    return value

"""Serpentine belt networks: one belt around many pulleys and an automatic tensioner.

* :mod:`.geometry` -- tangent spans, wrap angles, belt length, the checks of a simple loop;
* :mod:`.scene` -- the network scene schema (frozen, validated) and the shipped network scenes;
* :mod:`.model` -- the linear (flexible) tier: ``M q'' + C q' + K q = f``, statics, modes, runs.

The derivation is in ``docs/serpentine.md``.
"""

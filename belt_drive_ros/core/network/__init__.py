"""Serpentine belt networks: one belt around many pulleys and an automatic tensioner (``docs/serpentine.md``).

:mod:`.scene` reads them, :mod:`.geometry` lays out the spans, :mod:`.model` and :mod:`.simulate` run the
linear tiers, :mod:`.slip` and :mod:`.slip_kernel` the slipping tier, :mod:`.tick` the node's ticks.
"""

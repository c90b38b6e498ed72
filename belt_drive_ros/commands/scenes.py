"""``belt-drive scenes``: list the shipped scenes, or print one as YAML."""

from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("scenes", help="list shipped scenes or print one (YAML) to start your own",
                       description="List the shipped scenes; with a NAME, print that scene as YAML.")
    p.add_argument("name", nargs="?", help="scene to print")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..io.scenes import is_network, load_either_scene, load_network, load_scene, scene_yaml, shipped_networks
    from ..core.scene import shipped_scenes
    from ..io.network_plot import describe

    if args.name is not None and is_network(args.name):  # a belt network: its computed geometry
        print(describe(load_network(args.name)), end="")
        return 0
    if args.name is not None:  # ('' is an unknown scene, not the list)
        print(scene_yaml(load_either_scene(args.name)), end="")
        return 0
    for name in shipped_scenes():
        print(f"{name:18s} {load_scene(name).description}")
    for name in shipped_networks():
        print(f"{name:18s} (belt network) {load_network(name).description}")
    print("\nparameters (YAML keys under 'params', the paper's symbols):")
    print(describe_fields())
    return 0


def describe_fields() -> str:
    """Human-readable table of the parameter fields with units (for ``belt-drive scenes`` and docs)."""
    from ..core.params import FIELD_DOCS

    width = max(len(n) for n in FIELD_DOCS)
    return "\n".join(f"  {n:<{width}}  [{u}]  {d}" for n, (u, d) in FIELD_DOCS.items())

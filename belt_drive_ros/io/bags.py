"""Reference recordings in ``bags/``: a torque profile and its golden output run each.

For every reference case (:data:`REFERENCE_BAGS`) ``belt-drive make-bags``
(``make bags``) writes three files:

``<name>.yaml``
    The scene: a shipped scene with its drive, load or duration changed
    (:func:`reference_scene`), its ``model`` and ``method`` fixed to the ones
    the golden run uses, so a fresh run cannot take another ``auto`` choice.
``<name>_torque.mcap``
    The torque profile: ``/drive_torque`` (``std_msgs/Float64`` [N m], 1 kHz)
    of the scene run with its own drive (the engine's firing pulsations and
    governor, the motor's curve ...), plus the scene metadata.
``<name>_golden.mcap``
    The golden output: the scene driven by that recorded torque (zero-order
    hold, :func:`belt_drive_ros.io.torque_bag.scene_with_torque_bag`), every output
    topic at 1 kHz from the offline simulator
    (:func:`belt_drive_ros.io.recording.write_result_mcap`), with the scene
    metadata referring to the torque bag by name and sha256.

A fresh run must reproduce the golden file::

    belt-drive sim bags/engine_idle.yaml --torque-bag bags/engine_idle_torque.mcap --out fresh.mcap
    msg-tools compare fresh.mcap bags/engine_idle_golden.mcap      # exit 0

Everything is deterministic: regenerating gives byte-identical files on the
same platform and library versions (the files hold no wall-clock time).
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence

__all__ = ["REFERENCE_BAGS", "ReferenceBag", "make_bags", "reference_scene"]

#: Message rate of the reference bags [Hz].
OUTPUT_RATE = 1000.0
#: topics of a golden file: the signals a comparison checks (no robot_description: a regression
#: reference, not a file to look at; ``belt-drive sim --out`` writes it)
GOLDEN_TOPICS = ("drive_torque", "joint_states", "shaft_speed", "load_torque", "belt_torque", "relative_deflection")


@dataclass(frozen=True)
class ReferenceBag:
    """One reference case: how its scene is derived from a shipped scene."""

    name: str
    description: str
    build: Callable[[], "object"]

    def files(self, folder) -> Dict[str, Path]:
        folder = Path(folder)
        return {
            "scene": folder / f"{self.name}.yaml",
            "torque": folder / f"{self.name}_torque.mcap",
            "golden": folder / f"{self.name}_golden.mcap",
        }


#: time stamp of scene time 0 in the reference bags: fixed (2026-01-01T00:00:00Z), so that
#: `make bags` gives byte-identical files, and viewers show a date rather than 1970
BAGS_START_NS = 1_767_225_600_000_000_000

def _truck():
    """truck_compressor at the 1 ms step the reference bags were made with (the scene's default moved to 0.5 ms
    for its slipping run; the bags are regression references: their bytes stay)."""
    from .scenes import load_scene

    return dataclasses.replace(load_scene("truck_compressor"), dt=1e-3)


def _engine_idle():
    s = _truck()
    return dataclasses.replace(
        s, name="engine_idle", duration=2.0, load=s.load.inactive,
        description=(
            "Six-cylinder diesel at high idle (740 rpm) with firing pulsations (37 Hz, ~0.5 of the "
            "belt mode) drives the unloaded air compressor."
        ),
    )


def _engine_runup():
    s = _truck()
    return dataclasses.replace(
        s, name="engine_runup", duration=2.5, load=s.load.inactive,
        drive=dataclasses.replace(s.drive, speed_setpoint=200.0, max_torque=200.0),
        description=(
            "Diesel runs up from idle to 1900 rpm (governor at its 200 N m limit): the firing "
            "frequency sweeps 37 -> 95 Hz through the belt mode; the unloaded compressor follows."
        ),
    )


def _e_motor_start():
    from .scenes import load_scene

    s = load_scene("e_motor_start")
    return dataclasses.replace(s, duration=3.0)


def _compressor_cycling():
    s = _truck()
    return dataclasses.replace(
        s, name="compressor_cycling", duration=3.0,
        load=dataclasses.replace(s.load, periods=((0.5, 1.25), (2.0, 2.75))),
        description=(
            "Diesel at high idle; the air compressor loads (pumps, 18 N m + stroke pulsations) "
            "and unloads twice in 3 s."
        ),
    )


#: The reference cases, by name.
REFERENCE_BAGS: Dict[str, ReferenceBag] = {
    bag.name: bag
    for bag in (
        ReferenceBag("engine_idle", "engine idle with firing pulsations", _engine_idle),
        ReferenceBag("engine_runup", "engine run-up through the belt resonance", _engine_runup),
        ReferenceBag("e_motor_start", "electric motor soft start", _e_motor_start),
        ReferenceBag("compressor_cycling", "compressor load cycling at engine idle", _compressor_cycling),
    )
}


def reference_scene(name: str):
    """The scene of reference case ``name`` (before its model is fixed)."""
    try:
        return REFERENCE_BAGS[name].build()
    except KeyError:
        raise ValueError(f"unknown reference bag {name!r}; known: {', '.join(REFERENCE_BAGS)}") from None


def make_bags(out="bags", *, force: bool = False, only: Optional[Sequence[str]] = None,
              log: Callable[[str], None] = print) -> List[Path]:
    """Write the reference scenes, torque bags and golden bags into ``out``.

    Parameters
    ----------
    out : path
        Folder (created if missing).
    force : bool
        Replace existing files; without it nothing is written if any exists.
    only : sequence of str, optional
        Names of the cases to make (default all).
    log : callable
        Receives one line per file written.

    Returns
    -------
    list of Path
        Files written.

    Raises
    ------
    BagExistsError
        If a file exists and ``force`` is False (checked before writing anything).
    ValueError
        For an unknown name in ``only``.
    """
    import yaml

    from .atomic import atomic_output
    from .recording import BagExistsError, scene_mapping, write_result_mcap
    from .torque_bag import scene_with_torque_bag
    from ..core.simulate import simulate

    names = list(only) if only else list(REFERENCE_BAGS)
    for name in names:
        if name not in REFERENCE_BAGS:
            raise ValueError(f"unknown reference bag {name!r}; known: {', '.join(REFERENCE_BAGS)}")
    folder = Path(out)
    if not force:
        existing = [str(p) for n in names for p in REFERENCE_BAGS[n].files(folder).values() if p.exists()]
        if existing:
            raise BagExistsError(
                f"{existing[0]} exists"
                + (f" (and {len(existing) - 1} more file(s) it would write)" if len(existing) > 1 else "")
                + "; pass --force to overwrite it"
            )
    folder.mkdir(parents=True, exist_ok=True)
    written: List[Path] = []
    for name in names:
        case = REFERENCE_BAGS[name]
        files = case.files(folder)
        base = case.build()
        # 1. the torque profile: the scene's own drive, recorded at 1 kHz
        source_run = simulate(base)
        with atomic_output(files["torque"], force=force, what="reference bag") as f:  # whole or not at all
            write_result_mcap(source_run, f, output_rate=OUTPUT_RATE, topics=("drive_torque",),
                              start_time_ns=BAGS_START_NS)
        # 2. the scene file, with the model fixed to the source run's choice. The goldens are the
        #    node's replay references and the node steps the linear tiers only: where auto went on
        #    to slipping, the golden keeps the flexible belt (the node's model for that scene).
        model = "flexible" if source_run.model == "slipping" else source_run.model
        scene = dataclasses.replace(base, model=model, output_rate=OUTPUT_RATE)
        header = (
            f"# Reference case '{name}': {case.description}.\n"
            f"# Written by 'belt-drive make-bags' (belt_drive_ros/bags.py); do not edit, regenerate.\n"
            f"# Drive this scene with {files['torque'].name} to reproduce {files['golden'].name}.\n"
        )
        with atomic_output(files["scene"], force=force, mode="w", what="reference scene") as f:
            f.write(header + yaml.safe_dump(scene_mapping(scene), sort_keys=False))
        # 3. the golden output: the scene driven by the recorded torque
        replayed = scene_with_torque_bag(scene, files["torque"])
        golden_run = simulate(replayed)
        with atomic_output(files["golden"], force=force, what="golden bag") as f:
            write_result_mcap(golden_run, f, output_rate=OUTPUT_RATE, start_time_ns=BAGS_START_NS,
                              topics=GOLDEN_TOPICS)
        for key in ("scene", "torque", "golden"):
            path = files[key]
            written.append(path)
            log(f"wrote {path} ({os.path.getsize(path) / 1024:.0f} KiB)")
    return written

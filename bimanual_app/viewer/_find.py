"""Where the parts of a run folder are: the layout of ``bijcr run`` (calibration/, segments/, grasps/,
tasks/) or a flat folder holding the same files; and the scene folder the run was made from.

Each lookup is a list of named candidate paths tried in order, so a message can say where it looked.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from bimanual_app.io_utils import InputError, Problem


@dataclass
class RunPaths:
    """Files of a run folder; None where absent. ``tasks`` maps a task name to its folder."""

    root: Path
    calibration: Path
    cloud: Path | None
    segments: Path | None
    grasps: Path | None
    tasks: dict[str, Path] = field(default_factory=dict)


def _first(cands: list[Path]) -> Path | None:
    return next((p for p in cands if p.is_file()), None)


def find_run(root: str | Path) -> RunPaths:
    """The files of run folder ``root``; raises InputError when it holds no calibration.json."""
    root = Path(root)
    if not root.is_dir():
        raise InputError(Problem(str(root), "", "run folder not found",
                                 "give the --out folder of `bijcr run` (or one holding calibration/calibration.json)"))
    cal_c = [root / "calibration" / "calibration.json", root / "calibration.json"]
    cal = _first(cal_c)
    if cal is None:
        raise InputError(Problem(str(root), "calibration.json",
                                 "not a run folder: no " + " or ".join(str(p.relative_to(root)) for p in cal_c),
                                 f"run `bijcr run SCENE --out {root}` first, or give the folder it wrote"))
    cloud = _first([cal.parent / "scene_b1.ply", root / "scene_b1.ply"])
    seg = _first([root / "segments" / "segments.npz", root / "segments.npz", cal.parent / "segments.npz"])
    grasps = _first([root / "grasps" / "grasps.json", root / "grasps.json"])
    tasks = {}
    if (root / "tasks").is_dir():
        tasks = {d.name: d for d in sorted((root / "tasks").iterdir()) if (d / "task.json").is_file()}
    return RunPaths(root, cal, cloud, seg, grasps, tasks)


def _is_scene(p: Path) -> bool:
    return (p / "scene.yaml").is_file()


def _json_or_none(path: Path) -> dict | None:
    try:
        d = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) else None


def find_scene(paths: RunPaths, cal: dict, explicit: str | Path | None = None) -> tuple[Path | None, str]:
    """(scene folder or None, how it was found / why not).

    Strategies in order: ``--scene``; ``run.json: scene`` (written by ``bijcr run``); calibration.json's
    ``scene_dir``, ``paths.scene`` or ``scene`` when one is a folder holding scene.yaml (relative paths
    are taken from the calibration's folder).
    """
    if explicit is not None:
        p = Path(explicit)
        if not _is_scene(p):
            raise InputError(Problem(str(p), "--scene", "no scene.yaml in this folder",
                                     "give the scene folder of the run"))
        return p, "--scene"
    strategies: list[tuple[str, object, Path]] = []
    run = _json_or_none(paths.root / "run.json")
    if run is not None:
        strategies.append(("run.json: scene", run.get("scene"), paths.root))
    base = paths.calibration.parent
    strategies.append(("calibration.json: scene_dir", cal.get("scene_dir"), base))
    if isinstance(cal.get("paths"), dict):
        strategies.append(("calibration.json: paths.scene", cal["paths"].get("scene"), base))
    strategies.append(("calibration.json: scene", cal.get("scene"), base))
    for how, value, rel in strategies:
        if isinstance(value, str) and value:
            p = Path(value) if Path(value).is_absolute() else rel / value
            if _is_scene(p):
                return p.resolve(), how
    return None, ("the scene folder was not found (looked at run.json and calibration.json's scene); "
                  "give it with --scene SCENE")

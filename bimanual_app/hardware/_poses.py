"""The capture's poses file (POSES.yaml): joint poses to visit, and how to move between them.

```yaml
format: 1
robot: piper              # optional (default piper)
units: rad                # rad (default) or deg, for poses and home
speed: 0.25               # optional: fraction (0, 1] of the allowed joint speeds for the moves
settle_s: 0.5             # optional: wait after each move before the frame is taken
workspace:                # optional: box in this arm's base frame (metres); default: the package's box
  min: [-0.40, -0.70, 0.02]
  max: [0.75, 0.70, 0.85]
home: [0, 0, 0, 0, 0, 0]  # optional: pose to return to after the last frame
poses:                    # the views, in capture order: a list of 6 joint values, or name + q
  - [0.0, 1.2, -0.8, 0.0, 0.4, 0.0]
  - {name: left, q: [0.4, 1.3, -0.9, 0.2, 0.5, -0.3]}
```
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from bimanual_app.io_utils import InputError, Problem

from ._limits import WorkspaceBox

__all__ = ["PoseList", "load_poses", "dump_poses", "POSES_KEYS"]

POSES_KEYS = {"format", "robot", "units", "speed", "settle_s", "workspace", "home", "poses"}


@dataclass
class PoseList:
    """A parsed poses file.

    Attributes:
        q: (N, 6) joint poses in radians, capture order.
        names: (N,) pose names (``pose_000`` ... when not given).
        robot: robot model name or URDF path.
        speed: fraction of the allowed joint speeds for the moves.
        settle_s: wait after each move before the frame.
        workspace: the box, or None for the package default.
        home: (6,) pose to return to at the end, or None.
        source: where it was read from.
        comments: header comment lines (for :func:`dump_poses`).
    """

    q: np.ndarray
    names: list[str]
    robot: str = "piper"
    speed: float = 0.25
    settle_s: float = 0.5
    workspace: WorkspaceBox | None = None
    home: np.ndarray | None = None
    source: str = ""
    comments: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.q)


def _number_list(v, n: int) -> list[float] | None:
    if not isinstance(v, (list, tuple)) or len(v) != n:
        return None
    out = []
    for x in v:
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            return None
        out.append(float(x))
    return out


def load_poses(path: str | Path, n_joints: int = 6) -> PoseList:
    """Read and check a poses file; raises :class:`InputError` listing every problem (file, field, fix)."""
    path = Path(path)
    f = str(path)
    if not path.is_file():
        raise InputError(Problem(f, "", "poses file is missing", "write one (bijcr capture --suggest > POSES.yaml)"))
    try:
        d = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise InputError(Problem(f, "", f"not valid YAML: {e}", "fix the YAML syntax")) from None
    if not isinstance(d, dict):
        raise InputError(Problem(f, "", "must be a YAML mapping with a 'poses:' list", "see docs/hardware.md"))
    P: list[Problem] = []
    for k in sorted(set(d) - POSES_KEYS):
        P.append(Problem(f, k, "unknown key", f"use only: {', '.join(sorted(POSES_KEYS))}"))
    if d.get("format", 1) != 1:
        P.append(Problem(f, "format", f"format must be 1, got {d.get('format')!r}", "write 'format: 1'"))
    units = d.get("units", "rad")
    if units not in ("rad", "deg"):
        P.append(Problem(f, "units", f"units must be rad or deg, got {units!r}", "write 'units: rad'"))
        units = "rad"
    scale = math.pi / 180.0 if units == "deg" else 1.0
    robot = d.get("robot", "piper")
    if not isinstance(robot, str) or not robot.strip():
        P.append(Problem(f, "robot", f"robot must be a name or URDF path, got {robot!r}", "write 'robot: piper'"))
        robot = "piper"
    speed = d.get("speed", 0.25)
    if isinstance(speed, bool) or not isinstance(speed, (int, float)) or not 0 < speed <= 1:
        P.append(Problem(f, "speed", f"speed must be a fraction in (0, 1], got {speed!r}", "write e.g. 'speed: 0.25'"))
        speed = 0.25
    settle = d.get("settle_s", 0.5)
    if isinstance(settle, bool) or not isinstance(settle, (int, float)) or not 0 <= settle <= 30:
        P.append(Problem(f, "settle_s", f"settle_s must be seconds in [0, 30], got {settle!r}", "write e.g. 'settle_s: 0.5'"))
        settle = 0.5
    box = None
    ws = d.get("workspace")
    if ws is not None:
        lo = _number_list(ws.get("min"), 3) if isinstance(ws, dict) else None
        hi = _number_list(ws.get("max"), 3) if isinstance(ws, dict) else None
        if lo is None or hi is None or not all(a < b for a, b in zip(lo, hi)):
            P.append(Problem(f, "workspace", "workspace needs min: [x, y, z] and max: [x, y, z] (metres), min < max",
                             "write e.g. 'workspace: {min: [-0.4, -0.7, 0.02], max: [0.75, 0.7, 0.85]}'"))
        else:
            box = WorkspaceBox(tuple(lo), tuple(hi))
    home = None
    if d.get("home") is not None:
        h = _number_list(d["home"], n_joints)
        if h is None:
            P.append(Problem(f, "home", f"home must be a list of {n_joints} numbers", f"write {n_joints} joint values"))
        else:
            home = np.array(h) * scale
    raw = d.get("poses")
    qs, names = [], []
    if not isinstance(raw, list) or not raw:
        P.append(Problem(f, "poses", "poses must be a non-empty list", "list joint poses under 'poses:'"))
        raw = []
    for i, item in enumerate(raw):
        name, vals = f"pose_{i:03d}", item
        if isinstance(item, dict):
            name = str(item.get("name", name))
            vals = item.get("q")
            extra = set(item) - {"name", "q"}
            if extra:
                P.append(Problem(f, f"poses[{i}]", f"unknown key(s) {sorted(extra)}", "use name and q"))
        q = _number_list(vals, n_joints)
        if q is None:
            P.append(Problem(f, f"poses[{i}]", f"must be {n_joints} joint values (or name + q), got {vals!r}",
                             f"write a list of {n_joints} numbers in {units}"))
            continue
        qs.append(np.array(q) * scale)
        names.append(name)
    if len(set(names)) != len(names):
        P.append(Problem(f, "poses", "pose names repeat", "give every pose its own name"))
    if P:
        raise InputError(P)
    return PoseList(np.array(qs), names, robot, float(speed), float(settle), box, home, f)


def dump_poses(poses: PoseList) -> str:
    """YAML text of a pose list (radians), readable back by :func:`load_poses`."""
    lines = [f"# {c}" if c else "#" for c in poses.comments]
    lines += ["format: 1", f"robot: {poses.robot}", "units: rad", f"speed: {poses.speed:g}",
              f"settle_s: {poses.settle_s:g}"]
    if poses.workspace is not None:
        w = poses.workspace
        lines += ["workspace:", f"  min: [{', '.join(f'{v:.3f}' for v in w.lower)}]",
                  f"  max: [{', '.join(f'{v:.3f}' for v in w.upper)}]"]
    if poses.home is not None:
        lines.append(f"home: [{', '.join(f'{v:.4f}' for v in poses.home)}]")
    lines.append("poses:")
    for name, q in zip(poses.names, poses.q):
        lines.append(f"  - {{name: {name}, q: [{', '.join(f'{v:+.4f}' for v in q)}]}}")
    return "\n".join(lines) + "\n"

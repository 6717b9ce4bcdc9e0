"""Writing reconstruction.npz safely: enough views per arm, atomic, never over a user's file unasked."""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np

from bimanual_app.io_utils import InputError, Problem
from bimanual_app.scene import Reconstruction, Scene, write_reconstruction

__all__ = ["check_views", "check_can_write", "save_reconstruction", "backup_name"]

OUTPUT_NAME = "reconstruction.npz"


def check_views(rec: Reconstruction, scene: Scene, min_views: int, backend: str) -> dict[str, int]:
    """Registered views per arm; raise :class:`InputError` naming the unregistered images when an arm has
    fewer than ``min_views`` (calibration needs at least 3 motions' worth of views per arm)."""
    counts, probs = {}, []
    for arm in scene.arms:
        csv_rows, _ = rec.rows_for(arm.index, arm.images)
        counts[arm.name] = len(csv_rows)
        if len(csv_rows) < min_views:
            missing = [arm.images[i] for i in sorted(set(range(len(arm))) - set(csv_rows.tolist()))]
            shown = ", ".join(f"{arm.name}/{k}" for k in missing[:12]) + (f" (+{len(missing) - 12} more)" if len(missing) > 12 else "")
            probs.append(Problem(f"{arm.name}/ee_poses.csv", "image",
                                 f"{backend} registered only {len(csv_rows)} of {len(arm)} {arm.name} views (need {min_views}); "
                                 f"not registered: {shown or '(none)'}",
                                 "capture more views that overlap the other views (textured table, 30-60 deg apart), "
                                 "or use a foundation-model backend (--backend dust3r/mast3r/vggt with --input)"))
    if probs:
        raise InputError(probs)
    return counts


def check_can_write(scene_path: Path, force: bool) -> None:
    """Refuse early (before any work) to replace an existing reconstruction.npz without ``force``."""
    out = Path(scene_path) / OUTPUT_NAME
    if out.exists() and not force:
        raise InputError(Problem(str(out), "", "already exists and would be replaced",
                                 "pass --force to replace it (a backup copy is kept), or move it away"))


def backup_name(path: Path) -> Path:
    """A free name ``reconstruction.bak-YYYYmmdd-HHMMSS[-k].npz`` beside ``path``."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    k = 0
    while True:
        cand = path.with_name(f"{path.stem}.bak-{stamp}" + (f"-{k}" if k else "") + path.suffix)
        if not cand.exists():
            return cand
        k += 1


def save_reconstruction(scene_path: Path, rec: Reconstruction, force: bool = False) -> tuple[Path, Path | None]:
    """Write ``rec`` as ``scene_path/reconstruction.npz`` atomically.

    An existing file is replaced only with ``force``, after copying it to a backup name.
    Returns ``(path, backup path or None)``.
    """
    out = Path(scene_path) / OUTPUT_NAME
    check_can_write(scene_path, force)
    backup = None
    if out.exists():
        backup = backup_name(out)
        shutil.copy2(out, backup)
    rec.arm = np.asarray(rec.arm, dtype=np.int64)
    write_reconstruction(out, rec)
    return out, backup

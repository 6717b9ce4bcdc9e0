"""The reconstruction stage: a scene's images (or a model's export) -> reconstruction.npz."""

from __future__ import annotations

import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bimanual_app.io_utils import InputError, Problem
from bimanual_app.scene import ARM_INDEX, Reconstruction, Scene, validate_scene

from ._agreement import motion_agreement
from ._colmap import ColmapOptions, run_colmap
from ._dense import DenseOptions
from ._images import arm_intrinsics, check_images, read_rgb
from ._importers import IMPORT_MODELS, import_export
from ._kinematic import inconsistent_views
from ._maps import colmap_point_maps
from ._output import OUTPUT_NAME, check_can_write, check_views, save_reconstruction
from ._plot import plot_reconstruction
from ._pointmap import default_map_size

__all__ = ["BACKENDS", "ReconstructResult", "load_scene_for_reconstruction", "build_reconstruction", "reconstruct"]

BACKENDS = ("colmap",) + IMPORT_MODELS
Log = Callable[[str], None]


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


@dataclass
class ReconstructResult:
    """What ``reconstruct`` made.

    Attributes:
        reconstruction: the Reconstruction written (or built, when not written).
        registered: views registered per arm; total: views per arm.
        path: reconstruction.npz written (None when not written); backup: the previous file's copy.
        plot: the PNG written, or None.
        info: backend details (COLMAP attempts, densification, timings).
    """

    reconstruction: Reconstruction
    registered: dict[str, int]
    total: dict[str, int]
    path: Path | None = None
    backup: Path | None = None
    plot: Path | None = None
    info: dict = field(default_factory=dict)


def load_scene_for_reconstruction(path: str | Path, force: bool = False) -> Scene:
    """Load a scene; with ``force``, a broken reconstruction.npz (about to be replaced) is ignored."""
    root = Path(path).expanduser().resolve()
    scene, problems = validate_scene(root)
    if scene is not None:
        return scene
    errors = [p for p in problems if p.severity == "error"]
    if force and errors and all(p.file.endswith(OUTPUT_NAME) for p in errors):
        with tempfile.TemporaryDirectory(prefix="bijcr-scene-") as tmp:
            for child in root.iterdir():
                if child.name != OUTPUT_NAME:
                    (Path(tmp) / child.name).symlink_to(child)
            scene, problems = validate_scene(tmp)
        if scene is not None:
            scene.path = root
            return scene
        errors = [p for p in problems if p.severity == "error"]
    raise InputError(errors)


def _kinematic_check(scene: Scene, tol_deg: float):
    """``check(names, T_w_c) -> bad (M,)``: views whose camera rotations contradict their arm's motions."""
    if not tol_deg:
        return None
    rows = {f"{arm.name}/{k}": (arm.name, arm.T_b_e[i]) for arm in scene.arms for i, k in enumerate(arm.images)}

    def check(names: list[str], T_w_c: np.ndarray) -> np.ndarray:
        bad = np.zeros(len(names), bool)
        for arm in scene.arms:
            idx = [i for i, n in enumerate(names) if rows[n][0] == arm.name]
            if len(idx) >= 3:
                bad[idx] = inconsistent_views(np.array([rows[names[i]][1] for i in idx]), T_w_c[idx], tol_deg)
        return bad

    return check


def _agreement(scene: Scene):
    """``agree(names, T_w_c) -> motion_agreement``: how well the views' camera motions match their arm's."""
    rows = {f"{arm.name}/{k}": (arm.name, arm.T_b_e[i]) for arm in scene.arms for i, k in enumerate(arm.images)}

    def agree(names: list[str], T_w_c: np.ndarray) -> dict:
        per = {}
        for arm in scene.arms:
            idx = [i for i, n in enumerate(names) if rows[n][0] == arm.name]
            per[arm.name] = (np.array([rows[names[i]][1] for i in idx]).reshape(-1, 4, 4), T_w_c[idx])
        return motion_agreement(per)

    return agree


def agreement_extras(attempts: list[dict], chosen: str) -> dict:
    """reconstruction.npz extension keys recording every attempt's kinematic agreement (docs/scene-format.md).

    Args:
        attempts: per attempt ``{"name", "registered": {arm: n}, "points", "agreement": motion_agreement or None}``.
    """
    agr = np.full((len(attempts), 3), np.nan)
    for k, a in enumerate(attempts):
        if a.get("agreement"):
            agr[k] = [a["agreement"]["rot_deg"], a["agreement"]["trans_rel"], a["agreement"]["score"]]
    names = [a["name"] for a in attempts]
    return {"attempts": np.array(names, dtype=str), "attempt_agreement": agr,
            "attempt_views": np.array([[a["registered"].get(arm, 0) for arm in ("primary", "secondary")]
                                       for a in attempts], dtype=np.int64).reshape(-1, 2),
            "attempt_points": np.array([a["points"] for a in attempts], dtype=np.int64),
            "attempt_chosen": np.array(names.index(chosen) if chosen in names else -1, dtype=np.int64)}


def _colmap(scene: Scene, map_width: int, dense: bool, copts: ColmapOptions, dopts: DenseOptions,
            workdir: Path | None, log: Log, check: bool = True) -> tuple[Reconstruction, dict]:
    arms = check_images(scene)
    intr = {a: arm_intrinsics(scene, ai) for a, ai in arms.items()}
    for a, ai in arms.items():
        k = intr[a]
        log(f"  {a}: {len(ai.names)} images {ai.size[0]}x{ai.size[1]}, "
            + (f"intrinsics from scene.yaml (fx {k.fx:.1f}, fixed)" if k else "intrinsics estimated by COLMAP"))
    try:
        model = run_colmap(scene.path, arms, intr, copts, workdir=workdir, log=log,
                           check=_kinematic_check(scene, copts.max_motion_error_deg), agree=_agreement(scene))
    except RuntimeError as e:
        names = [n for ai in arms.values() for n in ai.names]
        raise InputError(Problem(", ".join(names[:6]) + (" ..." if len(names) > 6 else ""), "",
                                 f"colmap: {e}", "capture overlapping views of a textured scene, or use a GPU backend")) from None
    key_of = {n: (a, n[len(a) + 1:]) for a, ai in arms.items() for n in ai.names}
    order = sorted(range(len(model.names)), key=lambda i: (ARM_INDEX[key_of[model.names[i]][0]],
                                                            arms[key_of[model.names[i]][0]].names.index(model.names[i])))
    rec = Reconstruction(arm=np.array([ARM_INDEX[key_of[model.names[i]][0]] for i in order], dtype=np.int64),
                         image=np.array([key_of[model.names[i]][1] for i in order]),
                         T_w_c=model.T_w_c[order], model="colmap")
    if check:
        check_views(rec, scene, copts.min_views, "colmap")  # before the costly densification
    sizes = {ai.size for ai in arms.values()}
    if len({round(w / h, 3) for w, h in sizes}) > 1:
        raise InputError(Problem("primary/, secondary/", "size", f"the two arms' images have different aspect ratios {sorted(sizes)}",
                                 "reconstruction.npz holds one map size: capture both arms at one aspect ratio"))
    W0, H0 = next(iter(sizes))
    map_size = default_map_size(W0, H0, map_width)
    images = {n: read_rgb(scene.path / n) for n in model.names}
    log(f"  point maps {map_size[0]}x{map_size[1]}: " + ("sparse points + plane-sweep densification" if dense else "sparse points only"))
    pts3d, conf, colors, dinfo = colmap_point_maps(model, images, map_size, dense=dense, opts=dopts, log=log)
    rec.pts3d, rec.conf, rec.colors = pts3d[order], conf[order], colors[order]
    rec.extras = {"K": model.K[order], "image_size": np.array([images[model.names[i]].shape[1::-1] for i in order], dtype=np.int64),
                  "sparse_xyz": model.xyz.astype(np.float32), "sparse_rgb": model.rgb.astype(np.uint8),
                  **agreement_extras([a.__dict__ for a in model.attempts], model.chosen)}
    if model.dropped:
        log(f"  dropped {len(model.dropped)} view(s) COLMAP registered against the arm's kinematics "
            f"(camera rotations disagree with the end-effector's by > {copts.max_motion_error_deg:g} deg): "
            + ", ".join(model.dropped))
    info = {"attempts": [a.__dict__ for a in model.attempts], "chosen": model.chosen, "points": len(model.xyz),
            "dropped": list(model.dropped),
            "mean_track_length": float(model.track_len.mean()) if len(model.track_len) else 0.0, **dinfo}
    return rec, info


def build_reconstruction(scene: Scene, backend: str = "colmap", input: str | Path | None = None, map_width: int = 160,
                         dense: bool = True, colmap_options: ColmapOptions | None = None,
                         dense_options: DenseOptions | None = None, workdir: Path | None = None,
                         log: Log = _stderr, check: bool = True) -> tuple[Reconstruction, dict]:
    """Build (do not write) the reconstruction of ``scene`` with ``backend``; checks views per arm.

    ``input`` is the export file for the importer backends (dust3r, mast3r, vggt, raydiffusion).
    Raises :class:`InputError` on bad input or, with ``check``, too few registered views (``check=False``
    returns whatever registered: for evaluation).
    """
    if backend not in BACKENDS:
        raise InputError(Problem("", "--backend", f"unknown backend {backend!r}", f"use one of {', '.join(BACKENDS)}"))
    copts = colmap_options or ColmapOptions()
    t0 = time.perf_counter()
    if backend == "colmap":
        if input is not None:
            raise InputError(Problem(str(input), "--input", "the colmap backend reads the scene's images, not a file",
                                     "drop --input (it is for dust3r/mast3r/vggt/raydiffusion exports)"))
        rec, info = _colmap(scene, map_width, dense, copts, dense_options or DenseOptions(), workdir, log, check)
    else:
        if input is None:
            raise InputError(Problem("", "--input", f"the {backend} backend imports an export file",
                                     f"run tools/export_{backend}.py {scene.path} --out FILE in the {backend} environment, "
                                     "then pass --input FILE"))
        log(f"  importing {input} ({backend})")
        rec, info = import_export(scene, Path(input), backend, map_width=map_width)
        names = [f"{scene.arms[a - 1].name}/{k}" for a, k in zip(rec.arm.tolist(), rec.image.tolist())]
        n_arm = {arm.name: int(np.sum(rec.arm == arm.index)) for arm in scene.arms}
        att = {"name": backend, "registered": n_arm, "points": 0,
               "agreement": _agreement(scene)(names, rec.T_w_c) if min(n_arm.values()) >= 3 else None}
        info["agreement"] = att["agreement"]
        rec.extras.update(agreement_extras([att], backend))
        check = _kinematic_check(scene, copts.max_motion_error_deg)
        if check is not None:  # reported, not dropped: the calibration's outlier handling decides
            names = [f"{scene.arms[a - 1].name}/{k}" for a, k in zip(rec.arm.tolist(), rec.image.tolist())]
            info["inconsistent"] = [n for n, b in zip(names, check(names, rec.T_w_c)) if b]
            if info["inconsistent"]:
                log(f"  warning: {len(info['inconsistent'])} view(s) rotate unlike their arm (> "
                    f"{copts.max_motion_error_deg:g} deg): {', '.join(info['inconsistent'])}")
    info["registered"] = check_views(rec, scene, copts.min_views if check else 0, backend)
    info["seconds"] = time.perf_counter() - t0
    return rec, info


def reconstruct(scene_path: str | Path, backend: str = "colmap", input: str | Path | None = None, force: bool = False,
                map_width: int = 160, dense: bool = True, colmap_options: ColmapOptions | None = None,
                dense_options: DenseOptions | None = None, workdir: Path | None = None,
                plot: str | Path | None | bool = True, log: Log = _stderr) -> ReconstructResult:
    """Make ``scene_path/reconstruction.npz`` with ``backend`` (see :func:`build_reconstruction`).

    Refuses to replace an existing reconstruction.npz unless ``force`` (then a backup copy is kept).
    Nothing is written when the input is bad or an arm has fewer than ``min_views`` registered views.
    ``plot``: True -> ``scene_path/reconstruction.png``; a path; or False/None for no picture.
    """
    root = Path(scene_path).expanduser().resolve()
    check_can_write(root, force)
    scene = load_scene_for_reconstruction(root, force)
    log(f"reconstruct '{scene.name}' with {backend}: {len(scene.primary)} primary + {len(scene.secondary)} secondary views")
    rec, info = build_reconstruction(scene, backend, input, map_width, dense, colmap_options, dense_options, workdir, log)
    path, backup = save_reconstruction(root, rec, force)
    png = None
    if plot:
        png = root / "reconstruction.png" if plot is True else Path(plot)
        reg = info["registered"]
        title = f"{scene.name}: {backend}, registered primary {reg['primary']}/{len(scene.primary)}, " \
                f"secondary {reg['secondary']}/{len(scene.secondary)}"
        plot_reconstruction(png, scene, rec, title)
    return ReconstructResult(rec, info["registered"], {a.name: len(a) for a in scene.arms}, path, backup, png, info)

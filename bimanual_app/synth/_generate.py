"""make_synthetic_scene: build, capture, emulate and write one synthetic scene folder.

The folder is assembled under a hidden temporary name beside ``out_dir`` and renamed into place at the
end, so an interrupted run never leaves something that looks like a complete scene.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import yaml

from bimanual_app.io_utils import InputError, Problem
from bimanual_app.scene import ArmCapture, CameraIntrinsics, GroundTruth, Reconstruction, Scene, write_scene
from bimanual_app.transforms import rotation_angle_between

from ._camera import look_at
from ._emulator import (
    MAP_NOISES,
    NOISE_LEVELS,
    MapNoise,
    choose_outliers,
    map_depth_error,
    perturb_poses,
    point_map,
    random_frame,
    to_frame_w,
)
from ._layout import place_objects, sample_base_pose, sample_hand_eye, touching_pairs
from ._objects import choose_kinds, sample_spec
from ._preview import save_preview
from ._viewpoints import plan_views

GENERATOR = "bijcr synth 1"
DEPTH_UNITS_M = 1e-4  # ground-truth depth PNGs: uint16 in 0.1 mm (0 = no table/object surface)
ARMS = ("primary", "secondary")
# stream names of the seed's independent random generators: changing one stage never shifts another
_STREAMS = ("base", "hand_eye", "textures", "objects", "views1", "views2", "poses", "frame", "depth", "outliers")


class _Log:
    """Progress on stderr: a rich progress bar for the rendering, one line per stage otherwise."""

    def __init__(self, enabled: bool):
        self.enabled = enabled
        self.t0 = time.perf_counter()
        self.console = None
        if enabled:
            from rich.console import Console

            self.console = Console(stderr=True)

    def __call__(self, msg: str) -> None:
        if self.enabled:
            self.console.print(f"[dim]{time.perf_counter() - self.t0:6.1f} s[/dim]  synth: {msg}", highlight=False)

    @contextmanager
    def bar(self, label: str, total: int):
        if not self.enabled:
            yield lambda: None
            return
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      console=self.console, transient=False) as prog:
            task = prog.add_task(label, total=total)
            yield lambda: prog.advance(task)


#: the farthest pivot of the pose errors (m) bijcr synth accepts: beyond it no wrist camera sees the point
MAX_POSE_PIVOT_M = 5.0
#: the viewpoints per arm and the objects on the table bijcr synth makes (inclusive)
VIEWS_RANGE, OBJECTS_RANGE = (3, 40), (1, 10)


def _check_args(out: Path, views, objects, noise, outliers, touching, overwrite, pointmap_size, image_size,
                map_noise=None, pose_pivot_m=0.0) -> None:
    probs = []

    def bad(field, msg, fix):
        probs.append(Problem("bijcr synth", field, msg, fix))

    (v_lo, v_hi), (o_lo, o_hi) = VIEWS_RANGE, OBJECTS_RANGE
    if not isinstance(views, (int, np.integer)) or not v_lo <= views <= v_hi:
        bad("views", f"views per arm must be an integer in {v_lo}..{v_hi}, got {views!r}",
            "hand-eye calibration needs >= 3 views")
    if not isinstance(objects, (int, np.integer)) or not o_lo <= objects <= o_hi:
        bad("objects", f"objects must be an integer in {o_lo}..{o_hi}, got {objects!r}", "the table holds at most 10")
    if noise not in NOISE_LEVELS:
        bad("noise", f"unknown noise level {noise!r}", f"use one of {', '.join(NOISE_LEVELS)}")
    if map_noise is not None and not isinstance(map_noise, MapNoise) and map_noise not in MAP_NOISES:
        bad("map_noise", f"unknown point-map noise model {map_noise!r}",
            f"use one of {', '.join(MAP_NOISES)}, a MapNoise, or None for the noise level's own depth noise")
    if not 0.0 <= float(pose_pivot_m) <= MAX_POSE_PIVOT_M:
        bad("pose_pivot_m", f"the pivot of the pose errors must be in [0, {MAX_POSE_PIVOT_M:g}] m ahead of the "
            f"camera, got {pose_pivot_m!r}", "e.g. --pose-pivot-m 1.0 (0: errors turn about the camera centre)")
    if not 0.0 <= float(outliers) <= 0.5:
        bad("outliers", f"outlier fraction must be in [0, 0.5], got {outliers!r}", "e.g. --outliers 0.2")
    if not 0.0 <= float(touching) <= 1.0:
        bad("touching", f"touching fraction must be in [0, 1], got {touching!r}", "e.g. --touching 0.5")
    W, H = image_size
    w, h = pointmap_size
    if w <= 0 or h <= 0 or W % w or H % h:
        bad("pointmap_size", f"point-map size {w}x{h} must divide the image size {W}x{H}", "e.g. 160x120 for 640x480")
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        if not overwrite:
            bad("OUT", f"{out} exists and is not empty", "choose a new folder, or pass --overwrite to replace a"
                " folder made by bijcr synth")
        elif not _is_synth_scene(out):
            bad("OUT", f"{out} was not made by bijcr synth: refusing to replace it", "choose a new folder")
    if probs:
        raise InputError(probs)


def _is_synth_scene(path: Path) -> bool:
    gt = path / "ground_truth.yaml"
    if not path.is_dir() or not gt.is_file():
        return False
    try:
        data = yaml.safe_load(gt.read_text())
    except yaml.YAMLError:
        return False
    return isinstance(data, dict) and isinstance(data.get("synthetic"), dict)


def _save_png(path: Path, arr: np.ndarray) -> None:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(arr).save(path, format="PNG", compress_level=6)


def make_synthetic_scene(out_dir: str | os.PathLike, seed: int = 0, views: int = 8, objects: int = 5,
                         noise: str = "paper", outliers: float = 0.0, render: bool = True, touching: float = 0.5,
                         *, image_size: tuple[int, int] = (640, 480), focal: float = 420.0,
                         pointmap_size: tuple[int, int] = (160, 120), depth_stride: int = 2,
                         as_joints: bool = False, name: str | None = None, overwrite: bool = False,
                         progress: bool = True, preview: bool = True, map_noise: str | MapNoise | None = None,
                         pose_pivot_m: float = 0.0) -> Path:
    """Generate a synthetic scene folder (docs/synth.md) and return its path.

    Args:
        out_dir: the scene folder to create (must not exist or be empty; ``overwrite`` replaces a folder
            that bijcr synth made, never anything else).
        seed: everything (layout, mounts, viewpoints, noise, frame) follows from it.
        views: viewpoints per arm (3..40).
        objects: objects on the table (1..10): a large box, a small box, a cylinder, a mesh, then a mix.
        noise: emulator noise level, one of ``none``, ``low``, ``paper``, ``harsh``.
        outliers: fraction of each arm's views that get a gross pose error (0..0.5).
        render: False skips images, masks, depth and point maps (poses-only reconstruction; fast).
        touching: fraction of the objects placed in contact with a neighbour.
        image_size, focal: the wrist cameras (width, height) and focal length in pixels (principal
            point at the image centre).
        pointmap_size: (w, h) of the emulated point maps; must divide ``image_size``.
        depth_stride: ground-truth depth PNGs keep every ``depth_stride``-th pixel in x and y.
        as_joints: write ee_poses.csv as joint angles j1..j6 instead of poses.
        name: scene name (default: the folder name).
        progress: log stages and a progress bar on stderr.
        preview: write preview.png.
        map_noise: point-map error model replacing the noise level's depth noise: ``"fm"`` (foundation-model
            like: per-view depth scale, smooth warp, correlated noise; docs/synth.md), a
            :class:`~bimanual_app.synth._emulator.MapNoise`, or None (default: the level's own depth noise;
            scenes are then byte-identical to those made before this option existed).
        pose_pivot_m: the reported camera poses' rotation errors turn about the point this far (m, 0..5)
            along each camera's optical axis instead of its centre, so the centre errs by about
            ``pose_pivot_m`` x the rotation error on top of the level's own centre noise (what real
            reconstructions do: docs/synth.md). 0 (default): byte-identical to scenes made before the option.
    """
    out = Path(out_dir).expanduser().absolute()
    _check_args(out, views, objects, noise, outliers, touching, overwrite, pointmap_size, image_size, map_noise,
                pose_pivot_m)
    level = NOISE_LEVELS[noise]
    if float(pose_pivot_m):
        level = replace(level, pivot_m=float(pose_pivot_m))
    map_model = MAP_NOISES[map_noise] if isinstance(map_noise, str) else map_noise
    log = _Log(progress)
    out.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(stage, 0o777 & ~umask)  # mkdtemp makes it private; the scene is an ordinary folder
    try:
        _generate(stage, out.name if name is None else name, int(seed), int(views), int(objects), level,
                  float(outliers), bool(render), float(touching), tuple(image_size), float(focal),
                  tuple(pointmap_size), int(depth_stride), bool(as_joints), bool(preview), log, map_model)
        if out.exists():
            old = out.parent / f".{out.name}.old-{os.getpid()}"
            os.replace(out, old)
            os.replace(stage, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(stage, out)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    log(f"wrote {out}")
    return out


@dataclass
class _Poses:
    """The emulator's view poses of both arms (independent of rendering: same numbers with render=False)."""

    T_b1_c_true: list[np.ndarray]   # per arm (N, 4, 4) true camera poses in b1
    is_out: list[np.ndarray]        # per arm (N,) bool: views with a gross pose error
    rot_err: list[np.ndarray]       # per arm (N,) rad
    trans_err: list[np.ndarray]     # per arm (N,) m
    T_w_b1: np.ndarray              # (4, 4) the reconstruction frame
    scale: float                    # reconstruction units per metre
    T_w_c: list[np.ndarray]         # per arm (N, 4, 4) reported camera poses in w


@dataclass
class _Renders:
    """What rendering produced: point maps of every view (primary first) and per-arm thumbnails."""

    pts: list = field(default_factory=list)
    conf: list = field(default_factory=list)
    colors: list = field(default_factory=list)
    thumbs: list = field(default_factory=list)
    depth_scale_err: list = field(default_factory=lambda: [[], []])


def _place_and_plan(world, rngs: dict, n_objects: int, n_views: int, touching: float, K: np.ndarray,
                    image_size, log: _Log) -> tuple[list, list, list, list, list]:
    """Objects on the table and both arms' viewpoints: (specs, T_b1_o, touching pairs, plans, view stats)."""
    specs = [sample_spec(k, rngs["objects"]) for k in choose_kinds(n_objects, rngs["objects"])]
    T_b1_o = place_objects(world, specs, rngs["objects"], touching=touching)
    pairs = touching_pairs(world, world.object_ids)
    log(f"placed {', '.join(s.kind for s in specs)}; touching pairs {pairs}")
    centre = np.mean([T[:3, 3] for T in T_b1_o], axis=0)
    centre[2] = 0.0
    plans, vstats = [], []
    for a in range(2):
        v, st = plan_views(world, a, n_views, rngs[("views1", "views2")[a]], centre, K=K, image_size=image_size)
        plans.append(v)
        vstats.append(st)
        log(f"{ARMS[a]}: {st['visible']} feasible viewpoints of {st['candidates']} tried, chose {n_views}"
            f" (smallest rotation between two: {st['min_pair_rotation_deg']:.1f} deg)")
    return specs, T_b1_o, pairs, plans, vstats


def _emulate_poses(plans: list, T_b1_b: list[np.ndarray], T_e_c: list[np.ndarray], level, n_views: int,
                   outlier_frac: float, rngs: dict) -> _Poses:
    """True camera poses, the perturbed poses the emulator reports, and the random reconstruction frame."""
    T_b1_c_true = [np.array([T_b1_b[a] @ v.T_b_e @ T_e_c[a] for v in plans[a]]) for a in range(2)]
    is_out = [choose_outliers(rngs["outliers"], n_views, outlier_frac) for _ in range(2)]
    reported, rot_err, trans_err = [], [], []
    for a in range(2):
        Tr, re, te = perturb_poses(T_b1_c_true[a], level, is_out[a], rngs["poses"])
        reported.append(Tr)
        rot_err.append(re)
        trans_err.append(te)
    T_w_b1, scale = random_frame(rngs["frame"])
    T_w_c = [to_frame_w(reported[a], T_w_b1, scale) for a in range(2)]
    return _Poses(T_b1_c_true, is_out, rot_err, trans_err, T_w_b1, scale, T_w_c)


def _render_view(world, root: Path, a: int, i: int, key: str, poses: _Poses, K: np.ndarray, image_size, pm_size,
                 depth_stride: int, level, map_model: MapNoise | None, rngs: dict, static: set,
                 out: _Renders) -> None:
    """Render view ``i`` of arm ``a``: write its image, mask and ground-truth depth, emulate its point map."""
    W, H = image_size
    rgb, depth, seg = world.render(poses.T_b1_c_true[a][i], K, W, H)
    mask = np.zeros((H, W), np.uint8)
    for k, body in enumerate(world.object_ids):
        mask[seg == body] = k + 1
    gt_depth = np.where(np.isin(seg, list(static)) & np.isfinite(depth), depth, 0.0)
    gt_depth = gt_depth[::depth_stride, ::depth_stride]
    gt_q = np.round(gt_depth / DEPTH_UNITS_M)
    gt_q[gt_q > 65535] = 0
    arm_dir = root / ARMS[a]
    _save_png(arm_dir / key, rgb)
    _save_png(arm_dir / "masks" / f"{i:03d}.png", mask)
    _save_png(arm_dir / "depth" / f"{i:03d}.png", gt_q.astype(np.uint16))
    err = None
    if map_model is not None:
        err, s_err = map_depth_error(map_model, pm_size[1], pm_size[0], rngs["depth"])
        out.depth_scale_err[a].append(s_err)
    p3, cf, co = point_map(depth, rgb, K, poses.T_w_c[a][i], poses.scale, pm_size, level.depth_rel,
                           rngs["depth"], depth_error=err)
    out.pts.append(p3)
    out.conf.append(cf)
    out.colors.append(co)
    out.thumbs[a].append(rgb[::4, ::4])


def _render_all(world, root: Path, plans: list, keys: list[str], poses: _Poses, K: np.ndarray, image_size, pm_size,
                depth_stride: int, level, map_model: MapNoise | None, rngs: dict, log: _Log) -> _Renders:
    """Render every view of both arms (the other arm parked)."""
    out = _Renders()
    static = set(world.static_ids) | set(world.object_ids)
    with log.bar("rendering", 2 * len(keys)) as step:
        for a in range(2):
            world.set_arm(1 - a, world.q_park)
            out.thumbs.append([])
            for i, v in enumerate(plans[a]):
                world.set_arm(a, v.q)
                _render_view(world, root, a, i, keys[i], poses, K, image_size, pm_size, depth_stride, level,
                             map_model, rngs, static, out)
                step()
            world.set_arm(a, world.q_park)
    return out


def _overview(world, T_b1_b2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Overview picture: both arms parked, seen from the side of the table; (image, K (3, 3), T_b1_camera)."""
    for a in range(2):
        world.set_arm(a, world.q_park)
    across = np.array([-T_b1_b2[1, 3], T_b1_b2[0, 3], 0.0])
    across /= np.linalg.norm(across)
    mid = 0.5 * T_b1_b2[:3, 3] * np.array([1, 1, 0])
    T_b1_ov = look_at(mid - 0.75 * across + np.array([0.0, 0.0, 0.7]), mid + np.array([0, 0, 0.12]))
    K_ov = np.array([[520.0, 0.0, 399.5], [0.0, 520.0, 299.5], [0.0, 0.0, 1.0]])
    return world.render(T_b1_ov, K_ov, 800, 600)[0], K_ov, T_b1_ov


def _object_records(specs: list, T_b1_o: list, pairs: list) -> list[dict]:
    """The ground-truth object list."""
    objs = []
    for k, (spec, T) in enumerate(zip(specs, T_b1_o)):
        objs.append({
            "id": k, "name": f"{spec.kind}_{k}", "kind": spec.kind, "shape": spec.shape, "mask_label": k + 1,
            "T_b1_o": T, "size": spec.size.round(6), "mass": spec.mass,
            "fits_gripper": spec.fits_gripper, "needs_two_hands": spec.needs_two_hands,
            "touching": sorted({j for p in pairs for j in p if k in p} - {k}),
        })
    return objs


def _gt_extras(seed: int, n_views: int, n_objects: int, level, outlier_frac: float, touching: float, render: bool,
               image_size, pm_size, depth_stride: int, park: np.ndarray, poses: _Poses, keys: list[str],
               vstats: list, table, map_model: MapNoise | None, renders: _Renders) -> dict:
    """The ground truth's extra keys: generator settings, noise, pose errors, outliers, viewpoints, table."""
    extras = {
        "T_w_b1": poses.T_w_b1,
        "synthetic": {
            "generator": GENERATOR, "seed": seed, "views": n_views, "objects": n_objects, "noise": level.name,
            "outliers": outlier_frac, "touching": touching, "render": render,
            "image_size": list(image_size), "pointmap_size": list(pm_size) if render else None,
            "depth": {"folder": "depth", "stride": depth_stride, "units_m": DEPTH_UNITS_M,
                      "meaning": "uint16 z-depth of table and object surfaces at image pixels (stride*i, stride*j);"
                                 " 0 where the ray hits a robot, a camera or nothing"} if render else None,
            "park_q": park,
        },
        "noise": {"level": level.name, "rot_rms_deg": level.rot_deg, "trans_rms_m": level.trans_m,
                  "depth_rel_sigma": level.depth_rel},
        "pose_errors": {ARMS[a]: {"rot_deg": np.rad2deg(poses.rot_err[a]).round(4),
                                  "trans_m": poses.trans_err[a].round(6)} for a in range(2)},
        "outlier_views": {ARMS[a]: [keys[i] for i in np.flatnonzero(poses.is_out[a])] for a in range(2)},
        "viewpoints": {ARMS[a]: {k: (round(v, 3) if isinstance(v, float) else v) for k, v in vstats[a].items()}
                       for a in range(2)},
        "table": {"T_b1_t": table.T_b1_t, "size": table.size},
    }
    if level.pivot_m:  # only then: default scenes stay byte-identical
        extras["synthetic"]["pose_pivot_m"] = level.pivot_m
        extras["noise"]["pose_pivot_m"] = level.pivot_m
    if map_model is not None:  # only then: default scenes stay byte-identical
        extras["synthetic"]["map_noise"] = map_model.name
        extras["noise"]["map_noise"] = {"model": map_model.name, "depth_scale_rel_sigma": map_model.scale_rel,
                                        "warp_rel_rms": map_model.warp_rel, "correlated_rel_sigma": map_model.corr_rel,
                                        "correlation_cells": map_model.corr_cells}
        if render:
            extras["map_errors"] = {ARMS[a]: {"depth_scale_rel": np.round(renders.depth_scale_err[a], 6)}
                                    for a in range(2)}
    return extras


def _generate(root: Path, name: str, seed: int, n_views: int, n_objects: int, level, outlier_frac: float,
              render: bool, touching: float, image_size, focal: float, pm_size, depth_stride: int,
              as_joints: bool, preview: bool, log: _Log, map_model: MapNoise | None = None) -> None:
    from bimanual_app.robots import load_robot

    from ._world import SynthWorld

    rngs = dict(zip(_STREAMS, (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(len(_STREAMS)))))
    robot = load_robot("piper")
    W, H = image_size
    cam = CameraIntrinsics(W, H, focal, focal, (W - 1) / 2, (H - 1) / 2)
    K = cam.K
    T_b1_b2 = sample_base_pose(rngs["base"])
    T_e_c = [sample_hand_eye(rngs["hand_eye"]), sample_hand_eye(rngs["hand_eye"])]
    log(f"seed {seed}: bases {np.linalg.norm(T_b1_b2[:3, 3]):.3f} m apart, {n_objects} objects, {n_views} views per arm")

    with SynthWorld(robot, T_b1_b2, rngs["textures"]) as world:
        for a in range(2):
            world.set_hand_eye(a, T_e_c[a])
        specs, T_b1_o, pairs, plans, vstats = _place_and_plan(world, rngs, n_objects, n_views, touching, K,
                                                              image_size, log)
        poses = _emulate_poses(plans, [np.eye(4), T_b1_b2], T_e_c, level, n_views, outlier_frac, rngs)
        keys = [f"images/{i:03d}.png" for i in range(n_views)]
        renders = _render_all(world, root, plans, keys, poses, K, image_size, pm_size, depth_stride, level,
                              map_model, rngs, log) if render else _Renders()
        overview = _overview(world, T_b1_b2) if preview else None
        park = world.q_park.copy()
        table = world.table

    # ---- ground truth and the scene files
    objs = _object_records(specs, T_b1_o, pairs)
    arms = [ArmCapture(ARMS[a], list(keys), np.array([v.T_b_e for v in plans[a]]), np.array([v.q for v in plans[a]]))
            for a in range(2)]
    extras = _gt_extras(seed, n_views, n_objects, level, outlier_frac, touching, render, image_size, pm_size,
                        depth_stride, park, poses, keys, vstats, table, map_model, renders)
    gt = GroundTruth(T_e_c[0], T_e_c[1], T_b1_b2, poses.scale, objs, extras)
    rec = Reconstruction(
        arm=np.repeat([1, 2], n_views), image=np.array(keys + keys), T_w_c=np.concatenate(poses.T_w_c),
        pts3d=np.stack(renders.pts) if render else None, conf=np.stack(renders.conf) if render else None,
        model="synthetic", colors=np.stack(renders.colors) if render else None)
    assert len(rec) == 2 * n_views
    scene = Scene(root, name, arms[0], arms[1], robot="piper", ee_link=robot.ee_link, camera=cam,
                  reconstruction=rec, ground_truth=gt)
    write_scene(scene, root, as_joints=as_joints)
    if preview:
        ov, K_ov, T_b1_ov = overview
        title = (f"{name}: seed {seed}, {n_views} views per arm, noise {level.name}, outliers {outlier_frac:g}"
                 f" - bases {np.linalg.norm(T_b1_b2[:3, 3]):.2f} m apart")
        save_preview(root / "preview.png", ov, K_ov, T_b1_ov, poses.T_b1_c_true, K, image_size, objs,
                     renders.thumbs if render else None, poses.is_out, title)
    min_rot = [float(np.rad2deg(rotation_angle_between(T[:, None, :3, :3], T[None, :, :3, :3])[~np.eye(len(T), dtype=bool)].min()))
               for T in poses.T_b1_c_true]
    log(f"smallest rotation between views: primary {min_rot[0]:.1f} deg, secondary {min_rot[1]:.1f} deg")


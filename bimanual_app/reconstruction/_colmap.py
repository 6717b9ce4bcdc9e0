"""Structure from motion with pycolmap: SIFT on the CPU, exhaustive matching, incremental mapping.

Both arms' images go into one database and are matched all against all (so pairs across the arms are
matched too); each arm is one camera (its images share intrinsics). With ``scene.yaml`` intrinsics the
cameras are PINHOLE with those values, held fixed in bundle adjustment; without, each arm gets a
SIMPLE_RADIAL camera that COLMAP estimates.

To register as many views as it can, the mapper runs a ladder of attempts and keeps the best model:
default options, then relaxed initialisation and registration thresholds; then, if views are still
missing or the model is thin (fewer than ``points_per_view`` points per view), features re-extracted
denser (lower peak threshold, affine shape, domain-size pooling) with a looser matcher, and the same
ladder again; if views are still missing, those features re-matched with other RANSAC seeds (with
a few dozen inliers per pair, geometric verification is a lottery). Each attempt may make several
models (COLMAP's ``multiple_models``); each attempt's best one is the one with the most views registered
while both arms have at least ``min_views`` (then the most points), counting only the views that pass
the caller's check (the arms' kinematics: see ``_kinematic``); views that fail it are left out. Between
attempts, the usable models that register the most views are compared by the caller's ``agree``, how well
their camera motions match the robot's (``_agreement``): the best-agreeing one is kept, near-ties going to
more points.
All random seeds are fixed and feature extraction and mapping run on one thread (with several, runs
differed), so a run is repeatable; matching uses ``num_threads``.

Pixel convention: COLMAP puts pixel centres at +0.5 (the image spans 0..W), OpenCV at integers; this
module converts at its boundary, everything it returns is OpenCV.
"""

from __future__ import annotations

import contextlib
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bimanual_app.scene import CameraIntrinsics
from bimanual_app.transforms import check_T, inv_T

from ._agreement import choose_attempt
from ._images import ArmImages

__all__ = ["ColmapOptions", "Attempt", "SparseModel", "run_colmap"]

Log = Callable[[str], None]


@dataclass
class ColmapOptions:
    """Knobs of the COLMAP backend (defaults suit 640x480 table-top captures on a small CPU)."""

    max_features: int = 4096
    max_image_size: int = 1600
    num_threads: int = 2
    seed: int = 0
    retries: bool = True            # relaxed mapper options and denser features when views are missing
    min_views: int = 3              # per arm, for a model to count as usable
    points_per_view: int = 60       # fewer sparse points than this per view: also try the denser features
    reseeds: int = 2                # views still missing: re-match the dense features with this many other seeds
    max_motion_error_deg: float = 5.0  # kinematic check: a view whose motions disagree more is dropped (0: off)
    verbose: bool = False           # COLMAP's own log


@dataclass
class Attempt:
    """One mapper run: what it used and how many views of each arm its best model registered."""

    name: str
    registered: dict[str, int]
    models: int
    points: int
    seconds: float
    agreement: dict | None = None   # motion_agreement of the model's kept views (None: not usable / not scored)


@dataclass
class SparseModel:
    """A registered COLMAP model as plain arrays (OpenCV pixel convention).

    Attributes:
        names: (M,) scene-relative image names of the registered images.
        T_w_c: (M, 4, 4) camera-to-world poses (COLMAP's cam_from_world inverted).
        cameras: (M,) pycolmap.Camera of each image (for undistortion; COLMAP pixel convention inside).
        K: (M, 3, 3) pinhole part of each camera, OpenCV convention.
        xyz: (P, 3) sparse points in w; rgb: (P, 3) uint8; track_len: (P,) int; error: (P,) reprojection px.
        obs: (M,) per image a pair (xy (k, 2) OpenCV pixels, point index (k,) into xyz).
        attempts: every mapper attempt, in order; chosen: the attempt the model comes from.
        dropped: names of views COLMAP registered but ``check`` rejected (kinematically inconsistent).
    """

    names: list[str]
    T_w_c: np.ndarray
    cameras: list
    K: np.ndarray
    xyz: np.ndarray
    rgb: np.ndarray
    track_len: np.ndarray
    error: np.ndarray
    obs: list[tuple[np.ndarray, np.ndarray]]
    attempts: list[Attempt] = field(default_factory=list)
    chosen: str = ""
    dropped: list[str] = field(default_factory=list)


@contextlib.contextmanager
def _colmap_log(verbose: bool):
    import pycolmap

    old = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 0 if verbose else 3  # the ladder expects failures: hide them
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = old


def _feature_configs(opts: ColmapOptions) -> list[tuple[str, dict, dict, dict]]:
    """(name, SIFT extraction, SIFT matching, two-view geometry) settings, in the order they are tried."""
    base = ("sift", {"max_num_features": opts.max_features}, {}, {})
    # low-contrast texture (plain table tops, close-ups) gives COLMAP's default detector a few hundred
    # keypoints: a 3x lower peak threshold, affine shapes with domain-size pooling, a looser ratio test
    # and guided matching find several times more correspondences
    dense = ("sift-dense", {"max_num_features": 2 * opts.max_features, "peak_threshold": 0.002,
                            "estimate_affine_shape": True, "domain_size_pooling": True},
             {"max_ratio": 0.85, "guided": True}, {"min_num_inliers": 10})
    return [base, dense] if opts.retries else [base]


def _mapper_configs(opts: ColmapOptions) -> list[tuple[str, dict, dict, dict]]:
    """(name, pipeline, mapper, triangulation) option overrides, from strict (COLMAP's defaults) to loose."""
    default = ("default", {}, {}, {})
    relaxed = ("relaxed", {"min_num_matches": 10},
               {"init_min_num_inliers": 50, "init_min_tri_angle": 8.0, "abs_pose_min_num_inliers": 15,
                "abs_pose_min_inlier_ratio": 0.15, "max_reg_trials": 5},
               {"ignore_two_view_tracks": False})
    loose = ("loose", {"min_num_matches": 8},
             {"init_min_num_inliers": 25, "init_min_tri_angle": 4.0, "init_max_error": 6.0,
              "abs_pose_min_num_inliers": 10, "abs_pose_min_inlier_ratio": 0.1, "abs_pose_max_error": 16.0,
              "filter_min_tri_angle": 1.0, "max_reg_trials": 8},
             {"ignore_two_view_tracks": False, "min_angle": 1.0})
    return [default, relaxed, loose] if opts.retries else [default]


def _set(obj, values: dict) -> None:
    for k, v in values.items():
        setattr(obj, k, v)


def _build_database(db: Path, root: Path, arms: dict[str, ArmImages], intr: dict[str, CameraIntrinsics | None],
                    feat: dict, opts: ColmapOptions) -> None:
    """Extract SIFT features of every image into a fresh database, one camera per arm."""
    import pycolmap

    eo = pycolmap.FeatureExtractionOptions()
    eo.num_threads = 1  # several extraction threads gave different models run to run (measured); one is repeatable
    eo.max_image_size = opts.max_image_size
    _set(eo.sift, feat)
    for name, ai in arms.items():
        ro = pycolmap.ImageReaderOptions()
        K = intr.get(name)
        if K is not None:
            # PINHOLE with the user's intrinsics; COLMAP pixel centres are at +0.5.
            cam = pycolmap.Camera(model="PINHOLE", width=K.width, height=K.height,
                                  params=[K.fx, K.fy, K.cx + 0.5, K.cy + 0.5])
            cam.has_prior_focal_length = True
            with pycolmap.Database.open(db) as d:
                ro.existing_camera_id = d.write_camera(cam)
            mode = pycolmap.CameraMode.SINGLE
        else:
            ro.camera_model = "SIMPLE_RADIAL"
            mode = pycolmap.CameraMode.SINGLE  # one new camera per call = one per arm
        pycolmap.extract_features(db, root, image_names=ai.names, camera_mode=mode, reader_options=ro,
                                  extraction_options=eo, device=pycolmap.Device.cpu)


def _match(db: Path, match: dict, geom: dict, opts: ColmapOptions, seed: int) -> None:
    """Exhaustive matching of all pairs (both arms together) with geometric verification."""
    import pycolmap

    mo = pycolmap.FeatureMatchingOptions()
    mo.num_threads = opts.num_threads
    mo.guided_matching = bool(match.get("guided", False))
    if "max_ratio" in match:
        mo.sift.max_ratio = match["max_ratio"]
    vo = pycolmap.TwoViewGeometryOptions()
    vo.ransac.random_seed = seed  # COLMAP's default (-1) reseeds every run: results would differ run to run
    _set(vo, geom)
    pycolmap.match_exhaustive(db, matching_options=mo, verification_options=vo, device=pycolmap.Device.cpu)


Check = Callable[[list[str], np.ndarray], np.ndarray]
Agree = Callable[[list[str], np.ndarray], dict]


def _poses(rec) -> tuple[list[int], list[str], np.ndarray]:
    """Registered image ids, names and camera-to-world poses (M, 4, 4) of a pycolmap.Reconstruction."""
    ids = sorted(rec.reg_image_ids(), key=lambda i: rec.image(i).name)
    T = np.tile(np.eye(4), (len(ids), 1, 1))
    for k, iid in enumerate(ids):
        T[k, :3, :] = rec.image(iid).cam_from_world().matrix()  # COLMAP stores world-to-camera: invert
    return ids, [rec.image(i).name for i in ids], inv_T(T)


def _kept(rec, check: Check | None) -> tuple[list[int], list[str]]:
    """Registered image ids that pass ``check`` (kinematic consistency), and the names of those that fail."""
    ids, names, T = _poses(rec)
    bad = check(names, T) if check is not None and ids else np.zeros(len(ids), bool)
    return [i for i, b in zip(ids, bad) if not b], [n for n, b in zip(names, bad) if b]


def _per_arm(rec, arm_of: dict[str, str], ids: list[int]) -> dict[str, int]:
    counts = {a: 0 for a in sorted(set(arm_of.values()))}
    for iid in ids:
        counts[arm_of[rec.image(iid).name]] += 1
    return counts


def _score(rec, arm_of: dict[str, str], min_views: int, check: Check | None) -> tuple:
    ids, _ = _kept(rec, check)
    counts = _per_arm(rec, arm_of, ids)
    return (min(counts.values()) >= min_views, sum(counts.values()), rec.num_points3D())


def _map(db: Path, root: Path, out: Path, cfg: tuple, fixed_intrinsics: bool, opts: ColmapOptions) -> dict:
    import pycolmap

    name, pipe, mapper, tri = cfg
    po = pycolmap.IncrementalPipelineOptions()
    po.num_threads = 1  # mapping is a small share of the time; one thread makes bundle adjustment repeatable
    po.random_seed = opts.seed
    po.mapper.random_seed = opts.seed
    po.triangulation.random_seed = opts.seed
    po.min_model_size = max(2, opts.min_views)
    po.multiple_models = True
    po.max_num_models = 10
    if fixed_intrinsics:
        po.ba_refine_focal_length = False
        po.ba_refine_principal_point = False
        po.ba_refine_extra_params = False
        po.mapper.abs_pose_refine_focal_length = False
        po.mapper.abs_pose_refine_extra_params = False
    _set(po, pipe)
    _set(po.mapper, mapper)
    _set(po.triangulation, tri)
    out.mkdir(parents=True, exist_ok=True)
    return pycolmap.incremental_mapping(db, root, out, po)


def _to_sparse(rec, check: Check | None) -> SparseModel:
    """Plain arrays (OpenCV pixels, camera-to-world poses) from a pycolmap.Reconstruction, without the
    views that fail ``check``; points are kept when at least two kept views observe them."""
    ids, dropped = _kept(rec, check)
    seen: dict[int, int] = {}
    for iid in ids:
        for p in rec.image(iid).points2D:
            if p.has_point3D():
                seen[p.point3D_id] = seen.get(p.point3D_id, 0) + 1
    pid_list = sorted(pid for pid, n in seen.items() if n >= 2)
    index = {pid: k for k, pid in enumerate(pid_list)}
    xyz = np.array([rec.point3D(p).xyz for p in pid_list], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([rec.point3D(p).color for p in pid_list], dtype=np.uint8).reshape(-1, 3)
    track = np.array([rec.point3D(p).track.length() for p in pid_list], dtype=np.int64)
    err = np.array([rec.point3D(p).error for p in pid_list], dtype=np.float64)
    names, Ts, cams, Ks, obs = [], [], [], [], []
    for iid in ids:
        im = rec.image(iid)
        cam = rec.camera(im.camera_id)
        T_c_w = np.eye(4)
        T_c_w[:3, :] = im.cam_from_world().matrix()  # COLMAP stores world-to-camera: invert
        Ts.append(inv_T(T_c_w))
        names.append(im.name)
        cams.append(cam)
        K = np.array(cam.calibration_matrix(), dtype=np.float64)
        K[0, 2] -= 0.5
        K[1, 2] -= 0.5
        Ks.append(K)
        p2d = [p for p in im.points2D if p.has_point3D() and p.point3D_id in index]
        xy = np.array([p.xy for p in p2d], dtype=np.float64).reshape(-1, 2) - 0.5
        pidx = np.array([index[p.point3D_id] for p in p2d], dtype=np.int64)
        obs.append((xy, pidx))
    T = check_T("colmap T_w_c", np.array(Ts).reshape(-1, 4, 4), tol=1e-6)
    return SparseModel(names, T, cams, np.array(Ks).reshape(-1, 3, 3), xyz, rgb, track, err, obs, dropped=dropped)


def _feature_rounds(opts: ColmapOptions) -> list[tuple[str, dict, dict, dict, int]]:
    """The feature ladder: (name, SIFT extraction, SIFT matching, two-view geometry, RANSAC seed) per round, in
    the order tried. Rounds named ``<features>~seed<k>`` re-match the previous round's features."""
    configs = _feature_configs(opts)
    rounds = [(f, feat, match, geom, opts.seed) for f, feat, match, geom in configs]
    if opts.retries:  # last resort: the densest features, re-matched with other RANSAC seeds
        f, feat, match, geom = configs[-1]
        rounds += [(f"{f}~seed{k}", feat, match, geom, opts.seed + k) for k in range(1, opts.reseeds + 1)]
    return rounds


def _ladder_done(best_score: tuple | None, fname: str, n_images: int, opts: ColmapOptions) -> bool:
    """True when every view is registered in a well-populated model, or only reseeding rounds are left."""
    all_in = best_score is not None and best_score[1] == n_images
    return all_in and (best_score[2] >= opts.points_per_view * n_images or "~" in fname)


def _features_and_matches(db: Path | None, workdir: Path, root: Path, arms: dict[str, ArmImages],
                          intrinsics: dict[str, CameraIntrinsics | None], n_images: int, round_: tuple,
                          opts: ColmapOptions, log: Log) -> Path:
    """One feature round: a fresh database with its features (or, for a reseeding round, the previous one's
    matches cleared), then exhaustive matching. Returns the database."""
    import pycolmap

    fname, feat, match, geom, seed = round_
    t0 = time.perf_counter()
    if "~" not in fname:
        db = workdir / f"{fname}.db"
        if db.exists():
            db.unlink()
        log(f"  [{fname}] extracting SIFT features of {n_images} images (CPU)")
        _build_database(db, root, arms, intrinsics, feat, opts)
    else:
        # few inliers per pair make geometric verification a lottery: another RANSAC seed can
        # verify the pair that brings a missing view in (measured: 2/3 vs 3/4 views on 4-view scenes)
        with pycolmap.Database.open(db) as d:
            d.clear_matches()
            d.clear_two_view_geometries()
    log(f"  [{fname}] exhaustive matching ({n_images * (n_images - 1) // 2} pairs, both arms together)")
    _match(db, match, geom, opts, seed)
    with pycolmap.Database.open(db) as d:
        n_pairs = d.num_verified_image_pairs()
    log(f"  [{fname}] {n_pairs} verified image pairs ({time.perf_counter() - t0:.1f} s)")
    return db


def _mapper_attempt(db: Path, root: Path, workdir: Path, name: str, cfg: tuple, fixed: bool, opts: ColmapOptions,
                    arms: dict[str, ArmImages], arm_of: dict[str, str], check: Check | None, agree: Agree | None,
                    log: Log) -> tuple[Attempt, tuple | None]:
    """One mapper run: its :class:`Attempt` and (score, pycolmap.Reconstruction) of its best model, or None."""
    t0 = time.perf_counter()
    log(f"  [{name}] incremental mapping")
    models = _map(db, root, workdir / name.replace("/", "-").replace("~", "-"), cfg, fixed, opts)
    top = None
    for rec in models.values():
        sc = _score(rec, arm_of, opts.min_views, check)
        if top is None or sc > top[0]:
            top = (sc, rec)
    counts = _per_arm(top[1], arm_of, _kept(top[1], check)[0]) if top else {a: 0 for a in sorted(arms)}
    att = Attempt(name, counts, len(models), top[1].num_points3D() if top else 0,
                  time.perf_counter() - t0)
    if top is not None and top[0][0] and agree is not None:
        att.agreement = _agreement_of(top[1], check, agree)
    log(f"  [{name}] {len(models)} model(s); best registers "
        + ", ".join(f"{a} {counts[a]}/{len(arms[a].names)}" for a in arms)
        + (f"; motions vs robot {att.agreement['rot_deg']:.2f} deg, "
           f"{100 * att.agreement['trans_rel']:.1f} % (score {att.agreement['score']:.3f})"
           if att.agreement else "")
        + f" ({time.perf_counter() - t0:.1f} s)")
    return att, top


def _pick_candidate(candidates: list[tuple[int, tuple, object]], attempts: list[Attempt]) -> int:
    """Index into ``candidates`` of the model to keep (``_agreement.choose_attempt``)."""
    scores = [attempts[a].agreement["score"] if attempts[a].agreement else float("inf") for a, _, _ in candidates]
    return choose_attempt([sc[0] for _, sc, _ in candidates], [sc[1] for _, sc, _ in candidates],
                          [sc[2] for _, sc, _ in candidates], scores)


def run_colmap(root: Path, arms: dict[str, ArmImages], intrinsics: dict[str, CameraIntrinsics | None],
               opts: ColmapOptions | None = None, workdir: Path | None = None, log: Log = print,
               check: Check | None = None, agree: Agree | None = None) -> SparseModel:
    """Run COLMAP on the scene's images and return its best model.

    Args:
        root: scene folder; image names are relative to it.
        arms: checked images per arm (``primary``, ``secondary``).
        intrinsics: per arm the scene.yaml intrinsics for that arm's image size, or None (estimate).
        opts: options; workdir: where the database and models go (a temporary folder when None).
        log: progress lines.
        check: ``check(names, T_w_c) -> (M,) bool`` flags registered views to distrust (the kinematic
            consistency test of ``_kinematic``); they count as unregistered when models are compared
            and are left out of the result.
        agree: ``agree(names, T_w_c) -> {"score", ...}`` scores a usable model's kept views by how well
            their camera motions match the robot's (lower is better; ``_agreement.motion_agreement``);
            the attempt to keep is chosen by it (``_agreement.choose_attempt``). None: most views, then
            most points.

    Raises RuntimeError when no model at all could be built (the caller turns it into an input error
    naming the images).
    """
    import pycolmap

    opts = opts or ColmapOptions()
    arm_of = {n: a for a, ai in arms.items() for n in ai.names}
    n_images = len(arm_of)
    fixed = all(intrinsics.get(a) is not None for a in arms)
    pycolmap.set_random_seed(opts.seed)
    attempts: list[Attempt] = []
    candidates: list[tuple[int, tuple, object]] = []  # (attempt index, _score, pycolmap.Reconstruction)
    best_score = None
    with contextlib.ExitStack() as stack:
        if workdir is None:
            workdir = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="bijcr-colmap-")))
        workdir = Path(workdir)
        workdir.mkdir(parents=True, exist_ok=True)
        stack.enter_context(_colmap_log(opts.verbose))
        db = None
        for round_ in _feature_rounds(opts):
            fname = round_[0]
            if _ladder_done(best_score, fname, n_images, opts):
                break
            db = _features_and_matches(db, workdir, root, arms, intrinsics, n_images, round_, opts, log)
            for cfg in _mapper_configs(opts):
                att, top = _mapper_attempt(db, root, workdir, f"{fname}/{cfg[0]}", cfg, fixed, opts, arms, arm_of,
                                           check, agree, log)
                attempts.append(att)
                if top is None:
                    continue
                candidates.append((len(attempts) - 1, top[0], top[1]))
                if best_score is None or top[0] > best_score:
                    best_score = top[0]
                if top[0][1] == n_images:  # this database registers all: stop relaxing
                    break
        if not candidates:
            raise RuntimeError("COLMAP could not build any model (no image pair with enough verified matches)")
        pick = _pick_candidate(candidates, attempts)
        best_name = attempts[candidates[pick][0]].name
        model = _to_sparse(candidates[pick][2], check)
    model.attempts, model.chosen = attempts, best_name
    return model


def _agreement_of(rec, check: Check | None, agree: Agree) -> dict:
    """``agree`` on the registered views of ``rec`` that pass ``check``."""
    ids, names, T = _poses(rec)
    bad = check(names, T) if check is not None and ids else np.zeros(len(ids), bool)
    keep = np.flatnonzero(~np.asarray(bad, bool))
    return agree([names[k] for k in keep], T[keep])

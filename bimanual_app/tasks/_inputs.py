"""What a task needs, found or produced: calibration, metric cloud, segments and grasps of one scene.

:func:`ensure_stages` runs the earlier stages (``calibrate``, ``segment``, ``grasp``: the library calls of
their ``bijcr`` sub-commands) when their outputs are missing, timing each; :func:`load_inputs` reads them and refuses a
calibration that belongs to another scene (name, number of views, and the camera poses it implies).
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bimanual_app.io_utils import InputError, Problem
from bimanual_app.transforms import check_T, rotation_angle_between

__all__ = ["StagePaths", "TaskInputs", "stage_paths", "ensure_stages", "load_inputs", "check_calibration_scene"]

# A calibration whose implied camera poses are further than this from the reconstruction's (median over
# the registered views) is not a calibration of this capture.
MAX_VIEW_ROT_DEG = 10.0
MAX_VIEW_TRANS_M = 0.05


@dataclass
class StagePaths:
    """Where each earlier stage writes inside the work folder."""

    work: Path
    calibration: Path
    cloud: Path
    segments: Path
    grasps: Path

    def argv(self, scene: Path, masks: bool | None = None) -> dict[str, list[str]]:
        """The ``bijcr`` command lines equal to each stage (shown to the user, who may run one by hand;
        :func:`ensure_stages` makes the same library calls).

        ``masks``: segment with the scene's per-image masks (``--masks``); None: when the scene has a
        ``masks`` folder, as ``bijcr run`` does.
        """
        from bimanual_app.app.stages import scene_has_masks

        cal_dir, seg_dir, grasp_dir = self.calibration.parent, self.segments.parent, self.grasps.parent
        scene = Path(scene)
        if masks is None:
            masks = scene_has_masks(scene)
        return {
            "calibrate": ["calibrate", str(scene), "--out", str(cal_dir)],
            "segment": ["segment", str(self.cloud), "--out", str(seg_dir)] + (["--masks", str(scene)] if masks else []),
            "grasp": ["grasp", str(self.cloud), "--segments", str(self.segments), "--calibration",
                      str(self.calibration), "--out", str(grasp_dir)],
        }


def stage_paths(work: str | Path) -> StagePaths:
    w = Path(work)
    return StagePaths(w, w / "calibration" / "calibration.json", w / "calibration" / "scene_b1.ply",
                      w / "segments" / "segments.npz", w / "grasps" / "grasps.json")


def ensure_stages(scene_path: Path, paths: StagePaths, timings: dict[str, float], quiet: bool = False,
                  scene=None, masks: bool | None = None, leave_out: tuple = ()) -> list[str]:
    """Run ``calibrate`` / ``segment`` / ``grasp`` in-process for each missing output; returns the stages run.

    Each is the library call of its ``bijcr`` sub-command (:mod:`bimanual_app.app.stages`). ``timings``
    receives the seconds of each stage run now (``calibrate``, ``segment``, ``grasp``); ``masks`` as in
    :meth:`StagePaths.argv`. A calibration present but made for another scene is refused *before*
    anything downstream runs on it. Raises InputError naming the stage, its output and its error when a
    stage fails; KeyboardInterrupt propagates.
    """
    from functools import partial

    from bimanual_app.app import stages as S

    argv = paths.argv(scene_path, masks)
    use_masks = Path(scene_path) if "--masks" in argv["segment"] else None
    steps = [("calibrate", [paths.calibration, paths.cloud],
              partial(S.calibrate, Path(scene_path), paths.calibration.parent)),
             ("segment", [paths.segments], partial(S.segment, paths.cloud, paths.segments.parent, paths.calibration,
                                                   use_masks, progress=not quiet)),
             ("grasp", [paths.grasps], partial(S.grasp, paths.cloud, paths.segments, paths.calibration,
                                               paths.grasps.parent, leave_out=leave_out))]
    ran = []
    for name, outputs, run in steps:
        if name == "segment" and scene is not None and paths.calibration.exists():
            # never segment / grasp a cloud made by another scene's calibration
            check_calibration_scene(scene, _read_calibration(paths.calibration), paths.calibration)
        if all(o.exists() for o in outputs):
            continue
        if not quiet:
            print(f"task: running `bijcr {' '.join(argv[name])}` ({', '.join(o.name for o in outputs)} missing)",
                  file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        _run_stage(name, run, outputs, argv[name], quiet)
        timings[name] = time.perf_counter() - t0
        ran.append(name)
    return ran


def _run_stage(name: str, run, outputs: list[Path], argv: list[str], quiet: bool) -> None:
    """One earlier stage; InputError naming it, its output and its error when it fails."""
    from bimanual_app.app.pipeline import StageFailure

    fix = f"fix the problem above, or run `bijcr {' '.join(argv)}` by hand"
    try:
        run((lambda m: None) if quiet else (lambda m: print(m, file=sys.stderr, flush=True)))
    except (InputError, StageFailure) as e:
        raise InputError(Problem(str(outputs[0]), name, f"the '{name}' stage failed: " + " | ".join(str(e).splitlines()),
                                 fix)) from None
    missing = [str(o) for o in outputs if not o.exists()]
    if missing:
        raise InputError(Problem(str(outputs[0]), name, f"the '{name}' stage did not write {', '.join(missing)}", fix))


def _read_calibration(path: Path) -> dict:
    try:
        cal = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise InputError(Problem(str(path), "", f"cannot read calibration: {e}",
                                 "re-run `bijcr calibrate SCENE --out DIR`")) from None
    if not isinstance(cal, dict):
        raise InputError(Problem(str(path), "", "not a calibration object", "re-run `bijcr calibrate`"))
    return cal


def _T(cal: dict, key: str, path: Path) -> np.ndarray:
    try:
        return check_T(key, np.asarray(cal[key], dtype=np.float64))
    except KeyError:
        raise InputError(Problem(str(path), key, "missing", "re-run `bijcr calibrate`")) from None
    except (ValueError, TypeError) as e:
        raise InputError(Problem(str(path), key, f"not a valid 4x4 transform: {e}", "re-run `bijcr calibrate`")) from None


def check_calibration_scene(scene, cal: dict, path: Path) -> None:
    """Refuse a calibration made for another scene.

    Checks: ``scene`` equals scene.yaml's ``name``; ``views_used`` per arm is at most that arm's rows;
    and when the scene has a reconstruction, the camera poses the calibration implies for each registered
    primary and secondary view (``T_b1_w @ P(scale)`` against ``T_b1_b @ T_b_e @ T_e_c``) agree with the
    arm poses to within 10 degrees / 5 cm (median): a calibration of another capture does not.
    """
    problems = []
    name = cal.get("scene")
    if name != scene.name:
        problems.append(Problem(str(path), "scene", f"this calibration is for scene {name!r}, not {scene.name!r}"
                                f" ({scene.path / 'scene.yaml'})",
                                "calibrate this scene (delete the work folder's calibration/ or pass --work DIR)"))
    used = cal.get("views_used") or {}
    for arm in scene.arms:
        n = used.get(arm.name)
        if isinstance(n, (int, float)) and n > len(arm):
            problems.append(Problem(str(path), f"views_used.{arm.name}",
                                    f"uses {int(n)} views but {arm.name}/ee_poses.csv has {len(arm)} rows",
                                    "calibrate this scene (the calibration comes from another capture)"))
    if problems:
        raise InputError(problems)
    rec = scene.reconstruction
    if rec is None or "scale" not in cal:
        return
    scale = float(cal["scale"])
    T_b1_w = _T(cal, "T_b1_w", path)
    T_b1_b2 = _T(cal, "T_b1_b2", path)
    rot, trans = [], []
    for arm, X_key, T_b1_b in ((scene.primary, "T_e1_c1", np.eye(4)), (scene.secondary, "T_e2_c2", T_b1_b2)):
        X = _T(cal, X_key, path)
        csv_rows, rec_rows = rec.rows_for(arm.index, arm.images)
        if len(csv_rows) == 0:
            continue
        P = np.array(rec.T_w_c[rec_rows], dtype=np.float64)
        P[:, :3, 3] *= scale  # P(s): metric camera poses, as calibration defines T_b_w = T_b_e X P(s)^-1
        T_cal = T_b1_w @ P
        T_arm = T_b1_b @ arm.T_b_e[csv_rows] @ X
        rot.append(np.degrees(rotation_angle_between(T_cal[:, :3, :3], T_arm[:, :3, :3])))
        trans.append(np.linalg.norm(T_cal[:, :3, 3] - T_arm[:, :3, 3], axis=1))
    if not rot:
        return
    r, t = float(np.median(np.concatenate(rot))), float(np.median(np.concatenate(trans)))
    if r > MAX_VIEW_ROT_DEG or t > MAX_VIEW_TRANS_M:
        raise InputError(Problem(str(path), "T_b1_w",
                                 f"the calibration does not fit this scene's views (median camera pose error "
                                 f"{r:.1f} deg, {t * 100:.1f} cm; a calibration of this capture is within "
                                 f"{MAX_VIEW_ROT_DEG:.0f} deg / {MAX_VIEW_TRANS_M * 100:.0f} cm): it was made "
                                 "from another capture",
                                 "calibrate this scene (delete the work folder's calibration/ or pass --work DIR)"))


@dataclass
class TaskInputs:
    """Everything a task plans with.

    Attributes:
        scene: the loaded :class:`bimanual_app.scene.Scene`.
        calibration: calibration.json's content.
        T_b1_b2: (4,4) secondary base in b1 (calibrated).
        points: (N,3) metric cloud in b1; labels: (N,) int32 segment labels.
        seg_extras: other arrays of segments.npz (boxes, table plane, ...).
        grasps: grasps.json's content.
        paths: the stage paths.
    """

    scene: object
    calibration: dict
    T_b1_b2: np.ndarray
    points: np.ndarray
    labels: np.ndarray
    seg_extras: dict
    grasps: dict
    paths: StagePaths
    warnings: list[str] = field(default_factory=list)


def load_inputs(scene, paths: StagePaths) -> TaskInputs:
    """Read calibration, cloud, segments and grasps; check they belong together and to ``scene``."""
    from segmentation import read_cloud

    cal = _read_calibration(paths.calibration)
    check_calibration_scene(scene, cal, paths.calibration)
    T_b1_b2 = _T(cal, "T_b1_b2", paths.calibration)
    points = read_cloud(paths.cloud)[0]
    try:
        with np.load(paths.segments, allow_pickle=False) as z:
            seg = {k: z[k] for k in z.files}
    except (OSError, ValueError) as e:
        raise InputError(Problem(str(paths.segments), "", f"cannot read segments: {e}",
                                 "re-run `bijcr segment`")) from None
    if "labels" not in seg:
        raise InputError(Problem(str(paths.segments), "labels", "missing", "re-run `bijcr segment`"))
    labels = np.asarray(seg.pop("labels")).astype(np.int64).reshape(-1)
    if len(labels) != len(points):
        raise InputError(Problem(str(paths.segments), "labels",
                                 f"{len(labels)} labels for a cloud of {len(points)} points ({paths.cloud})",
                                 "re-run `bijcr segment` on this cloud"))
    try:
        grasps = json.loads(paths.grasps.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise InputError(Problem(str(paths.grasps), "", f"cannot read grasps: {e}", "re-run `bijcr grasp`")) from None
    return TaskInputs(scene, cal, T_b1_b2, points, labels, seg, grasps, paths)

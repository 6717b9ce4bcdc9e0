"""The pipeline's stages as library calls, shared by ``bijcr run`` and ``bijcr task`` (which produces the
earlier stages' results it is missing). Each runs the same function as its ``bijcr`` sub-command, writes
the same files, sends the lines that command prints to ``log``, and raises its typed errors (InputError,
DegenerateCaptureError, :class:`~bimanual_app.app.pipeline.StageFailure`) instead of printing them.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

__all__ = ["scene_has_masks", "reconstruct", "calibrate", "segment", "grasp", "task"]

Log = Callable[[str], None]


def scene_has_masks(scene: str | Path) -> bool:
    """Whether the scene has per-image masks (a user's, or a synthetic scene's renders): extra evidence
    the segmenter uses by default."""
    return any((Path(scene) / arm / "masks").is_dir() for arm in ("primary", "secondary"))


def _lines(log: Log, lines: list[str]) -> None:
    for line in lines:
        log(line)


def reconstruct(scene: Path, backend: str, log: Log) -> None:
    """``bijcr reconstruct SCENE --backend BACKEND``: SCENE/reconstruction.npz."""
    from bimanual_app.reconstruction import reconstruct as run

    res = run(scene, backend=backend, log=log)
    log(f"wrote {res.path} (model '{res.reconstruction.model}', {len(res.reconstruction)} views)")


def calibrate(scene: Path, out: Path, log: Log) -> None:
    """``bijcr calibrate SCENE --out OUT``: calibration.json, scene_b1.ply, figures, ROS exports."""
    import time

    from calibration import calibrate_stage
    from calibration.cli import report_lines

    t0 = time.perf_counter()
    st = calibrate_stage(scene, out, log=lambda m: log(f"[{time.perf_counter() - t0:5.2f} s] calibrate: {m}"))
    _lines(log, report_lines(st))


def segment(cloud: Path, out: Path, calibration: Path, masks: Path | None, log: Log, progress: bool = True) -> None:
    """``bijcr segment CLOUD --out OUT --calibration JSON [--masks SCENE]``: segments.npz / .json / .png.
    ``progress``: the segmenter's own progress lines on stderr."""
    from segmentation import segment_stage
    from segmentation.cli import report_lines

    _lines(log, report_lines(segment_stage(cloud, out, calibration=calibration, masks=masks, progress=progress)))


def grasp(cloud: Path, segments: Path, calibration: Path, out: Path, log: Log, leave_out: tuple = ()) -> None:
    """``bijcr grasp CLOUD --segments NPZ --calibration JSON --out OUT``: grasps.json / .png (``leave_out``:
    hand-over fallbacks not to try, ``grasping.HANDOVER_FALLBACKS``)."""
    from grasping import grasp_stage
    from grasping.cli import report_lines

    st = grasp_stage(cloud, segments, out, calibration=calibration, log=lambda m: log(f"[grasp] {m}"),
                     leave_out=tuple(leave_out))
    _lines(log, [f"warning: {p}" for p in st.warnings] + report_lines(st))


def task(name: str, scene: Path, work: Path, out: Path, log: Log) -> None:
    """``bijcr task NAME SCENE --work WORK --out OUT``; StageFailure when the task does not succeed."""
    from bimanual_app.tasks import TaskOptions, run_task

    from .pipeline import StageFailure

    res = run_task(TaskOptions(task=name, scene=str(scene), work=str(work), out=str(out)))
    log(f"{name}: {'SUCCESS' if res.success else 'FAILED'} - {res.reason}")
    if res.object_id is not None:
        log(f"object {res.object_id}: {res.object_reason}")
    if not res.success:
        raise StageFailure(f"{name}: {res.reason}")

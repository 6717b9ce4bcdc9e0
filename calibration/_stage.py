"""The calibration stage as one library call: a scene folder in, the calibration's files out.

``bijcr calibrate``, ``bijcr run`` and ``bijcr task`` (when it produces a missing calibration) all call
:func:`calibrate_stage`; it raises typed errors (InputError and its DegenerateCaptureError) instead of
printing them, and returns what it made.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["CalibrationStage", "calibrate_stage", "require_torch"]


@dataclass
class CalibrationStage:
    """What :func:`calibrate_stage` made: the loaded scene, the result, the output folder and its files."""

    scene: object
    result: object
    out: Path
    files: dict = field(default_factory=dict)


def require_torch(method: str) -> None:
    """The ``paper`` method refines with PyTorch (the optional extra ``[paper]``): InputError naming the
    install command when it is missing. Other methods need no torch."""
    if method != "paper":
        return
    try:
        import torch  # noqa: F401
    except ImportError:
        from bimanual_app.io_utils import InputError, Problem

        raise InputError(Problem("command line", "--method", "the paper method refines with PyTorch, which is not "
                                 "installed", "pip install -e .[paper]  (or use the default --method absolute, "
                                 "which needs no torch)")) from None


def calibrate_stage(scene: str | Path, out: str | Path, method: str = "absolute", options=None,
                    conf_threshold: float | None = None, figure: bool = True,
                    log: Callable[[str], None] | None = None, confirm_unsure: bool = False) -> CalibrationStage:
    """Calibrate the scene folder ``scene`` and write calibration.json, scene_b1.ply, the figures and the
    ROS exports into ``out``.

    The output folder is checked before anything is read or computed. ``options``: CalibrationOptions
    (default: the defaults); ``log``: progress lines; ``confirm_unsure``: keep the unsure points other views
    confirm, flagged in the cloud (:func:`~calibration._api.write_outputs`). Raises InputError (a bad scene or output folder, the
    paper method without torch) or DegenerateCaptureError (views that do not determine the calibration).
    """
    from threadpoolctl import threadpool_limits

    from bimanual_app.io_utils import check_output_dir
    from bimanual_app.scene import load_scene

    from ._api import calibrate, write_outputs
    from ._figures import FigureWorker

    log = log or (lambda msg: None)
    out = check_output_dir(out)
    require_torch(method)
    sc = load_scene(scene)
    log(f"loaded scene '{sc.name}'")
    # BLAS on one thread: the stage's products are (N, 3) x (3, 3) and small dense systems, for which
    # OpenBLAS's threads cost far more to start and synchronise than they give (on a busy 2-core machine
    # an (N, 3) x (3, 3) product of the cloud took 100 ms instead of 2 ms); each product is the same sum
    # either way. The figures' process starts now: it loads matplotlib while the solve runs (_figures.py).
    with threadpool_limits(limits=1, user_api="blas"), FigureWorker(parallel=figure) as figures:
        result = calibrate(sc, method=method, options=options, progress=log)
        pm = result.info.get("point_maps")
        log(f"joint solve in {result.info['time_total_s']:.3f} s"
            + (f", point-map refinement in {pm['time_s']:.1f} s" if pm else ""))
        files = write_outputs(out, sc, result, conf_threshold=conf_threshold, figure=figure, log=log,
                              figures=figures, confirm_unsure=confirm_unsure)
    return CalibrationStage(sc, result, out, files)

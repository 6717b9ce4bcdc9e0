"""When a point-map estimate is still a correction of the pose-only solve it started from.

The point-map estimators (the joint estimate, ``_estimate``; the refinement, ``_pointmap_refine``) start from
the pose-only solve and are refused when they move an output further than a correction would. How far a
correction may go depends on how well the pose-only solve pinned that output: a capture of many views pins
the hand-eyes to millimetres, one of 4-5 views per arm with a foundation model's pose noise leaves them
uncertain by centimetres, and the point maps then rightly move them that far. So each output's limit is the
larger of a fixed floor (the limits these estimators always had) and ``CORRECTION_SIGMAS`` times the pose-only
solve's own 1-sigma uncertainty of it (docs/calibration.md, "Past the paper").
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

#: the floors: changes up to these are corrections whatever the pose-only solve's uncertainty
MAX_ROT_CHANGE_DEG = 5.0
MAX_TRANS_CHANGE_M = 0.05
MAX_LOG_SCALE_CHANGE = 0.1
#: beyond the floors a change is a correction while it stays within this many of the pose-only solve's
#: sigmas. Those sigmas are honest (RMS of error / sigma 1.1, largest 3.1 over 118 studied few-view scenes),
#: so a true correction, which undoes the pose-only error, stays within about 3 of them; 5 leaves room for a
#: sigma that is itself estimated from few views.
CORRECTION_SIGMAS = 5.0
#: the outputs judged, each a (4, 4) transform of the estimate's state
TRANSFORMS = ("T_e1_c1", "T_e2_c2", "T_b1_b2")


def correction_limits(uncertainty: Mapping | None) -> dict:
    """How far the point maps may move each output: ``{name: (rotation deg, translation m)}`` for
    :data:`TRANSFORMS` and ``"log_scale"``: the floors, raised to :data:`CORRECTION_SIGMAS` times the pose-only
    solve's 1-sigma (``CalibrationResult.uncertainty``: ``rotation_deg``, ``translation_norm_mm``, ``scale``
    ``percent``; ``inf`` where the views do not determine an output). Missing or empty: the floors."""
    u = uncertainty or {}
    k = CORRECTION_SIGMAS

    def raised(floor: float, sigma) -> float:
        return max(floor, k * float(sigma)) if sigma is not None else floor

    limits = {name: (raised(MAX_ROT_CHANGE_DEG, u.get(name, {}).get("rotation_deg")),
                     raised(MAX_TRANS_CHANGE_M, _mm_to_m(u.get(name, {}).get("translation_norm_mm"))))
              for name in TRANSFORMS}
    pct = u.get("scale", {}).get("percent")
    limits["log_scale"] = raised(MAX_LOG_SCALE_CHANGE, None if pct is None else np.log1p(float(pct) / 100.0))
    return limits


def _mm_to_m(v):
    return None if v is None else float(v) * 1e-3


def output_changes(before: Mapping, after: Mapping) -> dict:
    """``{name: (rotation deg, translation m)}`` for :data:`TRANSFORMS` and ``"log_scale"``: how far each output
    moved. ``before``, ``after``: the outputs by name (``T_e1_c1``, ``T_e2_c2``, ``T_b1_b2``: (4, 4); ``scale``)."""
    from bimanual_app.transforms import rotation_angle_between

    out = {}
    for name in TRANSFORMS:
        a, b = np.asarray(before[name], dtype=np.float64), np.asarray(after[name], dtype=np.float64)
        if a.shape != (4, 4) or b.shape != (4, 4):
            raise ValueError(f"{name}: expected (4, 4) transforms, got {a.shape} and {b.shape}")
        out[name] = (float(np.degrees(rotation_angle_between(a[:3, :3], b[:3, :3]))),
                     float(np.linalg.norm(a[:3, 3] - b[:3, 3])))
    out["log_scale"] = float(np.log(float(after["scale"]) / float(before["scale"])))
    return out


def beyond_correction(before: Mapping, after: Mapping, limits: Mapping, what: str) -> str | None:
    """Why ``after`` is no correction of ``before`` (``what`` names the estimate in the message), or None when
    every output moved within its limit (:func:`correction_limits`)."""
    moved = output_changes(before, after)
    over = [name for name in TRANSFORMS
            if moved[name][0] > limits[name][0] or moved[name][1] > limits[name][1]]
    if abs(moved["log_scale"]) > limits["log_scale"]:
        over.append("scale")
    if not over:
        return None
    name = over[0]
    if name == "scale":
        return (f"{what} would change the scale by {np.expm1(moved['log_scale']) * 100:+.1f} %, more than a "
                f"correction of the pose-only solve (at most {np.expm1(limits['log_scale']) * 100:.1f} %: "
                f"{CORRECTION_SIGMAS:g} of its sigmas, at least {np.expm1(MAX_LOG_SCALE_CHANGE) * 100:.1f} %)")
    rot, trans = moved[name]
    return (f"{what} would move {name} by {rot:.1f} deg / {trans * 1e3:.0f} mm, more than a correction of the "
            f"pose-only solve (at most {limits[name][0]:.1f} deg / {limits[name][1] * 1e3:.0f} mm: "
            f"{CORRECTION_SIGMAS:g} of its sigmas, at least {MAX_ROT_CHANGE_DEG:g} deg / "
            f"{MAX_TRANS_CHANGE_M * 1e3:.0f} mm)")

"""Is a capture rich enough to calibrate? Checks on the end-effector motions (exact: from the robot).

Hand-eye calibration from ``AX = XB`` needs relative rotations about at least two different axes: with
rotations about one axis only, the camera offset along that axis is not observable (any value fits), and
with too little rotation the rotation itself drowns in noise. The shared scale needs the cameras to move
(translate). Each finding says why and which extra pose would fix it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# thresholds (degrees / metres); "error" means the answer would be arbitrary, "warning" poorly determined
MIN_VIEWS = 3
MIN_ROTATION_ERROR_DEG = 2.0
MIN_ROTATION_WARN_DEG = 10.0
AXIS_SPREAD_ERROR = 0.03   # sqrt(lambda2 / lambda1) of the rotation-axis scatter: ~2 deg of axis spread
AXIS_SPREAD_WARN = 0.10    # ~6 deg
MIN_TRAVEL_ERROR_M = 0.005  # both arms below: the scale is not observable
MIN_TRAVEL_WARN_M = 0.03


@dataclass(frozen=True)
class Finding:
    """One degeneracy: ``severity`` is "error" or "warning"; ``code`` a short id."""

    arm: str
    severity: str
    code: str
    message: str
    fix: str


def _fmt(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{x:+.2f}" for x in v) + "]"


def analyse_arm(name: str, T_b_e: np.ndarray) -> list[Finding]:
    """Degeneracy findings for one arm's end-effector poses (N, 4, 4) (the views in use)."""
    n = len(T_b_e)
    out: list[Finding] = []
    if n < MIN_VIEWS:
        out.append(Finding(name, "error", "too_few_views",
                           f"{n} usable view(s) of the {name} arm; at least {MIN_VIEWS} are needed (6 or more recommended)",
                           f"capture {MIN_VIEWS - n} or more extra {name} views whose wrist orientation differs by 20-40 deg "
                           "about different axes, then re-run the reconstruction"))
        return out
    from bimanual_app.transforms import inv_T, so3_log

    i, j = np.triu_indices(n, 1)
    A = inv_T(T_b_e[i]) @ T_b_e[j]
    a = so3_log(A[:, :3, :3])  # axes in the end-effector frame
    ang = np.linalg.norm(a, axis=1)
    max_deg = float(np.rad2deg(ang.max()))
    if max_deg < MIN_ROTATION_WARN_DEG:
        sev = "error" if max_deg < MIN_ROTATION_ERROR_DEG else "warning"
        out.append(Finding(name, sev, "too_little_rotation",
                           f"the {name} end effector rotates at most {max_deg:.1f} deg between views: the camera rotation "
                           "and offset are " + ("not determined" if sev == "error" else "poorly determined"),
                           f"add {name} poses whose wrist orientation differs from the others by 20-40 deg, about two "
                           "different axes (e.g. tilt the gripper forward/back and left/right)"))
        if sev == "error":
            return out
    S = a.T @ a  # scatter of the rotation vectors (weights each pair by its angle^2)
    lam, V = np.linalg.eigh(S)
    spread = float(np.sqrt(max(lam[1], 0.0) / max(lam[2], 1e-300)))
    if spread < AXIS_SPREAD_WARN:
        sev = "error" if spread < AXIS_SPREAD_ERROR else "warning"
        axis, perp = V[:, 2], V[:, 1]
        out.append(Finding(name, sev, "single_axis",
                           f"all {name} motions rotate about nearly one axis {_fmt(axis)} of the end-effector frame "
                           f"(axis spread {np.rad2deg(np.arcsin(min(spread, 1.0))):.1f} deg): the camera offset along "
                           "that axis is " + ("not observable" if sev == "error" else "poorly determined"),
                           f"add a {name} pose rotated by 20-40 deg about an axis perpendicular to it, e.g. about "
                           f"{_fmt(perp)} of the end-effector frame (tilt the wrist instead of only turning it)"))
    travel = camera_travel(T_b_e)
    if travel < MIN_TRAVEL_WARN_M:
        out.append(Finding(name, "warning", "little_travel",
                           f"the {name} end effector stays within {travel * 1000:.0f} mm of one point: this arm adds "
                           "little to the metric scale",
                           f"add {name} poses 10-20 cm apart (move the wrist around the workspace, not only rotate it)"))
    return out


def camera_travel(T_b_e: np.ndarray) -> float:
    """Largest distance (m) of an end-effector position from their mean."""
    return float(np.linalg.norm(T_b_e[:, :3, 3] - T_b_e[:, :3, 3].mean(0), axis=1).max()) if len(T_b_e) else 0.0


def analyse_capture(arms: dict[str, np.ndarray]) -> list[Finding]:
    """Findings of every arm (name -> (N, 4, 4) end-effector poses) plus the joint scale check."""
    out = [f for name, T in arms.items() for f in analyse_arm(name, T)]
    if all(camera_travel(T) < MIN_TRAVEL_ERROR_M for T in arms.values()):
        out.append(Finding("both", "error", "no_travel",
                           "neither end effector moves more than "
                           f"{MIN_TRAVEL_ERROR_M * 1000:.0f} mm: the metric scale cannot be determined",
                           "add poses 10-20 cm apart on at least one arm (move the wrist, not only rotate it)"))
    return out

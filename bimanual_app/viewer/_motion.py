"""Replaying a task plan: which gripper holds the object when, and where the object is at time t.

The plan (plan.npz) gives joint angles and gripper widths; task.json gives the phases. A gripper takes
hold of the object at the end of a closing phase it takes part in (``grasp``, ``close``, ``squeeze``,
``receive-grasp``: the names ``bimanual_app.tasks`` gives them) and lets go at the start of a ``release``
phase it takes part in. While held, the object moves rigidly with its holder's gripper frame; when one
gripper lets go and another still holds it (the hand-over), the other carries on from where it is.
Pure functions of the phases and a gripper-pose function, so they are tested without a 3D view.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bimanual_app.transforms import inv_T

from ._types import PhaseSpan

__all__ = ["GRAB_PHASES", "RELEASE_PHASES", "Hold", "hold_intervals", "object_track", "object_pose", "gripper_poses"]

GRAB_PHASES = ("grasp", "close", "squeeze", "receive-grasp")
RELEASE_PHASES = ("release",)

PoseFn = Callable[[str, float], np.ndarray]  # (arm, t) -> T_b1_g (4, 4)


@dataclass(frozen=True)
class Hold:
    """From ``t0`` to ``t1`` the object is at ``pose_fn(arm, t) @ T_g_o`` (``T_g_o``: (4, 4))."""

    t0: float
    t1: float
    arm: str
    T_g_o: np.ndarray


def hold_intervals(phases: list[PhaseSpan]) -> dict[str, list[tuple[float, float]]]:
    """Arm -> ``[(t_grab, t_release), ...]`` on the plan's clock (``inf`` when it never lets go)."""
    out: dict[str, list[tuple[float, float]]] = {}
    since: dict[str, float] = {}
    for ph in phases:
        for arm in ph.arms:
            if ph.name in RELEASE_PHASES and arm in since:
                out.setdefault(arm, []).append((since.pop(arm), ph.t0))
        for arm in ph.arms:
            if ph.name in GRAB_PHASES and arm not in since:
                since[arm] = ph.t1
    for arm, t0 in since.items():
        out.setdefault(arm, []).append((t0, float("inf")))
    return out


def object_track(phases: list[PhaseSpan], pose_fn: PoseFn) -> list[Hold]:
    """The object's carried spans in time order; between them it stays where the last one left it (at
    rest, the identity, before the first)."""
    holds = hold_intervals(phases)

    def holding(arm: str, t: float) -> bool:
        return any(a <= t < b for a, b in holds.get(arm, []))

    times = sorted({t for iv in holds.values() for span in iv for t in span if np.isfinite(t)})
    track: list[Hold] = []
    cur, T_o = None, np.eye(4)
    for t in times:
        if cur is not None:
            T_o = pose_fn(cur.arm, t) @ cur.T_g_o
            if holding(cur.arm, t):
                continue  # another gripper closing on the object does not take it over
            track.append(Hold(cur.t0, t, cur.arm, cur.T_g_o))
            cur = None
        arm = next((a for a in sorted(holds) if holding(a, t)), None)
        if arm is not None:
            cur = Hold(t, float("inf"), arm, inv_T(pose_fn(arm, t)) @ T_o)
    if cur is not None:
        track.append(cur)
    return track


def object_pose(track: list[Hold], pose_fn: PoseFn, t: float) -> np.ndarray:
    """(4, 4) the object's rigid motion from where it lies at the start (b1 -> b1) at time ``t``."""
    T = np.eye(4)
    for h in track:
        if t < h.t0:
            break
        end = min(t, h.t1)
        T = pose_fn(h.arm, end) @ h.T_g_o
    return T


def gripper_poses(robot, T_b1_b: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Gripper frames g in b1: ``T_b1_b @ fk(q) @ T_e_g`` for q (J,) -> (4, 4) or (N, J) -> (N, 4, 4)."""
    T_e_g = robot.T_e_g if robot.T_e_g is not None else np.eye(4)
    return T_b1_b @ robot.fk(q) @ T_e_g

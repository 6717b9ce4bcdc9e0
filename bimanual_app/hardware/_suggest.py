"""Capture viewpoints that make the calibration well conditioned (``bijcr capture --suggest``).

Hand-eye calibration (AX = XB, and Bi-JCR's joint form of it) is well conditioned when the motions
between views are large rotations about *different* axes (Tsai & Lenz 1989; Shah et al. 2012): with
parallel rotation axes the camera offset along that axis is unobservable, with small angles the noise
dominates. The views must also all see the same table region (the reconstruction needs overlap).

Method:

1. candidate tool poses: the tool point (``gripper_tcp``, the wrist camera's approximate viewpoint) on a
   spherical cap above a point of the table region (a disc around the target), its approach axis (z)
   pointing at that point, with varied azimuth, elevation, distance and roll about the viewing axis;
2. inverse kinematics for each (the project's ``bimanual_app.kinematics.IKSolver``, seeded from the ready
   pose); keep solutions that pass the joint (with a margin) and workspace checks;
3. greedy selection: start from the most central view, then repeatedly add the candidate that keeps every
   pairwise rotation above ``min_angle_deg`` and maximises its rotation angle to the nearest chosen view
   (farthest-point sampling on SO(3)) plus the spread of the relative rotation axes (the smallest
   eigenvalue of the mean of ``a a^T`` over the unit axes ``a`` of all pairwise relative rotations);
4. order the views for a short capture (largest joint travel per move; nearest neighbour + 2-opt from
   the view nearest the ready pose) and check every move between consecutive views.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bimanual_app.transforms import make_T, rotation_angle, so3_exp, so3_log

from ._limits import SafetyLimits
from ._poses import PoseList
from ._trajectory import joint_move

__all__ = ["Suggestion", "suggest_viewpoints", "conditioning"]


@dataclass
class Suggestion:
    """Suggested viewpoints.

    Attributes:
        q: (N, 6) joint poses (rad), capture order.
        T_b_t: (N, 4, 4) tool-point poses in the base frame (z axis looks at the target).
        target: (3,) target point in the base frame (m).
        min_angle_deg: smallest rotation between any two views.
        axis_spread: smallest eigenvalue of the mean ``a a^T`` over relative rotation axes (1/3 = isotropic).
        candidates: how many candidate viewpoints had an IK solution.
    """

    q: np.ndarray
    T_b_t: np.ndarray
    target: np.ndarray
    min_angle_deg: float
    axis_spread: float
    candidates: int

    def as_pose_list(self, arm: str = "primary", robot: str = "piper", limits: SafetyLimits | None = None) -> PoseList:
        names = [f"view_{i:02d}" for i in range(len(self.q))]
        c = [f"Suggested by 'bijcr capture --suggest' for the {arm} arm ({robot}): {len(self.q)} views whose tool",
             f"axis looks at ({self.target[0]:.2f}, {self.target[1]:.2f}, {self.target[2]:.2f}) m in the arm's base frame.",
             f"Smallest rotation between two views {self.min_angle_deg:.1f} deg; rotation-axis spread "
             f"{self.axis_spread:.3f} (0 = all about one axis, 0.333 = isotropic).",
             "Check the camera sees the table region from each view before a long capture."]
        return PoseList(self.q.copy(), names, robot, 0.25, 0.5,
                        limits.workspace if limits is not None else None, None, "", c)


def conditioning(R: np.ndarray) -> tuple[float, float]:
    """(min pairwise rotation angle in degrees, axis spread) of rotations ``R`` (N, 3, 3)."""
    n = len(R)
    if n < 2:
        return 0.0, 0.0
    i, j = np.triu_indices(n, 1)
    rel = np.swapaxes(R[i], -1, -2) @ R[j]          # motions in the tool frame (what AX = XB sees)
    w = so3_log(rel)
    ang = np.linalg.norm(w, axis=-1)
    a = w / np.maximum(ang, 1e-12)[:, None]
    S = (a[:, :, None] * a[:, None, :]).mean(axis=0)
    return float(np.degrees(ang.min())), float(np.linalg.eigvalsh(S)[0])


def _look_rotation(eye: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    """R_b_t with z from ``eye`` towards ``target``, rolled by ``roll`` about z (x starts horizontal)."""
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross([0.0, 0.0, 1.0], z)
    if np.linalg.norm(x) < 1e-6:
        x = np.array([1.0, 0.0, 0.0])
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=1)
    return R @ so3_exp(np.array([0.0, 0.0, roll]))


def _short_tour(Q: np.ndarray, q_start: np.ndarray) -> list[int]:
    """Visiting order of configurations ``Q`` (N, J) with a short total move time, starting nearest to
    ``q_start``: nearest neighbour, then 2-opt. The cost of a move is its largest joint travel (a
    synchronised joint move takes time proportional to it)."""
    n = len(Q)
    C = np.abs(Q[:, None, :] - Q[None, :, :]).max(-1)
    tour = [int(np.argmin(np.abs(Q - q_start).max(-1)))]
    while len(tour) < n:
        rest = [j for j in range(n) if j not in tour]
        tour.append(min(rest, key=lambda j: C[tour[-1], j]))

    def length(t):
        return sum(C[a, b] for a, b in zip(t[:-1], t[1:]))

    improved = True
    while improved:  # 2-opt on an open path with a fixed start (n <= a few dozen: cheap)
        improved = False
        for i in range(1, n - 1):
            for k in range(i + 1, n):
                cand = tour[:i] + tour[i:k + 1][::-1] + tour[k + 1:]
                if length(cand) < length(tour) - 1e-9:
                    tour, improved = cand, True
    return tour


def _candidate_views(target: np.ndarray, n_candidates: int, rng: np.random.Generator, region_radius: float,
                     distance, elevation_deg, azimuth_deg, roll_deg) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stratified candidate views (deterministic for a seed): eye points (C, 3), looked-at points (C, 3) and
    (C, 3) rows of (azimuth, elevation, roll) in radians."""
    back = -target[:2] / max(np.linalg.norm(target[:2]), 1e-9)     # from the target towards the base
    u = np.array([back[0], back[1], 0.0])
    v = np.cross([0.0, 0.0, 1.0], u)
    k = np.arange(n_candidates)
    az = np.radians(azimuth_deg[0] + (azimuth_deg[1] - azimuth_deg[0]) * ((k * 0.618034 + rng.uniform()) % 1.0))
    el = np.radians(elevation_deg[0] + (elevation_deg[1] - elevation_deg[0]) * ((k * 0.754878 + rng.uniform()) % 1.0))
    dist = distance[0] + (distance[1] - distance[0]) * ((k * 0.569840 + rng.uniform()) % 1.0)
    roll = np.radians(roll_deg[0] + (roll_deg[1] - roll_deg[0]) * ((k * 0.865 + rng.uniform()) % 1.0))
    jitter_r = region_radius * np.sqrt(rng.uniform(size=n_candidates))
    jitter_a = rng.uniform(0, 2 * np.pi, size=n_candidates)
    look = target + np.stack([jitter_r * np.cos(jitter_a), jitter_r * np.sin(jitter_a), np.zeros(n_candidates)], 1)
    eyes = []
    for i in range(n_candidates):
        d = np.cos(el[i]) * (np.cos(az[i]) * u + np.sin(az[i]) * v) + np.sin(el[i]) * np.array([0.0, 0.0, 1.0])
        eyes.append(look[i] + dist[i] * d)
    return np.array(eyes).reshape(n_candidates, 3), look, np.stack([az, el, roll], axis=1)


def _reachable_views(solver, limits: SafetyLimits, link: str, lower: np.ndarray, upper: np.ndarray,
                     q_ready: np.ndarray, eyes: np.ndarray, looks: np.ndarray,
                     meta: np.ndarray) -> tuple[list, list, list]:
    """Joint poses, tool poses and (azimuth, elevation, roll) of the candidates with an IK solution inside the
    joint limits (with margin) and the workspace checks."""
    qs, Ts, kept = [], [], []
    for eye, look, m in zip(eyes, looks, meta):
        T_goal = make_T(_look_rotation(eye, look, m[2]), eye)
        res = solver.solve(T_goal, q_current=q_ready, n_solutions=4, max_seeds=8)
        q = None
        for cand in (res.solutions if res.success else []):
            if np.all(cand >= lower) and np.all(cand <= upper) and not limits.config_problems(cand[None], "q"):
                q = cand
                break
        if q is None:
            continue
        qs.append(q)
        Ts.append(limits.robot.fk_link(q, link))
        kept.append((m[0], m[1], m[2]))
    return qs, Ts, kept


def _pick_views(R: np.ndarray, meta: np.ndarray, views: int, elevation_deg, min_angle_deg: float) -> list[int]:
    """Greedy farthest-point selection on SO(3) of ``views`` of the rotations ``R`` (C, 3, 3), starting from the
    most central view; raises ``ValueError`` when too few are ``min_angle_deg`` apart."""
    # start: the most central view (small azimuth and roll, mid elevation)
    mid_el = np.radians(np.mean(elevation_deg))
    chosen = [int(np.argmin(np.abs(meta[:, 0]) + np.abs(meta[:, 2]) + np.abs(meta[:, 1] - mid_el)))]
    min_rad = np.radians(min_angle_deg)
    while len(chosen) < views:
        best, best_score = None, -np.inf
        for c in range(len(R)):
            if c in chosen:
                continue
            ang = rotation_angle(np.swapaxes(R[chosen], -1, -2) @ R[c])
            if ang.min() <= min_rad:
                continue
            _, spread = conditioning(R[chosen + [c]])
            score = float(ang.min()) + spread  # far from every chosen view, and varied axes
            if score > best_score:
                best, best_score = c, score
        if best is None:
            raise ValueError(f"cannot pick {views} views at least {min_angle_deg:.0f} deg apart from {len(R)} reachable "
                             "candidates: lower --views, or widen the ranges")
        chosen.append(best)
    return chosen


def _check_moves(q_sel: np.ndarray, limits: SafetyLimits) -> None:
    """Every move between consecutive views must stay within the limits."""
    for a, b in zip(q_sel[:-1], q_sel[1:]):
        move = joint_move(a, b, limits.velocity * 0.25, limits.velocity * 0.5)
        probs = limits.trajectory_problems(move)
        if probs:
            raise ValueError(f"the move between two suggested views leaves the limits: {probs[0]}")


def suggest_viewpoints(robot="piper", views: int = 8, target=(0.40, 0.0, 0.0), region_radius: float = 0.05,
                       distance=(0.15, 0.26), elevation_deg=(30.0, 75.0), azimuth_deg=(-45.0, 45.0),
                       roll_deg=(-90.0, 90.0), min_angle_deg: float = 25.0, limits: SafetyLimits | None = None,
                       look_link: str | None = None, n_candidates: int = 300, seed: int = 0,
                       joint_margin: float = 0.05) -> Suggestion:
    """Viewpoints for ``views`` captures that look at a table region from varied directions.

    Each view's tool axis looks at a point within ``region_radius`` of ``target`` (base frame, m), from
    ``distance`` metres away, at an elevation in ``elevation_deg`` above the table, an azimuth in
    ``azimuth_deg`` (0 = from the side of the target facing the arm's base, positive counter-clockwise
    seen from above; the Piper's wrist (joint 5 within +-70 deg) does not reach much beyond +-45 deg), and
    rolled about the viewing axis within ``roll_deg``. Raises ``ValueError`` when fewer than ``views``
    views meet ``min_angle_deg``.
    """
    if limits is None:
        limits = SafetyLimits.from_robot(robot)
    model = limits.robot
    link = look_link or getattr(model, "tcp_link", None) or model.ee_link
    rng = np.random.default_rng(seed)
    target = np.asarray(target, float)
    lower, upper = limits.lower + joint_margin, limits.upper - joint_margin
    eyes, looks, meta = _candidate_views(target, n_candidates, rng, region_radius, distance, elevation_deg,
                                         azimuth_deg, roll_deg)
    base_yaw = np.arctan2(target[1], target[0])
    from bimanual_app.kinematics import IKSolver

    solver = IKSolver(model, link=link, seed=seed)
    q_ready = np.clip(np.array([base_yaw, 1.2, -0.8, 0.0, 0.4, 0.0]), lower, upper)
    qs, Ts, meta = _reachable_views(solver, limits, link, lower, upper, q_ready, eyes, looks, meta)
    if len(qs) < views:
        raise ValueError(f"only {len(qs)} reachable viewpoints of {n_candidates} candidates around target "
                         f"{target.tolist()} (need {views}): move the target closer to the arm or widen the ranges")
    qs, Ts, meta = np.array(qs), np.array(Ts), np.array(meta)
    R = Ts[:, :3, :3]
    chosen = _pick_views(R, meta, views, elevation_deg, min_angle_deg)
    order = [chosen[i] for i in _short_tour(qs[chosen], q_ready)]
    q_sel = qs[order]
    # every move between consecutive views (and the first from the arm's usual ready pose) must be valid
    _check_moves(q_sel, limits)
    m, spread = conditioning(R[order])
    return Suggestion(q_sel, Ts[order], target, m, spread, len(qs))

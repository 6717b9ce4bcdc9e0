"""Choose N capture viewpoints for one arm, as a careful operator would for hand-eye calibration.

Candidates look at the objects from 20-38 cm, 35-80 degrees above the table, from anywhere within
+-75 degrees of the arm's own side, with the camera rolled +-60 degrees about its axis. Each is solved
by IK, re-checked by forward kinematics, rejected when the arm or its camera comes within 1 cm of
anything (table, objects, the other arm, itself) or when the view shows too little of the table. From
the survivors (each must show at least two objects) a greedy farthest-point pass picks N views whose orientations are as far apart as possible
(rotations about different axes: what makes AX = XB well conditioned), then orders them into a short
joint-space path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bimanual_app.transforms import inv_T, rotation_angle_between

from ._camera import look_at

MIN_STATIC_FRACTION = 0.55  # share of a preview image that must show the table or objects
MIN_OBJECT_FRACTION = 0.04  # share that must show objects
SHOULDER_HEIGHT = 0.123  # Piper joint 2 above the base (m)
MAX_FLANGE_REACH = 0.62  # flange distance from the shoulder the Piper can reach (m): 0.285 + 0.251 + 0.091
EXTRA_CANDIDATES = 4  # when too few views are feasible, keep drawing up to this many times the budget
MIN_OBJECT_PIXELS = 12  # an object counts as seen with this many preview pixels (80 x 60); two must be seen
IK_ACCEPT = (5e-3, np.deg2rad(2.0))  # a start that stops short of the IK tolerance still counts within this


@dataclass
class View:
    """One chosen viewpoint of an arm.

    Attributes:
        q: (J,) joint angles; T_b_e: (4, 4) flange in the arm's base (forward kinematics of q);
        T_b1_c: (4, 4) camera in b1; ik_pos_err / ik_rot_err: IK residual to the requested pose (m, rad).
    """

    q: np.ndarray
    T_b_e: np.ndarray
    T_b1_c: np.ndarray
    ik_pos_err: float
    ik_rot_err: float
    object_fraction: float


def _candidate(rng: np.random.Generator, centre: np.ndarray, base_xy: np.ndarray, spread: float) -> np.ndarray:
    """A camera pose T_b1_c (4, 4) looking at the objects from the arm's side of the table."""
    target = centre + np.r_[rng.normal(scale=spread, size=2), rng.uniform(0.0, 0.05)]
    home = np.arctan2(*(base_xy - target[:2])[::-1])  # azimuth from the target towards the arm's base
    az = home + np.deg2rad(rng.uniform(-75.0, 75.0))
    el = np.deg2rad(rng.uniform(35.0, 80.0))
    r = rng.uniform(0.20, 0.38)
    eye = target + r * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return look_at(eye, target, roll=np.deg2rad(rng.uniform(-60.0, 60.0)))


def plan_views(world, arm: int, n_views: int, rng: np.random.Generator, centre: np.ndarray,
               max_candidates: int | None = None, preview_size: tuple[int, int] = (80, 60),
               K: np.ndarray | None = None, image_size: tuple[int, int] = (640, 480)) -> tuple[list[View], dict]:
    """N viewpoints for arm ``arm`` (0 primary, 1 secondary) of ``world``; the other arm stays parked.

    Args:
        centre: (3,) point in b1 the views centre on (the objects' centroid on the table).
        K: (3, 3) intrinsics of the full image (``image_size`` = width, height), scaled down to
            ``preview_size`` for the visibility check (None: no check).
    Returns:
        ``(views, stats)``: views in capture order; stats: candidates tried / reachable / collision-free /
        visible, and the minimum pairwise rotation between the chosen views (degrees).
    Raises:
        RuntimeError when fewer than ``n_views`` viewpoints are feasible after ``EXTRA_CANDIDATES`` times
        ``max_candidates`` draws (the budget is extended only while too few are feasible, so a layout that
        fills it draws exactly as many candidates as without the extension).
    """
    from bimanual_app.kinematics import IKSolver

    robot = world.robot
    solver = IKSolver(robot, link=robot.ee_link, max_iter=80)
    T_b1_b = world.T_b1_b[arm]
    T_b_b1 = inv_T(T_b1_b)
    T_c_e = inv_T(world.T_e_c[arm])
    base_xy = T_b1_b[:2, 3]
    world.set_arm(1 - arm, world.q_park)
    max_candidates = max_candidates or max(150, 40 * n_views)
    pw, ph = preview_size
    Kp = None
    if K is not None:
        sx, sy = pw / image_size[0], ph / image_size[1]
        Kp = np.array([[K[0, 0] * sx, 0.0, (K[0, 2] + 0.5) * sx - 0.5],
                       [0.0, K[1, 1] * sy, (K[1, 2] + 0.5) * sy - 0.5], [0.0, 0.0, 1.0]])
    stats = {"candidates": 0, "reachable": 0, "collision_free": 0, "visible": 0}
    feasible: list[View] = []
    target_pool = max(24, 6 * n_views)
    for i in range(EXTRA_CANDIDATES * max_candidates):
        if len(feasible) >= target_pool or (i >= max_candidates and len(feasible) >= n_views):
            break  # past the budget: keep drawing only while too few views are feasible (a far or crowded layout)
        stats["candidates"] += 1
        T_b1_c_want = _candidate(rng, centre, base_xy, spread=0.09)
        T_b_e_want = T_b_b1 @ T_b1_c_want @ T_c_e
        p = T_b_e_want[:3, 3]
        if np.linalg.norm(p - [0.0, 0.0, SHOULDER_HEIGHT]) > MAX_FLANGE_REACH:
            continue
        seeds = np.array([[np.arctan2(p[1], p[0]), 1.2, -1.2, 0.0, 0.6, 0.0],
                          [np.arctan2(p[1], p[0]), 1.8, -1.0, 0.0, -0.4, 0.0]])
        seeds = np.vstack([seeds, robot.random_q(3, rng, margin=0.2)])
        q, pe, re = _flange_ik(solver, T_b_e_want, seeds)
        if q is None:
            continue
        stats["reachable"] += 1
        T_b_e = world.set_arm(arm, q)
        if world.arm_collides(arm) is not None:
            continue
        stats["collision_free"] += 1
        T_b1_c = T_b1_b @ T_b_e @ world.T_e_c[arm]
        obj_frac = 1.0
        if Kp is not None:
            _, depth, seg = world.render(T_b1_c, Kp, pw, ph, shadows=False)
            static = np.isin(seg, world.static_ids[:1] + world.object_ids)
            obj_frac = float(np.isin(seg, world.object_ids).mean())
            n_seen = sum(int(np.count_nonzero(seg == b)) >= MIN_OBJECT_PIXELS for b in world.object_ids)
            if static.mean() < MIN_STATIC_FRACTION or obj_frac < MIN_OBJECT_FRACTION or n_seen < min(2, len(world.object_ids)):
                continue
        stats["visible"] += 1
        feasible.append(View(q, T_b_e, T_b1_c, pe, re, obj_frac))
    world.set_arm(arm, world.q_park)
    if len(feasible) < n_views:
        raise RuntimeError(f"arm {arm + 1}: only {len(feasible)} of {n_views} viewpoints are reachable, collision-free"
                           f" and see the table ({stats}); try another seed or fewer views")
    chosen = _farthest_rotations(feasible, n_views)
    ordered = _order_path([feasible[i] for i in chosen], world.q_park)
    R = np.array([v.T_b1_c[:3, :3] for v in ordered])
    ang = rotation_angle_between(R[:, None], R[None, :])
    stats["min_pair_rotation_deg"] = float(np.rad2deg(ang[~np.eye(len(R), dtype=bool)].min())) if len(R) > 1 else 0.0
    return ordered, stats


def _flange_ik(solver, T_b_e: np.ndarray, seeds: np.ndarray) -> tuple[np.ndarray | None, float, float]:
    """``(q (J,) or None, position error m, rotation error rad)``: the flange at ``T_b_e`` (4, 4) from the starts
    ``seeds`` (S, J), tried in order; the best attempt is taken when it is within ``IK_ACCEPT`` (the camera pose
    is re-derived from q by forward kinematics, so a view is where the arm really is)."""
    r = solver.solve(T_b_e, q_current=seeds[0], seeds=seeds[1:], max_seeds=len(seeds))
    q = r.q if r.success else r.best_attempt
    if q is None or r.pos_error > IK_ACCEPT[0] or r.rot_error > IK_ACCEPT[1]:
        return None, r.pos_error, r.rot_error
    return q, r.pos_error, r.rot_error


def _farthest_rotations(views: list[View], n: int) -> list[int]:
    """Indices of ``n`` views chosen greedily to maximise the smallest pairwise distance.

    Distance = rotation angle / 30 degrees + camera-centre distance / 50 cm (rotation dominates).
    The first pick is the view that sees the most of the objects.
    """
    R = np.array([v.T_b1_c[:3, :3] for v in views])
    t = np.array([v.T_b1_c[:3, 3] for v in views])
    D = rotation_angle_between(R[:, None], R[None, :]) / np.deg2rad(30.0)
    D = D + np.linalg.norm(t[:, None] - t[None, :], axis=-1) / 0.5
    chosen = [int(np.argmax([v.object_fraction for v in views]))]
    dmin = D[chosen[0]].copy()
    while len(chosen) < n:
        dmin[chosen] = -np.inf
        k = int(np.argmax(dmin))
        chosen.append(k)
        dmin = np.minimum(dmin, D[k])
    return chosen


def _order_path(views: list[View], q_start: np.ndarray) -> list[View]:
    """Nearest-neighbour tour in joint space from ``q_start`` (the operator's natural sweep)."""
    left = list(range(len(views)))
    out, q = [], q_start
    while left:
        k = min(left, key=lambda i: float(np.abs(views[i].q - q).max()))
        out.append(views[k])
        q = views[k].q
        left.remove(k)
    return out

"""Hand-over: the primary (giver) carries the object to a transfer pose both arms reach, the secondary
(receiver) grasps it there, and the giver lets go.

Transfer poses are tried in order of preference: the object's centre above the midpoint between the two
bases at ``heights`` above the table, then shifted sideways by ``offsets``; the object turned so that the
giver's approach points towards the secondary's base, tilted down by ``tilts``, and rolled about it by
``rolls``. The object moves rigidly with the giver's grasp, so for a transfer pose the giver's gripper is
that motion applied to its pick grasp; if the giver's arm reaches it only turned 180 degrees about its
approach (the gripper is symmetric), the object's transfer pose turns with it. Poses the primary is
predicted not to reach (its reach filter's ``prior``) are skipped before any IK.

Receiver grasps come from the object sampled in free space (its unseen bottom closed, approaches from
every side, no table), moved with the object. One is kept when its gripper -- open, along its approach
sweep -- stays ``gap`` away from the giver's closed gripper, the giver's retreat sweep stays ``gap`` away
from the receiver's closed gripper, the secondary reaches it (with its pre-grasp), and the two arms do not
collide. The first transfer pose with such a pair wins.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import zip_longest

import numpy as np

from bimanual_app.transforms import inv_T

from ._antipodal import GraspSet, rotate_about_approach
from ._arms import Arm, ArmGrasps, TwoArmCheck
from ._collision import GripperCollider, grippers_collide, grippers_distance
from ._objects import ObjectGeometry, Support

__all__ = ["HandoverParams", "Handover", "plan_handover"]


@dataclass(frozen=True)
class HandoverParams:
    """Transfer poses and checks (metres, radians).

    heights: the object's centre above the table. offsets: sideways from the line between the bases.
    tilts: the giver's approach, down from horizontal (0 = pointing at the secondary's base, pi/2 = down).
    rolls: turns of the object about the giver's approach.
    gap: least distance between the two grippers (and the giver's retreat sweep).
    givers: giver grasps tried (best first). receivers_checked: receiver grasps sent to the reach filter
    per transfer pose. prior_cut: transfer poses whose giver pose the primary is predicted not to reach
    (see ``ArmReach.prior``) are skipped.
    """

    heights: tuple[float, ...] = (0.25, 0.20, 0.30)
    offsets: tuple[float, ...] = (0.0, 0.06, -0.06)
    tilts: tuple[float, ...] = (0.0, np.pi / 4, np.pi / 3)
    rolls: tuple[float, ...] = (0.0, np.pi / 2, -np.pi / 2, np.pi)
    gap: float = 0.015
    givers: int = 3
    receivers_checked: int = 6
    prior_cut: float = 0.08
    max_transfer_checks: int = 24


@dataclass
class Handover:
    """A planned hand-over (all poses in b1).

    T_move: (4, 4) rigid motion taking the object from where it lies to the transfer pose.
    centre: (3,) the object's centre at the transfer pose.
    giver_index: index of the giver's grasp in the primary's reachable pick grasps.
    giver_T_b1_g: (4, 4) giver's gripper at the transfer pose; giver_q: (J,) its joints there.
    giver_width: the giver's closed width (the object's contact width).
    receiver: the receiver's grasp at the transfer pose: ``T_b1_g``, ``width``, ``contact_width``, ``score``,
        ``q``, ``q_pre``, ``index`` (in the free-space grasp set).
    gap: smallest distance between the two grippers when both hold the object (m).
    score: mean of the two grasp scores.
    """

    T_move: np.ndarray
    centre: np.ndarray
    giver_index: int
    giver_T_b1_g: np.ndarray
    giver_q: np.ndarray
    giver_width: float
    receiver: dict
    gap: float
    score: float
    tried: dict = field(default_factory=dict)


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)


def _align(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) taking unit vector a to unit vector b."""
    v = np.cross(a, b)
    s, c = float(np.linalg.norm(v)), float(a @ b)
    if s < 1e-9:
        if c > 0:
            return np.eye(3)
        perp = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
        return _axis_angle(perp / np.linalg.norm(perp), np.pi)
    return _axis_angle(v / s, float(np.arctan2(s, c)))


def _transfer_moves(geo: ObjectGeometry, support: Support, T_b1_b2: np.ndarray, G: np.ndarray,
                    p: HandoverParams) -> list[np.ndarray]:
    """Rigid motions (4, 4) of the object, in order of preference, for the giver's pick grasp ``G`` (4, 4)."""
    up = support.up
    o2 = T_b1_b2[:3, 3]
    mid = 0.5 * o2
    mid = mid - (mid @ up - support.height) * up  # on the table
    line = o2 - (o2 @ up) * up
    line /= max(np.linalg.norm(line), 1e-9)
    across = np.cross(up, line)
    zg = G[:3, 2]
    moves = []
    for h in p.heights:
        for off in p.offsets:
            target = mid + h * up + off * across
            for tilt in p.tilts:
                z_t = np.cos(tilt) * line - np.sin(tilt) * up
                R0 = _align(zg, z_t)
                for roll in p.rolls:
                    R = _axis_angle(z_t, roll) @ R0
                    T = np.eye(4)
                    T[:3, :3] = R
                    T[:3, 3] = target - R @ geo.centre
                    moves.append(T)
    return moves


def plan_handover(geo: ObjectGeometry, support: Support, giver: ArmGrasps, free: GraspSet, arms: dict[str, Arm],
                  collider: GripperCollider, check: TwoArmCheck | None, params: HandoverParams = HandoverParams()
                  ) -> tuple[Handover | None, dict]:
    """The first feasible hand-over (see the module docstring), or None; with counts of what was tried."""
    stats = {"transfer_poses": 0, "giver_reached": 0, "receiver_candidates": 0, "receiver_reached": 0}
    if len(giver) == 0 or len(free) == 0 or "secondary" not in arms:
        return None, stats
    prim, sec = arms["primary"], arms["secondary"]
    T_b2_b1 = inv_T(sec.T_b1_b)
    T_b_b1 = inv_T(prim.T_b1_b)
    # (giver, move) candidates in order of preference; those the primary is predicted not to reach go
    prior = getattr(prim.reach, "prior", None)
    per_giver = []
    for gi in range(min(params.givers, len(giver))):
        G = giver.grasps.T_b1_g[gi]
        moves = _transfer_moves(geo, support, sec.T_b1_b, G, params)
        if prior is not None:
            d = prior(np.stack([T_b_b1 @ M @ G for M in moves]))
            moves = [moves[k] for k in np.nonzero(d < params.prior_cut)[0]]
        per_giver.append([(gi, M) for M in moves])
    # round robin over the givers, so that each giver's preferred poses come early
    todo = [gm for rnd in zip_longest(*per_giver) for gm in rnd if gm is not None]
    for gi, T_move in todo[: params.max_transfer_checks]:
        stats["transfer_poses"] += 1
        G = giver.grasps.T_b1_g[gi]
        w_closed = float(giver.grasps.contact_width[gi])
        Gt = T_move @ G
        rg = prim.reach((T_b_b1 @ Gt)[None], np.array([giver.grasps.width[gi]]))
        if not rg.ok[0]:
            continue
        stats["giver_reached"] += 1
        move = T_move
        if rg.flipped[0]:
            Gt = rotate_about_approach(Gt)
            move = Gt @ inv_T(G)
        Rt = move @ free.T_b1_g
        order = np.arange(len(free))  # best score first ...
        rprior = getattr(sec.reach, "prior", None)
        if rprior is not None:  # ... within tiers of the secondary's predicted reach
            tiers = np.digitize(rprior(T_b2_b1 @ Rt), (0.05, 0.08, 0.12))
            order = np.concatenate([order[tiers == t] for t in range(3)])
        cands = []
        for k in order:
            if grippers_collide(collider, Gt, w_closed, Rt[k], free.width[k], margin=params.gap, swept2=True):
                continue
            if grippers_collide(collider, Gt, giver.grasps.width[gi], Rt[k], free.contact_width[k],
                                margin=params.gap, swept1=True):
                continue
            cands.append(int(k))
            if len(cands) >= params.receivers_checked:
                break
        stats["receiver_candidates"] += len(cands)
        if not cands:
            continue
        cands = np.array(cands)
        rr = sec.reach(T_b2_b1 @ Rt[cands], free.width[cands])
        for n, k in enumerate(cands):
            if not rr.ok[n]:
                continue
            stats["receiver_reached"] += 1
            R_used = Rt[k] if not rr.flipped[n] else rotate_about_approach(Rt[k])
            if check is not None:
                ok, _ = check(rg.q[0], w_closed, rr.q[n], float(free.width[k]))
                if not ok:
                    continue
            gap = grippers_distance(collider, Gt, w_closed, R_used, float(free.contact_width[k]))
            receiver = {"T_b1_g": R_used, "width": float(free.width[k]), "contact_width": float(free.contact_width[k]),
                        "depth": float(free.depth[k]), "score": float(free.score[k]),
                        "terms": {t: float(v[k]) for t, v in free.terms.items()},
                        "q": rr.q[n], "q_pre": rr.q_pre[n], "index": int(k)}
            score = 0.5 * (float(giver.grasps.score[gi]) + float(free.score[k]))
            return Handover(move, move[:3, :3] @ geo.centre + move[:3, 3], gi, Gt, rg.q[0], w_closed, receiver,
                            gap, score, dict(stats)), stats
    return None, stats

"""Joint (two-arm) grasps: one grasp per arm, on opposite sides of the object, balanced about its centre.

Two kinds of pair:

- ``push``: two push contacts (``_push``) on opposite faces of the object's box, squeezing towards each other, at
  heights within ``max_height_gap``: the grippers squeeze the object between them along a line through
  its centre. For objects wider than the stroke.
- ``pinch``: two antipodal grasps towards the two ends of a long object, on opposite sides of the centre
  along its long axis, at least ``min_spread`` of its length apart (farther is better), and the grippers
  ``gap`` apart.

A pair is kept when the primary reaches its grasp, the secondary reaches its own, the grippers do not
come within ``gap`` of each other, and the two arms in those configurations do not collide (arm against
arm). With a :class:`PairLift`, the pairs both arms can also lift the object from (some end pose of the
lift that the task's planner samples, :mod:`bimanual_app.kinematics._lift`, within both arms' reach with their
grasps) come before those they cannot. Balance is the horizontal distance from the object's centre to the midpoint of the two contact
centres, relative to half their distance (0 = perfectly balanced); pairs above ``max_imbalance`` are
dropped. Score: the mean of the two grasp scores, less half the imbalance.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ._arms import ArmGrasps, TwoArmCheck
from ._collision import GripperCollider, SceneOctree, grippers_collide
from ._objects import ObjectGeometry, Support

__all__ = ["JointPair", "PairLift", "joint_pairs", "spread_order", "lift_clear", "LIFT_STAGES"]

LIFT_STAGES = tuple(np.arange(1, 12) / 11)  # fractions of a lift where a gripper is checked (about 1 cm apart)


def lift_clear(collider: GripperCollider, scene: SceneOctree, lifts, T_b1_g: np.ndarray, width: float,
               margin: float, ok: np.ndarray | None = None, stages: tuple = LIFT_STAGES) -> np.ndarray:
    """(C,) bool: along which of the C lifts ``lifts`` (:class:`~bimanual_app.kinematics.LiftCandidates`) the
    gripper holding the object at ``T_b1_g`` (4,4), opened ``width`` m, keeps ``margin`` m from ``scene`` at
    every one of ``stages`` (fractions of the way, :func:`~bimanual_app.kinematics.along`); only the lifts
    ``ok`` (C,) bool are checked (default all)."""
    from bimanual_app.kinematics import along

    ok = np.ones(len(lifts), dtype=bool) if ok is None else np.asarray(ok, dtype=bool).copy()
    T_b1_g = np.asarray(T_b1_g, dtype=np.float64).reshape(4, 4)
    for s in stages:
        idx = np.flatnonzero(ok)
        if not len(idx):
            break
        T = along(lifts, s)[idx] @ T_b1_g
        ok[idx] = ~collider.collides(scene, T, np.full(len(idx), float(width)), swept=False, margin=margin)
    return ok


@dataclass
class JointPair:
    """A two-arm grasp: indices into the primary's and the secondary's reachable grasps."""

    kind: str
    i_primary: int
    i_secondary: int
    imbalance: float
    separation: float
    score: float
    liftable: bool = True  # both arms can lift the object from it (False: only when checked, see PairLift)


@dataclass
class PairLift:
    """Whether both arms can lift an object together from a pair of grasps: the end poses of the lift that
    the task's planner samples (:func:`bimanual_app.kinematics._lift.lift_candidates`, here at the least lift
    ``lift_min`` only: any higher is the planner's choice), each arm's IK for its grasp carried along them
    (:func:`bimanual_app.kinematics._lift.arms_ik`, once per grasp, cached), and, with a ``scene``, the
    gripper clear of it (within ``margin``) along the way (the task's planner checks the arms
    along the lift against its map as well; :func:`lift_clear`), and the pair passes when both arms follow one of them.

    solvers: arm name -> (IK solver with ``solve_many``, ``T_b_b1`` (4,4) the arm's base from b1);
    centre: (3,) the object's centre in b1; up: (3,) the table normal in b1; collider / scene: the gripper
    collider and the scene octree without the object (None: IK only).
    """

    solvers: dict
    centre: np.ndarray
    up: np.ndarray
    lift_min: float = 0.105
    radius: float = 0.08
    seeds: int = 1  # IK seeds per lift stage: the previous stage's solution (a continuation)
    collider: GripperCollider | None = None
    scene: SceneOctree | None = None
    margin: float = 0.003  # m: the task planner's contact margin
    _reach: dict = field(default_factory=dict, repr=False)  # (arm, grasp index, pose) -> (C,) bool
    _lifts: object = field(default=None, repr=False)  # the LiftCandidates

    @classmethod
    def for_arms(cls, arms: dict, centre: np.ndarray, up: np.ndarray, **kw) -> PairLift | None:
        """From ``grasping.Arm`` objects whose reach filters have an IK ``solver``; None when one has not."""
        from bimanual_app.transforms import inv_T

        solvers = {n: (getattr(a.reach, "solver", None), inv_T(a.T_b1_b)) for n, a in arms.items()}
        if any(s is None or not hasattr(s, "solve_many") for s, _ in solvers.values()):
            return None
        return cls(solvers, np.asarray(centre, dtype=np.float64), np.asarray(up, dtype=np.float64), **kw)

    def _candidates(self):
        from bimanual_app.kinematics import lift_candidates

        if self._lifts is None:
            self._lifts = lift_candidates(self.centre, self.up, self.lift_min, self.lift_min, radius=self.radius,
                                          n_heights=1)
        return self._lifts

    def reach(self, ag: ArmGrasps, i: int) -> np.ndarray:
        """(C,) bool: along which lifts ``ag``'s arm carries its grasp ``i`` (:func:`~bimanual_app.kinematics._lift.
        arms_ik` for that arm alone: the IK followed from the grasp's joint solution)."""
        from bimanual_app.kinematics import LiftArm, arms_ik

        key = (ag.arm, int(ag.index[i]), ag.grasps.T_b1_g[i].tobytes())
        if key not in self._reach:
            solver, T_b_b1 = self.solvers[ag.arm]
            arm = LiftArm.from_solver(solver, T_b_b1, ag.q[i], self.seeds)
            ok = arms_ik({ag.arm: arm}, {ag.arm: ag.grasps.T_b1_g[i]}, self._candidates())[ag.arm][1]
            self._reach[key] = self._clear(ag, i, ok)
        return self._reach[key]

    def _clear(self, ag: ArmGrasps, i: int, ok: np.ndarray) -> np.ndarray:
        """(C,) bool: ``ok`` (C,) where ``ag``'s gripper holding the object by its grasp ``i`` stays clear of
        ``scene`` along the lift (:func:`lift_clear`)."""
        if self.scene is None or self.collider is None:
            return ok
        return lift_clear(self.collider, self.scene, self._candidates(), ag.grasps.T_b1_g[i],
                          float(ag.grasps.width[i]), self.margin, ok)

    def __call__(self, primary: ArmGrasps, i: int, secondary: ArmGrasps, j: int) -> bool:
        return bool(np.any(self.reach(primary, i) & self.reach(secondary, j)))


def _contact_centres(ag: ArmGrasps) -> np.ndarray:
    g = ag.grasps
    if "contact" in g.extra:  # push contacts: where the fingertips meet the face
        return g.extra["contact"]
    return g.T_b1_g[:, :3, 3] - g.T_b1_g[:, :3, 2] * g.depth[:, None]


def spread_order(points: np.ndarray, groups: np.ndarray, min_dist: float) -> np.ndarray:
    """(N,) an order of N candidates listed best first (``points`` (N, 3), ``groups`` (N,) or (N, k) labels such
    as a push contact's face): within each group, first those at least ``min_dist`` m from every one taken
    before them (greedily, best first), then the rest, best first. The best candidate stays first; the
    next ones are other places on the object, not the same place again."""
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    G = np.asarray(groups).reshape(len(P), -1)
    first, rest = [], []
    for i in range(len(P)):
        same = [j for j in first if np.array_equal(G[j], G[i])]
        if all(np.linalg.norm(P[i] - P[j]) >= min_dist for j in same):
            first.append(i)
        else:
            rest.append(i)
    return np.array(first + rest, dtype=int)


def _horiz(v: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``v`` (3,) or (n, 3) without its component along ``up``."""
    return v - np.outer(v @ up, up) if v.ndim == 2 else v - (v @ up) * up


# m: two push contacts lie at most this far apart across the squeeze (the presses' lever against each other).
# A pair of contacts at each face's middle is up to 2 cm apart (the turned approaches' fingertips; 578 pairs
# of the task bench's pipeline runs); contacts off the middle (``PushParams.laterals``) pair across from each
# other within the same.
MAX_COUPLE = 0.025


def _push_terms(primary: ArmGrasps, secondary: ArmGrasps, i: int, j: int, c1: np.ndarray, c2: np.ndarray,
                up: np.ndarray, d: np.ndarray, sep: float, mid: np.ndarray,
                max_height_gap: float) -> tuple[float, float, int] | None:
    """(imbalance, score adjustment, tier) of two push contacts, or None when they do not make a squeeze:
    opposite faces, at one height (else the squeeze twists the object). Each gripper presses along its face's
    inward normal (``extra["squeeze"]``), and those are opposed for opposite faces; the approaches need not
    be: each is turned from its own face's normal (a swivel, or aimed away from its arm's base, ``_push``),
    and two arms on either side of an object off the line between their bases reach it turned opposite
    ways. Pairs whose approaches are not opposed come after all those whose are (tier 1): they are what the
    arms reach where nothing else is, not a better squeeze. Pairs with a contact that would lie on the top edge
    at the task's squeeze depth (``extra["clears_top"]`` False, ``_push.PushParams.squeeze_margin``) come after
    all those without (tiers 2, 3)."""
    f1, f2 = primary.grasps.extra["face"][i], secondary.grasps.extra["face"][j]
    if f1[0] != f2[0] or f1[1] != -f2[1]:
        return None  # not opposite faces
    dh = abs(float((c1[i] - c2[j]) @ up))
    if dh > max_height_gap:
        return None  # not at one height: the squeeze would twist the object
    squeeze = _horiz(primary.grasps.extra["squeeze"][i], up)
    across = np.cross(up, squeeze / max(float(np.linalg.norm(squeeze)), 1e-9))
    if abs(float((c1[i] - c2[j]) @ across)) > MAX_COUPLE:
        return None  # the two presses are not on one line: they turn the object instead of holding it
    zh1, zh2 = _horiz(primary.grasps.T_b1_g[i, :3, 2], up), _horiz(secondary.grasps.T_b1_g[j, :3, 2], up)
    tier = int(zh1 @ zh2 > -0.9 * np.linalg.norm(zh1) * np.linalg.norm(zh2))
    clears = primary.grasps.extra.get("clears_top"), secondary.grasps.extra.get("clears_top")
    if clears[0] is not None and clears[1] is not None and not (clears[0][i] and clears[1][j]):
        tier += 2  # pressed as deep as the task squeezes, a gripper would lie on the top edge (_push.PushParams)
    # for a squeeze the lateral offset of the line from the centre matters, not where along it
    dn = d / sep
    imb = float(np.linalg.norm(mid - (mid @ dn) * dn)) / (0.5 * sep)
    return imb, -(0.5 * dh / max_height_gap * 0.2), tier  # a squeeze line off the horizontal twists a little


def _lift_terms(geo: ObjectGeometry, c1: np.ndarray, c2: np.ndarray, sep: float, imb: float,
                min_spread: float) -> tuple[float, float, int] | None:
    """(imbalance, score adjustment, tier 0) of two grasps of a long object (contacts ``c1``, ``c2`` (3,)), or None
    when they are on one side of its centre or too close together to keep it level."""
    axis = geo.T_b1_box[:3, 0]
    s1, s2 = (c1 - geo.centre) @ axis, (c2 - geo.centre) @ axis
    if s1 * s2 >= 0:
        return None  # same side of the centre
    if abs(s1 - s2) < min_spread * geo.extent[0]:
        return None  # too close together to keep a long object level
    return imb, 0.2 * min(1.0, sep / (0.8 * geo.extent[0])), 0  # far apart: steadier


def _nearest_centre(centre: np.ndarray, span: np.ndarray | None, p: np.ndarray) -> np.ndarray:
    """(3,) the point of the segment from ``centre`` (3,) to ``centre + span`` (the places the object's centre may
    be; ``span`` None: only ``centre``) nearest to ``p`` (3,)."""
    if span is None:
        return centre
    t = float(np.clip((p - centre) @ span / max(float(span @ span), 1e-12), 0.0, 1.0))
    return centre + t * span


def _ranked_pairs(geo: ObjectGeometry, up: np.ndarray, primary: ArmGrasps, secondary: ArmGrasps, c1: np.ndarray,
                  c2: np.ndarray, max_imbalance: float, max_height_gap: float, min_spread: float,
                  stats: dict, span: np.ndarray | None = None) -> list[tuple]:
    """Every balanced pair as ``(score, i, j, imbalance, separation)``, best first (within tiers, see
    ``_push_terms``); balance is measured from the nearest place the centre may be (``span``, see
    :func:`joint_pairs`)."""
    kind = primary.grasps.kind
    cand = []
    for i in range(len(primary)):
        for j in range(len(secondary)):
            d = _horiz(c2[j] - c1[i], up)
            sep = float(np.linalg.norm(d))
            if sep < 1e-6:
                continue
            m = 0.5 * (c1[i] + c2[j])
            mid = _horiz(m - _nearest_centre(geo.centre, span, m), up)
            imb = float(np.linalg.norm(mid)) / (0.5 * sep)
            terms = (_push_terms(primary, secondary, i, j, c1, c2, up, d, sep, mid, max_height_gap) if kind == "push"
                     else _lift_terms(geo, c1[i], c2[j], sep, imb, min_spread))
            if terms is None:
                continue
            imb, adjust, tier = terms
            stats["candidates"] += 1
            if imb > max_imbalance:
                continue
            stats["balanced"] += 1
            score = 0.5 * (primary.grasps.score[i] + secondary.grasps.score[j]) - 0.5 * imb
            score += adjust
            cand.append((score, i, j, imb, sep, tier))
    cand.sort(key=lambda c: (c[5], -c[0]))
    return [c[:5] for c in cand]


def joint_pairs(geo: ObjectGeometry, support: Support, primary: ArmGrasps, secondary: ArmGrasps,
                collider: GripperCollider, check: TwoArmCheck | None, max_pairs: int = 5, gap: float = 0.02,
                max_imbalance: float = 0.25, max_checks: int = 60, max_height_gap: float = 0.015,
                min_spread: float = 0.4, distinct: float = 0.03,
                lift: PairLift | None = None, centre_span: np.ndarray | None = None) -> tuple[list[JointPair], dict]:
    """Balanced, reachable, collision-free pairs from each arm's reachable grasps of one kind: the best
    first, then the pairs whose two contacts are not both within ``distinct`` m of an earlier pair's (a
    pair that fails for where it holds the object is not followed by the same pair again), then the rest;
    at most ``max_pairs``. With ``lift``, the pairs both arms cannot lift the object from come after all
    those they can (kept: the check is kinematic, the planner has the last word). ``centre_span`` (3,): the
    object's centre may lie anywhere from ``geo.centre`` to ``geo.centre + centre_span`` (an object whose far
    end no camera saw, ``_push.open_ends``); a pair is balanced about the nearest of those places."""
    stats = {"candidates": 0, "balanced": 0, "grippers_apart": 0, "arms_apart": 0, "liftable": 0}
    if len(primary) == 0 or len(secondary) == 0:
        return [], stats
    kind = primary.grasps.kind
    c1, c2 = _contact_centres(primary), _contact_centres(secondary)
    cand = _ranked_pairs(geo, support.up, primary, secondary, c1, c2, max_imbalance, max_height_gap, min_spread,
                         stats, centre_span)
    out: list[JointPair] = []
    similar: list[JointPair] = []
    stuck: list[JointPair] = []  # the arms cannot lift the object from them
    for score, i, j, imb, sep in cand[:max_checks]:
        w1, w2 = primary.grasps.width[i], secondary.grasps.width[j]
        if grippers_collide(collider, primary.grasps.T_b1_g[i], w1, secondary.grasps.T_b1_g[j], w2, margin=gap,
                            swept1=True, swept2=True):
            continue
        stats["grippers_apart"] += 1
        if check is not None:
            ok, _ = check(primary.q[i], w1, secondary.q[j], w2)
            if not ok:
                continue
            ok, _ = check(primary.q_pre[i], w1, secondary.q_pre[j], w2)
            if not ok:
                continue
        stats["arms_apart"] += 1
        pair = JointPair(kind, i, j, imb, sep, float(score))
        if lift is not None and not lift(primary, i, secondary, j):
            stuck.append(JointPair(kind, i, j, imb, sep, float(score), liftable=False))
            continue
        stats["liftable"] += 1
        near = any(np.linalg.norm(c1[i] - c1[p.i_primary]) < distinct and np.linalg.norm(c2[j] - c2[p.i_secondary]) < distinct
                   for p in out)
        (similar if near else out).append(pair)
        if len(out) >= max_pairs:
            break
    stats["distinct"] = len(out)
    return (out + similar + stuck)[:max_pairs], stats

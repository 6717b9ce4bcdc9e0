"""The two arms as the grasp planner sees them: base poses, reach filters, and the arm-against-arm check."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bimanual_app.transforms import inv_T

from ._antipodal import GraspSet, rotate_about_approach
from ._reach import ReachFilter, ReachResult

__all__ = ["Arm", "ArmGrasps", "reachable_grasps", "reachable_by_group", "TwoArmCheck", "make_arms"]


@dataclass
class Arm:
    """One arm: ``name`` ("primary" / "secondary"), base pose ``T_b1_b`` (4, 4) in b1, and its reach filter
    (grasps in the arm's own base frame -> ReachResult; see ``_reach``)."""

    name: str
    T_b1_b: np.ndarray
    reach: ReachFilter

    def for_scene(self, points_b1: np.ndarray) -> Arm:
        """This arm with its reach filter bound to a scene map (when the filter supports it)."""
        f = getattr(self.reach, "for_scene", None)
        return Arm(self.name, self.T_b1_b, f(points_b1) if f else self.reach)


@dataclass
class ArmGrasps:
    """The grasps of one object that one arm reaches.

    grasps: the reachable grasps, as reached (``T_b1_g`` turned about z where the arm needed it).
    index: (n,) their indices in the object's grasp set. q, q_pre: (n, J) joint solutions at the grasp and
    the pre-grasp. T_b_g: (n, 4, 4) the grasps in the arm's own base frame. tried: how many were checked.
    reasons: why the others failed (text -> count).
    """

    arm: str
    grasps: GraspSet
    index: np.ndarray
    q: np.ndarray
    q_pre: np.ndarray
    T_b_g: np.ndarray
    tried: int = 0
    reasons: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.index)


class LiftingReach:
    """A reach filter that also asks the arm to carry each grasp it reaches ``lift`` metres along ``up_b``
    (3,; the arm's base frame) in a straight line, gripper orientation kept: a two-arm grasp is only worth
    having if both arms can then lift the object. Wraps an ``ArmReach`` (needs its ``follow``); everything
    else (``prior``, ``robot``, ...) is the wrapped filter's."""

    def __init__(self, reach, up_b: np.ndarray, lift: float):
        self.reach, self.up_b, self.lift = reach, np.asarray(up_b, dtype=np.float64), float(lift)

    def __getattr__(self, name):
        return getattr(self.reach, name)

    def __call__(self, T_b_g: np.ndarray, width: np.ndarray | None = None, retreat: np.ndarray | None = None,
                 hold_off: np.ndarray | None = None):
        T_b_g = np.asarray(T_b_g, dtype=np.float64).reshape(-1, 4, 4)
        res = self.reach(T_b_g, width, retreat, hold_off)
        res.reason = list(res.reason) + [""] * (len(T_b_g) - len(res.reason))
        for k in np.nonzero(res.ok)[0]:
            T = rotate_about_approach(T_b_g[k]) if res.flipped[k] else T_b_g[k]
            why = self.reach.follow(T, res.q[k], self.up_b, self.lift)
            if why:
                res.ok[k] = False
                res.reason[k] = f"cannot lift it {self.lift * 100:.0f} cm: {why}"
        return res


def lifting_arm(arm: Arm, up_b1: np.ndarray, lift: float) -> Arm | None:
    """``arm`` with a ``LiftingReach`` filter (lift along ``up_b1`` (3,), in b1), or None when its filter
    cannot follow a straight line (a plain callable filter)."""
    if not hasattr(arm.reach, "follow"):
        return None
    up_b = inv_T(arm.T_b1_b)[:3, :3] @ np.asarray(up_b1, dtype=np.float64)
    return Arm(arm.name, arm.T_b1_b, LiftingReach(arm.reach, up_b, lift))


def _reach_either_way(arm: Arm, T_b: np.ndarray, width: np.ndarray, retreats_b1: np.ndarray, T_b_b1: np.ndarray,
                      hold_off_b1: np.ndarray | None = None) -> tuple[ReachResult, np.ndarray]:
    """Reach filter on grasps (n, 4, 4) that have several ways in (``retreats_b1`` (n, R, 3) unit directions to
    the pre-grasp in b1, NaN where blocked): each tried in turn until one works; ``hold_off_b1`` (n, 3): where
    each approach ends, from the grasp (b1). Returns the result and the direction used (n, 3) (NaN where none
    worked)."""
    hold_b = None if hold_off_b1 is None else np.asarray(hold_off_b1, dtype=np.float64) @ T_b_b1[:3, :3].T
    n = len(T_b)
    res = None
    used = np.full((n, 3), np.nan)
    for r in range(retreats_b1.shape[1]):
        rts = retreats_b1[:, r]
        todo = np.isfinite(rts).all(axis=1) & (np.ones(n, bool) if res is None else ~res.ok)
        if not todo.any():
            continue
        sub = arm.reach(T_b[todo], width[todo], rts[todo] @ T_b_b1[:3, :3].T, None if hold_b is None else hold_b[todo])
        if res is None:
            J = sub.q.shape[1]
            res = ReachResult(np.zeros(n, bool), np.full((n, J), np.nan), np.full((n, J), np.nan), np.zeros(n, bool),
                              ["no free way in"] * n)
        for k_sub, k in enumerate(np.nonzero(todo)[0]):
            res.ok[k], res.q[k], res.q_pre[k] = sub.ok[k_sub], sub.q[k_sub], sub.q_pre[k_sub]
            res.flipped[k], res.reason[k] = sub.flipped[k_sub], sub.reason[k_sub]
            if sub.ok[k_sub]:
                used[k] = rts[k]
    if res is None:
        J = int(getattr(getattr(arm.reach, "robot", None), "nq_arm", 6))
        res = ReachResult(np.zeros(n, bool), np.full((n, J), np.nan), np.full((n, J), np.nan), np.zeros(n, bool),
                          ["no free way in"] * n)
    return res, used


def reachable_grasps(gs: GraspSet, arm: Arm, max_tries: int = 40, want: int = 10, batch: int = 8,
                     prior_tiers: tuple[float, ...] = (0.05, 0.08, 0.12), prefer: np.ndarray | None = None) -> ArmGrasps:
    """Check ``gs`` (best first) with ``arm``'s reach filter until ``want`` pass or ``max_tries`` are tried.

    When the filter has a ``prior`` (predicted distance to the reachable set, m), grasps are checked in
    tiers of it (``prior_tiers``: under the first, then the second, ..., the rest last): the IK budget goes
    to the grasps the arm is likely to reach. ``prefer`` (N,) bool puts those grasps before all others.
    The kept grasps keep their score order.
    """
    T_b_b1 = inv_T(arm.T_b1_b)
    keep, qs, qps, Ts, rts_kept = [], [], [], [], []
    reasons: dict[str, int] = {}
    tried = 0
    T_used = gs.T_b1_g.copy()
    order = np.arange(len(gs))
    prior = getattr(arm.reach, "prior", None)
    if prior is not None and len(gs):
        # check the grasps the arm is likely to reach first (best score first within each tier)
        d = prior(T_b_b1 @ gs.T_b1_g)
        tiers = np.digitize(d, prior_tiers)
        order = np.concatenate([order[tiers == t] for t in range(len(prior_tiers) + 1)])
    if prefer is not None and len(gs):
        pref = np.asarray(prefer, dtype=bool)[order]
        order = np.concatenate([order[pref], order[~pref]])
    n_check = min(len(order), max_tries)
    while tried < n_check and len(keep) < want:
        idx = order[tried: min(tried + batch, n_check)]
        T_b = T_b_b1 @ gs.T_b1_g[idx]
        if "retreats" in gs.extra:  # push contacts: one of their two ways in, whichever is free and reachable
            hold = gs.extra["hold_off"][idx] if "hold_off" in gs.extra else None
            res, rt_used = _reach_either_way(arm, T_b, gs.width[idx], gs.extra["retreats"][idx], T_b_b1, hold)
        else:
            res, rt_used = arm.reach(T_b, gs.width[idx]), np.full((len(idx), 3), np.nan)
        for k, i in enumerate(idx):
            if res.ok[k]:
                keep.append(int(i))
                rts_kept.append(rt_used[k])
                qs.append(res.q[k])
                qps.append(res.q_pre[k])
                Tk = rotate_about_approach(T_b[k]) if res.flipped[k] else T_b[k]
                Ts.append(Tk)
                T_used[i] = arm.T_b1_b @ Tk
            else:
                r = res.reason[k] if k < len(res.reason) else "unreachable"
                key = r.split(" (best")[0]
                reasons[key] = reasons.get(key, 0) + 1
        tried += len(idx)
    keep_sorted = sorted(range(len(keep)), key=lambda a: keep[a])
    keep = [keep[a] for a in keep_sorted]
    qs = [qs[a] for a in keep_sorted]
    qps = [qps[a] for a in keep_sorted]
    Ts = [Ts[a] for a in keep_sorted]
    rts_kept = [rts_kept[a] for a in keep_sorted]
    sub = gs.take(keep)
    if "retreats" in sub.extra:
        sub.extra["retreat"] = np.array(rts_kept).reshape(-1, 3)  # the way in the arm uses (b1)
    sub.T_b1_g = T_used[keep] if keep else sub.T_b1_g
    J = qs[0].shape[0] if qs else int(getattr(getattr(arm.reach, "robot", None), "nq_arm", 6))
    if len(gs) > tried:
        reasons["not checked (enough found, or the check budget spent)"] = len(gs) - tried
    return ArmGrasps(arm.name, sub, np.array(keep, dtype=int), np.array(qs).reshape(-1, J), np.array(qps).reshape(-1, J),
                     np.array(Ts).reshape(-1, 4, 4), tried, reasons)


def reachable_by_group(gs: GraspSet, arm: Arm, groups: np.ndarray, tries_per_group: int = 25, want_per_group: int = 4,
                       prefer: np.ndarray | None = None) -> ArmGrasps:
    """``reachable_grasps`` with a separate budget for each group of grasps (``groups`` (N,) labels, e.g. the
    face of a push contact), so that a group the arm cannot reach does not use up the others' checks."""
    parts = []
    groups = np.asarray(groups)
    for gval in np.unique(groups, axis=0):
        sel = np.nonzero(np.all(groups == gval, axis=-1) if groups.ndim > 1 else groups == gval)[0]
        ag = reachable_grasps(gs.take(sel), arm, tries_per_group, want_per_group,
                              prefer=None if prefer is None else prefer[sel])
        ag.index = sel[ag.index]
        parts.append(ag)
    reasons: dict[str, int] = {}
    for ag in parts:
        for r, c in ag.reasons.items():
            reasons[r] = reasons.get(r, 0) + c
    if not parts:
        return reachable_grasps(gs.take([]), arm)
    J = parts[0].q.shape[1]
    return ArmGrasps(arm.name, GraspSet.concat([ag.grasps for ag in parts]), np.concatenate([ag.index for ag in parts]),
                     np.concatenate([ag.q for ag in parts]).reshape(-1, J),
                     np.concatenate([ag.q_pre for ag in parts]).reshape(-1, J),
                     np.concatenate([ag.T_b_g for ag in parts]).reshape(-1, 4, 4),
                     sum(ag.tried for ag in parts), reasons)


class TwoArmCheck:
    """Arm-against-arm (and self) collision of a primary and a secondary configuration, both arms in b1."""

    def __init__(self, robot, gripper, T_b1_b2: np.ndarray, margin: float = 0.01):
        from bimanual_app.collision import CollisionWorld

        self.gripper = gripper
        self.world = CollisionWorld(robot, T_b1_b2, None, margin=margin)

    def __call__(self, q1: np.ndarray, w1: float, q2: np.ndarray, w2: float) -> tuple[bool, str]:
        if not (np.all(np.isfinite(q1)) and np.all(np.isfinite(q2))):
            return False, "no joint solution"
        self.world.set_opening(0, self.gripper.robot_opening(w1))
        self.world.set_opening(1, self.gripper.robot_opening(w2))
        if self.world.valid(q1, q2):
            return True, ""
        why = self.world.explain(q1, q2)
        return False, why[0] if why else "the arms collide"


def make_arms(robot, gripper, T_b1_b2: np.ndarray | None, pregrasp: float = 0.09, **reach_kw) -> dict[str, Arm]:
    """The primary (and, with ``T_b1_b2``, the secondary) arm with the project's IK / collision reach filter."""
    from ._reach import ArmReach

    arms = {"primary": Arm("primary", np.eye(4), ArmReach(robot, gripper, np.eye(4), None, pregrasp, name="primary", **reach_kw))}
    if T_b1_b2 is not None:
        T = np.asarray(T_b1_b2, dtype=np.float64)
        arms["secondary"] = Arm("secondary", T, ArmReach(robot, gripper, T, None, pregrasp, name="secondary",
                                                         _solver=arms["primary"].reach.solver, **reach_kw))
    return arms

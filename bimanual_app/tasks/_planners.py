"""The two tasks as phases: joint grasp (both arms lift one object together) and hand-over.

Every arm motion comes from :class:`~._motion.TaskMotion` (OMPL for free motions, Cartesian IK paths for
straight moves), each validated (limits, velocities, collisions) in the collision context of its phase;
gripper phases keep the arms still. Gripper widths are part of every trajectory, so the plan's timeline
is complete: what the preview simulates is what the hardware would run.

Joint grasp: reach both pre-grasps (12-DoF OMPL query) -> straight approach -> close (pinch) or squeeze
(push: the open fingertips are driven ``press`` past the faces) -> lift: the *object's* motion is planned
(straight up by ``lift``), each gripper's pose is that motion applied to its grasp, IK at every
waypoint for both arms on one clock, the object's own clearance checked along it -> hold 2.3 s (checked)
-> place (the reverse) -> release -> retreat.

Hand-over: (the secondary turns aside about its base when it stands in the primary's way) primary reaches,
approaches, closes on the object, lifts 6 cm, carries it (object attached)
to the transfer pose -> secondary reaches its pre-grasp (object attached to the primary, as an obstacle)
-> straight approach -> closes -> primary opens -> retreats 8 cm along its approach -> hold 2.3 s
(checked: held by the secondary only).
"""

from __future__ import annotations

import numpy as np

from ._grasps import GraspSpec, HandoverChoice, JointChoice
from ._motion import CONTACT_MARGIN, OBJECT_PADDING, PlanFailure, TaskMotion, line_poses, translate_along
from ._plan import Phase, TaskPlan

__all__ = ["plan_joint_grasp", "plan_handover", "object_lifts", "LIFT", "HOLD_S"]

LIFT = 0.15  # m the joint grasp lifts the object (>= 10 cm needed)
LIFT_MIN = 0.105  # m: the least lift it falls back to at the top of the arms' reach
RETREAT_UP = 0.08  # m of the fallback retreats of a push pair (straight up, or further back from the faces)
# m: a push pair's approach stops this far out from the faces, and the squeeze starts there. The faces'
# depth comes from the segment's points, which miss the last millimetres of an edge (on the task bench the
# large box came out 4-10 mm shorter than it is): an approach from above that ended on the estimated face
# put the fingertips on the real box's top.
PUSH_STANDOFF = 0.01
HANDOVER_LIFT = 0.06  # m straight up after the pick, before the free carry
HANDOVER_LIFTS = (HANDOVER_LIFT, 0.10, 0.14, 0.04)  # tried in order: higher beside a taller neighbour
RETREAT_MIN = 0.045  # m: the least back-off of the giver that leaves its open fingers clear of the object
HOLD_S = 2.3  # s of the checked hold (2 s needed)
CLOSE_S = 1.0  # s to close a gripper (force limited: it stops on the object)
SETTLE_S = 0.4  # s still after a gripper change
CLOSED = 0.0  # commanded width when closing on an object (the force limit stops the fingers)


def _jt(times, q, widths):
    from bimanual_app.hardware import JointTrajectory

    times = np.asarray(times, dtype=np.float64)
    w = np.broadcast_to(np.asarray(widths, dtype=np.float64), times.shape).copy()
    return JointTrajectory(times, np.asarray(q, dtype=np.float64), w)


def _ramp(times, w0, w1):
    """Widths from w0 to w1 linearly over ``times``."""
    t = np.asarray(times, dtype=np.float64)
    s = t / t[-1] if t[-1] > 0 else np.ones_like(t)
    return w0 + s * (w1 - w0)


def _still(q, widths_from, widths_to, close_s=CLOSE_S, settle_s=SETTLE_S):
    """An arm standing still while its gripper goes from one width to another (then settles)."""
    times = np.array([0.0, close_s, close_s + settle_s])
    return _jt(times, np.stack([q, q, q]), [widths_from, widths_to, widths_to])


def _pre(motion: TaskMotion, g: GraspSpec) -> np.ndarray:
    """The pre-grasp pose in b1: where the grasping stage checked it (the gripper pose of its pre-grasp
    joint solution ``q_pregrasp``, which also knows the direction it backed off along), else
    ``g.pre_dist`` back along the approach."""
    if g.q_pre is not None and np.all(np.isfinite(g.q_pre)):
        T = motion.tcp_pose(g.arm, g.q_pre)
        # the grasping stage's pre-grasp belongs to this grasp only if it backs off from this pose
        if np.linalg.norm(T[:3, 3] - g.T_b1_g[:3, 3]) < 2 * g.pre_dist + 0.02:
            return T
    return translate_along(g.T_b1_g, g.T_b1_g[:3, 2], -g.pre_dist)


def object_lifts(motion: TaskMotion, up: np.ndarray, lift: float) -> list[tuple[np.ndarray, str]]:
    """The object's possible lifts, in order of preference: ``(rigid motions (K,4,4), how)`` whose swept
    object stays clear of the scene map (the arms' reach is the caller's to check).

    Tried in order: straight up; up while moving 3 cm, then 6 cm, horizontally away from the nearest
    obstacle around the object (a neighbour it touches); up while moving 3 cm, then 6 cm, towards the
    line between the two bases (nearer both arms); up while moving 4 cm, then 8 cm, towards the midpoint
    of the bases (an object near one base is at the far end of the other's reach); each horizontal move
    reached over the first half of the lift. Raises PlanFailure when none is clear.
    """
    from scipy.spatial import cKDTree

    P = motion.object_points
    centre = P.mean(axis=0)
    cand = [(np.zeros(3), "straight up")]
    pts = motion.cut_map.points
    near = pts[cKDTree(P).query(pts, k=1, distance_upper_bound=0.06)[0] < np.inf]
    h = near @ up
    near = near[h > (P @ up).min() + 0.01]  # not the table under it
    if len(near):
        d = centre - near.mean(axis=0)
        d = d - (d @ up) * up
        if np.linalg.norm(d) > 1e-6:
            d /= np.linalg.norm(d)
            cand += [(0.03 * d, "up and 3 cm away from its neighbour"), (0.06 * d, "up and 6 cm away from its neighbour")]
    # towards the line between the two bases: nearer both arms, where an arm at the top of its reach
    # can follow the lift
    b2 = motion.setup.T_b1_b("secondary")[:3, 3]
    line = b2 - (b2 @ up) * up
    if np.linalg.norm(line) > 1e-6:
        u = line / np.linalg.norm(line)
        c = centre - (centre @ up) * up
        off = c - (c @ u) * u  # from the line to the object, horizontally
        dist = float(np.linalg.norm(off))
        for k in (0.03, 0.06):
            if dist > 0.01 and (k == 0.03 or dist > 0.03):  # the line nearer than 3 cm: one step, onto it
                step = -off / dist * min(k, dist)
                cand.append((step, f"up and {np.linalg.norm(step) * 100:.0f} cm towards the line between the bases"))
        # towards the midpoint of the bases: an object near one base is at the far end of the other's reach
        mid = 0.5 * line
        to_mid = mid - c
        n_mid = float(np.linalg.norm(to_mid))
        if n_mid > 0.01:
            for k in (0.04, 0.08):
                if k == 0.08 and n_mid <= 0.04:
                    continue  # the midpoint nearer than 4 cm: one step, onto it
                step = to_mid / n_mid * min(k, n_mid)
                cand.append((step, f"up and {np.linalg.norm(step) * 100:.0f} cm towards the midpoint of the bases"))
    n = max(2, int(np.ceil(lift / 0.01)) + 1)
    s = np.linspace(0.0, 1.0, n)
    first, out = None, []
    for shift, how in cand:
        T = np.stack([np.eye(4)] * n)
        T[:, :3, 3] = (s * lift)[:, None] * up + np.minimum(2 * s, 1.0)[:, None] * shift
        problems = motion.object_clear(T, up=up)
        if not problems:
            out.append((T, how))
        first = first or (problems[0] if problems else None)
    if not out:
        raise PlanFailure("validation", first)
    return out


def _face_gap(motion: TaskMotion, g: GraspSpec, lateral: float = 0.03, cap: float = 0.02) -> float:
    """How far (m) the fingertips of a push contact still are from the object along the squeeze direction:
    the nearest object point (its hull, the body the preview simulates) within ``lateral`` m of the squeeze
    line through the fingertips' contact (``g.contact``; the gripper origin when unknown). The grasping
    stage puts the fingertips on the face at its points' median depth; the first contact is the outermost
    point, so the squeeze is extended by the gap (at most ``cap``) to press ``press`` past it on both sides.

    Measured from the fingertips, not from the gripper origin: that lies half a finger's thickness (and
    more on a tilted gripper) outside the face, and counting it drove the fingertips 2 cm into the box on
    the task bench, where the pressed finger then caught the box's top edge."""
    n = g.squeeze_dir
    origin = g.T_b1_g[:3, 3] if g.contact is None else np.asarray(g.contact, dtype=np.float64)
    d = motion.object_points - origin
    along = d @ n
    side = np.linalg.norm(d - np.outer(along, n), axis=1)
    near = along[side < lateral]
    if not len(near):
        return 0.0
    return float(np.clip(near.min(), 0.0, cap))


def _retreat_directions(T_b1_g: np.ndarray, up: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """Ways an open gripper can leave an object it straddles: any direction across its closing axis y
    slides the fingers along the object's faces. In order: back along the approach, horizontally back
    towards its own base side, straight up."""
    y = T_b1_g[:3, 1]
    out = [("back along its approach", -T_b1_g[:3, 2])]
    for name, d in (("horizontally back", -(T_b1_g[:3, 2] - (T_b1_g[:3, 2] @ up) * up)), ("up", up)):
        d = d - (d @ y) * y
        n = np.linalg.norm(d)
        if n > 0.3:
            out.append((name, d / n))
    return out


def _lift_directions(motion: TaskMotion, T_b1_g: np.ndarray, object_points: np.ndarray, up: np.ndarray,
                     near: float = 0.03) -> list[tuple[str, np.ndarray]]:
    """A picked object's lift directions (unit (3,) in b1), in order of preference.

    Straight up; up and towards the primary's base (near the edge of the reach); up and away from the
    neighbours it stands beside (map points within ``near`` m of its points, above its bottom): a lift
    straight up beside a taller neighbour slides along it, and where the arm cannot go higher, the carry
    would start too close to it; back out along the approach, where that rises.
    """
    dirs = [("straight up", up)]
    to_base = -T_b1_g[:3, 3] + (T_b1_g[:3, 3] @ up) * up
    if np.linalg.norm(to_base) > 1e-6:
        to_base /= np.linalg.norm(to_base)
        dirs.append(("up and towards the base", (up + to_base) / np.linalg.norm(up + to_base)))
    d, i = motion._cut_tree.query(object_points, k=1, distance_upper_bound=near)
    C = motion._cut_tree.data[np.unique(i[np.isfinite(d)])]
    C = C[C @ up > (object_points @ up).min() + 0.01]  # the neighbours' sides, not the table
    if len(C):
        away = object_points.mean(0) - C.mean(0)
        away -= (away @ up) * up
        if np.linalg.norm(away) > 1e-6:
            away /= np.linalg.norm(away)
            for how, k in (("up and away from its neighbour", 1.0), ("up, a little away from its neighbour", 0.5)):
                dirs.append((how, (up + k * away) / np.linalg.norm(up + k * away)))
    back = -T_b1_g[:3, 2]
    if back @ up > 0.3:
        dirs.append(("back out along the approach", back))
    return dirs


def _giver_retreat(motion: TaskMotion, gt: GraspSpec, q: dict, held: tuple, up: np.ndarray,
                   openings: dict) -> tuple:
    """The giver's straight back-off from its grasp ``gt`` once the receiver holds the object:
    (trajectory, distance m, how). Near the reach limit it backs off less far: the largest distance from
    its pre-grasp distance down to ``RETREAT_MIN`` that is reachable and leaves the open fingers clear of
    the held object. Raises PlanFailure with the reason when none is."""
    distances = np.arange(gt.pre_dist, RETREAT_MIN, -0.01)
    if len(distances) == 0:
        raise PlanFailure("reach", f"the {gt.arm}'s pre-grasp is only {gt.pre_dist * 100:.1f} cm back from its "
                                   f"grasp: it cannot back off the {RETREAT_MIN * 100:.1f} cm that keeps its open "
                                   "fingers clear of the object")
    err = None
    for how, direction in _retreat_directions(gt.T_b1_g, up):
        for dist in distances:
            back = translate_along(gt.T_b1_g, direction, dist)
            try:
                with motion.context("cut", openings=openings):
                    tr = motion.cartesian({gt.arm: (gt.T_b1_g, back)}, q)[gt.arm]
                with motion.context("attached", openings=openings, attach=held):
                    why = motion.problems({**q, gt.arm: tr.q[-1]})
                if why:
                    raise PlanFailure("validation", f"after backing off {dist * 100:.0f} cm ({how}) the {gt.arm} "
                                                    f"still touches the object: {why[0]}")
                return tr, float(dist), how
            except PlanFailure as e:
                err = e
    raise err or PlanFailure("reach", f"the {gt.arm} has no direction to back off along")


def _approachable(motion: TaskMotion, arm: str, sols: np.ndarray, T_pre: np.ndarray, T: np.ndarray) -> np.ndarray:
    """The pre-grasp IK solutions (order kept) from which the straight approach to ``T`` stays on one IK
    branch (so the OMPL goal and the approach that follows it agree); raises the first failure if none."""
    ok, err = [], None
    poses = line_poses(T_pre, T)  # the very waypoints the approach will use
    for q in sols:
        try:
            motion.ik_path({arm: poses}, {arm: q})
            ok.append(q)
        except PlanFailure as e:
            err = err or e
    if not ok:
        raise err
    return np.stack(ok)


def _goal_ik(motion: TaskMotion, arm: str, T: np.ndarray, seeds: list) -> np.ndarray:
    """IK solutions for T, trying the grasping stage's solution as the first seed."""
    last = None
    for s in seeds:
        if s is None:
            continue
        try:
            return motion.ik(arm, T, s)
        except PlanFailure as e:
            last = e
    raise last or PlanFailure("reach", f"no seed for the {arm} arm")


def plan_joint_grasp(motion: TaskMotion, choice: JointChoice, q_start: dict, width_start: dict,
                     lift: float = LIFT, up: np.ndarray | None = None) -> TaskPlan:
    """The joint-grasp plan for ``choice`` from ``q_start`` (arm -> (J,)); raises PlanFailure (its message
    starts with the phase that could not be planned)."""
    at = ["reach"]
    try:
        return _joint_grasp(motion, choice, q_start, width_start, lift, up, at)
    except PlanFailure as e:
        raise PlanFailure(e.stage, f"{at[-1]}: {e.message}") from None


def _joint_grasp(motion, choice, q_start, width_start, lift, up, at) -> TaskPlan:
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=np.float64)
    plan = TaskPlan({a: np.asarray(q, float) for a, q in q_start.items()}, dict(width_start))
    arms = ("primary", "secondary")
    G = {"primary": choice.primary, "secondary": choice.secondary}
    push = choice.kind == "push"
    w_open = {a: G[a].width for a in arms}
    w_hold = {a: (G[a].width if push else CLOSED) for a in arms}
    opening_hold = {a: (G[a].width if push else (G[a].contact_width or 0.0)) for a in arms}
    plan.info = {"kind": choice.kind, "score": choice.score, **choice.info, "grip": {a: G[a].kind for a in arms},
                 "grasps": {a: {"T_b1_g": G[a].T_b1_g, "width": G[a].width, "press": G[a].press} for a in arms}}

    # 1. reach both pre-grasps together (12 DoF): the object is an obstacle
    pre = {a: _pre(motion, G[a]) for a in arms}
    with motion.context("map", openings=w_open):
        sols = {a: _approachable(motion, a, _goal_ik(motion, a, pre[a], [G[a].q_pre, q_start[a], G[a].q]), pre[a],
                                 G[a].T_b1_g) for a in arms}
        goals = [{"primary": s1, "secondary": s2} for s1 in sols["primary"][:3] for s2 in sols["secondary"][:3]]
        goals = [g for g in goals if not motion.problems(g)] or goals[:1]
        tr = motion.plan_free(list(arms), q_start, goals)
    plan.add(Phase("reach", {a: _jt(tr[a].times, tr[a].q, _ramp(tr[a].times, width_start[a], w_open[a]))
                             for a in arms}, "both grippers to their pre-grasps, opening", "ompl"))

    at.append("approach")
    # 2. straight approach to contact (the object is cut out: the fingers meet it); a push pair stops short
    # of the faces by PUSH_STANDOFF
    q, _ = plan.end_state()
    touch = {a: (translate_along(G[a].T_b1_g, G[a].squeeze_dir, -PUSH_STANDOFF) if push else G[a].T_b1_g)
             for a in arms}
    with motion.context("cut", openings=w_open):
        tr = motion.cartesian({a: (pre[a], touch[a]) for a in arms}, q)
    plan.add(Phase("approach", {a: _jt(tr[a].times, tr[a].q, w_open[a]) for a in arms},
                   f"straight {G['primary'].pre_dist * 100:.0f} cm approach to the object", "cartesian"))

    at.append("squeeze")
    # 3. grip: close (pinch) or squeeze (push)
    q, _ = plan.end_state()
    if push:
        # driven press + gap past the contact; where an arm cannot go that far (the far end of its reach),
        # half the gap, then the press alone
        gap = {a: _face_gap(motion, G[a]) for a in arms}
        tr, err = None, None
        for f in (1.0, 0.5, 0.0):
            S = {a: translate_along(G[a].T_b1_g, G[a].squeeze_dir, G[a].press + f * gap[a]) for a in arms}
            try:
                with motion.context("cut", openings=w_open):
                    tr = motion.cartesian({a: (touch[a], S[a]) for a in arms}, q, min_duration=1.0)
                break
            except PlanFailure as e:
                err = err or e
            if max(gap.values()) < 1e-4:
                break
        if tr is None:
            raise err
        plan.add(Phase("squeeze", {a: _jt(tr[a].times, tr[a].q, w_open[a]) for a in arms},
                       "fingertips pressed into both faces: the object is held between the grippers", "cartesian"))
    else:
        S = {a: G[a].T_b1_g for a in arms}
        plan.add(Phase("close", {a: _still(q[a], w_open[a], CLOSED) for a in arms},
                       "both grippers close (force limited)", "gripper"))

    at.append("lift")
    # 4. lift: the object's motion, both grippers follow it
    q, _ = plan.end_state()
    tr, err = None, None
    # near the top of the reach, lift less: down to LIFT_MIN, 5 mm over the 10 cm needed (the bench's joint
    # lifts rise in reality as planned, within 0.1 mm)
    for h in (lift, 0.85 * lift, max(0.74 * lift, 0.11), LIFT_MIN):
        try:
            lifts = object_lifts(motion, up, h)
        except PlanFailure as e:
            err = err or e
            continue
        for T_moves, how in lifts:  # the first one both arms can follow
            try:
                with motion.context("cut", openings=opening_hold):
                    tr = motion.cartesian({a: T_moves @ S[a] for a in arms}, q)
                break
            except PlanFailure as e:
                err = err or e
        if tr is not None:
            lift = h
            break
    if tr is None:
        raise err
    plan.add(Phase("lift", {a: _jt(tr[a].times, tr[a].q, w_hold[a]) for a in arms},
                   f"object lifted {lift * 100:.0f} cm ({how}), both grippers following it", "cartesian"))
    plan.info["object_motion"] = {"lift_m": lift, "how": how, "T_move_end": T_moves[-1], "waypoints": len(T_moves)}

    # 5. hold (checked)
    q, _ = plan.end_state()
    plan.add(Phase("hold", {a: _jt([0.0, HOLD_S], np.stack([q[a], q[a]]), w_hold[a]) for a in arms},
                   f"held up for {HOLD_S:g} s", "hold", check="joint-lift"))

    at.append("place")
    # 6. place, release, retreat
    with motion.context("cut", openings=opening_hold):
        tr = motion.cartesian({a: (T_moves @ S[a])[::-1] for a in arms}, q)
    plan.add(Phase("place", {a: _jt(tr[a].times, tr[a].q, w_hold[a]) for a in arms},
                   "object set back down", "cartesian"))
    at.append("retreat")
    q, _ = plan.end_state()
    if push:
        # let go first: the squeeze undone (straight back out of the faces to where the fingertips first
        # touched, the states the squeeze was checked through), so the fingertips stop pressing before the
        # gripper moves along its approach (a tilted approach leaves upwards and, still pressing, would drag
        # the object up with it)
        U = {a: G[a].T_b1_g for a in arms}
        with motion.context("cut", openings=w_open):
            tr = motion.cartesian({a: (S[a], U[a]) for a in arms}, q, min_duration=0.6)
        plan.add(Phase("release", {a: _jt(tr[a].times, tr[a].q, w_open[a]) for a in arms},
                       "fingertips back out of both faces: the object rests on the table", "cartesian"))
        q, _ = plan.end_state()
        # back to the pre-grasps; where that line is blocked, straight up or further back out of the faces
        tr, err, how = None, None, ""
        for how, ends in (("to their pre-grasps", pre),
                          ("straight up", {a: translate_along(U[a], up, RETREAT_UP) for a in arms}),
                          ("back from the faces", {a: translate_along(U[a], G[a].squeeze_dir, -RETREAT_UP)
                                                   for a in arms})):
            try:
                with motion.context("cut", openings=w_open):
                    tr = motion.cartesian({a: (U[a], ends[a]) for a in arms}, q)
                break
            except PlanFailure as e:
                err = PlanFailure(e.stage, f"{err.message}; {how}: {e.message}" if err else f"{how}: {e.message}")
        if tr is None:
            raise err
        plan.add(Phase("retreat", {a: _jt(tr[a].times, tr[a].q, w_open[a]) for a in arms},
                       f"both grippers back off {how}", "cartesian"))
    else:
        plan.add(Phase("release", {a: _still(q[a], CLOSED, w_open[a]) for a in arms}, "both grippers open",
                       "gripper"))
        q, _ = plan.end_state()
        with motion.context("cut", openings=w_open):
            tr = motion.cartesian({a: (S[a], pre[a]) for a in arms}, q)
        plan.add(Phase("retreat", {a: _jt(tr[a].times, tr[a].q, w_open[a]) for a in arms},
                       "both grippers back off to their pre-grasps", "cartesian"))
    return plan


MAKE_WAY_TURNS = (1.2, -1.2, 0.6, -0.6)  # rad about the secondary's base joint (joint 1), tried in order


def plan_handover(motion: TaskMotion, choice: HandoverChoice, q_start: dict, width_start: dict,
                  object_points: np.ndarray, up: np.ndarray | None = None) -> TaskPlan:
    """The hand-over plan for ``choice`` from ``q_start``; raises PlanFailure (its message starts with the
    phase that could not be planned).

    Where the waiting secondary is in the primary's way (its reach, approach or lift meet the secondary),
    the plan starts with a ``make-way`` phase: the secondary turns about its base joint by the first of
    ``MAKE_WAY_TURNS`` from which the rest plans.

    ``object_points``: (M,3) the object's points in b1 where it lies (attached to a gripper while carried).
    """
    at = ["reach"]
    try:
        return _handover(motion, choice, q_start, width_start, object_points, up, at)
    except PlanFailure as e:
        first = PlanFailure(e.stage, f"{at[-1]}: {e.message}")
        if at[-1] not in ("reach", "approach", "lift") or "secondary" not in e.message:
            raise first from None
    # the waiting secondary is in the primary's way to the object or up from it (an object beside the
    # secondary's base): it first turns about its base joint, out of the way, and takes the object over
    # from there
    w_sec = width_start["secondary"]
    lo, hi = motion.robot.lower, motion.robot.upper
    for turn in MAKE_WAY_TURNS:
        q_aside = np.asarray(q_start["secondary"], dtype=np.float64).copy()
        q_aside[0] += turn
        if not lo[0] <= q_aside[0] <= hi[0]:
            continue
        q_from = {**q_start, "secondary": q_aside}
        with motion.context("map", openings={"primary": width_start["primary"], "secondary": w_sec}):
            if motion.problems(q_from):
                continue
            try:
                way = motion.plan_free(["secondary"], q_start, [{"secondary": q_aside}])["secondary"]
            except PlanFailure:
                continue
        at = ["reach"]
        try:
            rest = _handover(motion, choice, q_from, width_start, object_points, up, at)
        except PlanFailure:
            continue
        plan = TaskPlan({a: np.asarray(q, float) for a, q in q_start.items()}, dict(width_start), info=rest.info)
        plan.add(Phase("make-way", {"secondary": _jt(way.times, way.q, w_sec)},
                       f"the secondary turns {np.degrees(turn):+.0f} deg about its base, out of the primary's way",
                       "ompl"))
        for ph in rest.phases:
            plan.add(ph)
        plan.info["make_way_rad"] = float(turn)
        return plan
    raise first from None


def _handover(motion, choice, q_start, width_start, object_points, up, at) -> TaskPlan:
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=np.float64)
    plan = TaskPlan({a: np.asarray(q, float) for a, q in q_start.items()}, dict(width_start))
    pick, gt, rec = choice.pick, choice.giver_transfer, choice.receiver
    wg, wr = pick.width, rec.width
    wl = min(gt.width, wg)  # the giver lets go opening this far (no wider than it picked)
    cw_g = pick.contact_width or 0.0
    cw_r = rec.contact_width or 0.0
    plan.info = {"score": choice.score, **choice.info, "T_move": choice.T_move,
                 "transfer_centre_b1": (choice.T_move @ np.r_[object_points.mean(0), 1.0])[:3],
                 "grasps": {"pick": {"T_b1_g": pick.T_b1_g, "width": wg},
                            "giver_transfer": {"T_b1_g": gt.T_b1_g},
                            "receiver": {"T_b1_g": rec.T_b1_g, "width": wr}}}

    # 1-3. primary picks
    pre_pick = _pre(motion, pick)
    with motion.context("map", openings={"primary": wg, "secondary": width_start["secondary"]}):
        sols = _approachable(motion, "primary", _goal_ik(motion, "primary", pre_pick, [pick.q_pre, q_start["primary"],
                                                                                      pick.q]), pre_pick, pick.T_b1_g)
        goals = [{"primary": s} for s in sols[:4]]
        tr = motion.plan_free(["primary"], q_start, goals)["primary"]
    plan.add(Phase("reach", {"primary": _jt(tr.times, tr.q, _ramp(tr.times, width_start["primary"], wg))},
                   "primary to its pre-grasp, opening", "ompl"))
    at.append("approach")
    q, _ = plan.end_state()
    with motion.context("cut", openings={"primary": wg}):
        tr = motion.cartesian({"primary": (pre_pick, pick.T_b1_g)}, q)["primary"]
    plan.add(Phase("approach", {"primary": _jt(tr.times, tr.q, wg)}, "straight approach", "cartesian"))
    q, _ = plan.end_state()
    q_grasp = q["primary"].copy()
    plan.add(Phase("grasp", {"primary": _still(q_grasp, wg, CLOSED)}, "primary closes (force limited)", "gripper"))

    at.append("lift")
    # 4-5. lift, then carry to the transfer pose (object attached to the primary)
    attach = ("primary", q_grasp, object_points)
    # off the table: the object rests on it at the start, so it is checked by itself (its points along the
    # motion against the map) rather than attached (it would touch the table at once); in the directions
    # of _lift_directions, higher, or less far (the carry that follows is planned with the object
    # attached, clear of the table).
    dirs = _lift_directions(motion, pick.T_b1_g, object_points, up)
    with motion.context("cut", openings={"primary": cw_g}):
        if motion.problems(q):  # the closed fingers meet points the segment left out: the object's own
            motion.cut_grasped(pick.T_b1_g, wg)
    def try_lifts(q, pad=OBJECT_PADDING):
        """The first lift (in the order of HANDOVER_LIFTS x dirs) the primary can follow with the secondary
        at q, the carried object's box grown by ``pad``: (trajectory or None, distance, how, first error)."""
        err = None
        for dist in HANDOVER_LIFTS:
            for how, d in dirs:
                n_steps = max(7, int(np.ceil(dist / 0.01)) + 1)
                moves = np.stack([np.eye(4)] * n_steps)
                moves[:, :3, 3] = np.linspace(0.0, dist, n_steps)[:, None] * d
                try:
                    problems = motion.object_clear(moves, up=up)
                    if problems:
                        raise PlanFailure("validation", problems[0])
                    with motion.context("cut", openings={"primary": cw_g}):
                        tr = motion.cartesian({"primary": (pick.T_b1_g, moves[-1] @ pick.T_b1_g)}, q)["primary"]
                    # the carry is planned with the object attached, kept clear by the free-motion margin: an
                    # object lifted beside a taller neighbour still touches it, so lift higher
                    with motion.context("attached", openings={"primary": cw_g}, attach=attach, object_padding=pad):
                        why = motion.problems({"primary": tr.q[-1], "secondary": q["secondary"]})
                    if why:
                        raise PlanFailure("validation", f"lifted {dist * 100:.0f} cm ({how}), the carried object is "
                                                        f"still too close to the scene: {why[0]}")
                    return tr, dist, how, err
                except PlanFailure as e:
                    err = err or e
        return None, 0.0, "", err

    tr, dist, how, err = try_lifts(q)
    carry_pad = OBJECT_PADDING
    if tr is None:
        # at the top of its reach the arm lifts the object no higher than where it is still within the carry's
        # margin of a neighbour: as the last resort, the carry keeps the object about half the free-motion
        # margin less from the scene (the receiver's last resort too; on the task bench a can 49 cm out rose
        # 6 cm, 1.6 cm over the small box beside it)
        carry_pad = OBJECT_PADDING - 0.5 * (motion.world.margin - CONTACT_MARGIN) - 0.002
        tr, dist, how, _ = try_lifts(q, carry_pad)
        if tr is not None:
            plan.info["carry_padding_m"] = carry_pad
    if tr is None:
        raise PlanFailure(err.stage, f"{err.message} (and {len(HANDOVER_LIFTS) * len(dirs) - 1} other lifts: "
                                     f"{', '.join(h for h, _ in dirs[1:])}; up to {max(HANDOVER_LIFTS) * 100:.0f} cm)")
    plan.add(Phase("lift", {"primary": _jt(tr.times, tr.q, CLOSED)}, f"lifted {dist * 100:.0f} cm ({how})",
                   "cartesian"))
    at.append("transfer")
    q, _ = plan.end_state()
    w0 = width_start["secondary"]
    pre_rec = _pre(motion, rec)
    with motion.context("attached", openings={"primary": cw_g, "secondary": w0}, attach=attach,
                        object_padding=carry_pad):
        sols = _goal_ik(motion, "primary", gt.T_b1_g, [gt.q, q["primary"]])
        if all(any("secondary" in w for w in motion.problems({**q, "primary": s_})) for s_ in sols[:4]):
            # the transfer pose brings the object against the waiting secondary: it goes to its pre-grasp
            # in the same motion (out of the way, to where it takes the object over)
            # (opening on the way: checked at the wider of its two openings)
            with motion.context("attached", openings={"primary": cw_g, "secondary": max(w0, wr)}, attach=attach,
                                object_padding=carry_pad):
                sols_r = _goal_ik(motion, "secondary", pre_rec, [rec.q_pre, q_start["secondary"], rec.q])
                goals = [{"primary": s1, "secondary": s2} for s1 in sols[:3] for s2 in sols_r[:3]]
                goals = [g_ for g_ in goals if not motion.problems(g_)] or goals[:1]
                tr = motion.plan_free(["primary", "secondary"], q, goals)
            ts = tr["secondary"].times
            plan.add(Phase("transfer", {"primary": _jt(tr["primary"].times, tr["primary"].q, CLOSED),
                                        "secondary": _jt(ts, tr["secondary"].q, _ramp(ts, w0, wr))},
                           "object carried to the transfer pose; the secondary to its pre-grasp, out of its way",
                           "ompl"))
        else:
            tr = motion.plan_free(["primary"], q, [{"primary": s} for s in sols[:4]])["primary"]
            plan.add(Phase("transfer", {"primary": _jt(tr.times, tr.q, CLOSED)}, "object carried to the transfer pose",
                           "ompl"))

    at.append("receive-reach")
    # 6-8. the secondary takes it
    q, w_now = plan.end_state()
    w0 = w_now["secondary"]  # as it was (or opened to the receiver's width on a two-arm transfer)
    # the pre-grasp, or further back along the same line where its open fingers are within the free-motion
    # margin of the carried object (a pre-grasp the grasping stage kept short near the edge of the reach)
    back = pre_rec[:3, 3] - rec.T_b1_g[:3, 3]
    back = back / max(np.linalg.norm(back), 1e-9)
    # As the last resort (a receiver at the edge of its reach, its pre-grasp short and no further one
    # reachable), its open fingers may come within about half the free-motion margin of the carried object
    # there (its box shrunk): the straight approach that follows passes the fingers that near it anyway
    # (the receiver's clearance, 1 cm a side).
    sols, err, pad = None, None, OBJECT_PADDING
    near_pad = OBJECT_PADDING - 0.5 * (motion.world.margin - CONTACT_MARGIN) - 0.002
    for extra, pad in ((0.0, OBJECT_PADDING), (0.02, OBJECT_PADDING), (0.04, OBJECT_PADDING), (0.0, near_pad)):
        with motion.context("attached", openings={"primary": cw_g, "secondary": wr}, attach=attach,
                            object_padding=pad):
            T_pre = pre_rec.copy()
            T_pre[:3, 3] += extra * back
            try:
                seeds = [q["secondary"], rec.q_pre, q_start["secondary"], rec.q]
                cand = _approachable(motion, "secondary", _goal_ik(motion, "secondary", T_pre, seeds), T_pre, rec.T_b1_g)
            except PlanFailure as e:
                err = err or e
                continue
            # the goals open (checked at the receiver's opening); the way there keeps the gripper as it was:
            # the transfer pose may bring the object near the waiting secondary, whose fingers, opened where
            # it stands, would touch it before it moves
            ok = [s_ for s_ in cand if not motion.problems({**q, "secondary": s_})]
        if ok or sols is None:
            sols, pre_used, pad_used = np.stack(ok or [cand[0]]), T_pre, pad
        if ok:
            break
    if sols is None:
        raise err
    pre_rec = pre_used
    try:
        with motion.context("attached", openings={"primary": cw_g, "secondary": w0}, attach=attach,
                            object_padding=pad_used):
            tr = motion.plan_free(["secondary"], q, [{"secondary": s} for s in sols[:4]])["secondary"]
        times = np.concatenate([tr.times, tr.times[-1] + np.array([0.5 * CLOSE_S, CLOSE_S])])
        jt = _jt(times, np.concatenate([tr.q, [tr.q[-1], tr.q[-1]]]), np.r_[np.full(len(tr.times), w0), 0.5 * (w0 + wr), wr])
    except PlanFailure:  # where the goal needs the fingers open already (they straddle the object's edge)
        with motion.context("attached", openings={"primary": cw_g, "secondary": wr}, attach=attach,
                            object_padding=pad_used):
            tr = motion.plan_free(["secondary"], q, [{"secondary": s} for s in sols[:4]])["secondary"]
        jt = _jt(tr.times, tr.q, _ramp(tr.times, w0, wr))
    plan.add(Phase("receive-reach", {"secondary": jt}, "secondary to its pre-grasp at the transfer pose, opening",
                   "ompl"))
    at.append("receive-approach")
    q, _ = plan.end_state()
    with motion.context("cut", openings={"primary": cw_g, "secondary": wr}):
        tr = motion.cartesian({"secondary": (pre_rec, rec.T_b1_g)}, q)["secondary"]
    plan.add(Phase("receive-approach", {"secondary": _jt(tr.times, tr.q, wr)}, "secondary's straight approach",
                   "cartesian"))
    q, _ = plan.end_state()
    plan.add(Phase("receive-grasp", {"secondary": _still(q["secondary"], wr, CLOSED)},
                   "secondary closes (force limited)", "gripper"))

    # 9-11. the primary lets go and backs off; the secondary holds (checked)
    q, _ = plan.end_state()
    plan.add(Phase("release", {"primary": _still(q["primary"], CLOSED, wl)}, "primary opens", "gripper"))
    q, _ = plan.end_state()
    held_pts = object_points @ choice.T_move[:3, :3].T + choice.T_move[:3, 3]
    held = ("secondary", q["secondary"], held_pts)
    at.append("retreat")
    tr, dist, how = _giver_retreat(motion, gt, q, held, up, {"primary": wl, "secondary": cw_r})
    plan.add(Phase("retreat", {"primary": _jt(tr.times, tr.q, wl)},
                   f"primary backs off {dist * 100:.0f} cm ({how})", "cartesian"))
    at.append("home")
    # the primary goes back to its start; the object, now in the secondary's gripper, is an obstacle
    q, _ = plan.end_state()
    with motion.context("attached", openings={"primary": wl, "secondary": cw_r}, attach=held):
        home_blocked = motion.problems({"primary": q_start["primary"], "secondary": q["secondary"]})
        if not home_blocked:
            tr = motion.plan_free(["primary"], q, [{"primary": q_start["primary"]}])["primary"]
    if home_blocked:  # the object, now held by the secondary, is where the primary started: it stays backed off
        plan.info["home"] = f"skipped: the primary's start pose meets the held object ({home_blocked[0]})"
    else:
        plan.add(Phase("home", {"primary": _jt(tr.times, tr.q, wl)}, "primary back to its start pose", "ompl"))
    q, _ = plan.end_state()
    plan.add(Phase("hold", {"secondary": _jt([0.0, HOLD_S], np.stack([q["secondary"]] * 2), CLOSED)},
                   f"secondary holds the object alone for {HOLD_S:g} s", "hold", check="handover"))
    # where each closed gripper's fingers rest on the object (the whole-plan validation takes them there,
    # as the phases above were planned): the primary from its grasp to its release, the secondary after
    held_by = {"primary": ("grasp", "lift", "transfer", "receive-reach", "receive-approach", "receive-grasp", "release"),
               "secondary": ("receive-grasp", "release", "retreat", "home", "hold")}
    for ph in plan.phases:
        ph.resting = {a: w for a, w in (("primary", cw_g), ("secondary", cw_r)) if ph.name in held_by[a] and w > 0}
    return plan

"""The two tasks as phases: joint grasp (both arms lift one object together) and hand-over.

Every arm motion comes from :class:`~._motion.TaskMotion` (OMPL for free motions, Cartesian IK paths for
straight moves), each validated (limits, velocities, collisions) in the collision context of its phase;
gripper phases keep the arms still. Gripper widths are part of every trajectory, so the plan's timeline
is complete: what the preview simulates is what the hardware would run.

Joint grasp: reach both pre-grasps (12-DoF OMPL query) -> straight approach -> close (pinch) or squeeze
(push: the open fingertips are driven ``press`` past the faces) -> lift: the *object's* motion is planned
(its end pose chosen within both arms' reach, ``kinematics._lift``: up by ``lift`` down to LIFT_MIN, shifted and turned
about the vertical where that brings it within reach), each gripper's pose is that motion applied to its
grasp, IK at every waypoint for both arms on one clock, the object's own clearance checked along it -> hold 2.3 s (checked)
-> place (the reverse) -> release -> retreat.

Hand-over: (the secondary turns aside about its base when it stands in the primary's way) primary reaches,
approaches, closes on the object, lifts 6 cm, carries it (object attached)
to the transfer pose -> secondary reaches its pre-grasp (object attached to the primary, as an obstacle)
-> straight approach -> closes -> primary opens -> retreats 8 cm along its approach -> hold 2.3 s
(checked: held by the secondary only). The giver may also be the secondary (``HandoverChoice.giver``): the same
phases with the arms' roles swapped, the hold then checked as held by the primary only.

Each fallback ladder (a push pair's squeeze depth, the joint lift's end poses in score order, a push pair's back-off, the
secondary's make-way turn, the hand-over's lift and carry padding, the receiver's pre-grasp and its way
there) is a list of named :class:`Strategy` tried in order by :func:`first_success`, each attempt
testable on its own.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from ._grasps import GraspSpec, HandoverChoice, JointChoice
from ._motion import CONTACT_MARGIN, OBJECT_PADDING, PlanFailure, TaskMotion, line_poses, translate_along
from ._plan import Phase, TaskPlan

__all__ = ["plan_joint_grasp", "plan_handover", "LIFT", "HOLD_S", "FALLBACKS"]

# The planner's fallbacks by name: the rungs after a ladder's first. ``TaskOptions.leave_out`` (bench/tasks.py
# --leave-out) leaves them out, to measure what each buys on scenes nobody tuned on (docs/tasks.md, *The
# fallbacks, each left out*); a plan lists those it used in ``info["fallbacks"]``.
FALLBACKS = {
    "lower-joint-lift": "the joint lift's end poses below LIFT, down to LIFT_MIN",
    "make-way": "the receiver first turns about its base out of the giver's way (MAKE_WAY_TURNS)",
    "carry-padding": "the carried object's box shrunk where no lift ends clear of the free-motion margin",
    "receiver-back-off": "the receiver's pre-grasp 2 or 4 cm further back, or with the carried object's box shrunk",
    "skip-home": "the giver stays backed off where its start pose meets the object the receiver holds",
    "open-at-goal": "a gripper whose fingers, opened where it stands, would meet the map moves as it is and opens "
                    "at its goal",
    "preview-redraw": "where every hand-over previewed failed its preview, the grasp stage's search runs again on "
                      "those objects without the picks that failed (grasping.redraw_handovers), for REDRAW_PREVIEWS "
                      "more previews",
}

LIFT = 0.15  # m the joint grasp lifts the object (>= 10 cm needed)
LIFT_MIN = 0.105  # m: the least lift it falls back to at the top of the arms' reach
LIFT_RADIUS = 0.08  # m: the largest horizontal shift of the object's lift (towards where both arms reach it)
LIFT_TRIES_PER_HEIGHT = 3  # straight lift paths tried at each sampled height, best first
LIFT_IK_SEEDS = 1  # IK seeds per sampled lift pose and arm: the previous stage's solution only (continuation)
RETREAT_UP = 0.08  # m of the fallback retreats of a push pair (straight up, or further back from the faces)
# m: a push pair's approach stops this far out from the faces, and the squeeze starts there. The faces'
# depth comes from the segment's points, which miss the last millimetres of an edge (a box's segment comes
# out a few millimetres shorter than the box): an approach from above that ended on the estimated face
# would put the fingertips on the real box's top (docs/tasks.md).
PUSH_STANDOFF = 0.01
# m: a push pair's squeeze goes this much deeper than the grasp's ``press`` past the estimated faces. A
# reconstruction's box comes out wider than the real one (the fused views' faces blur outwards: on the
# task bench's pipeline clouds its width errs by +5.8 to +8.8 mm at the 95th percentile, 138 and 76 studied
# boxes), so pressed only ``press`` past the estimated faces, the fingertips pressed the real box 4-6 mm and
# a 2 kg carton slid out of them (docs/tasks.md). Where the deeper squeeze cannot be planned, the press alone.
PUSH_PRESS_MARGIN = 0.006
HANDOVER_LIFT = 0.06  # m straight up after the pick, before the free carry
HANDOVER_LIFTS = (HANDOVER_LIFT, 0.10, 0.14, 0.04)  # tried in order: higher beside a taller neighbour
RETREAT_MIN = 0.045  # m: the least back-off of the giver that leaves its open fingers clear of the object
HOLD_S = 2.3  # s of the checked hold (2 s needed)
CLOSE_S = 1.0  # s to close a gripper (force limited: it stops on the object)
SETTLE_S = 0.4  # s still after a gripper change
CLOSED = 0.0  # commanded width when closing on an object (the force limit stops the fingers)
ARMS = ("primary", "secondary")
HANDOVER_CHECK = {"secondary": "handover", "primary": "handover-to-primary"}  # receiver -> the hold's check


def _jt(times, q, widths):
    from bimanual_app.hardware import JointTrajectory

    times = np.asarray(times, dtype=np.float64)
    w = np.broadcast_to(np.asarray(widths, dtype=np.float64), times.shape).copy()
    return JointTrajectory(times, np.asarray(q, dtype=np.float64), w)


def _free_opening(motion: TaskMotion, plan: TaskPlan, arms: list, q_now: dict, goals: list[dict], ctx,
                  w_from: dict, w_to: dict) -> list[dict]:
    """The free motion of ``arms`` from ``q_now`` to one of ``goals`` (arm -> (J,)) while each of their
    grippers goes from ``w_from`` to ``w_to`` (arm -> width; ``ctx(openings)`` is the collision context at
    those openings), as phases' trajectories (arm -> JointTrajectory): the motion, and where the grippers
    open at the goal, their opening there.

    The grippers open on the way, the motion checked at the wider of the two widths all along. Where the
    start is not free with them open but is as they are (the fingers, opened where the arm stands, would
    meet the map: points the start's clean-up of the map kept), they move as they are, checked at
    ``w_from``, and open at a goal that is free with them open (fallback ``open-at-goal``). Where no goal is
    free with them open either, the failure names what blocks the goals (another arm in the way is what
    the hand-over's ``make-way`` turns aside), not the start."""
    wide = {a: max(w_from[a], w_to[a]) for a in w_from}

    def opening_on_the_way():
        tr = motion.plan_free(arms, q_now, goals)
        return [{a: _jt(tr[a].times, tr[a].q, _ramp(tr[a].times, w_from[a], w_to[a])) for a in arms}]

    with ctx(wide):
        if not motion.problems(q_now) or not _fallback(motion, "open-at-goal"):
            return opening_on_the_way()
        open_goals = [g for g in goals if not motion.problems({**q_now, **g})]
        if not open_goals:  # the goals are blocked too: that is what to report (an arm in the way makes way)
            why = motion.problems({**q_now, **goals[0]}) if goals else ["no goal"]
            raise PlanFailure("reach", f"{' + '.join(arms)} motion: no goal is free with the gripper open "
                                       f"({why[0]}), nor is the start")
    with ctx(w_from):
        if not motion.problems(q_now):  # (open_goals is not empty: raised above)
            tr = motion.plan_free(arms, q_now, open_goals)
            _used(plan, "open-at-goal")
            return [{a: _jt(tr[a].times, tr[a].q, w_from[a]) for a in arms},
                    {a: _still(tr[a].q[-1], w_from[a], w_to[a]) for a in arms}]
    with ctx(wide):  # not free as they are either: as it was (the start fails)
        return opening_on_the_way()


def _add_opening(plan: TaskPlan, name: str, parts: list[dict], note: str) -> None:
    """The phases of :func:`_free_opening` added to ``plan`` under ``name`` (an opening at the goal is a
    phase of its own: the plan's validation takes each phase's widest opening)."""
    plan.add(Phase(name, parts[0], note, "ompl"))
    for jts in parts[1:]:
        plan.add(Phase(name, jts, "opening at the goal (the fingers met the map where the arm stood)", "gripper"))


def _reversed(tr, widths):
    """A JointTrajectory run backwards (the same states in reverse order, on the same clock), at ``widths``."""
    t = np.asarray(tr.times, dtype=np.float64)
    return _jt(t[-1] - t[::-1], np.asarray(tr.q)[::-1], widths)


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


def _face_gap(motion: TaskMotion, g: GraspSpec, lateral: float = 0.03, cap: float = 0.02) -> float:
    """How far (m) the fingertips of a push contact still are from the object along the squeeze direction:
    the nearest object point (its hull, the body the preview simulates) within ``lateral`` m of the squeeze
    line through the fingertips' contact (``g.contact``; the gripper origin when unknown). The grasping
    stage puts the fingertips on the face at its points' median depth; the first contact is the outermost
    point, so the squeeze is extended by the gap (at most ``cap``) to press ``press`` past it on both sides.

    Measured from the fingertips, not from the gripper origin: that lies half a finger's thickness (and
    more on a tilted gripper) outside the face, and counting it would drive the fingertips centimetres into
    the box, where the pressed finger can catch the box's top edge."""
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
                     base_b1: np.ndarray | None = None, near: float = 0.03) -> list[tuple[str, np.ndarray]]:
    """A picked object's lift directions (unit (3,) in b1), in order of preference.

    Straight up; up and towards the picking arm's base ``base_b1`` (3,; default b1's origin, the primary's)
    (near the edge of the reach); up and away from the
    neighbours it stands beside (map points within ``near`` m of its points, above its bottom): a lift
    straight up beside a taller neighbour slides along it, and where the arm cannot go higher, the carry
    would start too close to it; back out along the approach, where that rises.
    """
    dirs = [("straight up", up)]
    d_base = (np.zeros(3) if base_b1 is None else np.asarray(base_b1, dtype=np.float64)) - T_b1_g[:3, 3]
    to_base = d_base - (d_base @ up) * up
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


def _straight_failure(motion: TaskMotion, arm: str, q: np.ndarray, T0: np.ndarray, T1: np.ndarray,
                      how: str) -> PlanFailure | None:
    """Why ``arm`` at ``q`` (J,), its gripper at T0 (4, 4), cannot move straight to T1 (4, 4), or None: ``how``
    'branch' asks for the IK chain on one branch (``TaskMotion.ik_path``), 'straight' for any move
    ``cartesian`` runs (``TaskMotion.straight``: that chain, else the joints moved directly where the gripper
    keeps to the line)."""
    try:
        if how == "branch":
            motion.ik_path({arm: line_poses(T0, T1)}, {arm: q})
        else:
            motion.straight({arm: (T0, T1)}, {arm: q})
        return None
    except PlanFailure as e:
        return e


def _approachable(motion: TaskMotion, arm: str, sols: np.ndarray, T_pre: np.ndarray, T: np.ndarray) -> np.ndarray:
    """The pre-grasp IK solutions (order kept) from which the straight approach to ``T`` stays on one IK
    branch (so the OMPL goal and the approach that follows it agree); where none does, those from which
    ``cartesian`` runs the approach all the same (the joints moved directly: the line passes a wrist
    singularity, where the IK chain flips the wrist); raises the first solution's failure if none."""
    for how in ("branch", "straight"):
        fails = [_straight_failure(motion, arm, q, T_pre, T, how) for q in sols]
        ok = [q for q, f in zip(sols, fails) if f is None]
        if ok:
            return np.stack(ok)
    raise fails[0]


def _retreatable(motion: TaskMotion, arm: str, sols: np.ndarray, T: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Of the IK solutions ``sols`` (K, J) of gripper pose ``T`` (4, 4), those (order kept) from which the open
    gripper can back off ``RETREAT_MIN`` along one of its retreat directions on one IK branch, else (where
    none can) those from which ``cartesian`` runs such a retreat all the same (``_approachable``); all of them
    when none can (the retreat then reports why).

    A free motion's goal decides the IK branch of the straight moves after it: at a transfer pose, a
    solution with a wrist joint at its limit (the same gripper pose with joints 4 and 6 turned half a turn
    and joint 5 negated) reaches the pose, but no retreat from it stays on its branch."""
    ends = [translate_along(T, d, RETREAT_MIN) for _, d in _retreat_directions(T, up)]
    for how in ("branch", "straight"):
        ok = np.array([any(_straight_failure(motion, arm, q, T, T1, how) is None for T1 in ends) for q in sols],
                      dtype=bool)
        if ok.any():
            return sols[ok]
    return sols


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


@dataclass(frozen=True)
class Strategy:
    """One way to do a step of a plan: its name (what the plan says it did) and the attempt, a callable
    that returns the step's result or raises PlanFailure."""

    name: str
    attempt: Callable[[], object]


class StrategiesFailed(Exception):
    """Every strategy of a ladder failed: ``failures`` holds ``(name, PlanFailure)`` of each, in order."""

    def __init__(self, failures: list[tuple[str, PlanFailure]]):
        self.failures = failures
        super().__init__("; ".join(f"{name}: {e.message}" for name, e in failures) or "no strategy to try")

    @property
    def first(self) -> PlanFailure:
        return self.failures[0][1]

    @property
    def last(self) -> PlanFailure:
        return self.failures[-1][1]

    def combined(self) -> PlanFailure:
        """One failure naming every strategy and its reason, with the stage of the last."""
        return PlanFailure(self.last.stage, "; ".join(f"{name}: {e.message}" for name, e in self.failures))


def first_success(strategies: Iterable[Strategy]) -> tuple[str, object]:
    """Try ``strategies`` in order and return ``(name, result)`` of the first whose attempt does not raise
    PlanFailure (the later ones are not tried). Raises :class:`StrategiesFailed` with the name and reason
    of each failure when none succeeds."""
    failures = []
    for s in strategies:
        try:
            return s.name, s.attempt()
        except PlanFailure as e:
            failures.append((s.name, e))
    raise StrategiesFailed(failures)


def _fallback(motion: TaskMotion, name: str) -> bool:
    """Whether the fallback ``name`` (a key of FALLBACKS) may be tried (it is not in ``motion.leave_out``)."""
    assert name in FALLBACKS, name
    return name not in motion.leave_out


def _used(plan: TaskPlan, name: str) -> None:
    """Record in ``plan.info["fallbacks"]`` that the plan took the fallback ``name``."""
    assert name in FALLBACKS, name
    plan.info.setdefault("fallbacks", []).append(name)


def plan_joint_grasp(motion: TaskMotion, choice: JointChoice, q_start: dict, width_start: dict,
                     lift: float = LIFT, up: np.ndarray | None = None) -> TaskPlan:
    """The joint-grasp plan for ``choice`` from ``q_start`` (arm -> (J,)); raises PlanFailure (its message
    starts with the phase that could not be planned). A push pair squeezes ``PUSH_PRESS_MARGIN`` deeper than
    its press first; where that plan fails from the squeeze on (an arm at the far end of its reach), it is
    planned again at the press alone."""
    margins = (PUSH_PRESS_MARGIN, 0.0) if choice.kind == "push" else (0.0,)
    for margin in margins:
        at = ["reach"]
        try:
            return _joint_grasp(motion, choice, q_start, width_start, lift, up, at, margin)
        except PlanFailure as e:
            failure = PlanFailure(e.stage, f"{at[-1]}: {e.message}")
            if at[-1] in ("reach", "approach"):
                break  # before the squeeze: the press does not change it
    raise failure


@dataclass
class _Pair:
    """A joint grasp's fixed inputs: the grasps per arm and the gripper openings of its phases."""

    motion: TaskMotion
    G: dict  # arm -> GraspSpec
    push: bool  # a push pair (the fingertips squeeze two faces) rather than a pinch pair
    up: np.ndarray  # (3,) up in b1
    press_margin: float = 0.0  # m a push pair's squeeze goes past its grasps' press (PUSH_PRESS_MARGIN)
    w_open: dict = field(init=False)  # arm -> commanded width while open
    w_hold: dict = field(init=False)  # arm -> commanded width while holding
    opening_hold: dict = field(init=False)  # arm -> the fingers' opening while holding (collision checks)

    def __post_init__(self):
        G = self.G
        self.w_open = {a: G[a].width for a in ARMS}
        self.w_hold = {a: (G[a].width if self.push else CLOSED) for a in ARMS}
        self.opening_hold = {a: (G[a].width if self.push else (G[a].contact_width or 0.0)) for a in ARMS}


def _joint_grasp(motion, choice, q_start, width_start, lift, up, at, press_margin=0.0) -> TaskPlan:
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=np.float64)
    plan = TaskPlan({a: np.asarray(q, float) for a, q in q_start.items()}, dict(width_start))
    P = _Pair(motion, {"primary": choice.primary, "secondary": choice.secondary}, choice.kind == "push", up,
              press_margin)
    G = P.G
    plan.info = {"kind": choice.kind, "score": choice.score, **choice.info, "grip": {a: G[a].kind for a in ARMS},
                 "grasps": {a: {"T_b1_g": G[a].T_b1_g, "width": G[a].width, "press": G[a].press} for a in ARMS}}
    if P.push:
        plan.info["press_margin"] = press_margin
    pre = _joint_reach(P, plan, q_start, width_start)
    at.append("approach")
    touch = _joint_approach(P, plan, pre)
    at.append("squeeze")
    S = _joint_grip(P, plan, touch)
    at.append("lift")
    lifted = _joint_lift(P, plan, S, lift)
    # 5. hold (checked)
    q, _ = plan.end_state()
    plan.add(Phase("hold", {a: _jt([0.0, HOLD_S], np.stack([q[a], q[a]]), P.w_hold[a]) for a in ARMS},
                   f"held up for {HOLD_S:g} s", "hold", check="joint-lift"))
    at.append("place")
    # 6. place: the lift's own joint path run backwards, the same poses in reverse (solved again from the top,
    # the path could leave on another IK branch beside a wrist singularity and swing the arm over), then
    # release, retreat
    plan.add(Phase("place", {a: _reversed(lifted[a], P.w_hold[a]) for a in ARMS}, "object set back down (the lift reversed)",
                   "cartesian"))
    at.append("retreat")
    if P.push:
        _push_release(P, plan, S, pre)
    else:
        q, _ = plan.end_state()
        plan.add(Phase("release", {a: _still(q[a], CLOSED, P.w_open[a]) for a in ARMS}, "both grippers open",
                       "gripper"))
        q, _ = plan.end_state()
        with motion.context("cut", openings=P.w_open):
            tr = motion.cartesian({a: (S[a], pre[a]) for a in ARMS}, q)
        plan.add(Phase("retreat", {a: _jt(tr[a].times, tr[a].q, P.w_open[a]) for a in ARMS},
                       "both grippers back off to their pre-grasps", "cartesian"))
    return plan


def _joint_reach(P: _Pair, plan: TaskPlan, q_start: dict, width_start: dict) -> dict:
    """1. Both pre-grasps reached together (12 DoF), the object an obstacle. Returns the pre-grasp poses."""
    motion, G = P.motion, P.G
    pre = {a: _pre(motion, G[a]) for a in ARMS}
    with motion.context("map", openings=P.w_open):
        sols = {a: _approachable(motion, a, _goal_ik(motion, a, pre[a], [G[a].q_pre, q_start[a], G[a].q]), pre[a],
                                 G[a].T_b1_g) for a in ARMS}
        goals = [{"primary": s1, "secondary": s2} for s1 in sols["primary"][:3] for s2 in sols["secondary"][:3]]
        goals = [g for g in goals if not motion.problems(g)] or goals[:1]
    parts = _free_opening(motion, plan, list(ARMS), q_start, goals, lambda op: motion.context("map", openings=op),
                          width_start, P.w_open)
    _add_opening(plan, "reach", parts, "both grippers to their pre-grasps, opening")
    return pre


def _joint_approach(P: _Pair, plan: TaskPlan, pre: dict) -> dict:
    """2. Straight approach to contact (the object is cut out: the fingers meet it); a push pair stops short
    of the faces by PUSH_STANDOFF. Returns the poses reached."""
    motion, G = P.motion, P.G
    q, _ = plan.end_state()
    touch = {a: (translate_along(G[a].T_b1_g, G[a].squeeze_dir, -PUSH_STANDOFF) if P.push else G[a].T_b1_g)
             for a in ARMS}
    with motion.context("cut", openings=P.w_open):
        tr = motion.cartesian({a: (pre[a], touch[a]) for a in ARMS}, q)
    plan.add(Phase("approach", {a: _jt(tr[a].times, tr[a].q, P.w_open[a]) for a in ARMS},
                   f"straight {G['primary'].pre_dist * 100:.0f} cm approach to the object", "cartesian"))
    return touch


def _squeeze_strategies(P: _Pair, touch: dict, q: dict) -> list[Strategy]:
    """A push pair's squeezes, in order: the press (and the pair's ``press_margin``) plus the gap to the faces
    past the contact; where an arm cannot go that far (the far end of its reach), half the gap, then the press
    alone (only the first when there is no gap). Each attempt returns ``(squeeze poses, trajectories)``."""
    gap = {a: _face_gap(P.motion, P.G[a]) for a in ARMS}

    def attempt(f):
        S = {a: translate_along(P.G[a].T_b1_g, P.G[a].squeeze_dir, P.G[a].press + P.press_margin + f * gap[a])
             for a in ARMS}
        with P.motion.context("cut", openings=P.w_open):
            return S, P.motion.cartesian({a: (touch[a], S[a]) for a in ARMS}, q, min_duration=1.0)

    steps = (("press and the gap", 1.0), ("press and half the gap", 0.5), ("press alone", 0.0))
    if max(gap.values()) < 1e-4:
        steps = steps[:1]
    return [Strategy(name, partial(attempt, f)) for name, f in steps]


def _joint_grip(P: _Pair, plan: TaskPlan, touch: dict) -> dict:
    """3. Grip: close (pinch) or squeeze (push). Returns the gripper poses that hold the object."""
    q, _ = plan.end_state()
    if not P.push:
        plan.add(Phase("close", {a: _still(q[a], P.w_open[a], CLOSED) for a in ARMS},
                       "both grippers close (force limited)", "gripper"))
        return {a: P.G[a].T_b1_g for a in ARMS}
    try:
        _, (S, tr) = first_success(_squeeze_strategies(P, touch, q))
    except StrategiesFailed as e:
        raise e.first from None
    plan.add(Phase("squeeze", {a: _jt(tr[a].times, tr[a].q, P.w_open[a]) for a in ARMS},
                   "fingertips pressed into both faces: the object is held between the grippers", "cartesian"))
    return S


def _lift_arms(motion: TaskMotion, q: dict) -> dict:
    """Both arms for the lift search (:class:`~bimanual_app.kinematics.LiftArm`) holding the object at ``q``
    (arm -> (J,)), on the task's IK solvers with ``LIFT_IK_SEEDS`` seeds per target; their solves count in
    ``motion.stats["ik_calls"]``."""
    from bimanual_app.kinematics import LiftArm

    def count(n):
        motion.stats["ik_calls"] += n

    return {a: LiftArm.from_solver(motion.setup.ik_solver(a), np.linalg.inv(motion.setup.T_b1_b(a)), q[a],
                                   LIFT_IK_SEEDS, on_solve=count) for a in ARMS}


def _lift_strategies(P: _Pair, S: dict, q: dict, lift: float) -> Iterable[Strategy]:
    """The object's lifts, best first: end poses of the lift sampled (:func:`~bimanual_app.kinematics._lift.lift_candidates`:
    ``lift`` down to LIFT_MIN, shifted up to LIFT_RADIUS, turned about ``up``), both arms' IK followed
    along all of them in one batch per stage (:func:`~bimanual_app.kinematics._lift.arms_ik`), the ones both arms follow ranked by
    the named costs of ``kinematics._lift.LIFT_COSTS``; those
    whose swept object is clear of the map (along the first of ``kinematics.LIFT_PATHS`` that keeps it clear:
    :func:`_clear_lift_path`) are tried with the straight path both arms follow, at most
    LIFT_TRIES_PER_HEIGHT at each height (failures at one height share their cause: the top of an arm's
    reach). Each attempt returns ``(trajectories, object motion (K,4,4), how, height)``. Raises PlanFailure
    when both arms follow none of the lifts, or every one they follow sweeps the object through the map."""
    from bimanual_app.kinematics import arms_ik, lift_candidates, lift_costs, rank_lifts

    low = min(LIFT_MIN, lift) if _fallback(P.motion, "lower-joint-lift") else lift
    c = lift_candidates(P.motion.object_points.mean(axis=0), P.up, lift, low, radius=LIFT_RADIUS,
                        n_heights=4 if low < lift else 1)
    arms = _lift_arms(P.motion, q)
    ik = arms_ik(arms, S, c)
    order = rank_lifts(c, ik, lift_costs(c, ik, arms))
    if len(order):
        clear = P.motion.grippers_clear(c, S, P.opening_hold, among=order)  # those both arms follow
        if not clear[order].any():
            raise PlanFailure("validation", f"every lift both arms follow ({len(order)}) brings a gripper within "
                                            f"{P.motion.contact_margin * 1000:.0f} mm of the scene map")
        order = order[clear[order]]
    if not len(order):
        short = [a for a in ARMS if not ik[a][1].any()]
        who = f"the {' and '.join(short)} arm" if short else "the two arms together"
        raise PlanFailure("reach", f"{who} cannot follow any lift of the object with the grasps "
                                   f"({len(c)} tried: {c.height.min() * 100:.1f}-{lift * 100:.0f} cm up, "
                                   f"shifted up to {LIFT_RADIUS * 100:.0f} cm, turned up to "
                                   f"{np.degrees(np.abs(c.yaw).max()):.0f} deg)")

    def attempt(T_moves, how, i):
        with P.motion.context("cut", openings=P.opening_hold):
            tr = P.motion.cartesian({a: T_moves @ S[a] for a in ARMS}, q)
        return tr, T_moves, how, float(c.height[i])

    tries: dict = {}
    first_clash = None
    for i in order:
        h = round(float(c.height[i]), 4)
        if tries.get(h, 0) >= LIFT_TRIES_PER_HEIGHT:
            continue
        T_moves, how, clash = _clear_lift_path(P.motion, c, i, P.up)
        if clash:
            first_clash = first_clash or clash
            continue
        tries[h] = tries.get(h, 0) + 1
        yield Strategy(how, partial(attempt, T_moves, how, i))
    if not tries:  # every lift both arms reach sweeps the object through the scene
        raise PlanFailure("validation", first_clash or "no lift to try")


def _clear_lift_path(motion: TaskMotion, c, i: int, up: np.ndarray) -> tuple:
    """The first of ``kinematics.LIFT_PATHS`` to lift candidate ``i``'s end pose along which the swept object
    keeps clear of the map (only the first where the lift neither shifts nor turns: they are the same path).
    Returns ``(T_moves (K,4,4), how, "")``, or ``(None, "", the first path's problem)`` when none is clear."""
    from bimanual_app.kinematics import LIFT_PATHS, object_motion

    moves = np.linalg.norm(c.shift[i]) > 1e-6 or abs(c.yaw[i]) > 1e-9
    first = ""
    for path in LIFT_PATHS if moves else LIFT_PATHS[:1]:
        T_moves = object_motion(c, i, path=path)
        clash = motion.object_clear(T_moves, up=up)
        if not clash:
            return T_moves, ", ".join(p for p in (_lift_name(c, i), path[0]) if p), ""
        first = first or clash[0]
    return None, "", first


def _lift_name(c, i: int) -> str:
    """How candidate ``i`` of :class:`~bimanual_app.kinematics._lift.LiftCandidates` moves the object, in words."""
    parts = [f"up {c.height[i] * 100:.1f} cm"]
    if np.linalg.norm(c.shift[i]) > 1e-4:
        parts.append(f"{np.linalg.norm(c.shift[i]) * 100:.0f} cm sideways")
    if abs(c.yaw[i]) > 1e-6:
        parts.append(f"turned {np.degrees(c.yaw[i]):.0f} deg about the vertical")
    return ", ".join(parts)


def _joint_lift(P: _Pair, plan: TaskPlan, S: dict, lift: float) -> dict:
    """4. Lift: the object's motion, both grippers follow it. Returns the lift phase's trajectories (arm ->
    JointTrajectory)."""
    q, _ = plan.end_state()
    asked = lift
    try:
        _, (tr, T_moves, how, lift) = first_success(_lift_strategies(P, S, q, lift))
    except StrategiesFailed as e:
        raise e.first from None
    if lift < asked - 1e-6:
        _used(plan, "lower-joint-lift")
    lifted = {a: _jt(tr[a].times, tr[a].q, P.w_hold[a]) for a in ARMS}
    plan.add(Phase("lift", lifted, f"object lifted {lift * 100:.0f} cm ({how}), both grippers following it",
                   "cartesian"))
    plan.info["object_motion"] = {"lift_m": lift, "how": how, "T_move_end": T_moves[-1], "waypoints": len(T_moves)}
    return lifted


def _push_retreat_strategies(P: _Pair, U: dict, pre: dict, q: dict) -> list[Strategy]:
    """A push pair's back-offs once the squeeze is undone, in order: to the pre-grasps; where that line is
    blocked, straight up, or further back out of the faces. Each attempt returns the trajectories."""

    def attempt(ends):
        with P.motion.context("cut", openings=P.w_open):
            return P.motion.cartesian({a: (U[a], ends[a]) for a in ARMS}, q)

    return [Strategy("to their pre-grasps", partial(attempt, pre)),
            Strategy("straight up", partial(attempt, {a: translate_along(U[a], P.up, RETREAT_UP) for a in ARMS})),
            Strategy("back from the faces", partial(attempt, {a: translate_along(U[a], P.G[a].squeeze_dir,
                                                                                 -RETREAT_UP) for a in ARMS}))]


def _push_release(P: _Pair, plan: TaskPlan, S: dict, pre: dict) -> None:
    """6. A push pair lets go: the squeeze undone, then the back-off (:func:`_push_retreat_strategies`)."""
    # let go first: the squeeze undone (straight back out of the faces to where the fingertips first
    # touched, the states the squeeze was checked through), so the fingertips stop pressing before the
    # gripper moves along its approach (a tilted approach leaves upwards and, still pressing, would drag
    # the object up with it)
    q, _ = plan.end_state()
    U = {a: P.G[a].T_b1_g for a in ARMS}
    with P.motion.context("cut", openings=P.w_open):
        tr = P.motion.cartesian({a: (S[a], U[a]) for a in ARMS}, q, min_duration=0.6)
    plan.add(Phase("release", {a: _jt(tr[a].times, tr[a].q, P.w_open[a]) for a in ARMS},
                   "fingertips back out of both faces: the object rests on the table", "cartesian"))
    q, _ = plan.end_state()
    try:
        how, tr = first_success(_push_retreat_strategies(P, U, pre, q))
    except StrategiesFailed as e:
        raise e.combined() from None
    plan.add(Phase("retreat", {a: _jt(tr[a].times, tr[a].q, P.w_open[a]) for a in ARMS},
                   f"both grippers back off {how}", "cartesian"))


MAKE_WAY_TURNS = (1.2, -1.2, 0.6, -0.6)  # rad about the receiver's base joint (joint 1), tried in order


def plan_handover(motion: TaskMotion, choice: HandoverChoice, q_start: dict, width_start: dict,
                  object_points: np.ndarray, up: np.ndarray | None = None) -> TaskPlan:
    """The hand-over plan for ``choice`` from ``q_start``; raises PlanFailure (its message starts with the
    phase that could not be planned).

    The giver is ``choice.giver`` (the primary, or the secondary where grasps.json says so), the receiver the
    other arm; below, "primary" and "secondary" stand for giver and receiver. Where the waiting secondary is
    in the primary's way (its reach, approach or lift meet the secondary),
    the plan starts with a ``make-way`` phase: the secondary turns about its base joint by the first of
    ``MAKE_WAY_TURNS`` from which the rest plans.

    ``object_points``: (M,3) the object's points in b1 where it lies (attached to a gripper while carried).
    """
    at = ["reach"]
    try:
        return _handover(motion, choice, q_start, width_start, object_points, up, at)
    except PlanFailure as e:
        first = PlanFailure(e.stage, f"{at[-1]}: {e.message}")
        if (at[-1] not in ("reach", "approach", "lift") or choice.taker not in e.message
                or not _fallback(motion, "make-way")):
            raise first from None
    # the waiting secondary is in the primary's way to the object or up from it (an object beside the
    # secondary's base): it first turns about its base joint, out of the way, and takes the object over
    # from there
    try:
        return first_success(_make_way_strategies(motion, choice, q_start, width_start, object_points, up))[1]
    except StrategiesFailed:
        raise first from None


def _make_way_strategies(motion: TaskMotion, choice: HandoverChoice, q_start: dict, width_start: dict,
                         object_points: np.ndarray, up) -> list[Strategy]:
    """The receiver's turns out of the giver's way (``MAKE_WAY_TURNS``, in order). Each attempt returns
    the whole plan: the turn (a free motion from a start free in the map), then the hand-over from there."""
    g, r = choice.giver, choice.taker
    w_sec = width_start[r]

    def attempt(turn):
        q_aside = np.asarray(q_start[r], dtype=np.float64).copy()
        q_aside[0] += turn
        if not motion.robot.lower[0] <= q_aside[0] <= motion.robot.upper[0]:
            raise PlanFailure("reach", "the turn is beyond the base joint's limits")
        q_from = {**q_start, r: q_aside}
        with motion.context("map", openings={g: width_start[g], r: w_sec}):
            why = motion.problems(q_from)
            if why:
                raise PlanFailure("validation", f"the turned {r} meets the scene: {why[0]}")
            way = motion.plan_free([r], q_start, [{r: q_aside}])[r]
        rest = _handover(motion, choice, q_from, width_start, object_points, up, ["reach"])
        plan = TaskPlan({a: np.asarray(q, float) for a, q in q_start.items()}, dict(width_start), info=rest.info)
        plan.add(Phase("make-way", {r: _jt(way.times, way.q, w_sec)},
                       f"the {r} turns {np.degrees(turn):+.0f} deg about its base, out of the {g}'s way",
                       "ompl"))
        for ph in rest.phases:
            plan.add(ph)
        plan.info["make_way_rad"] = float(turn)
        _used(plan, "make-way")
        return plan

    return [Strategy(f"turn {np.degrees(t):+.0f} deg", partial(attempt, t)) for t in MAKE_WAY_TURNS]


@dataclass
class _Handover:
    """A hand-over's fixed inputs: the grasps, the gripper openings and the carried object."""

    motion: TaskMotion
    choice: HandoverChoice
    object_points: np.ndarray  # (M, 3) where the object lies, b1
    up: np.ndarray  # (3,) up in b1
    q_start: dict
    width_start: dict
    g: str = field(init=False)  # the giver arm's name
    r: str = field(init=False)  # the receiver arm's name
    pick: GraspSpec = field(init=False)  # the giver's grasp where the object lies
    gt: GraspSpec = field(init=False)  # the giver's grasp at the transfer pose
    rec: GraspSpec = field(init=False)  # the receiver's grasp at the transfer pose
    wg: float = field(init=False)  # m: the primary's opening to pick
    wr: float = field(init=False)  # m: the receiver's opening
    wl: float = field(init=False)  # m: the primary's opening as it lets go
    cw_g: float = field(init=False)
    cw_r: float = field(init=False)
    near_pad: float = field(init=False)

    def __post_init__(self):
        c = self.choice
        self.g, self.r = c.giver, c.taker
        self.pick, self.gt, self.rec = c.pick, c.giver_transfer, c.receiver
        self.wg, self.wr = self.pick.width, self.rec.width
        self.wl = min(self.gt.width, self.wg)  # the giver lets go opening this far (no wider than it picked)
        self.cw_g = self.pick.contact_width or 0.0  # the closed fingers' opening on the object
        self.cw_r = self.rec.contact_width or 0.0
        # as the last resort (the carry, a receiver at the edge of its reach), the carried object's box is
        # grown by about half the free-motion margin less
        self.near_pad = OBJECT_PADDING - 0.5 * (self.motion.world.margin - CONTACT_MARGIN) - 0.002


def _handover(motion, choice, q_start, width_start, object_points, up, at) -> TaskPlan:
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=np.float64)
    plan = TaskPlan({a: np.asarray(q, float) for a, q in q_start.items()}, dict(width_start))
    H = _Handover(motion, choice, object_points, up, q_start, width_start)
    plan.info = {"score": choice.score, **choice.info, "giver": H.g, "receiver": H.r, "T_move": choice.T_move,
                 "transfer_centre_b1": (choice.T_move @ np.r_[object_points.mean(0), 1.0])[:3],
                 "grasps": {"pick": {"T_b1_g": H.pick.T_b1_g, "width": H.wg},
                            "giver_transfer": {"T_b1_g": H.gt.T_b1_g},
                            "receiver": {"T_b1_g": H.rec.T_b1_g, "width": H.wr}}}
    q_grasp = _handover_pick(H, plan, at)
    at.append("lift")
    attach = (H.g, q_grasp, object_points)
    carry_pad = _handover_lift(H, plan, attach)
    at.append("transfer")
    pre_rec = _handover_transfer(H, plan, attach, carry_pad)
    at.append("receive-reach")
    pre_rec = _receive_reach(H, plan, attach, pre_rec)
    at.append("receive-approach")
    q, _ = plan.end_state()
    with motion.context("cut", openings={H.g: H.cw_g, H.r: H.wr}):
        tr = motion.cartesian({H.r: (pre_rec, H.rec.T_b1_g)}, q)[H.r]
    plan.add(Phase("receive-approach", {H.r: _jt(tr.times, tr.q, H.wr)}, f"{H.r}'s straight approach",
                   "cartesian"))
    q, _ = plan.end_state()
    plan.add(Phase("receive-grasp", {H.r: _still(q[H.r], H.wr, CLOSED)},
                   f"{H.r} closes (force limited)", "gripper"))
    _giver_lets_go(H, plan, at)
    # where each closed gripper's fingers rest on the object (the whole-plan validation takes them there,
    # as the phases above were planned): the primary from its grasp to its release, the secondary after
    held_by = {H.g: ("grasp", "lift", "transfer", "receive-reach", "receive-approach", "receive-grasp", "release"),
               H.r: ("receive-grasp", "release", "retreat", "home", "hold")}
    for ph in plan.phases:
        ph.resting = {a: w for a, w in ((H.g, H.cw_g), (H.r, H.cw_r))
                      if ph.name in held_by[a] and w > 0}
    return plan


def _handover_pick(H: _Handover, plan: TaskPlan, at: list) -> np.ndarray:
    """1-3. The primary reaches, approaches and closes on the object. Returns its grasp configuration."""
    motion, pick = H.motion, H.pick
    pre_pick = _pre(motion, pick)
    with motion.context("map", openings={H.g: H.wg, H.r: H.width_start[H.r]}):
        sols = _approachable(motion, H.g, _goal_ik(motion, H.g, pre_pick,
                                                         [pick.q_pre, H.q_start[H.g], pick.q]),
                             pre_pick, pick.T_b1_g)
        goals = [{H.g: s} for s in sols[:4]]
    parts = _free_opening(motion, plan, [H.g], H.q_start, goals,
                          lambda op: motion.context("map", openings={H.g: op[H.g], H.r: H.width_start[H.r]}),
                          {H.g: H.width_start[H.g]}, {H.g: H.wg})
    _add_opening(plan, "reach", parts, f"{H.g} to its pre-grasp, opening")
    at.append("approach")
    q, _ = plan.end_state()
    with motion.context("cut", openings={H.g: H.wg}):
        tr = motion.cartesian({H.g: (pre_pick, pick.T_b1_g)}, q)[H.g]
    plan.add(Phase("approach", {H.g: _jt(tr.times, tr.q, H.wg)}, "straight approach", "cartesian"))
    q, _ = plan.end_state()
    q_grasp = q[H.g].copy()
    plan.add(Phase("grasp", {H.g: _still(q_grasp, H.wg, CLOSED)}, f"{H.g} closes (force limited)", "gripper"))
    return q_grasp


def _handover_lift_strategies(H: _Handover, q: dict, dirs: list, attach: tuple, pad: float) -> list[Strategy]:
    """The pick's lifts (``HANDOVER_LIFTS`` x ``dirs``, in that order) with the carried object's box grown by
    ``pad``. Each attempt returns ``(trajectory, distance, how)``: the primary follows it, the object's
    motion is clear of the map, and at its end the attached object is clear of the scene with the
    secondary at ``q``."""
    motion, pick = H.motion, H.pick

    def attempt(dist, how, d):
        n_steps = max(7, int(np.ceil(dist / 0.01)) + 1)
        moves = np.stack([np.eye(4)] * n_steps)
        moves[:, :3, 3] = np.linspace(0.0, dist, n_steps)[:, None] * d
        problems = motion.object_clear(moves, up=H.up)
        if problems:
            raise PlanFailure("validation", problems[0])
        with motion.context("cut", openings={H.g: H.cw_g}):
            tr = motion.cartesian({H.g: (pick.T_b1_g, moves[-1] @ pick.T_b1_g)}, q)[H.g]
        # the carry is planned with the object attached, kept clear by the free-motion margin: an
        # object lifted beside a taller neighbour still touches it, so lift higher
        with motion.context("attached", openings={H.g: H.cw_g}, attach=attach, object_padding=pad):
            why = motion.problems({H.g: tr.q[-1], H.r: q[H.r]})
        if why:
            raise PlanFailure("validation", f"lifted {dist * 100:.0f} cm ({how}), the carried object is "
                                            f"still too close to the scene: {why[0]}")
        return tr, dist, how

    return [Strategy(f"{dist * 100:.0f} cm {how}", partial(attempt, dist, how, d))
            for dist in HANDOVER_LIFTS for how, d in dirs]


def _carry_padding_strategies(H: _Handover, q: dict, dirs: list, attach: tuple) -> list[Strategy]:
    """The carry's padding, in order: the free-motion padding, then (the last resort: at the top of its
    reach the arm lifts the object no higher than where it is still within the carry's margin of a
    neighbour) ``near_pad``. Each attempt returns ``(trajectory, distance, how, padding)`` of the first lift
    (:func:`_handover_lift_strategies`) and fails with the first reason."""

    def attempt(pad):
        try:
            _, r = first_success(_handover_lift_strategies(H, q, dirs, attach, pad))
        except StrategiesFailed as e:
            raise e.first from None
        return (*r, pad)

    return [Strategy("object padding", partial(attempt, OBJECT_PADDING))] + (
        [Strategy("reduced object padding", partial(attempt, H.near_pad))] if _fallback(H.motion, "carry-padding")
        else [])


def _handover_lift(H: _Handover, plan: TaskPlan, attach: tuple) -> float:
    """4. The lift off the table. Returns the padding of the carried object's box the carry keeps."""
    motion = H.motion
    q, _ = plan.end_state()
    # off the table: the object rests on it at the start, so it is checked by itself (its points along the
    # motion against the map) rather than attached (it would touch the table at once); in the directions
    # of _lift_directions, higher, or less far (the carry that follows is planned with the object
    # attached, clear of the table).
    dirs = _lift_directions(motion, H.pick.T_b1_g, H.object_points, H.up, motion.setup.T_b1_b(H.g)[:3, 3])
    with motion.context("cut", openings={H.g: H.cw_g}):
        if motion.problems(q):  # the closed fingers meet points the segment left out: the object's own
            motion.cut_grasped(H.pick.T_b1_g, H.wg)
    try:
        name, (tr, dist, how, carry_pad) = first_success(_carry_padding_strategies(H, q, dirs, attach))
    except StrategiesFailed as e:
        err = e.first
        raise PlanFailure(err.stage, f"{err.message} (and {len(HANDOVER_LIFTS) * len(dirs) - 1} other lifts: "
                                     f"{', '.join(h for h, _ in dirs[1:])}; up to {max(HANDOVER_LIFTS) * 100:.0f} cm)"
                          ) from None
    if name == "reduced object padding":
        plan.info["carry_padding_m"] = carry_pad
        _used(plan, "carry-padding")
    plan.add(Phase("lift", {H.g: _jt(tr.times, tr.q, CLOSED)}, f"lifted {dist * 100:.0f} cm ({how})",
                   "cartesian"))
    return carry_pad


def _handover_transfer(H: _Handover, plan: TaskPlan, attach: tuple, carry_pad: float) -> np.ndarray:
    """5. The carry to the transfer pose (object attached to the primary). Returns the receiver's pre-grasp."""
    motion, rec = H.motion, H.rec
    q, _ = plan.end_state()
    w0 = H.width_start[H.r]
    pre_rec = _pre(motion, rec)
    with motion.context("attached", openings={H.g: H.cw_g, H.r: w0}, attach=attach,
                        object_padding=carry_pad):
        sols = _retreatable(motion, H.g, _goal_ik(motion, H.g, H.gt.T_b1_g, [H.gt.q, q[H.g]])[:4],
                            H.gt.T_b1_g, H.up)
        if not all(any(H.r in w for w in motion.problems({**q, H.g: s_})) for s_ in sols[:4]):
            tr = motion.plan_free([H.g], q, [{H.g: s} for s in sols[:4]])[H.g]
            plan.add(Phase("transfer", {H.g: _jt(tr.times, tr.q, CLOSED)}, "object carried to the transfer pose",
                           "ompl"))
            return pre_rec
        # the transfer pose brings the object against the waiting secondary: it goes to its pre-grasp
        # in the same motion (out of the way, to where it takes the object over)
        # (opening on the way: checked at the wider of its two openings)
        def ctx(op):
            return motion.context("attached", openings={H.g: H.cw_g, H.r: op[H.r]}, attach=attach,
                                  object_padding=carry_pad)

        with ctx({H.r: max(w0, H.wr)}):
            sols_r = _goal_ik(motion, H.r, pre_rec, [rec.q_pre, H.q_start[H.r], rec.q])
            goals = [{H.g: s1, H.r: s2} for s1 in sols[:3] for s2 in sols_r[:3]]
            goals = [g_ for g_ in goals if not motion.problems(g_)] or goals[:1]
        parts = _free_opening(motion, plan, [H.g, H.r], q, goals, ctx, {H.g: CLOSED, H.r: w0},
                              {H.g: CLOSED, H.r: H.wr})
        _add_opening(plan, "transfer", parts, f"object carried to the transfer pose; the {H.r} to its pre-grasp, "
                                              "out of its way")
    return pre_rec


def _receiver_pregrasp_strategies(H: _Handover, q: dict, attach: tuple, pre_rec: np.ndarray,
                                  fallback: list) -> list[Strategy]:
    """The receiver's pre-grasps, in order: its own; 2 cm, then 4 cm further back along the same line, where
    its open fingers are within the free-motion margin of the carried object (a pre-grasp the grasping stage
    kept short near the edge of the reach); as the last resort (a receiver at the edge of its reach, its
    pre-grasp short and no further one reachable), its own with the carried object's box shrunk to
    ``near_pad``: the straight approach that follows passes the fingers that near it anyway.

    Each attempt returns ``(solutions (S, J), pre-grasp, padding)`` with the solutions from which the
    approach stays on one IK branch and whose goal is free; one with solutions none of which is free fails,
    the first such is appended to ``fallback`` as ``(solutions[:1], pre-grasp, padding)``."""
    motion, rec = H.motion, H.rec
    back = pre_rec[:3, 3] - rec.T_b1_g[:3, 3]
    back = back / max(np.linalg.norm(back), 1e-9)

    def attempt(extra, pad):
        with motion.context("attached", openings={H.g: H.cw_g, H.r: H.wr}, attach=attach,
                            object_padding=pad):
            T_pre = pre_rec.copy()
            T_pre[:3, 3] += extra * back
            seeds = [q[H.r], rec.q_pre, H.q_start[H.r], rec.q]
            cand = _approachable(motion, H.r, _goal_ik(motion, H.r, T_pre, seeds), T_pre, rec.T_b1_g)
            # the goals open (checked at the receiver's opening); the way there keeps the gripper as it was:
            # the transfer pose may bring the object near the waiting secondary, whose fingers, opened where
            # it stands, would touch it before it moves
            why = [motion.problems({**q, H.r: s_}) for s_ in cand]
        ok = [s_ for s_, w in zip(cand, why) if not w]
        if not ok:
            if not fallback:
                fallback.append((np.stack([cand[0]]), T_pre, pad))
            raise PlanFailure("validation", f"no pre-grasp solution is free: {why[0][0]}")
        return np.stack(ok), T_pre, pad

    rungs = (("its pre-grasp", 0.0, OBJECT_PADDING), ("2 cm further back", 0.02, OBJECT_PADDING),
             ("4 cm further back", 0.04, OBJECT_PADDING), ("its pre-grasp, the object's box shrunk", 0.0, H.near_pad))
    return [Strategy(name, partial(attempt, extra, pad))
            for name, extra, pad in rungs[:None if _fallback(motion, "receiver-back-off") else 1]]


def _receive_reach_strategies(H: _Handover, q: dict, attach: tuple, sols: np.ndarray, pad: float,
                              w0: float) -> list[Strategy]:
    """The receiver's way to its pre-grasp, in order: its gripper as it was, opening once there; where the
    goal needs the fingers open already (they straddle the object's edge), opening on the way. Each attempt
    returns the secondary's joint trajectory."""
    motion = H.motion

    def plan_to_goals(opening):
        with motion.context("attached", openings={H.g: H.cw_g, H.r: opening}, attach=attach,
                            object_padding=pad):
            return motion.plan_free([H.r], q, [{H.r: s} for s in sols[:4]])[H.r]

    def open_there():
        tr = plan_to_goals(w0)
        times = np.concatenate([tr.times, tr.times[-1] + np.array([0.5 * CLOSE_S, CLOSE_S])])
        return _jt(times, np.concatenate([tr.q, [tr.q[-1], tr.q[-1]]]),
                   np.r_[np.full(len(tr.times), w0), 0.5 * (w0 + H.wr), H.wr])

    def open_on_the_way():
        tr = plan_to_goals(H.wr)
        return _jt(tr.times, tr.q, _ramp(tr.times, w0, H.wr))

    return [Strategy("opening at the pre-grasp", open_there), Strategy("opening on the way", open_on_the_way)]


def _receive_reach(H: _Handover, plan: TaskPlan, attach: tuple, pre_rec: np.ndarray) -> np.ndarray:
    """6. The secondary to its pre-grasp at the transfer pose. Returns the pre-grasp used."""
    q, w_now = plan.end_state()
    w0 = w_now[H.r]  # as it was (or opened to the receiver's width on a two-arm transfer)
    fallback: list = []
    try:
        how, (sols, pre_used, pad_used) = first_success(_receiver_pregrasp_strategies(H, q, attach, pre_rec, fallback))
        if how != "its pre-grasp":
            _used(plan, "receiver-back-off")
    except StrategiesFailed as e:
        if not fallback:  # no pre-grasp had a solution
            raise e.first from None
        sols, pre_used, pad_used = fallback[0]
    try:
        _, jt = first_success(_receive_reach_strategies(H, q, attach, sols, pad_used, w0))
    except StrategiesFailed as e:
        raise e.last from None
    plan.add(Phase("receive-reach", {H.r: jt}, f"{H.r} to its pre-grasp at the transfer pose, opening",
                   "ompl"))
    return pre_used


def _giver_lets_go(H: _Handover, plan: TaskPlan, at: list) -> None:
    """9-11. The primary lets go, backs off and goes home (where it can); the secondary holds (checked)."""
    motion = H.motion
    q, _ = plan.end_state()
    plan.add(Phase("release", {H.g: _still(q[H.g], CLOSED, H.wl)}, f"{H.g} opens", "gripper"))
    q, _ = plan.end_state()
    held_pts = H.object_points @ H.choice.T_move[:3, :3].T + H.choice.T_move[:3, 3]
    held = (H.r, q[H.r], held_pts)
    at.append("retreat")
    tr, dist, how = _giver_retreat(motion, H.gt, q, held, H.up, {H.g: H.wl, H.r: H.cw_r})
    plan.add(Phase("retreat", {H.g: _jt(tr.times, tr.q, H.wl)},
                   f"{H.g} backs off {dist * 100:.0f} cm ({how})", "cartesian"))
    at.append("home")
    # the primary goes back to its start; the object, now in the secondary's gripper, is an obstacle
    q, _ = plan.end_state()
    with motion.context("attached", openings={H.g: H.wl, H.r: H.cw_r}, attach=held):
        home_blocked = motion.problems({H.g: H.q_start[H.g], H.r: q[H.r]})
        if not home_blocked:
            tr = motion.plan_free([H.g], q, [{H.g: H.q_start[H.g]}])[H.g]
    if home_blocked and not _fallback(motion, "skip-home"):
        raise PlanFailure("validation", f"the {H.g}'s start pose meets the held object ({home_blocked[0]})")
    if home_blocked:  # the object, now held by the secondary, is where the primary started: it stays backed off
        plan.info["home"] = f"skipped: the {H.g}'s start pose meets the held object ({home_blocked[0]})"
        _used(plan, "skip-home")
    else:
        plan.add(Phase("home", {H.g: _jt(tr.times, tr.q, H.wl)}, f"{H.g} back to its start pose", "ompl"))
    q, _ = plan.end_state()
    plan.add(Phase("hold", {H.r: _jt([0.0, HOLD_S], np.stack([q[H.r]] * 2), CLOSED)},
                   f"{H.r} holds the object alone for {HOLD_S:g} s", "hold", check=HANDOVER_CHECK[H.r]))

"""Grasp planning for a whole segmented scene: per object, single-arm grasps, joint pairs and a hand-over.

For each object (label >= 0):

1. its geometry (gravity-aligned box, surface points and normals) and the checks that rule out every
   single-arm grasp (too few points, narrower than the fingers resolve, wider than the stroke);
2. antipodal grasps against the rest of the scene map (``_antipodal``), then each arm's reach filter on
   them, best first, in that arm's own base frame; when no arm reaches any, a second, denser round;
3. its *mode*: ``joint`` when it is wider than the stroke, longer than ``large_extent`` or heavier (box
   volume x ``density``) than one arm's ``payload``; ``single`` otherwise;
4. for ``joint`` objects, two-arm pairs (``_joint``): push pairs on opposite faces and pinch pairs at the
   two ends; for ``single`` objects with both arms known, a hand-over (``_handover``).

Every grasp in the result has passed the collision checks, and -- when arms are given -- the reach
filter of the arm it is listed for; nothing unchecked is returned.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np

from bimanual_app.io_utils import InputError, Problem

from ._antipodal import GraspSet, SamplerParams, sample_grasps
from ._arms import Arm, ArmGrasps, TwoArmCheck, lifting_arm, reachable_by_group, reachable_grasps
from ._collision import GripperCollider, SceneOctree
from ._gripper import GripperModel
from ._handover import (
    ARM_NAMES,
    Handover,
    HandoverParams,
    handover_givers,
    other_arm,
    plan_handovers,
    waiting_receiver_last,
)
from ._inputs import SceneCloud
from ._joint import JointPair, PairLift, joint_pairs, spread_order
from ._objects import (
    WALLS_MIN_SIDE,
    ObjectGeometry,
    Support,
    check_graspable,
    closed_geometry,
    complete_walls,
    estimate_support,
    object_geometry,
    primitive_fit,
    unseen_space,
)
from ._push import PushParams, open_ends, push_contacts
from ._unseen import carved_unseen

__all__ = ["PlanParams", "ObjectPlan", "GraspPlan", "plan_grasps", "plan_object"]


@dataclass(frozen=True)
class PlanParams:
    """Scene-level parameters (metres, kilograms).

    octree_resolution: voxel size of the scene map the gripper is checked against. 5 mm, with the sampler's
        3 mm ``scene_margin``: the task planner's map and contact margin (``bimanual_app.tasks``:
        ``MAP_RESOLUTION``, ``CONTACT_MARGIN``), on the same octree cells (octomap's grid is fixed in b1) and
        with more points (the task also cuts the map within 1.5 cm of the object), so a grasp accepted here
        is never refused by the task's check of the same straight approach. With 3 mm / 2 mm, fingers that
        pass 3-5 mm over the table were accepted here and then touched the task's map.
    reach_tries / reach_want: grasps checked by each arm's reach filter, and enough reachable ones to stop.
    push_tries_per_face / push_want_per_face: each face's push contacts are checked for reach until
        ``push_want_per_face`` pass, or ``push_tries_per_face`` were tried (None: all of them), at each place
        across the face (``PushParams.laterals``) on its own. All by default:
        the check is closed-form IK (about 0.5 ms a contact), and an arm pushing the face of a large box a
        hand's width from its own base reaches 1-2 % of that face's contacts, often none of the first 30.
    push_spread: push contacts are checked for reach best first, but first those this far (m) from every
        better one on the same face (``spread_order``): the reachable contacts, and the pairs of them, are
        then several places on each face, not one place found again a few millimetres away.
    large_extent: objects longer than this (horizontally) need two arms.
    density, payload: mass estimate (box volume x density) and the most one arm lifts.
    min_object_points: fewer points than this is an empty segment.
    joint_for_all: also look for two-arm pairs on objects one arm can lift (when they are long enough).
    max_joint_pairs: two-arm pairs kept per kind (push, pinch).
    open_end_shift: an object with an open end (a face no camera saw, nothing seen beyond it: a carton whose far
        end was out of view) may be longer than its seen box; a two-arm squeeze is balanced about any place of
        its centre up to this fraction of its seen length towards that end (0: only the seen box's centre).
    joint_lift_check: two-arm grasps are first looked for among those both arms can also carry this far
        straight up (the task's lifts are 11-15 cm); 0 turns the check off.
    handover: plan a hand-over for objects one arm can lift (needs both arms).
    handover_givers: the arms that may give in a hand-over, in order of preference: an object is searched
        with the next one only when the one before finds no hand-over for it (or reaches none of its picks);
        the primary gives by default, the secondary where the primary cannot (an object only the secondary
        reaches). ``("primary",)``: the primary always gives.
    workspace_radius: background points farther than this from every base (horizontally) are dropped.
    retry_factor: when no arm (or not the primary, which picks) reaches any grasp of an object, sample again
        with this many times the candidates, hinted by the lacking arms (and twice the reach budget); 1
        turns it off.
    unseen_radius: when > 0 (m), the space within this distance of an object that no camera saw into
        (neither table nor another object seen there, in a direction where the object's side was not seen:
        ``_objects.unseen_space``) is solid for its single-arm grasps and a hand-over's receiver: the
        object may go on there (seen from one side, a 7.5 cm cylinder is a 3.5 cm shell). Not for the push
        contacts of large objects, whose box their seen top fixes. Off by default: at 0.05 it cost the
        grasping bench 4 graspable small boxes (touching a carton, their side against it unseen) and the
        task bench one hand-over (docs/grasping.md).
    carve_radius: when > 0 (m) and the cloud has the capture's depth views, the cells within this distance
        of an object that no camera saw past (``_unseen.carved_unseen``: a mug's handle on its far side may be
        there) are solid for a first hand-over search (``_clear_of_unseen``: the giver's picks and the
        receiver's grasps drawn again with them solid); where it finds none, the search runs as without them.
        Not solid for every grasp: wrist cameras on two arms leave much of the space around most objects
        unseen (their far sides, the air they hide), and solid, it took every grasp of most objects of the
        bench's captures (docs/grasping.md).
    """

    sampler: SamplerParams = SamplerParams()
    push: PushParams = PushParams()
    handover_params: HandoverParams = HandoverParams()
    octree_resolution: float = 0.005
    reach_tries: int = 40
    push_tries_per_face: int | None = None
    push_spread: float = 0.03
    push_want_per_face: int = 4
    reach_want: int = 10
    large_extent: float = 0.25
    density: float = 400.0
    payload: float = 1.2
    min_object_points: int = 30
    joint_for_all: bool = False
    joint_min_extent: float = 0.15
    handover: bool = True
    handover_givers: tuple[str, ...] = ARM_NAMES
    max_joint_pairs: int = 5
    open_end_shift: float = 0.25
    joint_lift_check: float = 0.12
    workspace_radius: float = 1.0
    retry_factor: int = 4
    unseen_radius: float = 0.0
    carve_radius: float = 0.03

    def __post_init__(self):
        bad = [a for a in self.handover_givers if a not in ARM_NAMES]
        if bad or len(set(self.handover_givers)) != len(self.handover_givers):
            raise ValueError(f"PlanParams.handover_givers: {tuple(self.handover_givers)!r} must name 'primary' and/or "
                             "'secondary', each once, in order of preference")


@dataclass
class ObjectPlan:
    """Everything planned for one object.

    geometry: its ObjectGeometry (None for an empty segment). mode: ``"single"``, ``"joint"`` or ``"none"``.
    problems: why single-arm (or all) grasps are impossible. notes: other messages for the user.
    grasps: collision-free antipodal grasps, scored, best first (reach not yet applied).
    reach: arm name -> ArmGrasps (the grasps that arm reaches). push: push contacts (joint objects) and
    push_reach: arm name -> ArmGrasps of them; pinch_reach: arm name -> ArmGrasps of the pinches towards the
    two ends (for pinch pairs). joint: JointPair list (``pair_grasps`` gives the grasp sets they index).
    handover: Handover or None (the best found). handover_alternatives: further hand-overs with another
    giver grasp or transfer pose (``HandoverParams.alternatives``), for the task to fall back on.
    unseen: (K, 3) points filling the space around the object no camera saw into (``PlanParams.unseen_radius``).
    carved: (K, 3) centres of the cells near the object that no camera of the capture saw past
        (``PlanParams.carve_radius``; empty without the capture's depth views): hand-overs are searched first
        with the picks and receivers whose swept gripper keeps out of them.
    shape, shape_fit: ``"box"``, ``"cylinder"`` or ``"free-form"`` and the share of the seen points that fit the
        primitive (``_objects.primitive_fit``): whether the cloud determines the object's shape.
    stats, timings: counts and seconds per stage.
    """

    id: int
    geometry: ObjectGeometry | None
    mode: str
    problems: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    grasps: GraspSet | None = None
    reach: dict = field(default_factory=dict)
    push: GraspSet | None = None
    push_reach: dict = field(default_factory=dict)
    pinch_reach: dict = field(default_factory=dict)
    joint: list = field(default_factory=list)
    handover: Handover | None = None
    handover_alternatives: list = field(default_factory=list)
    giver_picks: GraspSet | None = None  # the grasps ``handover.givers.index`` points into: grasps (then shallow holds)
    free_grasps: GraspSet | None = None
    unseen: np.ndarray | None = None
    carved: np.ndarray | None = None
    open_ends: list = field(default_factory=list)  # outward normals (3,) of faces it may go on past (_push.open_ends)
    shape: str = "free-form"
    shape_fit: float = 0.0
    mass_estimate: float = 0.0
    stats: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    #: giver arm -> a hand-over search from it with fresh grasp draws, run by ``plan_grasps`` only when no
    #: object has a hand-over from that giver or one before it (``_redraw_where_none``)
    redraws: dict = field(default_factory=dict, repr=False, compare=False)

    def pair_grasps(self, pair: JointPair) -> tuple[ArmGrasps, ArmGrasps]:
        """The primary's and the secondary's reachable grasp sets a joint pair indexes into."""
        src = self.push_reach if pair.kind == "push" else self.pinch_reach
        return src["primary"], src["secondary"]


@dataclass
class GraspPlan:
    """The plan for a scene: the table, the arms used, and one ObjectPlan per object."""

    support: Support
    gripper: GripperModel
    objects: list[ObjectPlan]
    arms: list[str]
    T_b1_b2: np.ndarray | None
    params: PlanParams
    timings: dict = field(default_factory=dict)


def _log_default(msg: str) -> None:
    pass


def plan_object(k: int, cloud: SceneCloud, support: Support, gripper: GripperModel, collider: GripperCollider,
                arms: dict[str, Arm] | None, T_b1_b2: np.ndarray | None, params: PlanParams,
                source: str = "segments", log: Callable[[str], None] = _log_default) -> ObjectPlan:
    """Plan grasps for object ``k`` of ``cloud`` (see the module docstring)."""
    t0 = time.perf_counter()
    mask = cloud.labels == k
    n = int(mask.sum())
    if n < params.min_object_points:
        pr = Problem(source, f"object {k}", f"segment has {n} point(s); at least {params.min_object_points} are needed",
                     "check the segmentation (an empty or speck segment), or capture the object from more views")
        return ObjectPlan(k, None, "none", [pr])
    geo = object_geometry(k, cloud.points[mask], support, voxel=params.sampler.ray_radius * 0.75,
                          background=cloud.points[cloud.labels < 0], others=cloud.points[(cloud.labels >= 0) & ~mask])
    plan = ObjectPlan(k, geo, "single")
    plan.shape, plan.shape_fit = primitive_fit(geo, support, views=cloud.views)
    sp = params.sampler
    max_cw = sp.max_contact_width(gripper)
    plan.problems = check_graspable(geo, max(sp.min_width, gripper.min_width + 2 * sp.min_clearance), max_cw, source,
                                    params.min_object_points)
    too_wide = any("wider than" in p.message for p in plan.problems)
    mass = float(np.prod(geo.extent) * params.density)
    plan.mass_estimate = mass
    long_side = float(np.max(geo.extent[:2]))
    if too_wide or long_side > params.large_extent or mass > params.payload:
        plan.mode = "joint"
        why = ("wider than the stroke" if too_wide else f"{long_side * 100:.0f} cm long" if long_side > params.large_extent
               else f"about {mass:.1f} kg (box volume x {params.density:g} kg/m^3) > {params.payload:g} kg payload")
        plan.notes.append(f"needs two arms: {why}")
    if plan.problems and not too_wide:
        plan.mode = "none"
        return plan
    # the rest of the scene near the object: all the swept gripper can touch (fingers, palm, approach)
    others_pts = cloud.points[~mask]
    near = np.linalg.norm(others_pts - geo.centre, axis=1) < 0.5 * float(np.linalg.norm(geo.extent)) + 0.3
    others_pts, others_lab = others_pts[near], cloud.labels[~mask][near]
    others = SceneOctree(others_pts, params.octree_resolution)
    plan.open_ends = open_ends(geo, others, params.push)  # seen only in part: its box may be cut short
    plan.unseen, plan.carved = np.zeros((0, 3)), np.zeros((0, 3))
    obs = geo.observed if geo.observed is not None else np.ones(len(geo.points), bool)  # the seen points
    if params.carve_radius > 0 and cloud.views is not None and not too_wide:
        plan.carved = carved_unseen(geo.points[obs], others_pts, support, cloud.views, radius=params.carve_radius)
    if params.unseen_radius > 0 and not too_wide:
        # only in the directions where the object's own side was not seen (its seen points and normals)
        plan.unseen = unseen_space(geo.points[obs], others_pts[others_lab < 0], others_pts[others_lab >= 0],
                                   support, params.unseen_radius, normals=geo.normals[obs])
        plan.stats["unseen_points"] = int(len(plan.unseen))
    blocked = SceneOctree(np.concatenate([others_pts, plan.unseen]), params.octree_resolution) if len(plan.unseen) \
        else others
    arms = dict(arms or {})
    _single_or_walled(plan, support, gripper, collider, blocked, arms, params, too_wide, long_side)
    if "primary" in arms and "secondary" in arms:
        robot = getattr(arms["primary"].reach, "robot", None)
        check = TwoArmCheck(robot, gripper, arms["secondary"].T_b1_b) if robot is not None else None
        if plan.mode == "joint" or (params.joint_for_all and long_side >= params.joint_min_extent):
            t1 = time.perf_counter()
            _joint(plan, support, gripper, collider, others, arms, check, params, long_side)
            plan.timings["joint"] = time.perf_counter() - t1
        givers = [a for a in params.handover_givers if len(plan.reach.get(a, []))]  # those reaching a pick
        if plan.mode == "single" and params.handover and givers:
            t1 = time.perf_counter()
            _handover(plan, support, gripper, collider, arms, check, params, cloud.points[~mask], blocked, givers)
            plan.timings["handover"] = time.perf_counter() - t1
    elif arms:
        plan.notes.append("secondary arm unknown (no T_b1_b2): no joint grasps or hand-over")
    plan.timings["total"] = time.perf_counter() - t0
    log(f"object {k}: {plan.mode}, {len(plan.grasps) if plan.grasps is not None else 0} grasps, "
        + ", ".join(f"{a}: {len(g)} reachable" for a, g in plan.reach.items())
        + (f", {len(plan.joint)} joint pair(s)" if plan.joint else "")
        + (", hand-over found" if plan.handover is not None else "")
        + f" ({plan.timings['total']:.2f} s)")
    return plan


def _single_or_walled(plan: ObjectPlan, support: Support, gripper: GripperModel, collider: GripperCollider,
                      others: SceneOctree, arms: dict[str, Arm], params: PlanParams, too_wide: bool,
                      long_side: float) -> None:
    """:func:`_single`, and where it finds no grasp on a box seen from above (:func:`_walls_wanted`), again with
    the box's side walls filled in: such a box has few points on its sides (no antipodal pair, or fingers closing
    on a handful of edge points), and its walls stand under its top's outline down to the table."""
    n_notes = len(plan.notes)
    _single(plan, support, gripper, collider, others, arms, params, too_wide, long_side)
    if _walls_wanted(plan, support):
        plan.geometry = complete_walls(plan.geometry, support)
        plan.mode, plan.notes = "single", plan.notes[:n_notes]  # the first round's "no grasp" note goes
        plan.notes.append("no grasp on its seen points: its box's side walls (unseen) filled in under its top's outline")
        _single(plan, support, gripper, collider, others, arms, params, too_wide, long_side)


def _walls_wanted(plan: ObjectPlan, support: Support) -> bool:
    """Whether a single-arm object found no collision-free grasp on its seen points and is a box standing on
    the table whose side walls were not completed (:func:`complete_walls`: only cartons get them up front, as
    walls assumed where a small box's faces were not seen change the grasps of the boxes that had good ones)."""
    geo = plan.geometry
    if plan.mode != "none" or plan.shape != "box" or plan.grasps is None or len(plan.grasps):
        return False
    bottom = float(support.elevation(geo.centre[None])[0]) - 0.5 * float(geo.extent[2])
    return abs(bottom) < 1e-3 and min(geo.extent[0], geo.extent[1]) < WALLS_MIN_SIDE


def _workspace(cloud: SceneCloud, arms: dict[str, Arm] | None, radius: float) -> SceneCloud:
    """The cloud without background points farther than ``radius`` (horizontally) from every arm base.

    Object points are all kept (labels keep their meaning); far background (the floor and walls of a
    room) only slows the collision maps down and can mislead the table fit.
    """
    bases = [np.zeros(3)] + ([a.T_b1_b[:3, 3] for a in arms.values()] if arms else [])
    d = np.min([np.linalg.norm(cloud.points[:, :2] - b[:2], axis=1) for b in bases], axis=0)
    keep = (cloud.labels >= 0) | (d <= radius)
    if keep.all():
        return cloud
    # replace(): the cloud's other fields (plane, source, views, any added later) are kept as they are
    return replace(cloud, points=cloud.points[keep], labels=cloud.labels[keep],
                   colors=None if cloud.colors is None else cloud.colors[keep])


def _balanced_hints(per_arm: list[np.ndarray]) -> np.ndarray | None:
    """One (K, 3) set of approach hints in which each arm's (a list of (K_i, 3)) is equally represented
    (each repeated up to the largest count): the sampler draws hints at random, and an arm at the far end
    of its reach has a few where the nearer arm has hundreds. None when there are none."""
    per_arm = [h for h in per_arm if len(h)]
    if not per_arm:
        return None
    n = max(len(h) for h in per_arm)
    return np.concatenate([h[np.arange(n) % len(h)] for h in per_arm])


def _single(plan: ObjectPlan, support: Support, gripper: GripperModel, collider: GripperCollider,
            others: SceneOctree, arms: dict[str, Arm], params: PlanParams, too_wide: bool, long_side: float) -> None:
    """Antipodal grasps of the object and each arm's reachable ones (a denser second round when none)."""
    geo, sp = plan.geometry, params.sampler
    hints = _balanced_hints([a.reach.approach_hints(geo.centre) for a in arms.values() if hasattr(a.reach, "approach_hints")])
    t1 = time.perf_counter()
    if too_wide:
        plan.grasps = GraspSet.empty(plan.id)
    else:
        # a long object keeps more grasps: the best-scored ones sit in the middle, a two-arm pinch needs the ends
        sp_obj = replace(sp, max_keep=3 * sp.max_keep) if long_side >= params.joint_min_extent else sp
        plan.grasps, plan.stats["sampler"] = sample_grasps(geo, support, gripper, collider, others, sp_obj,
                                                           approach_hints=hints)
    plan.timings["sample"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    for name, arm in arms.items():
        plan.reach[name] = reachable_grasps(plan.grasps, arm, params.reach_tries, params.reach_want)
    plan.timings["reach"] = time.perf_counter() - t1
    lacking = [name for name, ag in plan.reach.items() if not len(ag)]
    if (arms and not too_wide and params.retry_factor > 1 and (len(lacking) == len(arms) or "primary" in lacking)
            and plan.stats["sampler"]["pairs"] > 0):
        # cluttered or awkward: no grasp an arm reaches among the first candidates (or the primary, which
        # picks, reaches none: an object at the far end of its reach, which only grasps tilted away from its
        # base reach, while the first round's hints were mostly the nearer arm's). Sample again, denser
        # (collision-free grasps are rare there), with the lacking arms' approach hints, and give the reach
        # filters a larger budget.
        t1 = time.perf_counter()
        retry_hints = _balanced_hints([arms[n].reach.approach_hints(geo.centre) for n in lacking
                                       if hasattr(arms[n].reach, "approach_hints")])
        retry_hints = hints if retry_hints is None else retry_hints
        dense = replace(sp, n_candidates=sp.n_candidates * params.retry_factor, max_keep=2 * sp.max_keep, seed=sp.seed + 1)
        more, plan.stats["sampler_retry"] = sample_grasps(geo, support, gripper, collider, others, dense,
                                                          approach_hints=retry_hints)
        both = GraspSet.concat([plan.grasps, more]) if len(plan.grasps) else more
        plan.grasps = both.take(np.argsort(-both.score, kind="stable"))
        for name, arm in arms.items():
            plan.reach[name] = reachable_grasps(plan.grasps, arm, 2 * params.reach_tries, params.reach_want)
        plan.timings["retry"] = time.perf_counter() - t1
    if arms:
        plan.stats["reach"] = {n: {"reachable": len(a), "tried": a.tried, "why_not": a.reasons} for n, a in plan.reach.items()}
    if too_wide:
        return
    if len(plan.grasps) == 0:
        st = plan.stats.get("sampler_retry", plan.stats["sampler"])
        plan.notes.append(f"no collision-free antipodal grasp among {st['candidates']} candidates"
                          f" ({st['pairs']} antipodal contact pairs)")
        if plan.mode == "single":
            plan.mode = "none"
    elif arms and not any(len(a) for a in plan.reach.values()):
        reasons: dict[str, int] = {}
        for a in plan.reach.values():
            for r, c in a.reasons.items():
                reasons[r] = reasons.get(r, 0) + c
        top = max(reasons, key=reasons.get) if reasons else "unreachable"
        plan.notes.append(f"none of the {len(plan.grasps)} collision-free grasps is reachable (most often: {top})")
        if plan.mode == "single":
            plan.mode = "none"


def _joint(plan: ObjectPlan, support: Support, gripper: GripperModel, collider: GripperCollider, others: SceneOctree,
           arms: dict[str, Arm], check: TwoArmCheck | None, params: PlanParams, long_side: float) -> None:
    """Two-arm pairs: push pairs on opposite faces, and pinch pairs towards the two ends of a long object.

    Each arm's grasps are first checked with ``lifting_arm`` (the arm must also carry the grasp
    ``params.joint_lift_check`` straight up): a pair the arms cannot lift is no two-arm grasp. When that
    leaves no pair, the plain reach check is used, and the task's planner tries other lifts.
    """
    geo = plan.geometry
    plan.stats["push"] = {}
    bases = np.array([a.T_b1_b[:3, 3] for a in arms.values()]) if arms else None
    push = push_contacts(geo, support, gripper, collider, others, params.push, plan.stats["push"], bases)
    if len(push) and params.push_spread > 0:  # the reach budget goes to several places on each face
        push = push.take(spread_order(push.extra["contact"], push.extra["face"], params.push_spread))
    plan.push = push
    span = _centre_span(geo, plan.open_ends, params)
    if span is not None:
        shift = float(np.linalg.norm(span))
        plan.stats["open_end_shift_m"] = shift
        plan.notes.append(f"its end towards ({span[0] / shift:+.2f}, {span[1] / shift:+.2f}) "
                          "in b1 was not seen and nothing beyond it was: it may be longer than seen and its centre "
                          f"up to {100 * shift:.0f} cm further that way (views covering it make both sure)")
    lifting = {name: lifting_arm(arm, support.up, params.joint_lift_check) for name, arm in arms.items()}
    rounds = [lifting, arms] if params.joint_lift_check > 0 and all(lifting.values()) else [arms]
    for r, round_arms in enumerate(rounds):
        pairs = _joint_pairs(plan, support, collider, others, round_arms, check, params, long_side, push, span)
        plan.stats["joint_lift_checked"] = r == 0 and len(rounds) == 2
        if pairs:
            break
    # the best few of each kind, in joint_pairs' order (the best, then pairs holding the object elsewhere);
    # the kind with the better best pair first
    kinds = [[p for p in pairs if p.kind == k][: params.max_joint_pairs] for k in ("push", "pinch")]
    kinds.sort(key=lambda ps: -ps[0].score if ps else np.inf)
    plan.joint = [p for p in kinds[0] + kinds[1] if p.liftable] + [p for p in kinds[0] + kinds[1] if not p.liftable]
    if plan.mode == "joint" and not plan.joint:
        plan.notes.append("no balanced two-arm grasp that both arms reach without colliding"
                          f" ({len(push)} push contacts on its faces)")


def _joint_pairs(plan: ObjectPlan, support: Support, collider: GripperCollider, others: SceneOctree,
                 arms: dict[str, Arm], check: TwoArmCheck | None, params: PlanParams, long_side: float,
                 push, span: np.ndarray | None = None) -> list[JointPair]:
    """One round of ``_joint``: each arm's reachable push contacts and end pinches, and the pairs of them
    (``span``: where the centre may be, :func:`_centre_span`)."""
    geo = plan.geometry
    pairs: list[JointPair] = []
    # pairs the arms can lift the object from, their grippers clear of the scene, first
    lift = PairLift.for_arms(arms, geo.centre, support.up, collider=collider, scene=others,
                             margin=params.sampler.scene_margin)
    if len(push):
        for name, arm in arms.items():
            # each face gets its own reach budget; the faces that look towards this arm's base first
            to_base = arm.T_b1_b[:3, 3] - push.extra["contact"]
            to_base -= np.outer(to_base @ support.up, support.up)
            to_base /= np.maximum(np.linalg.norm(to_base, axis=1, keepdims=True), 1e-9)
            facing = np.einsum("nk,nk->n", -push.extra["squeeze"], to_base) > 0.3
            tries = len(push) if params.push_tries_per_face is None else params.push_tries_per_face
            # (a pair's contacts are across from each other: each place across a face gets its own budget)
            places = np.c_[push.extra["face"], push.extra["lateral"]]
            plan.push_reach[name] = reachable_by_group(push, arm, places, tries, params.push_want_per_face,
                                                       prefer=facing)
        plan.stats["push_reach"] = {n: {"reachable": len(a), "tried": a.tried, "why_not": a.reasons}
                                    for n, a in plan.push_reach.items()}
        pp, plan.stats["joint_push"] = joint_pairs(geo, support, plan.push_reach["primary"], plan.push_reach["secondary"],
                                                   collider, check, params.max_joint_pairs, lift=lift, centre_span=span)
        pairs += pp
    if plan.grasps is not None and len(plan.grasps) and long_side >= params.joint_min_extent:
        # pinches towards the two ends (the single-arm ranking favours the middle): each half of the object
        # gets its own reach budget, the far grasps first
        g = plan.grasps
        s_ax = (g.T_b1_g[:, :3, 3] - g.T_b1_g[:, :3, 2] * g.depth[:, None] - geo.centre) @ geo.T_b1_box[:3, 0]
        far = np.abs(s_ax) > 0.25 * geo.extent[0]
        for name, arm in arms.items():
            plan.pinch_reach[name] = reachable_by_group(g, arm, np.sign(s_ax), params.reach_tries, params.reach_want,
                                                        prefer=far)
        pp, plan.stats["joint_pinch"] = joint_pairs(geo, support, plan.pinch_reach["primary"],
                                                    plan.pinch_reach["secondary"], collider, check, params.max_joint_pairs,
                                                    lift=lift)
        pairs += pp
    return pairs


def _centre_span(geo, ends: list, params: PlanParams) -> np.ndarray | None:
    """(3,) how far the object's centre may lie past the centre of its seen box, towards its open ``ends`` (the
    outward normals of faces no camera saw, with nothing seen beyond: :func:`_push.open_ends`), or None when it
    has none: up to ``params.open_end_shift`` of its seen length along each (an end open both ways cancels)."""
    if not ends or params.open_end_shift <= 0:
        return None
    span = sum(params.open_end_shift * float(geo.extent[np.argmax(np.abs(geo.T_b1_box[:3, :2].T @ n))]) * n for n in ends)
    return span if float(np.linalg.norm(span)) > 1e-6 else None


def _handover(plan: ObjectPlan, support: Support, gripper: GripperModel, collider: GripperCollider,
              arms: dict[str, Arm], check: TwoArmCheck | None, params: PlanParams, obstacles_b1: np.ndarray,
              blocked: SceneOctree, givers: list[str]) -> None:
    """A hand-over: receiver grasps sampled on the object in the air (its bottom closed, from every side), then
    the ``givers`` in turn (those of ``params.handover_givers`` that reach a pick of the object) until one
    finds a hand-over (``_handover_from``)."""
    closed = closed_geometry(plan.geometry, support)
    # every collision-free candidate, not only the best-scored: those cluster at the object's centre, where
    # the giver's fingers are, and the receiver needs grasps away from them (measured on the demo's mug and
    # torus: 120 kept found no hand-over, all 500 found both, for 0.6 s more)
    # the receiver opens wider than a pick (``receiver_clearance`` past the object on each side, within the
    # stroke): in the air nothing but the giver is near, and the spare opening absorbs the calibration error
    free_params = _receiver_sampling(params, params.sampler.n_candidates)
    # the space around the object no camera saw into stays solid for the receiver (it moves with the object)
    unseen = plan.unseen if plan.unseen is not None else np.zeros((0, 3))
    receiver_blocked = SceneOctree(unseen, params.octree_resolution)
    plan.free_grasps, _ = sample_grasps(closed, support, gripper, collider, receiver_blocked, free_params)
    found: list = []
    for giver in givers:
        found = _handover_from(plan, giver, support, gripper, collider, arms, check, params, obstacles_b1, blocked,
                               closed)
        if found:
            break
        if params.handover_params.redraws:
            plan.redraws[giver] = partial(_redraw_handovers, plan, support, gripper, collider, arms, check, params,
                                          obstacles_b1, blocked, receiver_blocked, closed, free_params, giver)
    _set_handover(plan, found)


def _handover_from(plan: ObjectPlan, giver: str, support: Support, gripper: GripperModel, collider: GripperCollider,
                   arms: dict[str, Arm], check: TwoArmCheck | None, params: PlanParams, obstacles_b1: np.ndarray,
                   blocked: SceneOctree, closed) -> list:
    """The hand-overs from ``giver`` (an arm name): grasps clear of the space no camera saw into first, then its
    reachable picks, then shallow holds."""
    found = _clear_of_unseen(plan, giver, support, gripper, collider, arms, check, params, obstacles_b1, blocked,
                             closed)
    if found:
        return found
    # the giver holds the object where it leaves the receiver room, not where a single-arm pick is best
    plan.giver_picks = plan.grasps
    found = _search_handovers(plan, support, collider, arms, check, params, obstacles_b1, closed, giver=giver)
    if not found and params.handover_params.shallow_depths:
        # none: the picks go as deep as the fingers fit, and a small object held so may be covered where the
        # receiver's fingers would go. Search again with shallow holds as the givers (the same sampler at the
        # shallow depths only, with the giver's approach hints). Only then: on the task bench, offered
        # alongside the picks, shallow holds displaced deep ones that had worked (seed 3's can).
        shallow, _ = sample_grasps(plan.geometry, support, gripper, collider, blocked,
                                   replace(params.sampler, depths=params.handover_params.shallow_depths),
                                   approach_hints=_giver_hints(plan, arms, giver))
        if len(shallow):
            plan.giver_picks = shallow
            found = _search_handovers(plan, support, collider, arms, check, params, obstacles_b1, closed,
                                      reached=False, giver=giver)
            plan.stats["handover"]["shallow_picks"] = len(shallow)
            _after_the_picks(plan, shallow, found)
    return found


def _clear_of_unseen(plan: ObjectPlan, giver: str, support: Support, gripper: GripperModel,
                     collider: GripperCollider, arms: dict[str, Arm], check: TwoArmCheck | None, params: PlanParams,
                     obstacles_b1: np.ndarray, blocked: SceneOctree, closed) -> list:
    """Hand-overs whose giver's picks and receiver's grasps are drawn with ``plan.carved`` solid (the space near
    the object no camera saw past: more of the object may be there), searched as the shallow holds are; []
    when the object has no such cells or none is found (the plan's draws are then left as they were)."""
    if plan.carved is None or not len(plan.carved):
        return []
    first_free = plan.free_grasps
    solid = np.concatenate([blocked.points, plan.carved])
    # denser draws (as a redraw's picks): the grasps that keep out are the few that close across the seen side
    n = params.sampler.n_candidates * params.retry_factor
    plan.free_grasps, _ = sample_grasps(closed, support, gripper, collider,
                                        SceneOctree(plan.carved, params.octree_resolution), _receiver_sampling(params, n))
    picks, _ = sample_grasps(plan.geometry, support, gripper, collider, SceneOctree(solid, params.octree_resolution),
                             replace(params.sampler, n_candidates=n), approach_hints=_giver_hints(plan, arms, giver))
    found = []
    if len(picks) and len(plan.free_grasps):
        plan.giver_picks = picks
        found = _search_handovers(plan, support, collider, arms, check, params, obstacles_b1, closed, reached=False,
                                  giver=giver)
    plan.stats["unseen"] = {"cells": int(len(plan.carved)), "handover_clear_of_them": bool(found)}
    if found:
        _after_the_picks(plan, picks, found)
    else:
        plan.free_grasps = first_free
    return found


def _receiver_sampling(params: PlanParams, n: int) -> SamplerParams:
    """The sampler's parameters for the receiver's grasps in free space: ``n`` candidates, every one kept that
    passes, from all round, opening ``receiver_clearance`` past the object (within the stroke)."""
    return replace(params.sampler, full_circle=True, n_candidates=n, max_keep=n,
                   clearance=max(params.sampler.clearance, params.handover_params.receiver_clearance))


def _giver_hints(plan: ObjectPlan, arms: dict[str, Arm], giver: str) -> np.ndarray | None:
    """(K, 3) approach directions with which the giver reaches near the object, or None."""
    reach = arms[giver].reach
    return reach.approach_hints(plan.geometry.centre) if hasattr(reach, "approach_hints") else None


def _after_the_picks(plan: ObjectPlan, extra: GraspSet, found: list) -> None:
    """Givers searched among ``extra`` (shallow holds, a second draw): ``plan.giver_picks`` becomes the picks,
    then ``extra``, and the found hand-overs' giver indices point past the picks into it (a giver's index is
    never taken for a pick's: grasps.json's giver.grasp_rank stays null)."""
    plan.giver_picks = GraspSet.concat([plan.grasps, extra])
    for givers in {id(h.givers): h.givers for h in found}.values():
        givers.index = givers.index + len(plan.grasps)


NO_HANDOVER = ("no hand-over found: no transfer pose where one arm holds it and the other reaches a grasp clear of"
               " the first one's fingers")


def _set_handover(plan: ObjectPlan, found: list) -> None:
    """The best of ``found`` as the plan's hand-over, the rest as its alternatives; a note when none."""
    plan.handover = found[0] if found else None
    plan.handover_alternatives = found[1:]
    plan.notes = [n for n in plan.notes if n != NO_HANDOVER] + ([] if found else [NO_HANDOVER])


def _redraw_where_none(plans: list[ObjectPlan], log: Callable[[str], None] = _log_default,
                       givers: tuple[str, ...] = ARM_NAMES) -> None:
    """For each of ``givers`` in turn (``PlanParams.handover_givers``): when no object has a hand-over from it
    or from a giver before it, each object whose search from it found none searches again with fresh grasp
    draws (``_redraw_handovers``); a hand-over found so replaces one from a later giver. A scene that has one
    already keeps its plans (the draws cost a second or two per object, and the task needs one object)."""
    done: list[str] = []
    for giver in givers:
        done.append(giver)
        if any(p.handover is not None and p.handover.giver_arm in done for p in plans):
            return
        for p in plans:
            if giver not in p.redraws:
                continue
            t1 = time.perf_counter()
            found = p.redraws[giver]()
            if found or p.handover is None:
                _set_handover(p, found)
            dt = time.perf_counter() - t1
            p.timings["handover_redraw"] = p.timings.get("handover_redraw", 0.0) + dt
            p.timings["total"] = p.timings.get("total", 0.0) + dt
            log(f"object {p.id}: no object had a hand-over from the {giver}; grasps drawn again: "
                f"{'hand-over found' if found else 'none'} ({dt:.2f} s)")


def _redraw_handovers(plan: ObjectPlan, support: Support, gripper: GripperModel, collider: GripperCollider,
                      arms: dict[str, Arm], check: TwoArmCheck | None, params: PlanParams, obstacles_b1: np.ndarray,
                      blocked: SceneOctree, receiver_blocked: SceneOctree, closed, free_params: SamplerParams,
                      giver: str = "primary") -> list:
    """No hand-over from ``giver`` with the first draws: the receiver's grasps and the giver's picks drawn again
    with other seeds (``HandoverParams.redraws`` times; the picks denser, with the giver's approach hints),
    searched as the shallow holds are. The first draws stay in the plan when none is found."""
    hints = _giver_hints(plan, arms, giver)
    first_free, first_picks, stats = plan.free_grasps, plan.giver_picks, plan.stats.get("handover", {})
    sp = params.sampler
    for k in range(1, params.handover_params.redraws + 1):
        seed = sp.seed + 100 * k  # away from the picks' own retry (seed + 1)
        plan.free_grasps, _ = sample_grasps(closed, support, gripper, collider, receiver_blocked,
                                            replace(free_params, seed=seed))
        picks, _ = sample_grasps(plan.geometry, support, gripper, collider, blocked,
                                 replace(sp, seed=seed, n_candidates=sp.n_candidates * params.retry_factor),
                                 approach_hints=hints)
        if not len(picks) or not len(plan.free_grasps):
            continue
        plan.giver_picks = picks
        found = _search_handovers(plan, support, collider, arms, check, params, obstacles_b1, closed, reached=False,
                                  giver=giver)
        plan.stats["handover"]["redraw"] = k
        if found:
            _after_the_picks(plan, picks, found)
            return found
    plan.free_grasps, plan.giver_picks = first_free, first_picks
    plan.stats["handover"] = {**stats, "redraws_tried": params.handover_params.redraws}
    return []


def _search_handovers(plan: ObjectPlan, support: Support, collider: GripperCollider, arms: dict[str, Arm],
                      check: TwoArmCheck | None, params: PlanParams, obstacles_b1: np.ndarray, closed,
                      reached: bool = True, giver: str = "primary") -> list:
    """Hand-overs from the arm ``giver`` with its grasps chosen among ``plan.giver_picks`` (``handover_givers``,
    ``plan_handovers``); ``reached``: those are ``plan.grasps``, whose reachable ones ``plan.reach[giver]``
    holds already. Sets ``plan.stats["handover"]`` (with the giver's name)."""
    ag = plan.reach[giver]
    known = ag if reached else ArmGrasps(ag.arm, ag.grasps.take([]), np.zeros(0, int), ag.q[:0], ag.q_pre[:0],
                                         ag.T_b_g[:0])
    givers, clear = handover_givers(plan.giver_picks, plan.free_grasps, known, arms[giver],
                                    collider, params.handover_params)
    receiver = other_arm(giver)
    q_waiting = getattr(arms[receiver].reach, "q_current", None) if receiver in arms else None
    blocked = 0
    if check is not None and q_waiting is not None and len(givers):
        givers, clear, blocked = waiting_receiver_last(givers, clear, q_waiting, check, giver)
    found, plan.stats["handover"] = plan_handovers(plan.geometry, support, givers, plan.free_grasps, arms, collider,
                                                   check, params.handover_params, clear, obstacles_b1, closed.points,
                                                   giver_arm=giver)
    plan.stats["handover"]["giver_arm"] = giver
    plan.stats["handover"]["picks_against_the_waiting_arm"] = blocked
    plan.stats["handover"]["givers"] = {"reachable": len(givers), "tried": givers.tried, "why_not": givers.reasons}
    return found


def plan_grasps(cloud: SceneCloud, gripper: GripperModel | None = None, arms: dict[str, Arm] | None = None,
                T_b1_b2: np.ndarray | None = None, params: PlanParams = PlanParams(), objects: list[int] | None = None,
                log: Callable[[str], None] = _log_default) -> GraspPlan:
    """Plan grasps for every object of ``cloud`` (or the ids in ``objects``).

    ``arms``: name -> Arm with reach filters (``make_arms``); None skips reachability (then the grasps are
    only collision-checked, and no joint pairs or hand-overs are planned). Raises InputError when the
    cloud has no object, or an id in ``objects`` is not in it.
    """
    from ._gripper import load_gripper

    t0 = time.perf_counter()
    src = cloud.source.get("segments", "segments")
    present = cloud.object_ids
    # the contract numbers objects 0..K-1: a missing id in that range is an empty segment
    ids = list(range(max(present) + 1)) if present else []
    if not ids:
        raise InputError(Problem(src, "labels", "no object in the segments (every label is -1)",
                                 "check the segmentation: it found only the table/background"))
    if objects is not None:
        missing = [o for o in objects if o not in present]
        if missing:
            raise InputError(Problem(src, "labels", f"object id(s) {missing} not in the segments (ids: {present})",
                                     "pick ids from the segments file"))
        ids = list(objects)
    gripper = gripper or load_gripper("piper")
    cloud = _workspace(cloud, arms, params.workspace_radius)
    # the arms' collision maps: the whole scene, once (the reach filters leave the gripper's own shapes
    # against the map to the sampler's exact checks, so the object being grasped can stay in the map)
    arms = {name: a.for_scene(cloud.points) for name, a in arms.items()} if arms else arms
    support = estimate_support(cloud.points, cloud.labels, cloud.table_plane)
    collider = GripperCollider(gripper, params.sampler.approach)
    plans = [plan_object(k, cloud, support, gripper, collider, arms, T_b1_b2, params, src, log) for k in ids]
    _redraw_where_none(plans, log, params.handover_givers)
    for p in plans:  # the deferred searches hold each object's octrees and geometry: not kept with the plan
        p.redraws = {}
    return GraspPlan(support, gripper, plans, sorted(arms) if arms else [], T_b1_b2, params,
                     {"total": time.perf_counter() - t0})

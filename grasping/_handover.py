"""Hand-over: the giver (the primary, or the secondary where the primary reaches no pick: ``giver_arm``)
carries the object to a transfer pose both arms reach, the other arm (the receiver) grasps it there, and the
giver lets go. Below, "primary" and "secondary" stand for giver and receiver.

A transfer pose puts the object's centre above the line between the two bases (at ``heights`` above the
table, at least ``min_rise`` above where it lies, shifted sideways by ``offsets``), turned so that the
giver's approach points towards the secondary's base tilted down by ``tilts`` (pi/2: straight down, as it
was picked), and rolled about that approach by ``rolls``. The object moves rigidly with the giver's grasp,
so for a transfer pose the giver's gripper is that motion applied to its pick grasp; if the giver's arm
reaches it only turned 180 degrees about its approach (the gripper is symmetric), the object's transfer pose
turns with it.

Receiver grasps come from the object sampled in free space (its unseen bottom closed, approaches from
every side, no table), moved with the object. Whether a receiver grasp keeps clear of the giver does not
depend on the transfer pose (both move with the object), so for each giver grasp the receivers whose open
gripper -- along its approach sweep -- stays ``gap`` away from the giver's closed gripper, and from whose
closed gripper the giver's retreat sweep stays ``gap`` away, are found once. The search over (giver grasp,
transfer pose) then runs in order of predicted cost: each arm's reach ``prior`` (the distance from a pose
to the nearest one the arm was seen to reach; see ``ArmReach.prior``) for the giver's pose plus the best
clear receiver's, so that the exact IK checks go first where both arms are likely to reach. A pair is kept
when the primary reaches its pose, the secondary reaches a clear receiver grasp (with its pre-grasp), and
the two arms do not collide. The first such pair wins.

Beside these giver-first transfer poses, the search ranks poses solved for a (giver, clear receiver) pair
together (``_handover_pairs``): the object turned so that each gripper comes in from its own base's side,
scored by named, weighted terms (both arms' priors, the receiver's grasp score and how surely its pads end on
the object) and checked exactly with that one receiver. The places include points towards where the object
lies (raised), not only the line between the bases. Receivers whose contact lies at their fingertips (a hold
on the object's edge) go after deeper ones of the same reach and catch.

Why not a fixed order of transfer poses: measured on the 20 bench scenes, the Piper's long wrist (22 cm from
joint 5 to the fingertips, joint 5 within +-70 degrees) leaves few poses at 20-30 cm above the table that
both arms reach, and a fixed order spent its IK budget on the giver's side alone.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np

from bimanual_app.transforms import inv_T, perpendicular_basis, rotation_angle_between

from ._antipodal import GraspSet, rotate_about_approach
from ._arms import Arm, ArmGrasps, TwoArmCheck, reachable_grasps
from ._collision import (
    GripperCollider,
    PlacedGrippers,
    PointClearance,
    SceneOctree,
    grippers_collide_many,
    grippers_distance,
    place_grippers,
)
from ._handover_pairs import PairParams, pair_costs, pair_moves
from ._objects import ObjectGeometry, Support

__all__ = ["HandoverParams", "Handover", "handover_givers", "plan_handover", "plan_handovers", "release_width",
           "catch_probability",
           "giver_hold_probability"]


@dataclass(frozen=True)
class HandoverParams:
    """Transfer poses and checks (metres, radians).

    heights: the object's centre above the table. min_rise: ... and at least this far above where it lies
        (the task counts a hand-over when the object ends 10 cm up).
    offsets: sideways from the line between the bases. fractions: where along that line, from the primary
        (0) to the secondary (1). towards_object: further places, these fractions of the way from the
        line's midpoint to above where the object lies (1: straight above it).
    tilts: the giver's approach, down from horizontal (0 = pointing at the secondary's base, pi/2 = down).
    rolls: turns of the object about the giver's approach.
    gap: least distance between the two grippers (and the giver's retreat sweep).
    object_clearance: the object at the transfer pose keeps this far from the rest of the scene (the large
        box the bases face across is often right below the midpoint).
    max_receivers_ranked: clear receivers (best score first) whose predicted reach ranks a transfer pose.
    receiver_pregrasp: the receiver's pre-grasp distance back along its approach. In the air its fingers only
        need to clear the object (a contact at most 4.25 cm behind the fingertips, plus the object's near
        half); the pick's longer pre-grasp (9 cm) would pull the wrist back towards the secondary's base,
        which the Piper cannot follow at a transfer pose between two bases 50-70 cm apart.
    givers: giver grasps tried: the giver's reachable pick grasps that leave the most clear receiver grasps
        (counted up to ``enough_clear``, then the best-scored: a shallow grasp at the object's very end
        leaves the most room but holds least well); giver_tries: pick grasps sent to its reach filter.
    receivers_checked: receiver grasps sent to the reach filter
    per transfer pose. prior_cut: (giver, transfer pose) candidates whose giver pose or best receiver pose
    the arm is predicted not to reach (see ``ArmReach.prior``) are skipped. max_transfer_checks: candidates
    checked exactly (IK), cheapest predicted first.
    object_sigma_m, pad_half_height: an object's position error in the cloud (1 sigma; 5-15 mm on the bench's
        pipeline clouds) and how far a pad reaches past its contact centre: givers are ranked first by how
        likely they still hold the object despite that error (:func:`giver_hold_probability`), in tiers of 0.1.
    receiver_clearance: how far the receiver's fingers open past the object on each side (within the stroke;
        a pick opens 1 cm): at the transfer pose only the giver is near, and the spare opening is what absorbs
        the calibration error below.
    release_clearance: the giver lets go at the transfer pose opening this far past the object on each side
        (no wider than it picked: a pick may open wider, for the object's position error on the table); its
        retreat sweep is checked at that opening.
    shallow_depths: when no hand-over is found, the giver may also hold the object shallow: pick grasps
        sampled again for the primary with their contact centres at most these fractions of the finger length
        behind the fingertips (the picks go as deep as the fingers fit, and cover a small object where the
        receiver's fingers would go; on the task bench's seed 16 no pick of the mug left the secondary a grasp
        it reached, a shallower hold did); empty: only the picks.
    pairs: transfer poses solved for a (giver, receiver) pair together (:mod:`._handover_pairs`), ranked with
        the giver-first ones by the same predicted cost.
    redraws: when no object of the scene has a hand-over, each object whose search (picks, then shallow
        holds) found none draws the receiver's grasps and the giver's picks again this many times, with other
        sampler seeds (the picks denser, with the primary's approach hints), and searches again: which grasps
        one draw holds decides many hand-overs (a last-digit change of the pipeline's cloud, as between two
        machines' BLAS kernels, flipped the hand-over of 14 of 50 held-out scenes, most in this search).
    alternatives: hand-overs kept per object (:func:`plan_handovers`): the best first, then ones with another
        giver grasp or transfer pose, for the task to fall back on when one cannot be planned or previewed.
    refused_picks: K giver picks T_b1_g (4, 4) a task's physics preview saw fail (``grasping.redraw_handovers``):
        picks within ``REFUSED_SHIFT`` m and ``REFUSED_TURN`` rad of one (either way round its approach) are
        not given from.
    receiver_scene_margin: at the transfer pose, the receiver's open gripper, swept from its pre-grasp, keeps
        this far from the rest of the scene (the task planner's contact margin, which its approach keeps there).
    b2b_sigma_m, b2b_sigma_rad: 1-sigma error of the calibrated ``T_b1_b2`` (translation per axis, rotation)
        (``bijcr grasp`` takes them from calibration.json's ``uncertainty``). The secondary's idea of where the
        object is at the transfer pose is off by about ``sqrt(s_m^2 + (s_rad d)^2)`` along any axis, d = the
        distance from its base; the receiver's open fingers catch it when that error along its closing axis
        is under the margin ``(width - contact_width) / 2`` (see :func:`catch_probability`). Among receivers
        the secondary is about as likely to reach, the ones more likely to catch go first.
    """

    heights: tuple[float, ...] = (0.12, 0.16, 0.20, 0.25)
    min_rise: float = 0.12
    offsets: tuple[float, ...] = (0.0, 0.06, -0.06, 0.12, -0.12)
    fractions: tuple[float, ...] = (0.5, 0.4, 0.6)
    tilts: tuple[float, ...] = (0.0, np.pi / 6, np.pi / 4, np.pi / 3, np.pi / 2)
    rolls: tuple[float, ...] = (0.0, np.pi / 2, -np.pi / 2, np.pi)
    gap: float = 0.015
    receiver_pregrasp: float = 0.06
    object_clearance: float = 0.025
    max_receivers_ranked: int = 150
    givers: int = 4
    giver_tries: int = 24
    enough_clear: int = 6
    receivers_checked: int = 6
    prior_cut: float = 0.10
    max_transfer_checks: int = 80
    receiver_clearance: float = 0.025
    object_sigma_m: float = 0.008
    pad_half_height: float = 0.005
    b2b_sigma_m: float = 0.007
    b2b_sigma_rad: float = 0.012
    alternatives: int = 3
    redraws: int = 1
    release_clearance: float = 0.010
    shallow_depths: tuple[float, ...] = (0.4, 0.25)
    pairs: PairParams = PairParams()
    towards_object: tuple[float, ...] = (0.5, 1.0)
    refused_picks: tuple = ()
    receiver_scene_margin: float = 0.003


# The hand-over search's fallbacks by name (``grasp_stage(leave_out=)``, bench/tasks.py --leave-out): each
# left out, to measure what it buys on scenes nobody tuned on (docs/tasks.md, *The fallbacks, each left out*).
HANDOVER_FALLBACKS = {
    "shallow-holds": "where no hand-over is found, the giver's picks drawn again as shallow holds (shallow_depths)",
    "handover-redraws": "where no object has a hand-over, the receivers and picks drawn again (redraws)",
}


def without_fallbacks(params: HandoverParams, leave_out) -> HandoverParams:
    """``params`` with the hand-over fallbacks named in ``leave_out`` (keys of HANDOVER_FALLBACKS; other names
    are ignored) switched off."""
    from dataclasses import replace

    names = set(leave_out)
    if "shallow-holds" in names:
        params = replace(params, shallow_depths=())
    if "handover-redraws" in names:
        params = replace(params, redraws=0)
    return params


@dataclass
class Handover:
    """A planned hand-over (all poses in b1).

    T_move: (4, 4) rigid motion taking the object from where it lies to the transfer pose.
    centre: (3,) the object's centre at the transfer pose.
    giver_index: index of the giver's grasp in ``givers`` (the giver's reachable pick grasps chosen for
        the hand-over).
    giver_T_b1_g: (4, 4) giver's gripper at the transfer pose; giver_q: (J,) its joints there.
    giver_width: the giver's closed width (the object's contact width).
    receiver: the receiver's grasp at the transfer pose: ``T_b1_g``, ``width``, ``contact_width``, ``score``,
        ``q``, ``q_pre``, ``index`` (in the free-space grasp set).
    gap: smallest distance between the two grippers when both hold the object (m).
    score: mean of the two grasp scores times ``catch`` and both grippers' hold probabilities
        (:func:`giver_hold_probability` of each one's depth).
    catch: probability that the receiver's open fingers close around the object given the calibration
        error (:func:`catch_probability`); margin: the receiver's opening past the object on each side (m);
        sigma: the position error assumed at the transfer pose (1-sigma, m).
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
    catch: float = 1.0
    margin: float = 0.0
    sigma: float = 0.0
    givers: ArmGrasps | None = None  # the giver candidates ``giver_index`` indexes (None: the giver's reach set)
    giver_release_width: float = 0.0  # the giver's opening when it lets go (m; :func:`release_width`)
    giver_arm: str = "primary"  # the arm that picks and gives ("primary" or "secondary"); the other receives

    @property
    def receiver_arm(self) -> str:
        return other_arm(self.giver_arm)


ARM_NAMES = ("primary", "secondary")
# a giver pick this near a refused one (HandoverParams.refused_picks) is the same pick: the pick poses the
# sampler draws are a centimetre or more apart where they differ in where the fingers close
REFUSED_SHIFT = 0.01
REFUSED_TURN = np.deg2rad(20.0)


def other_arm(arm: str) -> str:
    """The other one of ``ARM_NAMES``."""
    return ARM_NAMES[1 - ARM_NAMES.index(arm)]


@dataclass
class _Roles:
    """The two arms of one hand-over by role: ``giver`` picks and gives, ``receiver`` takes it over.
    ``T_b1_b2`` (4, 4): the secondary's base, whichever arm gives (the calibration error is the error of that
    transform). ``check(q_giver, w_giver, q_receiver, w_receiver)``: the arm-against-arm check, or None."""

    giver: Arm
    receiver: Arm
    T_b1_b2: np.ndarray
    check: Callable[[np.ndarray, float, np.ndarray, float], tuple[bool, str]] | None = None


def _roles(arms: dict[str, Arm], giver: str, check: TwoArmCheck | None) -> _Roles:
    """``arms`` (by name) as the roles of a hand-over from ``giver``; ``check`` takes (primary, secondary)
    configurations, so a hand-over from the secondary swaps its arguments."""
    if giver not in ARM_NAMES:
        raise ValueError(f"giver must be one of {ARM_NAMES}, not {giver!r}")
    return _Roles(arms[giver], arms[other_arm(giver)], arms["secondary"].T_b1_b, _giver_first(check, giver))


def _giver_first(check: TwoArmCheck | None, giver: str):
    """``check``, which takes (primary, secondary) configurations, as ``check(q_giver, w_giver, q_receiver,
    w_receiver)`` for a hand-over from ``giver`` (its arguments swapped when the secondary gives); None stays."""
    if check is None or giver == "primary":
        return check

    def swapped(q_g, w_g, q_r, w_r):
        return check(q_r, w_r, q_g, w_g)
    return swapped


def release_width(width: np.ndarray, contact_width: np.ndarray, params: HandoverParams) -> np.ndarray:
    """The giver's opening (m, same shape) when it lets go: ``release_clearance`` past the object on each side,
    no wider than it opened to pick (``width``)."""
    return np.minimum(np.asarray(width, dtype=np.float64),
                      np.asarray(contact_width, dtype=np.float64) + 2 * params.release_clearance)


def catch_probability(margin: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Probability that a receiver whose fingers open ``margin`` (m, any shape) past the object on each side
    closes around it when the object is off by a zero-mean normal error of ``sigma`` (m) along the closing
    axis: ``P(|e| < margin) = erf(margin / (sigma sqrt 2))``."""
    from scipy.special import erf

    margin = np.maximum(np.asarray(margin, dtype=np.float64), 0.0)
    return erf(margin / (np.sqrt(2.0) * np.maximum(np.asarray(sigma, dtype=np.float64), 1e-6)))


def giver_hold_probability(depth: np.ndarray, params: HandoverParams) -> np.ndarray:
    """(N,) probability that a pick whose contact centre lies ``depth`` (N,) m behind the fingertips still
    has its pads on the object when the object's top is off by a normal error of ``params.object_sigma_m``:
    ``catch_probability(depth + pad_half_height, object_sigma_m)``. A shallow pick at the very top of an
    object (what leaves a receiver the most room) slips off when the object is a few millimetres lower than
    the cloud says."""
    return catch_probability(np.asarray(depth, dtype=np.float64) + params.pad_half_height, params.object_sigma_m)


def _transfer_sigma(p: HandoverParams, T_b1_b2: np.ndarray, points_b1: np.ndarray) -> np.ndarray:
    """(K,) the secondary's position error (1-sigma, m) at ``points_b1`` (K, 3) from T_b1_b2's uncertainty."""
    d = np.linalg.norm(np.asarray(points_b1, dtype=np.float64).reshape(-1, 3) - T_b1_b2[:3, 3], axis=1)
    return np.sqrt(p.b2b_sigma_m ** 2 + (p.b2b_sigma_rad * d) ** 2)


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
        return _axis_angle(perpendicular_basis(a)[0], np.pi)
    return _axis_angle(v / s, float(np.arctan2(s, c)))


def _transfer_targets(geo: ObjectGeometry, support: Support, roles: _Roles, p: HandoverParams
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(K, 3) the object centre's places at the transfer poses, in order of preference, and (3,) the unit
    direction from the giver's base to the receiver's (horizontal)."""
    up = support.up
    o_g, o_r = roles.giver.T_b1_b[:3, 3], roles.receiver.T_b1_b[:3, 3]
    start = o_g - (o_g @ up) * up  # the giver's base, horizontally (b1's origin for the primary)
    base_line = (o_r - o_g) - ((o_r - o_g) @ up) * up
    line = base_line / max(np.linalg.norm(base_line), 1e-9)
    across = np.cross(up, line)
    floor = support.height * up  # the table plane below b1's origin
    lowest = float(geo.centre @ up - support.height) + p.min_rise  # the centre's height above the table
    heights = [h for h in p.heights if h >= lowest] or [lowest]
    targets = [start + f * base_line + floor + h * up + off * across for h in heights for f in p.fractions for off in p.offsets]
    # and towards where the object lies (raised): near the edge of both reaches, the place both arms reach
    # may be nearer the object than the line between the bases
    here = geo.centre - (geo.centre @ up) * up
    mid = start + 0.5 * base_line
    targets += [(1 - f) * mid + f * here + floor + h * up for h in heights for f in p.towards_object]
    return np.array(targets).reshape(-1, 3), line


def _transfer_moves(geo: ObjectGeometry, support: Support, roles: _Roles, G: np.ndarray,
                    p: HandoverParams) -> list[np.ndarray]:
    """Rigid motions (4, 4) of the object, for the giver's pick grasp ``G`` (4, 4), in order of preference."""
    up = support.up
    targets, line = _transfer_targets(geo, support, roles, p)
    zg = G[:3, 2]
    moves = []
    for target in targets:
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


def _place_receivers(collider: GripperCollider, free: GraspSet) -> tuple[PlacedGrippers, PlacedGrippers]:
    """The free-space grasps ``free`` placed for ``_clear_receivers``, once for all givers: open and swept
    along their approach, and closed on the object."""
    return (place_grippers(collider, free.T_b1_g, free.width, swept=True),
            place_grippers(collider, free.T_b1_g, free.contact_width))


def _clear_receivers(collider: GripperCollider, G: np.ndarray, w_open: float, w_closed: float, free: GraspSet,
                     gap: float, placed: tuple[PlacedGrippers, PlacedGrippers] | None = None) -> np.ndarray:
    """Indices of the free-space grasps ``free`` whose open gripper (swept along its approach) keeps ``gap``
    from the giver's closed gripper at ``G`` (4, 4), and whose closed gripper the giver's retreat sweep (open
    at ``w_open``) keeps ``gap`` from. Both grippers hold the object where it lies; moving it moves both.
    ``placed``: ``_place_receivers(collider, free)``, when already made."""
    if not len(free):
        return np.zeros(0, dtype=int)
    open_swept, closed = placed if placed is not None else _place_receivers(collider, free)
    hit = grippers_collide_many(collider, G, w_closed, None, None, margin=gap, placed2=open_swept)
    todo = np.nonzero(~hit)[0]
    hit[todo] = grippers_collide_many(collider, G, w_open, None, None, margin=gap, swept1=True,
                                      placed2=closed.take(todo))
    return np.nonzero(~hit)[0]


def _clear_of_scene(index, moves: np.ndarray, obj_pts: np.ndarray) -> np.ndarray:
    """(M,) bool (or a bool for one move (4, 4)): the object's points ``obj_pts`` (K, 3) moved by each of
    ``moves`` (M, 4, 4) keep the clearance of ``index`` (a ``PointClearance`` of the scene's points)."""
    one = np.ndim(moves) == 2
    Ms = np.asarray(moves, dtype=np.float64).reshape(-1, 4, 4)
    moved = np.einsum("mij,pj->mpi", Ms[:, :3, :3], obj_pts) + Ms[:, None, :3, 3]
    ok = index.clear(moved)
    return bool(ok[0]) if one else ok


def _prior(arm: Arm, T_b1_g: np.ndarray) -> np.ndarray:
    """(N,) the arm's predicted distance to reaching poses ``T_b1_g`` (N, 4, 4); zeros without a prior."""
    prior = getattr(arm.reach, "prior", None)
    if prior is None or len(T_b1_g) == 0:
        return np.zeros(len(T_b1_g))
    return prior(inv_T(arm.T_b1_b) @ T_b1_g)


def _prior_min(arm: Arm, moves_b1: np.ndarray, T_b1_g: np.ndarray, cut: float) -> np.ndarray:
    """(M,) per rigid motion ``moves_b1`` (M, 4, 4), the smallest prior of the arm over the poses ``T_b1_g``
    (K, 4, 4) moved by it; values not under ``cut`` may come back as ``inf``."""
    T_b_b1 = inv_T(arm.T_b1_b)
    fast = getattr(arm.reach, "prior_min", None)
    if fast is not None:
        return fast(T_b_b1 @ moves_b1, T_b1_g, cut)
    prior = getattr(arm.reach, "prior", None)
    if prior is None or len(T_b1_g) == 0:
        return np.zeros(len(moves_b1)) if prior is None else np.full(len(moves_b1), np.inf)
    Rt = (T_b_b1 @ moves_b1)[:, None] @ np.asarray(T_b1_g)[None]
    return prior(Rt.reshape(-1, 4, 4)).reshape(len(moves_b1), -1).min(axis=1)


def handover_givers(picks: GraspSet, free: GraspSet, reached: ArmGrasps, prim: Arm, collider: GripperCollider,
                    params: HandoverParams = HandoverParams()) -> tuple[ArmGrasps, list[np.ndarray]]:
    """The giver's (``prim``'s) pick grasps to hand over from, and the free-space receiver grasps each leaves clear.

    A centred, deep pick (what the single-arm ranking prefers) covers a small object with the giver's fingers
    and leaves the receiver nothing; so every collision-free pick grasp of ``picks`` is ranked by how many
    receiver grasps it leaves clear (up to ``params.enough_clear``, then by score), and the first
    ``params.givers`` the primary reaches are returned: those already in ``reached`` (its reachable pick grasps) as they are,
    the others through its reach filter (at most ``params.giver_tries`` checks).
    """
    w_release = release_width(picks.width, picks.contact_width, params)
    placed = _place_receivers(collider, free) if len(free) else None
    clear = [_clear_receivers(collider, picks.T_b1_g[i], float(w_release[i]), float(picks.contact_width[i]),
                              free, params.gap, placed) for i in range(len(picks))]
    n = np.array([len(c) for c in clear], dtype=int)
    cand = np.nonzero(n > 0)[0]
    cand = cand[~refused(picks.T_b1_g[cand], params.refused_picks)]
    hold = np.round(giver_hold_probability(picks.depth[cand], params), 1)
    cand = cand[np.lexsort((-picks.score[cand], -np.minimum(n[cand], params.enough_clear), -hold))]
    known = {int(i): j for j, i in enumerate(reached.index)}
    unknown = np.array([i for i in cand if int(i) not in known], dtype=int)
    more = reachable_grasps(picks.take(unknown), prim, params.giver_tries, params.givers)
    more.index = unknown[more.index]
    found = {int(i): ("reached", j) for i, j in known.items()}
    found.update({int(i): ("more", j) for j, i in enumerate(more.index)})
    chosen = [int(i) for i in cand if int(i) in found][: params.givers]
    rows = {"reached": reached, "more": more}
    parts = [(rows[found[i][0]], found[i][1]) for i in chosen]
    J = reached.q.shape[1] if reached.q.ndim == 2 else more.q.shape[1]
    givers = ArmGrasps(prim.name, GraspSet.concat([ag.grasps.take([j]) for ag, j in parts]) if parts else picks.take([]),
                       np.array(chosen, dtype=int),
                       np.array([ag.q[j] for ag, j in parts]).reshape(-1, J),
                       np.array([ag.q_pre[j] for ag, j in parts]).reshape(-1, J),
                       np.array([ag.T_b_g[j] for ag, j in parts]).reshape(-1, 4, 4),
                       more.tried, more.reasons)
    return givers, [clear[i] for i in chosen]


def refused(T_b1_g: np.ndarray, refused_picks: np.ndarray) -> np.ndarray:
    """(N,) bool: the poses ``T_b1_g`` (N, 4, 4) within ``REFUSED_SHIFT`` m and ``REFUSED_TURN`` rad of one of
    ``refused_picks`` (K, 4, 4), or of it turned 180 degrees about its approach (the same grasp)."""
    T = np.asarray(T_b1_g, dtype=np.float64).reshape(-1, 4, 4)
    Rf = np.asarray(refused_picks, dtype=np.float64).reshape(-1, 4, 4)
    if not len(T) or not len(Rf):
        return np.zeros(len(T), dtype=bool)
    near = np.linalg.norm(T[:, None, :3, 3] - Rf[None, :, :3, 3], axis=-1) < REFUSED_SHIFT
    out = np.zeros(len(T), dtype=bool)
    for Rk in (Rf, rotate_about_approach(Rf)):
        turn = rotation_angle_between(T[:, None, :3, :3], Rk[None, :, :3, :3])
        out |= np.any(near & (turn < REFUSED_TURN), axis=1)
    return out


def waiting_receiver_last(givers: ArmGrasps, clear: list, q_receiver: np.ndarray, check: TwoArmCheck,
                          giver_arm: str = "primary") -> tuple[ArmGrasps, list, int]:
    """``givers`` (from :func:`handover_givers`) with the picks whose arm, at the pre-grasp or the grasp, comes
    within the check's margin of the receiver waiting at ``q_receiver`` (J,; grippers closed, as the task
    starts) moved after the others, order kept within each part; ``clear`` reordered alike; and how many were
    moved. The task's first move takes the giver to that pre-grasp with the receiver still there: its goal
    check refuses such a pick whatever comes after (the same arm-against-arm world and margin)."""
    clash = _giver_first(check, giver_arm)
    w = givers.grasps.width
    ok = np.array([all(clash(q, float(w[k]), q_receiver, 0.0)[0] for q in (givers.q_pre[k], givers.q[k]))
                   for k in range(len(givers))], dtype=bool)
    order = np.r_[np.nonzero(ok)[0], np.nonzero(~ok)[0]].astype(int)
    moved = ArmGrasps(givers.arm, givers.grasps.take(order), givers.index[order], givers.q[order],
                      givers.q_pre[order], givers.T_b_g[order], givers.tried, givers.reasons)
    return moved, [clear[k] for k in order], int(np.count_nonzero(~ok))


def plan_handover(geo: ObjectGeometry, support: Support, giver: ArmGrasps, free: GraspSet, arms: dict[str, Arm],
                  collider: GripperCollider, check: TwoArmCheck | None, params: HandoverParams = HandoverParams(),
                  clear: list[np.ndarray] | None = None, obstacles_b1: np.ndarray | None = None,
                  object_points_b1: np.ndarray | None = None, giver_arm: str = "primary"
                  ) -> tuple[Handover | None, dict]:
    """The first feasible hand-over (see the module docstring), or None; with counts of what was tried.

    ``giver_arm``: the arm that picks and gives (``arms`` by name; the other one receives). ``giver``: its
    reachable pick grasps to try, best first (``handover_givers``); ``clear``: for
    each, the indices of the ``free`` grasps it leaves clear (computed when not given). ``obstacles_b1``
    (M, 3): the rest of the scene; transfer poses where the object comes within ``object_clearance`` of it
    are skipped; ``object_points_b1`` (K, 3): the object's points for that check (default ``geo.points``; pass
    its closed geometry's, which include the unseen bottom)."""
    found, stats = plan_handovers(geo, support, giver, free, arms, collider, check, params, clear, obstacles_b1,
                                  object_points_b1, n=1, giver_arm=giver_arm)
    return (found[0] if found else None), stats


def _distinct(h: Handover, found: list[Handover], min_shift: float = 0.04, min_turn: float = np.deg2rad(30)) -> bool:
    """Whether ``h`` differs from every hand-over in ``found``: another giver grasp, or a transfer pose
    ``min_shift`` m or ``min_turn`` rad away (an alternative that fails for another reason than the first)."""
    for f in found:
        if f.giver_index != h.giver_index:
            continue
        dR = f.T_move[:3, :3].T @ h.T_move[:3, :3]
        turn = np.arccos(np.clip((np.trace(dR) - 1.0) / 2.0, -1.0, 1.0))
        if np.linalg.norm(f.centre - h.centre) < min_shift and turn < min_turn:
            return False
    return True


def plan_handovers(geo: ObjectGeometry, support: Support, giver: ArmGrasps, free: GraspSet, arms: dict[str, Arm],
                   collider: GripperCollider, check: TwoArmCheck | None, params: HandoverParams = HandoverParams(),
                   clear: list[np.ndarray] | None = None, obstacles_b1: np.ndarray | None = None,
                   object_points_b1: np.ndarray | None = None, n: int | None = None, giver_arm: str = "primary"
                   ) -> tuple[list[Handover], dict]:
    """Up to ``n`` (default ``params.alternatives``) feasible, mutually distinct hand-overs (:func:`_distinct`):
    the first the search finds (:func:`plan_handover`'s), then those with a giver grasp not used before, then
    the others, each group in the order found; with counts of what was tried.
    The search budget (``params.max_transfer_checks``) is shared: alternatives only use what the first left.
    Arguments as for :func:`plan_handover`."""
    n = params.alternatives if n is None else int(n)
    stats = {"transfer_poses": 0, "object_in_scene": 0, "giver_reached": 0, "giver_goal_blocked": 0,
             "clear_receivers": 0, "receiver_candidates": 0, "receiver_reached": 0, "receiver_in_scene": 0}
    found: list[Handover] = []
    if len(giver) == 0 or len(free) == 0 or "secondary" not in arms or n < 1:
        return found, stats
    roles = _roles(arms, giver_arm, check)
    # alternatives with another giver grasp first: a pick that does not hold the object fails every hand-over
    # that starts with it, whatever the transfer pose (while givers are left unused, the search goes on for
    # at most 2n distinct hand-overs)
    same: list[Handover] = []
    n_givers = min(params.givers, len(giver))
    for h in _search(geo, support, giver, free, roles, collider, params, clear, obstacles_b1, object_points_b1, stats):
        if _distinct(h, found + same):
            h.tried = dict(stats)
            (found if all(f.giver_index != h.giver_index for f in found) else same).append(h)
            enough = len(found) + len(same) >= (n if len(found) >= n_givers else 2 * n)
            if len(found) >= n or enough:
                break
    return (found + same)[:n], stats


def _scene_clearance(geo: ObjectGeometry, support: Support, roles: _Roles, params: HandoverParams, obstacles_b1,
                     object_points_b1) -> tuple[PointClearance | None, np.ndarray | None]:
    """(the scene's clearance index over the transfer region, the object's points (<= ~300, 3) it is checked
    with), or (None, None) without obstacles."""
    if obstacles_b1 is None or not len(obstacles_b1):
        return None, None
    pts = geo.points if object_points_b1 is None else np.asarray(object_points_b1, dtype=np.float64).reshape(-1, 3)
    obj_pts = pts[:: max(1, len(pts) // 300)]
    # every transfer pose puts the object's centre on one of the targets: its points stay within its radius
    targets, _ = _transfer_targets(geo, support, roles, params)
    radius = float(np.linalg.norm(obj_pts - geo.centre, axis=1).max()) if len(obj_pts) else 0.0
    return PointClearance(obstacles_b1, params.object_clearance,
                          (targets.min(axis=0) - radius, targets.max(axis=0) + radius)), obj_pts


RECEIVER_SCENE_RESOLUTION = 0.005  # m: voxels of the scene the receivers are checked against (the task's map)


@dataclass(frozen=True)
class _ReceiverScene:
    """The rest of the scene near the transfer poses (``octree``) and the receiver's gripper swept from its
    pre-grasp (``collider``): a receiver grasp whose gripper comes within ``margin`` of it ``touches``."""

    octree: SceneOctree
    collider: GripperCollider
    margin: float

    def touches(self, T_b1_g: np.ndarray, width: float) -> bool:
        """Whether the open gripper at ``T_b1_g`` (4, 4), swept back to its pre-grasp, meets the scene."""
        return bool(self.collider.collides(self.octree, T_b1_g[None], np.array([width]), swept=True,
                                           margin=self.margin)[0])


def _receiver_scene(geo: ObjectGeometry, support: Support, roles: _Roles, params: HandoverParams, gripper,
                    obstacles_b1) -> _ReceiverScene | None:
    """The scene check of the receivers at the transfer poses (the points within reach of a receiver's gripper
    at one of them), or None without obstacles. The pick's own check leaves the gripper against the map to
    the sampler; in the air nothing else checks it, and the task's approach there keeps its contact margin."""
    if obstacles_b1 is None or not len(obstacles_b1):
        return None
    targets, _ = _transfer_targets(geo, support, roles, params)
    collider = GripperCollider(gripper, params.receiver_pregrasp)
    # a receiver's grasp lies within the object's radius of its centre, and its gripper, open and swept from
    # the pre-grasp, within its shapes' bounding spheres of the grasp (a hand-set 21 cm fell 3 cm short of them)
    swept = place_grippers(collider, np.eye(4)[None], np.array([gripper.max_width]), swept=True)
    reach = (float(np.linalg.norm(geo.extent)) / 2 + float(np.max(np.linalg.norm(swept.box_c[0], axis=1) + swept.radius))
             + params.receiver_scene_margin + RECEIVER_SCENE_RESOLUTION)  # and what the check's broad phase adds
    P = np.asarray(obstacles_b1, dtype=np.float64).reshape(-1, 3)
    near = np.all((P > targets.min(axis=0) - reach) & (P < targets.max(axis=0) + reach), axis=1)
    return _ReceiverScene(SceneOctree(P[near], RECEIVER_SCENE_RESOLUTION), collider, params.receiver_scene_margin)


RANK_CHUNK = 64  # transfer poses scored at a time (scene clearance, the receivers' prior) by _ranked_transfers


def _cost_key(cost: float, pref: int) -> tuple[int, int]:
    """The rank of a candidate: its predicted cost in 2 cm bins, then its order of preference."""
    return round(cost / 0.02), pref


def _ranked_transfers(geo, support, giver, free, roles, collider, params, clear, scene_clear, obj_pts,
                      stats) -> Iterator[tuple]:
    """(giver, move) candidates, cheaper predicted cost first (the giver's prior + the best clear receiver's;
    ties: order of preference): ``(cost, order of preference, giver index, move (4, 4), clear receivers)``.

    Lazily: a transfer pose's cost is at least its giver's prior, so the poses are scored (scene clearance,
    then the receivers' ``prior_min``, the costly part) in order of that bound, ``RANK_CHUNK`` at a time, and
    a candidate is yielded once no pose left unscored can rank before it: the order of scoring them all
    first, for the candidates the search asks for. ``stats["object_in_scene"]`` counts the poses scored."""
    prim = roles.giver
    clear_of, scored, pending = {}, {}, []  # giver -> clear receivers; giver -> (moves, prior, receivers, first)
    n_pref = 0
    placed = _place_receivers(collider, free) if clear is None and len(free) else None
    for gi in range(min(params.givers, len(giver))):
        G = giver.grasps.T_b1_g[gi]
        clear_g = (clear[gi] if clear is not None else
                   _clear_receivers(collider, G, float(release_width(giver.grasps.width[gi], giver.grasps.contact_width[gi],
                                                                     params)),
                                    float(giver.grasps.contact_width[gi]), free, params.gap, placed))
        stats["clear_receivers"] += len(clear_g)
        if not len(clear_g):
            continue
        clear_of[gi] = clear_g
        moves = np.stack(_transfer_moves(geo, support, roles, G, params))
        pg = _prior(prim, moves @ G)
        scored[gi] = (moves, pg, clear_g[: params.max_receivers_ranked], n_pref)  # receivers: best score first
        pending += [(_cost_key(float(pg[m]), n_pref + int(m)), gi, int(m)) for m in np.nonzero(pg < params.prior_cut)[0]]
        n_pref += len(moves)
    pending.sort()
    ready = [(_cost_key(c[0], c[1]), c) for c in _paired_transfers(geo, support, giver, free, roles, params, clear_of,
                                                                     scene_clear, obj_pts, stats)]
    heapq.heapify(ready)
    for i in range(0, len(pending) + RANK_CHUNK, RANK_CHUNK):
        bound = pending[i][0] if i < len(pending) else None
        while ready and (bound is None or ready[0][0] < bound):
            yield heapq.heappop(ready)[1]
        if bound is None:
            return
        for c in _score_moves(pending[i: i + RANK_CHUNK], scored, free, roles.receiver, params, scene_clear, obj_pts,
                              stats):
            heapq.heappush(ready, (_cost_key(c[0], c[1]), c))


def _score_moves(chunk: list, scored: dict, free, sec: Arm, params, scene_clear, obj_pts, stats) -> list[tuple]:
    """The candidates among ``chunk`` ((key, giver, move index) rows): the transfer poses where the object
    keeps clear of the scene and the receiving arm ``sec`` is predicted to reach a clear receiver, with their costs."""
    out = []
    for gi in dict.fromkeys(g for _, g, _ in chunk):
        moves, pg, receivers, first = scored[gi]
        ok = np.array([m for _, g, m in chunk if g == gi], dtype=int)
        if scene_clear is not None:
            free_of_scene = _clear_of_scene(scene_clear, moves[ok], obj_pts)
            stats["object_in_scene"] += int((~free_of_scene).sum())
            ok = ok[free_of_scene]
        if not len(ok):
            continue
        best = _prior_min(sec, moves[ok], free.T_b1_g[receivers], params.prior_cut)
        out += [(float(pg[m] + best[j]), first + int(m), gi, moves[m], receivers)
                for j, m in enumerate(ok) if best[j] < params.prior_cut]
    return out


def _paired_transfers(geo, support, giver, free, roles, params, clear_of, scene_clear, obj_pts, stats) -> list[tuple]:
    """Candidates as :func:`_ranked_transfers`'s, their transfer poses solved for each (giver, clear receiver)
    pair (:func:`._handover_pairs.pair_moves`): cost = the named terms of ``PAIR_COST_TERMS`` (both arms'
    priors, the receiver's score); each candidate offers only its own receiver. After the giver-first
    candidates of equal cost."""
    prim, sec = roles.giver, roles.receiver
    pp = params.pairs
    targets, _ = _transfer_targets(geo, support, roles, params)
    out = []
    for gi, clear_g in clear_of.items():
        G = giver.grasps.T_b1_g[gi]
        ks = clear_g[: pp.receivers]
        moves, which = pair_moves(geo.centre, support.up, G[:3, 2], free.T_b1_g[ks][:, :3, 2], targets,
                                  prim.T_b1_b[:3, 3], sec.T_b1_b[:3, 3], pp)
        moves, which = moves.reshape(-1, 4, 4), ks[which.reshape(-1)]
        pg = _prior(prim, moves @ G)
        ok = np.nonzero(pg < params.prior_cut)[0]
        pr = _prior(sec, moves[ok] @ free.T_b1_g[which[ok]])
        ok, pr = ok[pr < params.prior_cut], pr[pr < params.prior_cut]
        cost = pair_costs({"giver_reach": pg[ok], "receiver_reach": pr, "receiver_grasp": 1.0 - free.score[which[ok]],
                           "receiver_hold": 1.0 - giver_hold_probability(free.depth[which[ok]], params)})
        best = np.argsort(cost, kind="stable")[: pp.keep]
        ok, cost = ok[best], cost[best]
        if scene_clear is not None and len(ok):
            free_of_scene = _clear_of_scene(scene_clear, moves[ok], obj_pts)
            stats["object_in_scene"] += int((~free_of_scene).sum())
            ok, cost = ok[free_of_scene], cost[free_of_scene]
        stats["paired_poses"] = stats.get("paired_poses", 0) + len(ok)
        out += [(float(c), 10 ** 7 + len(out) + j, gi, moves[m], np.array([which[m]])) for j, (c, m) in
                enumerate(zip(cost, ok))]
    return out


def _receiver_order(roles: _Roles, Rt: np.ndarray, free: GraspSet, clear: np.ndarray,
                    params: HandoverParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(the clear receivers to check, as indices into ``clear``; catch probability and margin of every clear
    receiver): those the receiving arm is likely to reach, best score first within tiers of its prior and, within
    a tier, the more likely to catch the object despite the calibration error first."""
    tiers = np.digitize(_prior(roles.receiver, Rt), (0.05, 0.08, 0.12))
    margin = 0.5 * (free.width[clear] - free.contact_width[clear])
    catch = catch_probability(margin, _transfer_sigma(params, roles.T_b1_b2, Rt[:, :3, 3]))
    # and whether its pads end up on the object: a receiver whose contact lies at its fingertips (depth 0)
    # closes on the object's edge and lets it slip when the object is a few millimetres off along its approach
    likely = np.round(catch * giver_hold_probability(free.depth[clear], params), 1)
    order = np.concatenate([(lambda i: i[np.argsort(-likely[i], kind="stable")])(np.nonzero(tiers == t)[0])
                            for t in range(3)])[: params.receivers_checked]
    return order, catch, margin


def _first_receiver(geo, giver, free, roles, rec_reach, rec_scene, collider, params, gi, move, Gt, rg, clear,
                    stats) -> Handover | None:
    """The hand-over with the first clear receiver that the receiving arm reaches (its gripper clear of the
    scene, ``rec_scene``, and the roles' arm-against-arm ``check`` passing) for the
    giver grasp ``gi`` moved by ``move`` to ``Gt`` (reached as ``rg``), or None."""
    w_closed = float(giver.grasps.contact_width[gi])
    Rt = move @ free.T_b1_g[clear]
    order, catch, margin = _receiver_order(roles, Rt, free, clear, params)
    stats["receiver_candidates"] += len(order)
    if not len(order):
        return None
    ks = clear[order]
    rr = rec_reach(inv_T(roles.receiver.T_b1_b) @ Rt[order], free.width[ks])
    for n, k in enumerate(ks):
        if not rr.ok[n]:
            continue
        stats["receiver_reached"] += 1
        R_k = Rt[order[n]]
        R_used = R_k if not rr.flipped[n] else rotate_about_approach(R_k)
        if rec_scene is not None and rec_scene.touches(R_used, float(free.width[k])):
            stats["receiver_in_scene"] += 1
            continue
        if roles.check is not None:
            ok2, _ = roles.check(rg.q[0], w_closed, rr.q[n], float(free.width[k]))
            if not ok2:
                continue
        gap = grippers_distance(collider, Gt, w_closed, R_used, float(free.contact_width[k]))
        receiver = {"T_b1_g": R_used, "width": float(free.width[k]), "contact_width": float(free.contact_width[k]),
                    "depth": float(free.depth[k]), "score": float(free.score[k]),
                    "terms": {t: float(v[k]) for t, v in free.terms.items()},
                    "q": rr.q[n], "q_pre": rr.q_pre[n], "index": int(k)}
        c = float(catch[order[n]])
        hold = float(giver_hold_probability(np.array([giver.grasps.depth[gi], free.depth[k]]), params).prod())
        score = 0.5 * (float(giver.grasps.score[gi]) + float(free.score[k])) * c * hold
        return Handover(move, move[:3, :3] @ geo.centre + move[:3, 3], gi, Gt, rg.q[0], w_closed, receiver,
                        gap, score, dict(stats), c, float(margin[order[n]]),
                        float(_transfer_sigma(params, roles.T_b1_b2, R_used[:3, 3])[0]), giver,
                        float(release_width(giver.grasps.width[gi], w_closed, params)), roles.giver.name)
    return None  # one receiver per (giver, transfer pose): the next alternative is another pose


def _search(geo, support, giver, free, roles, collider, params, clear, obstacles_b1, object_points_b1, stats):
    """Every feasible hand-over, cheapest predicted first (see the module docstring); counts into ``stats``."""
    prim, sec = roles.giver, roles.receiver
    with_pre = getattr(sec.reach, "with_pregrasp", None)
    rec_reach = with_pre(params.receiver_pregrasp) if with_pre is not None else sec.reach
    # the carry's free motion ends with the giver at the transfer pose, holding the object: that configuration
    # is its goal (``ArmReach.goal_problems``; a filter without it checks nothing there)
    goal_problems = getattr(prim.reach, "goal_problems", None)
    T_b_b1 = inv_T(prim.T_b1_b)
    scene_clear, obj_pts = _scene_clearance(geo, support, roles, params, obstacles_b1, object_points_b1)
    rec_scene = _receiver_scene(geo, support, roles, params, collider.gripper, obstacles_b1)
    cands = _ranked_transfers(geo, support, giver, free, roles, collider, params, clear, scene_clear, obj_pts, stats)
    for _, _, gi, T_move, clear in itertools.islice(cands, params.max_transfer_checks):
        stats["transfer_poses"] += 1
        G = giver.grasps.T_b1_g[gi]
        Gt = T_move @ G
        rg = prim.reach((T_b_b1 @ Gt)[None], np.array([giver.grasps.width[gi]]))
        if not rg.ok[0]:
            continue
        if goal_problems is not None and goal_problems(rg.q[0], float(giver.grasps.contact_width[gi])):
            stats["giver_goal_blocked"] += 1
            continue
        stats["giver_reached"] += 1
        move = T_move
        if rg.flipped[0]:
            Gt = rotate_about_approach(Gt)
            move = Gt @ inv_T(G)
            if scene_clear is not None and not _clear_of_scene(scene_clear, move, obj_pts):
                stats["object_in_scene"] += 1  # turned with the giver's wrist, the object meets the scene
                continue
        found = _first_receiver(geo, giver, free, roles, rec_reach, rec_scene, collider, params, gi, move, Gt, rg,
                                clear, stats)
        if found is not None:
            yield found

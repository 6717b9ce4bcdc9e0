"""Push contacts for two-arm lifts of objects wider than the stroke: the fingertips press a vertical face.

An object too wide for one gripper (every side wider than the stroke) is lifted by two grippers pressing
opposite faces, like two palms: the pair squeezes the object along a line through its centre, and friction
at the fingertips carries the weight. One push contact is a gripper pose whose fingertips, closed into one
pad, touch a vertical face of the object's gravity-aligned box:

- z (approach) along the face's inward normal, or tilted down from it (``tilts``): the arm squeezes by
  moving the gripper along the face normal (``extra["squeeze"]``), not along its approach, so a tilted
  gripper presses the face with the edge of its fingertips; tilts let an arm that cannot point its
  gripper horizontally near the table reach the face;
- y (closing direction) along the face at a few rolls (the closed pad presses the same either way; the
  roll is for the wrist's joint limits);
- the way in from the pre-contact (``approach`` back along the face normal, or along the approach axis)
  free of the object and the scene;
- the fingertips on the face (the deepest fingertip corner touching the face plane, measured from the
  face's own points), at the height of the centre or a little above it (then the object hangs below the
  squeeze line and does not tip), at the face's middle or off it (``laterals``);
- both fingertips must land inside the face on its points -- seen, or filled in by symmetric completion
  (``_objects.complete_by_symmetry``; a face is often seen only in part) -- where a plane fitted to the
  points around each lies within the friction cone of the face normal; or, on a planar face, between
  its points (within the range they span; the face's own plane then gives the normal); fingertips not
  on seen points scale the antipodal term down to half.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from ._antipodal import GraspSet
from ._collision import GripperCollider, SceneOctree
from ._gripper import GripperModel
from ._objects import ObjectGeometry, Support

__all__ = ["PushParams", "push_contacts", "open_ends"]


@dataclass(frozen=True)
class PushParams:
    """Push contacts (metres, radians).

    rolls: turns of the gripper about its approach (the closed pad is symmetric; for the arm's reach).
    heights: contact heights above the box centre, as fractions of the box's half height (above the centre:
        the object hangs below the squeeze line; higher is easier to reach for an arm on the table).
    laterals: contact places across the face from its middle, as fractions of the face's half width: an arm
        that reaches a face only near one of its edges (the far end of its reach, or its own base in the
        way) still finds a contact there. A pair squeezes along one line (``grasping._joint``: the two
        contacts level across the squeeze), so the other arm's contact sits across from it.
    tilts: approach tilts down from horizontal (radians; negative: pointing slightly up). The steepest (88
        degrees: the fingers hang beside the face and press it with their sides) is what a Piper reaches
        closest to its own base: on a bench scene it reached a face 14.5 cm from its base 18 times in 48,
        against 2 at 80 degrees.
    swivels: approach turns about the vertical away from the face normal (radians): an arm beside the face
        rather than in front of it reaches it turned; the squeeze stays along the face normal.
    aim_max: with the arms' bases given (``push_contacts``' ``bases_b1``), each face is also tried with its
        approach aimed straight away from each base (horizontally), where that is within this angle of the
        face normal. Close to its own base a Piper reaches a pose only with the approach in the vertical
        plane through the base (its wrist bends out of that plane too little): 14-16 cm out, a face is
        reached at tilts of 35-65 degrees with the approach within a few degrees of that plane, and at
        none 10 degrees off it; a fixed set of swivels misses that.
    press: how far past the face the fingertips are driven to squeeze (the grasp's ``depth`` is -press).
    standoff: the gap kept for the collision check of the approach: the task's approach stops this far
        out from the face (``bimanual_app.tasks._planners.PUSH_STANDOFF``), and the squeeze starts there;
        the arms' reach check ends the approach there too (``extra["hold_off"]``).
    pad_depth: points within this distance of the face plane count as under a pad.
    min_pad_points: face points needed around each fingertip (within ``fit_radius``).
    edge_margin: the pads stay this far inside the face's edges.
    fit_radius: face points within this distance of a fingertip give the plane its normal is taken from.
    face_rms: a face whose points fit a plane within this RMS (m) counts as planar: a fingertip may land on
        it between seen points (inside the range they span) with the whole face's normal.
    friction: fingertip friction coefficient (the tilt and normals must stay in its cone).
    cut_radius, contact_margin: the contact and the contact pressed ``press`` past the face must be clear of
        the scene without what lies within ``cut_radius`` of the object, by ``contact_margin``: the map and
        margin the task checks its approach and squeeze with (``bimanual_app.tasks``: ``TaskMotion``'s
        ``cut_radius``, ``CONTACT_MARGIN``).
    beyond, beyond_min_points: a face none of whose own points was seen (only filled in by the symmetric
        completion) is pushed only when the scene was seen beyond it: at least ``beyond_min_points`` points of
        the rest of the scene (table, neighbours) lie ``beyond`` (from, to; m) past it, across its width.
        Otherwise the cameras saw nothing there, and the object may go on (a box seen over half its length
        ends where the views end: pushed there, the fingertips meet the box's unseen top).
    face_shortfall, top_margin: the gripper pressed ``press + face_shortfall`` past the face (a face's points
        miss its last millimetres: the bench's cartons came out 4-10 mm shorter than they are, so the real
        face is that much further out and the fingers go that much deeper into it) keeps ``top_margin`` from
        the object's top face (its upward-facing points inside the face). A steep finger whose tips press
        1.5 cm under the top edge crosses the face plane higher up, and pressed that deep it lay on the top
        edge: in the task bench's ground-truth preview (seed 11) it rode onto the top and the carton slipped
        out of both grippers, while the preview on the slightly shorter estimate held it.
    squeeze_margin: the task squeezes this much deeper than ``press`` (``bimanual_app.tasks._planners.
        PUSH_PRESS_MARGIN``). Contacts whose gripper keeps ``top_margin`` from the top pressed that much deeper too
        (``extra["clears_top"]``) are paired first (``grasping._joint``): a tilted finger pressing just under the
        top edge lies on it once the real face is a few millimetres further out than the estimate, and the
        carton slips out of both grippers where the preview on the estimate held it.
    """

    rolls: tuple[float, ...] = (0.0, np.pi / 2, np.pi / 4, -np.pi / 4)
    heights: tuple[float, ...] = (0.3, 0.1, 0.5, 0.7)
    laterals: tuple[float, ...] = (0.0, 0.4, -0.4)
    tilts: tuple[float, ...] = (np.deg2rad(-15.0), 0.0, np.deg2rad(20.0), np.deg2rad(40.0), np.deg2rad(55.0),
                                np.deg2rad(70.0), np.deg2rad(80.0), np.deg2rad(88.0))
    swivels: tuple[float, ...] = (0.0, np.deg2rad(25.0), np.deg2rad(-25.0))
    aim_max: float = np.deg2rad(35.0)
    leans: tuple[float, ...] = (np.deg2rad(25.0), np.deg2rad(-25.0))
    lean_min_tilt: float = np.deg2rad(50.0)
    press: float = 0.008
    standoff: float = 0.010
    pad_depth: float = 0.008
    min_pad_points: int = 4
    edge_margin: float = 0.005
    fit_radius: float = 0.02
    face_rms: float = 0.003
    friction: float = 0.5
    scene_margin: float = 0.004
    approach: float = 0.09
    cut_radius: float = 0.015
    contact_margin: float = 0.003
    beyond: tuple[float, float] = (0.01, 0.15)
    beyond_min_points: int = 50
    face_shortfall: float = 0.005
    top_margin: float = 0.0
    squeeze_margin: float = 0.006


def _cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The cross product of two 3-vectors (np.cross costs ten times as much on one pair: the frame loop below
    makes thousands)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _without_near(octree: SceneOctree, points: np.ndarray, radius: float) -> SceneOctree:
    """``octree``'s points farther than ``radius`` from every one of ``points`` (M, 3), as a new octree."""
    from scipy.spatial import cKDTree

    Q = octree.points
    if not len(Q) or not len(points):
        return octree
    d, _ = cKDTree(np.asarray(points, dtype=np.float64)).query(Q, k=1, distance_upper_bound=radius)
    return SceneOctree(Q[~np.isfinite(d)], octree.resolution)


_STAT_KEYS = ("faces_seen", "unseen_beyond", "candidates", "off_face", "unseen", "outside_cone", "near_table",
              "on_top_edge", "hits_object", "hits_scene", "kept")


@dataclass
class _Face:
    """One vertical face of the object's box, as the per-candidate checks need it (see :func:`_face`)."""

    axis: int
    sign: float
    n: np.ndarray  # (3,) outward face normal
    t: np.ndarray  # (3,) horizontal direction along the face
    offset: float  # the face's distance from the box centre along n, measured from its own points
    lat: np.ndarray  # (K,) the face's own points: along t from the centre
    hgt: np.ndarray  # (K,) ... along up from the centre
    observed: np.ndarray  # (K,) ... seen (not filled in by completion)
    points: np.ndarray  # (K, 3) ... in b1
    top: SceneOctree | None  # the object's top face inside this face (see ``PushParams.top_margin``)
    planar: bool  # its points fit a plane within ``face_rms``
    align: float  # |cos| between that plane's normal and n
    rect: tuple | None  # ((lat lo, hi), (hgt lo, hi)) the range its points span


def _fingertips(gripper: GripperModel, w: float) -> tuple[list[np.ndarray], np.ndarray]:
    """Fingertip corners in g (the 4 corners of each finger box nearest the tip, (4, 3) each) and all the
    gripper's box corners (M, 3), at opening ``w``."""
    tips = []
    for s in (s for s in gripper.shapes if s.role == "finger"):
        c = s.corners_g(w)
        tips.append(c[np.argsort(-c[:, 2])[:4]])
    return tips, np.concatenate([s.corners_g(w) for s in gripper.shapes])


def _seen_beyond(geo: ObjectGeometry, others: SceneOctree, n: np.ndarray, t: np.ndarray, half: float, width: float,
                 params: PushParams) -> bool:
    """Whether the rest of the scene was seen past the face with outward normal ``n`` (see ``beyond``)."""
    ro = others.points - geo.centre
    a_o = ro @ n
    beyond = ((a_o > half + params.beyond[0]) & (a_o < half + params.beyond[1]) & (np.abs(ro @ t) < 0.5 * width))
    return beyond.sum() >= params.beyond_min_points


def _open_end(geo: ObjectGeometry, others: SceneOctree, axis: int, sign: float, params: PushParams,
              near_face: np.ndarray) -> bool:
    """Whether the box's face on ``axis`` at ``sign`` is no face at all: none of its own points was seen (it is
    only filled in by the symmetric completion) and nothing of the scene was seen beyond it, so the object may
    go on past it. ``near_face`` (N,) bool: the object's points near that face."""
    n = sign * geo.T_b1_box[:3, axis]
    if (near_face & (geo.normals @ n > 0.7) & geo.observed).any():
        return False
    t = np.cross(geo.T_b1_box[:3, 2], n)
    return not _seen_beyond(geo, others, n, t, 0.5 * geo.extent[axis], geo.extent[1 - axis], params)


def _near_face(geo: ObjectGeometry, axis: int, sign: float, params: PushParams) -> np.ndarray | None:
    """(N,) bool: the object's points near its box face on ``axis`` at ``sign`` (within 2 cm inside it, across
    its width); None when there are too few for a face the cameras saw (``2 * params.min_pad_points``)."""
    n = sign * geo.T_b1_box[:3, axis]
    rel = geo.points - geo.centre
    near = (rel @ n > 0.5 * geo.extent[axis] - 0.02) & (np.abs(rel @ np.cross(geo.T_b1_box[:3, 2], n))
                                                       < 0.5 * geo.extent[1 - axis])
    return near if near.sum() >= 2 * params.min_pad_points else None


def open_ends(geo: ObjectGeometry, others: SceneOctree, params: PushParams = PushParams()) -> list[np.ndarray]:
    """The outward normals (3,) of the object's box faces it may go on past (:func:`_open_end`: a carton whose
    far end no camera saw, its box cut short where the views stopped)."""
    out = []
    for axis in (0, 1):
        for sign in (1.0, -1.0):
            near = _near_face(geo, axis, sign, params)
            if near is not None and _open_end(geo, others, axis, sign, params, near):
                out.append(sign * geo.T_b1_box[:3, axis])
    return out


def _face(geo: ObjectGeometry, others: SceneOctree, axis: int, sign: float, params: PushParams,
          st: dict) -> _Face | None:
    """The face of the box on ``axis`` at ``sign``, or None when it may not be pushed (not seen, or only
    completed by symmetry with nothing seen beyond it)."""
    P, N, up, ext = geo.points, geo.normals, geo.T_b1_box[:3, 2], geo.extent
    n = sign * geo.T_b1_box[:3, axis]  # outward face normal
    t = np.cross(up, n)
    rel = P - geo.centre
    along, lat, hgt = rel @ n, rel @ t, rel @ up
    near_face = _near_face(geo, axis, sign, params)
    if near_face is None:
        return None  # a face the cameras did not see: no blind pushes
    st["faces_seen"] += 1
    if _open_end(geo, others, axis, sign, params, near_face):
        st["unseen_beyond"] += 1
        return None
    # the face's depth from its own points (normals along n), not from the sides' edge points near it
    own_face = near_face & (N @ n > 0.7)
    face_off = float(np.median(along[own_face])) if own_face.sum() >= params.min_pad_points \
        else float(np.percentile(along[near_face], 90))
    on_face = np.abs(along - face_off) < params.pad_depth
    top = (N @ up > 0.8) & (hgt > 0.5 * ext[2] - 0.02) & (along < face_off - params.pad_depth)
    # the face as a whole: planar (a plane fits its points within face_rms) and inside the friction
    # cone; then a fingertip on a part of it no camera saw still lands on it (the box model)
    planar, face_align, rect = False, 0.0, None
    if on_face.sum() >= 10:
        Qf = P[on_face] - P[on_face].mean(axis=0)
        _, sv, Vt = np.linalg.svd(Qf, full_matrices=False)
        planar = float(sv[-1] / np.sqrt(len(Qf))) < params.face_rms
        face_align = abs(float(Vt[-1] @ n))
        rect = (np.percentile(lat[on_face], [2, 98]), np.percentile(hgt[on_face], [2, 98]))
    return _Face(axis, sign, n, t, face_off, lat[on_face], hgt[on_face], geo.observed[on_face], P[on_face],
                 SceneOctree(P[top], 0.002) if top.any() else None, planar, face_align, rect)


def aimed_swivels(n: np.ndarray, t: np.ndarray, contact: np.ndarray, bases_b1: np.ndarray, max_angle: float,
                  known: tuple[float, ...] = ()) -> list[float]:
    """The swivels (rad, as ``PushParams.swivels``) that point the approach of a push at ``contact`` (3,)
    horizontally straight away from each of ``bases_b1`` (B, 3), on the face with outward normal ``n`` and
    horizontal tangent ``t`` (3,): those within ``max_angle`` of the normal and not within 1 degree of
    ``known`` or of each other."""
    out: list[float] = []
    for base in np.asarray(bases_b1, dtype=np.float64).reshape(-1, 3):
        aim = contact - base
        h = np.array([aim @ n, aim @ t])  # its horizontal part, in the face's (n, t)
        if np.linalg.norm(h) < 1e-6:
            continue
        # the approach's horizontal direction is -(cos(sw) n + sin(sw) t); aimed away from the base it is aim
        sw = float(np.arctan2(-h[1], -h[0]))
        if abs(sw) <= max_angle and all(abs(sw - k) > np.deg2rad(1.0) for k in (*known, *out)):
            out.append(sw)
    return out


def _frames(face: _Face, up: np.ndarray, params: PushParams, aimed: tuple[float, ...] = ()
            ) -> list[tuple[float, np.ndarray]]:
    """``(tilt, R_b1_g (3, 3))`` of every gripper orientation tried on ``face``: tilts, swivels (and the
    ``aimed`` ones), leans, rolls."""
    n, t = face.n, face.t
    frames = []
    for tilt in params.tilts:
        turns = [(sw, 0.0) for sw in (*params.swivels, *aimed)]
        if tilt >= params.lean_min_tilt:
            turns += [(0.0, ln) for ln in params.leans]
        for swivel, lean in turns:
            # swivel: the approach turned about the vertical, away from the face normal
            h_dir = np.cos(swivel) * n + np.sin(swivel) * t
            z = -np.cos(tilt) * h_dir - np.sin(tilt) * up
            # lean: the approach turned about the face normal, its top towards t (the pad's plane stays on
            # the face): an arm beside the face, not in front of it, carries a steep gripper up only when it
            # leans away from the arm's base
            z = np.cos(lean) * z + np.sin(lean) * _cross3(n, z) + (1 - np.cos(lean)) * (n @ z) * n
            # the fingers are closed into one pad (2 x 2 cm for the Piper), so the press is symmetric about
            # the gripper whatever its roll about z; the rolls only help the arm reach it
            zt = _cross3(z, t)
            zt /= np.linalg.norm(zt)
            tz = _cross3(zt, z)  # t made perpendicular to z (it is not when swivelled)
            for roll in params.rolls:
                y = np.cos(roll) * tz + np.sin(roll) * zt
                y = y / np.linalg.norm(y)
                frames.append((tilt, np.stack([_cross3(y, z), y, z], axis=1)))
    return frames


def _pads(geo: ObjectGeometry, face: _Face, tips: list[np.ndarray], R: np.ndarray, o: np.ndarray,
          params: PushParams) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(landed, seen, align, inside)`` (C,) of the fingertips at the poses (R (C, 3, 3), o (C, 3)) on ``face``.

    The pads must lie inside the box's face, and each on seen face points whose local plane is inside the
    friction cone, or (on a planar face) between its points (a face is often seen only in part: the pad then
    rests on the box model of the face, which the score marks down).
    """
    up, ext = geo.T_b1_box[:3, 2], geo.extent
    C = len(R)
    landed, seen, align, inside = np.zeros(C, int), np.zeros(C, int), np.ones(C), np.ones(C, bool)
    normals: dict[bytes, float] = {}  # |cos| of a pad's plane, by the face points it rests on (poses share them)
    Rt = np.swapaxes(R, 1, 2)
    for tc in tips:
        tw = tc @ Rt + o[:, None] - geo.centre  # (C, 4, 3) the tip's corners, from the box centre
        pl, ph = tw @ face.t, tw @ up
        lo_l, hi_l = pl.min(axis=1) - 0.002, pl.max(axis=1) + 0.002
        lo_h, hi_h = ph.min(axis=1) - 0.002, ph.max(axis=1) + 0.002
        inside &= ((np.maximum(np.abs(lo_l), np.abs(hi_l)) <= 0.5 * ext[1 - face.axis] - params.edge_margin)
                   & (lo_h >= -0.5 * ext[2] + params.edge_margin) & (hi_h <= 0.5 * ext[2] - params.edge_margin))
        # the face around the fingertip (within fit_radius of it): points there, and a plane fitted to them
        # (per-point normals of a face seen at a grazing angle are too noisy; a sparse face still has a
        # well-defined plane)
        mid_l, mid_h = 0.5 * (lo_l + hi_l), 0.5 * (lo_h + hi_h)
        around = np.hypot(face.lat - mid_l[:, None], face.hgt - mid_h[:, None]) < params.fit_radius  # (C, K)
        on = around.sum(axis=1) >= params.min_pad_points
        landed += on
        seen += on & ((around & face.observed).sum(axis=1) >= params.min_pad_points)
        for c in np.nonzero(on)[0]:
            key = around[c].tobytes()
            if key not in normals:
                Q = face.points[around[c]] - face.points[around[c]].mean(axis=0)
                normals[key] = abs(float(np.linalg.svd(Q, full_matrices=False)[2][-1] @ face.n))
            align[c] = min(align[c], normals[key])
        if face.planar:  # on the face's plane, between points seen around it
            between = (~on & (face.rect[0][0] <= mid_l) & (mid_l <= face.rect[0][1]) & (face.rect[1][0] <= mid_h)
                       & (mid_h <= face.rect[1][1]))
            landed += between
            align[between] = np.minimum(align[between], face.align)
    return landed, seen, align, inside


def _face_rows(geo: ObjectGeometry, support: Support, face: _Face, tips: list[np.ndarray], all_corners: np.ndarray,
               cone_cos: float, params: PushParams, st: dict, bases_b1: np.ndarray | None = None) -> list[tuple]:
    """The candidates on ``face`` that pass the per-pose checks (pads on the face, gripper above the table),
    as rows ``(T, face axis, face sign, height fraction, tilt, pad alignment, contact width, n, seen, contact,
    lateral fraction)``.
    With ``bases_b1`` (B, 3), also the approaches aimed away from each base (``PushParams.aim_max``)."""
    up, ext, n = geo.T_b1_box[:3, 2], geo.extent, face.n
    aimed = () if bases_b1 is None else tuple(aimed_swivels(n, face.t, geo.centre + face.offset * n, bases_b1,
                                                              params.aim_max, params.swivels))
    frames = _frames(face, up, params, aimed)
    tilts = np.array([tilt for tilt, _ in frames])
    R = np.stack([Rf for _, Rf in frames])  # (F, 3, 3)
    Rt = np.swapaxes(R, 1, 2)
    # fingertips on the face: shifted along the normal so that the deepest tip corner touches it
    depth_c = [(tc @ Rt) @ -n for tc in tips]  # (F, 4) per tip
    pen = np.max([dc.max(axis=1) for dc in depth_c], axis=0)
    deepest = [dc >= dc.max(axis=1, keepdims=True) - 1e-6 for dc in depth_c]  # (F, 4) per tip: its touching corners
    touch = (sum((tc[None] * m[..., None]).sum(axis=1) for tc, m in zip(tips, deepest))
             / sum(m.sum(axis=1) for m in deepest)[:, None])  # (F, 3) the touching corners' mean, in g
    corners = all_corners @ Rt  # (F, corners, 3) the gripper's corners, from o
    rows = []
    for lf, hf in itertools.product(params.laterals, params.heights):
        c = geo.centre + face.offset * n + lf * 0.5 * ext[1 - face.axis] * face.t + hf * 0.5 * ext[2] * up
        o = c + pen[:, None] * n  # (F, 3)
        landed, seen, align, inside = _pads(geo, face, tips, R, o, params)
        st["candidates"] += len(R)
        bad = ~inside | (landed < len(tips)) | (align < cone_cos)
        st["off_face"] += int((~inside).sum())
        st["unseen"] += int((inside & (landed < len(tips))).sum())
        st["outside_cone"] += int((inside & (landed >= len(tips)) & (align < cone_cos)).sum())
        # the whole gripper above the table by the margin
        low = ~bad & (support.elevation(corners + o[:, None]).min(axis=1) < params.scene_margin + 0.002)
        st["near_table"] += int(low.sum())
        for f in np.nonzero(~bad & ~low)[0]:
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = R[f], o[f]
            rows.append((T, face.axis, face.sign, hf, tilts[f], align[f], ext[face.axis], n, seen[f] / len(tips),
                         touch[f] @ R[f].T + o[f], lf))
    return rows


def _contact_free(collider: GripperCollider, contact_map: SceneOctree, tops: dict, rows: list[tuple],
                  T: np.ndarray, nrm: np.ndarray, wv: np.ndarray, params: PushParams,
                  st: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n,) bool arrays: the task's own check of the contact and the squeeze.

    The task's approach comes in along the way in right up to the contact (not held off), then its squeeze
    presses ``press`` past the face along the inward normal; it checks them against the scene without what
    lies within ``cut_radius`` of the object, with its contact margin (held off by the standoff alone, a
    fingertip sliding in low beside the face or past a neighbour's edge would pass here and then touch the
    task's map in the last millimetres). Pressed ``press + face_shortfall`` deep, the gripper must also keep
    ``top_margin`` from the object's top face.
    """
    T_in = T.copy()
    T_in[:, :3, 3] -= params.press * nrm
    at_contact = ~collider.collides(contact_map, T, wv, swept=False, margin=params.contact_margin)
    at_contact[at_contact] = ~collider.collides(contact_map, T_in[at_contact], wv[at_contact], swept=False,
                                                margin=params.contact_margin)
    faces = [(r[1], r[2]) for r in rows]

    def clear_of_top(ok: np.ndarray, depth: float) -> np.ndarray:
        T_deep = T.copy()
        T_deep[:, :3, 3] -= depth * nrm
        out = np.ones(len(T), dtype=bool)
        for key, tree in tops.items():
            idx = np.array([i for i, f in enumerate(faces) if f == key and ok[i]], dtype=int)
            if tree is not None and len(idx):
                out[idx] = ~collider.collides(tree, T_deep[idx], wv[idx], swept=False, margin=params.top_margin)
        return out

    under_top = clear_of_top(at_contact, params.press + params.face_shortfall)
    st["on_top_edge"] = int((at_contact & ~under_top).sum())
    clears = clear_of_top(at_contact & under_top, params.press + params.squeeze_margin + params.face_shortfall)
    return at_contact & under_top, under_top, clears


def _ways_in(collider: GripperCollider, own: SceneOctree, others: SceneOctree, contact_map: SceneOctree,
             T: np.ndarray, T_off: np.ndarray, wv: np.ndarray, retreats: np.ndarray, at_contact: np.ndarray,
             params: PushParams) -> tuple[np.ndarray, np.ndarray]:
    """``(path_ok (n, 3), hit_obj (n,))``: which ways in are free, and which contacts (held off) hit the object.

    Each way is checked at the contact held off by the standoff and at points back to the pre-contact,
    against the object and the scene, then from the contact itself against the task's contact map.
    """
    path_ok = np.zeros((len(T), retreats.shape[1]), dtype=bool)
    hit_obj = np.zeros(len(T), dtype=bool)
    for r in range(retreats.shape[1]):
        free = at_contact.copy()
        for dist in np.linspace(0.0, params.approach, 4):
            Tk = T_off.copy()
            Tk[:, :3, 3] += dist * retreats[:, r]
            free[free] = ~collider.collides(own, Tk[free], wv[free], swept=False)
            if r == 0 and dist == 0.0:
                hit_obj = ~free.copy() & at_contact
            free[free] = ~collider.collides(others, Tk[free], wv[free], swept=False, margin=params.scene_margin)
        for dist in np.linspace(0.0, params.approach, 10)[1:]:
            Tk = T.copy()
            Tk[:, :3, 3] += dist * retreats[:, r]
            free[free] = ~collider.collides(contact_map, Tk[free], wv[free], swept=False, margin=params.contact_margin)
        path_ok[:, r] = free
    return path_ok, hit_obj


def _scored(geo: ObjectGeometry, collider: GripperCollider, others: SceneOctree, rows: list[tuple], T: np.ndarray,
            T_off: np.ndarray, nrm: np.ndarray, wv: np.ndarray, retreats: np.ndarray, cone_cos: float,
            params: PushParams, clears_top: np.ndarray) -> GraspSet:
    """The kept candidates as a push :class:`GraspSet` with their score terms: those clear of the top at the
    task's squeeze depth (``clears_top`` (n,)) first, best first within each."""
    from ._score import CLEARANCE_LEVELS, WEIGHTS

    clear = collider.clearance(others, T_off, wv, CLEARANCE_LEVELS) / CLEARANCE_LEVELS[-1]
    tilt = np.array([r[4] for r in rows])
    hf = np.array([r[3] for r in rows])
    lateral = np.array([r[10] for r in rows], dtype=np.float64)
    max_tilt = max(max(params.tilts), 1e-9)
    terms = {
        "antipodal": np.clip((np.array([r[5] for r in rows]) - cone_cos) / (1 - cone_cos), 0, 1)
                     * (0.5 + 0.5 * np.array([r[8] for r in rows])),
        # off the face's middle counts against it too: the middle first where an arm reaches both
        "centring": 1.0 - np.clip(np.abs(hf - 0.3) / 0.7 + 0.5 * np.abs(lateral), 0, 1),
        "clearance": clear,
        "approach": 1.0 - 0.5 * np.abs(tilt) / max_tilt,
        "contact": np.ones(len(rows)),
    }
    score = sum(WEIGHTS[k] * v for k, v in terms.items())
    gs = GraspSet(geo.id, T, wv, np.array([r[6] for r in rows]), np.full(len(rows), -params.press), score, terms,
                  kind="push", extra={"face": np.array([(r[1], r[2]) for r in rows]),
                                      "lateral": lateral, "squeeze": -nrm,
                                      "contact": np.array([r[9] for r in rows]), "retreats": retreats,
                                      "clears_top": np.asarray(clears_top, dtype=bool),
                                      "hold_off": params.standoff * nrm})
    # those clear of the top at the task's squeeze depth first (their reach is checked first: ``PushParams``)
    return gs.take(np.lexsort((-score, ~gs.extra["clears_top"])))


def push_contacts(geo: ObjectGeometry, support: Support, gripper: GripperModel, collider: GripperCollider,
                  others: SceneOctree, params: PushParams = PushParams(), stats: dict | None = None,
                  bases_b1: np.ndarray | None = None) -> GraspSet:
    """Push contacts on the four vertical faces of the object's box (kind ``"push"``), scored, best first.
    ``bases_b1`` (B, 3): the arms' base positions, for approaches aimed away from them (``PushParams.aim_max``).

    ``depth`` holds -press; ``contact_width`` the object's width between this face and the opposite one;
    ``extra["face"]`` (n, 2) the box axis and side of the face; ``extra["lateral"]`` (n,) the place across it
    (one of ``params.laterals``); ``extra["squeeze"]`` (n, 3) the direction
    the gripper presses in (the face's inward normal, horizontal); ``extra["contact"]`` (n, 3) the point
    midway between the fingertips' contacts with the face; ``extra["retreats"]`` (n, 3, 3) the three ways in
    (unit directions from the contact to the pre-contact: along the face normal, along -z, up), NaN where that
    way is blocked; ``extra["clears_top"]`` (n,) whether the gripper keeps off the top at the task's squeeze
    depth (``PushParams.squeeze_margin``; those that do come first). ``stats`` (a dict) receives counts of the
    candidates dropped at each check.
    """
    up = geo.T_b1_box[:3, 2]
    w = gripper.min_width  # fingers closed: one pad
    cone_cos = float(np.cos(np.arctan(params.friction)))
    tips, all_corners = _fingertips(gripper, w)
    st = stats if stats is not None else {}
    for k in _STAT_KEYS:
        st[k] = 0
    rows = []  # (T, face axis, face sign, height fraction, tilt, pad alignment, contact width, n, seen, contact, lateral)
    tops = {}  # (axis, sign) -> octree of the top face's points inside that face (see ``top_margin``)
    for axis in (0, 1):
        for sign in (1.0, -1.0):
            face = _face(geo, others, axis, sign, params, st)
            if face is None:
                continue
            tops[(axis, sign)] = face.top
            rows += _face_rows(geo, support, face, tips, all_corners, cone_cos, params, st, bases_b1)
    if not rows:
        return GraspSet.empty(geo.id, kind="push")
    T = np.stack([r[0] for r in rows])
    nrm = np.stack([r[7] for r in rows])
    T_off = T.copy()
    T_off[:, :3, 3] += params.standoff * nrm  # held off the face for the approach check
    wv = np.full(len(T), w)
    # the ways in, from the pre-contact: back along the face normal, back along the approach axis (from above,
    # for a tilted gripper), or straight up (an arm near the face's own base reaches the contact with a steep
    # gripper but not a pre-contact 9 cm back towards its base); kept when free: the arm's reach filter may
    # use any of them
    retreats = np.stack([nrm, -T[:, :3, 2], np.broadcast_to(up, nrm.shape)], axis=1)  # (n, 3, 3)
    contact_map = _without_near(others, geo.points, params.cut_radius)
    at_contact, under_top, clears = _contact_free(collider, contact_map, tops, rows, T, nrm, wv, params, st)
    path_ok, hit_obj = _ways_in(collider, SceneOctree(geo.points, 0.002), others, contact_map, T, T_off, wv,
                                retreats, at_contact, params)
    free = path_ok.any(axis=1)
    st["hits_object"] = int(hit_obj.sum())
    st["hits_scene"] = int((~free & ~hit_obj & under_top).sum())
    st["kept"] = int(free.sum())
    keep = np.nonzero(free)[0]
    if len(keep) == 0:
        return GraspSet.empty(geo.id, kind="push")
    retreats = np.where(path_ok[keep][:, :, None], retreats[keep], np.nan)
    return _scored(geo, collider, others, [rows[i] for i in keep], T[keep], T_off[keep], nrm[keep], wv[keep],
                   retreats, cone_cos, params, clears[keep])

"""Grasp choices a task plans with, read from grasps.json (``bijcr grasp``), and the choice of object.

:class:`GraspSpec` is one arm's grasp as the task uses it: the gripper pose in b1 when the fingers meet
the object (``T_b1_g``, contract gripper frame g), the opening while approaching, and for a push contact
how far past the face the fingertips squeeze. :class:`JointChoice` / :class:`HandoverChoice` are the two
tasks' inputs. :func:`joint_candidates` / :func:`handover_candidates` list them from grasps.json, best
first; :func:`choose` picks the requested object or the best one and says why.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bimanual_app.io_utils import InputError, Problem
from bimanual_app.transforms import check_T

from ._plan import ARMS

__all__ = ["GraspSpec", "JointChoice", "HandoverChoice", "joint_candidates", "handover_candidates", "choose"]


@dataclass
class GraspSpec:
    """One arm's grasp.

    Attributes:
        arm: ``primary`` or ``secondary``.
        T_b1_g: (4,4) gripper pose in b1 at contact.
        width: opening while approaching (m).
        kind: ``pinch`` (fingers close on the object) or ``push`` (open fingertips press a face).
        press: push only: how far past the face the fingertips are driven to squeeze (m).
        contact_width: the object's width between the contacts (m), or None.
        score: grasp score (higher is better).
        q: (J,) the grasping stage's IK solution (a seed), or None.
        q_pre: (J,) its pre-grasp solution, or None.
        squeeze: push only: (3,) unit direction in b1 the fingertips are driven along (the face's inward
            normal; default the approach z).
        pre_dist: pre-grasp distance back along the approach (m; grasps.json ``pregrasp_distance``, the
            distance the grasping stage checked the pre-grasp at).
        contact: push only: (3,) where the fingertips meet the face in b1 (grasps.json ``contact_b1``), or
            None (then the gripper's origin stands for it).
    """

    arm: str
    T_b1_g: np.ndarray
    width: float
    kind: str = "pinch"
    press: float = 0.0
    contact_width: float | None = None
    score: float = 0.0
    q: np.ndarray | None = None
    q_pre: np.ndarray | None = None
    squeeze: np.ndarray | None = None
    pre_dist: float = 0.08
    contact: np.ndarray | None = None

    @property
    def squeeze_dir(self) -> np.ndarray:
        d = self.T_b1_g[:3, 2] if self.squeeze is None else np.asarray(self.squeeze, dtype=np.float64)
        return d / np.linalg.norm(d)


@dataclass
class JointChoice:
    object_id: int
    primary: GraspSpec
    secondary: GraspSpec
    score: float
    kind: str
    info: dict = field(default_factory=dict)


@dataclass
class HandoverChoice:
    """A hand-over: the giver's pick grasp, the rigid object motion to the transfer pose, and the grasps
    there (all in b1). The giver is ``pick.arm`` (``primary`` or ``secondary``), the receiver ``receiver.arm``."""

    object_id: int
    pick: GraspSpec
    T_move: np.ndarray
    giver_transfer: GraspSpec
    receiver: GraspSpec
    score: float
    info: dict = field(default_factory=dict)

    @property
    def giver(self) -> str:
        return self.pick.arm

    @property
    def taker(self) -> str:
        return self.receiver.arm


def _arr(d: dict, key: str, shape=None):
    v = d.get(key)
    if v is None:
        return None
    a = np.asarray(v, dtype=np.float64)
    if shape is not None and a.shape != shape:
        return None
    return a


def _spec(d: dict, arm: str, path: str, where: str, pre_dist: float = 0.08) -> GraspSpec:
    """A GraspSpec from one grasps.json grasp entry."""
    try:
        T = check_T(f"{where}.T_b1_g", np.asarray(d["T_b1_g"], dtype=np.float64))
        width = float(d["width"])
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(Problem(path, where, f"not a usable grasp ({e})", "re-run `bijcr grasp`")) from None
    kind = str(d.get("kind", "pinch"))
    depth = float(d.get("depth", 0.0) or 0.0)
    press = float(d.get("press", -depth if kind == "push" and depth < 0 else 0.0))
    cw = d.get("contact_width")
    q_pre = _arr(d, "q_pregrasp", (6,))
    return GraspSpec(arm, T, width, kind, press, None if cw is None else float(cw), float(d.get("score", 0.0)),
                     _arr(d, "q", (6,)), q_pre if q_pre is not None else _arr(d, "q_pre", (6,)),
                     _arr(d, "squeeze_b1", (3,)), float(pre_dist), _arr(d, "contact_b1", (3,)))


def _objects(grasps: dict) -> list[dict]:
    return [o for o in grasps.get("objects", []) or [] if isinstance(o, dict)]


def joint_candidates(grasps: dict, path: str) -> list[JointChoice]:
    """Every joint pair of every object in grasps.json: the objects by their best pair's score, each object's
    pairs in grasps.json's order (the grasping stage puts the best first, then pairs that hold the object
    elsewhere, then near copies of those: a task that falls back to the next pair gets another place)."""
    out = []
    pre = float(grasps.get("pregrasp_distance") or 0.08)
    for o in _objects(grasps):
        oid = int(o.get("id", -1))
        for n, pair in enumerate(o.get("joint_grasps") or []):
            where = f"objects[{oid}].joint_grasps[{n}]"
            p, s = pair.get("primary"), pair.get("secondary")
            if not isinstance(p, dict) or not isinstance(s, dict):
                raise InputError(Problem(path, where, "a joint pair needs 'primary' and 'secondary' grasps",
                                         "re-run `bijcr grasp`"))
            kind = str(pair.get("kind", p.get("kind", "pinch")))
            p = dict(p, kind=p.get("kind", kind))
            s = dict(s, kind=s.get("kind", kind))
            out.append(JointChoice(oid, _spec(p, "primary", path, where + ".primary", pre),
                                   _spec(s, "secondary", path, where + ".secondary", pre),
                                   float(pair.get("score", 0.0)), kind,
                                   {"source": where, **{k: pair[k] for k in ("imbalance", "separation") if k in pair}}))
    best: dict[int, float] = {}
    for c in out:
        best[c.object_id] = max(best.get(c.object_id, -np.inf), c.score)
    order = sorted(range(len(out)), key=lambda n: (-best[out[n].object_id], n))
    return [out[n] for n in order]


def shape_kind(o: dict) -> str:
    """A grasps.json object's ``shape.kind``: ``box``, ``cylinder``, ``free-form`` (its seen points fit
    neither), or ``unknown`` for a grasps.json without ``shape`` (such objects count as determined)."""
    shape = o.get("shape")
    return str(shape.get("kind", "unknown")) if isinstance(shape, dict) else "unknown"


def open_end_count(o: dict) -> int:
    """A grasps.json object's ``shape.open_ends``: how many faces of its box no camera saw, with nothing seen beyond
    them (the object may go on past them: seen only in part); 0 for a grasps.json without it."""
    shape = o.get("shape")
    n = shape.get("open_ends", 0) if isinstance(shape, dict) else 0
    return int(n) if isinstance(n, (int, float)) else 0


def handover_candidates(grasps: dict, path: str) -> list[HandoverChoice]:
    """Every hand-over in grasps.json (each object's ``handover`` and its ``handover_alternatives``): those of
    objects whose shape the cloud determines (a cylinder, or a box seen whole: grasps.json ``shape``) first, then
    the others (free-form, or a box with an open end: ``shape.open_ends``); best score first within each. A free-form
    object seen from some sides only (a mug without its handle, a bunny's far side) hides what meets the
    receiver's fingers, and an object whose box ends where the views ended may be several times the body
    planned with, so such a hand-over can pass the preview on the reconstruction and fail in reality where a
    box or a cylinder seen whole would not (docs/tasks.md)."""
    out = []
    pre = float(grasps.get("pregrasp_distance") or 0.08)
    for o in _objects(grasps):
        oid = int(o.get("id", -1))
        entries = [(f"objects[{oid}].handover", o.get("handover"))]
        entries += [(f"objects[{oid}].handover_alternatives[{n}]", h)
                    for n, h in enumerate(o.get("handover_alternatives") or [])]
        for where, h in entries:
            if isinstance(h, dict) and h:
                c = _handover_choice(oid, h, path, where, pre)
                c.info["source"] = where  # which grasps.json entry (the report names an alternative used)
                c.info["shape"] = shape_kind(o)
                c.info["free_form"] = c.info["shape"] == "free-form"
                c.info["open_ends"] = open_end_count(o)
                # a box ends at its faces, seen or not; a cylinder's fitted circle gives all of it
                c.info["undetermined"] = c.info["free_form"] or (c.info["shape"] == "box" and c.info["open_ends"] > 0)
                out.append(c)
    # the primary gives by preference (grasps.json offers the secondary's only where the primary gives none)
    out.sort(key=lambda c: (c.info["undetermined"], c.giver != "primary", -c.score))
    return out


def _handover_choice(oid: int, h: dict, path: str, where: str, pre: float) -> HandoverChoice:
    """One grasps.json hand-over entry as a HandoverChoice."""
    try:
        T_move = check_T(where + ".T_move", np.asarray(h["T_move"], dtype=np.float64))
    except (KeyError, ValueError) as e:
        raise InputError(Problem(path, where + ".T_move", f"missing or invalid ({e})", "re-run `bijcr grasp`")) from None
    giver = h.get("giver") or {}
    arm_g, arm_r = _handover_arms(h, path, where)
    cw = giver.get("contact_width")
    pick = _spec(dict(giver.get("pick", {}), contact_width=cw), arm_g, path, where + ".giver.pick", pre)
    # the giver lets go at the transfer pose opening ``release_width`` (grasps.json; else as wide as it picked)
    tr = dict(giver.get("transfer", {}), width=giver.get("release_width", pick.width), contact_width=cw)
    if "T_b1_g" not in tr:
        tr["T_b1_g"] = T_move @ pick.T_b1_g
    gt = _spec(tr, arm_g, path, where + ".giver.transfer", pre)
    rec = _spec(h.get("receiver") or {}, arm_r, path, where + ".receiver", pre)
    return HandoverChoice(oid, pick, T_move, gt, rec, float(h.get("score", 0.0)), {k: h[k] for k in ("gap",) if k in h})


def _handover_arms(h: dict, path: str, where: str) -> tuple[str, str]:
    """(giver, receiver) arm names of a grasps.json hand-over entry: ``giver.arm`` and ``receiver.arm``
    (absent: the primary gives, as grasps.json files before either arm could give)."""
    arm_g = (h.get("giver") or {}).get("arm", "primary")
    arm_r = (h.get("receiver") or {}).get("arm", ARMS[1 - ARMS.index(arm_g)] if arm_g in ARMS else "secondary")
    for field_, arm in (("giver.arm", arm_g), ("receiver.arm", arm_r)):
        if arm not in ARMS:
            raise InputError(Problem(path, f"{where}.{field_}", f"unknown arm {arm!r}",
                                     "use 'primary' or 'secondary' (or re-run `bijcr grasp`)"))
    if arm_g == arm_r:
        raise InputError(Problem(path, f"{where}.receiver.arm", f"the giver and the receiver are both the {arm_g}",
                                 "one arm gives and the other receives: re-run `bijcr grasp`"))
    return arm_g, arm_r


def choose(cands: list, object_id: int | None, task: str, path: str, known_ids: list[int]):
    """The candidates to try (one object) and the reason for the object.

    With ``object_id``: that object's candidates (InputError when the id is unknown; an empty list when
    the object has none: the caller reports it as unreachable). Without: the object of the best-scoring
    candidate.
    """
    if object_id is not None:
        if object_id not in known_ids:
            raise InputError(Problem(path, "--object", f"no object {object_id} in the segments "
                                     f"(objects: {', '.join(map(str, sorted(known_ids))) or 'none'})",
                                     "pass one of the listed ids, or leave --object out to let the task choose"))
        mine = [c for c in cands if c.object_id == object_id]
        return mine, f"object {object_id}, as requested"
    if not cands:
        return [], "no object has a feasible " + ("two-arm grasp" if task == "joint-grasp" else "hand-over")
    best = cands[0].object_id
    mine = [c for c in cands if c.object_id == best]
    others = sorted({c.object_id for c in cands} - {best})
    what = "two-arm grasp pair" if task == "joint-grasp" else "hand-over"
    top = max(cands, key=lambda c: c.score)
    if task == "handover" and top.object_id != best and top.info.get("undetermined") \
            and not cands[0].info.get("undetermined"):
        # the best score belongs to an object whose shape the cloud does not determine, passed over
        why = ("is free-form: what no camera saw of it may meet the fingers" if top.info.get("free_form") else
               "was not seen whole (an end of it where the views ended): it may be larger than planned with")
        reason = (f"object {best} has the best-scoring {what} among the objects whose shape the cloud determines "
                  f"(a {cands[0].info.get('shape', 'primitive')}; score {cands[0].score:.2f}); object {top.object_id} "
                  f"scores higher ({top.score:.2f}) but {why}"
                  + (f"; other candidates: {', '.join(map(str, others))}" if others else ""))
        return mine, reason
    reason = (f"object {best} has the best-scoring {what} (score {cands[0].score:.2f}"
              + (f"; other candidates: {', '.join(map(str, others))}" if others else "; the only candidate") + ")")
    return mine, reason

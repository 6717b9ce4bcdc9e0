"""The collision world: one or two arms in frame b1 against the scene map, each other, and themselves.

Checks run in two phases over a batch of configurations:

1. broad phase, vectorised with numpy: every shape's bounding capsule is placed by batched FK; capsule
   pairs (self and arm-vs-arm) get their exact segment distance (``_capsules.segment_distance``), and
   capsules against the scene get conservative lower / upper bounds from the map's distance field
   (``SceneMap``). A pair is *clear* when the lower bound exceeds the margin, *in collision* when the
   shapes are exactly capsules and the upper bound is below it, and *undecided* otherwise;
2. narrow phase, with coal, only for the undecided pairs: ``coal.collide`` with the margin as security
   margin (shape vs shape, shape vs the coal octree of the scene).

So the answer is the exact one of coal on the URDF's collision shapes and the octree, at the cost of
numpy for all clear configurations. Distances (``distance``) are computed by coal for every pair.

Validity: a configuration is valid when every moving arm shape is at least ``margin`` from the scene
map (the base link stands on the table and is not checked against the map) and every shape is at least
``margin`` from the other arm, and self-collision pairs are at least ``self_margin`` apart (pairs of shapes on the
same or adjacent arm links are never checked). An object can be cut out of the map and attached to a
gripper; it then moves with the gripper and is checked against the scene and the other arm.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from bimanual_app.collision._capsules import segment_distance
from bimanual_app.collision._scene_map import SceneMap, shared_scene_map
from bimanual_app.collision._shapes import ArmShapes, Shape, arm_shapes, obb_of_points
from bimanual_app.transforms import check_shape, check_T

__all__ = ["CollisionWorld", "DistanceReport", "ARM_NAMES"]

ARM_NAMES = ("primary", "secondary")


@dataclass
class DistanceReport:
    """Exact (coal) clearances of one configuration pair, in metres; negative means penetration.

    min_distance: the smallest over all checked pairs. valid: every clearance meets its margin.
    scene: arm name -> (distance, shape name) closest to the map (None without a map).
    arm_arm: (distance, shape of primary, shape of secondary) (None with one arm).
    self: arm name -> (distance, shape, shape) of the closest self-collision pair.
    contacts: descriptions of the pairs closer than their margin.
    """

    min_distance: float
    valid: bool
    scene: dict = field(default_factory=dict)
    arm_arm: tuple | None = None
    self: dict = field(default_factory=dict)
    contacts: list = field(default_factory=list)


_SHAPE_VERSIONS = itertools.count()


class _Arm:
    """One arm placed in b1: its robot, base pose, shapes and broad-phase sample points."""

    def __init__(self, name: str, robot, T_b1_b: np.ndarray, opening: float, step: float,
                 extra: list[Shape] | None = None):
        self.name = name
        self.robot = robot
        self.T_b1_b = check_T(f"T_b1_b ({name})", T_b1_b)
        self.opening = float(opening)
        self.extra = list(extra or [])
        self.step = step
        self.rebuild()

    def rebuild(self) -> None:
        self.shapes: ArmShapes = arm_shapes(self.robot, extra=self.extra)
        # a new number for every rebuild: the world's tables are cached by it (an object's id() is no key:
        # a freed ArmShapes' address is reused by the next one, which left stale tables after attach / detach)
        self.version = next(_SHAPE_VERSIONS)
        sh = self.shapes
        joints_used = np.unique(sh.joint)
        self.joints_used = joints_used
        self.shape_slot = np.searchsorted(joints_used, sh.joint)  # index into the gathered placements
        # scene samples: points along each bounding-capsule axis; the ball of radius cover[s] (capsule
        # radius + half the spacing) around the nearest sample contains every point of shape s
        pts, owner, cover = [], [], []
        for s in range(len(sh.shapes)):
            L = float(np.linalg.norm(sh.b[s] - sh.a[s]))
            n = max(1, int(np.ceil(L / self.step)) + 1) if L > 1e-9 else 1
            t = np.linspace(0.0, 1.0, n) if n > 1 else np.zeros(1)
            pts.append(sh.a[s] + t[:, None] * (sh.b[s] - sh.a[s]))
            owner.append(np.full(n, s))
            cover.append(float(sh.radius[s]) + (L / (n - 1) / 2 if n > 1 else 0.0))
        self.sample_local = np.concatenate(pts)
        self.sample_owner = np.concatenate(owner)
        self.sample_slot = self.shape_slot[self.sample_owner]
        self.sample_start = np.searchsorted(self.sample_owner, np.arange(len(sh.shapes)))
        # all local points (segment ends a, b, then samples), grouped by joint slot for one matmul each
        local = np.concatenate([sh.a, sh.b, self.sample_local])
        slot = np.concatenate([self.shape_slot, self.shape_slot, self.sample_slot])
        order = np.argsort(slot, kind="stable")
        self._pt_local = local[order]
        self._pt_bounds = np.searchsorted(slot[order], np.arange(len(joints_used) + 1))
        self._pt_slot = slot[order]
        where = np.empty(len(order), dtype=int)
        where[order] = np.arange(len(order))
        S = len(sh.shapes)
        self._idx_a, self._idx_b, self._idx_s = where[:S], where[S:2 * S], where[2 * S:]
        self.cover = np.array(cover)
        self.fixed = sh.group == 0  # shapes that no arm joint moves (the base)
        self.lever = self._levers()

    def _levers(self) -> np.ndarray:
        """(J,) for each arm joint, an upper bound of the distance from its axis to any shape it moves.

        A joint step dq then moves every point of the arm by at most sum_i lever_i |dq_i| (m).
        """
        model = self.robot.model
        arm = list(self.robot._arm_joint_ids)
        fl = np.abs(np.concatenate([self.robot._finger_lower, self.robot._finger_upper]))
        finger_travel = float(fl.max()) if fl.size else 0.0
        lever = np.zeros(len(arm))
        sh = self.shapes
        for s in range(len(sh.shapes)):
            ext = max(np.linalg.norm(sh.a[s]), np.linalg.norm(sh.b[s])) + sh.radius[s]
            # walk from the shape's joint up to the root, adding the joint offsets
            j, dist = int(sh.joint[s]), ext
            while j > 0:
                if j in arm:
                    k = arm.index(j)
                    lever[k] = max(lever[k], dist)
                else:
                    dist += finger_travel
                dist += float(np.linalg.norm(model.jointPlacements[j].translation))
                j = int(model.parents[j])
        return lever

    def placements(self, Q: np.ndarray) -> np.ndarray:
        """(N, len(joints_used), 4, 4) b1 placements of the joints carrying shapes, for arm q (N,J)."""
        JP = self.robot.joint_placements(self.robot.full_q(Q, self.opening))[:, self.joints_used]
        return self.T_b1_b @ JP

    def points(self, W: np.ndarray, with_samples: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """World capsule segments A, B (N,S,3) and sample points (N,K,3) from joint placements ``W``."""
        if len(W) == 1:  # one configuration: a single gather + einsum beats the per-joint loop
            Wp = W[0, self._pt_slot]
            out = (np.einsum("pij,pj->pi", Wp[:, :3, :3], self._pt_local) + Wp[:, :3, 3])[None]
            return out[:, self._idx_a], out[:, self._idx_b], (out[:, self._idx_s] if with_samples else None)
        out = np.empty((len(W), len(self._pt_local), 3))
        for j in range(len(self.joints_used)):
            lo, hi = self._pt_bounds[j], self._pt_bounds[j + 1]
            if hi > lo:
                out[:, lo:hi] = self._pt_local[lo:hi] @ W[:, j, :3, :3].transpose(0, 2, 1) + W[:, j, None, :3, 3]
        return out[:, self._idx_a], out[:, self._idx_b], (out[:, self._idx_s] if with_samples else None)

    def shape_tf(self, W_n: np.ndarray, s: int):
        """coal.Transform3s of shape ``s`` for one configuration's placements ``W_n`` (G,4,4)."""
        import coal

        T = W_n[self.shape_slot[s]] @ self.shapes.M[s]
        return coal.Transform3s(T[:3, :3].copy(), T[:3, 3].copy())


class CollisionWorld:
    """Arms in frame b1 against a scene map, each other and themselves (see the module docstring).

    Args:
        robot: RobotModel of the primary arm (base b1 = identity).
        T_b1_b2: (4,4) base of the secondary arm in b1, or None for a single-arm world.
        scene: SceneMap, (N,3) points in b1, or None (no scene).
        robot2: RobotModel of the secondary arm (default: the same model as the primary).
        resolution: voxel size of the scene map (m) when ``scene`` is points.
        margin: required clearance to the scene and between the arms (m). The clearance to the scene may be
            changed later (``world.margin``, e.g. for moves in contact); the one between the arms stays
            ``arm_margin``, this value.
        self_margin: required clearance between non-adjacent links of one arm (m).
        openings: gripper opening of each arm (m) used for the finger shapes.
        crop: drop scene points farther than reach + 0.3 m from every base (they cannot matter).
        scene_exempt: link names whose shapes are not checked against the scene (still against the other
            arm and the arm itself): e.g. a gripper whose scene clearance a finer check already decided.
        T_b1_b: (4,4) base of the first arm in b1 (default identity: the primary); a single-arm world of the
            secondary is ``CollisionWorld(robot, None, scene, T_b1_b=T_b1_b2)``, against the same map in b1.
    """

    def __init__(self, robot, T_b1_b2: np.ndarray | None = None, scene=None, *, robot2=None,
                 resolution: float = 0.01, margin: float = 0.01, self_margin: float = 0.0,
                 openings: tuple[float, float] = (0.0, 0.0), crop: bool = True, scene_exempt: tuple[str, ...] = (),
                 T_b1_b: np.ndarray | None = None):
        step = resolution  # broad-phase sample spacing along capsules
        self.arms = [_Arm(ARM_NAMES[0], robot, np.eye(4) if T_b1_b is None else T_b1_b, openings[0], step)]
        if T_b1_b2 is not None:
            self.arms.append(_Arm(ARM_NAMES[1], robot2 or robot, T_b1_b2, openings[1], step))
        self.margin = float(margin)
        self.arm_margin = float(margin)
        self.scene_exempt = frozenset(scene_exempt)
        self.self_margin = float(self_margin)
        self.resolution = float(resolution)
        if scene is None or isinstance(scene, SceneMap):
            self.scene = scene
        else:
            crop_box = None
            if crop:
                bases = np.stack([a.T_b1_b[:3, 3] for a in self.arms])
                reach = max(float(np.sum(a.lever[:1])) for a in self.arms) + 0.3
                crop_box = (bases.min(axis=0) - reach, bases.max(axis=0) + reach)
            pad = max(float(a.shapes.radius.max()) for a in self.arms) + self.margin + 0.1
            # built once per process for these points (the maps are never edited): the worlds of both tasks
            # of one run, and of every object a task tries, share it
            self.scene = shared_scene_map(scene, resolution, pad=pad, crop=crop_box)
        self.stats = {"configs": 0, "narrow": 0}
        self.chunk = 512  # configurations per vectorised pass

    # ------------------------------------------------------------------ set-up
    @property
    def n_arms(self) -> int:
        return len(self.arms)

    def arm_index(self, arm: int | str) -> int:
        if isinstance(arm, str):
            if arm not in ARM_NAMES[: self.n_arms]:
                raise ValueError(f"arm must be one of {ARM_NAMES[: self.n_arms]}, got {arm!r}")
            return ARM_NAMES.index(arm)
        if not 0 <= arm < self.n_arms:
            raise ValueError(f"arm index {arm} out of range for {self.n_arms} arm(s)")
        return int(arm)

    def set_scene(self, scene: SceneMap | None) -> None:
        self.scene = scene

    def set_opening(self, arm: int | str, opening: float) -> None:
        self.arms[self.arm_index(arm)].opening = float(opening)

    def cut(self, mask: np.ndarray) -> None:
        """Remove the scene points where ``mask`` (N,) is True (an object about to be grasped)."""
        if self.scene is None:
            raise ValueError("this world has no scene map to cut")
        self.scene = self.scene.without(mask)

    def attach(self, arm: int | str, points_b1: np.ndarray, q: np.ndarray, name: str = "object",
               padding: float = 0.005, cut_radius: float | None = None, axis_b1: np.ndarray | None = None) -> None:
        """Attach an object, given by its points (M,3) in b1, to ``arm``'s tool link at configuration ``q``.

        The object becomes an oriented box (padded) that moves with the tool; it is checked against the
        scene and the other arm, not against its own gripper and wrist. With ``cut_radius`` the scene
        points within that distance of the object's points are removed from the map first. ``axis_b1``
        (3,): a direction the box may keep an edge along (the table normal, for an object standing on it;
        see :func:`obb_of_points`).
        """
        import coal

        k = self.arm_index(arm)
        a = self.arms[k]
        P = np.asarray(points_b1, dtype=np.float64).reshape(-1, 3)
        if len(P) < 3:
            raise ValueError("attach: need at least 3 object points")
        if cut_radius is not None and self.scene is not None:
            self.scene = self.scene.without_near(P, cut_radius)
        ee_joint = int(a.robot.model.frames[a.robot.frame_id(a.robot.ee_link)].parentJoint)
        JP = a.robot.joint_placements(a.robot.full_q(np.asarray(q, float)[None], a.opening))[0]
        T_b1_j = a.T_b1_b @ JP[ee_joint]
        P_j = (np.linalg.inv(T_b1_j) @ np.c_[P, np.ones(len(P))].T).T[:, :3]
        axis_j = None if axis_b1 is None else T_b1_j[:3, :3].T @ np.asarray(axis_b1, dtype=np.float64)
        T_j_box, half = obb_of_points(P_j, padding, axis=axis_j)
        geom = coal.Box(*(2 * half))
        k_long = int(np.argmax(half))
        ea = np.zeros(3)
        ea[k_long] = half[k_long]
        r = float(np.linalg.norm(np.delete(half, k_long)))
        # the tool link's joint is the last arm joint: the object shares its group (gripper, fingers)
        shape = Shape(name, ee_joint, ee_joint, geom, T_j_box, T_j_box[:3, :3] @ -ea + T_j_box[:3, 3],
                      T_j_box[:3, :3] @ ea + T_j_box[:3, 3], r, False)
        a.extra = [s for s in a.extra if s.name != name] + [shape]
        a.rebuild()

    def detach(self, arm: int | str, name: str | None = None) -> None:
        a = self.arms[self.arm_index(arm)]
        a.extra = [s for s in a.extra if name is not None and s.name != name]
        a.rebuild()

    def motion_bound(self, arm: int | str, dq: np.ndarray) -> np.ndarray:
        """Upper bound (m) of how far any point of ``arm`` moves for joint steps ``dq`` (..., J) -> (...)."""
        return np.abs(np.asarray(dq)) @ self.arms[self.arm_index(arm)].lever

    # ------------------------------------------------------------------ checks
    def _configs(self, Qs) -> tuple[list[np.ndarray], int]:
        if len(Qs) != self.n_arms:
            raise ValueError(f"this world has {self.n_arms} arm(s); give one configuration (array) per arm")
        out, n = [], 1
        for a, Q in zip(self.arms, Qs):
            Q = np.asarray(Q, dtype=np.float64)
            if Q.shape[-1] != a.robot.nq_arm or Q.ndim > 2:
                raise ValueError(f"{a.name}: expected q of shape ({a.robot.nq_arm},) or (N, {a.robot.nq_arm}), got {Q.shape}")
            if Q.ndim == 2:
                if n not in (1, len(Q)):
                    raise ValueError("configuration batches of the two arms differ in length")
                n = max(n, len(Q))
            out.append(Q)
        return out, n

    def valid_batch(self, Q1: np.ndarray, Q2: np.ndarray | None = None) -> np.ndarray:
        """(N,) bool: each configuration pair is collision free. Q1 (N,J) or (J,); Q2 likewise (two arms).

        A single (J,) configuration of an arm is held for the whole batch (the other arm planning).
        """
        Qs, n = self._configs([Q1] if self.n_arms == 1 else [Q1, Q2])
        if n <= self.chunk:
            return self._check(Qs, n)[0]
        # large batches in chunks: the intermediate arrays stay in cache (about 3x faster at 20,000)
        out = np.empty(n, dtype=bool)
        for lo in range(0, n, self.chunk):
            hi = min(n, lo + self.chunk)
            part = [Q[lo:hi] if Q.ndim == 2 else Q for Q in Qs]
            out[lo:hi] = self._check(part, hi - lo)[0]
        return out

    def valid(self, q1: np.ndarray, q2: np.ndarray | None = None) -> bool:
        """True when the configuration (pair) is collision free."""
        return bool(self.valid_batch(np.asarray(q1, float)[None], None if q2 is None else np.asarray(q2, float))[0])

    def explain(self, q1: np.ndarray, q2: np.ndarray | None = None) -> list[str]:
        """Descriptions of the collisions of one configuration pair ([] when valid)."""
        Qs, n = self._configs([np.asarray(q1, float)[None]] + ([] if q2 is None else [np.asarray(q2, float)[None]]))
        return self._check(Qs, 1, explain=True)[1]

    def near_arms(self, points_b1: np.ndarray, qs: list[np.ndarray], pad: float) -> np.ndarray:
        """(N,) True for the points ``points_b1`` (N, 3) within ``pad`` m of an arm's bounding capsules with the
        arms at ``qs`` (one (J,) configuration per arm, in order): the space the arms take up there, padded.
        The base's shapes are left out, as in the checks against the map (the base stands on the table).
        Capsules bound the exact shapes, so this is a superset of the points the exact shapes come within
        ``pad`` of."""
        P = check_shape("points_b1", np.asarray(points_b1, dtype=np.float64), (None, 3))
        if len(qs) != self.n_arms:
            raise ValueError(f"near_arms: one configuration per arm ({self.n_arms}), got {len(qs)}")
        out = np.zeros(len(P), dtype=bool)
        for arm, q in zip(self.arms, qs):
            A, B, _ = arm.points(arm.placements(np.asarray(q, dtype=np.float64)[None]), with_samples=False)
            moving = np.flatnonzero(~arm.fixed)
            A, B, reach = A[0, moving], B[0, moving], arm.shapes.radius[moving] + float(pad)
            lo, hi = np.minimum(A, B) - reach[:, None], np.maximum(A, B) + reach[:, None]
            near = np.flatnonzero(np.all((P >= lo.min(axis=0)) & (P <= hi.max(axis=0)), axis=1))  # the arm's box
            for s in range(len(A)):  # a shape at a time, on the points in its padded bounding box
                idx = near[~out[near] & np.all((P[near] >= lo[s]) & (P[near] <= hi[s]), axis=1)]
                if len(idx):
                    out[idx] = segment_distance(A[s], B[s], P[idx], P[idx]) <= reach[s]
        return out

    def _tables(self) -> dict:
        """Shape, sample and pair tables over all arms (cached; rebuilt after attach / detach)."""
        key = tuple(a.version for a in self.arms)
        if getattr(self, "_tab_key", None) == key:
            return self._tab
        arm_of, local, offs, pairs, margins, kinds = [], [], [], [], [], []
        o = 0
        for k, a in enumerate(self.arms):
            S = len(a.shapes.shapes)
            arm_of += [k] * S
            local += list(range(S))
            offs.append(o)
            for i, j in a.shapes.self_pairs:
                pairs.append((o + i, o + j))
                margins.append(self.self_margin)
                kinds.append("self")
            o += S
        if self.n_arms == 2:
            S1, S2 = len(self.arms[0].shapes.shapes), len(self.arms[1].shapes.shapes)
            for i in range(S1):
                for j in range(S2):
                    pairs.append((i, offs[1] + j))
                    margins.append(self.arm_margin)
                    kinds.append("arms")
        cat = lambda f: np.concatenate([f(a) for a in self.arms])  # noqa: E731
        P = np.array(pairs, dtype=int).reshape(-1, 2)
        radius, exact = cat(lambda a: a.shapes.radius), cat(lambda a: a.shapes.exact)
        sample_owner = np.concatenate([a.sample_owner + offs[k] for k, a in enumerate(self.arms)])
        self._tab = dict(
            arm_of=np.array(arm_of), local=np.array(local), radius=radius, exact=exact,
            fixed=cat(lambda a: a.fixed | np.array([n.split("#")[0] in self.scene_exempt for n in a.shapes.names],
                                                   dtype=bool)),
            cover=cat(lambda a: a.cover),
            sample_start=np.searchsorted(sample_owner, np.arange(len(radius))),
            pairs=P, pair_margin=np.array(margins), pair_exact=exact[P[:, 0]] & exact[P[:, 1]] if len(P) else np.zeros(0, bool),
            pair_rsum=radius[P[:, 0]] + radius[P[:, 1]] if len(P) else np.zeros(0), pair_kind=kinds,
            names=[(self.arms[k].name, self.arms[k].shapes.names[s]) for k, s in zip(arm_of, local)],
        )
        self._tab_key = key
        return self._tab

    def _check(self, Qs: list[np.ndarray], n: int, explain: bool = False) -> tuple[np.ndarray, list[str]]:
        """(n,) validity of a batch and, with ``explain``, the collisions of configuration 0 as text.

        Broad phase (scene bounds, then capsule pairs) decides what it can; coal decides the rest.
        """
        self.stats["configs"] += n
        tab = self._tables()
        ok = np.ones(n, dtype=bool)
        reasons: list[str] = []
        undecided: list[tuple] = []  # (config, "scene", global shape) or (config, "pair", pair index)
        W, A, B, samples = self._place(Qs, n)
        if self.scene is not None:
            self._scene_bounds(tab, samples, ok, reasons, undecided, explain)
        if len(tab["pairs"]):
            self._pair_bounds(tab, A, B, ok, reasons, undecided, explain)
        if undecided:
            self._narrow_phase(tab, W, undecided, ok, reasons, explain)
        return ok, reasons

    def _place(self, Qs: list[np.ndarray], n: int) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, list]:
        """Shape placements per arm, capsule end points A, B (n, S, 3) over all arms, and scene samples per arm.

        An arm held at one configuration is evaluated once and broadcast over the batch.
        """
        W, As, Bs, samples = [], [], [], []
        for a, Q in zip(self.arms, Qs):
            Wa = a.placements(Q if Q.ndim == 2 else Q[None])
            A, B, Sm = a.points(Wa, with_samples=self.scene is not None)
            if len(Wa) == 1 and n > 1:
                A, B = np.broadcast_to(A, (n,) + A.shape[1:]), np.broadcast_to(B, (n,) + B.shape[1:])
                Sm = None if Sm is None else np.broadcast_to(Sm, (n,) + Sm.shape[1:])
            W.append(Wa)
            As.append(A)
            Bs.append(B)
            samples.append(Sm)
        A = np.concatenate(As, axis=1) if len(As) > 1 else As[0]
        B = np.concatenate(Bs, axis=1) if len(Bs) > 1 else Bs[0]
        return W, A, B, samples

    def _scene_bounds(self, tab: dict, samples: list, ok: np.ndarray, reasons: list[str], undecided: list[tuple],
                      explain: bool) -> None:
        """Broad phase against the scene: distance-field bounds per shape; updates ``ok`` and ``undecided``."""
        sm, names = self.scene, tab["names"]
        Sm = np.concatenate(samples, axis=1) if len(samples) > 1 else samples[0]
        dmin = np.minimum.reduceat(sm.lookup(Sm), tab["sample_start"], axis=1)  # (n, S)
        lb = dmin - (sm.slack_lower + tab["cover"])
        clear = (lb >= self.margin) | tab["fixed"]  # the base stands on the table: never checked
        # an upper bound only below the field's cap (a capped value says "at least pad away")
        hit = (~clear) & tab["exact"] & (dmin < sm.pad) & (dmin + (sm.slack_upper - tab["radius"]) < self.margin)
        ok &= ~hit.any(axis=1)
        if explain:
            reasons += [f"{names[s][0]} {names[s][1]} touches the scene map" for s in np.nonzero(hit[0])[0]]
        for i, s in zip(*np.nonzero(~clear & ~hit)):
            undecided.append((i, "scene", s))

    def _pair_bounds(self, tab: dict, A: np.ndarray, B: np.ndarray, ok: np.ndarray, reasons: list[str],
                     undecided: list[tuple], explain: bool) -> None:
        """Broad phase for self and arm-vs-arm pairs: exact capsule distances; updates ``ok`` and ``undecided``."""
        P = tab["pairs"]
        # bounding spheres first (centre of the segment, half length + radius); exact segment distances
        # only for the pairs whose spheres come within the margin
        C = 0.5 * (A + B)
        rs = 0.5 * np.linalg.norm(B - A, axis=-1) + tab["radius"]
        dc = C[:, P[:, 0]] - C[:, P[:, 1]]
        near = np.einsum("npi,npi->np", dc, dc) < (rs[:, P[:, 0]] + rs[:, P[:, 1]] + tab["pair_margin"]) ** 2
        clear = ~near
        ii, pp = np.nonzero(near)
        if len(ii):
            g1, g2 = P[pp, 0], P[pp, 1]
            d = segment_distance(A[ii, g1], B[ii, g1], A[ii, g2], B[ii, g2]) - tab["pair_rsum"][pp]
            clear[ii, pp] = d >= tab["pair_margin"][pp]
        hit = (~clear) & tab["pair_exact"]
        ok &= ~hit.any(axis=1)
        if explain:
            reasons += [self._pair_text(tab, tab["names"], p) for p in np.nonzero(hit[0])[0]]
        for i, p in zip(*np.nonzero(~clear & ~hit)):
            undecided.append((i, "pair", p))

    def _narrow_phase(self, tab: dict, W: list[np.ndarray], undecided: list[tuple], ok: np.ndarray,
                      reasons: list[str], explain: bool) -> None:
        """coal.collide for what the bounds could not decide (skipping configurations already in collision)."""
        import coal

        def w(k, i):  # placements of arm k for configuration i (broadcast for held arms)
            return W[k][i if len(W[k]) > 1 else 0]

        names, P = tab["names"], tab["pairs"]
        req, res = coal.CollisionRequest(), coal.CollisionResult()
        ident = coal.Transform3s()
        for i, kind, x in undecided:
            if not ok[i] and not explain:
                continue
            self.stats["narrow"] += 1
            res.clear()
            if kind == "scene":
                k, s = tab["arm_of"][x], tab["local"][x]
                a = self.arms[k]
                req.security_margin = self.margin
                hit = coal.collide(a.shapes.shapes[s].geometry, a.shape_tf(w(k, i), s), self.scene.octree, ident, req, res)
                msg = f"{names[x][0]} {names[x][1]} touches the scene map"
            else:
                g1, g2 = P[x]
                k1, s1, k2, s2 = tab["arm_of"][g1], tab["local"][g1], tab["arm_of"][g2], tab["local"][g2]
                a1, a2 = self.arms[k1], self.arms[k2]
                req.security_margin = float(tab["pair_margin"][x])
                hit = coal.collide(a1.shapes.shapes[s1].geometry, a1.shape_tf(w(k1, i), s1),
                                   a2.shapes.shapes[s2].geometry, a2.shape_tf(w(k2, i), s2), req, res)
                msg = self._pair_text(tab, names, x)
            if hit:
                ok[i] = False
                if explain:
                    reasons.append(msg)

    @staticmethod
    def _pair_text(tab: dict, names: list, p: int) -> str:
        g1, g2 = tab["pairs"][p]
        if tab["pair_kind"][p] == "self":
            return f"{names[g1][0]} self collision {names[g1][1]} / {names[g2][1]}"
        return f"primary {names[g1][1]} / secondary {names[g2][1]} collide"

    # ------------------------------------------------------------------ distances
    def distance(self, q1: np.ndarray, q2: np.ndarray | None = None) -> DistanceReport:
        """Exact clearances (coal) of one configuration pair; see :class:`DistanceReport`."""
        import coal

        Qs, _ = self._configs([np.asarray(q1, float)] + ([] if q2 is None else [np.asarray(q2, float)]))
        W = [a.placements(Q[None])[0] for a, Q in zip(self.arms, Qs)]
        req, res = coal.DistanceRequest(), coal.DistanceResult()

        def dist(g1, t1, g2, t2) -> float:
            res.clear()
            return float(coal.distance(g1, t1, g2, t2, req, res))

        rep = DistanceReport(min_distance=np.inf, valid=True)

        def note(d, margin, text):
            rep.min_distance = min(rep.min_distance, d)
            if d < margin or d <= 0.0:  # coal reports 0 (not a depth) for meshes in contact
                rep.valid = False
                rep.contacts.append(f"{text} ({d * 1000:.1f} mm)")

        ident = coal.Transform3s()
        for k, a in enumerate(self.arms):
            tfs = [a.shape_tf(W[k], s) for s in range(len(a.shapes.shapes))]
            if self.scene is not None:
                best = (np.inf, "")
                for s, sh in enumerate(a.shapes.shapes):
                    if a.fixed[s] or sh.name.split("#")[0] in self.scene_exempt:
                        continue
                    d = dist(sh.geometry, tfs[s], self.scene.octree, ident)
                    best = min(best, (d, sh.name))
                    note(d, self.margin, f"{a.name} {sh.name} / scene")
                rep.scene[a.name] = best
            best = (np.inf, "", "")
            for s1, s2 in a.shapes.self_pairs:
                d = dist(a.shapes.shapes[s1].geometry, tfs[s1], a.shapes.shapes[s2].geometry, tfs[s2])
                best = min(best, (d, a.shapes.names[s1], a.shapes.names[s2]))
                note(d, self.self_margin, f"{a.name} {a.shapes.names[s1]} / {a.shapes.names[s2]}")
            rep.self[a.name] = best
            a._tfs = tfs
        if self.n_arms == 2:
            a1, a2 = self.arms
            best = (np.inf, "", "")
            for s1, g1 in enumerate(a1.shapes.shapes):
                for s2, g2 in enumerate(a2.shapes.shapes):
                    d = dist(g1.geometry, a1._tfs[s1], g2.geometry, a2._tfs[s2])
                    best = min(best, (d, g1.name, g2.name))
                    note(d, self.arm_margin, f"primary {g1.name} / secondary {g2.name}")
            rep.arm_arm = best
        return rep

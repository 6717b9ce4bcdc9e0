"""Reachability of grasps by one arm: a pluggable filter.

A *reach filter* is any callable ``f(T_b_g, width, retreat=None, hold_off=None) -> ReachResult`` taking
grasps ``T_b_g`` (N, 4, 4) in that arm's own base frame, openings ``width`` (N,) and optionally the
directions to their pre-grasps ``retreat`` (N, 3) (default: back along each approach axis) and the offsets
``hold_off`` (N, 3) from each grasp to where its approach ends (a push contact's standoff from the face:
the task approaches to there, then squeezes), and returning which of them the arm reaches, with the joint
solutions. The grasp planner only calls it; tests and benchmarks may pass their own. A filter
may also have ``for_scene(points_b1) -> filter``: the planner then binds it to the scene map once.

:class:`ArmReach` is the real one, on the project's kinematics and collision world: a grasp is reachable
when

- the IK (``bimanual_app.kinematics.IKSolver``, damped least squares within the joint limits) reaches it
  (up to ``n_solutions`` branches are tried for what follows),
  trying the grasp and the same grasp turned 180 degrees about the approach axis (a parallel gripper is
  symmetric; the wrist's joint limits often allow only one of them) -- ``ReachResult.flipped`` says which;
- the pre-grasp, ``pregrasp`` metres back along the approach (or ``retreat``), and points at most 2 cm
  apart between (from the held-off pose, where there is one: the very line the task's approach follows), are
  reached by IK
  seeded from the grasp's solution, each step moving no joint more than ``max_step`` radians (a straight
  approach the arm can follow, not a jump to another IK branch);
- the grasp, the pre-grasp and the points between are free of collisions with the scene map (object
  included) and of self collisions (``bimanual_app.collision.CollisionWorld``); the gripper's own shapes
  (flange, palm, fingers) against the map are left to the grasp sampler's exact checks (swept, against
  the object's own points and the rest of the scene), which the world's coarser voxels and margin would
  otherwise overrule for every grasp, whose fingers are by design close to the object and the table.
- the pre-grasp, where the task's free motion ends (its goal), is free of collisions with the whole arm,
  gripper included, at that motion's clearance (``goal_margin`` on a ``goal_resolution`` map, the task
  planner's settings): the sampler's sweep passes a gripper that clears the scene by less, which the
  planner then cannot move to.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from bimanual_app.transforms import inv_T

from ._antipodal import rotate_about_approach

__all__ = ["ReachResult", "ReachFilter", "ArmReach", "pregrasp_pose", "callable_filter"]


@dataclass
class ReachResult:
    """Outcome of a reach filter on N grasps.

    ok: (N,) bool. q: (N, J) joint solution at the grasp (NaN where not ok). q_pre: (N, J) at the pre-grasp.
    flipped: (N,) bool, the arm reaches the grasp turned 180 degrees about its approach axis (use
    ``rotate_about_approach``). reason: (N,) why not ('' where ok).
    """

    ok: np.ndarray
    q: np.ndarray
    q_pre: np.ndarray
    flipped: np.ndarray
    reason: list = field(default_factory=list)


class ReachFilter(Protocol):
    def __call__(self, T_b_g: np.ndarray, width: np.ndarray | None = None, retreat: np.ndarray | None = None,
                 hold_off: np.ndarray | None = None) -> ReachResult: ...


def pregrasp_pose(T_b_g: np.ndarray, distance: float, retreat: np.ndarray | None = None) -> np.ndarray:
    """Poses (..., 4, 4) ``distance`` metres back along each grasp's approach axis (its -z), or along the
    unit directions ``retreat`` (..., 3) when given (push contacts come in along the face normal)."""
    T = np.array(T_b_g, dtype=np.float64, copy=True)
    d = -T[..., :3, 2] if retreat is None else np.asarray(retreat, dtype=np.float64)
    T[..., :3, 3] += distance * d
    return T


class ArmReach:
    """Reachability of grasps by one arm (see the module docstring).

    Args:
        robot: ``RobotModel`` of the arm (its ``tcp_link`` is the gripper frame g).
        gripper: the ``GripperModel`` (to turn widths into finger joint openings).
        T_b1_b: (4, 4) the arm's base in b1 (identity for the primary, ``T_b1_b2`` for the secondary).
        scene_points_b1: (N, 3) scene map points in b1 for the collision check, or None (no scene).
        pregrasp: pre-grasp distance (m), 0.08-0.10 by the grasp contract.
        margin: clearance the arm's links keep from the scene map (m).
        max_seeds: IK seeds per attempt (fewer: faster rejection of unreachable grasps).
        max_step: largest joint change (rad) between successive approach points.
        n_solutions: IK branches tried for the approach (distinct solutions of the grasp pose).
        q_current: (J,) configuration the closest IK solution is sought to (default: the rest pose).
        resolution: voxel size of the collision scene map (m).
        goal_margin, goal_resolution: the clearance (m) the whole arm keeps at the pre-grasp from the scene map
            and that map's voxel size (m): the task planner's free-motion margin and map resolution
            (``TaskMotion``), since the pre-grasp is its free motion's goal; ``goal_margin=None``: not checked.
    """

    def __init__(self, robot, gripper, T_b1_b: np.ndarray | None = None, scene_points_b1: np.ndarray | None = None,
                 pregrasp: float = 0.09, margin: float = 0.004, max_seeds: int = 6, max_step: float = 0.6,
                 q_current: np.ndarray | None = None, resolution: float = 0.01, name: str = "primary",
                 n_solutions: int = 3, goal_margin: float | None = 0.01, goal_resolution: float = 0.005,
                 _solver=None):
        from bimanual_app.kinematics import IKSolver

        self.robot = robot
        self.gripper = gripper
        self.name = name
        self.T_b1_b = np.eye(4) if T_b1_b is None else np.asarray(T_b1_b, dtype=np.float64)
        self.pregrasp = float(pregrasp)
        self.margin = float(margin)
        self.max_seeds = int(max_seeds)
        self.max_step = float(max_step)
        self.resolution = float(resolution)
        self.n_solutions = int(n_solutions)
        self.goal_margin = None if goal_margin is None else float(goal_margin)
        self.goal_resolution = float(goal_resolution)
        self.q_current = robot.neutral() if q_current is None else np.asarray(q_current, dtype=np.float64)
        self.solver = _solver or IKSolver(robot, link=robot.tcp_link)
        self._ik_cache: dict = {}  # see ``_first_ik``; shared with ``with_pregrasp`` copies (same arm, same IK)
        self._reach_cache: dict = {}  # see ``__call__``; shared with ``with_pregrasp`` copies (same world)
        self.world = self.goal_world = None
        if scene_points_b1 is not None:
            self.world, self.goal_world = self._worlds(scene_points_b1)

    def _worlds(self, points_b1: np.ndarray) -> tuple:
        """The collision worlds of the grasp and approach check, and of the pre-grasp (goal) check (None when
        ``goal_margin`` is None), for scene points (N, 3) in b1; (None, None) when the arm can touch none."""
        from bimanual_app.collision import CollisionWorld, SceneMap

        P = np.asarray(points_b1, dtype=np.float64).reshape(-1, 3)
        P_b = P @ inv_T(self.T_b1_b)[:3, :3].T + inv_T(self.T_b1_b)[:3, 3]
        # only what the arm can touch: within its reach (plus its thickness) of the base, not below it
        P_b = P_b[(np.linalg.norm(P_b, axis=1) < self.solver.reach + 0.25) & (P_b[:, 2] > -0.05)]
        if len(P_b) == 0:
            return None, None
        # this world is built in the arm's own base frame (its primary slot has an identity base)
        scene = SceneMap(P_b, self.resolution, pad=0.2, source="scene map")
        # the gripper's own shapes against the scene are left out: the grasp planner has checked them already,
        # exactly (swept, against the octree and the object's own points), while this world's coarser map
        # (``resolution`` voxels plus ``margin``) would reject fingertips that pass just above the table
        world = CollisionWorld(self.robot, None, scene, margin=self.margin, scene_exempt=tuple(self.gripper.links))
        if self.goal_margin is None:
            return world, None
        # the goal world keeps to the task planner's map: in b1 (its voxels where the planner's are; a map in
        # the secondary's base frame would voxelise the same points differently, by up to a voxel), shared by
        # both arms' filters (``shared_scene_map``: the same points give the same map)
        return world, CollisionWorld(self.robot, None, P, resolution=self.goal_resolution, margin=self.goal_margin,
                                     crop=False, T_b1_b=self.T_b1_b)

    @property
    def _pose_map(self):
        """KD-tree over gripper poses of random configurations (position, weighted rotation): a capability map."""
        return _capability_map(self.robot, self._ROT_W)[0]

    def approach_hints(self, p_b1: np.ndarray, radius: float = 0.05, max_hints: int = 200) -> np.ndarray:
        """(K, 3) approach directions (z of g, in b1) with which the arm was seen to reach within ``radius``
        of the point ``p_b1`` (3,): where to aim the grasp sampler's approach directions near an object."""
        _, tree, Z = _capability_map(self.robot, self._ROT_W)
        p_b = inv_T(self.T_b1_b) @ np.append(np.asarray(p_b1, dtype=np.float64), 1.0)
        idx = tree.query_ball_point(p_b[:3], radius)
        Z_b = Z[np.asarray(idx, dtype=int)[:max_hints]]
        if len(Z_b) < self.MIN_MAP_HINTS:
            # the random map is sparse near the table at the far end of the reach (3 poses within 5 cm of a
            # point 48 cm out, where only grasps tilted away from the base reach): ask the IK directly
            Z_b = np.concatenate([Z_b, self._probed_approaches(p_b[:3])])
        return Z_b @ self.T_b1_b[:3, :3].T

    MIN_MAP_HINTS = 20
    _PROBE_TILTS = np.deg2rad([0.0, 20.0, 40.0, 60.0, 80.0])
    _PROBE_AZIMUTHS = 12

    def _probed_approaches(self, p_b: np.ndarray) -> np.ndarray:
        """(K, 3) approach directions (in the arm's base frame) with which the IK reaches the point ``p_b``
        (3,): tilts of 0-80 degrees from straight down, at 12 azimuths, two turns about the approach each."""
        dirs, poses = [], []
        for tilt in self._PROBE_TILTS:
            for k in range(self._PROBE_AZIMUTHS if tilt > 0 else 1):
                az = 2 * np.pi * k / self._PROBE_AZIMUTHS
                z = np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), -np.cos(tilt)])
                dirs.append(z)
                for roll in (0.0, np.pi / 2):
                    a = np.array([np.cos(az + roll), np.sin(az + roll), 0.0])
                    y = a - (a @ z) * z
                    if np.linalg.norm(y) < 1e-6:
                        y = np.array([-np.sin(az + roll), np.cos(az + roll), 0.0])
                    y /= np.linalg.norm(y)
                    T = np.eye(4)
                    T[:3, :3] = np.stack([np.cross(y, z), y, z], axis=1)
                    T[:3, 3] = p_b
                    poses.append(T)
        ok = np.array([r.success for r in self.solver.solve_many(np.stack(poses), max_seeds=4, screen=True)])
        ok = ok.reshape(-1, 2)
        return np.array(dirs)[ok.any(axis=1)].reshape(-1, 3)

    _ROT_W = 0.1  # metres per unit of rotation-matrix difference

    PRIOR_HORIZON = 0.12  # m: the largest prior distance any caller tells apart (its tiers and cut-offs)

    def prior(self, T_b_g: np.ndarray) -> np.ndarray:
        """(N,) distance from each grasp (or its turned twin) to the nearest pose the arm was seen to reach;
        ``inf`` beyond ``PRIOR_HORIZON`` (the callers rank grasps within it and treat all beyond alike).

        A cheap predictor used to order the exact checks (small first); it decides nothing on its own. The
        horizon bounds the KD-tree search: most poses of a hand-over's search lie far from the map, and an
        unbounded nearest-neighbour search in 12 dimensions visits much of the tree for each.
        """
        T = np.asarray(T_b_g, dtype=np.float64).reshape(-1, 4, 4)
        n = len(T)
        both = np.concatenate([T, rotate_about_approach(T)])  # the grasps, then their turned twins
        f = np.concatenate([both[:, :3, 3], self._ROT_W * both[:, :3, :3].reshape(-1, 9)], axis=1)
        d = self._pose_map.query(f, k=1, distance_upper_bound=self.PRIOR_HORIZON)[0]
        return np.minimum(d[:n], d[n:])

    def prior_min(self, T_move: np.ndarray, T_set: np.ndarray, cut: float | None = None) -> np.ndarray:
        """(M,) for each rigid motion ``T_move`` (M, 4, 4) (base frame), the smallest ``prior`` over the poses
        ``T_set`` (K, 4, 4) moved by it: ``min_k prior(T_move[m] @ T_set[k])``; ``inf`` where that is not
        under ``cut`` (default ``PRIOR_HORIZON``).

        Exact, with far fewer tree queries than M x K: the feature distance between two poses of the set does
        not change when both move rigidly (rotations keep both the position and the rotation parts' norms),
        and the prior is 1-Lipschitz in the features, so ``prior(k) >= prior(j) - |f_k - f_j|`` for every pose
        j already queried. A (move, pose) pair whose bound is not under the move's best so far is skipped.
        """
        cut = self.PRIOR_HORIZON if cut is None else min(float(cut), self.PRIOR_HORIZON)
        Mv = np.asarray(T_move, dtype=np.float64).reshape(-1, 4, 4)
        S = np.asarray(T_set, dtype=np.float64).reshape(-1, 4, 4)
        S = np.concatenate([S, rotate_about_approach(S)])  # the prior takes the nearer of a pose and its twin
        M, K = len(Mv), len(S)
        best = np.full(M, np.inf)
        if M == 0 or K == 0:
            return best
        fs = np.concatenate([S[:, :3, 3], self._ROT_W * S[:, :3, :3].reshape(K, 9)], axis=1)
        D = np.linalg.norm(fs[:, None] - fs[None], axis=-1)  # (K, K), the same for every move
        lb = np.zeros((M, K))  # lower bounds on each (move, pose) prior
        todo = np.ones((M, K), dtype=bool)
        tree = self._pose_map
        while True:
            live = todo & (lb < np.minimum(best, cut)[:, None])
            if not live.any():
                return np.where(best < cut, best, np.inf)
            # per move, the pose with the smallest bound not yet queried
            k = np.argmin(np.where(live, lb, np.inf), axis=1)
            m = np.nonzero(live.any(axis=1))[0]
            k = k[m]
            T = Mv[m] @ S[k]
            f = np.concatenate([T[:, :3, 3], self._ROT_W * T[:, :3, :3].reshape(-1, 9)], axis=1)
            d = tree.query(f, k=1, distance_upper_bound=cut)[0]
            todo[m, k] = False
            best[m] = np.minimum(best[m], d)
            # a pose farther than the cut from the map bounds the others only by the cut itself
            lb[m] = np.maximum(lb[m], np.minimum(d, cut)[:, None] - D[k])

    def follow(self, T_b_g: np.ndarray, q: np.ndarray, direction_b: np.ndarray, distance: float) -> str:
        """'' when the arm carries its gripper from ``T_b_g`` (4, 4; joints ``q`` (J,)) ``distance`` metres along
        ``direction_b`` (3,; base frame) in a straight line, orientation kept (IK seeded step by step, no
        joint jump), else why not. Kinematics only: what the gripper carries is the caller's to check.

        Steps of at most 2 cm: near the wrist singularity (joint 5 near 0) joints 4 and 6 trade large
        opposite turns over a few centimetres, which coarser steps would take for a jump between branches."""
        n = max(3, int(np.ceil(distance / 0.02)))
        along = np.arange(1, n + 1) / n * distance
        d = np.asarray(direction_b, dtype=np.float64)
        _, k, res = self._walk([pregrasp_pose(T_b_g, a, d) for a in along], q)
        if k < 0:
            return ""
        why = "a jump between IK branches" if res.success else res.message.split(" (best")[0]
        return f"{along[k] * 100:.0f} cm along: {why}"

    def _walk(self, poses: list[np.ndarray], q: np.ndarray) -> tuple[list[np.ndarray], int, object]:
        """IK through ``poses`` (each (4, 4)), each seeded with the solution before (the first with q (J,)), no
        joint moving more than ``max_step`` between neighbours (a line the arm can follow, not a jump between
        IK branches). Returns (the solutions found, in order; the index of the pose that failed, -1 when none
        did; that pose's IKResult: unsolved, or solved on another branch)."""
        qs, prev = [], np.asarray(q, dtype=np.float64)
        for k, Tk in enumerate(poses):
            res = self.solver.solve(Tk, q_current=prev, max_seeds=4)
            if not res.success or np.max(np.abs(res.q - prev)) > self.max_step:
                return qs, k, res
            qs.append(res.q)
            prev = res.q
        return qs, -1, None

    def with_pregrasp(self, pregrasp: float) -> ArmReach:
        """The same filter (solver and scene map shared) checking pre-grasps ``pregrasp`` metres back."""
        import copy

        other = copy.copy(self)
        other.pregrasp = float(pregrasp)
        return other

    def for_scene(self, points_b1: np.ndarray) -> ArmReach:
        """The same filter with another scene map (points (N, 3) in b1); shares the IK solver."""
        return ArmReach(self.robot, self.gripper, self.T_b1_b, points_b1, self.pregrasp, self.margin,
                        self.max_seeds, self.max_step, self.q_current, self.resolution, self.name, self.n_solutions,
                        self.goal_margin, self.goal_resolution, _solver=self.solver)

    def _approach(self, T: np.ndarray, q: np.ndarray, retreat: np.ndarray | None = None,
                  hold_off: np.ndarray | None = None) -> tuple[np.ndarray | None, list[np.ndarray], str]:
        """IK along the straight approach from the grasp back to the pre-grasp, seeded step by step; with
        ``hold_off`` (3,), first the held-off pose, then the line from it to the pre-grasp."""
        poses, where = _approach_poses(T, self.pregrasp, retreat, hold_off)
        qs, k, res = self._walk(poses, q)
        if k < 0:
            return qs[-1], qs, ""
        if res.success:
            return None, qs, "the straight approach needs a jump between IK branches"
        return None, qs, f"{where[k]}: {res.message}"

    FIRST_IK_CACHE = 4096  # grasp poses whose IK (from q_current) is remembered

    def _first_ik(self, T: np.ndarray) -> list:
        """``solver.solve_many`` of poses ``T`` (K, 4, 4) from the current configuration, remembering each pose's
        result: a push contact is checked once per way in, and its IK does not depend on the way in (the
        seeds are deterministic: the current configuration, then the closed-form branches or the nearest
        poses of the solver's table)."""
        if self.max_seeds > 1 + self.solver.n_near:  # random seeds would make a repeat differ
            return self.solver.solve_many(T, self.q_current, max_seeds=self.max_seeds, screen=True)
        cache = self._ik_cache
        keys = [(Tk.tobytes(), self.q_current.tobytes(), self.max_seeds) for Tk in T]
        todo = {key: k for k, key in enumerate(keys) if key not in cache}  # key -> an index of that pose
        if todo and len(cache) + len(todo) > self.FIRST_IK_CACHE:
            cache.clear()  # then this batch's poses that were remembered are solved again too
            todo = {key: k for k, key in enumerate(keys)}
        if todo:
            # screened by the closed form: most candidates far from the current configuration are out of reach
            idx = list(todo.values())
            for key, r in zip(todo, self.solver.solve_many(T[idx], self.q_current, max_seeds=self.max_seeds,
                                                           screen=True)):
                cache[key] = r
        return [cache[key] for key in keys]

    def _collisions(self, Q: np.ndarray) -> str:
        """'' when configurations Q (K, J) are collision free, else what collides (the gripper's own shapes
        are not checked against the scene: see ``_world``)."""
        valid = self.world.valid_batch(Q)
        for k in np.nonzero(~valid)[0]:
            why = self.world.explain(Q[k]) or ["in collision"]
            return f"{'grasp' if k == 0 else 'approach'} in collision: {why[0]}"
        return ""

    def goal_problems(self, q: np.ndarray, width: float) -> list[str]:
        """What the whole arm at configuration q (J,), its gripper open ``width`` m, touches within the task
        planner's free-motion margin (``goal_margin``) of the scene map; [] when nothing (or unchecked):
        the check of a free motion's goal, as at the pre-grasp."""
        if self.goal_world is None:
            return []
        q = np.asarray(q, dtype=np.float64)
        self.goal_world.set_opening(0, self.gripper.robot_opening(float(width)))
        if self.goal_world.valid(q):
            return []
        return self.goal_world.explain(q) or ["in collision"]

    REACH_CACHE = 4096  # grasps whose whole check (IK, approach, collisions) is remembered

    def __call__(self, T_b_g: np.ndarray, width: np.ndarray | None = None, retreat: np.ndarray | None = None,
                 hold_off: np.ndarray | None = None) -> ReachResult:
        """Reachability of grasps ``T_b_g`` (N, 4, 4) in this arm's base frame at openings ``width`` (N,);
        ``retreat`` (N, 3): unit directions (base frame) to the pre-grasp, default each grasp's -z;
        ``hold_off`` (N, 3): where each approach ends, from the grasp (base frame; default: at the grasp).

        Each grasp's outcome is remembered: the single-arm, two-arm and hand-over searches check many of
        the same grasps (a third of them on a cluttered scene), and a check is a pure function of the grasp,
        its opening, retreat and hold-off and this filter's settings (its IK seeds are deterministic)."""
        T_b_g = np.asarray(T_b_g, dtype=np.float64).reshape(-1, 4, 4)
        rt = None if retreat is None else np.asarray(retreat, dtype=np.float64).reshape(-1, 3)
        ho = None if hold_off is None else np.asarray(hold_off, dtype=np.float64).reshape(-1, 3)
        n = len(T_b_g)
        w = np.full(n, self.gripper.min_width) if width is None else np.broadcast_to(np.asarray(width, float), (n,))
        if self.max_seeds > 1 + self.solver.n_near:  # random seeds would make a repeat differ
            return self._check(T_b_g, w, rt, ho)
        setting = (self.pregrasp, self.q_current.tobytes(), self.max_seeds, self.n_solutions, self.max_step)
        keys = [(T_b_g[i].tobytes(), float(w[i]), None if rt is None else rt[i].tobytes(),
                 None if ho is None else ho[i].tobytes(), setting) for i in range(n)]
        cache = self._reach_cache
        found = {i: cache[key] for i, key in enumerate(keys) if key in cache}  # taken before a clear below
        todo = [i for i in range(n) if i not in found]
        if todo:
            if len(cache) + len(todo) > self.REACH_CACHE:
                cache.clear()
            res = self._check(T_b_g[todo], w[todo], None if rt is None else rt[todo], None if ho is None else ho[todo])
            for j, i in enumerate(todo):
                found[i] = cache[keys[i]] = (res.ok[j], res.q[j].copy(), res.q_pre[j].copy(), res.flipped[j],
                                             res.reason[j])
        rows = [found[i] for i in range(n)]
        J = self.robot.nq_arm
        return ReachResult(np.array([r[0] for r in rows], dtype=bool), np.array([r[1] for r in rows]).reshape(n, J),
                           np.array([r[2] for r in rows]).reshape(n, J), np.array([r[3] for r in rows], dtype=bool),
                           [r[4] for r in rows])

    def _check(self, T_b_g: np.ndarray, w: np.ndarray, rt: np.ndarray | None, ho: np.ndarray | None) -> ReachResult:
        """The reach check of ``__call__`` for grasps ``T_b_g`` (N, 4, 4), openings ``w`` (N,), retreats and
        hold-offs (N, 3) or None, every grasp computed.

        Per grasp, in order until one passes: as given, then turned about z; for each, the IK branch nearest
        the current configuration, then (``n_solutions`` > 1) the others, asked for all grasps at once once
        their first branch's approach or collision check failed. The last failure is the reason."""
        n = len(T_b_g)
        J = self.robot.nq_arm
        out = ReachResult(np.zeros(n, bool), np.full((n, J), np.nan), np.full((n, J), np.nan), np.zeros(n, bool), [""] * n)
        # the grasps' IK, as given and turned about z, all in one batch (most of the cost: failures try every seed)
        T_both = np.concatenate([T_b_g, rotate_about_approach(T_b_g)])
        first = self._first_ik(T_both)
        why: list[list[str]] = [[] for _ in range(n)]
        for flip in (False, True):
            todo = []
            for i in np.nonzero(~out.ok)[0]:
                res = first[n + i] if flip else first[i]
                if res.success:
                    todo.append(i)
                else:
                    why[i].append(res.message)
            rows = [n * flip + i for i in todo]
            blocked = self._screen_approaches(T_both[rows], np.array([first[r].q for r in rows]).reshape(-1, J),
                                              None if rt is None else rt[todo], None if ho is None else ho[todo])
            for i, msg in zip(todo, blocked):
                if msg:  # every IK branch of the grasp shares this approach: none of them can pass
                    why[i].append(msg)
            todo = [i for i, msg in zip(todo, blocked) if not msg]
            for i in todo:
                self._try_branch(out, why, i, T_both[n * flip + i], first[n * flip + i].q, flip, w, rt, ho)
            failed = [i for i in todo if not out.ok[i]]
            if self.n_solutions > 1 and failed:  # the grasps' other IK branches, closest to the current first
                more = self.solver.solve_many(T_both[[n * flip + i for i in failed]], self.q_current,
                                              max_seeds=self.max_seeds, n_solutions=self.n_solutions)
                for i, r in zip(failed, more):
                    q0 = first[n * flip + i].q
                    for q in (q for q in r.solutions if np.abs(q - q0).max() > 1e-3):
                        if self._try_branch(out, why, i, T_both[n * flip + i], q, flip, w, rt, ho):
                            break
        for i in np.nonzero(~out.ok)[0]:
            out.reason[i] = why[i][-1] if why[i] else "unreachable"
        return out

    def _screen_approaches(self, T: np.ndarray, q: np.ndarray, rt: np.ndarray | None, ho: np.ndarray | None
                           ) -> list[str]:
        """Per grasp T (K, 4, 4) with its first IK solution q (K, J): why its straight approach (``_approach``)
        must fail, or '' when it may pass: the first pose along it with no closed-form IK branch within the
        limits (``IKSolver.screen``), all grasps' poses in one batch. Most approaches of far push contacts
        end there, and the step-by-step solve spends a failing descent on that pose first."""
        paths = [_approach_poses(T[k], self.pregrasp, None if rt is None else rt[k], None if ho is None else ho[k])
                 for k in range(len(T))]
        if not paths:
            return []
        owner = np.concatenate([np.full(len(poses), k) for k, (poses, _) in enumerate(paths)])
        why = self.solver.screen(np.concatenate([np.stack(poses) for poses, _ in paths]), q[owner])
        if why is None:
            return [""] * len(T)
        out, start = [], 0
        for poses, where in paths:
            bad = next((f"{at}: {msg}" for at, msg in zip(where, why[start:start + len(poses)]) if msg), "")
            out.append(bad)
            start += len(poses)
        return out

    def _try_branch(self, out: ReachResult, why: list, i: int, T: np.ndarray, q: np.ndarray, flip: bool,
                    w: np.ndarray, rt: np.ndarray | None, ho: np.ndarray | None) -> bool:
        """Grasp ``i`` at pose T (4, 4) with the IK branch q (J,): its approach and collision check; fills
        ``out``'s row i and returns True when it passes, else appends why to ``why[i]``."""
        q_pre, q_path, msg = self._approach(T, q, None if rt is None else rt[i], None if ho is None else ho[i])
        if q_pre is None:
            why[i].append(msg)
            return False
        if self.world is not None:
            self.world.set_opening(0, self.gripper.robot_opening(float(w[i])))
            bad = self._collisions(np.stack([q] + q_path))
            if bad:
                why[i].append(bad)
                return False
        goal = self.goal_problems(q_pre, float(w[i]))
        if goal:
            why[i].append(f"pre-grasp within the free motion's margin of the scene: {goal[0]}")
            return False
        out.ok[i], out.q[i], out.q_pre[i], out.flipped[i] = True, q, q_pre, flip
        return True


def _approach_poses(T: np.ndarray, pregrasp: float, retreat: np.ndarray | None, hold_off: np.ndarray | None
                    ) -> tuple[list[np.ndarray], list[str]]:
    """The poses (4, 4) an approach to grasp ``T`` is checked at, from the grasp outwards, and what each is:
    at most 2 cm apart on the straight line to the pre-grasp (``pregrasp`` metres along ``retreat``, default
    -z); with ``hold_off`` (3,), the held-off pose first and the line from it (the task's approach line)."""
    n = max(3, int(np.ceil(pregrasp / 0.02)))  # 2 cm steps: see ``ArmReach.follow`` (the wrist singularity)
    if hold_off is None:
        return ([pregrasp_pose(T, s * pregrasp, retreat) for s in np.arange(1, n + 1) / n],
                [f"pre-grasp {s * pregrasp * 100:.0f} cm back" for s in np.arange(1, n + 1) / n])
    T_end = T.copy()
    T_end[:3, 3] += hold_off
    line = pregrasp_pose(T, pregrasp, retreat)[:3, 3] - T_end[:3, 3]
    n = max(n, int(np.ceil(np.linalg.norm(line) / 0.02)))
    poses, where = [T_end], [f"held off {np.linalg.norm(hold_off) * 1000:.0f} mm"]
    for s in np.arange(1, n + 1) / n:
        Tk = T_end.copy()
        Tk[:3, 3] += s * line
        poses.append(Tk)
        where.append(f"pre-grasp {s * np.linalg.norm(line) * 100:.0f} cm back")
    return poses, where


_MAPS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _capability_map(robot, rot_w: float, size: int = 40000) -> tuple:
    """(pose KD-tree (position, ``rot_w`` x rotation), position KD-tree, approach axes (size, 3)) of the
    gripper poses of ``size`` random configurations of ``robot``: built once per robot model in a process."""
    per_robot = _MAPS.setdefault(robot, {})
    if (rot_w, size) not in per_robot:
        from scipy.spatial import cKDTree

        q = robot.random_q(size, rng=7)
        T = robot.fk_link(q, robot.tcp_link)
        feats = np.concatenate([T[:, :3, 3], rot_w * T[:, :3, :3].reshape(-1, 9)], axis=1)
        # leaves of 32 poses: nearest-pose queries in these 12 dimensions run a quarter faster than with the
        # default 16 (the same distances)
        per_robot[(rot_w, size)] = (cKDTree(feats, leafsize=32), cKDTree(T[:, :3, 3]), T[:, :3, 2].copy())
    return per_robot[(rot_w, size)]


def callable_filter(fn: Callable[[np.ndarray], np.ndarray], J: int = 6) -> ReachFilter:
    """A reach filter from a plain predicate on poses (N, 4, 4) -> (N,) bool (no joint solutions)."""

    def f(T_b_g: np.ndarray, width: np.ndarray | None = None, retreat: np.ndarray | None = None,
          hold_off: np.ndarray | None = None) -> ReachResult:
        T_b_g = np.asarray(T_b_g, dtype=np.float64).reshape(-1, 4, 4)
        ok = np.asarray(fn(T_b_g), dtype=bool)
        n = len(T_b_g)
        return ReachResult(ok, np.full((n, J), np.nan), np.full((n, J), np.nan), np.zeros(n, bool),
                           ["" if o else "rejected by the reach predicate" for o in ok])

    return f

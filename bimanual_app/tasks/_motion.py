"""The motion a task needs, on the motion layer's public API (``bimanual_app.planning``, ``collision``).

Free motions go through :meth:`BimanualSetup.plan_configurations` (IK goals -> OMPL -> time
parametrisation -> dense validation). Two things a task needs that the motion layer does not offer as one
call are composed here from its public pieces, and nothing else:

- **Cartesian moves** (approach, squeeze, lift, retreat, the coupled carry of a joint grasp): the gripper
  poses along a straight line, IK at every waypoint (1 cm apart) seeded with the previous solution
  (``BimanualSetup.ik``, closest solution first), the joint path stacked over the moving arms,
  :func:`bimanual_app.planning.parametrize` within the velocity/acceleration limits and
  :func:`bimanual_app.planning.validate_samples` (joint, velocity, acceleration limits and collisions
  with no step larger than the margin) on exactly the samples returned.
- **The object's own clearance** while both grippers carry it: the collision world attaches an object to
  one gripper only, so for a two-arm carry the object's points are moved along the planned object motion
  and looked up in the scene map's distance field (``SceneMap.lookup``).

The collision context is explicit: :meth:`TaskMotion.context` says whether the target object is part of
the map (free motions towards it), cut out (the last centimetres of an approach, where the fingers
straddle it), or attached to a gripper (carrying). Every trajectory returned has been validated.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from bimanual_app.kinematics import WAYPOINT_STEP, follow_poses, line_poses
from bimanual_app.transforms import check_shape, check_T

__all__ = ["PlanFailure", "TaskMotion", "translate_along", "line_poses", "robot_points_mask", "arms_at_start_mask",
           "WAYPOINT_STEP", "BASE_RADIUS", "START_PAD"]

BASE_RADIUS = 0.15  # m: background points this close to a base's vertical axis are the robot itself
START_PAD = 0.02  # m: the arms' space at the start, padded by the free-motion margin (1 cm) and one more for the map
# The grasping stage checks its grippers against a 3 mm octree with a 2 mm margin (2-5 mm of clearance in
# effect); the task's map at 5 mm voxels with a 3 mm margin in contact (3-8 mm) keeps to nearly the same,
# where 1 cm voxels with 4 mm (4-14 mm) refused approaches the grasping stage had found clear.
MAP_RESOLUTION = 0.005  # m: voxel size of the task's collision map
OBJECT_CLEARANCE = 0.002  # m: a carried object's points keep this far from the map's points
TOUCH_BAND = 0.005  # m: object points this much nearer than that where it lies touch a neighbour (not checked)
# m: the carried body's sides are checked this far in from where they are estimated: a box or hull fitted to a
# noisy cloud is off by a few mm, and a neighbour's rim seen right above the body's edge (its near side, against
# the object, unseen) is then grazed by a lift that slides along it in reality (the physics preview judges that)
SIDE_TOLERANCE = 0.005
CONTACT_MARGIN = 0.003  # m: clearance of the moves in contact (approach, squeeze, lift, place, retreat)
OBJECT_PADDING = 0.002  # m the carried object's box is grown by past its points


def robot_points_mask(points: np.ndarray, labels: np.ndarray, bases_b1: np.ndarray, up: np.ndarray,
                      table_height: float, radius: float = BASE_RADIUS, above: float = 0.015) -> np.ndarray:
    """(N,) True for cloud points that are the robots themselves, not obstacles: background points
    (label -1) more than ``above`` m over the table within ``radius`` m of a base's vertical axis.

    The wrist cameras see both arms, so a reconstruction's cloud holds them, at their capture poses, as
    points around the bases; in a collision map they would put the arms in collision with themselves
    (the rest pose included). A smallest adapter until the cloud comes without robot pixels.
    """
    P = np.asarray(points, dtype=np.float64)
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    h = P @ up - table_height
    mask = np.zeros(len(P), dtype=bool)
    for b in np.atleast_2d(bases_b1):
        d = P - b
        d -= np.outer(d @ up, up)
        mask |= np.linalg.norm(d, axis=1) < radius
    return mask & (np.asarray(labels) < 0) & (h > above)


def arms_at_start_mask(robot, T_b1_b2: np.ndarray, points: np.ndarray, q_start: dict, pad: float = START_PAD
                       ) -> np.ndarray:
    """(N,) True for the cloud points ``points`` (N, 3) in b1 that lie in the space the arms take up at their
    start configuration (``q_start``: arm -> (J,)), padded by ``pad`` m (their bounding capsules,
    ``CollisionWorld.near_arms``).

    Nothing but the arms can be there when the task starts, so what the cloud holds there is not an
    obstacle: the arms themselves as a camera saw them, or a depth map's stray pixels. Kept in the map,
    such points put the start configuration in collision and the task fails before it plans. Unlike
    :func:`robot_points_mask` (a column around each base) this follows the arms wherever they stand.
    """
    from bimanual_app.collision import CollisionWorld

    world = CollisionWorld(robot, check_T("T_b1_b2", T_b1_b2))
    return world.near_arms(points, [q_start["primary"], q_start["secondary"]], pad)


class PlanFailure(Exception):
    """A task could not be planned: ``stage`` (``reach``, ``plan``, ``cartesian``, ``validation``...) and why."""

    def __init__(self, stage: str, message: str):
        self.stage = stage
        self.message = message
        super().__init__(f"{stage}: {message}")


def translate_along(T: np.ndarray, axis_b1: np.ndarray, dist: float) -> np.ndarray:
    """``T`` (4,4) moved by ``dist`` m along ``axis_b1`` (3,) (a direction in b1)."""
    out = np.array(T, dtype=np.float64)
    out[:3, 3] += dist * np.asarray(axis_b1, dtype=np.float64)
    return out


def _sides_in(points: np.ndarray, up: np.ndarray, d: float) -> np.ndarray:
    """(N, 3) ``points`` (N, 3) each moved ``d`` m horizontally towards their centroid's vertical (points nearer
    to it than ``2 d`` stay): an object's sides taken in by ``d``, its top and bottom heights kept."""
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    h = points - points.mean(axis=0)
    h -= np.outer(h @ up, up)
    r = np.linalg.norm(h, axis=1, keepdims=True)
    return points - np.where(r > 2 * d, d * h / np.maximum(r, 1e-12), 0.0)


@dataclass
class _Traj:
    """A validated trajectory of one arm (times (T,), q (T,J)); gripper widths are added by the task."""

    times: np.ndarray
    q: np.ndarray

    @property
    def duration(self) -> float:
        return float(self.times[-1])


class TaskMotion:
    """Both arms, the scene map, and one target object, for planning one task.

    Args:
        robot: RobotModel (both arms).
        T_b1_b2: (4,4) secondary base in b1 (calibrated).
        points: (N,3) metric scene cloud in b1.
        object_points: (M,3) the target object's points in b1 (extruded to the table: the body's hull).
        segment_points: (K,3) the object's points in the cloud (cut out of the map with ``cut_radius``).
        body: the object's estimated :class:`bimanual_app.simulation.BodyShape`; map points inside it
            (grown by ``cut_radius``) are cut out too.
        up: (3,) the table normal in b1: the carried object's box keeps an edge along it (its points are
            extruded down to the table); None: principal axes only.
        seed: base seed of OMPL's random numbers, combined with each query's inputs (start, goals, scene
            map), so that a task run again on the same inputs plans the same motions in any process (alone,
            or after the other stages in ``bijcr run``) and its preview approval stays valid; None: time-seeded.
        plan_time: OMPL time limit per query (s).
        speed: fraction of the velocity/acceleration limits used.
        margin: collision margin (m) of free motions.
        contact_margin: collision margin (m) of the straight moves in contact (see :meth:`context`).
        leave_out: names of the planner's fallbacks not to try (``tasks._planners.FALLBACKS``), to measure
            what each buys; empty by default.
    """

    def __init__(self, robot, T_b1_b2: np.ndarray, points: np.ndarray, object_points: np.ndarray,
                 segment_points: np.ndarray | None = None, plan_time: float = 5.0, speed: float = 0.5, margin: float = 0.01,
                 cut_radius: float = 0.015, contact_margin: float = CONTACT_MARGIN, resolution: float = MAP_RESOLUTION,
                 body=None, seed: int | None = 0, up: np.ndarray | None = None, leave_out: Iterable[str] = ()):
        from bimanual_app.planning import BimanualSetup

        self.robot = robot
        self.setup = BimanualSetup(robot, check_T("T_b1_b2", T_b1_b2), points, margin=margin, speed=speed,
                                   resolution=resolution)
        self.world = self.setup.world
        self.plan_time = float(plan_time)
        self.contact_margin = float(contact_margin)
        self.seed = seed
        self.leave_out = frozenset(leave_out)
        self.speed = float(speed)
        self.up = None if up is None else check_shape("up", np.asarray(up, dtype=np.float64), (3,))
        self.object_points = np.asarray(object_points, dtype=np.float64)
        self.full_map = self.world.scene
        cut = self.object_points if segment_points is None else np.vstack([segment_points, self.object_points])
        drop = self.full_map.near_mask(cut, cut_radius)
        if body is not None:  # also whatever lies inside the object's body (points segmented with another label)
            drop |= body.contains(self.full_map.points, cut_radius)
        self.cut_map = self.full_map.without(drop)
        self.stats = {"ompl_queries": 0, "cartesian_moves": 0, "ik_calls": 0, "plan_s": 0.0}

    # ------------------------------------------------------------------ collision context
    @contextlib.contextmanager
    def context(self, object_mode: str = "map", openings: dict | None = None, attach: tuple | None = None,
                object_padding: float = OBJECT_PADDING):
        """Set the world for a query, restore it after.

        object_mode: ``map`` (the object is an obstacle), ``cut`` (ignored: the fingers meet it), or
            ``attached`` (cut from the map and attached to ``attach = (arm, q_at_attach, points_b1)``).
        openings: arm name -> gripper opening (m) for the finger shapes.
        object_padding: the attached object's box grows by this (m) past its points; negative shrinks it,
            so that the free-motion margin to it is less (never below the contact margin: see the callers).

        In ``cut`` (the slow straight moves in contact: approach, squeeze, lift, place, retreat) the arms
        keep ``contact_margin`` from the scene instead of ``margin``: the clearance the grasping stage
        checked its grasps and pre-grasps with. With the free-motion margin, a grasp whose fingers pass
        5 mm over the table or a neighbour -- checked and accepted there -- could never be approached.
        """
        w = self.world
        old_margin = w.margin
        if object_mode == "cut":
            w.margin = self.contact_margin
        old_openings = {a.name: a.opening for a in w.arms}
        w.set_scene(self.full_map if object_mode == "map" else self.cut_map)
        for arm, o in (openings or {}).items():
            w.set_opening(arm, o)
        if object_mode == "attached":
            arm, q, pts = attach
            w.attach(arm, pts, q, name="object", padding=object_padding, axis_b1=self.up)
        try:
            yield w
        finally:
            if object_mode == "attached":
                w.detach(attach[0], "object")
            for arm, o in old_openings.items():
                w.set_opening(arm, o)
            w.set_scene(self.full_map)
            w.margin = old_margin

    # ------------------------------------------------------------------ IK
    def tcp_pose(self, arm: str, q: np.ndarray) -> np.ndarray:
        """(4,4) gripper frame in b1 of ``arm`` at configuration q (J,)."""
        link = self.robot.tcp_link or self.robot.ee_link
        return self.setup.T_b1_b(arm) @ self.robot.fk_link(np.asarray(q, dtype=np.float64), link)

    def ik(self, arm: str, T_b1_g: np.ndarray, q_seed: np.ndarray, n: int = 6) -> np.ndarray:
        """(K,J) IK solutions for the gripper frame at ``T_b1_g`` in b1, closest to ``q_seed`` first.
        Raises PlanFailure('reach') when there is none."""
        self.stats["ik_calls"] += 1
        r = self.setup.ik(arm, T_b1_g, q_seed, n_solutions=n)
        if not r.success:
            p = np.round(T_b1_g[:3, 3], 3).tolist()
            raise PlanFailure("reach", f"the {arm} gripper cannot reach {p} in b1 with that orientation: {r.message}")
        return r.solutions

    def cut_grasped(self, T_b1_g: np.ndarray, width: float, slack: float = 0.003) -> int:
        """Cut out of the map (in the ``cut`` and ``attached`` contexts) the points between the open fingers
        of a grasp (``T_b1_g`` (4,4) in b1, opening ``width`` m): what the fingers close on is the object,
        whether or not the segmenter labelled it so (a bunny's ear left as background; the closed fingers
        then "touched" it). Returns how many points were cut."""
        from grasping import load_gripper

        g = load_gripper(self.robot.name)
        T = check_T("T_b1_g", T_b1_g)
        P = self.cut_map.points
        L = (P - T[:3, 3]) @ T[:3, :3]
        inside = ((np.abs(L[:, 0]) <= max(abs(g.finger_x[0]), abs(g.finger_x[1])) + slack)
                  & (np.abs(L[:, 1]) <= 0.5 * float(width)) & (L[:, 2] >= g.finger_z[0] - slack)
                  & (L[:, 2] <= g.finger_z[1] + slack))
        if inside.any():
            self.cut_map = self.cut_map.without(inside)
            self._cut_tree_ = None
            self.stats["grasped_points_cut"] = self.stats.get("grasped_points_cut", 0) + int(inside.sum())
        return int(inside.sum())

    def problems(self, q: dict) -> list[str]:
        """Problems of a configuration of both arms in the current context ([] when valid)."""
        if self.world.valid(q["primary"], q["secondary"]):
            return []
        return self.world.explain(q["primary"], q["secondary"]) or ["in collision"]

    def ik_valid(self, arm: str, T_b1_g: np.ndarray, q_seed: np.ndarray, q_other: np.ndarray) -> np.ndarray:
        """The IK solutions (closest first) that are collision free with the other arm at ``q_other``."""
        sols = self.ik(arm, T_b1_g, q_seed)
        other = "secondary" if arm == "primary" else "primary"
        ok = [s for s in sols if not self.problems({arm: s, other: q_other})]
        if not ok:
            why = self.problems({arm: sols[0], other: q_other})
            raise PlanFailure("reach", f"the {arm} arm reaches {np.round(T_b1_g[:3, 3], 3).tolist()} only in "
                                       f"collision: {'; '.join(why[:2])}")
        return np.stack(ok)

    # ------------------------------------------------------------------ free motion (OMPL)
    def plan_free(self, arms: list[str], q_now: dict, goals: list[dict]) -> dict:
        """OMPL motion of ``arms`` from ``q_now`` to one of ``goals`` (arm -> (J,)); arm -> _Traj, validated."""
        self.stats["ompl_queries"] += 1
        start = {a: q_now[a] for a in arms}
        if all(all(np.allclose(g[a], q_now[a], atol=1e-9) for a in arms) for g in goals[:1]):
            return {a: _Traj(np.array([0.0, 0.05]), np.stack([q_now[a], q_now[a]])) for a in arms}
        plan = self.setup.plan_configurations(arms, start, goals, q_now, timeout=self.plan_time, seed=self.seed)
        self.stats["plan_s"] += float(plan.timings.get("total", plan.timings.get("plan", 0.0)))
        if not plan.success:
            stage = {"search": "plan", "goal": "reach", "start": "start"}.get(plan.reason, "plan")
            extra = f" (no path found within the {self.plan_time:g} s limit)" if plan.reason == "search" else ""
            raise PlanFailure(stage, f"{' + '.join(arms)} motion: {plan.message}{extra}")
        return {a: _Traj(np.asarray(t.times), np.asarray(t.q)) for a, t in plan.trajectories.items()}

    # ------------------------------------------------------------------ Cartesian moves
    def ik_path(self, poses: dict, q0: dict) -> dict:
        """Joint waypoints through gripper poses, all arms on the same waypoints.

        poses: arm -> (K,4,4) gripper poses in b1; q0: arm -> (J,) start. Returns arm -> (K',J) (K' >= K),
        each IK seeded by the previous solution, on one IK branch (:func:`bimanual_app.kinematics.follow_poses`);
        a branch switch or a pose out of reach raises PlanFailure. (Fast joints are slowed by the time
        parametrisation.)
        """
        def solver(a):
            def solve(T, q, n_solutions, max_seeds):
                self.stats["ik_calls"] += 1
                return self.setup.ik(a, T, q, n_solutions=n_solutions, max_seeds=max_seeds)
            return solve

        def forward(a):
            ik = self.setup.ik_solver(a)
            T_b1_b = self.setup.T_b1_b(a)
            return lambda Q: T_b1_b @ ik.robot.fk_link(np.atleast_2d(Q), ik.link)

        Q, fail = follow_poses({a: solver(a) for a in poses}, poses, q0, fk={a: forward(a) for a in poses})
        if fail is None:
            return Q
        if fail.kind == "reach":
            raise PlanFailure("cartesian", f"the {fail.arm} gripper leaves its reach {fail.index * WAYPOINT_STEP * 100:.0f}"
                                           f" cm along the move (at {np.round(fail.T[:3, 3], 3).tolist()})")
        raise PlanFailure("cartesian", f"the {' / '.join(poses)} arm would swing to another joint branch on "
                                       f"the move (joint step {fail.jump:.2f} rad over {fail.step * 100:.2f} cm)")

    def cartesian(self, moves: dict, q_now: dict, min_duration: float = 0.0) -> dict:
        """Cartesian moves of the grippers, all moving arms together on one clock.

        moves: arm -> a tuple (T_from (4,4), T_to (4,4)) in b1 (a straight line, orientation by slerp), or
            arm -> an array (K,4,4) of gripper poses to pass through (e.g. a planned object motion applied to a grasp; every
            arm given so must have the same K, about 1 cm apart);
        returns arm -> _Traj, validated with the other arm held at ``q_now``.
        """
        from bimanual_app.planning import JointSpace, parametrize, validate_samples

        self.stats["cartesian_moves"] += 1
        arms = [a for a in ("primary", "secondary") if a in moves]
        given = {a: np.asarray(m, dtype=np.float64) for a, m in moves.items() if not isinstance(m, tuple)}
        pairs = {a: m for a, m in moves.items() if a not in given}
        if given:
            n = len(next(iter(given.values())))
            if any(len(v) != n for v in given.values()) or pairs:
                raise ValueError("cartesian: give either waypoint arrays of one length for every arm, or (from, to) pairs")
        Qs = self.ik_path(given, q_now) if given else self.straight(pairs, q_now)
        paths = [Qs[a] for a in arms]
        W = np.concatenate(paths, axis=1)
        hold = {a: q_now[a] for a in ("primary", "secondary") if a not in arms}
        space = JointSpace(self.world, arms, hold)
        traj = parametrize(W, space.vmax * self.speed, space.amax * self.speed)
        times, Q = traj.sample_uniform(self.setup.dt)
        if times[-1] < min_duration:  # slow, gentle moves (squeeze): stretch time, limits still hold
            times = times * (min_duration / max(times[-1], 1e-9))
        rep = validate_samples(space, times, Q)
        if not rep.ok:
            raise PlanFailure("validation", f"straight {' + '.join(arms)} move: {'; '.join(rep.problems[:2])}")
        out = {}
        for i, a in enumerate(arms):
            sl = slice(space.offsets[i], space.offsets[i + 1])
            out[a] = _Traj(times, Q[:, sl].copy())
        return out

    def validate_timeline(self, timeline: dict, openings: list[tuple[float, float, dict]] | None = None) -> None:
        """Validate the whole plan (arm -> JointTrajectory, one clock) as the hardware will run it: both
        arms sampled at the union of their sample times, joint / velocity / acceleration limits and
        collisions (arms against the scene with the target object cut out, and against each other)
        densely, with ``validate_samples``. Raises PlanFailure.

        openings: ``(t_start, t_end, arm -> opening)`` spans (the phases, cut where grippers start or stop
            moving: :meth:`TaskPlan.opening_spans`):
            the fingers' shapes in each span are those of its widest opening, so an arm holding an object
            is checked with its fingers where they are, not closed. Default: one span, the world's openings.
        """
        from bimanual_app.planning import JointSpace, validate_samples

        arms = [a for a in ("primary", "secondary") if a in timeline]
        times = np.unique(np.concatenate([np.asarray(timeline[a].times) for a in arms]))
        Q = np.concatenate([timeline[a].sample_many(times)[0] for a in arms], axis=1)
        spans = openings or [(float(times[0]), float(times[-1]), {})]
        for t0, t1, widths in spans:
            sel = (times >= t0 - 1e-9) & (times <= t1 + 1e-9)
            if sel.sum() < 2:
                continue
            with self.context("cut", openings=widths):
                rep = validate_samples(JointSpace(self.world, arms, {}), times[sel] - times[sel][0], Q[sel])
            if not rep.ok:
                raise PlanFailure("validation", f"the whole plan ({t0:.2f}-{t1:.2f} s): " + "; ".join(rep.problems[:2]))

    def straight(self, pairs: dict, q_now: dict) -> dict:
        """Joint waypoints of straight gripper moves, as ``cartesian`` runs them (no timing, no collision check).

        pairs: arm -> (T_from (4,4), T_to (4,4)) in b1; q_now: arm -> (J,) at T_from. Returns arm -> (K, J): the
        IK chain on one branch (``ik_path``), else, where that chain leaves its branch, the joints moved
        directly to the goal (``_joint_line``). Raises PlanFailure when neither follows the line. The planner's
        checks of a straight move ask this, so that they accept exactly the moves ``cartesian`` can run.
        """
        n = max(len(line_poses(T0, T1)) for T0, T1 in pairs.values())
        try:
            return self.ik_path({a: line_poses(T0, T1, n=n) for a, (T0, T1) in pairs.items()}, q_now)
        except PlanFailure as e:
            if e.stage != "cartesian":
                raise
            return self._joint_line(pairs, q_now, n, e)

    def _joint_line(self, pairs: dict, q_now: dict, n: int, err: PlanFailure, tol_m: float = 0.01,
                    tol_rad: float = 0.1) -> dict:
        """Fallback for a short straight move whose IK chain leaves its branch (near a wrist singularity):
        joints interpolated linearly from ``q_now`` to the goal's IK solution closest to it, accepted when
        the gripper stays within ``tol_m`` / ``tol_rad`` of the straight line (FK at every waypoint)."""
        from bimanual_app.transforms import rotation_angle_between

        out = {}
        for a, (T0, T1) in pairs.items():
            sols = self.ik(a, T1, q_now[a])
            q1 = sols[0]
            Q = q_now[a] + np.linspace(0.0, 1.0, 4 * n)[:, None] * (q1 - q_now[a])
            link = self.robot.tcp_link or self.robot.ee_link
            T = self.setup.T_b1_b(a) @ self.robot.fk_link(Q, link)
            line = line_poses(T0, T1, n=len(Q))
            dev = float(np.max(np.linalg.norm(T[:, :3, 3] - line[:, :3, 3], axis=1)))
            rot = float(np.max(rotation_angle_between(T[:, :3, :3], line[:, :3, :3])))
            if dev > tol_m or rot > tol_rad:
                raise PlanFailure("cartesian", f"{err.message}; moving the joints directly strays {dev * 100:.1f} cm "
                                               f"/ {np.degrees(rot):.0f} deg from the straight line")
            out[a] = Q
        return out

    def object_clear(self, T_moves: np.ndarray, skip_rise: float = 0.02, up: np.ndarray | None = None) -> list[str]:
        """Problems of the carried object along rigid motions ``T_moves`` (K,4,4) (applied to its points):
        any object point nearer than ``OBJECT_CLEARANCE`` to a point of the map (object cut out) once it
        rose ``skip_rise`` (the distance field finds the candidates, a k-d tree decides); points that start
        that near (where the object touches a neighbour) are left to the physics preview. The object's sides
        are taken ``SIDE_TOLERANCE`` in first (its estimated body is that far off)."""
        up = np.array([0.0, 0.0, 1.0]) if up is None else up
        P, touching = self._carried_at_rest(up)
        smap = self.cut_map
        for k, T in enumerate(T_moves):
            if float(T[:3, 3] @ up) < skip_rise and np.allclose(T[:3, :3], np.eye(3), atol=1e-6):
                continue
            Pk = P @ T[:3, :3].T + T[:3, 3]
            inside = (smap.lookup(Pk) <= 0.0) & ~touching  # in an occupied cell: as near as the cell size
            if not inside.any():
                continue
            d, _ = self._cut_tree.query(Pk[inside], k=1, distance_upper_bound=2 * OBJECT_CLEARANCE)  # exactly
            bad = d < OBJECT_CLEARANCE
            if bad.any():
                return [f"the carried object meets the scene at step {k} of {len(T_moves)} "
                        f"(near {np.round(Pk[inside][bad][0], 3).tolist()})"]
        return []

    def _carried_at_rest(self, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The carried object's points with their sides taken in (``_sides_in``; (M, 3)) and which of them touch
        a neighbour where it lies ((M,) bool), for ``up`` (3,) and the current cut map: the same for every motion
        ``object_clear`` checks (a lift tries many), so kept until the map or ``up`` changes."""
        key = (self.cut_map, tuple(np.asarray(up, dtype=np.float64).tolist()))
        kept = getattr(self, "_carried_at_rest_", None)
        if kept is None or kept[0] is not key[0] or kept[1] != key[1]:
            P = _sides_in(self.object_points, up, SIDE_TOLERANCE)
            # points that touch a neighbour where the object lies (objects often stand against each other) are
            # not checked: a lift slides them along it, and at the map's sampling and noise a slide cannot be
            # told from a push (the physics preview judges that contact); every other point keeps
            # OBJECT_CLEARANCE from the map
            # (searches bounded by the distances that matter: the object is cut out of this map, so an unbounded
            # nearest-neighbour search from each of its points walks much of the tree)
            near = OBJECT_CLEARANCE + TOUCH_BAND
            d0, _ = self._cut_tree.query(P, k=1, distance_upper_bound=2 * near)
            self._carried_at_rest_ = (*key, P, d0 < near)
        return self._carried_at_rest_[2], self._carried_at_rest_[3]

    def grippers_clear(self, lifts, S: dict, openings: dict, among: np.ndarray | None = None) -> np.ndarray:
        """(C,) bool: the lifts ``lifts`` (:class:`~bimanual_app.kinematics.LiftCandidates`, C of them) along
        which every gripper holding the object (arm -> ``S`` (4,4) its pose in b1, opened ``openings[arm]``
        m) keeps ``contact_margin`` from the cut map (``grasping.lift_clear``: the gripper's shapes about
        every centimetre of the way, before any IK); only the lifts ``among`` (indices) are checked (default
        all). The grasp stage checks its pairs' lifts the same way."""
        from grasping import GripperCollider, SceneOctree, lift_clear, load_gripper

        if getattr(self, "_gripper_collider_", None) is None:
            self._gripper_collider_ = GripperCollider(load_gripper(self.robot.name), 0.0)
        if getattr(self, "_gripper_scene_", (None, None))[0] is not self.cut_map:  # the map's own octree
            m = self.cut_map
            self._gripper_scene_ = (m, SceneOctree(m.points, m.resolution, octree=m.octree))
        ok = np.zeros(len(lifts), dtype=bool)
        ok[np.arange(len(lifts)) if among is None else among] = True
        for a, T in S.items():
            ok = lift_clear(self._gripper_collider_, self._gripper_scene_[1], lifts, T, openings[a],
                            self.contact_margin, ok)
        return ok

    @property
    def _cut_tree(self):
        if getattr(self, "_cut_tree_", None) is None:
            from scipy.spatial import cKDTree

            self._cut_tree_ = cKDTree(self.cut_map.points)
        return self._cut_tree_

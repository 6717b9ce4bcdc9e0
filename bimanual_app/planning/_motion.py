"""BimanualSetup: both arms in frame b1 with the scene map; IK, planning, time parametrisation, validation.

Every plan goes: targets -> IK (several solutions, closest to the current configuration first) ->
valid goals -> OMPL path (``_ompl_plan``) -> time parametrisation within the velocity and acceleration
limits (``_time``; corners blended, or full stops when a blend is not collision free) -> trajectory samples
every ``dt`` -> dense validation of exactly those samples (``_validate``). Only a validated trajectory is
returned; anything else is a failure with a message.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from bimanual_app.collision import CollisionWorld
from bimanual_app.kinematics import IKSolver
from bimanual_app.planning._ompl_plan import plan_path
from bimanual_app.planning._space import JointSpace
from bimanual_app.planning._time import parametrize
from bimanual_app.planning._validate import ValidationReport, validate_samples
from bimanual_app.transforms import check_T

__all__ = ["BimanualSetup", "MotionPlan", "Trajectory", "default_ready"]


@dataclass
class Trajectory:
    """One arm's time-parametrised trajectory (what ``bimanual_app.hardware.as_trajectory`` reads).

    times: (T,) seconds from 0; q: (T,J) radians; joint_names: (J,); gripper: (T,) widths or None.
    """

    arm: str
    times: np.ndarray
    q: np.ndarray
    joint_names: list
    gripper: np.ndarray | None = None

    @property
    def duration(self) -> float:
        return float(self.times[-1])


@dataclass
class MotionPlan:
    """Result of a planning query.

    success: a validated trajectory exists. message: why not (or notes). trajectories: arm -> Trajectory
    for the moving arms. hold: arm -> (J,) configuration of arms that stay still. waypoints: (M, dim)
    path. validation: the dense check of the returned samples. timings: seconds per stage.
    """

    success: bool
    message: str
    trajectories: dict = field(default_factory=dict)
    hold: dict = field(default_factory=dict)
    waypoints: np.ndarray | None = None
    validation: ValidationReport | None = None
    method: str = ""
    blended: bool = False
    timings: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    reason: str = ""  # on failure: "reach" (no IK) | "start" | "goal" | "search" | "validation" | "input"

    def to_json(self) -> dict:
        """A JSON-ready dict (contract frames: b1; radians, seconds)."""
        v = self.validation
        return {
            "format": 1,
            "kind": "bijcr.trajectory",
            "success": self.success,
            "message": self.message,
            "arms": {
                name: {"joint_names": list(t.joint_names), "times": t.times, "q": t.q,
                       "gripper": None if t.gripper is None else t.gripper}
                for name, t in self.trajectories.items()
            },
            "hold": {k: np.asarray(v_) for k, v_ in self.hold.items()},
            "waypoints": self.waypoints,
            "planner": {"method": self.method, "blended_corners": self.blended, "timings_s": self.timings,
                        **self.stats},
            "validation": None if v is None else {
                "ok": v.ok, "problems": v.problems, "states_checked": v.states_checked,
                "max_step_m": v.max_step, "max_velocity_ratio": v.max_vel_ratio,
                "max_acceleration_ratio": v.max_acc_ratio,
            },
        }


class BimanualSetup:
    """Two arms (or one) in frame b1 with the scene map.

    Args:
        robot: RobotModel of the primary arm; ``robot2`` of the secondary (default the same).
        T_b1_b2: (4,4) secondary base in b1 (calibration.json or ground truth), or None for one arm.
        points_b1: (N,3) metric scene cloud in b1, a SceneMap, or None (no scene).
        resolution, margin, self_margin, openings: see CollisionWorld.
        speed: fraction (0, 1] of the robots' velocity and acceleration limits used by trajectories.
        dt: sample period of the returned trajectories (s).
    """

    def __init__(self, robot, T_b1_b2=None, points_b1=None, *, robot2=None, resolution: float = 0.01,
                 margin: float = 0.01, self_margin: float = 0.0, openings=(0.0, 0.0), speed: float = 0.5,
                 dt: float = 0.01):
        if not 0 < speed <= 1:
            raise ValueError(f"speed must be in (0, 1], got {speed}")
        if T_b1_b2 is not None:
            T_b1_b2 = check_T("T_b1_b2", T_b1_b2)
        self.world = CollisionWorld(robot, T_b1_b2, points_b1, robot2=robot2, resolution=resolution,
                                    margin=margin, self_margin=self_margin, openings=openings)
        self.speed = float(speed)
        self.dt = float(dt)
        self.arm_names = [a.name for a in self.world.arms]
        self._T_b_b1 = [np.linalg.inv(a.T_b1_b) for a in self.world.arms]
        self._ik: dict[str, IKSolver] = {}

    # ------------------------------------------------------------------ frames and IK
    def robot(self, arm: str):
        return self.world.arms[self.world.arm_index(arm)].robot

    def T_b1_b(self, arm: str) -> np.ndarray:
        return self.world.arms[self.world.arm_index(arm)].T_b1_b

    def ik_solver(self, arm: str) -> IKSolver:
        if arm not in self._ik:
            self._ik[arm] = IKSolver(self.robot(arm))
        return self._ik[arm]

    def ik(self, arm: str, T_b1_target: np.ndarray, q_current: np.ndarray | None = None,
           position_only: bool = False, n_solutions: int = 6, max_seeds: int = 16):
        """IK of ``arm``'s gripper frame (tool link without one) for a target pose in b1."""
        T_b1_target = np.asarray(T_b1_target, dtype=np.float64)
        if T_b1_target.shape != (4, 4) or not np.all(np.isfinite(T_b1_target)):
            check_T("T_b1_target", T_b1_target)  # raises with the reason
        k = self.world.arm_index(arm)
        T_b_target = self._T_b_b1[k] @ T_b1_target
        return self.ik_solver(arm).solve(T_b_target, q_current=q_current, position_only=position_only,
                                         n_solutions=n_solutions, max_seeds=max_seeds)

    def space(self, arms, q_now: dict) -> JointSpace:
        hold = {a: q_now[a] for a in self.arm_names if a not in arms}
        return JointSpace(self.world, arms, hold)

    # ------------------------------------------------------------------ planning
    def plan_reach(self, arm: str, T_b1_target: np.ndarray, q_now: dict, position_only: bool = False,
                   timeout: float = 2.0, max_goals: int = 4, seed: int | None = None) -> MotionPlan:
        """Move ``arm``'s gripper frame to ``T_b1_target`` (4,4) in b1 (position only when asked); the other
        arm holds ``q_now[other]``. ``q_now``: arm name -> (J,) current configurations."""
        t0 = time.perf_counter()
        q_now = {k: np.asarray(v, dtype=np.float64) for k, v in q_now.items()}
        missing = [a for a in self.arm_names if a not in q_now]
        if missing:
            raise ValueError(f"q_now: give the current configuration of {missing}")
        ik = self.ik(arm, T_b1_target, q_now[arm], position_only=position_only)
        t_ik = time.perf_counter() - t0
        if not ik.success:
            return MotionPlan(False, f"target out of reach for the {arm} arm: {ik.message}", hold=dict(q_now),
                              timings={"ik": t_ik}, reason="reach")
        goals = ik.solutions[:max_goals]
        plan = self.plan_configurations([arm], {arm: q_now[arm]}, [{arm: g} for g in goals], q_now,
                                        timeout=timeout, seed=seed)
        plan.timings["ik"] = t_ik
        plan.timings["total"] = time.perf_counter() - t0
        if not plan.success and "no goal configuration is valid" in plan.message:
            plan.message = (f"the {arm} arm reaches the target only in collision ({len(goals)} IK solutions "
                            f"tried): " + plan.message.split(": ", 1)[-1])
        return plan

    def plan_configurations(self, arms, q_start: dict, goals: list[dict], q_now: dict | None = None,
                            timeout: float = 2.0, seed: int | None = None) -> MotionPlan:
        """Plan the arms ``arms`` from ``q_start`` to any of ``goals`` (list of arm -> (J,)), preferred first.
        Arms not in ``arms`` hold ``q_now[arm]``. Both arms at once gives a 2 x J DoF query."""
        t0 = time.perf_counter()
        q_now = dict(q_now or {})
        q_now.update(q_start)
        arms = list(arms)
        try:
            space = self.space(arms, q_now)
        except ValueError as e:
            return MotionPlan(False, str(e), reason="input")
        start = np.concatenate([np.asarray(q_start[a], dtype=np.float64) for a in arms])
        G = np.stack([np.concatenate([np.asarray(g[a], dtype=np.float64) for a in arms]) for g in goals])
        hold = {a: q_now[a] for a in self.arm_names if a not in arms}
        res = plan_path(space, start, G, timeout=timeout, seed=seed)
        timings = {"plan": res.plan_time}
        if not res.success:
            return MotionPlan(False, res.message, hold=hold, timings=timings, stats=res.stats, reason=res.reason)
        t1 = time.perf_counter()
        plan = self._time_and_validate(space, arms, res.path, hold)
        if not plan.success:
            # the planner checks each edge at states one margin apart, the validation checks the timed
            # trajectory at other states as far apart: a path that dips inside the margin between two checked
            # states is refused. Once: the edges checked FINE_EDGE_STEP times as densely
            fine = plan_path(space, start, G, timeout=timeout, seed=seed, step=space.world.margin * FINE_EDGE_STEP)
            timings["plan_fine"] = fine.plan_time
            again = self._time_and_validate(space, arms, fine.path, hold) if fine.success else None
            if again is not None and again.success:
                plan, res = again, fine
        timings["parametrize_validate"] = time.perf_counter() - t1
        timings["total"] = time.perf_counter() - t0
        plan.timings.update(timings)
        plan.method = res.method
        plan.stats.update(res.stats, goal_index=res.goal_index)
        return plan

    def _time_and_validate(self, space: JointSpace, arms: list[str], path: np.ndarray, hold: dict) -> MotionPlan:
        vmax, amax = space.vmax * self.speed, space.amax * self.speed
        last = None
        for stop in ([False, True] if len(path) > 2 else [False]):
            traj = parametrize(path, vmax, amax, stop_at_waypoints=stop)
            times, Q = traj.sample_uniform(self.dt)
            rep = validate_samples(_Scaled(space, self.speed), times, Q)
            last = rep
            if rep.ok:
                trajs = {}
                for i, a in enumerate(arms):
                    sl = slice(space.offsets[i], space.offsets[i + 1])
                    trajs[a] = Trajectory(a, times, Q[:, sl].copy(), list(self.robot(a).joint_names))
                return MotionPlan(True, "" if not stop else "corners not blendable without collision: stops at waypoints",
                                  trajs, hold, path, rep, blended=not stop)
        return MotionPlan(False, "the time-parametrised trajectory failed validation: " + "; ".join(last.problems),
                          hold=hold, waypoints=path, validation=last, reason="validation")

    def check(self, q_now: dict) -> list[str]:
        """Problems of a configuration of all arms ([] when valid)."""
        space = self.space(self.arm_names, q_now)
        return space.explain(np.concatenate([np.asarray(q_now[a], dtype=np.float64) for a in self.arm_names]))


FINE_EDGE_STEP = 0.25  # of the margin: the edge check's spacing when a plan failed its dense validation


class _Scaled:
    """A JointSpace whose velocity / acceleration limits are scaled (for validating scaled trajectories)."""

    def __init__(self, space: JointSpace, speed: float):
        self._s = space
        self.vmax = space.vmax * speed
        self.amax = space.amax * speed

    def __getattr__(self, name):
        return getattr(self._s, name)


def default_ready(robot) -> np.ndarray:
    """A configuration clear of the table for arms that have no known current configuration: the rest
    pose (all zeros, clipped to the limits) for the Piper, the middle of the limits otherwise."""
    if robot.name == "piper":
        return robot.neutral()
    return 0.5 * (robot.lower + robot.upper)


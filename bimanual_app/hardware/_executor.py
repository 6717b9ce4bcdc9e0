"""The checked control loop that streams joint trajectories to one or two Piper arms.

Order of checks (nothing reaches an arm before all pre-flight checks pass):

1. approval (plans only): a passing, signed preview approval for exactly this plan;
2. limits of the whole plan: joint limits, joint speeds, workspace box along the densely sampled path;
3. live state: joint feedback fresh, no fault in the status frame, the plan starts where each arm is;
4. motors enabled, CAN joint control at the starting speed percentage;
5. every cycle (``period_s``), for every arm, *before* any arm is sent its command: feedback age below
   ``feedback_timeout_s``; no fault; feedback within ``tracking_tol_rad`` of some setpoint sent in the last
   ``tracking_window_s`` (the arm lags its setpoints); the new setpoint inside the joint limits and the
   workspace box, and its step from the previous one within the speed limits;
6. at the end, the last setpoint is held until every arm is within ``settle_tol_rad`` of it.

Speed ramp: the plan is played back at a rate that starts at ``start_rate`` and rises smoothly to 1 over
``ramp_s`` (times ``speed_scale`` overall); the SDK speed percentage rises with it from
``speed_pct_start`` to ``speed_pct_max``. A slower playback never exceeds the checked speeds.

Any error, a feedback timeout, or Ctrl-C (``KeyboardInterrupt``) inside the loop stops *every* arm
(:meth:`PiperArm.stop`: hold + quick emergency stop) before the exception reaches the caller.
"""

from __future__ import annotations

import collections
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bimanual_app.io_utils import Problem

from ._approval import PreviewApproval, check_approval
from ._errors import ArmFault, ConnectionFailed, FeedbackTimeout, HardwareError, LimitViolation, TrackingError
from ._trajectory import JointTrajectory, as_trajectory, joint_move

__all__ = ["ExecutionConfig", "ExecutionReport", "CycleInfo", "execute_plan", "move_arm", "stop_all"]


@dataclass
class ExecutionConfig:
    """Timing, ramp and watchdog settings of the control loop (defaults suit a real Piper)."""

    period_s: float = 0.01            # command period (100 Hz)
    speed_scale: float = 1.0          # overall playback rate, (0, 1]: 0.5 plays the plan at half speed
    ramp_s: float = 1.0               # time for the playback rate to reach speed_scale
    start_rate: float = 0.2           # playback rate at the start, as a fraction of speed_scale
    speed_pct_start: int = 10         # SDK speed percentage at the start
    speed_pct_max: int = 60           # ... after the ramp
    feedback_timeout_s: float = 0.25  # joint feedback older than this stops the arms
    tracking_tol_rad: float = 0.15    # max distance of the measured joints from recent setpoints (inf-norm)
    tracking_window_s: float = 0.5    # "recent" setpoints
    start_tol_rad: float = 0.05       # the plan must start this close to the measured joints
    settle_tol_rad: float = 0.02      # final convergence tolerance
    settle_time_s: float = 0.05       # ... held for this long
    settle_timeout_s: float = 3.0     # ... reached within this long
    enable_timeout_s: float = 2.0

    def __post_init__(self) -> None:
        if not 0 < self.speed_scale <= 1:
            raise ValueError(f"speed_scale must be in (0, 1], got {self.speed_scale}")
        if not 0 < self.start_rate <= 1:
            raise ValueError(f"start_rate must be in (0, 1], got {self.start_rate}")
        if not 1 <= self.speed_pct_start <= self.speed_pct_max <= 100:
            raise ValueError("need 1 <= speed_pct_start <= speed_pct_max <= 100")

    def rate(self, t: float) -> float:
        """Playback rate at wall time ``t`` since the start (smoothstep ramp)."""
        u = 1.0 if self.ramp_s <= 0 else min(max(t / self.ramp_s, 0.0), 1.0)
        s = u * u * (3 - 2 * u)
        return self.speed_scale * (self.start_rate + (1.0 - self.start_rate) * s)

    def speed_pct(self, t: float) -> int:
        u = 1.0 if self.ramp_s <= 0 else min(max(t / self.ramp_s, 0.0), 1.0)
        s = u * u * (3 - 2 * u)
        return int(round(self.speed_pct_start + (self.speed_pct_max - self.speed_pct_start) * s))


@dataclass
class CycleInfo:
    """What a progress callback sees each cycle."""

    cycle: int
    wall_s: float          # since the start of the loop
    plan_s: float          # position in the plan (seconds of plan time)
    duration_s: float      # plan duration
    rate: float            # current playback rate
    speed_pct: int
    q_cmd: dict[str, np.ndarray]
    q_meas: dict[str, np.ndarray]
    phase: str             # "move" or "settle"


@dataclass
class ExecutionReport:
    """Outcome of a completed run (errors raise instead)."""

    arms: list[str]
    plan_duration_s: float
    wall_s: float
    cycles: int
    max_tracking_rad: dict[str, float]
    final_error_rad: dict[str, float]
    final_q: dict[str, np.ndarray]
    late_cycles: int = 0   # cycles that started more than one period late (loop overrun)
    trace: dict[str, list] = field(default_factory=dict)  # arm -> [(wall_s, plan_s, q_cmd (J,), q_meas (J,))]

    def plot(self, path) -> None:
        """PNG of commanded (dashed) and measured (solid) joints over time, one panel per arm."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from bimanual_app.io_utils import atomic_path

        arms = [a for a in self.arms if self.trace.get(a)]
        fig, axes = plt.subplots(len(arms) or 1, 1, figsize=(8, 3 * max(len(arms), 1)), squeeze=False)
        for ax, a in zip(axes[:, 0], arms):
            t = np.array([r[0] for r in self.trace[a]])
            qc = np.array([r[2] for r in self.trace[a]])
            qm = np.array([r[3] for r in self.trace[a]])
            for j in range(qc.shape[1]):
                ax.plot(t, qm[:, j], color=f"C{j}", lw=1.2, label=f"j{j + 1}")
                ax.plot(t, qc[:, j], color=f"C{j}", lw=0.8, ls="--")
            ax.set_title(f"{a}: measured (solid) vs commanded (dashed); max tracking "
                         f"{self.max_tracking_rad.get(a, 0.0):.3f} rad")
            ax.set_xlabel("time (s)"), ax.set_ylabel("rad")
            ax.legend(fontsize=7, ncol=6)
        fig.tight_layout()
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=90)
        plt.close(fig)


def stop_all(arms: Mapping[str, Any]) -> tuple[str, ...]:
    """Send the stop sequence to every arm; one failing arm does not keep the others from stopping.

    A KeyboardInterrupt arriving while stopping one arm is noted and that arm is tried once more; it is
    re-raised once all arms were tried. Returns the names of the arms that were sent the stop.
    """
    stopped, pending_interrupt = [], None
    for name, arm in arms.items():
        for _attempt in range(2):
            try:
                arm.stop()
                stopped.append(name)
                break
            except KeyboardInterrupt as e:
                pending_interrupt = e
            except Exception as e:  # noqa: BLE001 - keep stopping the other arms
                print(f"[{name}] stop failed: {e}", file=sys.stderr)
                break
    if pending_interrupt is not None and not stopped:
        raise pending_interrupt
    return tuple(stopped)


def _preflight(arms: Mapping[str, Any], trajs: Mapping[str, JointTrajectory], cfg: ExecutionConfig) -> None:
    """Checks that need no motion; raise before anything is sent."""
    if set(arms) != set(trajs):
        raise LimitViolation(Problem("plan", "arms", f"plan has arms {sorted(trajs)}, hardware has {sorted(arms)}",
                                     "give one trajectory per connected arm"))
    problems: list[Problem] = []
    for name, tr in trajs.items():
        problems += arms[name].limits.trajectory_problems(tr, dt=max(cfg.period_s, 0.01))
    if problems:
        raise LimitViolation(problems)
    for name, arm in arms.items():
        if not arm.connected:
            raise ConnectionFailed("not connected (call connect() first)", name)
        fb = arm.read()
        if fb.age_s > cfg.feedback_timeout_s:
            raise FeedbackTimeout(f"joint feedback is {fb.age_s:.2f} s old before the start (limit "
                                  f"{cfg.feedback_timeout_s:.2f} s); is the arm still on the bus?", name)
        if fb.status not in (None, 0x00):
            raise ArmFault(f"the arm reports '{fb.status_text}' (status 0x{fb.status:02X}) before the start", name)
        d = np.abs(fb.q - trajs[name].q[0])
        if np.max(d) > cfg.start_tol_rad:
            j = int(np.argmax(d))
            raise LimitViolation(Problem(name, f"q[0].j{j + 1}",
                                         f"the plan starts {d[j]:.3f} rad from where the arm is (joint {j + 1}: "
                                         f"measured {fb.q[j]:+.3f}, plan {trajs[name].q[0][j]:+.3f}); limit "
                                         f"{cfg.start_tol_rad:.3f} rad",
                                         "move the arm to the plan's start first (PiperArm.move_to), or re-plan "
                                         "from the measured joints"))


@dataclass
class _LoopState:
    """Mutable state of the control loop between cycles."""

    t0: float
    q_prev: dict[str, np.ndarray]            # last setpoint sent to each arm
    recent: dict[str, collections.deque]     # arm -> recent (time, setpoint) for the tracking check
    tau: float = 0.0                         # position in the plan (seconds of plan time)
    t_last: float = 0.0
    cycle: int = 0
    phase: str = "move"
    settle_since: float | None = None
    settle_start: float | None = None
    next_tick: float = 0.0


def _start_loop(arms: Mapping[str, Any], trajs: Mapping[str, JointTrajectory], names: list[str],
                cfg: ExecutionConfig) -> _LoopState:
    """Enable every arm and set up the loop state at the plan's first sample."""
    for n in names:
        arms[n].ensure_enabled(cfg.speed_pct_start, cfg.enable_timeout_s)
    t0 = time.monotonic()
    # the speed check of the first command starts from the plan's first sample: the step from the
    # measured joints to it is bounded by start_tol_rad (pre-flight) and taken at the start speed %
    q_prev = {n: trajs[n].q[0].copy() for n in names}
    recent = {n: collections.deque([(t0, arms[n].read().q.copy()), (t0, q_prev[n].copy())]) for n in names}
    return _LoopState(t0, q_prev, recent, t_last=t0, next_tick=t0)


def _watch_arms(arms: Mapping[str, Any], names: list[str], st: _LoopState, cfg: ExecutionConfig,
                report: ExecutionReport, now: float) -> dict[str, np.ndarray]:
    """Read and watch every arm before commanding any: feedback age, faults, tracking. Returns measured joints."""
    meas = {}
    for n in names:
        fb = arms[n].read()
        if fb.age_s > cfg.feedback_timeout_s:
            raise FeedbackTimeout(f"joint feedback stopped: the newest frame is {fb.age_s:.3f} s old "
                                  f"(limit {cfg.feedback_timeout_s:.3f} s) at plan time {st.tau:.2f} s", n)
        if fb.status not in (None, 0x00):
            raise ArmFault(f"the arm reports '{fb.status_text}' (status 0x{fb.status:02X}) at plan time "
                           f"{st.tau:.2f} s", n)
        dq = st.recent[n]
        while len(dq) > 1 and now - dq[0][0] > cfg.tracking_window_s:
            dq.popleft()
        err = min(float(np.max(np.abs(fb.q - q))) for _, q in dq)
        report.max_tracking_rad[n] = max(report.max_tracking_rad[n], err)
        if err > cfg.tracking_tol_rad:
            raise TrackingError(f"the arm is {err:.3f} rad from its recent setpoints (limit "
                                f"{cfg.tracking_tol_rad:.3f} rad) at plan time {st.tau:.2f} s: blocked, "
                                "collided, or too slow for the plan", n)
        meas[n] = fb.q
    return meas


def _next_setpoints(arms: Mapping[str, Any], trajs: Mapping[str, JointTrajectory], names: list[str],
                    st: _LoopState, dt: float) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Sample every arm's next setpoint at the plan time and check it against the limits before any is sent."""
    cmd, grip = {}, {}
    for n in names:
        q, g = trajs[n].sample(st.tau)
        arms[n].limits.check_command(q, st.q_prev[n], max(dt, 1e-3))
        cmd[n], grip[n] = q, g
    return cmd, grip


def _send_setpoints(arms: Mapping[str, Any], names: list[str], st: _LoopState, report: ExecutionReport,
                    cmd: dict[str, np.ndarray], grip: dict[str, Any], meas: dict[str, np.ndarray],
                    pct: int, now: float, wall: float) -> None:
    """Send the checked setpoints and record them for the tracking check and the trace."""
    for n in names:
        arms[n]._send(cmd[n], pct, grip[n])
        st.q_prev[n] = cmd[n]
        st.recent[n].append((now, cmd[n].copy()))
        report.trace[n].append((wall, st.tau, cmd[n].copy(), meas[n].copy()))


def _settled(trajs: Mapping[str, JointTrajectory], names: list[str], st: _LoopState, cfg: ExecutionConfig,
             report: ExecutionReport, meas: dict[str, np.ndarray], now: float) -> bool:
    """Settle phase: True once every arm has held the last setpoint long enough; raises on a settle timeout."""
    errs = {n: float(np.max(np.abs(meas[n] - trajs[n].q[-1]))) for n in names}
    if max(errs.values()) <= cfg.settle_tol_rad:
        st.settle_since = st.settle_since or now
        if now - st.settle_since >= cfg.settle_time_s:
            report.final_error_rad = errs
            report.final_q = {n: meas[n].copy() for n in names}
            return True
    else:
        st.settle_since = None
    if now - st.settle_start > cfg.settle_timeout_s:
        worst = max(errs, key=errs.get)
        raise TrackingError(f"did not settle at the end of the plan: {errs[worst]:.3f} rad away after "
                            f"{cfg.settle_timeout_s:.1f} s (limit {cfg.settle_tol_rad:.3f} rad)", worst)
    return False


def _wait_for_tick(st: _LoopState, cfg: ExecutionConfig) -> None:
    """Sleep until the next cycle; after an overrun the schedule restarts from now."""
    st.next_tick += cfg.period_s
    delay = st.next_tick - time.monotonic()
    if delay > 0:
        time.sleep(delay)
    else:
        st.next_tick = time.monotonic()


def _loop(arms: Mapping[str, Any], trajs: Mapping[str, JointTrajectory], cfg: ExecutionConfig,
          progress: Callable[[CycleInfo], None] | None, report: ExecutionReport) -> ExecutionReport:
    """The control loop proper: one cycle per ``period_s`` until the plan has played and every arm settled."""
    names, duration = report.arms, report.plan_duration_s
    st = _start_loop(arms, trajs, names, cfg)
    while True:
        now = time.monotonic()
        dt = now - st.t_last
        st.t_last = now
        wall = now - st.t0
        if now - st.next_tick > cfg.period_s:
            report.late_cycles += 1
        meas = _watch_arms(arms, names, st, cfg, report, now)
        rate = cfg.rate(wall)
        pct = cfg.speed_pct(wall)
        if st.phase == "move":
            st.tau = min(duration, st.tau + rate * dt)
        cmd, grip = _next_setpoints(arms, trajs, names, st, dt)
        _send_setpoints(arms, names, st, report, cmd, grip, meas, pct, now, wall)
        st.cycle += 1
        report.cycles = st.cycle
        report.wall_s = time.monotonic() - st.t0
        if progress is not None:
            progress(CycleInfo(st.cycle, wall, st.tau, duration, rate, pct, cmd, meas, st.phase))
        # ---- end: hold the last setpoint until every arm has settled
        if st.phase == "move" and st.tau >= duration:
            st.phase, st.settle_start = "settle", now
        if st.phase == "settle" and _settled(trajs, names, st, cfg, report, meas, now):
            break
        _wait_for_tick(st, cfg)
    report.cycles = st.cycle
    report.wall_s = time.monotonic() - st.t0
    return report


def _run(arms: Mapping[str, Any], trajs: Mapping[str, JointTrajectory], cfg: ExecutionConfig,
         progress: Callable[[CycleInfo], None] | None) -> ExecutionReport:
    """Pre-flight, then the control loop; any failure inside the loop stops every arm before it propagates."""
    _preflight(arms, trajs, cfg)
    names = list(arms)
    duration = max(tr.duration for tr in trajs.values())
    report = ExecutionReport(names, duration, 0.0, 0, {n: 0.0 for n in names}, {}, {},
                             trace={n: [] for n in names})
    try:
        return _loop(arms, trajs, cfg, progress, report)
    except HardwareError as e:
        e.report = report  # what happened up to the failure (trace, tracking)
        raise e.with_stopped(stop_all(arms)) from None
    except LimitViolation as e:
        stopped = stop_all(arms)
        e.problems.append(Problem("control loop", "", f"arms stopped: {', '.join(stopped) or 'none'}",
                                  "check the plan against the limits before running it"))
        raise
    except KeyboardInterrupt:
        stopped = stop_all(arms)
        print(f"interrupted: stop sent to {', '.join(stopped) or 'no arm'}", file=sys.stderr)
        raise
    except BaseException as e:
        stopped = stop_all(arms)
        raise HardwareError(f"unexpected error in the control loop: {type(e).__name__}: {e}", "", stopped) from e


def execute_plan(arms: Mapping[str, Any], trajectories: Mapping[str, Any],
                 approval: PreviewApproval | str | None, config: ExecutionConfig | None = None,
                 progress: Callable[[CycleInfo], None] | None = None,
                 approval_key: bytes | None = None) -> ExecutionReport:
    """Run a previewed plan (arm name -> trajectory) on connected arms (arm name -> :class:`PiperArm`).

    Raises :class:`ApprovalError` / :class:`LimitViolation` before anything is sent, and the
    :class:`HardwareError` family (after stopping every arm) when something goes wrong while moving.
    """
    trajs = {n: as_trajectory(t) for n, t in trajectories.items()}
    check_approval(approval, trajs, key=approval_key)
    return _run(arms, trajs, config or ExecutionConfig(), progress)


def move_arm(arm: Any, q_goal: np.ndarray, speed: float = 0.25, config: ExecutionConfig | None = None,
             progress: Callable[[CycleInfo], None] | None = None) -> ExecutionReport:
    """Guarded point-to-point move of one arm (see :meth:`PiperArm.move_to`)."""
    if not 0 < speed <= 1:
        raise ValueError(f"speed must be in (0, 1], got {speed}")
    cfg = config or ExecutionConfig()
    q_goal = np.asarray(q_goal, float).reshape(-1)
    goal_problems = arm.limits.config_problems(q_goal[None], "goal")
    if goal_problems:
        raise LimitViolation(goal_problems)
    if not arm.connected:
        raise ConnectionFailed("not connected (call connect() first)", arm.name)
    fb = arm.read()
    if fb.age_s > cfg.feedback_timeout_s:
        raise FeedbackTimeout(f"joint feedback is {fb.age_s:.2f} s old; cannot plan a move from it", arm.name)
    accel = getattr(arm.robot, "accel_limits", arm.limits.velocity * 2.0)
    traj = joint_move(fb.q, q_goal, arm.limits.velocity * speed, np.asarray(accel, float) * speed, cfg.period_s)
    return _run({arm.name: arm}, {arm.name: traj}, cfg, progress)

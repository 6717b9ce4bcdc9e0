"""Two Piper arms driven together: one control loop commands both, an error on either stops both."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from bimanual_app.io_utils import Problem

from ._approval import check_approval
from ._errors import LimitViolation
from ._executor import CycleInfo, ExecutionConfig, ExecutionReport, execute_plan, stop_all
from ._limits import DEFAULT_WORKSPACE, SafetyLimits, WorkspaceBox
from ._piper import Feedback, PiperArm
from ._trajectory import as_trajectory

__all__ = ["BimanualHardware", "validate_plan"]


class BimanualHardware:
    """The primary and secondary Piper arms.

    Args:
        primary, secondary: the two :class:`PiperArm` objects (names ``primary`` / ``secondary``).

    Use :meth:`from_channels` to build both from CAN channel names. :meth:`execute` runs a plan
    ``{"primary": traj, "secondary": traj}`` that passed the preview; both arms are commanded in the same
    cycle of one loop, and any error, feedback timeout or Ctrl-C stops both.
    """

    def __init__(self, primary: PiperArm, secondary: PiperArm):
        if primary.can_channel == secondary.can_channel:
            raise ValueError(f"both arms are on CAN channel {primary.can_channel!r}; each Piper needs its own")
        self.arms: dict[str, PiperArm] = {"primary": primary, "secondary": secondary}
        for n, a in self.arms.items():
            a.name = n
            a.limits.name = n

    @classmethod
    def from_channels(cls, primary_can: str = "can0", secondary_can: str = "can1", *, robot: Any = "piper",
                      workspace_primary: WorkspaceBox | None = DEFAULT_WORKSPACE,
                      workspace_secondary: WorkspaceBox | None = DEFAULT_WORKSPACE,
                      velocity_fraction: float = 0.5, bustype: str = "socketcan", check_port: bool = True,
                      execute: str | None = None) -> BimanualHardware:
        """Both arms from channel names; each workspace box is in that arm's own base frame."""
        if isinstance(robot, str):
            from bimanual_app.robots import load_robot

            robot = load_robot(robot)
        arms = []
        for name, can, box in (("primary", primary_can, workspace_primary),
                               ("secondary", secondary_can, workspace_secondary)):
            lim = SafetyLimits.from_robot(robot, velocity_fraction=velocity_fraction, workspace=box, name=name)
            arms.append(PiperArm(can, name, limits=lim, bustype=bustype, check_port=check_port, execute=execute))
        return cls(*arms)

    def connect(self, timeout_s: float = 2.0) -> BimanualHardware:
        """Connect both (listen only); if the second fails the first is closed again."""
        done = []
        try:
            for a in self.arms.values():
                a.connect(timeout_s)
                done.append(a)
        except BaseException:
            for a in done:
                a.close()
            raise
        return self

    def close(self) -> None:
        for a in self.arms.values():
            a.close()

    def __enter__(self) -> BimanualHardware:
        return self.connect()

    def __exit__(self, *exc) -> None:
        self.close()

    def read(self) -> dict[str, Feedback]:
        return {n: a.read() for n, a in self.arms.items()}

    def stop(self) -> tuple[str, ...]:
        """Stop both arms (hold + quick emergency stop); returns the names that were sent the stop."""
        return stop_all(self.arms)

    def execute(self, plan: Mapping[str, Any], approval, config: ExecutionConfig | None = None,
                progress: Callable[[CycleInfo], None] | None = None,
                approval_key: bytes | None = None) -> ExecutionReport:
        """Run a previewed plan on both arms (see ``execute_plan`` for the checks and their order)."""
        return execute_plan(self.arms, plan, approval, config, progress, approval_key)


def validate_plan(plan: Mapping[str, Any], approval, limits: Mapping[str, SafetyLimits],
                  approval_key: bytes | None = None) -> list[str]:
    """Everything that can be checked without the arms (approval, joint/velocity/workspace limits).

    Returns summary lines; raises :class:`ApprovalError` / :class:`LimitViolation`. This is the dry run
    of ``--execute hardware``: it connects to nothing.
    """
    trajs = {n: as_trajectory(t) for n, t in plan.items()}
    rec = check_approval(approval, trajs, key=approval_key)
    problems: list[Problem] = []
    for n, tr in trajs.items():
        if n not in limits:
            problems.append(Problem("plan", n, f"no limits for arm {n!r}", "name arms primary / secondary"))
            continue
        problems += limits[n].trajectory_problems(tr)
    if problems:
        raise LimitViolation(problems)
    lines = [f"plan {rec.plan_sha256[:12]}: preview verdict {rec.verdict} ({rec.created})"]
    for n, tr in trajs.items():
        v = abs(tr.velocities()).max() if len(tr) > 1 else 0.0
        lines.append(f"  {n}: {len(tr)} samples, {tr.duration:.2f} s, peak joint speed {v:.2f} rad/s"
                     + (", gripper commanded" if tr.gripper is not None else ""))
    return lines

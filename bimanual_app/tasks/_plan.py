"""A task plan: named phases of time-parametrised joint trajectories with gripper widths, per arm.

Each :class:`Phase` holds, for the arms that move in it, a
:class:`bimanual_app.hardware.JointTrajectory` (times from 0, q (T, 6), gripper widths (T,)); an arm
absent from a phase holds its configuration and gripper. :meth:`TaskPlan.timeline` joins the phases
into one trajectory per arm on a shared clock: the exact thing the preview simulates, the approval
hashes and the hardware runs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Phase", "TaskPlan", "ARMS"]

ARMS = ("primary", "secondary")


@dataclass
class Phase:
    """One step of a task.

    Attributes:
        name: short name (``approach``, ``close``, ``lift``...).
        trajectories: arm name -> JointTrajectory (times from 0; gripper widths or None to keep the width).
        note: what happens, for people.
        planner: how it was made (``ompl``, ``cartesian``, ``gripper``, ``hold``).
        check: the success check that runs at its end, if any (``lift``, ``handover``).
        resting: arm name -> width (m) its fingers rest at on a held object in this phase (the object's
            contact width): the collision checks take the fingers there, not where the commanded width
            (closed, 0) would put them, inside the object.
    """

    name: str
    trajectories: dict
    note: str = ""
    planner: str = ""
    check: str = ""
    resting: dict = field(default_factory=dict)

    @property
    def duration(self) -> float:
        return max((float(t.duration) for t in self.trajectories.values()), default=0.0)

    @property
    def n_waypoints(self) -> int:
        return max((len(t) for t in self.trajectories.values()), default=0)


@dataclass
class TaskPlan:
    """The phases of a task from a start state.

    Attributes:
        q_start: arm name -> (J,) configuration at the start.
        width_start: arm name -> gripper opening at the start (m).
        phases: the phases in order.
        info: task-specific facts (grasps used, object motion...) for task.json.
    """

    q_start: dict
    width_start: dict
    phases: list[Phase] = field(default_factory=list)
    info: dict = field(default_factory=dict)

    def add(self, phase: Phase) -> Phase:
        """Append ``phase`` after checking it starts where the plan is now (continuity, 1e-6 rad)."""
        end_q, _ = self.end_state()
        for arm, tr in phase.trajectories.items():
            if not np.allclose(tr.q[0], end_q[arm], atol=1e-6):
                raise ValueError(f"phase {phase.name!r}: {arm} starts at {np.round(tr.q[0], 4)} but the plan is at "
                                 f"{np.round(end_q[arm], 4)}")
        self.phases.append(phase)
        return phase

    def end_state(self) -> tuple[dict, dict]:
        """(arm -> q, arm -> width) after the last phase."""
        q = {a: np.asarray(v, dtype=np.float64).copy() for a, v in self.q_start.items()}
        w = dict(self.width_start)
        for ph in self.phases:
            for arm, tr in ph.trajectories.items():
                q[arm] = tr.q[-1].copy()
                if tr.gripper is not None:
                    w[arm] = float(tr.gripper[-1])
        return q, w

    @property
    def duration(self) -> float:
        return float(sum(ph.duration for ph in self.phases))

    def phase_trajectories(self, k: int) -> dict:
        """Phase ``k`` as full trajectories for *both* arms (an idle arm holds q and gripper)."""
        from bimanual_app.hardware import JointTrajectory

        q, w = self._state_before(k)
        ph = self.phases[k]
        dur = ph.duration
        out = {}
        for arm in self.q_start:
            tr = ph.trajectories.get(arm)
            if tr is None:
                out[arm] = JointTrajectory([0.0, max(dur, 1e-3)], np.stack([q[arm], q[arm]]), [w[arm], w[arm]])
                continue
            g = tr.gripper if tr.gripper is not None else np.full(len(tr), w[arm])
            times, qs = tr.times, tr.q
            if tr.duration < dur - 1e-9:  # this arm finishes early: hold its end until the phase ends
                times = np.append(times, dur)
                qs = np.vstack([qs, qs[-1]])
                g = np.append(g, g[-1])
            out[arm] = JointTrajectory(times, qs, g)
        return out

    def _state_before(self, k: int) -> tuple[dict, dict]:
        sub = TaskPlan(self.q_start, self.width_start, self.phases[:k])
        return sub.end_state()

    def timeline(self) -> dict:
        """arm name -> one JointTrajectory for the whole task (phases back to back, shared clock)."""
        from bimanual_app.hardware import JointTrajectory

        acc = {a: ([], [], []) for a in self.q_start}
        t0 = 0.0
        for k in range(len(self.phases)):
            trs = self.phase_trajectories(k)
            for arm, tr in trs.items():
                ts, qs, gs = acc[arm]
                skip = 1 if ts else 0  # the first sample repeats the previous phase's last one
                ts.extend((tr.times[skip:] + t0).tolist())
                qs.extend(tr.q[skip:])
                gs.extend(tr.gripper[skip:].tolist())
            t0 += self.phases[k].duration
        out = {}
        for arm, (ts, qs, gs) in acc.items():
            if not ts:
                q = np.asarray(self.q_start[arm], dtype=np.float64)
                out[arm] = JointTrajectory([0.0], q[None], [self.width_start[arm]])
            else:
                out[arm] = JointTrajectory(np.array(ts), np.array(qs), np.array(gs))
        return out

    def opening_spans(self) -> list[tuple[float, float, dict]]:
        """Spans of the shared clock with ``(t_start, t_end, arm -> widest gripper opening in it)``, no narrower
        than where its fingers rest on a held object (``Phase.resting``): each phase cut where its grippers
        start or stop moving (``_width_runs``), so that an arm opening at the end of a motion is checked with its
        fingers as they were on the way and open only where they open."""
        out, t0 = [], 0.0
        for k, ph in enumerate(self.phases):
            for a, b, widest in _width_runs(self.phase_trajectories(k)):
                out.append((t0 + a, t0 + b, {arm: max(w, float(ph.resting.get(arm, 0.0))) for arm, w in widest.items()}))
            t0 += ph.duration
        return out

    def summary(self) -> list[dict]:
        """Per phase: name, duration (s), number of waypoints, planner, note."""
        return [{"phase": ph.name, "duration_s": round(ph.duration, 3), "n_waypoints": ph.n_waypoints,
                 "arms": sorted(ph.trajectories), "planner": ph.planner, "note": ph.note} for ph in self.phases]


def _width_runs(trs: dict) -> list[tuple[float, float, dict]]:
    """One phase's trajectories (arm -> JointTrajectory, both arms, one clock from 0) cut into runs where every
    gripper holds its width and runs where some gripper moves: ``(t_start, t_end, arm -> widest opening)``
    per run (widths are linear between samples, so the widest is at a sample)."""
    times = np.unique(np.concatenate([np.asarray(tr.times, dtype=np.float64) for tr in trs.values()]))
    G = {a: np.interp(times, tr.times, tr.gripper) for a, tr in trs.items()}
    if len(times) < 2:
        return [(0.0, float(times[-1]), {a: float(g.max()) for a, g in G.items()})]
    moving = np.any([np.abs(np.diff(g)) > 1e-9 for g in G.values()], axis=0)  # (T-1,) per interval
    cuts = np.r_[0, np.nonzero(np.diff(moving.astype(int)))[0] + 1, len(moving)]  # interval runs
    return [(float(times[i]), float(times[j]), {a: float(g[i:j + 1].max()) for a, g in G.items()})
            for i, j in zip(cuts[:-1], cuts[1:])]

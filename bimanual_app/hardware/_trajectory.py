"""Time-parametrised joint trajectories as the hardware layer takes them, and point-to-point moves.

The motion layer (``bimanual_app.planning``) hands over, per arm, sample times ``(T,)`` and joint angles
``(T, 6)`` (radians), optionally gripper opening widths ``(T,)`` (metres). :class:`JointTrajectory` holds
that, checks it, samples it at any time (linear interpolation between the planner's samples) and gives a
canonical hash used by the preview approval.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bimanual_app.io_utils import InputError, Problem, atomic_path
from bimanual_app.transforms import check_shape

__all__ = ["JointTrajectory", "as_trajectory", "trajectory_hash", "joint_move", "save_plan", "load_plan"]

# Quantum of the canonical hash: values are rounded to 1e-9 (s, rad, m) so a JSON/text round trip of
# the same plan gives the same hash, while any real change of the plan changes it.
_HASH_QUANTUM = 1e-9


@dataclass
class JointTrajectory:
    """One arm's trajectory.

    Attributes:
        times: (T,) seconds, strictly increasing, starting at 0 (shifted on construction).
        q: (T, J) joint angles in radians.
        gripper: (T,) gripper opening width in metres, or None (the gripper is left alone).
    """

    times: np.ndarray
    q: np.ndarray
    gripper: np.ndarray | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.times, dtype=np.float64).reshape(-1)
        q = np.asarray(self.q, dtype=np.float64)
        if q.ndim == 1 and len(t) == 1:
            q = q[None]
        check_shape("trajectory.q", q, (len(t), None))
        problems = []
        if len(t) < 1:
            problems.append(Problem("trajectory", "times", "the trajectory has no samples", "give at least one sample"))
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q))):
            problems.append(Problem("trajectory", "times/q", "contains NaN or inf", "fix the planner output"))
        elif len(t) > 1 and np.any(np.diff(t) <= 0):
            i = int(np.argmax(np.diff(t) <= 0))
            problems.append(Problem("trajectory", f"times[{i + 1}]",
                                    f"times must increase strictly ({t[i]:.6f} then {t[i + 1]:.6f})",
                                    "sort the samples / drop duplicate time stamps"))
        g = None
        if self.gripper is not None:
            g = np.asarray(self.gripper, dtype=np.float64).reshape(-1)
            if g.shape != t.shape:
                problems.append(Problem("trajectory", "gripper", f"gripper has {len(g)} samples, times {len(t)}",
                                        "give one gripper width per sample or none"))
            elif not np.all(np.isfinite(g)):
                problems.append(Problem("trajectory", "gripper", "contains NaN or inf", "fix the planner output"))
        if problems:
            raise InputError(problems)
        self.times = t - t[0]
        self.q = q
        self.gripper = g

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    @property
    def n_joints(self) -> int:
        return int(self.q.shape[1])

    def __len__(self) -> int:
        return len(self.times)

    def sample(self, t: float) -> tuple[np.ndarray, float | None]:
        """Joint angles (J,) and gripper width (or None) at time ``t`` (clamped to [0, duration])."""
        t = min(max(float(t), 0.0), self.duration)
        if len(self.times) == 1:
            return self.q[0].copy(), (None if self.gripper is None else float(self.gripper[0]))
        i = int(np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, len(self.times) - 2))
        t0, t1 = self.times[i], self.times[i + 1]
        a = (t - t0) / (t1 - t0)
        q = (1.0 - a) * self.q[i] + a * self.q[i + 1]
        g = None if self.gripper is None else float((1.0 - a) * self.gripper[i] + a * self.gripper[i + 1])
        return q, g

    def sample_many(self, ts: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """:meth:`sample` at every time of ``ts`` (T,) at once: joint angles (T,J) and widths (T,) or None,
        the same numbers as one call per time."""
        t = np.clip(np.asarray(ts, dtype=np.float64), 0.0, self.duration)
        if len(self.times) == 1:
            g = None if self.gripper is None else np.full(len(t), float(self.gripper[0]))
            return np.repeat(self.q[:1], len(t), axis=0), g
        i = np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, len(self.times) - 2)
        a = (t - self.times[i]) / (self.times[i + 1] - self.times[i])
        q = (1.0 - a)[:, None] * self.q[i] + a[:, None] * self.q[i + 1]
        g = None if self.gripper is None else (1.0 - a) * self.gripper[i] + a * self.gripper[i + 1]
        return q, g

    def resample(self, dt: float) -> JointTrajectory:
        """The same motion sampled every ``dt`` seconds (end point kept)."""
        n = max(2, int(np.ceil(self.duration / dt)) + 1)
        ts = np.linspace(0.0, self.duration, n) if self.duration > 0 else np.zeros(1)
        qs = np.stack([self.sample(t)[0] for t in ts])
        gs = None if self.gripper is None else np.array([self.sample(t)[1] for t in ts])
        return JointTrajectory(ts, qs, gs)

    def velocities(self) -> np.ndarray:
        """(T-1, J) finite-difference joint velocities between consecutive samples (rad/s)."""
        if len(self.times) < 2:
            return np.zeros((0, self.n_joints))
        return np.diff(self.q, axis=0) / np.diff(self.times)[:, None]


def as_trajectory(obj: Any) -> JointTrajectory:
    """Accept a :class:`JointTrajectory`, a mapping (``times``/``t``, ``q``/``positions``, optional
    ``gripper``/``gripper_width``) or any object with such attributes (the planner's dataclass)."""
    if isinstance(obj, JointTrajectory):
        return obj

    def get(*names):
        for n in names:
            if isinstance(obj, Mapping) and n in obj:
                return obj[n]
            if not isinstance(obj, Mapping) and hasattr(obj, n):
                return getattr(obj, n)
        return None

    times, q = get("times", "t", "time"), get("q", "positions", "qs")
    if times is None or q is None:
        raise InputError(Problem("trajectory", "", f"cannot read a joint trajectory from {type(obj).__name__}",
                                 "give times (T,) and q (T, 6), e.g. JointTrajectory(times, q)"))
    return JointTrajectory(times, q, get("gripper", "gripper_width", "widths"))


def _canonical_bytes(traj: JointTrajectory) -> bytes:
    parts = [np.round(traj.times / _HASH_QUANTUM).astype("<i8").tobytes(),
             np.asarray(traj.q.shape, "<i8").tobytes(),
             np.round(traj.q / _HASH_QUANTUM).astype("<i8").tobytes()]
    if traj.gripper is not None:
        parts.append(b"gripper")
        parts.append(np.round(traj.gripper / _HASH_QUANTUM).astype("<i8").tobytes())
    return b"|".join(parts)


def trajectory_hash(trajectories: Mapping[str, Any]) -> str:
    """SHA-256 (hex) of a plan: arm name -> trajectory, in a canonical form (values rounded to 1e-9).

    The arm names are part of the hash, so a plan approved for ``primary`` is not approved for
    ``secondary``.
    """
    h = hashlib.sha256(b"bijcr-plan-v1")
    for name in sorted(trajectories):
        h.update(b"#" + name.encode() + b"#")
        h.update(_canonical_bytes(as_trajectory(trajectories[name])))
    return h.hexdigest()


def joint_move(q0: np.ndarray, q1: np.ndarray, v_max: np.ndarray, a_max: np.ndarray, dt: float = 0.01,
               min_duration: float = 0.2) -> JointTrajectory:
    """A smooth synchronised point-to-point move from ``q0`` to ``q1`` (both (J,)).

    Quintic time scaling ``s(u) = 10u^3 - 15u^4 + 6u^5`` (zero velocity and acceleration at both ends); the
    duration ``T`` is the smallest for which every joint stays within ``v_max`` and ``a_max`` (J,): the
    peak of ``ds/dt`` is ``1.875 / T`` and of ``d2s/dt2`` is ``5.7735 / T^2``.
    """
    q0 = np.asarray(q0, np.float64)
    q1 = np.asarray(q1, np.float64)
    d = np.abs(q1 - q0)
    v_max = np.broadcast_to(np.asarray(v_max, np.float64), d.shape)
    a_max = np.broadcast_to(np.asarray(a_max, np.float64), d.shape)
    T = max(min_duration, float(np.max(1.875 * d / v_max)), float(np.max(np.sqrt(5.7735 * d / a_max))))
    n = max(2, int(np.ceil(T / dt)) + 1)
    u = np.linspace(0.0, 1.0, n)
    s = 10 * u**3 - 15 * u**4 + 6 * u**5
    return JointTrajectory(u * T, q0 + s[:, None] * (q1 - q0))


def save_plan(path: str | Path, trajectories: Mapping[str, Any]) -> None:
    """Write a plan (arm name -> trajectory) to an ``.npz`` (keys ``NAME/times``, ``NAME/q``, ``NAME/gripper``)."""
    data = {}
    for name, tr in trajectories.items():
        tr = as_trajectory(tr)
        data[f"{name}/times"] = tr.times
        data[f"{name}/q"] = tr.q
        if tr.gripper is not None:
            data[f"{name}/gripper"] = tr.gripper
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **data)


def load_plan(path: str | Path) -> dict[str, JointTrajectory]:
    """Read a plan written by :func:`save_plan`."""
    path = Path(path)
    if not path.is_file():
        raise InputError(Problem(str(path), "", "plan file is missing", "write it with save_plan()"))
    with np.load(path) as z:
        names = sorted({k.split("/")[0] for k in z.files})
        out = {}
        for n in names:
            if f"{n}/times" not in z.files or f"{n}/q" not in z.files:
                raise InputError(Problem(str(path), n, "needs both NAME/times and NAME/q", "re-save the plan"))
            out[n] = JointTrajectory(z[f"{n}/times"], z[f"{n}/q"], z[f"{n}/gripper"] if f"{n}/gripper" in z.files else None)
    return out

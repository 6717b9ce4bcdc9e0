"""Dense validation of a sampled trajectory: limits, and collisions with no step larger than the margin."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["ValidationReport", "validate_samples"]


@dataclass
class ValidationReport:
    """ok: everything passed. problems: what failed. states_checked: configurations collision-checked.
    max_step: the largest lever-bound displacement between consecutive checked states (m).
    max_vel_ratio / max_acc_ratio: largest |qd| / vmax and |qdd| / amax (finite differences)."""

    ok: bool
    problems: list = field(default_factory=list)
    states_checked: int = 0
    max_step: float = 0.0
    max_vel_ratio: float = 0.0
    max_acc_ratio: float = 0.0


def validate_samples(space, times: np.ndarray, Q: np.ndarray, step: float | None = None,
                     tol: float = 1e-6) -> ValidationReport:
    """Validate the trajectory that linearly interpolates samples ``Q`` (T, dim) at ``times`` (T,).

    That is what the hardware layer executes. Checks: joint limits at every sample; velocity
    (|dq/dt| <= vmax) and acceleration (second differences <= amax) limits; collisions at every sample and
    at extra states inserted so that no point of any arm moves more than ``step`` (default: the world's
    margin) between consecutive checked states.
    """
    times = np.asarray(times, dtype=np.float64)
    Q = np.asarray(Q, dtype=np.float64)
    step = float(step if step is not None else space.world.margin)
    rep = ValidationReport(ok=True)
    if Q.ndim != 2 or Q.shape[1] != space.dim or len(times) != len(Q):
        rep.ok = False
        rep.problems.append(f"trajectory shape {Q.shape} / {times.shape} does not match {space.dim} joints")
        return rep
    if not np.all(np.isfinite(Q)) or not np.all(np.isfinite(times)):
        rep.ok = False
        rep.problems.append("trajectory contains NaN or inf")
        return rep
    out = (Q < space.lower - 1e-9) | (Q > space.upper + 1e-9)
    if out.any():
        i, j = np.argwhere(out)[0]
        rep.ok = False
        rep.problems.append(f"sample {i}: joint {j} = {Q[i, j]:.4f} outside [{space.lower[j]:.4f}, {space.upper[j]:.4f}]")
    if len(Q) > 1:
        dt = np.diff(times)
        if np.any(dt <= 0):
            rep.ok = False
            rep.problems.append("times do not increase strictly")
            return rep
        vel = np.diff(Q, axis=0) / dt[:, None]
        rep.max_vel_ratio = float(np.max(np.abs(vel) / space.vmax))
        if rep.max_vel_ratio > 1 + tol:
            rep.ok = False
            rep.problems.append(f"velocity limit exceeded ({rep.max_vel_ratio:.3f} x vmax)")
        if len(Q) > 2:
            acc = np.diff(vel, axis=0) / (0.5 * (dt[1:] + dt[:-1]))[:, None]
            rep.max_acc_ratio = float(np.max(np.abs(acc) / space.amax))
            if rep.max_acc_ratio > 1 + 1e-3:
                rep.ok = False
                rep.problems.append(f"acceleration limit exceeded ({rep.max_acc_ratio:.3f} x amax)")
    # dense collision check of the piecewise-linear motion
    if len(Q) > 1:
        bound = space.motion_bound(np.diff(Q, axis=0))
        k = np.maximum(1, np.ceil(bound / step).astype(int))
        seg = np.repeat(np.arange(len(Q) - 1), k)
        frac = np.concatenate([np.arange(n) / n for n in k])
        dense = np.concatenate([Q[seg] + frac[:, None] * (Q[seg + 1] - Q[seg]), Q[-1:]])
        rep.max_step = float(np.max(bound / k))
    else:
        dense = Q
    valid = space.valid_batch(dense)
    rep.states_checked = len(dense)
    if not valid.all():
        i = int(np.argmin(valid))
        rep.ok = False
        why = "; ".join(space.explain(dense[i])[:3]) or "in collision"
        rep.problems.append(f"state {i} of {len(dense)} on the trajectory is not valid: {why}")
    return rep

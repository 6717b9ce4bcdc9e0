"""The joint space a query plans in: one arm (the other held still) or both arms stacked (2 x J DoF)."""

from __future__ import annotations

import numpy as np

__all__ = ["JointSpace"]


class JointSpace:
    """Which arms move, their stacked limits, and vectorised validity / motion bounds.

    Args:
        world: CollisionWorld.
        arms: names (or indices) of the moving arms, in the order their joints are stacked.
        hold: arm name -> (J,) configuration of each arm that does not move (every other arm of the world).
    """

    def __init__(self, world, arms, hold: dict | None = None):
        self.world = world
        self.arms = [world.arm_index(a) for a in arms]
        if len(set(self.arms)) != len(self.arms) or not self.arms:
            raise ValueError(f"arms: give distinct moving arms, got {arms}")
        hold = {world.arm_index(k): np.asarray(v, dtype=np.float64) for k, v in (hold or {}).items()}
        self.hold = {}
        for k in range(world.n_arms):
            if k in self.arms:
                continue
            if k not in hold:
                raise ValueError(f"the {world.arms[k].name} arm does not move in this query: give its configuration")
            self.hold[k] = hold[k]
        robots = [world.arms[k].robot for k in self.arms]
        self.dims = [r.nq_arm for r in robots]
        self.offsets = np.concatenate([[0], np.cumsum(self.dims)]).astype(int)
        self.dim = int(self.offsets[-1])
        self.lower = np.concatenate([r.lower for r in robots])
        self.upper = np.concatenate([r.upper for r in robots])
        self.vmax = np.concatenate([r.velocity_limits for r in robots])
        self.amax = np.concatenate([r.accel_limits for r in robots])
        self.lever = np.concatenate([world.arms[k].lever for k in self.arms])
        self.names = [world.arms[k].name for k in self.arms]

    def split(self, Q: np.ndarray) -> list[np.ndarray]:
        """Per-world-arm configurations (held arms as (J,)) from stacked ``Q`` (..., dim)."""
        out = []
        for k in range(self.world.n_arms):
            if k in self.arms:
                i = self.arms.index(k)
                out.append(Q[..., self.offsets[i]:self.offsets[i + 1]])
            else:
                out.append(self.hold[k])
        return out

    def valid_batch(self, Q: np.ndarray) -> np.ndarray:
        """(N,) collision free and within limits, for stacked configurations (N, dim)."""
        Q = np.atleast_2d(np.asarray(Q, dtype=np.float64))
        inside = np.all((Q >= self.lower - 1e-9) & (Q <= self.upper + 1e-9), axis=1)
        ok = np.zeros(len(Q), dtype=bool)
        if inside.any():
            parts = self.split(Q[inside])
            ok[inside] = self.world.valid_batch(*parts)
        return ok

    def motion_bound(self, dQ: np.ndarray) -> np.ndarray:
        """Upper bound (m) of the displacement of any arm point for joint steps (..., dim); arms summed."""
        return np.abs(np.asarray(dQ)) @ self.lever

    def explain(self, q: np.ndarray) -> list[str]:
        parts = self.split(np.asarray(q, dtype=np.float64))
        out = []
        for i, k in enumerate(self.arms):
            qa = parts[k]
            r = self.world.arms[k].robot
            bad = np.nonzero((qa < r.lower - 1e-9) | (qa > r.upper + 1e-9))[0]
            out += [f"{self.names[i]} joint {r.joint_names[j]} = {qa[j]:.4f} rad outside "
                    f"[{r.lower[j]:.4f}, {r.upper[j]:.4f}]" for j in bad]
        return out + self.world.explain(*parts)

    def interpolate(self, q0: np.ndarray, q1: np.ndarray, step: float) -> np.ndarray:
        """States (K,dim) on the straight joint segment q0 -> q1, endpoints included, so that no point of
        any arm moves more than ``step`` metres between consecutive states (the lever bound)."""
        n = max(1, int(np.ceil(self.motion_bound(q1 - q0) / step)))
        s = np.linspace(0.0, 1.0, n + 1)[:, None]
        return q0 + s * (q1 - q0)

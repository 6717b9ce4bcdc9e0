"""Time parametrisation of a joint-space path within velocity and acceleration limits.

The path is a polyline through waypoints q_0..q_n (what the planner validated). The trajectory moves all
joints together along each segment at a constant velocity v_k and changes velocity in parabolic blends
(linear velocity ramps) centred on the interior waypoints, starting and ending at rest (linear segments
with parabolic blends, Craig, Introduction to Robotics, 7.3, synchronised over the joints):

- segment durations T_k >= max_j |dq_jk| / vmax_j (velocity limit),
- blend durations t_k = max_j |v_jk - v_j,k-1| / amax_j (acceleration limit; v_-1 = v_n = 0),
- blends may not overlap: t_k / 2 + t_(k+1) / 2 <= T_k; segments are slowed until they fit.

A symmetric blend integrates the same displacement as the corner it cuts, so outside the blends the
trajectory lies exactly on the validated segments; inside an interior blend it cuts the corner by at most
|dv| t / 8 per joint (the final dense validation checks those parts). The start and end blends stay on
their segment. ``stop_at_waypoints=True`` makes every waypoint a full stop (no corner is cut): the
fallback when a blended corner is not collision free. Written by hand: no time-parametrisation library
(TOPP-RA, Ruckig) is in the project's dependencies, and this profile is short and exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BlendedTrajectory", "parametrize"]


@dataclass
class BlendedTrajectory:
    """A rest-to-rest trajectory: linear segments with parabolic blends.

    waypoints: (M,J); seg_dur: (M-1,) T_k; blend: (M,) t_k (blend k centred on waypoint k);
    vel: (M+1,J) velocities v_-1..v_(M-1) (zero at both ends); t0: (M,) time of the centre of blend k.
    """

    waypoints: np.ndarray
    seg_dur: np.ndarray
    blend: np.ndarray
    vel: np.ndarray
    t0: np.ndarray

    @property
    def duration(self) -> float:
        return float(self.t0[-1] + self.blend[-1] / 2)

    def breakpoints(self) -> np.ndarray:
        """Times where the acceleration changes (blend starts and ends), sorted, within [0, duration]."""
        b = np.concatenate([self.t0 - self.blend / 2, self.t0 + self.blend / 2])
        return np.unique(np.clip(b, 0.0, self.duration))

    def sample(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions (T,J) and velocities (T,J) at ``times`` (T,) (clamped to [0, duration])."""
        t = np.clip(np.asarray(times, dtype=np.float64), 0.0, self.duration)
        W, v, t0, tb = self.waypoints, self.vel, self.t0, self.blend
        # the polyline p(t) through (t0_k, W_k) with velocity v_k+1 after waypoint k, held outside
        k = np.clip(np.searchsorted(t0, t, side="right") - 1, 0, len(t0) - 1)
        q = W[k] + v[k + 1] * (t - t0[k])[:, None]
        qd = v[k + 1].copy()
        # inside blend m, replace by the ramp from v_m to v_m+1 (v indices shifted by one)
        for m in range(len(t0)):
            lo, hi = t0[m] - tb[m] / 2, t0[m] + tb[m] / 2
            inb = (t >= lo) & (t <= hi)
            if not inb.any() or tb[m] <= 0:
                continue
            tau = t[inb] - lo
            a = (v[m + 1] - v[m]) / tb[m]
            # start of the blend lies on the polyline before waypoint m: W_m - v_m tb/2
            q[inb] = W[m] - v[m] * (tb[m] / 2) + v[m] * tau[:, None] + 0.5 * a * tau[:, None] ** 2
            qd[inb] = v[m] + a * tau[:, None]
        return q, qd

    def sample_uniform(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Times (T,) every ``dt`` (end point included) and positions (T,J)."""
        n = max(1, int(np.ceil(self.duration / dt)))
        times = np.linspace(0.0, self.duration, n + 1)
        return times, self.sample(times)[0]


def parametrize(waypoints: np.ndarray, vmax: np.ndarray, amax: np.ndarray,
                stop_at_waypoints: bool = False) -> BlendedTrajectory:
    """Time-parametrise the polyline ``waypoints`` (M,J) within ``vmax`` (J,) and ``amax`` (J,)."""
    W = np.asarray(waypoints, dtype=np.float64)
    vmax = np.asarray(vmax, dtype=np.float64)
    amax = np.asarray(amax, dtype=np.float64)
    if W.ndim != 2 or len(W) < 1:
        raise ValueError(f"waypoints: expected (M, J), got {W.shape}")
    if np.any(vmax <= 0) or np.any(amax <= 0):
        raise ValueError("velocity and acceleration limits must be positive")
    # drop repeated waypoints (zero-length segments)
    keep = np.r_[True, np.any(np.abs(np.diff(W, axis=0)) > 1e-12, axis=1)]
    W = W[keep]
    if stop_at_waypoints and len(W) > 2:
        parts = [parametrize(W[i:i + 2], vmax, amax) for i in range(len(W) - 1)]
        return _concatenate(parts)
    J = W.shape[1]
    if len(W) == 1:
        return BlendedTrajectory(W, np.zeros(0), np.zeros(1), np.zeros((2, J)), np.zeros(1))
    D = np.diff(W, axis=0)  # (n, J)
    T = np.max(np.abs(D) / vmax, axis=1)  # velocity-limited segment durations
    T = np.maximum(T, 1e-9)
    for _ in range(200):
        v = np.concatenate([np.zeros((1, J)), D / T[:, None], np.zeros((1, J))])  # v_-1 .. v_n
        tb = np.max(np.abs(np.diff(v, axis=0)) / amax, axis=1)  # (n+1,) blends at waypoints 0..n
        need = (tb[:-1] + tb[1:]) / 2
        if np.all(need <= T * (1 + 1e-9)):
            break
        # slow down the segments whose blends overlap; sqrt converges fast for the triangular case
        over = need > T
        T = np.where(over, np.maximum(T * 1.02, np.sqrt(T * need)), T)
    else:  # pragma: no cover - the iteration converges geometrically
        raise RuntimeError("time parametrisation did not converge")
    t0 = np.concatenate([[tb[0] / 2], tb[0] / 2 + np.cumsum(T)])
    return BlendedTrajectory(W, T, tb, v, t0)


def _concatenate(parts: list[BlendedTrajectory]) -> BlendedTrajectory:
    """Rest-to-rest pieces one after another, as one trajectory (a waypoint between two is a stop)."""
    return _Chain(parts)


class _Chain(BlendedTrajectory):
    """Several rest-to-rest trajectories played one after the other."""

    def __init__(self, parts: list[BlendedTrajectory]):
        self.parts = parts
        self.starts = np.concatenate([[0.0], np.cumsum([p.duration for p in parts])])
        self.waypoints = np.concatenate([parts[0].waypoints[:1]] + [p.waypoints[1:] for p in parts])

    @property
    def duration(self) -> float:
        return float(self.starts[-1])

    def breakpoints(self) -> np.ndarray:
        return np.unique(np.concatenate([p.breakpoints() + s for p, s in zip(self.parts, self.starts)]))

    def sample(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = np.clip(np.asarray(times, dtype=np.float64), 0.0, self.duration)
        k = np.clip(np.searchsorted(self.starts, t, side="right") - 1, 0, len(self.parts) - 1)
        J = self.waypoints.shape[1]
        q, qd = np.empty((len(t), J)), np.empty((len(t), J))
        for i, p in enumerate(self.parts):
            m = k == i
            if m.any():
                q[m], qd[m] = p.sample(t[m] - self.starts[i])
        return q, qd

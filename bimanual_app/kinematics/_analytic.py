"""Closed-form IK branches of a six-joint revolute arm whose first two axes meet and whose last three meet
(a spherical wrist): the Piper's layout, and that of most six-axis arms with a wrist centre.

The branches come from Paden-Kahan subproblems on the arm's screw axes at its zero configuration (the
product of exponentials ``T(q) = e^[xi1 q1] ... e^[xi6 q6] T(0)``):

1. the wrist centre ``c`` moves only with joints 1-3; its distance from the shoulder (where axes 1 and 2
   meet) depends on joint 3 alone: subproblem 3 gives joint 3 (two elbows);
2. joints 1 and 2 then take the rotated wrist centre to the target's: subproblem 2 (two shoulders);
3. joints 4 and 5 take a point of axis 6 where the target puts it: subproblem 2 (two wrists); joint 6 by
   subproblem 1. Up to eight branches in all.

Why hand-written: no maintained Python package gives this closed form (IKFast needs OpenRAVE's code
generator, opw_kinematics is C++ only), and the grasp planner's thousands of queries need it batched over
targets. The branches are starting points, not answers: a real wrist's axes meet only to within a fraction
of a millimetre (Piper: 0.09 mm), so ``IKSolver`` polishes each branch with its damped least squares (one or
two steps) and keeps only what converges within the joint limits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bimanual_app.transforms import skew

from ._dls import _cross

__all__ = ["WristChain", "wrist_chain", "ik_branches"]

LIMIT_SLACK = 0.02  # rad: a branch this far outside a joint limit is still polished (clipped) from the limit


@dataclass(frozen=True)
class WristChain:
    """A six-joint revolute chain's screw axes at q = 0, in the base frame.

    w: (6, 3) unit joint axes; r: (6, 3) a point on each axis; T_home_inv: (4, 4) the inverse of the target
    frame's pose at q = 0;
    shoulder: (3,) where axes 1 and 2 meet; wrist: (3,) where axes 4 and 5 meet (axis 6 passes within
    ``wrist_gap`` metres); lower, upper: (6,) joint limits (rad).
    """

    w: np.ndarray
    r: np.ndarray
    T_home_inv: np.ndarray
    shoulder: np.ndarray
    wrist: np.ndarray
    wrist_gap: float
    lower: np.ndarray
    upper: np.ndarray


def _closest_points(r1, w1, r2, w2) -> tuple[np.ndarray, np.ndarray] | None:
    """The closest points (3,), (3,) of two lines (point, unit direction); None when they are parallel."""
    n = _cross(w1, w2)
    if np.linalg.norm(n) < 1e-6:
        return None
    # r1 + a w1 - (r2 + b w2) is perpendicular to both directions
    A = np.array([[w1 @ w1, -(w1 @ w2)], [w1 @ w2, -(w2 @ w2)]])
    a, b = np.linalg.solve(A, np.array([(r2 - r1) @ w1, (r2 - r1) @ w2]))
    return r1 + a * w1, r2 + b * w2


def _line_distance(p, r, w) -> float:
    """Distance (m) of the point p (3,) from the line through r (3,) along the unit w (3,)."""
    d = p - r
    return float(np.linalg.norm(d - (d @ w) * w))


def wrist_chain(kin, lower: np.ndarray, upper: np.ndarray, tol: float = 1e-3) -> WristChain | None:
    """The chain of ``kin`` (a ``_dls.ChainKinematics``) as a ``WristChain``, or None when it is not six
    revolute joints whose axes 1 and 2 meet and 4, 5, 6 meet (each within ``tol`` metres), with joint 3
    changing the wrist centre's distance from the shoulder. ``lower``, ``upper``: (6,) joint limits."""
    if len(kin.cols) != 6 or not kin.revolute.all() or kin.nv != 6:
        return None
    R, p = np.eye(3), np.zeros(3)
    w, r = np.zeros((6, 3)), np.zeros((6, 3))
    for i in range(6):  # joint frames at q = 0: each placement in its parent's frame
        p = p + R @ kin.M_t[i]
        R = R @ kin.M_R[i]
        w[i], r[i] = R @ kin.axes[i], p
    sh, wr = _closest_points(r[0], w[0], r[1], w[1]), _closest_points(r[3], w[3], r[4], w[4])
    if sh is None or wr is None or np.linalg.norm(sh[0] - sh[1]) > tol or np.linalg.norm(wr[0] - wr[1]) > tol:
        return None
    wrist = 0.5 * (wr[0] + wr[1])
    gap = _line_distance(wrist, r[5], w[5])
    shoulder = 0.5 * (sh[0] + sh[1])
    # joint 3 must change the wrist centre's distance from the shoulder: neither may lie on its axis
    if gap > tol or min(_line_distance(wrist, r[2], w[2]), _line_distance(shoulder, r[2], w[2])) < 1e-3:
        return None
    T_home = kin(np.zeros((1, kin.nv)))[0][0]
    return WristChain(w, r, np.linalg.inv(T_home), shoulder, wrist, gap,
                      np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64))


# ---------------------------------------------------------------- batched Paden-Kahan subproblems

_SKEW_T: dict[bytes, np.ndarray] = {}  # K_w^T by axis: a chain has six axes, asked for thousands of times


def _skew_t(w: np.ndarray) -> np.ndarray:
    """The transposed skew matrix (3, 3) of the axis w (3,) (``u @ _skew_t(w)`` = w x u for rows u)."""
    key = w.tobytes()
    K = _SKEW_T.get(key)
    if K is None:
        if len(_SKEW_T) > 64:
            _SKEW_T.clear()
        K = _SKEW_T[key] = skew(w).T.copy()
    return K


def _rotate(w: np.ndarray, r: np.ndarray, theta: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Points (N, 3): p (N, 3) rotated by theta (N,) about the axis through r (3,) along the unit w (3,)."""
    u = p - r
    c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
    return r + u * c + (u @ _skew_t(w)) * s + w * (u @ w)[:, None] * (1 - c)


def _rotation(w: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) about the unit axis w (3,) by theta (N,) (Rodrigues)."""
    K = _skew_t(w).T
    s, c = np.sin(theta)[:, None, None], (1 - np.cos(theta))[:, None, None]
    return np.eye(3) + s * K + c * (K @ K)


def sp1(w: np.ndarray, r: np.ndarray, p: np.ndarray, q: np.ndarray, fallback: np.ndarray,
        eps: float = 1e-9) -> np.ndarray:
    """(N,) the angle about the axis (r (3,), unit w (3,)) that takes p (N, 3) nearest to q (N, 3);
    ``fallback`` (N,) where either point lies within ``eps`` metres of the axis (any angle does, nearly)."""
    u, v = p - r, q - r
    u = u - (u @ w)[:, None] * w
    v = v - (v @ w)[:, None] * w
    # (u x v) . w = u . (v x w) = -u . (K_w v)
    theta = np.arctan2(-(u * (v @ _skew_t(w))).sum(axis=1), (u * v).sum(axis=1))
    degenerate = np.minimum((u * u).sum(axis=1), (v * v).sum(axis=1)) < eps ** 2
    return np.where(degenerate, fallback, theta)


def sp2(w1, w2, r, p, q, fallback1, fallback2, eps1: float = 1e-9):
    """Angles (t1 (N, 2), t2 (N, 2)) and ok (N,) with ``e^[w1 t1] e^[w2 t2] p = q`` for two axes (unit w1,
    w2 (3,)) through one point r (3,); p, q (N, 3). Two solutions per row; ok is False where none exists
    (a shortfall of at most 1 mm is taken as touching). t1 is ``fallback1`` (N,) where q lies within
    ``eps1`` metres of axis 1 (t2's ``fallback2`` where p lies on axis 2)."""
    u, v = p - r, q - r
    c12 = w1 @ w2
    den = c12 ** 2 - 1
    alpha = (c12 * (u @ w2) - v @ w1) / den
    beta = (c12 * (v @ w1) - u @ w2) / den
    n = _cross(w1, w2)
    uu = (u * u).sum(axis=1)
    g2 = (uu - alpha ** 2 - beta ** 2 - 2 * alpha * beta * c12) / (n @ n)
    ok = g2 > -1e-3 * np.sqrt(uu + 1e-12)
    g = np.sqrt(np.maximum(g2, 0.0))
    # both solutions at once: rows (2N), the + sign's first
    m = alpha[:, None] * w1 + beta[:, None] * w2
    z = r + np.concatenate([m, m]) + np.concatenate([g, -g])[:, None] * n
    p2, q2 = np.concatenate([p, p]), np.concatenate([q, q])
    t2 = sp1(w2, r, p2, z, np.concatenate([fallback2, fallback2]))
    t1 = sp1(w1, r, _rotate(w2, r, t2, p2), q2, np.concatenate([fallback1, fallback1]), eps1)
    return t1.reshape(2, -1).T, t2.reshape(2, -1).T, ok


def sp3(w, r, p, q, delta):
    """Angles (N, 2) about the axis (r (3,), unit w (3,)) that put p (N, 3) at distance delta (N,) from
    q (N, 3), and ok (N,) (False where no angle does, beyond a 1 mm shortfall; then the nearest angle)."""
    u, v = p - r, q - r
    up = u - (u @ w)[:, None] * w
    vp = v - (v @ w)[:, None] * w
    d2 = delta ** 2 - ((p - q) @ w) ** 2
    theta0 = np.arctan2(-(up * (vp @ _skew_t(w))).sum(axis=1), (up * vp).sum(axis=1))
    nu, nv = np.sqrt((up * up).sum(axis=1)), np.sqrt((vp * vp).sum(axis=1))
    cos_phi = (nu ** 2 + nv ** 2 - d2) / np.maximum(2 * nu * nv, 1e-12)
    slack = 1e-3 * (nu + nv) / np.maximum(nu * nv, 1e-12)  # a 1 mm shortfall of the distance, in cosine terms
    ok = np.abs(cos_phi) <= 1 + slack
    phi = np.arccos(np.clip(cos_phi, -1.0, 1.0))
    return np.stack([theta0 - phi, theta0 + phi], axis=1), ok


# ---------------------------------------------------------------- the branches


def _into_limits(theta: np.ndarray, lower: np.ndarray, upper: np.ndarray, slack) -> tuple[np.ndarray, np.ndarray]:
    """(angles within [lower, upper] (N, J), excess (N, J)): theta (N, J) turned by whole turns into the
    limits (J,) and clipped to them; excess: by how much (rad) they missed the limits beyond ``slack`` (rad,
    (N, J)), 0 where by at most that."""
    a = theta + 2 * np.pi * np.ceil((lower - theta) / (2 * np.pi))  # the smallest turn of theta >= lower
    below = a - 2 * np.pi  # the largest one < lower
    over, under = np.maximum(a - upper, 0.0), lower - below
    pick = np.where(over <= under, a, below)
    return np.clip(pick, lower, upper), np.maximum(np.minimum(over, under) - slack, 0.0)


WRIST_ALIGNED = 0.1  # rad: joint 5 this near where axes 4 and 6 align leaves joints 4 and 6 a shared turn


def _split_wrist(chain: WristChain, Q: np.ndarray, hint: np.ndarray) -> np.ndarray:
    """Q (N, 6) with joints 4 and 6 re-split where axes 4 and 6 (parallel at q = 0) nearly align and the
    closed form's split leaves their limits.

    There only their sum (or difference) moves the frame much: turning joint 4 by d and joint 6 by -d (times
    the sign of w4 . w6) moves it by about |q5| d. The closed form's split is then ill-conditioned (a
    tenth of a millimetre off the wrist centre turns it by a radian), and where it leaves the limits, the split
    nearest ``hint``'s (N, 6) joint 4 that keeps both joints within them is a start for the polish."""
    sign = float(chain.w[3] @ chain.w[5])
    outside = (Q[:, [3, 5]] < chain.lower[[3, 5]] - LIMIT_SLACK) | (Q[:, [3, 5]] > chain.upper[[3, 5]] + LIMIT_SLACK)
    near = (np.abs(Q[:, 4]) < WRIST_ALIGNED) & outside.any(axis=1)  # axes 4 and 6 align at q5 = 0
    if abs(abs(sign) - 1) > 1e-6 or not near.any():
        return Q
    sign = np.sign(sign)
    lo4, hi4, lo6, hi6 = chain.lower[3], chain.upper[3], chain.lower[5], chain.upper[5]
    q4, q6 = Q[near, 3], Q[near, 5]
    # d keeps q4 + d within joint 4's limits and q6 - sign d within joint 6's
    d6 = np.sort(np.stack([sign * (q6 - hi6), sign * (q6 - lo6)]), axis=0)
    d_lo, d_hi = np.maximum(lo4 - q4, d6[0]), np.minimum(hi4 - q4, d6[1])
    d = np.clip(hint[near, 3] - q4, d_lo, np.maximum(d_lo, d_hi))
    out = Q.copy()
    out[near, 3], out[near, 5] = q4 + d, q6 - sign * d
    return out


def ik_branches(chain: WristChain, T_targets: np.ndarray, hint: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form configurations for the targets ``T_targets`` (N, 4, 4) of the chain's frame.

    Returns (Q (N, 8, 6) clipped to the joint limits, excess (N, 8): by how much (rad, summed over the
    joints) each branch left the limits beyond its slack: 0 for a branch within them, ``inf`` where the
    branch does not exist (the wrist centre out of its reach)). The slack is ``LIMIT_SLACK``, and near the
    shoulder singularity also the closed form's error there (joints 1 and 4-6). Where a joint's
    angle is free (a singular pose: the wrist centre on axis 1, or axes 4 and 6 aligned) it takes ``hint``'s
    (N, 6), the caller's current configuration. Each step runs on every branch at once (rows: target-major,
    then elbow, shoulder, wrist), so a call costs about the same for one target as for a hundred.
    """
    T = np.asarray(T_targets, dtype=np.float64).reshape(-1, 4, 4)
    n = len(T)
    hint = np.asarray(hint, dtype=np.float64).reshape(n, 6)
    w, r, c = chain.w, chain.r, chain.wrist
    g = T @ chain.T_home_inv  # e^[xi1 q1] ... e^[xi6 q6]
    c_t = g[:, :3, :3] @ c + g[:, :3, 3]  # where the wrist centre must go
    # elbows (joint 3): the wrist centre's distance from the shoulder
    q3, ok3 = sp3(w[2], r[2], np.broadcast_to(c, (n, 3)), np.broadcast_to(chain.shoulder, (n, 3)),
                  np.linalg.norm(c_t - chain.shoulder, axis=1))
    e2, q3 = np.repeat(np.arange(n), 2), q3.reshape(-1)  # rows (2N): target, elbow
    c3 = _rotate(w[2], r[2], q3, np.broadcast_to(c, (2 * n, 3)))
    # shoulders (joints 1, 2): the wrist centre to its place
    q1, q2, ok12 = sp2(w[0], w[1], chain.shoulder, c3, c_t[e2], hint[e2, 0], hint[e2, 1])
    s4, q1, q2, q3 = np.repeat(np.arange(n), 4), q1.reshape(-1), q2.reshape(-1), np.repeat(q3, 2)  # rows (4N)
    R123 = _rotation(w[0], q1) @ _rotation(w[1], q2) @ _rotation(w[2], q3)
    t123 = _rotate(w[0], r[0], q1, _rotate(w[1], r[1], q2, _rotate(w[2], r[2], q3, np.zeros((4 * n, 3)))))
    # wrists (joints 4, 5, 6): G = (e^[xi1 q1] e^[xi2 q2] e^[xi3 q3])^-1 g = e^[xi4 q4] e^[xi5 q5] e^[xi6 q6]
    Rt = np.swapaxes(R123, 1, 2)
    GR = Rt @ g[s4, :3, :3]
    Gt = (Rt @ (g[s4, :3, 3] - t123)[..., None])[..., 0]
    p6 = r[5] + 0.1 * w[5]  # a point of axis 6: joint 6 leaves it in place
    side = _cross(w[5], w[4])  # a direction off axis 6, to read joint 6's angle
    p_off = r[5] + 0.1 * side / np.linalg.norm(side)
    q4, q5, ok45 = sp2(w[3], w[4], c, np.broadcast_to(p6, (4 * n, 3)), GR @ p6 + Gt, hint[s4, 3], hint[s4, 4])
    w8, q4, q5 = np.repeat(np.arange(n), 8), q4.reshape(-1), q5.reshape(-1)  # rows (8N)
    R45 = _rotation(w[3], q4) @ _rotation(w[4], q5)
    # e^[xi6 q6] = (e^[xi4 q4] e^[xi5 q5])^-1 G; both turn about c, so it takes p to R45^T (G p - c) + c
    Hp = np.einsum("nji,nj->ni", R45, np.repeat(GR @ p_off + Gt, 2, axis=0) - c) + c
    q6 = sp1(w[5], r[5], np.broadcast_to(p_off, (8 * n, 3)), Hp, hint[w8, 5])
    Q = np.stack([np.repeat(q1, 2), np.repeat(q2, 2), np.repeat(q3, 2), q4, q5, q6], axis=1)
    Q = _split_wrist(chain, Q, hint[w8])
    ok = np.repeat(ok3, 8) & np.repeat(ok12, 4) & np.repeat(ok45, 2)
    # joint 1's angle is read off the wrist centre's direction from axis 1: the wrist's approximation
    # (``wrist_gap``) turns it by up to gap / distance, a large angle when the wrist centre nears the axis,
    # and the wrist's joints, which turn the hand back to the target's orientation, follow it by as much
    rho = np.linalg.norm(_cross(c_t - chain.shoulder, w[0]), axis=1)
    slack = np.full((8 * n, 6), LIMIT_SLACK)
    slack[:, [0, 3, 4, 5]] += np.repeat(3 * chain.wrist_gap / np.maximum(rho, 1e-9), 8)[:, None]
    Q, excess = _into_limits(Q, chain.lower, chain.upper, slack)
    return Q.reshape(n, 8, 6), np.where(ok, excess.sum(axis=1), np.inf).reshape(n, 8)

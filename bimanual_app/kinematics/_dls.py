"""Damped-least-squares IK iterations over many (seed, target) lanes at once, on numpy arrays.

Pinocchio's Python API evaluates one configuration per call, and a DLS iteration through it costs tens of
microseconds of interpreter overhead for a few microseconds of arithmetic. The grasp planner asks for
thousands of IK solves, most of which fail after every seed has stagnated, so this module runs the same
iteration for L lanes in one pass of numpy: forward kinematics of the chain to the target frame (the joint
placements and axes ``bimanual_app.robots.BatchFK`` reads from the model), the frame Jacobian in the frame's
own axes (Pinocchio's LOCAL convention) from the joint axes and origins (both checked against Pinocchio to
1e-12), the SE(3) log of the error (Pinocchio's ``log6`` formulas), and batched 6x6
solves. Hand-written for the batch dimension only; tests check each piece against Pinocchio.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ChainKinematics", "log6", "descend"]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of (..., 3) arrays (np.cross costs several times more on small batches)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


class ChainKinematics:
    """Pose and LOCAL Jacobian of one frame of a Pinocchio model (revolute / prismatic joints), batched.

    Only the joints on the path from the root to the frame move it; they form a serial chain, evaluated
    joint by joint with every lane at once (the same placements and axes ``bimanual_app.robots.BatchFK``
    reads from the model)."""

    def __init__(self, model, frame_id: int):
        from bimanual_app.robots._fk import BatchFK

        fk = BatchFK(model)
        chain, j = [], int(fk.frame_parent[frame_id])
        while j > 0:
            chain.append(j)
            j = fk.parents[j]
        chain.reverse()
        self.nv = fk.nq
        self.cols = fk.idx_q[chain]  # configuration (and Jacobian column) index of each chain joint
        self.revolute = np.array([fk.kinds[i] == "R" for i in chain])
        self.axes = fk.axes[chain]  # (C, 3) in each joint's frame
        self.M_R, self.M_t = fk.M[chain, :3, :3], fk.M[chain, :3, 3]  # placements in the parent joint's frame
        K = np.zeros((len(chain), 3, 3))
        a = self.axes
        K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -a[:, 2], a[:, 1], -a[:, 0]
        K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = a[:, 2], -a[:, 1], a[:, 0]
        self.K, self.K2 = K, K @ K  # Rodrigues: R = I + sin q K + (1 - cos q) K^2
        self.F = fk.frame_M[frame_id]

    def __call__(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Frame poses ``(L, 4, 4)`` and LOCAL Jacobians ``(L, 6, nv)`` (rows: linear, angular) for ``Q`` (L, nq)."""
        q = np.asarray(Q, dtype=np.float64)[:, self.cols]  # (L, C)
        L, C = q.shape
        rev = self.revolute
        qr = np.where(rev, q, 0.0)
        s, c = np.sin(qr)[..., None, None], (1.0 - np.cos(qr))[..., None, None]
        A = self.M_R @ (np.eye(3) + s * self.K + c * self.K2)  # (L, C, 3, 3) joint motion in the parent's frame
        t = np.broadcast_to(self.M_t, (L, C, 3))
        if not rev.all():  # prismatic joints slide along their axis
            t = t + np.einsum("cij,cj,lc->lci", self.M_R, self.axes, np.where(rev, 0.0, q))
        Rw = np.empty((L, C, 3, 3))
        pw = np.empty((L, C, 3))
        R, p = np.broadcast_to(np.eye(3), (L, 3, 3)), np.zeros((L, 3))
        for i in range(C):
            p = p + (R @ t[:, i, :, None])[..., 0]
            R = R @ A[:, i]
            Rw[:, i], pw[:, i] = R, p
        Rf = R @ self.F[:3, :3]
        pf = p + R @ self.F[:3, 3]
        w = (Rw @ self.axes[:, :, None])[..., 0]  # joint axes in the base frame
        lin = np.where(rev[None, :, None], _cross(w, pf[:, None] - pw), w)
        ang = np.where(rev[None, :, None], w, 0.0)
        J = np.zeros((L, 6, self.nv))
        Rt = np.swapaxes(Rf, 1, 2)
        J[:, :3, self.cols] = Rt @ np.swapaxes(lin, 1, 2)  # in the frame's own axes (LOCAL)
        J[:, 3:, self.cols] = Rt @ np.swapaxes(ang, 1, 2)
        Tf = np.zeros((L, 4, 4))
        Tf[:, :3, :3], Tf[:, :3, 3], Tf[:, 3, 3] = Rf, pf, 1.0
        return Tf, J


def _log3(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation vectors (L, 3) and angles (L,) of rotations R (L, 3, 3) (Pinocchio's ``log3``)."""
    tr = np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(tr)
    vee = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    s = np.sin(theta)
    small = theta < 1e-4
    near_pi = theta > np.pi - 1e-3
    f = np.where(small, 0.5 + theta ** 2 / 12.0, theta / (2.0 * np.where(small | near_pi, 1.0, s)))
    w = f[:, None] * vee
    if near_pi.any():
        # about a half turn the antisymmetric part vanishes: the axis from R + R^T = 2 (I + (1 - c) a a^T - ...)
        Rp = R[near_pi]
        th = theta[near_pi]
        c = np.cos(th)
        d = np.clip((np.diagonal(Rp, axis1=1, axis2=2) - c[:, None]) / (1.0 - c[:, None]), 0.0, None)
        a = np.sqrt(d)
        # signs: relative to the largest component, from the symmetric off-diagonal terms, and overall from vee
        k = np.argmax(a, axis=1)
        sym = Rp + np.swapaxes(Rp, 1, 2)
        rows = sym[np.arange(len(k)), k]  # (P, 3): 2 (1 - c) a_k a_j off the diagonal
        sgn = np.where(rows >= 0, 1.0, -1.0)
        sgn[np.arange(len(k)), k] = 1.0
        a = a * sgn
        v = vee[near_pi]
        flip = np.einsum("pi,pi->p", a, v) < 0
        a[flip] *= -1.0
        w[near_pi] = a * th[:, None]
    return w, theta


def log6(T: np.ndarray) -> np.ndarray:
    """Twists (L, 6) (linear, angular) of rigid transforms T (L, 4, 4): Pinocchio's ``log6``."""
    w, theta = _log3(T[:, :3, :3])
    p = T[:, :3, 3]
    small = theta < 1e-4
    th = np.where(small, 1.0, theta)
    one_minus_c = np.where(small, 1.0, 1.0 - np.cos(th))
    alpha = np.where(small, 1.0 - theta ** 2 / 12.0 - theta ** 4 / 720.0, th * np.sin(th) / (2.0 * one_minus_c))
    beta = np.where(small, 1.0 / 12.0 + theta ** 2 / 720.0,
                    1.0 / th ** 2 - np.sin(th) / (2.0 * th * one_minus_c))
    v = alpha[:, None] * p - 0.5 * _cross(w, p) + (beta * (w * p).sum(axis=1))[:, None] * w
    return np.concatenate([v, w], axis=1)


def _position_error(Tf: np.ndarray, Jfull: np.ndarray, targets: np.ndarray, tp2: float, tr2: float) -> tuple:
    """Position-only error of frames ``Tf`` (L, 4, 4) against ``targets`` (L, 4, 4), in the frame's axes:
    (e (L, 3), |e_pos|^2, |e_rot|^2 (zeros), done (L,), Jacobian rows (L, 3, J), |e|^2)."""
    d = targets[:, :3, 3] - Tf[:, :3, 3]
    e = (np.swapaxes(Tf[:, :3, :3], 1, 2) @ d[..., None])[..., 0]  # in the frame's axes (Jacobian rows 0..2)
    e_p2 = (e * e).sum(axis=1)
    e_r2 = np.zeros(len(Tf))
    return e, e_p2, e_r2, e_p2 < tp2, Jfull[:, :3], e_p2


def _pose_error(Tf: np.ndarray, Jfull: np.ndarray, targets: np.ndarray, tp2: float, tr2: float) -> tuple:
    """Full-pose error (SE(3) log of Tf^-1 Tt) of frames ``Tf`` (L, 4, 4) against ``targets`` (L, 4, 4):
    (e (L, 6), |e_pos|^2, |e_rot|^2, done (L,), Jacobian (L, 6, J), |e|^2)."""
    dM = np.zeros_like(targets)  # the target in the frame's own axes: Tf^-1 Tt
    Rt = np.swapaxes(Tf[:, :3, :3], 1, 2)
    dM[:, :3, :3] = Rt @ targets[:, :3, :3]
    dM[:, :3, 3] = (Rt @ (targets[:, :3, 3] - Tf[:, :3, 3])[..., None])[..., 0]
    dM[:, 3, 3] = 1.0
    e = log6(dM)
    t = dM[:, :3, 3]
    e_p2 = (t * t).sum(axis=1)
    e_r2 = (e[:, 3:] * e[:, 3:]).sum(axis=1)
    return e, e_p2, e_r2, (e_p2 < tp2) & (e_r2 < tr2), Jfull, (e * e).sum(axis=1)


def _limited_step(q: np.ndarray, e: np.ndarray, Jr: np.ndarray, ee: np.ndarray, lower: np.ndarray,
                  upper: np.ndarray, damping: float, far_damping: float, max_step: float,
                  eye: np.ndarray) -> np.ndarray:
    """The next configurations (L, J): a damped step, capped far from the solution, kept within the limits."""
    lam = damping + far_damping * ee
    dq = _step(Jr, e, lam, eye)
    far = ee > 1e-2  # far from the solution: cap the step (near it the full step is small anyway)
    n = np.abs(dq).max(axis=1)
    scale = np.where(far & (n > max_step), max_step / np.where(n > 0, n, 1.0), 1.0)
    dq *= scale[:, None]
    qn = q + dq
    qc = np.minimum(np.maximum(qn, lower), upper)
    clipped = (qc != qn).any(axis=1)
    blocked = ((q <= lower) & (dq < 0)) | ((q >= upper) & (dq > 0))
    redo = clipped & blocked.any(axis=1)
    if redo.any():
        # joints already on a limit and pushed outwards are frozen and the step re-solved with the others;
        # the rest are clipped (overshooting joints land on the limit)
        Jb = Jr[redo] * ~blocked[redo][:, None, :]
        dq2 = _step(Jb, e[redo], lam[redo], eye)
        n2 = np.abs(dq2).max(axis=1)
        dq2 *= np.where(n2 > max_step, max_step / np.where(n2 > 0, n2, 1.0), 1.0)[:, None]
        qc[redo] = np.minimum(np.maximum(q[redo] + dq2, lower), upper)
    return qc


def descend(kin: ChainKinematics, Q: np.ndarray, targets: np.ndarray, lower: np.ndarray, upper: np.ndarray,
            position_only: bool, tol_pos: float, tol_rot: float, max_iter: int, damping: float, far_damping: float,
            max_step: float, tail=None, tail_lanes: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """DLS from seeds ``Q`` (L, J) towards ``targets`` (L, 4, 4) (only their translation when
    ``position_only``); every lane follows the single-seed iteration of ``IKSolver``:

    a full step (capped at ``max_step`` per joint far from the solution), lambda^2 = damping + far_damping
    |e|^2, joints on a limit that are pushed outwards frozen for the step (an active set), the rest clipped
    to the limits; a lane stops when within (tol_pos, tol_rot), or when its error (|e_pos|^2 + 0.01
    |e_rot|^2) has not fallen below 0.64 x its value 9 iterations before (after 15 iterations).

    Returns (Q (L, J), position error (L,), rotation error (L,), iterations (L,)); a lane that ran out of
    iterations returns its last configuration with the error measured before its last step.

    ``tail(lane, q, it, history)``, when given, finishes the last ``tail_lanes`` or fewer live lanes one by
    one from iteration ``it`` (``history``: their errors so far, iterations 1..it-1) and returns (q, position
    error, rotation error, iterations): a few slow lanes would otherwise keep the whole batch iterating at the
    cost of many.
    """
    Q = np.array(Q, dtype=np.float64)
    L, nj = Q.shape
    m = 3 if position_only else 6
    eye = np.eye(m)
    targets = np.asarray(targets, dtype=np.float64)
    tp2, tr2 = tol_pos ** 2, tol_rot ** 2
    error = _position_error if position_only else _pose_error
    ep2 = np.full(L, np.inf)
    er2 = np.full(L, np.inf) if not position_only else np.zeros(L)
    iters = np.zeros(L, dtype=int)
    hist = np.full((max_iter + 1, L), np.inf)
    live = np.arange(L)
    for it in range(1, max_iter + 1):
        if tail is not None and it > 1 and len(live) <= tail_lanes:
            for lane in live:
                Q[lane], ep, er, iters[lane] = tail(int(lane), Q[lane], it, hist[1:it, lane])
                ep2[lane], er2[lane] = ep ** 2, er ** 2
            break
        q = Q[live]
        Tf, Jfull = kin(q)
        iters[live] = it
        e, e_p2, e_r2, done, Jr, ee = error(Tf, Jfull, targets[live], tp2, tr2)
        ep2[live], er2[live] = e_p2, e_r2
        score = e_p2 + 0.01 * e_r2
        hist[it, live] = score
        stuck = (score > 0.64 * hist[it - 9, live]) if it > 15 else np.zeros(len(live), dtype=bool)
        go = ~(done | stuck)
        if not go.any():
            break
        live, q, e, Jr, ee = live[go], q[go], e[go], Jr[go], ee[go]
        Q[live] = _limited_step(q, e, Jr, ee, lower, upper, damping, far_damping, max_step, eye)
    return Q, np.sqrt(ep2), np.sqrt(er2), iters


def _step(Jr: np.ndarray, e: np.ndarray, lam: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """dq (L, J) = J^T (J J^T + lam I)^-1 e for Jacobians Jr (L, m, J), errors e (L, m), dampings lam (L,)."""
    A = Jr @ np.swapaxes(Jr, 1, 2) + lam[:, None, None] * eye
    x = np.linalg.solve(A, e[..., None])[..., 0]
    return (np.swapaxes(Jr, 1, 2) @ x[..., None])[..., 0]

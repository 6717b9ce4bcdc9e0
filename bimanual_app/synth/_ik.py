"""Inverse kinematics of one arm for the synthetic capture, on the project's robot model (Pinocchio).

Damped least squares on the flange pose error ``log6(T_b_e(q)^-1 T_target)`` with the analytic
Pinocchio Jacobian, joints clipped to their limits at every step, several starts. Pinocchio has no
bounded IK solver of its own and PyBullet's ``calculateInverseKinematics`` ignores the limits of a
6-DoF arm unless given null-space terms that bias the solution, hence this short loop (its answer is
always re-checked by forward kinematics before use).
"""

from __future__ import annotations

import numpy as np


def solve_ik(robot, T_b_e: np.ndarray, seeds: np.ndarray, iters: int = 80, damping: float = 1e-4,
             pos_tol: float = 1e-4, rot_tol: float = 1e-3) -> tuple[np.ndarray | None, float, float]:
    """Joint angles reaching the flange pose ``T_b_e`` (4, 4) of ``robot`` (a RobotModel).

    Args:
        seeds: (S, J) start configurations, tried in order.
    Returns:
        ``(q, pos_err_m, rot_err_rad)``: the best configuration (J,) inside the limits (None when no start
        converged within 5 mm / 2 degrees) and its remaining errors.
    """
    import pinocchio as pin

    model = robot.model
    data = model.createData()
    fid = robot.frame_id(robot.ee_link)
    J = robot.nq_arm
    target = pin.SE3(np.asarray(T_b_e[:3, :3], dtype=np.float64), np.asarray(T_b_e[:3, 3], dtype=np.float64))
    best = (None, np.inf, np.inf)
    damp = damping * np.eye(6)
    lo, hi = robot.lower, robot.upper
    for q0 in np.atleast_2d(seeds):
        q = robot.full_q(np.clip(q0, lo, hi))
        prev = np.inf
        for it in range(iters):
            pin.framesForwardKinematics(model, data, q)
            err = pin.log6(data.oMf[fid].actInv(target)).vector  # twist (v, w) in the flange frame
            ep, er = np.sqrt(err[:3] @ err[:3]), np.sqrt(err[3:] @ err[3:])
            if ep < pos_tol and er < rot_tol:
                break
            if it % 10 == 9:  # stuck against the limits or in a local minimum: next start
                cost = ep + 0.1 * er
                if cost > 0.9 * prev and cost > 5e-3:
                    break
                prev = cost
            Jac = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL)[:, :J]
            dq = Jac.T @ np.linalg.solve(Jac @ Jac.T + damp, err)
            step = np.sqrt(dq @ dq)
            if step > 0.5:  # trust region: big jumps overshoot near singularities
                dq *= 0.5 / step
            q[:J] = np.minimum(np.maximum(q[:J] + dq, lo), hi)
        pin.framesForwardKinematics(model, data, q)
        err = pin.log6(data.oMf[fid].actInv(target)).vector
        pe, re = float(np.linalg.norm(err[:3])), float(np.linalg.norm(err[3:]))
        if pe + 0.1 * re < best[1] + 0.1 * best[2]:
            best = (q[:J].copy(), pe, re)
        if pe < pos_tol and re < rot_tol:
            break
    q, pe, re = best
    if q is None or pe > 5e-3 or re > np.deg2rad(2.0):
        return None, pe, re
    return q, pe, re

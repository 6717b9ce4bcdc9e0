"""Inverse kinematics: closed-form branches polished by damped least squares, or DLS from several seeds.

For an arm with a wrist centre (six revolute joints, axes 1-2 and 4-5-6 meeting: the Piper), the seeds after
the current configuration are the closed-form branches of ``_analytic`` (up to eight; those within the joint
limits, nearest to the current configuration first, at most ``max_seeds - 1``), each polished by the DLS
iteration below in one or two steps (the real wrist's axes meet only to a fraction of a millimetre). The
branches are every solution there is (up to the closed form's error, which ``_analytic`` allows for at the
limits), so a target whose branches all leave the limits, or whose wrist centre is out of reach, fails
without further seeds. The current
configuration stays first: a move continued step by step keeps its branch through the singularities, where
the closed form's free angle is ill-conditioned. Other chains, position-only targets and callers with seeds of
their own use the DLS seeds below.

One DLS solve runs Levenberg-Marquardt style damped least squares on the SE(3) log error of the target link
(the frame Jacobian in its LOCAL axes and ``log6``, as Pinocchio defines them), a full step (1.0, capped in
size far from the solution), with joints that sit on a limit and are pushed outwards frozen for the step (an
active set), and the result clipped to the limits. A seed whose error stops shrinking is abandoned early.
Seeds, in order: the current configuration, then the configurations of a precomputed table of FK samples
whose tool poses are nearest to the target (scipy cKDTree), then uniform random ones; a caller with better
starts of its own (the capture planner, which knows the arm's usual poses) passes them as ``seeds`` instead
of the table's and the random ones. Every converged, distinct solution is kept; they are returned sorted by
joint-space distance to the current configuration, so the closest comes first. A target beyond the arm's
reach (checked against the largest shoulder-to-tool distance of the table, with a margin) fails at once
without iterating.

``solve_many`` runs the seeds of many targets together, vectorised over (target, seed) lanes (``_dls``):
the grasp planner's thousands of queries, most of them failing after every seed, cost one numpy pass per
iteration instead of one interpreter round trip per seed and iteration.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field

import numpy as np

from bimanual_app.transforms import check_shape, check_T

from ._analytic import ik_branches, wrist_chain
from ._dls import ChainKinematics, descend

__all__ = ["IKResult", "IKSolver"]


@dataclass
class IKResult:
    """Result of one IK query.

    success: a solution within tolerance was found.
    q: (J,) the solution closest to the current configuration (None on failure).
    solutions: (K, J) all distinct solutions found, sorted by distance to the current configuration.
    pos_error, rot_error: residual of ``q`` (m, rad); of the best attempt when it failed.
    iterations: DLS iterations over all seeds; seeds: seeds tried.
    message: why it failed ('' on success).
    """

    success: bool
    q: np.ndarray | None
    solutions: np.ndarray
    pos_error: float
    rot_error: float
    iterations: int
    seeds: int
    message: str = ""
    best_attempt: np.ndarray | None = field(default=None, repr=False)


class IKSolver:
    """Damped-least-squares IK for one link of one robot (default: the gripper frame, else the ee link).

    Args:
        robot: a ``bimanual_app.robots.RobotModel``.
        link: target link or frame (default ``robot.tcp_link`` or ``robot.ee_link``).
        tol_pos, tol_rot: convergence tolerance (m, rad).
        max_iter: DLS iterations per seed.
        damping: base damping lambda^2; ``far_damping`` * |error|^2 is added (Levenberg-Marquardt style).
        max_step: largest joint change per iteration (rad); the step is 1.0 below it.
        table_size: FK samples used for nearest-pose seeding.
        opening: gripper opening used for the finger joints (they do not move the target frames).
    """

    def __init__(self, robot, link: str | None = None, tol_pos: float = 1e-4, tol_rot: float = 1e-3,
                 max_iter: int = 60, damping: float = 1e-6, far_damping: float = 1e-2, max_step: float = 0.5,
                 table_size: int = 10000, opening: float = 0.0, seed: int = 0):
        import pinocchio as pin

        self.robot = robot
        self.link = link or robot.tcp_link or robot.ee_link
        robot.frame_id(self.link)  # raises for unknown links
        finger_ids = [robot.model.getJointId(n) for n in robot.finger_joints]
        q_ref = robot.full_q(robot.neutral(), opening)
        self.model = pin.buildReducedModel(robot.model, finger_ids, q_ref) if finger_ids else robot.model
        self.data = self.model.createData()
        self.fid = self.model.getFrameId(self.link)
        self.lower, self.upper = robot.lower.copy(), robot.upper.copy()
        self.tol_pos, self.tol_rot = tol_pos, tol_rot
        self.max_iter, self.damping = max_iter, damping
        self.far_damping = far_damping  # lambda^2 += far_damping * |error|^2
        self.n_near = 12  # nearest-pose seeds from the table, tried after the current configuration
        self.max_step = max_step  # rad per iteration, largest joint change
        self._rng = np.random.default_rng(seed)
        self._pin = pin
        from scipy.linalg import lapack

        self._dposv = lapack.dposv  # a 6x6 SPD solve: 1 us against np.linalg.solve's 4-6 us
        self._eye3, self._eye6 = np.eye(3), np.eye(6)
        self._kin = ChainKinematics(self.model, self.fid)
        # the closed-form branches (``_analytic``) when the chain has a wrist centre, else None
        self.chain = wrist_chain(self._kin, self.lower, self.upper)

        # nearest-pose seed table, and the arm's reach from the first joint to move the target in space
        self._rot_weight = 0.15  # metres per unit of rotation-matrix difference in the seed metric
        (self._table_q, self._table_pos, self._pose_tree, self._pos_tree, self._shoulder,
         self.reach) = _seed_table(robot, self.link, table_size, opening, seed, self._rot_weight)

    # ------------------------------------------------------------------ one seed
    def _descend_one(self, q: np.ndarray, target, position_only: bool, first: int = 1,
                     history: list[float] | None = None) -> tuple[np.ndarray, float, float, int]:
        """DLS from seed ``q`` (J,) to ``target`` (pinocchio SE3, or (3,) when ``position_only``); returns (q,
        position error, rotation error, iterations). The iteration of ``_dls.descend`` for one lane, on
        Pinocchio's C++ kinematics: one lane through numpy costs about five times as much per iteration (its
        per-call overhead), many lanes far less per lane; ``_run_lanes`` picks by the number of lanes.
        ``first`` and ``history`` continue a lane that ``_dls.descend`` started: the iteration to start at and
        the errors (``|e_pos|^2 + 0.01 |e_rot|^2``) of the iterations before it."""
        pin, dposv = self._pin, self._dposv
        # the Pinocchio and numpy calls bound to locals: this loop runs some 10^5 iterations per grasp stage,
        # where each attribute lookup is a measurable share of a 15 us iteration
        jacobians, place, frame_jacobian, log6 = (pin.computeJointJacobians, pin.updateFramePlacement,
                                                 pin.getFrameJacobian, pin.log6)
        minimum, maximum = np.minimum, np.maximum
        model, data, fid, LOCAL = self.model, self.data, self.fid, pin.LOCAL
        lower, upper = self.lower, self.upper
        damping, far_damping, max_step = self.damping, self.far_damping, self.max_step
        eye = self._eye3 if position_only else self._eye6
        tp2, tr2 = self.tol_pos ** 2, self.tol_rot ** 2
        history = [] if history is None else list(history)
        ep2 = er2 = np.inf
        for it in range(first, self.max_iter + 1):
            jacobians(model, data, q)  # forward kinematics and joint Jacobians in one pass
            cur = place(model, data, fid)
            J = frame_jacobian(model, data, fid, LOCAL)
            if position_only:
                e = cur.rotation.T @ (target - cur.translation)  # in the frame's axes, like LOCAL rows 0..2
                ep2, er2 = float(e @ e), 0.0
                if ep2 < tp2:
                    return q, np.sqrt(ep2), 0.0, it
                Jr = J[:3]
                ee = ep2
            else:
                dM = cur.actInv(target)
                e = log6(dM).vector
                t = dM.translation
                w = e[3:]
                ep2, er2 = float(t @ t), float(w @ w)
                if ep2 < tp2 and er2 < tr2:
                    return q, np.sqrt(ep2), np.sqrt(er2), it
                # J maps joint rates to the frame's twist; the log's own Jacobian (Jlog6) is the identity at
                # the solution and changed neither the iteration count nor the success rate in tests, so it
                # is left out (2 us per iteration)
                Jr = J
                ee = float(e @ e)
            # stagnation: stuck against a limit or in a local minimum -> give up this seed early
            score = ep2 + 0.01 * er2
            history.append(score)
            if it > 15 and score > 0.64 * history[-10]:
                break
            lam = damping + far_damping * ee  # more damping far from the solution
            _, x, _ = dposv(Jr @ Jr.T + lam * eye, e)
            dq = Jr.T @ x
            if ee > 1e-2:  # far from the solution: cap the step (near it the full step is small anyway)
                n = max(map(abs, dq.tolist()))  # = abs(dq).max() for a finite step; 3x faster on 6 numbers
                if n > max_step:
                    dq *= max_step / n
            qn = q + dq
            qc = minimum(maximum(qn, lower), upper)
            if qc.tolist() != qn.tolist():  # = (qc != qn).any(), NaN included, at a third of its cost
                # joints already on a limit and pushed outwards are frozen and the step is re-solved with
                # the others (an active set); the rest are clipped (overshooting joints land on the limit)
                blocked = ((q <= lower) & (dq < 0)) | ((q >= upper) & (dq > 0))
                if blocked.any():
                    Jr = Jr * ~blocked
                    _, x, _ = dposv(Jr @ Jr.T + lam * eye, e)
                    dq = Jr.T @ x
                    n = abs(dq).max()
                    if n > max_step:
                        dq *= max_step / n
                    qc = minimum(maximum(q + dq, lower), upper)
            q = qc
        return q, float(np.sqrt(ep2)), float(np.sqrt(er2)), it

    BATCH_MIN = 16  # lanes from which one numpy pass beats a Pinocchio loop (measured: 12-16 on 2 loaded cores)

    # ------------------------------------------------------------------ public
    def solve(self, T_target: np.ndarray, q_current: np.ndarray | None = None, position_only: bool = False,
              n_solutions: int = 1, max_seeds: int = 16, seeds: np.ndarray | None = None) -> IKResult:
        """IK for ``T_target`` (4,4) = pose of ``self.link`` in the robot's base frame.

        ``position_only`` uses only ``T_target[:3, 3]``. Stops after ``n_solutions`` distinct solutions or
        ``max_seeds`` seeds (closed-form branches, or DLS starts: see the module docstring). Solutions lie
        within the joint limits. ``seeds`` (S, J): the starts tried after ``q_current``, in order, instead of
        the closed-form branches or the table's nearest poses and random ones.
        """
        T_target = np.asarray(T_target, dtype=np.float64)
        if T_target.shape != (4, 4) or not np.all(np.isfinite(T_target)):
            T_target = check_T("T_target", T_target)  # raises with the reason
        return self.solve_many(T_target[None], q_current, position_only, n_solutions, max_seeds, seeds)[0]

    def solve_many(self, T_targets: np.ndarray, q_current: np.ndarray | None = None, position_only: bool = False,
                   n_solutions: int = 1, max_seeds: int = 16, seeds: np.ndarray | None = None,
                   screen: bool = False) -> list[IKResult]:
        """IK for each of ``T_targets`` (N, 4, 4), from ``q_current`` (J,) or one per target (N, J); one
        ``IKResult`` per target, each the one ``solve`` gives for that target alone. ``seeds`` (S, J), when
        given, are every target's further starts (clipped to the limits; at most ``max_seeds - 1`` of them).

        The seeds of all targets descend together (``_dls.descend``): first every target's current
        configuration, then, for the targets that still lack solutions, all their remaining seeds at once
        (the solutions are then taken in seed order, as one target's sequential search would).

        ``screen`` (a chain with a closed form, full poses, no ``seeds``): the closed-form branches of all the
        targets come first, and a target none of whose branches lies within the joint limits fails without
        any descent (the same outcome: the branches are every solution there is). For a batch of targets
        far from the current configuration, most of them unreachable (the grasp planner's first check of
        its candidates), that saves their failing descents; for one target near it the descent is cheaper.
        """
        T = np.asarray(T_targets, dtype=np.float64).reshape(-1, 4, 4)
        n, J = len(T), self.robot.nq_arm
        if not np.all(np.isfinite(T)):
            raise ValueError("T_targets: non-finite values")
        qc = self.robot.neutral() if q_current is None else np.asarray(q_current, dtype=np.float64)
        if qc.shape == (J,):
            qc = np.broadcast_to(qc, (n, J))
        if qc.shape != (n, J):
            raise ValueError(f"q_current: expected shape ({J},) or ({n}, {J}), got {np.shape(q_current)}")
        qc = np.clip(qc, self.lower, self.upper)
        if seeds is not None:
            seeds = check_shape("seeds", np.asarray(seeds, dtype=np.float64), (None, J))
        dist, far = self._far(T)
        seeds_of: list[list[np.ndarray]] = [[qc[i]] for i in range(n)]  # per target, its starts in order
        runs: list[list[tuple]] = [[] for _ in range(n)]  # per target: (q, ep, er, iterations) per seed tried
        why: list[str] = [""] * n  # per target, when not empty: why no (further) seed was tried
        known = {}  # target -> its closed-form branches, when already computed
        if screen and self.chain is not None and not position_only and seeds is None:
            known = self._ruled_out(T, qc, far, why)  # no seed at all for those: failed with that message
        live = [i for i in range(n) if not far[i] and not why[i]]
        self._run_lanes([(i, 0) for i in live], seeds_of, runs, T, position_only, n_solutions)
        more = [i for i in live if max_seeds > 1 and self._n_sols(runs[i]) < n_solutions]
        if more and seeds is not None:
            given = list(np.clip(seeds, self.lower, self.upper)[:max_seeds - 1])
            for i in more:
                seeds_of[i] += given
            self._run_lanes([(i, k) for i in more for k in range(1, len(seeds_of[i]))], seeds_of, runs, T,
                            position_only, n_solutions)
        elif more and self.chain is not None and not position_only:
            self._closed_form_lanes(more, T, qc, seeds_of, runs, n_solutions, max_seeds, why, known)
        elif more:
            p = T[more, :3, 3]
            if position_only:
                _, idx = self._pos_tree.query(p, k=self.n_near)
            else:
                feats = np.concatenate([p, self._rot_weight * T[more, :3, :3].reshape(-1, 9)], axis=1)
                _, idx = self._pose_tree.query(feats, k=self.n_near)
            idx = np.asarray(idx).reshape(len(more), -1)
            lanes = []
            for r, i in enumerate(more):
                seeds_of[i] += [self._table_q[j] for j in idx[r]]
                extra = max_seeds - len(seeds_of[i])
                if extra > 0:  # beyond the table's nearest poses: uniform random seeds
                    seeds_of[i] += list(self.robot.random_q(extra, rng=self._rng))
                lanes += [(i, k) for k in range(1, min(max_seeds, len(seeds_of[i])))]
            self._run_lanes(lanes, seeds_of, runs, T, position_only, n_solutions)
        return self._results(T, qc, far, dist, runs, n_solutions, why)

    def screen(self, T_targets: np.ndarray, hint: np.ndarray) -> list[str] | None:
        """Which of the targets ``T_targets`` (N, 4, 4) have no solution, without any descent: per target ''
        where a closed-form branch lies within the joint limits (a solve may still fail, e.g. from seeds that
        do not converge), else why there is none -- the message a failed ``solve`` gives. ``hint`` (J,) or
        (N, J): the free angles at singular poses (the caller's current configuration). None for a chain
        without a closed form (nothing can be ruled out cheaply)."""
        if self.chain is None:
            return None
        T = np.asarray(T_targets, dtype=np.float64).reshape(-1, 4, 4)
        n, J = len(T), self.robot.nq_arm
        qc = np.clip(np.broadcast_to(np.asarray(hint, dtype=np.float64), (n, J)), self.lower, self.upper)
        dist, far = self._far(T)
        why = [self._far_message(T[i], dist[i]) if far[i] else "" for i in range(n)]
        self._ruled_out(T, qc, far, why)
        return why

    def _far(self, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance from the shoulder (N,), beyond the arm's reach (N,) bool) of targets T (N, 4, 4): those
        fail at once."""
        dist = np.linalg.norm(T[:, :3, 3] - self._shoulder, axis=1)
        return dist, dist > self.reach * 1.03 + 0.01

    def _ruled_out(self, T: np.ndarray, qc: np.ndarray, far: np.ndarray, why: list[str]) -> dict:
        """The closed-form branches of the targets T (N, 4, 4) within reach (not ``far``), hints ``qc`` (N, J);
        sets ``why[i]`` for each target none of whose branches lies within the limits. Returns the branches
        by target (``_branches``)."""
        known = self._branches([i for i in range(len(T)) if not far[i]], T, qc)
        for i, (_, excess) in known.items():
            if not (excess == 0).any():
                why[i] = _no_branch_message(excess)
        return known

    def _results(self, T: np.ndarray, qc: np.ndarray, far: np.ndarray, dist: np.ndarray, runs: list,
                 n_solutions: int, why: list[str]) -> list[IKResult]:
        """One IKResult per target from its seeds' outcomes ``runs``; ``why[i]``, when not empty, is a failed
        target's message."""
        out, J = [], self.robot.nq_arm
        for i in range(len(T)):
            if far[i]:
                out.append(IKResult(False, None, np.zeros((0, J)), np.inf, np.inf, 0, 0,
                                    self._far_message(T[i], dist[i])))
                continue
            res = self._collect(runs[i], qc[i], n_solutions)
            if not res.success and why[i]:
                res.message = why[i]
            out.append(res)
        return out

    def _far_message(self, T: np.ndarray, dist: float) -> str:
        """Why a target T (4, 4) ``dist`` metres from the shoulder fails at once."""
        return (f"target {np.round(T[:3, 3], 3).tolist()} is {dist:.3f} m from the shoulder; "
                f"the arm reaches about {self.reach:.3f} m")

    def _branches(self, todo: list[int], T: np.ndarray, qc: np.ndarray) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """Target -> its closed-form branches (Q (8, J), excess (8,); ``_analytic.ik_branches``), for ``todo``."""
        if not todo:
            return {}
        Q, excess = ik_branches(self.chain, T[todo], qc[todo])
        return {i: (Q[r], excess[r]) for r, i in enumerate(todo)}

    def _closed_form_lanes(self, todo: list[int], T: np.ndarray, qc: np.ndarray, seeds_of: list, runs: list,
                           n_solutions: int, max_seeds: int, why: list[str], known: dict) -> None:
        """Polish the closed-form branches (``_analytic``) of the targets ``todo`` (their seeds after the current
        configuration): those within the joint limits, nearest to the current configuration first, at most
        ``max_seeds - 1``, all together by the DLS iteration. Sets ``why[i]`` for a target none was tried for:
        the branches are all the solutions there are, so such a target fails without more seeds. ``known``:
        branches already computed (by target)."""
        branches = {**known, **self._branches([i for i in todo if i not in known], T, qc)}
        lanes = []
        for i in todo:
            Q, excess = branches[i]
            ok = excess == 0
            order = np.argsort(np.where(ok, np.linalg.norm(Q - qc[i], axis=1), np.inf), kind="stable")
            starts = [Q[b] for b in order[:max_seeds - 1] if ok[b]]
            lanes += [(i, len(seeds_of[i]) + k) for k in range(len(starts))]
            seeds_of[i] = seeds_of[i] + starts
            if not starts:
                why[i] = _no_branch_message(excess)
        self._run_lanes(lanes, seeds_of, runs, T, False, n_solutions)

    def _n_sols(self, runs: list[tuple]) -> int:
        """Distinct solutions among a target's seed outcomes."""
        sols: list[np.ndarray] = []
        for q, ep, er, _ in runs:
            if ep < self.tol_pos and er < self.tol_rot and not any(np.abs(q - s).max() < 1e-3 for s in sols):
                sols.append(q)
        return len(sols)

    def _run_lanes(self, lanes: list[tuple[int, int]], seeds, runs, T: np.ndarray, position_only: bool,
                   n_solutions: int) -> None:
        """Descend every (target, seed index) lane at once and append each lane's outcome to ``runs``."""
        if not lanes:
            return
        if len(lanes) < self.BATCH_MIN:
            for i, k in lanes:  # in seed order; a target stops at its n_solutions, as a sequential search does
                if self._n_sols(runs[i]) >= n_solutions:
                    continue
                Ti = T[i]
                goal = Ti[:3, 3].copy() if position_only else self._pin.SE3(Ti[:3, :3].copy(), Ti[:3, 3].copy())
                runs[i].append(self._descend_one(seeds[i][k].copy(), goal, position_only))
            return
        Q0 = np.stack([seeds[i][k] for i, k in lanes])
        Tl = T[[i for i, _ in lanes]]

        def tail(lane: int, q: np.ndarray, first: int, history: np.ndarray):
            Ti = Tl[lane]
            goal = Ti[:3, 3].copy() if position_only else self._pin.SE3(Ti[:3, :3].copy(), Ti[:3, 3].copy())
            return self._descend_one(q.copy(), goal, position_only, first, history.tolist())

        Q, ep, er, it = descend(self._kin, Q0, Tl, self.lower, self.upper, position_only, self.tol_pos, self.tol_rot,
                                self.max_iter, self.damping, self.far_damping, self.max_step,
                                tail=tail, tail_lanes=self.BATCH_MIN // 2)
        for r, (i, _) in enumerate(lanes):
            runs[i].append((Q[r], float(ep[r]), float(er[r]), int(it[r])))

    def _collect(self, runs: list[tuple], q_current: np.ndarray, n_solutions: int) -> IKResult:
        """One target's result from its seeds' outcomes, in seed order, stopping at ``n_solutions``."""
        sols: list[np.ndarray] = []
        errs: list[tuple[float, float]] = []
        best = (np.inf, np.inf, None)
        iters = k = 0
        for q, ep, er, it in runs:
            if len(sols) >= n_solutions:
                break
            k += 1
            iters += it
            if ep < self.tol_pos and er < self.tol_rot:
                if not any(np.abs(q - s).max() < 1e-3 for s in sols):
                    sols.append(q)
                    errs.append((ep, er))
            elif ep + 0.1 * er < best[0] + 0.1 * best[1]:
                best = (ep, er, q)
        J = self.robot.nq_arm
        if not sols:
            return IKResult(False, None, np.zeros((0, J)), best[0], best[1], iters, k,
                            f"no IK solution within the joint limits after {k} seeds "
                            f"(best: {best[0] * 1e3:.1f} mm, {np.degrees(best[1]):.1f} deg off)",
                            best_attempt=best[2])
        if len(sols) == 1:
            return IKResult(True, sols[0], sols[0][None], errs[0][0], errs[0][1], iters, k)
        order = np.argsort(np.linalg.norm(np.stack(sols) - q_current, axis=1))
        S = np.stack(sols)[order]
        return IKResult(True, S[0].copy(), S, errs[order[0]][0], errs[order[0]][1], iters, k)

    def error(self, q: np.ndarray, T_target: np.ndarray, position_only: bool = False) -> tuple[float, float]:
        """(position error m, rotation error rad) of configuration ``q`` (J,) against ``T_target``."""
        T = self.robot.fk_link(q, self.link)
        ep = float(np.linalg.norm(T[:3, 3] - T_target[:3, 3]))
        if position_only:
            return ep, 0.0
        R = T[:3, :3].T @ T_target[:3, :3]
        return ep, float(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)))


_TABLES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _seed_table(robot, link: str, size: int, opening: float, seed: int, rot_weight: float) -> tuple:
    """(table_q (size, J), tool positions (size, 3), pose KD-tree, position KD-tree, shoulder (3,), reach m): FK
    samples of the arm for nearest-pose seeds, built once per robot model and parameters in a process (every
    IKSolver of the grasp and task stages of one ``bijcr run`` shares them)."""
    from scipy.spatial import cKDTree

    per_robot = _TABLES.setdefault(robot, {})
    key = (link, int(size), float(opening), int(seed), float(rot_weight))
    if key not in per_robot:
        table_q = robot.random_q(size, rng=seed)
        T = robot.fk_link(table_q, link, opening=opening)
        pos = T[:, :3, 3].copy()
        pose_tree = cKDTree(np.concatenate([pos, rot_weight * T[:, :3, :3].reshape(-1, 9)], 1))
        origins = robot.joint_placements(robot.full_q(robot.neutral()))[0, 1:, :3, 3]
        # the shoulder: the first joint origin that the target's distance varies about
        shoulder = origins[min(1, len(origins) - 1)]
        reach = float(np.max(np.linalg.norm(pos - shoulder, axis=1)))
        per_robot[key] = (table_q, pos, pose_tree, cKDTree(pos), shoulder, reach)
    return per_robot[key]


def _no_branch_message(excess: np.ndarray) -> str:
    """Why a target whose closed-form branches have ``excess`` (8,) (``_analytic.ik_branches``) has no solution."""
    if np.isfinite(excess).any():
        return "no IK solution within the joint limits: every closed-form branch leaves them"
    return "no IK solution: the target's wrist centre is beyond the arm's reach"

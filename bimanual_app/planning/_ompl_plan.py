"""Joint-space path planning with OMPL (RRTConnect), batched collision checks, shortcutting.

Order of work for one query: start and goal validity (an impossible query fails at once, with the
reason); the straight joint-space segment (most table-top reaches are free and need no search); else
OMPL's RRTConnect with a Python motion validator that checks a whole edge in one vectorised batch
(states spaced so that no arm point moves more than the collision margin between checks); then OMPL's
PathSimplifier (vertex reduction and rope shortcutting).
"""

from __future__ import annotations

import hashlib
import time
import weakref
from dataclasses import dataclass, field

import numpy as np

__all__ = ["PathResult", "plan_path"]

_SCENE_DIGESTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


@dataclass
class PathResult:
    """success; path (M, dim) waypoints (start first); message on failure; timings and counts."""

    success: bool
    path: np.ndarray | None
    message: str = ""
    method: str = ""  # "direct" | "rrtconnect"
    plan_time: float = 0.0
    goal_index: int = -1  # which of the goals was reached
    stats: dict = field(default_factory=dict)
    reason: str = ""  # on failure: "input" | "start" | "goal" | "search"


def _quiet_ompl() -> None:
    """OMPL's info/debug lines and nanobind's leak report at exit are noise for users."""
    try:
        from ompl import util as ou

        ou.setLogLevel(ou.LogLevel.LOG_WARN)
    except Exception:  # pragma: no cover - logging control is best effort
        pass
    try:
        import nanobind  # noqa: F401  (only present when the module exposes it)
        import ompl._ompl as _o
    except Exception:
        _o = None
    for mod in (_o,):
        fn = getattr(mod, "set_leak_warnings", None) if mod is not None else None
        if fn is not None:
            fn(False)


def _scene_digest(world) -> bytes:
    """SHA-256 of the world's scene map points (cached per map object: maps are rebuilt, not edited)."""
    scene = getattr(world, "scene", None)
    points = getattr(scene, "points", None)
    if points is None:
        return b""
    try:
        return _SCENE_DIGESTS[scene]
    except (KeyError, TypeError):
        pass
    digest = hashlib.sha256(np.ascontiguousarray(points, dtype=np.float64).tobytes()).digest()
    try:
        _SCENE_DIGESTS[scene] = digest
    except TypeError:  # not weak-referenceable: hashed again next time
        pass
    return digest


def query_seed(space, q_start: np.ndarray, goals: np.ndarray, seed: int) -> int:
    """A seed in [1, 2^31) from one query's inputs: the base ``seed``, start (dim,), goals (G, dim), the
    configurations of the arms held still, the joint limits and the scene map. The same query gets the same
    random numbers whatever ran before it in the process."""
    h = hashlib.sha256(str(int(seed)).encode())
    hold = getattr(space, "hold", {})
    for a in (q_start, goals, space.lower, space.upper, *[hold[k] for k in sorted(hold)]):
        h.update(np.round(np.asarray(a, dtype=np.float64), 12).tobytes())
    h.update(_scene_digest(space.world))
    return int.from_bytes(h.digest()[:4], "little") % (2**31 - 1) + 1  # OMPL rejects 0


def _seed_query(seed: int) -> None:
    """Re-seed OMPL's seed generator: every RNG created after this (the planner's sampler, its nearest-
    neighbour structure, the path simplifier) draws from ``seed``. OMPL logs an error when seeds were
    drawn before (RNGs that already exist keep theirs, which is what makes a process-wide seed depend on
    the process's history); that is the intent here, so the message is silenced."""
    from ompl import util as ou

    ou.setLogLevel(ou.LogLevel.LOG_NONE)
    try:
        ou.RNG.setSeed(int(seed))
    finally:
        ou.setLogLevel(ou.LogLevel.LOG_WARN)


def _rrt_connect(space, q_start: np.ndarray, goals: np.ndarray, edge_ok, stats: dict, timeout: float,
                 simplify: bool) -> tuple[np.ndarray | None, str]:
    """OMPL RRTConnect from ``q_start`` (dim,) to any of ``goals`` (G, dim) with ``edge_ok(a, b)`` as the
    motion validator, then PathSimplifier; (waypoints (M, dim) or None, OMPL's status)."""
    import ompl.base as ob
    import ompl.geometric as og

    _quiet_ompl()
    d = space.dim
    sp = ob.RealVectorStateSpace(d)
    bounds = ob.RealVectorBounds(d)
    for i in range(d):
        bounds.setLow(i, float(space.lower[i]))
        bounds.setHigh(i, float(space.upper[i]))
    sp.setBounds(bounds)
    si = ob.SpaceInformation(sp)

    def to_np(s) -> np.ndarray:
        return np.array([s[i] for i in range(d)])

    def state_valid(s) -> bool:
        stats["states"] += 1
        return bool(space.valid_batch(to_np(s)[None])[0])

    class BatchMotionValidator(ob.MotionValidator):
        """checkMotion: the whole edge as one vectorised batch (states spaced by the margin)."""

        def checkMotion(self, s1, s2):  # noqa: N802 (OMPL's name)
            return edge_ok(to_np(s1), to_np(s2))

    si.setStateValidityChecker(state_valid)
    mv = BatchMotionValidator(si)
    si.setMotionValidator(mv)
    si.setup()
    pdef = ob.ProblemDefinition(si)
    start = si.allocState()
    for i in range(d):
        start[i] = float(q_start[i])
    pdef.addStartState(start)
    goal = ob.GoalStates(si)
    gstates = []
    for g in goals:
        s = si.allocState()
        for i in range(d):
            s[i] = float(g[i])
        goal.addState(s)
        gstates.append(s)
    pdef.setGoal(goal)
    planner = og.RRTConnect(si)
    planner.setProblemDefinition(pdef)
    planner.setup()
    status = planner.solve(float(timeout))
    if not pdef.hasExactSolution():
        return None, str(status)
    path = pdef.getSolutionPath()
    if simplify:
        ps = og.PathSimplifier(si)
        ps.reduceVertices(path)
        ps.ropeShortcutPath(path)
        ps.reduceVertices(path)
    W = np.stack([to_np(path.getState(i)) for i in range(path.getStateCount())])
    # keep OMPL objects alive until here (nanobind owns them)
    del planner, pdef, goal, gstates, mv
    return W, str(status)


def plan_path(space, q_start: np.ndarray, goals: np.ndarray, timeout: float = 2.0, step: float | None = None,
              simplify: bool = True, try_direct: bool = True, seed: int | None = None) -> PathResult:
    """Plan from ``q_start`` (dim,) to any of ``goals`` (G, dim) (preferred first) in ``space``.

    ``step``: largest displacement (m) of any arm point between collision-checked states (default: the
    world's margin). ``seed``: base seed of OMPL's random numbers, combined with the query's inputs
    (:func:`query_seed`) so that a query plans alike in any process; None: OMPL's own (time) seed.
    """
    t_start = time.perf_counter()
    q_start = np.asarray(q_start, dtype=np.float64).reshape(-1)
    goals = np.atleast_2d(np.asarray(goals, dtype=np.float64))
    step = float(step if step is not None else space.world.margin)
    stats = {"edges": 0, "states": 0}

    def fail(msg, reason):
        return PathResult(False, None, msg, "", time.perf_counter() - t_start, -1, stats, reason)

    if q_start.shape != (space.dim,) or goals.shape[1] != space.dim:
        return fail(f"expected configurations of {space.dim} joints, got start {q_start.shape}, goals {goals.shape}",
                    "input")
    # 1. start and goals
    if not space.valid_batch(q_start[None])[0]:
        return fail("the start configuration is not valid: " + "; ".join(space.explain(q_start)[:4]), "start")
    gvalid = space.valid_batch(goals)
    if not gvalid.any():
        return fail("no goal configuration is valid: " + "; ".join(space.explain(goals[0])[:4]), "goal")
    goal_ids = np.nonzero(gvalid)[0]

    def edge_ok(a, b) -> bool:
        states = space.interpolate(a, b, step)
        stats["edges"] += 1
        if len(states) > 24:  # every 8th state first: most invalid edges fail there, at an eighth of the cost
            coarse = states[::8]
            stats["states"] += len(coarse)
            if not space.valid_batch(coarse).all():
                return False
            states = np.delete(states, np.s_[::8], axis=0)
        stats["states"] += len(states)
        return bool(space.valid_batch(states).all())

    # 2. the straight segment
    if try_direct:
        for g in goal_ids:
            if edge_ok(q_start, goals[g]):
                return PathResult(True, np.stack([q_start, goals[g]]), "", "direct", time.perf_counter() - t_start, int(g), stats)

    # 3. RRTConnect
    if seed is not None:
        _seed_query(query_seed(space, q_start, goals[goal_ids], seed))
    W, status = _rrt_connect(space, q_start, goals[goal_ids], edge_ok, stats, timeout, simplify)
    if W is None:
        return fail(f"RRTConnect found no path in {timeout:.1f} s ({status}); the goal may be enclosed by obstacles",
                    "search")
    gi = int(goal_ids[int(np.argmin(np.linalg.norm(goals[goal_ids] - W[-1], axis=1)))])
    W[0], W[-1] = q_start, goals[gi]  # exact endpoints (OMPL copies them; remove float noise)
    return PathResult(True, W, "", "rrtconnect", time.perf_counter() - t_start, gi, stats)

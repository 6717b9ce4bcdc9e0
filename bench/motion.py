"""Motion-layer benchmark: IK, collision checks, planning (issue 5).

    .venv/bin/python bench/motion.py [--quick] [--scene DIR] [--no-save]

Scene map: the true metric cloud of a synthetic scene (``bimanual_app.synth``): ``--scene`` if given,
else ``scenes/demo`` when it is a rendered synthetic scene, else one generated into a temporary folder
(seed 0, 4 views per arm, 5 objects). Prints a markdown table; every speed row carries a ratio against a
reference measured in the same run; targets print PASS/FAIL. Times are this process's CPU time
(``time.process_time``: the machine is shared, and waiting for a core is not the code's cost); the target
rows show the wall-clock time beside it. Saves the output to docs/bench/motion.md.
"""

from __future__ import annotations

import argparse
import atexit
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _now() -> tuple[float, float]:
    """(wall clock, this process's CPU time) in seconds."""
    return time.perf_counter(), time.process_time()


def _since(t0: tuple[float, float]) -> tuple[float, float]:
    """(wall, CPU) seconds elapsed since ``t0``."""
    w, c = _now()
    return w - t0[0], c - t0[1]


def _scene(args) -> tuple[Path, str]:
    from bimanual_app.synth import make_synthetic_scene

    if args.scene:
        return Path(args.scene), args.scene
    demo = ROOT / "scenes" / "demo"
    if (demo / "ground_truth.yaml").is_file():
        try:
            from bimanual_app.synth import ground_truth_cloud

            ground_truth_cloud(demo, stride=8)
            return demo, "scenes/demo"
        except Exception:
            pass
    tmp = Path(tempfile.mkdtemp(prefix="bijcr-bench-motion-"))
    atexit.register(shutil.rmtree, tmp, True)
    path = make_synthetic_scene(tmp / "scene", seed=0, views=4, objects=5, progress=False, preview=False)
    return path, "synthetic (seed 0, 4 views, 5 objects)"


def _tabletop(robot, space_valid, T_b1_b, table_z, n, rng, hold_valid=None):
    """(n, J) valid configurations with the gripper 3..25 cm above the table, in front, pointing down-ish."""
    out = []
    tries = 0
    while len(out) < n and tries < 200:
        tries += 1
        Q = robot.random_q(4000, rng)
        T_local = robot.fk_link(Q, robot.tcp_link)
        T = T_b1_b @ T_local
        p = T_local[:, :3, 3]
        ok = (T[:, 2, 3] > table_z + 0.03) & (T[:, 2, 3] < table_z + 0.25) & (p[:, 0] > 0.12) & (p[:, 0] < 0.5) \
            & (np.abs(p[:, 1]) < 0.3) & (T[:, 2, 2] < -0.3)
        Q = Q[ok]
        if len(Q):
            out += list(Q[space_valid(Q)])
    return np.array(out[:n])


def _brute_force_rate(world, Q1, Q2) -> float:
    """Reference: the same checks with coal only (every pair, no broad phase), configurations per second."""
    import coal

    req, res = coal.CollisionRequest(), coal.CollisionResult()
    ident = coal.Transform3s()
    t0 = _now()
    for q1, q2 in zip(Q1, Q2):
        W = [a.placements(q[None])[0] for a, q in zip(world.arms, (q1, q2))]
        tfs = [[a.shape_tf(W[k], s) for s in range(len(a.shapes.shapes))] for k, a in enumerate(world.arms)]
        hit = False
        for k, a in enumerate(world.arms):
            req.security_margin = world.margin
            for s, sh in enumerate(a.shapes.shapes):
                if not a.fixed[s]:
                    res.clear()
                    hit |= coal.collide(sh.geometry, tfs[k][s], world.scene.octree, ident, req, res)
            req.security_margin = world.self_margin
            for i, j in a.shapes.self_pairs:
                res.clear()
                hit |= coal.collide(a.shapes.shapes[i].geometry, tfs[k][i], a.shapes.shapes[j].geometry, tfs[k][j], req, res)
        req.security_margin = world.margin
        a1, a2 = world.arms
        for i, s1 in enumerate(a1.shapes.shapes):
            for j, s2 in enumerate(a2.shapes.shapes):
                res.clear()
                hit |= coal.collide(s1.geometry, tfs[0][i], s2.geometry, tfs[1][j], req, res)
    return len(Q1) / _since(t0)[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer samples (CI smoke run)")
    ap.add_argument("--scene", help="a rendered synthetic scene folder")
    ap.add_argument("--no-save", action="store_true", help="do not write docs/bench/motion.md")
    args = ap.parse_args()
    n_ik, n_coll, n_plan, n_both = (200, 2000, 20, 5) if args.quick else (1000, 20000, 100, 20)

    from bimanual_app.kinematics import IKSolver
    from bimanual_app.planning import BimanualSetup, default_ready
    from bimanual_app.robots import load_robot
    from bimanual_app.scene import load_scene
    from bimanual_app.synth import ground_truth_cloud

    log = lambda m: print(m, file=sys.stderr, flush=True)  # noqa: E731
    scene_path, scene_desc = _scene(args)
    scene = load_scene(scene_path)
    T_b1_b2 = scene.ground_truth.T_b1_b2
    points, _, labels = ground_truth_cloud(scene_path, voxel=0.004)
    # the table top: background points within reach of b1 (the cloud may also hold the floor)
    near = (labels < 0) & (np.linalg.norm(points[:, :2], axis=1) < 0.6) & (np.abs(points[:, 2]) < 0.3)
    table_z = float(np.median(points[near, 2]))
    robot = load_robot("piper")
    t0 = time.perf_counter()
    setup = BimanualSetup(robot, T_b1_b2, points)
    t_build = time.perf_counter() - t0
    world = setup.world
    log(f"scene map: {len(world.scene)} points, {world.scene.n_cells} voxels, built in {t_build:.2f} s")
    rows = []

    def row(name, value, target="", ok=None, ratio=""):
        rows.append((name, value, target, "" if ok is None else ("PASS" if ok else "FAIL"), ratio))

    # ---------------------------------------------------------------- IK
    rng = np.random.default_rng(0)
    fk_t = []
    q_probe = robot.random_q(200, rng)
    for q in q_probe:
        t = _now()
        robot.fk_link(q, "gripper_tcp")
        fk_t.append(_since(t)[1])
    fk_med = float(np.median(fk_t))
    for arm in ("primary", "secondary"):
        setup.ik_solver(arm)
        Q = robot.random_q(n_ik, rng)
        T_b1 = setup.T_b1_b(arm) @ robot.fk_link(Q, "gripper_tcp")
        q0 = default_ready(robot)
        times, ok = [], 0
        for T in T_b1:
            t = _now()
            res = setup.ik(arm, T, q0, n_solutions=1)
            times.append(_since(t))
            ok += res.success
        wall, cpu = np.median(np.array(times), axis=0)
        row(f"IK {arm}: median time per solve ({n_ik} FK targets, seeded from the rest pose)",
            f"{cpu * 1e3:.3f} ms CPU ({wall * 1e3:.3f} ms wall)", "< 0.3 ms", cpu < 0.3e-3, f"{cpu / fk_med:.0f} x one FK")
        row(f"IK {arm}: p95 time per solve (CPU)", f"{np.percentile(np.array(times)[:, 1], 95) * 1e3:.3f} ms")
        row(f"IK {arm}: success on reachable targets", f"{100 * ok / n_ik:.1f} %", ">= 99.5 %", ok / n_ik >= 0.995)
    solver = IKSolver(robot)
    Q = robot.random_q(n_ik, rng)
    T = robot.fk_link(Q, "gripper_tcp")
    near = Q + rng.normal(scale=0.05, size=Q.shape)
    times = []
    for i in range(n_ik):
        t = _now()
        solver.solve(T[i], near[i])
        times.append(_since(t)[1])
    row("IK tracking: median time, seeded 0.05 rad from the solution (CPU)", f"{np.median(times) * 1e3:.3f} ms", "",
        None, f"{np.median(times) / fk_med:.0f} x one FK")
    log("IK done")

    # ---------------------------------------------------------------- collision
    Q1, Q2 = robot.random_q(n_coll, rng), robot.random_q(n_coll, rng)
    world.valid_batch(Q1[:100], Q2[:100])  # warm-up
    t = _now()
    v = world.valid_batch(Q1, Q2)
    wall, cpu = _since(t)
    rate_rand, rate_rand_wall = n_coll / cpu, n_coll / wall
    n_ref = min(300, n_coll)
    rate_ref = _brute_force_rate(world, Q1[:n_ref], Q2[:n_ref])
    row(f"collision: two-arm checks per second, batch of {n_coll} random configurations ({100 * v.mean():.0f} % free)",
        f"{rate_rand:,.0f} /s CPU ({rate_rand_wall:,.0f} /s wall)", ">= 10,000 /s", rate_rand >= 1e4,
        f"{rate_rand / rate_ref:.1f} x coal only")
    hold = default_ready(robot)
    T1 = _tabletop(robot, lambda Q: world.valid_batch(Q, hold), np.eye(4), table_z, n_coll // 4, rng)
    T2 = _tabletop(robot, lambda Q: world.valid_batch(hold, Q), T_b1_b2, table_z, n_coll // 4, rng)
    m = min(len(T1), len(T2))
    t = _now()
    v = world.valid_batch(T1[:m], T2[:m])
    wall, cpu = _since(t)
    rate_tt, rate_tt_wall = m / cpu, m / wall
    row(f"collision: two-arm checks per second, batch of {m} table-top configurations ({100 * v.mean():.0f} % free)",
        f"{rate_tt:,.0f} /s CPU ({rate_tt_wall:,.0f} /s wall)", ">= 10,000 /s", rate_tt >= 1e4,
        f"{rate_tt / rate_ref:.1f} x coal only")
    t = _now()
    for i in range(200):
        world.valid(Q1[i], Q2[i])
    rate_single = 200 / _since(t)[1]
    row("collision: single-configuration calls per second (CPU)", f"{rate_single:,.0f} /s", "", None,
        f"{rate_single / rate_ref:.1f} x coal only")
    row("collision: reference, coal only (all pairs, no broad phase; CPU)", f"{rate_ref:,.0f} /s")
    log("collision done")

    # ---------------------------------------------------------------- planning
    q_now = {"primary": hold, "secondary": hold}
    starts = _tabletop(robot, lambda Q: world.valid_batch(Q, hold), np.eye(4), table_z, n_plan, rng)
    goals = _tabletop(robot, lambda Q: world.valid_batch(Q, hold), np.eye(4), table_z, n_plan, rng)
    space = setup.space(["primary"], q_now)
    plan_t, line_t, ok, direct, durations, states, reasons = [], [], 0, 0, [], [], {}
    for i in range(n_plan):
        T_goal = robot.fk_link(goals[i], "gripper_tcp")
        t = _now()
        plan = setup.plan_reach("primary", T_goal, {"primary": starts[i], "secondary": hold}, seed=1)
        plan_t.append(_since(t))
        t = _now()
        space.valid_batch(space.interpolate(starts[i], goals[i], world.margin)).all()
        line_t.append(_since(t)[1])
        if not plan.success:
            reasons[plan.reason] = reasons.get(plan.reason, 0) + 1
            log(f"query {i} failed ({plan.reason}): {plan.message[:200]}")
        if plan.success:
            ok += 1
            direct += plan.method == "direct"
            durations.append(plan.trajectories["primary"].duration)
            states.append(plan.validation.states_checked)
    med_wall, med = np.median(np.array(plan_t), axis=0)
    med_line = float(np.median(line_t))
    row(f"planning one arm: median time per table-top reach (IK + plan + time + validation, {n_plan} queries)",
        f"{med * 1e3:.1f} ms CPU ({med_wall * 1e3:.1f} ms wall)", "< 100 ms", med < 0.1,
        f"{med / med_line:.1f} x straight-line check")
    row("planning one arm: p90 time (CPU)", f"{np.percentile(np.array(plan_t)[:, 1], 90) * 1e3:.1f} ms")
    fails = ", ".join(f"{v} {k}" for k, v in reasons.items())
    row("planning one arm: success", f"{100 * ok / n_plan:.0f} % ({direct} straight, {ok - direct} RRTConnect"
        + (f"; failed: {fails}" if fails else "") + ")")
    row("reference: straight-line interpolation check of the same queries (median, CPU)", f"{med_line * 1e3:.2f} ms")
    if durations:
        row("trajectories: median duration at half the SDK limits / states validated", f"{np.median(durations):.2f} s / "
            f"{int(np.median(states))}")
    b_t, b_ok = [], 0
    g1 = _tabletop(robot, lambda Q: world.valid_batch(Q, hold), np.eye(4), table_z, n_both, rng)
    for i in range(n_both):
        g2 = _tabletop(robot, lambda Q, i=i: world.valid_batch(g1[i], Q), T_b1_b2, table_z, 1, rng)
        if len(g2) == 0:
            continue
        t = _now()
        plan = setup.plan_configurations(["primary", "secondary"], {"primary": hold, "secondary": hold},
                                         [{"primary": g1[i], "secondary": g2[0]}], seed=1)
        b_t.append(_since(t)[1])
        b_ok += plan.success
    if b_t:
        row(f"planning both arms (12 DoF), rest -> table-top pair: median CPU time ({len(b_t)} queries)",
            f"{np.median(b_t) * 1e3:.1f} ms", "", None, f"{np.median(b_t) / med_line:.1f} x straight-line check")
        row("planning both arms: success", f"{100 * b_ok / len(b_t):.0f} %")
    log("planning done")

    cmd = "nice .venv/bin/python bench/motion.py" + (" --quick" if args.quick else "") + \
        (f" --scene {args.scene}" if args.scene else "")
    lines = [f"Command: `{cmd}`", "",
             f"Scene map: {scene_desc}; table top at z = {table_z * 100:.1f} cm in b1; {len(world.scene)} points in reach, {world.scene.n_cells} voxels of "
             f"{world.resolution * 100:.0f} cm, map built in {t_build:.2f} s; margin {world.margin * 100:.0f} cm; "
             f"{os.cpu_count()} CPU cores, load average {os.getloadavg()[0]:.1f} at the end (other jobs share the"
             " machine; the ratios are measured side by side and are steadier than the absolute times).", "",
             "| measure | value | target | result | ratio vs reference |", "| --- | --- | --- | --- | --- |"]
    lines += [f"| {a} | {b} | {c} | {d} | {e} |" for a, b, c, d, e in rows]
    text = "\n".join(lines) + "\n"
    print(text)
    if not args.no_save:
        out = ROOT / "docs" / "bench" / "motion.md"
        out.parent.mkdir(parents=True, exist_ok=True)
        from bimanual_app.io_utils import atomic_open

        with atomic_open(out) as f:
            f.write("# Motion benchmark (IK, collision, planning)\n\n" + text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

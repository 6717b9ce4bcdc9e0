"""Shared fixtures for the motion-layer tests: a small table-top scene cloud and two facing Pipers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bimanual_app.transforms import make_T

# secondary base 0.7 m in front of the primary, facing it
T_B1_B2 = make_T(Rotation.from_euler("z", np.pi).as_matrix(), np.array([0.7, 0.0, 0.0]))
BOX_CENTER = np.array([0.32, 0.0, 0.08])  # a 10 x 10 x 16 cm box standing on the table
BOX_HALF = np.array([0.05, 0.05, 0.08])


@pytest.fixture(scope="module")
def piper():
    """The Piper robot model (import this fixture into a test module)."""
    from bimanual_app.robots import load_robot

    return load_robot("piper")


@pytest.fixture(scope="module")
def solver(piper):
    """An IK solver for :func:`piper`."""
    from bimanual_app.kinematics import IKSolver

    return IKSolver(piper)


def table_cloud(spacing: float = 0.008, box: bool = True, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Table top (z = 0, points just below) under both bases plus one box: (points (N,3), box mask (N,))."""
    rng = np.random.default_rng(seed)
    g = np.mgrid[-0.25:0.95:spacing, -0.45:0.45:spacing].reshape(2, -1).T
    table = np.c_[g, np.full(len(g), -0.004)] + rng.normal(0, 0.001, (len(g), 3))
    parts, masks = [table], [np.zeros(len(table), bool)]
    if box:
        lo, hi = BOX_CENTER - BOX_HALF, BOX_CENTER + BOX_HALF
        faces = []
        for axis in range(3):
            for side in (lo[axis], hi[axis]):
                u, v = [a for a in range(3) if a != axis]
                gu = np.arange(lo[u], hi[u] + 1e-9, spacing / 2)
                gv = np.arange(lo[v], hi[v] + 1e-9, spacing / 2)
                U, V = np.meshgrid(gu, gv, indexing="ij")
                f = np.zeros((U.size, 3))
                f[:, axis], f[:, u], f[:, v] = side, U.ravel(), V.ravel()
                faces.append(f)
        bx = np.concatenate(faces)
        parts.append(bx)
        masks.append(np.ones(len(bx), bool))
    return np.concatenate(parts), np.concatenate(masks)


def tabletop_configs(robot, world, n: int, rng, arm: str = "primary", q_other=None, T_b1_b=None) -> np.ndarray:
    """(n, J) valid configurations whose gripper frame is 3..25 cm above the table, in front of the arm
    and pointing down-ish (the poses of table-top reaches)."""
    rng = np.random.default_rng(rng)
    T_b1_b = np.eye(4) if T_b1_b is None else T_b1_b
    out = []
    while len(out) < n:
        Q = robot.random_q(4000, rng)
        T = T_b1_b @ robot.fk_link(Q, robot.tcp_link)
        p_local = robot.fk_link(Q, robot.tcp_link)[:, :3, 3]
        ok = (T[:, 2, 3] > 0.03) & (T[:, 2, 3] < 0.25) & (p_local[:, 0] > 0.12) & (p_local[:, 0] < 0.5) \
            & (np.abs(p_local[:, 1]) < 0.3) & (T[:, 2, 2] < -0.3)
        Q = Q[ok]
        if len(Q) == 0:
            continue
        if world.n_arms == 2:
            other = np.asarray(q_other)
            valid = world.valid_batch(Q, other) if arm == "primary" else world.valid_batch(other, Q)
        else:
            valid = world.valid_batch(Q)
        out += list(Q[valid])
    return np.array(out[:n])


def write_reach_scene(root, cloud: np.ndarray | None = None, calibration: bool = True):
    """A small contract scene (tests/_scene_fixtures) plus calibration/calibration.json and scene_b1.ply
    (the table cloud) as `bijcr calibrate` writes them. Returns (scene folder, T_b1_b2)."""
    import json
    from pathlib import Path

    import open3d as o3d
    from _scene_fixtures import make_scene

    root = Path(root)
    scene = make_scene(root / "scene", n=3, seed=0, images=False)
    T_b1_b2 = scene.ground_truth.T_b1_b2
    if calibration:
        cal = root / "scene" / "calibration"
        cal.mkdir(parents=True, exist_ok=True)
        gt, rec, scale = scene.ground_truth, scene.reconstruction, scene.ground_truth.scale or 0.7
        T_b1_w = np.eye(4)
        if rec is not None:  # the true calibration of this capture (`bijcr reach` checks it belongs to it)
            rows, rec_rows = rec.rows_for(scene.primary.index, scene.primary.images)
            P = np.array(rec.T_w_c[rec_rows[0]], dtype=np.float64)
            P[:3, 3] *= scale
            T_b1_w = scene.primary.T_b_e[rows[0]] @ gt.T_e1_c1 @ np.linalg.inv(P)
        (cal / "calibration.json").write_text(json.dumps({
            "format": 1, "scene": scene.name, "scale": scale, "T_e1_c1": gt.T_e1_c1.tolist(),
            "T_e2_c2": gt.T_e2_c2.tolist(), "T_b1_w": T_b1_w.tolist(),
            "T_b2_w": (np.linalg.inv(T_b1_b2) @ T_b1_w).tolist(), "T_b1_b2": T_b1_b2.tolist(),
            "views_used": {"primary": 3, "secondary": 3}, "residuals": {"rotation_rad": 0.0, "translation_m": 0.0}}))
        pc = o3d.geometry.PointCloud()
        pc.points = o3d.utility.Vector3dVector(table_cloud(spacing=0.012)[0] if cloud is None else cloud)
        o3d.io.write_point_cloud(str(cal / "scene_b1.ply"), pc)
    return root / "scene", T_b1_b2


def down_pose(p) -> np.ndarray:
    """T_b_g pointing straight down at ``p`` (3,), the gripper's x axis towards the arm's base (the way
    the Piper reaches a table from above)."""
    p = np.asarray(p, dtype=np.float64)
    yaw = np.arctan2(p[1], p[0])
    return make_T(Rotation.from_euler("z", yaw).as_matrix() @ np.diag([-1.0, 1.0, -1.0]), p)

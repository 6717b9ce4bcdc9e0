"""Pictures of a plan: a PyBullet (TinyRenderer, headless) view of the end state, and joint curves."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bimanual_app.io_utils import atomic_path

__all__ = ["render_end_state", "plot_trajectory"]


def _cloud_bodies(p, cid, points: np.ndarray, colors: np.ndarray | None, size: float) -> None:
    """The cloud as small static boxes, one batch per colour bin (TinyRenderer draws no debug points)."""
    if colors is None or len(colors) != len(points):
        z = points[:, 2]
        t = (z - z.min()) / max(float(np.ptp(z)), 1e-6)
        colors = (np.stack([0.35 + 0.5 * t, 0.55 - 0.2 * t, 0.75 - 0.5 * t], 1) * 255).astype(np.uint8)
    bins = (np.asarray(colors, dtype=np.int64) // 64)  # 4 levels per channel
    keys = bins[:, 0] * 16 + bins[:, 1] * 4 + bins[:, 2]
    for key in np.unique(keys):
        sel = points[keys == key]
        rgb = (np.array([key // 16, (key // 4) % 4, key % 4]) * 64 + 32) / 255.0
        vs = p.createVisualShape(p.GEOM_BOX, halfExtents=[size / 2] * 3, rgbaColor=[*rgb, 1.0], physicsClientId=cid)
        for chunk in range(0, len(sel), 1000):  # batchPositions in chunks keeps the call small
            p.createMultiBody(baseMass=0, baseVisualShapeIndex=vs, batchPositions=sel[chunk:chunk + 1000].tolist(),
                              physicsClientId=cid)


def render_end_state(path: str | Path, robots: list, bases: list[np.ndarray], configs: list[np.ndarray],
                     points_b1: np.ndarray | None = None, colors: np.ndarray | None = None,
                     target_b1: np.ndarray | None = None, tcp_path_b1: np.ndarray | None = None,
                     max_points: int = 6000, size: tuple[int, int] = (640, 480), seed: int = 0) -> Path:
    """Render the arms at ``configs`` on their ``bases`` (T_b1_b) with the cloud, to a PNG (atomic)."""
    import pybullet as p
    from PIL import Image

    from bimanual_app.transforms import xyz_quat_from_T

    cid = p.connect(p.DIRECT)
    try:
        for robot, T, q in zip(robots, bases, configs):
            xyz, quat = xyz_quat_from_T(np.asarray(T))
            body = p.loadURDF(str(robot.urdf_path), basePosition=list(xyz), baseOrientation=list(quat),
                              useFixedBase=True, physicsClientId=cid)
            names = {p.getJointInfo(body, j, physicsClientId=cid)[1].decode(): j
                     for j in range(p.getNumJoints(body, physicsClientId=cid))}
            full = robot.full_q(np.asarray(q, dtype=np.float64))
            for name, v in zip(robot.joint_names + robot.finger_joints, full):
                p.resetJointState(body, names[name], float(v), physicsClientId=cid)
        if points_b1 is not None and len(points_b1):
            P = np.asarray(points_b1, dtype=np.float64)
            C = None if colors is None else np.asarray(colors)
            if len(P) > max_points:
                idx = np.random.default_rng(seed).choice(len(P), max_points, replace=False)
                P, C = P[idx], (None if C is None else C[idx])
            _cloud_bodies(p, cid, P, C, 0.008)
        marks = []
        if tcp_path_b1 is not None:
            marks += [(x, 0.006, [0.1, 0.4, 1.0, 1.0]) for x in np.asarray(tcp_path_b1)]
        if target_b1 is not None:
            marks.append((np.asarray(target_b1), 0.015, [1.0, 0.1, 0.1, 1.0]))
        for x, r, rgba in marks:
            vs = p.createVisualShape(p.GEOM_SPHERE, radius=r, rgbaColor=rgba, physicsClientId=cid)
            p.createMultiBody(baseMass=0, baseVisualShapeIndex=vs, basePosition=list(map(float, x)), physicsClientId=cid)
        # look at the middle of the bases from the side and above
        mid = np.mean([np.asarray(T)[:3, 3] for T in bases], axis=0) + np.array([0.0, 0.0, 0.12])
        span = max(0.6, float(np.linalg.norm(np.ptp(np.array([np.asarray(T)[:3, 3] for T in bases]), axis=0))))
        view = p.computeViewMatrixFromYawPitchRoll(list(mid), 1.1 * span + 0.5, 35.0, -30.0, 0.0, 2, physicsClientId=cid)
        proj = p.computeProjectionMatrixFOV(50.0, size[0] / size[1], 0.05, 10.0, physicsClientId=cid)
        img = p.getCameraImage(size[0], size[1], view, proj, renderer=p.ER_TINY_RENDERER,
                               lightDirection=[0.4, -0.6, 1.0], shadow=0, physicsClientId=cid)
        rgb = np.reshape(np.asarray(img[2], dtype=np.uint8), (size[1], size[0], 4))[:, :, :3]
    finally:
        p.disconnect(cid)
    path = Path(path)
    with atomic_path(path) as tmp:
        Image.fromarray(rgb).save(tmp, format="PNG")
    return path


def plot_trajectory(path: str | Path, times: np.ndarray, Q: np.ndarray, names: list[str], vmax: np.ndarray,
                    title: str = "") -> Path:
    """Joint angles and velocities against time (matplotlib, headless) to a PNG (atomic)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for j, n in enumerate(names):
        ax[0].plot(times, Q[:, j], label=n)
    if len(times) > 1:
        vel = np.diff(Q, axis=0) / np.diff(times)[:, None]
        tm = 0.5 * (times[1:] + times[:-1])
        for j in range(Q.shape[1]):
            ax[1].plot(tm, vel[:, j] / vmax[j])
    ax[0].set_ylabel("joint angle (rad)")
    ax[0].legend(fontsize=7, ncol=3)
    ax[1].set_ylabel("velocity / limit")
    ax[1].set_xlabel("time (s)")
    ax[1].axhline(1.0, color="k", lw=0.5, ls="--")
    ax[1].axhline(-1.0, color="k", lw=0.5, ls="--")
    fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)
    return path

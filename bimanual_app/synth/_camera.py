"""Pinhole camera maths for the synthetic renderer: OpenCV intrinsics <-> PyBullet (OpenGL) matrices.

Pure functions on arrays. Conventions: camera frame ``c`` is OpenCV (x right, y down, z forward); pixel
``(u, v)`` has its centre at integer coordinates (``u = fx X / Z + cx``).

PyBullet's TinyRenderer samples pixel ``i`` at the integer window coordinate ``i`` (measured: an edge at
``u = 380 - eps`` leaves pixel 380 empty, at ``380 + eps`` covers it), and returns rows top-down. The
projection matrix below is built so the rendered pixel ``(u, v)`` is exactly the OpenCV pixel ``(u, v)``
of ``K``; tests/test_synth.py checks it by back-projecting rendered depth onto known geometry.
"""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import check_T, inv_T

# OpenGL camera (x right, y up, z backward) from OpenCV camera (x right, y down, z forward).
T_GL_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def projection_matrix(width: int, height: int, fx: float, fy: float, cx: float, cy: float,
                      near: float, far: float) -> list[float]:
    """PyBullet projection matrix (16 floats, column-major) that renders the OpenCV camera ``K``.

    Window coordinates: ``x_win = u`` and ``y_win = height - 1 - v`` (TinyRenderer samples pixel centres at
    integer window coordinates and flips rows), hence the ``cx`` and ``cy + 1`` terms.
    """
    P = np.zeros((4, 4))
    P[0, 0] = 2.0 * fx / width
    P[0, 2] = 1.0 - 2.0 * cx / width
    P[1, 1] = 2.0 * fy / height
    P[1, 2] = 2.0 * (cy + 1.0) / height - 1.0
    P[2, 2] = -(far + near) / (far - near)
    P[2, 3] = -2.0 * far * near / (far - near)
    P[3, 2] = -1.0
    return P.T.reshape(-1).tolist()


def view_matrix(T_world_c: np.ndarray) -> list[float]:
    """PyBullet view matrix (16 floats, column-major) of an OpenCV camera at pose ``T_world_c`` (4, 4)."""
    T_world_c = check_T("T_world_c", T_world_c)
    return (T_GL_CV @ inv_T(T_world_c)).T.reshape(-1).tolist()


def linear_depth(zbuffer: np.ndarray, near: float, far: float) -> np.ndarray:
    """Metric depth along the optical axis (H, W) float64 from PyBullet's non-linear depth buffer (H, W)."""
    d = np.asarray(zbuffer, dtype=np.float64)
    return far * near / (far - (far - near) * d)


def pixel_rays(K: np.ndarray, width: int, height: int, scale_x: float = 1.0, scale_y: float = 1.0) -> np.ndarray:
    """Rays ``(X/Z, Y/Z, 1)`` (H', W', 3) through the pixels of a (possibly reduced) image.

    With ``scale_x = width_full / width`` (likewise y), pixel ``(u, v)`` of the reduced grid stands for the
    full-image point ``((u + 0.5) * scale_x - 0.5, (v + 0.5) * scale_y - 0.5)``, the centre of its block.
    """
    K = np.asarray(K, dtype=np.float64)
    u = (np.arange(width) + 0.5) * scale_x - 0.5
    v = (np.arange(height) + 0.5) * scale_y - 0.5
    uu, vv = np.meshgrid(u, v)
    x = (uu - K[0, 2]) / K[0, 0]
    y = (vv - K[1, 2]) / K[1, 1]
    return np.stack([x, y, np.ones_like(x)], axis=-1)


def look_at(eye: np.ndarray, target: np.ndarray, up_hint: np.ndarray | None = None,
            roll: float = 0.0) -> np.ndarray:
    """OpenCV camera pose (4, 4) at ``eye`` (3,) with z towards ``target`` (3,), then rolled about z.

    With ``roll = 0`` the image's "up" (-y) points as close to ``up_hint`` (default +z) as possible.
    """
    up_hint = np.array([0.0, 0.0, 1.0]) if up_hint is None else up_hint
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up_hint)
    if np.linalg.norm(x) < 1e-6:  # looking straight along the hint: any x will do
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=1)
    c, s = np.cos(roll), np.sin(roll)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = R @ Rz
    T[:3, 3] = eye
    return T

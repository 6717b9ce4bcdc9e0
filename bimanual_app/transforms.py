"""Rigid transforms and rotations, batched, on numpy arrays.

Conventions (the scene contract): ``T_a_b`` is a 4x4 float64 homogeneous transform that maps points in
frame ``b`` to frame ``a`` (``p_a = T_a_b @ p_b``); metres and radians; quaternions are (x, y, z, w)
and always passed by name.

Every function accepts a single item or a leading batch dimension (``(..., 4, 4)``, ``(..., 3, 3)``,
``(..., 3)``). Rotation conversions use scipy's ``Rotation``; the SO(3) log/exp here are written out
because they must be smooth at small angles in batched form and scipy has no batched ``log`` for
matrices that returns the rotation vector without a round-trip through quaternions (which is what
``so3_log`` does, via scipy, for robustness near pi).
"""

from __future__ import annotations

import numpy as np


def _rotation():
    """scipy's ``Rotation`` class, imported on first use (importing scipy.spatial costs 0.4 s, and every
    command's parser imports this module)."""
    from scipy.spatial.transform import Rotation

    return Rotation

__all__ = [
    "make_T",
    "inv_T",
    "check_T",
    "check_shape",
    "T_from_xyz_quat",
    "xyz_quat_from_T",
    "so3_exp",
    "so3_log",
    "skew",
    "perpendicular_basis",
    "rotation_angle",
    "rotation_angle_between",
    "mean_rotation",
    "mean_T",
    "project_to_SO3",
    "random_T",
    "apply_T",
]


def check_shape(name: str, a: np.ndarray, shape: tuple) -> np.ndarray:
    """Check ``a`` against ``shape`` (``None`` entries match any size; a leading ``...`` any batch).

    Returns ``a`` as a numpy array; raises ``ValueError`` naming ``name`` otherwise.
    """
    a = np.asarray(a)
    if shape and shape[0] is Ellipsis:
        tail = shape[1:]
        ok = a.ndim >= len(tail) and all(
            s is None or s == d for s, d in zip(tail, a.shape[a.ndim - len(tail):])
        )
    else:
        ok = a.ndim == len(shape) and all(s is None or s == d for s, d in zip(shape, a.shape))
    if not ok:
        want = "(" + ", ".join("..." if s is Ellipsis else ("N" if s is None else str(s)) for s in shape) + ")"
        raise ValueError(f"{name}: expected an array of shape {want}, got {a.shape}")
    return a


def check_T(name: str, T: np.ndarray, tol: float = 1e-4) -> np.ndarray:
    """Validate homogeneous transforms ``(..., 4, 4)``: finite, proper rotation, bottom row 0 0 0 1.

    Returns the input as float64. Raises ``ValueError`` naming ``name`` and what is wrong.
    """
    T = check_shape(name, np.asarray(T, dtype=np.float64), (..., 4, 4))
    if not np.all(np.isfinite(T)):
        raise ValueError(f"{name}: contains non-finite values (NaN or inf)")
    if not np.allclose(T[..., 3, :], [0.0, 0.0, 0.0, 1.0], atol=tol):
        raise ValueError(f"{name}: bottom row must be [0, 0, 0, 1]")
    R = T[..., :3, :3]
    err = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(-1, -2))
    if np.any(err > tol):
        raise ValueError(
            f"{name}: rotation part is not orthonormal (max |R^T R - I| = {float(np.max(err)):.2e});"
            " re-orthonormalise it (e.g. bimanual_app.transforms.project_to_SO3)"
        )
    if np.any(np.linalg.det(R) < 0):
        raise ValueError(f"{name}: rotation part is a reflection (det < 0)")
    return T


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Build ``(..., 4, 4)`` transforms from rotations ``(..., 3, 3)`` and translations ``(..., 3)``."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    batch = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(batch + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def inv_T(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``(..., 4, 4)`` (uses R^T, not a general matrix inverse)."""
    T = np.asarray(T, dtype=np.float64)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_T(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def apply_T(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply one transform ``(4, 4)`` to points ``(..., 3)``; returns ``(..., 3)``."""
    T = np.asarray(T, dtype=np.float64)
    p = np.asarray(p)
    return p @ T[:3, :3].T + T[:3, 3]


def T_from_xyz_quat(xyz: np.ndarray, quat_xyzw: np.ndarray) -> np.ndarray:
    """Transforms ``(..., 4, 4)`` from positions ``(..., 3)`` and unit quaternions (x, y, z, w) ``(..., 4)``."""
    xyz = np.asarray(xyz, dtype=np.float64)
    q = np.asarray(quat_xyzw, dtype=np.float64)
    R = _rotation().from_quat(q.reshape(-1, 4)).as_matrix().reshape(q.shape[:-1] + (3, 3))
    return make_T(R, xyz)


def xyz_quat_from_T(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``(..., 3)`` and quaternions (x, y, z, w) ``(..., 4)``, w >= 0, from transforms ``(..., 4, 4)``."""
    T = np.asarray(T, dtype=np.float64)
    q = _rotation().from_matrix(T[..., :3, :3].reshape(-1, 3, 3)).as_quat().reshape(T.shape[:-2] + (4,))
    q = np.where(q[..., 3:4] < 0, -q, q)
    return T[..., :3, 3].copy(), q


def skew(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrices ``(..., 3, 3)`` of vectors ``(..., 3)``."""
    v = np.asarray(v, dtype=np.float64)
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def perpendicular_basis(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``(e1, e2)`` (3,) that make ``(e1, e2, z)`` a right-handed orthonormal frame, for a unit
    ``z`` (3,): ``e1 = z x x_b`` normalised, with the base x axis (the y axis when z is within 26 degrees of
    x), and ``e2 = z x e1``."""
    z = np.asarray(z, dtype=np.float64)
    e1 = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(z, e1)


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` from rotation vectors (axis * angle) ``(..., 3)``."""
    w = np.asarray(w, dtype=np.float64)
    return _rotation().from_rotvec(w.reshape(-1, 3)).as_matrix().reshape(w.shape[:-1] + (3, 3))


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` (axis * angle, angle in [0, pi]) of rotation matrices ``(..., 3, 3)``.

    Goes through quaternions (scipy), which stays accurate at small angles and near pi, where the
    textbook ``omega / (2 sin omega) * vee(R - R^T)`` formula loses precision or divides by zero.
    """
    R = np.asarray(R, dtype=np.float64)
    return _rotation().from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle in radians, in [0, pi], of rotations ``(..., 3, 3)``; returns ``(...)``."""
    return np.linalg.norm(so3_log(R), axis=-1)


def rotation_angle_between(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Geodesic angle (radians) between rotations ``(..., 3, 3)`` and ``(..., 3, 3)``."""
    return rotation_angle(np.swapaxes(np.asarray(Ra), -1, -2) @ np.asarray(Rb))


def project_to_SO3(M: np.ndarray) -> np.ndarray:
    """Nearest rotation (Frobenius) to each matrix ``(..., 3, 3)``, by SVD with the det fix."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=np.float64))
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.zeros(U.shape)
    D[..., 0, 0] = 1.0
    D[..., 1, 1] = 1.0
    D[..., 2, 2] = d
    return U @ D @ Vt


def mean_rotation(R: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Chordal L2 mean of rotations ``(N, 3, 3)`` (optionally weighted ``(N,)``); returns ``(3, 3)``.

    A proper rotation mean (scipy's quaternion-based ``Rotation.mean``), not an element-wise average.
    """
    R = check_shape("R", R, (None, 3, 3))
    return _rotation().from_matrix(R).mean(weights=weights).as_matrix()


def mean_T(T: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Mean of rigid transforms ``(N, 4, 4)`` on SE(3): rotation mean and weighted translation mean."""
    T = check_shape("T", T, (None, 4, 4))
    w = np.ones(len(T)) if weights is None else np.asarray(weights, dtype=np.float64)
    t = (w[:, None] * T[:, :3, 3]).sum(0) / w.sum()
    return make_T(mean_rotation(T[:, :3, :3], w), t)


def random_T(rng: np.random.Generator, n: int | None = None, trans_scale: float = 1.0) -> np.ndarray:
    """Uniformly random rotations with Gaussian translations (std ``trans_scale``): ``(4, 4)`` or ``(n, 4, 4)``."""
    m = 1 if n is None else n
    R = _rotation().random(m, random_state=rng).as_matrix()
    T = make_T(R, rng.normal(scale=trans_scale, size=(m, 3)))
    return T[0] if n is None else T

"""Batched forward kinematics on numpy arrays, built from a Pinocchio model.

Pinocchio's Python API evaluates one configuration per call (a few microseconds each, plus the cost of
copying every placement out); collision checking and benchmarks need thousands of configurations at
once, so this module re-evaluates the *same* Pinocchio model (its joint placements, joint types and axes)
with numpy over a leading batch dimension. It is hand-written for that reason only; tests check it
against ``pinocchio.forwardKinematics`` to 1e-12.
"""

from __future__ import annotations

import numpy as np

__all__ = ["BatchFK"]

_AXES = {"X": np.array([1.0, 0.0, 0.0]), "Y": np.array([0.0, 1.0, 0.0]), "Z": np.array([0.0, 0.0, 1.0])}


def _joint_kind(jmodel) -> tuple[str, np.ndarray]:
    """('R' | 'P', unit axis (3,)) of a one-DoF Pinocchio joint model."""
    name = jmodel.shortname()
    if name in ("JointModelRX", "JointModelRY", "JointModelRZ"):
        return "R", _AXES[name[-1]]
    if name in ("JointModelPX", "JointModelPY", "JointModelPZ"):
        return "P", _AXES[name[-1]]
    if name == "JointModelRevoluteUnaligned":
        return "R", np.asarray(jmodel.extract().axis, dtype=np.float64).copy()
    if name == "JointModelPrismaticUnaligned":
        return "P", np.asarray(jmodel.extract().axis, dtype=np.float64).copy()
    raise ValueError(
        f"joint type {name} is not supported (only revolute and prismatic joints with one degree of freedom;"
        " continuous, floating and planar joints are not)"
    )


class BatchFK:
    """Vectorised FK of every joint and frame of a Pinocchio model.

    ``joints(Q)`` takes full configurations ``(N, model.nq)`` and returns ``(N, model.njoints, 4, 4)``
    placements ``T_b_joint`` (index 0 is the root, identity).
    """

    def __init__(self, model):
        self.nq = int(model.nq)
        self.njoints = int(model.njoints)
        self.parents = [int(p) for p in model.parents]
        self.M = np.stack([np.asarray(model.jointPlacements[i].homogeneous) for i in range(self.njoints)])
        self.kinds: list[str] = ["F"]
        self.axes = np.zeros((self.njoints, 3))
        self.idx_q = np.zeros(self.njoints, dtype=int)
        for i in range(1, self.njoints):
            kind, axis = _joint_kind(model.joints[i])
            self.kinds.append(kind)
            self.axes[i] = axis / np.linalg.norm(axis)
            self.idx_q[i] = model.joints[i].idx_q
        self.frame_parent = np.array([int(f.parentJoint) for f in model.frames])
        self.frame_M = np.stack([np.asarray(f.placement.homogeneous) for f in model.frames])

    def _motion(self, i: int, q: np.ndarray) -> np.ndarray:
        """Joint motion ``(N, 4, 4)`` of joint ``i`` for joint values ``q`` (N,)."""
        n = q.shape[0]
        T = np.zeros((n, 4, 4))
        T[:, 3, 3] = 1.0
        a = self.axes[i]
        if self.kinds[i] == "P":
            T[:, 0, 0] = T[:, 1, 1] = T[:, 2, 2] = 1.0
            T[:, :3, 3] = q[:, None] * a
            return T
        c, s = np.cos(q), np.sin(q)
        K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
        # Rodrigues: R = I + s K + (1 - c) K^2
        T[:, :3, :3] = np.eye(3) + s[:, None, None] * K + (1.0 - c)[:, None, None] * (K @ K)
        return T

    def joints(self, Q: np.ndarray, only: set[int] | None = None) -> np.ndarray:
        """Placements of all joints ``(N, njoints, 4, 4)`` for configurations ``Q`` (N, nq); with ``only`` (joint
        indices closed under parents), only those are computed (the others are left unset)."""
        Q = np.asarray(Q, dtype=np.float64)
        n = Q.shape[0]
        out = np.empty((n, self.njoints, 4, 4))
        out[:, 0] = np.eye(4)
        for i in range(1, self.njoints):
            if only is None or i in only:
                out[:, i] = out[:, self.parents[i]] @ self.M[i] @ self._motion(i, Q[:, self.idx_q[i]])
        return out

    CHUNK = 4096  # configurations per pass in ``frames``: the working arrays stay in cache, not in fresh pages

    def frames(self, Q: np.ndarray, frame_ids) -> np.ndarray:
        """Placements ``(N, len(frame_ids), 4, 4)`` of the given frames (only the joints that move them are
        evaluated, a chunk of configurations at a time)."""
        Q = np.asarray(Q, dtype=np.float64)
        ids = np.asarray(frame_ids, dtype=int)
        need: set[int] = set()
        for j in self.frame_parent[ids]:
            while j > 0 and j not in need:
                need.add(int(j))
                j = self.parents[j]
        out = np.empty((len(Q), len(ids), 4, 4))
        for a in range(0, len(Q), self.CHUNK):
            J = self.joints(Q[a:a + self.CHUNK], need)
            out[a:a + self.CHUNK] = J[:, self.frame_parent[ids]] @ self.frame_M[ids]
        return out

"""Hand-over transfer poses chosen for a (giver grasp, receiver grasp) pair together.

The giver-first transfer poses (``_handover._transfer_moves``) turn the object so that the giver's approach
points along the line between the bases; where the receiver's grasp then ends up is left to chance, and at
the far end of the primary's reach the few giver grasps it reaches often leave no clear receiver the
secondary reaches (its IK fails at the grasp itself). Here the object's orientation at a transfer pose is
solved for each pair: the rotation that best takes the giver's approach to a direction away from the
primary's base and the receiver's approach to a direction away from the secondary's base (each tilted down
by a few angles), with a weak pull keeping the object's up near up (it decides the turn about the approaches
when they are opposite). That is a weighted orthogonal Procrustes (Wahba) problem, solved in a batch by SVD.

The candidates are then ranked by a list of named, weighted cost terms (:data:`PAIR_COST_TERMS`): both arms'
reach priors (``ArmReach.prior``: the distance of the pose to the nearest the arm was seen to reach) and the
receiver grasp's shortfall from a perfect score and from a sure hold; the exact checks (IK, clearance, the two-arm check) are the caller's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PairParams", "PAIR_COST_TERMS", "wahba_rotations", "pair_moves", "pair_costs"]

# name -> weight of each term of a pair candidate's cost: the two arms' reach priors (m) and the receiver
# grasp's shortfall from a perfect score (1 - score, in [0, 1]) and the probability that its pads miss the
# object (1 - hold probability of its depth, see ``_handover.giver_hold_probability``)
PAIR_COST_TERMS = {"giver_reach": 1.0, "receiver_reach": 1.0, "receiver_grasp": 0.02, "receiver_hold": 0.05}


@dataclass(frozen=True)
class PairParams:
    """giver_tilts / receiver_tilts: each approach's direction down from horizontal (radians) at the transfer
    pose; up_weight: the pull keeping the object upright, relative to the approaches' (1 each);
    receivers: clear receivers (best score first) paired with each giver; keep: candidates returned."""

    giver_tilts: tuple[float, ...] = (0.0, np.pi / 4, np.pi / 2)
    receiver_tilts: tuple[float, ...] = (0.0, np.pi / 4)
    up_weight: float = 0.2
    receivers: int = 16
    keep: int = 300


def wahba_rotations(src: np.ndarray, dst: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(N, 3, 3) proper rotations R minimising ``sum_i w_i |dst[n, i] - R src[n, i]|^2`` for unit vectors
    ``src``, ``dst`` (N, V, 3) and weights (V,) (Kabsch / Wahba, by batched SVD)."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 3 or src.shape[2] != 3:
        raise ValueError(f"src and dst must both be (N, V, 3); got {src.shape} and {dst.shape}")
    B = np.einsum("v,nvi,nvj->nij", np.asarray(weights, dtype=np.float64), dst, src)
    U, _, Vt = np.linalg.svd(B)
    d = np.sign(np.linalg.det(U @ Vt))
    U[:, :, 2] *= d[:, None]
    return U @ Vt


def _tilted(horizontal: np.ndarray, up: np.ndarray, tilts) -> np.ndarray:
    """(T, K, 3) unit directions: the horizontal ones (T, 3) tilted down from horizontal by each of ``tilts`` (K,)."""
    t = np.asarray(tilts, dtype=np.float64)
    return np.cos(t)[None, :, None] * horizontal[:, None] - np.sin(t)[None, :, None] * up


def _away(targets: np.ndarray, origin: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(T, 3) unit horizontal directions from ``origin`` (3,) to each target (T, 3)."""
    h = targets - origin
    h = h - np.outer(h @ up, up)
    return h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-9)


def pair_moves(centre: np.ndarray, up: np.ndarray, a_giver: np.ndarray, a_recv: np.ndarray, targets: np.ndarray,
               o_prim: np.ndarray, o_sec: np.ndarray, p: PairParams = PairParams()) -> tuple[np.ndarray, np.ndarray]:
    """Rigid motions of the object for one giver and R receivers.

    centre (3,): the object's centre where it lies; up (3,): up (b1); a_giver (3,), a_recv (R, 3): the
    approaches (z of g, b1) where it lies; targets (T, 3): the centre's places at the transfer poses;
    o_prim, o_sec (3,): the bases' origins (b1). Returns (moves (R, T, G, H, 4, 4), receiver of each (same
    leading shape) as an index into ``a_recv``), G x H the giver and receiver tilts."""
    a_recv = np.asarray(a_recv, dtype=np.float64).reshape(-1, 3)
    R, T = len(a_recv), len(targets)
    G, H = len(p.giver_tilts), len(p.receiver_tilts)
    d_g = _tilted(_away(targets, o_prim, up), up, p.giver_tilts)  # (T, G, 3)
    d_r = _tilted(_away(targets, o_sec, up), up, p.receiver_tilts)  # (T, H, 3)
    shape = (R, T, G, H)
    dst = np.stack([np.broadcast_to(d_g[None, :, :, None], shape + (3,)),
                    np.broadcast_to(d_r[None, :, None, :], shape + (3,)),
                    np.broadcast_to(up, shape + (3,))], axis=-2).reshape(-1, 3, 3)
    src = np.stack([np.broadcast_to(a_giver, shape + (3,)),
                    np.broadcast_to(a_recv[:, None, None, None], shape + (3,)),
                    np.broadcast_to(up, shape + (3,))], axis=-2).reshape(-1, 3, 3)
    Rot = wahba_rotations(src, dst, np.array([1.0, 1.0, p.up_weight]))
    moves = np.tile(np.eye(4), (len(Rot), 1, 1))
    moves[:, :3, :3] = Rot
    tgt = np.broadcast_to(targets[None, :, None, None], shape + (3,)).reshape(-1, 3)
    moves[:, :3, 3] = tgt - Rot @ np.asarray(centre, dtype=np.float64)
    which = np.broadcast_to(np.arange(R)[:, None, None, None], shape)
    return moves.reshape(shape + (4, 4)), which


def pair_costs(terms: dict[str, np.ndarray], weights: dict[str, float] = PAIR_COST_TERMS) -> np.ndarray:
    """(N,) the weighted sum of the named cost terms (each (N,), lower is better); a term without a weight in
    ``weights`` is an error."""
    unknown = set(terms) - set(weights)
    if unknown:
        raise ValueError(f"cost terms without a weight: {sorted(unknown)}; known: {sorted(weights)}")
    return np.sum([weights[name] * np.asarray(v, dtype=np.float64) for name, v in terms.items()], axis=0)

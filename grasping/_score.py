"""Grasp quality: a weighted sum of terms in [0, 1].

antipodal   how well the surface normals at the two finger faces line up with the closing axis, from the
            friction-cone edge (0) to perfectly opposed (1), the median over the points under each finger;
            the weaker of the two fingers counts; x 0.7
            when a finger lands only on points filled in by symmetric completion.
contact     how much of the fingers' length touches the object (z span of the closing region's points).
centring    horizontal distance from the contact centre to the object's centre of mass estimate
            (gravity-aligned box centre), relative to the object's half-diagonal: a grasp near the centre
            lifts without a torque that twists the object out of the fingers.
clearance   distance of the swept gripper from the rest of the scene (table, neighbours), up to 3 cm.
approach    1 from straight above, 0.5 from the side (never from below, which the sampler excludes); 1 for
            every direction when sampling an object held in the air (``full_circle``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["WEIGHTS", "score_grasps", "antipodal_quality", "Antipodal"]

class Antipodal(NamedTuple):
    antipodal: np.ndarray
    contact: np.ndarray
    count: np.ndarray
    seen_lo: np.ndarray
    seen_hi: np.ndarray
    min_cos: np.ndarray


WEIGHTS = {"antipodal": 0.30, "centring": 0.25, "clearance": 0.15, "approach": 0.15, "contact": 0.15}
CLEARANCE_LEVELS = (0.005, 0.01, 0.02, 0.03)
UNSEEN_CONTACT = 0.7  # antipodal term factor when one finger lands only on completed (unseen) points


def antipodal_quality(P: np.ndarray, N: np.ndarray, T_b_g: np.ndarray, width: np.ndarray, gripper, cone_cos: float,
                      band: float = 0.004, observed: np.ndarray | None = None, chunk: int = 128) -> Antipodal:
    """Per grasp (n,): antipodal term, contact term, the number of points in the closing region, whether the
    lower (-y) and the upper (+y) finger's side was seen, and the weaker finger's median |n . y|
    (an :class:`Antipodal` tuple).

    P (M, 3) object points and N (M, 3) their normals; T_b_g (n, 4, 4); width (n,). ``observed`` (M,) marks
    the points a camera saw: a finger whose contact band holds only completed points scales the term by
    ``UNSEEN_CONTACT``. Computed ``chunk`` grasps at a time (the (n, M) arrays of a thousand grasps on a
    few thousand points would not stay in cache).
    """
    if observed is None:
        observed = np.ones(len(P), dtype=bool)
    parts = [_antipodal_chunk(P, N, T_b_g[a:a + chunk], width[a:a + chunk], gripper, cone_cos, band, observed)
             for a in range(0, len(T_b_g), chunk)]
    if not parts:
        return Antipodal(*(np.zeros(0, dtype=d) for d in (float, float, int, bool, bool, float)))
    return Antipodal(*(np.concatenate(col) for col in zip(*parts)))


def _row_medians(mask: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(n,) the median of each row's ``values`` (n, M) where ``mask`` (n, M); NaN for an empty row. The same
    numbers as ``np.nanmedian`` over the masked rows (the mean of the two middle values for an even count),
    from one sort of the masked entries instead of a partition of every full row."""
    r, c = np.nonzero(mask)
    v = values[r, c]
    order = np.lexsort((v, r))
    v = v[order]
    counts = np.bincount(r, minlength=len(mask))
    starts = np.cumsum(counts) - counts
    has = counts > 0
    med = np.full(len(mask), np.nan)
    med[has] = (v[(starts + (counts - 1) // 2)[has]] + v[(starts + counts // 2)[has]]) / 2
    return med


def _antipodal_chunk(P, N, T_b_g, width, gripper, cone_cos: float, band: float, observed: np.ndarray) -> tuple:
    """``antipodal_quality`` for a few grasps T_b_g (n, 4, 4), width (n,)."""
    R = T_b_g[:, :3, :3]
    L = np.matmul(P[None], R) - np.matmul(T_b_g[:, None, :3, 3], R)
    fx, fz = gripper.finger_x, gripper.finger_z
    reg = ((L[..., 0] >= fx[0]) & (L[..., 0] <= fx[1]) & (L[..., 2] >= fz[0]) & (L[..., 2] <= fz[1])
           & (np.abs(L[..., 1]) <= width[:, None] / 2))
    y = L[..., 1]
    ymin = np.where(reg, y, np.inf).min(axis=1, keepdims=True)
    ymax = np.where(reg, y, -np.inf).max(axis=1, keepdims=True)
    ny = np.abs(R[:, :, 1] @ N.T)
    lo = reg & (y <= ymin + band)
    hi = reg & (y >= ymax - band)
    # median over each finger's band: the pad presses the face, and the few points of an adjacent face at
    # the edge (a box's top) must not decide; an empty band is a 0
    a_lo = np.nan_to_num(_row_medians(lo, ny), nan=0.0)
    a_hi = np.nan_to_num(_row_medians(hi, ny), nan=0.0)
    a = np.minimum(a_lo, a_hi)
    anti = np.clip((a - cone_cos) / (1 - cone_cos), 0.0, 1.0)
    # a finger's side counts as seen when a camera saw points of a face it presses (normal along the
    # closing axis), not only the edge of a neighbouring face
    face = observed[None] & (ny >= cone_cos)
    seen_lo, seen_hi = (lo & face).any(1), (hi & face).any(1)
    anti = anti * np.where(seen_lo & seen_hi, 1.0, UNSEEN_CONTACT)
    z = L[..., 2]
    zspan = np.where(reg, z, -np.inf).max(1) - np.where(reg, z, np.inf).min(1)
    contact = np.clip(np.where(np.isfinite(zspan), zspan, 0.0) / gripper.finger_length, 0.0, 1.0)
    return anti, contact, reg.sum(1), seen_lo, seen_hi, a


def score_grasps(gs, geo, support, gripper, collider, others, params):
    """Fill ``gs.terms`` and ``gs.score`` (see the module docstring); returns ``gs``."""
    n = len(gs)
    if n == 0:
        return gs
    T = gs.T_b1_g
    aq = antipodal_quality(geo.points, geo.normals, T, gs.width, gripper, params.cone_cos, observed=geo.observed)
    anti, contact = aq.antipodal, aq.contact
    gs.extra["seen"] = np.stack([aq.seen_lo, aq.seen_hi], axis=1)
    gs.extra["contact_cos"] = aq.min_cos
    up = support.up
    centre = T[:, :3, 3] - T[:, :3, 2] * gs.depth[:, None]
    d = centre - geo.centre
    d_h = np.linalg.norm(d - np.outer(d @ up, up), axis=1)
    r = max(0.5 * float(np.hypot(geo.extent[0], geo.extent[1])), 1e-3)
    centring = 1.0 - np.clip(d_h / r, 0.0, 1.0)
    approach = (np.ones(n) if params.full_circle  # in the air (hand-over): no direction is better
                else 0.5 + 0.5 * np.clip(-(T[:, :3, 2] @ up), 0.0, 1.0))
    clear = collider.clearance(others, T, gs.width, CLEARANCE_LEVELS) / CLEARANCE_LEVELS[-1]
    gs.terms = {"antipodal": anti, "centring": centring, "clearance": clear, "approach": approach, "contact": contact}
    gs.score = sum(WEIGHTS[k] * v for k, v in gs.terms.items())
    return gs

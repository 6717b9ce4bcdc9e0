"""Foundation-model emulator: what DUSt3R / MASt3R / VGGT would report for the rendered capture.

Pure functions on arrays. The true camera poses ``T_b1_c`` are perturbed (noise level, outliers), put into
a random frame ``w`` at a random scale (metric = scale * w units, so ``p_w = (T_w_b1 @ p_b1) / scale`` with
``T_w_b1``'s translation in metres), and each view's point map is the rendered depth (with depth noise)
back-projected through the *reported* pose, as a model's global alignment would make it: point maps of
a badly posed view are consistent with that bad pose.

Noise levels (per camera pose; the rotation error is a rotation about a uniformly random axis through
the camera centre, the translation error moves the camera centre):

| level | rotation error (RMS angle) | camera-centre error (RMS) | depth noise (1 sigma, relative) |
| --- | --- | --- | --- |
| none | 0 | 0 | 0 |
| low | 0.5 deg | 3 mm | 0.2 % |
| paper | 1.5 deg | 10 mm | 0.5 % |
| harsh | 3 deg | 25 mm | 1.5 % |

Each component of the rotation vector is N(0, (rms / sqrt 3)^2), likewise the centre offset, so the RMS
of the angle and of the offset norm are the table's values. Depth noise: per point-map pixel,
``z' = z (1 + s (0.8 n + 0.6 m))`` with ``n`` white N(0, 1) and ``m`` a smooth per-view field (bicubic
from a 4 x 3 grid of N(0, 1)): a sigma of about ``s`` with spatially correlated warps, like a network's.

Pose errors that turn about a point ahead of the camera (``NoiseLevel.pivot_m``, ``bijcr synth
--pose-pivot-m L``): an image pins the scene it shows better than the camera's pose, so a real
reconstruction's pose errors are mostly turns about a scene point the camera looks at (measured on a real
capture: about 1 m along the optical axis). With ``pivot_m = l`` the rotation error turns the camera about
the point ``(0, 0, l)`` of its own frame instead of its centre: that point stays where it was and the
centre moves by ``(R - R') (0, 0, l)`` (``l x dphi`` for small turns, ``dphi`` the rotation error), on top
of the level's own independent centre error. ``pivot_m = 0`` (every preset) is the camera-centre model,
with the same random draws and the same numbers as before the option existed.

Outliers: the chosen views get a rotation error of 10-40 degrees (uniform, random axis) and a centre
error of 10-30 cm (uniform, random direction) instead.

Point-map error models (``MAP_NOISES``; the level's own depth noise above is the default): ``fm`` is what a
foundation model gets wrong, a relative depth error per view made of a depth scale error (1 % sigma, one
number per view: the model's scale of that view differs from the others'), a smooth quadratic warp over
the image (RMS 0.5 %) and spatially correlated per-pixel noise (0.3 %, Gaussian correlation of 2 map
cells). Each view's map is still built with its reported pose, so map and pose err together.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bimanual_app.transforms import check_shape, check_T, make_T, so3_exp

BACKGROUND_DEPTH = 8.0  # metres: where rays that hit nothing are put (with the lowest confidence)
CONF_MIN, CONF_MAX = 1.0, 10.0


@dataclass(frozen=True)
class NoiseLevel:
    """Per-camera-pose noise: RMS rotation angle (deg), RMS camera-centre offset (m), relative depth sigma,
    and the distance (m) along the optical axis of the point the rotation errors turn about (0: the camera
    centre; ``dataclasses.replace(level, pivot_m=1.0)`` for a real model's errors, module docstring)."""

    name: str
    rot_deg: float
    trans_m: float
    depth_rel: float
    pivot_m: float = 0.0


NOISE_LEVELS = {
    "none": NoiseLevel("none", 0.0, 0.0, 0.0),
    "low": NoiseLevel("low", 0.5, 0.003, 0.002),
    "paper": NoiseLevel("paper", 1.5, 0.010, 0.005),
    "harsh": NoiseLevel("harsh", 3.0, 0.025, 0.015),
}


@dataclass(frozen=True)
class MapNoise:
    """A point-map (depth) error model: relative depth error ``e(u, v)`` of each view, ``z' = z (1 + e)``.

    ``e = scale_rel n_v + warp_rel q_v(u, v) + corr_rel c_v(u, v)``: ``n_v`` one N(0, 1) number per view
    (a depth scale error), ``q_v`` a quadratic polynomial in the normalised image coordinates with N(0, 1)
    coefficients, normalised to zero mean and unit RMS over the map, ``c_v`` white N(0, 1) noise smoothed
    by a Gaussian of ``corr_cells`` map cells and renormalised to unit standard deviation (white when 0).
    """

    name: str
    scale_rel: float
    warp_rel: float
    corr_rel: float
    corr_cells: float = 2.0


MAP_NOISES = {"fm": MapNoise("fm", 0.01, 0.005, 0.003, 2.0)}

OUTLIER_ROT_DEG = (10.0, 40.0)
OUTLIER_TRANS_M = (0.10, 0.30)


def _random_unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def perturb_poses(T_b1_c: np.ndarray, level: NoiseLevel, outlier: np.ndarray, rng: np.random.Generator
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reported camera poses (M, 4, 4) in b1 from the true ones (M, 4, 4).

    Args:
        outlier: (M,) bool, views that get a gross error instead of the level's noise.
    Returns:
        ``(T_b1_c_reported, rot_err_rad (M,), centre_err_m (M,))``; with ``level.pivot_m`` the centre error
        includes the move of the turn about the pivot (outlier views keep their gross error as drawn).
    """
    T = check_T("T_b1_c", T_b1_c)
    M = len(T)
    w = rng.normal(scale=np.deg2rad(level.rot_deg) / np.sqrt(3.0), size=(M, 3))
    dt = rng.normal(scale=level.trans_m / np.sqrt(3.0), size=(M, 3))
    n_out = int(np.sum(outlier))
    if n_out:
        w[outlier] = _random_unit(rng, n_out) * np.deg2rad(rng.uniform(*OUTLIER_ROT_DEG, n_out))[:, None]
        dt[outlier] = _random_unit(rng, n_out) * rng.uniform(*OUTLIER_TRANS_M, n_out)[:, None]
    R = T[:, :3, :3] @ so3_exp(w)  # rotation about the camera centre
    if level.pivot_m:  # ... or about the point pivot_m ahead: that point stays, the centre moves (R - R') l
        ell = np.array([0.0, 0.0, float(level.pivot_m)])
        dt = dt + np.where(np.asarray(outlier, dtype=bool)[:, None], 0.0, (T[:, :3, :3] - R) @ ell)
    out = make_T(R, T[:, :3, 3] + dt)
    return out, np.linalg.norm(w, axis=1), np.linalg.norm(dt, axis=1)


def choose_outliers(rng: np.random.Generator, n: int, fraction: float) -> np.ndarray:
    """(n,) bool: the views whose poses get gross errors: round(fraction * n) of them (at least one when
    fraction > 0), never the first view."""
    k = int(round(fraction * n))
    if fraction > 0:
        k = max(k, 1)
    out = np.zeros(n, dtype=bool)
    if k:
        out[1 + rng.choice(n - 1, size=min(k, n - 1), replace=False)] = True
    return out


def to_frame_w(T_b1_c: np.ndarray, T_w_b1: np.ndarray, scale: float) -> np.ndarray:
    """Camera poses in the reconstruction frame (M, 4, 4): ``T_w_b1 @ T_b1_c`` with translations / scale."""
    T = check_T("T_w_b1", T_w_b1) @ check_T("T_b1_c", T_b1_c)
    T[..., :3, 3] /= scale
    return T


def random_frame(rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """A random reconstruction frame: ``T_w_b1`` (uniform rotation, N(0, 0.5 m) translation) and a scale
    log-uniform in [0.25, 4] (metric = scale * w units)."""
    from scipy.spatial.transform import Rotation

    R = Rotation.random(random_state=rng).as_matrix()
    return make_T(R, rng.normal(scale=0.5, size=3)), float(np.exp(rng.uniform(np.log(0.25), np.log(4.0))))


def block_reduce(a: np.ndarray, fy: int, fx: int) -> np.ndarray:
    """(H, W, ...) -> (H/fy, W/fx, fy*fx, ...): the pixels of each block, for reductions."""
    H, W = a.shape[:2]
    b = a.reshape(H // fy, fy, W // fx, fx, *a.shape[2:])
    b = np.moveaxis(b, 2, 1)
    return b.reshape(H // fy, W // fx, fy * fx, *a.shape[2:])


def _smooth_field(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    import cv2

    grid = rng.normal(size=(3, 4)).astype(np.float32)
    return cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC).astype(np.float64)


def map_depth_error(model: MapNoise, h: int, w: int, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """One view's relative depth error (h, w) under ``model`` and its depth scale error (the per-view part)."""
    import cv2

    scale_err = float(model.scale_rel * rng.normal())
    y, x = np.meshgrid(np.linspace(-1.0, 1.0, h), np.linspace(-1.0, 1.0, w), indexing="ij")
    basis = np.stack([x, y, x * x, x * y, y * y])
    q = np.tensordot(rng.normal(size=5), basis, axes=1)
    q -= q.mean()
    q /= max(float(np.sqrt(np.mean(q ** 2))), 1e-12)
    c = rng.normal(size=(h, w))
    if model.corr_cells > 0:
        c = cv2.GaussianBlur(c, (0, 0), model.corr_cells, borderType=cv2.BORDER_REFLECT)
        c /= max(float(c.std()), 1e-12)
    return scale_err + model.warp_rel * q + model.corr_rel * c, scale_err


def point_map(depth: np.ndarray, rgb: np.ndarray, K: np.ndarray, T_w_c: np.ndarray, scale: float,
              size: tuple[int, int], depth_rel: float, rng: np.random.Generator,
              depth_error: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A model-like point map of one view at reduced resolution.

    Args:
        depth: (H, W) metric depth along the optical axis, inf where nothing is hit.
        rgb: (H, W, 3) uint8 image.
        K: (3, 3) intrinsics of the (H, W) image.
        T_w_c: (4, 4) the *reported* pose in w units.
        scale: metric = scale * w units.
        size: (w, h) of the point map; H and W must be multiples of h and w. Pixel (u, v) stands for the
            block of image pixels around ((u + 0.5) W / w - 0.5, (v + 0.5) H / h - 0.5).
        depth_rel: relative depth noise sigma (the noise level's own model; ignored with ``depth_error``).
        depth_error: (h, w) relative depth error replacing the level's noise (:func:`map_depth_error`), or None.
    Returns:
        ``pts3d`` (h, w, 3) float32 in w (16 mantissa bits, see :func:`compact_float32`), ``conf``
        (h, w) float32 in [1, 10] (two decimals), ``colors`` (h, w, 3) uint8 (block means of the image).

    Depth of a block = 1 / mean(1 / z) of its pixels (exact at the block centre for planes; blocks across
    a depth edge land in between: "flying pixels", as real models make them). Confidence drops at depth
    edges and creases (second difference of inverse depth), with distance beyond 0.8 m, and is the minimum
    where a block sees background.
    """
    from ._camera import pixel_rays

    H, W = depth.shape
    w, h = size
    if H % h or W % w:
        raise ValueError(f"point map size {w}x{h} must divide the image size {W}x{H}")
    fy, fx = H // h, W // w
    inv = np.where(np.isfinite(depth), 1.0 / depth, 1.0 / BACKGROUND_DEPTH)
    blocks = block_reduce(inv, fy, fx)
    inv_b = blocks.mean(axis=2)
    spread = blocks.max(axis=2) / blocks.min(axis=2) - 1.0  # relative depth range inside the block
    background = block_reduce(~np.isfinite(depth), fy, fx).any(axis=2)
    z = 1.0 / inv_b
    # edges / creases: a plane has linear inverse depth, so its second difference vanishes
    pad = np.pad(inv_b, 1, mode="edge")
    d2 = np.maximum(np.abs(pad[1:-1, :-2] - 2 * inv_b + pad[1:-1, 2:]), np.abs(pad[:-2, 1:-1] - 2 * inv_b + pad[2:, 1:-1]))
    edge = np.maximum(d2 / inv_b, spread)
    conf = CONF_MIN + (CONF_MAX - CONF_MIN) * np.exp(-(edge / 0.02) ** 2) * np.exp(-np.maximum(z - 0.8, 0.0) / 0.7)
    conf[background] = CONF_MIN
    if depth_error is not None:
        z = z * (1.0 + check_shape("depth_error", depth_error, (h, w)))
    elif depth_rel > 0:
        z = z * (1.0 + depth_rel * (0.8 * rng.normal(size=z.shape) + 0.6 * _smooth_field(rng, h, w)))
    rays = pixel_rays(K, w, h, W / w, H / h)
    P_c = rays * z[..., None]
    P_w = (P_c @ T_w_c[:3, :3].T) / scale + T_w_c[:3, 3]
    colors = block_reduce(rgb.astype(np.float64), fy, fx).mean(axis=2)
    conf = np.round(conf, 2)  # two decimals: plenty for a confidence, and it compresses
    return compact_float32(P_w), conf.astype(np.float32), np.clip(np.round(colors), 0, 255).astype(np.uint8)


def compact_float32(a: np.ndarray, keep_bits: int = 16) -> np.ndarray:
    """float32 copy of ``a`` rounded to ``keep_bits`` mantissa bits (of 23), so that zlib can compress it.

    16 bits is a relative precision of 1.5e-5: under 0.03 mm for points within 2 m of the frame's origin,
    far below any emulated noise. Rounds to nearest (ties away from zero in magnitude).
    """
    x = np.ascontiguousarray(a, dtype=np.float32)
    drop = 23 - keep_bits
    u = x.view(np.uint32).astype(np.uint64)
    u = (u + (1 << (drop - 1))) & ~np.uint64((1 << drop) - 1)
    return u.astype(np.uint32).view(np.float32).reshape(x.shape)

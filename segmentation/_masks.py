"""Per-image instance masks as extra evidence, carried into b1 through the reconstruction's point maps.

A scene's ``reconstruction.npz`` holds, per registered image, a point map ``pts3d`` (H, W, 3) in frame
w; the calibration maps w into b1 (``x_b1 = T_b1_w (scale * x_w)``). A mask image of the same view
(``<arm>/masks/<stem>.png``, any size: 0 = table/background, k > 0 = an instance; ids need not agree
between images) gives each point-map pixel an id. A point of the cloud then takes, per view, the id of
the nearest point-map pixel of that view within a small radius, or -1 when the view did not see it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bimanual_app.io_utils import InputError, Problem

#: points whose confidence is below this fraction of the view's median are dropped (background,
#: depth edges): confidence scales differ between producers, so the rule is relative.
CONF_FRACTION = 0.2


class MaskViews:
    """Mask ids of V views, each as a cloud of points in b1 with one id per point.

    Args:
        views: list of ``(points_b1 (M_v, 3), ids (M_v,) int)``.
        names: a name per view (``primary/images/000.png``), for reports.
        radius: a point takes a view's id when that view has a point within this distance (m).
    """

    def __init__(self, views: list[tuple[np.ndarray, np.ndarray]], names: list[str] | None = None,
                 radius: float = 0.008):
        from scipy.spatial import cKDTree

        self.names = list(names or [str(i) for i in range(len(views))])
        self.radius = float(radius)
        self._trees = [(cKDTree(p), np.asarray(i, dtype=np.int64)) for p, i in views if len(p)]

    def __len__(self) -> int:
        return len(self._trees)

    def lookup(self, points_b1: np.ndarray) -> np.ndarray:
        """(M, V) int64 mask id of each point (M, 3, b1) in each view; -1 where the view has no point near."""
        out = np.full((len(points_b1), len(self._trees)), -1, np.int64)
        for v, (tree, ids) in enumerate(self._trees):
            d, j = tree.query(points_b1, k=1, distance_upper_bound=self.radius, workers=-1)
            ok = np.isfinite(d)
            out[ok, v] = ids[j[ok]]
        return out

    @classmethod
    def from_scene(cls, scene_path: str | Path, T_b1_w: np.ndarray, scale: float, radius: float = 0.008,
                   stride: int = 1) -> MaskViews:
        """Views of a scene folder that have both a point map and a mask image.

        ``T_b1_w`` (4, 4) and ``scale`` come from the calibration (calibration.json). ``stride`` keeps
        every stride-th point-map pixel. Raises InputError when the scene has no point maps or no masks.
        """
        from PIL import Image

        from bimanual_app.scene import load_scene
        from bimanual_app.transforms import check_T

        T_b1_w = check_T("T_b1_w", np.asarray(T_b1_w, dtype=np.float64))
        scene = load_scene(scene_path)
        rec = scene.reconstruction
        root = Path(scene.path)
        if rec is None or rec.pts3d is None:
            raise InputError(Problem(str(root / "reconstruction.npz"), "pts3d", "no point maps: masks cannot be "
                                     "carried into the cloud", "run bijcr reconstruct on the scene first, or "
                                     "segment without --masks"))
        views, names = [], []
        for arm in scene.arms:
            _, rows = rec.rows_for(arm.index, arm.images)
            for j in rows:
                key = str(rec.image[j])
                mpath = root / arm.name / "masks" / f"{Path(key).stem}.png"
                if not mpath.is_file():
                    continue
                mask = np.asarray(Image.open(mpath))
                if mask.ndim == 3:
                    mask = mask[..., 0]
                P = rec.pts3d[j][::stride, ::stride]
                H, W = rec.pts3d.shape[1:3]
                hh, ww = P.shape[:2]
                vv = np.minimum(((np.arange(0, H, stride) + 0.5) * mask.shape[0] / H).astype(int), mask.shape[0] - 1)
                uu = np.minimum(((np.arange(0, W, stride) + 0.5) * mask.shape[1] / W).astype(int), mask.shape[1] - 1)
                ids = mask[vv[:, None], uu[None, :]].astype(np.int64)
                ok = np.all(np.isfinite(P), axis=-1)
                if rec.conf is not None:
                    c = rec.conf[j][::stride, ::stride]
                    pos = c[c > 0]
                    ok &= c > (CONF_FRACTION * float(np.median(pos)) if pos.size else 0.0)
                p = P[ok].astype(np.float64) * float(scale)
                views.append((p @ T_b1_w[:3, :3].T + T_b1_w[:3, 3], ids[ok]))
                names.append(f"{arm.name}/{key}")
        if not views:
            raise InputError(Problem(str(root), "masks", "no mask images next to the registered images "
                                     "(expected <arm>/masks/<image stem>.png)",
                                     "add one instance mask per image (0 = background, k > 0 = object) or "
                                     "segment without --masks"))
        return cls(views, names, radius)


def read_calibration(path: str | Path) -> tuple[np.ndarray, float, np.ndarray | None]:
    """``(T_b1_w (4, 4), scale, T_b1_b2 (4, 4) or None)`` from a calibration.json (InputError if unusable)."""
    import json

    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(Problem(str(path), "", "file not found", "run bijcr calibrate SCENE --out DIR first, "
                                 "or give its calibration.json with --calibration")) from None
    except (OSError, ValueError) as e:
        raise InputError(Problem(str(path), "", f"not readable as JSON ({e})", "give the calibration.json that "
                                 "bijcr calibrate wrote")) from None
    try:
        T = np.asarray(data["T_b1_w"], dtype=np.float64)
        s = float(data["scale"])
    except (KeyError, TypeError, ValueError):
        raise InputError(Problem(str(path), "T_b1_w / scale", "missing or malformed", "give the calibration.json "
                                 "that bijcr calibrate wrote (it has T_b1_w and scale)")) from None
    if T.shape != (4, 4) or not np.isfinite(T).all() or not (np.isfinite(s) and s > 0):
        raise InputError(Problem(str(path), "T_b1_w / scale", "not a 4x4 transform and a positive scale",
                                 "re-run bijcr calibrate"))
    T12 = data.get("T_b1_b2")
    T12 = np.asarray(T12, dtype=np.float64) if T12 is not None else None
    if T12 is not None and (T12.shape != (4, 4) or not np.isfinite(T12).all()):
        T12 = None
    return T, s, T12

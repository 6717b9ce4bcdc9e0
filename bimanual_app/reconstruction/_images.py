"""The scene's images: check they exist, can be read, and have one size per camera (arm)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bimanual_app.io_utils import InputError, Problem
from bimanual_app.scene import ArmCapture, CameraIntrinsics, Scene

__all__ = ["ArmImages", "check_images", "read_rgb", "arm_intrinsics"]


@dataclass
class ArmImages:
    """One arm's images, all checked.

    Attributes:
        arm: the capture (CSV rows).
        names: (N,) scene-relative paths (``primary/images/000.png``), the names COLMAP sees.
        size: (W, H) of every image of this arm.
    """

    arm: ArmCapture
    names: list[str]
    size: tuple[int, int]


def read_rgb(path: Path) -> np.ndarray | None:
    """(H, W, 3) uint8 RGB image, or None when the file cannot be decoded."""
    import cv2  # here, not at the top: ``bijcr --help`` imports this module

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    return None if img is None else np.ascontiguousarray(img[:, :, ::-1])


def _header_size(path: Path) -> tuple[int, int] | None:
    """(W, H) from the file header (Pillow reads only the header), or None when unreadable."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            im.verify()
        with Image.open(path) as im:  # verify() leaves the file unusable: reopen for the size
            return int(im.size[0]), int(im.size[1])
    except Exception:  # any decoder error: truncated, not an image, unsupported
        return None


def check_images(scene: Scene) -> dict[str, ArmImages]:
    """Check every image of both arms; raise :class:`InputError` naming each bad image.

    Problems found: missing files, files that do not decode as images, and images of a size
    different from the rest of their arm's (one camera per arm means one size per arm).
    """
    problems: list[Problem] = []
    out: dict[str, ArmImages] = {}
    for arm in scene.arms:
        names, sizes = [], {}
        csv_name = f"{arm.name}/ee_poses.csv"
        for key in arm.images:
            rel = f"{arm.name}/{key}"
            path = scene.path / rel
            names.append(rel)
            if not path.is_file():
                problems.append(Problem(rel, "", f"image file is missing (row of {csv_name})",
                                        f"put the image at {path} or remove its row from {csv_name}"))
                continue
            size = _header_size(path)
            if size is None or read_rgb(path) is None:
                problems.append(Problem(rel, "", "cannot be read as an image (corrupt, truncated or not an image)",
                                        "re-export it as PNG or JPEG, or remove its row"))
                continue
            sizes[rel] = size
        if sizes:
            common, _ = Counter(sizes.values()).most_common(1)[0]
            odd = {k: s for k, s in sizes.items() if s != common}
            for rel, s in odd.items():
                problems.append(Problem(rel, "size", f"is {s[0]}x{s[1]} but the other {arm.name} images are "
                                        f"{common[0]}x{common[1]} (one camera per arm: one image size)",
                                        "capture all of an arm's images at one resolution, or resize them all"))
            out[arm.name] = ArmImages(arm, names, common)
    if problems:
        raise InputError(problems)
    return out


def arm_intrinsics(scene: Scene, images: ArmImages) -> CameraIntrinsics | None:
    """scene.yaml's intrinsics for this arm's image size (scaled when the aspect ratio matches), or None.

    Raises :class:`InputError` when the images' aspect ratio differs from scene.yaml's camera.
    """
    cam = scene.camera
    if cam is None:
        return None
    W, H = images.size
    if (W, H) == (cam.width, cam.height):
        return cam
    if abs(W / H - cam.width / cam.height) > 0.01:
        raise InputError(Problem("scene.yaml", "camera", f"intrinsics are for {cam.width}x{cam.height} images but the "
                                 f"{images.arm.name} images are {W}x{H} (another aspect ratio)",
                                 "give the intrinsics of the images as captured, or drop 'camera' to let COLMAP estimate them"))
    return cam.scaled(W, H)

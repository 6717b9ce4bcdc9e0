"""Frame sources for the capture: a real camera through OpenCV, or a folder of images (stand-in).

Both return ``(H, W, 3) uint8`` frames in OpenCV's BGR order, ready for ``cv2.imwrite``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Protocol

import numpy as np

from bimanual_app.io_utils import InputError, Problem

from ._errors import HardwareError

__all__ = ["CameraSource", "CameraError", "OpenCVCamera", "ImageFolderCamera", "open_camera", "IMAGE_SUFFIXES"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


class CameraError(HardwareError):
    """The camera cannot be opened or delivers no frame."""


class CameraSource(Protocol):
    description: str

    def open(self) -> None: ...

    def grab(self) -> np.ndarray: ...

    def close(self) -> None: ...


class OpenCVCamera:
    """A camera through ``cv2.VideoCapture`` (device index, ``/dev/videoN``, or a stream URL).

    Args:
        source: device index or path/URL.
        width, height: requested frame size (None: the camera's default).
        flush_frames: frames read and dropped before each grab, so the frame is taken *after* the arm
            settled and not from the driver's buffer (V4L2 keeps a few frames).
        timeout_s: how long to retry a failing read.
    """

    def __init__(self, source: int | str = 0, width: int | None = None, height: int | None = None,
                 flush_frames: int = 5, timeout_s: float = 2.0):
        self.source = source
        self.width, self.height = width, height
        self.flush_frames = flush_frames
        self.timeout_s = timeout_s
        self.description = f"OpenCV camera {source!r}"
        self._cap = None

    def open(self) -> None:
        import cv2

        cap = cv2.VideoCapture(self.source)
        if not cap.isOpened():
            raise CameraError(f"cannot open {self.description} (is it connected? try another --camera index)")
        if self.width:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
        if self.height:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        self._cap = cap

    def grab(self) -> np.ndarray:
        if self._cap is None:
            self.open()
        for _ in range(self.flush_frames):
            self._cap.grab()
        t_end = time.monotonic() + self.timeout_s
        while True:
            ok, frame = self._cap.read()
            if ok and frame is not None and frame.size:
                return frame if frame.ndim == 3 else np.repeat(frame[..., None], 3, axis=2)
            if time.monotonic() > t_end:
                raise CameraError(f"{self.description} delivered no frame within {self.timeout_s:.1f} s")
            time.sleep(0.02)

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


class ImageFolderCamera:
    """Serves image files in name order, one per :meth:`grab` (a camera stand-in for tests and dry runs).

    Args:
        folder: a folder of images, or a list of image files.
        loop: start again after the last file (else running out is an error).
    """

    def __init__(self, folder: str | Path | list, loop: bool = False):
        if isinstance(folder, (list, tuple)):
            self.files = [Path(f) for f in folder]
            where = f"{len(self.files)} files"
        else:
            folder = Path(folder)
            if not folder.is_dir():
                raise InputError(Problem(str(folder), "", "camera stand-in folder does not exist", "give a folder of images"))
            self.files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            where = str(folder)
        if not self.files:
            raise InputError(Problem(where, "", "no image files (png, jpg, ...) to serve", "put images there"))
        self.loop = loop
        self.description = f"image folder {where}"
        self._i = 0

    def open(self) -> None:
        self._i = 0

    def grab(self) -> np.ndarray:
        import cv2

        if self._i >= len(self.files):
            if not self.loop:
                raise CameraError(f"{self.description}: all {len(self.files)} images were served")
            self._i = 0
        path = self.files[self._i]
        self._i += 1
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise CameraError(f"{self.description}: cannot read {path}")
        return img

    def close(self) -> None:
        pass


def open_camera(spec: str | int, width: int | None = None, height: int | None = None) -> CameraSource:
    """A camera from a CLI value: an integer -> OpenCV device index; an existing folder -> the image-folder
    stand-in; anything else -> OpenCV path/URL (``/dev/video2``, ``rtsp://...``)."""
    s = str(spec).strip()
    if s.lstrip("-").isdigit():
        return OpenCVCamera(int(s), width, height)
    if Path(s).is_dir():
        return ImageFolderCamera(s)
    return OpenCVCamera(s, width, height)

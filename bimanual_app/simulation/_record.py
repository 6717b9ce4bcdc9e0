"""Frames of the preview: TinyRenderer images at a fixed rate -> animated GIF, plus named key frames (PNG).

TinyRenderer rasterises every triangle of every body for each frame, and the table, which covers much of
the picture and never moves, costs about a third of a frame. So the bodies that cannot move (no joints, no
mass) are rendered once, with their depth, and each frame renders the others alone and keeps, pixel by
pixel, the nearer of the two: the same image (shadows are off, so no body changes another's pixels), for
two thirds of the cost. The still picture is rendered again when a still body's pose or colour changes."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np

from bimanual_app.io_utils import atomic_path

__all__ = ["Recorder", "default_camera"]


def default_camera(T_b1_b2: np.ndarray, focus: np.ndarray | None = None) -> dict:
    """A side view of the workspace: looking at the point between the bases (or ``focus`` (3,)),
    from the side of the line joining the two bases, 1.3 m away, 30 degrees down."""
    b2 = np.asarray(T_b1_b2, dtype=np.float64)[:3, 3]
    mid = b2 / 2 if focus is None else 0.5 * (b2 / 2) + 0.5 * np.asarray(focus, dtype=np.float64)
    target = [float(mid[0]), float(mid[1]), 0.15]
    d = b2[:2] if np.linalg.norm(b2[:2]) > 1e-6 else np.array([1.0, 0.0])
    yaw = float(np.degrees(np.arctan2(d[1], d[0])))  # camera looks across the base line
    return {"target": target, "distance": max(1.1, 1.4 * float(np.linalg.norm(b2[:2]))), "yaw": yaw, "pitch": -30.0}


class Recorder:
    """Captures frames every ``1/fps`` s of simulated time and key frames on request.

    Args:
        width, height: image size in pixels.
        fps: animation frame rate (simulated time); the GIF plays in real time.
        camera: dict with ``target`` (3,), ``distance``, ``yaw``, ``pitch`` (degrees); default from the world.
        max_frames: frames beyond this are dropped evenly (keeps GIFs small for long tasks).
    """

    def __init__(self, width: int = 360, height: int = 270, fps: float = 10.0, camera: dict | None = None,
                 max_frames: int = 400):
        self.width, self.height, self.fps = int(width), int(height), float(fps)
        self.camera = camera
        self.max_frames = int(max_frames)
        self.frames: list[np.ndarray] = []
        self.keyframes: list[tuple[str, np.ndarray]] = []
        self._next = 0.0
        self._world = None
        self._view = self._proj = None
        self._bodies: _Bodies | None = None
        self._background: tuple | None = None  # (still bodies' state, colour, depth)

    def attach(self, world) -> None:
        self._world = world
        if self.camera is None:
            self.camera = default_camera(world.T_b1_b2)
        self._matrices()

    def _matrices(self) -> None:
        p = self._world.p
        c = self.camera
        self._view = p.computeViewMatrixFromYawPitchRoll(c["target"], c["distance"], c["yaw"], c["pitch"], 0.0, 2)
        self._proj = p.computeProjectionMatrixFOV(45.0, self.width / self.height, 0.05, 6.0)

    def _shot(self) -> tuple[np.ndarray, np.ndarray]:
        """The world as TinyRenderer draws it now: ((H, W, 3) uint8 colour, (H, W) float32 depth buffer)."""
        w = self._world
        p = w.p
        img = p.getCameraImage(self.width, self.height, self._view, self._proj, renderer=p.ER_TINY_RENDERER,
                               shadow=0, lightDirection=[0.4, -0.6, 1.0], flags=p.ER_NO_SEGMENTATION_MASK,
                               physicsClientId=w.cid)
        rgba = np.reshape(np.asarray(img[2], dtype=np.uint8), (self.height, self.width, 4))
        return rgba[:, :, :3].copy(), np.reshape(np.asarray(img[3], dtype=np.float32), (self.height, self.width))

    def render(self) -> np.ndarray:
        """(H, W, 3) uint8 image of the world now (the still bodies from their cached picture: module notes)."""
        bodies = self._split_bodies()
        if not bodies.still or not bodies.moving:
            return self._shot()[0]
        key = bodies.key(self._world)
        if self._background is None or self._background[0] != key:
            with bodies.hidden(self._world, bodies.moving):
                self._background = (key, *self._shot())
        _, rgb_bg, depth_bg = self._background
        with bodies.hidden(self._world, bodies.still):
            rgb, depth = self._shot()
        return np.where((depth < depth_bg)[..., None], rgb, rgb_bg)

    def _split_bodies(self) -> _Bodies:
        """The world's bodies, split into still and moving (again when bodies were added)."""
        w = self._world
        n = w.p.getNumBodies(physicsClientId=w.cid)
        if self._bodies is None or self._bodies.count != n:
            self._bodies = _Bodies.of(w)
            self._background = None
        return self._bodies

    def on_step(self, world) -> None:
        if world.time + 1e-9 >= self._next:
            self.frames.append(self.render())
            self._next = world.time + 1.0 / self.fps

    def keyframe(self, name: str) -> np.ndarray:
        """Render now and keep the image as key frame ``name`` (also added to the animation)."""
        im = self.render()
        self.keyframes.append((name, im))
        return im

    def _frames_for_gif(self) -> list[np.ndarray]:
        f = self.frames
        if len(f) > self.max_frames:
            idx = np.linspace(0, len(f) - 1, self.max_frames).round().astype(int)
            f = [f[i] for i in idx]
        return f

    def save_gif(self, path: str | Path) -> Path:
        """Write the animation (atomic), playing in real time. Raises ValueError when no frame was captured.

        Every frame is mapped to one palette (median cut over a sample of the frames, Pillow): colours do
        not flicker from frame to frame, and it costs a fifth of quantizing each frame on its own."""
        from PIL import Image

        frames = self._frames_for_gif()
        if not frames:
            raise ValueError("no frames were recorded")
        step = max(1, int(np.ceil(len(self.frames) / max(len(frames), 1))))
        ms = max(20, int(round(1000.0 * step / self.fps)))  # per frame, so the GIF plays in real time
        sample = np.concatenate(frames[:: max(1, len(frames) // 8)], axis=0)
        palette = Image.fromarray(sample).quantize(256, method=Image.Quantize.MEDIANCUT)
        ims = [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]
        path = Path(path)
        with atomic_path(path) as tmp:
            ims[0].save(tmp, format="GIF", save_all=True, append_images=ims[1:], duration=ms, loop=0)
        return path

    def save_keyframes(self, folder: str | Path, prefix: str = "") -> list[Path]:
        """Write each key frame as ``folder/{prefix}{k:02d}_{name}.png`` (atomic); returns the paths."""
        import imageio.v2 as imageio

        out = []
        for k, (name, im) in enumerate(self.keyframes):
            safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name)
            path = Path(folder) / f"{prefix}{k:02d}_{safe}.png"
            with atomic_path(path) as tmp:
                imageio.imwrite(tmp, im, format="PNG")
            out.append(path)
        return out


class _Bodies:
    """A world's bodies for rendering: ``still`` (fixed base, no joints, massless) and ``moving`` ids (both
    empty when the world must be rendered whole)."""

    def __init__(self, count: int, still: list[int], moving: list[int]):
        self.count, self.still, self.moving = count, still, moving

    @classmethod
    def of(cls, world) -> _Bodies:
        p, cid = world.p, world.cid
        n = p.getNumBodies(physicsClientId=cid)
        ids = [p.getBodyUniqueId(k, physicsClientId=cid) for k in range(n)]
        for b in ids:
            colours: dict[int, set] = {}
            for v in p.getVisualShapeData(b, physicsClientId=cid):
                colours.setdefault(int(v[1]), set()).add(tuple(v[7]))
            if any(len(c) > 1 for c in colours.values()):
                # pybullet recolours a link's visual shapes together: hiding them and showing them again would
                # lose the differing colours, so such a world is rendered whole
                return cls(n, [], [])
        still = [b for b in ids if p.getNumJoints(b, physicsClientId=cid) == 0
                 and p.getDynamicsInfo(b, -1, physicsClientId=cid)[0] == 0.0]
        return cls(n, still, [b for b in ids if b not in still])

    def key(self, world) -> tuple:
        """The still bodies' poses and colours: the cached picture holds while this does not change."""
        p, cid = world.p, world.cid
        return tuple((b, p.getBasePositionAndOrientation(b, physicsClientId=cid),
                      tuple(tuple(v[7]) for v in p.getVisualShapeData(b, physicsClientId=cid))) for b in self.still)

    @staticmethod
    @contextlib.contextmanager
    def hidden(world, bodies: list[int]):
        """Within the block, ``bodies`` are transparent, which TinyRenderer skips (colour and depth); their
        colours as they were before the block are given back after it."""
        p, cid = world.p, world.cid
        colours = {(b, int(v[1])): list(v[7]) for b in bodies for v in p.getVisualShapeData(b, physicsClientId=cid)}
        for b, link in colours:
            p.changeVisualShape(b, link, rgbaColor=[0.0, 0.0, 0.0, 0.0], physicsClientId=cid)
        try:
            yield
        finally:
            for (b, link), rgba in colours.items():
                p.changeVisualShape(b, link, rgbaColor=rgba, physicsClientId=cid)

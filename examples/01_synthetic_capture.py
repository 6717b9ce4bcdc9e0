"""01 - Make a synthetic capture with ground truth and validate it.

A real PyBullet scene (table, textured objects, two Piper arms with wrist cameras) rendered from N
viewpoints per arm, plus a foundation-model emulator's reconstruction.npz.

    .venv/bin/python examples/01_synthetic_capture.py [OUT]
"""

import sys
from pathlib import Path

from bimanual_app.scene import load_scene
from bimanual_app.synth import make_synthetic_scene

out = Path(sys.argv[1] if len(sys.argv) > 1 else "runs/example_scene")
scene_dir = make_synthetic_scene(out, seed=3, views=8, objects=5, noise="paper", overwrite=True)
scene = load_scene(scene_dir)
print(f"{scene.name}: {len(scene.primary)} primary and {len(scene.secondary)} secondary views")
print(f"reconstruction by '{scene.reconstruction.model}', point maps {scene.reconstruction.pts3d.shape}")
print(f"preview picture: {scene_dir / 'preview.png'}")

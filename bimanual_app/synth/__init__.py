"""Synthetic captures: a PyBullet table-top scene, two Piper arms with wrist cameras, a foundation-model emulator.

Public API:
    make_synthetic_scene(out_dir, seed=0, views=8, objects=5, noise="paper", outliers=0.0, render=True,
                         touching=0.5, ...) -> Path
    ground_truth_cloud(scene_path, ...) -> (points_b1 (N, 3) float64, colors (N, 3) uint8, labels (N,) int32)
    NOISE_LEVELS: the emulator's noise levels (name -> NoiseLevel(rot_deg, trans_m, depth_rel)).
    MAP_NOISES: point-map error models (``make_synthetic_scene(map_noise="fm")``; name -> MapNoise).
    VIEWS_RANGE, OBJECTS_RANGE: the views per arm and objects it makes, (lo, hi) inclusive.
    mesh_hull(kind, size) -> (K, 3): a catalogue mesh's convex hull at a ground-truth size (its collision shape).
    (ground_truth_cloud and mesh_hull live in bimanual_app.scene, which readers of ground truth use.)
See docs/synth.md.
"""

from bimanual_app.scene import ground_truth_cloud, mesh_hull

from ._emulator import MAP_NOISES, NOISE_LEVELS, MapNoise, NoiseLevel
from ._generate import OBJECTS_RANGE, VIEWS_RANGE, make_synthetic_scene

__all__ = ["make_synthetic_scene", "VIEWS_RANGE", "OBJECTS_RANGE", "ground_truth_cloud", "mesh_hull", "NOISE_LEVELS", "NoiseLevel", "MAP_NOISES", "MapNoise"]

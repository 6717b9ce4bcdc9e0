"""Scene folders and results, per the data contract (docs/scene-format.md).

Also what ground truth means, for scenes that have it: ``ground_truth_cloud(scene_path, ...)`` (the true
metric cloud in b1 with object labels, from a rendered synthetic scene's depth) and ``mesh_hull(kind, size)``
(the collision hull of a catalogue mesh that a ground-truth object names).
"""

from .load import load_reconstruction, load_scene, validate_scene
from .meshes import mesh_hull
from .truth import ground_truth_cloud
from .types import ARM_INDEX, ARM_NAMES, ArmCapture, CameraIntrinsics, GroundTruth, Reconstruction, Scene
from .write import write_ee_poses, write_ground_truth, write_reconstruction, write_scene

__all__ = [
    "ARM_INDEX", "ARM_NAMES", "ArmCapture", "CameraIntrinsics", "GroundTruth", "Reconstruction", "Scene",
    "load_scene", "validate_scene", "load_reconstruction",
    "write_scene", "write_ee_poses", "write_reconstruction", "write_ground_truth",
    "ground_truth_cloud", "mesh_hull",
]

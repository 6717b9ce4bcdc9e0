"""Scene folders and results, per the data contract (docs/scene-format.md)."""

from .load import load_reconstruction, load_scene, validate_scene
from .types import ARM_INDEX, ARM_NAMES, ArmCapture, CameraIntrinsics, GroundTruth, Reconstruction, Scene
from .write import write_ee_poses, write_ground_truth, write_reconstruction, write_scene

__all__ = [
    "ARM_INDEX", "ARM_NAMES", "ArmCapture", "CameraIntrinsics", "GroundTruth", "Reconstruction", "Scene",
    "load_scene", "validate_scene", "load_reconstruction",
    "write_scene", "write_ee_poses", "write_reconstruction", "write_ground_truth",
]

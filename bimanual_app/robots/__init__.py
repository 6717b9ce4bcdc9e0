"""Robot models: the project's AgileX Piper (URDF written from the reference kinematics) and any URDF.

Public API:
    load_robot(name_or_urdf_path, base_dir=None, ee_link=None) -> RobotModel
    known_robots() -> list[str]
    RobotModel: .name .urdf_path .model .nq_arm .lower .upper .velocity_limits .accel_limits .ee_link
                .tcp_link .T_e_g .fk(q) .fk_link(q, link) .fk_frames(q, links) .random_q(n, rng)
    PIPER_URDF: path of the packaged Piper URDF.
"""

from bimanual_app.robots._model import RobotModel, load_robot
from bimanual_app.robots._registry import REGISTRY, RobotSpec, known_robots

PIPER_URDF = REGISTRY["piper"].urdf

__all__ = ["RobotModel", "RobotSpec", "load_robot", "known_robots", "PIPER_URDF"]

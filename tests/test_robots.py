"""Robot models: the Piper URDF against piper_sdk's FK, PyBullet and Pinocchio agreement, the registry."""

from __future__ import annotations

import os

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bimanual_app.io_utils import InputError
from bimanual_app.robots import PIPER_URDF, known_robots, load_robot
from bimanual_app.transforms import rotation_angle_between


@pytest.fixture(scope="module")
def piper():
    return load_robot("piper")


def _pybullet_data() -> str:
    import pybullet_data

    return pybullet_data.getDataPath()


def _sdk_T(pose) -> np.ndarray:
    """piper_sdk pose [x, y, z mm, roll, pitch, yaw deg] (R = Rz Ry Rx) -> T (4,4) in metres."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("ZYX", [pose[5], pose[4], pose[3]], degrees=True).as_matrix()
    T[:3, 3] = np.asarray(pose[:3]) / 1000.0
    return T


def test_piper_fk_matches_piper_sdk(piper):
    from piper_sdk.kinematics import C_PiperForwardKinematics

    sdk = C_PiperForwardKinematics()  # default dh_is_offset=1 (the 2-degree offset setting)
    Q = piper.random_q(200, rng=1)
    T_model = piper.fk(Q)  # batched path
    pos_err, ang_err = [], []
    for q, T in zip(Q, T_model):
        T_sdk = _sdk_T(sdk.CalFK(list(q))[5])  # link6 = the flange
        pos_err.append(np.linalg.norm(T[:3, 3] - T_sdk[:3, 3]))
        ang_err.append(rotation_angle_between(T[:3, :3], T_sdk[:3, :3]))
        np.testing.assert_allclose(piper.fk(q), T, atol=1e-12)  # single (Pinocchio) path == batched path
    assert max(pos_err) < 0.5e-3, f"max position error {max(pos_err) * 1e3:.3f} mm"
    assert np.degrees(max(ang_err)) < 0.1, f"max orientation error {np.degrees(max(ang_err)):.4f} deg"
    # the error is a small rounding of the reference table (~0.1 mm), not a frame mismatch
    assert max(pos_err) < 0.2e-3


def test_piper_model_facts(piper):
    assert piper.nq_arm == 6 and piper.model.nq == 8
    assert piper.ee_link == "link6" and piper.tcp_link == "gripper_tcp"
    assert piper.finger_joints == ["joint7", "joint8"]
    np.testing.assert_allclose(piper.lower, [-2.618, 0, -2.967, -1.745, -1.22, -2.0944])
    np.testing.assert_allclose(piper.upper, [2.618, 3.14, 0, 1.745, 1.22, 2.0944])
    np.testing.assert_allclose(piper.velocity_limits, 3.0)
    np.testing.assert_allclose(piper.accel_limits, 5.0)
    mass = sum(inertia.mass for inertia in piper.model.inertias)
    assert 3.5 < mass < 5.0
    assert piper.collision_model.ngeoms >= 10  # primitive shapes only, no meshes
    names = {f.name for f in piper.model.frames}
    assert {"base_link", "link1", "link6", "gripper_base", "link7", "link8", "gripper_tcp"} <= names


def test_packaged_urdf_is_the_generator_output():
    from bimanual_app.robots._piper_urdf import piper_urdf_text

    assert PIPER_URDF.read_text() == piper_urdf_text()
    assert "<mesh" not in PIPER_URDF.read_text()


@pytest.mark.parametrize("opening", [0.0, 0.03, 0.07])
def test_piper_gripper_frame(piper, opening):
    """g: origin midway between the fingertips, z approach (away from the palm), y closing direction."""
    np.testing.assert_allclose(piper.T_e_g[:3, :3], np.eye(3), atol=1e-9)
    np.testing.assert_allclose(piper.T_e_g[:3, 3], [0, 0, 0.1358], atol=1e-9)
    q = piper.random_q(1, rng=3)[0]
    T_b_g = piper.fk_link(q, "gripper_tcp", opening=opening)
    np.testing.assert_allclose(T_b_g, piper.fk(q) @ piper.T_e_g, atol=1e-12)
    T_g_b = np.linalg.inv(T_b_g)
    tip7 = (T_g_b @ piper.fk_link(q, "link7", opening=opening))[:3, 3]
    tip8 = (T_g_b @ piper.fk_link(q, "link8", opening=opening))[:3, 3]
    # 1e-6: the table's angles are rounded (1.5708 for pi/2), which tilts the finger axes by ~4e-6 rad
    np.testing.assert_allclose(tip7, [0, -opening / 2, 0], atol=1e-6)
    np.testing.assert_allclose(tip8, [0, opening / 2, 0], atol=1e-6)
    # the palm (gripper_base) lies behind g along -z
    palm = (T_g_b @ piper.fk_link(q, "gripper_base"))[:3, 3]
    assert palm[2] < -0.1


def test_batch_fk_matches_pinocchio_for_every_frame(piper):
    import pinocchio as pin

    data = piper.model.createData()
    Q = piper.full_q(piper.random_q(10, rng=4), opening=0.05)
    names = [f.name for f in piper.model.frames]
    batch = piper.fk_frames(Q, names)
    for k, q in enumerate(Q):
        pin.framesForwardKinematics(piper.model, data, q)
        for i in range(len(names)):
            np.testing.assert_allclose(batch[k, i], data.oMf[i].homogeneous, atol=1e-12)


def test_batch_fk_of_one_frame_across_chunks_matches_pinocchio(piper, monkeypatch):
    """``frames`` evaluates only the joints above the asked frame, a chunk of configurations at a time."""
    import pinocchio as pin

    monkeypatch.setattr(piper._batch, "CHUNK", 3)
    data = piper.model.createData()
    Q = piper.random_q(8, rng=5)
    T = piper.fk_link(Q, piper.tcp_link)
    fid = piper.frame_id(piper.tcp_link)
    for k, q in enumerate(Q):
        pin.framesForwardKinematics(piper.model, data, piper.full_q(q))
        np.testing.assert_allclose(T[k], data.oMf[fid].homogeneous, atol=1e-12)


def _pybullet_link_poses(urdf: str, q_full: np.ndarray, link_names: list[str]) -> dict[str, np.ndarray]:
    import pybullet as p

    cid = p.connect(p.DIRECT)
    try:
        body = p.loadURDF(urdf, useFixedBase=True, physicsClientId=cid)
        index = {}
        movable = []
        for j in range(p.getNumJoints(body, physicsClientId=cid)):
            info = p.getJointInfo(body, j, physicsClientId=cid)
            index[info[12].decode()] = j
            if info[2] in (p.JOINT_REVOLUTE, p.JOINT_PRISMATIC):
                movable.append(j)
        assert len(movable) == len(q_full)
        for j, v in zip(movable, q_full):
            p.resetJointState(body, j, float(v), physicsClientId=cid)
        out = {}
        for name in link_names:
            st = p.getLinkState(body, index[name], computeForwardKinematics=True, physicsClientId=cid)
            T = np.eye(4)
            T[:3, :3] = Rotation.from_quat(st[5]).as_matrix()
            T[:3, 3] = st[4]
            out[name] = T
        return out
    finally:
        p.disconnect(cid)


def test_piper_pybullet_and_pinocchio_agree(piper):
    links = ["link1", "link2", "link3", "link4", "link5", "link6", "gripper_base", "link7", "link8", "gripper_tcp"]
    for seed in range(5):
        q = piper.full_q(piper.random_q(1, rng=10 + seed)[0], opening=0.04)
        pb = _pybullet_link_poses(str(PIPER_URDF), q, links)
        for name in links:
            np.testing.assert_allclose(piper.fk_link(q, name), pb[name], atol=1e-6, err_msg=name)


@pytest.mark.parametrize(
    "rel, ee",
    [("franka_panda/panda.urdf", None), ("franka_panda/panda.urdf", "panda_hand"), ("xarm/xarm6_robot.urdf", None)],
)
def test_registry_loads_other_urdfs(rel, ee):
    robot = load_robot(rel, base_dir=_pybullet_data(), ee_link=ee)
    assert robot.nq_arm == (7 if "panda" in rel else 6)
    assert robot.ee_link == (ee or ("panda_link7" if "panda" in rel else "link6"))
    assert robot.T_e_g is None
    assert np.all(robot.velocity_limits > 0) and np.all(robot.accel_limits > 0)
    for seed in range(3):
        q = robot.random_q(1, rng=seed)[0]
        qf = robot.full_q(q)
        pb = _pybullet_link_poses(str(robot.urdf_path), qf, [robot.ee_link])
        np.testing.assert_allclose(robot.fk(q), pb[robot.ee_link], atol=1e-5)
    assert robot.collision_model.ngeoms > 0  # meshes resolved relative to the URDF


def test_registry_errors(tmp_path):
    assert "piper" in known_robots()
    with pytest.raises(InputError, match="unknown robot 'ur5'.*piper"):
        load_robot("ur5")
    with pytest.raises(InputError, match="not found"):
        load_robot("missing/arm.urdf", base_dir=tmp_path)
    with pytest.raises(InputError, match="no link named 'flange'"):
        load_robot("piper", ee_link="flange")
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot name='x'><link name='a'/><joint name='j' type='revolute'>")
    with pytest.raises(InputError, match="bad.urdf"):
        load_robot(str(bad))
    # relative to base_dir
    rel = os.path.relpath(PIPER_URDF, PIPER_URDF.parent.parent)
    robot = load_robot(rel, base_dir=PIPER_URDF.parent.parent)
    assert robot.nq_arm == 6 and robot.name == "piper"


def test_fk_shapes_and_limits(piper):
    q = piper.neutral()
    assert piper.fk(q).shape == (4, 4)
    assert piper.fk(np.stack([q, q, q])).shape == (3, 4, 4)
    assert piper.within_limits(q) and not piper.within_limits(piper.upper + 0.1)
    with pytest.raises(ValueError, match="last dimension"):
        piper.fk(np.zeros(5))
    with pytest.raises(ValueError, match="no link"):
        piper.fk_link(q, "nope")

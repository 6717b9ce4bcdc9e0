import numpy as np
import pytest

from bimanual_app import transforms as tf


def test_inverse_and_compose_roundtrip():
    rng = np.random.default_rng(0)
    T = tf.random_T(rng, 10)
    I = tf.inv_T(T) @ T
    assert np.allclose(I, np.eye(4), atol=1e-12)
    p_b = rng.normal(size=3)
    T_a_b = T[0]
    p_a = tf.apply_T(T_a_b, p_b)
    assert np.allclose(tf.apply_T(tf.inv_T(T_a_b), p_a), p_b)


def test_quaternion_roundtrip_is_xyzw_by_name():
    T = tf.T_from_xyz_quat([0.1, 0.2, 0.3], [0.0, 0.7071068, 0.0, 0.7071068])
    # 90 deg about y: x axis goes to -z
    assert np.allclose(T[:3, :3] @ [1, 0, 0], [0, 0, -1], atol=1e-6)
    xyz, q = tf.xyz_quat_from_T(T)
    assert np.allclose(xyz, [0.1, 0.2, 0.3]) and np.allclose(q, [0, 0.7071068, 0, 0.7071068], atol=1e-6)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-4, 0.5, np.pi - 1e-6, np.pi])
def test_log_exp_stable_at_small_and_large_angles(angle):
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    R = tf.so3_exp(axis * angle)
    w = tf.so3_log(R)
    assert np.all(np.isfinite(w))
    assert np.isclose(np.linalg.norm(w), angle, atol=1e-6)
    assert np.allclose(tf.so3_exp(w), R, atol=1e-9)


def test_mean_rotation_is_a_rotation_and_not_elementwise():
    rng = np.random.default_rng(1)
    R0 = tf.so3_exp(rng.normal(size=3))
    Rs = R0 @ tf.so3_exp(rng.normal(scale=0.05, size=(50, 3)))
    M = tf.mean_rotation(Rs)
    assert np.allclose(M.T @ M, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(M), 1)
    assert np.degrees(tf.rotation_angle_between(M, R0)) < 1.5
    T = tf.mean_T(tf.make_T(Rs, rng.normal(size=(50, 3))))
    tf.check_T("mean", T)


def test_check_T_rejects_bad_transforms():
    with pytest.raises(ValueError, match="non-finite"):
        tf.check_T("X", np.full((4, 4), np.nan))
    bad = np.eye(4)
    bad[0, 0] = 2
    with pytest.raises(ValueError, match="orthonormal"):
        tf.check_T("X", bad)
    refl = np.diag([1.0, 1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match="reflection"):
        tf.check_T("X", refl)
    with pytest.raises(ValueError, match="shape"):
        tf.check_T("X", np.eye(3))


def test_project_to_SO3():
    rng = np.random.default_rng(2)
    R = tf.project_to_SO3(rng.normal(size=(5, 3, 3)))
    assert np.allclose(np.swapaxes(R, 1, 2) @ R, np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(R), 1)

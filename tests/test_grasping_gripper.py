"""The gripper model read from the Piper URDF: stroke, finger and palm geometry, the contract's frame g."""

import numpy as np

from grasping import load_gripper


def test_piper_gripper_stroke_and_fingers():
    g = load_gripper("piper")
    assert abs(g.stroke - 0.070) < 1e-4  # 70 mm stroke (2 x 35 mm finger travel in the URDF)
    assert 0.0 <= g.min_width < 0.005 and abs(g.max_width - g.min_width - 0.070) < 1e-4
    # fingertips at z = 0 (origin midway between the closed fingertips), fingers reach back along -z
    assert abs(g.finger_z[1]) < 1e-6 and g.finger_length > 0.03
    assert g.palm_z <= g.finger_z[0] + 1e-3  # the palm is behind the fingers
    assert g.finger_width > 0.01
    roles = sorted(s.role for s in g.shapes)
    assert roles.count("finger") == 2 and roles.count("palm") >= 1


def test_frame_convention_fingers_close_along_y():
    g = load_gripper("piper")
    fingers = [s for s in g.shapes if s.role == "finger"]
    for w in (g.min_width, 0.04, g.max_width):
        boxes = [s.aabb_g0 + s.motion_g * w for s in fingers]
        ys = sorted(boxes, key=lambda b: b[0, 1])
        # one finger on each side of the y = 0 plane; the inner gap equals the opening
        assert ys[0][1, 1] <= 1e-9 and ys[1][0, 1] >= -1e-9
        assert abs((ys[1][0, 1] - ys[0][1, 1]) - w) < 1e-6
        for b in boxes:  # fingers move along y only: x and z extents do not change with the opening
            assert np.allclose(b[:, [0, 2]], boxes[0][:, [0, 2]], atol=1e-6)
    # motion along +-y
    for s in fingers:
        assert abs(abs(s.motion_g[1]) - 0.5) < 1e-6 and np.allclose(s.motion_g[[0, 2]], 0, atol=1e-5)


def test_T_e_g_matches_robot_model():
    from bimanual_app.robots import load_robot

    g = load_gripper("piper")
    r = load_robot("piper")
    assert np.allclose(g.T_e_g, r.T_e_g, atol=1e-9)
    # the robot's finger joints at the gripper's opening reproduce the width
    assert abs(g.robot_opening(0.05) - (0.05 - g.min_width)) < 1e-6

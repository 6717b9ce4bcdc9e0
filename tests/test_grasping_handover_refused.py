"""A pick a task's preview saw fail is refused as a giver, either way round its approach."""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import make_T, so3_exp
from grasping._antipodal import rotate_about_approach
from grasping._handover import REFUSED_SHIFT, REFUSED_TURN, refused


def rot_z(a: float) -> np.ndarray:
    return so3_exp(np.array([0.0, 0.0, a]))


def test_a_pick_near_a_refused_one_is_the_same_pick():
    T = make_T(rot_z(0.3), np.array([0.3, -0.1, 0.05]))
    near = make_T(rot_z(0.3 + 0.5 * REFUSED_TURN), T[:3, 3] + [0.5 * REFUSED_SHIFT, 0.0, 0.0])
    turned = make_T(rot_z(0.3 + 2 * REFUSED_TURN), T[:3, 3])  # the same place, closing across another way
    moved = make_T(rot_z(0.3), T[:3, 3] + [2 * REFUSED_SHIFT, 0.0, 0.0])
    poses = np.stack([T, near, rotate_about_approach(T), turned, moved])
    assert refused(poses, (T,)).tolist() == [True, True, True, False, False]
    assert not refused(poses, ()).any() and refused(poses[:0], (T,)).shape == (0,)

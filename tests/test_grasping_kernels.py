"""The grasp planner's vectorised kernels against plain references: gripper-against-gripper collisions (a
sphere broad phase before coal), the object-against-scene clearance (a grid before the KD-tree) and the
capability prior (a bounded nearest-neighbour search)."""

from __future__ import annotations

import numpy as np
import pytest

from grasping import GripperCollider, load_gripper, rotate_about_approach
from grasping._collision import PointClearance, grippers_collide, grippers_collide_many, obb_overlap


@pytest.fixture(scope="module")
def collider():
    return GripperCollider(load_gripper("piper"), approach=0.09)


def _random_poses(rng, n: int, spread: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.random(n, random_state=rng.integers(1 << 31)).as_matrix()
    T[:, :3, 3] = rng.normal(0.0, spread, (n, 3))
    return T


def _coal_reference(collider, T1, w1, T2, w2, margin, swept1, swept2) -> bool:
    """Every shape pair through coal, no broad phase."""
    import coal

    geoms = [g for g, _ in collider.swept], [s.geometry for s in collider.gripper.shapes]
    A = collider._placements(T1[None], np.array([w1]), swept1)[0]
    B = collider._placements(T2[None], np.array([w2]), swept2)[0]
    req, res = coal.CollisionRequest(), coal.CollisionResult()
    req.security_margin = margin
    for sa, Ta in zip(geoms[0] if swept1 else geoms[1], A):
        for sb, Tb in zip(geoms[0] if swept2 else geoms[1], B):
            res.clear()
            if coal.collide(sa, coal.Transform3s(Ta[:3, :3], Ta[:3, 3]), sb, coal.Transform3s(Tb[:3, :3], Tb[:3, 3]),
                            req, res):
                return True
    return False


@pytest.mark.parametrize("swept1,swept2", [(False, False), (False, True), (True, False)])
def test_grippers_collide_many_equals_pairwise_coal(collider, swept1, swept2):
    rng = np.random.default_rng(3)
    T1 = _random_poses(rng, 1, 0.0)[0]
    T2 = _random_poses(rng, 150, 0.08)  # many near, some touching, some far
    w2 = rng.uniform(0.01, 0.07, 150)
    got = grippers_collide_many(collider, T1, 0.03, T2, w2, margin=0.015, swept1=swept1, swept2=swept2)
    want = np.array([_coal_reference(collider, T1, 0.03, T2[k], w2[k], 0.015, swept1, swept2) for k in range(150)])
    assert 10 < want.sum() < 140  # both outcomes occur
    assert np.array_equal(got, want)
    assert grippers_collide(collider, T1, 0.03, T2[0], w2[0], 0.015, swept1, swept2) == want[0]


def test_obb_overlap_equals_coal_on_boxes():
    """The separating-axis broad phase agrees with coal on pairs of boxes, touching or not, parallel included."""
    import coal

    rng = np.random.default_rng(8)
    n = 3000
    A, B = _random_poses(rng, n, 0.05), _random_poses(rng, n, 0.05)
    B[:200, :3, :3] = A[:200, :3, :3]  # parallel edges: cross-product axes vanish
    h1, h2 = rng.uniform(0.005, 0.05, (n, 3)), rng.uniform(0.005, 0.05, (n, 3))
    got = obb_overlap(A[:, :3, 3], A[:, :3, :3], h1, B[:, :3, 3], B[:, :3, :3], h2)
    req = coal.CollisionRequest()
    want = np.array([coal.collide(coal.Box(*(2 * h1[p])), coal.Transform3s(A[p, :3, :3], A[p, :3, 3]),
                                  coal.Box(*(2 * h2[p])), coal.Transform3s(B[p, :3, :3], B[p, :3, 3]), req,
                                  coal.CollisionResult()) for p in range(n)])
    assert 0.1 < want.mean() < 0.9 and 0.1 < want[:200].mean() < 0.9
    assert np.array_equal(got, want)


def test_point_clearance_equals_kdtree():
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(4)
    scene = np.c_[rng.uniform(-0.5, 0.5, (20000, 2)), rng.uniform(0.0, 0.02, 20000)]  # a table
    scene = np.vstack([scene, rng.uniform([0.1, 0.1, 0.0], [0.2, 0.2, 0.15], (3000, 3))])  # a box on it
    obj = rng.normal(0.0, 0.03, (300, 3))
    centres = np.c_[rng.uniform(-0.6, 0.6, (400, 2)), rng.uniform(-0.02, 0.3, 400)]
    moved = obj[None] + centres[:, None]
    d, _ = cKDTree(scene).query(moved.reshape(-1, 3), k=1)
    want = (d.reshape(400, -1) >= 0.025).all(axis=1)
    assert 20 < want.sum() < 380
    assert np.array_equal(PointClearance(scene, 0.025).clear(moved), want)
    # a region that holds only some of the moved points: the others are answered by the whole tree
    region = (np.array([-0.3, -0.3, 0.0]), np.array([0.3, 0.3, 0.2]))
    assert np.array_equal(PointClearance(scene, 0.025, region).clear(moved), want)
    assert np.array_equal(PointClearance(scene, 0.025, region).clear(moved[:1]), want[:1])


def test_prior_is_the_nearest_map_pose_within_its_horizon():
    from bimanual_app.robots import load_robot
    from grasping import ArmReach

    robot = load_robot("piper")
    arm = ArmReach(robot, load_gripper("piper"))
    rng = np.random.default_rng(6)
    T = robot.fk_link(robot.random_q(300, rng=rng), robot.tcp_link)
    T[:, :3, 3] += rng.normal(0.0, 0.08, (300, 3))
    got = arm.prior(T)
    tree = arm._pose_map
    d = []
    for Tk in (T, rotate_about_approach(T)):
        f = np.concatenate([Tk[:, :3, 3], arm._ROT_W * Tk[:, :3, :3].reshape(-1, 9)], axis=1)
        d.append(tree.query(f, k=1)[0])
    want = np.minimum(*d)
    inside = want < arm.PRIOR_HORIZON
    assert 30 < inside.sum() < 290
    assert np.allclose(got[inside], want[inside], atol=1e-12)
    assert np.all(np.isinf(got[~inside]) | (got[~inside] >= arm.PRIOR_HORIZON))


def test_prior_min_equals_the_minimum_over_every_moved_pose():
    from bimanual_app.robots import load_robot
    from grasping import ArmReach

    robot = load_robot("piper")
    arm = ArmReach(robot, load_gripper("piper"))
    rng = np.random.default_rng(9)
    T_set = _random_poses(rng, 40, 0.03)  # grasps about an object at the origin
    moves = _random_poses(rng, 120, 0.0)
    moves[:, :3, 3] = np.c_[rng.uniform(0.1, 0.45, 120), rng.uniform(-0.3, 0.3, 120), rng.uniform(0.0, 0.35, 120)]
    got = arm.prior_min(moves, T_set, cut=0.045)
    full = arm.prior((moves[:, None] @ T_set[None]).reshape(-1, 4, 4)).reshape(120, 40).min(axis=1)
    inside = full < 0.045
    assert 10 < inside.sum() < 110
    assert np.allclose(got[inside], full[inside], atol=1e-12)
    assert np.all(np.isinf(got[~inside]))


def test_dedupe_equals_pairwise_reference():
    from grasping._antipodal import GraspSet, _dedupe

    rng = np.random.default_rng(10)
    n = 400
    T = _random_poses(rng, n, 0.004)  # many within 4 mm of each other
    T[:, :3, :3] = T[rng.integers(0, 20, n), :3, :3]  # and only 20 orientations
    score = rng.uniform(0, 1, n)
    gs = GraspSet(0, T, np.full(n, 0.03), np.full(n, 0.02), np.zeros(n), score, {}, kind="pinch")
    got = _dedupe(gs, 60)

    order, kept, cos_t = np.argsort(-score), [], np.cos(np.deg2rad(8))
    for i in order:  # the plain best-first pairwise rule
        if not any(np.linalg.norm(T[i, :3, 3] - T[j, :3, 3]) < 0.004 and T[i, :3, 2] @ T[j, :3, 2] > cos_t
                   and abs(T[i, :3, 1] @ T[j, :3, 1]) > cos_t for j in kept):
            kept.append(i)
            if len(kept) >= 60:
                break
    assert 20 < len(kept) and np.array_equal(got.T_b1_g, T[kept])


@pytest.mark.parametrize("swept,margin", [(True, 0.0), (False, 0.003), (True, 0.02)])
def test_collides_with_broad_phase_equals_coal_on_every_shape(collider, swept, margin):
    import coal

    from grasping import SceneOctree

    rng = np.random.default_rng(12)
    table = np.c_[rng.uniform(-0.3, 0.3, (30000, 2)), np.zeros(30000)]
    box = rng.uniform([0.0, 0.0, 0.0], [0.06, 0.06, 0.1], (4000, 3))
    scene = SceneOctree(np.vstack([table, box]), 0.005)
    T = _random_poses(rng, 300, 0.0)
    T[:, :3, 3] = np.c_[rng.uniform(-0.2, 0.25, (300, 2)), rng.uniform(0.0, 0.3, 300)]
    w = rng.uniform(0.01, 0.07, 300)
    got = collider.collides(scene, T, w, swept=swept, margin=margin)
    P = collider._placements(T, w, swept)
    geoms = [g for g, _ in collider.swept] if swept else [s.geometry for s in collider.gripper.shapes]
    req = coal.CollisionRequest()
    req.security_margin = margin

    def touches(i: int, k: int) -> bool:
        return coal.collide(geoms[k], coal.Transform3s(P[i, k, :3, :3], P[i, k, :3, 3]), scene.octree,
                            coal.Transform3s(), req, coal.CollisionResult())

    want = np.array([any(touches(i, k) for k in range(len(geoms))) for i in range(300)])
    assert 20 < want.sum() < 280
    assert np.array_equal(got, want)
    active = rng.uniform(size=300) < 0.5
    assert np.array_equal(collider.collides(scene, T, w, swept=swept, margin=margin, active=active), want & active)


def test_row_medians_equal_nanmedian_bit_for_bit():
    import warnings

    from grasping._score import _row_medians

    rng = np.random.default_rng(21)
    for _ in range(100):
        n, m = rng.integers(1, 30), rng.integers(1, 60)
        mask = rng.uniform(size=(n, m)) < rng.uniform()
        v = rng.normal(size=(n, m))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows
            want = np.nanmedian(np.where(mask, v, np.nan), axis=1)
        np.testing.assert_array_equal(_row_medians(mask, v), want)  # NaN where empty, on both sides

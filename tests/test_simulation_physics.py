"""Physics preview: a scripted grasp-and-lift of a body built from points holds; a miss does not; a
scripted handover ends with the object held by the secondary gripper only; frames are recorded."""

import numpy as np
import pytest

from bimanual_app.hardware import JointTrajectory, joint_move
from bimanual_app.robots import load_robot
from bimanual_app.simulation import HoldMonitor, Recorder, build_world, shape_from_points, table_from_plane
from bimanual_app.transforms import inv_T, make_T
from tests._task_fixtures import R_TILTED, T_B1_B2, box_surface_points, grasp_R, ik

SEED = np.array([0.0, 1.2, -1.0, 0.0, 0.5, 0.0])


@pytest.fixture(scope="module")
def robot():
    return load_robot("piper")


def _slow(robot):
    return robot.velocity_limits * 0.4, robot.accel_limits * 0.4


def _grip(q, w0, w1, t=0.8):
    return JointTrajectory([0.0, t], [q, q], [w0, w1])


def _pick(world, robot, obj, centre_xy, grasp_z, lift_to):
    """Primary: pre-grasp 8 cm back along the approach, approach, close, lift to ``lift_to`` (3,)."""
    arm = world.arms["primary"]
    a = R_TILTED[:, 2]
    g = np.array([centre_xy[0], centre_xy[1], grasp_z])
    qg = ik(robot, make_T(R_TILTED, g), SEED)
    qpre = ik(robot, make_T(R_TILTED, g - 0.08 * a), qg)
    qup = ik(robot, make_T(R_TILTED, lift_to), qg)
    arm.reset(qpre, 0.07)
    v, acc = _slow(robot)
    world.run_plan({"primary": joint_move(qpre, qg, v, acc)})
    world.run_plan({"primary": _grip(qg, 0.07, 0.0)}, settle=0.3)
    world.run_plan({"primary": joint_move(qg, qup, v, acc)}, settle=0.2)
    return qup


@pytest.mark.parametrize("offset, expect", [(0.0, True), (0.07, False)])
def test_grasp_and_lift_of_a_body_built_from_points(robot, offset, expect, tmp_path):
    size = np.array([0.04, 0.045, 0.10])
    pts = box_surface_points([0.32, 0.0, 0.05], size, 1500, noise=0.0005)
    table = table_from_plane([0, 0, 1], 0.0)
    shape = shape_from_points(pts, table)
    rec = Recorder(width=160, height=120, fps=5)
    world, phys = build_world(robot, T_B1_B2, table, {0: shape}, recorder=rec)
    try:
        obj = phys[0]
        assert world.on_table(obj) and world.height(obj) == pytest.approx(0.05, abs=0.005)
        world.arms["secondary"].reset(robot.neutral(), 0.0)
        mon = HoldMonitor(world, obj)
        world.add_listener(mon)
        # a miss: the same motion aimed 7 cm to the side of the object
        _pick(world, robot, obj, (0.32, offset), 0.085, [0.30, offset, 0.25])
        rec.keyframe("lifted")
        world.hold(2.2)
        v = mon.lifted_and_held({"primary"}, rise=0.10, hold_s=2.0)
        assert v.ok is expect, v.detail
        if expect:
            assert v.max_rise > 0.12 and world.arms["primary"].holds(obj.body)
            assert 0.035 < world.arms["primary"].width() < 0.05  # stopped by the 4.5 cm object, not closed
        else:
            assert world.on_table(obj) and v.max_rise < 0.02
            assert "rose only" in v.detail
        gif = rec.save_gif(tmp_path / "p.gif")
        pngs = rec.save_keyframes(tmp_path)
        assert gif.stat().st_size > 1000 and [p.name for p in pngs] == ["00_lifted.png"]
        assert not list(tmp_path.glob(".*tmp*"))  # atomic writes leave no temporary files
    finally:
        world.close()


def test_handover_ends_held_by_the_secondary_only(robot):
    table = table_from_plane([0, 0, 1], 0.0)
    from bimanual_app.simulation import box_shape

    box = box_shape(make_T(np.eye(3), [0.28, 0.0, 0.06]), [0.04, 0.04, 0.12], mass=0.15)
    world, phys = build_world(robot, T_B1_B2, table, {0: box})
    try:
        obj = phys[0]
        P, S = world.arms["primary"], world.arms["secondary"]
        S.reset(robot.neutral(), 0.07)
        mon = HoldMonitor(world, obj)
        world.add_listener(mon)
        qT = _pick(world, robot, obj, (0.28, 0.0), 0.09, [0.28, 0.0, 0.31])
        # secondary: horizontal approach from its side onto the lower half, closing along b1's -y
        c = world.object_pose(obj)[:3, 3]
        Rs = grasp_R([-1, 0, 0], [0, -1, 0])
        iT = inv_T(T_B1_B2)
        qs_pre = ik(robot, iT @ make_T(Rs, c + [0.10, 0, -0.035]), SEED)
        qs = ik(robot, iT @ make_T(Rs, c + [0.0, 0, -0.035]), qs_pre)
        v, acc = _slow(robot)
        world.run_plan({"secondary": joint_move(robot.neutral(), qs_pre, v, acc)})
        world.run_plan({"secondary": joint_move(qs_pre, qs, v, acc)})
        world.run_plan({"secondary": _grip(qs, 0.07, 0.0)}, settle=0.3)
        both = world.time
        world.hold(0.3)
        assert P.holds(obj.body) and S.holds(obj.body)
        v_both = mon.lifted_and_held({"secondary"}, hold_s=0.25, since=both, exclusive=True)
        assert not v_both.ok and "touched by primary" in v_both.detail
        # primary releases and retreats; the secondary alone keeps the object up
        world.run_plan({"primary": _grip(qT, 0.0, 0.07)}, settle=0.2)
        t = world.time
        world.run_plan({"primary": joint_move(qT, qT + [0, -0.35, 0, 0, 0, 0], v, acc)})
        world.hold(2.2)
        verdict = mon.lifted_and_held({"secondary"}, rise=0.10, hold_s=2.0, since=t, exclusive=True)
        assert verdict.ok, verdict.detail
        assert not P.touches(obj.body) and not world.on_table(obj)
    finally:
        world.close()


def test_a_push_is_a_hold_of_the_gripper_not_of_both_fingers(robot):
    """An open gripper, tilted, pressing one fingertip down on a box: the gripper presses it (a push hold),
    but the fingers do not pinch it (one finger carries the load)."""
    from bimanual_app.simulation import box_shape

    table = table_from_plane([0, 0, 1], 0.0)
    box = box_shape(make_T(np.eye(3), [0.30, 0.0, 0.03]), [0.08, 0.08, 0.06], mass=0.2)
    world, phys = build_world(robot, T_B1_B2, table, {0: box})
    try:
        obj = phys[0]
        arm = world.arms["primary"]
        down = grasp_R([0, 0.5, -1], [0, 1, 0])  # tilted about x: one fingertip lower than the other
        q_above = ik(robot, make_T(down, [0.30, 0.0, 0.07]), SEED)
        q_in = ik(robot, make_T(down, [0.30, 0.0, 0.055]), q_above)  # 5 mm into the top face
        arm.reset(q_above, 0.06)
        v, acc = _slow(robot)
        world.run_plan({"primary": joint_move(q_above, q_in, v, acc)}, settle=0.3)
        assert arm.presses(obj.body, 2.0) and not arm.holds(obj.body)
        mon = HoldMonitor(world, obj, grip={"primary": "push"})
        assert "primary" in mon.sample().holders
        assert "primary" not in HoldMonitor(world, obj).sample().holders
    finally:
        world.close()


def test_a_press_into_a_rigid_box_is_compliant_not_effort_limited(robot):
    """A pushing gripper's contacts are compliant (PAD_STIFFNESS): pressing 1 cm into a box on the table gives
    tens of newtons, as a position-controlled Piper would, not the hundreds its rigid joint motors could
    push with (which drove fingertips over the top edge of cartons in two-arm squeezes)."""
    from bimanual_app.simulation import box_shape

    table = table_from_plane([0, 0, 1], 0.0)
    box = box_shape(make_T(np.eye(3), [0.30, 0.0, 0.03]), [0.08, 0.08, 0.06], mass=0.5)
    world, phys = build_world(robot, T_B1_B2, table, {0: box})
    try:
        obj = phys[0]
        arm = world.arms["primary"]
        down = grasp_R([0, 0, -1], [0, 1, 0])
        q_above = ik(robot, make_T(down, [0.30, 0.0, 0.08]), SEED)
        q_in = ik(robot, make_T(down, [0.30, 0.0, 0.05]), q_above)  # closed fingertips 1 cm into the top face
        arm.reset(q_above, 0.0)
        arm.set_push_compliance()
        v, acc = _slow(robot)
        world.run_plan({"primary": joint_move(q_above, q_in, v, acc)}, settle=0.5)
        total = 0.0
        for link in arm.gripper_links:
            total += sum(c[9] for c in world.p.getContactPoints(arm.body, obj.body, linkIndexA=link,
                                                               physicsClientId=world.cid))
        assert 5.0 < total < 120.0, total
    finally:
        world.close()


def test_an_object_that_fell_off_the_table_is_said_so():
    """The verdict's detail says the object fell off the table rather than that it "rose only -7509 cm"."""
    from types import SimpleNamespace

    from bimanual_app.simulation._checks import HoldSample

    world = SimpleNamespace(height=lambda obj: 0.05, dt=1.0 / 240.0)
    mon = HoldMonitor(world, SimpleNamespace(body=0))
    mon.samples = [HoldSample(t, -0.5 * t * t * 9.81, frozenset(), frozenset(), False) for t in np.arange(0, 3, 0.1)]
    v = mon.lifted_and_held({"secondary"}, rise=0.10, hold_s=2.0)
    assert not v.ok and "fell off the table" in v.detail and "rose only" not in v.detail
    mon.samples = [HoldSample(t, 0.03, frozenset(), frozenset(), False) for t in np.arange(0, 3, 0.1)]
    assert "rose only 3.0 cm" in mon.lifted_and_held({"secondary"}).detail


def test_frames_drawn_over_the_cached_still_bodies_equal_whole_renders(robot):
    """The recorder draws the still bodies (the table) once and the moving ones each frame; the pictures are
    the ones TinyRenderer gives for the whole world, while the arm and the object move, and after a still
    body moved (its cached picture is redrawn); a recolour made by the world is kept."""
    table = table_from_plane([0, 0, 1], 0.0)
    shape = shape_from_points(box_surface_points([0.32, 0.0, 0.05], np.array([0.04, 0.045, 0.10]), 1500), table)
    rec = Recorder(width=120, height=90)
    world, phys = build_world(robot, T_B1_B2, table, {0: shape}, recorder=rec)
    p, cid = world.p, world.cid

    def whole():
        return rec._shot()[0]

    try:
        bodies = rec._split_bodies()
        assert len(bodies.still) == 1 and len(bodies.moving) == 3  # the table; two arms and the object
        for q in (robot.neutral(), SEED):
            world.arms["primary"].reset(q, 0.05)
            world.hold(0.1)
            assert np.array_equal(rec.render(), whole())
        p.resetBasePositionAndOrientation(phys[0].body, [0.25, 0.1, 0.3], [0, 0, 0, 1], physicsClientId=cid)
        assert np.array_equal(rec.render(), whole())
        (table_id,) = bodies.still
        p.resetBasePositionAndOrientation(table_id, [0.0, 0.0, -0.05], [0, 0, 0, 1], physicsClientId=cid)
        assert np.array_equal(rec.render(), whole())
        p.changeVisualShape(phys[0].body, -1, rgbaColor=[0.9, 0.1, 0.1, 1.0], physicsClientId=cid)
        img = rec.render()
        assert np.array_equal(img, whole())
        assert p.getVisualShapeData(phys[0].body, physicsClientId=cid)[0][7] == pytest.approx((0.9, 0.1, 0.1, 1.0))
    finally:
        world.close()

"""Task building blocks: the plan timeline, object choice from grasps.json, the robot-points filter."""

import numpy as np
import pytest

from bimanual_app.hardware import JointTrajectory
from bimanual_app.io_utils import InputError
from bimanual_app.tasks import Phase, TaskPlan, handover_candidates, joint_candidates
from bimanual_app.tasks._grasps import choose
from bimanual_app.tasks._motion import PlanFailure, robot_points_mask


def test_timeline_joins_phases_on_one_clock_and_idle_arms_hold():
    q0 = {"primary": np.zeros(6), "secondary": np.ones(6)}
    plan = TaskPlan(q0, {"primary": 0.0, "secondary": 0.0})
    q1 = np.full(6, 0.2)
    plan.add(Phase("a", {"primary": JointTrajectory([0, 0.5, 1.0], [q0["primary"], q1 / 2, q1], [0.0, 0.03, 0.06])}))
    plan.add(Phase("b", {"secondary": JointTrajectory([0, 2.0], [q0["secondary"], q0["secondary"] + 0.1])}))
    with pytest.raises(ValueError, match="starts at"):
        plan.add(Phase("c", {"primary": JointTrajectory([0, 1.0], [np.zeros(6), q1])}))  # not where it is
    tl = plan.timeline()
    assert tl["primary"].duration == pytest.approx(3.0) and tl["secondary"].duration == pytest.approx(3.0)
    q, w = tl["primary"].sample(2.0)  # primary idle in phase b: holds its end and its gripper width
    assert np.allclose(q, q1) and w == pytest.approx(0.06)
    q, w = tl["secondary"].sample(0.5)  # secondary idle in phase a
    assert np.allclose(q, 1.0) and w == 0.0
    assert np.allclose(tl["secondary"].sample(3.0)[0], 1.1)
    assert [s["phase"] for s in plan.summary()] == ["a", "b"] and plan.summary()[1]["duration_s"] == 2.0


def test_opening_spans_cut_a_phase_where_its_gripper_starts_to_open():
    """The whole-plan check takes the fingers of each span at their widest: an arm that moves with its gripper
    closed and opens once there is checked closed on the way and open only where it opens (a receiver that
    starts next to the table would otherwise be checked with its fingers open at its start). A gripper
    that opens on the way is checked open all along; fingers resting on a held object stay at that width."""
    q0 = {"primary": np.zeros(6), "secondary": np.ones(6)}
    plan = TaskPlan(q0, {"primary": 0.0, "secondary": 0.03})
    q1 = np.full(6, 0.2)
    plan.add(Phase("reach", {"primary": JointTrajectory([0, 1.0, 2.0, 2.5, 3.0], [q0["primary"], q1 / 2, q1, q1, q1],
                                                        [0.0, 0.0, 0.0, 0.035, 0.07])}, resting={"secondary": 0.04}))
    plan.add(Phase("ramp", {"primary": JointTrajectory([0, 1.0], [q1, q0["primary"]], [0.07, 0.0])}))
    spans = plan.opening_spans()
    assert [(a, b) for a, b, _ in spans] == [(0.0, 2.0), (2.0, 3.0), (3.0, 4.0)]
    assert [w["primary"] for _, _, w in spans] == [0.0, 0.07, 0.07]
    assert [w["secondary"] for _, _, w in spans] == [0.04, 0.04, 0.03]  # resting on the object, then as it is


def _grasp(x, score=0.5):
    T = np.eye(4)
    T[:3, 3] = [x, 0, 0.05]
    return {"kind": "pinch", "T_b1_g": T.tolist(), "width": 0.06, "score": score}


def test_object_choice_takes_the_best_candidate_and_says_why():
    g = {"pregrasp_distance": 0.09, "objects": [
        {"id": 0, "joint_grasps": [{"kind": "pinch", "score": 0.4, "primary": _grasp(0.2), "secondary": _grasp(0.4)}],
         "handover": None},
        {"id": 3, "joint_grasps": [{"kind": "push", "score": 0.7,
                                    "primary": dict(_grasp(0.2), kind="push", press=0.008, squeeze_b1=[1, 0, 0]),
                                    "secondary": dict(_grasp(0.5), kind="push", press=0.008)}],
         "handover": None},
        {"id": 5, "joint_grasps": []}]}
    cands = joint_candidates(g, "grasps.json")
    assert [c.object_id for c in cands] == [3, 0]
    assert cands[0].primary.kind == "push" and cands[0].primary.press == 0.008
    assert np.allclose(cands[0].primary.squeeze_dir, [1, 0, 0]) and cands[0].primary.pre_dist == 0.09
    mine, why = choose(cands, None, "joint-grasp", "grasps.json", [0, 3, 5])
    assert [c.object_id for c in mine] == [3] and "best-scoring" in why and "other candidates: 0" in why
    mine, why = choose(cands, 5, "joint-grasp", "grasps.json", [0, 3, 5])
    assert mine == [] and "as requested" in why
    with pytest.raises(InputError, match="no object 9"):
        choose(cands, 9, "joint-grasp", "grasps.json", [0, 3, 5])
    assert handover_candidates(g, "grasps.json") == []
    bad = {"objects": [{"id": 1, "joint_grasps": [{"primary": {"T_b1_g": "x"}, "secondary": {}}]}]}
    with pytest.raises(InputError, match="not a usable grasp"):
        joint_candidates(bad, "grasps.json")



def test_handover_candidates_include_the_alternatives_best_first():
    def ho(x, score):
        return {"T_move": np.eye(4).tolist(), "score": score,
                "giver": {"pick": _grasp(x), "transfer": {"T_b1_g": _grasp(x + 0.1)["T_b1_g"]}, "contact_width": 0.04},
                "receiver": _grasp(x + 0.2)}

    g = {"objects": [{"id": 2, "handover": ho(0.30, 0.6), "handover_alternatives": [ho(0.31, 0.4), ho(0.32, 0.7)]},
                     {"id": 4, "handover": ho(0.25, 0.5)}]}
    cands = handover_candidates(g, "grasps.json")
    assert [(c.object_id, c.score) for c in cands] == [(2, 0.7), (2, 0.6), (4, 0.5), (2, 0.4)]
    assert cands[0].pick.T_b1_g[0, 3] == pytest.approx(0.32) and cands[0].receiver.arm == "secondary"
    mine, _ = choose(cands, None, "handover", "grasps.json", [2, 4])
    assert [c.score for c in mine] == [0.7, 0.6, 0.4]
    g["objects"][0]["handover_alternatives"][1]["T_move"] = "x"
    with pytest.raises(InputError, match=r"objects\[2\]\.handover_alternatives\[1\]\.T_move"):
        handover_candidates(g, "grasps.json")


def test_handover_candidates_of_determined_shapes_go_before_free_form_ones():
    """An object whose seen points fit a box or a cylinder (grasps.json ``shape``) is handed over before a
    higher-scoring free-form one (a mug seen from one side hides its handle from the receiver), and the
    reason says so; without ``shape`` (an older grasps.json) the score alone decides."""
    def ho(x, score):
        return {"T_move": np.eye(4).tolist(), "score": score,
                "giver": {"pick": _grasp(x), "transfer": {"T_b1_g": _grasp(x + 0.1)["T_b1_g"]}, "contact_width": 0.04},
                "receiver": _grasp(x + 0.2)}

    g = {"objects": [{"id": 1, "shape": {"kind": "free-form", "fit": 0.6}, "handover": ho(0.30, 0.9)},
                     {"id": 2, "shape": {"kind": "cylinder", "fit": 0.97}, "handover": ho(0.25, 0.5),
                      "handover_alternatives": [ho(0.26, 0.4)]},
                     {"id": 3, "handover": ho(0.2, 0.45)}]}
    cands = handover_candidates(g, "grasps.json")
    assert [(c.object_id, c.score) for c in cands] == [(2, 0.5), (3, 0.45), (2, 0.4), (1, 0.9)]
    mine, why = choose(cands, None, "handover", "grasps.json", [1, 2, 3])
    assert [c.object_id for c in mine] == [2, 2]
    assert "object 1 scores higher (0.90) but is free-form" in why and "cylinder" in why
    g["objects"][1]["shape"]["kind"] = "free-form"
    g["objects"][2]["shape"] = {"kind": "free-form", "fit": 0.5}
    assert [c.object_id for c in handover_candidates(g, "grasps.json")] == [1, 2, 3, 2]


def test_handover_candidates_of_boxes_seen_whole_go_before_one_cut_short_by_the_views():
    """A box whose far end no camera saw (grasps.json ``shape.open_ends``: a sliver of a larger box, seen where
    the views ended) goes with the free-form objects, after a lower-scoring box seen whole, and the reason says
    why; without ``open_ends`` (an older grasps.json) it counts as seen whole."""
    def ho(x, score):
        return {"T_move": np.eye(4).tolist(), "score": score,
                "giver": {"pick": _grasp(x), "transfer": {"T_b1_g": _grasp(x + 0.1)["T_b1_g"]}, "contact_width": 0.04},
                "receiver": _grasp(x + 0.2)}

    g = {"objects": [{"id": 4, "shape": {"kind": "box", "fit": 1.0, "open_ends": 1}, "handover": ho(0.30, 0.61)},
                     {"id": 3, "shape": {"kind": "box", "fit": 0.99, "open_ends": 0}, "handover": ho(0.25, 0.46)},
                     {"id": 2, "shape": {"kind": "free-form", "fit": 0.57}, "handover": ho(0.2, 0.37)}]}
    cands = handover_candidates(g, "grasps.json")
    assert [c.object_id for c in cands] == [3, 4, 2]
    mine, why = choose(cands, None, "handover", "grasps.json", [2, 3, 4])
    assert [c.object_id for c in mine] == [3]
    assert "object 4 scores higher (0.61) but was not seen whole" in why
    del g["objects"][0]["shape"]["open_ends"]
    assert [c.object_id for c in handover_candidates(g, "grasps.json")] == [4, 3, 2]
    # a cylinder's fitted circle gives all of it: an end of its box unseen leaves it determined
    g["objects"][0]["shape"] = {"kind": "cylinder", "fit": 1.0, "open_ends": 1}
    assert [c.object_id for c in handover_candidates(g, "grasps.json")] == [4, 3, 2]
    # when every candidate is undetermined, the reason does not claim one is determined
    for o in g["objects"]:
        o["shape"] = {"kind": "free-form", "fit": 0.5}
    _, why = choose(handover_candidates(g, "grasps.json"), None, "handover", "grasps.json", [2, 3, 4])
    assert "determines" not in why

def test_robot_points_around_the_bases_are_not_obstacles():
    bases = np.array([[0.0, 0.0, 0.0], [0.6, 0.0, 0.0]])
    pts = np.array([[0.05, 0.02, 0.15],   # the primary arm seen by a camera
                    [0.55, 0.05, 0.20],   # the secondary arm
                    [0.05, 0.0, 0.005],   # table right by the base
                    [0.30, 0.0, 0.10],    # a background thing in the middle: an obstacle
                    [0.10, 0.0, 0.05]])   # an object's point close to the base
    labels = np.array([-1, -1, -1, -1, 2])
    m = robot_points_mask(pts, labels, bases, np.array([0, 0, 1.0]), 0.0)
    assert m.tolist() == [True, True, False, False, False]


def test_points_where_the_arms_stand_at_the_start_are_not_obstacles():
    """Stray points on the primary's gripper at its rest configuration (the Piper's rest holds it out 19 cm
    from the base, 22 cm up: beyond the base columns) put the start in collision; they go from the map, and
    nothing else does: not the table under the base, not an object 5 cm from the gripper."""
    from bimanual_app.collision import CollisionWorld
    from bimanual_app.robots import load_robot
    from bimanual_app.tasks._motion import START_PAD, arms_at_start_mask
    from tests._task_fixtures import FIX_T_B1_B2, table_points

    robot = load_robot("piper")
    q = {"primary": robot.neutral(), "secondary": robot.neutral()}
    rng = np.random.default_rng(0)
    stray = np.array([0.19, -0.01, 0.235]) + rng.normal(scale=0.004, size=(40, 3))  # on the primary's fingers
    near = np.array([0.19, 0.0, 0.29]) + rng.normal(scale=0.002, size=(40, 3))  # 5 cm over them: an obstacle
    table = table_points()
    P = np.vstack([table, stray, near])
    m = arms_at_start_mask(robot, FIX_T_B1_B2, P, q)
    assert m[len(table):len(table) + 40].all() and not m[len(table) + 40:].any() and not m[:len(table)].any()
    with_stray = CollisionWorld(robot, FIX_T_B1_B2, P, resolution=0.005)
    assert not with_stray.valid(q["primary"], q["secondary"])
    assert CollisionWorld(robot, FIX_T_B1_B2, P[~m], resolution=0.005).valid(q["primary"], q["secondary"])
    # the padded space: a point just outside the pad past the fingertip capsule is kept
    tip = CollisionWorld(robot, FIX_T_B1_B2)
    a = tip.arms[0]
    A, B, _ = a.points(a.placements(q["primary"][None]), with_samples=False)
    k = a.shapes.names.index("link7")
    reach = float(a.shapes.radius[k]) + START_PAD
    axis = (B[0, k] - A[0, k]) / np.linalg.norm(B[0, k] - A[0, k])
    probe = np.stack([B[0, k] + (reach - 0.002) * axis, B[0, k] + (reach + 0.002) * axis])
    assert arms_at_start_mask(robot, FIX_T_B1_B2, probe, q).tolist() == [True, False]


def test_carried_object_may_slide_past_a_touching_neighbour_but_not_hit_others():
    from bimanual_app.robots import load_robot
    from bimanual_app.tasks._motion import TaskMotion
    from tests._task_fixtures import FIX_T_B1_B2, box_surface_points, table_points

    obj = box_surface_points([0.30, 0.0, 0.05], [0.04, 0.04, 0.10], 1500, visible_only=False)
    # a neighbour touching the object's +x face (1 mm apart; kept in the map: a tiny cut radius), and a
    # shelf overhanging it
    wall = box_surface_points([0.321 + 0.02, 0.0, 0.05], [0.04, 0.06, 0.10], 1500, seed=2)
    shelf = box_surface_points([0.29, 0.0, 0.16], [0.05, 0.06, 0.01], 600, seed=3)
    points = np.vstack([table_points(), obj, wall])
    motion = TaskMotion(load_robot("piper"), FIX_T_B1_B2, points, obj, obj, cut_radius=0.0005)
    assert np.sum(np.abs(motion.cut_map.points[:, 0] - 0.321) < 1e-3) > 50  # the wall's face is in the map

    def lift(h, n=11):
        T = np.stack([np.eye(4)] * n)
        T[:, 2, 3] = np.linspace(0.0, h, n)
        return T

    assert motion.object_clear(lift(0.10)) == []  # straight up along the touching neighbour: fine
    far = TaskMotion(load_robot("piper"), FIX_T_B1_B2, np.vstack([table_points(), obj, wall + [0.02, 0, 0]]), obj,
                     obj, cut_radius=0.0005)
    side = lift(0.10)
    side[:, 0, 3] = np.linspace(0.0, 0.03, len(side))  # a neighbour 2 cm away: moving 3 cm into it is not
    assert far.object_clear(side) and "meets the scene" in far.object_clear(side)[0]
    motion2 = TaskMotion(load_robot("piper"), FIX_T_B1_B2, np.vstack([points, shelf]), obj, obj)
    assert motion2.object_clear(lift(0.10))  # an overhang above it stops the lift
    assert motion2.object_clear(lift(0.04)) == []  # (below it, not)
    # a taller neighbour against the +x face whose near side no camera saw: only its top rim, 2 mm over the
    # object's estimated edge (a fit a few mm off), is in the map; the lift slides past it (SIDE_TOLERANCE)
    rng = np.random.default_rng(4)
    rim = np.c_[rng.uniform(0.318, 0.36, 400), rng.uniform(-0.02, 0.02, 400), np.full(400, 0.13)]
    motion3 = TaskMotion(load_robot("piper"), FIX_T_B1_B2, np.vstack([table_points(), obj, rim]), obj, obj,
                         cut_radius=0.0005)
    assert motion3.object_clear(lift(0.10)) == []
    deep = rim - [0.012, 0.0, 0.0]  # 1.4 cm over it: a real overhang
    motion4 = TaskMotion(load_robot("piper"), FIX_T_B1_B2, np.vstack([table_points(), obj, deep]), obj, obj,
                         cut_radius=0.0005)
    assert motion4.object_clear(lift(0.10))


def test_segment_stage_uses_the_scene_masks_when_there_are_some(tmp_path):
    from bimanual_app.tasks._inputs import stage_paths

    paths = stage_paths(tmp_path / "work")
    scene = tmp_path / "scene"
    (scene / "primary").mkdir(parents=True)
    assert "--masks" not in paths.argv(scene)["segment"]
    (scene / "primary" / "masks").mkdir()
    assert paths.argv(scene)["segment"][-2:] == ["--masks", str(scene)]
    assert "--masks" not in paths.argv(scene, masks=False)["segment"]  # bijcr task --no-masks


def test_push_squeeze_gap_is_measured_from_the_fingertips():
    """The squeeze is extended by the gap between the fingertips and the object's nearest point along the
    squeeze line; the gripper origin lies half a finger (and more when tilted) outside the face, and
    counting that drove the fingertips centimetres into the box."""
    from types import SimpleNamespace

    from bimanual_app.tasks._grasps import GraspSpec
    from bimanual_app.tasks._planners import _face_gap

    yy, zz = np.meshgrid(np.linspace(-0.03, 0.03, 13), np.linspace(0.02, 0.08, 13))
    face = np.stack([np.full(yy.size, 0.2), yy.ravel(), zz.ravel()], axis=1)  # a face at x = 0.2
    motion = SimpleNamespace(object_points=face)
    T = np.eye(4)
    T[:3, 3] = [0.19, 0.0, 0.05]  # the gripper origin 1 cm outside the face
    squeeze = np.array([1.0, 0.0, 0.0])
    on_face = GraspSpec("primary", T, 0.002, "push", 0.008, squeeze=squeeze, contact=np.array([0.2, 0.0, 0.05]))
    short = GraspSpec("primary", T, 0.002, "push", 0.008, squeeze=squeeze, contact=np.array([0.197, 0.0, 0.05]))
    unknown = GraspSpec("primary", T, 0.002, "push", 0.008, squeeze=squeeze)
    assert _face_gap(motion, on_face) == pytest.approx(0.0, abs=1e-9)
    assert _face_gap(motion, short) == pytest.approx(0.003, abs=1e-9)
    assert _face_gap(motion, unknown) == pytest.approx(0.01, abs=1e-9)  # no contact known: from the origin


def test_lift_directions_lead_away_from_a_taller_neighbour():
    """Beside a taller neighbour, a lift straight up slides along it and the carry would start too close;
    the lifts also go up and away from it (the neighbour's side, not the table, sets the direction)."""
    from bimanual_app.robots import load_robot
    from bimanual_app.tasks._motion import TaskMotion
    from bimanual_app.tasks._planners import _lift_directions
    from tests._task_fixtures import FIX_T_B1_B2, box_surface_points, table_points

    obj = box_surface_points([0.40, 0.10, 0.04], [0.05, 0.05, 0.08], 1500, visible_only=False)
    wall = box_surface_points([0.40 - 0.025 - 0.012 - 0.03, 0.10 - 0.02, 0.06], [0.06, 0.08, 0.12], 1500, seed=2)
    motion = TaskMotion(load_robot("piper"), FIX_T_B1_B2, np.vstack([table_points(), obj, wall]), obj, obj)
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # from above
    T[:3, 3] = [0.40, 0.10, 0.06]
    up = np.array([0.0, 0.0, 1.0])
    dirs = dict(_lift_directions(motion, T, obj, up))
    assert np.allclose(dirs["straight up"], up)
    away = dirs["up and away from its neighbour"]
    assert away @ up == pytest.approx(np.sqrt(0.5), abs=1e-6)  # 45 degrees
    assert away[0] > 0.6 and away[1] > 0.0  # from the wall's side (-x, -y) outwards
    assert "up, a little away from its neighbour" in dirs
    assert "back out along the approach" in dirs  # from above: backing out rises
    alone = TaskMotion(load_robot("piper"), FIX_T_B1_B2, np.vstack([table_points(), obj]), obj, obj)
    assert not any("neighbour" in h for h, _ in _lift_directions(alone, T, obj, up))  # the table is no neighbour


def test_grasping_checks_push_approaches_where_the_task_stops_them():
    """The grasping stage checks a push contact's way in held off the face by its standoff; the task's
    approach stops PUSH_STANDOFF out and squeezes from there. Checked nearer the face, a way in 1 cm out
    passed a neighbour's side that the task's finger then touched (task bench seed 6)."""
    from bimanual_app.tasks._planners import PUSH_STANDOFF
    from grasping import PushParams

    assert PushParams().standoff == pytest.approx(PUSH_STANDOFF)


def _handover_fixture():
    """(robot, TaskMotion, the fixture's best hand-over choice, the small box's points (M,3), up (3,)) for
    planning the fixture's hand-over directly."""
    from bimanual_app.robots import load_robot
    from bimanual_app.tasks._motion import TaskMotion
    from tests._task_fixtures import FIX_T_B1_B2, SMALL_BOX, _cloud, box_surface_points, fixture_grasps

    robot = load_robot("piper")
    pts, labels = _cloud()
    obj = box_surface_points(SMALL_BOX["centre"], SMALL_BOX["size"], 1500, visible_only=False)
    up = np.array([0.0, 0.0, 1.0])
    motion = TaskMotion(robot, FIX_T_B1_B2, pts, obj, pts[labels == 0], up=up)
    return robot, motion, handover_candidates(fixture_grasps(robot), "grasps.json")[0], obj, up


def test_handover_moves_a_secondary_in_the_way_aside_during_the_transfer():
    """A secondary waiting where the object is carried to: the transfer pose would put the object against
    it, so it goes to its pre-grasp in the same (12-DoF) motion; the plan then validates as a whole, its
    held fingers taken where they rest on the object (``Phase.resting``)."""
    from bimanual_app.planning import default_ready
    from bimanual_app.tasks._planners import plan_handover

    robot, motion, choice, obj, up = _handover_fixture()
    # the secondary stands with its gripper where the receiver grasp will be, closed
    q_start = {"primary": default_ready(robot), "secondary": choice.receiver.q}
    assert not motion.problems(q_start)
    plan = plan_handover(motion, choice, q_start, {"primary": 0.0, "secondary": 0.0}, obj, up=up)
    transfer = next(p for p in plan.phases if p.name == "transfer")
    assert set(transfer.trajectories) == {"primary", "secondary"} and "out of its way" in transfer.note
    assert transfer.trajectories["secondary"].gripper[-1] == pytest.approx(choice.receiver.width)
    assert motion.tcp_pose("secondary", transfer.trajectories["secondary"].q[-1])[:3, 3] @ choice.receiver.T_b1_g[:3, 2] \
        < choice.receiver.T_b1_g[:3, 3] @ choice.receiver.T_b1_g[:3, 2] - 0.02  # backed off along its approach
    spans = plan.opening_spans()
    names = [p.name for p in plan.phases]
    t_release = sum(p.duration for p in plan.phases[:names.index("release")])
    release = next(w for t0, _, w in spans if t0 >= t_release - 1e-9)
    assert release["secondary"] == pytest.approx(choice.receiver.contact_width)  # resting on the object, not 0
    motion.validate_timeline(plan.timeline(), spans)  # raises if any sample collides or breaks a limit


def test_a_hand_over_the_secondary_gives_plans_as_the_mirror_of_the_primarys():
    """The fixture's world mirrored onto the other arm (FIX_T_B1_B2 is a half turn about the vertical, its own
    inverse: each arm sees the mirrored world as the other saw the original) and its hand-over with the roles
    swapped, joint values kept: the secondary reaches, picks, lifts and carries, the primary receives, and
    the hold checks that the primary alone holds; the plan validates as a whole."""
    from bimanual_app.planning import default_ready
    from bimanual_app.robots import load_robot
    from bimanual_app.tasks._motion import TaskMotion
    from bimanual_app.tasks._planners import plan_handover
    from tests._task_fixtures import FIX_T_B1_B2 as M
    from tests._task_fixtures import SMALL_BOX, _cloud, box_surface_points, fixture_grasps

    assert np.allclose(M @ M, np.eye(4))

    def mirror(P):
        return np.asarray(P) @ M[:3, :3].T + M[:3, 3]

    robot = load_robot("piper")
    pts, labels = _cloud()
    pts = mirror(pts)
    obj = mirror(box_surface_points(SMALL_BOX["centre"], SMALL_BOX["size"], 1500, visible_only=False))
    up = np.array([0.0, 0.0, 1.0])
    motion = TaskMotion(robot, M, pts, obj, pts[labels == 0], up=up)
    g = fixture_grasps(robot)
    h = g["objects"][0]["handover"]
    h["T_move"] = M @ h["T_move"] @ M
    h["giver"]["arm"], h["receiver"]["arm"] = "secondary", "primary"
    for d in (h["giver"]["pick"], h["giver"]["transfer"], h["receiver"]):
        d["T_b1_g"] = M @ d["T_b1_g"]
    choice = handover_candidates(g, "grasps.json")[0]
    assert (choice.giver, choice.taker) == ("secondary", "primary")
    q0 = default_ready(robot)
    plan = plan_handover(motion, choice, {"primary": q0, "secondary": q0}, {"primary": 0.0, "secondary": 0.0}, obj,
                         up=up)
    moved = {p.name: set(p.trajectories) for p in plan.phases}
    for name in ("reach", "approach", "grasp", "lift", "release", "retreat"):
        assert moved[name] == {"secondary"}, (name, moved)
    for name in ("receive-reach", "receive-approach", "receive-grasp", "hold"):
        assert moved[name] == {"primary"}, (name, moved)
    assert plan.phases[-1].check == "handover-to-primary" and "primary holds" in plan.phases[-1].note
    assert (plan.info["giver"], plan.info["receiver"]) == ("secondary", "primary")  # task.json plan.info
    motion.validate_timeline(plan.timeline(), plan.opening_spans())


def test_handover_arms_in_grasps_json_are_checked():
    g = fixture_handover_json()
    g["objects"][0]["handover"]["receiver"]["arm"] = "primary"
    with pytest.raises(InputError, match=r"receiver\.arm.*both the primary"):
        handover_candidates(g, "grasps.json")
    g["objects"][0]["handover"]["giver"]["arm"] = "left"
    with pytest.raises(InputError, match=r"giver\.arm.*unknown arm 'left'"):
        handover_candidates(g, "grasps.json")
    del g["objects"][0]["handover"]["giver"]["arm"], g["objects"][0]["handover"]["receiver"]["arm"]
    c = handover_candidates(g, "grasps.json")[0]  # a grasps.json from before either arm could give
    assert (c.giver, c.taker) == ("primary", "secondary")


def fixture_handover_json() -> dict:
    """The fixture's grasps.json (its hand-over only), without joint solutions."""
    from bimanual_app.robots import load_robot
    from tests._task_fixtures import fixture_grasps

    g = fixture_grasps(load_robot("piper"))
    g["objects"] = g["objects"][:1]
    return g


def test_points_between_the_open_fingers_of_a_pick_are_cut_as_the_object():
    """A part of the object the segmenter left as background (a bunny's ear) lies between the fingers of
    its pick: the closed fingers "touch" it. It is the object: ``cut_grasped`` takes it out of the map,
    and nothing outside the fingers' span."""
    from bimanual_app.robots import load_robot
    from bimanual_app.tasks._motion import TaskMotion
    from tests._task_fixtures import FIX_T_B1_B2, box_surface_points, table_points

    obj = box_surface_points([0.30, 0.0, 0.03], [0.03, 0.03, 0.06], 800, visible_only=False)
    ear = box_surface_points([0.30, 0.024, 0.045], [0.02, 0.012, 0.03], 300, seed=4)  # beside it, unlabelled
    far = box_surface_points([0.30, 0.10, 0.03], [0.03, 0.03, 0.06], 300, seed=5)  # a real neighbour
    motion = TaskMotion(load_robot("piper"), FIX_T_B1_B2, np.vstack([table_points(), obj, ear, far]), obj, obj,
                        cut_radius=0.002)
    T = np.eye(4)
    T[:3, :3] = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])  # from above, closing along b1's y
    T[:3, 3] = [0.30, 0.0, 0.025]  # fingertips 2.5 cm up, the fingers above them
    before = len(motion.cut_map.points)
    n = motion.cut_grasped(T, 0.07)
    assert n > 100 and len(motion.cut_map.points) == before - n
    d, _ = motion._cut_tree.query(ear, k=1)
    assert np.all(d > 1e-9)  # the ear is gone
    d, _ = motion._cut_tree.query(far, k=1)
    assert np.all(d < 1e-9)  # the neighbour stays
    assert np.sum(motion.cut_map.points[:, 2] < 0.004) > 0.9 * len(table_points())  # and the table


def test_handover_primary_stays_backed_off_when_its_start_is_where_the_object_is_held():
    """The primary started where the object is handed over (its transfer pose): going home would put it
    into the object the secondary now holds, so it stays backed off; the plan still validates."""
    from bimanual_app.planning import default_ready
    from bimanual_app.tasks._planners import plan_handover

    robot, motion, choice, obj, up = _handover_fixture()
    # the primary starts with its palm where the transfer pose holds the object (4 cm further in)
    T_in = choice.giver_transfer.T_b1_g.copy()
    T_in[:3, 3] += 0.04 * T_in[:3, 2]
    q_start = {"primary": motion.ik("primary", T_in, choice.giver_transfer.q)[0], "secondary": default_ready(robot)}
    assert not motion.problems(q_start)
    plan = plan_handover(motion, choice, q_start, {"primary": 0.0, "secondary": 0.0}, obj, up=up)
    names = [p.name for p in plan.phases]
    assert "home" not in names and names[-2:] == ["retreat", "hold"]
    assert plan.info["home"].startswith("skipped: the primary's start pose meets the held object")
    assert plan.info["fallbacks"] == ["skip-home"]
    motion.validate_timeline(plan.timeline(), plan.opening_spans())
    motion.leave_out = frozenset({"skip-home"})  # left out (TaskOptions.leave_out): the plan fails there
    with pytest.raises(PlanFailure, match="home: the primary's start pose meets the held object"):
        plan_handover(motion, choice, q_start, {"primary": 0.0, "secondary": 0.0}, obj, up=up)


def test_receiver_pre_grasp_backs_off_where_its_open_fingers_are_too_near_the_carried_object():
    """A receiver pre-grasp only 1.5 cm back from its grasp (the grasping stage keeps them short near the
    edge of the reach) leaves its open fingers within the free-motion margin of the carried object: the
    secondary goes to a pre-grasp further back along the same line, and approaches from there."""
    from dataclasses import replace

    from bimanual_app.planning import default_ready
    from bimanual_app.tasks._motion import translate_along
    from bimanual_app.tasks._planners import plan_handover

    robot, motion, choice, obj, up = _handover_fixture()
    R = choice.receiver.T_b1_g
    short = translate_along(R, R[:3, 2], -0.015)
    # opened 5 mm past the 4 cm box on each side: 1.5 cm back, the fingertips still reach past its near face
    rec = replace(choice.receiver, q_pre=motion.ik("secondary", short, choice.receiver.q)[0], width=0.05)
    choice = replace(choice, receiver=rec)
    q_start = {"primary": default_ready(robot), "secondary": default_ready(robot)}
    plan = plan_handover(motion, choice, q_start, {"primary": 0.0, "secondary": 0.0}, obj, up=up)
    appr = next(p for p in plan.phases if p.name == "receive-approach").trajectories["secondary"]
    start = motion.tcp_pose("secondary", appr.q[0])[:3, 3]
    assert np.linalg.norm(start - R[:3, 3]) > 0.03  # 3.5 or 5.5 cm back, not 1.5
    assert np.allclose(np.cross(start - R[:3, 3], R[:3, 2]), 0, atol=2e-3)  # on the approach line
    assert plan.info["fallbacks"] == ["receiver-back-off"]
    motion.validate_timeline(plan.timeline(), plan.opening_spans())
    motion.leave_out = frozenset({"receiver-back-off"})  # left out: no free pre-grasp, the reach fails
    with pytest.raises(PlanFailure, match="receive-reach"):
        plan_handover(motion, choice, q_start, {"primary": 0.0, "secondary": 0.0}, obj, up=up)


def test_handover_carry_keeps_less_margin_where_the_arm_cannot_lift_the_object_clear(monkeypatch):
    """At the top of its reach the primary lifts the object 6 cm straight up and no higher (bench seed 8: a can
    49 cm out, beside a small box and the carton); there it is still within the carry's free-motion margin of
    its neighbour. As the last resort the carry keeps the object about half that margin less from the scene
    (the receiver's last resort too) rather than fail; the plan validates as a whole. Lifted clear, the carry
    keeps the whole margin."""
    from bimanual_app.planning import default_ready
    from bimanual_app.robots import load_robot
    from bimanual_app.tasks._motion import OBJECT_PADDING, PlanFailure, TaskMotion
    from bimanual_app.tasks._planners import plan_handover
    from tests._task_fixtures import FIX_T_B1_B2, SMALL_BOX, _cloud, box_surface_points, fixture_grasps

    robot = load_robot("piper")
    pts, labels = _cloud()
    # a box as tall as the small box, 1.7 cm off its +x face (beyond the 1.5 cm the grasp cuts from the map)
    beside = box_surface_points([0.357, -0.16, 0.05], [0.04, 0.04, 0.10], 1500, seed=9)
    pts = np.vstack([pts, beside])
    labels = np.r_[labels, np.full(len(beside), 2)].astype(np.int32)
    obj = box_surface_points(SMALL_BOX["centre"], SMALL_BOX["size"], 1500, visible_only=False)
    up = np.array([0.0, 0.0, 1.0])
    choice = handover_candidates(fixture_grasps(robot), "grasps.json")[0]
    q0 = {"primary": default_ready(robot), "secondary": default_ready(robot)}
    w0 = {"primary": 0.0, "secondary": 0.0}

    def plan_with_lifts_up_to(top, leave_out=()):
        # a free-motion margin of 2 cm: the neighbour 1.7 cm away is within it
        motion = TaskMotion(robot, FIX_T_B1_B2, pts, obj, pts[labels == 0], up=up, margin=0.02, leave_out=leave_out)
        real = motion.cartesian

        def cartesian(moves, q_now, min_duration=0.0):
            for m in moves.values():  # the lift: no higher than ``top``, straight up only
                T0, T1 = (m[0], m[-1]) if isinstance(m, np.ndarray) else m
                d = T1[:3, 3] - T0[:3, 3]
                if d[2] > 0.02 and (d[2] > top or np.linalg.norm(d[:2]) > 0.005):
                    raise PlanFailure("reach", "the primary gripper leaves its reach (test)")
            return real(moves, q_now, min_duration=min_duration)

        monkeypatch.setattr(motion, "cartesian", cartesian)
        return motion, plan_handover(motion, choice, q0, w0, obj, up=up)

    motion, plan = plan_with_lifts_up_to(0.065)
    lift = next(p for p in plan.phases if p.name == "lift")
    assert "6 cm (straight up)" in lift.note
    assert plan.info["carry_padding_m"] < OBJECT_PADDING - 0.005 and plan.info["fallbacks"] == ["carry-padding"]
    motion.validate_timeline(plan.timeline(), plan.opening_spans())
    with pytest.raises(PlanFailure, match="lift: lifted 6 cm"):  # the fallback left out
        plan_with_lifts_up_to(0.065, leave_out=("carry-padding",))
    _, plan = plan_with_lifts_up_to(0.2)  # 14 cm up it is clear of the neighbour
    assert "14 cm" in next(p for p in plan.phases if p.name == "lift").note and "carry_padding_m" not in plan.info


def test_handover_secondary_in_the_primarys_way_turns_aside_first():
    """The waiting secondary stands where the primary's pre-grasp is (an object beside the secondary's
    base): the plan starts with the secondary turning about its base joint (``make-way``), and validates
    as a whole; a secondary out of the way does not move first."""
    from bimanual_app.planning import default_ready
    from bimanual_app.tasks._planners import MAKE_WAY_TURNS, _pre, plan_handover

    robot, motion, choice, obj, up = _handover_fixture()
    q_p = default_ready(robot)
    q_s = np.array([0.24, 1.923, -1.155, 0.0, 0.0, 0.0])  # leaning over the primary's way in
    q_pre = motion.ik("primary", _pre(motion, choice.pick), q_p)[0]
    assert not motion.problems({"primary": q_p, "secondary": q_s})  # a valid start ...
    assert any("secondary" in w for w in motion.problems({"primary": q_pre, "secondary": q_s}))  # ... in the way
    plan = plan_handover(motion, choice, {"primary": q_p, "secondary": q_s}, {"primary": 0.0, "secondary": 0.0},
                         obj, up=up)
    names = [p.name for p in plan.phases]
    assert names[:2] == ["make-way", "reach"] and plan.info["make_way_rad"] in MAKE_WAY_TURNS
    way = plan.phases[0].trajectories["secondary"]
    assert way.q[-1][0] == pytest.approx(q_s[0] + plan.info["make_way_rad"])
    assert np.allclose(way.q[-1][1:], q_s[1:]) and plan.info["fallbacks"] == ["make-way"]
    motion.validate_timeline(plan.timeline(), plan.opening_spans())
    motion.leave_out = frozenset({"make-way"})  # left out: the primary's reach meets the secondary
    with pytest.raises(PlanFailure, match="secondary"):
        plan_handover(motion, choice, {"primary": q_p, "secondary": q_s}, {"primary": 0.0, "secondary": 0.0},
                      obj, up=up)
    motion.leave_out = frozenset()
    plan = plan_handover(motion, choice, {"primary": q_p, "secondary": default_ready(robot)},
                         {"primary": 0.0, "secondary": 0.0}, obj, up=up)
    assert plan.phases[0].name == "reach" and "make_way_rad" not in plan.info


def _bar_pair():
    """The fixture's bar and its pinch pair: (robot, cloud points, labels, the bar's points, the joint choice,
    start configurations, start openings)."""
    from bimanual_app.planning import default_ready
    from bimanual_app.robots import load_robot
    from tests._task_fixtures import BAR, _cloud, box_surface_points, fixture_grasps

    robot = load_robot("piper")
    pts, labels = _cloud()
    obj = box_surface_points(BAR["centre"], BAR["size"], 1500, visible_only=False)
    choice = joint_candidates(fixture_grasps(robot), "grasps.json")[0]
    q0 = {"primary": default_ready(robot), "secondary": default_ready(robot)}
    return robot, pts, labels, obj, choice, q0, {"primary": 0.0, "secondary": 0.0}


def test_joint_lift_falls_back_to_the_least_lift_at_the_top_of_the_reach(monkeypatch):
    """Where the arms cannot follow the object higher than 11 cm (both at the top of their reach: bench
    seed 3's 47 cm carton held at its ends), the joint grasp lifts ``LIFT_MIN`` (10.5 cm: the 10 cm the
    task needs, with 5 mm to spare) rather than fail; lower than that it fails."""
    from bimanual_app.tasks._motion import PlanFailure, TaskMotion
    from bimanual_app.tasks._planners import LIFT_MIN, plan_joint_grasp
    from tests._task_fixtures import FIX_T_B1_B2

    robot, pts, labels, obj, choice, q0, w0 = _bar_pair()

    def plan_with_reach_up_to(top, leave_out=()):
        motion = TaskMotion(robot, FIX_T_B1_B2, pts, obj, pts[labels == 1], up=np.array([0.0, 0.0, 1.0]),
                            leave_out=leave_out)
        real = motion.cartesian

        def cartesian(moves, q_now, min_duration=0.0):
            for poses in moves.values():
                if isinstance(poses, np.ndarray) and poses.ndim == 3 and poses[-1, 2, 3] - poses[0, 2, 3] > top:
                    raise PlanFailure("reach", "the secondary gripper leaves its reach (test)")
            return real(moves, q_now, min_duration=min_duration)

        monkeypatch.setattr(motion, "cartesian", cartesian)
        return plan_joint_grasp(motion, choice, q0, w0)

    plan = plan_with_reach_up_to(0.11)
    assert plan.info["object_motion"]["lift_m"] == pytest.approx(LIFT_MIN) and LIFT_MIN >= 0.105
    assert plan.info["fallbacks"] == ["lower-joint-lift"]
    with pytest.raises(PlanFailure, match="leaves its reach"):
        plan_with_reach_up_to(0.10)
    with pytest.raises(PlanFailure, match="leaves its reach"):  # the lower lifts left out
        plan_with_reach_up_to(0.11, leave_out=("lower-joint-lift",))
    assert "fallbacks" not in plan_with_reach_up_to(0.2).info  # the full lift: no fallback


def test_joint_place_is_the_lift_run_backwards_in_joint_space():
    """The joint grasp sets the object down along its lift's own joint path, reversed: the same states in
    reverse order (solved again from the top, the arms could leave on another IK branch and swing over)."""
    from bimanual_app.planning import default_ready
    from bimanual_app.robots import load_robot
    from bimanual_app.tasks._motion import TaskMotion
    from bimanual_app.tasks._planners import plan_joint_grasp
    from tests._task_fixtures import BAR, FIX_T_B1_B2, _cloud, box_surface_points, fixture_grasps

    robot = load_robot("piper")
    pts, labels = _cloud()
    obj = box_surface_points(BAR["centre"], BAR["size"], 1500, visible_only=False)
    choice = joint_candidates(fixture_grasps(robot), "grasps.json")[0]
    q0 = {"primary": default_ready(robot), "secondary": default_ready(robot)}
    motion = TaskMotion(robot, FIX_T_B1_B2, pts, obj, pts[labels == 1], up=np.array([0.0, 0.0, 1.0]))
    plan = plan_joint_grasp(motion, choice, q0, {"primary": 0.0, "secondary": 0.0})
    phases = {ph.name: ph for ph in plan.phases}
    for arm in ("primary", "secondary"):
        lift, place = phases["lift"].trajectories[arm], phases["place"].trajectories[arm]
        assert np.allclose(place.q, lift.q[::-1])
        assert np.allclose(place.times, lift.times[-1] - lift.times[::-1])


def test_giver_retreat_with_a_short_pre_grasp_is_a_plan_failure_with_a_reason():
    """A pre-grasp nearer than the least back-off gives a PlanFailure naming why (it was a TypeError)."""
    from bimanual_app.tasks._grasps import GraspSpec
    from bimanual_app.tasks._motion import PlanFailure
    from bimanual_app.tasks._planners import _giver_retreat

    gt = GraspSpec("primary", np.eye(4), 0.05, pre_dist=0.03)
    q = {"primary": np.zeros(6), "secondary": np.zeros(6)}
    with pytest.raises(PlanFailure) as e:
        _giver_retreat(None, gt, q, ("secondary", q["secondary"], np.zeros((1, 3))), np.array([0, 0, 1.0]),
                       {"primary": 0.05, "secondary": 0.0})
    assert "3.0 cm" in e.value.message and "back off" in e.value.message


def test_task_motion_names_its_problem_list_problems():
    """TaskMotion.problems(q) lists problems ([] when free); no valid() that is truthy when invalid."""
    from bimanual_app.tasks import TaskMotion

    assert callable(TaskMotion.problems) and not hasattr(TaskMotion, "valid")


def test_preview_bodies_are_the_grasping_stages_primitives_where_it_determined_one():
    """grasps.json's box and cylinder objects become that box / the upright cylinder in it (what the grasps
    were planned on); a free-form object, or one without a shape, stays the body of its points."""
    from types import SimpleNamespace

    from bimanual_app.tasks._preview import primitive_bodies, scene_bodies
    from tests._task_fixtures import box_surface_points, table_points

    T = np.eye(4)
    T[:3, 3] = [0.3, 0.1, 0.05]
    objs = [{"id": 0, "shape": {"kind": "box", "fit": 0.99}, "T_b1_box": T, "extent": [0.3, 0.2, 0.1]},
            {"id": 1, "shape": {"kind": "cylinder", "fit": 0.98}, "T_b1_box": T, "extent": [0.06, 0.056, 0.12]},
            {"id": 2, "shape": {"kind": "free-form", "fit": 0.7}, "T_b1_box": T, "extent": [0.05, 0.05, 0.05]},
            {"id": 3, "T_b1_box": T, "extent": [0.05, 0.05, 0.05]}]
    prim = primitive_bodies({"objects": objs}, [0, 1, 2, 3])
    assert set(prim) == {0, 1}
    assert prim[0].kind == "box" and np.allclose(prim[0].size, [0.3, 0.2, 0.1]) and np.allclose(prim[0].T_b1_o, T)
    assert prim[1].kind == "cylinder" and np.allclose(prim[1].size, [0.058, 0.058, 0.12])
    assert primitive_bodies({"objects": objs}, [2, 3]) == {}
    # the cameras saw the cylinder's upper half only (its lower part hidden behind a neighbour): with the
    # table, the body stands on it instead of floating at the height of the seen part
    from bimanual_app.simulation import table_from_plane

    Tc = np.eye(4)
    Tc[:3, 3] = [0.3, 0.1, 0.08]
    half = [{"id": 1, "shape": {"kind": "cylinder", "fit": 1.0}, "T_b1_box": Tc, "extent": [0.06, 0.06, 0.06]}]
    floating = primitive_bodies({"objects": half}, [1])[1]
    standing = primitive_bodies({"objects": half}, [1], table_from_plane([0.0, 0.0, 1.0], -0.01))[1]
    assert np.isclose(floating.T_b1_o[2, 3] - floating.size[2] / 2, 0.05)
    assert np.isclose(standing.T_b1_o[2, 3] - standing.size[2] / 2, 0.01) and np.isclose(standing.size[2], 0.10)
    assert np.allclose(standing.T_b1_o[:2, 3], [0.3, 0.1]) and np.allclose(standing.size[:2], 0.06)
    # in a task's bodies: the box object is the grasps' box, the other one the body of its points
    pts = np.vstack([table_points(), box_surface_points([0.3, 0.1, 0.05], [0.26, 0.18, 0.1], 1500),
                     box_surface_points([0.3, -0.2, 0.03], [0.04, 0.04, 0.06], 800, seed=3)])
    labels = np.r_[np.full(3000, -1), np.zeros(1500, int), np.ones(800, int)]
    inputs = SimpleNamespace(points=pts, labels=labels, seg_extras={}, grasps={"objects": objs[:1]})
    _, shapes, _ = scene_bodies(inputs)
    assert np.allclose(shapes[0].size, [0.3, 0.2, 0.1], atol=1e-3) and shapes[1].size[0] < 0.06


def test_transfer_goals_keep_the_wrist_branch_the_giver_can_back_off_from():
    """Two IK solutions of one giver pose at a transfer: wrist joints 4 and 6 half a turn apart, joint 5
    negated (a bench scene's OMPL goal and the grasp stage's). From the one with joint 4 0.12 rad from its
    limit every retreat leaves the branch, so only the other is kept; alone, it is kept (the retreat then
    says why it fails)."""
    from _task_fixtures import FIX_T_B1_B2, box_surface_points, table_points

    from bimanual_app.robots import load_robot
    from bimanual_app.tasks._motion import TaskMotion
    from bimanual_app.tasks._planners import _retreatable

    robot = load_robot("piper")
    obj = box_surface_points([0.3, 0.0, 0.03], [0.05, 0.05, 0.06])
    motion = TaskMotion(robot, FIX_T_B1_B2, np.vstack([table_points(), obj]), obj, obj)
    q_free = np.array([0.899, 1.271, -0.537, -1.518, 0.674, 2.013])
    T = robot.fk_link(q_free[None], robot.tcp_link)[0]
    # the same pose on the other wrist branch: joint 4 at 1.62 (limit 1.745); the wrist's axes pass 0.2 mm
    # apart, so IK finds the exact solution near the flipped joints
    q_limit = motion.ik("primary", T, q_free + np.array([0.0, 0.0, 0.0, np.pi, -2 * q_free[4], -np.pi]))[0]
    assert abs(q_limit[3] - 1.624) < 0.01 and abs(q_limit[4] + 0.674) < 0.01
    up = np.array([0.0, 0.0, 1.0])
    kept = _retreatable(motion, "primary", np.stack([q_limit, q_free]), T, up)
    np.testing.assert_allclose(kept, q_free[None])
    np.testing.assert_allclose(_retreatable(motion, "primary", q_limit[None], T, up), q_limit[None])


def test_leave_out_names_only_the_planners_fallbacks():
    """``TaskOptions.leave_out`` (what bench/tasks.py --leave-out measures) takes names from FALLBACKS; any
    other name is refused before anything runs, naming the field and the known names."""
    from bimanual_app.tasks import FALLBACKS, TaskOptions, run_task

    assert {"make-way", "carry-padding", "receiver-back-off", "skip-home", "lower-joint-lift"} <= set(FALLBACKS)
    for bad in (("make_way",), "make-way"):
        with pytest.raises(InputError, match=r"leave_out.*unknown fallback.*make-way, .*shallow-holds"):
            run_task(TaskOptions("handover", "no-such-scene", leave_out=bad))


def test_joint_lift_tries_only_lifts_that_keep_both_grippers_off_the_map(monkeypatch):
    """The lift search drops the lifts along which a gripper comes within the contact margin of the map
    (``TaskMotion.grippers_clear``, the grasp stage's check of its pairs) before any of them is tried."""
    from bimanual_app.kinematics import lift_candidates
    from bimanual_app.tasks._motion import TaskMotion
    from bimanual_app.tasks._planners import plan_joint_grasp
    from tests._task_fixtures import FIX_T_B1_B2

    robot, pts, labels, obj, choice, q0, w0 = _bar_pair()
    up = np.array([0.0, 0.0, 1.0])
    S = {"primary": choice.primary.T_b1_g, "secondary": choice.secondary.T_b1_g}
    widths = {"primary": 0.045, "secondary": 0.045}
    # the check itself: a plate 3 cm over the primary's flange blocks lifting straight up, not every lift
    motion = TaskMotion(robot, FIX_T_B1_B2, pts, obj, pts[labels == 1], up=up)
    c = lift_candidates(obj.mean(axis=0), up, 0.12, 0.105, n_heights=2)
    assert motion.grippers_clear(c, S, widths).all()
    flange = S["primary"] @ np.r_[0.0, 0.0, -0.14, 1.0]
    xx, yy = np.meshgrid(np.linspace(-0.02, 0.02, 9), np.linspace(-0.02, 0.02, 9))
    plate = np.c_[flange[0] + xx.ravel(), flange[1] + yy.ravel(), np.full(xx.size, flange[2] + 0.07)]
    blocked = TaskMotion(robot, FIX_T_B1_B2, np.vstack([pts, plate]), obj, pts[labels == 1], up=up)
    ok = blocked.grippers_clear(c, S, widths)
    assert not ok[0] and ok.any()  # straight up (the first candidate) is not clear
    assert np.array_equal(blocked.grippers_clear(c, S, widths, among=np.array([0, 5])),
                          np.isin(np.arange(len(c)), [0, 5]) & ok)  # only those asked about

    def plan(clear):
        m = TaskMotion(robot, FIX_T_B1_B2, pts, obj, pts[labels == 1], up=up)
        monkeypatch.setattr(m, "grippers_clear", lambda lifts, S, openings, among: clear(lifts))
        return plan_joint_grasp(m, choice, q0, w0)

    full = plan(lambda lifts: np.ones(len(lifts), bool)).info["object_motion"]["lift_m"]
    lower = plan(lambda lifts: lifts.height < lifts.height.max() - 1e-6)  # none of the highest lifts is clear
    assert lower.info["object_motion"]["lift_m"] < full - 1e-3
    with pytest.raises(PlanFailure, match="brings a gripper within 3 mm of the scene map"):
        plan(lambda lifts: np.zeros(len(lifts), bool))


def test_a_gripper_whose_fingers_would_open_into_the_map_where_it_stands_opens_at_its_goal():
    """A few points beside the primary's closed fingers at the start (what the start's clean-up of the map
    kept): opened there, the fingers meet them. The reach is planned with the gripper as it is and it opens
    at its pre-grasp, a phase of its own checked open (``open-at-goal``); left out, the start is not valid."""
    from bimanual_app.tasks._motion import TaskMotion
    from bimanual_app.tasks._planners import plan_joint_grasp
    from tests._task_fixtures import FIX_T_B1_B2

    robot, pts, labels, obj, choice, q0, w0 = _bar_pair()
    up = np.array([0.0, 0.0, 1.0])
    T = TaskMotion(robot, FIX_T_B1_B2, pts, obj, pts[labels == 1], up=up).tcp_pose("primary", q0["primary"])
    g = np.linspace(-0.004, 0.004, 3)
    X, Z = np.meshgrid(g, g)
    stray = (T @ np.c_[X.ravel(), np.full(X.size, 0.035), Z.ravel() - 0.01, np.ones(X.size)].T).T[:, :3]

    def motion(leave_out=()):
        return TaskMotion(robot, FIX_T_B1_B2, np.vstack([pts, stray]), obj, pts[labels == 1], up=up,
                          leave_out=leave_out)

    m = motion()
    with m.context("map", openings={"primary": 0.0, "secondary": 0.0}):
        assert not m.problems(q0)
    with m.context("map", openings={"primary": 0.03, "secondary": 0.0}):
        assert m.problems(q0)
    plan = plan_joint_grasp(m, choice, q0, w0)
    assert "open-at-goal" in plan.info["fallbacks"]
    move, opening = plan.phases[0], plan.phases[1]
    assert move.name == opening.name == "reach" and opening.planner == "gripper"
    assert np.all(move.trajectories["primary"].gripper == 0.0)
    assert opening.trajectories["primary"].gripper[-1] > 0.03
    assert np.ptp(opening.trajectories["primary"].q, axis=0).max() == 0.0  # still while it opens
    with pytest.raises(PlanFailure, match="start configuration is not valid"):
        plan_joint_grasp(motion(leave_out=("open-at-goal",)), choice, q0, w0)


def test_a_reach_blocked_open_at_its_start_and_at_its_goals_names_what_blocks_the_goals():
    """The primary's fingers, opened where it stands, meet the map, and its pre-grasp meets the waiting
    secondary: the failure is the goal's (it names the secondary, whom the hand-over's make-way turns aside),
    not the start's (which opening at the goal would have solved); nothing is planned."""
    import contextlib

    from bimanual_app.tasks._planners import _free_opening

    start, goal = {"primary": np.zeros(6), "secondary": np.zeros(6)}, {"primary": np.ones(6)}

    class Motion:
        leave_out, opening = (), 0.0

        def problems(self, q):
            if q["primary"] is goal["primary"]:
                return ["primary gripper_base / secondary gripper_base collide"]
            return ["primary link8 touches the scene map"] if self.opening > 0 else []

        def plan_free(self, *args):
            raise AssertionError("planned towards a blocked goal")

    m = Motion()

    @contextlib.contextmanager
    def ctx(openings):
        m.opening = openings["primary"]
        yield

    with pytest.raises(PlanFailure, match="no goal is free .*secondary gripper_base") as e:
        _free_opening(m, TaskPlan(start, {"primary": 0.0}), ["primary"], start, [goal], ctx, {"primary": 0.0},
                      {"primary": 0.07})
    assert e.value.stage == "reach" and "start" not in e.value.message.split("(")[0]


def test_an_approach_through_the_wrist_singularity_is_checked_as_the_straight_move_runs_it():
    """A horizontal approach along the forearm (a bench scene's receiving grasp): joint 5 goes from +0.2 to
    -0.25 rad, so the line passes the wrist singularity, and the IK chain seeded along it turns joints 4 and 6
    until joint 4 meets its limit and flips the wrist (a branch switch however split). Moving the joints
    directly keeps the gripper on the line: ``TaskMotion.straight`` (what ``cartesian`` runs) follows it, and
    the approach check keeps that pre-grasp solution instead of refusing every one."""
    from _task_fixtures import FIX_T_B1_B2, box_surface_points, table_points

    from bimanual_app.robots import load_robot
    from bimanual_app.tasks._motion import TaskMotion, line_poses
    from bimanual_app.tasks._planners import _approachable

    robot = load_robot("piper")
    obj = box_surface_points([0.3, 0.3, 0.03], [0.05, 0.05, 0.06])
    motion = TaskMotion(robot, FIX_T_B1_B2, np.vstack([table_points(), obj]), obj, obj)
    q_pre = np.array([-0.045, 0.132, -0.196, 0.037, 0.199, -0.037])
    q = np.array([-0.031, 0.573, -0.185, 0.028, -0.254, -0.028])
    T_pre, T = robot.fk_link(np.stack([q_pre, q]), robot.tcp_link)
    with pytest.raises(PlanFailure, match="another joint branch"):
        motion.ik_path({"primary": line_poses(T_pre, T)}, {"primary": q_pre})
    Q = motion.straight({"primary": (T_pre, T)}, {"primary": q_pre})["primary"]
    np.testing.assert_allclose(Q[0], q_pre, atol=1e-9)
    np.testing.assert_allclose(robot.fk_link(Q[-1:], robot.tcp_link)[0], T, atol=1e-4)
    assert np.abs(np.diff(Q, axis=0)).max() < 0.05  # no joint jumps on the way
    np.testing.assert_allclose(_approachable(motion, "primary", q_pre[None], T_pre, T), q_pre[None])
    # neither way: the same line 40 cm on (through the same flip) to a pose whose joints, moved directly,
    # take the gripper centimetres off the line, is still refused
    T_far = T.copy()
    T_far[:3, 3] += 0.4 * T[:3, 2]
    with pytest.raises(PlanFailure, match=r"another joint branch.*moving the joints directly strays"):
        _approachable(motion, "primary", q_pre[None], T_pre, T_far)

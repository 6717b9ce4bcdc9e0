"""Shared helpers for the simulation and task tests: box surface points and a scripted single-arm grasp."""

from __future__ import annotations

import numpy as np

from bimanual_app.transforms import make_T

# top-down grasp: approach (z) down, closing (y) along b1's x, x = y cross z
R_TOP_DOWN = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
T_B1_B2 = make_T(np.diag([-1.0, -1.0, 1.0]), [0.7, 0.0, 0.0])  # secondary facing the primary, 0.7 m away


def box_surface_points(centre, size, n: int = 1500, seed: int = 0, visible_only: bool = True,
                       noise: float = 0.0) -> np.ndarray:
    """(n,3) points on an axis-aligned box's faces (without the bottom face when ``visible_only``)."""
    rng = np.random.default_rng(seed)
    c, s = np.asarray(centre, float), np.asarray(size, float)
    faces = [(2, +1), (0, -1), (0, +1), (1, -1), (1, +1)] + ([] if visible_only else [(2, -1)])
    pts = []
    for k in range(n):
        ax, sign = faces[k % len(faces)]
        u = rng.uniform(-0.5, 0.5, 3) * s
        u[ax] = sign * s[ax] / 2
        pts.append(c + u)
    return np.asarray(pts) + rng.normal(scale=noise, size=(n, 3))


def table_points(n: int = 3000, z: float = 0.0, half: float = 0.5, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack([rng.uniform(-0.1, 2 * half, n), rng.uniform(-half, half, n), np.full(n, z)], 1) \
        + rng.normal(scale=0.001, size=(n, 3))


def ik(robot, T_b_g, seed):
    """The project's IK, asserting success (tests build reachable poses)."""
    from bimanual_app.kinematics import solve_ik

    r = solve_ik(robot, T_b_g, np.asarray(seed, float))
    assert r.success, r.message
    return r.q


def grasp_R(approach, closing) -> np.ndarray:
    """(3,3) gripper orientation in b1 from its approach (z) and closing (y) directions."""
    z = np.asarray(approach, float) / np.linalg.norm(approach)
    y = np.asarray(closing, float)
    y = y - (y @ z) * z
    y /= np.linalg.norm(y)
    return np.column_stack([np.cross(y, z), y, z])


# approach 45 degrees down and away from the base, closing along b1's y: reachable over the table-top
R_TILTED = grasp_R([1.0, 0.0, -1.0], [0.0, 1.0, 0.0])


# ------------------------------------------------------------------------------------------------------
# A small, complete task work folder built in code (no rendering, no heavy stages): a scene folder whose
# calibration.json is its ground truth, the metric cloud (table + two objects), segments and grasps.json
# in the formats of `bijcr calibrate / segment / grasp`. Geometry (b1): the secondary faces the primary
# 0.6 m away; object 0 is a tall small box for the hand-over, object 1 a long bar for the joint grasp.

FIX_T_B1_B2 = make_T(np.diag([-1.0, -1.0, 1.0]), [0.6, 0.0, 0.0])
SMALL_BOX = {"centre": [0.30, -0.16, 0.05], "size": [0.04, 0.04, 0.10], "mass": 0.10}
BAR = {"centre": [0.30, 0.14, 0.03], "size": [0.30, 0.045, 0.06], "mass": 0.30}


def _scene_folder(root, name: str = "fixture", n: int = 5, seed: int = 0, T_b1_b2=FIX_T_B1_B2,
                  objects: list | None = None):
    """A contract scene folder (poses + reconstruction of camera poses, no images) and its ground truth."""
    from bimanual_app.scene import ArmCapture, GroundTruth, Reconstruction, Scene, write_scene
    from bimanual_app.transforms import so3_exp

    rng = np.random.default_rng(seed)
    T_e1_c1 = make_T(so3_exp(np.array([0.1, -0.2, 0.05])), [0.03, -0.05, 0.06])
    T_e2_c2 = make_T(so3_exp(np.array([-0.1, 0.15, 0.1])), [-0.02, 0.05, 0.07])
    scale = 0.7
    T_w_b1 = make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3))
    arms, T_w_c, arm_idx, keys = [], [], [], []
    for a, (arm, X, T_b1_b) in enumerate([("primary", T_e1_c1, np.eye(4)), ("secondary", T_e2_c2, T_b1_b2)], 1):
        t = np.stack([rng.uniform(0.2, 0.4, n), rng.uniform(-0.2, 0.2, n), rng.uniform(0.15, 0.4, n)], 1)
        T_b_e = make_T(so3_exp(rng.normal(scale=0.6, size=(n, 3))), t)
        ims = [f"images/{i:03d}.png" for i in range(n)]
        arms.append(ArmCapture(arm, ims, T_b_e))
        Twc = T_w_b1 @ T_b1_b @ T_b_e @ X
        Twc[:, :3, 3] /= scale
        T_w_c.append(Twc)
        arm_idx += [a] * n
        keys += ims
    rec = Reconstruction(np.array(arm_idx), np.array(keys), np.concatenate(T_w_c), model="synthetic")
    gt = GroundTruth(T_e1_c1, T_e2_c2, T_b1_b2, scale, objects=list(objects or []),
                     extras={"T_w_b1": T_w_b1.tolist()})
    scene = Scene(root, name, arms[0], arms[1], robot="piper", reconstruction=rec, ground_truth=gt)
    write_scene(scene, root)
    cal = {"format": 1, "scene": name, "scale": scale, "T_e1_c1": T_e1_c1, "T_e2_c2": T_e2_c2,
           "T_b1_w": np.linalg.inv(T_w_b1), "T_b2_w": np.linalg.inv(T_b1_b2) @ np.linalg.inv(T_w_b1),
           "T_b1_b2": T_b1_b2, "views_used": {"primary": n, "secondary": n},
           "residuals": {"rotation_rad": 0.0, "translation_m": 0.0}}
    return scene, cal


def _cloud(seed: int = 0):
    rng = np.random.default_rng(seed)
    n = 6000
    table = np.stack([rng.uniform(-0.15, 0.75, n), rng.uniform(-0.45, 0.45, n), rng.normal(0, 0.0007, n)], 1)
    objs = [box_surface_points(o["centre"], o["size"], 1500, seed=seed + k + 1, noise=0.0007)
            for k, o in enumerate((SMALL_BOX, BAR))]
    # the table is not seen under the objects
    for o in (SMALL_BOX, BAR):
        c, s = np.asarray(o["centre"]), np.asarray(o["size"])
        table = table[~np.all(np.abs(table[:, :2] - c[:2]) < s[:2] / 2 + 0.003, axis=1)]
    pts = np.vstack([table] + objs)
    labels = np.r_[np.full(len(table), -1), np.zeros(len(objs[0]), int), np.ones(len(objs[1]), int)].astype(np.int32)
    return pts, labels


def _grasp(T, width, q=None, q_pre=None, **kw):
    d = {"kind": "pinch", "T_b1_g": T, "width": width, "contact_width": kw.pop("contact_width", None),
         "depth": 0.0, "score": kw.pop("score", 0.8)}
    if q is not None:
        d["q"], d["q_pregrasp"] = q, q_pre
    d.update(kw)
    return d


def fixture_grasps(robot) -> dict:
    """grasps.json for the fixture: a hand-over of object 0 and a pinch pair at the bar's two ends."""
    from bimanual_app.transforms import inv_T

    seed = np.array([0.0, 1.2, -1.0, 0.0, 0.5, 0.0])
    c0 = np.asarray(SMALL_BOX["centre"])
    # pick: tilted approach from the primary's side (+x), fingers on the box's upper part, closing across
    # two opposite faces (a square box pinched across its corners would turn in the fingers)
    d = np.array([1.0, 0.0])
    R_pick = grasp_R([d[0], d[1], -1.0], [-d[1], d[0], 0.0])
    pick = make_T(R_pick, c0 + [0, 0, 0.03])
    # transfer: the object turned so the giver's approach points along +x, raised to 0.28 m
    yaw = -np.arctan2(d[1], d[0])
    Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1.0]])
    target = np.array([0.28, 0.0, 0.28])
    T_move = make_T(Rz, target - Rz @ c0)
    giver_T = T_move @ pick
    receiver = make_T(grasp_R([-1, 0, 0], [0, -1, 0]), target + [0, 0, -0.025])
    q_pick = ik(robot, pick, seed)
    q_give = ik(robot, giver_T, seed)
    q_rec = ik(robot, inv_T(FIX_T_B1_B2) @ receiver, seed)
    handover = {"T_move": T_move, "object_centre_b1": target, "gap": 0.02, "score": 0.7,
                "giver": {"arm": "primary", "pick": {"T_b1_g": pick, "q": q_pick, "width": 0.065},
                          "transfer": {"T_b1_g": giver_T, "q": q_give}, "contact_width": 0.04},
                "receiver": {"arm": "secondary", "T_b1_g": receiver, "width": 0.065, "contact_width": 0.04,
                             "depth": 0.0, "score": 0.7, "q": q_rec}}
    # joint pinch pair: tilted approaches at the bar's ends, each from its own arm's side
    c1, s1 = np.asarray(BAR["centre"]), np.asarray(BAR["size"])
    end1 = c1 + [-s1[0] / 2 + 0.03, 0, 0.015]
    end2 = c1 + [s1[0] / 2 - 0.03, 0, 0.015]
    d1 = end1[:2] / np.linalg.norm(end1[:2])
    T1 = make_T(grasp_R([d1[0], d1[1], -1.0], [0, 1, 0]), end1)
    d2 = (end2[:2] - FIX_T_B1_B2[:2, 3]) / np.linalg.norm(end2[:2] - FIX_T_B1_B2[:2, 3])
    T2 = make_T(grasp_R([d2[0], d2[1], -1.0], [0, -1, 0]), end2)
    joint = [{"rank": 1, "kind": "pinch", "score": 0.75, "imbalance": 0.0, "separation": 0.24,
              "primary": _grasp(T1, 0.065, contact_width=0.045),
              "secondary": _grasp(T2, 0.065, contact_width=0.045)}]
    objects = [{"id": 0, "mode": "single", "grasps": [], "joint_grasps": [], "handover": handover},
               {"id": 1, "mode": "joint", "grasps": [], "joint_grasps": joint, "handover": None}]
    return {"format": 1, "frame": "b1", "T_b1_b2": FIX_T_B1_B2, "pregrasp_distance": 0.08, "objects": objects}


def truth_objects() -> list[dict]:
    out = []
    for k, o in enumerate((SMALL_BOX, BAR)):
        out.append({"id": k, "kind": "box", "shape": "box", "T_b1_o": make_T(np.eye(3), o["centre"]),
                    "size": o["size"], "mass": o["mass"]})
    return out


def make_task_workdir(root, robot, name: str = "fixture"):
    """Write ROOT/scene (scene folder) and ROOT/work/{calibration,segments,grasps}; returns (scene, work)."""
    from pathlib import Path

    import open3d as o3d

    from bimanual_app.io_utils import write_json

    root = Path(root)
    scene, cal = _scene_folder(root / "scene", name=name, objects=truth_objects())
    work = root / "work"
    (work / "calibration").mkdir(parents=True)
    write_json(work / "calibration" / "calibration.json", cal)
    pts, labels = _cloud()
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    o3d.io.write_point_cloud(str(work / "calibration" / "scene_b1.ply"), pc)
    (work / "segments").mkdir()
    np.savez(work / "segments" / "segments.npz", labels=labels)
    write_json(work / "grasps" / "grasps.json", fixture_grasps(robot))
    return root / "scene", work

"""The PyBullet world of a synthetic capture: table, floor, objects, two Piper arms, two wrist cameras.

The simulation's world frame is ``b1`` (the primary arm's base). The table top is the plane z = 0 of b1
(both arms stand on it; the secondary on a pedestal when its base is raised). Headless: ``p.DIRECT`` and
the TinyRenderer, no GUI, no physics stepping (everything is placed kinematically).
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from bimanual_app.transforms import check_T, make_T, xyz_quat_from_T

from ._camera import linear_depth, projection_matrix, view_matrix
from ._objects import ObjectSpec, box_mesh
from ._textures import floor_texture, table_texture, wall_texture

TABLE_THICKNESS = 0.03
TABLE_HEIGHT = 0.75  # floor at z = -TABLE_HEIGHT
# Camera housing (a small depth camera): width, height, depth (m); the optical centre sits on its front face.
CAMERA_BOX = (0.042, 0.042, 0.023)
FINGER_OPENING = 0.04  # metres between the fingers during the capture
NEAR, FAR = 0.02, 10.0
ROOM_HALF = 2.5  # the room: floor and walls 2.5 m from the table's centre
WALL_HEIGHT = 2.6


def park_pose(robot) -> np.ndarray:
    """(J,) where an idle arm waits: the Piper upright ("candle", out of the table's workspace).

    For another robot: its neutral pose (0 clipped into the limits).
    """
    if robot.name == "piper":
        return np.array([0.0, 1.4, -2.8, 0.0, 0.0, 0.0])
    return robot.neutral()


@dataclass
class Table:
    """Table top in b1: ``T_b1_t`` (4, 4) at the top face's centre (z up), ``size`` (3,) x, y, thickness."""

    T_b1_t: np.ndarray
    size: np.ndarray


def _pose(T: np.ndarray) -> tuple[list[float], list[float]]:
    xyz, q = xyz_quat_from_T(T)
    return xyz.tolist(), q.tolist()


def _write_obj(path: Path, V: np.ndarray, F: np.ndarray, UV: np.ndarray, N: np.ndarray) -> None:
    """A minimal Wavefront OBJ with texture coordinates and normals (what PyBullet's loader reads)."""
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in V]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in UV]
    lines += [f"vn {x:.6f} {y:.6f} {z:.6f}" for x, y, z in N]
    lines += ["f " + " ".join(f"{i + 1}/{i + 1}/{i + 1}" for i in f) for f in F]
    path.write_text("\n".join(lines) + "\n")


class SynthWorld:
    """A headless PyBullet client holding the scene. Use as a context manager (disconnects on exit).

    Args:
        robot: the arm model (RobotModel); both arms use it.
        T_b1_b2: (4, 4) secondary base in b1.
        rng: texture randomness.
    """

    def __init__(self, robot, T_b1_b2: np.ndarray, rng: np.random.Generator):
        import pybullet as p

        self.p = p
        self.robot = robot
        self.T_b1_b = [np.eye(4), check_T("T_b1_b2", T_b1_b2).copy()]
        self._tmp = tempfile.TemporaryDirectory(prefix="bijcr-synth-")
        self.tmp = Path(self._tmp.name)
        self.cid = p.connect(p.DIRECT)
        self._n_tex = 0
        self._n_mesh = 0
        self.object_ids: list[int] = []
        self.static_ids: list[int] = []  # table, legs, floor, pedestal
        self._build_room(rng)
        self.arm_ids = [self._load_arm(T) for T in self.T_b1_b]
        self._joint_index = self._arm_joint_indices()
        self.camera_ids = [self._camera_body() for _ in range(2)]
        self.T_e_c = [np.eye(4), np.eye(4)]
        self.q_park = park_pose(robot)
        self.q = [self.q_park.copy(), self.q_park.copy()]
        for a in range(2):
            self.set_arm(a, self.q[a])

    # ------------------------------------------------------------------ building
    def __enter__(self) -> SynthWorld:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self.cid is not None:
            self.p.disconnect(self.cid)
            self.cid = None
        self._tmp.cleanup()

    def _texture(self, img: np.ndarray) -> int:
        path = self.tmp / f"tex{self._n_tex:03d}.png"
        self._n_tex += 1
        Image.fromarray(img).save(path)
        return self.p.loadTexture(str(path), physicsClientId=self.cid)

    def _mesh_file(self, V, F, UV, N) -> str:
        path = self.tmp / f"mesh{self._n_mesh:03d}.obj"
        self._n_mesh += 1
        _write_obj(path, V, F, UV, N)
        return str(path)

    def _box_visual(self, size, rgba=(1, 1, 1, 1), textured: bool = False) -> int:
        p = self.p
        if textured:
            return p.createVisualShape(p.GEOM_MESH, fileName=self._mesh_file(*box_mesh(size)), physicsClientId=self.cid)
        half = (np.asarray(size, dtype=np.float64) / 2).tolist()
        return p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=list(rgba), physicsClientId=self.cid)

    def _box(self, T: np.ndarray, size, rgba=(1, 1, 1, 1), texture: np.ndarray | None = None, mass: float = 0.0) -> int:
        p = self.p
        half = (np.asarray(size, dtype=np.float64) / 2).tolist()
        vs = self._box_visual(size, rgba, textured=texture is not None)
        cs = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=self.cid)
        pos, orn = _pose(T)
        b = p.createMultiBody(mass, cs, vs, basePosition=pos, baseOrientation=orn, physicsClientId=self.cid)
        if texture is not None:
            p.changeVisualShape(b, -1, textureUniqueId=self._texture(texture), rgbaColor=[1, 1, 1, 1],
                                physicsClientId=self.cid)
        return b

    def _build_room(self, rng: np.random.Generator) -> None:
        t12 = self.T_b1_b[1][:3, 3]
        mid = 0.5 * t12[:2]
        yaw = float(np.arctan2(t12[1], t12[0]))
        length = float(np.linalg.norm(t12[:2])) + 0.7
        width = 1.0
        c, s = np.cos(yaw), np.sin(yaw)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        self.table = Table(make_T(R, [mid[0], mid[1], 0.0]), np.array([length, width, TABLE_THICKNESS]))
        top = self.table.T_b1_t @ make_T(np.eye(3), [0.0, 0.0, -TABLE_THICKNESS / 2])
        self.table_id = self._box(top, self.table.size, texture=table_texture(rng))
        self.static_ids.append(self.table_id)
        leg_h = TABLE_HEIGHT - TABLE_THICKNESS
        for sx in (-1, 1):
            for sy in (-1, 1):
                T = self.table.T_b1_t @ make_T(np.eye(3), [sx * (length / 2 - 0.05), sy * (width / 2 - 0.05),
                                                           -TABLE_THICKNESS - leg_h / 2])
                self.static_ids.append(self._box(T, [0.05, 0.05, leg_h], rgba=(0.35, 0.3, 0.25, 1)))
        floor = self.table.T_b1_t @ make_T(np.eye(3), [0.0, 0.0, -TABLE_HEIGHT - 0.01])
        self.static_ids.append(self._box(floor, [2 * ROOM_HALF, 2 * ROOM_HALF, 0.02], texture=floor_texture(rng)))
        for k in range(4):  # walls, so that no view looks into the void
            Rk = self.table.T_b1_t[:3, :3] @ np.array([[np.cos(k * np.pi / 2), -np.sin(k * np.pi / 2), 0.0],
                                                        [np.sin(k * np.pi / 2), np.cos(k * np.pi / 2), 0.0], [0, 0, 1]])
            c = self.table.T_b1_t[:3, 3] + Rk @ np.array([ROOM_HALF, 0.0, WALL_HEIGHT / 2 - TABLE_HEIGHT])
            self.static_ids.append(self._box(make_T(Rk, c), [0.02, 2 * ROOM_HALF, WALL_HEIGHT], texture=wall_texture(rng)))
        dz = float(t12[2])
        if dz > 1e-3:  # the secondary arm stands on a plate of that height
            T = make_T(self.T_b1_b[1][:3, :3], t12 - np.array([0.0, 0.0, dz / 2]))
            self.static_ids.append(self._box(T, [0.16, 0.16, dz], rgba=(0.25, 0.25, 0.28, 1)))

    def _load_arm(self, T_b1_b: np.ndarray) -> int:
        p = self.p
        pos, orn = _pose(T_b1_b)
        return p.loadURDF(str(self.robot.urdf_path), basePosition=pos, baseOrientation=orn, useFixedBase=True,
                          physicsClientId=self.cid)

    def _arm_joint_indices(self) -> dict[str, int]:
        p = self.p
        body = self.arm_ids[0]
        out = {}
        for j in range(p.getNumJoints(body, physicsClientId=self.cid)):
            info = p.getJointInfo(body, j, physicsClientId=self.cid)
            out[info[1].decode()] = j
        return out

    def _camera_body(self) -> int:
        p = self.p
        w, h, d = CAMERA_BOX
        vs = p.createVisualShape(p.GEOM_BOX, halfExtents=[w / 2, h / 2, d / 2], rgbaColor=[0.08, 0.08, 0.1, 1],
                                 visualFramePosition=[0.0, 0.0, -d / 2 - 0.001], physicsClientId=self.cid)
        cs = p.createCollisionShape(p.GEOM_BOX, halfExtents=[w / 2, h / 2, d / 2],
                                    collisionFramePosition=[0.0, 0.0, -d / 2 - 0.001], physicsClientId=self.cid)
        return p.createMultiBody(0.0, cs, vs, physicsClientId=self.cid)

    def add_object(self, spec: ObjectSpec, T_b1_o: np.ndarray) -> int:
        """Create the body of ``spec`` at ``T_b1_o``; returns its PyBullet id (label order = call order)."""
        p = self.p
        half = (spec.size / 2).tolist()
        if spec.shape == "box":
            vs = self._box_visual(spec.size, textured=True)
            cs = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=self.cid)
        elif spec.shape == "cylinder":
            r, h = spec.size[0] / 2, spec.size[2]
            vs = p.createVisualShape(p.GEOM_CYLINDER, radius=r, length=h, physicsClientId=self.cid)
            cs = p.createCollisionShape(p.GEOM_CYLINDER, radius=r, height=h, physicsClientId=self.cid)
        else:
            path = self._mesh_file(spec.vertices, spec.faces, spec.uv, spec.normals)
            vs = p.createVisualShape(p.GEOM_MESH, fileName=path, physicsClientId=self.cid)
            cs = p.createCollisionShape(p.GEOM_MESH, vertices=spec.hull.tolist(), physicsClientId=self.cid)
        pos, orn = _pose(T_b1_o)
        b = p.createMultiBody(spec.mass, cs, vs, basePosition=pos, baseOrientation=orn, physicsClientId=self.cid)
        p.changeVisualShape(b, -1, textureUniqueId=self._texture(spec.texture), rgbaColor=[1, 1, 1, 1],
                            physicsClientId=self.cid)
        self.object_ids.append(b)
        return b

    def move_object(self, body: int, T_b1_o: np.ndarray) -> None:
        pos, orn = _pose(T_b1_o)
        self.p.resetBasePositionAndOrientation(body, pos, orn, physicsClientId=self.cid)

    def remove_object(self, body: int) -> None:
        self.p.removeBody(body, physicsClientId=self.cid)
        self.object_ids.remove(body)

    def distance(self, a: int, b: int, max_distance: float = 1.0) -> float:
        """Signed closest distance (m) between two bodies' collision shapes (negative: overlapping)."""
        pts = self.p.getClosestPoints(a, b, max_distance, physicsClientId=self.cid)
        return min((c[8] for c in pts), default=np.inf)

    # ------------------------------------------------------------------ arms
    def set_hand_eye(self, arm: int, T_e_c: np.ndarray) -> None:
        self.T_e_c[arm] = check_T("T_e_c", T_e_c).copy()
        self.set_arm(arm, self.q[arm])

    def set_arm(self, arm: int, q: np.ndarray) -> np.ndarray:
        """Put arm 0 (primary) or 1 (secondary) at joints q (J,); moves its camera; returns ``T_b_e`` (4, 4)."""
        p = self.p
        q = np.asarray(q, dtype=np.float64)
        self.q[arm] = q.copy()
        body = self.arm_ids[arm]
        for name, v in zip(self.robot.joint_names, q):
            p.resetJointState(body, self._joint_index[name], float(v), physicsClientId=self.cid)
        for name, v in zip(self.robot.finger_joints, self.robot.finger_q(FINGER_OPENING)):
            p.resetJointState(body, self._joint_index[name], float(v), physicsClientId=self.cid)
        T_b_e = self.robot.fk(q)
        pos, orn = _pose(self.T_b1_b[arm] @ T_b_e @ self.T_e_c[arm])
        p.resetBasePositionAndOrientation(self.camera_ids[arm], pos, orn, physicsClientId=self.cid)
        return T_b_e

    def arm_collides(self, arm: int, margin: float = 0.01) -> str | None:
        """What arm ``arm`` (with its camera) touches within ``margin`` metres, or None when free.

        Checks the arm's links and camera against the table, pedestal, objects, the other arm and camera,
        and its own non-neighbouring links (pairs at least three joints apart).
        """
        p = self.p
        me, cam = self.arm_ids[arm], self.camera_ids[arm]
        other = [self.arm_ids[1 - arm], self.camera_ids[1 - arm]]
        n = p.getNumJoints(me, physicsClientId=self.cid)
        for obstacle in self.static_ids + self.object_ids + other:
            for link in range(0 if obstacle in self.static_ids else -1, n):  # the base stands on the table
                if p.getClosestPoints(me, obstacle, margin, linkIndexA=link, physicsClientId=self.cid):
                    return f"link {link} vs body {obstacle}"
            if p.getClosestPoints(cam, obstacle, margin, physicsClientId=self.cid):
                return f"camera vs body {obstacle}"
        wrist = self._joint_index[self.robot.joint_names[-1]]
        hand = set(range(wrist, n))  # flange, gripper and fingers: rigidly together or sliding
        for i in range(-1, n):
            for j in range(i + 3, n):
                if i in hand and j in hand:
                    continue
                if p.getClosestPoints(me, me, margin / 2, linkIndexA=i, linkIndexB=j, physicsClientId=self.cid):
                    return f"self: link {i} vs link {j}"
        for link in range(-1, self._joint_index[self.robot.joint_names[-2]]):  # camera vs own arm up to the forearm
            if p.getClosestPoints(cam, me, margin / 2, linkIndexB=link, physicsClientId=self.cid):
                return f"camera vs own link {link}"
        return None

    # ------------------------------------------------------------------ rendering
    def render(self, T_b1_c: np.ndarray, K: np.ndarray, width: int, height: int, shadows: bool = True
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Render the OpenCV camera ``T_b1_c`` (4, 4) with intrinsics ``K`` (3, 3).

        Returns ``rgb`` (H, W, 3) uint8, ``depth`` (H, W) float64 metric z (inf where nothing is hit) and
        ``seg`` (H, W) int32 PyBullet body ids (-1 where nothing is hit).
        """
        p = self.p
        proj = projection_matrix(width, height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], NEAR, FAR)
        light = self.table.T_b1_t[:3, :3] @ np.array([0.4, 0.25, 1.0])
        _, _, rgb, zbuf, seg = p.getCameraImage(
            width, height, view_matrix(T_b1_c), proj, renderer=p.ER_TINY_RENDERER, shadow=int(shadows),
            lightDirection=light.tolist(), lightColor=[1.0, 1.0, 0.97], lightDistance=3.0,
            lightAmbientCoeff=0.55, lightDiffuseCoeff=0.45, lightSpecularCoeff=0.05, physicsClientId=self.cid)
        rgb = np.reshape(np.asarray(rgb, dtype=np.uint8), (height, width, 4))[..., :3].copy()
        depth = linear_depth(np.reshape(np.asarray(zbuf, dtype=np.float32), (height, width)), NEAR, FAR)
        seg = np.reshape(np.asarray(seg, dtype=np.int32), (height, width))
        depth[(seg < 0) | (depth > 0.999 * FAR)] = np.inf
        return rgb, depth, seg

    def robot_body_ids(self) -> list[int]:
        return list(self.arm_ids) + list(self.camera_ids)

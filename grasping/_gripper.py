"""The parallel gripper's collision geometry, read from the robot model's URDF, in the gripper frame g.

Frame g is the contract's gripper frame: origin midway between the fingertips when closed, z the approach
(from the palm towards the object), y the closing direction, x = y x z. The shapes are the robot model's
own collision geometry (Pinocchio's geometry model of the URDF, coal shapes), so a change to the URDF's
finger or palm boxes changes the planner with it; nothing here repeats their sizes.

Which shapes belong to the gripper: every collision geometry attached to the joint that carries the tool
frame (flange, palm) or to a finger joint. The fingers' motion is taken from the URDF too: each finger
joint is moved to its limits to find its opening direction and how the gap between the fingers' inner
faces grows with it (linear for prismatic fingers, checked).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from bimanual_app.transforms import inv_T

__all__ = ["GripperShape", "GripperModel", "load_gripper"]


@dataclass(frozen=True)
class GripperShape:
    """One collision shape of the gripper.

    Attributes:
        name: geometry name from the URDF (``link7_0``).
        link: the URDF link it belongs to (``link7``).
        geometry: the coal shape (Box, Cylinder, Sphere, ...).
        T_g_s0: (4, 4) placement of the shape in g at opening width 0 (for fingers: their closed placement
            extrapolated back by the closed gap, so that ``T_g_s(w)`` is exact for every width in the stroke).
        motion_g: (3,) displacement of the shape in g per metre of opening width (zero for palm shapes).
        role: ``"palm"`` or ``"finger"``.
        aabb_local: (2, 3) the shape's local axis-aligned box (min, max), for drawing and the closing region.
    """

    name: str
    link: str
    geometry: object
    T_g_s0: np.ndarray
    motion_g: np.ndarray
    role: str
    aabb_local: np.ndarray

    def T_g_s(self, width: float | np.ndarray) -> np.ndarray:
        """Placement(s) ``(4, 4)`` or ``(N, 4, 4)`` of the shape in g at opening width(s) ``width`` (m)."""
        w = np.asarray(width, dtype=np.float64)
        T = np.broadcast_to(self.T_g_s0, w.shape + (4, 4)).copy()
        T[..., :3, 3] += w[..., None] * self.motion_g
        return T

    @property
    def aabb_g0(self) -> np.ndarray:
        """(2, 3) axis-aligned box (min, max) in g of the shape's local box at opening 0; at opening w it is
        translated by ``motion_g * w``."""
        c = self.corners_g(0.0)
        return np.stack([c.min(axis=0), c.max(axis=0)])

    def corners_g(self, width: float) -> np.ndarray:
        """The 8 corners ``(8, 3)`` of the shape's local box, in g, at opening ``width``."""
        lo, hi = self.aabb_local
        c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        T = self.T_g_s(width)
        return c @ T[:3, :3].T + T[:3, 3]


@dataclass(frozen=True)
class GripperModel:
    """A parallel gripper in frame g.

    Attributes:
        robot: robot model name.
        shapes: palm and finger collision shapes.
        min_width: inner gap (m) between the fingers when closed.
        max_width: inner gap (m) when fully open (min_width + stroke).
        finger_x: (2,) x range (m) of the fingers' pads in g (both fingers overlap here).
        finger_z: (2,) z range (m) of the fingers in g (``finger_z[1]`` is the fingertip plane, 0 by contract).
        palm_z: z (m) of the palm's front face in g (the closest non-finger shape ahead of the flange).
        T_e_g: (4, 4) flange (tool link) -> gripper frame.
        finger_joints: names of the finger joints.
    """

    robot: str
    shapes: tuple[GripperShape, ...]
    min_width: float
    max_width: float
    finger_x: np.ndarray
    finger_z: np.ndarray
    palm_z: float
    T_e_g: np.ndarray
    finger_joints: tuple[str, ...] = ()
    finger_gain: tuple[float, ...] = field(default=())  # joint value per metre of opening width, per finger joint
    finger_closed: tuple[float, ...] = field(default=())  # joint value when closed, per finger joint

    @property
    def links(self) -> set[str]:
        """Names of the URDF links the gripper's shapes belong to (flange, palm, fingers)."""
        return {s.link for s in self.shapes}

    @property
    def stroke(self) -> float:
        """Opening range (m): ``max_width - min_width``."""
        return self.max_width - self.min_width

    @property
    def finger_length(self) -> float:
        """Length (m) of the fingers along the approach axis."""
        return float(self.finger_z[1] - self.finger_z[0])

    @property
    def finger_width(self) -> float:
        """Width (m) of the finger pads along x."""
        return float(self.finger_x[1] - self.finger_x[0])

    def finger_q(self, width: float) -> np.ndarray:
        """Finger joint values ``(F,)`` that open the gripper to ``width`` (m), clipped to the stroke."""
        w = float(np.clip(width, self.min_width, self.max_width)) - self.min_width
        return np.array([c + g * w for c, g in zip(self.finger_closed, self.finger_gain)])

    def robot_opening(self, width: float) -> float:
        """The ``opening`` argument of ``RobotModel.finger_q`` / ``CollisionWorld.set_opening`` (the sum of the
        finger joints' travel) that gives an inner gap of ``width`` metres."""
        return float(np.sum(np.abs(self.finger_q(width) - np.asarray(self.finger_closed))))

    def swept_boxes(self, width: np.ndarray, approach: float = 0.0) -> np.ndarray:
        """(N, S, 2, 3) axis-aligned boxes in g of every shape at openings ``width`` (N,), extended back along
        -z by ``approach`` (the volume swept from the pre-grasp). Exact for the box-shaped fingers and palm,
        a bounding box for other shapes."""
        w = np.asarray(width, dtype=np.float64).reshape(-1)
        B0 = np.stack([s.aabb_g0 for s in self.shapes])  # (S, 2, 3)
        mo = np.stack([s.motion_g for s in self.shapes])  # (S, 3)
        B = B0[None] + (w[:, None, None] * mo[None])[:, :, None, :]
        B[:, :, 0, 2] -= approach
        return B

    def shape_poses(self, T_b_g: np.ndarray, width: np.ndarray) -> np.ndarray:
        """Placements ``(N, S, 4, 4)`` in frame b of every shape for grasps ``T_b_g`` (N, 4, 4) at ``width`` (N,)."""
        T_b_g = np.asarray(T_b_g, dtype=np.float64).reshape(-1, 4, 4)
        w = np.broadcast_to(np.asarray(width, dtype=np.float64), (len(T_b_g),))
        T0, motion = self._shape_frames
        # T_g_s per shape, per candidate: (N, S, 4, 4); a new array, so callers may change it in place
        T_g_s = np.broadcast_to(T0, (len(w),) + T0.shape).copy()
        T_g_s[..., :3, 3] += w[:, None, None] * motion
        return T_b_g[:, None] @ T_g_s

    @cached_property
    def _shape_frames(self) -> tuple[np.ndarray, np.ndarray]:
        """(S, 4, 4) every shape's placement in g at opening 0 and (S, 3) its motion per metre of opening."""
        return (np.stack([s.T_g_s0 for s in self.shapes]), np.stack([s.motion_g for s in self.shapes]))


def _local_aabb(geometry) -> np.ndarray:
    geometry.computeLocalAABB()
    bb = geometry.aabb_local
    return np.array([np.asarray(bb.min_, dtype=np.float64), np.asarray(bb.max_, dtype=np.float64)])


def _box_corners(aabb: np.ndarray, T: np.ndarray) -> np.ndarray:
    lo, hi = aabb
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return c @ T[:3, :3].T + T[:3, 3]


_CACHE: dict[str, GripperModel] = {}


@dataclass
class _Hand:
    """The robot model's parts that move the gripper: the tool frame, the hand joint, the finger joints."""

    robot: str
    model: object
    data: object
    geom: object
    gdata: object
    tcp_id: int
    hand_joint: int
    fingers: tuple[str, ...]
    finger_jids: list[int]
    finger_idx: list[int]
    q_mid: np.ndarray
    lo: np.ndarray  # (F,) finger joints' lower limits
    hi: np.ndarray  # (F,) ... upper limits
    by_name: dict  # geometry name -> geometry object

    def placements(self, qf: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """(T_g_shape (4, 4) of every hand and finger shape by name, T_b_g (4, 4)) with the fingers at ``qf``."""
        import pinocchio as pin

        model, data = self.model, self.data
        q = self.q_mid.copy()
        for i, v in zip(self.finger_idx, qf):
            q[i] = v
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        pin.updateGeometryPlacements(model, data, self.geom, self.gdata, q)
        T_b_g = np.asarray(data.oMf[self.tcp_id].homogeneous)
        T_g_b = inv_T(T_b_g)
        out = {}
        for k, go in enumerate(self.geom.geometryObjects):
            if go.parentJoint == self.hand_joint or go.parentJoint in self.finger_jids:
                out[go.name] = T_g_b @ np.asarray(self.gdata.oMg[k].homogeneous)
        return out, T_b_g

    def inner_gap(self, P: dict[str, np.ndarray]) -> tuple[float, list[np.ndarray]]:
        """(the gap between the fingers' inner faces along y, the fingers' box corners (8, 3) each) at placements P."""
        neg, pos, corners = [], [], []
        for n, T in P.items():
            if self.by_name[n].parentJoint in self.finger_jids:
                c = _box_corners(_local_aabb(self.by_name[n].geometry), T)
                corners.append(c)
                (pos if c[:, 1].mean() > 0 else neg).append(c)
        if not neg or not pos:
            raise ValueError(f"robot '{self.robot}': the fingers are not on both sides of the gripper frame's y = 0 plane")
        return float(min(c[:, 1].min() for c in pos) - max(c[:, 1].max() for c in neg)), corners


def _hand(robot: str, rm) -> _Hand:
    """The gripper's joints and frames of the loaded robot model ``rm`` (raises ValueError when missing)."""
    import pinocchio as pin

    tcp = getattr(rm, "tcp_link", None)
    if not tcp:
        raise ValueError(f"robot '{robot}' has no gripper frame (tcp_link); grasps need one")
    model = rm.model
    fingers = tuple(rm.finger_joints)
    if len(fingers) < 2:
        raise ValueError(f"robot '{robot}' has {len(fingers)} finger joint(s); a parallel gripper needs two")
    geom = rm.collision_model
    data, gdata = model.createData(), geom.createData()
    tcp_id = model.getFrameId(tcp)
    hand_joint = int(model.frames[tcp_id].parentJoint)
    finger_jids = [model.getJointId(n) for n in fingers]
    if any(j >= model.njoints for j in finger_jids):
        raise ValueError(f"finger joints {fingers} not all in robot '{robot}'")
    finger_idx = [model.joints[j].idx_q for j in finger_jids]
    lo = np.array([model.lowerPositionLimit[i] for i in finger_idx])
    hi = np.array([model.upperPositionLimit[i] for i in finger_idx])
    return _Hand(robot, model, data, geom, gdata, tcp_id, hand_joint, fingers, finger_jids, finger_idx,
                 pin.neutral(model), lo, hi, {go.name: go for go in geom.geometryObjects})


def _closed_end(hand: _Hand) -> np.ndarray:
    """(F,) which end of each finger joint's range is "closed": the one that brings its shapes nearest y = 0."""
    P_lo, _ = hand.placements(hand.lo)
    P_hi, _ = hand.placements(hand.hi)
    closed = np.empty(len(hand.fingers))
    for f, jid in enumerate(hand.finger_jids):
        names = [n for n, go in hand.by_name.items() if go.parentJoint == jid and n in P_lo]
        if not names:
            raise ValueError(f"finger joint {hand.fingers[f]} of robot '{hand.robot}' carries no collision geometry")
        y_lo = min(np.abs(_box_corners(_local_aabb(hand.by_name[n].geometry), P_lo[n])[:, 1]).min() for n in names)
        y_hi = min(np.abs(_box_corners(_local_aabb(hand.by_name[n].geometry), P_hi[n])[:, 1]).min() for n in names)
        closed[f] = hand.lo[f] if y_lo <= y_hi else hand.hi[f]
    return closed


def _shapes(hand: _Hand, P0: dict[str, np.ndarray], P1: dict[str, np.ndarray], gap0: float,
            stroke: float) -> list[GripperShape]:
    """The gripper's shapes, fingers moving linearly with the opening (placements closed P0 and open P1)."""
    shapes = []
    for n, T0 in P0.items():
        go = hand.by_name[n]
        is_finger = go.parentJoint in hand.finger_jids
        motion = (P1[n][:3, 3] - T0[:3, 3]) / stroke if is_finger else np.zeros(3)
        T_w0 = T0.copy()
        T_w0[:3, 3] -= gap0 * motion  # extrapolated to opening 0, so that T_g_s(w) = T_w0 + w * motion
        shapes.append(GripperShape(n, hand.model.frames[go.parentFrame].name, go.geometry, T_w0, motion,
                                   "finger" if is_finger else "palm", _local_aabb(go.geometry)))
    return shapes


def _palm_z(shapes: list[GripperShape]) -> float:
    """The palm's face: the highest z reached by any non-finger shape."""
    palm_z = -np.inf
    for s in shapes:
        if s.role == "palm":
            c = _box_corners(s.aabb_local, s.T_g_s0)
            palm_z = max(palm_z, float(c[:, 2].max()))
    return palm_z


def load_gripper(robot: str = "piper") -> GripperModel:
    """The gripper of robot ``robot`` (a registry name or URDF path), from its URDF's collision geometry.

    Raises ``ValueError`` when the model has no tool frame or no finger joints.
    """
    if robot in _CACHE:
        return _CACHE[robot]
    from bimanual_app.robots import load_robot

    rm = load_robot(robot)
    hand = _hand(robot, rm)
    closed = _closed_end(hand)
    opened = np.where(closed == hand.lo, hand.hi, hand.lo)
    P0, T_b_g0 = hand.placements(closed)
    P1, _ = hand.placements(opened)
    gap0, corners0 = hand.inner_gap(P0)
    gap1, _ = hand.inner_gap(P1)
    stroke = gap1 - gap0
    if stroke <= 1e-4:
        raise ValueError(f"robot '{robot}': the finger joints do not open the gripper along its y axis")
    # check linearity (prismatic fingers): half-open gives the mean gap
    P_half, _ = hand.placements((closed + opened) / 2)
    if abs(hand.inner_gap(P_half)[0] - (gap0 + gap1) / 2) > 1e-6:
        raise ValueError(f"robot '{robot}': finger gap is not linear in the joint values (prismatic fingers expected)")
    shapes = _shapes(hand, P0, P1, gap0, stroke)
    # pads: x and z ranges where both fingers are (intersection over the fingers' boxes)
    x_lo = max(c[:, 0].min() for c in corners0)
    x_hi = min(c[:, 0].max() for c in corners0)
    z_lo = max(c[:, 2].min() for c in corners0)
    z_hi = min(c[:, 2].max() for c in corners0)
    T_e_g = np.asarray(getattr(rm, "T_e_g", None)) if getattr(rm, "T_e_g", None) is not None else None
    if T_e_g is None:
        ee_id = hand.model.getFrameId(rm.ee_link)
        T_e_g = inv_T(np.asarray(hand.data.oMf[ee_id].homogeneous)) @ T_b_g0
    gm = GripperModel(
        robot=rm.name,
        shapes=tuple(shapes),
        min_width=float(gap0),
        max_width=float(gap1),
        finger_x=np.array([x_lo, x_hi]),
        finger_z=np.array([z_lo, z_hi]),
        palm_z=float(_palm_z(shapes)),
        T_e_g=np.asarray(T_e_g, dtype=np.float64),
        finger_joints=hand.fingers,
        finger_gain=tuple(float(v) for v in (opened - closed) / stroke),
        finger_closed=tuple(float(v) for v in closed),
    )
    _CACHE[robot] = gm
    return gm

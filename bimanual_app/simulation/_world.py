"""The PyBullet preview world: both arms at their base poses, the table and the objects, in frame b1.

PyBullet's world frame *is* b1: the primary arm's base sits at the origin, the secondary's at
``T_b1_b2`` (the calibrated transform for a preview; the true one when checking against reality).
Arms are driven by joint position control with the URDF's effort limits; the two prismatic fingers
close under a force limit, so a grasp holds only through real contacts and friction.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from bimanual_app.transforms import T_from_xyz_quat, check_T, xyz_quat_from_T

from ._bodies import BodyShape, TablePlane

__all__ = ["SimArm", "SimObject", "PreviewWorld", "GRIP_FORCE", "FINGER_FRICTION", "OBJECT_FRICTION", "PAD_STIFFNESS"]

GRIP_FORCE = 20.0  # N per finger while closing (the Piper gripper's rated grip is about 40 N in total)
COUPLING_FORCE = 200.0  # N: the follower finger holds the mirror position of the driven one (see couple_fingers)
FINGER_FRICTION = 1.0  # rubber pads; PyBullet multiplies the two bodies' coefficients
OBJECT_FRICTION = 0.9
TABLE_FRICTION = 0.6
# Compliance of a pushing gripper's contacts (per contact point; a flat face touches at up to 4), see
# SimArm.set_push_compliance. PyBullet's joint motors are rigid up to the URDF effort limits (100 N m), so a
# two-arm squeeze commanded 8 mm into a rigid carton pressed it with 700-900 N: the arms sagged, a fingertip
# rode up onto the top edge and pushed the carton into the table. A real position-controlled Piper yields
# (servo and gear compliance); this stiffness stands in for that: the same press gives about 80 N in total.
PAD_STIFFNESS = 1000.0  # N/m
PAD_DAMPING = 50.0  # N s/m


@dataclass
class SimObject:
    """One object body in the world.

    Attributes:
        name: ``"est:K"`` (estimated from segment K) or ``"true:ID"`` (ground truth), or any label.
        object_id: the segment / ground-truth id it stands for.
        body: PyBullet body id (``-1`` for none).
        shape: its :class:`BodyShape`.
        source: ``"estimate"`` or ``"truth"``.
        ghost: True for a visual-only body (no collision, no mass).
    """

    name: str
    object_id: int
    body: int
    shape: BodyShape
    source: str = "estimate"
    ghost: bool = False


class SimArm:
    """One Piper arm in the world: joint control, gripper, poses and contacts."""

    def __init__(self, client: int, robot, name: str, T_b1_b: np.ndarray, color: tuple | None = None):
        import pybullet as p

        self.p, self.cid, self.robot, self.name = p, client, robot, name
        self.T_b1_b = check_T(f"T_b1_b ({name})", T_b1_b)
        xyz, quat = xyz_quat_from_T(self.T_b1_b)
        self.body = p.loadURDF(str(robot.urdf_path), xyz.tolist(), quat.tolist(), useFixedBase=True,
                               physicsClientId=client)
        names = {}
        for j in range(p.getNumJoints(self.body, physicsClientId=client)):
            info = p.getJointInfo(self.body, j, physicsClientId=client)
            names[info[1].decode()] = j
            names["link:" + info[12].decode()] = j
        self.arm_joints = [names[n] for n in robot.joint_names]
        self.finger_joints = [names[n] for n in robot.finger_joints]
        self.finger_links = list(self.finger_joints)  # a joint's child link has the joint's index
        palm = {p.getJointInfo(self.body, j, physicsClientId=client)[16] for j in self.finger_joints}
        self.gripper_links = sorted(set(self.finger_links) | {int(i) for i in palm if i >= 0})
        tcp = robot.tcp_link or robot.ee_link
        self.tcp_link = names["link:" + tcp]
        self.efforts = np.array([p.getJointInfo(self.body, j, physicsClientId=client)[10] for j in self.arm_joints])
        self.efforts[~(self.efforts > 0)] = 50.0
        for j in self.finger_links:
            p.changeDynamics(self.body, j, lateralFriction=FINGER_FRICTION, spinningFriction=0.01,
                             frictionAnchor=1, physicsClientId=client)
        if color is not None:
            for j in range(-1, p.getNumJoints(self.body, physicsClientId=client)):
                if j not in self.finger_links:
                    p.changeVisualShape(self.body, j, rgbaColor=color, physicsClientId=client)
        self.q_cmd = robot.neutral()
        self.width_cmd = 0.0
        self.grip_force = GRIP_FORCE
        # the second finger's position as a multiple of the first's (-1: the two slide opposite ways)
        signs = robot.finger_q(1.0)
        self._mirror = float(signs[1] / signs[0]) if len(signs) == 2 and signs[0] != 0 and signs[1] != 0 else None

    def set_push_compliance(self) -> None:
        """Give the gripper's contacts the arm's compliance (``PAD_STIFFNESS``) from now on, for an arm that
        holds by pushing (two grippers squeezing an object between them), where the arm's joints make the force.

        A pinch leaves the contacts rigid: there the gripper's force-limited drive sets the grip force
        whatever the arm's stiffness, and PyBullet's soft contacts let a pinched object slip (measured: a
        hand-over's giver dropped a small box on the lift with soft pads, held it with rigid ones). One-way:
        PyBullet has no call that makes a link's contacts rigid again.
        """
        for j in self.gripper_links:
            self.p.changeDynamics(self.body, j, contactStiffness=PAD_STIFFNESS, contactDamping=PAD_DAMPING,
                                  physicsClientId=self.cid)

    # ------------------------------------------------------------------ state
    def reset(self, q: np.ndarray, width: float = 0.0) -> None:
        """Teleport to arm configuration q (J,) with the gripper open to ``width`` (m); commands follow."""
        q = np.asarray(q, dtype=np.float64).reshape(self.robot.nq_arm)
        for j, v in zip(self.arm_joints, q):
            self.p.resetJointState(self.body, j, float(v), 0.0, physicsClientId=self.cid)
        for j, v in zip(self.finger_joints, self.robot.finger_q(width)):
            self.p.resetJointState(self.body, j, float(v), 0.0, physicsClientId=self.cid)
        self.command(q)
        self.set_gripper(width)

    def q(self) -> np.ndarray:
        """(J,) measured arm joint angles."""
        return np.array([s[0] for s in self.p.getJointStates(self.body, self.arm_joints, physicsClientId=self.cid)])

    def width(self) -> float:
        """Measured gripper opening (m), in the robot model's convention (sum of finger travels)."""
        s = [st[0] for st in self.p.getJointStates(self.body, self.finger_joints, physicsClientId=self.cid)]
        return float(sum(abs(v) for v in s))

    def link_pose(self, link: int) -> np.ndarray:
        st = self.p.getLinkState(self.body, link, computeForwardKinematics=True, physicsClientId=self.cid)
        return T_from_xyz_quat(np.array(st[4]), np.array(st[5]))

    def tcp_pose(self) -> np.ndarray:
        """(4,4) ``T_b1_g`` of the gripper frame (measured)."""
        return self.link_pose(self.tcp_link)

    # ------------------------------------------------------------------ commands
    def command(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        """Position-control target q (J,) with feed-forward velocity qd (J,)."""
        self.q_cmd = np.asarray(q, dtype=np.float64)
        qd = np.zeros_like(self.q_cmd) if qd is None else np.asarray(qd, dtype=np.float64)
        n = len(self.arm_joints)
        self.p.setJointMotorControlArray(
            self.body, self.arm_joints, self.p.POSITION_CONTROL, targetPositions=self.q_cmd.tolist(),
            targetVelocities=qd.tolist(), forces=self.efforts.tolist(), positionGains=[0.3] * n,
            velocityGains=[1.0] * n, physicsClientId=self.cid)

    def set_gripper(self, width: float, force: float | None = None) -> None:
        """Drive the fingers towards opening ``width`` (m) with at most ``force`` N per finger.

        Closing on an object stops at contact and keeps squeezing with ``force``: the hold is physical.
        """
        self.width_cmd = float(width)
        f = self.grip_force if force is None else float(force)
        drive = self.finger_joints[:1] if self._mirror is not None else self.finger_joints  # see couple_fingers
        for j, v in zip(drive, self.robot.finger_q(max(width, 0.0))):
            self.p.setJointMotorControl2(self.body, j, self.p.POSITION_CONTROL, targetPosition=float(v),
                                         force=f, maxVelocity=0.08, positionGain=0.2, velocityGain=1.0,
                                         physicsClientId=self.cid)
        self.couple_fingers()

    def couple_fingers(self) -> None:
        """Keep the second finger at the mirror image of the first (called before every physics step).

        The Piper's fingers are driven by one motor through a rack and pinion: they always move together,
        so closing on an object pushes it to the middle of the gripper. Two independently driven fingers
        in the simulation would each stop where they first touch and leave an object off-centre (1.6 cm
        was seen), which a hand-over then misses. The first finger carries the force-limited drive; the
        second follows its mirror position (PyBullet's gear constraint couples rotations, not slides).
        """
        if len(self.finger_joints) != 2 or self._mirror is None:
            return
        lead = self.p.getJointState(self.body, self.finger_joints[0], physicsClientId=self.cid)[0]
        self.p.setJointMotorControl2(self.body, self.finger_joints[1], self.p.POSITION_CONTROL,
                                     targetPosition=float(self._mirror * lead), force=COUPLING_FORCE,
                                     positionGain=0.5, velocityGain=1.0, physicsClientId=self.cid)

    # ------------------------------------------------------------------ contacts
    def finger_forces(self, body: int) -> tuple[float, float]:
        """Total normal force (N) of each finger on ``body``."""
        out = []
        for link in self.finger_links:
            cps = self.p.getContactPoints(self.body, body, linkIndexA=link, physicsClientId=self.cid)
            out.append(float(sum(c[9] for c in cps)))
        return out[0], out[1]

    def touches(self, body: int) -> bool:
        """Any link of this arm in contact with ``body``."""
        return len(self.p.getContactPoints(self.body, body, physicsClientId=self.cid)) > 0

    def holds(self, body: int, min_force: float = 0.5) -> bool:
        """Both fingers press on ``body`` (each with at least ``min_force`` N): a pinch grasp."""
        a, b = self.finger_forces(body)
        return a >= min_force and b >= min_force

    def presses(self, body: int, min_force: float = 2.0) -> bool:
        """The gripper (fingers or palm) presses on ``body`` with at least ``min_force`` N in total: the hold
        of a push contact, where the open fingertips squeeze a face and often only one of them touches."""
        total = 0.0
        for link in self.gripper_links:
            cps = self.p.getContactPoints(self.body, body, linkIndexA=link, physicsClientId=self.cid)
            total += float(sum(c[9] for c in cps))
        return total >= min_force


class PreviewWorld:
    """A PyBullet world in frame b1 with two arms, a table and objects.

    Args:
        robot: :class:`bimanual_app.robots.RobotModel` of the arms (both the same model).
        T_b1_b2: (4,4) pose of the secondary base in b1.
        gui: open a window when a display exists (``DISPLAY`` set); otherwise headless (DIRECT).
        dt: physics step (s).
        recorder: a :class:`~._record.Recorder` called every step (captures frames at its own rate).
    """

    def __init__(self, robot, T_b1_b2: np.ndarray, gui: bool = False, dt: float = 1.0 / 240.0, recorder=None):
        import pybullet as p

        self.p = p
        self.gui = bool(gui and os.environ.get("DISPLAY"))
        if gui and not self.gui:
            print("simulation: --gui asked but no display (DISPLAY is unset): running headless", file=sys.stderr)
        self.cid = p.connect(p.GUI if self.gui else p.DIRECT)
        if self.cid < 0:
            raise RuntimeError("cannot start PyBullet")
        p.resetSimulation(physicsClientId=self.cid)
        p.setGravity(0, 0, -9.81, physicsClientId=self.cid)
        p.setTimeStep(dt, physicsClientId=self.cid)
        p.setPhysicsEngineParameter(numSolverIterations=150, physicsClientId=self.cid)
        self.dt = float(dt)
        self.time = 0.0
        self.robot = robot
        self.T_b1_b2 = check_T("T_b1_b2", T_b1_b2)
        self.arms: dict[str, SimArm] = {
            "primary": SimArm(self.cid, robot, "primary", np.eye(4), color=(0.78, 0.80, 0.85, 1)),
            "secondary": SimArm(self.cid, robot, "secondary", self.T_b1_b2, color=(0.85, 0.78, 0.62, 1)),
        }
        self.table: TablePlane | None = None
        self.table_body = -1
        self.objects: dict[str, SimObject] = {}
        self.recorder = recorder
        self._listeners: list[Callable[[PreviewWorld], None]] = []
        if recorder is not None:
            recorder.attach(self)

    # ------------------------------------------------------------------ scene
    def add_table(self, table: TablePlane) -> int:
        """A static box whose top face is the table plane."""
        p = self.p
        half = [float(table.size[0] / 2), float(table.size[1] / 2), table.thickness / 2]
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=self.cid)
        vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=[0.55, 0.45, 0.35, 1], physicsClientId=self.cid)
        T = table.T_b1_t.copy()
        T[:3, 3] -= table.normal * (table.thickness / 2)
        xyz, quat = xyz_quat_from_T(T)
        self.table_body = p.createMultiBody(0.0, col, vis, xyz.tolist(), quat.tolist(), physicsClientId=self.cid)
        p.changeDynamics(self.table_body, -1, lateralFriction=TABLE_FRICTION, physicsClientId=self.cid)
        self.table = table
        return self.table_body

    def add_object(self, name: str, shape: BodyShape, object_id: int = -1, source: str = "estimate",
                   color: tuple = (0.2, 0.55, 0.85, 1.0), ghost: bool = False) -> SimObject:
        """Add a body for ``shape``; ``ghost=True`` makes it visual-only (no collision, no mass)."""
        p = self.p
        if name in self.objects:
            raise ValueError(f"an object named {name!r} is already in the world")
        col = -1
        if shape.kind == "hull":
            verts = shape.vertices.tolist()
            if not ghost:
                col = p.createCollisionShape(p.GEOM_MESH, vertices=verts, physicsClientId=self.cid)
            vis = p.createVisualShape(p.GEOM_MESH, vertices=verts, indices=shape.faces.reshape(-1).tolist(),
                                      rgbaColor=list(color), physicsClientId=self.cid)
        elif shape.kind == "box":
            half = (shape.size / 2).tolist()
            if not ghost:
                col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=self.cid)
            vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=list(color), physicsClientId=self.cid)
        elif shape.kind == "cylinder":
            r, h = float(shape.size[0] / 2), float(shape.size[2])
            if not ghost:
                col = p.createCollisionShape(p.GEOM_CYLINDER, radius=r, height=h, physicsClientId=self.cid)
            vis = p.createVisualShape(p.GEOM_CYLINDER, radius=r, length=h, rgbaColor=list(color), physicsClientId=self.cid)
        elif shape.kind == "sphere":
            r = float(shape.size[0] / 2)
            if not ghost:
                col = p.createCollisionShape(p.GEOM_SPHERE, radius=r, physicsClientId=self.cid)
            vis = p.createVisualShape(p.GEOM_SPHERE, radius=r, rgbaColor=list(color), physicsClientId=self.cid)
        else:
            raise ValueError(f"unknown shape kind {shape.kind!r}")
        xyz, quat = xyz_quat_from_T(shape.T_b1_o)
        body = p.createMultiBody(0.0 if ghost else shape.mass, col, vis, xyz.tolist(), quat.tolist(),
                                 physicsClientId=self.cid)
        if not ghost:
            p.changeDynamics(body, -1, lateralFriction=OBJECT_FRICTION, spinningFriction=0.005,
                             rollingFriction=0.0005, frictionAnchor=1, physicsClientId=self.cid)
        obj = SimObject(name, int(object_id), body, shape, source, ghost)
        self.objects[name] = obj
        return obj

    def settle_objects(self, seconds: float = 0.3) -> None:
        """Let the objects come to rest on the table (arms held where they are)."""
        self.step(int(round(seconds / self.dt)), record=False)

    # ------------------------------------------------------------------ queries
    def object_pose(self, obj: SimObject | str) -> np.ndarray:
        """(4,4) ``T_b1_o`` of an object's body now."""
        obj = self.objects[obj] if isinstance(obj, str) else obj
        xyz, quat = self.p.getBasePositionAndOrientation(obj.body, physicsClientId=self.cid)
        return T_from_xyz_quat(np.array(xyz), np.array(quat))

    def on_table(self, obj: SimObject | str) -> bool:
        """The object touches the table."""
        obj = self.objects[obj] if isinstance(obj, str) else obj
        if self.table_body < 0:
            return False
        return len(self.p.getContactPoints(obj.body, self.table_body, physicsClientId=self.cid)) > 0

    def height(self, obj: SimObject | str) -> float:
        """Height of the object's origin above the table plane (or b1's z without a table)."""
        z = self.object_pose(obj)[:3, 3]
        return float(self.table.height(z)) if self.table is not None else float(z[2])

    def arm_contacts(self) -> list[tuple[str, str]]:
        """Pairs of things in contact that should not be: arm-arm, arm-table (for the validity report)."""
        out = []
        a, b = self.arms["primary"], self.arms["secondary"]
        if self.p.getContactPoints(a.body, b.body, physicsClientId=self.cid):
            out.append(("primary", "secondary"))
        if self.table_body >= 0:
            for arm in (a, b):
                if self.p.getContactPoints(arm.body, self.table_body, physicsClientId=self.cid):
                    out.append((arm.name, "table"))
        return out

    # ------------------------------------------------------------------ time
    def add_listener(self, fn: Callable[[PreviewWorld], None]) -> None:
        """Call ``fn(world)`` after every physics step (monitors, success checks)."""
        self._listeners.append(fn)

    def remove_listener(self, fn) -> None:
        self._listeners.remove(fn)

    def step(self, n: int = 1, record: bool = True) -> None:
        for _ in range(int(n)):
            if self.gui:  # a window plays in real time, so a person can follow it
                import time

                now = time.perf_counter()
                self._wall = getattr(self, "_wall", now)
                if self._wall > now:
                    time.sleep(self._wall - now)
                self._wall = max(self._wall, now) + self.dt
            for arm in self.arms.values():
                arm.couple_fingers()
            self.p.stepSimulation(physicsClientId=self.cid)
            self.time += self.dt
            for fn in list(self._listeners):
                fn(self)
            if record and self.recorder is not None:
                self.recorder.on_step(self)

    def hold(self, seconds: float) -> None:
        """Keep the current commands for ``seconds`` of simulated time."""
        self.step(int(round(seconds / self.dt)))

    def run_plan(self, plan: Mapping[str, object], settle: float = 0.0) -> None:
        """Execute time-parametrised trajectories, one per arm, on a shared clock.

        ``plan`` maps arm name -> trajectory (anything with ``sample(t) -> (q, width|None)`` and
        ``duration``, e.g. :class:`bimanual_app.hardware.JointTrajectory`). At each physics step every arm
        gets the position target and the feed-forward velocity at that time, and its gripper the width
        target; arms not in the plan keep their last commands.
        """
        dur = max((float(tr.duration) for tr in plan.values()), default=0.0)
        n = int(np.ceil(dur / self.dt))
        t = np.minimum(np.arange(n + 1) * self.dt, dur)
        t2 = np.minimum(t + self.dt, dur)
        samples = {name: _samples(tr, t) + (_samples(tr, t2)[0],) for name, tr in plan.items()}
        for k in range(n + 1):
            for name, (Q, W, Q2) in samples.items():
                arm = self.arms[name]
                arm.command(Q[k], (Q2[k] - Q[k]) / self.dt)
                w = None if W is None else float(W[k])
                if w is not None and abs(w - arm.width_cmd) > 1e-6:
                    arm.set_gripper(w)
            self.step(1)
        if settle > 0:
            self.hold(settle)

    def close(self) -> None:
        if self.cid is not None and self.cid >= 0:
            try:
                self.p.disconnect(physicsClientId=self.cid)
            except Exception:  # already gone (window closed by the user)
                pass
            self.cid = -1

    def __enter__(self) -> PreviewWorld:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _samples(tr, ts: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """A trajectory's joint angles (T,J) and widths (T,) or None at the times ``ts`` (T,): all at once where
    it can (``sample_many``), else one ``sample(t)`` per time."""
    if hasattr(tr, "sample_many"):
        return tr.sample_many(ts)
    out = [tr.sample(float(t)) for t in ts]
    W = None if out[0][1] is None else np.array([w for _, w in out], dtype=np.float64)
    return np.stack([np.asarray(q, dtype=np.float64) for q, _ in out]), W

"""RobotModel: one arm's Pinocchio model with its limits, tool link and forward kinematics."""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

import numpy as np

from bimanual_app.io_utils import InputError, Problem
from bimanual_app.robots._fk import BatchFK
from bimanual_app.robots._registry import REGISTRY, RobotSpec, known_robots

__all__ = ["RobotModel", "load_robot"]

# When a URDF names no acceleration limit (URDF cannot), assume full speed is reached in 0.5 s.
DEFAULT_ACCEL_PER_VELOCITY = 2.0  # 1/s
DEFAULT_VELOCITY = 1.0  # rad/s (or m/s) when the URDF gives 0 or nothing


class RobotModel:
    """One arm: Pinocchio model (arm joints first, then fingers), limits, tool frames, FK.

    Attributes:
        name: registry name, or the URDF's file stem.
        urdf_path: the URDF file (Path).
        model: ``pinocchio.Model`` of the whole URDF (arm and finger joints); ``model.nq`` >= ``nq_arm``.
        nq_arm: number of arm joints J (those on the chain from the root to ``ee_link``).
        joint_names: (J,) names of the arm joints, in configuration order.
        finger_joints: names of the other joints (fingers), held at ``finger_q(opening)`` by the arm API.
        lower, upper: (J,) arm joint limits (rad; m for prismatic).
        velocity_limits, accel_limits: (J,) per-joint limits (rad/s, rad/s^2).
        ee_link: the tool link whose pose ``fk`` returns (frame ``e`` of the contract).
        tcp_link: the gripper frame ``g`` link, or None.
        T_e_g: (4,4) ``T_e_g`` flange-to-gripper transform, or None without ``tcp_link``.
        limits_source: where the velocity / acceleration limits come from.
    """

    def __init__(self, name: str, urdf_path: Path, ee_link: str | None = None, spec: RobotSpec | None = None):
        self.name = name
        self.urdf_path = Path(urdf_path)
        self.spec = spec
        self._load_urdf()
        self._set_ee_link(ee_link, spec)
        self._set_arm_chain(spec)
        self._set_limits(spec)
        self._set_tcp(spec)

    def _load_urdf(self) -> None:
        """Pinocchio model, its data and the batched FK of the URDF; an InputError names a bad file."""
        import pinocchio as pin

        try:
            self.model = pin.buildModelFromUrdf(str(self.urdf_path))
        except Exception as e:  # urdfdom / pinocchio report malformed files with various exception types
            raise InputError(Problem(str(self.urdf_path), "", f"cannot parse URDF: {e}", "check the file is a valid URDF")) from e
        self._data = self.model.createData()
        self._finger_cache: dict[float, np.ndarray] = {}
        try:
            self._batch = BatchFK(self.model)
        except ValueError as e:
            raise InputError(Problem(str(self.urdf_path), "joints", str(e), "use a URDF with revolute/prismatic joints")) from e

    def _set_ee_link(self, ee_link: str | None, spec: RobotSpec | None) -> None:
        """The tool link: given, the registry's, or the flange found in the URDF; it must be a link."""
        import pinocchio as pin

        self.link_names = [f.name for f in self.model.frames if f.type == pin.FrameType.BODY]
        ee = ee_link or (spec.ee_link if spec else None) or self._default_ee_link()
        if not self.model.existFrame(ee) or self.model.frames[self.model.getFrameId(ee)].type != pin.FrameType.BODY:
            raise InputError(
                Problem(str(self.urdf_path), "ee_link", f"no link named {ee!r}", f"use one of: {', '.join(self.link_names)}")
            )
        self.ee_link = ee
        self._ee_id = self.model.getFrameId(ee)

    def _set_arm_chain(self, spec: RobotSpec | None) -> None:
        """Arm joints: the chain from the root to the ee link's joint; everything else counts as fingers."""
        ee = self.ee_link
        chain = []
        j = int(self.model.frames[self._ee_id].parentJoint)
        while j > 0:
            chain.append(j)
            j = int(self.model.parents[j])
        chain.reverse()
        self._arm_joint_ids = chain
        self.nq_arm = len(chain)
        idx = [int(self.model.joints[j].idx_q) for j in chain]
        if idx != list(range(self.nq_arm)):
            raise InputError(
                Problem(str(self.urdf_path), "joints", "the arm joints are not the first joints of the model",
                        "put the arm chain first in the URDF (side branches after the tool link)")
            )
        if self.nq_arm == 0:
            raise InputError(Problem(str(self.urdf_path), "ee_link", f"{ee!r} is not moved by any joint", "choose the arm's tool link"))
        self.joint_names = [self.model.names[j] for j in chain]
        self.finger_joints = [self.model.names[j] for j in range(1, self.model.njoints) if j not in chain]
        if spec and spec.finger_joints and tuple(self.finger_joints) != tuple(spec.finger_joints):
            raise InputError(
                Problem(str(self.urdf_path), "joints", f"finger joints {self.finger_joints} differ from the registry's"
                        f" {list(spec.finger_joints)}", "use the packaged URDF or pass the file as a path")
            )

    def _set_limits(self, spec: RobotSpec | None) -> None:
        """Position limits of arm and finger joints (finite, lower < upper), velocity and acceleration limits."""
        lo = np.asarray(self.model.lowerPositionLimit, dtype=np.float64)
        hi = np.asarray(self.model.upperPositionLimit, dtype=np.float64)
        self.lower = lo[: self.nq_arm].copy()
        self.upper = hi[: self.nq_arm].copy()
        self._finger_lower = lo[self.nq_arm:].copy()
        self._finger_upper = hi[self.nq_arm:].copy()
        if not (np.all(np.isfinite(self.lower)) and np.all(np.isfinite(self.upper)) and np.all(self.upper > self.lower)):
            raise InputError(
                Problem(str(self.urdf_path), "limit", "every arm joint needs finite lower < upper limits",
                        "add <limit lower=... upper=...> to each arm joint")
            )
        vel = np.asarray(self.model.velocityLimit, dtype=np.float64)[: self.nq_arm].copy()
        if spec and spec.velocity_limits:
            self.velocity_limits = np.asarray(spec.velocity_limits, dtype=np.float64)
            self.accel_limits = np.asarray(spec.accel_limits, dtype=np.float64)
            self.limits_source = spec.source
        else:
            vel[~(np.isfinite(vel) & (vel > 0))] = DEFAULT_VELOCITY
            self.velocity_limits = vel
            self.accel_limits = DEFAULT_ACCEL_PER_VELOCITY * vel
            self.limits_source = (
                f"URDF <limit velocity>; acceleration assumed {DEFAULT_ACCEL_PER_VELOCITY:g} x velocity per second"
            )

    def _set_tcp(self, spec: RobotSpec | None) -> None:
        """The gripper link and ``T_e_g`` (flange to gripper, at the neutral configuration), when the registry names one."""
        self.tcp_link = (spec.tcp_link if spec else None)
        if self.tcp_link is not None:
            q0 = self.neutral()
            self.T_e_g = np.linalg.inv(self.fk_link(q0, self.ee_link)) @ self.fk_link(q0, self.tcp_link)
            self.T_e_g[3] = [0.0, 0.0, 0.0, 1.0]
        else:
            self.T_e_g = None

    # ------------------------------------------------------------------ helpers
    def _default_ee_link(self) -> str:
        """The child link of the deepest revolute joint (the flange), for URDFs the registry does not know."""
        import pinocchio as pin

        best, best_depth = None, -1
        for i in range(1, self.model.njoints):
            if self._batch.kinds[i] != "R":
                continue
            depth, j = 0, i
            while j > 0:
                depth, j = depth + 1, int(self.model.parents[j])
            if depth > best_depth:
                best, best_depth = i, depth
        if best is None:
            raise InputError(Problem(str(self.urdf_path), "joints", "no revolute joint found", "pass a robot arm URDF"))
        for f in self.model.frames:  # the body frame that sits directly on that joint
            if f.type == pin.FrameType.BODY and int(f.parentJoint) == best and f.placement.isIdentity():
                return f.name
        return next(f.name for f in self.model.frames if f.type == pin.FrameType.BODY and int(f.parentJoint) == best)

    def neutral(self) -> np.ndarray:
        """(J,) a configuration inside the limits: 0 clipped into [lower, upper]."""
        return np.clip(np.zeros(self.nq_arm), self.lower, self.upper)

    def finger_q(self, opening: float = 0.0) -> np.ndarray:
        """(model.nq - J,) finger joint values for a gripper opening (metres between the fingers).

        A prismatic finger whose range is [0, a] moves +opening/2, one with [-a, 0] moves -opening/2;
        values are clipped to the limits. Non-prismatic extra joints stay at 0 clipped into range.
        """
        out = np.zeros(self.model.nq - self.nq_arm)
        for k, name in enumerate(self.finger_joints):
            j = self.model.getJointId(name)
            lo, hi = self._finger_lower[k], self._finger_upper[k]
            if self._batch.kinds[j] == "P" and lo >= -1e-9:
                out[k] = opening / 2
            elif self._batch.kinds[j] == "P" and hi <= 1e-9:
                out[k] = -opening / 2
            out[k] = np.clip(out[k], lo, hi)
        return out

    def full_q(self, q: np.ndarray, opening: float = 0.0) -> np.ndarray:
        """(..., model.nq) from arm configurations (..., J) (or full ones, returned as float64 copies)."""
        q = np.asarray(q, dtype=np.float64)
        if q.shape[-1] == self.model.nq:
            return q.copy()
        if q.shape[-1] != self.nq_arm:
            raise ValueError(f"q: expected last dimension {self.nq_arm} (arm) or {self.model.nq} (full), got {q.shape}")
        if self.model.nq == self.nq_arm:
            return q.copy()
        key = float(opening)
        fq = self._finger_cache.get(key)
        if fq is None:
            fq = self._finger_cache[key] = self.finger_q(opening)
        if q.ndim == 1:
            return np.concatenate([q, fq])
        return np.concatenate([q, np.broadcast_to(fq, q.shape[:-1] + fq.shape)], axis=-1)

    def within_limits(self, q: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        """bool (...,): arm configurations (..., J) inside [lower - tol, upper + tol]."""
        q = np.asarray(q, dtype=np.float64)
        return np.all((q >= self.lower - tol) & (q <= self.upper + tol), axis=-1)

    def random_q(self, n: int, rng: np.random.Generator | int | None = None, margin: float = 0.0) -> np.ndarray:
        """(n, J) configurations uniform inside the limits (shrunk by ``margin`` on each side)."""
        rng = np.random.default_rng(rng)
        return rng.uniform(self.lower + margin, self.upper - margin, size=(n, self.nq_arm))

    @cached_property
    def frame_ids(self) -> dict[str, int]:
        return {f.name: i for i, f in enumerate(self.model.frames)}

    def frame_id(self, link: str) -> int:
        if link not in self.frame_ids:
            raise ValueError(f"{self.name}: no link or frame named {link!r}; links: {', '.join(self.link_names)}")
        return self.frame_ids[link]

    # ------------------------------------------------------------------ kinematics
    def fk_link(self, q: np.ndarray, link: str, opening: float = 0.0) -> np.ndarray:
        """Pose ``T_b_link`` of any link/frame: q (J,) or (N,J) (or full nq) -> (4,4) or (N,4,4)."""
        import pinocchio as pin

        fid = self.frame_id(link)
        q = np.asarray(q, dtype=np.float64)
        if q.ndim == 1:
            qf = self.full_q(q, opening)
            pin.forwardKinematics(self.model, self._data, qf)
            return np.array(pin.updateFramePlacement(self.model, self._data, fid).homogeneous)
        if q.ndim != 2:
            raise ValueError(f"q: expected shape (J,) or (N, J), got {q.shape}")
        return self._batch.frames(self.full_q(q, opening), [fid])[:, 0]

    def fk(self, q: np.ndarray) -> np.ndarray:
        """``T_b_e`` of the tool link: q (J,) -> (4,4), (N,J) -> (N,4,4)."""
        return self.fk_link(q, self.ee_link)

    def fk_frames(self, q: np.ndarray, links: list[str], opening: float = 0.0) -> np.ndarray:
        """Poses of several links at once: q (N,J) -> (N, len(links), 4, 4)."""
        q = np.atleast_2d(np.asarray(q, dtype=np.float64))
        return self._batch.frames(self.full_q(q, opening), [self.frame_id(n) for n in links])

    def joint_placements(self, q_full: np.ndarray) -> np.ndarray:
        """(N, model.njoints, 4, 4) placements of every Pinocchio joint for full configurations (N, nq).

        Small batches go through Pinocchio (about 10 us per configuration), large ones through the
        vectorised numpy FK (a fixed ~100 us overhead, then about 1 us per configuration).
        """
        Q = np.atleast_2d(np.asarray(q_full, dtype=np.float64))
        if len(Q) > 8:
            return self._batch.joints(Q)
        import pinocchio as pin

        out = np.empty((len(Q), self.model.njoints, 4, 4))
        for k, q in enumerate(Q):
            pin.forwardKinematics(self.model, self._data, q)
            for j, M in enumerate(self._data.oMi):
                out[k, j] = M.homogeneous
        return out

    # ------------------------------------------------------------------ geometry
    @property
    def package_dirs(self) -> list[str]:
        """Folders searched for ``package://`` meshes: the URDF's folder and its parent."""
        return [str(self.urdf_path.parent), str(self.urdf_path.parent.parent)]

    @cached_property
    def collision_model(self):
        """``pinocchio.GeometryModel`` of the URDF's collision shapes (coal geometries)."""
        import pinocchio as pin

        try:
            return pin.buildGeomFromUrdf(self.model, str(self.urdf_path), pin.COLLISION, package_dirs=self.package_dirs)
        except Exception as e:
            raise InputError(
                Problem(str(self.urdf_path), "collision", f"cannot load collision geometry: {e}",
                        "make mesh paths resolvable relative to the URDF's folder")
            ) from e

    def __repr__(self) -> str:
        return f"RobotModel({self.name!r}, nq_arm={self.nq_arm}, ee_link={self.ee_link!r}, urdf={str(self.urdf_path)!r})"


def load_robot(name_or_urdf_path: str | Path, base_dir: str | Path | None = None, ee_link: str | None = None) -> RobotModel:
    """A robot by registry name (``"piper"``) or URDF path (relative paths are relative to ``base_dir``).

    Raises InputError naming the field and the fix for unknown names, missing files and unusable URDFs.
    """
    key = str(name_or_urdf_path).strip()
    if key in REGISTRY:
        spec = REGISTRY[key]
        return _cached(spec.name, Path(spec.urdf), ee_link, spec)
    path = Path(key).expanduser()
    looks_like_path = path.suffix.lower() in (".urdf", ".xml") or "/" in key or "\\" in key
    if not looks_like_path:
        raise InputError(
            Problem("scene.yaml", "robot", f"unknown robot {key!r}",
                    f"use one of {', '.join(known_robots())}, or a path to a URDF file")
        )
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    if not path.is_file():
        raise InputError(
            Problem(str(path), "robot", "URDF file not found",
                    "give a path to an existing URDF (relative paths are relative to the scene folder)")
        )
    return _cached(path.stem, path.resolve(), ee_link, None)


_MODELS: dict[tuple, RobotModel] = {}


def _cached(name: str, urdf: Path, ee_link: str | None, spec: RobotSpec | None) -> RobotModel:
    """One ``RobotModel`` per (URDF file and its modification time, tool link) in a process: the stages of
    ``bijcr run`` (grasp, both tasks) and the models built on it (IK tables, collision worlds) share it. A
    RobotModel is not changed after it is built."""
    key = (name, str(urdf), urdf.stat().st_mtime_ns if urdf.is_file() else None, ee_link, spec is not None)
    model = _MODELS.get(key)
    if model is None:
        model = _MODELS[key] = RobotModel(name, urdf, ee_link=ee_link, spec=spec)
    return model

"""One AgileX Piper arm over CAN, through ``piper_sdk``'s ``C_PiperInterface_V2``.

How the SDK reaches the bus: ``C_PiperInterface_V2(can_name, judge_flag, can_auto_init)`` builds a
``C_STD_CAN`` wrapper that calls ``can.interface.Bus(channel=can_name, bustype="socketcan", ...)`` (one
bus for receiving, one for sending on Linux) and a reader thread that decodes every frame into the SDK's
state (``GetArmJointMsgs()`` etc.). The bus type is fixed to socketcan in the constructor, but the SDK's
own ``CreateCanBus(can_name, bustype=...)`` takes any python-can interface. :class:`PiperArm` therefore
creates the interface with ``can_auto_init=False`` and calls ``CreateCanBus`` with the configured
``bustype``: ``"socketcan"`` on a real arm, ``"virtual"`` in the tests (python-can's in-process bus, where
a simulated Piper answers). No subclassing or monkey-patching of the SDK is needed.

Frames used (SDK v2 protocol, ``piper_sdk.piper_msgs.msg_v2.can_id.CanIDPiper``):

=========  ==========================================  ===============================================
CAN id     SDK call                                    meaning
=========  ==========================================  ===============================================
0x150      ``EmergencyStop(0x01)``                     quick stop (joints damped), 0x02 = reset/resume
0x151      ``MotionCtrl_2(0x01, 0x01, pct, 0x00)``     CAN control, MOVE J, speed percentage ``pct``
0x155-157  ``JointCtrl(j1..j6)``                       joint targets, int32 big-endian, 0.001 deg
0x159      ``GripperCtrl(width, effort, 0x01, 0)``     gripper opening 0.001 mm, effort 0.001 N m
0x471      ``EnableArm(7)`` / ``DisableArm(7)``        motor power on / off (7 = all motors)
0x2A1      ``GetArmStatus()``                          control mode, arm status (0 normal, 1 e-stop...)
0x2A5-2A7  ``GetArmJointMsgs()``                       joint feedback, 0.001 deg, with CAN time stamp
0x2A8      ``GetArmGripperMsgs()``                     gripper opening, 0.001 mm
0x261-266  ``GetArmEnableStatus()``                    per-motor driver status (bit 6: enabled)
=========  ==========================================  ===============================================
"""

from __future__ import annotations

import math
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bimanual_app.io_utils import Problem

from ._errors import ArmFault, ConnectionFailed, ExecuteNotRequested, HardwareError
from ._limits import SafetyLimits

__all__ = ["PiperArm", "require_execute_flag", "EXECUTE_HARDWARE", "Feedback", "STATUS_TEXT", "rad_to_sdk", "sdk_to_rad", "width_to_sdk", "sdk_to_width"]

# 0x2A1 arm_status codes (piper_sdk GetArmStatus docstring)
STATUS_TEXT = {
    0x00: "normal", 0x01: "emergency stop", 0x02: "no IK solution", 0x03: "singularity",
    0x04: "target angle beyond limit", 0x05: "joint communication error", 0x06: "joint brake not released",
    0x07: "collision detected", 0x08: "over speed in drag teaching", 0x09: "joint status abnormal",
    0x0A: "other error", 0x0B: "teach record", 0x0C: "teach execute", 0x0D: "teach pause",
    0x0E: "main controller over temperature", 0x0F: "release resistor over temperature",
}
EXECUTE_HARDWARE = "hardware"
GRIPPER_MAX_WIDTH_M = 0.070  # 70 mm stroke
N_JOINTS = 6

_open_channels: set[str] = set()
_open_lock = threading.Lock()


def require_execute_flag(execute: str | None, arm: str = "") -> None:
    """Raise :class:`ExecuteNotRequested` unless ``execute == "hardware"``."""
    if execute != EXECUTE_HARDWARE:
        raise ExecuteNotRequested(Problem(arm or "hardware", "execute",
                                          f"real arms are only driven with an explicit execute flag (got {execute!r})",
                                          "pass execute='hardware' (CLI: --execute hardware) once the plan is checked"))


def rad_to_sdk(q: np.ndarray) -> list[int]:
    """Joint angles (rad) -> SDK integers in 0.001 degree."""
    return [int(round(math.degrees(float(v)) * 1000.0)) for v in np.asarray(q, float).reshape(-1)]


def sdk_to_rad(v) -> np.ndarray:
    """SDK integers in 0.001 degree -> radians (float64 array)."""
    return np.radians(np.asarray(v, dtype=np.float64) / 1000.0)


def width_to_sdk(width_m: float) -> int:
    """Gripper opening (m) -> SDK integer in 0.001 mm."""
    return int(round(float(width_m) * 1e6))


def sdk_to_width(v: int) -> float:
    """SDK gripper opening (0.001 mm) -> metres."""
    return float(v) * 1e-6


@dataclass
class Feedback:
    """One snapshot of an arm's state as the SDK last decoded it.

    Attributes:
        q: (6,) joint angles, rad (from frames 0x2A5-0x2A7).
        age_s: seconds since the newest joint frame (CAN time stamp vs the wall clock); inf if none yet.
        status: arm status code of frame 0x2A1 (see ``STATUS_TEXT``), or None when no fresh status frame.
        ctrl_mode: control mode of frame 0x2A1 (0 standby, 1 CAN control, ...), or None.
        gripper_m: gripper opening (m), or None when no fresh gripper frame.
        enabled: (6,) bool per motor from frames 0x261-0x266, or None when none is fresh.
    """

    q: np.ndarray
    age_s: float
    status: int | None = None
    ctrl_mode: int | None = None
    gripper_m: float | None = None
    enabled: tuple[bool, ...] | None = None

    @property
    def status_text(self) -> str:
        return "no status" if self.status is None else STATUS_TEXT.get(self.status, f"code 0x{self.status:02X}")


class PiperArm:
    """One Piper arm on one CAN channel.

    Nothing is sent to the arm by the constructor or by :meth:`connect` (which only listens); motion is
    sent by :meth:`execute` (a previewed plan: needs a passing approval) and :meth:`move_to` (a guarded
    point-to-point joint move, used by the capture), both through the same checked control loop
    (``bimanual_app.hardware._executor``). :meth:`stop` leaves the arm in the Piper's quick-stop state.

    Args:
        can_channel: CAN interface name (``can0``) or the virtual channel name in tests.
        name: ``"primary"`` or ``"secondary"`` (used in messages and in the plan's approval hash).
        robot: robot model name/path or a loaded ``RobotModel`` (joint/velocity limits, FK).
        limits: the :class:`SafetyLimits` (default: from the robot registry with the default workspace).
        bustype: python-can interface: ``"socketcan"`` (real arm) or ``"virtual"`` (tests).
        check_port: for socketcan, check that the port exists, is up and runs at 1 Mbit/s before opening.
        gripper_effort_nm: gripper force setting when a trajectory commands the gripper (0..5 N m).
        sdk_factory: builds the SDK object for a channel (default ``C_PiperInterface_V2``); for other
            transports or tests.
        execute: must be ``"hardware"`` (the CLI's ``--execute hardware``) or :meth:`connect` refuses:
            real arms are only driven when the caller asks for it explicitly.
    """

    def __init__(self, can_channel: str = "can0", name: str = "primary", *, robot: Any = "piper",
                 limits: SafetyLimits | None = None, bustype: str = "socketcan", check_port: bool = True,
                 gripper_effort_nm: float = 1.0, sdk_factory: Callable[[str], Any] | None = None,
                 execute: str | None = None):
        self.execute_flag = execute
        self.can_channel = str(can_channel)
        self.name = name
        self.bustype = bustype
        self.check_port = check_port
        self.gripper_effort = int(round(min(max(gripper_effort_nm, 0.0), 5.0) * 1000))
        self.limits = limits if limits is not None else SafetyLimits.from_robot(robot, name=name)
        self.robot = self.limits.robot
        self._sdk_factory = sdk_factory
        self.sdk = None
        self.connected = False
        self.stopped = False  # an emergency stop was sent and not reset
        self._gripper_enabled = False
        self._last_q_cmd: np.ndarray | None = None
        self.feedback_fresh_s = 0.25  # status / enable frames older than this count as absent

    # ------------------------------------------------------------------ connection
    def _check_socketcan(self) -> None:
        state_file = Path(f"/sys/class/net/{self.can_channel}/operstate")
        setup = (f"bring it up: sudo ip link set {self.can_channel} up type can bitrate 1000000 "
                 f"(see docs/hardware.md)")
        if not state_file.exists():
            raise ConnectionFailed(f"CAN interface {self.can_channel!r} does not exist (is the USB-CAN adapter "
                                   f"plugged in?); {setup}", self.name)
        state = state_file.read_text().strip()
        if state not in ("up", "unknown"):
            raise ConnectionFailed(f"CAN interface {self.can_channel!r} is {state}; {setup}", self.name)

    def connect(self, timeout_s: float = 2.0) -> PiperArm:
        """Open the bus, start the SDK's reader thread and wait for the arm's joint feedback.

        Sends nothing. Raises :class:`ConnectionFailed` when the bus cannot be opened or no joint feedback
        arrives within ``timeout_s`` (arm off, wrong channel, wrong bitrate).
        """
        if self.connected:
            return self
        require_execute_flag(self.execute_flag, self.name)
        with _open_lock:
            if self.can_channel in _open_channels:
                raise ConnectionFailed(f"CAN channel {self.can_channel!r} is already open in this process "
                                       "(one PiperArm per channel)", self.name)
            _open_channels.add(self.can_channel)
        try:
            if self.bustype == "socketcan" and self.check_port:
                self._check_socketcan()
            if self._sdk_factory is not None:
                self.sdk = self._sdk_factory(self.can_channel)
            else:
                from piper_sdk import C_PiperInterface_V2

                # can_auto_init=False: the SDK would otherwise force bustype "socketcan"
                self.sdk = C_PiperInterface_V2(self.can_channel, judge_flag=False, can_auto_init=False)
            with warnings.catch_warnings():  # the SDK passes python-can's deprecated 'bustype' keyword
                warnings.simplefilter("ignore", DeprecationWarning)
                try:
                    self.sdk.CreateCanBus(self.can_channel, bustype=self.bustype,
                                          judge_flag=(self.bustype == "socketcan" and self.check_port))
                except Exception as e:  # the SDK wraps every failure as ConnectionError
                    raise ConnectionFailed(f"cannot open CAN bus {self.can_channel!r} ({self.bustype}): {e}; "
                                           "check the interface is up at 1000000 bit/s", self.name) from e
            self.sdk.ConnectPort(piper_init=False)  # piper_init would send parameter queries
            t_end = time.monotonic() + timeout_s
            while time.monotonic() < t_end:
                if self._joint_age() < self.feedback_fresh_s:
                    time.sleep(0.02)  # let all three joint frames (0x2A5-0x2A7) of a cycle arrive
                    self.connected = True
                    return self
                time.sleep(0.01)
            raise ConnectionFailed(f"no joint feedback from the arm on {self.can_channel!r} within {timeout_s:.1f} s "
                                   "(is the arm powered, on this CAN channel, and in CAN mode?)", self.name)
        except BaseException:
            self._release()
            raise

    def _release(self) -> None:
        if self.sdk is not None:
            try:
                self.sdk.DisconnectPort()
            except Exception:
                pass
            # piper_sdk 0.6 DisconnectPort leaves its CAN-monitor thread running; ask it to end
            ev = getattr(self.sdk, "_C_PiperInterface_V2__can_monitor_stop_event", None)
            if ev is not None:
                ev.set()
        self.connected = False
        with _open_lock:
            _open_channels.discard(self.can_channel)

    def close(self) -> None:
        """Close the bus (sends nothing: an enabled arm keeps holding its last target)."""
        self._release()

    def __enter__(self) -> PiperArm:
        return self.connect()

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ reading
    def _joint_age(self) -> float:
        stamp = float(self.sdk.GetArmJointMsgs().time_stamp or 0.0)
        return math.inf if stamp <= 0 else max(0.0, time.time() - stamp)

    def read(self) -> Feedback:
        """The latest decoded state (see :class:`Feedback`); never blocks."""
        if self.sdk is None:
            raise HardwareError("not connected (call connect() first)", self.name)
        now = time.time()
        msg = self.sdk.GetArmJointMsgs()
        js = msg.joint_state
        q = sdk_to_rad([js.joint_1, js.joint_2, js.joint_3, js.joint_4, js.joint_5, js.joint_6])
        stamp = float(msg.time_stamp or 0.0)
        age = math.inf if stamp <= 0 else max(0.0, now - stamp)
        fb = Feedback(q=q, age_s=age)
        st = self.sdk.GetArmStatus()
        if st.time_stamp and now - float(st.time_stamp) < self.feedback_fresh_s:
            fb.status = int(st.arm_status.arm_status)
            fb.ctrl_mode = int(st.arm_status.ctrl_mode)
        gr = self.sdk.GetArmGripperMsgs()
        if gr.time_stamp and now - float(gr.time_stamp) < self.feedback_fresh_s:
            fb.gripper_m = sdk_to_width(gr.gripper_state.grippers_angle)
        low = self.sdk.GetArmLowSpdInfoMsgs()
        if low.time_stamp and now - float(low.time_stamp) < 4 * self.feedback_fresh_s:
            fb.enabled = tuple(bool(v) for v in self.sdk.GetArmEnableStatus())
        return fb

    def joints(self) -> np.ndarray:
        """(6,) current joint angles (rad); raises :class:`HardwareError` when the feedback is stale."""
        fb = self.read()
        if fb.age_s > self.feedback_fresh_s:
            raise HardwareError(f"joint feedback is {fb.age_s:.2f} s old", self.name)
        return fb.q

    # ------------------------------------------------------------------ sending (no checks here: the
    # executor checks every command before calling these)
    def _set_mode(self, speed_pct: int) -> None:
        """0x151: CAN command control, MOVE J, speed percentage (1..100)."""
        self.sdk.MotionCtrl_2(0x01, 0x01, int(min(max(speed_pct, 1), 100)), 0x00)

    def _send(self, q: np.ndarray, speed_pct: int, gripper_m: float | None = None) -> None:
        """Mode + joint targets (+ gripper): frames 0x151, 0x155-0x157 (+ 0x159)."""
        self._set_mode(speed_pct)
        self.sdk.JointCtrl(*rad_to_sdk(q))
        self._last_q_cmd = np.asarray(q, float).copy()
        if gripper_m is not None:
            w = min(max(float(gripper_m), 0.0), GRIPPER_MAX_WIDTH_M)
            self.sdk.GripperCtrl(width_to_sdk(w), self.gripper_effort, 0x01, 0x00)
            self._gripper_enabled = True

    def ensure_enabled(self, speed_pct: int = 10, timeout_s: float = 2.0) -> None:
        """Power the motors (0x471) if they are not, and select CAN joint control at ``speed_pct``.

        Raises :class:`ArmFault` if the arm reports a fault or an emergency stop (reset it first), and
        :class:`HardwareError` if the motors do not report enabled within ``timeout_s``.
        """
        fb = self.read()
        if fb.status not in (None, 0x00):
            raise ArmFault(f"the arm reports '{fb.status_text}' (status 0x{fb.status:02X}); clear it before moving "
                           "(emergency stop: support the arm, then PiperArm.resume())", self.name)
        t_end = time.monotonic() + timeout_s
        while True:
            fb = self.read()
            if fb.enabled is not None and all(fb.enabled):
                break
            if time.monotonic() > t_end:
                raise HardwareError(f"motors did not report enabled within {timeout_s:.1f} s (driver status "
                                    f"{fb.enabled}); check the arm's power and e-stop button", self.name)
            self.sdk.EnableArm(7)
            time.sleep(0.05)
        self._set_mode(speed_pct)

    # ------------------------------------------------------------------ stopping
    def hold(self) -> bool:
        """Command the current measured position (stops a streamed motion). False if feedback is stale."""
        fb = self.read()
        if fb.age_s > self.feedback_fresh_s:
            return False
        self.sdk.JointCtrl(*rad_to_sdk(fb.q))
        return True

    def stop(self) -> None:
        """Leave the arm safe: hold the measured position (when feedback is fresh), then the Piper's quick
        emergency stop (0x150, 0x01: motion stops, joints damped). Motor power is left on: cutting it
        (:meth:`disable`) drops an arm that is not resting on something."""
        try:
            self.hold()
        finally:
            self.sdk.EmergencyStop(0x01)
            self.stopped = True

    def resume(self) -> None:
        """Clear an emergency stop (0x150, 0x02). The Piper *resets*: motors lose power and the arm drops:
        support it (or have it resting) first. Then :meth:`ensure_enabled` powers it again."""
        self.sdk.EmergencyStop(0x02)
        self.stopped = False

    def disable(self) -> None:
        """Cut motor power (0x471, all motors) and disable the gripper. Only with the arm resting."""
        self.sdk.DisableArm(7)
        if self._gripper_enabled:
            self.sdk.GripperCtrl(0, 0, 0x00, 0x00)
            self._gripper_enabled = False

    # ------------------------------------------------------------------ motion (checked, see _executor)
    def execute(self, trajectory, approval, config=None, progress=None, approval_key: bytes | None = None):
        """Run a previewed trajectory on this arm. ``approval`` must be a passing, signed record for
        ``{self.name: trajectory}`` (see ``bimanual_app.hardware.approve_plan``)."""
        from ._executor import execute_plan

        return execute_plan({self.name: self}, {self.name: trajectory}, approval, config, progress, approval_key)

    def move_to(self, q_goal: np.ndarray, speed: float = 0.25, config=None, progress=None):
        """Guarded point-to-point joint move from the measured position to ``q_goal`` (6,) (rad).

        A smooth joint-space move at ``speed`` times the allowed joint speeds; checked like a plan (joint,
        velocity, workspace along the path before anything is sent, and every command again), then run by
        the same control loop. Used for capture poses and homing; plans that interact with objects or the
        other arm go through :meth:`execute` and need the preview approval.
        """
        from ._executor import move_arm

        return move_arm(self, q_goal, speed, config, progress)

    def __repr__(self) -> str:
        return f"PiperArm({self.can_channel!r}, name={self.name!r}, bustype={self.bustype!r})"

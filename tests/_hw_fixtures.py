"""A simulated AgileX Piper on python-can's virtual bus, and helpers for the hardware tests.

:class:`SimPiper` is a thread with its own ``can.Bus(interface="virtual", channel=...)``. It decodes the
frames the SDK sends with the SDK's own parser (``C_PiperParserV2.DecodeMessage``: motion control 0x151,
joint control 0x155-0x157, gripper 0x159) plus the two transmit-only frames the parser does not decode
(0x150 emergency stop, 0x471 motor enable), moves its joints toward the target at a bounded speed
(``max_speed`` rad/s at 100 %, scaled by the commanded speed percentage) and publishes feedback with the
SDK's encoding (0x2A1 status, 0x2A5-0x2A7 joints in 0.001 deg, 0x2A8 gripper, 0x261-0x266 driver status
with the enable bit). It records every frame it receives, so tests can assert what was (not) sent.
"""

from __future__ import annotations

import itertools
import threading
import time
from dataclasses import dataclass

import can
import numpy as np
from piper_sdk.piper_msgs.msg_v2 import ArmMsgType, PiperMessage
from piper_sdk.protocol.protocol_v2 import C_PiperParserV2

_channel_counter = itertools.count()

JOINT_CTRL_IDS = (0x155, 0x156, 0x157)
MOTION_IDS = JOINT_CTRL_IDS + (0x151, 0x159)


def new_channel(prefix: str = "vpiper") -> str:
    """A fresh virtual channel name (one per test: no cross-talk, no reuse of the SDK's per-name singleton)."""
    return f"{prefix}{next(_channel_counter)}_{time.monotonic_ns() % 100000}"


@dataclass
class Frame:
    t: float
    arbitration_id: int
    data: bytes


class SimPiper:
    """A simulated Piper answering on a virtual CAN channel.

    Args:
        channel: virtual channel name.
        q0: (6,) initial joint angles (rad).
        max_speed: joint speed at 100 % (rad/s).
        rate_hz: feedback rate.
        silent_after_joint_cmds: stop publishing any feedback once this many joint-control frame triples
            were received (the arm "stops answering" mid-motion); None = never.
        noise_rad: feedback noise (deterministic, seeded).
    """

    def __init__(self, channel: str, q0=None, max_speed: float = 3.0, rate_hz: float = 200.0,
                 silent_after_joint_cmds: int | None = None, noise_rad: float = 0.0, seed: int = 0):
        self.channel = channel
        self.q = np.zeros(6) if q0 is None else np.asarray(q0, float).copy()
        self.target = self.q.copy()
        self.max_speed = max_speed
        self.period = 1.0 / rate_hz
        self.enabled = False
        self.ctrl_mode = 0
        self.move_mode = 0
        self.speed_pct = 0
        self.estopped = False
        self.gripper = 0.0
        self.gripper_target = 0.0
        self.silent_after = silent_after_joint_cmds
        self.silent = False
        self.noise = noise_rad
        self.rng = np.random.default_rng(seed)
        self.frames: list[Frame] = []
        self.joint_cmds: list[tuple[float, np.ndarray]] = []
        self.max_speed_seen = 0.0
        self._partial: dict[int, tuple[int, int]] = {}
        self._parser = C_PiperParserV2()
        self._msg = PiperMessage()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self._thread = threading.Thread(target=self._loop, name=f"SimPiper-{channel}", daemon=True)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> SimPiper:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._bus.shutdown()

    def __enter__(self) -> SimPiper:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ queries for tests
    def ids_received(self) -> list[int]:
        with self._lock:
            return [f.arbitration_id for f in self.frames]

    def motion_frames_after(self, t: float) -> list[Frame]:
        with self._lock:
            return [f for f in self.frames if f.t > t and f.arbitration_id in MOTION_IDS]

    def estop_time(self, wait_s: float = 0.5) -> float | None:
        """Arrival time of the first quick-stop frame (0x150, 0x01), waiting up to ``wait_s`` for the
        simulator thread to process frames already on the bus."""
        t_end = time.monotonic() + wait_s
        while True:
            with self._lock:
                for f in self.frames:
                    if f.arbitration_id == 0x150 and f.data[0] == 0x01:
                        return f.t
            if time.monotonic() > t_end:
                return None
            time.sleep(0.005)

    # ------------------------------------------------------------------ frame handling
    def _handle(self, m: can.Message) -> None:
        now = time.monotonic()
        cid = m.arbitration_id
        data = bytes(m.data)
        with self._lock:
            self.frames.append(Frame(now, cid, data))
        if cid == 0x150:  # MotionCtrl_1: byte 0 = emergency stop (1 stop, 2 resume/reset)
            if data[0] == 0x01:
                self.estopped = True
                self.target = self.q.copy()
            elif data[0] == 0x02:
                self.estopped = False
                self.enabled = False  # the real arm resets: motors off
                self.ctrl_mode = 0
            return
        if cid == 0x471:  # motor enable/disable: byte 0 motor (7 = all), byte 1 flag (1 disable, 2 enable)
            if data[0] in (7, 0xFF):
                self.enabled = data[1] == 0x02
            return
        if not self._parser.DecodeMessage(m, self._msg):
            return
        t = self._msg.type_
        if t == ArmMsgType.PiperMsgMotionCtrl_2:
            c = self._msg.arm_motion_ctrl_2
            self.ctrl_mode, self.move_mode, self.speed_pct = c.ctrl_mode, c.move_mode, c.move_spd_rate_ctrl
        elif t in (ArmMsgType.PiperMsgJointCtrl_12, ArmMsgType.PiperMsgJointCtrl_34, ArmMsgType.PiperMsgJointCtrl_56):
            jc = self._msg.arm_joint_ctrl
            if t == ArmMsgType.PiperMsgJointCtrl_12:
                self._partial[0] = (jc.joint_1, jc.joint_2)
            elif t == ArmMsgType.PiperMsgJointCtrl_34:
                self._partial[1] = (jc.joint_3, jc.joint_4)
            else:
                self._partial[2] = (jc.joint_5, jc.joint_6)
                if len(self._partial) == 3:
                    q = np.radians(np.array([v for k in range(3) for v in self._partial[k]], float) / 1000.0)
                    self.joint_cmds.append((now, q))
                    if self.enabled and not self.estopped and self.ctrl_mode == 0x01:
                        self.target = q
                    if self.silent_after is not None and len(self.joint_cmds) >= self.silent_after:
                        self.silent = True
                self._partial.clear()
        elif t == ArmMsgType.PiperMsgGripperCtrl:
            g = self._msg.arm_gripper_ctrl
            if g.status_code in (0x01, 0x03) and not self.estopped:
                self.gripper_target = g.grippers_angle * 1e-6

    def _send(self, cid: int, data: list[int]) -> None:
        self._bus.send(can.Message(arbitration_id=cid, data=data, is_extended_id=False))

    def _publish(self, cycle: int) -> None:
        p = self._parser
        q = self.q + (self.rng.normal(scale=self.noise, size=6) if self.noise else 0.0)
        mdeg = [int(round(np.degrees(v) * 1000)) for v in q]
        moving = int(np.max(np.abs(self.target - self.q)) > 1e-4)
        status = 0x01 if self.estopped else 0x00
        self._send(0x2A1, [self.ctrl_mode, status, self.move_mode, 0, moving, 0, 0, 0])
        self._send(0x2A5, p.ConvertToList_32bit(mdeg[0]) + p.ConvertToList_32bit(mdeg[1]))
        self._send(0x2A6, p.ConvertToList_32bit(mdeg[2]) + p.ConvertToList_32bit(mdeg[3]))
        self._send(0x2A7, p.ConvertToList_32bit(mdeg[4]) + p.ConvertToList_32bit(mdeg[5]))
        self._send(0x2A8, p.ConvertToList_32bit(int(round(self.gripper * 1e6))) + p.ConvertToList_16bit(0)
                   + [0x40 if self.enabled else 0x00, 0])
        if cycle % 10 == 0:
            foc = 0x40 if self.enabled else 0x00
            for k in range(6):
                self._send(0x261 + k, p.ConvertToList_16bit(240, False) + p.ConvertToList_16bit(30)
                           + p.ConvertToList_8bit(30) + p.ConvertToList_8bit(foc, False) + p.ConvertToList_16bit(0, False))

    def _loop(self) -> None:
        last = time.monotonic()
        for cycle in itertools.count():
            if self._stop.is_set():
                return
            while True:
                m = self._bus.recv(timeout=0)
                if m is None:
                    break
                self._handle(m)
            now = time.monotonic()
            dt, last = now - last, now
            if self.enabled and not self.estopped and self.ctrl_mode == 0x01:
                v = self.max_speed * max(self.speed_pct, 0) / 100.0
                step = np.clip(self.target - self.q, -v * dt, v * dt)
                if dt > 0:
                    self.max_speed_seen = max(self.max_speed_seen, float(np.max(np.abs(step)) / dt))
                self.q = self.q + step
                self.gripper += float(np.clip(self.gripper_target - self.gripper, -0.1 * dt, 0.1 * dt))
            if not self.silent:
                self._publish(cycle)
            time.sleep(self.period)


def fast_config(**kw):
    """An ExecutionConfig with short ramps, for quick tests. The feedback timeout is 1 s: the simulated arms
    answer from threads that a loaded CI machine can hold up for more than 0.15 s (a test that needs the
    timeout to fire sets its own)."""
    from bimanual_app.hardware import ExecutionConfig

    base = dict(period_s=0.01, ramp_s=0.3, start_rate=0.3, speed_pct_start=20, speed_pct_max=100,
                feedback_timeout_s=1.0, tracking_tol_rad=0.25, settle_timeout_s=2.0, settle_tol_rad=0.01)
    base.update(kw)
    return ExecutionConfig(**base)


def make_arm(channel: str, name: str = "primary", **kw):
    """A PiperArm on a virtual channel, explicitly allowed to drive the (simulated) hardware."""
    from bimanual_app.hardware import PiperArm

    return PiperArm(channel, name, bustype="virtual", check_port=False, execute="hardware", **kw)


def line_trajectory(q0, q1, duration: float = 0.6, n: int = 61, gripper=None):
    """A smooth (cosine) joint-space trajectory from q0 to q1 over ``duration`` seconds."""
    from bimanual_app.hardware import JointTrajectory

    q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
    t = np.linspace(0.0, duration, n)
    s = 0.5 - 0.5 * np.cos(np.pi * t / duration)
    g = None if gripper is None else np.linspace(gripper[0], gripper[1], n)
    return JointTrajectory(t, q0 + s[:, None] * (q1 - q0), g)


# A comfortable pose in front of the arm (inside limits and the default workspace)
Q_READY = np.array([0.0, 1.2, -0.8, 0.0, 0.4, 0.0])

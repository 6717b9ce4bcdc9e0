"""Hardware layer: AgileX Piper arms over CAN (``piper_sdk``), guarded execution, and scene capture.

Public API (imported lazily, so ``bijcr --help`` does not load numpy / python-can):

- :class:`PiperArm` (one arm on one CAN channel), :class:`BimanualHardware` (both arms, one loop);
- :class:`JointTrajectory` (times (T,), q (T, 6), gripper (T,) optional), :func:`joint_move`,
  :func:`save_plan` / :func:`load_plan`;
- preview approvals: :func:`approve_plan`, :func:`write_approval`, :func:`load_approval`,
  :func:`check_approval`, :func:`trajectory_hash`, :class:`PreviewApproval`;
- limits: :class:`SafetyLimits`, :class:`WorkspaceBox`; loop settings: :class:`ExecutionConfig`;
- :func:`validate_plan` (dry run), :func:`execute_plan`, :func:`stop_all`;
- errors: :class:`ExecuteNotRequested`, :class:`ApprovalError`, :class:`LimitViolation` (bad input,
  nothing sent) and :class:`HardwareError` > :class:`ConnectionFailed`, :class:`FeedbackTimeout`,
  :class:`TrackingError`, :class:`ArmFault` (arms already stopped);
- capture: :func:`capture_scene`, :func:`load_poses`, :func:`suggest_viewpoints`, camera sources
  :class:`OpenCVCamera`, :class:`ImageFolderCamera`, :func:`open_camera`.

See docs/hardware.md.
"""

from __future__ import annotations

from bimanual_app.lazy import lazy_exports

_EXPORTS = {
    "PiperArm": "_piper", "Feedback": "_piper", "STATUS_TEXT": "_piper", "EXECUTE_HARDWARE": "_piper",
    "require_execute_flag": "_piper",
    "BimanualHardware": "_bimanual", "validate_plan": "_bimanual",
    "JointTrajectory": "_trajectory", "as_trajectory": "_trajectory", "trajectory_hash": "_trajectory",
    "joint_move": "_trajectory", "save_plan": "_trajectory", "load_plan": "_trajectory",
    "PreviewApproval": "_approval", "approve_plan": "_approval", "write_approval": "_approval",
    "load_approval": "_approval", "check_approval": "_approval",
    "SafetyLimits": "_limits", "WorkspaceBox": "_limits", "DEFAULT_WORKSPACE": "_limits",
    "ExecutionConfig": "_executor", "ExecutionReport": "_executor", "CycleInfo": "_executor",
    "execute_plan": "_executor", "stop_all": "_executor",
    "ExecuteNotRequested": "_errors", "ApprovalError": "_errors", "LimitViolation": "_errors",
    "HardwareError": "_errors", "ConnectionFailed": "_errors", "FeedbackTimeout": "_errors",
    "TrackingError": "_errors", "ArmFault": "_errors",
    "capture_scene": "_capture", "CapturePlan": "_capture", "plan_capture": "_capture",
    "load_poses": "_poses", "PoseList": "_poses", "dump_poses": "_poses",
    "suggest_viewpoints": "_suggest",
    "OpenCVCamera": "_camera", "ImageFolderCamera": "_camera", "open_camera": "_camera",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

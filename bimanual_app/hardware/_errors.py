"""Errors of the hardware layer.

Two families:

- bad input found *before* anything is sent to an arm (a missing preview approval, a limit violation):
  :class:`ApprovalError`, :class:`LimitViolation`; both are :class:`~bimanual_app.io_utils.InputError`, so
  the CLI prints them as a problem list (file, field, fix);
- failures *while* the arms run (:class:`HardwareError` and its subclasses): the arms have already been
  stopped when one of these reaches the caller, and the message says so.
"""

from __future__ import annotations

from bimanual_app.io_utils import InputError, Problem

__all__ = [
    "ExecuteNotRequested",
    "ApprovalError",
    "LimitViolation",
    "HardwareError",
    "ConnectionFailed",
    "FeedbackTimeout",
    "TrackingError",
    "ArmFault",
]


class ExecuteNotRequested(InputError):
    """A real arm was about to be driven without the explicit ``execute="hardware"`` flag."""


class ApprovalError(InputError):
    """The trajectory has no passing, correctly signed preview approval. Nothing was sent to the arms."""


class LimitViolation(InputError):
    """A commanded joint value, velocity or workspace position is outside the limits.

    Raised before the offending command is sent. Found in the pre-flight check, nothing was sent; found
    in the control loop (a limit changed, or the live start point differs), the arms are stopped first.
    """


class HardwareError(RuntimeError):
    """A failure while talking to or moving the arms.

    Attributes:
        arm: name of the arm concerned (``"primary"``, ``"secondary"``) or ``""`` for several/none.
        stopped: names of the arms that were sent the stop sequence before this was raised.
        report: the control loop's ``ExecutionReport`` up to the failure (trace of commanded and measured
            joints), when it happened inside the loop; else None.
    """

    def __init__(self, message: str, arm: str = "", stopped: tuple[str, ...] = ()):
        self.report = None
        self.arm = arm
        self.stopped = tuple(stopped)
        self.reason = message
        super().__init__(self._text())

    def _text(self) -> str:
        where = f"[{self.arm}] " if self.arm else ""
        tail = ""
        if self.stopped:
            tail = f" -- stop sent to: {', '.join(self.stopped)} (emergency stop: the arm holds, damped;" \
                   " check it, then resume with PiperArm.resume())"
        return f"{where}{self.reason}{tail}"

    def with_stopped(self, stopped: tuple[str, ...]) -> HardwareError:
        """The same error, noting which arms were stopped."""
        self.stopped = tuple(stopped)
        self.args = (self._text(),)
        return self


class ConnectionFailed(HardwareError):
    """The CAN bus could not be opened, or the arm never answered (no joint feedback)."""


class FeedbackTimeout(HardwareError):
    """The arm's joint feedback stopped arriving (older than the configured timeout) during motion."""


class TrackingError(HardwareError):
    """The arm's joint feedback is too far from the commanded trajectory, or it did not settle at the end."""


class ArmFault(HardwareError):
    """The arm reports a fault in its status frame (emergency stop, collision, joint error, limit...)."""


def limit_problem(field: str, message: str, fix: str, file: str = "trajectory") -> Problem:
    """A :class:`Problem` for a limit violation (kept short: one line per violation)."""
    return Problem(file, field, message, fix)

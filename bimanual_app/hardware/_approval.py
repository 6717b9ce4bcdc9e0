"""Preview approvals: the record that lets a plan onto the hardware.

The simulation step (the PyBullet preview of ``bijcr task``) runs a plan with physics and writes a
:class:`PreviewApproval`: the plan's hash (:func:`trajectory_hash`), the verdict (``pass``/``fail``) and
what the preview measured, signed with HMAC-SHA256. The hardware backend refuses a plan unless a record
with the *same hash*, verdict ``pass`` and a *valid signature* is given.

What the signature is for: it tells a record produced by the preview code on this machine from one that
was edited by hand (verdict flipped to ``pass``) or copied from another plan. It is not protection against
someone who can read the key. The key is the environment variable ``BIJCR_APPROVAL_KEY`` when set, else
a random key kept in ``$XDG_CONFIG_HOME/bijcr/approval.key`` (``~/.config/bijcr/approval.key``, mode
0600, created on first use). A record signed on another machine does not verify here: re-run the preview.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import secrets
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from bimanual_app.io_utils import Problem, atomic_open, to_jsonable

from ._errors import ApprovalError
from ._trajectory import as_trajectory, trajectory_hash

__all__ = ["PreviewApproval", "approve_plan", "write_approval", "load_approval", "check_approval",
           "approval_key"]

KIND = "bijcr-preview-approval"
VERDICTS = ("pass", "fail")
KEY_ENV = "BIJCR_APPROVAL_KEY"


def _key_file() -> Path:
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "bijcr" / "approval.key"


def approval_key() -> bytes:
    """The signing key: ``$BIJCR_APPROVAL_KEY``, else the per-user key file (created on first use)."""
    env = os.environ.get(KEY_ENV)
    if env:
        return env.encode()
    path = _key_file()
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        # O_EXCL: two processes creating the key at once do not overwrite each other's key
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        except FileExistsError:
            return path.read_text().strip().encode()
        with os.fdopen(fd, "w") as f:
            f.write(secrets.token_hex(32) + "\n")
    return path.read_text().strip().encode()


@dataclass
class PreviewApproval:
    """The preview's verdict on one plan.

    Attributes:
        plan_sha256: :func:`trajectory_hash` of the plan (arm name -> trajectory).
        verdict: ``"pass"`` or ``"fail"``.
        arms: names of the arms in the plan.
        duration_s: longest trajectory duration (seconds).
        created: UTC time stamp (ISO 8601).
        preview: free-form details from the preview (task, scene, measured lift, ...).
        signature: ``"hmac-sha256:<hex>"`` over all the fields above.
    """

    plan_sha256: str
    verdict: str
    arms: list[str]
    duration_s: float
    created: str
    preview: dict = field(default_factory=dict)
    signature: str = ""
    format: int = 1
    kind: str = KIND

    def payload(self) -> bytes:
        """Canonical bytes that are signed (every field but the signature)."""
        d = asdict(self)
        d.pop("signature")
        return json.dumps(to_jsonable(d), sort_keys=True, separators=(",", ":")).encode()

    def sign(self, key: bytes | None = None) -> PreviewApproval:
        self.signature = "hmac-sha256:" + hmac.new(key or approval_key(), self.payload(), hashlib.sha256).hexdigest()
        return self

    def signature_ok(self, key: bytes | None = None) -> bool:
        want = "hmac-sha256:" + hmac.new(key or approval_key(), self.payload(), hashlib.sha256).hexdigest()
        return hmac.compare_digest(want, self.signature or "")

    @property
    def passed(self) -> bool:
        return self.verdict == "pass"


def approve_plan(trajectories: Mapping[str, Any], verdict: str, preview: dict | None = None,
                 key: bytes | None = None) -> PreviewApproval:
    """Make a signed approval record for a plan (called by the simulation step after its preview).

    Args:
        trajectories: arm name -> trajectory (:class:`JointTrajectory` or anything :func:`as_trajectory` takes).
        verdict: ``"pass"`` when the preview succeeded, else ``"fail"``.
        preview: details to keep with the record (JSON-able).
    """
    if verdict not in VERDICTS:
        raise ValueError(f"verdict must be one of {VERDICTS}, got {verdict!r}")
    trajs = {k: as_trajectory(v) for k, v in trajectories.items()}
    rec = PreviewApproval(
        plan_sha256=trajectory_hash(trajs), verdict=verdict, arms=sorted(trajs),
        duration_s=max((t.duration for t in trajs.values()), default=0.0),
        created=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        preview=to_jsonable(dict(preview or {})))
    return rec.sign(key)


def write_approval(path: str | Path, approval: PreviewApproval) -> None:
    """Write the record as JSON (atomically)."""
    with atomic_open(path) as f:
        json.dump(to_jsonable(asdict(approval)), f, indent=2, sort_keys=True)
        f.write("\n")


def load_approval(path: str | Path) -> PreviewApproval:
    """Read a record written by :func:`write_approval` (signature not checked here)."""
    path = Path(path)
    fix = "run the preview (bijcr task ...) to produce the approval"
    if not path.is_file():
        raise ApprovalError(Problem(str(path), "", "approval file is missing", fix))
    try:
        d = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ApprovalError(Problem(str(path), "", f"not valid JSON: {e}", fix)) from None
    if not isinstance(d, dict) or d.get("kind") != KIND or d.get("format") != 1:
        raise ApprovalError(Problem(str(path), "kind", f"not a preview approval record (kind {KIND}, format 1)", fix))
    try:
        return PreviewApproval(**{k: d[k] for k in ("plan_sha256", "verdict", "arms", "duration_s", "created",
                                                     "preview", "signature", "format", "kind")})
    except KeyError as e:
        raise ApprovalError(Problem(str(path), str(e.args[0]), "field is missing", fix)) from None


def check_approval(approval: PreviewApproval | str | Path | None, trajectories: Mapping[str, Any],
                   key: bytes | None = None) -> PreviewApproval:
    """Raise :class:`ApprovalError` unless ``approval`` is a valid, passing record for exactly this plan.

    Checked in order: present; signature valid (not edited, signed on this machine); verdict ``pass``;
    hash equal to the plan's hash (the plan has not changed since the preview).
    """
    src = str(approval) if isinstance(approval, (str, Path)) else "approval"
    fix_run = "run the PyBullet preview on this exact plan (bijcr task ...) and pass its approval"
    if approval is None:
        raise ApprovalError(Problem(src, "", "no preview approval given: the hardware only runs plans that "
                                    "passed the preview", fix_run))
    if isinstance(approval, (str, Path)):
        approval = load_approval(approval)
    if not approval.signature_ok(key):
        raise ApprovalError(Problem(src, "signature", "signature does not match: the record was edited, or "
                                    "signed with another key (another machine or user)", fix_run))
    if not approval.passed:
        raise ApprovalError(Problem(src, "verdict", f"the preview's verdict is {approval.verdict!r}, not 'pass'",
                                    "fix the plan until its preview passes"))
    h = trajectory_hash(trajectories)
    if not hmac.compare_digest(h, approval.plan_sha256):
        raise ApprovalError(Problem(src, "plan_sha256", f"the approval is for another plan (approved "
                                    f"{approval.plan_sha256[:12]}..., given {h[:12]}...; arms approved "
                                    f"{approval.arms}, given {sorted(trajectories)})", fix_run))
    return approval

"""The task examples run as a user runs them, on the shipped demo scene: earlier stages included, both
tasks planned and passing their physics preview (examples/04 and 05, the scripts themselves)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(script: str, cwd: Path) -> str:
    res = subprocess.run([sys.executable, str(ROOT / "examples" / script), str(ROOT / "scenes" / "demo")],
                         cwd=cwd, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    return res.stdout


def test_joint_grasp_and_handover_examples_on_the_demo_scene(tmp_path):
    out = _run("04_joint_grasp.py", tmp_path)
    assert "success: True" in out, out
    rec = json.loads((tmp_path / "runs" / "example_tasks" / "tasks" / "joint-grasp" / "task.json").read_text())
    assert rec["success"] and rec["preview"]["checks"]["hold"]["max_rise_m"] >= 0.10
    out = _run("05_handover.py", tmp_path)  # reuses the calibration, segments and grasps of the first
    assert "success: True" in out, out
    task = tmp_path / "runs" / "example_tasks" / "tasks" / "handover"
    rec = json.loads((task / "task.json").read_text())
    assert rec["success"] and "held by secondary only" in rec["reason"]
    assert (task / "preview.gif").read_bytes()[:6] in (b"GIF89a", b"GIF87a")

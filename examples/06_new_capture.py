"""06 - Plan a new capture on your own arms: well-conditioned viewpoints, then a checked capture plan.

Nothing here moves an arm. To capture for real, run the printed command with ``--execute hardware``.

    .venv/bin/python examples/06_new_capture.py [OUT_SCENE]
"""

import sys
from pathlib import Path

from bimanual_app.hardware import dump_poses, plan_capture, suggest_viewpoints

out = Path(sys.argv[1] if len(sys.argv) > 1 else "runs/my_new_scene")
suggestion = suggest_viewpoints("piper", views=8)
print(f"{len(suggestion.q)} viewpoints, at least {suggestion.min_angle_deg:.0f} deg apart")
poses_file = out.parent / "primary_poses.yaml"
poses_file.parent.mkdir(parents=True, exist_ok=True)
poses_file.write_text(dump_poses(suggestion.as_pose_list("primary")))

plan = plan_capture(poses_file, out, arm="primary")  # checks limits, workspace, moves and the output folder
print("\n".join(plan.lines))
print(f"\nto capture: bijcr capture --arm primary --poses {poses_file} --out {out} --execute hardware")

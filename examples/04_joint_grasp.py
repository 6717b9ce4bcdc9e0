"""04 - Joint grasp: both arms lift a large object together, previewed in PyBullet with physics.

Runs the earlier stages (calibrate, segment, grasp) when their outputs are missing.

    .venv/bin/python examples/04_joint_grasp.py [SCENE]
"""

import sys

from bimanual_app.tasks import TaskOptions, run_task

scene = sys.argv[1] if len(sys.argv) > 1 else "scenes/demo"
result = run_task(TaskOptions(task="joint-grasp", scene=scene, work="runs/example_tasks"))
print(f"success: {result.success} - {result.reason}")
print(f"object {result.object_id}: {result.object_reason}")
print(f"outputs (task.json, preview.gif, key frames): {result.out}")
# On real arms, after a passing preview: TaskOptions(..., execute="hardware", can_primary="can0", can_secondary="can1")

"""05 - Handover: one arm picks a small object and hands it to the other (the primary gives where it can,
else the secondary), checked in the PyBullet preview.

    .venv/bin/python examples/05_handover.py [SCENE]
"""

import sys

from bimanual_app.tasks import TaskOptions, run_task

scene = sys.argv[1] if len(sys.argv) > 1 else "scenes/demo"
result = run_task(TaskOptions(task="handover", scene=scene, work="runs/example_tasks"))
print(f"success: {result.success} - {result.reason}")
print(f"object {result.object_id}: {result.object_reason}")
print(f"outputs: {result.out}")

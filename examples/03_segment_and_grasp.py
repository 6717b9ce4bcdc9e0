"""03 - Segment the metric scene and inspect the objects (run 02 first).

    .venv/bin/python examples/03_segment_and_grasp.py [CALIBRATION_DIR]
"""

import sys
from pathlib import Path

from bimanual_app.cli import main as bijcr
from segmentation import read_cloud, segment

cal_dir = Path(sys.argv[1] if len(sys.argv) > 1 else "runs/example_calibration")
points, colors, normals = read_cloud(cal_dir / "scene_b1.ply")
result = segment(points, colors=colors, normals=normals, progress=True)
print(f"table plane: {result.table}")
for obj in result.objects:
    print(obj)

# The same through the command line stages, which also write the pictures and grasps.json:
seg_dir, grasp_dir = cal_dir.parent / "example_segments", cal_dir.parent / "example_grasps"
bijcr(["segment", str(cal_dir / "scene_b1.ply"), "--out", str(seg_dir)])
bijcr(["grasp", str(cal_dir / "scene_b1.ply"), "--segments", str(seg_dir / "segments.npz"),
       "--calibration", str(cal_dir / "calibration.json"), "--out", str(grasp_dir)])

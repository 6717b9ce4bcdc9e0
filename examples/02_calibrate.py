"""02 - Calibrate both wrist cameras, the scale and the second base from a scene.

    .venv/bin/python examples/02_calibrate.py [SCENE] [OUT]
"""

import sys
from pathlib import Path

import numpy as np

import calibration
from bimanual_app.scene import load_scene
from bimanual_app.transforms import rotation_angle_between

scene = load_scene(sys.argv[1] if len(sys.argv) > 1 else "scenes/demo")
out = Path(sys.argv[2] if len(sys.argv) > 2 else "runs/example_calibration")

result = calibration.calibrate(scene)  # default method: joint absolute-pose refinement
print(f"scale {result.scale:.4f} m per model unit")
print("T_b1_b2 =\n", np.round(result.T_b1_b2, 4))
for key, value in result.uncertainty.items():
    print(f"  1-sigma {key}: {value}")
for w in result.warnings:
    print("warning:", w)

gt = scene.ground_truth  # evaluation only: the solver never reads it
if gt is not None:
    for name, T_est, T_true in [("T_e1_c1", result.T_e1_c1, gt.T_e1_c1), ("T_e2_c2", result.T_e2_c2, gt.T_e2_c2),
                                ("T_b1_b2", result.T_b1_b2, gt.T_b1_b2)]:
        err_deg = np.degrees(rotation_angle_between(T_est[:3, :3], T_true[:3, :3]))
        err_mm = 1000 * np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])
        print(f"  {name} vs ground truth: {err_deg:.2f} deg, {err_mm:.1f} mm")

files = calibration.write_outputs(out, scene, result)  # calibration.json, scene_b1.ply, calibration.png, ros/
print("wrote", ", ".join(str(p) for p in files.values()))

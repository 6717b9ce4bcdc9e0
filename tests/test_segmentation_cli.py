"""``bijcr segment`` end to end on small PLY files."""

from __future__ import annotations

import json

import numpy as np
from _seg_fixtures import PALETTE, make_table_scene, write_mask_scene, write_ply
from test_segmentation_objects import best_iou, box_and_cylinder, flush_boxes

from bimanual_app.cli import main as bijcr


def test_cli_writes_labels_summary_and_picture(tmp_path, capsys):
    s = make_table_scene(0, box_and_cylinder() + flush_boxes(), n_points=30_000)
    ply = tmp_path / "scene_b1.ply"
    write_ply(ply, s.points, s.colors)
    out = tmp_path / "seg"
    assert bijcr(["segment", str(ply), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "4 objects" in text and "box l x w x h" in text
    z = np.load(out / "segments.npz")
    labels = z["labels"]
    assert labels.dtype == np.int32 and labels.shape == (len(s.points),)
    assert set(np.unique(labels)) == {-1, 0, 1, 2, 3}
    assert best_iou(s.labels, labels).min() > 0.85
    K = 4
    assert z["obb_centers"].shape == (K, 3) and z["obb_rotations"].shape == (K, 3, 3)
    assert z["obb_extents"].shape == (K, 3) and z["centroids"].shape == (K, 3)
    assert np.array_equal(z["point_counts"], np.bincount(labels[labels >= 0]))
    assert z["table_plane"].shape == (4,) and abs(z["table_plane"][3]) < 0.002
    summary = json.loads((out / "segments.json").read_text())
    assert len(summary["objects"]) == K and summary["points"] == len(s.points)
    assert summary["objects"][0]["obb"]["extents"] == z["obb_extents"][0].tolist()
    png = (out / "segments.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    assert not list(out.glob(".*tmp*"))  # no temporary files left behind


def test_cli_masks_and_calibration(tmp_path, capsys):
    s = make_table_scene(0, flush_boxes(colour_b=PALETTE[0]), n_points=9_000)
    root = write_mask_scene(tmp_path / "scene", s)
    ply = tmp_path / "calib" / "scene_b1.ply"
    ply.parent.mkdir()
    write_ply(ply, s.points, s.colors)
    # calibration.json next to the cloud: w = b1, scale 1; the secondary base far away on the table
    T12 = np.eye(4)
    T12[:3, 3] = [0.9, 0.3, 0.0]
    (ply.parent / "calibration.json").write_text(json.dumps({"T_b1_w": np.eye(4).tolist(), "scale": 1.0,
                                                             "T_b1_b2": T12.tolist()}))
    assert bijcr(["segment", str(ply), "--out", str(tmp_path / "a"), "--no-plot"]) == 0
    assert len(json.loads((tmp_path / "a" / "segments.json").read_text())["objects"]) == 1
    assert bijcr(["segment", str(ply), "--out", str(tmp_path / "b"), "--masks", str(root), "--no-plot"]) == 0
    assert "masks: 4 views" in capsys.readouterr().out
    labels = np.load(tmp_path / "b" / "segments.npz")["labels"]
    assert best_iou(s.labels, labels).min() > 0.85
    # --masks without any calibration: an input error, nothing written
    ply2 = tmp_path / "bare.ply"
    write_ply(ply2, s.points, s.colors)
    assert bijcr(["segment", str(ply2), "--out", str(tmp_path / "c"), "--masks", str(root)]) == 1
    assert "calibration" in capsys.readouterr().err
    assert not (tmp_path / "c" / "segments.npz").exists()

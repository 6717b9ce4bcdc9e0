"""Bad inputs to the segmenter: a clear InputError naming the file and the fix, and no labels file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _seg_fixtures import make_table_scene, write_ply

from bimanual_app.cli import main as bijcr
from bimanual_app.io_utils import InputError
from segmentation import read_cloud, segment


@pytest.fixture(scope="module")
def scene():
    return make_table_scene(0, 3, n_points=20_000, background=False)


def problems(exc: InputError) -> str:
    return "\n".join(str(p) for p in exc.problems)


def test_empty_cloud():
    with pytest.raises(InputError) as e:
        segment(np.zeros((0, 3)), source="empty.ply")
    assert "empty" in problems(e.value) and "empty.ply" in problems(e.value)


def test_nan_points_are_reported_not_dropped(scene):
    pts = scene.points.copy()
    pts[[5, 17]] = np.nan
    with pytest.raises(InputError) as e:
        segment(pts, source="cloud.ply")
    text = problems(e.value)
    assert "2 of" in text and "NaN" in text and "fix" in text


def test_millimetres_are_not_metres(scene):
    with pytest.raises(InputError) as e:
        segment(scene.points * 1000.0, scene.colors, source="mm.ply")
    assert "millimetres" in problems(e.value) and "mm.ply" in problems(e.value)


def test_a_table_the_size_of_a_house(scene):
    with pytest.raises(InputError) as e:
        segment(scene.points * 12.0, source="house.ply")
    assert "not a metric" in problems(e.value) or "across" in problems(e.value)


def test_no_plane_in_a_crop_of_objects(scene):
    crop = scene.points[scene.labels >= 0]
    rng = np.random.default_rng(0)
    blob = np.r_[crop, rng.normal(scale=0.05, size=(3000, 3)) + crop.mean(0)]
    with pytest.raises(InputError) as e:
        segment(blob, source="crop.ply")
    assert "no table" in problems(e.value)


def test_wrong_shapes(scene):
    with pytest.raises(InputError):
        segment(scene.points[:, :2])
    with pytest.raises(InputError):
        segment(scene.points, scene.colors[:10])
    with pytest.raises(InputError):
        segment(scene.points, mask_ids=np.zeros(10, int))


def test_read_cloud_errors(tmp_path):
    with pytest.raises(InputError) as e:
        read_cloud(tmp_path / "missing.ply")
    assert "not found" in problems(e.value)
    (tmp_path / "cloud.txt").write_text("1 2 3\n")
    with pytest.raises(InputError) as e:
        read_cloud(tmp_path / "cloud.txt")
    assert "format" in problems(e.value)
    (tmp_path / "broken.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nend_header\n")
    with pytest.raises(InputError) as e:
        read_cloud(tmp_path / "broken.ply")
    assert "no points" in problems(e.value)


def test_read_cloud_keeps_colours_and_nan(tmp_path, scene):
    write_ply(tmp_path / "c.ply", scene.points, scene.colors)
    p, c, n = read_cloud(tmp_path / "c.ply")
    assert p.shape == scene.points.shape and np.allclose(p, scene.points)
    assert c.dtype == np.uint8 and np.array_equal(c, scene.colors)
    pts = scene.points.copy()
    pts[3] = np.nan
    write_ply(tmp_path / "n.ply", pts)
    p, c, n = read_cloud(tmp_path / "n.ply")
    assert len(p) == len(pts) and np.isnan(p[3]).all() and c is None


@pytest.mark.parametrize("case", ["nan", "mm", "empty", "noplane"])
def test_cli_bad_input_leaves_no_labels_file(tmp_path, scene, case, capsys):
    pts = scene.points.copy()
    if case == "nan":
        pts[0] = np.nan
    elif case == "mm":
        pts = pts * 1000.0
    elif case == "noplane":
        pts = pts[scene.labels >= 0]
    ply = tmp_path / f"{case}.ply"
    if case == "empty":
        ply.write_text("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
                       "property float z\nend_header\n")
    else:
        write_ply(ply, pts)
    out = tmp_path / "out"
    assert bijcr(["segment", str(ply), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert str(ply) in err and "fix" in err
    assert not (out / "segments.npz").exists()
    assert not list(Path(tmp_path).rglob("*.npz"))

"""Unsure points (a cloud's steep sides, kept where other views confirmed them): the PLY flag written by the
calibration and read by the segmentation, and how they join segments without linking two."""

from __future__ import annotations

import numpy as np
import pytest

from calibration._export import write_ply
from segmentation import read_cloud, read_unsure, segment
from segmentation._unsure import join_unsure


def test_the_unsure_flag_goes_through_the_ply(tmp_path):
    rng = np.random.default_rng(0)
    P = rng.uniform(-1, 1, (500, 3))
    C = rng.integers(0, 255, (500, 3)).astype(np.uint8)
    U = rng.random(500) < 0.3
    write_ply(tmp_path / "a.ply", P, C, U)
    pts, cols, _ = read_cloud(tmp_path / "a.ply")  # Open3D skips the property it does not know
    assert np.allclose(pts, P, atol=1e-6) and np.array_equal(cols, C)
    assert np.array_equal(read_unsure(tmp_path / "a.ply", 500), U)
    assert read_unsure(tmp_path / "a.ply", 499) is None  # not the cloud it claims to flag
    write_ply(tmp_path / "b.ply", P, None)
    assert read_unsure(tmp_path / "b.ply") is None
    np.savez(tmp_path / "c.npz", points=P)
    assert read_unsure(tmp_path / "c.npz") is None
    (tmp_path / "d.ply").write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty uchar unsure\n"
                                    "end_header\n0 1\n")
    assert read_unsure(tmp_path / "d.ply") is None  # only the binary files the calibration writes
    with pytest.raises(ValueError, match="unsure"):
        write_ply(tmp_path / "e.ply", P, None, U[:-1])


def _column(x, y, z0, z1, step=0.004):
    z = np.arange(z0, z1, step)
    return np.stack([np.full_like(z, x), np.full_like(z, y), z], axis=1)


def test_unsure_sides_join_their_own_segment_down_to_the_table():
    # two box tops (sure, labels 0 and 1) 2.2 cm apart at 6 cm; each box's side a column of unsure points down to
    # the table, the two columns 6 mm apart near the ground (closer to each other than to anything else)
    top0 = np.array([[x, y, 0.06] for x in np.arange(0.0, 0.03, 0.004) for y in np.arange(0.0, 0.03, 0.004)])
    top1 = top0 + [0.052, 0.0, 0.0]
    side0 = _column(0.030, 0.012, 0.0, 0.058)
    side1 = _column(0.036, 0.012, 0.0, 0.058) + [0.0, 0.0, 0.0]
    side1[:, 0] = np.linspace(0.050, 0.036, len(side1))[::-1]  # slanting from the top of box 1 down towards box 0
    stray = np.array([[0.5, 0.5, 0.04]])  # an unsure point no chain reaches
    P = np.concatenate([top0, top1, side0, side1, stray])
    labels = np.concatenate([np.zeros(len(top0)), np.ones(len(top1)), -np.ones(len(side0) + len(side1) + 1)]).astype(
        np.int32)
    unsure = np.concatenate([np.zeros(len(top0) + len(top1), bool), np.ones(len(side0) + len(side1) + 1, bool)])
    out = join_unsure(P, labels, unsure, P[:, 2], min_height=0.005)
    s0 = slice(len(top0) + len(top1), len(top0) + len(top1) + len(side0))
    s1 = slice(s0.stop, s0.stop + len(side1))
    assert np.array_equal(out[: s0.start], labels[: s0.start])  # the sure points keep their labels
    high0, high1 = P[s0][:, 2] >= 0.005, P[s1][:, 2] >= 0.005
    assert np.all(out[s0][high0] == 0) and np.all(out[s1][high1] == 1)
    assert np.all(out[s0][~high0] == -1) and np.all(out[s1][~high1] == -1)  # the table's band
    assert out[-1] == -1
    with pytest.raises(ValueError, match="unsure"):
        join_unsure(P, labels, unsure[:-1], P[:, 2], 0.005)


def test_segment_keeps_unsure_points_out_of_the_graph():
    from _seg_fixtures import make_table_scene

    scene = make_table_scene(seed=2, objects=3, touching=0.0, n_points=40_000, background=False)
    P = scene.points
    none = segment(P, scene.colors)
    flags = np.zeros(len(P), bool)
    assert np.array_equal(segment(P, scene.colors, unsure=flags).labels, none.labels)  # no flag: the same
    # a bridge of unsure points between two objects' tops links nothing: each object keeps its own segment
    a, b = (none.labels == k for k in (0, 1))
    ca, cb = P[a].mean(0), P[b].mean(0)
    bridge = ca + np.linspace(0.0, 1.0, 400)[:, None] * (cb - ca)
    bridge[:, 2] = max(P[a][:, 2].max(), P[b][:, 2].max())
    Q = np.concatenate([P, bridge])
    C = np.concatenate([scene.colors, np.full((len(bridge), 3), 128, np.uint8)])
    res = segment(Q, C, unsure=np.concatenate([flags, np.ones(len(bridge), bool)]))
    assert res.stats["unsure_points"] == len(bridge) and res.stats["unsure_joined"] > 0
    assert np.array_equal(res.labels[: len(P)] >= 0, none.labels >= 0)
    assert len(res.objects) == len(none.objects)
    la, lb = np.bincount(res.labels[: len(P)][a]).argmax(), np.bincount(res.labels[: len(P)][b]).argmax()
    assert la != lb
    on_bridge = res.labels[len(P):]
    assert np.all(on_bridge[:40] == la) and np.all(on_bridge[-40:] == lb)  # each end joins its own object
    with pytest.raises(Exception, match="unsure"):
        segment(Q, C, unsure=np.ones(len(P), bool))  # one flag per point of the cloud, or none

"""Bad input: a segments file that does not match the cloud, empty segments, objects too narrow or too wide."""

import numpy as np
import pytest
from _grasp_fixtures import Obj, accept_all_arms, make_cloud, write_inputs

from bimanual_app.io_utils import InputError
from grasping import PlanParams, load_segments, plan_grasps, resolve_inputs, scene_cloud

FAST = PlanParams(handover=False, retry_factor=1)


def test_segments_must_match_the_cloud():
    P, L = make_cloud([Obj("box", (0.3, 0.0), (0.04, 0.04, 0.05))])
    with pytest.raises(InputError, match="does not belong to this cloud"):
        scene_cloud(P, L[:-5])
    with pytest.raises(InputError, match="integers"):
        scene_cloud(P, L + 0.5)
    with pytest.raises(InputError, match="< -1"):
        scene_cloud(P, np.where(L < 0, -3, L))
    Pn = P.copy()
    Pn[3] = np.nan
    with pytest.raises(InputError, match="not finite"):
        scene_cloud(Pn, L)
    with pytest.raises(InputError, match="no object"):
        plan_grasps(scene_cloud(P, np.full(len(P), -1)), arms=None, params=FAST)
    with pytest.raises(InputError, match="not in the segments"):
        plan_grasps(scene_cloud(P, L), arms=None, params=FAST, objects=[4])


def test_segments_file_problems(tmp_path):
    P, L = make_cloud([Obj("box", (0.3, 0.0), (0.04, 0.04, 0.05))])
    ply, seg, _ = write_inputs(tmp_path, P, L)
    np.savez(tmp_path / "bad.npz", segments=L)
    with pytest.raises(InputError, match="missing key 'labels'"):
        load_segments(tmp_path / "bad.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="cannot read"):
        load_segments(tmp_path / "junk.npz")
    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(InputError, match="no scene_b1.ply"):
        resolve_inputs(tmp_path / "empty_dir")
    assert resolve_inputs(tmp_path)[0] == ply


def test_empty_narrow_and_wide_objects_are_reported_not_grasped():
    objs = [
        Obj("box", (0.30, 0.15), (0.04, 0.05, 0.05)),  # 0: fine
        Obj("box", (0.30, -0.15), (0.003, 0.003, 0.004)),  # 1: a speck: too few points
        Obj("box", (0.42, 0.0), (0.004, 0.004, 0.08)),  # 2: a 4 mm pin: narrower than the fingers resolve
        Obj("box", (0.20, 0.0), (0.12, 0.12, 0.10)),  # 3: wider than the stroke every way
    ]
    P, L = make_cloud(objs, step=0.002)
    L = np.where(L == 1, 5, L)  # the speck becomes object 5: ids 1 and 4 are empty segments
    plan = plan_grasps(scene_cloud(P, L), arms=accept_all_arms(), params=FAST)
    by_id = {op.id: op for op in plan.objects}
    assert sorted(by_id) == [0, 1, 2, 3, 4, 5]
    assert by_id[0].mode == "single" and len(by_id[0].grasps) > 0 and not by_id[0].problems
    for k in (1, 4):  # empty segments
        assert by_id[k].mode == "none" and "0 point(s)" in by_id[k].problems[0].message
        assert by_id[k].grasps is None
    assert by_id[5].mode == "none" and "point(s)" in by_id[5].problems[0].message
    assert by_id[2].mode == "none" and "narrower than" in by_id[2].problems[0].message
    assert by_id[2].grasps is None or len(by_id[2].grasps) == 0
    assert "wider than" in by_id[3].problems[0].message and by_id[3].mode == "joint"
    assert len(by_id[3].grasps) == 0  # no single-arm grasp was made up for it
    # every problem names the file and the object
    for k in (1, 2, 3, 4, 5):
        p = by_id[k].problems[0]
        assert p.field == f"object {k}" and p.fix


def test_the_workspace_drops_far_background_and_keeps_every_object_point_and_field():
    """Background farther than the radius from both bases goes (a room's floor and walls); an object's points
    stay however far they are, and the cloud's plane, sources and colours come along."""
    from grasping._plan import _workspace

    P, L = make_cloud([Obj("box", (0.3, 0.0), (0.04, 0.04, 0.05))])
    far = np.array([[3.0, 0.0, 0.0], [0.0, 3.0, 0.0]])
    P, L = np.vstack([P, far, [[2.5, 0.0, 0.02]]]), np.r_[L, -1, -1, 0]
    C = (np.arange(len(P))[:, None] % 255 * np.ones(3)).astype(np.uint8)
    cloud = scene_cloud(P, L, C, table_plane=np.array([0.0, 0.0, 1.0, 0.0]), source={"cloud": "x.ply"})
    arms = accept_all_arms(np.eye(4))
    kept = _workspace(cloud, arms, radius=1.0)
    assert len(kept.points) == len(P) - 2 and not np.isin(far, kept.points).all(axis=1).any()
    assert (kept.labels == 0).sum() == (L == 0).sum() and [2.5, 0.0, 0.02] in kept.points.tolist()
    assert np.array_equal(kept.colors, C[:-3].tolist() + [C[-1].tolist()])
    assert kept.source == {"cloud": "x.ply"} and np.array_equal(kept.table_plane, [0.0, 0.0, 1.0, 0.0])

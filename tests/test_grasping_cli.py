"""`bijcr grasp` end to end on a small cloud + segments + calibration: grasps.json, grasps.png, bad input."""

import json

import numpy as np
import pytest
from _grasp_fixtures import Obj, facing_T_b1_b2, make_cloud, write_inputs

from bimanual_app.cli import main
from bimanual_app.transforms import check_T, inv_T

T12 = facing_T_b1_b2(0.6)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("grasp_cli")
    objs = [Obj("box", (0.25, 0.22), (0.045, 0.06, 0.06), 0.4),  # graspable with one hand
            Obj("box", (0.30, -0.05), (0.16, 0.30, 0.10), 0.05)]  # needs two arms
    P, L = make_cloud(objs, table_size=(0.8, 0.9), noise=0.0005)
    ply, seg, cal = write_inputs(d / "in", P, L, T12)
    rc = main(["grasp", str(d / "in"), "--segments", str(seg), "--out", str(d / "out"), "--quiet", "--no-handover"])
    return d, rc, len(P)


def test_cli_writes_grasps_json_and_png(run_dir):
    d, rc, n = run_dir
    assert rc == 0
    out = json.loads((d / "out" / "grasps.json").read_text())
    assert (d / "out" / "grasps.png").stat().st_size > 10_000
    assert out["format"] == 1 and out["frame"] == "b1" and out["reach_checked"]
    assert np.allclose(out["T_b1_b2"], T12) and out["arms"] == ["primary", "secondary"]
    assert abs(out["gripper"]["stroke"] - 0.07) < 1e-3
    objs = {o["id"]: o for o in out["objects"]}
    small, large = objs[0], objs[1]
    assert small["mode"] == "single" and small["grasps"]
    assert small["shape"]["kind"] == "box" and large["shape"]["kind"] == "box" and small["shape"]["fit"] >= 0.9
    ranks = [g["rank"] for g in small["grasps"]]
    assert ranks == list(range(1, len(ranks) + 1))
    assert all(a["score"] >= b["score"] for a, b in zip(small["grasps"], small["grasps"][1:]))
    from bimanual_app.robots import load_robot

    robot = load_robot("piper")
    for g in small["grasps"]:
        T = check_T("T_b1_g", np.asarray(g["T_b1_g"]))
        assert np.allclose(np.asarray(g["T_b2_g"]), inv_T(T12) @ T, atol=1e-9)
        assert g["contact_width"] < g["width"] <= out["gripper"]["max_width"] + 1e-9
        assert g["arm"] in ("primary", "secondary", "both") and g["arms"]
        for arm, e in g["arms"].items():
            T_b1_b = np.eye(4) if arm == "primary" else T12
            assert np.allclose(T_b1_b @ np.asarray(e["T_b_g"]), np.asarray(e["T_b1_g"]), atol=1e-9)
            # the joint solution really puts the gripper there
            assert np.allclose(robot.fk_link(np.asarray(e["q"]), robot.tcp_link), np.asarray(e["T_b_g"]), atol=2e-3)
            assert len(e["q_pregrasp"]) == 6
    assert large["mode"] == "joint" and large["joint_grasps"] and not large["grasps"]
    pair = large["joint_grasps"][0]
    assert pair["kind"] == "push" and pair["imbalance"] <= 0.25
    assert np.dot(pair["primary"]["squeeze_b1"], pair["secondary"]["squeeze_b1"]) < -0.9
    assert any("wider than" in p for p in large["problems"])


def test_cli_rejects_segments_of_another_cloud(tmp_path, run_dir, capsys):
    d, _, n = run_dir
    np.savez(tmp_path / "segments.npz", labels=np.zeros(n - 3, np.int32))
    rc = main(["grasp", str(d / "in" / "scene_b1.ply"), "--segments", str(tmp_path / "segments.npz"),
               "--out", str(tmp_path / "out"), "--quiet"])
    assert rc == 1
    assert "does not belong to this cloud" in capsys.readouterr().err
    assert not (tmp_path / "out" / "grasps.json").exists()


def test_cli_says_why_a_wide_object_has_no_two_arm_grasp(tmp_path, capsys):
    """A box too wide for one gripper, out of both arms' reach: the stage fails, and says both that it
    needs two arms and that no two-arm grasp was found (not only the first)."""
    P, L = make_cloud([Obj("box", (0.30, 0.75), (0.16, 0.30, 0.10), 0.0)], table_size=(0.8, 1.8))
    _, seg, _ = write_inputs(tmp_path / "in", P, L, T12)
    rc = main(["grasp", str(tmp_path / "in"), "--segments", str(seg), "--out", str(tmp_path / "out"), "--quiet",
               "--no-handover"])
    assert rc == 1
    err = capsys.readouterr().err
    assert "wider than the gripper's stroke" in err and "no balanced two-arm grasp" in err
    assert not (tmp_path / "out" / "grasps.json").exists()


def test_cli_handover_giver_option_sets_the_givers(capsys):
    import argparse

    from grasping.cli import GIVERS, add_arguments

    p = argparse.ArgumentParser()
    add_arguments(p)
    base = ["cloud.ply", "--segments", "s.npz", "--out", "o"]
    assert GIVERS[p.parse_args(base).handover_giver] == ("primary", "secondary")  # either arm, primary first
    assert GIVERS[p.parse_args(base + ["--handover-giver", "primary"]).handover_giver] == ("primary",)
    with pytest.raises(SystemExit):
        p.parse_args(base + ["--handover-giver", "left"])
    assert "invalid choice" in capsys.readouterr().err

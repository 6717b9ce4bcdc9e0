"""`bijcr capture --suggest`: well-conditioned, reachable viewpoints that all look at the table region."""

import numpy as np
import pytest
import yaml

from bimanual_app.cli import main as cli_main
from bimanual_app.hardware import SafetyLimits, load_poses, plan_capture, suggest_viewpoints
from bimanual_app.hardware._suggest import conditioning
from bimanual_app.transforms import rotation_angle, so3_exp


@pytest.fixture(scope="module")
def limits():
    return SafetyLimits.from_robot("piper")


@pytest.fixture(scope="module")
def suggestion(limits):
    return suggest_viewpoints(limits.robot, views=8, target=(0.40, 0.0, 0.0), limits=limits, seed=0)


def test_views_are_reachable_and_well_conditioned(suggestion, limits):
    s = suggestion
    assert s.q.shape == (8, 6)
    assert not limits.config_problems(s.q), "every view inside the joint limits and the workspace box"
    # FK of the returned joints is the returned tool pose
    np.testing.assert_allclose(limits.robot.fk_link(s.q, "gripper_tcp"), s.T_b_t, atol=1e-9)
    R = s.T_b_t[:, :3, :3]
    i, j = np.triu_indices(8, 1)
    angles = np.degrees(rotation_angle(np.swapaxes(R[i], -1, -2) @ R[j]))
    assert angles.min() > 25.0 and angles.min() == pytest.approx(s.min_angle_deg, abs=1e-6)
    assert s.axis_spread > 0.05, "relative rotations about varied axes, not one"


def test_views_look_at_the_table_region(suggestion):
    s = suggestion
    p, z = s.T_b_t[:, :3, 3], s.T_b_t[:, :3, 2]
    assert np.all(z[:, 2] < -0.2), "looking down at the table"
    t = (s.target[2] - p[:, 2]) / z[:, 2]
    hit = p + t[:, None] * z
    assert np.all(np.linalg.norm(hit - s.target, axis=1) < 0.06), "every viewing ray hits the region"
    assert np.all((t > 0.1) & (t < 0.4))


def test_conditioning_measure():
    axes = so3_exp(np.array([[0, 0, a] for a in (0.0, 0.6, 1.2, 1.8)]))
    m, spread = conditioning(axes)
    assert m == pytest.approx(np.degrees(0.6)) and spread < 1e-9  # all about z: degenerate
    rng = np.random.default_rng(0)
    _, spread_rand = conditioning(so3_exp(rng.normal(size=(8, 3))))
    assert spread_rand > 0.1


def test_cli_output_is_a_usable_poses_file(tmp_path, capsys):
    assert cli_main(["capture", "--suggest", "--views", "6", "--plot", str(tmp_path / "views.png")]) == 0
    text = capsys.readouterr().out
    path = tmp_path / "poses.yaml"
    path.write_text(text)
    assert yaml.safe_load(text)["robot"] == "piper"
    pl = load_poses(path)
    assert len(pl) == 6 and pl.names[0] == "view_00"
    plan = plan_capture(pl, tmp_path / "scene", "secondary")  # passes every capture check
    assert len(plan.lines) > 6
    assert (tmp_path / "views.png").stat().st_size > 1000
    with pytest.raises(SystemExit):
        cli_main(["capture", "--suggest", "--views", "x"])

"""When a point-map estimate still counts as a correction of the pose-only solve (calibration._correction): the
limits grow with the pose-only solve's own uncertainty, so a capture of few views, whose pose-only answer is
uncertain by centimetres, is not refused the large correction its point maps make."""

from __future__ import annotations

import numpy as np
import pytest

from bimanual_app.transforms import make_T


def _outputs(dx_m=0.0, droll_deg=0.0, scale=1.0, name="T_b1_b2"):
    out = {"T_e1_c1": np.eye(4), "T_e2_c2": np.eye(4), "T_b1_b2": np.eye(4), "scale": scale}
    c, s = np.cos(np.radians(droll_deg)), np.sin(np.radians(droll_deg))
    R = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    out[name] = make_T(R, [dx_m, 0.0, 0.0])
    return out


def _uncertainty(rot_deg, trans_mm, scale_pct):
    one = {"rotation_deg": rot_deg, "translation_norm_mm": trans_mm}
    return {"T_e1_c1": one, "T_e2_c2": one, "T_b1_b2": one, "scale": {"percent": scale_pct}}


def test_limits_are_the_floors_without_an_uncertainty_and_grow_with_it():
    from calibration._correction import (
        CORRECTION_SIGMAS,
        MAX_LOG_SCALE_CHANGE,
        MAX_ROT_CHANGE_DEG,
        MAX_TRANS_CHANGE_M,
        correction_limits,
    )

    for u in (None, {}):
        lim = correction_limits(u)
        assert lim["T_b1_b2"] == (MAX_ROT_CHANGE_DEG, MAX_TRANS_CHANGE_M)
        assert lim["log_scale"] == MAX_LOG_SCALE_CHANGE
    small = correction_limits(_uncertainty(0.2, 2.0, 0.5))  # a well-pinned solve: the floors stand
    assert small["T_e1_c1"] == (MAX_ROT_CHANGE_DEG, MAX_TRANS_CHANGE_M) and small["log_scale"] == MAX_LOG_SCALE_CHANGE
    big = correction_limits(_uncertainty(2.0, 33.0, 4.0))  # 4-5 views at a foundation model's pose noise
    assert big["T_b1_b2"] == pytest.approx((CORRECTION_SIGMAS * 2.0, CORRECTION_SIGMAS * 0.033))
    assert big["log_scale"] == pytest.approx(max(MAX_LOG_SCALE_CHANGE, CORRECTION_SIGMAS * np.log1p(0.04)))
    unbounded = correction_limits(_uncertainty(float("inf"), float("inf"), 1.0))
    assert unbounded["T_e2_c2"] == (float("inf"), float("inf"))


def test_beyond_correction_names_the_output_that_moved_too_far():
    from calibration._correction import beyond_correction, correction_limits

    start = _outputs(0.0)
    floors = correction_limits(None)
    assert beyond_correction(start, _outputs(0.03, 2.0), floors, "the joint estimate") is None
    why = beyond_correction(start, _outputs(0.072, name="T_e2_c2"), floors, "the joint estimate")
    assert why.startswith("the joint estimate would move T_e2_c2 by 0.0 deg / 72 mm") and "at most" in why
    assert "T_b1_b2" in beyond_correction(start, _outputs(0.0, 6.0), floors, "x")
    assert "scale by +20.0 %" in beyond_correction(start, _outputs(scale=1.2), floors, "x")
    # the same 72 mm is a correction of a pose-only solve uncertain by 33 mm (2.2 of its sigmas)
    assert beyond_correction(start, _outputs(0.072, name="T_e2_c2"), correction_limits(_uncertainty(2.0, 33.0, 2.0)),
                             "x") is None
    with pytest.raises(ValueError, match="T_e1_c1"):
        beyond_correction({**start, "T_e1_c1": np.eye(3)}, start, floors, "x")


def test_the_joint_estimate_is_judged_by_the_limits_it_is_given(synth_paper):
    """On a rendered scene the joint estimate is accepted with the pose-only solve's own limits, and refused
    (pose-only values kept, the output named) when the limits are made tighter than its correction."""
    from bimanual_app.scene import load_scene
    from calibration import CalibrationOptions, calibrate
    from calibration._api import _map_views, _views_of
    from calibration._correction import correction_limits
    from calibration._estimate import estimate_jointly
    from calibration._joint import JointState

    scene = load_scene(synth_paper)
    plain = calibrate(scene, options=CalibrationOptions(point_maps=False))
    rows, arms, E = _views_of(scene, plain)
    views = _map_views(scene, plain, rows, arms, E)
    P = scene.reconstruction.T_w_c[rows]
    start = JointState(plain.T_e1_c1, plain.T_e2_c2, plain.scale, plain.T_b1_b2, plain.T_b1_w, np.zeros(len(rows)))
    noise = (np.radians(plain.noise["rotation_deg"]), plain.noise["translation_mm"] * 1e-3)
    fit = estimate_jointly(views, arms, E, P, start, noise, limits=correction_limits(plain.uncertainty))
    assert fit.accepted, fit.reason
    tight = {k: ((1e-3, 1e-5) if k != "log_scale" else 1.0) for k in correction_limits(None)}
    refused = estimate_jointly(views, arms, E, P, start, noise, limits=tight)
    assert not refused.accepted and "more than a correction of the pose-only solve" in refused.reason
    assert refused.state is start

"""The warning for a second base placed too loosely for a hand-over (calibration._advice): its threshold, its
wording (what is wrong and the fix), and that `calibrate` and a hand-over task pass it on to the user."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest


def _unc(mm):
    return {"T_b1_b2": {"translation_norm_mm": mm, "rotation_deg": 0.1}}


def test_the_advice_names_the_sigma_and_the_fix_above_the_threshold_only():
    from calibration import base_to_base_advice
    from calibration._advice import HANDOVER_SIGMA_MM

    assert base_to_base_advice(None) is None and base_to_base_advice({}) is None
    assert base_to_base_advice(_unc(HANDOVER_SIGMA_MM - 0.1)) is None
    assert base_to_base_advice(_unc(float("nan"))) is None
    msg = base_to_base_advice(_unc(20.8))
    assert "T_b1_b2" in msg and "+-21 mm" in msg and "-> fix:" in msg and "more views" in msg
    assert "not determined by these views" in base_to_base_advice(_unc(float("inf")))


def test_calibrate_appends_the_advice_of_its_final_uncertainty(synth_paper, monkeypatch):
    import calibration._advice as advice
    from bimanual_app.scene import load_scene
    from calibration import CalibrationOptions, calibrate

    scene = load_scene(synth_paper)
    monkeypatch.setattr(advice, "HANDOVER_SIGMA_MM", 0.0)  # any uncertainty is too loose
    res = calibrate(scene, options=CalibrationOptions(point_maps=False))
    mm = res.uncertainty["T_b1_b2"]["translation_norm_mm"]
    assert any(w.startswith("the second base (T_b1_b2)") and f"+-{mm:.0f} mm" in w for w in res.warnings)
    monkeypatch.setattr(advice, "HANDOVER_SIGMA_MM", float("inf"))
    res = calibrate(scene, options=CalibrationOptions(point_maps=False))
    assert not any("the second base (T_b1_b2)" in w for w in res.warnings)


@pytest.mark.parametrize("task, warned", [("handover", True), ("joint-grasp", False)])
def test_a_hand_over_task_repeats_the_advice_with_the_file_it_comes_from(task, warned, capsys):
    from bimanual_app.tasks._run import _input_warnings

    cal = Path("runs/x/calibration/calibration.json")
    inputs = SimpleNamespace(calibration={"uncertainty": _unc(12.0)}, paths=SimpleNamespace(calibration=cal))
    out = _input_warnings(SimpleNamespace(task=task, quiet=False), inputs)
    assert bool(out) == warned
    if warned:
        assert out[0].startswith(f"{cal}: the second base") and "warning:" in capsys.readouterr().err
    assert _input_warnings(SimpleNamespace(task=task, quiet=True),
                           SimpleNamespace(calibration={}, paths=inputs.paths)) == []

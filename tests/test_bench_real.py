"""bench/real.py end to end on a small rendered fixture (the real captures stay outside the repository)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
from _recon_fixtures import render_scene

from bimanual_app.transforms import inv_T

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location("bench_real", ROOT / "bench" / "real.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_runs_every_scene_with_a_truth_file_and_reports_targets(tmp_path, monkeypatch):
    bench = _bench()
    data = tmp_path / "realdata"
    gt = render_scene(data / "tiny", views_per_arm=4)
    render_scene(data / "no_truth", views_per_arm=3)  # skipped: no truth file beside it
    truth = {"T_b1_b2": (gt["T_b_w"]["primary"] @ inv_T(gt["T_b_w"]["secondary"])).tolist(),
             "T_e1_c1": gt["T_e_c"]["primary"].tolist(), "T_e2_c2": gt["T_e_c"]["secondary"].tolist()}
    (data / "tiny.truth.json").write_text(json.dumps(truth))
    for p in (data / "tiny").rglob("*"):  # the shared data are read-only: the bench must copy them
        p.chmod(0o555 if p.is_dir() else 0o444)
    monkeypatch.setattr(bench, "WORK", tmp_path / "work")
    out = tmp_path / "real.md"
    try:
        assert bench.main(["--data", str(data), "--out", str(out)]) == 0
    finally:
        for p in (data / "tiny").rglob("*"):
            p.chmod(0o755 if p.is_dir() else 0o644)
    text = out.read_text()
    assert "| tiny | default |" in text and "| tiny | pose only |" in text and "no_truth" not in text
    assert "tiny, defaults: base-to-base <= 0.4 deg / 5 mm" in text  # the generic targets for other captures
    assert not (data / "tiny" / "reconstruction.npz").exists()  # the source is never written
    assert (tmp_path / "work" / "tiny" / "reconstruction.npz").exists()
    row = next(line for line in text.splitlines() if line.startswith("| tiny | pose only |"))
    b2b_deg, b2b_mm = (float(v) for v in row.split("|")[3].split("/"))
    assert b2b_deg < 1.0 and b2b_mm < 10.0  # a clean render: COLMAP + calibration land near the truth


def test_a_bad_truth_file_is_named(tmp_path):
    bench = _bench()
    bad = tmp_path / "x.truth.json"
    bad.write_text(json.dumps({"T_b1_b2": np.eye(4).tolist(), "T_e1_c1": np.eye(3).tolist(), "T_e2_c2": np.eye(4).tolist()}))
    with pytest.raises(SystemExit) as e:
        bench.read_truth(bad)
    assert "T_e1_c1" in str(e.value) and "x.truth.json" in str(e.value)
    bad.write_text(json.dumps({"T_b1_b2": np.eye(4).tolist()}))
    with pytest.raises(SystemExit) as e:
        bench.read_truth(bad)
    assert "'T_e1_c1' is missing" in str(e.value)

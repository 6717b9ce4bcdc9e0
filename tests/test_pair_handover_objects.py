"""tools/pair_handover_objects.py: objects with a hand-over in two bench bases, paired object by object."""

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

from pair_handover_objects import handover_objects, main, pair_objects, verdict  # noqa: E402


def _grasps(base: Path, scene: str, objects: list[dict]) -> None:
    d = base / "pipeline" / scene / "grasps"
    d.mkdir(parents=True)
    (d / "grasps.json").write_text(json.dumps({"objects": objects}))


def _obj(i: int, handover: bool, kind: str = "box", single: bool = True) -> dict:
    return {"id": i, "shape": {"kind": kind}, "stats": {"sampler": {"kept": 3}} if single else {},
            "handover": {"score": 0.5} if handover else None}


def test_objects_gained_and_lost_between_two_bases(tmp_path, capsys):
    before, after = tmp_path / "before", tmp_path / "after"
    _grasps(before, "synth_1", [_obj(0, False, single=False), _obj(1, True), _obj(2, False, "free-form")])
    _grasps(before, "synth_2", [_obj(1, True)])
    _grasps(after, "synth_1", [_obj(0, False, single=False), _obj(1, False), _obj(2, True, "free-form")])
    _grasps(after, "synth_2", [_obj(1, True)])
    _grasps(after, "synth_3", [_obj(1, True)])  # only in one base: not compared
    a, b = handover_objects(before), handover_objects(after)
    assert set(a) == {("synth_1", 1), ("synth_1", 2), ("synth_2", 1)}  # the joint-only object is left out
    p = pair_objects(a, b)
    assert (p["objects"], p["before"], p["after"]) == (3, 2, 2)
    assert p["gained"] == [("synth_1", 2)] and p["lost"] == [("synth_1", 1)]
    assert main([str(before), str(after)]) == 0
    out = capsys.readouterr().out
    assert "2 -> 2 of 3" in out and "synth_1 #2 (free-form)" in out


def test_verdict_names_the_dangerous_kind():
    assert verdict({"planned": True, "estimate_ok": True, "truth_ok": True}) == "held"
    assert verdict({"planned": True, "estimate_ok": True, "truth_ok": False}) == "approved, fails in reality"
    assert verdict({"planned": True, "estimate_ok": False, "truth_ok": False}) == "not approved"
    assert verdict({"planned": False}) == "no plan"

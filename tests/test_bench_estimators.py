"""The estimator bench's pieces: seed ranges and issue 21's targets on its rows."""

from __future__ import annotations

from bench import estimators as be


def test_seeds_take_lists_and_ranges():
    assert be.parse_seeds("301-304") == [301, 302, 303, 304]
    assert be.parse_seeds("5,1100-1102, 7") == [5, 1100, 1101, 1102, 7]


def _row(est, he_rot, he_mm, b2b_mm, scale, z=None):
    return {"seed": 1, "noise": "fm", "estimator": est, "accepted": True, "he_rot": [he_rot, he_rot],
            "he_mm": [he_mm, he_mm], "b2b_rot": 0.5, "b2b_mm": b2b_mm, "scale": scale, "z": z}


def test_targets_compare_the_joint_estimate_with_park_and_the_pose_only_solve():
    z1 = {"he_rot": [1.0, 1.0], "he_mm": [1.0, 1.0], "b2b_rot": 1.0, "b2b_mm": 1.0, "scale": 1.0}
    rows = [_row("joint", 0.4, 3.0, 6.0, 0.8, z1), _row("pose-only", 1.0, 8.0, 12.0, 1.2), _row(be.PARK, 1.1, 7.0, 13.0, 0.0)]
    lines = be.targets(rows)
    assert sum("| PASS |" in x for x in lines) == 6 and not any("FAIL" in x for x in lines)
    z3 = {k: (3.0 if not isinstance(v, list) else [3.0, 3.0]) for k, v in z1.items()}
    rows = [_row("joint", 0.9, 9.0, 14.0, 1.5, z3), _row("pose-only", 1.0, 8.0, 12.0, 1.2), _row(be.PARK, 1.1, 7.0, 13.0, 0.0)]
    verdicts = {x.split(" | ")[0].lstrip("| "): x.rstrip(" |").rsplit("| ", 1)[1] for x in be.targets(rows) if x.startswith("| ")
                and "---" not in x and "target" not in x}
    assert verdicts["hand-eye rotation <= 0.8x Park"] == "FAIL"  # 0.9 > 0.8 x 1.1
    assert verdicts["hand-eye translation <= 1.0x Park"] == "FAIL"
    assert verdicts["scale within 1 %"] == "FAIL"
    assert verdicts["base-to-base within 1 deg / 10 mm"] == "FAIL"
    assert verdicts["never worse: within 1.1x of pose-only (hand-eye, base-to-base)"] == "FAIL"  # 14 > 1.1 x 12 mm
    assert verdicts["uncertainty honest: RMS(error/sigma) over all outputs in [0.7, 1.4]"] == "FAIL"


def test_the_report_gives_the_tail_and_the_counts_and_no_targets_without_fm_rows():
    z1 = {"he_rot": [1.0, 1.0], "he_mm": [1.0, 1.0], "b2b_rot": 1.0, "b2b_mm": 1.0, "scale": 1.0}
    rows = [{**_row("joint", 0.4, 3.0, b2b, 0.8, z1), "noise": "emulator", "seed": s}
            for s, b2b in zip(range(10), [1.0] * 9 + [50.0])]
    assert be.targets(rows) == []  # issue 21's targets are judged on fm maps only
    text = be.report(rows, list(range(10)), "cmd", views=4, objects=6)
    assert "(4 views per arm, 6 objects" in text
    line = next(x for x in text.splitlines() if x.startswith("| emulator | joint |"))
    assert "| 5.90 | 5.9 / 50.0 |" in line  # the mean, then the 90th percentile and the worst
    assert "Targets" not in text

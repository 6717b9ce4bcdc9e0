"""The task bench's pieces: Wilson intervals, the sets and their targets, the oracle's segments."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench import tasks as bench_tasks
from bench._stats import format_rate, wilson_interval
from bench._truth import MIN_OBJECT_POINTS, oracle_segments, truth_cloud, write_oracle_inputs


@pytest.mark.parametrize("k, n, low, high", [
    (13, 20, 0.43285, 0.81881),  # issue 22: "65 % (95 % interval 43-82 %)"
    (12, 20, 0.38658, 0.78119),  # "60 % (39-78 %)"
    (18, 20, 0.69897, 0.97213),  # "18/20 has a 95 % interval of about 70-97 %"
    (0, 10, 0.0, 0.27753),       # the textbook value for no success in 10
    (10, 10, 0.72247, 1.0),
    (45, 50, 0.78640, 0.95652),  # 90 % on 50 scenes: lower end under 80 %
])
def test_wilson_interval_known_values(k, n, low, high):
    lo, hi = wilson_interval(k, n)
    assert lo == pytest.approx(low, abs=1e-4) and hi == pytest.approx(high, abs=1e-4)
    # the closed form (Wilson 1927) gives the same
    z = 1.959963984540054
    p = k / n
    c = (p + z * z / (2 * n)) / (1 + z * z / n)
    h = z / (1 + z * z / n) * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    assert lo == pytest.approx(c - h, abs=1e-9) and hi == pytest.approx(c + h, abs=1e-9)


def test_wilson_interval_edges():
    assert wilson_interval(0, 0) == (0.0, 1.0)
    with pytest.raises(ValueError):
        wilson_interval(3, 2)
    assert format_rate(13, 20) == "13/20 = 65 % (43-82 %)"


def test_sets_are_disjoint_and_the_heldout_set_is_fresh():
    held, tune = set(bench_tasks.HELDOUT_SEEDS), set(bench_tasks.TUNING_SEEDS)
    assert len(held) >= 50 and tune == set(range(20))
    assert not held & tune and not held & set(bench_tasks.STUDIED_SEEDS)  # studied ranges are tuning data now
    assert bench_tasks.set_of(20003) == "heldout" and bench_tasks.set_of(4) == "tuning"
    assert all(bench_tasks.set_of(s) == "other" for s in (1005, 7003, 9003, 12003, 14003, 15003, 16003, 17003, 18003,
                                                          19003))


def test_choose_full_run_and_subsets():
    seeds, modes, tasks, full = bench_tasks.choose(bench_tasks.parse_args([]))
    assert full and len(seeds) == 70 and modes == ["pipeline", "gt", "oracle"] and tasks == list(bench_tasks.TASKS)
    seeds, modes, tasks, full = bench_tasks.choose(bench_tasks.parse_args(
        ["--seeds", "7000", "--tasks", "joint-grasp", "--modes", "pipeline,oracle"]))
    assert not full and seeds == [7000] and modes == ["pipeline", "oracle"] and tasks == ["joint-grasp"]
    seeds, _, _, full = bench_tasks.choose(bench_tasks.parse_args(["--set", "heldout", "--quick"]))
    assert not full and seeds == [20000, 20001, 20002]
    with pytest.raises(SystemExit):
        bench_tasks.choose(bench_tasks.parse_args(["--modes", "pipline"]))
    _, _, _, full = bench_tasks.choose(bench_tasks.parse_args(["--views", "6"]))
    assert not full  # other counts never rewrite the docs' table


def test_leave_out_runs_never_rewrite_the_table_and_name_known_fallbacks():
    """``--leave-out`` (what a planner fallback buys): its runs are not the full run, and an unknown name is
    refused with the known ones."""
    args = bench_tasks.parse_args(["--leave-out", "make-way,skip-home"])
    assert bench_tasks.leave_out_names(args) == ("make-way", "skip-home") and not bench_tasks.choose(args)[3]
    with pytest.raises(SystemExit, match="unknown fallback.*make_way.*fix: names from lower-joint-lift"):
        bench_tasks.choose(bench_tasks.parse_args(["--leave-out", "make_way"]))


def test_fallback_rows_count_the_plans_that_took_each_fallback():
    res = _results({"pipeline": [True, False, True]})
    res[0]["rows"]["pipeline"]["joint-grasp"]["fallbacks"] = ["lower-joint-lift"]
    res[1]["rows"]["pipeline"]["joint-grasp"]["fallbacks"] = ["lower-joint-lift"]
    text = "\n".join(bench_tasks.fallback_rows(res, ["pipeline"], ["joint-grasp"]))
    assert "| joint-grasp | pipeline (calibrated) | lower-joint-lift | 2 | 1 |" in text
    assert "no plan took one" in bench_tasks.fallback_rows(_results({"pipeline": [True]}), ["pipeline"],
                                                           ["joint-grasp"])[0]


def test_scenes_of_other_counts_get_their_own_folders():
    assert bench_tasks.scene_name(18000) == "synth_18000"
    assert bench_tasks.scene_name(18000, views=6, objects=7) == "synth_18000_v6_o7"
    assert bench_tasks.scene_name(18000, views=8, objects=7) != bench_tasks.scene_name(18000)


def test_another_cpus_blas_kernels_run_beside_the_default_stage_outputs():
    """``--blas-kernel``: the workers get OPENBLAS_CORETYPE, the stage outputs their own folders (the scenes
    stay shared), the run never rewrites the docs, and a core OpenBLAS does not know is refused."""
    args = bench_tasks.parse_args(["--set", "heldout", "--blas-kernel", "SkylakeX"])
    _, modes, _, full = bench_tasks.choose(args)
    assert not full
    assert bench_tasks.stage_folders(modes, "SkylakeX")["pipeline"] == "pipeline-blas-SkylakeX"
    assert bench_tasks.stage_folders(modes, None) == {m: m for m in modes}
    assert bench_tasks.blas_env("SkylakeX") == {"OPENBLAS_CORETYPE": "SkylakeX"} and bench_tasks.blas_env(None) == {}
    assert bench_tasks.blas_core("Sandybridge") == "Sandybridge"
    with pytest.raises(ValueError, match="does not know"):
        bench_tasks.blas_core("NoSuchCore")


def _results(outcomes: dict[str, list[bool]]) -> list[dict]:
    """Fake scene results: mode -> success per scene (joint grasp only)."""
    n = len(next(iter(outcomes.values())))
    return [{"seed": 7000 + i, "scene": f"synth_{7000 + i}", "stage_t": {}, "synth_s": 0.0, "wall": 1.0,
             "rows": {m: {"joint-grasp": {"truth_ok": ok[i], "planned": True, "estimate_ok": ok[i],
                                          "stage": "" if ok[i] else "reach", "reason": "", "scene": f"synth_{7000 + i}"}}
                      for m, ok in outcomes.items()}} for i in range(n)]


def test_targets_need_the_rate_and_the_lower_end_of_its_interval():
    modes, tasks = ["pipeline", "gt", "oracle"], ["joint-grasp"]
    # 46/50 = 92 % (lower end 81 %): pass; the oracle fails scene 0 (out of reach), the pipeline fails 0-3
    pipe = [i >= 4 for i in range(50)]
    rows = bench_tasks.target_rows(_results({"pipeline": pipe, "gt": [i >= 2 for i in range(50)],
                                             "oracle": [i >= 1 for i in range(50)]}), modes, tasks)
    text = "\n".join(rows)
    assert "| 46/50 = 92 % (81-97 %) | PASS |" in text
    assert "92 % vs 96 % (-4 points) | PASS |" in text  # within 5 points of the ground-truth transforms
    assert "| 46/49 = 94 % (83-98 %) | FAIL |" in text  # among the 49 oracle-solved: under 97 %
    # 45/50 = 90 % meets the rate but not the lower end (79 % < 80 %); 7 points under gt
    rows = bench_tasks.target_rows(_results({"pipeline": [i >= 5 for i in range(50)], "gt": [True] * 49 + [False],
                                             "oracle": [True] * 50}), modes, tasks)
    text = "\n".join(rows)
    assert "| 45/50 = 90 % (79-96 %) | FAIL |" in text and "(-8 points) | FAIL |" in text


def test_a_plan_that_fails_its_own_preview_is_no_success_even_where_it_would_hold():
    planned = {"plans": {"primary": []}, "failed_stage": "preview"}
    rejected = bench_tasks.outcome({**planned, "preview": {"success": False, "reason": "not held by secondary"},
                                    "preview_truth": {"success": True, "reason": "held"}})
    assert rejected["reality_ok"] and not rejected["truth_ok"]
    assert rejected["stage"] == "preview" and rejected["reason"].startswith("not approved")
    assert "not held by secondary" in rejected["reason"]
    approved = bench_tasks.outcome({"plans": {"primary": []}, "preview": {"success": True},
                                    "preview_truth": {"success": True, "reason": "held"}})
    assert approved["truth_ok"] and approved["stage"] == ""
    wrong = bench_tasks.outcome({"plans": {"primary": []}, "preview": {"success": True},
                                 "preview_truth": {"success": False, "reason": "dropped"}})
    assert not wrong["truth_ok"] and wrong["reason"] == "dropped"
    unplanned = bench_tasks.outcome({"failed_stage": "grasp", "reason": "no object has a feasible hand-over"})
    assert not unplanned["planned"] and unplanned["stage"] == "grasp" and "feasible" in unplanned["reason"]


def test_set_table_reports_among_oracle_solved():
    res = _results({"pipeline": [True, False, True, False], "oracle": [True, True, False, False]})
    text = "\n".join(bench_tasks.set_table(res, ["pipeline", "oracle"], ["joint-grasp"]))
    assert "| 2/4 = 50 % (15-85 %) | 1/2 = 50 % (9-91 %) |" in text
    assert "| reach 2 |" in text


def test_oracle_segments_relabel_true_objects_largest_first():
    rng = np.random.default_rng(0)
    T_b1_t = np.eye(4)
    T_b1_t[:3, 3] = [0.3, 0.0, 0.01]
    table = np.c_[rng.uniform(0, 0.6, (2000, 2)), np.full(2000, 0.01)]
    small = rng.uniform([0.2, 0.1, 0.01], [0.25, 0.15, 0.06], (120, 3))   # true id 5
    large = rng.uniform([0.4, -0.2, 0.01], [0.55, -0.1, 0.09], (400, 3))  # true id 2
    speck = rng.uniform([0.1, -0.1, 0.01], [0.11, -0.09, 0.02], (MIN_OBJECT_POINTS - 1, 3))  # true id 7
    pts = np.r_[table, small, large, speck]
    ids = np.r_[np.full(2000, -1), np.full(120, 5), np.full(400, 2), np.full(MIN_OBJECT_POINTS - 1, 7)]
    res = oracle_segments(pts, ids, T_b1_t, [1.2, 0.8])
    assert res.labels.dtype == np.int32 and res.labels.shape == (len(pts),)
    assert np.all(res.labels[ids == 2] == 0) and np.all(res.labels[ids == 5] == 1)
    assert np.all(res.labels[(ids == -1) | (ids == 7)] == -1)
    assert res.stats["truth_ids"] == [2, 5] and res.stats["left_as_background"] == [7]
    assert np.allclose(res.table.coefficients, [0, 0, 1, -0.01])
    assert [o.points for o in res.objects] == [400, 120]
    assert res.objects[0].extents[2] == pytest.approx(0.08, abs=0.005)  # from the table up to its top
    with pytest.raises(ValueError):
        oracle_segments(pts, ids[:-1], T_b1_t, [1.2, 0.8])


def test_write_oracle_inputs_on_a_synthetic_scene(synth_none, tmp_path):
    from bimanual_app.scene import load_scene
    from segmentation import read_cloud

    work = tmp_path / "oracle"
    assert write_oracle_inputs(synth_none, work) > 0
    pts, _, _ = read_cloud(work / "calibration" / "scene_b1.ply")
    with np.load(work / "segments" / "segments.npz") as z:
        labels, plane = z["labels"], z["table_plane"]
    meta = json.loads((work / "segments" / "segments.json").read_text())
    cal = json.loads((work / "calibration" / "calibration.json").read_text())
    gt = load_scene(synth_none).ground_truth
    assert cal["scene"] == load_scene(synth_none).name
    assert np.allclose(cal["T_b1_b2"], gt.T_b1_b2)
    from bimanual_app.views import load_views

    assert len(load_views(work / "calibration" / "views.npz")) == 6  # the true depth views, as calibrate writes
    true_pts, _, true_ids = truth_cloud(synth_none)
    assert labels.shape == (len(pts),) and np.allclose(pts, true_pts, atol=1e-6)  # same points, same order
    truth = meta["stats"]["truth_ids"]
    assert sorted(truth) == sorted(int(i) for i, c in zip(*np.unique(true_ids[true_ids >= 0], return_counts=True))
                                   if c >= MIN_OBJECT_POINTS)
    objects = {int(o["id"]): o for o in gt.objects}
    for label, tid in enumerate(truth):
        assert np.array_equal(labels == label, true_ids == tid)
        # each segment's points lie around its true object
        centre = np.asarray(objects[tid]["T_b1_o"])[:3, 3]
        size = np.asarray(objects[tid]["size"])
        assert np.linalg.norm(pts[labels == label].mean(0)[:2] - centre[:2]) < size.max()
    T_b1_t = np.asarray(gt.extras["table"]["T_b1_t"])
    assert np.allclose(plane[:3], T_b1_t[:3, 2]) and abs(plane[:3] @ T_b1_t[:3, 3] + plane[3]) < 1e-9
    assert write_oracle_inputs(synth_none, work) == 0.0  # reused


def test_two_runs_paired_scene_by_scene_from_their_progress_lines():
    """tools/pair_task_runs.py reads the lines ``scene_line`` prints and says what a change gained and lost."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "tools" / "pair_task_runs.py"
    spec = importlib.util.spec_from_file_location("pair_task_runs", path)
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)

    def line(i, seed, outcomes):  # outcomes: mode -> task -> stage ("" = success)
        rows = {m: {t: {"truth_ok": not st, "stage": st} for t, st in by.items()} for m, by in outcomes.items()}
        res = {"seed": seed, "scene": f"synth_{seed:03d}", "rows": rows, "wall": 12.0}
        return "[bench tasks] " + bench_tasks.scene_line(i, 3, res)

    before = [line(1, 15000, {"pipeline": {"joint-grasp": "", "handover": "grasp"}}),
              "some other output",
              line(2, 15001, {"pipeline": {"joint-grasp": "reach", "handover": ""}}),
              line(3, 5, {"pipeline": {"joint-grasp": "", "handover": ""}})]
    after = [line(1, 15001, {"pipeline": {"joint-grasp": "", "handover": "preview"}}),
             line(2, 15000, {"pipeline": {"joint-grasp": "", "handover": ""}})]
    rows = {(r["mode"], r["task"]): r for r in tool.pair(tool.parse_lines(before), tool.parse_lines(after))}
    assert set(rows) == {("pipeline", "joint-grasp"), ("pipeline", "handover")}  # seed 5: before only
    jg, ho = rows[("pipeline", "joint-grasp")], rows[("pipeline", "handover")]
    assert (jg["n"], jg["ok_before"], jg["ok_after"], jg["gained"], jg["lost"]) == (2, 1, 2, [15001], [])
    assert (ho["ok_before"], ho["ok_after"], ho["gained"], ho["lost"]) == (1, 1, [15000], [(15001, "FAIL[preview]")])
    assert tool.main(["only-one.log"]) == 2
    other = {"seed": 18200, "scene": bench_tasks.scene_name(18200, 5, 7), "wall": 3.0,
             "rows": {"pipeline": {"handover": {"truth_ok": True, "stage": ""}}}}
    assert tool.parse_lines(["[bench tasks] " + bench_tasks.scene_line(1, 1, other)]) == {
        ("pipeline", "handover", 18200): "OK"}  # a scene of other counts


def test_leave_out_takes_the_hand_over_searchs_fallbacks_too():
    args = bench_tasks.parse_args(["--leave-out", "shallow-holds,handover-redraws"])
    assert bench_tasks.leave_out_names(args) == ("shallow-holds", "handover-redraws")


def test_failed_previews_say_where_the_object_was_lost():
    def track(*held):  # the arms holding the object after each phase
        return [{"phase": p, "rise_m": 0.0, "held_by": h, "touched_by": h, "on_table": True}
                for p, h in zip(("grasp", "lift", "transfer"), held)]

    dropped = {"plans": {"primary": []}, "preview": {"success": True, "object_track": track(["primary"] * 3)},
               "preview_truth": {"success": False, "object_track": track(["primary"], [], [])}}
    assert bench_tasks.outcome(dropped)["lost"] == "reality: after lift"
    refused = {"plans": {"primary": []}, "preview": {"success": False, "object_track": track([], [], [])},
               "preview_truth": {"success": False, "object_track": track([], [], [])}}
    assert bench_tasks.outcome(refused)["lost"] == "reconstruction: never held"
    assert bench_tasks.outcome({"failed_stage": "grasp", "reason": "none"})["lost"] == ""
    res = _results({"pipeline": [False, False, True]})
    for r, where in zip(res, ("reality: after lift", "reality: after lift", "")):
        r["rows"]["pipeline"]["joint-grasp"]["lost"] = where
    text = "\n".join(bench_tasks.lost_rows(res, ["pipeline"], ["joint-grasp"]))
    assert "| joint-grasp | pipeline (calibrated) | reality: after lift | 2 |" in text
    assert "none lost" in bench_tasks.lost_rows(_results({"pipeline": [True]}), ["pipeline"], ["joint-grasp"])[0]

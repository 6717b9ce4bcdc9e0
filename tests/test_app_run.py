"""`bijcr run`: stages in order, cached outputs reused, a failing stage named, and a self-contained report."""

import base64
import json
import re
import shutil
import subprocess
from functools import partial

import pytest

from bimanual_app.app import stages as S
from bimanual_app.app.pipeline import Stage, fingerprint, run_stages
from bimanual_app.cli import main as bijcr
from bimanual_app.synth import make_synthetic_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return make_synthetic_scene(tmp_path_factory.mktemp("run") / "scene", seed=4, views=5, objects=2,
                                noise="low", render=True, pointmap_size=(80, 60), progress=False)


def test_run_calibrates_segments_and_reports_then_reuses_cache(scene, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["run", str(scene), "--out", str(out), "--skip", "grasp", "--skip", "joint-grasp", "--skip", "handover"]
    assert bijcr(argv) == 0
    err = capsys.readouterr().err
    assert "calibrate: ran" in err and "segment: ran" in err
    assert (out / "calibration" / "calibration.json").exists() and (out / "segments" / "segments.npz").exists()
    page = (out / "report.html").read_text()
    # every picture is embedded (self-contained) and decodes as a PNG
    imgs = re.findall(r'src="data:image/png;base64,([^"]+)"', page)
    assert len(imgs) >= 3  # capture preview, calibration figure, segments figure
    assert all(base64.b64decode(b)[:8] == b"\x89PNG\r\n\x1a\n" for b in imgs)
    assert "T_e1_c1" in page and "uncertainty" in page and "scale" in page
    # the point-map refinement's verdict, and its figure when it ran
    cal = json.loads((out / "calibration" / "calibration.json").read_text())
    pm = cal["info"]["point_maps"]
    what = "Joint estimate (kinematic loop + point maps)" if pm.get("estimator") else "Point-map refinement"
    assert (f"{what} applied" if pm["accepted"] else f"{what} not applied") in page
    assert (out / "calibration" / "point_maps.png").exists() == ("Distances between overlapping views" in page)
    # the segments table reads segments.json: every object's box has numbers
    seg = json.loads((out / "segments" / "segments.json").read_text())
    for o in seg["objects"]:
        ext = " x ".join(f"{100 * x:.1f}" for x in o["obb"]["extents"])
        assert f"<td>{o['id']}</td><td>{o['points']}</td>" in page and ext in page
    assert "nan" not in page.split("Metric scene")[-1].split("</table>")[0]
    # second run: nothing changed, both stages reused
    assert bijcr(argv) == 0
    err = capsys.readouterr().err
    assert "calibrate: cached" in err and "segment: cached" in err


def test_changed_input_reruns_the_stage(tmp_path):
    src = tmp_path / "in.txt"
    src.write_text("a")
    assert fingerprint([src], ["x"]) != fingerprint([src], ["y"])
    before = fingerprint([src], ["x"])
    src.write_text("b")
    assert fingerprint([src], ["x"]) != before


def test_other_code_reruns_the_stage(tmp_path, monkeypatch):
    """A result made by other code (an update of the product, a local change) is not reused."""
    from bimanual_app.app import pipeline

    src = tmp_path / "in.txt"
    src.write_text("a")
    out = tmp_path / "out.txt"
    runs = []

    def stage():
        return Stage("s", lambda log: (runs.append(1), out.write_text("done")), [src], [out])

    run_stages([stage()], tmp_path / ".stages")
    run_stages([stage()], tmp_path / ".stages")
    assert len(runs) == 1  # same inputs, same code: reused
    fp = pipeline.code_fingerprint()
    assert len(fp) == 64 and int(fp, 16) >= 0
    monkeypatch.setattr(pipeline, "code_fingerprint", lambda: "other code")
    run_stages([stage()], tmp_path / ".stages")
    assert len(runs) == 2


def test_failing_stage_is_named_and_earlier_results_kept(scene, tmp_path):
    broken = tmp_path / "broken"
    shutil.copytree(scene, broken)
    (broken / "reconstruction.npz").unlink()
    shutil.rmtree(broken / "primary" / "images")  # neither images nor a reconstruction: calibrate cannot run
    out = tmp_path / "out"
    cal = out / "calibration"
    stages = [Stage("check", lambda log: log("checked"), [], []),
              Stage("calibrate", partial(S.calibrate, broken, cal), [], [cal / "calibration.json"]),
              Stage("segment", partial(S.segment, cal / "scene_b1.ply", out / "seg", cal / "calibration.json", None),
                    [], [])]
    records = run_stages(stages, out / ".stages")
    assert [r.status for r in records] == ["ran", "failed", "skipped"]
    assert "reconstruction.npz" in records[1].message and "bijcr reconstruct" in records[1].message
    assert records[1].message in records[1].log and records[0].log == "checked"
    assert not (cal / "calibration.json").exists()


def test_ctrl_c_in_a_task_stops_the_whole_run(scene, tmp_path, monkeypatch, capsys):
    """Ctrl-C during a task stage ends `bijcr run` at once with exit code 130: the next task does not start,
    no report claims a finished run, the finished stages keep their results and records, and the
    interrupted stage leaves no result or record."""
    import bimanual_app.tasks as tasks

    started = []

    def interrupted(opts):
        started.append(opts.task)
        raise KeyboardInterrupt

    # patched where the run looks it up: the package's lazy export (kept on the package once first read), so
    # that the package does not keep the patched function for the tests after this one
    monkeypatch.setattr(tasks, "run_task", interrupted)
    out = tmp_path / "out"
    out.mkdir()
    (out / "report.html").write_text("an earlier run's report")  # no longer describes what is in OUT
    rc = bijcr(["run", str(scene), "--out", str(out), "--skip", "grasp"])
    assert rc == 130 and started == ["joint-grasp"]
    assert "interrupted" in capsys.readouterr().err
    assert not (out / "report.html").exists()
    assert (out / ".stages" / "calibrate.json").exists() and (out / ".stages" / "segment.json").exists()
    assert (out / "calibration" / "calibration.json").exists() and (out / "segments" / "segments.npz").exists()
    assert not (out / ".stages" / "joint-grasp.json").exists() and not (out / "tasks").exists()


_PROBE = """<script>
window.addEventListener('load', () => {
  const imgs = [...document.images];
  const bad = imgs.filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.alt || i.src.slice(0, 40));
  const vids = [...document.querySelectorAll('video')];
  const gifs = imgs.filter(i => i.src.startsWith('data:image/gif') && i.complete && i.naturalWidth > 0).length;
  document.body.setAttribute('data-probe', JSON.stringify({images: imgs.length, broken: bad, videos: vids.length,
                                                           gifs: gifs}));
});
</script>"""


def test_report_renders_in_headless_chromium(scene, tmp_path):
    """Open report.html in Debian's chromium (installed by `make test`) and check every figure and the
    preview animation load."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    assert chromium, "chromium is missing: `make test` installs it (tools/setup_test_deps.sh)"
    out = tmp_path / "out"
    # a real hand-over preview (the small task fixture: a few seconds) where the report looks for it, so the
    # page carries an animation as well as the figures
    from bimanual_app.robots import load_robot
    from tests._task_fixtures import make_task_workdir

    fx_scene, fx_work = make_task_workdir(tmp_path / "fx", load_robot("piper"))
    assert bijcr(["task", "handover", str(fx_scene), "--work", str(fx_work), "--out", str(out / "tasks" / "handover"),
                  "--frame-size", "160x120", "--quiet"]) == 0
    assert bijcr(["run", str(scene), "--out", str(out), "--skip", "grasp", "--skip", "joint-grasp",
                  "--skip", "handover"]) == 0
    page = (out / "report.html").read_text()
    assert page.count('src="data:image/gif;base64,') == 1  # the preview animation, embedded
    probe = tmp_path / "probe.html"
    probe.write_text(page.replace("</body>", _PROBE + "</body>"))
    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             f"--user-data-dir={tmp_path / 'profile'}", "--virtual-time-budget=5000"]
    dom = subprocess.run([chromium, *flags, "--dump-dom", probe.as_uri()], capture_output=True, text=True,
                         timeout=120).stdout
    m = re.search(r"data-probe=\"([^\"]*)\"", dom)
    assert m, "the page did not finish loading in chromium"
    result = json.loads(m.group(1).replace("&quot;", '"'))
    assert result["images"] >= 4 and result["broken"] == []  # figures and the animation all decoded
    assert result["gifs"] == 1
    shot = tmp_path / "report.png"
    subprocess.run([chromium, *flags, "--window-size=1200,2000", f"--screenshot={shot}", (out / "report.html").as_uri()],
                   capture_output=True, timeout=120)
    assert shot.exists() and shot.read_bytes()[:4] == b"\x89PNG"


def test_report_grasps_table_reads_grasps_json(tmp_path):
    from bimanual_app.app.report import _grasps_section

    g = {"objects": [
        {"id": 0, "mode": "joint", "grasps": [], "joint_grasps": [{"score": 0.8}, {"score": 0.6}], "handover": None,
         "problems": ["x.npz [object 0]: object is 113 mm across -> fix: lift it with both arms"]},
        {"id": 1, "mode": "single", "grasps": [{"score": 0.5}, {"score": 0.9}], "joint_grasps": [],
         "handover": {"score": 0.7, "T_move": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}}]}
    (tmp_path / "grasps.json").write_text(json.dumps(g))
    html = _grasps_section(tmp_path)
    assert "<td>0</td><td>joint</td><td>none</td><td>2 (0.80)</td><td>no</td><td>object is 113 mm across</td>" in html
    assert "<td>1</td><td>single</td><td>2 (0.90)</td><td>none</td><td>yes (0.70)</td>" in html


def test_report_says_what_the_task_used_tried_and_lacks(tmp_path):
    """The task section names the alternative hand-over it used, lists the failed previews before the one that
    passed with their reasons, shows the ground-truth evaluation; absent masks / ground truth are said."""
    from types import SimpleNamespace

    import numpy as np

    from bimanual_app.app.report import write_report

    eye = np.eye(4).tolist()
    (tmp_path / "calibration").mkdir()
    (tmp_path / "calibration" / "calibration.json").write_text(json.dumps(
        {"T_e1_c1": eye, "T_e2_c2": eye, "T_b1_b2": eye, "scale": 1.0, "uncertainty": {}}))
    (tmp_path / "segments").mkdir()
    (tmp_path / "segments" / "segments.json").write_text(json.dumps({"objects": []}))
    d = tmp_path / "tasks" / "handover"
    d.mkdir(parents=True)
    (d / "task.json").write_text(json.dumps({
        "success": True, "reason": "preview passed: held", "object": 3,
        "object_reason": "object 3 has the best-scoring hand-over (score 0.64; the only candidate)",
        "plan": {"info": {"candidate": {"grasps_json": "objects[3].handover_alternatives[1]", "score": 0.64}}},
        "previews_tried": [{"object": 3, "candidate_rank": 0, "success": False, "reason": "the object fell"},
                           {"object": 3, "candidate_rank": 1, "success": True, "reason": "held"}]}))
    T = np.eye(4)
    T[0, 3] = 0.002
    gt = SimpleNamespace(T_e1_c1=T, T_e2_c2=np.eye(4), T_b1_b2=np.eye(4), scale=1.0)
    with_gt = SimpleNamespace(path=tmp_path / "scene", ground_truth=gt, reconstruction=SimpleNamespace(model="synthetic"))
    page = write_report(tmp_path, "s", [], [], scene=with_gt).read_text()
    assert "objects[3].handover_alternatives[1]" in page and "an alternative" in page
    assert "the object fell" in page and "failed" in page
    assert "Against ground_truth.yaml" in page and "<td>T_e1_c1</td><td>0.000°</td><td>2.00 mm</td>" in page
    assert "Per-image masks: absent" in page
    assert "(score 0.64; the only candidate)</p>" in page and "candidate))" not in page
    bare = SimpleNamespace(path=tmp_path / "scene", ground_truth=None, reconstruction=None)
    page = write_report(tmp_path, "s", [], [], scene=bare).read_text()
    assert "Ground truth: absent" in page


def test_object_reason_has_balanced_parentheses():
    """The free-form hand-over reason closed a parenthesis it never opened."""
    from types import SimpleNamespace

    from bimanual_app.tasks._grasps import choose

    c = lambda oid, score, free: SimpleNamespace(object_id=oid, score=score,  # noqa: E731
                                                 info={"free_form": free, "shape": "free-form" if free else "box"})
    _, why = choose([c(1, 0.5, False), c(2, 0.9, True)], None, "handover", "g.json", [1, 2])
    assert why.count("(") == why.count(")"), why

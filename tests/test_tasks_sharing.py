"""Two tasks in one process (as `bijcr run` runs them) share one scene map: the second builds none of its
own, cuts its object out of the shared one, and plans exactly what it plans alone in a fresh process."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bimanual_app.robots import load_robot
from tests._task_fixtures import make_task_workdir

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def fixture_dirs(tmp_path_factory):
    return make_task_workdir(tmp_path_factory.mktemp("tasksharing"), load_robot("piper"))


def _args(task, scene, work, out):
    return ["task", task, str(scene), "--work", str(work), "--out", str(out), "--no-record", "--quiet"]


def _plan(out) -> dict:
    with np.load(out / "plan.npz") as z:
        return {k: z[k] for k in z.files}


def test_second_task_reuses_the_map_and_plans_as_a_fresh_process(fixture_dirs, tmp_path, monkeypatch):
    import bimanual_app.collision._scene_map as sm
    from bimanual_app.cli import main
    from bimanual_app.collision import clear_shared_maps

    monkeypatch.setenv("BIJCR_APPROVAL_KEY", "test-key")
    scene, work = fixture_dirs
    alone = tmp_path / "alone"
    code = f"from bimanual_app.cli import main; raise SystemExit(main({_args('joint-grasp', scene, work, alone)!r}))"
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=True, timeout=600)

    clear_shared_maps()
    built = []
    init = sm.SceneMap.__init__

    def counting_init(self, *a, **k):
        built.append(1)
        init(self, *a, **k)

    monkeypatch.setattr(sm.SceneMap, "__init__", counting_init)
    assert main(_args("handover", scene, work, tmp_path / "handover")) == 0
    assert len(built) == 1  # the task's map, once (the object is cut out of it without a rebuild)
    assert main(_args("joint-grasp", scene, work, tmp_path / "joint")) == 0
    assert len(built) == 1  # the second task built no map
    together, fresh = _plan(tmp_path / "joint"), _plan(alone)
    assert together.keys() == fresh.keys()
    for k in fresh:
        np.testing.assert_array_equal(together[k], fresh[k], err_msg=k)
    rec_t, rec_f = (json.loads((d / "task.json").read_text()) for d in (tmp_path / "joint", alone))
    assert rec_t["success"] and rec_f["success"]
    assert rec_t["approval"]["plan_sha256"] == rec_f["approval"]["plan_sha256"]
    assert rec_t["preview"]["checks"] == rec_f["preview"]["checks"]

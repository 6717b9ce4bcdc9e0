"""The bench's Ray fan-out: each job a Ray task in its own fresh worker process, results in order."""

from __future__ import annotations

import os

from bench._ray import SceneError, map_scenes


def _job(x: int) -> tuple[int, str | None, int]:
    if x < 0:
        raise RuntimeError(f"job {x} broke")
    return os.getpid(), os.environ.get("OMP_NUM_THREADS"), 10 * x


def test_map_scenes_runs_each_job_in_a_fresh_worker_in_order():
    seen = []
    out = map_scenes(_job, [1, 2, -1], num_cpus=1, return_exceptions=True,
                     progress=lambda done, total, i, res: seen.append((done, total, i)))
    (pid1, omp1, v1), (pid2, omp2, v2), err = out
    assert (v1, v2) == (10, 20)  # the jobs' order, whatever order they finished in
    assert pid1 != pid2 and os.getpid() not in (pid1, pid2)  # max_calls=1: one worker per job
    assert omp1 == omp2 == "1"
    assert isinstance(err, SceneError) and "job -1 broke" in str(err)
    assert [d for d, _, _ in seen] == [1, 2, 3] and sorted(i for _, _, i in seen) == [0, 1, 2]
    assert all(t == 3 for _, t, _ in seen)
    import ray

    assert not ray.is_initialized()  # the Ray it started is stopped again


def _where_grasping_comes_from(_) -> tuple[str, str]:
    import importlib.util
    import sys

    return sys.path[0], importlib.util.find_spec("grasping").origin


def test_the_workers_import_this_checkout_whatever_the_working_directory(tmp_path, monkeypatch):
    """Ray puts the driver's working directory and script folder first on a worker's path: from a folder
    holding a ``grasping`` module of its own, the workers still import the checkout's package."""
    from pathlib import Path

    from bench._ray import ROOT

    (tmp_path / "grasping.py").write_text("raise ImportError('the working directory shadowed the package')\n")
    monkeypatch.chdir(tmp_path)
    ((first, origin),) = map_scenes(_where_grasping_comes_from, [0], num_cpus=1)
    assert first == str(ROOT)
    assert Path(origin).resolve() == (ROOT / "grasping" / "__init__.py").resolve()

"""Sweeps over scenes on Ray: one task per scene, each in a fresh worker process.

``map_scenes(fn, jobs)`` runs ``fn(job)`` for every job as a Ray task and returns the results in the jobs'
order, calling ``progress`` as each one finishes. Ray is a bench/dev extra (``pip install .[bench]``);
nothing in ``bijcr`` imports it.

Why one process per scene: OMPL takes its random seed once per process, so a worker that planned other
scenes first would plan the next one from another point of its random sequence, and which scenes a worker
gets depends on timing (the table then changes from run to run). ``max_calls=1`` makes Ray retire a
worker after one task. ``OMP_NUM_THREADS=1`` in the workers' environment: the calibration's cloud differs in
its last digits with the number of OpenMP threads, and the scenes run side by side anyway.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
WORKER_ENV = {"OMP_NUM_THREADS": "1"}
OBJECT_STORE_BYTES = 200 * 1024 ** 2  # results are small dicts; do not reserve 30 % of the machine's memory


def _in_checkout(root: str, fn: Callable[[Any], Any]) -> Callable[[Any], Any]:
    """``fn`` run with the checkout ``root`` first on the worker's path (a closure: pickled by value).

    Ray starts each task with the driver's working directory and script folder ahead of PYTHONPATH: run from
    another folder, ``bench/grasping.py`` would stand in for the ``grasping`` package; run from another
    checkout (a trial worktree's bench started from the main one), that checkout's code would run."""

    def run(job):
        if sys.path[:1] != [root]:
            sys.path.insert(0, root)
        return fn(job)

    return run


class SceneError(RuntimeError):
    """A job whose task raised or whose worker died (returned in its place with ``return_exceptions``)."""


def _init(address: str | None, num_cpus: int | None, env: dict[str, str]) -> None:
    import ray

    # the project's root on the workers' path: the jobs' functions import the project's packages and
    # bench helpers (on a cluster given by --address, every node needs the checkout at the same path)
    path = os.pathsep.join([str(ROOT)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])
    runtime_env = {"env_vars": {**WORKER_ENV, "PYTHONPATH": path, **env}}
    common = dict(runtime_env=runtime_env, log_to_driver=False, logging_level="WARNING",
                  configure_logging=True)
    if address:
        ray.init(address=address, **common)
    else:
        ray.init(num_cpus=int(num_cpus or os.cpu_count() or 1), include_dashboard=False,
                 object_store_memory=OBJECT_STORE_BYTES, **common)


def map_scenes(fn: Callable[[Any], Any], jobs: Sequence[Any], address: str | None = None,
               num_cpus: int | None = None, progress: Callable[[int, int, int, Any], None] | None = None,
               env: dict[str, str] | None = None, return_exceptions: bool = False) -> list[Any]:
    """``[fn(job) for job in jobs]``, each call a Ray task in a fresh worker process.

    Args:
        fn: a picklable function of one job; its module is shipped by value (a bench script or test
            module is not importable on the workers).
        jobs: the jobs (picklable), e.g. one per scene.
        address: an existing Ray cluster to join (``ray.init(address=...)``, e.g. ``"auto"`` or
            ``"ray://head:10001"``); None starts Ray on this machine for the sweep and stops it after.
        num_cpus: CPUs of the local Ray instance (jobs run side by side, one CPU each); None: all cores.
            Ignored with ``address``: the cluster's CPUs decide.
        progress: called in the driver as each job finishes, ``progress(done, total, index, result)``.
        env: extra environment variables for the workers (beside ``OMP_NUM_THREADS=1``).
        return_exceptions: put a :class:`SceneError` in place of a failed job's result instead of raising
            (a long sweep keeps the other scenes).
    Returns:
        The results, in the order of ``jobs``.
    """
    import ray
    from ray import cloudpickle

    if not jobs:
        return []
    started = not ray.is_initialized()
    if started:
        _init(address, num_cpus, dict(env or {}))
    module = sys.modules.get(getattr(fn, "__module__", "") or "")
    by_value = module is not None and module.__name__ != "__main__"
    if by_value:
        cloudpickle.register_pickle_by_value(module)
    try:
        # max_calls=1: the worker exits after its task; max_retries=1: a worker killed from outside (out
        # of memory) is given one more try, a task that raises is not retried
        remote = ray.remote(max_calls=1, num_cpus=1, max_retries=1)(_in_checkout(str(ROOT), fn))
        index = {remote.remote(job): i for i, job in enumerate(jobs)}
        results: list[Any] = [None] * len(jobs)
        pending = list(index)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                i = index[ref]
                try:
                    results[i] = ray.get(ref)
                except ray.exceptions.RayError as e:  # the task raised, or its worker died
                    if not return_exceptions:
                        raise
                    results[i] = SceneError(f"job {i} failed: {str(e).strip().splitlines()[-1][:300]}")
                if progress is not None:
                    progress(len(jobs) - len(pending), len(jobs), i, results[i])
        return results
    finally:
        if by_value:
            cloudpickle.unregister_pickle_by_value(module)
        if started:
            ray.shutdown()

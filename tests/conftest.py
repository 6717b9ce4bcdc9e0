"""Test-wide settings: headless plotting, single-threaded numerics (CI has 2 cores), the session fixtures,
and how `make test` spreads the modules over its pytest-xdist workers."""

import os

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import matplotlib  # noqa: E402

matplotlib.use("Agg")

# registered here, not imported by each test module: an imported fixture is a new fixture of that module,
# built again in every module that imports it
from tests._synth_fixtures import synth_none, synth_outliers, synth_paper  # noqa: E402, F401

# `make test` runs `pytest -n auto --dist loadscope --no-loadscope-reorder`: the tests of one module go to one
# worker together (a module-scoped fixture is built once), and the longest modules are handed out first so that
# the workers finish together. Order only: every test runs whatever its module's place.
LONGEST_FIRST = ("test_examples", "test_tasks_cli", "test_calibration_pointmaps", "test_reconstruction_colmap",
                 "test_viewer", "test_app_run", "test_synth", "test_grasping_pairs", "test_reconstruction_agreement",
                 "test_bench_real", "test_calibration_joint", "test_tasks_units", "test_grasping_cli")


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.stem, len(rank)))  # stable: the order inside a module stays

"""The calibration stage's faster code paths give the same numbers and files as the plain ones (issue 24):
the numpy 3x3 min/max filter and NaN median, and figures drawn in a child process."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from bimanual_app.views import filter3
from calibration._figures import FigureWorker
from calibration._selfmask import _nanmedian0


def test_filter3_is_scipy_ndimage_min_max_filter():
    from scipy.ndimage import maximum_filter, minimum_filter

    rng = np.random.default_rng(0)
    Z = rng.normal(size=(4, 9, 13))
    Z[0, 3, 4] = np.inf
    Z[1, 0, 0] = -np.inf
    Z[2, 8, 12] = np.inf
    for ours, theirs, fn in ((np.minimum, minimum_filter, "min"), (np.maximum, maximum_filter, "max")):
        want = np.stack([theirs(z, size=3, mode="nearest") for z in Z])
        assert np.array_equal(filter3(Z, ours), want), fn


@pytest.mark.parametrize("views", [3, 4, 8])
def test_nanmedian0_is_numpys_nanmedian(views):
    rng = np.random.default_rng(views)
    a = rng.normal(size=(views, 30, 40, 3))
    a[rng.random(a.shape) < 0.35] = np.nan
    a[:, 0, 0] = np.nan  # a pixel empty in every view
    a[:, 1, 1] = 2.5  # ties
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        want = np.nanmedian(a, axis=0)
    assert np.array_equal(_nanmedian0(a), want, equal_nan=True)


def _figure_args():
    rng = np.random.default_rng(1)
    return rng.normal(scale=1e-3, size=500), rng.normal(scale=5e-4, size=500), {
        "accepted": True, "rounds": [{"radius_m": 0.03, "rms_m": 0.002}, {"radius_m": 0.01, "rms_m": 0.001}]}


@pytest.fixture
def single_threaded(monkeypatch):
    """The fork guard as in a single-threaded command (pytest-xdist workers run a thread of their own)."""
    from calibration import _figures

    monkeypatch.setattr(_figures.threading, "active_count", lambda: 1)


def test_no_child_while_other_threads_run():
    import threading

    stop = threading.Event()
    t = threading.Thread(target=stop.wait)
    t.start()
    try:
        worker = FigureWorker()
        assert worker._proc is None, "a process with other threads must not fork"
        worker.finish()
    finally:
        stop.set()
        t.join()


def test_figures_drawn_in_the_child_are_the_same_files(tmp_path, single_threaded):
    before, after, report = _figure_args()
    with FigureWorker(parallel=False) as inline:
        inline.draw("save_point_map_figure", tmp_path / "inline.png", before, after, report, title="t")
    with FigureWorker() as child:
        assert child._proc is not None
        child.draw("save_point_map_figure", tmp_path / "child.png", before, after, report, title="t")
        child.finish()
        assert (tmp_path / "child.png").is_file(), "finish() returns once the file is written"
    assert (tmp_path / "child.png").read_bytes() == (tmp_path / "inline.png").read_bytes()


def test_a_figure_that_fails_in_the_child_raises_in_finish(tmp_path, single_threaded):
    before, after, report = _figure_args()
    (tmp_path / "a_file").write_text("not a folder")
    worker = FigureWorker()
    assert worker._proc is not None
    worker.draw("save_point_map_figure", tmp_path / "a_file" / "x.png", before, after, report)
    with pytest.raises(RuntimeError, match="drawing a calibration figure failed"):
        worker.finish()
    worker.finish()  # finished: nothing left to wait for

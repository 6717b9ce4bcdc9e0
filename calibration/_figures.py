"""The calibration's figures drawn in a child process, beside the solve.

Importing matplotlib and drawing the two figures costs about as much CPU as the joint estimate itself,
and none of it depends on the solve until the very end. A forked child imports matplotlib while the parent
solves, then draws each figure as soon as the parent sends its data (the point-map figure while the parent
builds the cloud, the calibration figure while it writes the JSON, PLY and ROS files): on a machine with a
second core that time leaves the command's wall time. :meth:`FigureWorker.finish` waits for every figure,
so the files are complete when the stage returns; a figure that failed raises there, with the child's
traceback. Where ``fork`` is not available, or the process runs other threads (a Ray worker, a GUI: a
forked child gets only the calling thread, and a lock another thread held at the fork would never be
released in it), the figures are drawn in the calling process, as before.

The child draws with the same functions (``_plot``), so the PNG files are the same bytes either way.
"""

from __future__ import annotations

import multiprocessing
import threading
import traceback

__all__ = ["FigureWorker"]

FIGURE_TIMEOUT_S = 120.0  # a figure takes about a second: a child silent this long is stuck


def _serve(conn) -> None:
    """The child: import the plotting stack, then draw each ``(function name, args, kwargs)`` job received
    until ``None``; answers ``None`` per job done or the traceback of one that failed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot  # noqa: F401  (the import is the slow part: done while the parent solves)
    import mpl_toolkits.mplot3d  # noqa: F401

    from . import _plot

    while (job := conn.recv()) is not None:
        name, args, kwargs = job
        try:
            getattr(_plot, name)(*args, **kwargs)
            conn.send(None)
        except Exception:  # reported to the parent, which raises it
            conn.send(traceback.format_exc())
    conn.close()


def _fork_is_safe() -> bool:
    """``fork`` exists and this process runs no other thread (module docstring)."""
    return "fork" in multiprocessing.get_all_start_methods() and threading.active_count() == 1


class FigureWorker:
    """Draws ``_plot`` figures in a forked child (module docstring). Use :meth:`draw` for each figure, then
    :meth:`finish` (always: it also ends the child), or the object as a context manager."""

    def __init__(self, parallel: bool = True):
        self._conn = self._proc = None
        if parallel and _fork_is_safe():
            ctx = multiprocessing.get_context("fork")
            self._conn, child = ctx.Pipe()
            self._proc = ctx.Process(target=_serve, args=(child,), daemon=True, name="bijcr-figures")
            self._proc.start()
            child.close()
        self._pending = 0

    def draw(self, name: str, *args, **kwargs) -> None:
        """Draw ``_plot.<name>(*args, **kwargs)`` (in the child when there is one)."""
        if self._proc is None:
            from . import _plot

            getattr(_plot, name)(*args, **kwargs)
            return
        self._conn.send((name, args, kwargs))
        self._pending += 1

    def finish(self) -> None:
        """Wait for every figure sent and end the child; raises RuntimeError when one failed."""
        if self._proc is None:
            return
        errors = []
        try:
            for _ in range(self._pending):
                if not self._conn.poll(FIGURE_TIMEOUT_S):
                    raise OSError(f"no answer in {FIGURE_TIMEOUT_S:g} s")
                if (err := self._conn.recv()) is not None:
                    errors.append(err)
            self._conn.send(None)
        except (EOFError, OSError) as e:
            errors.append(f"the figure process ended early (exit code {self._proc.exitcode}): {e}")
        finally:
            self._pending = 0
            self._proc.join(timeout=30)
            if self._proc.is_alive():
                self._proc.kill()
            self._conn.close()
            self._proc = None
        if errors:
            raise RuntimeError("drawing a calibration figure failed:\n" + "\n".join(errors))

    def __enter__(self) -> FigureWorker:
        return self

    def __exit__(self, *exc) -> None:
        if exc[0] is None:
            self.finish()
        elif self._proc is not None:  # an error elsewhere: do not wait for figures nobody will see
            self._proc.kill()
            self._proc.join()
            self._conn.close()
            self._proc = None

"""``bijcr view RUN_DIR``: the run's metric cloud and segments, both arms, the calibrated cameras and
frames, the grasps and each task's plan in an interactive 3D page served with viser.

RUN_DIR is the --out folder of ``bijcr run`` (or any folder holding calibration/, segments/, grasps/,
tasks/). The page listens on 127.0.0.1 only unless --host is given; from another machine, forward the
port over SSH. Layers the folder does not hold are left out with a note. Stops after --timeout seconds
or on Ctrl-C. Needs the optional `viser` package: pip install -e .[view]. See docs/viewer.md.
"""

from __future__ import annotations

import argparse

HELP = "serve an interactive 3D page of a run: cloud, segments, arms, cameras, grasps, task replays"
DESCRIPTION = __doc__

LOOPBACK = ("127.0.0.1", "localhost", "::1")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", metavar="RUN_DIR", help="output folder of `bijcr run` (holds calibration/ ...)")
    p.add_argument("--port", type=int, default=8080, help="port to serve on (default 8080; the next free one if taken)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1: this machine only; 0.0.0.0: every interface)")
    p.add_argument("--scene", metavar="SCENE", default=None,
                   help="the scene folder, for the capture cameras and images (default: the one the run names)")
    p.add_argument("--timeout", type=float, default=None, metavar="S", help="stop serving after S seconds")
    p.add_argument("--task", default=None, help="open with this task's replay chosen (a folder name under tasks/)")
    p.add_argument("--at", type=float, default=0.0, metavar="T", help="with --task: open at T seconds into the plan")
    p.add_argument("--hide", action="append", default=[], metavar="LAYER",
                   choices=("cloud", "ids", "arms", "cameras", "frames", "sigma", "grasps", "carried"),
                   help="start with this layer hidden (repeatable; each has a checkbox on the page)")


def _require_viser() -> None:
    import importlib.util

    missing = [m for m in ("viser", "yourdfpy") if importlib.util.find_spec(m) is None]
    if missing:
        from bimanual_app.io_utils import InputError, Problem

        raise InputError(Problem("", "bijcr view", f"the optional package(s) {', '.join(missing)} are not installed",
                                 "pip install -e .[view]   (from the project folder, in its environment)"))


def run(args: argparse.Namespace) -> int:
    import socket
    import sys

    from bimanual_app.io_utils import InputError, Problem

    _require_viser()
    if not 0 < args.port < 65536:
        raise InputError(Problem("", "--port", f"{args.port} is not a port number", "give 1..65535, e.g. --port 8080"))
    from bimanual_app.viewer import load_run, serve

    layers = load_run(args.run_dir, scene=args.scene)
    if args.task is not None and args.task not in {t.name for t in layers.tasks}:
        raise InputError(Problem(str(args.run_dir), "--task", f"no replayable task {args.task!r}",
                                 f"choose one of: {', '.join(t.name for t in layers.tasks) or 'none (no plan.npz)'}"))
    for n in layers.notes:
        print(f"note: {n}", file=sys.stderr)

    def ready(port: int) -> None:
        local = args.host in LOOPBACK
        url_host = "127.0.0.1" if local or args.host in ("0.0.0.0", "::") else args.host
        print(f"bijcr view: serving {args.run_dir} at http://{url_host}:{port}", flush=True)
        if local:
            print(f"  listening on {args.host} only (this machine); --host 0.0.0.0 opens it to the network", flush=True)
        else:
            print(f"  listening on {args.host}: anyone who can reach this machine on port {port} can open the page",
                  flush=True)
        print(f"  from another machine: ssh -L {port}:127.0.0.1:{port} {socket.gethostname()}  then open "
              f"http://127.0.0.1:{port}", flush=True)
        print("  Ctrl-C stops" + (f"; stops by itself after {args.timeout:g} s" if args.timeout else ""), flush=True)

    _exit_soon_after_ctrl_c()
    try:
        serve(layers, host=args.host, port=args.port, timeout=args.timeout, on_ready=ready, task=args.task, at=args.at,
              hide=tuple(args.hide))
    except KeyboardInterrupt:
        print("bijcr view: interrupted", file=sys.stderr, flush=True)
        _end_process(130)
    print("bijcr view: stopped", flush=True)
    _end_process(0)
    return 0


#: seconds the server may take to stop after Ctrl-C before the process ends regardless
STOP_GRACE_S = 10.0


def _exit_soon_after_ctrl_c() -> None:
    """Ctrl-C raises KeyboardInterrupt as usual (the server stops in order), and also starts a watchdog that
    ends the process after STOP_GRACE_S if stopping hangs (in a full test run the server's stop once never
    returned); a second Ctrl-C ends it at once."""
    import signal
    import sys
    import threading

    def on_sigint(signum, frame):
        if getattr(on_sigint, "fired", False):
            _end_process(130)
        on_sigint.fired = True

        def give_up():
            print("bijcr view: interrupted (the server did not stop in time)", file=sys.stderr, flush=True)
            _end_process(130)

        watchdog = threading.Timer(STOP_GRACE_S, give_up)
        watchdog.daemon = True
        watchdog.start()
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, on_sigint)


def _end_process(code: int) -> None:
    """End the process now that the server has stopped. viser runs the page's callbacks on a thread pool, and
    interpreter shutdown waits for every running callback: one caught mid-way (a browser that just left)
    kept the process alive after Ctrl-C. The viewer writes nothing, so nothing is left half-done."""
    import os
    import sys

    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)

"""The ``bijcr`` command line.

Each sub-command lives in its own module exposing ``HELP`` (one line), ``add_arguments(parser)`` and
``run(args) -> int``. Those modules import only the standard library at top level, so ``bijcr --help``
starts fast; heavy libraries (torch, open3d, pybullet) are imported inside ``run``.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# command name -> module; order is the order shown in --help
COMMANDS: dict[str, str] = {
    "check": "bimanual_app.scene.cli",
    "synth": "bimanual_app.synth.cli",
    "reconstruct": "bimanual_app.reconstruction.cli",
    "calibrate": "calibration.cli",
    "segment": "segmentation.cli",
    "grasp": "grasping.cli",
    "reach": "bimanual_app.planning.cli",
    "task": "bimanual_app.tasks.cli",
    "capture": "bimanual_app.hardware.capture_cli",
    "run": "bimanual_app.app.run_cli",
    "view": "bimanual_app.viewer.cli",
}


def _available(only: str | None = None) -> dict[str, object]:
    mods = {}
    for name, modname in COMMANDS.items():
        if only is not None and name != only:
            continue
        try:
            mods[name] = importlib.import_module(modname)
        except ModuleNotFoundError as e:  # a stage not built yet in this checkout
            if e.name and modname.startswith(e.name):
                continue
            raise
    return mods


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The ``bijcr`` parser with every command, or with the command ``only`` (a command's module may import
    what its options need: building one is faster than building all when the command is known)."""
    parser = argparse.ArgumentParser(
        prog="bijcr",
        description="Bi-JCR: marker-free calibration of two robot arms with wrist cameras, and bimanual tasks.",
        epilog="Every command checks its output path (a folder it can write) before it reads or computes anything. "
               "Bad input is one line per problem: the file or option, what is wrong, and the fix. Exit codes: 0 "
               "done; 1 bad input, or a result that failed (e.g. a task whose preview failed); 2 bad arguments; "
               "130 interrupted (Ctrl-C).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, mod in _available(only).items():
        p = sub.add_parser(name, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP))
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv[0] if argv and argv[0] in COMMANDS else None)
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    from bimanual_app.io_utils import InputError

    try:
        return int(args._run(args) or 0)
    except InputError as e:
        if len(e.problems) == 1:  # one line: the file, the field, what is wrong and the fix
            print(f"bijcr {args.command}: {e.problems[0]}", file=sys.stderr)
            return 1
        print(f"bijcr {args.command}: input problem(s):", file=sys.stderr)
        for p in e.problems:
            print(f"  - {p}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"bijcr {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

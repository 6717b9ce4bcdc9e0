"""Run the stages of the product one after another, with caching, timing and a failure record.

Each stage is a ``bijcr`` sub-command run in-process (so a stage behaves exactly as when a user runs it
by hand) plus the list of files it reads and writes. A stage is skipped when its outputs exist and the
fingerprint of its inputs and arguments matches the one recorded when it last succeeded
(``DIR/.stages/NAME.json``). A failing stage stops the run, keeps everything the earlier stages
produced, and is recorded with its error so the report can say which stage failed and why.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from bimanual_app.io_utils import InputError, write_json

__all__ = ["Stage", "StageRecord", "run_stages", "fingerprint"]


@dataclass
class Stage:
    """One step of the pipeline.

    Attributes:
        name: short name (``calibrate``).
        argv: the ``bijcr`` arguments that run it (``["calibrate", SCENE, "--out", DIR]``).
        inputs: files (or folders) whose content decides whether a cached result is still valid.
        outputs: files that must all exist for the stage to count as done.
        optional: when True, a failure is recorded as a warning and the run continues.
    """

    name: str
    argv: list[str]
    inputs: list[Path]
    outputs: list[Path]
    optional: bool = False
    before: Callable[[], None] | None = None


@dataclass
class StageRecord:
    name: str
    status: str  # "ran", "cached", "failed", "skipped"
    seconds: float = 0.0
    message: str = ""
    log: str = ""
    outputs: list[str] = field(default_factory=list)


def _hash_path(h: "hashlib._Hash", p: Path) -> None:
    if p.is_dir():
        for q in sorted(p.rglob("*")):
            if q.is_file() and not q.name.startswith("."):
                h.update(str(q.relative_to(p)).encode())
                _hash_path(h, q)
    elif p.is_file():
        with open(p, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
    else:
        h.update(b"<missing>")


def fingerprint(inputs: list[Path], argv: list[str]) -> str:
    """SHA-256 over the inputs' contents and the stage's arguments."""
    h = hashlib.sha256()
    h.update(json.dumps(argv).encode())
    for p in inputs:
        h.update(str(p).encode())
        _hash_path(h, Path(p))
    return h.hexdigest()


class _Tee(io.TextIOBase):
    """Write to the terminal and keep a copy for the report."""

    def __init__(self, *streams):
        self.streams = streams

    def write(self, s):
        for st in self.streams:
            st.write(s)
        return len(s)

    def flush(self):
        for st in self.streams:
            st.flush()


def run_stages(stages: list[Stage], state_dir: Path, force: bool = False,
               on_start: Callable[[Stage, int, int], None] | None = None,
               on_end: Callable[[StageRecord], None] | None = None) -> list[StageRecord]:
    """Run ``stages`` in order; returns one record per stage (failed / skipped ones included)."""
    import sys

    from bimanual_app.cli import main as cli_main

    state_dir.mkdir(parents=True, exist_ok=True)
    records: list[StageRecord] = []
    failed = False
    for k, st in enumerate(stages):
        if failed:
            records.append(StageRecord(st.name, "skipped", message="an earlier stage failed"))
            continue
        if on_start:
            on_start(st, k, len(stages))
        stamp_path = state_dir / f"{st.name}.json"
        fp = fingerprint(st.inputs, st.argv)
        try:
            old = json.loads(stamp_path.read_text()) if stamp_path.exists() else {}
        except json.JSONDecodeError:
            old = {}
        if not force and old.get("fingerprint") == fp and all(Path(o).exists() for o in st.outputs):
            rec = StageRecord(st.name, "cached", old.get("seconds", 0.0), "inputs unchanged: reused",
                              old.get("log", ""), [str(o) for o in st.outputs])
            records.append(rec)
            if on_end:
                on_end(rec)
            continue
        buf = io.StringIO()
        t0 = time.perf_counter()
        status, message = "ran", ""
        try:
            if st.before:
                st.before()
            with contextlib.redirect_stdout(_Tee(sys.stdout, buf)), contextlib.redirect_stderr(_Tee(sys.stderr, buf)):
                rc = cli_main(st.argv)
            if rc != 0:
                # the last line a command prints is its one-line verdict; the whole log goes to the report
                tail = [l.strip() for l in buf.getvalue().strip().splitlines() if l.strip()][-1:]
                status, message = "failed", (f"'bijcr {st.argv[0]}' exited with code {rc}"
                                             + (": " + tail[0][:400] if tail else ""))
            else:
                missing = [str(o) for o in st.outputs if not Path(o).exists()]
                if missing:
                    status, message = "failed", f"finished but did not write {', '.join(missing)}"
        except InputError as e:
            status, message = "failed", str(e)
        except Exception as e:  # a stage's bug must not lose the earlier stages' results
            status, message = "failed", f"{type(e).__name__}: {e}"
            buf.write(traceback.format_exc())
        dt = time.perf_counter() - t0
        rec = StageRecord(st.name, status, dt, message, buf.getvalue()[-20000:], [str(o) for o in st.outputs])
        records.append(rec)
        if status == "ran":
            write_json(stamp_path, {"fingerprint": fp, "seconds": dt, "log": rec.log})
        else:
            stamp_path.unlink(missing_ok=True)
            if not st.optional:
                failed = True
            else:
                rec.status = "failed"
        if on_end:
            on_end(rec)
    return records

"""Run the stages of the product one after another, with caching, timing and a failure record.

Each stage is a library call (``calibrate_stage``, ``segment_stage``, ``grasp_stage``, ``run_task``, ...:
the very functions the ``bijcr`` sub-commands call) plus the list of files it reads and writes. A stage is
skipped when its outputs exist and the fingerprint of its inputs, its arguments and the product's code matches
the one recorded when it last succeeded (``DIR/.stages/NAME.json``). A failing stage stops the run, keeps everything the
earlier stages produced, and is recorded with its error so the report can say which stage failed and why.
Ctrl-C (KeyboardInterrupt) is never a stage's failure: it stops the whole run at once, leaving the
finished stages' results and records, and no record for the interrupted stage.
"""

from __future__ import annotations

import functools
import hashlib
import json
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from bimanual_app.io_utils import InputError, write_json

__all__ = ["Stage", "StageRecord", "StageFailure", "run_stages", "fingerprint"]

Log = Callable[[str], None]


class StageFailure(RuntimeError):
    """A stage ran to its end without a usable result (e.g. a task whose physics preview failed)."""


@dataclass
class Stage:
    """One step of the pipeline.

    Attributes:
        name: short name (``calibrate``).
        run: does the stage's work; gets a log function for its progress lines. Raises InputError (bad
            input), StageFailure (no usable result) or another exception (a bug).
        inputs: files (or folders) whose content decides whether a cached result is still valid.
        outputs: files that must all exist for the stage to count as done.
        key: the stage's arguments (e.g. the command line it equals), part of the fingerprint.
        optional: when True, a failure is recorded as a warning and the run continues.
    """

    name: str
    run: Callable[[Log], object]
    inputs: list[Path]
    outputs: list[Path]
    key: list[str] = field(default_factory=list)
    optional: bool = False


@dataclass
class StageRecord:
    name: str
    status: str  # "ran", "cached", "failed", "skipped"
    seconds: float = 0.0
    message: str = ""
    log: str = ""
    outputs: list[str] = field(default_factory=list)


def _hash_path(h: hashlib._Hash, p: Path, pattern: str = "*") -> None:
    """Feed ``h`` with a file's bytes, or a folder's files matching ``pattern`` (names and bytes, dot-files left out)."""
    if p.is_dir():
        for q in sorted(p.rglob(pattern)):
            if q.is_file() and not q.name.startswith("."):
                h.update(str(q.relative_to(p)).encode())
                _hash_path(h, q)
    elif p.is_file():
        with open(p, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
    else:
        h.update(b"<missing>")


CODE_PACKAGES = ("calibration", "segmentation", "grasping", "bimanual_app")  # the code the stages run


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """SHA-256 over the Python sources of the product's packages (``CODE_PACKAGES``), as installed: a result
    made by other code (an update, a local change) is not reused. About 300 files, read once per process."""
    import importlib.util

    h = hashlib.sha256()
    for name in CODE_PACKAGES:
        spec = importlib.util.find_spec(name)
        h.update(name.encode())
        if spec is not None and spec.origin:
            _hash_path(h, Path(spec.origin).parent, "*.py")
    return h.hexdigest()


def fingerprint(inputs: list[Path], key: list[str]) -> str:
    """SHA-256 over the inputs' contents, the stage's arguments and the code (:func:`code_fingerprint`)."""
    h = hashlib.sha256()
    h.update(code_fingerprint().encode())
    h.update(json.dumps(key).encode())
    for p in inputs:
        h.update(str(p).encode())
        _hash_path(h, Path(p))
    return h.hexdigest()


def _cached(st: Stage, stamp_path: Path, fp: str) -> StageRecord | None:
    """The record of a stage whose outputs exist and whose fingerprint is the one it last succeeded with."""
    try:
        old = json.loads(stamp_path.read_text()) if stamp_path.exists() else {}
    except json.JSONDecodeError:
        old = {}
    if old.get("fingerprint") != fp or not all(Path(o).exists() for o in st.outputs):
        return None
    return StageRecord(st.name, "cached", old.get("seconds", 0.0), "inputs unchanged: reused", old.get("log", ""),
                       [str(o) for o in st.outputs])


def _run_one(st: Stage) -> StageRecord:
    """Run one stage; its progress lines go to stderr and into the record. KeyboardInterrupt propagates."""
    lines: list[str] = []

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)
        lines.append(msg)

    t0 = time.perf_counter()
    status, message = "ran", ""
    try:
        st.run(log)
        missing = [str(o) for o in st.outputs if not Path(o).exists()]
        if missing:
            status, message = "failed", f"finished but did not write {', '.join(missing)}"
    except (InputError, StageFailure) as e:
        status, message = "failed", "; ".join(str(e).splitlines())
        lines.append(str(e))
    except Exception as e:  # a stage's bug must not lose the earlier stages' results
        status, message = "failed", f"{type(e).__name__}: {e}"
        lines.append(traceback.format_exc())
    log_text = "\n".join(lines)[-20000:]
    return StageRecord(st.name, status, time.perf_counter() - t0, message, log_text, [str(o) for o in st.outputs])


def run_stages(stages: list[Stage], state_dir: Path, force: bool = False,
               on_start: Callable[[Stage, int, int], None] | None = None,
               on_end: Callable[[StageRecord], None] | None = None) -> list[StageRecord]:
    """Run ``stages`` in order; returns one record per stage (failed / skipped ones included).

    KeyboardInterrupt is not caught: the stages finished before it keep their outputs and records.
    """
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
        fp = fingerprint(st.inputs, st.key)
        rec = None if force else _cached(st, stamp_path, fp)
        if rec is None:
            stamp_path.unlink(missing_ok=True)  # a stage run now is valid only once it has succeeded
            rec = _run_one(st)
            if rec.status == "ran":
                write_json(stamp_path, {"fingerprint": fp, "seconds": rec.seconds, "log": rec.log})
            elif not st.optional:
                failed = True
        records.append(rec)
        if on_end:
            on_end(rec)
    return records

"""Pair two task-bench runs scene by scene: what a change gained and lost, per mode and task.

The task bench (``bench/tasks.py``) prints one progress line per scene (``bench.tasks.scene_line``); save its
output (``2> base.log``) for the code before and after a change on the same stage inputs, then:

    .venv/bin/python tools/pair_task_runs.py base.log [more base logs] -- change.log [more change logs]

Only the scenes and tasks present in both are compared; each total carries its 95 % Wilson interval. A scene
in several logs of one side counts as in the last of them (a re-run of some scenes overrides them).
"""

from __future__ import annotations

import re
import sys
from collections import defaultdict
from pathlib import Path

USAGE = "usage: tools/pair_task_runs.py BEFORE.log [...] -- AFTER.log [...]"
# (scenes of other view and object counts are named synth_SEED_vV_oO: bench.tasks.scene_name)
_LINE = re.compile(r"\[bench tasks\] \d+/\d+ synth_(\d+)(?:_v\d+_o\d+)? \(.*?\) \d+ s: (.*)$")


def parse_lines(lines) -> dict:
    """``(mode, task, seed) -> "OK" | "FAIL[stage]"`` from the bench's progress lines (others are skipped)."""
    out = {}
    for line in lines:
        m = _LINE.search(line.strip())
        if not m:
            continue
        seed = int(m.group(1))
        for part in m.group(2).split("; "):
            mode, _, cells = part.partition(": ")
            for cell in cells.split(", "):
                task, _, outcome = cell.strip().partition(" ")
                out[(mode, task, seed)] = outcome
    return out


def pair(before: dict, after: dict) -> list[dict]:
    """Per (mode, task) present in both: ``{mode, task, n, ok_before, ok_after, gained, lost}``; ``gained`` the
    seeds that succeed only after, ``lost`` ``(seed, outcome after)`` of those that succeed only before."""
    keys = defaultdict(list)
    for k in sorted(set(before) & set(after)):
        keys[k[:2]].append(k)
    rows = []
    for (mode, task), ks in sorted(keys.items()):
        rows.append({"mode": mode, "task": task, "n": len(ks),
                     "ok_before": sum(before[k] == "OK" for k in ks), "ok_after": sum(after[k] == "OK" for k in ks),
                     "gained": [k[2] for k in ks if before[k] != "OK" and after[k] == "OK"],
                     "lost": [(k[2], after[k]) for k in ks if before[k] == "OK" and after[k] != "OK"]})
    return rows


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "--" not in argv or argv.index("--") == 0 or argv.index("--") == len(argv) - 1:
        print(USAGE, file=sys.stderr)
        return 2
    i = argv.index("--")

    def read(paths):
        lines = []
        for p in paths:
            lines += Path(p).read_text(errors="replace").splitlines()
        return parse_lines(lines)

    from bench._stats import format_rate

    rows = pair(read(argv[:i]), read(argv[i + 1:]))
    print("| mode | task | before | after | gained | lost |")
    print("| --- | --- | --- | --- | --- | --- |")
    for r in rows:
        lost = ", ".join(f"{s} ({o})" for s, o in r["lost"]) or "-"
        print(f"| {r['mode']} | {r['task']} | {format_rate(r['ok_before'], r['n'])} | {format_rate(r['ok_after'], r['n'])} "
              f"| {', '.join(map(str, r['gained'])) or '-'} | {lost} |")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    raise SystemExit(main())

"""Assemble docs/benchmarks.md from each benchmark's latest output in docs/bench/<area>.md.

Each bench script writes its own table with the command that produced it on top (the segmentation benches
keep the page's earlier runs below it: ``bench/_doc.py``); this joins them in the pipeline's order so
docs/benchmarks.md always shows the latest output of every bench.
Run: .venv/bin/python tools/assemble_benchmarks.py
"""

from __future__ import annotations

from pathlib import Path

ORDER = ["calibration", "estimators", "reconstruction", "real", "segmentation", "segmentation_steps", "motion", "grasping", "tasks", "pipeline"]


DEFAULT_ROOT = Path(__file__).resolve().parents[1]


def main(root: Path = DEFAULT_ROOT) -> Path:
    bench_dir = root / "docs" / "bench"
    parts = ["# Benchmarks", "",
             "The latest output of every benchmark in `bench/`, each under the command that produced it "
             "(assembled by `tools/assemble_benchmarks.py` from `docs/bench/*.md`). Speed rows carry a ratio "
             "against a reference measured in the same run; targets are checked by the benches (PASS/FAIL rows), "
             "not by timed tests. Machine: 2 CPU cores, shared with other work while these ran.", ""]
    names = ORDER + sorted(p.stem for p in bench_dir.glob("*.md") if p.stem not in ORDER)
    for name in names:
        p = bench_dir / f"{name}.md"
        if not p.exists():
            parts += [f"## {name}", "", f"Not run yet: `bench/{name}.py` does not exist or has no recorded output.", ""]
            continue
        text = p.read_text().strip()
        # demote the file's own headings one level under this section
        text = "\n".join(("#" + line) if line.startswith("#") else line for line in text.splitlines())
        parts += [f"## {name}", "", text, ""]
    out = root / "docs" / "benchmarks.md"
    out.write_text("\n".join(parts))
    return out


if __name__ == "__main__":
    print(main())

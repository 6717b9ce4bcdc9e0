"""One rule for every bench: it prints every row and exits 0 when it ran (a FAIL row is data, not an exit
code), and `make bench` runs every bench and always assembles docs/benchmarks.md."""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAKE_BENCHES = ("calibration", "estimators", "reconstruction", "real", "segmentation", "segmentation_steps", "motion",
                "grasping", "tasks", "pipeline")  # `make bench`
BENCHES = [ROOT / "bench" / f"{b}.py" for b in MAKE_BENCHES]


@pytest.mark.parametrize("path", BENCHES, ids=lambda p: p.name)
def test_a_bench_exit_code_does_not_depend_on_its_verdicts(path):
    """main() returns constants (0 once it ran; non-zero only where it could not run), never a value computed
    from its PASS/FAIL rows (as `return 0 if ok else 1` did)."""
    tree = ast.parse(path.read_text())
    funcs = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)}

    def constant_exits(fn, seen=()) -> bool:  # every return: a constant, or what a function of the module returns
        returns, todo = [], list(fn.body)
        while todo:  # the function's own returns (not those of functions defined inside it)
            n = todo.pop()
            if isinstance(n, ast.Return):
                returns.append(n)
            elif not isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                todo += list(ast.iter_child_nodes(n))
        return bool(returns) and all(
            isinstance(r.value, ast.Constant)
            or (isinstance(r.value, ast.Call) and isinstance(r.value.func, ast.Name) and r.value.func.id in funcs
                and r.value.func.id not in seen and constant_exits(funcs[r.value.func.id], (*seen, fn.name)))
            for r in returns)

    assert constant_exits(funcs["main"]), f"{path.name}: main()'s exit code must not carry the verdicts"
    assert "ok else 1" not in path.read_text()


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
def test_make_bench_runs_every_bench_and_assembles_even_after_a_failure(tmp_path):
    log = tmp_path / "calls.txt"
    fake = tmp_path / "python"  # stands in for .venv/bin/python: every bench crashes (exit 1)
    fake.write_text(f'#!/bin/sh\necho "$1" >> {log}\ncase "$1" in bench/*) exit 1;; esac\nexit 0\n')
    fake.chmod(0o755)
    env = dict(os.environ, MAKEFLAGS="")
    # -o setup: the environment is taken as built (nothing is installed)
    r = subprocess.run(["make", "-s", "-o", "setup", "bench", f"PY={fake}"], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=60)
    calls = log.read_text().split()
    assert calls[-1] == "tools/assemble_benchmarks.py", r.stdout + r.stderr
    assert [c for c in calls if c.startswith("bench/")] == [f"bench/{b}.py" for b in MAKE_BENCHES]
    assert r.returncode != 0  # a bench that crashed is still an error of `make bench`, after assembling

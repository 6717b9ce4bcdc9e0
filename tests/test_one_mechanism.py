"""One of each mechanism: production code does not import the synthetic generator, and clouds are read,
planes fitted and minimum-area rectangles taken in one place each."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = ("calibration", "segmentation", "grasping", "bimanual_app")


def _modules(packages=LIBRARY):
    for pkg in packages:
        yield from sorted((ROOT / pkg).rglob("*.py"))


def _imported(tree: ast.AST) -> set[str]:
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
    return names


def _calls(tree: ast.AST, attr: str) -> int:
    return sum(isinstance(n, ast.Attribute) and n.attr == attr for n in ast.walk(tree))


def test_production_code_does_not_import_the_generator():
    synth = ROOT / "bimanual_app" / "synth"
    offenders = [str(p.relative_to(ROOT)) for p in _modules() if synth not in p.parents
                 and any(m == "bimanual_app.synth" or m.startswith("bimanual_app.synth.")
                         for m in _imported(ast.parse(p.read_text())))]
    assert offenders == []


def test_one_cloud_reader_one_plane_fitter_one_rectangle():
    where = {"read_point_cloud": set(), "segment_plane": set(), "oriented_bounds_2D": set()}
    for p in _modules():
        tree = ast.parse(p.read_text())
        for attr, found in where.items():
            if _calls(tree, attr):
                found.add(str(p.relative_to(ROOT)))
    assert where["read_point_cloud"] == {"segmentation/_io.py"}
    assert where["segment_plane"] == {"segmentation/_plane.py"}
    assert where["oriented_bounds_2D"] == set()  # minimum-area rectangles: OpenCV's minAreaRect


def test_lazy_exports_load_on_first_use_and_stay():
    import sys
    import types

    import pytest

    from bimanual_app.lazy import lazy_exports

    pkg = types.ModuleType("lazy_probe")
    sys.modules["lazy_probe"] = pkg
    sys.modules["lazy_probe.inner"] = inner = types.ModuleType("lazy_probe.inner")
    inner.answer = 42
    try:
        pkg.__getattr__, pkg.__dir__ = lazy_exports("lazy_probe", {"answer": "inner"})
        assert "answer" not in vars(pkg) and "answer" in pkg.__dir__()
        assert pkg.answer == 42 and vars(pkg)["answer"] == 42  # kept: later look-ups skip __getattr__
        with pytest.raises(AttributeError, match="lazy_probe.*missing"):
            getattr(pkg, "missing")  # noqa: B009 (the attribute access under test)
    finally:
        del sys.modules["lazy_probe"], sys.modules["lazy_probe.inner"]


def test_ground_truth_readers_live_beside_the_scene_format():
    import numpy as np
    import pytest

    import bimanual_app.scene as scene
    import bimanual_app.synth as synth
    from bimanual_app.scene.meshes import load_catalogue_mesh

    assert synth.ground_truth_cloud is scene.ground_truth_cloud and synth.mesh_hull is scene.mesh_hull
    _, V = load_catalogue_mesh("duck")
    ext = V.max(0) - V.min(0)
    size = 0.06 * ext / ext.max()
    hull = scene.mesh_hull("duck", size)
    assert np.allclose(hull.max(0) - hull.min(0), size, atol=1e-9)  # the recorded size, centred on o
    assert np.allclose(hull.max(0) + hull.min(0), 0.0, atol=1e-9)
    with pytest.raises(ValueError, match="uniform scale"):
        scene.mesh_hull("duck", size * [1.0, 1.5, 1.0])
    with pytest.raises(ValueError, match="catalogue"):
        scene.mesh_hull("teapot", size)


MAX_FUNCTION_LINES = 80  # issue 23: a longer function decides more than one thing; split it by what it decides


def test_no_library_function_is_longer_than_80_lines():
    long = []
    for p in _modules():
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{p.relative_to(ROOT)}:{node.lineno} {node.name} ({n} lines)")
    assert long == []


def test_stages_call_each_other_as_library_functions_not_through_the_cli():
    """No library module runs a command line in-process (``main(argv)`` of a ``*.cli`` module, or a ``cli_main``)
    or captures a stage's printed output to parse it; the CLI module itself is the only caller of ``run``."""
    offenders = []
    for p in _modules():
        if p.name == "cli.py" and p.parent.name == "bimanual_app":
            continue
        tree = ast.parse(p.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and (node.module == "bimanual_app.cli"
                                                                     or node.module.endswith(".cli")):
                if any(a.name in ("main", "cli_main") for a in node.names):
                    offenders.append(f"{p.relative_to(ROOT)}: imports main from {node.module}")
            if isinstance(node, ast.ClassDef) and "Tee" in node.name:
                offenders.append(f"{p.relative_to(ROOT)}: class {node.name}")
            if isinstance(node, ast.Name) and node.id == "cli_main":
                offenders.append(f"{p.relative_to(ROOT)}: cli_main")
    assert offenders == []

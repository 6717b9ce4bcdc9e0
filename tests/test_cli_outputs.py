"""Every command checks its output path before it reads or computes anything: a file where a folder is
wanted, or a place that cannot be written, is one line naming the path and a fix (exit code 1)."""

from __future__ import annotations

import pytest

from bimanual_app.cli import main

UNWRITABLE = "/proc/bijcr-no-such-place/out"  # /proc takes no new files, even for root


def _commands(tmp, bad):
    """(argv, bad path) per command; the inputs do not exist: the output is checked first."""
    scene, cloud, seg = str(tmp / "no-scene"), str(tmp / "no.ply"), str(tmp / "no.npz")
    return {
        "calibrate": ["calibrate", scene, "--out", bad],
        "segment": ["segment", cloud, "--out", bad],
        "grasp": ["grasp", cloud, "--segments", seg, "--out", bad],
        "reach": ["reach", scene, "--to", "0.3,0,0.2", "--use-ground-truth", "--out", bad],
        "task --work": ["task", "joint-grasp", scene, "--work", bad],
        "task --out": ["task", "joint-grasp", scene, "--work", str(tmp / "w"), "--out", bad],
        "run": ["run", "scenes/demo", "--out", bad],
        "synth": ["synth", bad, "--no-render"],
        "reconstruct --workdir": ["reconstruct", scene, "--workdir", bad],
        "capture": ["capture", "--arm", "primary", "--poses", str(tmp / "no-poses.yaml"), "--out", bad],
    }


COMMANDS = list(_commands(__import__("pathlib").Path("/"), "x"))


@pytest.mark.parametrize("kind", ["file", "unwritable"])
@pytest.mark.parametrize("command", COMMANDS)
def test_output_folder_is_checked_first(command, kind, tmp_path, capsys):
    if kind == "file":
        bad = tmp_path / "a-file"
        bad.write_text("not a folder")
        bad = str(bad)
    else:
        bad = UNWRITABLE
    argv = _commands(tmp_path, bad)[command]
    assert main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert bad in err[0] and "fix:" in err[0], err[0]
    assert ("not a folder" if kind == "file" else "cannot be written") in err[0]


@pytest.mark.parametrize("kind", ["folder", "unwritable"])
def test_reconstruct_plot_file_is_checked_first(kind, tmp_path, capsys):
    bad = str(tmp_path) if kind == "folder" else UNWRITABLE + ".png"
    assert main(["reconstruct", str(tmp_path / "no-scene"), "--plot", bad]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and bad in err[0] and "fix:" in err[0], err


@pytest.mark.parametrize("kind", ["folder", "unwritable"])
def test_capture_suggest_plot_is_checked_first(kind, tmp_path, capsys):
    bad = str(tmp_path) if kind == "folder" else UNWRITABLE + ".png"
    assert main(["capture", "--suggest", "--views", "8", "--plot", bad]) == 1
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and bad in err[0] and "fix:" in err[0], err
    assert captured.out == ""  # no poses printed: nothing was computed


HEAVY = ("scipy", "open3d", "coal", "pybullet", "pinocchio", "torch", "matplotlib", "cv2", "trimesh")


@pytest.mark.parametrize("argv", [["--help"], ["segment", "--help"], ["grasp", "--help"], ["task", "--help"]])
def test_help_starts_without_the_heavy_libraries(argv):
    """``bijcr --help`` builds every command's parser; neither it nor a command's help loads a numerical
    library (each costs 0.1-1 s at start-up): they are imported by the commands that run."""
    import json
    import subprocess
    import sys

    code = ("import sys, json, contextlib, io\nfrom bimanual_app.cli import main\n"
            f"with contextlib.redirect_stdout(io.StringIO()):\n    try:\n        main({argv!r})\n"
            "    except SystemExit:\n        pass\n"
            f"print(json.dumps(sorted(m for m in {HEAVY!r} if m in sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []

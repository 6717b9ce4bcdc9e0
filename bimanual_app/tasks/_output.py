"""The task's output folder, written all-or-nothing.

Everything (``task.json``, ``preview.gif``, key frames, ``plan.npz``, ``approval.json``) is written into
a hidden staging folder beside ``OUT``; :meth:`OutputDir.commit` swaps it into place in two renames.
A run that fails half-way leaves ``OUT`` as it was (the staging folder is removed), so a folder that
holds a ``task.json`` always holds the complete result of one run.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from bimanual_app.io_utils import InputError, Problem

__all__ = ["OutputDir"]

MARKER = "task.json"


class OutputDir:
    """Staging area for ``out``; refuses to replace a folder that is not an earlier task result."""

    def __init__(self, out: str | Path):
        self.out = Path(out).resolve()
        if self.out.exists():
            if not self.out.is_dir():
                raise InputError(Problem(str(self.out), "--out", "exists and is not a folder", "choose a folder path"))
            if any(self.out.iterdir()) and not (self.out / MARKER).exists():
                raise InputError(Problem(str(self.out), "--out", "the folder holds files that are not a task result;"
                                         " they would be replaced", "choose an empty or new folder"))
        self.out.parent.mkdir(parents=True, exist_ok=True)
        self.staging = Path(tempfile.mkdtemp(prefix=f".{self.out.name}.tmp-", dir=self.out.parent))
        umask = os.umask(0)
        os.umask(umask)
        self._mode = 0o666 & ~umask
        os.chmod(self.staging, 0o777 & ~umask)  # mkdtemp makes it private; the result is an ordinary folder
        self.committed = False

    def path(self, name: str) -> Path:
        """Where to write ``name`` now (inside the staging folder)."""
        return self.staging / name

    def final(self, name: str) -> Path:
        """Where ``name`` will be once committed."""
        return self.out / name

    def commit(self) -> Path:
        """Move the staged result into place (replacing an earlier result); returns ``out``."""
        for f in self.staging.iterdir():  # temporary files are created private; results are ordinary files
            if f.is_file():
                os.chmod(f, self._mode)
        old = None
        if self.out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{self.out.name}.old-", dir=self.out.parent))
            old.rmdir()
            self.out.rename(old)
        self.staging.rename(self.out)
        self.committed = True
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return self.out

    def abort(self) -> None:
        """Drop everything staged."""
        if not self.committed:
            shutil.rmtree(self.staging, ignore_errors=True)

    def __enter__(self) -> OutputDir:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None or not self.committed:
            self.abort()

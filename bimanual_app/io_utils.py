"""Small I/O helpers shared by every stage: atomic writes, errors that name file, field and fix."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

__all__ = ["Problem", "InputError", "atomic_path", "atomic_open", "write_json", "to_jsonable", "check_output_dir",
           "check_output_file"]


@dataclass(frozen=True)
class Problem:
    """One thing wrong with an input: where (file, field/row), what, and how to fix it."""

    file: str
    field: str
    message: str
    fix: str = ""
    severity: str = "error"  # or "warning"

    def __str__(self) -> str:
        where = f"{self.file}" + (f" [{self.field}]" if self.field else "")
        text = f"{where}: {self.message}"
        return text + (f" -> fix: {self.fix}" if self.fix else "")


class InputError(ValueError):
    """Bad input: carries the list of problems, each naming file, field and fix."""

    def __init__(self, problems: list[Problem] | Problem | str):
        if isinstance(problems, str):
            problems = [Problem("", "", problems)]
        elif isinstance(problems, Problem):
            problems = [problems]
        self.problems = list(problems)
        super().__init__("\n".join(str(p) for p in self.problems))


def _writable_folder(folder: Path, path: Path, option: str, fix: str) -> None:
    """Raise InputError unless a file can be created in ``folder`` (tried: a temporary file, removed)."""
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as e:
        raise InputError(Problem(str(path), option, f"cannot be written: creating a file in {folder} fails "
                                 f"({e.strerror or e})", fix)) from None


def _existing_parent(path: Path, option: str, fix: str) -> Path:
    """The nearest folder above ``path`` that exists; InputError when a file stands in the way."""
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(Problem(str(path), option, f"{parent} is a file, not a folder", fix))
    return parent


def check_output_dir(path: str | os.PathLike, option: str = "--out",
                     fix: str = "give a new folder, or one you can write to") -> Path:
    """Check, before any work, that ``path`` is (or can become) a folder this process can write into.

    Creates nothing. Raises InputError naming the path, the option and a fix when it is a file, lies under
    a file, or cannot be written (a read-only or virtual file system, no permission). Returns the Path.
    """
    path = Path(path)
    if path.exists():
        if not path.is_dir():
            raise InputError(Problem(str(path), option, "exists and is not a folder", fix))
        _writable_folder(path, path, option, fix)
    else:
        _writable_folder(_existing_parent(path, option, fix), path, option, fix)
    return path


def check_output_file(path: str | os.PathLike, option: str = "--out",
                      fix: str = "give a file path in a folder you can write to") -> Path:
    """As :func:`check_output_dir` for a file to be (re)written: not a folder, its folder writable."""
    path = Path(path)
    if path.is_dir():
        raise InputError(Problem(str(path), option, "is a folder, not a file", fix))
    _writable_folder(_existing_parent(path, option, fix), path, option, fix)
    return path


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it onto ``path``, else remove it.

    A partial output never looks complete: readers see either the old file or the whole new one.
    The temporary name keeps the final suffix (``.tmp-XXXX.npz``) so libraries that key on it work.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.tmp-", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        # mkstemp creates the file 0600; give it the permissions a plain open() would (umask applies)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "w") -> Iterator[IO]:
    """Open a temporary file beside ``path`` for writing; renamed onto ``path`` when the block succeeds."""
    with atomic_path(path) as tmp:
        with open(tmp, mode) as f:
            yield f


def to_jsonable(obj):
    """Convert numpy arrays / scalars / Paths inside ``obj`` to plain JSON types."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json(path: str | os.PathLike, data: dict) -> None:
    """Write ``data`` as indented JSON, atomically."""
    with atomic_open(path) as f:
        json.dump(to_jsonable(data), f, indent=2)
        f.write("\n")

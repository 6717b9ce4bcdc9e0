"""Atomic file writes with ordinary permissions (temp name beside the target, then rename)."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from bimanual_app.io_utils import atomic_path, to_jsonable


def readable(tmp: Path) -> None:
    """Give a finished temp file the permissions a plain ``open`` would (mkstemp creates it 0600)."""
    um = os.umask(0)
    os.umask(um)
    os.chmod(tmp, 0o666 & ~um)


@contextmanager
def atomic_file(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temp path beside ``path``; on success it gets normal permissions and is renamed onto ``path``."""
    with atomic_path(path) as tmp:
        yield tmp
        readable(tmp)


def write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_file(path) as tmp:
        Path(tmp).write_text(text)


def write_json(path: str | os.PathLike, data: dict) -> None:
    write_text(path, json.dumps(to_jsonable(data), indent=2) + "\n")

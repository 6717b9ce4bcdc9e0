"""Small readers shared by the run-folder readers: JSON objects and 4x4 transforms with named errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from bimanual_app.io_utils import InputError, Problem
from bimanual_app.transforms import check_T


def read_json(path: Path, fix: str) -> dict:
    """The JSON object in ``path``; InputError (file, fix) when it is not readable JSON or not an object."""
    try:
        d = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(Problem(str(path), "", f"cannot read as JSON: {e}", fix)) from None
    if not isinstance(d, dict):
        raise InputError(Problem(str(path), "", "not a JSON object", fix))
    return d


def as_T(path: Path, field: str, value, fix: str) -> np.ndarray:
    """``value`` as a checked (4, 4) rigid transform; InputError naming ``path`` and ``field`` otherwise."""
    try:
        return check_T(field, np.asarray(value, dtype=np.float64))
    except (ValueError, TypeError) as e:
        raise InputError(Problem(str(path), field, f"not a 4x4 rigid transform ({e})", fix)) from None

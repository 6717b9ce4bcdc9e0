"""Writing a bench's report into its docs/bench/*.md without losing the runs before it.

A bench's report replaces the page's current table, but the page also holds what earlier runs measured and
the notes written under them (the history the figures are read against); rewriting the page with the new
report alone dropped that. :func:`save_report` writes the new report on top and the page as it was below it,
atomically (a partial page never replaces the old one).
"""

from __future__ import annotations

import datetime
from pathlib import Path

__all__ = ["save_report", "with_earlier"]

EARLIER = "## The run before (the page as it was until {date})"


def with_earlier(report: str, previous: str | None, date: str) -> str:
    """The page: ``report`` (its first line the page's ``# title``), then, when there was a page before,
    ``previous`` without its title line under an :data:`EARLIER` heading dated ``date``."""
    report = report.rstrip("\n") + "\n"
    if not previous or not previous.strip():
        return report
    lines = previous.splitlines()
    body = "\n".join(lines[1:] if lines and lines[0].startswith("# ") else lines).strip("\n")
    return f"{report}\n{EARLIER.format(date=date)}\n\n{body}\n"


def save_report(path: str | Path, report: str, date: str | None = None) -> Path:
    """Write ``report`` to ``path`` with the page's earlier content kept below it (:func:`with_earlier`),
    atomically; ``date`` defaults to today (ISO). Returns the path."""
    from bimanual_app.io_utils import atomic_open

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    previous = path.read_text() if path.is_file() else None
    with atomic_open(path) as f:
        f.write(with_earlier(report, previous, date or datetime.date.today().isoformat()))
    return path

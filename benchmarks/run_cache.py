"""The benchmarks' caches of finished runs: JSON lines, one run a line, appended as each run
ends so that an interrupted benchmark resumes. A path ending in ``.gz`` is gzip-compressed,
one gzip member per appended run (what ``benchmarks/results/`` commits: the same lines, a
quarter of the bytes); any other path is plain text."""

from __future__ import annotations

import gzip
import json
from pathlib import Path


def read_runs(path: Path) -> list[dict]:
    """Every run recorded in ``path`` (none when it does not exist)."""
    if not path.exists():
        return []
    data = path.read_bytes()
    text = (gzip.decompress(data) if path.suffix == ".gz" else data).decode()
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def append_run(path: Path, run: dict) -> None:
    """Add one run to ``path``. A gzip member's header carries no time (``mtime=0``), so the
    same runs written again give the same bytes."""
    line = json.dumps(run) + "\n"
    if path.suffix != ".gz":
        with open(path, "a") as fh:
            fh.write(line)
        return
    with open(path, "ab") as raw, gzip.GzipFile(fileobj=raw, mode="wb", mtime=0) as fh:
        fh.write(line.encode())
        fh.flush()  # (as gzip.open's text mode did: the same bytes but the time)

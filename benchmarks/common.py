"""What the benchmark scripts share: running ``hyprog`` in a child process, importing a C-MAPSS
training file once, the key of a cached run, a file's hash, and ranges of integers on the
command line.

Importing this module is cheap (the standard library only), so that a script's ``--help``
stays fast."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import time
from pathlib import Path

#: The repository root: every ``hyprog`` child runs there, on this checkout's packages.
ROOT = Path(__file__).resolve().parents[1]

#: How many of a failed child's last stderr lines :func:`hyprog` prints when it hid them.
FAILED_TAIL = 30


def hyprog(*args: str | Path, quiet: bool = False, announce: bool = False,
           capture: bool = False) -> None:
    """Run ``hyprog ARGS`` with this interpreter in the repository root (:data:`ROOT`) and stop
    on failure (:class:`subprocess.CalledProcessError`).

    The child runs in :data:`ROOT`, so a relative path means something else there than in the
    caller's folder: pass paths as :class:`~pathlib.Path` (made absolute here), never as
    ``str``. ``quiet`` adds ``--quiet``; ``announce`` prints the command with the time first;
    ``capture`` keeps the child's stderr off the terminal and prints its last
    :data:`FAILED_TAIL` lines only when it fails."""
    argv = [str(a.resolve()) if isinstance(a, Path) else a for a in args]
    cmd = [sys.executable, "-m", "cli.main", *argv, *(["--quiet"] if quiet else [])]
    if announce:
        print(f"[{time.strftime('%H:%M:%S')}] hyprog {' '.join(argv)}", flush=True)
    if not capture:
        subprocess.run(cmd, cwd=ROOT, check=True)
        return
    proc = subprocess.run(cmd, cwd=ROOT, stderr=subprocess.PIPE, text=True)
    if proc.returncode:
        tail = proc.stderr.splitlines()[-FAILED_TAIL:]
        print(f"hyprog {' '.join(argv)} failed (exit {proc.returncode}); the last lines of "
              "its stderr:", *tail, sep="\n", file=sys.stderr, flush=True)
        raise subprocess.CalledProcessError(proc.returncode, cmd, stderr=proc.stderr)


def imported(data_dir: Path, work: Path, subset: str, capture: bool = False) -> Path:
    """NASA's ``train_{subset}.txt`` in ``data_dir`` imported into ``work`` (``hyprog data
    import-cmapss``, once: an existing folder is reused); the imported table's path,
    ``work/fd00x``."""
    raw = work / subset.lower()
    if not raw.exists():
        hyprog("data", "import-cmapss", data_dir / f"train_{subset}.txt", "--out", raw,
               "--overwrite", quiet=True, capture=capture)
    return raw


def run_key(body: dict, length: int = 16) -> str:
    """The cache key of a run: the first ``length`` hex digits of the SHA-256 of ``body`` as
    sorted JSON (``benchmarks/cmapss.py`` keys with 16, ``benchmarks/health_features.py`` and
    ``benchmarks/health_study.py`` with 20)."""
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()[:length]


def file_sha(path: Path) -> str:
    """The SHA-256 of the file's bytes (hex): what names a calibration made with an adapted
    model (``--model-effects``) in the benchmarks' caches."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def parse_range(text: str) -> list[int]:
    """``"0-9"``, ``"0,3,5"``, ``"1000-1399"`` or a mix (``"0-2,7"``) as a list of integers,
    ranges inclusive."""
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b) + 1)) if b else [int(a)]
    return out

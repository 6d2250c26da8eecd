"""The paper's experiment on our ``ds02`` fleet, end to end and resumable (issue 13).

    OMP_WAIT_POLICY=PASSIVE nohup python benchmarks/paper_experiment.py > out/paper.log 2>&1 &

Steps, each skipped or resumed when its output is already there:

1. ``hyprog simulate --preset ds02 --rate 0.1 --seed 0 --out out/ds02`` (the fleet; a
   folder hyprog wrote is kept, so a rerun does not simulate again);
2. ``hyprog calibrate out/ds02 --method ukf --jobs 2 --out out/ds02-features`` (the paper's
   three health parameters, the default random walk; units already written are resumed);
3. ``hyprog experiment paper --data out/ds02-features --out out/paper --seeds 5`` (main
   table, horizon, ablations I, III, IV, conformal, physics baseline; every training run is
   cached by its configuration in ``out/paper/runs/``, so an interrupted experiment resumes);
4. the tables (Markdown, CSV: one row per training run) and the figures are copied to
   ``benchmarks/results/paper/`` to be committed; the trained models stay in ``out/``.

It takes many hours on two CPU cores (about 55 training runs; a CNN epoch over the
development set is about a minute of CPU); ``--device cuda`` where a GPU is available.
Options: ``--seeds``, ``--ablations``, ``--epochs``, ``--device`` are passed to step 3.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "out"
RESULTS = ROOT / "benchmarks" / "results" / "paper"


def hyprog(*args: str) -> None:
    """Run one ``hyprog`` command (this interpreter), stop on failure."""
    cmd = [sys.executable, "-c", "from cli.main import app; app()", *args]
    print(f"[{time.strftime('%H:%M:%S')}] hyprog {' '.join(args)}", flush=True)
    subprocess.run(cmd, cwd=ROOT, check=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="5")
    ap.add_argument("--ablations", default="all")
    ap.add_argument("--epochs", type=int)
    ap.add_argument("--device", default="auto")
    a = ap.parse_args()
    fleet, features, paper = OUT / "ds02", OUT / "ds02-features", OUT / "paper"
    if not fleet.exists():
        hyprog("simulate", "--preset", "ds02", "--rate", "0.1", "--seed", "0",
               "--out", str(fleet))
    hyprog("calibrate", str(fleet), "--method", "ukf", "--jobs", "2", "--out", str(features))
    exp = ["experiment", "paper", "--data", str(features), "--out", str(paper),
           "--seeds", a.seeds, "--ablations", a.ablations, "--device", a.device]
    if a.epochs is not None:
        exp += ["--epochs", str(a.epochs)]
    hyprog(*exp)
    RESULTS.mkdir(parents=True, exist_ok=True)
    copied = 0
    for f in sorted(paper.rglob("*")):
        if f.is_file() and "runs" not in f.relative_to(paper).parts \
                and f.suffix in (".md", ".csv", ".png", ".json"):
            dest = RESULTS / f.relative_to(paper)
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(f, dest)
            copied += 1
    print(f"copied {copied} tables and figures to {RESULTS.relative_to(ROOT)}")


if __name__ == "__main__":
    main()

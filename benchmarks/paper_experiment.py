"""The paper's experiment on our ``ds02`` fleet, end to end and resumable (issue 13).

    mkdir -p out && OMP_WAIT_POLICY=PASSIVE nohup python benchmarks/paper_experiment.py \\
        [--results benchmarks/results/paper] > out/paper.log 2>&1 &

Steps, each skipped or resumed when its output is already there:

1. ``hyprog simulate --preset ds02 --rate 0.1 --seed 0 --out out/ds02`` (the fleet; a
   folder hyprog wrote is kept, so a rerun does not simulate again);
2. ``hyprog calibrate out/ds02 --method ukf --jobs 2 --out out/ds02-features`` (the paper's
   three health parameters, the default random walk; units already written are resumed);
3. ``hyprog experiment paper --data out/ds02-features --out out/paper --seeds 5`` (main
   table, horizon, ablations I, III, IV, conformal, physics baseline; every training run is
   cached by its configuration in ``out/paper/runs/``, so an interrupted experiment resumes);
4. with ``--results DIR`` (the committed ones: ``benchmarks/results/paper``), the tables
   (Markdown, CSV: one row per training run) and the figures are copied to ``DIR`` and the
   finished runs' records to ``DIR/runs/``, to be committed; without it the report stays in
   ``out/paper/`` and nothing is written under ``benchmarks/``. The trained models stay in
   ``out/``.

It takes about 3 hours on two idle CPU cores (68 training runs, most ended early by early
stopping: FNN 0.5-2 min, CNN 2-8 min each, measured 2026-11-25; a CNN epoch over the
development set is 13 s wall, ``benchmarks/results/prognostics_speed.md``), longer on a shared
machine; ``--device cuda`` where a GPU is available.
Options: ``--seeds``, ``--ablations``, ``--epochs``, ``--device`` are passed to step 3.

What is committed. ``benchmarks/results/paper/`` holds small files only: the report (tables,
``runs.csv``, figures) and, per finished run, its record (``result.json``: configuration,
metrics, training history) and its per-cycle predictions (``per_cycle.csv``: per test unit and
cycle the true RUL and the mean, min and max of the predicted RUL, the interval's mean bounds
when there is one) under ``runs/<key>/``. The per-sample predictions
(``predictions.parquet``, about 1.2 MB a run) and the trained weights stay in ``out/paper/runs/``
and are not committed; regenerating them, and every table and figure from them, is rerunning
this script (same code, seed and libraries give the same feature table, and the same runs at
the same torch thread count: :mod:`prognostics.training`).
``--store-only --results DIR`` writes the records of the runs finished so far to
``DIR/runs/`` (the experiment may be running: a run's ``result.json`` is written last and
atomically); ``--life-table --results DIR`` rewrites the accuracy-over-life table from the
runs stored in ``DIR``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout, not whichever tree is installed
sys.path.insert(0, str(ROOT / "benchmarks"))
from common import hyprog  # noqa: E402

OUT = ROOT / "out"
#: the committed report (``--results`` names it; nothing is written there otherwise)
RESULTS = ROOT / "benchmarks" / "results" / "paper"


def copy_runs(src: Path, dest: Path) -> int:
    """Store the record of every finished run (one with ``result.json``) in ``src`` that
    ``dest`` lacks: ``per_cycle.csv`` from its predictions (or the baseline's per-cycle
    table), then ``result.json`` last and by rename, so that a copy cut short is never a stored
    run (it is stored again next time)."""
    import pandas as pd

    from prognostics.metrics import per_cycle

    copied = 0
    for run in sorted(src.glob("*/result.json")):
        key = run.parent.name
        if (dest / key / "result.json").is_file():
            continue
        (dest / key).mkdir(parents=True, exist_ok=True)
        preds = run.parent / "predictions.parquet"
        if preds.is_file():
            table = per_cycle(pd.read_parquet(preds))
            tmp = dest / key / f".per_cycle.csv.tmp-{os.getpid()}"
            table.to_csv(tmp, index=False, float_format="%.6g")
            os.replace(tmp, dest / key / "per_cycle.csv")
        tmp = dest / key / f".result.json.tmp-{os.getpid()}"
        shutil.copy2(run, tmp)
        os.replace(tmp, dest / key / "result.json")
        copied += 1
    return copied


def write_life_table(results: Path = RESULTS) -> str:
    """The report's accuracy-over-life table (:func:`workflows.paper.paper_report.life_table`)
    from the runs stored in ``results/runs`` (``result.json`` and ``per_cycle.csv`` of each),
    written to ``results/tables/life.csv`` and as the section after the horizon table in
    ``results/tables.md``."""
    import json

    import pandas as pd

    from workflows.paper.paper_report import _md, life_table

    runs = []
    for d in sorted((results / "runs").iterdir()):
        rec = json.loads((d / "result.json").read_text())
        if rec["run"]["part"] != "baseline":
            runs.append((rec, pd.read_csv(d / "per_cycle.csv")))
    table = life_table(runs)
    table.to_csv(results / "tables" / "life.csv", index=False)
    title = ("## Accuracy over life (Saxena et al. 2010): fraction of the test units within "
             "±20 % of the true RUL at λ of their life, and relative accuracy, mean ± std "
             "over seeds")
    md = (results / "tables.md").read_text()
    parts = md.split("\n## ")
    parts = [x for x in parts if not x.startswith(title[3:40])]
    at = next(i for i, x in enumerate(parts) if x.startswith("Prediction horizon")) + 1
    parts.insert(at, title[3:] + "\n\n" + _md(table) + "\n")
    (results / "tables.md").write_text("\n## ".join(parts))
    return f"accuracy over life of {len(runs)} runs in {len(table)} configurations"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="5")
    ap.add_argument("--ablations", default="all")
    ap.add_argument("--epochs", type=int)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--results", type=Path, default=None,
                    help="copy the report and the finished runs' records there (the "
                    "committed ones: benchmarks/results/paper); without it nothing is "
                    "written under benchmarks/")
    ap.add_argument("--store-only", action="store_true",
                    help="copy the finished runs to RESULTS/runs and stop (needs --results)")
    ap.add_argument("--life-table", action="store_true",
                    help="write the accuracy-over-life table from the per-cycle predictions "
                    "of the runs in RESULTS/runs (RESULTS/tables/life.csv, a section of "
                    "RESULTS/tables.md) and stop (needs --results)")
    a = ap.parse_args()
    if (a.life_table or a.store_only) and a.results is None:
        ap.error("--life-table and --store-only write into --results: name it (the "
                 "committed report: --results benchmarks/results/paper)")
    if a.life_table:
        print(write_life_table(a.results))
        return
    fleet, features, paper = OUT / "ds02", OUT / "ds02-features", OUT / "paper"
    if a.store_only:
        print(f"stored {copy_runs(paper / 'runs', a.results / 'runs')} finished runs in "
              f"{a.results / 'runs'}")
        return
    from workflows.paper.experiment import check_experiment_out

    check_experiment_out(paper)  # an experiment's folder, empty or absent: nothing else
    if not fleet.exists():
        hyprog("simulate", "--preset", "ds02", "--rate", "0.1", "--seed", "0",
               "--out", fleet, announce=True)
    hyprog("calibrate", fleet, "--method", "ukf", "--jobs", "2", "--out", features,
           announce=True)
    exp = ["experiment", "paper", "--data", features, "--out", paper,
           "--seeds", a.seeds, "--ablations", a.ablations, "--device", a.device]
    if a.epochs is not None:
        exp += ["--epochs", str(a.epochs)]
    hyprog(*exp, announce=True)
    if a.results is None:
        print(f"the report is in {paper}; --results DIR copies it there")
        return
    a.results.mkdir(parents=True, exist_ok=True)
    copied = 0
    for f in sorted(paper.rglob("*")):
        if f.is_file() and "runs" not in f.relative_to(paper).parts \
                and f.suffix in (".md", ".csv", ".png", ".json"):
            dest = a.results / f.relative_to(paper)
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(f, dest)
            copied += 1
    print(f"copied {copied} tables and figures to {a.results}")
    print(f"stored {copy_runs(paper / 'runs', a.results / 'runs')} finished runs in "
          f"{a.results / 'runs'}")


if __name__ == "__main__":
    main()

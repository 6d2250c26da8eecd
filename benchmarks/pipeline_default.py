"""The default ``hyprog pipeline`` on the packaged sample fleet, as the README's quick start
runs it, with its report committed under ``benchmarks/results/pipeline/``.

    python benchmarks/pipeline_default.py [--out out/pipeline-default] [--results DIR]
    python benchmarks/pipeline_default.py --results benchmarks/results/pipeline   # committed

About 2 minutes on 2 idle cores. Runs ``hyprog pipeline --out OUT`` (default
``out/pipeline-default``; no DATA: ``data_samples/tiny``, units 1-3 development, unit 4 test;
every option at its default) in a fresh output folder (an existing ``OUT`` that a pipeline
wrote, or the default folder, is removed first; any other existing folder is refused), and
prints the RUL table of the test unit with the stage timings. With ``--results DIR`` it also
copies the report (``report.md``, ``metrics.json``, ``run.json``, ``figures/*.png``) to
``DIR``, replacing those files there; without it nothing is written under ``benchmarks/``.
The numbers depend only on the code, the data and the seed (``metrics.json`` is the same byte
for byte on a rerun); timings are the machine's.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from common import hyprog  # noqa: E402

OUT = ROOT / "out" / "pipeline-default"
KEPT = ("report.md", "metrics.json", "run.json")


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def fresh(out: Path) -> None:
    """Remove ``out`` for a fresh run when it is the default folder or a pipeline's output
    (it holds ``run.json``); refuse any other existing folder."""
    if not out.exists():
        return
    if out.resolve() != OUT.resolve() and not (out / "run.json").is_file():
        raise SystemExit(f"error: {out} exists and is not a pipeline's output (no run.json): "
                         "name a new folder")
    shutil.rmtree(out)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=OUT,
                    help="the pipeline's output folder (default out/pipeline-default)")
    ap.add_argument("--results", type=Path, default=None,
                    help="copy the report there (the committed one: "
                    "benchmarks/results/pipeline)")
    a = ap.parse_args(argv)
    out = a.out
    fresh(out)
    hyprog("pipeline", "--out", out, quiet=True)
    metrics = json.loads((out / "metrics.json").read_text())
    run = json.loads((out / "run.json").read_text())
    print(f"machine: {platform.machine()}, {_cpu_model()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}")
    print(f"{'inputs':<12} {'RMSE':>7} {'NASA s':>8} {'last-cycle |error|':>20} {'horizon':>8}")
    for inputs, m in metrics["rul"].items():
        s, last = m["samples"]["overall"], m["last"]["overall"]
        print(f"{inputs:<12} {s['rmse']:7.3f} {s['score']:8.1f} {last['rmse']:20.2f} "
              f"{m['horizon']['mean']:8.1f}")
    print("stage seconds: " + ", ".join(f"{k} {v['seconds']:.1f}"
                                        for k, v in run["stages"].items()))
    if a.results is None:
        print(f"the report is in {out}; --results DIR copies it there")
        return
    (a.results / "figures").mkdir(parents=True, exist_ok=True)
    for old in (a.results / "figures").glob("*.png"):  # figures of an earlier report
        old.unlink()
    for name in KEPT:
        shutil.copy2(out / name, a.results / name)
    for fig in sorted((out / "figures").glob("*.png")):
        shutil.copy2(fig, a.results / "figures" / fig.name)
    print(f"copied the report to {a.results}")


if __name__ == "__main__":
    main()

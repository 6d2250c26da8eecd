"""The default ``hyprog pipeline`` on the packaged sample fleet, as the README's quick start
runs it, with its report committed under ``benchmarks/results/pipeline/``.

    python benchmarks/pipeline_default.py            # about 2 minutes on 2 idle cores

Runs ``hyprog pipeline --out out/pipeline`` (no DATA: ``data_samples/tiny``, units 1-3
development, unit 4 test; every option at its default) in a fresh output folder, copies the
report (``report.md``, ``metrics.json``, ``run.json``, ``figures/``) to
``benchmarks/results/pipeline/`` and prints the RUL table of the test unit with the stage
timings. The numbers depend only on the code, the data and the seed (``metrics.json`` is the
same byte for byte on a rerun); timings are the machine's.
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "out" / "pipeline-default"
RESULTS = ROOT / "benchmarks" / "results" / "pipeline"
KEPT = ("report.md", "metrics.json", "run.json")


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def main() -> None:
    if OUT.exists():
        shutil.rmtree(OUT)
    cmd = [sys.executable, "-c", "from cli.main import app; app()", "pipeline", "--out",
           str(OUT), "--quiet"]
    subprocess.run(cmd, cwd=ROOT, check=True)
    if RESULTS.exists():
        shutil.rmtree(RESULTS)
    (RESULTS / "figures").mkdir(parents=True)
    for name in KEPT:
        shutil.copy2(OUT / name, RESULTS / name)
    for fig in sorted((OUT / "figures").glob("*.png")):
        shutil.copy2(fig, RESULTS / "figures" / fig.name)
    metrics = json.loads((OUT / "metrics.json").read_text())
    run = json.loads((OUT / "run.json").read_text())
    print(f"machine: {platform.machine()}, {_cpu_model()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}")
    print(f"{'inputs':<12} {'RMSE':>7} {'NASA s':>8} {'last-cycle |error|':>20} {'horizon':>8}")
    for inputs, m in metrics["rul"].items():
        s, last = m["samples"]["overall"], m["last"]["overall"]
        print(f"{inputs:<12} {s['rmse']:7.3f} {s['score']:8.1f} {last['rmse']:20.2f} "
              f"{m['horizon']['mean']:8.1f}")
    print("stage seconds: " + ", ".join(f"{k} {v['seconds']:.1f}"
                                        for k, v in run["stages"].items()))
    print(f"copied the report to {RESULTS.relative_to(ROOT)}")


if __name__ == "__main__":
    main()

"""Scale of the pipeline's data stages: a fleet of N units at 0.1 Hz simulated, calibrated and
turned into the feature table one unit (or a few) at a time, with the peak memory of each
stage measured in its own process.

    python benchmarks/pipeline_scale.py --units 100            # the issue's 100-unit fleet
    python benchmarks/pipeline_scale.py --units 2 4 --chunk 1  # does the peak grow with N?

The fleet cycles through the ds02 preset's unit specifications (DS02-sized units: about 83,000
samples at 0.1 Hz each, so 100 units are about 8.3 M rows), renumbered 1..N, the last fifth
test units. Stages, each in a fresh ``python`` process so that its peak resident set size
(``ru_maxrss`` of the child) is its own:

- ``simulate``: :func:`engine_model.fleet.simulate` with ``out``: parquet written unit by unit;
- ``calibrate``: :func:`calibration.fleet.calibrate_fleet` called on ``--chunk`` units at a
  time into one feature table (a call reads only its units; the filters hold a call's units in
  lockstep, so ``--chunk`` bounds what is in memory);
- ``features``: what the pipeline's features stage reads (the table's keys and columns, no
  value column) and the per-unit row counts.

Memory is bounded when the peaks do not grow with N (compare ``--units 2 4``). Prints one
Markdown table: N, stage, rows, seconds, peak RSS (MiB).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# this folder holds benchmarks/calibration.py, which would shadow the calibration package
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).parent]


def preset(n: int):
    from dataclasses import replace

    from engine_model.fleet import get_preset

    ds02 = get_preset("ds02")
    specs = []
    n_test = max(1, n // 5)
    for i in range(n):
        s = ds02.units[i % len(ds02.units)]
        specs.append(replace(s, unit=i + 1, split="test" if i >= n - n_test else "dev"))
    return replace(ds02, name=f"scale{n}", description=f"{n} ds02-like units",
                   units=tuple(specs))


def stage(name: str, n: int, work: Path, chunk: int) -> dict:
    """Run one stage in this process; returns rows and seconds."""
    t0 = time.perf_counter()
    fleet, feats = work / "fleet", work / "features"
    if name == "simulate":
        from engine_model.fleet import simulate

        _, rep = simulate(preset(n), out=fleet, seed=0)
        rows = rep.total_rows
    elif name == "calibrate":
        from calibration import CalibrationSetup
        from calibration.fleet import calibrate_fleet
        from engine_model.datasets import read_dataset

        units = sorted(read_dataset(fleet, columns=[])[0]["unit"].unique().tolist())
        rows = 0
        for i in range(0, len(units), chunk):
            res = calibrate_fleet(fleet, "ukf", CalibrationSetup(), units=units[i:i + chunk],
                                  out=feats, keep_results=False)
            rows += res.samples
    elif name == "features":
        from engine_model.datasets import read_columns, read_dataset

        keys = read_dataset(feats, columns=[])[0]
        columns = read_columns(feats)
        rows = int(len(keys))
        assert "HPT_eff_mod_hat" in columns
    else:
        raise SystemExit(f"unknown stage {name}")
    return {"rows": int(rows), "seconds": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, nargs="+", default=[100])
    ap.add_argument("--chunk", type=int, default=1, help="units per calibrate call")
    ap.add_argument("--stage", help=argparse.SUPPRESS)
    ap.add_argument("--work", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.stage:  # a child: one stage, its numbers as JSON on stdout
        rec = stage(a.stage, a.units[0], Path(a.work), a.chunk)
        rec["peak_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(json.dumps(rec))
        return
    print("| units | stage | rows | seconds | peak RSS (MiB) |")
    print("|---|---|---|---|---|")
    for n in a.units:
        with tempfile.TemporaryDirectory(prefix="hyprog-scale-") as work:
            for name in ("simulate", "calibrate", "features"):
                r = subprocess.run([sys.executable, __file__, "--stage", name, "--units",
                                    str(n), "--chunk", str(a.chunk), "--work", work],
                                   capture_output=True, text=True)
                if r.returncode != 0:
                    raise SystemExit(f"stage {name} failed:\n{r.stderr[-3000:]}")
                rec = json.loads(r.stdout.strip().splitlines()[-1])
                print(f"| {n} | {name} | {rec['rows']:,} | {rec['seconds']:.1f} | "
                      f"{rec['peak_mib']:.0f} |", flush=True)


if __name__ == "__main__":
    main()

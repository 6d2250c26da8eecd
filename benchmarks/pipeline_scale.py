"""Scale of the pipeline's data stages: a fleet of N units at 0.1 Hz simulated, calibrated and
turned into the features stage's checks, unit by unit, with the peak memory of each stage
measured in its own process. Resumable: rerun the same command after an interruption.

    python benchmarks/pipeline_scale.py --units 100                 # the issue's 100-unit fleet
    python benchmarks/pipeline_scale.py --units 1 4                 # does the peak grow with N?
    python benchmarks/pipeline_scale.py --units 100 --scheduler tcp://host:8786 --work /shared/s

The fleet cycles through the ds02 preset's unit specifications (DS02-sized units: about 83,000
samples at 0.1 Hz each, so 100 units are about 8.3 M rows), renumbered 1..N, the last fifth
test units. Stages, each in a fresh ``python`` process so that its peak resident set size
(``ru_maxrss`` of the child) is its own, each calling what ``hyprog pipeline`` calls:

- ``simulate``: :func:`engine_model.simulator.fleet.simulate` into ``WORK/fleet``: units
  written one at a time (and kept across an interruption: the rerun simulates only the
  missing ones);
- ``calibrate``: :func:`calibration.calibrate_fleet.calibrate_fleet` (UKF) into
  ``WORK/features``: the client reads one unit at a time, a lockstep task holds at most
  ``calibration.calibrate_fleet.LOCKSTEP_MAX_ROWS`` samples, every unit is written when done (a
  rerun skips the units written);
- ``features``: the pipeline's features stage on that table: rows per unit from the part
  files' footers, the columns, the split and the inputs of both input sets.

Memory is bounded when the peaks do not grow with N (compare ``--units 1 4``: 4 units are more
than one lockstep task). Prints one Markdown table: N, stage, status (done / resumed), rows,
seconds, peak RSS (MiB). ``--jobs`` / ``--scheduler`` spread simulate and calibrate as the
pipeline's ``[run]`` table does (the workers' memory is theirs, not in the table).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path


def preset(n: int, base: str = "ds02"):
    """N units cycling through the ``base`` preset's specifications (``tiny``: a quick check
    of this script), renumbered 1..N, the last fifth test units."""
    from dataclasses import replace

    from engine_model.simulator.fleet import get_preset

    ref = get_preset(base)
    specs = []
    n_test = max(1, n // 5)
    for i in range(n):
        s = ref.units[i % len(ref.units)]
        specs.append(replace(s, unit=i + 1, split="test" if i >= n - n_test else "dev"))
    return replace(ref, name=f"scale{n}-{base}", description=f"{n} {base}-like units",
                   units=tuple(specs))


def stage(name: str, n: int, work: Path, jobs: int, scheduler: str | None,
          base: str) -> dict:
    """Run one stage in this process; returns status, rows and seconds."""
    from engine_model.datasets import written_units

    t0 = time.perf_counter()
    fleet, feats = work / "fleet", work / "features"
    if name == "simulate":
        from engine_model.simulator.fleet import simulate

        if written_units(fleet) == list(range(1, n + 1)):
            status = "kept"
            rows = None
        else:
            _, rep = simulate(preset(n, base), out=fleet, seed=0, jobs=jobs,
                              scheduler=scheduler)
            rows, status = rep.total_rows, "done"
    elif name == "calibrate":
        from calibration import CalibrationSetup
        from calibration.calibrate_fleet import calibrate_fleet

        drift = 0.01 if base == "tiny" else None  # the tiny fleet's fast wear (README)
        setup = CalibrationSetup() if drift is None else CalibrationSetup(
            drift=drift)
        res = calibrate_fleet(fleet, "ukf", setup, out=feats, keep_results=False,
                              jobs=jobs, scheduler=scheduler)
        rows = res.samples
        status = f"resumed {len(res.skipped)}" if res.skipped else "done"
    elif name == "features":
        from engine_model.datasets import read_columns, read_metadata
        from prognostics.features import resolve_inputs
        from workflows.pipeline.config import defaults
        from workflows.pipeline.stages import split_units, unit_rows

        per_unit = unit_rows(feats)
        columns = read_columns(feats)
        split_units(list(per_unit), read_metadata(feats), defaults()["data"], str(feats))
        for inputs in ("data-driven", "hybrid"):
            resolve_inputs(inputs, columns, str(feats))
        rows, status = int(sum(per_unit.values())), "done"
    else:
        raise SystemExit(f"unknown stage {name}")
    return {"status": status, "rows": rows, "seconds": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, nargs="+", default=[100])
    ap.add_argument("--work", help="folder of the runs (default out/pipeline-scale); a rerun "
                    "resumes there")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--scheduler", default=None, help="Dask scheduler address or 'local'")
    ap.add_argument("--base", default="ds02", choices=("ds02", "tiny"),
                    help="preset whose units are cycled (tiny: a quick check of the script)")
    ap.add_argument("--stage", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.stage:  # a child: one stage, its numbers as JSON on stdout
        rec = stage(a.stage, a.units[0], Path(a.work), a.jobs, a.scheduler, a.base)
        rec["peak_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(json.dumps(rec))
        return
    root = Path(a.work or "out/pipeline-scale")
    print("| units | stage | status | rows | seconds | peak RSS (MiB) |")
    print("|---|---|---|---|---|---|")
    for n in a.units:
        work = root / f"{a.base}-n{n}"
        work.mkdir(parents=True, exist_ok=True)
        for name in ("simulate", "calibrate", "features"):
            cmd = [sys.executable, __file__, "--stage", name, "--units", str(n), "--work",
                   str(work), "--jobs", str(a.jobs), "--base", a.base]
            if a.scheduler:
                cmd += ["--scheduler", a.scheduler]
            r = subprocess.run(cmd, capture_output=True, text=True)
            if r.returncode != 0:
                raise SystemExit(f"stage {name} failed:\n{r.stderr[-3000:]}")
            rec = json.loads(r.stdout.strip().splitlines()[-1])
            rows = "–" if rec["rows"] is None else f"{rec['rows']:,}"
            print(f"| {n} | {name} | {rec['status']} | {rows} | {rec['seconds']:.1f} | "
                  f"{rec['peak_mib']:.0f} |", flush=True)


if __name__ == "__main__":
    main()

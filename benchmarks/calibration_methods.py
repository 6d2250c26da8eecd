"""Accuracy and speed of every calibration method on a simulated fleet, against the truth and
the Cramér-Rao bound (:mod:`calibration.compare`).

    python benchmarks/calibration_methods.py                             # ds02 at 0.1 Hz, 2 jobs
    python benchmarks/calibration_methods.py --methods ukf,mhe --units 2,14 --jobs 2
    python benchmarks/calibration_methods.py --data fleet/ --params all  # a fleet already simulated

The fleet is simulated with :func:`engine_model.simulator.fleet.simulate` (seed 0) unless
``--data`` is given; its true theta columns are the reference and are never read by the estimators.
Units run in ``--jobs`` worker processes. Prints the machine, one table per method (RMSE, bias,
consistency, mean reported std, CRB, RMSE / CRB, residual whiteness, wall time, samples/s) and
the RMSE per unit.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calibration import CalibrationSetup  # noqa: E402
from calibration.compare import compare, format_report  # noqa: E402
from engine_model.channels import THETA_NAMES  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="ds02")
    ap.add_argument("--rate", type=float, default=0.1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--data", help="a simulated dataset (skips the simulation)")
    ap.add_argument("--units", help="comma-separated units [all]")
    ap.add_argument("--methods", default="ukf,ekf,mhe,map_cycle")
    ap.add_argument("--params", help="comma-separated health parameters, or 'all' [paper's 3]")
    ap.add_argument("--drift", type=float, help="random-walk std per sqrt(h) [1e-3]")
    ap.add_argument("--window", type=int, default=60)
    ap.add_argument("--mode", default="constant")
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args(argv)
    units = [int(u) for u in a.units.split(",")] if a.units else None
    kw = {}
    if a.params:
        kw["params"] = THETA_NAMES if a.params == "all" else tuple(a.params.split(","))
    if a.drift is not None:
        kw["drift"] = a.drift
    setup = CalibrationSetup(**kw)
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python "
          f"{platform.python_version()}; {a.jobs} worker processes")
    with tempfile.TemporaryDirectory() as tmp:
        data = a.data
        if data is None:
            from engine_model.simulator import fleet

            t0 = time.perf_counter()
            data = Path(tmp) / "fleet"
            fleet.simulate(a.preset, data, units, a.rate, a.seed)
            print(f"simulated {a.preset} at {a.rate:g} Hz (seed {a.seed}) in "
                  f"{time.perf_counter() - t0:.0f} s")
        methods = tuple(a.methods.split(","))
        opts = {"mhe": {"window": a.window, "mode": a.mode}}
        t0 = time.perf_counter()
        rep = compare(data, methods, setup, opts, units, jobs=a.jobs,
                      progress=lambda m, d, n: print(f"  {m}: {d}/{n} units", flush=True))
        print(f"total {time.perf_counter() - t0:.0f} s (calibration plus bounds)\n")
    print(format_report(rep))


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()

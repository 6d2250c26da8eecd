"""Fleet-simulator throughput: the ``ds02`` preset at 0.1 Hz and 1 Hz, written as parquet.

Run by hand: ``python benchmarks/fleet_generation.py [--rates 0.1 1] [--seed 0]``. Each rate
runs in a fresh child process so that its peak resident memory (``ru_maxrss``) is its own.
Prints one row per rate: rows, seconds, rows/s, peak memory. The README quotes the table with
the machine it ran on.
"""

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time

# this checkout, not whichever tree is installed
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))


def _one(rate: float, seed: int) -> dict:
    from engine_model import EngineModel
    from engine_model.simulator import fleet

    EngineModel()  # load (or build) the compiled model outside the timed part
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        path, rep = fleet.simulate("ds02", out=os.path.join(tmp, "ds02"), rate_hz=rate,
                                   seed=seed)
        dt = time.perf_counter() - t0
        size = sum(f.stat().st_size for f in path.rglob("*.parquet"))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # MiB (Linux: KiB)
    return {"rate": rate, "rows": rep.total_rows, "seconds": dt, "rows_per_s": rep.total_rows / dt,
            "peak_mib": peak, "dropped": sum(rep.dropped.values()), "parquet_mib": size / 2**20}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rates", type=float, nargs="+", default=[0.1, 1.0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--child", type=float, default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child is not None:
        print(json.dumps(_one(a.child, a.seed)))
        return
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python "
          f"{platform.python_version()}")
    print(f"{'preset':8s}{'rate Hz':>8s}{'rows':>12s}{'seconds':>10s}{'rows/s':>10s}"
          f"{'peak MiB':>10s}{'parquet MiB':>13s}{'dropped':>9s}")
    for rate in a.rates:
        out = subprocess.run([sys.executable, __file__, "--child", str(rate), "--seed",
                              str(a.seed)], capture_output=True, text=True, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        print(f"{'ds02':8s}{r['rate']:8g}{r['rows']:12,d}{r['seconds']:10.1f}"
              f"{r['rows_per_s']:10,.0f}{r['peak_mib']:10.0f}{r['parquet_mib']:13.1f}"
              f"{r['dropped']:9d}")


if __name__ == "__main__":
    main()

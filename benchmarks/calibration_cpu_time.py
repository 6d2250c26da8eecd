"""UKF samples per CPU-second in one process: a figure that holds on a shared machine.

``benchmarks/calibration_methods.py`` reports wall-clock samples/s over a whole fleet on two
workers, which other processes on the same cores lower. This script runs
``get_estimator(METHOD).estimate`` on every unit of a dataset (default
``data_samples/tiny``) in this process and times it with ``time.process_time``, so two
versions of the code can be compared while other work runs::

    git worktree add /tmp/old <commit>
    PYTHONPATH=/tmp/old python benchmarks/calibration_cpu_time.py
    python benchmarks/calibration_cpu_time.py

Units are estimated one at a time here (no lockstep), so the figure is lower than the
fleet benchmark's per-worker rate; it is for comparisons, not for the README's speed claim.
"""

import argparse
import time
from pathlib import Path

import calibration
from calibration import CalibrationSetup, get_estimator
from engine_model.datasets import read_dataset

ROOT = Path(__file__).resolve().parents[1]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(ROOT / "data_samples" / "tiny"))
    ap.add_argument("--method", default="ukf")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    df, _ = read_dataset(a.data)
    est, setup = get_estimator(a.method), CalibrationSetup()
    units = [g for _, g in df.groupby("unit")]
    est.estimate(units[0].iloc[:200], setup)  # load the model, warm the caches
    times = []
    for _ in range(a.repeat):
        t0 = time.process_time()
        for g in units:
            est.estimate(g, setup)
        times.append(time.process_time() - t0)
    n = sum(len(g) for g in units)
    print(f"tree: {calibration.__file__.rsplit('/', 2)[0]}")
    print(f"{'method':>7}{'samples':>9}{'best CPU s':>12}{'samples / CPU s':>17}")
    print(f"{a.method:>7}{n:>9}{min(times):>12.2f}{n / min(times):>17,.0f}")


if __name__ == "__main__":
    main()

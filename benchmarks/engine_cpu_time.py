"""Single-thread steady-state speed in CPU time: a figure that holds on a shared machine.

``benchmarks/engine_throughput.py`` reports wall-clock points/s, which another process on
the same cores lowers. This script times the compiled Newton solve on one thread with
``time.process_time`` (the CPU time of this process only), so two versions of the code can be
compared while other work runs, e.g. before and after a refactor::

    git worktree add /tmp/old <commit>
    PYTHONPATH=/tmp/old python benchmarks/engine_cpu_time.py     # the old tree
    python benchmarks/engine_cpu_time.py                          # this tree

Points: ``engine_model.analysis.sampling.random_envelope`` (seed 0), as in engine_throughput.py.
Prints the tree it imported, and the best and median of ``--repeat`` timings.
"""

import argparse
import time

import numpy as np

import engine_model
from engine_model import EngineModel
from engine_model.analysis.sampling import random_envelope


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=20_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    w, th = random_envelope(a.n, seed=a.seed)
    m = EngineModel(compiled=True, n_threads=1)
    m.solve(w[:64], th[:64])
    rates, conv = [], 0.0
    for _ in range(a.repeat):
        t0 = time.process_time()
        r = m.solve(w, th)
        rates.append(a.n / (time.process_time() - t0))
        conv = r.converged.mean()
    print(f"tree: {engine_model.__file__.rsplit('/', 2)[0]}")
    print(f"{'points':>8}{'repeats':>9}{'best CPU points/s':>19}{'median':>10}{'converged':>11}")
    print(f"{a.n:>8}{a.repeat:>9}{max(rates):>19,.0f}{np.median(rates):>10,.0f}"
          f"{100 * conv:>10.3f}%")


if __name__ == "__main__":
    main()

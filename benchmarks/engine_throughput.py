"""Steady-state throughput, convergence rate and Jacobian throughput of the engine model.

Run by hand: ``python benchmarks/engine_throughput.py [--n 100000]``. Prints a table; the
README quotes it with the machine it ran on. Points: random civil envelope
(engine_model.analysis.sampling), theta uniform in [-0.05, 0].
"""

import argparse
import os
import platform
import sys
import time

import numpy as np

# this checkout, not whichever tree is installed
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from engine_model import EngineModel  # noqa: E402
from engine_model.analysis.sampling import random_envelope  # noqa: E402


def _time(fn, repeat=1):
    best = np.inf
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--n-interpreted", type=int, default=20_000)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    w, th = random_envelope(a.n, seed=a.seed)
    rows = []
    for compiled in (True, False):
        n = a.n if compiled else min(a.n, a.n_interpreted)
        for threads in (1, 2):
            m = EngineModel(compiled=compiled, n_threads=threads)
            m.solve(w[:64], th[:64])  # warm up the thread maps
            el, res = _time(lambda m=m, n=n: m.solve(w[:n], th[:n]))
            conv = res.converged.mean()
            rows.append(("steady state", "compiled" if compiled else "interpreted", threads, n,
                         n / el, conv, res.iterations[res.converged].mean()))
            if compiled:
                nj = min(n, 20_000)
                el_j, _ = _time(lambda m=m, nj=nj, res=res: m.sensitivities(
                    w[:nj], th[:nj], x=res.x[:nj]))
                rows.append(("d(x_s,x_v)/d(theta, w)", "compiled", threads, nj, nj / el_j,
                             np.nan, np.nan))
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}")
    print(f"{'what':<24}{'mode':<13}{'threads':>8}{'points':>9}{'points/s':>12}"
          f"{'converged':>11}{'iters':>7}")
    for what, mode, t, n, pps, conv, it in rows:
        c = "" if np.isnan(conv) else f"{100 * conv:.3f}%"
        i = "" if np.isnan(it) else f"{it:.2f}"
        print(f"{what:<24}{mode:<13}{t:>8}{n:>9}{pps:>12,.0f}{c:>11}{i:>7}")


if __name__ == "__main__":
    main()

"""The compiler's optimisation level for the engine model's outputs and sensitivities:
compiler time against speed.

    python benchmarks/codegen_opt.py [--opts=-O1,-Og] [--points 2048] [--seconds 1] \\
        [--rounds 5] [--compiles 3] [--seed 0] [--out benchmarks/results/engine_cold_library_og.md]

A compiled :class:`engine_model.EngineModel` builds, per model variant (its effects), the
hot library (the residual and its Newton Jacobian, the solver's inner loop, gcc ``-O3``) and
the code of the outputs, which every filter step evaluates at its sigma points, and of the
exact sensitivities, which the EKF, the observability test, the Cramér-Rao bound and the
discovery loop read (one library at ``-O1`` until 2026-11-29; since, the outputs at ``-O1``
and the sensitivities at ``-Og``, each in its own library). The sensitivities' C is three
times the hot library's (about 2.8 MB), so their compiler time is what every new variant,
and a test suite on an empty cache, pays most of. Here the base model's outputs and
sensitivities are written to C and compiled at each level of ``--opts`` ``--compiles`` times
(one core; the compiler's wall and CPU seconds, median and range), then evaluated on the
same converged points of the civil envelope over ``--rounds`` rounds of ``--seconds`` each
(serially, one thread; over 64 points, a filter step, and over ``--points``). Compiles and
rounds interleave the levels, in reverse order every other time, so that a machine whose
speed drifts from minute to minute drifts under every level alike; the table gives medians
and the largest difference between the levels' numbers relative to each output's largest
magnitude (none is expected: no level allows fast-math).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from sensitivities_ad import compiled, largest_difference, per_point, values  # noqa: E402


def compile_cpu(fn, folder: Path, opt: str) -> tuple:
    """:func:`sensitivities_ad.compiled` at ``opt``, with the compiler's CPU seconds: (the
    loaded Function, C bytes, wall seconds, CPU seconds)."""
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    lib, size, secs = compiled(fn, folder, opt)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return lib, size, secs, cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--opts", default="-O1,-Og", help="gcc levels, comma-separated")
    ap.add_argument("--points", type=int, default=2048)
    ap.add_argument("--seconds", type=float, default=1.0)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--compiles", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None, help="also write the table here")
    a = ap.parse_args()
    import os
    import platform
    import tempfile

    import numpy as np

    from engine_model import EngineModel
    from engine_model.analysis.sampling import random_envelope

    opts = a.opts.split(",")
    base = EngineModel()  # compiled: solves the points
    w, th = random_envelope(4 * a.points, seed=a.seed)
    sol = base.solve(w, th)
    ok = np.flatnonzero(sol.converged)[:a.points]
    n = len(ok)
    args = [sol.x[ok].T, w[ok].T, th[ok].T, np.zeros((0, n))]
    sym = EngineModel(compiled=False)
    functions = {"outputs": sym.residual_system().outputs, "sensitivities":
                 sym.sensitivity_function()}
    built, compiles, times = {}, {}, {}

    def order(r: int) -> list:  # every other time in reverse: no level always goes first
        return opts if r % 2 == 0 else opts[::-1]

    with tempfile.TemporaryDirectory() as tmp:
        for r in range(a.compiles):
            for name, fn in functions.items():
                for opt in order(r):
                    folder = Path(tmp) / f"{name}{opt}{r}"
                    folder.mkdir()
                    lib, size, secs, cpu = compile_cpu(fn, folder, opt)
                    built[name, opt] = (lib, size)
                    compiles.setdefault((name, opt), []).append((secs, cpu))
        for r in range(a.rounds):
            for opt in order(r):
                for name in functions:
                    for k in (min(64, n), n):
                        times.setdefault((name, opt, k), []).append(
                            per_point(built[name, opt][0], args, k, a.seconds))
        got = {key: values(lib, args, n) for key, (lib, _) in built.items()}

    lines = ["# The engine model's outputs and sensitivities: compiler level against speed", "",
             f"{platform.machine()}, {os.cpu_count()} cores, Python "
             f"{platform.python_version()}; {n} converged points of the civil envelope (seed "
             f"{a.seed}); gcc on one core, {a.compiles} compiles a level; evaluated "
             f"serially, one thread, over {a.rounds} rounds; the levels interleaved; medians "
             "(compiles: [range]).", "",
             "| function | level | C source | compile wall | compiler CPU | us/point (64) | "
             f"us/point ({n}) |", "|---|---|---|---|---|---|---|"]
    for (name, opt), (_, size) in sorted(built.items(), key=lambda kv: (
            list(functions).index(kv[0][0]), opts.index(kv[0][1]))):
        secs, cpu = (np.array([c[j] for c in compiles[name, opt]]) for j in (0, 1))
        t64, tn = (float(np.median(times[name, opt, k])) for k in (min(64, n), n))
        lines.append(f"| {name} | {opt} | {size / 1e6:.2f} MB | {np.median(secs):.1f} s | "
                     f"{np.median(cpu):.1f} s [{cpu.min():.1f}, {cpu.max():.1f}] | "
                     f"{t64:.2f} | {tn:.2f} |")
    lines += ["", f"Largest difference from {opts[0]}'s numbers, relative to the largest "
              "magnitude of each output:", ""]
    for name in functions:
        for opt in opts[1:]:
            d = largest_difference(got[name, opts[0]], got[name, opt])
            lines.append(f"- {name}, {opt}: {d:.1e}")
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        a.out.write_text(text)


if __name__ == "__main__":
    main()

"""The exact derivatives by CasADi's forward or reverse mode: the same numbers, how much code,
how long the compiler takes, how fast they run.

    python benchmarks/sensitivities_ad.py [--points 2048] [--seconds 3] [--seed 0] \\
        [--out benchmarks/results/sensitivities_ad.md]

The engine model's sensitivities ``dy/d(theta, w, p)`` (implicit function theorem,
:meth:`engine_model.EngineModel.sensitivity_function`) and the MHE's per-sample Jacobians
(:class:`calibration.mhe_nlp.StageKernels`) are built from Jacobians of the cycle's residuals
and outputs. CasADi differentiates an ``m x n`` Jacobian by forward mode (one tangent sweep
per input) or reverse mode (one adjoint sweep per output), its ``ad_weight``. Here each is
built both ways for four cases: the base model (36 outputs; inputs: 10 theta, 4 w), the
discovery loop's candidate model (``hyprog discover --candidates`` of the steady default
effects, map scaling and the sensor effects: 29 effect parameters), the adaptation's model
(its default candidates, the sensitivities of its seven channels only) and the MHE's
kernels. Each Function is written to C, compiled as the model compiled it when these figures
were made (gcc ``-O1``, one core; the model's cold library has been built at ``-Og`` since
2026-11-29, ``benchmarks/codegen_opt.py``) and evaluated on the same converged points over
``--points`` points and over 64 (a filter step), serially (one thread), for ``--seconds``
each; the table gives instructions (CasADi's count), C source size, compile seconds,
microseconds per point and the largest difference between the two modes' numbers relative to
the largest magnitude of each output. Speeds on a shared machine vary by 10-20 % from run to
run; the compile times more (run it with the cores otherwise idle).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

# (the project's modules are imported where they are used: ``--help`` answers at once)

MODES = ("forward", "reverse")


def compiled(fn, folder: Path, opt: str = "-O1"):
    """``fn`` written to C in ``folder``, compiled with the model's cold-library command at
    ``opt`` (``-O1``, the level of this script's committed figures); returns (the loaded
    Function, C bytes, compile seconds)."""
    import subprocess
    import time

    import casadi as ca

    from engine_model.solver.codegen import CFLAGS, compiler

    cg = ca.CodeGenerator(f"{fn.name()}.c", {"with_header": False, "casadi_real": "double"})
    cg.add(fn)
    src = Path(cg.generate(str(folder) + "/"))
    lib = folder / f"{fn.name()}.so"
    t0 = time.perf_counter()
    subprocess.run([compiler(), opt, *CFLAGS, str(src), "-o", str(lib), "-lm"], check=True)
    return ca.external(fn.name(), str(lib)), src.stat().st_size, time.perf_counter() - t0


def values(fn, args, n: int) -> list:
    """The outputs of ``fn`` mapped over ``n`` points, as numpy arrays."""
    import numpy as np

    out = fn.map(n, "serial")(*args)
    return [np.asarray(v) for v in (out if isinstance(out, tuple | list) else [out])]


def largest_difference(reference: list, other: list) -> float:
    """The largest difference between two lists of output arrays, relative to the largest
    magnitude of each ``reference`` output."""
    import numpy as np

    return max(float(np.max(np.abs(f - r)) / max(np.max(np.abs(f)), 1e-300))
               for f, r in zip(reference, other, strict=True))


def per_point(fn, args, n: int, seconds: float) -> float:
    """Microseconds per point of ``fn`` mapped serially over the first ``n`` columns."""
    import time

    f = fn.map(n, "serial")
    a = [x[:, :n] for x in args]
    f(*a)
    k, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        f(*a)
        k += 1
    return (time.perf_counter() - t0) / k / n * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=2048)
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None, help="also write the table here")
    a = ap.parse_args()
    import os
    import platform
    import tempfile

    import numpy as np

    from calibration.adaptation.data import DEFAULT_CHANNELS
    from calibration.adaptation.groups import build_groups
    from calibration.discrepancy.candidates import (
        MAP_CANDIDATES,
        SENSOR_DEFAULT,
        STEADY_DEFAULT,
        CandidateModel,
        build_candidates,
    )
    from calibration.mhe_nlp import StageKernels
    from engine_model import EngineModel
    from engine_model.analysis.sampling import random_envelope
    from engine_model.channels import OUTPUT_NAMES, XS_NAMES

    base = EngineModel()  # compiled: solves the points
    w, th = random_envelope(4 * a.points, seed=a.seed)
    sol = base.solve(w, th)
    ok = np.flatnonzero(sol.converged)[:a.points]
    n = len(ok)
    X, W, TH = sol.x[ok].T, w[ok].T, th[ok].T
    Y = base.outputs_at(sol.x[ok], w[ok], th[ok])[:, [OUTPUT_NAMES.index(c)
                                                      for c in XS_NAMES]].T

    discovery, _ = build_candidates(STEADY_DEFAULT + MAP_CANDIDATES + SENSOR_DEFAULT,
                                    XS_NAMES)
    models = {
        "base model, 36 outputs": EngineModel(compiled=False),
        "discovery candidates, 36 outputs": CandidateModel(discovery, compiled=False).model,
        "adaptation candidates, 7 channels": CandidateModel(
            build_groups(DEFAULT_CHANNELS), sens_outputs=DEFAULT_CHANNELS,
            compiled=False).model,
    }
    rows, diffs = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, m in models.items():
            P = np.tile(np.asarray(m.p_default, float)[:, None], (1, n))
            got = {}
            for mode in MODES:
                fn = m.sensitivity_function(mode)
                lib, size, secs = compiled(fn, Path(tmp) / f"{len(rows)}")
                args = [X, W, TH, P]
                got[mode] = values(lib, args, n)
                rows.append((label, f"{len(m.p_default)} p", mode, fn.n_instructions(), size,
                             secs, per_point(lib, args, min(64, n), a.seconds),
                             per_point(lib, args, n, a.seconds)))
            diffs[label] = largest_difference(got["forward"], got["reverse"])
        label = "MHE kernels jac + hgn (base)"
        got = {}
        for mode in MODES:
            k = StageKernels(models["base model, 36 outputs"], compiled=False, mode=mode)
            fns = [k.f["jac"], k.f["hgn"]]
            S = np.ones_like(Y)
            args = [X, TH, W, Y * 1.001, S, np.zeros((0, n))]
            libs = [compiled(f, Path(tmp) / f"{len(rows)}{f.name()}") for f in fns]
            got[mode] = [v for lib, _, _ in libs for v in values(lib, args, n)]
            rows.append((label, "-", mode, sum(f.n_instructions() for f in fns),
                         sum(s for _, s, _ in libs), sum(t for _, _, t in libs),
                         sum(per_point(lib, args, min(64, n), a.seconds) for lib, _, _ in libs),
                         sum(per_point(lib, args, n, a.seconds) for lib, _, _ in libs)))
        diffs[label] = largest_difference(got["forward"], got["reverse"])

    lines = ["# Exact derivatives by forward or reverse mode", "",
             f"{platform.machine()}, {os.cpu_count()} cores, Python "
             f"{platform.python_version()}; {n} converged points of the civil envelope "
             f"(seed {a.seed}); gcc -O1 on one core; evaluated serially, one thread.", "",
             "| what | inputs | mode | instructions | C source | compile | us/point (64) | "
             f"us/point ({n}) |", "|---|---|---|---|---|---|---|---|"]
    for label, p, mode, ins, size, secs, t64, tn in rows:
        lines.append(f"| {label} | {p} | {mode} | {ins:,} | {size / 1e6:.1f} MB | "
                     f"{secs:.1f} s | {t64:.1f} | {tn:.1f} |")
    lines += ["", "Largest difference between the modes, relative to the largest magnitude of "
              "each output:", ""]
    lines += [f"- {label}: {d:.1e}" for label, d in diffs.items()]
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        a.out.write_text(text)


if __name__ == "__main__":
    main()

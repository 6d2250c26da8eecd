"""Is the discrepancy loop's screen calibrated? Its score statistics at the *true* theta on
no-effect fleets, against their nominal null distribution.

    python benchmarks/discrepancy_null_calibration.py --seeds 1000-1399 --seeds 5000-5399 \\
        [--results benchmarks/results]

For each no-effect ``tiny`` fleet (one unit, ``1 + seed % 4``, the benchmark's
``benchmarks/discrepancy.py`` no-effect fleets for seeds 1000 + k), the model is linearised at
the true theta of every cycle (which the simulated data carry) with every candidate
parameter at 0. The residual is then the measurement noise alone, and every candidate's score
``s = J_phi^T e`` is exactly Gaussian with covariance ``J_phi^T J_phi`` if the noise model
``R`` is right; ``T = s^T (J^T J)^-1 s`` is chi-square with the candidate's number of
parameters (chi-bar-squared for a one-sided candidate: the screen's own statistic and
p-value, :mod:`calibration.discrepancy.score_statistics`). This
separates two causes of false discoveries: a statistic that is not calibrated (tail rates
above nominal) and the estimation of theta (false discoveries where the statistic at the
truth stays below the threshold). Printed: the share of tests below each nominal level
against its expectation, and the fleets whose smallest p-value at the truth is below the
family-wise critical value of :mod:`calibration.discrepancy.max_stat` (computed from the same
covariance). Runs are cached (JSON lines, ``--runs``) so that a rerun continues. ``--runs``
and ``--table`` default to ``discrepancy_null_calibration.jsonl.gz`` and ``.md`` in
``--results``, itself ``out/discrepancy`` unless named: the committed files (``--results
benchmarks/results``) are read and written only when asked.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from common import parse_range  # noqa: E402
from run_cache import append_run, read_runs  # noqa: E402

# (the project's modules and scipy are imported where they are used: ``--help`` answers at
# once)

#: where the runs and the table go unless ``--results`` names another folder
OUT = ROOT / "out" / "discrepancy"
LEVELS = (1e-2, 1e-3, 1e-4)


def one_fleet(base, setup, seed: int, cache: dict) -> dict:
    from calibration.discrepancy.candidates import CandidateModel, build_candidates
    from calibration.discrepancy.max_stat import screen
    from calibration.discrepancy.null_fit import Problem, unit_data
    from calibration.discrepancy.score_statistics import Scores
    from engine_model.simulator import fleet

    unit = 1 + seed % 4
    df, _, _ = fleet.simulate("tiny", units=[unit], seed=seed, model=base)
    u = unit_data(df, setup)
    if "cm" not in cache:
        carried, cands = build_candidates(None, u.series.sensors, True)
        cache["cm"], cache["cands"] = CandidateModel(carried, design=base.design), cands
    cm, cands = cache["cm"], cache["cands"]
    pr = Problem([u], setup, cm)
    true = np.zeros((u.n_cycles, pr.k))
    np.add.at(true, u.cyc, df[list(setup.params)].to_numpy(float))
    true /= np.bincount(u.cyc, minlength=u.n_cycles)[:, None]
    lin = pr.linearize([true], np.zeros(pr.n_phi))
    tested = np.arange(pr.n_phi)
    sc = Scores(tested, -lin.g_phi, lin.D, np.diag(lin.D).copy(),
                np.zeros((pr.n_theta, pr.n_phi)), np.arange(pr.n_theta))
    res = screen(sc, cands, 0.01, 20000, seed)
    rec = {"seed": seed, "unit": unit, "samples": int(u.n),
           "chi2_per_dof": float(lin.sse / (u.n * pr.m)), "p_crit": res.p_crit, "tests": {}}
    for i, c in enumerate(cands):
        rec["tests"][c.name] = [float(res.T[i]), int(res.df[i]), float(res.p[i])]
    return rec


def table(runs: list, label: str) -> list[str]:
    from scipy.stats import poisson

    p = np.array([v[2] for r in runs for v in r["tests"].values()])
    n_f = len(runs)
    out = [f"\n### {label}: {n_f} fleets, {p.size} tests\n",
           "| nominal level | tests below | expected | P(at least this many) |",
           "|---|---|---|---|"]
    for a in LEVELS:
        k = int(np.sum(p < a))
        out.append(f"| {a:g} | {k} ({k / p.size:.3%}) | {a * p.size:.1f} | "
                   f"{poisson.sf(k - 1, a * p.size):.2g} |")
    hits = [r for r in runs if min(v[2] for v in r["tests"].values()) <= r["p_crit"]]
    k = len(hits)
    out.append(f"\nfleets whose smallest p-value at the true theta is below the family-wise "
               f"critical value (alpha 0.01): {k} of {n_f} ({k / max(n_f, 1):.1%}); "
               f"P(at least {k} | 1 %) = {poisson.sf(k - 1, 0.01 * n_f):.2g}")
    for r in hits:
        name = min(r["tests"], key=lambda q: r["tests"][q][2])
        out.append(f"- seed {r['seed']} (unit {r['unit']}): {name}, T = "
                   f"{r['tests'][name][0]:.1f} on {r['tests'][name][1]} df, "
                   f"p = {r['tests'][name][2]:.2g} (critical {r['p_crit']:.2g})")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", action="append", required=True,
                    help="seeds, e.g. 1000-1399 or 1,5,9 (repeat for several blocks)")
    ap.add_argument("--results", type=Path, default=None,
                    help="the folder of the default --runs and --table (default "
                    "out/discrepancy; the committed ones: benchmarks/results)")
    ap.add_argument("--runs", default=None,
                    help="default RESULTS/discrepancy_null_calibration.jsonl.gz")
    ap.add_argument("--table", default=None,
                    help="default RESULTS/discrepancy_null_calibration.md")
    a = ap.parse_args(argv)
    from calibration.estimation_setup import CalibrationSetup
    from engine_model.runtime.shared_model import default_model

    results = OUT if a.results is None else a.results
    path = Path(a.runs or results / "discrepancy_null_calibration.jsonl.gz")
    table_path = Path(a.table or results / "discrepancy_null_calibration.md")
    path.parent.mkdir(parents=True, exist_ok=True)
    done = {}
    for r in read_runs(path):
        done[r["seed"]] = r
    base, setup, cache = default_model(), CalibrationSetup(), {}
    blocks = []
    for text in a.seeds:
        runs = []
        for seed in parse_range(text):
            if seed not in done:
                done[seed] = one_fleet(base, setup, seed, cache)
                append_run(path, done[seed])
            runs.append(done[seed])
        blocks.append((text, runs))
    lines = ["# Score statistics at the true theta on no-effect fleets",
             "", "`python benchmarks/discrepancy_null_calibration.py " +
             " ".join(f"--seeds {t}" for t in a.seeds) + "`"]
    for text, runs in blocks:
        lines += table(runs, f"seeds {text}")
    if len(blocks) > 1:
        lines += table([r for _, runs in blocks for r in runs], "all")
    print("\n".join(lines))
    table_path.parent.mkdir(parents=True, exist_ok=True)
    table_path.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()

"""A recorded adaptation refitted to convergence: do its figures hold?

    python benchmarks/adaptation_refit.py --data-dir ../shared/data/cmapss \\
        [--work out/adaptation] [--record benchmarks/results/adaptation/fd002-adapted.json] \\
        [--results benchmarks/results/adaptation]

A record written before the fleet fit's fix of 2026-11-28 (CHANGELOG, "Fixed") may hold fits
that stopped at the iteration cap (:data:`calibration.adaptation.fleet_fit.MAX_ITER`) short
of their optimum. Its fits with a condition left out
(:func:`calibration.adaptation.selection.condition_out`) are warm-started at the fit on
*every* condition, so a fit that stops short keeps part of what the held-out condition
told that start, and its held-out error is optimistic. This script refits the record's
chosen candidates on the same early-life data (its channels, cycles and model error), from
its recorded values to convergence, and scores each condition left out from three starts:

- the converged fit on every condition (what ``hyprog adapt`` does);
- the record's values, every engine's health at 0;
- zero: every shared parameter and every engine's health at 0 (no information from any
  condition).

With converged fits the three agree, whatever the start; the table beside the record's own
figures says how much of those came from fits that stopped short. Per row: chi2 per sample
and channel with each condition left out, that of condition 4 (FD002's one part-power
point), the worst mean error with its condition left out (and without condition 4), and the
Gauss-Newton iterations of the six held-out fits (``fleet_fit.MAX_ITER``, 40: stopped at
the cap).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from types import SimpleNamespace

sys.path.insert(0, str(Path(__file__).resolve().parent))
from adaptation_bounds import arguments, emit, on_bound, recorded  # noqa: E402
from adaptation_design_point import worst  # noqa: E402

# (the project's modules are imported where they are used: ``--help`` answers at once)


def main() -> None:
    a = arguments(__doc__).parse_args()
    import numpy as np

    from calibration.adaptation.adapt import record_groups
    from calibration.adaptation.fleet_fit import fit_fleet
    from calibration.adaptation.selection import condition_out, mean_errors, shared_of
    from calibration.discrepancy.candidates import CandidateModel

    record, _, data = recorded(a)
    sel = record["selection"]
    chosen = list(sel["chosen"])
    groups = record_groups(record, data.channels)
    value = {(p["candidate"], p["parameter"]): p["value"] for p in record["parameters"]}
    phi = np.zeros(sum(len(c.params) for c in groups))
    for c in groups:
        for j, q in enumerate(c.params):
            phi[c.index[j]] = value.get((c.name, q), 0.0)
    model = CandidateModel(groups, sens_outputs=data.channels)
    shared = shared_of(groups, chosen)
    t0 = time.perf_counter()
    full = fit_fleet(model, data, shared, phi)
    in_sample = (f"in sample: chi2 {full.chi2_per_sample():.3f} (the record: "
                 f"{sel['chi2_in_sample']['after']:.3f}), worst mean error "
                 f"{worst(mean_errors(data, full.prediction, full.converged))}, "
                 f"{full.iterations} iterations from the record's values, "
                 f"{len(on_bound(groups, chosen, full))} parameters on a bound, "
                 f"{time.perf_counter() - t0:.0f} s")
    print(in_sample, flush=True)
    health0 = np.zeros_like(full.delta)
    recorded_out = sel["mean_error_pct_condition_out"]["after"]
    def without_4(errors: dict) -> str:
        return worst({c: row for c, row in errors.items() if int(c) != 4})

    rows = [("the record (as written)", sel["chi2_condition_out"]["after"], None,
             worst(recorded_out), without_4(recorded_out), "-", None)]
    for name, start in (("converged fit on every condition", full),
                        ("the record's values, health 0",
                         SimpleNamespace(phi=phi, delta=health0)),
                        ("zero", SimpleNamespace(phi=np.zeros_like(phi), delta=health0))):
        t0 = time.perf_counter()
        oos = condition_out(model, data, shared, start)
        rows.append((name, oos.chi2_out, oos.chi2.get(4, float("nan")),
                     worst(oos.mean_error_pct), without_4(oos.mean_error_pct),
                     ", ".join(str(oos.iterations[c]) for c in sorted(oos.iterations)),
                     time.perf_counter() - t0))
        print(rows[-1], flush=True)
    lines = [f"# `{a.record.name}` refitted to convergence", "",
             "`python benchmarks/adaptation_refit.py`: the record's candidates refitted on "
             f"its data ({data.n_units} FD002 engines, {len(data.y)} early-life samples) "
             "with the fleet fit as it is now; each condition left out scored from three "
             "starts.", "", in_sample, "",
             "| condition-out fits started at | chi2, each condition left out | chi2, "
             "condition 4 left out | worst mean error, condition left out | the same without "
             "condition 4 | iterations (conditions 1-6) | s |", "|---|---|---|---|---|---|---|"]
    for name, chi2, chi2_4, w, w5, its, sec in rows:
        lines.append(f"| {name} | {chi2:.3f} | {'-' if chi2_4 is None else f'{chi2_4:.2f}'} | "
                     f"{w} | {w5} | {its} | {'-' if sec is None else f'{sec:.0f}'} |")
    emit(lines, a.results, "refit.md")


if __name__ == "__main__":
    main()

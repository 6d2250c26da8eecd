"""The adaptation's fits with the sensitivities of the fitted channels only, against every
output's: the same numbers, how much sooner.

    python benchmarks/adaptation_speed.py --data-dir ../shared/data/cmapss \\
        [--work out/adaptation] [--record benchmarks/results/adaptation/fd002-adapted.json] \\
        [--repeats 2] [--results benchmarks/results/adaptation]

A fleet fit spends most of its time in the exact sensitivities of the engine model (two
thirds of an adaptation's, measured with py-spy on a 12-engine fleet), and an adaptation
reads seven channels of the model's 36 outputs. ``CandidateModel(sens_outputs=channels)``
(:class:`engine_model.solver.model.EngineModel` ``sens_outputs``) compiles the
sensitivities of those channels only. This script refits the recorded adaptation's chosen
candidates to the FD002 engines' early life (:func:`calibration.adaptation.assess`: the
fit on every condition, then each condition left out) with each model, ``--repeats`` times
alternately (the first of each includes no compile: both models are built before any
timing), and prints the seconds and the figures of each, so that a reader sees they agree.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from adaptation_bounds import arguments, emit, recorded  # noqa: E402
from adaptation_design_point import worst  # noqa: E402

# (the project's modules are imported where they are used: ``--help`` answers at once)


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--repeats", type=int, default=2)
    a = ap.parse_args()
    import os
    import platform

    import numpy as np

    from calibration.adaptation import assess
    from calibration.adaptation.adapt import record_groups
    from calibration.discrepancy.candidates import CandidateModel

    record, df, data = recorded(a)
    models = {"every output (36)": CandidateModel(record_groups(record, data.channels)),
              f"the fitted channels ({len(data.channels)})": CandidateModel(
                  record_groups(record, data.channels), sens_outputs=data.channels)}
    rows, phis = {k: [] for k in models}, {}
    for _ in range(a.repeats):
        for label, model in models.items():
            t0 = time.perf_counter()
            fit, out = assess(df, record, model=model)
            rows[label].append((time.perf_counter() - t0, fit, out))
            phis[label] = fit.x
    lines = ["# The adaptation's fits: sensitivities of every output or of the fitted channels",
             "", f"Record {a.record.name} refitted to the FD002 engines' early life "
             f"({data.n_units} engines, {len(data.y):,} samples, channels "
             f"{', '.join(data.channels)}), then each condition left out "
             f"(`calibration.adaptation.assess`); {platform.machine()}, "
             f"{len(os.sched_getaffinity(0))} cores, "
             f"{time.strftime('%Y-%m-%d')}.", "",
             "| sensitivities of | seconds per refit | in-sample chi2 | chi2, condition out "
             "| worst error, condition out | iterations (all, held out) |",
             "|---|---|---|---|---|---|"]
    for label, runs in rows.items():
        secs = ", ".join(f"{s:.1f}" for s, _, _ in runs)
        _, fit, out = runs[-1]
        lines.append(f"| {label} | {secs} | {fit.chi2_per_sample():.6f} | "
                     f"{out.chi2_out:.6f} | {worst(out.mean_error_pct)} | "
                     f"{fit.iterations}, {sorted(out.iterations.values())} |")
    a_, b_ = phis.values()
    rel = float(np.max(np.abs(a_ - b_) / np.maximum(np.abs(a_), 1e-12)))
    lines += ["", f"Largest relative difference of the fitted parameters and healths between "
              f"the two: {rel:.1e}."]
    emit(lines, a.results, "speed.md")


if __name__ == "__main__":
    main()

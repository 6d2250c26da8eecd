"""Where along an adaptation's path its parameters reach the bounds of their valid range.

    python benchmarks/adaptation_bounds.py --data-dir ../shared/data/cmapss \\
        [--work out/adaptation] [--record benchmarks/results/adaptation/fd002-adapted.json] \\
        [--results benchmarks/results/adaptation]

The recorded adaptation (``hyprog adapt``'s JSON, :mod:`calibration.adaptation.artefact`)
chose its candidates in an order (``selection.chosen``: the levels of the five components,
then each candidate that entered). This script refits the fleet (the record's channels,
early cycles and model error, on the FD002 engines imported into ``--work`` as
``benchmarks/adaptation.py`` does) with the levels alone and then with each candidate
added in the recorded order, every fit warm-started at the previous one as
:func:`calibration.adaptation.selection.select` does, and prints after each step: the chi2
per sample and channel in sample, and every shared parameter that sits on a bound of its
valid range (:meth:`calibration.adaptation.adapt.Adaptation.parameters`'s test) with its
value. It answers whether the bounds are reached by the greedy path's later candidates or
are there from the start. Nothing is selected here; it takes a few minutes.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import imported  # noqa: E402

# (the project's modules are imported where they are used: ``--help`` answers at once)


def on_bound(groups, chosen, fit) -> list[str]:
    """``candidate.parameter=value`` of every chosen parameter on a bound of its valid range
    (:func:`calibration.adaptation.adapt.fitted_parameters`'s ``at_bound``, the test
    ``hyprog adapt``'s record carries)."""
    from calibration.adaptation.adapt import fitted_parameters

    return [f"{p['candidate']}.{p['parameter']}={p['value']:+.3g}"
            for p in fitted_parameters(groups, chosen, fit) if p["at_bound"]]


def arguments(doc: str) -> argparse.ArgumentParser:
    """The options every script on a recorded adaptation takes."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--data-dir", type=Path, required=True)
    ap.add_argument("--work", type=Path, default=Path("out/adaptation"))
    ap.add_argument("--record", type=Path,
                    default=Path("benchmarks/results/adaptation/fd002-adapted.json"))
    ap.add_argument("--results", type=Path, default=None)
    return ap


def recorded(a) -> tuple[dict, object, object]:
    """(the record, the FD002 table, its early-life fleet data as the record chose them)."""
    from calibration.adaptation.data import MODEL_ERROR, fleet_data
    from calibration.measurement_noise import EARLY_CYCLES
    from engine_model import datasets

    record = json.loads(a.record.read_text())
    info = record.get("data", {})
    df, _ = datasets.read_dataset(imported(a.data_dir, a.work, "FD002"))
    data, _ = fleet_data(df, tuple(record["channels"]), info.get("early_cycles", EARLY_CYCLES),
                         None, model_error=info.get("model_error", MODEL_ERROR),
                         shared_model_error=info.get("model_error_shared", False))
    return record, df, data


def emit(lines: list[str], results: Path | None, name: str) -> None:
    """Print the table and, with ``results``, write it there as ``name``."""
    text = "\n".join(lines) + "\n"
    print(text)
    if results:
        results.mkdir(parents=True, exist_ok=True)
        (results / name).write_text(text)


def main() -> None:
    a = arguments(__doc__).parse_args()
    from calibration.adaptation.fleet_fit import Shared, fit_fleet
    from calibration.adaptation.groups import LEVEL_GROUP, build_groups
    from calibration.adaptation.selection import shared_of
    from calibration.discrepancy.candidates import CandidateModel
    from calibration.measurement_noise import EARLY_CYCLES

    record, _, data = recorded(a)
    info = record.get("data", {})
    groups = build_groups(data.channels)
    model = CandidateModel(groups, sens_outputs=data.channels)
    chosen_all = list(record["selection"]["chosen"])
    n_levels = sum(c.registry_name == LEVEL_GROUP for c in groups if c.name in chosen_all)
    fit = fit_fleet(model, data, Shared.none())
    rows = [("no candidate", fit.chi2_per_sample(), 0, 0, [], 0.0)]
    for k in range(n_levels, len(chosen_all) + 1):
        chosen = chosen_all[:k]
        t0 = time.perf_counter()
        fit = fit_fleet(model, data, shared_of(groups, chosen), fit.phi, fit.delta, x0=fit.x)
        n_par = sum(len(c.params) for c in groups if c.name in chosen)
        bound = on_bound(groups, chosen, fit)
        step = "the levels" if k == n_levels else f"+ {chosen[-1]}"
        rows.append((step, fit.chi2_per_sample(), n_par, len(bound), bound,
                     time.perf_counter() - t0))
    lines = [f"# Parameters on a bound along the path of `{a.record.name}`", "",
             f"`python benchmarks/adaptation_bounds.py` on the {data.n_units} FD002 engines, "
             f"cycles 1-{info.get('early_cycles', EARLY_CYCLES)} ({len(data.y)} samples), the"
             f" record's order; each fit warm-started at the previous one.", "",
             "| step | chi2 per sample and channel, in sample | parameters | on a bound |"
             " which (value) | fit [s] |", "|---|---|---|---|---|---|"]
    for step, chi2, n_par, n_bound, which, sec in rows:
        lines.append(f"| {step} | {chi2:.3f} | {n_par} | {n_bound} | "
                     f"{', '.join(which) or '-'} | {sec:.1f} |")
    emit(lines, a.results, "bounds_along_path.md")


if __name__ == "__main__":
    main()

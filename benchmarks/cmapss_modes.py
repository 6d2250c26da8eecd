"""C-MAPSS cross-validation errors split by fault mode: which units a hybrid helps.

    python benchmarks/cmapss_modes.py --features out/cmapss/fd003-features-all \\
        --runs benchmarks/results/cmapss/runs.jsonl.gz --subset FD003 \\
        [--inputs "data-driven,hybrid-theta --params all"] [--model dcnn] [--results DIR]

FD003 and FD004 fail by two modes (HPC and fan degradation; Saxena et al., PHM 2008), and
NASA's files do not say which unit fails by which. The calibration does: each unit's change
of θ̂ over its life, the median of its last :data:`LIFE_CYCLES` cycles minus that of its first
ones, for every health parameter estimated in every unit. The units are split in two by
2-means on those changes, each parameter scaled by its spread across units (Lloyd's
iteration from the two units farthest apart: no random start, the same split every time);
the table gives each group's mean change per parameter (in %), so the reader names the
modes.

Then, for every predictor of ``--inputs`` (``--model``'s networks) in the benchmark's run
cache (``benchmarks/cmapss.py``'s ``runs.jsonl``, every partition of the folds it ran on),
the seeds' mean
prediction on each held-out unit (the ensemble, as in :func:`cmapss.ensemble_rmse`) is
scored per group: last-cycle RMSE and bias (``RUL - RUL_pred``, positive = early) over every
held-out unit of every partition. Cross-validation figures on training units, not test-set
figures.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cmapss import ensemble_deltas, split_partition  # noqa: E402
from run_cache import read_runs  # noqa: E402

#: cycles at each end of a unit's life whose median θ̂ gives its change over life (C-MAPSS's
#: shortest training unit lives 128 cycles; 20 is the early-life window of the adaptation)
LIFE_CYCLES = 20


def life_change(features: pd.DataFrame) -> pd.DataFrame:
    """Per unit, the change of every health estimate over life (in %), for the parameters
    estimated in every row, and the unit's life in cycles."""
    est = [c for c in features.columns if c.endswith("_mod_hat") and features[c].notna().all()]
    rows = {}
    for unit, g in features.sort_values(["unit", "cycle"]).groupby("unit"):
        change = (g[est].iloc[-LIFE_CYCLES:].median() - g[est].iloc[:LIFE_CYCLES].median()) * 100
        rows[int(unit)] = {**{c[:-len("_mod_hat")]: v for c, v in change.items()},
                           "life": len(g)}
    return pd.DataFrame.from_dict(rows, orient="index").sort_index()


def two_means(x: np.ndarray, iterations: int = 100) -> np.ndarray:
    """Labels 0/1 of the rows of ``x`` by 2-means (Lloyd), started from the two rows farthest
    apart; group 0 holds the first of them."""
    d = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=2)
    i, j = np.unravel_index(np.argmax(d), d.shape)
    centres = x[[min(i, j), max(i, j)]]
    labels = None
    for _ in range(iterations):
        new = np.argmin(np.linalg.norm(x[:, None, :] - centres[None], axis=2), axis=1)
        if labels is not None and np.array_equal(new, labels):
            break
        labels = new
        centres = np.stack([x[labels == k].mean(axis=0) for k in (0, 1)])
    return labels


def fault_groups(change: pd.DataFrame) -> pd.Series:
    """Each unit's group (0 or 1) from its change over life, parameters scaled by their
    spread across units; group 0 holds the lowest-numbered unit (the same groups whatever
    the order of the rows)."""
    params = change.drop(columns="life")
    z = (params - params.mean()) / params.std(ddof=1)
    group = pd.Series(two_means(z.to_numpy(float)), index=change.index, name="group")
    return 1 - group if group[group.index.min()] == 1 else group


def ensemble_errors(runs: list[dict], subset: str, inputs: list[str],
                    model: str = "dcnn") -> pd.DataFrame:
    """One row per predictor, partition, fold and held-out unit: the seeds' mean error
    (:func:`cmapss.ensemble_deltas`, folds with every seed done) of ``model``'s networks
    (the cache holds other models' runs under the same input labels: an ensemble mixes
    none)."""
    nets = pd.DataFrame([r for r in {r["key"]: r for r in runs}.values()
                         if r.get("kind") == "run" and r["subset"] == subset
                         and r["model"] == model])
    split = nets["inputs"].map(split_partition)
    nets = nets.assign(base=split.str[0], partition=split.str[1])
    rows = []
    for (base, part), h in nets[nets["base"].isin(inputs)].groupby(["base", "partition"]):
        for fold, deltas in ensemble_deltas(h).items():
            rows += [{"inputs": base, "partition": part, "fold": fold, "unit": int(unit),
                      "error": float(err)} for unit, err in deltas.items()]
    return pd.DataFrame(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--features", type=Path, required=True,
                    help="the calibrated feature table of the subset (hyprog calibrate's)")
    ap.add_argument("--runs", type=Path, required=True)
    ap.add_argument("--subset", required=True)
    ap.add_argument("--inputs", default="data-driven,hybrid-theta --params all",
                    help="the predictors' labels, separated by ';' (a label may hold commas) "
                    "or, when none holds one, by ','")
    ap.add_argument("--model", default="dcnn", help="the networks' model")
    ap.add_argument("--results", type=Path)
    args = ap.parse_args(argv)
    change = life_change(pd.read_parquet(args.features))
    group = fault_groups(change)
    lines = ["| group | units | life (cycles) | "
             + " | ".join(c for c in change.columns if c != "life") + " |",
             "|---|---|---|" + "---|" * (change.shape[1] - 1)]
    for k, g in change.groupby(group):
        lines.append(f"| {k} | {len(g)} | {g['life'].min()}–{g['life'].max()} | "
                     + " | ".join(f"{g[c].mean():+.2f}" for c in g.columns if c != "life")
                     + " |")
    labels = args.inputs.split(";" if ";" in args.inputs else ",")
    errors = ensemble_errors(read_runs(args.runs), args.subset, labels, args.model)
    errors = errors.assign(group=errors["unit"].map(group))
    lines += ["", "| predictor | group | held-out units | RMSE | bias |", "|---|---|---|---|---|"]
    for (inputs, k), e in errors.groupby(["inputs", "group"], sort=True):
        lines.append(f"| {inputs} | {k} | {len(e)} | {np.sqrt(np.mean(e['error'] ** 2)):.2f} | "
                     f"{e['error'].mean():+.2f} |")
    table = "\n".join(lines)
    print(table)
    if args.results:
        args.results.mkdir(parents=True, exist_ok=True)
        (args.results / f"{args.subset.lower()}_modes.md").write_text(table + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

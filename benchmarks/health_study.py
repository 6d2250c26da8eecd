"""The many-fleet study of issue 30: does physics help, by how much, and with how many units?

    mkdir -p out/study && OMP_NUM_THREADS=2 nohup python benchmarks/health_study.py \\
        --fleets 0-9 [--results DIR] > out/study/study.log 2>&1 &

One ``ds02``-like fleet per seed (``hyprog simulate --preset ds02-study --seed S``: 24
development and 6 test units, end of life and onset drawn per seed), calibrated as the paper
experiment does (``hyprog calibrate --method ukf``, the paper's three parameters). In every
fleet, for every number of training units ``n`` in :data:`SIZES` (the first ``n`` development
units in an order drawn by the fleet's seed, so that the smaller sets are nested in the
larger), every predictor of :data:`PREDICTORS` is trained on those units (three seeds, the
seeds' mean prediction) and evaluated on the fleet's 6 test units; the floors of
:mod:`prognostics.floors` are fitted on the same units.

The predictors are fixed here, before any fleet of the study is seen: flight models
(``tcn``, window 20) that differ only in their inputs, so that the difference is the
information: ``data-driven`` (the flights' means of ``w`` and ``x_s``), ``physics`` (the
health coordinates of θ̂ and θ̂ relative to early life: the choice of ``ds02``'s development
folds) and ``health`` (the health coordinates alone: the best on ``ds02``'s test units, named
here for that reason and reported as such). Added 2026-11-29, after the networks' runs and
before any fleet was scored with it: ``similarity`` (:mod:`prognostics.similarity`, window 10
flights, the choice of ``ds02``'s development folds; no network and no seeds), to ask of
every fleet whether it is ahead of the HI lookup floor beyond ``ds02``.

**Replication** (fixed 2026-11-29 before any of its fleets was simulated, after the 10-fleet
result for the similarity predictor was ahead of the HI lookup by 0.6-0.7 cycle with 95 %
intervals reaching zero): fleets 10-19, the floors and ``similarity`` only
(``--fleets 10-19 --predictors similarity --results
benchmarks/results/health_study/replication``). The test: the similarity predictor minus the
HI lookup per fleet at 6, 12 and 24 training units, mean and 95 % interval over these 10 new
fleets alone, reported whatever it is. Pooling them with fleets 0-9 after seeing those would
be optional stopping: a pooled figure is only ever reported beside it, as such.

**The health index relative to early life** (fixed 2026-11-29, nineteenth session, before
any of fleets 10-29 was scored with it): ``similarity-rel``, the same predictor (window 10)
on ``HI_hat_rel``, the health index minus its mean over the unit's first five flights
(:mod:`prognostics.flights`). Why: the simulator draws a unit's initial wear apart from its
end of life, so the level an engine starts at says little about how long it lasts, and the
absolute health index matches engines by that level; the change since entry into service is
the degradation (before onset, the phase where the similarity predictor trailed the life
floor: 12.4-14.1 against 10.0-12.4 on fleets 0-19, read after the replication). Found on
fleets 0-9 against three other variants scored there (a Gaussian prior on the lag between
the two engines' ages, with either column, and both columns matched together; none carried
forward): minus ``similarity`` -0.81, -0.74, -0.98, -0.82 at 3, 6, 12, 24 units (intervals
reaching 0), minus the life floor -1.86 to -2.06 (intervals excluding 0). The test: fleets
10-29 (10-19 scored so far with the floors and ``similarity`` only, 20-29 simulated and
calibrated and scored with nothing before this was committed), ``--fleets 10-29
--predictors similarity,similarity-rel --results benchmarks/results/health_study/relative``:
``similarity-rel`` minus ``similarity``, the HI lookup and the life floor per fleet at 6, 12
and 24 units, mean and 95 % interval over those 20 fleets, reported whatever they are. The
decision tied to it, fixed now: if ``similarity-rel`` minus ``similarity`` has its mean below
0 at 6, 12 and 24 units and its 95 % interval below 0 at 24, ``HI_hat_rel`` becomes the
similarity model's default input (``hyprog train --model similarity``), and that predictor,
the study's choice, is scored once on ``ds02``'s test units (its cross-validated RMSE on
``ds02``'s development folds reported beside it, choosing nothing); otherwise nothing
changes.

Report: per ``n``, the mean over fleets of each predictor's test RMSE, and the hybrid-minus-
data-driven difference per fleet with its 95 % confidence interval over fleets (Student t);
the hybrid minus each floor the same way (what a network adds to a lookup with no network);
the curve of the hybrid-minus-data-driven difference, and of each comparison fixed in
advance (:data:`COMPARISONS`), against ``n`` (``study.png``).
The tables and the figure go to ``--results`` (default: ``--work``, ``out/study``); the
committed ones are written only when asked, ``--results benchmarks/results/health_study``.
``--report`` trains nothing; without a cache it rewrites the tables from the committed
``benchmarks/results/health_study/study_runs.csv``. The tables cover the fleets of
``--fleets`` (default 0-9, the committed study) whatever else the cache holds.
``--predictors`` picks the predictors that run and that the tables cover (the floors always
do: they are cheap).
``--merge-committed`` adds the committed table's rows that the cache lacks, for each fleet
and ``n`` whose floors the cache reproduces (the floors are deterministic in the data and
the units, so equal floors mean the same fleet); a fleet and ``n`` whose floors differ are
refused, naming them.
Every run is cached in ``--work``/``runs.jsonl`` (fleet, n, predictor, data fingerprint); an
interrupted study resumes, and ``--fleets`` / ``--sizes`` pick what runs. ``--rate`` (default
0.05 Hz, half the paper experiment's, to halve the calibration) is the sampling rate of the
simulation.
"""

from __future__ import annotations

import argparse
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from common import hyprog, parse_range, run_key  # noqa: E402
from health_features import (  # noqa: E402
    KEY_LENGTH,
    library_body,
    library_predict,
    scores,
    train_predict,
)
from run_cache import append_run, read_runs  # noqa: E402

# (the project's modules are imported where they are used: ``--help`` answers at once)

#: the committed tables, read by ``--report`` when there is no cache
COMMITTED = ROOT / "benchmarks" / "results" / "health_study"

SIZES = (3, 6, 12, 24)
PREDICTORS = {"data-driven": ("tcn", "data-driven", 20), "physics": ("tcn", "physics", 20),
              "health": ("tcn", "health", 20)}
#: predictors with no network (model, window, health-index column): fitted once, no seeds
LIBRARY = {"similarity": ("similarity", 10, "HI_hat"),
           "similarity-rel": ("similarity", 10, "HI_hat_rel")}
SEEDS = (0, 1, 2)
HYBRIDS = ("physics", "health", "similarity")  # their columns always (the committed tables')
LATER_HYBRIDS = ("similarity-rel",)  # their columns where they ran
#: RMSE by phase (:mod:`prognostics.metrics`) -> its column in ``study_runs.csv``
PHASES = {"before onset": "before_onset", "after onset": "after_onset",
          "RUL <= 30": "rul_30"}
#: comparisons fixed before their test fleets were scored (the docstring): (a, b) is a - b
COMPARISONS = (("similarity-rel", "similarity"),)


def fleet_features(work: Path, seed: int, rate: float) -> Path:
    """The calibrated fleet ``seed`` under ``work`` (simulated and calibrated when absent);
    a fleet already there at another sample rate is refused, not reused."""
    from engine_model.datasets import read_metadata

    fleet, features = work / f"fleet-{seed}", work / f"fleet-{seed}-features"
    if fleet.exists():
        had = (read_metadata(fleet) or {}).get("sample_rate_hz")
        if had is not None and not np.isclose(float(had), rate):
            raise SystemExit(f"error: {fleet} was simulated at {had:g} Hz, not --rate {rate:g}"
                             "; give another --work")
    else:
        hyprog("simulate", "--preset", "ds02-study", "--rate", str(rate), "--seed", str(seed),
               "--out", fleet, announce=True)
    hyprog("calibrate", fleet, "--method", "ukf", "--jobs", "2", "--out", features,
           announce=True)
    return features


def run_fleet(work: Path, seed: int, rate: float, sizes, cache: Path, done: dict,
              predictors) -> None:
    from engine_model.datasets.dispatch import read_dataset
    from engine_model.datasets.fingerprint import table_fingerprint
    from prognostics.baseline import health_effects
    from prognostics.flights import to_samples
    from prognostics.floors import FLOORS, floor_predictions
    from prognostics.train_config import TrainConfig
    from prognostics.training import flight_frame

    df, meta = read_dataset(fleet_features(work, seed, rate))
    fp = table_fingerprint(df, meta)
    # the floors read the health index of the model θ̂ was calibrated with, as the networks do
    flights = flight_frame(df, effects=health_effects(meta))
    dev, test = [int(u) for u in meta["dev_units"]], [int(u) for u in meta["test_units"]]
    order = [int(u) for u in np.random.default_rng(seed).permutation(dev)]
    samples = df[df["unit"].isin(test)]
    test_fl = flights[flights["unit"].isin(test)]
    for n in sizes:
        units = sorted(order[:n])
        key = run_key({"data": fp, "n": n, "floors": list(FLOORS)}, KEY_LENGTH)
        if key not in done:
            fl = floor_predictions(flights[flights["unit"].isin(units)], test_fl)
            rec = {"key": key, "kind": "floors", "fleet": seed, "n": n, "units": units,
                   "floors": {k: scores(to_samples(p, samples)) for k, p in fl.items()}}
            append_run(cache, rec)
            done[key] = rec
        dev_fl = flights[flights["unit"].isin(units)]
        jobs = [(name, {"library": library_body(model, window, column)},
                 partial(library_predict, dev_fl, test_fl, window, samples, column))
                for name, (model, window, column) in LIBRARY.items()]
        for name, (model, inputs, window) in PREDICTORS.items():
            cfg = TrainConfig(model=model, inputs=inputs, window=window, device="cpu")
            jobs.append((name, {"seeds": list(SEEDS), "config": cfg.to_dict()},
                         partial(train_predict, flights, meta, cfg, SEEDS, units, test,
                                 samples)))
        for name, body, run in jobs:
            key = run_key({"data": fp, "n": n, "units": units, **body}, KEY_LENGTH)
            if name not in predictors or key in done:
                continue
            res = run()
            rec = {"key": key, "kind": "model", "fleet": seed, "n": n, "units": units,
                   "predictor": name, **res}
            append_run(cache, rec)
            done[key] = rec
            print(f"[{time.strftime('%H:%M:%S')}] fleet {seed} n {n} {name}: RMSE "
                  f"{res['ensemble']['rmse']:.2f} ({res['seconds']:.0f} s)", flush=True)


def merge_committed(t: pd.DataFrame, committed: pd.DataFrame) -> pd.DataFrame:
    """``t`` (the cache's :func:`runs_table`) with the rows of ``committed`` it lacks, for each
    (fleet, n) whose floors both hold and agree (to the committed table's 4 digits); a
    (fleet, n) of the cache whose floors disagree stops the merge, naming it."""
    floors = [f"floor: {k}" for k in ("life", "hi-lookup")]
    here = t[t["predictor"].isin(floors)].set_index(["fleet", "n", "predictor"])["rmse"]
    there = committed[committed["predictor"].isin(floors)].set_index(
        ["fleet", "n", "predictor"])["rmse"]
    same = set()
    for (fleet, n), g in here.groupby(level=[0, 1]):
        both = g.index.intersection(there.index)
        if len(both) < len(floors):
            continue
        if not np.allclose(g.loc[both], there.loc[both], rtol=1e-3, atol=0.0):
            raise SystemExit(f"error: fleet {fleet}, n {n}: the cache's floors "
                             f"{g.loc[both].round(2).tolist()} differ from the committed "
                             f"{there.loc[both].round(2).tolist()}: not the same fleet")
        same.add((fleet, n))
    have = set(zip(t["fleet"], t["n"], t["predictor"], strict=True))
    extra = committed[[(f, n) in same and (f, n, p) not in have for f, n, p in
                       zip(committed["fleet"], committed["n"], committed["predictor"],
                           strict=True)]]
    return pd.concat([t, extra], ignore_index=True)


def t_interval(x: np.ndarray) -> tuple[float, float, float]:
    """Mean and the 95 % Student-t interval of the mean of ``x``."""
    from scipy.stats import t

    m = float(np.mean(x))
    if len(x) < 2:
        return m, float("nan"), float("nan")
    h = float(t.ppf(0.975, len(x) - 1) * np.std(x, ddof=1) / np.sqrt(len(x)))
    return m, m - h, m + h


def runs_table(runs: list[dict]) -> pd.DataFrame:
    """One row per (fleet, n, predictor) of the cached runs: the columns of ``study_runs.csv``."""

    def life(v: dict) -> dict:  # accuracy over life at λ = 0.5 (runs before it: NaN)
        al = v.get("alpha_lambda")
        return {"within_0.5": al["fraction_within"]["0.5"] if al else np.nan,
                "ra_0.5": al["relative_accuracy"]["0.5"] if al else np.nan}

    def phases(v: dict) -> dict:
        return {col: v["phases"].get(k, np.nan) for k, col in PHASES.items()}

    rows = []
    for r in runs:
        if r["kind"] == "model":
            rows.append({"fleet": r["fleet"], "n": r["n"], "predictor": r["predictor"],
                         "rmse": r["ensemble"]["rmse"], "horizon": r["ensemble"]["horizon"],
                         **life(r["ensemble"]), **phases(r["ensemble"])})
        else:
            rows += [{"fleet": r["fleet"], "n": r["n"], "predictor": f"floor: {k}",
                      "rmse": v["rmse"], "horizon": v["horizon"], **life(v), **phases(v)}
                     for k, v in r["floors"].items()]
    return pd.DataFrame(rows)


def paired(p: pd.DataFrame, a: str, b: str) -> tuple[str, tuple | None]:
    """``a - b`` per fleet (a table of RMSE, fleets x predictors): the cell "mean [95 % CI]
    (fleets)" and (mean, low, high), or "-" and None where either is missing."""
    if a not in p or b not in p:
        return "-", None
    d = (p[a] - p[b]).dropna().to_numpy()
    m, lo, hi = t_interval(d)
    return f"{m:+.2f} [{lo:+.2f}, {hi:+.2f}] ({len(d)})", (m, lo, hi)


def differences(t: pd.DataFrame, pairs: list[tuple[str, str]], title: str,
                curve: dict | None = None) -> list[str]:
    """The Markdown table of ``a - b`` per fleet (:func:`paired`) for each pair and ``n``,
    under ``title``; each interval also joins ``curve[a, b]`` when a curve is given."""
    lines = ["", title, "", "| n units | " + " | ".join(f"{a} - {b}" for a, b in pairs) + " |",
             "|---" * (1 + len(pairs)) + "|"]
    for n, g in t.groupby("n"):
        p = g.pivot_table(index="fleet", columns="predictor", values="rmse")
        cells = []
        for a, b in pairs:
            cell, ci = paired(p, a, b)
            cells.append(cell)
            if ci and curve is not None:
                curve.setdefault((a, b), []).append((n, *ci))
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    return lines


def report(t: pd.DataFrame, results: Path) -> str:
    """Write ``study.md``, ``study.png`` and ``study_runs.csv`` from :func:`runs_table`."""
    if t.empty:
        return "no runs yet"
    results.mkdir(parents=True, exist_ok=True)
    t.to_csv(results / "study_runs.csv", index=False, float_format="%.4g")
    hybrids = [*HYBRIDS, *(h for h in LATER_HYBRIDS if h in set(t["predictor"]))]
    lines = ["# The many-fleet study (issue 30)", "",
             "`python benchmarks/health_study.py` (its docstring). Test RMSE (every sample of "
             "the 6 test units, the seeds' mean prediction), mean over fleets; the difference "
             "hybrid - data-driven per fleet, mean and 95 % CI over fleets.", "",
             "| n units | fleets | " + " | ".join(sorted(t["predictor"].unique())) +
             " | " + " | ".join(f"{h} - data-driven [95 % CI]" for h in hybrids) + " |",
             "|---" * (2 + t["predictor"].nunique() + len(hybrids)) + "|"]
    curve = {(h, "data-driven"): [] for h in hybrids}  # (a, b) -> points of a - b
    for n, g in t.groupby("n"):
        p = g.pivot_table(index="fleet", columns="predictor", values="rmse")
        cells = [f"{p[c].mean():.2f}" if c in p.columns else "-"
                 for c in sorted(t["predictor"].unique())]
        diffs = []
        for h in hybrids:
            cell, ci = paired(p, h, "data-driven")
            diffs.append(cell)
            if ci:
                curve[h, "data-driven"].append((n, *ci))
        lines.append(f"| {n} | {p.shape[0]} | " + " | ".join(cells) + " | " +
                     " | ".join(diffs) + " |")
    floors = [f for f in ("floor: hi-lookup", "floor: life") if f in set(t["predictor"])]
    lines += differences(t, [(h, f) for h in hybrids for f in floors],
                         "What a network adds to the floors: the hybrid minus each floor per "
                         "fleet, mean and 95 % CI over fleets (< 0: the network is better).")
    present = [(a, b) for a, b in COMPARISONS if {a, b} <= set(t["predictor"])]
    if present:
        lines += differences(t, present, "Comparisons fixed in advance (the script's "
                             "docstring): a - b per fleet, mean and 95 % CI over fleets "
                             "(< 0: a is better).", curve)
    cols = [c for c in PHASES.values() if c in t.columns]
    by_phase = t.dropna(subset=cols) if cols else t.iloc[:0]
    if not by_phase.empty:
        lines += ["", "RMSE by phase (before and after the onset of fault, the last 30 cycles), "
                  "mean over the fleets whose runs recorded it (runs cached before it was added "
                  "did not).", "",
                  "| n units | predictor | fleets | " + " | ".join(PHASES) + " |",
                  "|---" * (3 + len(PHASES)) + "|"]
        for (n, pred), g in by_phase.groupby(["n", "predictor"]):
            lines.append(f"| {n} | {pred} | {g['fleet'].nunique()} | " +
                         " | ".join(f"{g[c].mean():.2f}" for c in PHASES.values()) + " |")
    lines += ["", "Accuracy over life at λ = 0.5 (half-way from a unit's first prediction to its "
              "failure; Saxena et al. 2010): the fraction of test units whose prediction lies "
              "within ±20 % of the true RUL, and the mean relative accuracy; mean over the "
              "fleets whose runs recorded it (runs cached before it was added did not).", "",
              "| n units | predictor | fleets | within ±20 % | relative accuracy |",
              "|---|---|---|---|---|"]
    for (n, pred), g in t.dropna(subset=["within_0.5"]).groupby(["n", "predictor"]):
        lines.append(f"| {n} | {pred} | {g['fleet'].nunique()} | {g['within_0.5'].mean():.2f} "
                     f"| {g['ra_0.5'].mean():.2f} |")
    text = "\n".join(lines) + "\n"
    (results / "study.md").write_text(text)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5), dpi=150)
    for (a, b), pts in curve.items():
        if pts:
            n, m, lo, hi = map(np.array, zip(*pts, strict=True))
            ax.errorbar(n, m, yerr=[m - lo, hi - m], marker="o", capsize=4,
                        label=f"{a} - {b}")
    ax.axhline(0.0, color="grey", lw=0.8)
    ax.set_xscale("log", base=2)
    sizes = sorted(t["n"].unique())
    ax.set_xticks(sizes, [str(n) for n in sizes])
    ax.minorticks_off()
    ax.set_xlabel("training units")
    ax.set_title(f"95 % intervals over {t['fleet'].nunique()} fleets")
    ax.set_ylabel("test RMSE difference [cycles] (< 0: "
                  + ("the first is better)" if present else "physics helps)"))
    if ax.get_legend_handles_labels()[0]:  # (no data-driven run and no comparison: no curve)
        ax.legend()
    fig.tight_layout()
    fig.savefig(results / "study.png")
    plt.close(fig)
    return text


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fleets", default="0-9", help="fleet seeds, e.g. 0-9 or 0,3,5")
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)))
    ap.add_argument("--rate", type=float, default=0.05)
    ap.add_argument("--work", type=Path, default=ROOT / "out" / "study")
    ap.add_argument("--results", type=Path, default=None,
                    help="where the tables and the figure go (default: --work; the "
                    "committed ones: benchmarks/results/health_study)")
    ap.add_argument("--report", action="store_true", help="write the tables from the cache")
    names = [*PREDICTORS, *LIBRARY]
    ap.add_argument("--predictors", default=",".join(names),
                    help=f"the predictors that run, of {', '.join(names)} (the floors always)")
    ap.add_argument("--merge-committed", action="store_true",
                    help="add the committed table's rows the cache lacks, for the fleets and "
                    "sizes whose floors the cache reproduces")
    a = ap.parse_args(argv)
    a.work.mkdir(parents=True, exist_ok=True)
    results = a.work if a.results is None else a.results
    predictors = [p.strip() for p in a.predictors.split(",") if p.strip()]
    unknown = sorted(set(predictors) - set(names))
    if unknown:
        ap.error(f"--predictors: unknown {', '.join(unknown)} (known: {', '.join(names)})")
    cache = a.work / "runs.jsonl"
    if not a.report:
        done = {r["key"]: r for r in read_runs(cache)}
        sizes = [int(s) for s in a.sizes.split(",")]
        for seed in parse_range(a.fleets):
            run_fleet(a.work, seed, a.rate, sizes, cache, done, predictors)
    fleets = set(parse_range(a.fleets))  # the tables cover the fleets asked for
    t = runs_table([r for r in read_runs(cache) if r["fleet"] in fleets and (
        r["kind"] == "floors" or r["predictor"] in predictors)])  # ... and predictors
    committed = COMMITTED / "study_runs.csv"
    if t.empty and a.report and committed.is_file():  # no cache here: the committed table
        print(f"no runs in {cache}: the tables from {committed}", file=sys.stderr)
        t = pd.read_csv(committed)
        t = t[t["fleet"].isin(fleets)]
    elif a.merge_committed:
        t = merge_committed(t, pd.read_csv(committed))
    print(report(t, results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

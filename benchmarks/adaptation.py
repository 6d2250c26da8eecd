"""The engine model adapted to NASA's engine from the C-MAPSS FD002 training engines, and what
it changes: the model's error per condition, the health of new engines, FD001's fault.

    python benchmarks/adaptation.py --data-dir ../shared/data/cmapss [--work out/adaptation]
        [--results benchmarks/results/adaptation]

1. ``hyprog data import-cmapss train_FD002.txt`` and ``hyprog adapt`` (every candidate, early
   life = cycles 1-20 of every engine, :data:`ADAPT_OPTIONS`) into ``--work`` (reused when
   there): the record's
   errors per condition and channel before and after, in sample and with the condition left
   out, and the chi-square per sample and channel in sample, condition left out and engines
   left out; each condition's error left out over its std (:func:`z_tables`);
2. early-life health of new engines: ``hyprog calibrate`` of FD002 with the unadapted and the
   adapted model (``--model-effects``), the UKF and its default parameters, and the five
   health parameters that FD001's sensors observe together (:data:`FIVE`); the mean of
   theta_hat over cycles 1-20 per operating condition, its mean over conditions and its
   spread (largest minus smallest condition mean);
3. FD001's fault over life: units 1-20 (the issue's measurement) and every unit calibrated
   with :data:`FIVE`, unadapted and adapted; per unit the change of theta_hat from early life
   (cycles 1-20) to the end (last 10 cycles), the median over units per parameter, how far
   the HPC parameters move against the largest of the others (:func:`hpc_signature`) and
   its bootstrap interval over units;
4. ``hyprog discover`` on the 85 FD002 engines' first 40 cycles (3,400 samples), with the
   unadapted and the adapted model, R as in sections 2 and 3 (``--noise``,
   ``--model-error``): wall time, verdict, what it adds, and the residual before and after.

Every figure is printed as a table and, with ``--results``, written there (``--sections``:
some of them only). ``--noise``, ``--model-error`` and ``--sensors`` are ``hyprog
calibrate``'s, for the calibrations of sections 2 and 3; by
default ``--noise data --model-error consistent``, how measured data are calibrated (the
data's own noise and the model error at which the filter is consistent:
calibration.consistency); ``--noise model --model-error 0`` gives the simulator's noise.
An adapted model already at ``--work``'s ``fd002-adapted.json`` is used as it is (no
``hyprog adapt``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages
sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import file_sha, hyprog, imported  # noqa: E402

#: The five health parameters FD001's eight sensors observe together (a sixth, LPT flow, is
#: reported unobservable by ``hyprog calibrate``).
FIVE = ("fan_eff_mod", "HPC_eff_mod", "HPC_flow_mod", "HPT_eff_mod", "LPT_eff_mod")
#: ``hyprog adapt``'s options for the adapted model when ``--work`` has none: those of the
#: adopted model (2026-11-30, ffda0e17: the flow channels fitted too, six candidates judged
#: per step, the model error shared by each condition, ``hyprog adapt``'s default;
#: docs/adaptation.md). The committed ``adaptation.md`` of ccd7e93d was made with none.
ADAPT_OPTIONS = ("--channels", "T24,T30,T50,P15,P30,Nf,Nc,BPR,W31,W32", "--judge", "6")
EARLY = 20
LATE = 10


def calibrated(raw: Path, work: Path, tag: str, params=None, adapted: Path | None = None,
               units: str | None = None, options: tuple = ()) -> Path:
    """``raw`` calibrated into ``work`` (once) with the UKF, ``params``, the adapted model,
    ``units`` and ``options`` (``hyprog calibrate``'s ``--noise`` / ``--model-error`` /
    ``--sensors`` options, which name the folder too, as do the first 8 hex digits of the
    adapted model's SHA-256: a folder calibrated with another adapted model is not
    reused)."""
    out = work / (f"{raw.name}-{tag}"
                  + ("" if adapted is None else f"-{file_sha(adapted)[:8]}")
                  + "".join(f"-{a.lstrip('-')}" for a in options))
    if not out.exists():
        args = ["calibrate", raw, "--out", out, *options]
        if params:
            args += ["--params", ",".join(params)]
        if adapted is not None:
            args += ["--model-effects", adapted]
        if units:
            args += ["--units", units]
        hyprog(*args, quiet=True)
    return out


def markdown(df: pd.DataFrame, digits: int = 2) -> str:
    """``df`` as a Markdown table (index first)."""
    head = "| | " + " | ".join(map(str, df.columns)) + " |"
    rows = [head, "|---" * (len(df.columns) + 1) + "|"]
    for idx, r in df.iterrows():
        rows.append(f"| {idx} | " + " | ".join(f"{v:.{digits}f}" for v in r.to_numpy(float))
                    + " |")
    return "\n".join(rows)


def error_tables(rec: dict) -> str:
    s = rec["selection"]
    lines = ["Mean error per condition and channel [%] (model minus data, early life):", ""]
    chans = rec["channels"]
    for label, key in (("in sample", "mean_error_pct_in_sample"),
                       ("condition left out", "mean_error_pct_condition_out")):
        for when in ("before", "after"):
            tab = pd.DataFrame(s[key][when]).T.loc[:, chans]
            tab.index = [f"condition {c}" for c in tab.index]
            lines += [f"{label}, {when} (worst |error| {tab.abs().to_numpy().max():.2f} %):",
                      "", markdown(tab), ""]
    lines += ["| chi2 per sample and channel | before | after |", "|---|---|---|"]
    for label, key in (("in sample", "chi2_in_sample"), ("condition left out",
                                                         "chi2_condition_out"),
                       ("engines left out (3 folds)", "chi2_engines_out")):
        lines.append(f"| {label} | {s[key]['before']:.3g} | {s[key]['after']:.3g} |")
    lines += ["", "| candidate | parameter | value | std | valid range | at a bound |",
              "|---|---|---|---|---|---|"]
    for p in rec["parameters"]:
        lines.append(f"| {p['candidate']} | {p['parameter']} | {p['value']:.4g} | "
                     f"{p['std']:.2g} | [{p['valid'][0]:g}, {p['valid'][1]:g}] | "
                     f"{'yes' if p['at_bound'] else 'no'} |")
    lines += ["", "Selection steps (the best candidate of each step, judged with the "
              "condition left out; worst: the largest chi2 of one condition left out):", "",
              "| candidate | chi2 in sample | chi2 condition out | worst condition out | "
              "entered |", "|---|---|---|---|---|"]
    for st in s["steps"]:
        worst = f"{st['worst_out']:.3g}" if "worst_out" in st else "-"
        lines.append(f"| {st['candidate']} | {st['chi2_in']:.3g} | {st['chi2_out']:.3g} | "
                     f"{worst} | {'yes' if st['entered'] else 'no'} |")
    return "\n".join(lines)


def condition_out_std(rec: dict, fd002: Path) -> tuple[dict, str]:
    """The std of each held-out condition's mean error, before and after (the record's own,
    or, for a record written before it recorded them, :func:`calibration.adaptation.assess`
    of the record and of the model as designed refitted to the same data), and a line on
    how the refit's errors compare with the record's."""
    s = rec["selection"]
    if "std_pct_condition_out" in s:
        return s["std_pct_condition_out"], "the adaptation's own record"
    from calibration.adaptation import assess
    from engine_model.datasets import read_dataset

    df, _ = read_dataset(fd002)
    designed = {**rec, "selection": {"chosen": []}, "parameters": []}
    out, gap = {}, 0.0
    for when, r in (("before", designed), ("after", rec)):
        _, oos = assess(df, r, source=str(fd002))
        out[when] = oos.std_pct
        gap = max(gap, *(abs(oos.mean_error_pct[int(c)][ch] - v)
                         for c, row in s["mean_error_pct_condition_out"][when].items()
                         for ch, v in row.items()))
    return out, (f"calibration.adaptation.assess, the record refitted to the same data (its "
                 f"held-out errors within {gap:.3f} % of the record's)")


def z_tables(rec: dict, std: dict, how: str) -> str:
    """Each held-out condition's mean error over its std, before and after."""
    chans = rec["channels"]
    lines = ["Each condition left out: mean error / its std (the std of the mean prediction "
             "under the fit's posterior, the shared parameters and every engine's health, "
             "the readings' noise, and the model's own error, shared by the samples of a "
             "condition: calibration.adaptation.fleet_fit.mean_prediction_std; from "
             f"{how}). A model whose candidates, priors and model error hold is within "
             "about 3; the std itself [%] is the second table:", ""]
    for when in ("before", "after"):
        err = pd.DataFrame(rec["selection"]["mean_error_pct_condition_out"][when]).T
        sd = pd.DataFrame(std[when]).T
        err.index, sd.index = (pd.Index([str(i) for i in t.index]) for t in (err, sd))
        z = (err / sd).loc[:, chans]
        z.index = [f"condition {c}" for c in z.index]
        lines += [f"{when}, error / std:", "", markdown(z, 1), ""]
        if when == "after":
            sd = sd.loc[:, chans]
            sd.index = [f"condition {c}" for c in sd.index]
            lines += [f"{when}, std [%]:", "", markdown(sd, 3), ""]
    return "\n".join(lines)


def early_life_theta(feat: Path) -> pd.DataFrame:
    """Per parameter: mean of theta_hat over cycles 1-EARLY per condition, their mean and
    spread."""
    from engine_model.datasets import read_dataset

    df, _ = read_dataset(feat)
    early = df[df["cycle"] <= EARLY]
    cols = [c for c in early.columns if c.endswith("_mod_hat") and early[c].notna().any()]
    per = early.groupby("condition")[cols].mean() * 100
    out = pd.DataFrame({"mean over conditions [%]": per.mean(),
                        "spread between conditions [%]": per.max() - per.min()})
    out = pd.concat([out, per.T.add_prefix("condition ")], axis=1)
    out.index = [c[:-4] for c in out.index]
    return out


def change_over_life(feat: Path) -> pd.DataFrame:
    """Per unit: mean(theta_hat, last LATE cycles) - mean(first EARLY) [%] of :data:`FIVE`:
    the issue's measurement of FD001's fault. (``cmapss_modes.life_change`` is another
    statistic of the same change, medians of 20 cycles at each end, robust for clustering
    units by fault mode; each feeds its own committed table, so both stay.)"""
    from engine_model.datasets import read_dataset

    df, _ = read_dataset(feat)
    cols = [q + "_hat" for q in FIVE]
    per_unit = {}
    for unit, g in df.groupby("unit"):
        g = g.sort_values("cycle")
        per_unit[unit] = g[cols].tail(LATE).mean() - g[cols].head(EARLY).mean()
    out = pd.DataFrame(per_unit).T * 100
    out.columns = [c[:-4] for c in out.columns]
    return out


def hpc_signature(change: pd.DataFrame) -> float:
    """How far the HPC moves against the rest: the smaller of the HPC parameters' median
    changes over the largest of the others' (absolute values; > 2 is the issue's target)."""
    med = change.median()
    return float(min(abs(med["HPC_eff_mod"]), abs(med["HPC_flow_mod"]))
                 / med.drop(["HPC_eff_mod", "HPC_flow_mod"]).abs().max())


def signature_interval(change: pd.DataFrame, n: int = 2000, seed: int = 0) -> tuple:
    """95 % percentile-bootstrap interval of :func:`hpc_signature` over units (resampled
    with replacement, ``n`` times, seeded)."""
    rng = np.random.default_rng(seed)
    draws = [hpc_signature(change.iloc[rng.integers(0, len(change), len(change))])
             for _ in range(n)]
    return tuple(np.percentile(draws, [2.5, 97.5]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", type=Path, required=True)
    ap.add_argument("--work", type=Path, default=Path("out/adaptation"))
    ap.add_argument("--results", type=Path, default=None)
    ap.add_argument("--noise", choices=("model", "data"), default="data",
                    help="hyprog calibrate --noise for sections 2 and 3")
    ap.add_argument("--model-error", default="consistent",
                    help="hyprog calibrate --model-error for sections 2 and 3 (a number or "
                    "'consistent')")
    ap.add_argument("--sensors", default=None,
                    help="hyprog calibrate --sensors for sections 2 and 3 (default: every "
                    "measured channel x_s of the data; e.g. adding C-MAPSS's flow channels "
                    "BPR,W31,W32, which need --noise data)")
    ap.add_argument("--sections", default="1,2,3,4",
                    help="the sections to run and report (the adapted model is made or "
                    "loaded whichever; it is written to --results with section 1 only)")
    args = ap.parse_args(argv)
    try:
        sections = {int(k) for k in args.sections.split(",")}
    except ValueError:
        sections = set()
    if not sections or not sections <= {1, 2, 3, 4}:
        ap.error(f"--sections {args.sections!r}: some of 1,2,3,4, comma-separated")
    noise = (() if args.noise == "model" else ("--noise", args.noise)) + (
        () if args.model_error in ("0", "0.0") else ("--model-error", args.model_error))
    # the calibrations' options: discover (section 4) reads x_s with the same R
    calibrate = noise + (() if args.sensors is None else ("--sensors", args.sensors))
    args.work.mkdir(parents=True, exist_ok=True)
    report = []

    fd002 = imported(args.data_dir, args.work, "FD002")
    adapted = args.work / "fd002-adapted.json"
    if not adapted.exists():
        t0 = time.perf_counter()
        hyprog("adapt", fd002, "--out", adapted, *ADAPT_OPTIONS, quiet=True)
        print(f"adapted in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    if 1 in sections:
        report += section_1(json.loads(adapted.read_text()), fd002)
    if 2 in sections:
        report += section_2(args, fd002, adapted, calibrate)
    if 3 in sections:  # (its calibration options are said by section 2 when it runs)
        report += section_3(args, adapted, calibrate, say_options=2 not in sections)
    if 4 in sections:
        report += section_4(args, fd002, adapted, noise)
    text = "\n".join(report)
    print(text)
    if args.results is not None:
        args.results.mkdir(parents=True, exist_ok=True)
        (args.results / "adaptation.md").write_text(text + "\n")
        if 1 in sections:
            (args.results / "fd002-adapted.json").write_text(adapted.read_text())
    return 0


def section_1(rec: dict, fd002: Path) -> list[str]:
    """The adaptation's record ``rec``: its errors and each condition's error left out over
    its std: the lines."""
    return ["## 1. The adaptation (FD002, every engine, cycles 1-20)", "",
            f"Chosen, in order: {', '.join(rec['selection']['chosen']) or 'nothing'}; "
            f"{rec['data']['units']} engines, {rec['data']['samples']} samples, "
            f"{rec['seconds']:.0f} s.", "", error_tables(rec), "",
            z_tables(rec, *condition_out_std(rec, fd002)), ""]


def section_2(args, fd002: Path, adapted: Path, options: tuple) -> list[str]:
    """Early-life theta_hat of the FD002 engines, unadapted and adapted: the lines."""
    report = ["## 2. Early-life health of the FD002 engines [%]", "",
              f"Calibrated with {' '.join(options) or 'the simulator noise'} (sections 2, 3).",
              ""]
    for params, label in ((None, "default parameters"), (FIVE, "the five of FD001")):
        tag = "default" if params is None else "five"
        for model, path in (("unadapted", None), ("adapted", adapted)):
            feat = calibrated(fd002, args.work, f"{tag}-{model}", params, path,
                              options=options)
            tab = early_life_theta(feat)
            report += [f"{label}, {model} model:", "", markdown(tab), ""]
    return report


def section_3(args, adapted: Path, options: tuple, say_options: bool) -> list[str]:
    """FD001's change of theta_hat over life, unadapted and adapted: the lines (with the
    calibration's ``options`` when ``say_options``)."""
    said = (f" Calibrated with {' '.join(options) or 'the simulator noise'}." if say_options
            else "")
    report = ["## 3. FD001: change of theta_hat over life, median over units [%]", "",
              f"Per unit, the mean of the last {LATE} cycles minus the mean of the first "
              f"{EARLY}; units 1-20 (the issue's measurement) and every unit (each "
              "calibration on its own units, so the consistent model error is estimated on "
              "them); the interval is a 95 % bootstrap over units (2,000 draws, seed 0)."
              + said, ""]
    fd001 = imported(args.data_dir, args.work, "FD001")
    rows, intervals = {}, {}
    for units, tag in ((",".join(map(str, range(1, 21))), "units 1-20"), (None, "every unit")):
        for model, path in (("unadapted", None), ("adapted", adapted)):
            name = f"five-{model}" if units else f"five-{model}-all"
            change = change_over_life(calibrated(fd001, args.work, name, FIVE, path, units,
                                                 options))
            label = f"{model}, {tag} ({len(change)})"
            rows[label] = {**change.median().to_dict(),
                           "smaller HPC / largest other": hpc_signature(change)}
            intervals[label] = signature_interval(change)
    tab = pd.DataFrame(rows).T
    report += [markdown(tab, 3), "", "| | 95 % interval of the HPC signature |", "|---|---|"]
    report += [f"| {k} | {lo:.2f} - {hi:.2f} |" for k, (lo, hi) in intervals.items()]
    return report + [""]


def section_4(args, fd002: Path, adapted: Path, noise: tuple) -> list[str]:
    """``hyprog discover`` on FD002's first 40 cycles, unadapted and adapted: the lines."""
    report = ["## 4. hyprog discover on the FD002 engines' first 40 cycles", "",
              f"R: {' '.join(noise) or 'the simulator noise'} (as sections 2, 3); chi2 per "
              "degree of freedom of the whitened residual before and after the loop.", "",
              "| model | samples | sensors | wall s | verdict | added | chi2/dof before | "
              "after |", "|---|---|---|---|---|---|---|---|"]
    first40 = args.work / "fd002-first40"
    if not first40.exists():
        from engine_model.datasets import read_dataset, write_parquet
        df, meta = read_dataset(fd002)
        write_parquet(df[df["cycle"] <= 40].reset_index(drop=True), first40, meta)
    for model, path in (("unadapted", None), ("adapted", adapted)):
        out = args.work / f"discover-{model}"
        extra = [] if path is None else ["--model-effects", path]
        t0 = time.perf_counter()
        hyprog("discover", first40, "--out", out, "--overwrite", *extra, *noise, quiet=True)
        wall = time.perf_counter() - t0
        d = json.loads((out / "discover.json").read_text())
        added = ", ".join(f["spec"] for f in d["found"]) or "-"
        report.append(f"| {model} | {d['diagnostics']['samples']} | "
                      f"{', '.join(d['diagnostics']['sensors'])} | {wall:.0f} | "
                      f"{d['verdict']} | {added} | {d['before']['chi2_per_dof']:.3g} | "
                      f"{d['after']['chi2_per_dof']:.3g} |")
    return report


if __name__ == "__main__":
    raise SystemExit(main())

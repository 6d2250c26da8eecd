"""The experiment's report: per-run CSV, aggregated tables (Markdown + CSV), claims, figures.

Written into the experiment's output directory (atomically, :mod:`prognostics.outputs`):

- ``runs.csv``: one row per training run (``part, model, inputs, perturbation, train_units,
  conformal_units, seed, rmse, score, rmse_last, score_last, horizon, coverage, width,
  best_epoch, epochs_run, parameters, seconds, key``), and one ``baseline`` row.
- ``tables/<table>.csv`` and ``tables.md``: ``main`` (mean ± std over seeds, relative change
  hybrid vs data-driven, the seed ensembles), ``horizon`` (per test unit), ``small``
  (ablation I), ``features`` (ablation III), ``calibration`` (ablation IV), ``conformal``;
  the physics-only baseline is a row of every table. ``rel. change = (hybrid - data-driven)
  / data-driven`` of the means.
- the paper's claims, each marked reproduced or not with the numbers (``tables.md``).
- ``figures/``: predicted vs true RUL per test unit (per-cycle mean, min/max band, conformal
  interval), θ̂ trajectories, training curves. Without figures (``ExperimentConfig.figures``
  False, ``--no-figures``) an earlier run's figures are removed rather than left beside
  tables they may no longer match.

``s`` is the NASA score summed over all test samples (the paper's ``s``; it scales with the
number of samples, so compare it within one data set only).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from engine_model.channels import THETA_NAMES
from prognostics.metrics import evaluate_predictions, per_cycle
from prognostics.outputs import write_table, write_text

from .plan import PERFECT

METRICS = ("rmse", "score", "rmse_last", "score_last", "horizon", "coverage", "width")


def run_rows(records: list[dict], base: dict | None) -> pd.DataFrame:
    rows = []
    for r in records:
        run, m = r["run"], r["metrics"]
        s = m["samples"]["overall"]
        rows.append({
            "part": run["part"], "model": run["model"], "inputs": run["inputs"],
            "perturbation": run.get("perturbation") or "",
            "train_units": ",".join(map(str, run.get("units") or [])) or "dev",
            "conformal_units": ",".join(map(str, run.get("conformal_units") or [])),
            "seed": run["seed"], "rmse": s["rmse"], "score": s["score"],
            "rmse_last": m["last"]["overall"]["rmse"],
            "score_last": m["last"]["overall"]["score"], "horizon": m["horizon"]["mean"],
            "coverage": s.get("coverage", np.nan), "width": s.get("width", np.nan),
            "best_epoch": r.get("best_epoch"), "epochs_run": len(r.get("history") or []),
            "parameters": r.get("parameters"), "seconds": r.get("seconds"), "key": r["key"]})
    if base is not None:
        m = base["metrics"]
        rows.append({"part": "baseline", "model": "physics", "inputs": "theta_hat HI trend",
                     "perturbation": "", "train_units": "", "conformal_units": "",
                     "seed": np.nan, "rmse": m["samples"]["overall"]["rmse"],
                     "score": m["samples"]["overall"]["score"],
                     "rmse_last": m["last"]["overall"]["rmse"],
                     "score_last": m["last"]["overall"]["score"],
                     "horizon": m["horizon"]["mean"], "coverage": np.nan, "width": np.nan,
                     "best_epoch": np.nan, "epochs_run": 0, "parameters": 0,
                     "seconds": base.get("seconds"), "key": base["key"]})
    out = pd.DataFrame(rows)
    for c in ("seed", "best_epoch", "epochs_run", "parameters"):
        out[c] = out[c].astype("Int64")
    return out


def life_table(runs: list[tuple[dict, pd.DataFrame]]) -> pd.DataFrame:
    """Accuracy over life (:func:`prognostics.metrics.lambda_accuracy`: α-λ at α = 0.2 and
    relative accuracy, per λ) of every configuration, mean ± std over its seeds, from each
    run's record and per-cycle predictions (``unit``, ``cycle``, ``RUL``, ``mean``)."""
    from prognostics.metrics import LAMBDAS, lambda_accuracy

    rows = []
    for rec, pc in runs:
        run = rec["run"]
        al = lambda_accuracy(pc)
        row = {"part": run["part"], "model": run["model"], "inputs": run["inputs"],
               "perturbation": run.get("perturbation") or "", "seed": run["seed"]}
        for lam in LAMBDAS:
            row[f"within_{lam:g}"] = al["fraction_within"][f"{lam:g}"]
            row[f"ra_{lam:g}"] = al["relative_accuracy"][f"{lam:g}"]
        rows.append(row)
    if not rows:
        return pd.DataFrame()
    t = pd.DataFrame(rows)
    by = ["part", "model", "inputs", "perturbation"]
    out = []
    for key, g in t.groupby(by, sort=True):
        row = dict(zip(by, key, strict=True))
        row["runs"] = len(g)
        for lam in LAMBDAS:
            w, ra = g[f"within_{lam:g}"], g[f"ra_{lam:g}"]
            row[f"within ±20 % at λ {lam:g}"] = _pm(w.mean(), w.std(ddof=1) if len(g) > 1
                                                    else np.nan, ".2f")
            row[f"RA at λ {lam:g}"] = _pm(ra.mean(), ra.std(ddof=1) if len(g) > 1
                                          else np.nan, ".2f")
        out.append(row)
    return pd.DataFrame(out)


def _agg(rows: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    g = rows.groupby(by, sort=False)
    out = g.size().rename("runs").reset_index()
    for m in METRICS:
        out[m + "_mean"] = g[m].mean().to_numpy()
        out[m + "_std"] = g[m].std(ddof=1).fillna(0.0).to_numpy()
    return out


def _pm(mean, std, fmt=".3g") -> str:
    if mean is None or not np.isfinite(mean):
        return "–"
    return f"{mean:{fmt}} ± {std:{fmt}}" if std and np.isfinite(std) else f"{mean:{fmt}}"


def _rel(new, old) -> str:
    if not (np.isfinite(new) and np.isfinite(old)) or old == 0:
        return "–"
    return f"{100 * (new - old) / abs(old):+.0f} %"


def _md(df: pd.DataFrame) -> str:
    cols = list(df.columns)
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    lines += ["| " + " | ".join(str(v) for v in row) + " |" for row in df.itertuples(index=False)]
    return "\n".join(lines)


def _base_cells(base: dict | None) -> dict:
    if base is None:
        return {}
    m = base["metrics"]
    return {"rmse": m["samples"]["overall"]["rmse"], "score": m["samples"]["overall"]["score"],
            "rmse_last": m["last"]["overall"]["rmse"],
            "score_last": m["last"]["overall"]["score"], "horizon": m["horizon"]["mean"]}


def _row(a: pd.Series | None, metrics=("rmse", "score", "rmse_last", "score_last", "horizon")):
    if a is None:
        return ["–"] * len(metrics)
    return [_pm(a[m + "_mean"], a[m + "_std"]) for m in metrics]


def _pick(agg: pd.DataFrame, **kw) -> pd.Series | None:
    sel = agg
    for k, v in kw.items():
        sel = sel[sel[k] == v]
    return None if sel.empty else sel.iloc[0]


def _ensemble(out: Path, rows: pd.DataFrame) -> tuple[dict, pd.DataFrame] | None:
    preds = [pd.read_parquet(out / "runs" / k / "predictions.parquet") for k in rows["key"]]
    if not preds:
        return None
    p = preds[0].drop(columns=[c for c in preds[0].columns if c.startswith("RUL_")]).copy()
    stack = np.stack([q["RUL_pred"].to_numpy() for q in preds])
    p["RUL_pred"] = stack.mean(axis=0)
    if len(preds) > 1:
        p["RUL_std"] = stack.std(axis=0, ddof=1)
    metrics = evaluate_predictions(p)
    if len(preds) > 1:
        metrics["spread"] = float(p["RUL_std"].mean())
    pooled = pd.concat([q[["unit", "cycle", "RUL", "RUL_pred"]] for q in preds])
    pc = per_cycle(pooled).drop(columns="mean").merge(
        per_cycle(p)[["unit", "cycle", "mean"]], on=["unit", "cycle"])
    return metrics, pc


def _main_table(out: Path, rows: pd.DataFrame, agg: pd.DataFrame, base: dict | None,
                figures: Path | None) -> tuple[pd.DataFrame, dict]:
    """The main table and its seed ensembles; their figures drawn into ``figures`` (None:
    none drawn)."""
    from prognostics.plots import plot_rul

    head = ["model", "inputs", "runs", "RMSE", "s", "RMSE (last cycle)", "s (last cycle)",
            "horizon [cycles]"]
    table, ens = [], {}
    for model in ("fnn", "cnn"):
        a = {s: _pick(agg, part="main", model=model, inputs=s) for s in ("data-driven", "hybrid")}
        for s, r in a.items():
            table.append([model.upper(), s, 0 if r is None else int(r["runs"]), *_row(r)])
        if a["data-driven"] is not None and a["hybrid"] is not None:
            table.append([model.upper(), "rel. change", "", *[
                _rel(a["hybrid"][m + "_mean"], a["data-driven"][m + "_mean"])
                for m in ("rmse", "score", "rmse_last", "score_last", "horizon")]])
        for s in ("data-driven", "hybrid"):
            sel = rows[(rows.part == "main") & (rows.model == model) & (rows.inputs == s)]
            res = _ensemble(out, sel) if len(sel) else None
            if res is None:
                continue
            m, pc = res
            ens[(model, s)] = m
            spread = f", spread {m['spread']:.3g}" if "spread" in m else ""
            table.append([model.upper(), f"{s} ensemble ({len(sel)} seeds{spread})", len(sel),
                          f"{m['samples']['overall']['rmse']:.3g}",
                          f"{m['samples']['overall']['score']:.3g}",
                          f"{m['last']['overall']['rmse']:.3g}",
                          f"{m['last']['overall']['score']:.3g}",
                          f"{m['horizon']['mean']:.3g}"])
            if figures is not None:
                plot_rul(pc, f"{model.upper()} {s}: ensemble of {len(sel)} seeds",
                         figures / f"rul_main_{model}_{s}.png")
    b = _base_cells(base)
    if b:
        table.append(["physics", "baseline (θ̂ HI trend)", 1,
                      *[f"{b[m]:.3g}" for m in ("rmse", "score", "rmse_last", "score_last",
                                                  "horizon")]])
    return pd.DataFrame(table, columns=head), ens


def _horizon_table(records: list[dict], base: dict | None) -> pd.DataFrame:
    per = {}
    for r in records:
        run = r["run"]
        if run["part"] != "main":
            continue
        for u, h in r["metrics"]["horizon"]["units"].items():
            per.setdefault((run["model"], run["inputs"], int(u)), []).append(h)
    units = sorted({u for (_, _, u) in per})
    cols = [(m, s) for m in ("fnn", "cnn") for s in ("data-driven", "hybrid")]
    rows = []

    def mean(vals):
        return float(np.mean(vals)) if vals else np.nan

    for u in [*units, "fleet"]:
        vals = {}
        for c in cols:
            vals[c] = mean(per.get((*c, u), [])) if u != "fleet" else \
                mean([mean(per.get((*c, v), [])) for v in units])
        bh = np.nan
        if base is not None:
            bu = base["metrics"]["horizon"]["units"]
            bh = float(bu[str(u)]) if u != "fleet" and str(u) in bu else \
                (base["metrics"]["horizon"]["mean"] if u == "fleet" else np.nan)
        rows.append([u, *[f"{vals[c]:.3g}" if np.isfinite(vals[c]) else "–" for c in cols],
                     _rel(vals[("cnn", "hybrid")], vals[("cnn", "data-driven")]),
                     f"{bh:.3g}" if np.isfinite(bh) else "–"])
    head = ["unit", "FNN data-driven", "FNN hybrid", "CNN data-driven", "CNN hybrid",
            "CNN rel. change", "physics baseline"]
    return pd.DataFrame(rows, columns=head)


def _rows_table(agg: pd.DataFrame, picks, base: dict | None, first: str,
                extra: list | None = None) -> pd.DataFrame:
    """One row per ``(label, filter)`` of ``picks`` that ``agg`` has (RMSE, s, last-cycle
    RMSE), after the ``extra`` rows, then the physics baseline."""
    rows = [r for r in (extra or [])]
    for label, where in picks:
        a = _pick(agg, **where)
        if a is not None:
            rows.append([label, int(a["runs"]), *_row(a, ("rmse", "score", "rmse_last"))])
    b = _base_cells(base)
    if b:
        rows.append(["physics baseline", 1, f"{b['rmse']:.3g}", f"{b['score']:.3g}",
                     f"{b['rmse_last']:.3g}"])
    return pd.DataFrame(rows, columns=[first, "runs", "RMSE", "s", "RMSE (last cycle)"])


def _simple_table(agg: pd.DataFrame, part: str, key: str, order, base: dict | None,
                  extra: list | None = None) -> pd.DataFrame:
    return _rows_table(agg, [(v, {"part": part, key: v}) for v in order], base, key, extra)


FEATURE_ROWS = (  # ablation III: (inputs, perturbation, label)
    ("data-driven", "", "data-driven [w, x_s]"),
    ("denoised", PERFECT, "denoised [w, x_s, x̂_s], perfect calibration"),
    ("virtual", PERFECT, "virtual [w, x_s, x̂_s, x̂_v], perfect calibration"),
    ("hybrid", PERFECT, "hybrid [w, x_s, x̂_s, x̂_v, θ], perfect calibration"),
    ("denoised", "", "denoised, calibrated θ̂"),
    ("virtual", "", "virtual, calibrated θ̂"),
    ("hybrid", "", "hybrid, calibrated θ̂"),
    ("truth-theta", "", "truth-theta (true θ, x̂ from θ̂)"),
)


def _features_table(agg: pd.DataFrame, base: dict | None) -> pd.DataFrame:
    picks = [(label, {"part": "features", "inputs": inputs, "perturbation": pert})
             for inputs, pert, label in FEATURE_ROWS]
    return _rows_table(agg, picks, base, "inputs (CNN)")


def _small_table(agg: pd.DataFrame, base: dict | None) -> pd.DataFrame:
    rows = []
    for s in ("data-driven", "hybrid"):
        full = _pick(agg, part="main", model="cnn", inputs=s)
        small = _pick(agg, part="small", model="cnn", inputs=s)
        if small is None:
            continue
        rows.append([s, *_row(full, ("rmse", "score")), *_row(small, ("rmse", "score")),
                     _rel(small["rmse_mean"], full["rmse_mean"]) if full is not None else "–",
                     _rel(small["score_mean"], full["score_mean"]) if full is not None else "–"])
    b = _base_cells(base)
    if b:
        rows.append(["physics baseline", f"{b['rmse']:.3g}", f"{b['score']:.3g}",
                     f"{b['rmse']:.3g}", f"{b['score']:.3g}", "+0 %", "+0 %"])
    head = ["inputs (CNN)", "RMSE all dev units", "s all dev units", "RMSE small set",
            "s small set", "rel. change RMSE", "rel. change s"]
    return pd.DataFrame(rows, columns=head)


def _conformal_table(agg: pd.DataFrame, alpha: float) -> pd.DataFrame:
    rows = []
    for s in ("data-driven", "hybrid"):
        a = _pick(agg, part="conformal", inputs=s)
        if a is not None:
            rows.append([s, int(a["runs"]), f"{1 - alpha:.2f}",
                         *_row(a, ("coverage", "width", "rmse"))])
    return pd.DataFrame(rows, columns=["inputs (CNN)", "runs", "nominal", "coverage",
                                       "mean width [cycles]", "RMSE"])


def _claims(agg: pd.DataFrame) -> list[str]:
    out = []

    def mean(**kw):
        a = _pick(agg, **kw)
        return None if a is None else float(a["rmse_mean"])

    def say(text, ok, numbers):
        verdict = {True: "reproduced", False: "not reproduced"}.get(ok, ok)
        out.append(f"- {text}: **{verdict}** ({numbers})")

    for model in ("fnn", "cnn"):
        d, h = mean(part="main", model=model, inputs="data-driven"), \
            mean(part="main", model=model, inputs="hybrid")
        if d is not None and h is not None:
            say(f"{model.upper()}: hybrid beats data-driven (RMSE)", h < d,
                f"{h:.3g} vs {d:.3g}, {_rel(h, d)}")
    dh = _pick(agg, part="main", model="cnn", inputs="hybrid")
    dd = _pick(agg, part="main", model="cnn", inputs="data-driven")
    if dh is not None and dd is not None:
        say("CNN: hybrid has the longer prediction horizon", dh["horizon_mean"] >
            dd["horizon_mean"], f"{dh['horizon_mean']:.3g} vs {dd['horizon_mean']:.3g} cycles")
    sd, sh = mean(part="small", inputs="data-driven"), mean(part="small", inputs="hybrid")
    fd, fh = mean(part="main", model="cnn", inputs="data-driven"), \
        mean(part="main", model="cnn", inputs="hybrid")
    if None not in (sd, sh, fd, fh):
        # the claim is about a loss; where neither model loses, the data cannot test it
        ok = "not tested (both improve with fewer units)" if sh <= fh and sd <= fd else \
            (sh - fh) / fh < (sd - fd) / fd
        say("ablation I: with fewer training units the hybrid loses less than data-driven",
            ok, f"hybrid {_rel(sh, fh)}, data-driven {_rel(sd, fd)}; small set hybrid "
            f"{sh:.3g} vs data-driven {sd:.3g}")
    seq = [("data-driven", mean(part="features", inputs="data-driven", perturbation=""))] + \
        [(s, mean(part="features", inputs=s, perturbation=PERFECT))
         for s in ("denoised", "virtual", "hybrid")]
    if all(v is not None for _, v in seq):
        vals = [v for _, v in seq]
        say("ablation III: each added physics feature group lowers the RMSE (perfect "
            "calibration)", all(b < a for a, b in zip(vals, vals[1:], strict=False)),
            " -> ".join(f"{s} {v:.3g}" for s, v in seq))
        cal = mean(part="features", inputs="hybrid", perturbation="")
        if cal is not None:
            say("ablation III: perfect calibration does at least as well as θ̂",
                vals[-1] <= cal, f"hybrid perfect {vals[-1]:.3g} vs calibrated {cal:.3g}")
    pert = [(p, mean(part="calibration", perturbation=p))
            for p in ("snr20", "snr15", "bias+0.5", "bias-0.5")]
    if fd is not None and all(v is not None for _, v in pert):
        say("ablation IV: hybrid with noisy / biased θ̂ still beats data-driven",
            all(v < fd for _, v in pert),
            ", ".join(f"{p} {v:.3g}" for p, v in pert) + f"; data-driven {fd:.3g}")
    return out


def write_report(out: Path, records: list[dict], base: dict | None, df: pd.DataFrame,
                 cfg) -> dict:
    """Write everything listed in the module docstring; returns the paths written."""
    from prognostics.plots import plot_rul

    out = Path(out)
    figures, tables = out / "figures", out / "tables"
    draw = cfg.figures
    if not draw:  # an earlier run's figures may not match the tables any more
        _remove_own_figures(figures)
    rows = run_rows(records, base)
    write_table(out / "runs.csv", rows)
    trained = rows[rows.part != "baseline"].copy()
    agg = _agg(trained, ["part", "model", "inputs", "perturbation"])
    main, _ = _main_table(out, trained, agg, base, figures if draw else None)
    sections = {"main": ("Main table: data-driven vs hybrid (test units, mean ± std over seeds)",
                         main),
                "horizon": ("Prediction horizon t_EOL - t(|Δ| <= 5) per test unit [cycles], "
                            "mean over seeds", _horizon_table(records, base)),
                "life": ("Accuracy over life (Saxena et al. 2010): fraction of the test units "
                         "within ±20 % of the true RUL at λ of their life, and relative "
                         "accuracy, mean ± std over seeds",
                         life_table([(r, per_cycle(pd.read_parquet(
                             out / "runs" / r["key"] / "predictions.parquet")))
                             for r in records]))}
    parts = set(cfg.parts)
    if "small" in parts:
        sections["small"] = (f"Ablation I: CNN trained on units "
                             f"{', '.join(map(str, cfg.small_units))} only",
                             _small_table(agg, base))
    if "features" in parts:
        sections["features"] = ("Ablation III: physics-derived input groups (CNN); perfect "
                                "calibration: x̂_s, x̂_v and θ at their true values",
                                _features_table(agg, base))
    if "calibration" in parts:
        ref = []
        for s in ("hybrid", "data-driven"):
            a = _pick(agg, part="main", model="cnn", inputs=s)
            if a is not None:
                ref.append([f"clean θ̂ ({s}, main)", int(a["runs"]),
                            *_row(a, ("rmse", "score", "rmse_last"))])
        sections["calibration"] = ("Ablation IV: hybrid CNN with degraded θ̂",
                                   _simple_table(agg, "calibration", "perturbation",
                                                 ("snr20", "snr15", "bias+0.5", "bias-0.5"),
                                                 base, ref))
    if "conformal" in parts:
        sections["conformal"] = (f"Split-conformal intervals at level {1 - cfg.alpha:.2f} "
                                 "(one held-out development unit per seed; test units)",
                                 _conformal_table(agg, cfg.alpha))
        for s in ("data-driven", "hybrid"):
            sel = trained[(trained.part == "conformal") & (trained.inputs == s)]
            if draw and len(sel):
                p = pd.read_parquet(out / "runs" / sel["key"].iloc[0] / "predictions.parquet")
                plot_rul(per_cycle(p), f"CNN {s} with conformal interval (seed "
                         f"{int(sel['seed'].iloc[0])})", figures / f"rul_conformal_{s}.png")
    md = ["# Prognostics experiment", "",
          "RMSE and s (NASA score, summed over samples) on every test sample; *last cycle*: "
          "one prediction per test unit at its last observed cycle.", ""]
    for name, (title, table) in sections.items():
        write_table(tables / f"{name}.csv", table)
        md += [f"## {title}", "", _md(table), ""]
    claims = _claims(agg)
    if claims:
        md += ["## The paper's claims on this data", "", *claims, ""]
    write_text(out / "tables.md", "\n".join(md))
    if draw:
        _figures(out, records, base, df, figures)
    return {"tables": str(out / "tables.md"), "runs": str(out / "runs.csv"),
            "figures": [str(p) for p in _own_figures(figures)] if draw else []}


#: The figures this report draws; nothing else in ``OUT/figures`` is the report's.
OWN_FIGURES = ("rul_main_*.png", "rul_conformal_*.png", "theta_hat.png", "rul_baseline.png",
               "training_curves.png")


def _own_figures(figures: Path) -> list[Path]:
    """The report's own PNGs in ``figures`` (see :data:`OWN_FIGURES`), sorted."""
    if not figures.is_dir():
        return []
    return sorted({p for pattern in OWN_FIGURES for p in figures.glob(pattern)
                   if p.is_symlink() or p.is_file()})  # a folder of that name is not one


def _remove_own_figures(figures: Path) -> None:
    """Delete an earlier run's figures of this report, and nothing else.

    A user's own files in ``OUT/figures`` are kept, and a ``figures`` that is a symbolic link
    is left alone (deleting through it would reach outside ``OUT``); the folder is removed only
    when nothing is left in it.
    """
    if figures.is_symlink() or not figures.is_dir():
        return
    for png in _own_figures(figures):
        png.unlink()
    if not any(figures.iterdir()):
        figures.rmdir()


def _figures(out: Path, records: list[dict], base: dict | None, df: pd.DataFrame,
             figures: Path) -> None:
    """θ̂ per cycle, the physics baseline's RUL and the main runs' training curves."""
    from prognostics.baseline import theta_per_cycle
    from prognostics.plots import plot_rul, plot_theta, plot_training_curves

    hats = [q for q in THETA_NAMES if q + "_hat" in df.columns]
    if hats:
        th = theta_per_cycle(df)
        truth = theta_per_cycle(df, suffix="") if all(q in df.columns for q in hats) else None
        plot_theta(th, hats, figures / "theta_hat.png", truth)
    if base is not None:
        bp = pd.read_parquet(out / "runs" / base["key"] / "predictions.parquet")
        plot_rul(per_cycle(bp), "physics-only baseline (θ̂ health-index trend)",
                 figures / "rul_baseline.png")
    curves = {}
    for r in records:
        run = r["run"]
        label = f"{run['model']} {run['inputs']}"
        if run["part"] == "main" and label not in curves:
            curves[label] = r["history"]
    if curves:
        plot_training_curves(curves, figures / "training_curves.png")

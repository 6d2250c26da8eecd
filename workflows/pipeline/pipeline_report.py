"""The pipeline's report: ``report.md``, ``report.html`` (self-contained), ``metrics.json`` and
the PNG figures in ``OUT/figures``, all written atomically.

Sections: a summary a reader can act on (per test unit and input set: the predicted RUL at the
last observed cycle with its interval and, where known, the true RUL; the discrepancy verdict;
the calibration's quality), then the details: the fleet (units, split, cycles, end of life,
onset of abnormal degradation), the
calibration's accuracy against the true theta where the data carry it (RMSE, bias and the
fraction of samples whose truth lies inside theta_hat ± 1.96 std), theta_hat trajectories
(per-cycle means, truth dashed), the discrepancy findings before and after, the RUL metrics per
test unit of every input set (both protocols of :mod:`prognostics.metrics`), predicted against
true RUL with the interval, accuracy over life (α-λ, relative accuracy) and the error against
true RUL (box plots), training curves, the timings (the report's own up to its writing), the
configuration, the versions and the seed. The "all" rows appear only with several test units.

``metrics.json`` holds every number of the report except the timings and the paths, so two runs
with the same configuration, data and seed give identical files (the timings are in
``report.md`` and ``run.json``); its ``config`` leaves out the ``[run]`` table (workers, Dask
scheduler), which changes no number, so a run on 2 workers or a cluster writes the file a
serial run writes.
"""

from __future__ import annotations

import platform
import time
from importlib import metadata as importlib_metadata
from pathlib import Path

import numpy as np
import pandas as pd

from engine_model.channels import THETA_NAMES
from prognostics.metrics import per_cycle
from prognostics.outputs import write_bytes, write_json, write_text

from . import document
from .config import results_config, to_toml

FIGURES = "figures"
PACKAGES = ("numpy", "pandas", "scipy", "torch", "casadi", "pyarrow", "matplotlib")
Z95 = 1.959964


def versions() -> dict:
    from engine_model.datasets import hyprog_version

    out = {"hyprog": hyprog_version(), "python": platform.python_version()}
    for p in PACKAGES:
        try:
            out[p] = importlib_metadata.version(p)
        except importlib_metadata.PackageNotFoundError:
            out[p] = None
    return out


def calibration_accuracy(df: pd.DataFrame) -> dict | None:
    """theta_hat against the true theta per parameter, overall and per unit (None when the
    table has no truth)."""
    qs = [q for q in THETA_NAMES if q + "_hat" in df.columns and q in df.columns]
    if not qs:
        return None

    def stats(g):
        out = {}
        for q in qs:
            e = g[q + "_hat"].to_numpy(float) - g[q].to_numpy(float)
            s = g.get(q + "_hat_std")
            row = {"rmse": float(np.sqrt(np.mean(e * e))), "bias": float(np.mean(e))}
            if s is not None:
                row["coverage95"] = float(np.mean(np.abs(e) <= Z95 * s.to_numpy(float)))
            out[q] = row
        return out

    return {"overall": stats(df), "units": {str(int(u)): stats(g)
                                            for u, g in df.groupby("unit", sort=True)}}


def _f(v, fmt=".3g"):
    return "–" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{v:{fmt}}"


def _fleet_blocks(fleet: dict, split: dict) -> list:
    rows = [[u["unit"], "test" if u["unit"] in split["test"] else
             ("dev (conformal)" if u["unit"] in split["conformal"] else
              "dev" if u["unit"] in split["dev"] else "unused"),
             u["rows"], u["cycles"], u["eol"], _f(u["t_s"], "d") if u["t_s"] else "–",
             ",".join(map(str, u["Fc"]))] for u in fleet["units"]]
    how = {"config": "from the config's [data] table",
           "metadata": "from the data's metadata (dev_units / test_units)",
           "last unit": "no split in the metadata: the last unit is the test unit"}[split["how"]]
    conf = (f"units {', '.join(map(str, split['conformal']))} are held out to calibrate a "
            "split-conformal interval" if split["conformal"] else
            "no conformal units: with this few development units none is held out, so the "
            "report has no calibrated interval (set [data] conformal_units to get one)")
    t = fleet["totals"]
    return [("h", 2, "Fleet"),
            ("p", f"{t['units']} units, {t['rows']:,} samples, {t['cycles']:,} flight cycles"
                  + (f" at {_f(fleet['sample_rate_hz'])} Hz" if fleet.get("sample_rate_hz")
                     else " (one sample a cycle)" if t["rows"] == t["cycles"] else "")
                  + (f"; preset {fleet['preset']}, seed {fleet['seed']}"
                     if "preset" in fleet else "") + f". Split {how}; {conf}."),
            ("table", ["unit", "role", "samples", "cycles", "end of life", "onset t_s",
                       "flight classes"], rows)]


def _accuracy_rows(acc: dict) -> list:
    return [[q, _f(v["rmse"]), _f(v["bias"], "+.2e"), _f(v.get("coverage95"), ".3f")]
            for q, v in acc["overall"].items()]


def _calibration_blocks(cal: dict, acc: dict | None, theta_png: Path | None,
                        before: dict | None = None, effects: list | None = None) -> list:
    out = [("h", 2, "Calibration"),
           ("p", f"{cal['method']} over {cal['samples']:,} samples, parameters "
                 f"{', '.join(cal['params'])}, sensors {', '.join(cal['sensors'])}.")]
    head = ["parameter", "RMSE", "bias", "coverage (95 %)"]
    if acc is None:
        out.append(("p", "The data carry no true theta: accuracy against the truth is not "
                         "known."))
    else:
        out.append(("p", "theta_hat against the true theta over every sample; coverage: the "
                         "fraction of samples whose truth lies in theta_hat ± 1.96 std "
                         "(nominal 0.95)."))
        if before is not None:
            out += [("p", "With the base model (what discover started from):"),
                    ("table", head, _accuracy_rows(before)),
                    ("p", f"Recalibrated with {', '.join(effects or [])} (what the networks "
                          "learn from):")]
        out.append(("table", head, _accuracy_rows(acc)))
    if cal["warnings"]:
        out.append(("p", ("Warnings of the base-model calibration: " if before is not None
                          else "Warnings: ") + "; ".join(cal["warnings"])))
    if theta_png is not None:
        out.append(("img", theta_png, "theta_hat per cycle (mean over each flight), truth "
                                      "dashed"))
    return out


def _discovery_blocks(d: dict | None, augmented: list, png: Path | None) -> list:
    out = [("h", 2, "Model discrepancy")]
    if d is None:
        return out + [("p", "Not run ([discover] enabled = false).")]
    b, a = d["before"], d["after"]
    out.append(("p", f"Verdict: {d['verdict']}. {d['candidates']} candidate effects screened; "
                     f"drift of theta q = {_f(d['drift']['q'])} per sqrt(hour) "
                     f"({d['drift']['method']}). Residual chi^2 per degree of freedom on "
                     f"{b['on']}: {_f(b['chi2_per_dof'], '.4g')} before, "
                     f"{_f(a['chi2_per_dof'], '.4g')} after."))
    if d["found"]:
        out.append(("table", ["effect", "parameters", "p-value", "share of excess"],
                    [[f["name"], "; ".join(f"{q} = {_f(v, '.4g')} ± {_f(f['std'][q], '.2g')}"
                                           for q, v in f["params"].items()),
                      _f(f["p_value"]), _f(f["explained_share"], ".2f")] for f in d["found"]]))
    for amb in d["ambiguous"]:
        out.append(("p", f"Ambiguous: {amb['candidates'][0]} or {amb['candidates'][1]}."))
    if d["unknown"]:
        out.append(("p", f"Unexplained structure on {', '.join(d['unknown']['channels'])}."))
    te = d.get("theta_error")
    if te:
        out.append(("table", ["parameter", "RMSE before", "RMSE after", "bias before",
                              "bias after"],
                    [[q, _f(te["before"][q]["rmse"]), _f(te["after"][q]["rmse"]),
                      _f(te["before"][q]["bias"], "+.2e"), _f(te["after"][q]["bias"], "+.2e")]
                     for q in te["before"]]))
    out.append(("p", "The networks learn from a recalibration with " + ", ".join(augmented)
                if augmented else "The networks learn from the calibration above (no effect "
                "added: " + ("--augment not given" if d["found"] else "none found") + ")."))
    if png is not None:
        out.append(("img", png, "whitened residuals before and after (discover)"))
    return out


def _summary_blocks(ev: dict, acc: dict | None, cal: dict, disc: dict | None,
                    augmented: list) -> list:
    """What a reader acts on, before the details: per test unit and input set the RUL at the
    last observed cycle (with its interval), the discrepancy verdict, the calibration."""
    interval = any("lower" in u for e in ev.values()
                   for u in e["metrics"]["last"]["units"].values())
    rows = []
    for inputs, e in ev.items():
        for u, lu in e["metrics"]["last"]["units"].items():
            band = f"{_f(lu['lower'])} to {_f(lu['upper'])}" if "lower" in lu else "–"
            rows.append([u, inputs, lu["cycle"], _f(lu["RUL_pred"]),
                         *([band] if interval else []), _f(lu["RUL"]),
                         _f(lu["delta"], "+.3g")])
    head = ["unit", "inputs", "last cycle", "predicted RUL",
            *(["interval"] if interval else []), "true RUL", "Δ = true - predicted"]
    if disc is None:
        verdict = "Model discrepancy: not checked ([discover] enabled = false)."
    else:
        added = (f" Added to the model: {', '.join(augmented)}." if augmented else
                 " Nothing was added to the model" + (" (--augment not given)."
                                                      if disc["found"] else "."))
        verdict = (f"Model discrepancy: {disc['verdict']}; residual chi^2 per degree of "
                   f"freedom {_f(disc['before']['chi2_per_dof'], '.4g')} before, "
                   f"{_f(disc['after']['chi2_per_dof'], '.4g')} after.{added}")
    if acc is None:
        quality = ("Calibration: no true theta in the data, so its accuracy is not known"
                   + (f"; warnings: {'; '.join(cal['warnings'])}." if cal["warnings"] else
                      "; no warnings."))
    else:
        worst = max(acc["overall"], key=lambda q: acc["overall"][q]["rmse"])
        cov = [v["coverage95"] for v in acc["overall"].values() if "coverage95" in v]
        quality = (f"Calibration ({cal['method']}): the largest error is {worst}'s, RMSE "
                   f"{_f(acc['overall'][worst]['rmse'])}"
                   + (f"; the ±1.96 σ band holds the truth for {min(cov):.1%} to "
                      f"{max(cov):.1%} of the samples (nominal 95 %)" if cov else "")
                   + (f"; warnings: {'; '.join(cal['warnings'])}." if cal["warnings"] else "."))
    said = [f"{k}: {w}" for k, e in ev.items() for w in e.get("warnings", [])]
    return [("h", 2, "Summary"),
            ("p", "Remaining useful life of each test unit at its last observed cycle, in "
                  "cycles" + (" (interval: split-conformal)" if interval else "") + "."),
            ("table", head, rows), ("p", verdict), ("p", quality),
            *([("p", "Warning: " + "; ".join(said))] if said else [])]


def _rul_blocks(ev: dict, figs: dict, trained: dict) -> list:
    out = [("h", 2, "Remaining useful life")]
    interval = any("coverage" in e["metrics"]["samples"]["overall"] for e in ev.values())
    head = ["inputs", "unit", "samples", "RMSE", "NASA score", "last cycle", "true RUL",
            "predicted", "horizon", *(["coverage", "width"] if interval else [])]
    rows = []
    for inputs, e in ev.items():
        m = e["metrics"]
        s, last, hz = m["samples"], m["last"], m["horizon"]
        for u, v in s["units"].items():
            lu = last["units"][u]
            rows.append([inputs, u, v["n"], _f(v["rmse"]), _f(v["score"], ".4g"), lu["cycle"],
                         _f(lu["RUL"]), _f(lu["RUL_pred"]), _f(hz["units"][u]),
                         *([_f(v.get("coverage"), ".3f"), _f(v.get("width"))]
                           if interval else [])])
        if len(s["units"]) > 1:
            o = s["overall"]
            rows.append([inputs, "all", o["n"], _f(o["rmse"]), _f(o["score"], ".4g"), "", "",
                         "", _f(hz["mean"]), *([_f(o.get("coverage"), ".3f"),
                                                _f(o.get("width"))] if interval else [])])
    out += [("p", "Every test sample (the paper's protocol) and the last observed cycle "
                  "(C-MAPSS's); NASA score with delta = true - predicted; horizon: cycles "
                  "before failure from which the per-cycle mean stays within ±5 cycles."),
            ("table", head, rows)]
    life = []
    for inputs, e in ev.items():
        al = e["metrics"]["alpha_lambda"]
        for lam in al["lambdas"]:
            k = f"{lam:g}"
            seen = [r[k] for r in al["units"].values() if r[k] is not None]
            life.append([inputs, k, f"{sum(x['within'] for x in seen)} of {len(seen)}",
                         _f(al["relative_accuracy"][k], ".3f")])
    alpha = next(iter(ev.values()))["metrics"]["alpha_lambda"]["alpha"]
    out += [("p", "Accuracy over life (Saxena et al. 2010): at t_P + λ (t_EOL - t_P), λ a "
                  "fraction of the unit's life from its first prediction, whether the "
                  f"per-cycle mean lies within ±{alpha:.0%} of the true RUL (α-λ accuracy) "
                  "and the relative accuracy 1 - |error| / true RUL (1 is perfect)."),
            ("table", ["inputs", "λ", f"units within ±{alpha:.0%}", "relative accuracy"],
             life)]
    for inputs, png in figs.items():
        if inputs == "error_by_rul":
            out.append(("img", png, "error Δ = true - predicted RUL by bin of true RUL, every "
                                    "test sample (box: quartiles; whiskers: 5-95 %)"))
            continue
        t = trained[inputs]
        best = ", ".join(f"seed {m['seed']}: best epoch {m['best_epoch']} of {m['epochs_run']}"
                         for m in t["members"])
        what = f"{t['parameters']:,} parameters; {best}" if t["members"] else \
            "no network: the library of the training units"
        out.append(("img", png, f"{inputs}: predicted (per-cycle mean, min-max band) vs true "
                                f"RUL of the test units ({what})"))
    return out


def _history(trained: dict) -> dict:
    return {f"{inputs} seed {m['seed']}": m["history"]
            for inputs, t in trained.items() for m in t["members"]}


def write(out: Path, config: dict, s: dict, timings: dict) -> dict:
    """Write the report from the stage summaries ``s`` (keys ``data``, ``calibrate``,
    ``discover``, ``features``, ``train``, ``evaluate``); returns what was written."""
    from engine_model.datasets import read_dataset, read_metadata, summarize
    from prognostics.plots import plot_error_by_rul, plot_rul, plot_theta, plot_training_curves

    started = time.perf_counter()
    figs = out / FIGURES
    feats = s["features"]
    table, split = feats["table"], feats["split"]
    df, _ = read_dataset(out / table)
    meta = read_metadata(s["data"]["data"])
    fleet = summarize(df, meta)
    acc = calibration_accuracy(df)
    before = None
    if feats["effects"]:  # augmented: the base model's calibration too
        base, _ = read_dataset(out / s["calibrate"]["table"])
        before = calibration_accuracy(base)
        del base
    hat = [q + "_hat" for q in THETA_NAMES if q + "_hat" in df.columns]
    theta_png = None
    if hat:
        theta_png = figs / "theta.png"
        per = df.groupby(["unit", "cycle"], sort=True)[hat].mean().reset_index()
        sd = [h + "_std" for h in hat if h + "_std" in df.columns]
        std = None
        if sd:
            std = df.groupby(["unit", "cycle"], sort=True)[sd].mean().reset_index()
            std.columns = ["unit", "cycle", *(c.removesuffix("_std") for c in sd)]
        truth = None
        if acc is not None:
            qs = [h[:-4] for h in hat]
            truth = df.groupby(["unit", "cycle"], sort=True)[qs].mean().reset_index()
            truth.columns = ["unit", "cycle", *hat]
        plot_theta(per, hat, theta_png, truth, std)
    rul_figs = {}
    for inputs, e in s["evaluate"].items():
        pc = per_cycle(pd.read_parquet(out / e["predictions"]))
        rul_figs[inputs] = figs / f"rul_{inputs}.png"
        plot_rul(pc, f"{config['train']['model'].upper()} {inputs}", rul_figs[inputs])
    rul_figs["error_by_rul"] = figs / "error_by_rul.png"
    plot_error_by_rul({k: e["metrics"]["error_by_rul"] for k, e in s["evaluate"].items()},
                      rul_figs["error_by_rul"])
    history = _history(s["train"])  # none for a library model (similarity): no figure
    curves = figs / "training.png" if history else None
    if curves is not None:
        plot_training_curves(history, curves)
    disc = s.get("discover")
    disc_png = None
    if disc is not None:
        src = out / disc["report"] / "residuals.png"
        if src.is_file():
            disc_png = figs / "discrepancy.png"
            write_bytes(disc_png, src.read_bytes())

    vers = versions()
    seed = config["pipeline"]["seed"]
    head = [("h", 1, "hyprog pipeline report"),
            ("p", f"Data: {s['data']['label']}. Seed {seed}. hyprog {vers['hyprog']}.")]
    timings = {**timings, "report": {"status": "done",
                                     "seconds": time.perf_counter() - started}}
    blocks = (head + _summary_blocks(s["evaluate"], acc, s["calibrate"], disc, feats["effects"])
              + _fleet_blocks(fleet, split)
              + _calibration_blocks(s["calibrate"], acc, theta_png, before, feats["effects"])
              + _discovery_blocks(disc, feats["effects"], disc_png)
              + _rul_blocks(s["evaluate"], rul_figs, s["train"])
              + ([("img", curves, "training and validation loss per epoch")] if curves else [])
              + [("h", 2, "Timings"),
                 ("table", ["stage", "status", "seconds"],
                  [[k, v["status"], _f(v["seconds"], ".1f")] for k, v in timings.items()]),
                 ("p", f"Total {sum(v['seconds'] for v in timings.values()):.1f} s "
                       "(of this run; a skipped stage costs only its check; the report's "
                       "time runs to the start of writing its files)."),
                 ("h", 2, "Configuration"), ("pre", to_toml(config)),
                 ("h", 2, "Versions"),
                 ("table", ["package", "version"], [[k, v or "–"] for k, v in vers.items()])])
    write_text(out / "report.md", document.markdown(blocks, out))
    write_text(out / "report.html", document.html_page(blocks, "hyprog pipeline report"))
    metrics = {
        "seed": seed, "config": results_config(config), "versions": vers,
        "data": s["data"]["label"],
        "fleet": {k: fleet[k] for k in ("units", "totals", "sample_rate_hz", "effects")},
        "split": split,
        "calibration": {"method": s["calibrate"]["method"], "params": s["calibrate"]["params"],
                        "sensors": s["calibrate"]["sensors"], "accuracy": acc,
                        "accuracy_base_model": before,
                        "warnings": s["calibrate"]["warnings"]},
        "discovery": None if disc is None else
        {k: v for k, v in disc.items() if k not in ("report", "seconds")},
        "features": {"effects": feats["effects"], "inputs": feats["inputs"]},
        "training": {k: {kk: vv for kk, vv in v.items() if kk not in ("model", "seconds")}
                     for k, v in s["train"].items()},
        "rul": {k: v["metrics"] for k, v in s["evaluate"].items()},
    }
    write_json(out / "metrics.json", metrics)
    files = ["report.md", "report.html", "metrics.json",
             *sorted(str(p.relative_to(out)) for p in figs.glob("*.png"))]
    return {"files": files}

"""NASA C-MAPSS, cross-validated on the training units: data-driven against hybrid inputs,
beside the published models and the floors.

    python benchmarks/cmapss.py --data-dir ../shared/data/cmapss [--work out/cmapss]
        [--subsets FD001,FD002,FD003] [--models dcnn] [--folds 5] [--seeds 0,1,2]

For every ``train_FD00x.txt`` in ``--data-dir`` (FD001-FD004, whichever are there):

1. ``hyprog data import-cmapss`` and ``hyprog calibrate`` (UKF, the default parameters) into
   ``--work`` (reused when already there);
2. ``--folds`` folds of whole units (:func:`prognostics.cross_validation.unit_folds`, fold seed
   0); per fold and training seed, one network per input set trained on the other folds' units
   (validation on 10 % of them, whole units, drawn by the seed), the held-out units truncated
   at a seeded random cycle where the true RUL is uniform on [0, 125], and never before the
   window's last cycle (a unit shorter than 125 + window cycles has a narrower range: on
   FD001 10 of 100 units, mean RUL at the cut 62.0 against 62.5)
   (:func:`~prognostics.cross_validation.truncate_units`, seed = the fold seed) and scored
   once, at that cycle, predictions capped like the targets;
3. the floors on the same truncated units: the constant predictor (the mean capped RUL of the
   training rows) and the physics-only baseline (:mod:`prognostics.baseline`: the trend of the
   health index of θ̂, no network), per calibration variant (``--params``,
   ``--model-effects``, ``--noise``, ``--model-error``), the health index evaluated with the
   engine model θ̂ was calibrated with.

Inputs: ``data-driven`` is ``w + cmapss`` (the operating settings and NASA's 21 sensors;
constant ones are dropped by the training), ``hybrid`` adds ``xs_hat + xv_hat + theta_hat``
(the model's estimates of the measured and virtual sensors and the calibrated health
parameters), ``hybrid-theta`` adds ``theta_hat`` alone (the health estimate without the
model's sensor estimates, which on a multi-condition file add as many columns as there are
sensors and carry the condition more than the health), ``hybrid-theta-rel`` adds to that
``theta_rel``: θ̂ and the health index relative to the unit's own first cycles
(:mod:`prognostics.flights`, causal; engines leave the factory different, and on FD002 the
model's mismatch with NASA's engine lands in θ̂ as a per-unit offset), ``hybrid-theta-mode``
adds to ``hybrid-theta`` the failure mode, the direction cosines of θ̂'s change since the
unit's first cycles, shrunk to 0 while that change is within three standard deviations of θ̂
(:mod:`prognostics.flights`, causal; FD003 has two fault modes, HPC and fan, which θ̂'s
change tells apart). Each run is one line of
``--work/runs.jsonl`` (resumed); the table goes to stdout and, with ``--results``, to
``RESULTS/cmapss.md`` and ``RESULTS/cmapss_runs.csv``, with every line of the cache (not only
the table's) in ``RESULTS/runs.jsonl.gz``. The committed files are the ``--report`` of the
whole cache:

    python benchmarks/cmapss.py --data-dir ../shared/data/cmapss --report \\
        --results benchmarks/results/cmapss

Every figure here is a cross-validation figure on **training** units, not a test-set figure;
the published figures beside them are test-set figures on NASA's test files (same
last-cycle protocol, different units). If the folder holds ``test_FD00x.txt`` and
``RUL_FD00x.txt`` the chosen configuration is evaluated on them once, at the end (``--test``:
one model and one input set, data-driven beside it; each evaluation recorded in
``--work/test_touches.jsonl`` and never repeated).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402
from common import file_sha, imported, run_key  # noqa: E402
from run_cache import append_run, read_runs  # noqa: E402

#: Published last-cycle RMSE on NASA's test files (same protocol: targets capped at 125 or
#: 130, one prediction per test unit at its last cycle).
PUBLISHED = {
    "Babu 2016 CNN": {"FD001": 18.45, "FD002": 30.29, "FD003": 19.82, "FD004": 29.16},
    "Zheng 2017 LSTM": {"FD001": 16.14, "FD002": 24.49, "FD003": 16.18, "FD004": 28.17},
    "Li 2018 DCNN": {"FD001": 12.61, "FD002": 22.36, "FD003": 12.64, "FD004": 23.31},
}
INPUTS = {"data-driven": "w+cmapss", "hybrid": "w+cmapss+xs_hat+xv_hat+theta_hat",
          "hybrid-theta": "w+cmapss+theta_hat",
          "hybrid-theta-rel": "w+cmapss+theta_hat+theta_rel",
          "hybrid-theta-mode": "w+cmapss+theta_hat+mode"}
MAX_RUL = 125.0
MULTI_CONDITION = {"FD002", "FD004"}


def hyprog(*args: str) -> None:
    """``hyprog ARGS --quiet`` in the repository root (:func:`common.hyprog`: its stderr is
    shown only when it fails). Paths are passed as they are: :func:`main` makes the options'
    paths absolute, so that they mean the same in the child."""
    common.hyprog(*args, quiet=True, capture=True)


def model_error_option(text: str) -> float | str:
    """``--model-error``: a relative std, or ``consistent`` (the one at which the filter's
    normalised innovations have unit variance over the whole subset:
    :mod:`calibration.consistency`; it reads the sensors of every unit, no RUL)."""
    if text == "consistent":
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number nor 'consistent': {text!r}") from None


def measurement_options(noise: str, model_error: float | str,
                        sensors: str | None = None) -> tuple[list[str], str]:
    """``hyprog calibrate``'s options for the measurement model (the noise, the model's own
    error, the channels read) and the label they add (none by default)."""
    args = [] if noise == "model" else ["--noise", noise]
    if model_error == "consistent":
        args += ["--model-error", "consistent"]
    elif model_error != 0:
        args += ["--model-error", f"{model_error:g}"]
    if sensors:
        args += ["--sensors", sensors]
    return args, " ".join(args)


def prepare_subset(data_dir: Path, work: Path, subset: str, params: str = "default",
                   adapted: Path | None = None, noise: str = "model",
                   model_error: float | str = 0.0, sensors: str | None = None) -> Path:
    """Import ``subset``'s training file into ``work`` (once) and calibrate it
    (:func:`calibrated`); the feature table's path."""
    raw = imported(data_dir, work, subset, capture=True)
    return calibrated(raw, params, adapted, noise, model_error, sensors)


def calibrated(raw: Path, params: str = "default", adapted: Path | None = None,
               noise: str = "model", model_error: float | str = 0.0,
               sensors: str | None = None) -> Path:
    """The imported table ``raw`` calibrated beside it (once) with ``hyprog calibrate --params
    params`` (and ``--model-effects adapted``, ``--noise``, ``--model-error``,
    ``--sensors``), in a folder named after ``raw`` and the variant; its path."""
    noise_args, noise_tag = measurement_options(noise, model_error, sensors)
    feat = raw.parent / (f"{raw.name}-features" + ("" if params == "default" else f"-{params}")
                         + ("" if adapted is None else f"-adapted-{file_sha(adapted)[:8]}")
                         + ("" if not noise_tag else "-" + noise_tag.replace("--", "")
                            .replace(" ", "-")))
    if not feat.exists():  # (a calibration cut short resumes: run it again by hand)
        t0 = time.perf_counter()
        extra = [] if params == "default" else ["--params", params]
        extra += [] if adapted is None else ["--model-effects", str(adapted)]
        extra += noise_args
        hyprog("calibrate", str(raw), "--out", str(feat), *extra)
        print(f"{raw.name}: calibrated in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return feat


def test_files(data_dir: Path, subset: str) -> tuple[Path, Path] | None:
    """NASA's ``test_FD00x.txt`` and ``RUL_FD00x.txt`` when the folder holds both."""
    test, rul = data_dir / f"test_{subset}.txt", data_dir / f"RUL_{subset}.txt"
    return (test, rul) if test.exists() and rul.exists() else None


def evaluate_on_test_files(args, subset: str, model: str, overrides: dict) -> list[dict]:
    """The chosen configuration trained on every training unit and scored once on NASA's
    test units at their last cycle (import with ``--test/--rul``: test unit ``u`` is unit
    ``1000 + u``), per seed and for the seeds' ensemble; one record per input set of
    ``args.inputs``. Exactly the cross-validated variant: the same calibration (``--params``,
    ``--model-effects``, ``--noise``, ``--model-error``), the same columns left out
    (:func:`unobservable_somewhere`), the same pooled units (``--pool``), one network per
    seed with its own validation units."""
    from engine_model.datasets import read_dataset
    from prognostics.cross_validation import last_cycle_scores
    from prognostics.ensemble import fit
    from prognostics.train_config import TrainConfig

    test, rul = test_files(args.data_dir, subset)
    raw = args.work / f"{subset.lower()}-test"
    if not raw.exists():
        hyprog("data", "import-cmapss", str(args.data_dir / f"train_{subset}.txt"), "--test",
               str(test), "--rul", str(rul), "--out", str(raw), "--overwrite")
    df, meta = read_dataset(calibrated(raw, args.params, args.model_effects, args.noise,
                                       args.model_error, args.sensors))
    test_units = [int(u) for u in meta["test_units"]]
    df, pooled = pooled_units(df, pooled_subsets(args, subset), args)
    df = unobservable_somewhere(df, subset)
    train_units = sorted(set(df["unit"].unique().tolist()) - set(test_units))
    normalise = "condition" if subset in MULTI_CONDITION else "minmax"
    seeds = [int(x) for x in args.seeds.split(",")]
    out = []
    for name in args.inputs.split(","):
        cfg = replace(TrainConfig(model=model, inputs=INPUTS[name], max_rul=MAX_RUL,
                                  normalise=normalise, units=tuple(train_units),
                                  test_units=tuple(test_units), device="cpu"), **overrides)
        # one network per seed, each with its own validation units drawn by that seed, as
        # the cross-validation runs train them (fit(seeds=...) would share seed 0's split)
        preds = [fit(df, meta, replace(cfg, seed=s)).predict(df, test_units) for s in seeds]
        per_seed = [last_cycle_scores(p, MAX_RUL)["rmse"] for p in preds]
        # the ensemble as the cross-validation tables have it (ensemble_deltas): the mean of
        # the seeds' capped predictions (RulModel.predict caps the mean of the raw ones)
        ens_pred = preds[0].assign(RUL_pred=np.mean([p["RUL_pred"] for p in preds], axis=0))
        ens = last_cycle_scores(ens_pred, MAX_RUL)["rmse"]
        out.append({"subset": subset, "model": model, "inputs": name, "units": len(test_units),
                    "rmse_per_seed": per_seed, "rmse_ensemble": ens})
    return out


def test_section(args, subsets: list, overrides: dict) -> str:
    """The table's section on NASA's test files: each subset's chosen configuration evaluated
    by :func:`evaluate_on_test_files` **once**. Only one model and one input set (with
    ``data-driven`` beside it as the reference) may be named: the test files judge the
    configuration cross-validation chose, not a choice among several. Every evaluation is
    recorded in ``--work/test_touches.jsonl`` (its configuration, date and figures); asked
    again, the record is reported and nothing is trained, so that no configuration meets the
    test units twice; with ``--report`` only the records are reported."""
    names = args.inputs.split(",")
    if (len(args.models.split(",")) != 1 or len(names) > 2
            or (len(names) == 2 and "data-driven" not in names)):
        raise SystemExit("--test: name one --models and one --inputs (data-driven may stand "
                         "beside it): the test files judge the chosen configuration once")
    log = args.work / "test_touches.jsonl"
    touched = {r["key"]: r for r in read_runs(log)}
    found = [s for s in subsets if test_files(args.data_dir, s) is not None]
    if not found:
        return "\n\nNo test files in the folder."
    lines = ["", "Evaluated once on NASA's test files, after the choice above "
             "(trained on every training unit; records in test_touches.jsonl):", "",
             "| subset | predictor | test units | RMSE per seed | RMSE, ensemble | evaluated |",
             "|---|---|---|---|---|---|"]
    for subset in found:
        body = {"test": 1, "subset": subset, "model": args.models, "inputs": names,
                "params": args.params, "noise": args.noise, "model_error": args.model_error,
                "model_effects": None if args.model_effects is None
                else file_sha(args.model_effects),
                "pool": pooled_subsets(args, subset), "seeds": args.seeds, "settings": overrides}
        key = run_key(body)
        if key not in touched and not args.report:
            rec = {"key": key, "kind": "test", **body, "date": time.strftime("%Y-%m-%d %H:%M"),
                   "results": evaluate_on_test_files(args, subset, args.models, overrides)}
            append_run(log, rec)
            touched[key] = rec
        if key not in touched:
            lines.append(f"| {subset} | {args.models} {args.inputs} | - | not evaluated | - | "
                         "- |")
            continue
        rec = touched[key]
        for r in rec["results"]:
            lines.append(f"| {subset} | {rec['model']} {r['inputs']} | {r['units']} | "
                         + ", ".join(f"{v:.2f}" for v in r["rmse_per_seed"])
                         + f" | {r['rmse_ensemble']:.2f} | {rec['date']} |")
    return "\n".join(lines)


def pooled_subsets(args, subset: str) -> list[str]:
    """The subsets of ``--pool`` whose training units join ``subset``'s (itself excluded,
    only those whose file is in the folder)."""
    return [p for p in args.pool.split(",") if p and p != subset
            and (args.data_dir / f"train_{p}.txt").exists()]


#: The window of the runs the floors were first cached for (dcnn's): floors of held-out units
#: cut from another cycle (another window) carry it in their key and label (:data:`CUT_FROM`).
FLOORS_CUT_FROM = 30
CUT_FROM = "cut from cycle {}"


def settings_label(overrides: dict) -> str:
    """What a run's label says of ``--set`` (nothing when there is none), so that runs of
    one input set under different settings are summarised apart."""
    return " [" + ", ".join(f"{k}={v}" for k, v in sorted(overrides.items())) + "]" \
        if overrides else ""


def train_and_score(df, meta, cfg, held) -> dict:
    """One training run of ``cfg`` scored at the held-out units' last cycles: the cache
    record's fields. It carries torch's thread count: a run is reproducible bit for bit only
    at the same count (prognostics.training)."""
    from prognostics.cross_validation import last_cycle_scores
    from prognostics.ensemble import fit

    t0 = time.perf_counter()
    model = fit(df, meta, cfg)
    seconds = time.perf_counter() - t0
    pred = model.predict(held)
    scores = last_cycle_scores(pred, cfg.max_rul)
    m = model.members[0]
    return {"rmse": scores["rmse"], "score": scores["score"], "seconds": seconds,
            "best_epoch": m.best_epoch, "epochs_run": len(m.history),
            "batch_size": model.config.batch_size, "patience": model.config.patience,
            "columns": len(model.columns), "threads": model.info["trained_with"]["threads"],
            "deltas": {str(u): round(v["delta"], 3) for u, v in scores["units"].items()}}


def floors(df, fold, held, hi_fn) -> dict:
    """The floors' last-cycle RMSE on the held-out units: the constant (the training rows'
    mean capped RUL), the life floor (the training units' mean life minus the cycle), the HI
    lookup (the training rows' RUL against their health index, an isotonic curve) and the
    physics trend (prognostics.floors, prognostics.baseline); no network."""
    from prognostics.baseline import baseline_predictions
    from prognostics.cross_validation import last_cycle_scores
    from prognostics.flights import flight_table
    from prognostics.floors import floor_predictions

    train = df[df["unit"].isin(fold.train)]
    const = float(np.minimum(train["RUL"].to_numpy(float), MAX_RUL).mean())
    last = held.groupby("unit").tail(1)
    y = last["RUL"].to_numpy(float)
    out = {"constant": float(np.sqrt(np.mean((y - const) ** 2)))}
    pred = floor_predictions(flight_table(train, hi_fn), flight_table(held, hi_fn),
                             ("life", "hi-lookup"), MAX_RUL)
    out["life"] = last_cycle_scores(pred["life"], MAX_RUL)["rmse"]
    out["hi_lookup"] = last_cycle_scores(pred["hi-lookup"], MAX_RUL)["rmse"]
    out["physics"] = last_cycle_scores(baseline_predictions(held, hi_fn, MAX_RUL),
                                       MAX_RUL)["rmse"]
    return out


#: the label of a run or floor on another partition of the folds (``--fold-seed``), read
#: back by :func:`summarise`
PARTITION = "fold seed {}"


def pooled_units(df, pool, args) -> tuple:
    """``df`` with the training units of the subsets ``pool`` appended (calibrated with the
    same variant; unit ``u`` of the i-th pooled subset becomes ``100000 (i + 1) + u``), and
    their new ids. C-MAPSS's subsets share one engine and label their conditions alike
    (``hyprog data import-cmapss``), so the pooled rows join the statistics of their own
    condition in the per-condition standardisation (fitted on every training row)."""
    from engine_model.datasets import read_dataset

    if not pool:
        return df, []
    frames, ids = [df], []
    for i, other in enumerate(pool):
        feat = prepare_subset(args.data_dir, args.work, other, args.params,
                              args.model_effects, args.noise, args.model_error, args.sensors)
        extra, _ = read_dataset(feat)
        extra = extra.assign(unit=extra["unit"] + 100000 * (i + 1))
        frames.append(extra[[c for c in df.columns if c in extra.columns]])
        ids += sorted(extra["unit"].unique().tolist())
    return pd.concat(frames, ignore_index=True), ids


def unobservable_somewhere(df, subset: str):
    """``df`` with every health-parameter estimate that the calibration found unobservable in
    some unit (NaN in some rows) set to NaN in every row, so that the networks leave it out
    (prognostics.features.unobservable_columns): a network cannot read a parameter that one
    unit has and another lacks, and which units lack it is not known before calibration."""
    from engine_model.channels import THETA_NAMES

    cols = [q + "_hat" for q in THETA_NAMES if q + "_hat" in df.columns]
    part = [c for c in cols if df[c].isna().any() and not df[c].isna().all()]
    if part:
        print(f"{subset}: left out, unobservable in some units: "
              f"{', '.join(c[:-4] for c in part)}", file=sys.stderr)
        df = df.assign(**{c: np.nan for c in part})
    return df


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", type=Path, required=True)
    ap.add_argument("--work", type=Path, default=Path("out/cmapss"))
    ap.add_argument("--subsets", default="FD001,FD002,FD003,FD004")
    ap.add_argument("--models", default=None,
                    help="comma-separated model names (default: dcnn; with --report, every "
                    "model in the cache, so that the committed cache keeps every run)")
    ap.add_argument("--inputs", default="data-driven,hybrid")
    ap.add_argument("--params", default="default",
                    help="the health parameters calibrated for the hybrid inputs (hyprog "
                    "calibrate --params): 'default' or 'all' (those found unobservable in any "
                    "unit are left out: unobservable_somewhere)")
    ap.add_argument("--model-effects", type=Path, default=None,
                    help="an adapted model (hyprog adapt) for the calibration of the hybrid "
                    "inputs (a separate features folder; runs labelled 'adapted')")
    ap.add_argument("--noise", choices=("model", "data"), default="model",
                    help="the noise in the calibration's R (hyprog calibrate --noise; runs "
                    "labelled with it when not 'model')")
    ap.add_argument("--model-error", type=model_error_option, default=0.0,
                    help="hyprog calibrate --model-error: a relative std or 'consistent' "
                    "(runs labelled with it when not 0)")
    ap.add_argument("--sensors", default=None,
                    help="hyprog calibrate --sensors: the channels the calibration reads "
                    "(e.g. adding C-MAPSS's flow channels BPR,W31,W32, which need --noise "
                    "data; runs labelled with it)")
    ap.add_argument("--pool", default="",
                    help="subsets whose training units join every fold's training units of "
                    "the other subsets (same calibration variant; held-out units and floors "
                    "stay the subset's own; runs labelled '+ FD00x units'): NASA's engine is "
                    "the same in every subset, and FD001 flies FD002's condition 1")
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--fold-seed", type=int, default=0)
    ap.add_argument("--set", action="append", default=[],
                    help="TrainConfig field=value for every run (a setting under study)")
    ap.add_argument("--results", type=Path, default=None)
    ap.add_argument("--report", action="store_true",
                    help="summarise the runs already in --work/runs.jsonl; train nothing")
    ap.add_argument("--reverse", action="store_true",
                    help="folds in reverse order: a second process on the same --work shares "
                    "the work (each run is looked up in the cache just before it trains)")
    ap.add_argument("--test", action="store_true",
                    help="once the configuration is chosen (one --models, one --inputs, "
                    "data-driven beside it): train on every training unit and score NASA's "
                    "test files (test_FD00x.txt, RUL_FD00x.txt), when present; once only, "
                    "recorded in --work/test_touches.jsonl and reported from there after")
    args = ap.parse_args(argv)
    # (hyprog runs in the repository root: the paths it is given must not be relative)
    args.data_dir, args.work = args.data_dir.resolve(), args.work.resolve()
    if args.model_effects is not None:
        args.model_effects = args.model_effects.resolve()
    if args.models is None:
        cached = read_runs(args.work / "runs.jsonl") if args.report else []
        args.models = ",".join(dict.fromkeys(r["model"] for r in cached
                                             if r["kind"] == "run")) or "dcnn"

    from engine_model.datasets import read_dataset
    from prognostics.cross_validation import truncate_units, unit_folds
    from prognostics.train_config import TrainConfig

    args.work.mkdir(parents=True, exist_ok=True)
    cache = args.work / "runs.jsonl"
    done = {r["key"]: r for r in read_runs(cache)}
    overrides = {}
    for item in args.set:
        k, v = item.split("=", 1)
        overrides[k] = json.loads(v) if v[:1] in "0123456789-[{tfn" else v
    subsets = [s for s in args.subsets.split(",")
               if (args.data_dir / f"train_{s}.txt").exists()]
    noise_tag = measurement_options(args.noise, args.model_error, args.sensors)[1]
    rows = []
    for subset in subsets:
        if args.report:
            rows += [{**r, "settings": json.dumps(r.get("settings", {}))}
                     for r in done.values() if r["subset"] == subset
                     and (r["kind"] == "floors" or r["model"] in args.models.split(","))]
            continue
        feat = prepare_subset(args.data_dir, args.work, subset, args.params, args.model_effects,
                              args.noise, args.model_error, args.sensors)
        df, meta = read_dataset(feat)
        units = sorted(df["unit"].unique().tolist())
        pool = pooled_subsets(args, subset)
        df, pooled = pooled_units(df, pool, args)
        df = unobservable_somewhere(df, subset)
        normalise = "condition" if subset in MULTI_CONDITION else "minmax"
        hi_fn = None
        # the calibration's variant: what the hybrid inputs and the physics floor read
        variant, suffix = {}, ""
        if args.params != "default":
            variant["params"] = args.params
            suffix += f" --params {args.params}"
        if args.model_effects is not None:
            variant["model_effects"] = file_sha(args.model_effects)
            suffix += f", adapted {variant['model_effects'][:8]}"
        if noise_tag:  # the measurement model: noise, model error and --sensors
            variant["noise"] = noise_tag
            suffix += f" {noise_tag}"
        # what every run's label ends with: the pooled units, another partition of the folds
        partition = f", {PARTITION.format(args.fold_seed)}" if args.fold_seed else ""
        tail = (" + " + ", ".join(pool) + " units" if pool else "") + partition
        folds = list(enumerate(unit_folds(units, args.folds, args.fold_seed)))
        for k, fold in (reversed(folds) if args.reverse else folds):
            for model in args.models.split(","):
                base = TrainConfig(model=model, max_rul=MAX_RUL, normalise=normalise,
                                   units=(*fold.train, *pooled), test_units=(),
                                   device="cpu")
                base = replace(base, **overrides)
                cut_from = int(base.resolved().window)
                held = truncate_units(df, fold.held_out, seed=args.fold_seed,
                                      min_cycles=cut_from, max_rul=MAX_RUL)
                # the floors on the same cut points as the networks beside them: the
                # held-out units are cut no earlier than the model's window
                other_cut = {} if cut_from == FLOORS_CUT_FROM else {"cut_from": cut_from}
                fkey = run_key({"floors": 1, "subset": subset, "fold": k, "folds": args.folds,
                                "fold_seed": args.fold_seed, **variant, **other_cut})
                if fkey not in done:
                    if hi_fn is None:  # the health index of the model θ̂ belongs to
                        from prognostics.baseline import engine_health_index, health_effects
                        hi_fn = engine_health_index(health_effects(meta))
                    rec = {"key": fkey, "kind": "floors", "subset": subset, "fold": k,
                           "variant": (suffix + (f", {CUT_FROM.format(cut_from)}"
                                                 if other_cut else "") + partition).strip(", "),
                           **floors(df, fold, held, hi_fn)}
                    append_run(cache, rec)
                    done[fkey] = rec
                for name in args.inputs.split(","):
                    for seed in [int(s) for s in args.seeds.split(",")]:
                        cfg = replace(base, inputs=INPUTS[name], seed=seed)
                        body = {"subset": subset, "fold": k, "folds": args.folds,
                                "fold_seed": args.fold_seed, "config": cfg.to_dict()}
                        label = name
                        if name != "data-driven":  # (data-driven reads no estimate)
                            body.update(variant)
                            label += suffix
                        if pool:
                            body["pool"] = pool
                        label += settings_label(overrides) + tail
                        key = run_key(body)
                        if key not in done:  # another process may have done it since
                            done.update({r["key"]: r for r in read_runs(cache)})
                        if key not in done:
                            rec = {"key": key, "kind": "run", "subset": subset, "fold": k,
                                   "model": model, "inputs": label, "seed": seed,
                                   "settings": overrides,
                                   **train_and_score(df, meta, cfg, held)}
                            append_run(cache, rec)
                            done[key] = rec
                            print(f"{subset} fold {k} {model} {label} seed {seed}: RMSE "
                                  f"{rec['rmse']:.2f} in {rec['seconds']:.0f} s "
                                  f"(epoch {rec['best_epoch']}/{rec['epochs_run']})",
                                  file=sys.stderr, flush=True)
                        rows.append({**done[key], "settings": json.dumps(overrides)})
                rows.append({**done[fkey], "model": "-", "settings": json.dumps(overrides)})
    runs = pd.DataFrame(rows)
    table = summarise(runs)
    if args.test:
        table += test_section(args, subsets, overrides)
    print(table)
    if args.results is not None:
        args.results.mkdir(parents=True, exist_ok=True)
        (args.results / "cmapss.md").write_text(table + "\n")
        cols = ["subset", "fold", "model", "inputs", "seed", "rmse", "score", "seconds",
                "best_epoch", "epochs_run", "batch_size", "patience", "columns", "settings"]
        nets = runs[runs["kind"] == "run"]
        nets[cols].to_csv(args.results / "cmapss_runs.csv", index=False, float_format="%.4f")
        # every line of the cache, not only the table's rows: a table of some of the runs
        # (--models, --subsets, a training run without --report) keeps the others in the
        # committed cache (gunzip it to --work/runs.jsonl to resume from it)
        done.update({r["key"]: r for r in read_runs(cache)})  # a --reverse process's too
        kept = args.results / "runs.jsonl.gz"
        kept.unlink(missing_ok=True)
        for rec in done.values():
            append_run(kept, rec)
        if not args.report:
            print(f"{args.results / 'cmapss.md'} holds this run's table only; the committed "
                  "table is that of every cached run: regenerate it with --report",
                  file=sys.stderr)
    return 0


def ensemble_deltas(h: pd.DataFrame) -> dict:
    """Per fold with every seed done, the seeds' mean prediction's error on each held-out unit:
    the held-out units and their truths are the same for every seed of a fold, so the
    ensemble's error on a unit is the mean of the seeds' errors ``Δ = RUL - RUL_pred`` (each
    prediction capped like the targets, then averaged: where the seeds straddle the cap this
    differs from ``RulModel.predict``, which caps the mean; the ``--test`` table uses this
    one too). ``{fold: Series indexed by unit}``."""
    out = {}
    n_seeds = h["seed"].nunique()
    for fold, g in h.groupby("fold"):
        if len(g) >= max(n_seeds, 2):
            out[fold] = pd.DataFrame(list(g["deltas"])).mean(axis=0)
    return out


def ensemble_rmse(h: pd.DataFrame) -> pd.Series:
    """Per fold with every seed done, the last-cycle RMSE of the seeds' mean prediction
    (:func:`ensemble_deltas`)."""
    return pd.Series({fold: float(np.sqrt(np.mean(d.to_numpy(float) ** 2)))
                      for fold, d in ensemble_deltas(h).items()}, dtype=float)


def split_partition(label: str) -> tuple[str, int]:
    """A run's label without its partition of the folds, and that partition's fold seed (0,
    the default partition, carries no label)."""
    tag = ", " + PARTITION.format("")
    head, sep, seed = label.rpartition(tag)
    return (head, int(seed)) if sep and seed.isdigit() else (label, 0)


def paired(other: pd.DataFrame, ref: pd.DataFrame) -> tuple[pd.Series, pd.Series]:
    """The relative difference in % of two predictors' runs on the same units, run by run
    (same partition, fold and seed) and ensemble by ensemble (same partition and fold)."""
    runs, ensembles = [], []
    for part, o in other.groupby("partition"):
        r = ref[ref["partition"] == part]
        pair = pd.concat([o.set_index(["fold", "seed"])["rmse"],
                          r.set_index(["fold", "seed"])["rmse"]], axis=1, join="inner")
        runs.append((pair.iloc[:, 0] / pair.iloc[:, 1] - 1.0) * 100)
        eo, er = ensemble_rmse(o), ensemble_rmse(r)
        common = eo.index.intersection(er.index)
        ensembles.append((eo[common] / er[common] - 1.0) * 100)
    return pd.concat(runs, ignore_index=True), pd.concat(ensembles, ignore_index=True)


def paired_cell(rel: pd.Series) -> str:
    return (f"{rel.mean():+.1f} % ± {rel.std(ddof=1):.1f} % (better in "
            f"{int((rel < 0).sum())} of {len(rel)})")


def reference(label: str, labels) -> str | None:
    """The data-driven network ``label`` is compared with: among ``labels``, the data-driven
    one with ``label``'s :func:`ending` (settings, pooled units, partition); None for a
    data-driven label or where there is none."""
    if label.startswith("data-driven"):
        return None
    ends = [r for r in labels if r.startswith("data-driven") and ending(r) == ending(label)]
    return max(ends, key=len) if ends else None


def ending(label: str) -> tuple[str, str, int]:
    """What a run's label ends with after its inputs and calibration variant: its settings
    (:func:`settings_label`, or ``""``), its pooled units (``" + FD001 units"``, or ``""``)
    and its partition of the folds. A hybrid is paired only with the data-driven run of the
    same ending (a pooled hybrid against an unpooled data-driven network would mix the
    pooling into the inputs' effect)."""
    head, seed = split_partition(label)
    pool = ""
    if head.endswith(" units") and " + " in head:
        head, pool = head[:head.rfind(" + ")], head[head.rfind(" + "):]
    settings = head[head.rfind(" ["):] if head.endswith("]") and " [" in head else ""
    return settings, pool, seed


def across_partitions(subset: str, model: str, h: pd.DataFrame) -> list[str]:
    """The rows of every predictor of ``h`` (one model's runs, with ``base`` and
    ``partition`` columns) that ran on more than one partition of the folds: its runs and
    its seeds' ensembles over all of them, and its pairs with data-driven where that ran on
    the same partitions."""
    lines = []
    for base, b in h.groupby("base", sort=True):
        parts = sorted(b["partition"].unique())
        if len(parts) < 2:
            continue
        name = f"{model} {base}, fold seeds {', '.join(map(str, parts))}"
        ens = pd.concat([ensemble_rmse(q) for _, q in b.groupby("partition")])
        lines.append(f"| {subset} | {name} | {b['rmse'].mean():.2f} ± "
                     f"{b['rmse'].std(ddof=1):.2f} | {len(b)} | - |")
        lines.append(f"| {subset} | {name}, ensemble of the seeds | {ens.mean():.2f} "
                     f"± {ens.std(ddof=1):.2f} | {len(ens)} folds | - |")
        ref_base = reference(base, h["base"].unique())
        ref = h[(h["base"] == ref_base) & h["partition"].isin(parts)]
        if ref["partition"].nunique() < len(parts):
            continue
        rel, rel_ens = paired(b, ref)
        lines.append(f"| {subset} | {name} vs data-driven, paired | "
                     f"{paired_cell(rel)} | {len(rel)} pairs | - |")
        lines.append(f"| {subset} | {name} vs data-driven, ensembles paired | "
                     f"{paired_cell(rel_ens)} | {len(rel_ens)} folds | - |")
    return lines


def summarise(runs: pd.DataFrame) -> str:
    """Mean ± std of the last-cycle RMSE over folds x seeds per subset, model and inputs, the
    seeds' ensemble per fold, the paired hybrid / data-driven ratio (run by run and ensemble
    by ensemble), the same over every partition of the folds where a predictor ran on more
    than one, the floors, and the published figures."""
    lines = ["| subset | predictor | RMSE (CV, mean ± std) | runs | median s / run |",
             "|---|---|---|---|---|"]
    for subset, g in runs.groupby("subset", sort=True):
        nets = g[g["kind"] == "run"]
        for (model, inputs), h in nets.groupby(["model", "inputs"], sort=True):
            lines.append(f"| {subset} | {model} {inputs} | {h['rmse'].mean():.2f} ± "
                         f"{h['rmse'].std(ddof=1):.2f} | {len(h)} | "
                         f"{h['seconds'].median():.0f} |")
            ens = ensemble_rmse(h)
            if len(ens):
                lines.append(f"| {subset} | {model} {inputs}, ensemble of the seeds | "
                             f"{ens.mean():.2f} ± {ens.std(ddof=1):.2f} | {len(ens)} folds | - |")
        split = nets["inputs"].map(split_partition)
        nets = nets.assign(base=split.str[0], partition=split.str[1])
        for model, h in nets.groupby("model", sort=True):
            labels = list(dict.fromkeys(h["inputs"]))
            for other in labels:
                # against the data-driven network of the same units and folds
                ref = reference(other, labels)
                if ref is None:
                    continue
                rel, rel_ens = paired(h[h["inputs"] == other], h[h["inputs"] == ref])
                lines.append(f"| {subset} | {model}: {other} vs {ref}, paired | "
                             f"{paired_cell(rel)} | {len(rel)} pairs | - |")
                if len(rel_ens):
                    lines.append(f"| {subset} | {model}: {other} vs {ref}, ensembles paired | "
                                 f"{paired_cell(rel_ens)} | {len(rel_ens)} folds | - |")
            lines += across_partitions(subset, model, h)
        fl = g[g["kind"] == "floors"].drop_duplicates("key")
        fl = fl.assign(variant=fl["variant"].fillna("") if "variant" in fl else "")
        # the constant and life floors read no calibration: one per fold of each partition
        # (and of each cut of the held-out units)
        pattern = "(" + PARTITION.format(r"\d+") + ")$"
        part = fl["variant"].str.extract(pattern, expand=False).fillna("")
        cut = fl["variant"].str.extract("(" + CUT_FROM.format(r"\d+") + ")",
                                        expand=False).fillna("")
        for (c, label), h in fl.assign(cut=cut, partition=part).groupby(["cut", "partition"],
                                                                        sort=True):
            h = h.drop_duplicates("fold")
            tag = "".join(f", {x}" for x in (c, label) if x)
            for col, name in (("constant", "constant floor"), ("life", "life floor")):
                if col in h.columns and h[col].notna().any():
                    lines.append(f"| {subset} | {name}{tag} | {h[col].mean():.2f} ± "
                                 f"{h[col].std(ddof=1):.2f} | {len(h)} folds | - |")
        for variant, h in fl.groupby("variant", sort=True):
            for col, name in (("hi_lookup", "HI lookup floor"), ("physics", "physics floor")):
                if col in h.columns and h[col].notna().any():
                    lines.append(f"| {subset} | {name}{', ' if variant else ''}{variant} | "
                                 f"{h[col].mean():.2f} ± {h[col].std(ddof=1):.2f} | "
                                 f"{len(h)} folds | - |")
        for paper, figs in PUBLISHED.items():
            if subset in figs:
                lines.append(f"| {subset} | {paper} (test set) | {figs[subset]:.2f} | - | - |")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())

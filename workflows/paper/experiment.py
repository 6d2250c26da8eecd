"""The paper's experiments and ablations on a feature table, every training run cached.

Parts (``parts`` / ``--ablations`` select them; ``main`` and the baseline always run)
-------------------------------------------------------------------------------------
``main``         FNN and CNN x data-driven and hybrid, ``seeds`` (paper Table 5); the
                 prediction horizon per test unit (paper Table 6) comes from these runs, and
                 the ensemble of their seeds (mean and spread) is reported beside them.
``small``        ablation I: CNN x data-driven and hybrid trained on ``small_units`` only (the
                 paper's 16, 18, 20: one failure mode, half the units; paper Table 7).
``features``     ablation III (paper Table 8): CNN on data-driven, then denoised, virtual and
                 hybrid under *perfect calibration*, as the paper defines it: ``x̂_s``,
                 ``x̂_v`` and ``θ̂`` replaced by their ground truth, the engine model's outputs
                 at the true θ of every sample and the true θ itself
                 (:func:`perfect_calibration`). Beside them the same sets with the
                 calibrated ``θ̂`` and ``truth-theta`` (true θ, ``x̂`` from ``θ̂``;
                 :mod:`prognostics.features`).
``calibration``  ablation IV: CNN hybrid with θ̂ degraded (paper Sec. 5.2.3, Table 9):
                 white noise at SNR 20 and 15 dB, ``θ̂ + n``, ``n ~ N(0, σ²)`` with
                 ``σ² = P / 10^(SNR/10)`` and ``P = mean(θ̂²)`` of the column over the table; and
                 the bias ``θ̂_α(t) = θ̂(t) + α (θ̂(0) - θ̂(t))``, ``α = ±0.5``, where ``θ̂(0)``
                 is the unit's mean θ̂ over its first cycle (the paper's "increasing shift
                 proportional to" the degradation so far). Applied to train and test units.
``conformal``    CNN x data-driven and hybrid with one development unit held out per seed
                 (``dev_units[seed mod n]``) to calibrate a split-conformal interval at level
                 ``1 - alpha``; coverage and width on the test units.
baseline         physics-only RUL from the θ̂ health-index trend
                 (:mod:`prognostics.baseline`), in every table.

The ablations use ``ablation_seeds`` (default: the first three of ``seeds``; the issue's
minimum is 5 for the main table and 3 per ablation).

Cache and resume
----------------
A run's key is the SHA-256 of what determines its numbers (model, inputs, seed, training
units, perturbation, conformal units: the resolved training configuration) and the fingerprint
of the data (a hash of every value of the table, ``pandas.util.hash_pandas_object``, and of its
metadata: :func:`engine_model.datasets.fingerprint.table_fingerprint`). Its results live in
``OUT/runs/<key>/``: the model (``model/``,
:mod:`prognostics.checkpoint`), the test predictions (``predictions.parquet``) and ``result.json``,
written last and atomically: a run with ``result.json`` is done and is never trained again; an
interrupted run leaves no ``result.json`` and is redone. One process writes into ``OUT`` at a time
(the lock ``.<OUT>.hyprog-lock`` beside it, :func:`engine_model.runtime.output_lock`); it first
deletes the hidden temporaries a killed run left (``.<name>.tmp-<host>-<pid>-*`` of a process that
is gone), so a SIGKILL at any moment leaves only complete files under their names and the rerun
resumes from the completed runs. The part is not in the key, so a run that two parts share
(``features`` data-driven and hybrid are ``main``'s CNN runs) is trained once. The device is
not part of the key (a run resumed on another device reuses what was done; CPU and CUDA numbers
differ in the last bits).
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pandas as pd

from engine_model.channels import THETA_NAMES, W_NAMES, XS_NAMES, XV_NAMES
from engine_model.datasets.fingerprint import table_fingerprint
from engine_model.datasets.jsonable import jsonable
from engine_model.runtime import OutputKind, check_output, output_lock
from engine_model.runtime.atomic import remove_stale_temporaries
from engine_model.validation import InputError
from prognostics.checkpoint import FORMAT_VERSION, save_model
from prognostics.ensemble import fit
from prognostics.metrics import evaluate_predictions
from prognostics.outputs import write_json, write_table
from prognostics.splits import development_and_test_units
from prognostics.train_config import DEFAULT_EPOCHS, PAPER_RECIPE, TrainConfig

from .paper_report import write_report
from .plan import PERFECT, PERTURBATIONS, ExperimentConfig, Run, plan

CACHE_VERSION = 1


def perturb_theta(df: pd.DataFrame, name: str, seed: int) -> pd.DataFrame:
    """A copy of ``df`` with its ``<q>_hat`` columns degraded by perturbation ``name``."""
    if name not in PERTURBATIONS:
        raise InputError(f"unknown perturbation {name!r}; one of {', '.join(PERTURBATIONS)}")
    kind, value = PERTURBATIONS[name]
    cols = [q + "_hat" for q in THETA_NAMES if q + "_hat" in df.columns]
    if not cols:
        raise InputError("calibration ablation: the table has no theta_hat columns")
    out = df.copy()
    if kind == "noise":
        rng = np.random.default_rng(seed)
        for c in cols:
            v = out[c].to_numpy(np.float64)
            sigma = np.sqrt(np.nanmean(v * v) / 10.0 ** (value / 10.0))
            out[c] = v + rng.normal(0.0, sigma, len(v))
    else:
        first = out.groupby("unit")["cycle"].transform("min") == out["cycle"]
        theta0 = out[first].groupby("unit")[cols].mean()
        t0 = theta0.reindex(out["unit"]).to_numpy()
        v = out[cols].to_numpy(np.float64)
        out[cols] = v + value * (t0 - v)
    return out


def perfect_calibration(df: pd.DataFrame,
                        outputs_fn: Callable[[np.ndarray, np.ndarray], pd.DataFrame] | None
                        = None) -> pd.DataFrame:
    """A copy of ``df`` as a perfect calibration would have written it (the paper's ablation
    III: "x̂_s, x̂_v, θ are ground-truth values"). Every ``<c>_hat`` of an x_s or x_v channel
    becomes the engine model's output at the sample's operating point and *true* θ (all of
    ``THETA_NAMES``), and every ``<q>_hat`` becomes the true ``q``. ``outputs_fn(w, theta)``
    returns those outputs (a DataFrame with the channel names and ``converged``). The default
    is the default engine model (:func:`engine_model.runtime.shared_model.default_model`), the model
    the simulator flies and ``hyprog calibrate`` estimates with when no effect is declared.
    On a simulated fleet without undeclared effects, ``x̂_v`` is then the recorded ``x_v``
    and ``x̂_s`` the noise-free ``x_s``."""
    missing = [q for q in THETA_NAMES if q not in df.columns]
    if missing:
        raise InputError(f"ablation III (perfect calibration): the table has no true theta "
                         f"column(s) {', '.join(missing)}")
    if outputs_fn is None:
        from engine_model.runtime.shared_model import default_model

        outputs_fn = default_model().evaluate
    w = df[list(W_NAMES)].to_numpy(np.float64)
    theta = df[list(THETA_NAMES)].to_numpy(np.float64)
    ev = outputs_fn(w, theta)
    bad = int((~np.asarray(ev["converged"], bool)).sum())
    if bad:
        raise InputError(f"ablation III (perfect calibration): the engine model does not "
                         f"converge at {bad} of {len(df)} samples with their true theta")
    out = df.copy()
    for c in (*XS_NAMES, *XV_NAMES):
        if c + "_hat" in out.columns:
            out[c + "_hat"] = ev[c].to_numpy().astype(out[c + "_hat"].dtype)
    for q in THETA_NAMES:
        if q + "_hat" in out.columns:
            out[q + "_hat"] = out[q].astype(out[q + "_hat"].dtype)
    return out


def train_config(run: Run, cfg: ExperimentConfig, test_units: Sequence[int]) -> TrainConfig:
    """The run's configuration with the paper's recipe (:data:`PAPER_RECIPE`: batch 1024,
    patience 5, constant learning rate, min-max scaling, validation flights), not the
    library's size-dependent defaults."""
    epochs = DEFAULT_EPOCHS[run.model] if cfg.epochs is None else cfg.epochs  # the paper's
    return TrainConfig(model=run.model, inputs=run.inputs, seed=run.seed, epochs=epochs,
                       units=run.units, test_units=tuple(test_units),
                       conformal_units=run.conformal_units, alpha=cfg.alpha,
                       device=cfg.device, **PAPER_RECIPE).resolved()


def is_experiment_folder(path: Path) -> bool:
    """``path`` is an experiment's folder (it holds ``runs/``)."""
    return (path / "runs").is_dir()


#: The experiment's output folder (the ownership rule's kind): written into and resumed.
EXPERIMENT_FOLDER = OutputKind("an experiment's folder (with runs/)", directory=True,
                               ours=is_experiment_folder, resumed=True)


def check_experiment_out(out: Path, inputs=()) -> None:
    """``out`` is absent, empty (but for hyprog's hidden entries) or an experiment's folder,
    and none of ``inputs``: the experiment writes, resumes and cleans up only there, never in
    a folder of other files (the ownership rule, :mod:`engine_model.runtime.ownership`)."""
    check_output(out, EXPERIMENT_FOLDER, inputs=inputs)


def run_key(run: Run, tc: TrainConfig, fingerprint: str) -> str:
    d = tc.to_dict()
    d.pop("device")
    what = asdict(run)
    what.pop("part")
    body = {"cache": CACHE_VERSION, "format": FORMAT_VERSION, "run": what, "train": d,
            "data": fingerprint}
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()[:20]


def _execute(run: Run, tc: TrainConfig, df: pd.DataFrame, meta: dict, test: list[int],
             run_dir: Path, perfect: Callable[[], pd.DataFrame]) -> dict:
    t0 = time.perf_counter()
    if run.perturbation == PERFECT:
        data = perfect()
    elif run.perturbation:
        data = perturb_theta(df, run.perturbation, run.seed)
    else:
        data = df
    model = fit(data, meta, tc, quiet=True)
    metrics, pred = model.evaluate(data, test, tc.device)
    seconds = time.perf_counter() - t0
    save_model(model, run_dir / "model")
    write_table(run_dir / "predictions.parquet", pred)
    m = model.members[0]
    rec = {"run": asdict(run), "train": tc.to_dict(), "metrics": metrics,
           "history": m.history, "best_epoch": m.best_epoch, "parameters": m.parameters,
           "conformal": None if model.conformal is None else model.conformal.to_dict(),
           "seconds": seconds}
    write_json(run_dir / "result.json", jsonable(rec))
    return load_result(run_dir)  # the same (string-keyed) record a resumed run reads


def load_result(run_dir: Path) -> dict | None:
    f = run_dir / "result.json"
    if not f.is_file():
        return None
    try:
        return json.loads(f.read_text())
    except json.JSONDecodeError:
        return None


def _baseline(df, meta, dev, test, out: Path, fingerprint: str, hi_fn, log) -> dict:
    from prognostics.baseline import baseline_per_cycle, baseline_predictions, engine_health_index

    max_rul = float(df.loc[df["unit"].isin(dev), "RUL"].max())
    key = hashlib.sha256(json.dumps({"baseline": 1, "data": fingerprint, "max_rul": max_rul,
                                     "test": test}).encode()).hexdigest()[:20]
    run_dir = out / "runs" / f"baseline-{key}"
    done = load_result(run_dir)
    if done is not None:
        log("baseline: cached")
        done["key"] = run_dir.name
        return done
    hi = hi_fn if hi_fn is not None else engine_health_index()
    t0 = time.perf_counter()
    pred = baseline_predictions(df, hi, max_rul, test)
    pc = baseline_per_cycle(df, hi, max_rul, test)
    write_table(run_dir / "predictions.parquet", pred)
    write_table(run_dir / "per_cycle.parquet", pc)
    rec = {"run": {"part": "baseline", "model": "physics", "inputs": "theta_hat-HI-trend"},
           "metrics": evaluate_predictions(pred), "max_rul": max_rul,
           "seconds": time.perf_counter() - t0}
    write_json(run_dir / "result.json", jsonable(rec))
    log(f"baseline: rmse {rec['metrics']['samples']['overall']['rmse']:.3f}")
    rec = load_result(run_dir)
    rec["key"] = run_dir.name
    return rec


def run_experiment(df: pd.DataFrame, metadata: dict | None, out: str | Path,
                   config: ExperimentConfig | None = None,
                   hi_fn: Callable[[np.ndarray], np.ndarray] | None = None,
                   log: Callable[[str], None] | None = None, source: str = "table",
                   outputs_fn: Callable[[np.ndarray, np.ndarray], pd.DataFrame] | None = None,
                   inputs=()) -> dict:
    """Run (or resume) every selected run, then write the report (:mod:`.paper_report`).

    ``hi_fn`` is the health index for the baseline (default: the engine model's
    ``HealthIndex``, built only when the baseline is not cached); ``outputs_fn`` the model
    of :func:`perfect_calibration` (default: the engine model, evaluated only when a perfect-
    calibration run is not cached); ``inputs``: the paths the command read (the feature
    table), never written over. Returns ``{"trained", "cached", "runs", "report"}``.
    """

    log = log or (lambda s: None)
    cfg = (config or ExperimentConfig()).checked()
    out = Path(out)
    check_experiment_out(out, inputs)
    meta = metadata or {}
    present = np.unique(df["unit"].to_numpy()).tolist()
    dev, test = development_and_test_units(present, meta, source=source)
    if not test:
        raise InputError(f"{source}: the metadata names no test_units to evaluate on")
    if "small" in cfg.parts:
        development_and_test_units(present, meta, cfg.small_units, test, source)
    fingerprint = table_fingerprint(df, meta)
    runs = plan(cfg, dev)
    perfect_table: list[pd.DataFrame] = []

    def perfect() -> pd.DataFrame:  # computed once, when a run first needs it
        if not perfect_table:
            log("ablation III: the engine model at the true theta of every sample")
            perfect_table.append(perfect_calibration(df, outputs_fn))
        return perfect_table[0]

    records, trained, cached = [], 0, 0
    with output_lock(out):  # one writer per OUT (module docstring, "Cache and resume")
        remove_stale_temporaries(out)  # what a killed run was writing
        for i, run in enumerate(runs, 1):
            tc = train_config(run, cfg, test)
            key = run_key(run, tc, fingerprint)
            run_dir = out / "runs" / key
            rec = load_result(run_dir)
            if rec is None:
                rec = _execute(run, tc, df, meta, test, run_dir, perfect)
                trained += 1
                state = "trained"
            else:
                cached += 1
                state = "cached"
            # a run shared by two parts (features' data-driven and hybrid are main's) is
            # reported under each part that plans it, not under the part that trained it
            rec["run"] = {**rec["run"], "part": run.part}
            rec["key"] = key
            records.append(rec)
            rmse = rec["metrics"]["samples"]["overall"]["rmse"]
            log(f"[{i}/{len(runs)}] {run.label()}: rmse {rmse:.3f} ({state})")
        base = _baseline(df, meta, dev, test, out, fingerprint, hi_fn, log) if cfg.baseline \
            else None
        report = write_report(out, records, base, df, cfg)
    return {"trained": trained, "cached": cached, "runs": len(runs), "report": report}

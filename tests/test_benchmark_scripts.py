"""The benchmark scripts (``benchmarks/*.py``): ``--help`` answers at once and runs nothing
(several scripts once ran on ``--help``, one deleting a committed report), and the shared cache
key (``benchmarks/common.py``'s ``run_key``) is the one the committed caches were keyed with."""

import os
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from .conftest import REPO, load_script

BENCHMARKS = REPO / "benchmarks"
#: modules the scripts import, not scripts
MODULES = ("common.py", "run_cache.py")
SCRIPTS = sorted(p.name for p in BENCHMARKS.glob("*.py") if p.name not in MODULES)
assert len(SCRIPTS) >= 20 and "pipeline_default.py" in SCRIPTS
#: seconds one ``--help`` may take (they take well under one; this allows a loaded machine)
HELP_SECONDS = 15

#: a run's body and its keys as the scripts computed them before the key moved to
#: benchmarks/common.py (cmapss.run_key: 16 hex digits; health_features.key_of: 20)
BODY = {"subset": "FD001", "fold": 2, "folds": 5, "fold_seed": 0,
        "config": {"model": "dcnn", "window": 30, "max_rul": 125.0,
                   "inputs": "w+cmapss+theta_hat", "seed": 1, "units": [1, 2, 3]},
        "pool": ["FD002"], "noise": "--noise data"}
KEY_16 = "f685d17dd54d1ad3"
KEY_20 = "f685d17dd54d1ad3106b"


def _files(root):
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def test_help_answers_at_once_and_writes_nothing(tmp_path):
    """Every script's ``--help`` from a copy of ``benchmarks/`` (its parent folder the working
    directory, so that whatever a script writes, relative or beside itself, lands in the
    copy): exit 0 with the usage within :data:`HELP_SECONDS`, and no file added or removed.
    One test for all of them, so that the parallel test workers run the set once."""
    root = tmp_path / "repo"
    shutil.copytree(BENCHMARKS, root / "benchmarks",
                    ignore=shutil.ignore_patterns("results", "__pycache__"))
    before = _files(root)
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}

    def run(name):
        try:
            proc = subprocess.run([sys.executable, str(root / "benchmarks" / name), "--help"],
                                  cwd=root, env=env, capture_output=True, text=True,
                                  timeout=HELP_SECONDS)
        except subprocess.TimeoutExpired:
            return f"{name}: no answer within {HELP_SECONDS} s"
        if proc.returncode != 0 or not proc.stdout.startswith("usage:"):
            return f"{name}: exit {proc.returncode}: {(proc.stderr or proc.stdout)[-800:]}"
        return None

    with ThreadPoolExecutor(max_workers=4) as pool:
        failed = [f for f in pool.map(run, SCRIPTS) if f]
    assert not failed, "\n".join(failed)
    assert _files(root) == before


def test_run_key_is_the_key_the_caches_were_written_with():
    common = load_script(BENCHMARKS / "common.py", "benchmarks_common")
    assert common.run_key(BODY) == KEY_16
    assert common.run_key(BODY, 20) == KEY_20
    # a floors record of the committed C-MAPSS cache, keyed by its body
    runs = load_script(BENCHMARKS / "run_cache.py", "benchmarks_run_cache")
    keys = {r["key"] for r in runs.read_runs(BENCHMARKS / "results" / "cmapss" / "runs.jsonl.gz")}
    assert common.run_key({"floors": 1, "subset": "FD001", "fold": 0, "folds": 5,
                           "fold_seed": 0}) in keys


def test_the_scripts_key_with_the_shared_function():
    cmapss = load_script(BENCHMARKS / "cmapss.py", "cmapss_benchmark_keys")
    health = load_script(BENCHMARKS / "health_features.py", "health_features_keys")
    assert cmapss.run_key(BODY) == KEY_16
    assert health.run_key(BODY, health.KEY_LENGTH) == KEY_20


def test_cmapss_model_error_is_a_number_or_consistent():
    """``--model-error``: a relative std or ``consistent``, passed to ``hyprog calibrate`` as
    given and named in the run's label (and its features folder); 0 adds nothing."""
    import argparse

    cmapss = load_script(BENCHMARKS / "cmapss.py", "cmapss_benchmark_model_error")
    assert cmapss.model_error_option("0.003") == 0.003
    assert cmapss.model_error_option("consistent") == "consistent"
    with pytest.raises(argparse.ArgumentTypeError, match="'often'"):
        cmapss.model_error_option("often")
    assert cmapss.measurement_options("data", "consistent") == (
        ["--noise", "data", "--model-error", "consistent"],
        "--noise data --model-error consistent")
    assert cmapss.measurement_options("data", 0.003)[1] == "--noise data --model-error 0.003"
    assert cmapss.measurement_options("model", 0.0) == ([], "")
    assert cmapss.measurement_options("data", "consistent", "T30,BPR")[1] == (
        "--noise data --model-error consistent --sensors T30,BPR")


def test_parse_range_reads_ranges_and_lists():
    common = load_script(BENCHMARKS / "common.py", "benchmarks_common")
    assert common.parse_range("1000-1003") == [1000, 1001, 1002, 1003]
    assert common.parse_range("0,3,5") == [0, 3, 5]
    assert common.parse_range("0-2,7") == [0, 1, 2, 7]
    assert common.parse_range("5") == [5]


def test_health_features_chooses_on_every_fold_among_the_hybrids():
    """The candidate the test units meet: the lowest mean CV RMSE over every fold, never the
    data-driven reference or the true-θ ablation; none while a fold is missing."""
    hf = load_script(BENCHMARKS / "health_features.py", "health_features_bench")

    def cv(model, inputs, window, rmses):
        return [{"stage": "cv", "kind": "model", "model": model, "inputs": inputs,
                 "window": window, "fold": k, "ensemble": {"rmse": r}}
                for k, r in enumerate(rmses)]

    runs = (cv("tcn", "data-driven", 20, [1, 1, 1]) + cv("tcn", "health_true", 20, [2, 2, 2])
            + cv("tcn", "physics", 10, [5, 6, 7]) + cv("tcn", "health", 20, [4, 9, 9])
            + cv("trend", "physics", 20, [3, 3]))
    assert hf.chosen_on_cv(runs) == ("tcn", "physics", 10)
    assert hf.chosen_on_cv(cv("trend", "physics", 20, [3, 3])) is None


def test_health_features_scores_the_similarity_predictor_on_held_out_units():
    """library_predict: fitted on the development flights only, scored on the held-out
    units' samples like the networks, no seeds."""
    import numpy as np
    import pandas as pd
    import pytest

    from prognostics.similarity import SimilarityRul

    hf = load_script(BENCHMARKS / "health_features.py", "health_features_bench")
    rng = np.random.default_rng(0)
    flights = pd.concat([pd.DataFrame({
        "unit": u, "cycle": np.arange(1, life + 1), "RUL": life - np.arange(1, life + 1),
        "hs": (np.arange(1, life + 1) < life // 2).astype(int),
        "HI_hat": 1 - (np.arange(1, life + 1) / life) ** 2 + 0.01 * rng.standard_normal(life)})
        for u, life in ((1, 40), (2, 50), (3, 60), (4, 45))], ignore_index=True)
    dev, held = flights[flights["unit"] != 4], flights[flights["unit"] == 4]
    res = hf.library_predict(dev, held, 5, held[["unit", "cycle", "RUL", "hs"]])
    assert res["per_seed"] == []
    pred = SimilarityRul.fit(dev, 5).predict(held)
    err = pred["RUL"] - pred["RUL_pred"]
    assert res["ensemble"]["rmse"] == pytest.approx(float(np.sqrt(np.mean(err ** 2))))


def test_health_features_reports_a_model_without_seeds(tmp_path):
    """The similarity predictor (no network, no seeds) is a candidate like the networks: it
    can be chosen, and its test row has no per-seed column."""
    hf = load_script(BENCHMARKS / "health_features.py", "health_features_bench")
    scores = {"rmse": 4.0, "last_rmse": 1.0, "horizon": 30.0,
              "phases": {"before onset": 5.0, "after onset": 3.0, "RUL <= 30": 2.0}}

    def rec(stage, fold, model, inputs, window, rmse, seeds):
        return {"key": f"{stage}{fold}{model}{inputs}{window}", "kind": "model",
                "stage": stage, "fold": fold, "model": model, "inputs": inputs,
                "window": window, "held": [1], "ensemble": {**scores, "rmse": rmse},
                "per_seed": [{**scores, "rmse": rmse + s} for s in seeds]}

    runs = [rec("cv", k, "tcn", "physics", 10, 11.0, [0, 1]) for k in range(3)]
    runs += [rec("cv", k, "similarity", "hi", 10, 10.5, []) for k in range(3)]
    runs += [rec("cv", k, "tcn", "data-driven", 20, 9.0, [0, 1]) for k in range(3)]
    runs += [rec("test", 0, "similarity", "hi", 10, 4.0, []),
             rec("test", 0, "tcn", "data-driven", 20, 9.0, [0, 1])]
    assert hf.chosen_on_cv(runs) == ("similarity", "hi", 10)
    hf.report(runs, tmp_path, tmp_path / "runs.jsonl")
    table = (tmp_path / "health.md").read_text()
    assert "| similarity hi (window 10) (chosen) | 10.50 | - | 4.00 |" in table
    assert "| tcn data-driven (window 20) | 9.00 | 9.50 ± 0.71 | 9.00 |" in table


def test_health_study_merges_committed_rows_only_for_the_same_fleet():
    """``--merge-committed``: the committed rows the cache lacks join it for a fleet and size
    whose floors the cache reproduces (to the table's 4 digits); one whose floors differ stops
    the merge, naming the fleet; a row the cache has is never replaced."""
    import pandas as pd
    import pytest

    hs = load_script(BENCHMARKS / "health_study.py", "health_study_bench")

    def rows(fleet, n, life, lookup, **models):
        return [{"fleet": fleet, "n": n, "predictor": "floor: life", "rmse": life},
                {"fleet": fleet, "n": n, "predictor": "floor: hi-lookup", "rmse": lookup},
                *({"fleet": fleet, "n": n, "predictor": p, "rmse": r}
                  for p, r in models.items())]

    committed = pd.DataFrame(rows(0, 3, 14.46, 16.36, physics=10.0, health=11.0)
                             + rows(1, 3, 12.0, 11.0, physics=9.0))
    cache = pd.DataFrame(rows(0, 3, 14.4612, 16.3598, similarity=8.0, health=12.0))
    merged = hs.merge_committed(cache, committed).set_index(["fleet", "n", "predictor"])
    assert merged.loc[(0, 3, "physics"), "rmse"] == 10.0     # added: same floors
    assert merged.loc[(0, 3, "health"), "rmse"] == 12.0      # the cache's, not replaced
    assert merged.loc[(0, 3, "similarity"), "rmse"] == 8.0
    assert (1, 3, "physics") not in merged.index              # that fleet never ran here
    assert len(merged) == 5
    other = pd.DataFrame(rows(0, 3, 14.9, 16.36))
    with pytest.raises(SystemExit, match="fleet 0, n 3"):
        hs.merge_committed(other, committed)


def test_largest_difference_is_relative_to_each_reference_output():
    """The benchmarks that compare two builds of the same Functions (forward and reverse
    mode; two compiler levels) report the largest difference relative to each output's
    largest magnitude, so a large output does not hide a small one's error."""
    ad = load_script(BENCHMARKS / "sensitivities_ad.py", "sensitivities_ad_difference")
    big, small = np.array([1000.0, -2000.0]), np.array([0.5, 1.0])
    assert ad.largest_difference([big, small], [big, small]) == 0.0
    assert ad.largest_difference([big, small], [big + 2.0, small]) == pytest.approx(1e-3)
    assert ad.largest_difference([big, small], [big, small + 0.01]) == pytest.approx(0.01)

"""``hyprog train / evaluate / predict / experiment paper`` through the CLI on a tiny
synthetic feature table: the round trip, the resumable experiment, and bad input (one
``error:`` line naming the file or column, non-zero exit, nothing left behind).

Exit codes: only ``!= 0`` is asserted (the CLI's code for bad input vs failed computation is
set in cli.common).
"""

import json
import shutil

import numpy as np
import pandas as pd
import pytest

from cli.main import app
from engine_model.datasets import read_dataset, write_parquet
from engine_model.validation import InputError
from tests.cli_checks import assert_user_error as check_user_error
from tests.cli_checks import cli_runner
from tests.test_prognostics_training import resign_manifest

pytestmark = pytest.mark.usefixtures("torch_one_thread")

FAST = ["--epochs", "2", "--device", "cpu", "--quiet"]


@pytest.fixture(scope="module")
def runner():
    return cli_runner()


def assert_user_error(result, *fragments):
    check_user_error(result, *fragments, code=None)


def run(runner, *args):
    return runner.invoke(app, [str(a) for a in args])


def ok(result):
    assert result.exit_code == 0, (result.exit_code, result.stdout, result.stderr,
                                   result.exception)
    return result


def assert_nothing_left(directory, *names):
    for n in names:
        assert not (directory / n).exists(), n
    assert not [p.name for p in directory.iterdir() if ".tmp-" in p.name or ".old-" in p.name]


@pytest.fixture(scope="module")
def model_dir(runner, features_parquet, tmp_path_factory):
    """A CNN ensemble of two seeds with a conformal unit, trained through the CLI."""
    out = tmp_path_factory.mktemp("cli") / "cnn"
    r = ok(run(runner, "train", features_parquet, "--model", "cnn", "--inputs", "hybrid",
               "--window", "8", "--ensemble", "2", "--conformal-units", "4", "--json", *FAST,
               "--out", out))
    rep = json.loads(r.stdout)
    assert rep["window"] == 8 and len(rep["columns"]) == 50
    assert [m["seed"] for m in rep["members"]] == [0, 1]
    assert rep["conformal"]["units"] == [4]
    return out


def test_train_evaluate_predict_round_trip(runner, model_dir, features_parquet, tmp_path):
    r = ok(run(runner, "evaluate", model_dir, features_parquet, "--json"))
    m = json.loads(r.stdout)
    assert set(m["samples"]["units"]) == {"5", "6"}  # the metadata's test units
    assert set(m["last"]["units"]) == {"5", "6"}
    assert m["samples"]["overall"]["rmse"] > 0 and "coverage" in m["samples"]["overall"]
    assert set(m["horizon"]["units"]) == {"5", "6"}
    table = ok(run(runner, "evaluate", model_dir, features_parquet)).stdout
    assert "CNN hybrid" in table and "all" in table  # the title and the overall row

    out = tmp_path / "preds.csv"
    r = ok(run(runner, "predict", model_dir, features_parquet, "--units", "5", "--out", out,
               "--json"))
    rep = json.loads(r.stdout)
    pred = pd.read_csv(out)
    pc = pd.read_csv(tmp_path / "preds.per_cycle.csv")
    df, _ = read_dataset(features_parquet)
    n5 = int((df.unit == 5).sum())
    assert rep["samples"] == len(pred) == n5 - 7  # every sample that ends a window of 8
    assert {"RUL_pred", "RUL_std", "RUL_lower", "RUL_upper"} <= set(pred.columns)
    assert rep["cycles"] == len(pc) == pred.cycle.nunique()
    # evaluate's per-unit RMSE is the one of the written predictions
    d = pred.RUL - pred.RUL_pred
    assert m["samples"]["units"]["5"]["rmse"] == pytest.approx(np.sqrt(np.mean(d * d)))


def test_train_prints_the_parameter_count_and_a_progress_bar(runner, features_parquet,
                                                             tmp_path):
    r = ok(run(runner, "train", features_parquet, "--model", "fnn", "--inputs", "data-driven",
               "--epochs", "2", "--device", "cpu", "--out", tmp_path / "fnn"))
    assert "FNN on 20 inputs (data-driven), window 1: 94,701 trainable parameters" in r.stdout
    # which units validated (whole units by default), as the model records them
    from prognostics.checkpoint import load_model

    held = load_model(tmp_path / "fnn").info["units"]["validation"]
    assert f"validation on units {', '.join(map(str, held))}" in r.stdout
    assert (tmp_path / "fnn" / "model.json").is_file()
    # the bar (stderr) shows the running training and validation loss of every epoch
    assert "fnn data-driven seed 0 epoch 2" in r.stderr and " val " in r.stderr


def test_experiment_paper_runs_and_resumes_from_its_cache(runner, features_parquet, tmp_path):
    out = tmp_path / "exp"
    args = ["experiment", "paper", "--data", features_parquet, "--out", out, "--seeds", "1",
            "--epochs", "1", "--ablations", "small,calibration", "--small-units", "1,2",
            "--device", "cpu", "--json"]
    first = json.loads(ok(run(runner, *args)).stdout)
    # main 2 models x 2 sets, small 2 sets, calibration 4 perturbations; one seed each
    assert first["runs"] == 10 and first["trained"] == 10 and first["cached"] == 0
    rows = pd.read_csv(out / "runs.csv")
    assert {"model", "inputs", "seed", "rmse", "score"} <= set(rows.columns)
    assert len(rows) == 11 and rows.part.tolist().count("baseline") == 1
    assert np.isfinite(rows.rmse).all()
    md = (out / "tables.md").read_text()
    for title in ("Main table", "Ablation I", "Ablation IV", "physics baseline",
                  "The paper's claims"):
        assert title in md
    figures = {p.name for p in (out / "figures").glob("*.png")}
    assert {"theta_hat.png", "training_curves.png", "rul_baseline.png",
            "rul_main_cnn_hybrid.png"} <= figures
    # the reruns write the tables only: the first run's figures are removed, not left beside
    # tables they may no longer match
    second = json.loads(ok(run(runner, *args, "--no-figures")).stdout)
    assert second["trained"] == 0 and second["cached"] == 10
    assert second["report"]["figures"] == [] and not (out / "figures").exists()
    assert pd.read_csv(out / "runs.csv").drop(columns="seconds").equals(
        rows.drop(columns="seconds"))
    assert (out / "tables.md").read_text() == md
    # an interrupted run (no result.json) is the only one redone
    key = rows[rows.part == "small"].key.iloc[0]
    (out / "runs" / key / "result.json").unlink()
    third = json.loads(ok(run(runner, *args, "--no-figures")).stdout)
    assert third["trained"] == 1 and third["cached"] == 9


def test_experiment_reports_a_shared_run_under_each_part(runner, features_parquet, tmp_path):
    """Ablation III's data-driven and calibrated hybrid runs are main's CNN runs, trained once
    and listed under both parts: the main table averages main's runs only. Its perfect-
    calibration runs (denoised, virtual, hybrid on x̂ and θ at their true values, the engine
    model evaluated at every sample's true theta) are runs of their own."""
    out = tmp_path / "exp"
    r = json.loads(ok(run(runner, "experiment", "paper", "--data", features_parquet, "--out",
                          out, "--seeds", "1", "--epochs", "1", "--ablations", "features",
                          "--device", "cpu", "--no-figures", "--json")).stdout)
    # main 2 models x 2 sets; features 5 calibrated sets (data-driven and hybrid are main's)
    # and 3 perfect-calibration sets
    assert r["runs"] == 12 and r["trained"] == 10 and r["cached"] == 2
    rows = pd.read_csv(out / "runs.csv", keep_default_na=False)
    assert rows.part.value_counts().to_dict() == {"main": 4, "features": 8, "baseline": 1}
    cnn = rows[(rows.model == "cnn") & rows.inputs.isin(["data-driven", "hybrid"])
               & (rows.perturbation == "")]
    assert cnn.groupby("inputs").key.nunique().to_dict() == {"data-driven": 1, "hybrid": 1}
    assert cnn.groupby("inputs").part.apply(sorted).to_dict() == {
        "data-driven": ["features", "main"], "hybrid": ["features", "main"]}
    perfect = rows[rows.perturbation == "perfect"]
    assert sorted(perfect.inputs) == ["denoised", "hybrid", "virtual"]
    assert set(perfect.part) == {"features"} and perfect.key.nunique() == 3
    md = (out / "tables.md").read_text()
    iii = md[md.index("Ablation III"):md.index("The paper's claims")]
    assert "| data-driven [w, x_s] |" in iii and "| hybrid, calibrated θ̂ |" in iii
    assert "| hybrid [w, x_s, x̂_s, x̂_v, θ], perfect calibration |" in iii
    assert "perfect calibration does at least as well as θ̂" in md


# ---------------------------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------------------------


def test_missing_file(runner, tmp_path, model_dir):
    r = run(runner, "train", tmp_path / "nope.parquet", *FAST, "--out", tmp_path / "m")
    assert_user_error(r, "nope.parquet")
    assert_nothing_left(tmp_path, "m")
    assert_user_error(run(runner, "evaluate", tmp_path / "no-model", tmp_path / "x.parquet"),
                      "no-model")
    assert_user_error(run(runner, "predict", model_dir, tmp_path / "nope.parquet", "--out",
                          tmp_path / "p.csv"), "nope.parquet")
    assert_nothing_left(tmp_path, "p.csv", "p.per_cycle.csv")


def test_ensemble_zero_and_a_failed_training_leave_nothing(runner, features_parquet, tmp_path):
    assert_user_error(run(runner, "train", features_parquet, "--ensemble", "0", *FAST,
                          "--out", tmp_path / "m"), "--ensemble must be >= 1, got 0")
    assert_user_error(run(runner, "train", features_parquet, "--units", "1,99", *FAST,
                          "--out", tmp_path / "m"), "99")
    assert_user_error(run(runner, "train", features_parquet, "--inputs", "hybrid+htBleed",
                          *FAST, "--out", tmp_path / "m"), "htBleed")
    assert_user_error(run(runner, "train", features_parquet, "--model", "lstm", *FAST,
                          "--out", tmp_path / "m"), "lstm")
    assert_nothing_left(tmp_path, "m")


def test_train_refuses_to_overwrite_a_foreign_directory_before_training(runner,
                                                                        features_parquet,
                                                                        tmp_path):
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "keep.txt").write_text("mine")
    r = run(runner, "train", features_parquet, *FAST, "--out", tmp_path / "data")
    assert_user_error(r, "not a hyprog model directory")
    assert (tmp_path / "data" / "keep.txt").read_text() == "mine"


def test_a_table_without_the_models_input_columns(runner, model_dir, features_parquet,
                                                   tmp_path):
    df, meta = read_dataset(features_parquet)
    bad = write_parquet(df.drop(columns=["LPT_flow_mod_hat", "W21_hat"]),
                        tmp_path / "raw.parquet", meta)
    assert_user_error(run(runner, "evaluate", model_dir, bad), "raw.parquet",
                      "W21_hat", "LPT_flow_mod_hat")
    r = run(runner, "predict", model_dir, bad, "--out", tmp_path / "p.csv")
    assert_user_error(r, "raw.parquet", "W21_hat")
    assert_nothing_left(tmp_path, "p.csv", "p.per_cycle.csv")


def test_a_tampered_checkpoint_is_refused(runner, model_dir, features_parquet, tmp_path):
    d = tmp_path / "m"
    shutil.copytree(model_dir, d)
    blob = bytearray((d / "member-0.safetensors").read_bytes())
    blob[-3] ^= 0x10
    (d / "member-0.safetensors").write_bytes(bytes(blob))
    assert_user_error(run(runner, "evaluate", d, features_parquet), "member-0.safetensors",
                      "SHA-256 mismatch")
    r = run(runner, "predict", d, features_parquet, "--out", tmp_path / "p.csv")
    assert_user_error(r, "SHA-256 mismatch")
    assert_nothing_left(tmp_path, "p.csv")


@pytest.mark.parametrize("change, named", [
    ("deleted", "member-0.safetensors: weights file missing"),
    ("outside", "weights file missing"),  # a re-signed manifest naming a file elsewhere
    ("not a record", "model.json: malformed member record"),
    ("no seed", "model.json: malformed member record ('seed')"),
    ("no members", "model.json: no trained members"),
    ("scaler", "model.json: the scaler's columns differ from the inputs"),
    ("no config", "model.json: malformed manifest ('config')"),
])
def test_a_damaged_checkpoint_names_what_is_wrong(runner, model_dir, features_parquet,
                                                  tmp_path, change, named):
    d = tmp_path / "m"
    shutil.copytree(model_dir, d)
    body = json.loads((d / "model.json").read_text())
    first = dict(body["members"][0])
    if change == "deleted":
        (d / "member-0.safetensors").unlink()
    elif change == "outside":
        (tmp_path / "elsewhere.safetensors").write_bytes((d / first["file"]).read_bytes())
        resign_manifest(d, members=[{**first, "file": "../elsewhere.safetensors"}])
    elif change == "not a record":
        resign_manifest(d, members=["member-0.safetensors"])
    elif change == "no seed":
        resign_manifest(d, members=[{k: v for k, v in first.items() if k != "seed"}])
    elif change == "no members":
        resign_manifest(d, members=[])
    elif change == "scaler":
        resign_manifest(d, columns=body["columns"][::-1])
    else:
        resign_manifest(d, drop=("config",))
    assert_user_error(run(runner, "evaluate", d, features_parquet), named)


def test_a_checkpoint_from_another_version(runner, model_dir, features_parquet, tmp_path):
    """Another hyprog version with the same format version: a one-line warning, and it works;
    another format version: refused (checkpoint module docstring)."""
    d = tmp_path / "old"
    shutil.copytree(model_dir, d)
    resign_manifest(d, hyprog_version="0.0.1")
    r = ok(run(runner, "evaluate", d, features_parquet, "--json"))
    rep = json.loads(r.stdout)  # --json: the warning is in the report's warnings
    assert r.stderr == "" and len(rep["warnings"]) == 1
    assert "written by hyprog 0.0.1" in rep["warnings"][0]
    assert rep["samples"]["overall"]["n"] > 0
    r = ok(run(runner, "evaluate", d, features_parquet))
    assert r.stderr.startswith("warning: ") and "written by hyprog 0.0.1" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    resign_manifest(d, format_version=99)
    assert_user_error(run(runner, "evaluate", d, features_parquet), "format version 99",
                      "retrain")


def test_a_test_unit_shorter_than_the_window_is_left_padded(runner, model_dir,
                                                           features_parquet, tmp_path):
    """Documented behaviour (prognostics.windows): one prediction at its last sample."""
    df, meta = read_dataset(features_parquet)
    short = df[(df.unit == 6) & (df.cycle == 1)].head(5)  # 5 samples, window 8
    data = write_parquet(pd.concat([df[df.unit == 5], short]), tmp_path / "short.parquet",
                         meta)
    out = tmp_path / "p.csv"
    ok(run(runner, "predict", model_dir, data, "--out", out))
    pred = pd.read_csv(out)
    assert (pred.unit == 6).sum() == 1
    assert pred.loc[pred.unit == 6, "t"].item() == short.t.max()
    m = json.loads(ok(run(runner, "evaluate", model_dir, data, "--json")).stdout)
    assert m["samples"]["units"]["6"]["n"] == 1


def test_experiment_bad_options(runner, features_parquet, tmp_path):
    assert_user_error(run(runner, "experiment", "paper", "--data", features_parquet, "--out",
                          tmp_path / "e", "--ablations", "noise"), "unknown ablation", "noise")
    assert_user_error(run(runner, "experiment", "paper", "--data", features_parquet, "--out",
                          tmp_path / "e", "--seeds", "0"), "--seeds 0")
    assert_user_error(run(runner, "experiment", "paper", "--data", features_parquet, "--out",
                          tmp_path / "e", "--ablations", "small"), "16")  # default 16,18,20
    assert_user_error(run(runner, "experiment", "paper", "--data", features_parquet, "--out",
                          tmp_path / "e", "--alpha", "nan"), "--alpha must lie in (0, 1)")
    assert_nothing_left(tmp_path, "e")
    # a folder of other files is refused before anything is written or cleaned in it
    other = tmp_path / "home"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    (other / ".bashrc.old-2019").write_text("a user's backup")
    assert_user_error(run(runner, "experiment", "paper", "--data", features_parquet, "--out",
                          other), "not an experiment's")
    assert sorted(p.name for p in other.iterdir()) == [".bashrc.old-2019", "notes.txt"]


def test_cmapss_files_import_train_and_evaluate_unchanged(runner, tmp_path):
    """C-MAPSS text (one sample per cycle, test units truncated, RUL file) -> hyprog table ->
    train (data-driven plus C-MAPSS-only columns, whole validation units) -> evaluate; the
    last-cycle truth of each test unit is its RUL-file value."""
    rng = np.random.default_rng(3)

    def lines(units, truncate=None):
        out = []
        for u, life in units.items():
            for c in range(1, (truncate or {}).get(u, life) + 1):
                h = c / life
                settings = [rng.choice([0.0, 10.0, 35.0]), 0.6, 100.0]
                sensors = [500.0 + 20 * h + rng.normal(0, 0.5) for _ in range(21)]
                out.append(f"{u} {c} " + " ".join(f"{v:.4f}" for v in settings + sensors) + "  ")
        return out

    train = {1: 40, 2: 46, 3: 38, 4: 44}
    test = {1: 42, 2: 40}
    seen = {1: 25, 2: 18}  # observed cycles of the truncated test units
    (tmp_path / "train_FD002.txt").write_text("\n".join(lines(train)) + "\n")
    (tmp_path / "test_FD002.txt").write_text("\n".join(lines(test, seen)) + "\n")
    (tmp_path / "RUL_FD002.txt").write_text(
        "\n".join(f"{test[u] - seen[u]} " for u in test) + "\n")
    data = tmp_path / "fd002.parquet"
    ok(run(runner, "data", "import-cmapss", tmp_path / "train_FD002.txt", "--test",
           tmp_path / "test_FD002.txt", "--rul", tmp_path / "RUL_FD002.txt", "--out", data))
    df, meta = read_dataset(data)
    assert len(meta["test_units"]) == 2
    assert_user_error(run(runner, "train", data, "--inputs", "hybrid", *FAST, "--out",
                          tmp_path / "m"), "xs_hat", "hyprog calibrate")
    r = ok(run(runner, "train", data, "--inputs", "data-driven+phi,BPR", "--window", "5",
               "--val-units", "4", *FAST, "--json", "--out", tmp_path / "m"))
    cols = json.loads(r.stdout)["columns"]
    assert cols[-2:] == ["phi", "BPR"] and "Ps30" in cols and "P30" in cols
    # validation units drawn by the seed (10 % of four training units: one)
    ok(run(runner, "train", data, "--inputs", "data-driven", "--window", "5",
           "--val-units", "seed", *FAST, "--out", tmp_path / "m-seed"))
    cfg = json.loads((tmp_path / "m-seed" / "model.json").read_text())["config"]
    assert cfg["validation"] == "units" and cfg["val_units"] is None
    m = json.loads(ok(run(runner, "evaluate", tmp_path / "m", data, "--json")).stdout)
    last = m["last"]["units"]
    assert sorted(e["RUL"] for e in last.values()) == sorted(
        float(test[u] - seen[u]) for u in test)
    assert sorted(e["cycle"] for e in last.values()) == sorted(seen.values())
    assert m["samples"]["overall"]["n"] == sum(seen.values()) - 2 * 4  # windows of 5


@pytest.mark.parametrize("args, fragment", [
    (["--max-rul", "nan"], "--max-rul must be a positive finite number"),
    (["--max-rul", "inf"], "--max-rul must be a positive finite number"),
    (["--epochs", "0"], "--epochs must be >= 1, got 0"),
    (["--batch-size", "0"], "--batch-size must be >= 1"),
    (["--seed", "-1"], "--seed -1: expected an integer >= 0"),
    (["--window", "100000000"], "window 100000000 is longer than the longest development unit"),
    (["--lr", "inf"], "--lr (learning rate)"),
    (["--alpha", "nan", "--conformal-units", "4"], "alpha"),
])
def test_train_refuses_values_before_training(runner, features_parquet, tmp_path, args,
                                              fragment):
    """Issue 31: values that used to fail after training (a traceback, the work lost) or
    allocate without bound are refused up front, with nothing written."""
    out = tmp_path / "m"
    r = run(runner, "train", features_parquet, "--model", "cnn", "--inputs", "data-driven",
            *FAST, *args, "--out", out)
    assert_user_error(r, fragment)
    assert not out.exists()


def test_train_names_bad_unit_lists_in_the_metadata(runner, tmp_path):
    import pyarrow.parquet as pq

    from tests.conftest import synthetic_features

    df, meta = synthetic_features()
    with pytest.raises(InputError, match="metadata dev_units must be a list of unit numbers"):
        write_parquet(df, tmp_path / "f.parquet", {**meta, "dev_units": "abc"})
    path = write_parquet(df, tmp_path / "f.parquet", meta)
    for part in path.rglob("*.parquet"):  # as another tool would have written it
        t = pq.read_table(part)
        t = t.replace_schema_metadata({b"hyprog": json.dumps({**meta, "dev_units": "abc"})})
        pq.write_table(t, part)
    r = run(runner, "train", path, "--model", "fnn", *FAST, "--out", tmp_path / "m")
    assert_user_error(r, "metadata dev_units must be a list of unit numbers")


def _edited(features_parquet, tmp_path, edit):
    df, meta = read_dataset(features_parquet)
    df = df.copy()
    edit(df)
    return write_parquet(df, tmp_path / "edited.parquet", meta)


def _set(column, value, unit=5, row=10):
    def edit(df):
        i = df.index[df.unit == unit][row]
        df[column] = df[column].astype(float)
        df.loc[i, column] = value
    return edit


@pytest.mark.parametrize("edit, fragments", [
    (_set("RUL", np.nan), ["unit 5", "column RUL", "NaN"]),
    (_set("RUL", -3.0), ["unit 5", "column RUL", "-3", "negative"]),
    (_set("T30", 1e300), ["unit 5", "column T30", "1e+300", "32-bit"]),
], ids=["nan-rul", "negative-rul", "huge-input"])
def test_evaluate_refuses_bad_values_in_a_test_unit(runner, model_dir, features_parquet,
                                                    tmp_path, edit, fragments):
    """Issue 31: these gave exit 0 with RMSE nan (JSON null), a raw numpy RuntimeWarning, or
    a negative truth accepted; now one error line naming the unit and column."""
    bad = _edited(features_parquet, tmp_path, edit)
    r = run(runner, "evaluate", model_dir, bad, "--json")
    assert_user_error(r, "edited.parquet", *fragments)
    assert "RuntimeWarning" not in r.stderr


def test_evaluate_refuses_duplicated_time_stamps(runner, model_dir, features_parquet,
                                                 tmp_path):
    df, meta = read_dataset(features_parquet)
    dup = pd.concat([df, df[df.unit == 6].iloc[[3]]], ignore_index=True)
    bad = write_parquet(dup, tmp_path / "dup.parquet", meta)
    assert_user_error(run(runner, "evaluate", model_dir, bad), "dup.parquet", "unit 6",
                      "duplicated")


def test_train_refuses_a_negative_rul(runner, features_parquet, tmp_path):
    bad = _edited(features_parquet, tmp_path, _set("RUL", -1.0, unit=1))
    out = tmp_path / "m"
    r = run(runner, "train", bad, "--model", "fnn", *FAST, "--out", out)
    assert_user_error(r, "unit 1", "negative")
    assert not out.exists()


def test_evaluate_reports_accuracy_over_life_and_error_by_rul(runner, model_dir,
                                                              features_parquet):
    m = json.loads(ok(run(runner, "evaluate", model_dir, features_parquet, "--json")).stdout)
    al = m["alpha_lambda"]
    assert al["alpha"] == 0.2 and al["lambdas"] == [0.25, 0.5, 0.75]
    assert set(al["units"]) == {"5", "6"}
    for lam in ("0.25", "0.5", "0.75"):
        e = al["units"]["5"][lam]
        assert e["within"] == (abs(e["RUL_pred"] - e["RUL"]) <= 0.2 * e["RUL"])
        assert e["relative_accuracy"] == pytest.approx(
            1 - abs(e["RUL"] - e["RUL_pred"]) / e["RUL"])
    bins = m["error_by_rul"]
    assert sum(b["n"] for b in bins) == m["samples"]["overall"]["n"]
    assert all(b["q05"] <= b["q25"] <= b["median"] <= b["q75"] <= b["q95"] for b in bins)
    table = ok(run(runner, "evaluate", model_dir, features_parquet)).stdout
    assert "relative accuracy" in table and "true RUL" in table
    # a pipe is not a terminal: the table is as wide as it needs, headers whole
    assert "last cycle" in table and "horizon" in table and "…" not in table


def test_an_edited_window_in_the_manifest_is_refused_before_allocating(runner, model_dir,
                                                                       features_parquet,
                                                                       tmp_path):
    """Issue 31: a model.json saying ``window: 1e9`` (hash recomputed) made evaluate allocate
    200 GB; the weights are now checked against a network built on the meta device."""
    d = tmp_path / "edited"
    shutil.copytree(model_dir, d)
    body = json.loads((d / "model.json").read_text())
    resign_manifest(d, config={**body["config"], "window": 1_000_000_000})
    r = run(runner, "evaluate", d, features_parquet)
    assert_user_error(r, "model.json", "window 1000000000", "do not fit")
    assert str(features_parquet) not in r.stderr  # a model error names the model


def test_windows_longer_than_memory_allows_are_refused():
    from prognostics.windows import make_windows

    x = np.zeros((10, 3), np.float32)
    with pytest.raises(InputError, match="far longer than the data"):
        make_windows(x, np.array([0]), np.array([10]), 10**12, pad_all=True)


def test_alpha_needs_conformal_units_and_validation_units_are_not_test_units(
        runner, features_parquet, tmp_path):
    out = tmp_path / "m"
    r = run(runner, "train", features_parquet, "--model", "fnn", *FAST, "--alpha", "0.2",
            "--out", out)
    assert_user_error(r, "--alpha 0.2", "--conformal-units")
    r = run(runner, "train", features_parquet, "--model", "fnn", *FAST, "--val-units", "5",
            "--out", out)
    assert_user_error(r, "validation unit(s) 5 are test units")
    assert not out.exists()


def test_json_reports_carry_their_warnings(runner, model_dir, features_parquet, tmp_path):
    """Issue 31: ``--json`` output has a ``warnings`` list (the README says so), empty when
    nothing was said; a unit shorter than the window is said, not silently scored."""
    m = json.loads(ok(run(runner, "evaluate", model_dir, features_parquet, "--json")).stdout)
    assert m["warnings"] == []
    df, meta = read_dataset(features_parquet)
    short = df[(df.unit == 6) & (df.cycle == 1)].head(5)
    data = write_parquet(pd.concat([df[df.unit == 5], short]), tmp_path / "short.parquet",
                         meta)
    r = ok(run(runner, "evaluate", model_dir, data, "--json"))
    said = json.loads(r.stdout)["warnings"]
    assert len(said) == 1 and "unit(s) 6 have fewer samples than the window (8)" in said[0]
    assert r.stderr == ""  # in --json mode the warning is in the report only
    r = ok(run(runner, "evaluate", model_dir, data))
    assert r.stderr.startswith("warning: ") and "unit(s) 6" in r.stderr


def test_experiment_refuses_a_seed_listed_twice(runner, features_parquet, tmp_path):
    r = run(runner, "experiment", "paper", "--data", features_parquet, "--out",
            tmp_path / "e", "--seeds", "1,1")
    assert_user_error(r, "--seeds 1,1: 1 listed twice")
    assert not (tmp_path / "e").exists()
    r = run(runner, "experiment", "paper", "--data", features_parquet, "--out",
            tmp_path / "e", "--seeds", ",")
    assert_user_error(r, "--seeds ','", "empty list")
    assert not (tmp_path / "e").exists()


@pytest.mark.parametrize("raised, named", [
    (OSError(28, "No space left on device"), "out.csv: No space left on device"),
    (OSError(28, "No space left on device", "/data/.out.csv.tmp-123"),
     "out.csv: No space left on device"),
    (FileNotFoundError(2, "No such file", "/data/in.parquet"), "/data/in.parquet: no such"),
])
def test_write_errors_name_the_output_not_a_temporary(raised, named, capsys):
    """Issue 31: a full disk said ``error: None: Error writing bytes`` or named the input;
    an ``--out`` error named the hidden temporary."""
    import typer

    from cli.common import user_errors

    with pytest.raises(typer.Exit), user_errors("in.parquet", output="out.csv"):
        raise raised
    err = capsys.readouterr().err
    assert err.startswith("error: ") and named in err and "None" not in err, err
    assert ".tmp-" not in err


def test_quiet_prints_nothing_but_the_result_files(runner, model_dir, features_parquet,
                                                  tmp_path):
    """Issue 31: ``predict --quiet`` still printed its "wrote ..." line; --quiet now prints
    nothing on a success (the result is in --out), while evaluate's table is its result."""
    out = tmp_path / "p.csv"
    r = ok(run(runner, "predict", model_dir, features_parquet, "--out", out, "--quiet"))
    assert r.stdout == "" and r.stderr == "" and out.is_file()
    m = tmp_path / "m"
    r = ok(run(runner, "train", features_parquet, "--model", "fnn", *FAST, "--out", m))
    assert r.stdout == "" and (m / "model.json").is_file()
    # warnings are still said (two epochs may end a training whose loss still falls)
    [line] = r.stderr.splitlines()
    assert line.startswith("warning: seed 0: training used all 2 epochs and the validation "
                           "loss was still improving (best epoch ")
    r = ok(run(runner, "evaluate", model_dir, features_parquet, "--quiet"))
    assert "RMSE" in r.stdout and r.stderr == ""


def test_a_full_disk_names_the_output(runner, model_dir, features_parquet, tmp_path,
                                      monkeypatch):
    """Issue 31, through the CLI: a failed write named a hidden temporary (``--out``), the
    input (predict, train) or ``None`` (import-cmapss: pyarrow's error has no file name)."""
    import engine_model.datasets as datasets_module
    import prognostics.outputs as outputs_module

    out = tmp_path / "p.csv"

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device", str(tmp_path / ".p.csv.tmp-host-1"))

    monkeypatch.setattr(outputs_module, "write_predictions", full)
    r = run(runner, "predict", model_dir, features_parquet, "--out", out)
    assert_user_error(r, f"{out}: No space left on device")
    assert ".tmp-" not in r.stderr and str(features_parquet) not in r.stderr

    train = tmp_path / "train_FD001.txt"
    train.write_text("".join(f"1 {c} 0.0 0.0 100.0 " + " ".join(["500.0"] * 21) + "  \n"
                             for c in range(1, 6)))

    def pyarrow_full(*args, **kwargs):
        raise OSError("Error writing bytes to file. Detail: [errno 28] No space left on "
                      "device")

    monkeypatch.setattr(datasets_module, "write_parquet", pyarrow_full)
    r = run(runner, "data", "import-cmapss", train, "--out", tmp_path / "fd001")
    assert_user_error(r, f"{tmp_path / 'fd001'}: Error writing bytes")
    assert "None" not in r.stderr

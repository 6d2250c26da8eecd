"""The one ownership rule of every writer (engine_model.runtime.ownership), through the CLI:
each case of issue 27's data-loss paragraph is a test that the user's file survives.

- ``predict --out`` never writes over what it reads (the model's ``model.json``, its input
  table), never replaces a file hyprog cannot recognise (an unrelated ``keep.csv``, a
  ``NAME.per_cycle.csv`` sidecar the user never named) without ``--overwrite``, never a FIFO or
  a device node (not even with it), and a predict that fails while moving its outputs in leaves
  the previous ones;
- ``data import-cmapss``, ``simulate``, ``train`` and ``discover`` do not delete a user's file
  (``analysis.txt``, ``NOTES.md``) inside an output folder hyprog wrote earlier, without
  ``--overwrite``.

Also here: the fingerprints' values, pinned (computed with the code before it moved into
engine_model.datasets.fingerprint; resumed results and caches are keyed on them), and the one
JSON converter. Special files are made in the test's own temporary folder, never a system
path.
"""

import json
import os
import stat

import numpy as np
import pandas as pd
import pytest

from engine_model.datasets import SOURCE_ROW, read_dataset, write_parquet
from engine_model.datasets.fingerprint import (
    files_fingerprint,
    rows_fingerprint,
    table_fingerprint,
)
from engine_model.datasets.jsonable import jsonable
from tests.cli_checks import assert_user_error, cli_runner
from tests.test_prognostics_cli import ok, run

pytestmark = pytest.mark.usefixtures("torch_one_thread")

FAST = ["--epochs", "1", "--device", "cpu", "--quiet"]  # one epoch: only the files matter


@pytest.fixture(scope="module")
def runner():
    return cli_runner()


def snapshot(root):
    """Every entry under ``root``: relative path -> bytes of a file, or its kind."""
    out = {}
    for p in sorted(root.rglob("*")):
        mode = os.lstat(p).st_mode
        rel = str(p.relative_to(root))
        out[rel] = p.read_bytes() if stat.S_ISREG(mode) else stat.S_IFMT(mode)
    return out


@pytest.fixture(scope="module")
def model(runner, features_parquet, tmp_path_factory):
    """A small FNN (one epoch) trained through the CLI."""
    out = tmp_path_factory.mktemp("own") / "fnn"
    ok(run(runner, "train", features_parquet, "--model", "fnn", "--inputs", "data-driven",
           *FAST, "--out", out))
    return out


@pytest.fixture(scope="module")
def table_file(features_parquet, tmp_path_factory):
    """Units 5 and 6 of the feature table as one parquet file (a predict input)."""
    df, _ = read_dataset(features_parquet, units=[5, 6])
    path = tmp_path_factory.mktemp("own") / "units.parquet"
    df.to_parquet(path, index=False)
    return path


# ------------------------------------------------------------------------------------------
# predict --out
# ------------------------------------------------------------------------------------------
def test_predict_refuses_a_suffix_of_another_format(runner, model, table_file, tmp_path):
    for name in ("rul.h5", "rul.txt"):
        assert_user_error(run(runner, "predict", model, table_file, "--out", tmp_path / name),
                          "is written as CSV (.csv) or parquet")
    assert list(tmp_path.iterdir()) == []


def test_predict_never_writes_over_the_model_it_reads(runner, model, table_file):
    before = snapshot(model)
    assert_user_error(run(runner, "predict", model, table_file, "--out",
                          model / "model.json"), "is inside the input", "model.json")
    assert_user_error(run(runner, "predict", model, table_file, "--out",
                          model / "model.json", "--overwrite"), "is inside the input")
    assert snapshot(model) == before


def test_predict_never_writes_over_its_input_table(runner, model, table_file,
                                                   features_parquet):
    data = table_file.read_bytes()
    assert_user_error(run(runner, "predict", model, table_file, "--out", table_file,
                          "--overwrite"), str(table_file), "is the input")
    assert table_file.read_bytes() == data
    # the input under another name (a hard link) and a folder around it are the same input
    link = table_file.parent / "linked.parquet"
    os.link(table_file, link)
    assert_user_error(run(runner, "predict", model, table_file, "--out", link),
                      "is the input")
    before = snapshot(features_parquet)
    assert_user_error(run(runner, "predict", model, features_parquet, "--out",
                          features_parquet / "p.csv"), "is inside the input")
    assert snapshot(features_parquet) == before
    assert table_file.read_bytes() == data


def test_predict_replaces_an_unrelated_file_only_with_overwrite(runner, model, table_file,
                                                                tmp_path):
    keep = tmp_path / "keep.csv"
    keep.write_text("name,value\nalice,1\n")
    assert_user_error(run(runner, "predict", model, table_file, "--out", keep),
                      str(keep), "hyprog did not write", "--overwrite")
    assert keep.read_text() == "name,value\nalice,1\n"
    assert not (tmp_path / "keep.per_cycle.csv").exists()
    ok(run(runner, "predict", model, table_file, "--out", keep, "--overwrite"))
    assert "RUL_pred" in pd.read_csv(keep).columns
    # its own earlier output is replaced without --overwrite (a rerun)
    ok(run(runner, "predict", model, table_file, "--out", keep, "--units", "5"))
    assert set(pd.read_csv(keep)["unit"]) == {5}


def test_predict_never_replaces_a_sidecar_the_user_never_named(runner, model, table_file,
                                                               tmp_path):
    mine = tmp_path / "preds.per_cycle.csv"
    mine.write_text("my own per-cycle notes\n")
    assert_user_error(run(runner, "predict", model, table_file, "--out",
                          tmp_path / "preds.csv"), str(mine), "hyprog did not write")
    assert mine.read_text() == "my own per-cycle notes\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["preds.per_cycle.csv"]


def test_predict_never_writes_over_a_fifo(runner, model, table_file, tmp_path):
    pipe = tmp_path / "pipe.csv"
    os.mkfifo(pipe)
    link = tmp_path / "link.csv"
    link.symlink_to(pipe)
    for out in (pipe, link):
        assert_user_error(run(runner, "predict", model, table_file, "--out", out,
                              "--overwrite"), str(out), "named pipe", "not even with")
    assert stat.S_ISFIFO(os.lstat(pipe).st_mode) and link.is_symlink()
    sidecar = tmp_path / "p.per_cycle.csv"
    os.mkfifo(sidecar)
    assert_user_error(run(runner, "predict", model, table_file, "--out", tmp_path / "p.csv",
                          "--overwrite"), str(sidecar), "named pipe")
    assert stat.S_ISFIFO(os.lstat(sidecar).st_mode)
    assert not (tmp_path / "p.csv").exists()


def test_predict_never_writes_over_a_device_node(runner, model, table_file, tmp_path):
    node = tmp_path / "null"
    try:
        os.mknod(node, stat.S_IFCHR | 0o666, os.makedev(1, 3))  # like /dev/null, made here
    except (PermissionError, OSError) as e:
        pytest.skip(f"cannot make a device node here ({e.strerror}): needs root")
    assert_user_error(run(runner, "predict", model, table_file, "--out", node,
                          "--overwrite"), str(node), "character device")
    assert stat.S_ISCHR(os.lstat(node).st_mode)


def test_a_predict_that_fails_while_moving_its_outputs_in_leaves_the_old_ones(
        runner, model, table_file, tmp_path, monkeypatch):
    out, pc = tmp_path / "preds.csv", tmp_path / "preds.per_cycle.csv"
    ok(run(runner, "predict", model, table_file, "--out", out, "--units", "5"))
    before = snapshot(tmp_path)
    real = os.replace

    def replace(src, dst):  # the sidecar's rename fails, after the main table's
        if os.fspath(dst) == os.fspath(pc) and ".tmp-" in os.fspath(src):
            raise OSError(28, "No space left on device", os.fspath(dst))
        return real(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    assert_user_error(run(runner, "predict", model, table_file, "--out", out), "space")
    monkeypatch.setattr(os, "replace", real)
    assert snapshot(tmp_path) == before  # both old files, nothing half-done, no temporary
    assert set(pd.read_csv(out)["unit"]) == {5}


# ------------------------------------------------------------------------------------------
# a user's file inside an output folder hyprog wrote earlier
# ------------------------------------------------------------------------------------------
def cmapss_files(folder):
    """A tiny C-MAPSS training file: two units, one line per cycle."""
    rng = np.random.default_rng(0)
    lines = []
    for u, life in ((1, 12), (2, 10)):
        for c in range(1, life + 1):
            values = [0.0, 0.6, 100.0] + [500.0 + c + rng.normal(0, 0.5) for _ in range(21)]
            lines.append(f"{u} {c} " + " ".join(f"{v:.4f}" for v in values))
    path = folder / "train_FD001.txt"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_import_cmapss_keeps_a_users_file_in_its_earlier_output(runner, tmp_path):
    train = cmapss_files(tmp_path)
    out = tmp_path / "fd001"
    ok(run(runner, "data", "import-cmapss", train, "--out", out))
    ok(run(runner, "data", "import-cmapss", train, "--out", out))  # its own: replaced
    (out / "analysis.txt").write_text("three weeks of work")
    before = snapshot(tmp_path)
    assert_user_error(run(runner, "data", "import-cmapss", train, "--out", out), str(out),
                      "analysis.txt", "hyprog did not write", "--overwrite")
    assert snapshot(tmp_path) == before
    assert_user_error(run(runner, "data", "import-cmapss", train, "--out", train,
                          "--overwrite"), "is the input")
    assert snapshot(tmp_path) == before
    ok(run(runner, "data", "import-cmapss", train, "--out", out, "--overwrite"))
    assert not (out / "analysis.txt").exists()  # what --overwrite says it does


def test_simulate_keeps_a_users_file_in_its_earlier_output(runner, tmp_path):
    out = tmp_path / "fleet"
    ok(run(runner, "simulate", "--units", "1", "--out", out, "--quiet"))
    (out / "NOTES.md").write_text("unit 1 looks odd")
    (out / "unit=1" / "plot.png").write_bytes(b"\x89PNG mine")
    before = snapshot(tmp_path)
    r = run(runner, "simulate", "--units", "1", "--seed", "1", "--out", out, "--quiet")
    assert_user_error(r, "NOTES.md", "unit=1/plot.png", "2 entries")
    assert snapshot(tmp_path) == before


def test_train_keeps_a_users_file_in_its_earlier_model(runner, model, features_parquet,
                                                       tmp_path):
    import shutil

    out = tmp_path / "fnn"
    shutil.copytree(model, out)
    ok(run(runner, "train", features_parquet, "--model", "fnn", "--inputs", "data-driven",
           *FAST, "--seed", "1", "--out", out))  # its own model: replaced
    assert json.loads((out / "model.json").read_text())["members"][0]["seed"] == 1
    (out / "NOTES.md").write_text("seed 1 is the good one")
    before = snapshot(tmp_path)
    assert_user_error(run(runner, "train", features_parquet, "--model", "fnn", *FAST,
                          "--out", out), "NOTES.md", "--overwrite")
    assert snapshot(tmp_path) == before
    assert_user_error(run(runner, "train", features_parquet, *FAST, "--overwrite",
                          "--out", features_parquet), "is the input")
    assert snapshot(tmp_path) == before


def test_discover_keeps_a_users_file_in_its_earlier_report(runner, tmp_path):
    """The earlier report is recognised by its ``discover.json`` (written here as discover
    writes it); the refusal comes before the discovery run."""
    from data_samples import TINY_FLEET, sample_path

    out = tmp_path / "report"
    out.mkdir()
    for name in ("discover.json", "discover.md", "residuals.png"):
        (out / name).write_text("{}" if name.endswith(".json") else "earlier")
    (out / "NOTES.md").write_text("the bleed effect is real")
    before = snapshot(tmp_path)
    assert_user_error(run(runner, "discover", sample_path(TINY_FLEET), "--units", "1",
                          "--out", out, "--quiet"), "NOTES.md", "--overwrite")
    assert snapshot(tmp_path) == before
    data = tmp_path / "fleet"
    write_parquet(read_dataset(sample_path(TINY_FLEET), units=[1])[0], data)
    assert_user_error(run(runner, "discover", data, "--overwrite", "--out", data / "r"),
                      "is inside the input")
    assert not (data / "r").exists()


def test_paper_report_without_figures_removes_only_its_own(tmp_path):
    """``experiment paper --no-figures`` removes an earlier run's figures (they may not match
    the new tables) but keeps a user's file beside them, and never deletes through a
    ``figures`` that is a symbolic link to somewhere else."""
    from workflows.paper.paper_report import _remove_own_figures

    figures = tmp_path / "out" / "figures"
    figures.mkdir(parents=True)
    own = ("rul_main_cnn_hybrid.png", "rul_conformal_hybrid.png", "theta_hat.png",
           "rul_baseline.png", "training_curves.png")
    for name in (*own, "my_sketch.png"):
        (figures / name).write_bytes(b"png")
    _remove_own_figures(figures)
    assert sorted(p.name for p in figures.iterdir()) == ["my_sketch.png"]
    (figures / "my_sketch.png").unlink()
    (figures / "theta_hat.png").write_bytes(b"png")
    _remove_own_figures(figures)
    assert not figures.exists()  # empty once the report's figures are gone: removed

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "theta_hat.png").write_bytes(b"someone else's")
    figures.symlink_to(elsewhere, target_is_directory=True)
    _remove_own_figures(figures)
    assert figures.is_symlink() and (elsewhere / "theta_hat.png").read_bytes() == \
        b"someone else's"


# ------------------------------------------------------------------------------------------
# fingerprints (pinned) and the JSON converter
# ------------------------------------------------------------------------------------------
def small_table():
    return pd.DataFrame({"unit": np.array([1, 1, 2], np.int64),
                         "cycle": np.array([1, 2, 1], np.int64),
                         "t": np.array([0.0, 10.0, 0.5]),
                         "T24": np.array([641.5, 642.25, -1.0], np.float32)})


def test_fingerprints_keep_their_values():
    """Values computed with the code before it moved (calibration.fingerprint,
    workflows.pipeline.state.data_fingerprint, workflows.paper.experiment.data_fingerprint);
    stored feature tables, pipeline stage folders and the experiment's runs are keyed on
    them."""
    df = small_table()
    rows = "97f3212372e38a833e7c572d4c6b8652decd8149f4fa495b4a2cd4fe4b2c3468"
    assert rows_fingerprint(df) == rows
    assert rows_fingerprint(df.assign(**{SOURCE_ROW: np.arange(1, 4)})) == rows
    meta = {"dev_units": [1], "test_units": [2], "preset": "tiny"}
    assert table_fingerprint(df, meta) == \
        "767d787d890ba1ce96e9364b787d276ee81d454c3c69aef61a1fd0c1cf922b8e"
    assert table_fingerprint(df, None) == \
        "b751af13d53ffe17a63f74f993ce1f5e0b0469c7e8ef34585b528793a4220d39"


def test_files_fingerprint_keeps_its_value(tmp_path):
    d = tmp_path / "data"
    (d / "unit=1").mkdir(parents=True)
    (d / "unit=1" / "part-0.parquet").write_bytes(b"PAR1 one")
    (d / "unit=2").mkdir()
    (d / "unit=2" / "part-0.parquet").write_bytes(b"PAR1 two" * 1000)
    (d / ".hidden").write_bytes(b"ignored")
    (d / "unit=1" / ".x.tmp-h-1-a").write_bytes(b"ignored")
    assert files_fingerprint(d) == \
        "012c8b3c464388df3dcd8eb02fd4df9dcd571ea1949afa03e6ea6cd51aeb9fc0"
    assert files_fingerprint(d / "unit=2" / "part-0.parquet") == \
        "b1969674afb6270c35ae584cf3385f142dfcfad728a5d040e86d0771e43d6cf7"


def test_the_stage_fingerprint_keeps_its_value(monkeypatch):
    from workflows.pipeline import state

    monkeypatch.setattr(state, "hyprog_version", lambda: "1.2.3")
    fp = state.stage_fingerprint("train", {"train": {"epochs": 2, "inputs": ["hybrid"]},
                                           "x": None}, {"features": "abc"})
    assert fp == "66388b0640742db625be0f3fd345065162c14a339730e7c6bf6e272de13efcd3"


def test_one_json_converter():
    from pathlib import Path

    got = jsonable({1: (np.float32(0.5), np.int64(3)), "a": np.array([1.0, np.nan]),
                    "s": {3, 1}, "p": Path("x/y"), "inf": float("inf"), "ok": np.bool_(True)})
    assert got == {"1": [0.5, 3], "a": [1.0, None], "s": [1, 3], "p": "x/y", "inf": None,
                   "ok": True}
    assert json.loads(json.dumps(got)) == got

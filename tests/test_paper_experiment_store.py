"""benchmarks/paper_experiment.py keeps finished runs across machines: ``copy_runs`` copies a
run's record and predictions (not its weights) only when the run finished, ``result.json``
last, and never twice."""

import importlib.util
import json

from .conftest import REPO


def _script():
    spec = importlib.util.spec_from_file_location(
        "paper_experiment", REPO / "benchmarks" / "paper_experiment.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _run(root, key, finished=True):
    d = root / key
    (d / "model").mkdir(parents=True)
    (d / "model" / "weights.safetensors").write_bytes(b"w")
    (d / "predictions.parquet").write_bytes(b"p" + key.encode())
    if finished:
        (d / "result.json").write_text(json.dumps({"key": key}))


def test_copy_runs_keeps_finished_runs_without_weights(tmp_path):
    pe = _script()
    src, dest = tmp_path / "out" / "runs", tmp_path / "store"
    _run(src, "aaa")
    _run(src, "bbb", finished=False)  # interrupted: no result.json
    _run(src, "baseline-ccc")
    (src / "baseline-ccc" / "per_cycle.parquet").write_bytes(b"c")
    assert pe.copy_runs(src, dest) == 2
    assert sorted(p.name for p in dest.iterdir()) == ["aaa", "baseline-ccc"]
    assert json.loads((dest / "aaa" / "result.json").read_text()) == {"key": "aaa"}
    assert (dest / "aaa" / "predictions.parquet").read_bytes() == b"paaa"
    assert (dest / "baseline-ccc" / "per_cycle.parquet").read_bytes() == b"c"
    assert not (dest / "aaa" / "model").exists()
    assert not list(dest.rglob(".*"))  # no temporary left
    assert pe.copy_runs(src, dest) == 0  # nothing twice


def test_copy_runs_completes_a_copy_cut_short(tmp_path):
    pe = _script()
    src, dest = tmp_path / "src", tmp_path / "dest"
    _run(src, "aaa")
    (dest / "aaa").mkdir(parents=True)
    (dest / "aaa" / "predictions.parquet").write_bytes(b"partial")  # no result.json
    assert pe.copy_runs(src, dest) == 1
    assert (dest / "aaa" / "predictions.parquet").read_bytes() == b"paaa"
    assert (dest / "aaa" / "result.json").is_file()

"""benchmarks/paper_experiment.py stores finished runs as small files: ``copy_runs`` writes a
run's record and its per-cycle predictions (never the per-sample predictions or the weights)
only when the run finished, ``result.json`` last, and never twice."""

import json

import pandas as pd
import pytest

from .conftest import REPO, load_script


def _script():
    return load_script(REPO / "benchmarks" / "paper_experiment.py", "paper_experiment")


def _predictions(offset: float) -> pd.DataFrame:
    """Two units, two cycles each, three samples per cycle."""
    rows = [(u, c, 10.0 - c, 10.0 - c + offset + 0.5 * k)
            for u in (11, 14) for c in (1, 2) for k in range(3)]
    return pd.DataFrame(rows, columns=["unit", "cycle", "RUL", "RUL_pred"])


def _run(root, key, finished=True, offset=0.0):
    d = root / key
    (d / "model").mkdir(parents=True)
    (d / "model" / "weights.safetensors").write_bytes(b"w")
    _predictions(offset).to_parquet(d / "predictions.parquet")
    if finished:
        (d / "result.json").write_text(json.dumps({"key": key}))


def test_copy_runs_keeps_records_and_per_cycle_predictions_only(tmp_path):
    pe = _script()
    src, dest = tmp_path / "out" / "runs", tmp_path / "store"
    _run(src, "aaa", offset=1.0)
    _run(src, "bbb", finished=False)  # interrupted: no result.json
    _run(src, "baseline-ccc")
    assert pe.copy_runs(src, dest) == 2
    assert sorted(p.name for p in dest.iterdir()) == ["aaa", "baseline-ccc"]
    assert sorted(p.name for p in (dest / "aaa").iterdir()) == ["per_cycle.csv", "result.json"]
    assert json.loads((dest / "aaa" / "result.json").read_text()) == {"key": "aaa"}
    pc = pd.read_csv(dest / "aaa" / "per_cycle.csv")
    assert list(pc[["unit", "cycle"]].itertuples(index=False, name=None)) == [
        (11, 1), (11, 2), (14, 1), (14, 2)]
    # mean of 10 - c + 1 + {0, 0.5, 1} = 10 - c + 1.5; three samples per cycle
    assert pc["mean"].to_numpy() == pytest.approx([10.5, 9.5, 10.5, 9.5])
    assert pc["RUL"].tolist() == [9, 8, 9, 8] and pc["n"].tolist() == [3, 3, 3, 3]
    assert not list(dest.rglob("*.parquet")) and not (dest / "aaa" / "model").exists()
    assert not list(dest.rglob(".*"))  # no temporary left
    assert pe.copy_runs(src, dest) == 0  # nothing twice


def test_copy_runs_completes_a_copy_cut_short(tmp_path):
    pe = _script()
    src, dest = tmp_path / "src", tmp_path / "dest"
    _run(src, "aaa")
    (dest / "aaa").mkdir(parents=True)
    (dest / "aaa" / "per_cycle.csv").write_text("partial")  # no result.json: not stored
    assert pe.copy_runs(src, dest) == 1
    assert pd.read_csv(dest / "aaa" / "per_cycle.csv")["n"].sum() == 12
    assert (dest / "aaa" / "result.json").is_file()

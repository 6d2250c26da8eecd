"""Same seed, same numbers, however the work is spread (issue 15): ``hyprog pipeline`` with
``[run] jobs = 2`` (worker processes) and on a Dask cluster of two workers (reached by its
address, as a real cluster is) writes the serial run's ``metrics.json`` and feature table byte
for byte; ``hyprog simulate --scheduler ADDRESS`` writes the local simulation's files.

Kept small: the pipeline runs on a cut of the committed tiny fleet (units 3 and 4, first four
cycles each) with the discrepancy loop off and one epoch of one FNN (``hybrid``): what the
workers change is simulate, calibrate and features, and those are compared in full (the fleet,
the feature table's files); that training gives the same network from the same table and seed
is tested in tests/test_prognostics*.py, so one short training suffices here. The serial run
is in this process with the shared compiled model; the Dask cluster is started once for the
module.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from engine_model import datasets
from tests.conftest import REPO

pytest.importorskip("distributed")

TINY = REPO / "data_samples" / "tiny"
CONFIG = {"data": {"units": [3, 4]}, "discover": {"enabled": False},
          "train": {"model": "fnn", "epochs": 1, "inputs": ["hybrid"]}}


def files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and not any(s.startswith(".") for s in p.relative_to(root).parts)}


@pytest.fixture(scope="module")
def cluster():
    """A local Dask cluster of two single-threaded worker processes, used by address."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as c:
        yield c.scheduler_address


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    df, meta = datasets.read_dataset(TINY, units=[3, 4])
    path = tmp_path_factory.mktemp("fleet") / "fleet"
    datasets.write_parquet(df[df["cycle"] <= 4].reset_index(drop=True), path, meta)
    return path


def run(out: Path, data: Path, **run_table) -> dict:
    from workflows.pipeline import run_pipeline
    from workflows.pipeline.config import defaults, merge

    cfg = merge(defaults(), {**CONFIG, "run": run_table})
    return run_pipeline(out, cfg, data)


def features_table(out: Path) -> Path:
    (table,) = out.glob("stages/calibrate-*/features")
    return table


@pytest.fixture(scope="module")
def serial(tmp_path_factory, data):
    out = tmp_path_factory.mktemp("serial") / "out"
    run(out, data)
    return out


def assert_same_results(out: Path, serial: Path) -> None:
    assert (out / "metrics.json").read_bytes() == (serial / "metrics.json").read_bytes()
    a, b = features_table(out), features_table(serial)
    assert a.relative_to(out) == b.relative_to(serial)  # the same fingerprint
    assert files(a) == files(b) and datasets.written_units(a) == [3, 4]


def test_two_worker_processes_give_the_serial_files(tmp_path, data, serial):
    out = tmp_path / "out"
    res = run(out, data, jobs=2)
    assert res["stages"]["calibrate"]["status"] == "done"
    assert_same_results(out, serial)


def test_a_dask_cluster_gives_the_serial_files(tmp_path, data, serial, cluster):
    out = tmp_path / "out"
    res = run(out, data, scheduler=cluster)
    assert res["stages"]["calibrate"]["status"] == "done"
    assert_same_results(out, serial)
    # the [run] table is in no fingerprint: the serial run's folder resumes on the cluster
    again = run(serial, data, scheduler=cluster, jobs=2)
    assert {k: v["status"] for k, v in again["stages"].items() if k != "data"} == {
        k: "skipped" for k in ("calibrate", "features", "train", "evaluate", "report")}


def test_simulate_on_a_dask_cluster_gives_the_local_fleet(tmp_path, cluster):
    from engine_model.simulator.fleet import simulate

    local = tmp_path / "local"
    simulate("tiny", out=local, units=[4], seed=3)
    out = tmp_path / "dask"
    r = subprocess.run([sys.executable, "-m", "cli.main", "simulate", "--preset", "tiny",
                        "--units", "4", "--seed", "3", "--scheduler", cluster, "--out",
                        str(out), "--json"], cwd=REPO, capture_output=True, text=True,
                       env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["units"]["4"]["rows"] > 0
    assert files(out) == files(local)


def test_run_options_on_the_command_line_are_checked(tmp_path, data):
    """--jobs 0 and a scheduler that refuses the connection: one line, exit 2, nothing left
    (the cluster is reached when the first stage that uses it starts)."""
    from cli.main import app
    from tests.cli_checks import assert_user_error, cli_runner

    out = tmp_path / "out"
    runner = cli_runner()
    assert_user_error(runner.invoke(app, ["pipeline", str(data), "--jobs", "0", "--out",
                                          str(out)]), "[run] jobs", ">= 1")
    assert_user_error(runner.invoke(app, ["pipeline", str(data), "--scheduler",
                                          "tcp://127.0.0.1:9", "--out", str(out)]),
                      "tcp://127.0.0.1:9", "cannot connect")
    assert not out.exists()

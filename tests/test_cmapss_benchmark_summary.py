"""The C-MAPSS benchmarks' tables: partitions of the folds read back from the labels,
predictors paired run by run and ensemble by ensemble on the same units, the rows over every
partition (``benchmarks/cmapss.py``), and the units split by fault mode
(``benchmarks/cmapss_modes.py``)."""

import numpy as np
import pandas as pd
import pytest

from .conftest import REPO, load_script

SCRIPT = REPO / "benchmarks" / "cmapss.py"


@pytest.fixture(scope="module")
def bench():
    return load_script(SCRIPT, "cmapss_benchmark")


def runs_table(scale: float) -> pd.DataFrame:
    """Two partitions x two folds x two seeds; the hybrid's errors on every held-out unit are
    the data-driven network's times ``scale``."""
    rows = []
    rng = np.random.default_rng(0)
    for part in (0, 1):
        tag = f", fold seed {part}" if part else ""
        for fold in (0, 1):
            for seed in (0, 1):
                deltas = {str(u): float(d) for u, d in enumerate(rng.normal(0, 10, 4))}
                for name, k in (("data-driven", 1.0), ("hybrid-theta --params all", scale)):
                    d = {u: k * v for u, v in deltas.items()}
                    rows.append({"key": f"{part}{fold}{seed}{name}", "kind": "run",
                                 "subset": "FD001", "fold": fold, "model": "dcnn",
                                 "inputs": name + tag, "seed": seed, "seconds": 1.0,
                                 "rmse": float(np.sqrt(np.mean(np.square(list(d.values()))))),
                                 "deltas": d})
    return pd.DataFrame(rows)


def test_partition_read_back_from_the_label(bench):
    label = "hybrid-theta --params all, adapted ccd7e93d --noise data"
    assert bench.split_partition(label) == (label, 0)
    tagged = f"{label}, {bench.PARTITION.format(12)}"
    assert bench.split_partition(tagged) == (label, 12)
    pooled = f"data-driven + FD001 units, {bench.PARTITION.format(1)}"
    assert bench.split_partition(pooled) == ("data-driven + FD001 units", 1)


def test_paired_runs_and_ensembles_on_the_same_units(bench):
    runs = runs_table(0.8)
    split = runs["inputs"].map(bench.split_partition)
    runs = runs.assign(base=split.str[0], partition=split.str[1])
    rel, rel_ens = bench.paired(runs[runs["base"] != "data-driven"],
                                runs[runs["base"] == "data-driven"])
    assert len(rel) == 8 and len(rel_ens) == 4  # 2 partitions x 2 folds (x 2 seeds)
    np.testing.assert_allclose(rel, -20.0)
    np.testing.assert_allclose(rel_ens, -20.0)


def test_summary_pairs_each_partition_and_pools_them(bench):
    table = bench.summarise(runs_table(1.1))
    rows = {line.split(" | ")[1]: line for line in table.splitlines()[2:]}
    one = ("dcnn: hybrid-theta --params all, fold seed 1 vs data-driven, fold seed 1, "
           "ensembles paired")
    assert "+10.0 % ± 0.0 % (better in 0 of 2)" in rows[one]
    pooled = "dcnn hybrid-theta --params all, fold seeds 0, 1 vs data-driven, paired"
    assert "+10.0 % ± 0.0 % (better in 0 of 8)" in rows[pooled]
    assert "| 8 pairs |" in rows[pooled]
    assert "dcnn data-driven, fold seeds 0, 1, ensemble of the seeds" in rows


def test_runs_under_other_settings_and_floors_of_other_cuts_are_summarised_apart(bench):
    """A ``--set`` study's runs carry their settings in the label (before the partition), so
    they are neither pooled with nor paired against the same input set's default runs; the
    floors of held-out units cut from another cycle are their own rows."""
    runs = runs_table(1.1)
    study = runs[runs["inputs"].str.startswith("data-driven")].copy()
    label = "data-driven" + bench.settings_label({"window": 20, "lr": 0.01})
    assert label == "data-driven [lr=0.01, window=20]"
    study["inputs"] = study["inputs"].str.replace("data-driven", label, regex=False)
    study["key"] = study["key"] + "w"
    assert bench.split_partition(f"{label}, {bench.PARTITION.format(1)}") == (label, 1)
    floors = pd.DataFrame([{"key": f"f{c}{k}", "kind": "floors", "subset": "FD001", "fold": k,
                            "variant": c, "constant": 40.0 + k, "life": 30.0}
                           for c in ("", bench.CUT_FROM.format(20)) for k in (0, 1)])
    table = bench.summarise(pd.concat([runs, study, floors], ignore_index=True))
    rows = {line.split(" | ")[1]: line for line in table.splitlines()[2:]}
    assert "dcnn data-driven [lr=0.01, window=20]" in rows and "dcnn data-driven" in rows
    assert "| 4 pairs |" in rows["dcnn: hybrid-theta --params all vs data-driven, paired"]
    assert "constant floor" in rows and "constant floor, cut from cycle 20" in rows


def test_a_hybrid_is_paired_only_with_data_driven_of_the_same_units_and_partition(bench):
    """A pooled hybrid has no reference but the pooled data-driven network (the unpooled
    one would mix the pooling into the inputs' effect), and a partition pairs with its own."""
    labels = ["data-driven", "data-driven, fold seed 1", "data-driven + FD001 units"]
    assert bench.reference("hybrid-theta --params all", labels) == "data-driven"
    assert bench.reference("hybrid-theta, fold seed 1", labels) == "data-driven, fold seed 1"
    assert (bench.reference("hybrid-theta --params all, adapted ab12cd34 + FD001 units", labels)
            == "data-driven + FD001 units")
    assert bench.reference("hybrid-theta --params all + FD003 units", labels) is None
    assert bench.reference("hybrid-theta + FD001 units, fold seed 1", labels) is None
    assert bench.reference("data-driven + FD001 units", labels) is None


def test_the_test_files_are_calibrated_as_the_cross_validated_variant(bench, tmp_path,
                                                                     monkeypatch):
    calls = []
    monkeypatch.setattr(bench, "hyprog", lambda *a: calls.append(a))
    effects = tmp_path / "adapted.json"
    effects.write_text("{}")
    feat = bench.calibrated(tmp_path / "fd002-test", "all", effects, "data", 0.003)
    sha = bench.file_sha(effects)[:8]
    assert feat.name == f"fd002-test-features-all-adapted-{sha}-noise-data-model-error-0.003"
    assert calls == [("calibrate", str(tmp_path / "fd002-test"), "--out", str(feat),
                      "--params", "all", "--model-effects", str(effects), "--noise", "data",
                      "--model-error", "0.003")]


def test_the_test_files_are_touched_once(bench, tmp_path, monkeypatch):
    """``--test`` evaluates the chosen configuration once: asked again it reports the record
    and trains nothing; ``--report`` reports only records; two configurations at once are
    refused (the test files would choose between them)."""
    from types import SimpleNamespace

    calls = []

    def evaluate(args, subset, model, overrides):
        calls.append(subset)
        return [{"subset": subset, "model": model, "inputs": n, "units": 100,
                 "rmse_per_seed": [13.0, 14.0], "rmse_ensemble": 12.5}
                for n in args.inputs.split(",")]

    monkeypatch.setattr(bench, "evaluate_on_test_files", evaluate)
    monkeypatch.setattr(bench, "test_files", lambda d, s: ("t", "r"))
    args = SimpleNamespace(inputs="data-driven,hybrid-theta", models="dcnn", params="all",
                           noise="model", model_error=0.0, model_effects=None, pool="",
                           seeds="0,1", work=tmp_path, data_dir=tmp_path, report=False)
    first = bench.test_section(args, ["FD001"], {})
    again = bench.test_section(args, ["FD001"], {})
    assert calls == ["FD001"] and first == again
    assert "| FD001 | dcnn hybrid-theta | 100 | 13.00, 14.00 | 12.50 |" in first
    args.params, args.report = "default", True  # another configuration, report only
    assert "not evaluated" in bench.test_section(args, ["FD001"], {}) and calls == ["FD001"]
    args.inputs = "hybrid,hybrid-theta"
    with pytest.raises(SystemExit, match="one --inputs"):
        bench.test_section(args, ["FD001"], {})


@pytest.fixture(scope="module")
def modes():
    return load_script(SCRIPT.with_name("cmapss_modes.py"), "cmapss_modes")


def test_fault_groups_split_two_modes_of_change(modes):
    """Units whose θ̂ moves in one of two directions over life are split by direction, the
    same way every time, whatever their order."""
    rng = np.random.default_rng(1)
    rows = []
    for unit in range(1, 21):
        hpc = unit % 2 == 0
        life = 150 + 10 * unit
        drift = np.array([-1.0, 0.1]) if hpc else np.array([0.1, -1.0])  # HPC_eff, LPT_eff
        for cycle in range(1, life + 1):
            theta = drift * 0.01 * cycle / life + rng.normal(0, 1e-4, 2)
            rows.append({"unit": unit, "cycle": cycle, "HPC_eff_mod_hat": theta[0],
                         "LPT_eff_mod_hat": theta[1], "fan_eff_mod_hat": np.nan})
    features = pd.DataFrame(rows)
    change = modes.life_change(features)
    assert list(change.columns) == ["HPC_eff", "LPT_eff", "life"]  # fan_eff: not estimated
    assert change.loc[2, "life"] == 170
    # medians of the last and first 20 cycles of 170: cycles 160.5 and 10.5, in %
    np.testing.assert_allclose(change.loc[2, "HPC_eff"], -(160.5 - 10.5) / 170, atol=0.02)
    group = modes.fault_groups(change)
    even = group[change.index % 2 == 0]
    assert even.nunique() == 1 and group[change.index % 2 == 1].nunique() == 1
    assert group.nunique() == 2
    shuffled = change.sample(frac=1.0, random_state=0)
    np.testing.assert_array_equal(modes.fault_groups(shuffled).sort_index(), group)


def test_fault_mode_errors_average_one_models_seeds(modes):
    """The cache holds other models' runs under the same input labels (the TCN's beside the
    DCNN's on FD003): each ensemble averages the seeds of one model only."""
    def run(model, seed, delta):
        return {"key": f"{model}{seed}", "kind": "run", "subset": "FD003", "fold": 0,
                "model": model, "inputs": "data-driven", "seed": seed,
                "deltas": {"7": delta, "9": -delta}}

    runs = [run("dcnn", 0, 2.0), run("dcnn", 1, 4.0), run("tcn", 0, 30.0), run("tcn", 1, 50.0)]
    dcnn = modes.ensemble_errors(runs, "FD003", ["data-driven"])
    assert sorted(dcnn["error"]) == [-3.0, 3.0]
    tcn = modes.ensemble_errors(runs, "FD003", ["data-driven"], model="tcn")
    assert sorted(tcn["error"]) == [-40.0, 40.0]

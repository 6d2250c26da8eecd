"""Issue 30: the similarity predictor on the health index (prognostics.similarity)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pandas as pd
import pytest

from engine_model.validation import InputError
from prognostics.similarity import SimilarityRul


def trajectory(unit: int, life: int, rate: float, noise: float, rng) -> pd.DataFrame:
    """A unit's flights: a health index falling from 1 to 0 over ``life`` flights as
    ``1 - (c / life) ** rate``, with Gaussian noise."""
    c = np.arange(1, life + 1)
    hi = 1.0 - (c / life) ** rate + noise * rng.standard_normal(life)
    return pd.DataFrame({"unit": unit, "cycle": c, "RUL": life - c, "HI_hat": hi})


@pytest.fixture()
def library():
    rng = np.random.default_rng(0)
    return pd.concat([trajectory(u, life, rate, 0.01, rng) for u, life, rate in
                      ((1, 60, 2.0), (2, 80, 2.0), (3, 100, 3.0), (4, 70, 1.5))],
                     ignore_index=True)


def test_a_unit_of_the_library_is_found_again_at_its_own_rul():
    """Without noise, a library unit's own history matches itself exactly (d = 0) and, at a
    small noise level, every other unit is far less likely: the prediction is its own RUL
    wherever its windows differ from every other unit's."""
    rng = np.random.default_rng(1)
    clean = pd.concat([trajectory(u, life, rate, 0.0, rng) for u, life, rate in
                       ((1, 60, 2.0), (2, 80, 2.0), (3, 100, 3.0))], ignore_index=True)
    model = SimilarityRul(tuple((g["HI_hat"].to_numpy(), g["RUL"].to_numpy(float))
                                for _, g in clean.groupby("unit")), sigma2=1e-8, window=10)
    unit3 = clean[clean["unit"] == 3]
    pred = model.predict(unit3)
    late = (pred["cycle"] > 30).to_numpy()  # past the flat start
    np.testing.assert_allclose(pred.loc[late, "RUL_pred"], unit3.loc[late, "RUL"], atol=1e-6)


def test_votes_are_weighted_by_the_kernel_of_the_match():
    """Two library units, flat at 0.9 and 0.8: a unit at 0.86 for k flights matches each at
    its mean squared difference d (0.0016 and 0.0036), and the prediction is the kernel's
    weighted mean of their RUL votes, w_i = exp(-k (d_i - min d) / (4 sigma^2))."""
    flat = lambda level, life: (np.full(life, level), np.arange(life - 1, -1, -1.0))  # noqa: E731
    sigma2, k = 1e-4, 4
    model = SimilarityRul((flat(0.9, 10), flat(0.8, 20)), sigma2=sigma2, window=k)
    pred = model.predict_unit(np.full(k, 0.86))[-1]
    d = np.array([0.04 ** 2, 0.06 ** 2])
    w = np.exp(-k * (d - d.min()) / (4 * sigma2))
    # every window of a flat unit matches equally: the first (argmin), RUL at its last flight
    votes = np.array([10 - k, 20 - k], float)
    assert pred == pytest.approx(np.sum(w * votes) / np.sum(w), rel=1e-12)
    assert votes[0] < pred < votes[1]  # neither winner-take-all nor an unweighted mean
    assert pred != pytest.approx(votes.mean())


def test_the_noise_is_estimated_from_the_library(library):
    model = SimilarityRul.fit(library, window=5)
    assert 0.5 * 0.01 ** 2 < model.sigma2 < 2.0 * 0.01 ** 2


def test_predictions_are_causal(library):
    """A flight's prediction reads only the flights up to it: changing later flights changes
    no earlier prediction."""
    model = SimilarityRul.fit(library[library["unit"] != 2], window=10)
    unit = library[library["unit"] == 2].reset_index(drop=True)
    before = model.predict(unit)["RUL_pred"].to_numpy()
    changed = unit.copy()
    changed.loc[changed["cycle"] > 40, "HI_hat"] -= 0.3
    after = model.predict(changed)["RUL_pred"].to_numpy()
    np.testing.assert_array_equal(before[:40], after[:40])
    assert not np.allclose(before[40:], after[40:])


def test_a_held_out_unit_is_predicted_from_the_others():
    """A unit of life 65 held out, predicted from units of one shape and lives 60-120 (mean
    90): closer to its truth than the library's mean life minus the cycle, and capped."""
    rng = np.random.default_rng(2)
    lib = pd.concat([trajectory(u, life, 2.0, 0.01, rng) for u, life in
                     ((1, 60), (2, 80), (3, 100), (4, 120))], ignore_index=True)
    unit = trajectory(9, 65, 2.0, 0.01, rng)
    pred = SimilarityRul.fit(lib, window=10).predict(unit, max_rul=50.0)
    err = np.minimum(pred["RUL"], 50) - pred["RUL_pred"]
    life_floor = np.minimum(np.maximum(90 - unit["cycle"], 0), 50) - np.minimum(unit["RUL"], 50)
    assert np.sqrt(np.mean(err ** 2)) < 0.5 * np.sqrt(np.mean(life_floor ** 2))
    assert (pred["RUL_pred"] >= 0).all() and (pred["RUL_pred"] <= 50).all()


def test_bad_input_is_refused(library):
    with pytest.raises(InputError, match="window must be an integer >= 1"):
        SimilarityRul.fit(library, window=0)
    with pytest.raises(InputError, match="need a RUL column"):
        SimilarityRul.fit(library.drop(columns="RUL"))
    with pytest.raises(InputError, match="missing column\\(s\\) HI_hat"):
        SimilarityRul.fit(library.drop(columns="HI_hat"))
    nan = library.copy()
    nan.loc[3, "HI_hat"] = np.nan
    with pytest.raises(InputError, match="HI_hat is not finite"):
        SimilarityRul.fit(nan)
    nan = library.copy()
    nan.loc[3, "RUL"] = np.nan
    with pytest.raises(InputError, match="RUL is not finite"):
        SimilarityRul.fit(nan)
    model = SimilarityRul.fit(library)
    with pytest.raises(InputError, match="several rows for one unit and cycle"):
        model.predict(pd.concat([library, library]))  # a sample table, not flights
    with pytest.raises(InputError, match="no flights"):
        model.predict(library.iloc[:0])


# --- the trained model: hyprog train --model similarity -------------------------------------

def _linear_hi(monkeypatch, index=None):
    """The health index of test_flights' stand-in (no engine model), or of ``index`` (a
    subclass of it)."""
    import prognostics.baseline as baseline
    from tests.test_flights import LinearHI

    cls = index or LinearHI
    monkeypatch.setattr(baseline, "engine_health_index", lambda effects=(): cls())


def test_the_trained_model_is_the_library_of_its_flights_capped_and_round_trips(
        make_features, monkeypatch, tmp_path):
    """``fit`` with ``model="similarity"``: the library is the development units' flight
    table (RUL capped at max_rul), the predictions are those of
    :class:`SimilarityRul` on the test units' flights, carried by every sample, causal, and
    the model saved and loaded predicts the same, bit for bit."""
    from prognostics.checkpoint import load_model, save_model
    from prognostics.ensemble import fit
    from prognostics.train_config import TrainConfig
    from prognostics.training import flight_frame

    _linear_hi(monkeypatch)
    df, meta = make_features()
    m = fit(df, meta, TrainConfig(model="similarity", inputs="HI_hat", window=5, max_rul=20.0))
    assert m.members == [] and m.parameters == 0 and m.columns == ("HI_hat",)
    assert m.info["units"] == {"training": meta["dev_units"]}
    fl = flight_frame(df)
    dev = fl[fl.unit.isin(meta["dev_units"])].assign(RUL=lambda f: f["RUL"].clip(upper=20.0))
    want = SimilarityRul.fit(dev, 5).predict(fl[fl.unit.isin(meta["test_units"])], 20.0)
    test = df[df.unit.isin(meta["test_units"])]
    pred = m.predict(test)
    assert len(pred) == len(test) and pred["RUL_pred"].max() <= 20.0
    per_flight = pred.groupby(["unit", "cycle"])["RUL_pred"].first().to_numpy()
    np.testing.assert_array_equal(per_flight, want["RUL_pred"].to_numpy())
    cut = m.predict(test[(test.unit != 5) | (test.cycle <= 9)])  # causal
    np.testing.assert_array_equal(cut[cut.unit == 5]["RUL_pred"],
                                  pred[(pred.unit == 5) & (pred.cycle <= 9)]["RUL_pred"])
    save_model(m, tmp_path / "m")
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == ["library.safetensors",
                                                                  "model.json"]
    again = load_model(tmp_path / "m")
    pd.testing.assert_frame_equal(again.predict(test), pred)
    save_model(again, tmp_path / "m")  # a library model directory is one hyprog may replace
    from prognostics import RulEstimator

    assert RulEstimator(model="similarity").config.inputs == "HI_hat_rel"  # its default
    est = RulEstimator.load(tmp_path / "m")
    assert est.ensemble == 1 and est.model_.library is not None


def test_the_trained_model_takes_conformal_units_and_refuses_what_does_not_apply(
        make_features, monkeypatch):
    from prognostics.ensemble import fit
    from prognostics.train_config import TrainConfig

    _linear_hi(monkeypatch)
    df, meta = make_features()
    m = fit(df, meta, TrainConfig(model="similarity", inputs="HI_hat", window=5,
                                  conformal_units=(4,), alpha=0.2))
    assert m.info["units"] == {"training": [1, 2, 3], "conformal": [4]}
    assert m.conformal is not None and list(m.conformal.units) == [4]
    pred = m.predict(df[df.unit == 5])
    assert (pred["RUL_upper"] - pred["RUL_pred"]).round(9).nunique() == 1
    with pytest.raises(InputError, match="one health index .*8 columns|one health index"):
        fit(df, meta, TrainConfig(model="similarity", inputs="physics"))
    with pytest.raises(InputError, match="no validation units"):
        fit(df, meta, TrainConfig(model="similarity", inputs="HI_hat", val_units=(2,)))
    with pytest.raises(InputError, match="conformal unit.* 5 are test"):
        fit(df, meta, TrainConfig(model="similarity", inputs="HI_hat", conformal_units=(5,)))
    with pytest.raises(InputError, match="window 99 is longer than the longest development"):
        fit(df, meta, TrainConfig(model="similarity", inputs="HI_hat", window=99))
    lives = df.groupby("unit")["cycle"].max()
    assert lives[3] == lives.max() > lives[[1, 2, 4]].max()  # the fixture's: unit 3 longest
    with pytest.raises(InputError, match="longer than the longest library unit"):
        fit(df, meta, TrainConfig(model="similarity", inputs="HI_hat", window=int(lives[3]),
                                  conformal_units=(3,)))
    with pytest.raises(InputError, match="not an ensemble of 2"):
        fit(df, meta, TrainConfig(model="similarity", inputs="HI_hat"), seeds=[0, 1])


def test_a_stored_library_that_was_edited_is_refused(make_features, monkeypatch, tmp_path):
    """The library file is hashed like a network's weights, and arrays that do not describe
    units are refused, naming the file."""
    from prognostics.checkpoint import load_model, save_model
    from prognostics.ensemble import fit
    from prognostics.train_config import TrainConfig

    _linear_hi(monkeypatch)
    df, meta = make_features()
    save_model(fit(df, meta, TrainConfig(model="similarity", inputs="HI_hat", window=5)),
               tmp_path / "m")
    f = tmp_path / "m" / "library.safetensors"
    blob = bytearray(f.read_bytes())
    blob[-20] ^= 0xFF  # one byte of the arrays changed
    f.write_bytes(bytes(blob))
    with pytest.raises(InputError, match="library.safetensors: SHA-256 mismatch"):
        load_model(tmp_path / "m")
    with pytest.raises(InputError, match="lib: the arrays do not describe a library"):
        SimilarityRul.from_arrays({"hi": np.zeros(5), "rul": np.zeros(5),
                                   "lengths": np.array([2, 2])}, 1.0, 3, source="lib")
    lib = SimilarityRul.from_arrays({"hi": np.arange(5.0), "rul": np.arange(5.0)[::-1],
                                     "lengths": np.array([2, 3])}, 0.5, 2)
    np.testing.assert_array_equal(lib.to_arrays()["lengths"], [2, 3])


def test_hyprog_train_similarity_and_evaluate(make_features, monkeypatch, tmp_path):
    """Through the CLI: --model similarity reads HI_hat_rel by default, reports its library, and
    evaluate scores it; --ensemble 2 is refused (nothing random)."""
    from cli.main import app
    from engine_model.datasets import write_parquet
    from tests.cli_checks import cli_runner

    _linear_hi(monkeypatch)
    df, meta = make_features()
    table = write_parquet(df, tmp_path / "f.parquet", meta)
    runner = cli_runner()
    r = runner.invoke(app, ["train", str(table), "--model", "similarity", "--window", "5",
                            "--out", str(tmp_path / "m")])
    assert r.exit_code == 0, r.output
    assert "SIMILARITY on HI_hat_rel, window 5 flights: a library of 4 unit(s)" in r.stdout
    r = runner.invoke(app, ["evaluate", str(tmp_path / "m"), str(table), "--json"])
    assert r.exit_code == 0, r.output
    assert set(json.loads(r.stdout)["samples"]["units"]) == {"5", "6"}
    r = runner.invoke(app, ["train", str(table), "--model", "similarity", "--ensemble", "2",
                            "--out", str(tmp_path / "m2")])
    assert r.exit_code != 0 and "nothing random" in r.stderr
    assert not (tmp_path / "m2").exists()


def test_manifests_that_do_not_describe_the_model_are_refused_and_older_ones_load(
        make_features, monkeypatch, tmp_path, torch_one_thread):
    """A network's manifest without the ``library`` key (written before the similarity model
    existed) loads; a library on a network's manifest, and a library model with a network or
    with other inputs, are refused, naming the manifest."""
    from prognostics.checkpoint import load_model, save_model
    from prognostics.ensemble import fit
    from prognostics.train_config import TrainConfig
    from tests.test_prognostics_training import resign_manifest

    _linear_hi(monkeypatch)
    df, meta = make_features()
    save_model(fit(df, meta, TrainConfig(model="fnn", inputs="hybrid", epochs=1)),
               tmp_path / "net")
    save_model(fit(df, meta, TrainConfig(model="similarity", inputs="HI_hat", window=5)),
               tmp_path / "lib")
    lib_body = json.loads((tmp_path / "lib" / "model.json").read_text())
    net_body = json.loads((tmp_path / "net" / "model.json").read_text())
    resign_manifest(tmp_path / "net", drop=("library",))
    assert load_model(tmp_path / "net").library is None  # an older manifest
    resign_manifest(tmp_path / "net", library=lib_body["library"])
    with pytest.raises(InputError, match="a fnn model with a library"):
        load_model(tmp_path / "net")
    resign_manifest(tmp_path / "lib", members=net_body["members"])
    with pytest.raises(InputError, match="model.json: a similarity model with a library, 1 "):
        load_model(tmp_path / "lib")
    resign_manifest(tmp_path / "lib", members=[], library=None)
    with pytest.raises(InputError, match="a similarity model with no library"):
        load_model(tmp_path / "lib")


def test_hyprog_predict_with_a_similarity_model_and_its_interval(make_features, monkeypatch,
                                                                 tmp_path):
    from cli.main import app
    from engine_model.datasets import write_parquet
    from prognostics import RulEstimator
    from tests.cli_checks import cli_runner

    _linear_hi(monkeypatch)
    df, meta = make_features()
    table = write_parquet(df, tmp_path / "f.parquet", meta)
    runner = cli_runner()
    r = runner.invoke(app, ["train", str(table), "--model", "similarity", "--window", "5",
                            "--conformal-units", "4", "--json", "--out", str(tmp_path / "m")])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    assert rep["library"]["units"] == 3 and rep["validation"] is None
    r = runner.invoke(app, ["predict", str(tmp_path / "m"), str(table), "--units", "5",
                            "--out", str(tmp_path / "p.parquet")])
    assert r.exit_code == 0, r.output
    pred = pd.read_parquet(tmp_path / "p.parquet")
    assert len(pred) == int((df.unit == 5).sum())
    assert (pred["RUL_lower"] <= pred["RUL_pred"]).all() and \
        (pred["RUL_pred"] <= pred["RUL_upper"]).all()
    r = runner.invoke(app, ["train", str(table), "--model", "similarity", "--validation",
                            "units", "--out", str(tmp_path / "m3")])
    assert r.exit_code != 0 and "stops nothing early" in r.stderr
    with pytest.raises(InputError, match="ensemble 2 is not one"):
        RulEstimator(model="similarity", ensemble=2)


def test_on_the_health_index_relative_to_early_life_a_units_initial_level_does_not_count(
        make_features, monkeypatch):
    """``inputs="HI_hat_rel"``: the library and the match read the health index minus its
    mean over the unit's first flights (:mod:`prognostics.flights`), so a test unit whose θ̂
    sits lower by a constant from its first flight on (initial wear; the stand-in index is
    linear there) gets the same predictions, a unit that degrades faster does not, and the
    model on the absolute ``HI_hat`` reads the lower level as less life."""
    from prognostics.ensemble import fit
    from prognostics.train_config import TrainConfig
    from tests.test_flights import LinearHI

    class Linear(LinearHI):  # every margin 1 + 20 sum(θ): the index linear in θ everywhere
        A = dict.fromkeys(LinearHI.A, 20.0)

    _linear_hi(monkeypatch, Linear)
    df, meta = make_features()
    test = df[df.unit.isin(meta["test_units"])]
    worn = test.assign(HPT_eff_mod_hat=test["HPT_eff_mod_hat"] - 0.01)
    rel = fit(df, meta, TrainConfig(model="similarity", inputs="HI_hat_rel", window=5))
    assert rel.columns == ("HI_hat_rel",)
    base = rel.predict(test)["RUL_pred"]
    np.testing.assert_allclose(rel.predict(worn)["RUL_pred"], base, rtol=0, atol=1e-9)
    faster = test.assign(HPT_eff_mod_hat=1.5 * test["HPT_eff_mod_hat"])  # the change, not the level
    assert not np.allclose(rel.predict(faster)["RUL_pred"], base)
    absolute = fit(df, meta, TrainConfig(model="similarity", inputs="HI_hat", window=5))
    moved = absolute.predict(worn)["RUL_pred"] - absolute.predict(test)["RUL_pred"]
    assert (moved < 0).mean() > 0.5


def test_a_unit_that_starts_after_cycle_1_is_a_warning_for_inputs_relative_to_early_life(
        make_features, monkeypatch):
    """A unit whose table starts in mid-life: its first flights there are taken as its early
    life, so a model on ``HI_hat_rel`` warns, naming the unit and its first cycle; the same
    table with the absolute index does not."""
    from prognostics.ensemble import fit
    from prognostics.train_config import TrainConfig

    _linear_hi(monkeypatch)
    df, meta = make_features()
    test = df[df.unit.isin(meta["test_units"])]
    late = test[(test.unit != 5) | (test.cycle >= 4)]
    rel = fit(df, meta, TrainConfig(model="similarity", inputs="HI_hat_rel", window=5))
    with pytest.warns(UserWarning, match=r"unit\(s\) 5 \(cycle 4\) start after cycle 1"):
        rel.predict(late)
    absolute = fit(df, meta, TrainConfig(model="similarity", inputs="HI_hat", window=5))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        absolute.predict(late)
        rel.predict(test)


def test_the_pipeline_config_gives_the_similarity_model_its_own_default_inputs(tmp_path):
    """``[train] model = "similarity"`` without ``inputs`` takes the model's default, as
    ``hyprog train --model similarity`` does; inputs given are kept, and another model keeps
    the pipeline's default input sets."""
    from prognostics.train_config import DEFAULT_INPUTS
    from workflows.pipeline.config import load_config

    def inputs(toml):
        (tmp_path / "c.toml").write_text(toml)
        return load_config(tmp_path / "c.toml")["train"]["inputs"]

    assert inputs('[train]\nmodel = "similarity"\n') == [DEFAULT_INPUTS["similarity"]]
    assert inputs('[train]\nmodel = "similarity"\ninputs = ["HI_hat"]\n') == ["HI_hat"]
    assert inputs('[train]\nmodel = "tcn"\n') == ["data-driven", "hybrid"]

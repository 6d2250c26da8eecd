"""Training that fits the data (issue 28, item 2): the size rules of ``TrainConfig``, the
learning-rate schedule, per-condition standardisation, constant columns dropped, Li et al.'s
DCNN, and the truncation of held-out units within the target cap.

Synthetic tables (tests/conftest.py and below); every training run is a few seconds.
"""

import json

import numpy as np
import pandas as pd
import pytest
import torch

from engine_model.validation import InputError
from prognostics.checkpoint import load_model, save_model
from prognostics.cross_validation import truncate_units, unit_folds
from prognostics.ensemble import fit
from prognostics.models import DCNN, build_model, parameter_count
from prognostics.scaling import ConditionScaler, MinMaxScaler, fit_scaler, scaler_from_dict
from prognostics.train_config import (
    DEFAULT_EPOCHS,
    MIN_STEPS,
    PAPER_BATCH,
    PAPER_PATIENCE,
    PATIENCE_STEPS,
    TrainConfig,
)

pytestmark = pytest.mark.usefixtures("torch_one_thread")

# ---------------------------------------------------------------------------------------------
# size rules
# ---------------------------------------------------------------------------------------------


def test_size_rules_give_the_papers_values_at_the_papers_size():
    c = TrainConfig(model="cnn").sized(5_000_000, n_units=1)
    assert (c.batch_size, c.epochs, c.patience, c.validation) == \
        (PAPER_BATCH, DEFAULT_EPOCHS["cnn"], PAPER_PATIENCE, "flights")
    assert TrainConfig(model="cnn").sized(5_000_000, n_units=6).validation == "units"


def test_size_rules_on_a_cmapss_sized_table():
    n = 14_000  # FD001: about 17,700 windows of 30, 10 % of the units validate
    c = TrainConfig(model="dcnn").sized(n, n_units=80)
    # the largest power of two with at least 16 batches an epoch: 14,000 / 16 = 875 -> 512,
    # Li et al.'s batch
    assert c.batch_size == 512
    steps = -(-n // 512)  # 28 an epoch
    assert c.epochs == max(DEFAULT_EPOCHS["dcnn"], -(-MIN_STEPS // steps)) == 250
    assert c.patience == -(-PATIENCE_STEPS // steps) == 72
    assert c.validation == "units"  # whole held-out units
    small = TrainConfig(model="cnn").sized(600, n_units=80)
    assert small.batch_size == 32 and small.epochs == -(-MIN_STEPS // -(-600 // 32))


def test_given_values_are_kept_and_bad_ones_refused():
    c = TrainConfig(batch_size=77, epochs=3, patience=2, validation="flights")
    s = c.sized(14_000, n_units=80)
    assert (s.batch_size, s.epochs, s.patience, s.validation) == (77, 3, 2, "flights")
    for bad in ({"schedule": "cosine"}, {"normalise": "zscore"}, {"validation": "cycles"},
                {"batch_size": 0}, {"patience": 0}):
        with pytest.raises(InputError):
            TrainConfig(**bad).resolved()
    with pytest.raises(InputError, match="seed -1: expected an integer >= 0"):
        TrainConfig(seed=-1).resolved()
    with pytest.raises(InputError, match="cross-validation: seed -2"):
        unit_folds([1, 2, 3], 2, -2)
    with pytest.raises(InputError, match="truncate: seed -3"):
        truncate_units(pd.DataFrame({"unit": [1], "cycle": [1]}), [1], -3)


def test_a_training_run_that_diverges_is_a_clear_error(make_features):
    """A learning rate so large that no epoch's loss is finite: one line naming the seed and
    the rate, not a traceback from restoring a best epoch that never was."""
    df, meta = make_features()
    cfg = TrainConfig(model="fnn", inputs="data-driven", epochs=2, lr=1e30, device="cpu",
                      schedule="constant")
    with pytest.raises(InputError,
                       match=r"training diverged \(seed 0\).*lower --lr \(now 1e\+30\)"):
        fit(df, meta, cfg)


def test_the_trained_model_records_the_values_the_rules_chose(make_features):
    df, meta = make_features()
    m = fit(df, meta, TrainConfig(model="fnn", inputs="data-driven", epochs=2, device="cpu"))
    assert m.config.batch_size >= 32 and m.config.patience >= PAPER_PATIENCE
    assert m.config.validation == "units"  # whole held-out units by default (issue 30)


# ---------------------------------------------------------------------------------------------
# schedule
# ---------------------------------------------------------------------------------------------


def test_plateau_schedule_cuts_the_rate_tenfold_and_constant_keeps_it(make_features):
    df, meta = make_features()
    kw = dict(model="fnn", inputs="data-driven", epochs=14, patience=4, lr=0.05, seed=0,
              batch_size=64, device="cpu")
    flat = fit(df, meta, TrainConfig(schedule="constant", **kw)).members[0].history
    assert {r["lr"] for r in flat} == {0.05}
    plateau = fit(df, meta, TrainConfig(**kw)).members[0].history
    rates = sorted({r["lr"] for r in plateau}, reverse=True)
    assert rates[0] == 0.05
    assert len(rates) > 1 and rates[1] == pytest.approx(0.005)  # lr 0.05 stalls on this table
    assert min(rates) >= 0.05 * 0.01 * (1 - 1e-9)


# ---------------------------------------------------------------------------------------------
# per-condition standardisation and constant columns
# ---------------------------------------------------------------------------------------------


def _conditions_table(seed=0, units=(1, 2, 3, 4, 5, 6), eol=40):
    """One sample per cycle, three operating conditions whose levels dwarf the wear signal."""
    rng = np.random.default_rng(seed)
    rows = []
    levels = {1: (0.0, 0.0, 100.0, 500.0), 2: (20000.0, 0.7, 100.0, 900.0),
              3: (35000.0, 0.84, 60.0, 1400.0)}
    for u in units:
        for c in range(1, eol + 1):
            k = int(rng.integers(1, 4))
            alt, mach, tra, level = levels[k]
            h = c / eol
            rows.append({"unit": u, "cycle": c, "RUL": float(eol - c), "condition": k,
                         "alt": alt + rng.normal(0, 5), "Mach": mach, "TRA": tra,
                         "T30": level * (1 + 0.01 * h) + rng.normal(0, 0.5),
                         "Nc": level / 10 - 2 * h + rng.normal(0, 0.05), "farB": 0.02})
    return pd.DataFrame(rows)


def test_condition_scaler_standardises_each_sensor_within_its_condition():
    df = _conditions_table()
    rows = df["unit"].isin([1, 2, 3, 4]).to_numpy()
    s = ConditionScaler.fit_frame(df, ["alt", "T30", "Nc"], rows)
    x = s.transform_frame(df)
    for k in (1, 2, 3):
        pick = rows & (df["condition"] == k).to_numpy()
        v = df.loc[pick, "T30"].to_numpy()
        np.testing.assert_allclose(x[pick, 1], (v - v.mean()) / v.std(), rtol=1e-5, atol=1e-5)
    # the setting is min-max scaled over the fleet, not per condition
    alt = df.loc[rows, "alt"].to_numpy()
    np.testing.assert_allclose(x[rows, 0], 2 * (alt - alt.min()) / (alt.max() - alt.min()) - 1,
                               atol=1e-5)
    back = scaler_from_dict(json.loads(json.dumps(s.to_dict())))
    assert np.array_equal(back.transform_frame(df), x)


def test_condition_scaler_refuses_what_it_has_no_statistics_for():
    df = _conditions_table()
    with pytest.raises(InputError, match="needs a 'condition' column"):
        ConditionScaler.fit_frame(df.drop(columns="condition"), ["T30"])
    s = ConditionScaler.fit_frame(df[df["condition"] != 3], ["T30"])
    with pytest.raises(InputError, match=r"unit \d+, cycle \d+: condition 3 is not one"):
        s.transform_frame(df, source="f.parquet")
    zero = df.copy()
    zero.loc[5, "condition"] = 0
    with pytest.raises(InputError, match="cycle 6: condition 0"):
        ConditionScaler.fit_frame(zero, ["T30"])
    with pytest.raises(InputError, match="normalise must be"):
        fit_scaler("robust", df, ["T30"])


def test_constant_columns_are_dropped_and_recorded(tmp_path):
    df = _conditions_table()
    meta = {"dev_units": [1, 2, 3, 4, 5], "test_units": [6]}
    cfg = TrainConfig(model="fnn", inputs="alt,Mach,TRA,T30,Nc,farB", epochs=2, device="cpu",
                      normalise="minmax")
    m = fit(df, meta, cfg)
    assert m.info["dropped_constant"] == ["farB"]  # Mach, TRA vary between conditions
    assert "farB" not in m.columns and isinstance(m.scaler, MinMaxScaler)
    kept = fit(df, meta, TrainConfig(**{**cfg.__dict__, "drop_constant": False}))
    assert "farB" in kept.columns and kept.info["dropped_constant"] == []
    # per condition: a column constant within every condition goes too
    by = fit(df, meta, TrainConfig(**{**cfg.__dict__, "normalise": "condition",
                                      "inputs": "alt,T30,Nc,farB"}))
    assert by.info["dropped_constant"] == ["farB"] and isinstance(by.scaler, ConditionScaler)
    save_model(by, tmp_path / "m")
    back = load_model(tmp_path / "m")
    assert back.info["dropped_constant"] == ["farB"]
    p1, p2 = by.predict(df, [6]), back.predict(df, [6])
    assert np.array_equal(p1["RUL_pred"].to_numpy(), p2["RUL_pred"].to_numpy())
    with pytest.raises(InputError, match="every input column is constant"):
        fit(df, meta, TrainConfig(**{**cfg.__dict__, "inputs": "farB"}))


def test_the_scaler_of_a_training_run_reads_its_training_units_only():
    """Per-condition standardisation (and min-max) fitted inside training: validation,
    conformal and held-out units never reach its statistics. Their sensors moved by a huge
    amount leave the trained model's scaler unchanged."""
    from prognostics.training import prepare

    df = _conditions_table(units=tuple(range(1, 13)))
    meta = {"dev_units": list(range(1, 11)), "test_units": [11, 12]}
    for normalise in ("condition", "minmax"):
        cfg = TrainConfig(model="fnn", inputs="alt,Mach,TRA,T30,Nc", normalise=normalise,
                          val_units=(9,), conformal_units=(10,), validation="units",
                          device="cpu")
        base = prepare(df, meta, cfg).scaler.to_dict()
        moved = df.copy()
        far = moved["unit"].isin([9, 10, 11, 12])
        moved.loc[far, ["T30", "Nc"]] *= 50.0
        assert prepare(moved, meta, cfg).scaler.to_dict() == base, normalise
        moved.loc[moved["unit"] == 1, ["T30", "Nc"]] *= 50.0  # a training unit: it moves
        assert prepare(moved, meta, cfg).scaler.to_dict() != base, normalise


def test_per_condition_standardisation_helps_where_conditions_dominate():
    """With condition levels 100x the wear signal, min-max scaling hides the wear; the
    per-condition scaler exposes it (validation loss of the same tiny FNN, same seed)."""
    df = _conditions_table(units=tuple(range(1, 13)))
    meta = {"dev_units": list(range(1, 11)), "test_units": [11, 12]}
    kw = dict(model="fnn", inputs="alt,Mach,TRA,T30,Nc", epochs=30, batch_size=64, seed=0,
              device="cpu", val_units=(9, 10), validation="units")
    mm = fit(df, meta, TrainConfig(normalise="minmax", **kw)).members[0]
    cond = fit(df, meta, TrainConfig(normalise="condition", **kw)).members[0]
    best = lambda m: m.history[m.best_epoch - 1]["val_loss"]  # noqa: E731
    assert best(cond) < 0.1 * best(mm), (best(cond), best(mm))  # an order of magnitude


# ---------------------------------------------------------------------------------------------
# DCNN
# ---------------------------------------------------------------------------------------------


def test_dcnn_has_li_et_als_layers_and_parameter_count():
    net = build_model("dcnn", 14, 30, seed=0)
    x = torch.randn(3, 14, 30, generator=torch.Generator().manual_seed(0))
    assert isinstance(net, DCNN) and net(x).shape == (3,)
    # (10 n + 1) 10 + 3 (10 x 10 x 10 + 10) + (10 x 3 + 1) + (L + 1) 100 + 101
    assert parameter_count(net) == (10 * 14 * 10 + 10) + 3 * 1010 + 31 + 31 * 100 + 101 == 7672
    assert sum(isinstance(m, torch.nn.Dropout) for m in net.modules()) == 1


def test_dcnn_training_with_dropout_is_reproducible_and_leaves_the_global_rng(make_features):
    df, meta = make_features()
    cfg = TrainConfig(model="dcnn", inputs="data-driven", window=8, epochs=2, seed=3,
                      batch_size=128, device="cpu")
    torch.manual_seed(123)
    before = torch.rand(1)
    torch.manual_seed(123)
    a = fit(df, meta, cfg)
    after = torch.rand(1)  # the caller's generator is where it would be without training
    assert torch.equal(before, after)
    b = fit(df, meta, cfg)
    for (k, va), vb in zip(a.members[0].state.items(), b.members[0].state.values(),
                           strict=True):
        assert torch.equal(va, vb), k


# ---------------------------------------------------------------------------------------------
# truncation within the cap
# ---------------------------------------------------------------------------------------------


def test_truncation_within_the_cap_leaves_a_true_rul_up_to_the_cap():
    df = _conditions_table(units=tuple(range(1, 41)), eol=200)
    cut = truncate_units(df, range(1, 41), seed=0, min_cycles=30, max_rul=125)
    last = cut.groupby("unit").tail(1)
    assert last["RUL"].between(0, 125).all()
    assert last["RUL"].max() > 90 and last["RUL"].min() < 35  # spread over the range
    with pytest.raises(InputError, match="max_rul"):
        truncate_units(df, [1], seed=0, max_rul=-1)


def test_auto_normalisation_is_per_condition_only_where_there_are_several(make_features):
    df = _conditions_table()
    meta = {"dev_units": [1, 2, 3, 4, 5], "test_units": [6]}
    cfg = TrainConfig(model="fnn", inputs="alt,T30,Nc", epochs=1, device="cpu")
    assert fit(df, meta, cfg).config.normalise == "condition"
    one = df[df["condition"] == 2]
    assert fit(one, meta, cfg).config.normalise == "minmax"  # one condition
    unmatched = df.copy()
    unmatched.loc[3, "condition"] = 0
    assert fit(unmatched, meta, cfg).config.normalise == "minmax"  # a row without one
    sim, sim_meta = make_features()  # no condition column (a simulated fleet)
    m = fit(sim, sim_meta, TrainConfig(model="fnn", inputs="data-driven", epochs=1,
                                       device="cpu"))
    assert m.config.normalise == "minmax"


def test_predictions_of_a_capped_model_are_capped_like_its_targets(make_features):
    df, meta = make_features()
    cfg = TrainConfig(model="fnn", inputs="data-driven", epochs=3, max_rul=5.0, lr=0.01,
                      seed=0, device="cpu")
    p = fit(df, meta, cfg).predict(df, [5, 6])
    assert p["RUL_pred"].between(0.0, 5.0).all()
    assert (p["RUL_pred"] == 5.0).any()  # the raw outputs go beyond the cap on healthy cycles


def test_settings_of_a_single_operating_condition_are_dropped_as_noise():
    df = _conditions_table()
    one = df[df["condition"] == 2].copy()  # altitude carries noise around 20,000 ft
    meta = {"dev_units": [1, 2, 3, 4, 5], "test_units": [6]}
    cfg = TrainConfig(model="fnn", inputs="alt,Mach,TRA,T30,Nc", epochs=1, device="cpu")
    m = fit(one, meta, cfg)
    assert set(m.info["dropped_constant"]) == {"alt", "Mach", "TRA"}
    assert m.columns == ("T30", "Nc")
    assert set(fit(df, meta, cfg).columns) >= {"alt", "Mach", "TRA"}  # three conditions
    unlabelled = one.drop(columns="condition")  # no condition column: alt stays (not constant)
    assert "alt" in fit(unlabelled, meta, cfg).columns
    with pytest.raises(InputError, match="single operating condition"):
        fit(one, meta, TrainConfig(**{**cfg.__dict__, "inputs": "alt,Mach"}))

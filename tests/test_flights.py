"""Issue 30: flight tables, health coordinates of θ̂, the flight models, floors and phases."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import torch

from engine_model.channels import THETA_NAMES
from engine_model.validation import InputError
from prognostics.ensemble import fit
from prognostics.flights import causal_reference, flight_table, to_samples, unit_lives
from prognostics.floors import HiLookup, floor_predictions
from prognostics.metrics import evaluate_predictions, phase_metrics
from prognostics.splits import TRAIN, VALIDATION
from prognostics.train_config import TrainConfig
from prognostics.training import prepare
from prognostics.windows import make_windows

pytestmark = pytest.mark.usefixtures("torch_one_thread")


class LinearHI:
    """A stand-in health index, linear in θ (no engine model): margins ``1 + a_k · θ``."""

    A = {"SmFan": 0.0, "SmLPC": 0.0, "SmHPC": 5.0, "EGT": 20.0}

    def components(self, theta):
        th = np.atleast_2d(theta)
        s = th.sum(axis=1)
        return {k: 1.0 + a * s for k, a in self.A.items()}

    @staticmethod
    def of_components(c):
        return np.min(np.vstack(list(c.values())), axis=0)


def test_flight_table_means_labels_and_relative_theta(make_features):
    df, _ = make_features()
    ft = flight_table(df, LinearHI())
    assert not ft.duplicated(["unit", "cycle"]).any()
    g = df.groupby(["unit", "cycle"])
    np.testing.assert_allclose(ft["T24"], g["T24"].mean().to_numpy())
    np.testing.assert_array_equal(ft["RUL"], g["RUL"].last().to_numpy())
    # HI from the flight's mean theta-hat, placed by name (others at 0)
    th = sum(g[q + "_hat"].mean().to_numpy() for q in ("HPT_eff_mod", "LPT_eff_mod",
                                                       "LPT_flow_mod"))
    np.testing.assert_allclose(ft["HI_hat"], np.minimum(1.0, 1.0 + np.minimum(20 * th, 5 * th)))
    np.testing.assert_allclose(ft["margin_hpc_hat"], 1.0 + 5.0 * th)
    # relative to the mean of the unit's first 5 flights (expanding before that)
    u1 = ft[ft.unit == 1]["HPT_eff_mod_hat"].to_numpy()
    rel = ft[ft.unit == 1]["HPT_eff_mod_hat_rel"].to_numpy()
    np.testing.assert_allclose(rel[:3], u1[:3] - np.cumsum(u1[:3]) / np.arange(1, 4))
    np.testing.assert_allclose(rel[10], u1[10] - u1[:5].mean())
    # the true theta gives the truth's coordinates; a flight table again is unchanged
    assert "HI" in ft.columns and "HI_hat_rel" in ft.columns
    again = flight_table(ft, LinearHI())
    pd.testing.assert_frame_equal(again[ft.columns], ft)


def test_flight_features_are_causal(make_features):
    """A flight's row never depends on a later sample: altering every later flight, or
    cutting them off, leaves the rows up to it unchanged."""
    df, _ = make_features()
    ft = flight_table(df, LinearHI())
    later = (df.unit == 2) & (df.cycle > 7)
    changed = df.copy()
    num = [c for c in df.columns if c not in ("unit", "cycle", "t", "RUL")]
    changed.loc[later, num] = changed.loc[later, num] * 3.0 + 1.0
    for other in (changed, df[~later]):
        ft2 = flight_table(other, LinearHI())
        keep = (ft.unit != 2) | (ft.cycle <= 7)
        pd.testing.assert_frame_equal(ft2[(ft2.unit != 2) | (ft2.cycle <= 7)]
                                      .reset_index(drop=True),
                                      ft[keep].reset_index(drop=True))
    ref = causal_reference(np.array([1, 1, 1, 2, 2]), np.array([1.0, 3.0, 5.0, 2.0, 4.0]), 2)
    np.testing.assert_allclose(ref, [1.0, 2.0, 2.0, 2.0, 3.0])


def test_health_index_of_theta_hat_equals_the_simulators(model):
    """At the true θ (θ̂ = θ), the flight table's HI is the simulator's health index of the
    trajectory it drew (``degradation.simulate_health``), to 1e-6."""
    from engine_model.physics.health_index import HealthIndex
    from engine_model.simulator.degradation import simulate_health

    hi = HealthIndex(model)
    traj = simulate_health(model, "HPT+LPT", eol=(14, 14), t_s=(5, 5),
                           rng=np.random.default_rng(3), hi_fn=hi)
    rows = []
    for c in range(1, traj.eol + 1):
        for k in range(3):  # three samples a flight
            r = {"unit": 1, "cycle": c, "t": 10.0 * k, "RUL": traj.eol - c}
            r.update({q + "_hat": traj.theta[c - 1, j] for j, q in enumerate(THETA_NAMES)})
            rows.append(r)
    ft = flight_table(pd.DataFrame(rows), hi)
    np.testing.assert_allclose(ft["HI_hat"], traj.hi, atol=1e-6)
    assert abs(ft["HI_hat"].iloc[-1]) < 1e-6 and ft["HI_hat"].iloc[0] > 0.5
    np.testing.assert_allclose(ft["margin_egt_hat"], traj.margins["EGT"], atol=1e-9)


def test_validation_units_never_overlap_training_units(make_features):
    df, meta = make_features(units=tuple(range(1, 13)), test_units=(11, 12))
    for model in ("cnn", "tcn"):
        prep = prepare(df, meta, TrainConfig(model=model, inputs="data-driven", seed=4,
                                             window=3))
        assert prep.config.validation == "units"
        unit = prep.frame["unit"].to_numpy()
        train, val = set(unit[prep.roles == TRAIN]), set(unit[prep.roles == VALIDATION])
        assert val and train and not train & val
        assert not (train | val) & {11, 12}


def test_windows_padded_at_every_row():
    x = np.arange(14, dtype=np.float32).reshape(7, 2)
    w = make_windows(x, np.array([0, 3]), np.array([3, 7]), length=3, pad_all=True)
    assert len(w) == 7 and list(w.rows) == list(range(7))
    first = w.batch(np.array([0]))[0].numpy()  # row 0 with two copies of itself before it
    np.testing.assert_array_equal(first, np.repeat(x[[0]].T, 3, axis=1))
    fourth = w.batch(np.array([4]))[0].numpy()  # row 4 = second row of segment 2
    np.testing.assert_array_equal(fourth, x[[3, 3, 4]].T)


def test_a_flight_models_windows_read_the_whole_history_whatever_the_role(make_features):
    """With validation on flights, a training window that follows a validation flight reads
    that flight's inputs (the unit's real history, as at prediction), and every flight of the
    development units ends exactly one window, of its own role."""
    df, meta = make_features()
    prep = prepare(df, meta, TrainConfig(model="tcn", inputs="data-driven", window=4,
                                         validation="flights", seed=1))
    assert prep.config.validation == "flights"
    train, val = prep.windows[TRAIN], prep.windows[VALIDATION]
    assert (prep.roles[train.rows] == TRAIN).all() and (prep.roles[val.rows] == VALIDATION).all()
    used = np.flatnonzero(np.isin(prep.roles, (TRAIN, VALIDATION)))
    assert sorted([*train.rows, *val.rows]) == list(used)
    unit = prep.frame["unit"].to_numpy()
    v = int(val.rows[0])
    after = np.flatnonzero(train.rows == v + 1)
    assert unit[v + 1] == unit[v] and after.size == 1  # a training flight follows it
    window = train.batch(torch.as_tensor(after))[0].numpy()
    flight_v = val.batch(torch.as_tensor([0]))[0].numpy()[:, -1]  # flight v's own inputs
    np.testing.assert_array_equal(window[:, -2], flight_v)
    assert not np.array_equal(window[:, -2], window[:, -1])  # not a padded copy


def _fake_hi(monkeypatch):
    import prognostics.baseline as baseline

    monkeypatch.setattr(baseline, "engine_health_index", lambda effects=(): LinearHI())


@pytest.mark.parametrize("model", ["tcn", "trend"])
def test_flight_models_train_predict_and_stay_causal(make_features, monkeypatch, tmp_path,
                                                     model):
    from prognostics.checkpoint import load_model, save_model

    _fake_hi(monkeypatch)
    df, meta = make_features()
    cfg = TrainConfig(model=model, inputs="physics", window=6, epochs=4, device="cpu")
    m = fit(df, meta, cfg)
    assert m.config.per_flight and m.config.validation == "units"
    if model == "trend":
        lives = unit_lives(flight_table(df[df.unit.isin(meta["dev_units"])]))
        assert m.config.trend_cap <= lives.max()
    test = df[df.unit.isin(meta["test_units"])]
    pred = m.predict(test)
    assert len(pred) == len(test)  # every sample carries its flight's prediction
    per_flight = pred.groupby(["unit", "cycle"])["RUL_pred"].nunique()
    assert (per_flight == 1).all()
    # causal: cutting off unit 5's flights after 9 leaves its first 9 predictions as they were
    cut = m.predict(test[(test.unit != 5) | (test.cycle <= 9)])
    a = pred[(pred.unit == 5) & (pred.cycle <= 9)]["RUL_pred"].to_numpy()
    b = cut[cut.unit == 5]["RUL_pred"].to_numpy()
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
    save_model(m, tmp_path / "m")
    again = load_model(tmp_path / "m")
    pd.testing.assert_frame_equal(again.predict(test), pred)


def test_health_groups_need_a_flight_model_on_a_table_of_samples(make_features):
    df, meta = make_features()
    with pytest.raises(InputError, match="several rows per cycle .*tcn, trend or similarity"):
        fit(df, meta, TrainConfig(model="fnn", inputs="physics", epochs=1))


def test_a_sample_model_reads_health_coordinates_on_a_table_of_one_row_per_cycle(
        make_features, monkeypatch, tmp_path):
    """C-MAPSS has one row per cycle, so its flight table has the same rows: a sample model
    (the DCNN) reads θ̂ relative to early life and the health index there, evaluated with the
    engine model θ̂ was calibrated with (the metadata's effects), kept with the model."""
    import prognostics.baseline as baseline
    from prognostics.checkpoint import load_model, save_model

    asked = []

    def hi_of(effects=()):
        asked.append(tuple(effects))
        return LinearHI()

    monkeypatch.setattr(baseline, "engine_health_index", hi_of)
    df, meta = make_features(samples=(1, 1))
    effects = ["design_scaling:component=HPC,eff=-0.01,flow=0"]
    meta = {**meta, "calibration": {"effects": effects}}
    cfg = TrainConfig(model="cnn", inputs="w+xs+theta_hat+theta_rel", window=5, epochs=3,
                      device="cpu")
    m = fit(df, meta, cfg)
    assert not m.config.per_flight and m.config.reads_flights
    assert "HI_hat_rel" in m.columns and "HPT_eff_mod_hat_rel" in m.columns
    assert asked and set(asked) == {tuple(effects)}
    test = df[df.unit.isin(meta["test_units"])]
    pred = m.predict(test)
    assert len(pred) == len(test) - len(meta["test_units"]) * (cfg.window - 1)
    # causal: unit 5 cut after cycle 12 keeps its predictions up to there
    cut = m.predict(test[(test.unit != 5) | (test.cycle <= 12)])
    a = pred[(pred.unit == 5) & (pred.cycle <= 12)]["RUL_pred"].to_numpy()
    np.testing.assert_allclose(cut[cut.unit == 5]["RUL_pred"].to_numpy(), a, atol=1e-9)
    save_model(m, tmp_path / "m")
    again = load_model(tmp_path / "m")
    assert again.info["health_effects"] == effects
    asked.clear()
    pd.testing.assert_frame_equal(again.predict(test), pred)
    assert set(asked) == {tuple(effects)}


def test_health_index_of_an_adapted_model_reads_one_for_its_new_engine():
    """θ̂ is a deviation from the model it was calibrated with: with an adapted model's
    effects (here a 1 % customer bleed: its compiled variant is one the suite builds for its
    other tests, where a map scaling would cost a compile of its own) the health index of
    θ̂ = 0 is 1, where the designed model reads an engine whose HPC efficiency is 1 % lower
    as worn."""
    from prognostics.baseline import engine_health_index, health_effects

    effects = health_effects({"calibration": {"effects": ["customer_bleed:f0=0.01"]}})
    assert effects == ("customer_bleed:f0=0.01",)
    assert health_effects({}) == () and health_effects(None) == ()
    zero = np.zeros((1, len(THETA_NAMES)))
    np.testing.assert_allclose(engine_health_index(effects)(zero), 1.0, atol=1e-9)
    shifted = zero.copy()
    shifted[0, THETA_NAMES.index("HPC_eff_mod")] = -0.01
    assert engine_health_index()(shifted)[0] < 0.95  # the designed model: a worn engine


def test_floors_life_lookup_and_trend():
    rows = []
    for u, eol in ((1, 10), (2, 20), (3, 16)):
        for c in range(1, eol + 1):
            rows.append({"unit": u, "cycle": c, "RUL": eol - c, "HI_hat": (eol - c) / eol,
                         "hs": int(c < 4)})
    ft = pd.DataFrame(rows)
    dev, ev = ft[ft.unit < 3], ft[ft.unit == 3]
    np.testing.assert_array_equal(unit_lives(dev).to_numpy(), [10, 20])
    f = floor_predictions(dev, ev)
    np.testing.assert_allclose(f["life"]["RUL_pred"], np.maximum(15.0 - ev.cycle, 0.0))
    look = HiLookup.fit(dev["HI_hat"], dev["RUL"])
    assert np.all(np.diff(look.rul) >= 0) and np.all(np.diff(look.hi) > 0)
    assert look(-1.0) == look.rul[0] and look(2.0) == look.rul[-1]
    # a linear HI reaching 0 at the end: the trend predicts the life left once it has 2 flights
    trend = f["physics-trend"]["RUL_pred"].to_numpy()
    np.testing.assert_allclose(trend[2:], ev["RUL"].to_numpy()[2:], atol=1e-6)
    with pytest.raises(InputError, match="unknown floor"):
        floor_predictions(dev, ev, ["oracle"])
    # with a cap the lookup is the curve of the capped target, not the capped curve
    capped = floor_predictions(dev, ev, ["hi-lookup"], max_rul=12.0)["hi-lookup"]
    look12 = HiLookup.fit(dev["HI_hat"], np.minimum(dev["RUL"], 12.0))
    np.testing.assert_allclose(capped["RUL_pred"], look12(ev["HI_hat"]))
    assert capped["RUL_pred"].max() <= 12.0


def test_phase_metrics_split_before_and_after_onset():
    pred = pd.DataFrame({"unit": 1, "cycle": [1, 2, 3, 4], "RUL": [40.0, 30.0, 20.0, 10.0],
                         "RUL_pred": [44.0, 30.0, 23.0, 6.0], "hs": [1, 1, 0, 0]})
    ph = phase_metrics(pred)
    assert ph["before onset"]["rmse"] == pytest.approx(np.sqrt(8.0))
    assert ph["after onset"]["rmse"] == pytest.approx(np.sqrt(12.5))
    assert ph["RUL <= 30"]["n"] == 3
    assert "phases" in evaluate_predictions(pred)["samples"]
    assert to_samples(pred[["unit", "cycle", "RUL_pred"]].assign(RUL_pred=1.0),
                      pred.drop(columns="RUL_pred"))["RUL_pred"].eq(1.0).all()


def test_failure_mode_is_the_direction_of_the_change_once_it_exceeds_its_noise():
    """``<q>_mode`` (flights module docstring): the unit vector of θ̂'s change since early
    life once the change is well above θ̂'s standard deviation, near 0 before; HPT alone
    points along HPT, HPT with LPT between them."""
    rows = []
    for unit, lpt_share in ((1, 0.0), (2, 1.0)):
        for c in range(1, 31):
            loss = 0.0 if c <= 10 else 0.002 * (c - 10)  # onset after flight 10
            for k in range(4):
                rows.append({"unit": unit, "cycle": c, "t": float(k), "RUL": 30 - c,
                             "HPT_eff_mod_hat": -loss, "LPT_eff_mod_hat": -lpt_share * loss,
                             "LPT_flow_mod_hat": 0.0, "HPT_eff_mod_hat_std": 1e-3,
                             "LPT_eff_mod_hat_std": 1e-3, "LPT_flow_mod_hat_std": 1e-3})
    ft = flight_table(pd.DataFrame(rows), LinearHI())
    cols = ["HPT_eff_mod_mode", "LPT_eff_mod_mode", "LPT_flow_mod_mode"]
    m = ft[cols].to_numpy()
    assert np.all(np.linalg.norm(m, axis=1) <= 1.0 + 1e-12)
    early = ft.cycle <= 10
    np.testing.assert_allclose(m[early.to_numpy()], 0.0, atol=1e-12)  # no change: no mode
    last1 = ft[(ft.unit == 1)].iloc[-1][cols].to_numpy(float)
    last2 = ft[(ft.unit == 2)].iloc[-1][cols].to_numpy(float)
    np.testing.assert_allclose(last1, [-1.0, 0.0, 0.0], atol=0.01)  # |Δ| = 0.04 >> 3σ√3
    np.testing.assert_allclose(last2, [-1 / np.sqrt(2), -1 / np.sqrt(2), 0.0], atol=0.01)
    small = ft[(ft.unit == 1) & (ft.cycle == 11)][cols].to_numpy(float)[0]
    assert abs(small[0]) < 0.5  # a change of 0.002 is within 3 σ: hardly a direction yet

"""The physics-only baseline: trend fit and extrapolation by hand, no look-ahead, and (one test
with the engine model) RUL from a simulated unit's true θ trajectory."""

import math

import numpy as np
import pandas as pd
import pytest

from engine_model.channels import THETA_NAMES
from engine_model.validation import InputError
from prognostics.baseline import (
    baseline_per_cycle,
    baseline_predictions,
    fit_trend,
    rul_from_trend,
    theta_per_cycle,
    unit_rul,
)
from prognostics.cross_validation import truncate_units


def test_a_linear_health_index_is_extrapolated_exactly():
    c = np.arange(1.0, 31.0)
    hi = 1.0 - 0.02 * c  # reaches 0 at cycle 50
    a, b, lam = fit_trend(c, hi)
    assert a == pytest.approx(1.0 - 0.02 * 30) and b == pytest.approx(0.02)
    assert lam == pytest.approx(0.0, abs=1e-4)
    assert rul_from_trend(a, b, lam, 500.0) == pytest.approx(20.0, abs=1e-3)
    rul = unit_rul(c, hi, max_rul=500.0)
    assert rul[0] == 500.0  # one cycle: no trend, the prior
    np.testing.assert_allclose(rul[1:], 50.0 - c[1:], atol=1e-3)


def test_an_exponential_health_index_recovers_its_rate():
    c = np.arange(1.0, 31.0)
    hi = 1.0 - 0.1 * np.expm1(0.05 * c)  # HI = 0 at c = ln(11) / 0.05 = 47.96
    a, b, lam = fit_trend(c, hi)
    assert lam == pytest.approx(0.05, rel=1e-3)
    assert rul_from_trend(a, b, lam, 500.0) == pytest.approx(math.log(11) / 0.05 - 30, abs=0.01)


def test_rul_from_trend_edge_cases():
    assert rul_from_trend(-0.1, 0.02, 0.0, 100.0) == 0.0  # already failed
    assert rul_from_trend(0.5, 0.0, 0.0, 100.0) == 100.0  # no degradation: the cap
    assert rul_from_trend(0.5, -0.01, 0.3, 100.0) == 100.0
    assert rul_from_trend(0.9, 0.001, 0.0, 100.0) == 100.0  # 900 cycles, capped


def synthetic_hi(theta):
    """A stand-in health index: linear in the HPT efficiency (1 new, 0 at -1 %)."""
    return 1.0 + 100.0 * np.asarray(theta)[:, THETA_NAMES.index("HPT_eff_mod")]


def test_baseline_on_a_synthetic_theta_hat_trend_and_no_look_ahead(make_features):
    df, meta = make_features()
    pred = baseline_predictions(df, synthetic_hi, max_rul=60.0, units=[5, 6])
    assert len(pred) == int(df.unit.isin([5, 6]).sum())  # every sample carries its cycle's
    # at the end of life the HI reaches 0 and the prediction is 0 by construction: the claim
    # "within 5 cycles at the last cycle" is checked on units cut before it (as NASA cut its
    # test units), with ten cycles of history or more
    for seed in (0, 1, 2):
        cut = truncate_units(df, [5, 6], seed=seed, min_cycles=10)
        last = baseline_predictions(cut, synthetic_hi, max_rul=60.0).groupby("unit").tail(1)
        assert (last["RUL"] > 0).all()
        assert np.all(np.abs(last["RUL_pred"] - last["RUL"]) < 5.0), last
    # HI = 1 - h^2 of the true trend, so the end is found better as the unit ages: the late
    # half beats the early half
    pc = baseline_per_cycle(df, synthetic_hi, 60.0, units=[5])
    err = np.abs(pc.RUL_pred - pc.RUL).to_numpy()
    half = len(err) // 2
    assert err[half:].mean() < err[:half].mean()
    # no look-ahead: the unit cut at cycle 10 has the same predictions up to cycle 10
    cut = baseline_per_cycle(df[(df.unit == 5) & (df.cycle <= 10)], synthetic_hi, 60.0)
    np.testing.assert_array_equal(cut.RUL_pred.to_numpy(), pc.RUL_pred.to_numpy()[:10])


def test_theta_per_cycle_places_estimates_by_name_and_zeroes_the_rest(make_features):
    df, _ = make_features(units=(1,), test_units=())
    df.loc[df.cycle == 2, "LPT_flow_mod_hat"] = np.nan  # unobservable: nominal 0
    th = theta_per_cycle(df)
    assert list(th.columns) == ["unit", "cycle", *THETA_NAMES]
    assert (th["fan_eff_mod"] == 0).all()
    assert th.loc[th.cycle == 2, "LPT_flow_mod"].item() == 0.0
    first = df[df.cycle == 1]["HPT_eff_mod_hat"].mean()
    assert th.loc[th.cycle == 1, "HPT_eff_mod"].item() == pytest.approx(first)
    with pytest.raises(InputError, match="no theta columns"):
        theta_per_cycle(df.drop(columns=[c for c in df.columns if c.endswith("_hat")]))


@pytest.mark.parametrize("mode,seed", [("HPT", 0), ("LPT", 2)])
def test_baseline_from_a_simulated_units_true_theta(model, mode, seed):
    """With the engine model's health index and a perfect calibration (θ̂ = θ), the
    baseline's HI is the simulator's to rounding, and its RUL closes in on the truth: it is
    late (over-estimates) while the exponential onset accelerates, and within 5 cycles over
    the last 5 cycles of life."""
    from engine_model.physics.health_index import HealthIndex
    from engine_model.simulator.degradation import simulate_health

    hi = HealthIndex(model)
    tr = simulate_health(model, mode, (60, 60), (25, 25), np.random.default_rng(seed),
                         hi_fn=hi)
    n = tr.eol
    df = pd.DataFrame({"unit": 1, "cycle": np.arange(1, n + 1), "RUL": n - np.arange(1, n + 1.0)})
    for j, q in enumerate(THETA_NAMES):
        df[q + "_hat"] = tr.theta[:, j]
    pc = baseline_per_cycle(df, hi, max_rul=100.0)
    np.testing.assert_allclose(pc.HI.to_numpy(), tr.hi, atol=1e-9)
    err = (pc.RUL_pred - pc.RUL).to_numpy()
    assert np.all(np.abs(err[-5:]) <= 5.0), err[-5:]
    assert np.all(err[-20:] > 0)  # late: the trend under-rates the acceleration
    assert np.all(np.diff(err[-20:]) < 0)  # and closes in cycle by cycle

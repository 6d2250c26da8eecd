"""Prognostics metrics against hand-computed values, and split-conformal coverage.

Convention under test (prognostics.metrics): Δ = true - predicted; early (Δ > 0) costs
exp(Δ/13) - 1, late (Δ < 0) exp(|Δ|/10) - 1.
"""

import math

import numpy as np
import pandas as pd
import pytest

from engine_model.validation import InputError
from prognostics.conformal import SplitConformal, conformal_quantile, conformal_rank
from prognostics.metrics import (
    coverage,
    evaluate_predictions,
    mean_width,
    nasa_score,
    per_cycle,
    prediction_horizon,
    rmse,
)


def test_rmse_by_hand():
    assert rmse([10, 20, 30], [12, 17, 30]) == pytest.approx(math.sqrt((4 + 9 + 0) / 3))
    assert rmse([5.0], [5.0]) == 0.0


def test_nasa_score_by_hand_and_its_asymmetry():
    # Δ = +10 (predicted 10 cycles too few: early) and Δ = -10 (too many: late)
    early = nasa_score([50.0], [40.0])
    late = nasa_score([50.0], [60.0])
    assert early == pytest.approx(math.exp(10 / 13) - 1)  # 1.15811
    assert late == pytest.approx(math.e - 1)  # 1.7183
    assert late > early
    assert early == pytest.approx(1.15811, abs=1e-5)
    # sums over samples; perfect predictions cost 0
    y, p = [100, 50, 20, 7], [90, 53, 20, 0]
    by_hand = (math.exp(10 / 13) - 1) + (math.exp(3 / 10) - 1) + 0 + (math.exp(7 / 13) - 1)
    assert nasa_score(y, p) == pytest.approx(by_hand)
    assert nasa_score([3, 4], [3, 4]) == 0.0
    # the late side grows faster for every |Δ| > 0
    d = np.arange(1.0, 60.0)
    assert np.all([nasa_score([0.0], [x]) > nasa_score([x], [0.0]) for x in d])


def test_coverage_and_width():
    y = np.array([1.0, 2.0, 3.0, 4.0])
    lo = np.array([0.0, 2.5, 3.0, 3.0])
    hi = np.array([2.0, 3.0, 3.0, 3.5])
    assert coverage(y, lo, hi) == pytest.approx(0.5)  # 1 in, 2 below, 3 on both edges, 4 out
    assert mean_width(lo, hi) == pytest.approx((2 + 0.5 + 0 + 0.5) / 4)


def test_prediction_horizon_by_hand():
    cycles = np.arange(1, 11)
    true = 20.0 - cycles  # failure at cycle 20 (a truncated unit: 10 cycles observed)
    pred = true.copy()
    pred[[0, 1, 4]] += [12.0, -8.0, 6.0]  # off by more than 5 at cycles 1, 2 and 5
    # within 5 for every cycle from 6 on: t_EOL - t = (10 + 10) - 6
    assert prediction_horizon(cycles, true, pred) == pytest.approx(14.0)
    pred[4] = true[4] + 5.0  # exactly 5 is within
    assert prediction_horizon(cycles, true, pred) == pytest.approx(20.0 - 3.0)
    pred[-1] = true[-1] - 5.5  # last cycle off by more than 5: no horizon
    assert prediction_horizon(cycles, true, pred) == 0.0
    # always within: the horizon is the whole observed life
    assert prediction_horizon(cycles, true, true) == pytest.approx(20.0 - 1.0)


def prediction_frame():
    """Two units; unit 1 has 3 samples per cycle, unit 2 two."""
    rows = []
    for c, p in zip([1, 2, 3], [(10, 12, 14), (9, 9, 9), (6, 8, 7)], strict=True):
        rows += [(1, c, 10.0 - c, v) for v in p]
    for c, p in zip([1, 2], [(30, 20), (4, 6)], strict=True):
        rows += [(2, c, 6.0 - c, v) for v in p]
    return pd.DataFrame(rows, columns=["unit", "cycle", "RUL", "RUL_pred"])


def test_per_cycle_mean_and_band():
    pc = per_cycle(prediction_frame())
    assert pc[["unit", "cycle"]].to_numpy().tolist() == [[1, 1], [1, 2], [1, 3], [2, 1], [2, 2]]
    assert pc["mean"].tolist() == pytest.approx([12, 9, 7, 25, 5])
    assert pc["min"].tolist() == [10, 9, 6, 20, 4]
    assert pc["max"].tolist() == [14, 9, 8, 30, 6]
    assert pc["n"].tolist() == [3, 3, 3, 2, 2]
    assert pc["RUL"].tolist() == [9, 8, 7, 5, 4]


def test_both_protocols_per_unit_and_overall():
    pred = prediction_frame()
    m = evaluate_predictions(pred)
    s = m["samples"]
    assert s["overall"]["n"] == 13
    assert s["overall"]["rmse"] == pytest.approx(rmse(pred["RUL"], pred["RUL_pred"]))
    assert s["units"][2]["score"] == pytest.approx(nasa_score([5, 5, 4, 4], [30, 20, 4, 6]))
    last = m["last"]
    # last protocol: the per-cycle mean at the last cycle: unit 1 cycle 3 (7 vs 7), unit 2
    # cycle 2 (5 vs 4: Δ = -1, late)
    assert last["units"][1] == {"cycle": 3, "RUL": 7.0, "RUL_pred": 7.0, "delta": 0.0}
    assert last["units"][2]["delta"] == pytest.approx(-1.0)
    assert last["overall"]["rmse"] == pytest.approx(math.sqrt(0.5))
    assert last["overall"]["score"] == pytest.approx(math.exp(0.1) - 1)
    # horizon on the per-cycle mean: unit 1 within 5 at every cycle -> (3 + 7) - 1 = 9;
    # unit 2 off by 20 at cycle 1, within at cycle 2 -> (2 + 4) - 2 = 4
    assert m["horizon"]["units"] == {1: pytest.approx(9.0), 2: pytest.approx(4.0)}
    assert m["horizon"]["mean"] == pytest.approx(6.5)


def test_interval_metrics_in_both_protocols():
    pred = prediction_frame()
    pred["RUL_lower"] = pred["RUL_pred"] - 2.0
    pred["RUL_upper"] = pred["RUL_pred"] + 2.0
    m = evaluate_predictions(pred)
    inside = (pred["RUL_lower"] <= pred["RUL"]) & (pred["RUL"] <= pred["RUL_upper"])
    assert m["samples"]["overall"]["coverage"] == pytest.approx(inside.mean())
    assert m["samples"]["overall"]["width"] == pytest.approx(4.0)
    assert m["last"]["overall"]["coverage"] == 1.0


def test_evaluate_refuses_a_frame_without_truth():
    with pytest.raises(InputError, match="RUL"):
        evaluate_predictions(prediction_frame().drop(columns="RUL"))


# ---------------------------------------------------------------------------------------------
# split conformal
# ---------------------------------------------------------------------------------------------

def test_conformal_rank_and_quantile():
    assert conformal_rank(99, 0.1) == 90  # ceil(100 * 0.9), no rounding up of an exact 90
    assert conformal_rank(9, 0.1) == 9
    assert conformal_rank(5, 0.1) == 6  # > n: the interval is infinite
    scores = np.arange(1.0, 100.0)[::-1]  # 99 scores 1..99 in any order
    assert conformal_quantile(scores, 0.1) == 90.0
    assert conformal_quantile([1.0, 2.0], 0.1) == math.inf
    with pytest.raises(InputError, match="no calibration scores"):
        conformal_quantile([], 0.1)
    with pytest.raises(InputError, match=r"alpha must lie in \(0, 1\), got 1.5"):
        conformal_rank(10, 1.5)


@pytest.mark.parametrize("alpha", [0.1, 0.2])
def test_split_conformal_coverage_on_exchangeable_data_is_nominal(alpha):
    """Exchangeable calibration and test pairs, a deliberately poor predictor and skewed,
    heteroscedastic noise: the coverage averaged over trials equals
    k / (n + 1) = ceil((n+1)(1-α)) / (n+1) (>= 1 - α) within its sampling error."""
    rng = np.random.default_rng(7)
    trials, n_cal, n_test = 400, 99, 100
    expected = conformal_rank(n_cal, alpha) / (n_cal + 1)
    covered = np.empty(trials)
    widths = np.empty(trials)
    for i in range(trials):
        x = rng.uniform(0, 10, n_cal + n_test)
        y = 3.0 * x + (1 + x) * rng.exponential(1.0, x.size)  # skewed, heteroscedastic
        y_hat = 2.5 * x + 1.0  # a biased predictor: conformal does not need a good one
        conf = SplitConformal.calibrate(y[:n_cal], y_hat[:n_cal], alpha)
        lo, hi = conf.interval(y_hat[n_cal:])
        covered[i] = coverage(y[n_cal:], lo, hi)
        widths[i] = mean_width(lo, hi)
    # per-trial coverage: Beta(k, n + 1 - k) plus binomial noise of n_test points
    k = conformal_rank(n_cal, alpha)
    var_beta = k * (n_cal + 1 - k) / ((n_cal + 1) ** 2 * (n_cal + 2))
    var = var_beta + expected * (1 - expected) / n_test
    sem = math.sqrt(var / trials)
    assert abs(covered.mean() - expected) < 4 * sem, (covered.mean(), expected, sem)
    assert covered.mean() >= 1 - alpha - 4 * sem
    assert np.all(widths > 0)


def test_conformal_interval_is_clipped_at_zero_and_round_trips():
    conf = SplitConformal.calibrate([10.0, 12.0, 14.0], [11.0, 11.0, 11.0], 0.25, units=[4])
    lo, hi = conf.interval([1.0, 20.0])
    assert lo.tolist() == [0.0, 20.0 - conf.quantile]
    assert hi.tolist() == [1.0 + conf.quantile, 20.0 + conf.quantile]
    assert SplitConformal.from_dict(conf.to_dict()) == conf
    inf = SplitConformal.calibrate([1.0], [0.0], 0.1)
    assert SplitConformal.from_dict(inf.to_dict()).quantile == math.inf


def test_alpha_lambda_and_relative_accuracy_by_hand():
    """One unit observed at cycles 1..11, failing at 11 (t_P = 1, t_EOL = 11): the λ-points
    0.25, 0.5, 0.75 are cycles 3.5 -> 4, 6 and 8.5 -> 9 (the first predicted cycle at or
    after each)."""
    from prognostics.metrics import lambda_accuracy

    c = np.arange(1, 12)
    y = 11.0 - c
    m = y.copy()
    m[c == 4] = y[c == 4] * 1.1  # inside ±20 %
    m[c == 6] = y[c == 6] * 1.5  # outside
    m[c == 9] = 0.0              # outside, RA = 0
    pc = pd.DataFrame({"unit": 1, "cycle": c, "RUL": y, "mean": m})
    r = lambda_accuracy(pc)
    u = r["units"][1]
    assert [u[k]["cycle"] for k in ("0.25", "0.5", "0.75")] == [4, 6, 9]
    assert [u[k]["within"] for k in ("0.25", "0.5", "0.75")] == [True, False, False]
    assert u["0.25"]["relative_accuracy"] == pytest.approx(0.9)
    assert u["0.5"]["relative_accuracy"] == pytest.approx(0.5)
    assert u["0.75"]["relative_accuracy"] == pytest.approx(0.0)
    assert r["fraction_within"] == {"0.25": 1.0, "0.5": 0.0, "0.75": 0.0}


def test_a_lambda_point_after_the_last_observed_cycle_is_not_observed():
    from prognostics.metrics import lambda_accuracy

    # truncated at cycle 5 with 20 cycles left: t_EOL = 25, λ = 0.5 -> cycle 13, unseen
    pc = pd.DataFrame({"unit": 7, "cycle": np.arange(1, 6), "RUL": 24.0 - np.arange(5),
                       "mean": 24.0 - np.arange(5)})
    r = lambda_accuracy(pc)
    assert r["units"][7]["0.5"] is None and r["units"][7]["0.75"] is None
    assert np.isnan(r["fraction_within"]["0.5"])


def test_error_by_rul_bins():
    from prognostics.metrics import error_by_rul, rul_bin_width

    assert [rul_bin_width(m) for m in (5, 9, 40, 125, 200, 1000)] == [1, 2, 10, 20, 50, 200]
    y = np.arange(0.0, 100.0)
    pred = pd.DataFrame({"RUL": y, "RUL_pred": y - np.where(y < 50, 1.0, -2.0)})
    bins = error_by_rul(pred)
    assert [(b["lo"], b["hi"]) for b in bins] == [(k * 20.0, (k + 1) * 20.0) for k in range(5)]
    assert [b["n"] for b in bins] == [20] * 5
    assert bins[0]["median"] == 1.0 and bins[-1]["median"] == -2.0

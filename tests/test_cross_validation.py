"""The C-MAPSS protocol on training units (prognostics.cross_validation): folds of whole units,
held-out units cut at a seeded uniform cycle, one score per unit at its last observed cycle
with the prediction capped like the targets."""

import numpy as np
import pandas as pd
import pytest

from engine_model.validation import InputError
from prognostics.cross_validation import last_cycle_scores, truncate_units, unit_folds


def test_folds_hold_each_whole_unit_out_once_in_near_equal_folds():
    units = list(range(1, 24))
    folds = unit_folds(units, 5, seed=3)
    held = [u for f in folds for u in f.held_out]
    assert sorted(held) == units  # each unit once
    assert {len(f.held_out) for f in folds} <= {4, 5}
    for f in folds:
        assert not set(f.train) & set(f.held_out)
        assert sorted(f.train + f.held_out) == units
    assert unit_folds(units, 5, seed=3) == folds  # the seed fixes them
    assert unit_folds(units, 5, seed=4) != folds


@pytest.mark.parametrize("k", [1, 24])
def test_impossible_fold_counts_are_errors(k):
    with pytest.raises(InputError, match=f"{k} folds of 23 units"):
        unit_folds(range(1, 24), k, seed=0)


def _fleet(eols=(40, 55, 31, 80), start=1):
    rows = [(u, c, eol - c) for u, eol in enumerate(eols, 1)
            for c in range(start, eol + 1)]
    return pd.DataFrame(rows, columns=["unit", "cycle", "RUL"])


def test_truncation_cuts_each_unit_at_a_seeded_cycle_and_keeps_its_true_rul():
    df = _fleet()
    cut = truncate_units(df, [1, 2, 4], seed=7, min_cycles=30)
    assert sorted(cut["unit"].unique()) == [1, 2, 4]
    for u, g in cut.groupby("unit"):
        full = df[df.unit == u]
        last = g["cycle"].max()
        assert 30 <= last <= full["cycle"].max()
        assert g["cycle"].tolist() == list(range(1, last + 1))  # a prefix of the unit
        assert g["RUL"].tolist() == full["RUL"].tolist()[:last]  # true cycles to failure
    pd.testing.assert_frame_equal(cut, truncate_units(df, [1, 2, 4], seed=7, min_cycles=30))
    # a unit's cut depends on the seed and the unit only, not on the other units asked for
    alone = truncate_units(df, [2], seed=7, min_cycles=30)
    assert alone["cycle"].max() == cut[cut.unit == 2]["cycle"].max()
    # a unit shorter than min_cycles is kept whole
    short = truncate_units(_fleet(eols=(12,)), [1], seed=0, min_cycles=30)
    assert short["cycle"].max() == 12


def test_truncation_is_uniform_over_the_allowed_cycles():
    """Over many seeds the RUL at the cut of a 100-cycle unit (min 21 cycles) is uniform on
    0..79: mean 39.5 and every value drawn (each missed with probability 1e-11)."""
    df = _fleet(eols=(100,))
    rul = [int(truncate_units(df, [1], seed=s, min_cycles=21)["RUL"].iloc[-1])
           for s in range(2000)]
    assert min(rul) == 0 and max(rul) == 79 and len(set(rul)) == 80
    # std of the mean of 2000 draws of U{0..79}: 23.1 / sqrt(2000) = 0.52
    assert np.mean(rul) == pytest.approx(39.5, abs=4 * 0.52)


def test_truncation_errors_name_what_is_wrong():
    with pytest.raises(InputError, match=r"unit\(s\) \[9\] not in the table"):
        truncate_units(_fleet(), [1, 9], seed=0)
    with pytest.raises(InputError, match="min_cycles must be >= 1"):
        truncate_units(_fleet(), [1], seed=0, min_cycles=0)


def test_last_cycle_scores_use_the_last_cycle_capped_like_the_targets():
    pred = pd.DataFrame({
        "unit": [1, 1, 1, 2, 2, 3],
        "cycle": [5, 6, 6, 9, 9, 4],
        "RUL": [11, 10, 10, 140, 140, 3],
        "RUL_pred": [30, 14, 16, 150, 170, -2],  # unit 1 last cycle mean 15
    })
    s = last_cycle_scores(pred, max_rul=125)
    assert s["units"][1] == {"cycle": 6, "RUL": 10.0, "RUL_pred": 15.0, "delta": -5.0}
    assert s["units"][2]["RUL_pred"] == 125.0  # 160 capped at the target's 125
    assert s["units"][3]["RUL_pred"] == 0.0  # no negative RUL
    delta = np.array([10 - 15, 140 - 125, 3 - 0], float)
    assert s["n"] == 3
    assert s["rmse"] == pytest.approx(np.sqrt(np.mean(delta ** 2)))
    late, early = np.exp(5 / 10) - 1, np.exp(15 / 13) - 1 + np.exp(3 / 13) - 1
    assert s["score"] == pytest.approx(late + early)
    assert last_cycle_scores(pred)["units"][2]["RUL_pred"] == 160.0  # no cap given

"""Issue 30: the similarity predictor on the health index (prognostics.similarity)."""

from __future__ import annotations

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

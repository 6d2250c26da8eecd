"""The experiment's table transformations: ablation IV's degraded θ̂ (noise at a given SNR,
bias toward the first cycle) and ablation III's perfect calibration (x̂ and θ at their true
values, from the engine model)."""

import numpy as np
import pandas as pd
import pytest

from engine_model import THETA_NAMES
from engine_model.channels import XS_NAMES, XV_NAMES
from engine_model.validation import InputError
from workflows.paper.experiment import perfect_calibration, perturb_theta

from .conftest import synthetic_features


@pytest.fixture(scope="module")
def table():
    df, _ = synthetic_features(units=(1, 2), test_units=(2,), cycles=(6, 8), samples=(3, 4))
    return df


def test_noise_has_the_signal_to_noise_ratio_and_the_seed(table):
    big = pd.concat([table] * 200, ignore_index=True)
    hats = [q + "_hat" for q in THETA_NAMES if q + "_hat" in big.columns]
    out = perturb_theta(big, "snr15", seed=3)
    for c in hats:
        v = big[c].to_numpy()
        n = out[c].to_numpy() - v
        snr = 10 * np.log10(np.mean(v * v) / np.mean(n * n))
        assert snr == pytest.approx(15.0, abs=0.3)
    assert out.equals(perturb_theta(big, "snr15", seed=3))
    assert not out.equals(perturb_theta(big, "snr15", seed=4))
    assert out.drop(columns=hats).equals(big.drop(columns=hats))  # nothing else moves


def test_bias_pulls_theta_hat_toward_its_first_cycle(table):
    q = next(q + "_hat" for q in THETA_NAMES if q + "_hat" in table.columns)
    out = perturb_theta(table, "bias+0.5", seed=0)
    for _, g in table.groupby("unit"):
        t0 = g.loc[g.cycle == g.cycle.min(), q].mean()
        np.testing.assert_allclose(out.loc[g.index, q], g[q] + 0.5 * (t0 - g[q]), rtol=1e-12)


def test_perfect_calibration_is_the_engine_model_at_the_true_theta(table):
    """Every x̂ column becomes the engine model's output at the row's operating point and
    true θ (all ten), every θ̂ the true θ; nothing else changes."""
    from engine_model.runtime.shared_model import default_model

    rows = table.iloc[:12].reset_index(drop=True)
    out = perfect_calibration(rows)
    ev = default_model().evaluate(rows[["alt", "Mach", "TRA", "T2"]].to_numpy(),
                                  rows[list(THETA_NAMES)].to_numpy())
    for c in (*XS_NAMES, *XV_NAMES):
        np.testing.assert_allclose(out[c + "_hat"], ev[c], rtol=1e-12)
    hats = [q for q in THETA_NAMES if q + "_hat" in rows.columns]
    assert hats
    for q in hats:
        np.testing.assert_array_equal(out[q + "_hat"], rows[q])
    changed = [c + "_hat" for c in (*XS_NAMES, *XV_NAMES)] + [q + "_hat" for q in hats]
    assert out.drop(columns=changed).equals(rows.drop(columns=changed))


def test_perfect_calibration_needs_the_true_theta_and_a_converged_model(table):
    with pytest.raises(InputError, match="true theta column"):
        perfect_calibration(table.drop(columns=[THETA_NAMES[0]]))

    def not_converged(w, theta):
        ev = pd.DataFrame({c: np.zeros(len(w)) for c in (*XS_NAMES, *XV_NAMES)})
        ev["converged"] = np.arange(len(w)) > 0
        return ev

    with pytest.raises(InputError, match="does not converge at 1 of"):
        perfect_calibration(table, not_converged)

"""The adaptation benchmark's FD001 fault signature (``benchmarks/adaptation.py``): how far the
HPC parameters move against the others, and its bootstrap interval over units."""

import numpy as np
import pandas as pd
import pytest

from .conftest import REPO, load_script

COLUMNS = ["fan_eff_mod", "HPC_eff_mod", "HPC_flow_mod", "HPT_eff_mod", "LPT_eff_mod"]


@pytest.fixture(scope="module")
def bench():
    return load_script(REPO / "benchmarks" / "adaptation.py", "adaptation_benchmark")


def test_signature_is_the_smaller_hpc_median_over_the_largest_other(bench):
    change = pd.DataFrame([[-0.2, -0.6, -1.0, 0.1, 0.0],
                           [-0.3, -0.5, -0.9, -0.25, 0.05],
                           [0.4, -0.7, -1.1, -0.3, -0.1]], columns=COLUMNS)
    # medians: fan -0.2, HPC eff -0.6, HPC flow -1.0, HPT -0.25, LPT 0.0
    assert bench.hpc_signature(change) == pytest.approx(0.6 / 0.25)


def test_signature_interval_is_seeded_and_brackets_a_clear_signature(bench):
    rng = np.random.default_rng(1)
    n = 60
    change = pd.DataFrame({"fan_eff_mod": rng.normal(-0.2, 0.1, n),
                           "HPC_eff_mod": rng.normal(-0.6, 0.1, n),
                           "HPC_flow_mod": rng.normal(-0.9, 0.1, n),
                           "HPT_eff_mod": rng.normal(-0.2, 0.1, n),
                           "LPT_eff_mod": rng.normal(0.0, 0.1, n)})
    lo, hi = bench.signature_interval(change, n=400, seed=3)
    assert (lo, hi) == bench.signature_interval(change, n=400, seed=3)
    assert lo < bench.hpc_signature(change) < hi
    assert lo > 1.5 and hi < 6.0


def test_each_held_out_error_is_divided_by_its_own_std(bench):
    """A record read back from JSON keys its conditions by strings; the std recorded beside
    it (or recomputed) may use ints: each error is divided by the std of its own condition
    and channel."""
    err = {"1": {"T30": 0.5, "P30": -1.0}, "4": {"T30": 2.0, "P30": 3.0}}
    rec = {"channels": ["T30", "P30"],
           "selection": {"mean_error_pct_condition_out": {"before": err, "after": err}}}
    std = {"before": {1: {"T30": 0.1, "P30": 0.5}, 4: {"T30": 1.0, "P30": 2.0}},
           "after": {1: {"T30": 0.25, "P30": 0.25}, 4: {"T30": 4.0, "P30": 1.5}}}
    text = bench.z_tables(rec, std, "a test")
    assert "| condition 1 | 5.0 | -2.0 |" in text and "| condition 4 | 2.0 | 1.5 |" in text
    assert "| condition 1 | 2.0 | -4.0 |" in text and "| condition 4 | 0.5 | 2.0 |" in text
    assert "| condition 4 | 4.000 | 1.500 |" in text

"""The tests for structure left in the final residual (calibration.discrepancy.unknown), on
synthetic whitened residuals: no model run."""

from types import SimpleNamespace

import numpy as np
import pandas as pd

from calibration.discrepancy.unknown import structure

FLIGHTS, PER_FLIGHT = 10, 300


def _unit(rng):
    n = FLIGHTS * PER_FLIGHT
    cyc = np.repeat(np.arange(FLIGHTS), PER_FLIGHT)
    s = np.tile(np.linspace(0.0, 1.0, PER_FLIGHT), FLIGHTS)
    w = np.column_stack([3e4 * np.sin(np.pi * s), 0.3 + 0.5 * np.sin(np.pi * s),
                         60 + 30 * np.cos(2 * np.pi * s), 480 + rng.normal(0, 5, n)])
    ud = SimpleNamespace(series=SimpleNamespace(w=w), cyc=cyc, cycle=cyc + 1.0,
                         frame=pd.DataFrame({"t": np.tile(np.arange(PER_FLIGHT) * 10.0,
                                                          FLIGHTS)}))
    return ud, np.ones(n, bool), s


def test_white_noise_a_little_above_the_documented_level_is_not_structure():
    """A white residual 5 % above the documented std: noise, where the noise check estimated
    the level (it accepts 10 %); flagged by the size test only where it could not."""
    rng = np.random.default_rng(3)
    ud, ok, _ = _unit(rng)
    e = rng.standard_normal((len(ok), 2)) * np.array([1.05, 1.0])
    checked = structure([e], [(ud, ok)], ("A", "B"), 0.01, 0, [True, True])
    assert checked["structure"] == []
    assert checked["channels"]["A"]["p_chi2"] is None
    unchecked = structure([e], [(ud, ok)], ("A", "B"), 0.01, 0)
    assert unchecked["structure"] == ["A"]
    assert unchecked["channels"]["A"]["p_chi2"] < 0.01 / 8


def test_a_smooth_error_within_flights_is_structure_without_the_size_test():
    """An error that follows the flight (amplitude 0.5 noise std) is caught by the lag-1 and
    operating-point tests when the size test is off, and the hint names what it follows."""
    rng = np.random.default_rng(4)
    ud, ok, s = _unit(rng)
    e = rng.standard_normal((len(ok), 2))
    e[:, 1] += 0.5 * np.cos(2 * np.pi * s)  # follows TRA
    out = structure([e], [(ud, ok)], ("A", "B"), 0.01, 0, [True, True])
    assert out["structure"] == ["B"]
    ch = out["channels"]["B"]
    assert ch["p_white"] < 1e-6 and ch["p_operating"] < 1e-6
    assert out["hint"]["B"]["terms"][0] == "TRA"


def test_the_block_structured_normal_matrix_solves_like_the_dense_one():
    """``NormalMatrix.solve`` (with some coordinates held) and ``schur`` against dense
    algebra on a random bordered block-diagonal matrix."""
    from calibration.discrepancy.normal_matrix import NormalMatrix

    rng = np.random.default_rng(0)
    blocks, borders, offs = [], [], [0]
    for n in (6, 9, 3):
        a = rng.normal(size=(n, n))
        blocks.append(a @ a.T + n * np.eye(n))
        borders.append(rng.normal(size=(n, 5)))
        offs.append(offs[-1] + n)
    d = rng.normal(size=(5, 5))
    H = NormalMatrix(blocks, borders, d @ d.T + 40 * np.eye(5), np.array(offs))
    nt, free = H.n_theta, np.array([0, 2, 3])
    sel = np.r_[np.arange(nt), nt + free]
    Hs = H.dense()[np.ix_(sel, sel)]
    r = rng.normal(size=len(sel))
    np.testing.assert_allclose(H.solve(free, r), np.linalg.solve(Hs, r), atol=1e-10)
    held = np.zeros(len(sel), bool)
    held[[1, 5, nt + 1]] = True
    x = H.solve(free, np.where(held, 0.3, r), held)
    keep = ~held
    rhs = r[keep] - Hs[np.ix_(keep, held)] @ np.full(3, 0.3)
    ref = np.linalg.solve(Hs[np.ix_(keep, keep)], rhs)
    np.testing.assert_allclose(x[keep], ref, atol=1e-10)
    np.testing.assert_allclose(x[held], 0.3)
    np.testing.assert_allclose(np.linalg.inv(H.schur(free)), np.linalg.inv(Hs)[nt:, nt:],
                               atol=1e-12)

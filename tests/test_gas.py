"""Real-gas properties (engine_model.physics.gas): known values, integrals, inversions."""

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

from engine_model.physics import gas

TEMPS = np.linspace(200.0, 2000.0, 37)  # the validity range of Walsh & Fletcher F3.23
FARS = (0.0, 0.02, 0.05)


def test_cp_air_300K_matches_table():
    # Cengel & Boles, Thermodynamics, Table A-2(b), ideal-gas specific heats of air:
    # cp = 1.005 kJ/(kg K), k = 1.400 at 300 K
    assert float(gas.cp(300.0)) == pytest.approx(1005.0, rel=5e-3)
    # same table at 1000 K: cp = 1.142 kJ/(kg K), k = 1.336
    assert float(gas.cp(1000.0)) == pytest.approx(1142.0, rel=5e-3)


def test_gamma_air_and_combustion_products():
    g300 = float(gas.gamma(300.0))
    assert g300 == pytest.approx(1.400, rel=2e-3)
    assert float(gas.gamma(1000.0)) == pytest.approx(1.336, rel=2e-3)
    g1500_air = float(gas.gamma(1500.0, 0.0))
    g1500_prod = float(gas.gamma(1500.0, 0.02))
    # gamma falls with temperature (vibrational modes) and with CO2/H2O in the products
    assert g1500_prod < g1500_air < g300
    assert 1.28 < g1500_prod < 1.32
    # cp of products exceeds cp of air at every temperature
    assert np.all(np.asarray(gas.cp(TEMPS, 0.02)) > np.asarray(gas.cp(TEMPS, 0.0)))


@pytest.mark.parametrize("far", FARS)
def test_enthalpy_is_integral_of_cp(far):
    for T in TEMPS:
        ref, _ = quad(lambda t: float(gas.cp(t, far)), gas.T_REF, T, epsabs=0.0, epsrel=1e-13)
        h = float(gas.h(T, far))
        assert abs(h - ref) <= 1e-10 * max(abs(ref), 1.0e3), (T, far, h, ref)
    assert float(gas.h(gas.T_REF, far)) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("far", FARS)
def test_entropy_function_is_integral_of_cp_over_T(far):
    for T in TEMPS:
        ref, _ = quad(lambda t: float(gas.cp(t, far)) / t, gas.T_REF, T, epsabs=0.0,
                      epsrel=1e-13)
        s = float(gas.phi(T, far))
        assert abs(s - ref) <= 1e-10 * max(abs(ref), 1.0), (T, far, s, ref)


@pytest.mark.parametrize("far", FARS)
def test_t_from_h_inverts_enthalpy(far):
    # starting guesses as the callers make them: a first-order step cp(T0) from a nearby
    # known state T0 (compressors heat by up to x2.5, turbines and nozzles cool by ~x0.6)
    for T in TEMPS:
        target = float(gas.h(T, far))
        for ratio in (0.4, 0.6, 0.8, 1.0, 1.25, 1.7, 2.5):
            T0 = T / ratio
            if not 200.0 <= T0 <= 2000.0:
                continue
            guess = T0 + (target - float(gas.h(T0, far))) / float(gas.cp(T0, far))
            T_back = float(gas.t_from_h(target, far, guess))
            assert abs(T_back / T - 1.0) < 1e-10, (T, T0, far, T_back)


@pytest.mark.parametrize("far", FARS)
def test_t_from_phi_and_t_isentropic_invert(far):
    for T_in in TEMPS:
        for pr in (1.0 / 30.0, 0.1, 0.3, 0.7, 1.0, 1.5, 3.0, 10.0, 30.0):
            target = float(gas.phi(T_in, far)) + gas.R_GAS * np.log(pr)

            def f(t, target=target):
                return float(gas.phi(t, far)) - target

            lo, hi = 150.0, 2600.0
            if f(lo) > 0 or f(hi) < 0:
                continue
            T_exact = brentq(f, lo, hi, xtol=1e-14, rtol=1e-15)
            if not 200.0 <= T_exact <= 2000.0:
                continue
            T_out = float(gas.t_isentropic(T_in, far, pr))
            assert abs(T_out / T_exact - 1.0) < 1e-10, (T_in, pr, far, T_out, T_exact)
            # and back: the pressure ratio of that isentropic process
            pr_back = float(gas.pressure_ratio_isentropic(T_in, T_out, far))
            assert abs(pr_back / pr - 1.0) < 1e-10, (T_in, pr, far, pr_back)

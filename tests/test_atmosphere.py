"""ISA atmosphere and free-stream total conditions (engine_model.physics.atmosphere)."""

import casadi as ca
import numpy as np
import pytest

from engine_model.physics import atmosphere
from engine_model.units import FT_TO_M

TROPOPAUSE_FT = 11000.0 / FT_TO_M  # 36,089.24 ft


@pytest.mark.parametrize(
    "alt_ft, p_pa, t_k",
    [
        # ISO 2533 / ICAO Doc 7488 standard-atmosphere table values
        (0.0, 101325.0, 288.15),
        (5000.0 / FT_TO_M, 54019.9, 255.65),
        (TROPOPAUSE_FT, 22632.1, 216.65),  # 11 km
        (36089.0, 22632.1, 216.65),  # 36,089 ft, the tropopause in round feet
        (20000.0 / FT_TO_M, 5474.89, 216.65),  # 20 km, top of the isothermal layer
    ],
)
def test_isa_table_values(alt_ft, p_pa, t_k):
    assert float(atmosphere.isa_pressure(alt_ft)) == pytest.approx(p_pa, rel=2e-5)
    assert float(atmosphere.isa_temperature(alt_ft)) == pytest.approx(t_k, abs=1e-3)


def test_pressure_continuous_and_smooth_across_tropopause():
    eps = 1e-6  # ft
    below = float(atmosphere.isa_pressure(TROPOPAUSE_FT - eps))
    above = float(atmosphere.isa_pressure(TROPOPAUSE_FT + eps))
    assert abs(above / below - 1.0) < 1e-9
    # hydrostatic slope dP/dz = -rho g is continuous (T is), so the two laws meet C1
    a = ca.SX.sym("alt")
    dpdalt = ca.Function("dp", [a], [ca.jacobian(atmosphere.isa_pressure(a), a)])
    s_below = float(dpdalt(TROPOPAUSE_FT - 1e-3))
    s_above = float(dpdalt(TROPOPAUSE_FT + 1e-3))
    assert s_below < 0.0
    assert abs(s_above / s_below - 1.0) < 1e-6
    # and the slope is the hydrostatic one: dP/dz = -P g / (R T)
    p = float(atmosphere.isa_pressure(TROPOPAUSE_FT))
    hydro = -p * atmosphere.G0 / (atmosphere.R_ISA * 216.65) * FT_TO_M
    assert s_above == pytest.approx(hydro, rel=1e-6)


def test_pressure_decreases_monotonically():
    alts = np.linspace(-1500.0, 45000.0, 200)
    p = np.array([float(atmosphere.isa_pressure(a)) for a in alts])
    assert np.all(np.diff(p) < 0.0)


def test_t2_cruise_matches_cmapss():
    # 35,000 ft, Mach 0.84, ISA: perfect-gas estimate 218.81 K * (1 + 0.2 * 0.84^2) =
    # 449.43 degR; C-MAPSS FD002 lists T2 = 449.44 degR for this condition
    t2_R = float(atmosphere.t2_from_flight(35000.0, 0.84, 0.0)) * 1.8
    assert t2_R == pytest.approx(449.6, abs=0.1)
    assert t2_R == pytest.approx(449.44, rel=1e-3)
    # static case: total equals static temperature; a day offset adds one-for-one at M 0
    assert float(atmosphere.t2_from_flight(0.0, 0.0)) == pytest.approx(288.15, abs=1e-9)
    assert float(atmosphere.t2_from_flight(0.0, 0.0, 15.0)) == pytest.approx(303.15, abs=1e-9)


def test_static_temperature_inverts_total_temperature():
    for Ts in np.linspace(200.0, 330.0, 14):
        for mach in np.linspace(0.0, 0.9, 10):
            Tt = float(atmosphere.total_temperature(Ts, mach))
            assert Tt >= Ts
            back = float(atmosphere.static_temperature(Tt, mach))
            assert abs(back / Ts - 1.0) < 1e-10, (Ts, mach, back)


def test_total_temperature_energy_equation():
    # h(Tt) - h(Ts) = V^2 / 2 with V the true airspeed
    from engine_model.physics import gas

    for Ts, mach in ((288.15, 0.3), (218.81, 0.84), (216.65, 0.6)):
        Tt = float(atmosphere.total_temperature(Ts, mach))
        V = float(atmosphere.flight_speed(Ts, mach))
        assert float(gas.h(Tt) - gas.h(Ts)) == pytest.approx(0.5 * V**2, rel=1e-10)


def test_mach_from_cas():
    # at sea level ISA, CAS = TAS, so M = CAS / a0
    cas = 350.0 * 0.514444
    a0 = (1.4 * atmosphere.R_ISA * 288.15) ** 0.5
    assert float(atmosphere.mach_from_cas(cas, 0.0)) == pytest.approx(cas / a0, rel=1e-9)
    # 350 kt CAS at 30,000 ft is about Mach 0.91 (standard airspeed tables)
    assert float(atmosphere.mach_from_cas(cas, 30000.0)) == pytest.approx(0.909, abs=0.005)

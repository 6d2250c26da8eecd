"""International Standard Atmosphere and free-stream total conditions.

ISA per ISO 2533:1975 / ICAO Doc 7488: troposphere lapse rate 6.5 K/km to the tropopause at
11,000 m (36,089 ft), isothermal 216.65 K above, to 20,000 m. Ambient pressure is a function
of pressure altitude only, so a day-temperature offset ``dT_isa`` changes temperature, not
pressure (the usual convention of engine performance decks).

Free-stream total temperature and pressure use the real-gas properties of :mod:`gas`:
``h(Tt) = h(Ts) + V^2/2`` with ``V = M a(Ts)``, and ``Pt/Ps`` from the entropy function.
"""

import casadi as ca

from engine_model.units import FT_TO_M, P_STD_PA, T_STD_K

from . import gas

G0 = 9.80665  # m/s^2
LAPSE = 0.0065  # K/m
H_TROPOPAUSE = 11000.0  # m
T_TROPOPAUSE = T_STD_K - LAPSE * H_TROPOPAUSE  # 216.65 K
R_ISA = 287.05287  # J/(kg K), ISA's own gas constant
_EXP = G0 / (LAPSE * R_ISA)
P_TROPOPAUSE = P_STD_PA * (T_TROPOPAUSE / T_STD_K) ** _EXP  # 22632 Pa


def isa_temperature(alt_ft):
    """ISA static temperature [K] at pressure altitude ``alt_ft`` [ft]."""
    h_m = alt_ft * FT_TO_M
    return ca.fmax(T_STD_K - LAPSE * h_m, T_TROPOPAUSE)


def isa_pressure(alt_ft):
    """ISA static pressure [Pa] at pressure altitude ``alt_ft`` [ft] (C1-continuous)."""
    h_m = alt_ft * FT_TO_M
    p_tropo = P_STD_PA * (ca.fmax(T_STD_K - LAPSE * h_m, 1.0) / T_STD_K) ** _EXP
    p_strat = P_TROPOPAUSE * ca.exp(-G0 * (h_m - H_TROPOPAUSE) / (R_ISA * T_TROPOPAUSE))
    return ca.if_else(h_m <= H_TROPOPAUSE, p_tropo, p_strat)


def _kinetic(Ts, mach):
    """Specific kinetic energy V^2/2 [J/kg] at static temperature Ts and Mach number."""
    return 0.5 * mach**2 * gas.gamma(Ts) * gas.R_GAS * Ts


def total_temperature(Ts, mach):
    """Free-stream total temperature [K] from static temperature [K] and Mach."""
    return gas.t_from_h(gas.h(Ts) + _kinetic(Ts, mach), 0.0, Ts)


def static_temperature(Tt, mach, n_iter=4):
    """Free-stream static temperature [K] from total temperature [K] and Mach (Newton)."""
    g = gas.gamma(Tt)
    Ts = Tt / (1.0 + 0.5 * (g - 1.0) * mach**2)
    for _ in range(n_iter):
        f = gas.h(Tt) - gas.h(Ts) - _kinetic(Ts, mach)
        df = -gas.cp(Ts) - 0.5 * mach**2 * gas.gamma(Ts) * gas.R_GAS
        Ts = Ts - f / df
    return Ts


def total_pressure_ratio(Ts, Tt):
    """Pt/Ps of an isentropic stagnation from Ts to Tt (real gas)."""
    return gas.pressure_ratio_isentropic(Ts, Tt, 0.0)


def t2_from_flight(alt_ft, mach, dT_isa=0.0):
    """Fan-inlet total temperature T2 [K] from altitude, Mach and ISA day offset [K]."""
    return total_temperature(isa_temperature(alt_ft) + dT_isa, mach)


def flight_speed(Ts, mach):
    """True airspeed [m/s]."""
    return mach * ca.sqrt(gas.gamma(Ts) * gas.R_GAS * Ts)


def mach_from_cas(cas_ms, alt_ft):
    """Flight Mach number for a calibrated airspeed [m/s] at pressure altitude (subsonic).

    Standard subsonic relation: qc = P0 ((1 + 0.2 (CAS/a0)^2)^3.5 - 1) and
    M = sqrt(5 ((qc/p + 1)^(2/7) - 1)).
    """
    a0 = (1.4 * R_ISA * T_STD_K) ** 0.5
    qc = P_STD_PA * ((1.0 + 0.2 * (cas_ms / a0) ** 2) ** 3.5 - 1.0)
    p = isa_pressure(alt_ft)
    return ca.sqrt(5.0 * ((qc / p + 1.0) ** (2.0 / 7.0) - 1.0))

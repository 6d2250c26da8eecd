"""Real-gas thermodynamic properties of dry air and kerosene combustion products.

Specific heat at constant pressure as a function of static temperature ``T`` [K] and fuel-air
ratio ``far`` [-], from Walsh & Fletcher, *Gas Turbine Performance*, 2nd ed. (Blackwell, 2004),
chapter 3, formula F3.23 (coefficients A0..A8 for dry air, B0..B7 for the products of kerosene
combustion; valid 200-2000 K and far 0-0.05; the ambient static temperature of a cold day
at altitude, down to about 172 K at the envelope's corner (45,000 ft, ISA -45 K), is
evaluated about 28 K below that range, where the polynomial is smooth and close to the
constant cp of cold air (1,002.4 J/(kg K) at 172 K, 1,002.1 at 200 K), not checked)::

    cp = A0 + A1 Tz + ... + A8 Tz^8 + far/(1+far) * (B0 + B1 Tz + ... + B7 Tz^7)   [kJ/(kg K)]
    Tz = T / 1000

Enthalpy and the entropy function are the exact analytic integrals of that polynomial,

    h(T, far)   = int_{T_ref}^{T} cp dT'            [J/kg]
    phi(T, far) = int_{T_ref}^{T} cp / T' dT'       [J/(kg K)]

with datum ``T_REF = 288.15 K``, the datum of the fuel's lower heating value, so that a burner
energy balance written with these enthalpies needs no further correction. The gas constant of
kerosene products differs from that of air by less than 0.1 % (Walsh & Fletcher, F3.25); one
value ``R_GAS`` is used for both.

Isentropic processes use the entropy function: ``phi(T2) - phi(T1) = R ln(P2/P1)``.
Temperatures from enthalpy or entropy are solved by Newton iterations written into the
expression graph (:func:`t_from_h`, :func:`t_from_phi`), so they stay exact and differentiable.
All functions accept floats, numpy arrays or CasADi symbols.
"""

import casadi as ca

R_GAS = 287.05  # J/(kg K), Walsh & Fletcher F3.25 for air and kerosene products
T_REF = 288.15  # K, datum for enthalpy, entropy function and fuel heating value
LHV_KEROSENE = 43.124e6  # J/kg, Walsh & Fletcher, chapter 3 (kerosene, 288.15 K datum)

# Walsh & Fletcher F3.23, kJ/(kg K)
A_AIR = (0.992313, 0.236688, -1.852148, 6.083152, -8.893933, 7.097112, -3.234725, 0.794571,
         -0.081873)
B_KERO = (-0.718874, 8.747481, -15.863157, 17.254096, -10.233795, 3.081778, -0.361112,
          -0.003919)

# Newton iterations used for temperature inversions. From the first-order starting guess of the
# callers three reach machine precision for t_from_h and better than 1e-11 (relative) for
# t_isentropic at pressure ratios 1/30-45 over 200-2000 K (tests/test_gas.py asserts 1e-10);
# each iteration more is a quarter more code in the residual's Jacobian
N_NEWTON = 3


def _horner(coeffs, x):
    acc = coeffs[-1]
    for c in reversed(coeffs[:-1]):
        acc = acc * x + c
    return acc


# integral coefficients: int cp dTz -> sum A_i Tz^(i+1)/(i+1)
_A_H = (0.0,) + tuple(a / (i + 1) for i, a in enumerate(A_AIR))
_B_H = (0.0,) + tuple(b / (i + 1) for i, b in enumerate(B_KERO))
# int cp/Tz dTz = A0 ln Tz + sum_{i>=1} A_i Tz^i / i
_A_S = (0.0,) + tuple(a / i for i, a in enumerate(A_AIR) if i >= 1)
_B_S = (0.0,) + tuple(b / i for i, b in enumerate(B_KERO) if i >= 1)

_TZ_REF = T_REF / 1000.0
_H_A_REF = _horner(_A_H, _TZ_REF)
_H_B_REF = _horner(_B_H, _TZ_REF)
_S_A_REF = A_AIR[0] * ca.log(_TZ_REF) + _horner(_A_S, _TZ_REF)
_S_B_REF = B_KERO[0] * ca.log(_TZ_REF) + _horner(_B_S, _TZ_REF)


def _fuel_fraction(far):
    return far / (1.0 + far)


def cp(T, far=0.0):
    """Specific heat at constant pressure [J/(kg K)]."""
    tz = T / 1000.0
    return 1000.0 * (_horner(A_AIR, tz) + _fuel_fraction(far) * _horner(B_KERO, tz))


def h(T, far=0.0):
    """Specific enthalpy relative to ``T_REF`` [J/kg]."""
    tz = T / 1000.0
    ha = _horner(_A_H, tz) - _H_A_REF
    hb = _horner(_B_H, tz) - _H_B_REF
    return 1.0e6 * (ha + _fuel_fraction(far) * hb)


def phi(T, far=0.0):
    """Entropy function int cp/T dT from ``T_REF`` [J/(kg K)]."""
    tz = T / 1000.0
    lt = ca.log(tz)
    sa = A_AIR[0] * lt + _horner(_A_S, tz) - _S_A_REF
    sb = B_KERO[0] * lt + _horner(_B_S, tz) - _S_B_REF
    return 1000.0 * (sa + _fuel_fraction(far) * sb)


def gamma(T, far=0.0):
    """Ratio of specific heats [-]."""
    c = cp(T, far)
    return c / (c - R_GAS)


def t_from_h(h_target, far, T_guess, n_iter=N_NEWTON):
    """Temperature [K] whose enthalpy is ``h_target``; Newton from ``T_guess``."""
    T = T_guess
    for _ in range(n_iter):
        T = T - (h(T, far) - h_target) / cp(T, far)
    return T


def t_from_phi(phi_target, far, T_guess, n_iter=N_NEWTON):
    """Temperature [K] whose entropy function is ``phi_target``; Newton from ``T_guess``."""
    T = T_guess
    for _ in range(n_iter):
        T = T - (phi(T, far) - phi_target) * T / cp(T, far)
    return T


def t_isentropic(T_in, far, pressure_ratio, n_iter=N_NEWTON):
    """Temperature after an isentropic change of total pressure by ``pressure_ratio``.

    Starting guess from the perfect-gas relation with gamma at the inlet temperature.
    """
    g = gamma(T_in, far)
    guess = T_in * pressure_ratio ** ((g - 1.0) / g)
    return t_from_phi(phi(T_in, far) + R_GAS * ca.log(pressure_ratio), far, guess, n_iter)


def pressure_ratio_isentropic(T_in, T_out, far):
    """Total-pressure ratio of the isentropic process from ``T_in`` to ``T_out``."""
    return ca.exp((phi(T_out, far) - phi(T_in, far)) / R_GAS)

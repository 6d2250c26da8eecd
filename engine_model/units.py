"""Unit conversions between the model's SI internals and the N-CMAPSS imperial boundary.

Inside the model everything is SI: K, Pa, kg/s, J/kg, W, N, m. The boundary (inputs the user
passes, outputs the user reads) uses the units of the N-CMAPSS files: ft, degR, psia, lbm/s,
rpm, lbf. Every conversion in hyprog goes through the constants of this module.
"""

FT_TO_M = 0.3048
FT_PER_KFT = 1000.0  # C-MAPSS (2008) gives altitude in thousands of feet
PSIA_TO_PA = 6894.757293168
LBM_TO_KG = 0.45359237
LBF_TO_N = 4.4482216152605
R_PER_K = 1.8  # degR per K (a temperature difference or an absolute temperature)
R_TO_K = 1.0 / R_PER_K
KT_TO_MS = 0.514444444

T_STD_K = 288.15  # sea-level standard temperature (ISA), K
P_STD_PA = 101325.0  # sea-level standard pressure (ISA), Pa
T_STD_R = T_STD_K * R_PER_K  # 518.67 degR


def k_to_r(t_k):
    return t_k * R_PER_K


def r_to_k(t_r):
    return t_r * R_TO_K


def pa_to_psia(p_pa):
    return p_pa / PSIA_TO_PA


def psia_to_pa(p_psia):
    return p_psia * PSIA_TO_PA


def kgs_to_lbms(w):
    return w / LBM_TO_KG


def lbms_to_kgs(w):
    return w * LBM_TO_KG


def n_to_lbf(f):
    return f / LBF_TO_N


def ft_to_m(h):
    return h * FT_TO_M

# offsets and factors of the units a user's file may be in by mistake (calibration.unit_check)
C_TO_K = 273.15  # K at 0 degC
F_TO_R = 459.67  # degR at 0 degF
RPM_PER_REV_S = 60.0  # rpm per revolution per second

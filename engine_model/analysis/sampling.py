"""Random operating points of the civil flight envelope (used by the CLI, benchmarks, tests).

alt 0-42,000 ft; Mach from 0 up to min(0.85, the Mach of 350 kt calibrated airspeed at that
altitude); TRA 20-100 %; ISA day offset +-15 K; theta uniform in [-0.05, 0].
"""

import numpy as np
import pandas as pd

from engine_model.channels import THETA_NAMES, W_NAMES
from engine_model.physics import atmosphere
from engine_model.units import KT_TO_MS, k_to_r

MAX_CAS_KT = 350.0  # calibrated airspeed limit of the sampled envelope


def random_envelope(n, seed=0, theta_range=(-0.05, 0.0), return_day_offset=False):
    """``(w (n, 4), theta (n, 10))``, plus the ISA day offsets [K] if asked for."""
    rng = np.random.default_rng(seed)
    alt = rng.uniform(0.0, 42000.0, n)
    m_cas = np.array([float(atmosphere.mach_from_cas(MAX_CAS_KT * KT_TO_MS, a)) for a in alt])
    mach = rng.uniform(0.0, 1.0, n) * np.minimum(0.85, m_cas)
    tra = rng.uniform(20.0, 100.0, n)
    dT = rng.uniform(-15.0, 15.0, n)
    T2 = np.array([float(atmosphere.t2_from_flight(a, m, d))
                   for a, m, d in zip(alt, mach, dT, strict=True)])
    w = np.column_stack([alt, mach, tra, k_to_r(T2)])
    theta = rng.uniform(theta_range[0], theta_range[1], (n, 10))
    return (w, theta, dT) if return_day_offset else (w, theta)


def envelope_points(n: int, seed: int = 0) -> pd.DataFrame:
    """The draws of :func:`random_envelope` as a DataFrame: ``alt Mach TRA T2`` [ft, -, %,
    degR], the ten theta columns and ``dT_isa`` [K]."""
    w, theta, dT = random_envelope(n, seed, return_day_offset=True)
    df = pd.DataFrame(w, columns=list(W_NAMES))
    df[list(THETA_NAMES)] = theta
    df["dT_isa"] = dT
    return df

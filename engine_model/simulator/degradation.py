"""Health trajectories of a unit: initial wear, normal degradation, abnormal degradation from
the onset ``t_s``, failure when the health index reaches 0.

Health index: :mod:`engine_model.physics.health_index` (N-CMAPSS's definition).

Trajectory of one unit (cycles ``c = 1 .. EOL``; ``D(c)`` the cumulative damage, the sum of the
flights' severities normalised to mean 1, so harder missions wear faster)::

    theta(c) = theta_0 + r D(c) + A d g((D(c) - D(t_s - 1)) / tau)  for c >= t_s (else no A)
    g(u) = exp(u) - 1 - u                  (zero value and slope at the onset: a smooth onset)

- Which parameters wear: by default all ten; a preset may restrict initial wear and normal
  degradation to the failure modes' components (``ds02`` and ``tiny``: the paper's HPT efficiency,
  LPT efficiency and LPT flow, as N-CMAPSS DS02 degrades only "the affected system components",
  Arias Chao et al. 2022, the paper in ``shared/reference``, sec. 4), so that the paper's
  three-parameter calibration model is correctly specified.
- ``theta_0``: initial wear, every wearing parameter ``-U(0, 1) x`` :data:`INITIAL_WEAR`
  (efficiencies and flows up to 0.3 %); it consumes about 0-15 % of the health index
  (engine-to-engine variability about 10 % of HI; C-MAPSS (Saxena et al., PHM 2008) draws its
  initial wear of the same order).
- ``r``: normal degradation, every parameter ``-U(0.5, 1.5) x`` :data:`NORMAL_RATE` per unit
  of damage (about 0.5 % of efficiency over 60 cycles).
- ``d``: the failure mode's direction (:data:`MODES`, weights drawn per unit), ``tau`` sets the
  steepness (``(D(EOL) - D(t_s - 1)) / U(1.5, 3)``), and ``A`` is solved (Brent) so that HI reaches
  0 exactly at the drawn end of life.
- ``hs`` = 1 for ``c < t_s`` (healthy), 0 from the onset cycle ``t_s`` on (abnormal
  degradation), so ``t_s`` is the first cycle with ``hs = 0`` (as :func:`datasets.summarize`
  reads it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from engine_model.channels import THETA_NAMES
from engine_model.physics.health_index import HealthIndex
from engine_model.validation import ENVELOPE, InputError

INITIAL_WEAR = {t: 0.003 for t in THETA_NAMES}
NORMAL_RATE = {t: (1.0e-4 if t.endswith("eff_mod") else 0.6e-4) for t in THETA_NAMES}

# failure mode -> {theta: (low, high) weight of the abnormal direction, drawn uniformly}
MODES: dict[str, dict[str, tuple[float, float]]] = {
    "HPT": {"HPT_eff_mod": (1.0, 1.0)},
    "HPT+LPT": {"HPT_eff_mod": (1.0, 1.0), "LPT_eff_mod": (0.4, 0.8),
                "LPT_flow_mod": (0.4, 0.8)},
    "LPT": {"LPT_eff_mod": (1.0, 1.0), "LPT_flow_mod": (0.5, 1.0)},
    "HPC": {"HPC_eff_mod": (1.0, 1.0), "HPC_flow_mod": (0.3, 0.6)},
    "LPC+HPC": {"LPC_eff_mod": (1.0, 1.0), "LPC_flow_mod": (0.3, 0.6),
                "HPC_eff_mod": (0.6, 1.0), "HPC_flow_mod": (0.2, 0.4)},
    "fan": {"fan_eff_mod": (1.0, 1.0), "fan_flow_mod": (0.0, 0.2)},
}


@dataclass
class HealthTrajectory:
    """One unit's health: per cycle ``theta`` (n, 10), health index ``hi``, ``hs``; the end of
    life ``eol`` (last cycle, ``hi[eol-1] == 0``) and onset ``t_s``."""

    theta: np.ndarray
    hi: np.ndarray
    hs: np.ndarray
    eol: int
    t_s: int
    mode: str
    margins: dict


def _draw(rng, lo_hi):
    lo, hi = int(lo_hi[0]), int(lo_hi[1])
    if hi < lo:
        raise InputError(f"range ({lo}, {hi}) is empty")
    return int(rng.integers(lo, hi + 1))


def simulate_health(model, mode: str, eol, t_s, rng: np.random.Generator,
                    severity: np.ndarray | None = None, hi_fn: HealthIndex | None = None,
                    wear_params=None) -> HealthTrajectory:
    """Draw one unit's health trajectory (module docstring). ``eol`` and ``t_s`` are (low,
    high) cycle ranges; ``severity`` the per-cycle damage of its flights (length >= eol high,
    mean about 1; default all ones); ``wear_params`` the health parameters that carry initial
    wear and normal degradation (default all ten; the others stay at 0 unless the failure
    mode moves them). The random draws do not depend on ``wear_params``."""
    if mode not in MODES:
        raise InputError(f"unknown failure mode {mode!r}; one of {', '.join(MODES)}")
    hi_fn = hi_fn or HealthIndex(model)
    n_th = len(THETA_NAMES)
    eol_c = _draw(rng, eol)
    ts_c = _draw(rng, t_s)
    if not 2 <= ts_c < eol_c:
        raise InputError(f"onset t_s = {ts_c} must lie before the end of life {eol_c}")
    sev = np.ones(eol_c) if severity is None else np.asarray(severity, float)[:eol_c]
    if len(sev) < eol_c or np.any(sev <= 0):
        raise InputError("severity: need a positive value for every cycle up to the end of life")
    D = np.cumsum(sev)
    theta0 = -rng.uniform(0.0, 1.0, n_th) * np.array([INITIAL_WEAR[t] for t in THETA_NAMES])
    rate = -rng.uniform(0.5, 1.5, n_th) * np.array([NORMAL_RATE[t] for t in THETA_NAMES])
    if wear_params is not None:
        unknown = [q for q in wear_params if q not in THETA_NAMES]
        if unknown:
            raise InputError(f"wear_params: unknown health parameter(s) {', '.join(unknown)}")
        off = np.array([q not in wear_params for q in THETA_NAMES])
        theta0[off] = 0.0
        rate[off] = 0.0
    d = np.zeros(n_th)
    for name, (lo, hi) in MODES[mode].items():
        d[THETA_NAMES.index(name)] = -rng.uniform(lo, hi)
    kappa = rng.uniform(1.5, 3.0)
    D_onset = D[ts_c - 2]  # damage at the end of cycle t_s - 1: abnormal wear starts at t_s
    tau = (D[eol_c - 1] - D_onset) / kappa
    u = np.clip((D - D_onset) / tau, 0.0, None)
    g = np.expm1(u) - u

    def theta_of(A, idx):
        return theta0 + rate * D[idx, None] + A * d * g[idx, None]

    last = np.array([eol_c - 1])
    f = lambda A: float(hi_fn(theta_of(A, last))[0])  # noqa: E731
    if f(0.0) <= 0.0:
        raise InputError(f"mode {mode}: the unit reaches the limits by normal wear alone")
    # bracket the root: grow the abnormal step until HI < 0, keeping theta in the envelope
    base = theta_of(0.0, last)[0]
    g_end = g[eol_c - 1]
    lo_env = ENVELOPE.theta[0] + 0.005
    A_max = min((base[i] - lo_env) / (-d[i] * g_end) for i in np.flatnonzero(d))
    A_lo, A_hi = 0.0, min(A_max, 0.005 / g_end)
    while f(A_hi) > 0.0:
        if A_hi >= A_max:
            raise InputError(f"mode {mode}: the health index cannot reach 0 within the model's "
                             f"theta range {ENVELOPE.theta}")
        A_lo, A_hi = A_hi, min(A_max, 2.0 * A_hi)
    A = brentq(f, A_lo, A_hi, xtol=1e-14)
    idx = np.arange(eol_c)
    theta = theta_of(A, idx)
    hi = hi_fn(theta)
    hi[-1] = 0.0 if abs(hi[-1]) < 1e-6 else hi[-1]
    early = np.flatnonzero(hi[:-1] <= 0.0)
    if early.size:  # not monotone: the unit fails earlier than drawn
        eol_c = int(early[0]) + 1
        theta, hi = theta[:eol_c], hi[:eol_c]
    hs = (np.arange(1, eol_c + 1) < ts_c).astype(np.int64)
    return HealthTrajectory(theta=theta, hi=hi, hs=hs, eol=eol_c, t_s=ts_c, mode=mode,
                            margins=hi_fn.components(theta))

"""The health index of an engine from its health parameters, as N-CMAPSS defines it.

Arias Chao et al., *Data* 6(1):5, 2021: the minimum over the normalised margins of the fan,
LPC and HPC stall margins and of the EGT margin,

    HI = min_i (m_i(theta) - m_i,lim) / (m_i(0) - m_i,lim),   i in {SmFan, SmLPC, SmHPC, EGT}

with the EGT margin ``m_EGT = T48_lim - T48``, all evaluated at the **reference condition**
:data:`REFERENCE_W`: sea-level static, ISA + 15 K, TRA 100 (a hot-day take-off, the condition
at which an engine's EGT margin is quoted). A new engine (theta = 0) has HI = 1. Limits
(:data:`LIMITS`): T48 limit = new-engine T48 at the reference + 90 degR (50 K of EGT margin, the
order of a new CFM56/V2500-class engine's take-off EGT margin); stall margins may fall to 10 %
(fan), 8 % (LPC) and 15 % (HPC) from the new engine's (12.0 %, 14 % and 25.6 % at the
reference with the present maps: :attr:`HealthIndex.new`).
"""

from __future__ import annotations

import numpy as np

from engine_model.channels import THETA_NAMES
from engine_model.units import R_PER_K
from engine_model.validation import InputError

from .atmosphere import t2_from_flight

REFERENCE_DT_K = 15.0
REFERENCE_W = (0.0, 0.0, 100.0, float(t2_from_flight(0.0, 0.0, REFERENCE_DT_K)) * R_PER_K)

EGT_MARGIN_DEGR = 90.0
LIMITS = {"SmFan": 10.0, "SmLPC": 8.0, "SmHPC": 15.0}


def physical_p(model) -> np.ndarray | None:
    """The model's effect parameters with every sensor effect's at its neutral value: the
    engine's own stations, as its margins are defined, not what a faulty sensor reports
    (a biased T48 reading must not change the EGT margin, nor the wear the simulator solves
    for from it). None for a model without effects."""
    from .effect_library import SensorEffect

    if not len(model.param_names):
        return None
    p = np.array(model.p_default, float)
    for e in model.effects.effects:
        if isinstance(e, SensorEffect):
            for q in e.params:
                p[model.param_names.index(f"{e.name}.{q.name}")] = q.default
    return p


def reference_margins(model, theta: np.ndarray) -> dict[str, np.ndarray]:
    """Stall margins [%] and T48 [degR] at the reference condition for each row of theta
    (the engine's stations: :func:`physical_p`)."""
    theta = np.atleast_2d(theta)
    w = np.tile(np.asarray(REFERENCE_W, float), (len(theta), 1))
    df = model.evaluate(w, theta=theta, p=physical_p(model))
    if not df["converged"].all():
        i = int(np.flatnonzero(~df["converged"].to_numpy())[0])
        raise InputError(f"health index: the reference point did not converge at theta row {i}")
    return {k: df[k].to_numpy() for k in ("SmFan", "SmLPC", "SmHPC", "T48")}


class HealthIndex:
    """HI(theta) of the module docstring, with the new-engine margins of ``model``."""

    def __init__(self, model):
        self.model = model
        new = reference_margins(model, np.zeros(len(THETA_NAMES)))
        self.new = {k: float(v[0]) for k, v in new.items()}
        self.t48_lim = self.new["T48"] + EGT_MARGIN_DEGR

    def components(self, theta) -> dict[str, np.ndarray]:
        """The normalised margins ``SmFan``, ``SmLPC``, ``SmHPC`` and ``EGT`` (1 new, 0 at
        the limit) for each row of ``theta``."""
        m = reference_margins(self.model, theta)
        out = {k: (m[k] - lim) / (self.new[k] - lim) for k, lim in LIMITS.items()}
        out["EGT"] = (self.t48_lim - m["T48"]) / EGT_MARGIN_DEGR
        return out

    @staticmethod
    def of_components(components: dict[str, np.ndarray]) -> np.ndarray:
        """HI, the minimum of the normalised margins (module docstring)."""
        return np.min(np.vstack(list(components.values())), axis=0)

    def __call__(self, theta) -> np.ndarray:
        return self.of_components(self.components(theta))

"""A fleet's early-life samples as the arrays of the fleet fit.

Early life is ``cycle <= early_cycles`` (default :data:`.noise.EARLY_CYCLES`): engines nearly
new, whose health is their manufacturing scatter plus the first wear. Each sample's noise
std is its channel's at its operating condition, estimated from the same data
(:func:`.noise.noise_from_data`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from engine_model.channels import W_NAMES
from engine_model.validation import InputError

from .fleet_fit import FleetData
from .noise import EARLY_CYCLES, noise_from_data

#: The channels fitted by default: every C-MAPSS sensor that hyprog's model computes and whose
#: definition the data keep (``Ps30`` and ``phi`` do not: engine_model.analysis.reference),
#: except ``P2``, which C-MAPSS writes as one number per operating condition (no noise, no
#: engine-to-engine spread: a function of the settings, not a measurement).
DEFAULT_CHANNELS = ("T24", "T30", "T50", "P15", "P30", "Nf", "Nc")


def fleet_data(df: pd.DataFrame, channels=DEFAULT_CHANNELS, early_cycles: int = EARLY_CYCLES,
               units=None, condition: str = "condition",
               source: str = "data") -> tuple[FleetData, pd.DataFrame]:
    """``(FleetData, noise table)`` of the early-life rows of ``units`` (default all)."""
    missing = [c for c in (*W_NAMES, *channels) if c not in df.columns]
    if missing:
        raise InputError(f"{source}: missing column(s) {', '.join(missing)}")
    if units is not None:
        absent = sorted(set(units) - set(df["unit"].unique().tolist()))
        if absent:
            raise InputError(f"{source}: no unit(s) {', '.join(map(str, absent))}")
        df = df[df["unit"].isin(units)]
    early = df[df["cycle"] <= early_cycles].sort_values(["unit", "cycle"], kind="stable")
    if early.empty:
        raise InputError(f"{source}: no row with cycle <= {early_cycles}")
    noise = noise_from_data(early, channels, condition, early_cycles, source)
    cond = early[condition].to_numpy()
    sigma = noise.loc[cond, list(channels)].to_numpy(float)
    ids, unit = np.unique(early["unit"].to_numpy(), return_inverse=True)
    data = FleetData(early[list(W_NAMES)].to_numpy(float), early[list(channels)].to_numpy(float),
                     sigma, unit.astype(int), tuple(int(u) for u in ids), cond.astype(int),
                     early["cycle"].to_numpy(), tuple(channels))
    return data, noise

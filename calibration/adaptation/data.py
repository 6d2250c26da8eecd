"""A fleet's early-life samples as the arrays of the fleet fit.

Early life is ``cycle <= early_cycles`` (default
:data:`calibration.measurement_noise.EARLY_CYCLES`): engines nearly
new, whose health is their manufacturing scatter plus the first wear. Each sample's std
combines its channel's noise at its operating condition, estimated from the same data
(:func:`calibration.measurement_noise.noise_from_data`), with the model's own error (Kennedy
& O'Hagan, "Bayesian calibration of computer models", JRSS B 63, 2001: the model discrepancy
as a term of the likelihood; :func:`calibration.measurement_noise.with_model_error`)::

    sigma_nj^2 = sigma_noise,j,c(n)^2 + (model_error * ybar_j,c(n))^2

``ybar_j,c`` the channel's early-life mean at the condition. ``model_error`` (relative) is a
decision, not a fit: the precision asked of a 0D cycle model's mean prediction. The default
(:data:`MODEL_ERROR`) is ``0.001``, a tenth of the 1 % to which each condition's mean is to
be matched. With the noise alone (``model_error=0``) a channel written almost without noise
dominates the fit: C-MAPSS's ``P15`` carries only its rounding (0.003 psia, 0.01-0.05 % of
the reading) and ``Nf`` 0.03 rpm (0.001 %), against 0.2-0.4 % in ``T30`` and ``T50``. The FD002
adaptation of 2026-11-26 with the noise alone matched ``P15`` within 0.06 % at every
condition, left 0.84 % in ``T30``, 5.17 % with a condition left out, and ended with six
parameters on their bounds; with ``0.001`` (2026-11-27) 0.44 % in sample and 2.66 % with a
condition left out (docs/adaptation.md). A fleet simulated by the model itself has no model
error: pass ``model_error=0`` there.

The model error is the same for every sample at one operating condition (the model's mismatch
there does not change from one reading to the next), and the fleet fit treats it so by
default: one unknown offset per condition and channel with this prior (:mod:`.fleet_fit`,
``FleetData.shared_error``; the default since 2026-11-30, when the FD002 adaptation fitted so
met the rule fixed before it ran, docs/adaptation.md). ``shared_model_error=False`` counts it
as independent noise of every sample, as the FD002 adaptation ccd7e93d was fitted.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from engine_model.channels import OUTPUT_NAMES, W_NAMES
from engine_model.validation import InputError

from ..measurement_noise import EARLY_CYCLES, check_model_error, noise_from_data, with_model_error
from .fleet_fit import FleetData

#: The channels fitted by default: every C-MAPSS sensor that hyprog's model computes and whose
#: definition the data keep (``Ps30`` and ``phi`` do not: engine_model.analysis.reference),
#: except ``P2``, which C-MAPSS writes as one number per operating condition (no noise, no
#: engine-to-engine spread: a function of the settings, not a measurement).
DEFAULT_CHANNELS = ("T24", "T30", "T50", "P15", "P30", "Nf", "Nc")
#: The model's own error, relative std of a mean prediction (module docstring).
MODEL_ERROR = 0.001


def fleet_data(df: pd.DataFrame, channels=DEFAULT_CHANNELS, early_cycles: int = EARLY_CYCLES,
               units=None, condition: str = "condition", source: str = "data",
               model_error: float = MODEL_ERROR, shared_model_error: bool | None = None,
               ) -> tuple[FleetData, pd.DataFrame]:
    """``(FleetData, noise table)`` of the early-life rows of ``units`` (default all); each
    sample's std the noise and ``model_error`` combined, the model error shared by each
    condition's samples unless ``shared_model_error`` is False (None: shared whenever there is
    a model error; module docstring)."""
    model_error = check_model_error(model_error)
    if shared_model_error and not model_error:
        raise InputError("--model-error-shared: the model error is 0, so there is nothing to "
                         "share; give --model-error above 0")
    twice = sorted({c for c in channels if list(channels).count(c) > 1})
    if twice:
        raise InputError(f"{source}: channel(s) {', '.join(twice)} listed twice")
    not_model = [c for c in channels if c not in OUTPUT_NAMES]
    if not_model:
        raise InputError(f"--channels: {', '.join(not_model)} not an output of the engine "
                         f"model (its outputs: {', '.join(OUTPUT_NAMES)})")
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
    values = early[[*W_NAMES, *channels]].to_numpy(float)
    bad = ~np.isfinite(values)
    if bad.any():
        i, j = (int(v[0]) for v in np.nonzero(bad))
        row = early.iloc[i]
        raise InputError(f"{source}: unit {int(row['unit'])}, cycle {int(row['cycle'])}: "
                         f"column {[*W_NAMES, *channels][j]} is not a finite number; the "
                         "adaptation needs every early-life reading")
    noise = noise_from_data(early, channels, condition, early_cycles, source)
    cond = early[condition].to_numpy()
    sigma = noise.loc[cond, list(channels)].to_numpy(float)
    level = early.groupby(condition)[list(channels)].mean().loc[cond].to_numpy(float)
    sigma = with_model_error(sigma, model_error, level)
    ids, unit = np.unique(early["unit"].to_numpy(), return_inverse=True)
    data = FleetData(early[list(W_NAMES)].to_numpy(float), early[list(channels)].to_numpy(float),
                     sigma, unit.astype(int), tuple(int(u) for u in ids), cond.astype(int),
                     early["cycle"].to_numpy(), tuple(channels),
                     model_error * np.abs(level) if model_error else None,
                     bool(model_error) if shared_model_error is None else shared_model_error)
    return data, noise

"""Each channel's noise level from the data themselves (within engines, per operating
condition, early in life), and the model's own error added to it.

Used by the fleet fit of :mod:`calibration.adaptation` and by the estimators' measurement
covariance when a calibration asks for the data's noise (``CalibrationSetup(noise="data")``,
``hyprog calibrate --noise data``; :mod:`calibration.estimation_setup`).

Early in life an engine's health barely changes, so two early-life readings of one engine at
one operating condition differ by measurement noise (and by the scatter of the operating
point inside the condition's tolerance, which the model sees through ``w``). The pooled
within-group variance over the groups ``g = (engine, condition)`` with ``n_g >= 2`` samples::

    sigma_j,c^2 = sum_g sum_n (y_nj - ybar_gj)^2 / sum_g (n_g - 1)

is the unbiased one-way ANOVA estimate of the within-group variance (e.g. Montgomery, *Design
and Analysis of Experiments*, ch. 3). It excludes the engine-to-engine scatter (health, a
new engine's manufacturing scatter), which is the fit's business, not the noise's.

Resolution. A channel recorded to a resolution ``q`` (C-MAPSS writes P15 to 0.01 psia, which
at 42,000 ft is 0.2 % of the reading) carries at least the rounding error, uniform on
``[-q/2, q/2]``, std ``q / sqrt(12)`` (Widrow & Kollar, *Quantization Noise*, 2008, ch. 4),
even where every early reading of an engine is the same number. ``q`` is the smallest
difference between two distinct values of the channel within one condition, and the
estimate is floored at ``q / sqrt(12)``. A channel with one value per condition (C-MAPSS's
``P2``) has no resolution to find and no noise: it is refused. The
documented noise of hyprog's simulator is never used here: C-MAPSS's noise is not ours.

The model's own error (Kennedy & O'Hagan, "Bayesian calibration of computer models", JRSS B
63, 2001: the model discrepancy as a term of the likelihood) enters as a relative std added
in quadrature to the noise::

    sigma^2 = sigma_noise^2 + (model_error * level)^2

with ``level`` the reading (or its mean at the condition). It is a decision, not a fit: the
precision asked of a 0D cycle model's prediction (:func:`with_model_error`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from engine_model.validation import InputError

#: Cycles counted as early life (C-MAPSS: the reference table's means use cycles 1-20).
EARLY_CYCLES = 20


def noise_from_data(df: pd.DataFrame, channels, condition: str = "condition",
                    early_cycles: int = EARLY_CYCLES, source: str = "data") -> pd.DataFrame:
    """The noise std of every channel per operating condition (a frame indexed by the
    condition label, one column per channel) from the rows with ``cycle <= early_cycles``
    (module docstring). A condition with fewer than two samples of any engine, or a channel
    with no spread at all (a constant channel carries no noise to estimate), is an error
    naming it."""
    for c in ("unit", "cycle", condition, *channels):
        if c not in df.columns:
            raise InputError(f"{source}: no column {c!r} (noise from the data needs unit, "
                             f"cycle, {condition} and the channels)")
    labels = pd.to_numeric(df[condition], errors="coerce").to_numpy(float)
    bad = ~(np.isfinite(labels) & (labels == np.round(labels)))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{source}: row {i + 1}, column {condition} = {df[condition].iloc[i]}:"
                         " an operating-condition label must be an integer (noise is "
                         "estimated per condition)")
    early = df[df["cycle"] <= early_cycles]
    out = {}
    for cond, g in early.groupby(condition, sort=True):
        grouped = g.groupby("unit")[list(channels)]
        dev = g[list(channels)] - grouped.transform("mean")
        # per channel, its own readings: a missing one (NaN) counts in neither sum
        dof = (grouped.count() - 1).clip(lower=0).sum(axis=0)
        if (dof < 1).all():
            raise InputError(f"{source}: condition {cond}: no engine has two early-life "
                             f"samples (cycle <= {early_cycles}) to estimate the noise from")
        if (dof < 1).any():
            short = ", ".join(c for c in channels if dof[c] < 1)
            raise InputError(f"{source}: condition {cond}: no engine has two early-life "
                             f"readings of {short} to estimate its noise from")
        out[cond] = np.sqrt((dev ** 2).sum(axis=0) / dof)
    table = pd.DataFrame(out).T
    table.index.name = condition
    for c in channels:
        q = min((resolution(g[c].to_numpy(float)) for _, g in df.groupby(condition)),
                key=lambda v: v if v > 0 else np.inf)
        table[c] = np.maximum(table[c], q / np.sqrt(12.0))
    flat = [c for c in channels if not (table[c] > 0).all()]
    if flat:
        raise InputError(f"{source}: channel(s) {', '.join(flat)} do not vary within any "
                         "engine at some condition: no noise to estimate (leave them out)")
    return table


def check_model_error(model_error: float) -> float:
    """``model_error`` as a float, or an error unless it is a relative std in [0, 0.1)."""
    if not (np.isfinite(model_error) and 0.0 <= model_error < 0.1):
        raise InputError(f"model error {model_error}: must be in [0, 0.1) (a relative std)")
    return float(model_error)


def with_model_error(sigma, model_error: float, level) -> np.ndarray:
    """The noise std ``sigma`` and the model's own error ``model_error * |level|`` combined
    in quadrature (module docstring); ``sigma`` itself when ``model_error`` is 0."""
    sigma = np.asarray(sigma, float)
    if model_error == 0.0:
        return sigma
    return np.hypot(sigma, model_error * np.abs(np.asarray(level, float)))


def resolution(values: np.ndarray) -> float:
    """The smallest difference between two distinct finite values (0 when there is one)."""
    u = np.unique(values[np.isfinite(values)])
    d = np.diff(u)
    return float(d.min()) if len(d) else 0.0

"""Measurement noise of the 16 measured channels ``x_s``.

The noise is Gaussian, white, independent between channels and proportional to the reading:
``x_meas = x_true * (1 + sigma_rel * e)``, ``e ~ N(0, 1)``. Proportional noise keeps the
signal-to-noise ratio of a pressure the same at 40,000 ft (a third of its sea-level value) as
on the ground, as for a transducer whose accuracy is quoted in percent of reading.

Standard deviations (:data:`SIGMA_REL`, fractions of the reading). They are set from the scatter of
the C-MAPSS FD002 early-life means in ``shared/reference`` (one standard deviation, unit-to-unit
wear plus sensor noise: T24 0.35 degR, T30 4-4.5 degR, T50 5-6 degR, P30 0.4-0.6 psia, Nf 0.05-0.15
rpm, Nc 7-9 rpm), taking roughly half of each scatter as sensor noise (Nf: about the whole of it,
0.12 rpm), and for the channels C-MAPSS does not show, from the usual gas-path instrumentation
classes (thermocouples in the hot section about 0.25 % of reading, pressure transducers about 0.1 %,
fuel flow meters about 0.4 %):

========  ===========  ======================================
channel   sigma_rel    at sea-level static TRA 100
========  ===========  ======================================
Wf        0.004        about 0.028 lbm/s
Nf        5e-5         about 0.12 rpm
Nc        5e-4         about 4.5 rpm
T24       2e-4         about 0.13 degR
T30       1.5e-3       about 2.4 degR
T40       3e-3         about 9 degR at design (combustor exit, hard to measure)
T48       2.5e-3       about 5 degR
T50       2e-3         about 2.8 degR
P*        1e-3         e.g. 0.55 psia on P30, 0.015 psia on P2
========  ===========  ======================================

The calibration's default measurement covariance ``R`` is built from the same table
(:func:`sigma_abs`), so a filter run on simulated data is told the truth about the noise.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from engine_model.channels import XS_NAMES

SIGMA_REL: dict[str, float] = {
    "Wf": 4e-3, "Nf": 5e-5, "Nc": 5e-4,
    "T24": 2e-4, "T30": 1.5e-3, "T40": 3e-3, "T48": 2.5e-3, "T50": 2e-3,
    "P15": 1e-3, "P2": 1e-3, "P21": 1e-3, "P24": 1e-3, "Ps30": 1e-3, "P30": 1e-3,
    "P40": 1e-3, "P50": 1e-3,
}
assert set(SIGMA_REL) == set(XS_NAMES)


def sigma_abs(values, channels=XS_NAMES, scale: float = 1.0) -> np.ndarray:
    """Absolute standard deviations (N-CMAPSS units) of ``channels`` at readings ``values``
    ((N, k) array or DataFrame holding those columns): ``scale * sigma_rel * |value|``."""
    channels = tuple(channels)
    if isinstance(values, pd.DataFrame):
        values = values[list(channels)].to_numpy(float)
    rel = np.array([SIGMA_REL[c] for c in channels], float)
    return scale * rel * np.abs(np.asarray(values, float))


def add_noise(df: pd.DataFrame, rng: np.random.Generator, scale: float = 1.0,
              channels=XS_NAMES) -> pd.DataFrame:
    """A copy of ``df`` with measurement noise on every ``channels`` column it holds (the
    others, e.g. virtual sensors and the true theta, stay noise-free). Draws one standard
    normal per row and channel, in channel order, so the same ``rng`` state gives the same
    noise. ``scale=0`` returns the truth."""
    out = df.copy()
    cols = [c for c in channels if c in df.columns]
    if scale == 0.0 or not cols:
        return out
    e = rng.standard_normal((len(df), len(cols)))
    vals = df[cols].to_numpy(float)
    out[cols] = vals * (1.0 + scale * np.array([SIGMA_REL[c] for c in cols]) * e)
    return out

"""Input checks with messages a user can act on: they name the row and the column."""

from dataclasses import dataclass

import numpy as np

from .channels import THETA_NAMES, W_NAMES


class InputError(ValueError):
    """Bad input to the engine model (NaN, out of envelope, wrong columns)."""


@dataclass(frozen=True)
class Envelope:
    """The flight envelope the model is built and tested for."""

    alt_ft: tuple = (-1500.0, 45000.0)
    Mach: tuple = (0.0, 0.90)
    TRA: tuple = (15.0, 105.0)
    T2: tuple = (360.0, 620.0)  # degR: ISA -45 K at 45,000 ft to ISA +40 K at Mach 0.6 SL
    theta: tuple = (-0.15, 0.05)


ENVELOPE = Envelope()
_LIMITS = {"alt": ENVELOPE.alt_ft, "Mach": ENVELOPE.Mach, "TRA": ENVELOPE.TRA, "T2": ENVELOPE.T2}


def _first_bad(mask):
    return int(np.flatnonzero(mask)[0])


def check_columns(columns, required, what="input"):
    missing = [c for c in required if c not in columns]
    if missing:
        raise InputError(
            f"{what}: missing column(s) {', '.join(missing)}; expected {', '.join(required)}"
            f" (got {', '.join(map(str, columns))})")


def check_w(w: np.ndarray, row_labels=None, source="input"):
    """``w`` is (N, 4) in W_NAMES order."""
    labels = row_labels if row_labels is not None else np.arange(len(w))
    for j, name in enumerate(W_NAMES):
        col = w[:, j]
        bad = ~np.isfinite(col)
        if bad.any():
            i = _first_bad(bad)
            raise InputError(f"{source}: row {labels[i]}, column {name}: value is {col[i]}"
                             " (NaN or infinite)")
        lo, hi = _LIMITS[name]
        out = (col < lo) | (col > hi)
        if out.any():
            i = _first_bad(out)
            raise InputError(f"{source}: row {labels[i]}, column {name} = {col[i]:g} is outside"
                             f" the flight envelope [{lo:g}, {hi:g}]")


def check_theta(theta: np.ndarray, row_labels=None, source="input"):
    labels = row_labels if row_labels is not None else np.arange(len(theta))
    lo, hi = ENVELOPE.theta
    for j, name in enumerate(THETA_NAMES):
        col = theta[:, j]
        bad = ~np.isfinite(col)
        if bad.any():
            i = _first_bad(bad)
            raise InputError(f"{source}: row {labels[i]}, column {name}: value is {col[i]}")
        out = (col < lo) | (col > hi)
        if out.any():
            i = _first_bad(out)
            raise InputError(f"{source}: row {labels[i]}, column {name} = {col[i]:g} is outside"
                             f" [{lo:g}, {hi:g}] (fractional health delta)")

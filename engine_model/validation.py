"""Input checks with messages a user can act on: they name the row and the column; and the
library's warnings, collected for a report (:func:`collected_warnings`)."""

import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from .channels import THETA_NAMES, W_NAMES


class InputError(ValueError):
    """Bad input to the engine model (NaN, out of envelope, wrong columns)."""


@contextmanager
def collected_warnings() -> Iterator[list[str]]:
    """The library's warnings (``UserWarning`` and its subclasses) raised inside the block,
    as one-line messages, each once, in order (filled when the block ends), for a command or
    a stage to report; other categories (a dependency's deprecation, numpy's overflow) are
    handed back to Python's own filters after the block."""
    messages: list[str] = []
    others: list = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", UserWarning)
            try:
                yield messages
            finally:
                for w in caught:
                    m = " ".join(str(w.message).split())
                    if not issubclass(w.category, UserWarning):
                        others.append(w)
                    elif m not in messages:
                        messages.append(m)
    finally:  # outside the recording block: re-emitted there, they would be recorded again
        for w in others:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


@dataclass(frozen=True)
class Envelope:
    """The flight envelope the model is built and tested for."""

    alt_ft: tuple = (-1500.0, 45000.0)
    Mach: tuple = (0.0, 0.90)
    TRA: tuple = (15.0, 105.0)
    T2: tuple = (360.0, 620.0)  # degR: ISA -45 K at 45,000 ft to ISA +40 K at Mach 0.5 SL
    theta: tuple = (-0.15, 0.05)


ENVELOPE = Envelope()
_LIMITS = {"alt": ENVELOPE.alt_ft, "Mach": ENVELOPE.Mach, "TRA": ENVELOPE.TRA, "T2": ENVELOPE.T2}


def _first_bad(mask):
    return int(np.flatnonzero(mask)[0])


def check_seed(seed, what: str = "seed") -> int:
    """``seed`` as an int >= 0 (numpy's and torch's generators take no negative seed)."""
    if int(seed) != seed or int(seed) < 0:
        raise InputError(f"{what} {seed}: expected an integer >= 0")
    return int(seed)


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

"""Which rows train, which validate, which calibrate the intervals, which test.

Roles of the rows of a feature table (one integer per row, :data:`TRAIN` ...):

- **test**: the metadata's ``test_units`` (or units the caller names); never used in training,
  early stopping or interval calibration.
- **conformal**: whole development units held out for split-conformal calibration
  (:mod:`.conformal`); none by default. Whole units, because residuals within a unit are
  strongly correlated: the exchangeability the interval needs is between units of a fleet.
- **validation** (early stopping, 10 % of the development data as in the paper, Sec. 4.2):

  * ``"flights"`` (default): per training unit, ``max(1, round(0.1 n_c))`` of its ``n_c``
    cycles (whole flights) drawn without replacement by a seeded generator; a unit with one
    cycle keeps it for training.
  * ``"units"``: whole development units, the ``val_units`` given, or
    ``max(1, round(0.1 n_u))`` of the ``n_u`` units drawn by the seed. The default of
    training (``validation="auto"`` with two training units or more,
    :mod:`.train_config`): it measures the prediction of an engine the network has not seen,
    which validation flights of seen units do not (issue 30); and on a table with one sample
    per cycle (C-MAPSS) a validation "flight" would be one row, leaving one-row validation
    segments and cutting the training units into short runs.

- **train**: the remaining development rows.

Windows are cut inside runs of consecutive rows of one unit *and one role*
(:func:`segments`), so a window never straddles a unit or a split boundary: the flights of a
validation window are all validation flights.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from engine_model.datasets.metadata import unit_list
from engine_model.validation import InputError

TRAIN, VALIDATION, CONFORMAL, TEST, UNUSED = 0, 1, 2, 3, -1
ROLE_NAMES = {TRAIN: "train", VALIDATION: "validation", CONFORMAL: "conformal", TEST: "test",
              UNUSED: "unused"}
VALIDATION_MODES = ("flights", "units")


def _check_listed(units: Sequence[int], present: set[int], what: str, source: str) -> list[int]:
    units = [int(u) for u in units]
    missing = [u for u in units if u not in present]
    if missing:
        raise InputError(f"{source}: {what} unit(s) {', '.join(map(str, missing))} not in the "
                         "table")
    return units


def assign_roles(unit: np.ndarray, cycle: np.ndarray, dev_units: Sequence[int],
                 test_units: Sequence[int] = (), *, seed: int = 0,
                 val_fraction: float = 0.1, validation: str = "flights",
                 val_units: Sequence[int] | None = None,
                 conformal_units: Sequence[int] = (), source: str = "table") -> np.ndarray:
    """The role of every row (module docstring) as an int8 array."""
    if validation not in VALIDATION_MODES:
        raise InputError(f"validation must be one of {', '.join(VALIDATION_MODES)}, got "
                         f"{validation!r}")
    if not 0.0 <= val_fraction < 1.0:
        raise InputError(f"validation fraction must lie in [0, 1), got {val_fraction}")
    unit = np.asarray(unit)
    cycle = np.asarray(cycle)
    present = set(np.unique(unit).tolist())
    dev = _check_listed(dev_units, present, "development", source)
    test = _check_listed(test_units, present, "test", source)
    conf = _check_listed(conformal_units, present, "conformal", source)
    for name, group in (("test", test), ("conformal", conf)):
        both = sorted(set(group) & set(dev) if name == "test" else set(group) - set(dev))
        if both:
            what = "both development and test" if name == "test" else \
                "conformal but not development"
            raise InputError(f"{source}: unit(s) {', '.join(map(str, both))} are {what}")
    # sorted: the seed's draw must not depend on the order the units were listed in
    fit_units = sorted(u for u in dev if u not in set(conf))
    if not fit_units:
        raise InputError(f"{source}: no development unit left to train on")
    roles = np.full(len(unit), UNUSED, dtype=np.int8)
    roles[np.isin(unit, test)] = TEST
    roles[np.isin(unit, conf)] = CONFORMAL
    roles[np.isin(unit, fit_units)] = TRAIN
    rng = np.random.default_rng(seed)
    if validation == "units":
        if val_units is None:
            k = max(1, round(val_fraction * len(fit_units))) if val_fraction > 0 else 0
            val_units = sorted(rng.choice(fit_units, size=k, replace=False).tolist()) if k else []
        val = _check_listed(val_units, present, "validation", source)
        outside = [u for u in val if u not in set(fit_units)]
        if outside:
            raise InputError(f"{source}: validation unit(s) {', '.join(map(str, outside))} are "
                             "not training units")
        if set(val) == set(fit_units):
            raise InputError(f"{source}: every training unit is a validation unit")
        roles[np.isin(unit, val)] = VALIDATION
        return roles
    if val_fraction == 0:
        return roles
    for u in fit_units:
        rows = unit == u
        cycles = np.unique(cycle[rows])
        if len(cycles) < 2:
            continue
        k = max(1, round(val_fraction * len(cycles)))
        chosen = rng.choice(cycles, size=k, replace=False)
        roles[rows & np.isin(cycle, chosen)] = VALIDATION
    return roles


def segments(unit: np.ndarray, roles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (exclusive) row of every maximal run of consecutive rows with the same
    unit and role; rows must be ordered by unit, cycle, t."""
    unit = np.asarray(unit)
    roles = np.asarray(roles)
    n = len(unit)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    change = np.flatnonzero((unit[1:] != unit[:-1]) | (roles[1:] != roles[:-1])) + 1
    starts = np.concatenate([[0], change]).astype(np.int64)
    ends = np.concatenate([change, [n]]).astype(np.int64)
    return starts, ends


def metadata_units(meta: dict | None, key: str, source: str = "table") -> list[int] | None:
    """The metadata's list of units under ``key`` (``dev_units``, ``test_units``), None when
    absent (:func:`engine_model.datasets.metadata.unit_list`)."""
    return unit_list(meta, key, source)


def development_and_test_units(present: Sequence[int], metadata: dict | None,
                               units: Sequence[int] | None = None,
                               test_units: Sequence[int] | None = None,
                               source: str = "table") -> tuple[list[int], list[int]]:
    """The development and test units of a table.

    Development: ``units`` when given, else the metadata's ``dev_units``, else every unit not
    listed as a test unit. Test: ``test_units`` when given, else the metadata's ``test_units``
    (restricted to units present), else none.
    """
    meta = metadata or {}
    present_set = set(int(u) for u in present)
    if test_units is None:
        test_units = [u for u in metadata_units(meta, "test_units", source) or []
                      if u in present_set]
    test = _check_listed(test_units, present_set, "test", source)
    if units is None:
        listed = metadata_units(meta, "dev_units", source)
        if listed:
            units = [int(u) for u in listed if int(u) in present_set]
        else:
            units = sorted(present_set - set(test))
    dev = _check_listed(units, present_set, "development", source)
    both = sorted(set(dev) & set(test))
    if both:
        raise InputError(f"{source}: unit(s) {', '.join(map(str, both))} are both development "
                         "and test units")
    if not dev:
        raise InputError(f"{source}: no development units")
    return dev, test

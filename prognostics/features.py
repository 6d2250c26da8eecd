"""Input sets of the prognostics networks: names -> the columns of a feature table.

The feature table is the one ``hyprog calibrate`` writes (``CalibrationResult.to_features``):
the measured-data columns, ``<c>_hat`` for every x_s and x_v channel, ``<theta>_hat`` and
``<theta>_hat_std`` for every estimated health parameter. Any table with these names works
(a C-MAPSS table read into hyprog names, a user's file).

Groups (each resolves to the listed columns *that the table has*, in this order)
-------------------------------------------------------------------------------
``w``          ``alt Mach TRA T2``                         scenario descriptors
``xs``         ``channels.XS_NAMES``                        measured, 16 in the paper
``xs_hat``     ``<c>_hat`` for c in x_s                     model prediction of x_s
``xv``         ``channels.XV_NAMES``                        true virtual sensors (simulation)
``xv_hat``     ``<c>_hat`` for c in x_v                     virtual sensors of the model
``theta_hat``  ``<q>_hat`` for q in ``THETA_NAMES``        calibrated health parameters
``theta``      true ``q`` for every ``<q>_hat`` present     perfect calibration (if no ``_hat``
                                                            in the table: every true theta)
``cmapss``     the 21 C-MAPSS sensors as hyprog reads them  every measured channel of NASA's
               (``datasets.cmapss.CMAPSS_SENSORS``)         files, also those outside x_s
                                                            (epr, NRf, NRc, BPR, htBleed, ...)
``health``     ``HI_hat`` and ``margin_{fan,lpc,hpc,egt}``  health coordinates of θ̂ at the
               ``_hat``                                     reference condition (flight
                                                            tables, :mod:`.flights`)
``theta_rel``  ``<q>_hat_rel``, ``HI_hat_rel``              θ̂ and HI relative to the unit's
                                                            early life (flight tables)
``health_true`` ``HI``, ``margin_*``                        the same at the true θ
                                                            (simulation)
``mode``       ``<q>_mode``                                 the failure mode: the direction
                                                            of θ̂'s change since early life
                                                            (flight tables, :mod:`.flights`)

Named sets (the paper's, Sec. 4.2 and ablation III)
----------------------------------------------------
==============  ===========================================  ===============================
name            groups                                       paper
==============  ===========================================  ===============================
data-driven     w + xs                                       [w, x_s], n = 20
denoised        w + xs + xs_hat                              [w, x_s, x̂_s]
virtual         w + xs + xs_hat + xv_hat                     [w, x_s, x̂_s, x̂_v]
hybrid          w + xs + xs_hat + xv_hat + theta_hat         [w, x_s, x̂_s, x̂_v, θ̂], n = 50
truth-theta     w + xs + xs_hat + xv_hat + theta             θ from the data instead of θ̂
physics         health + theta_rel                           (issue 30: θ̂'s health
                                                            coordinates only)
hybrid-health   hybrid + health + theta_rel                  (issue 30)
physics-mode    health + theta_rel + mode                    (issue 30: with the failure mode)
health-mode     health + mode                                (issue 30)
==============  ===========================================  ===============================

The health groups exist in flight tables (:func:`prognostics.flights.flight_table`, which the
flight models ``tcn`` and ``trend`` build from a sample table themselves).

A specification (``--inputs``) is terms joined by ``+``: a set name, a group name, or a
comma-separated list of columns, e.g. ``hybrid``, ``w+xs+xs_hat``, ``alt,Mach,TRA,T2,T24``,
``hybrid+Ps30,phi``. Set and group names resolve to what the table has, but a group that
resolves to nothing is an error (``hybrid`` on a raw table without ``_hat`` columns would
silently be ``data-driven``); an explicit column that the table lacks is an error naming it.
Columns are deduplicated in first-seen order; the resolved list is what a model records.

Unobservable parameters. ``hyprog calibrate --params all`` asks for every health parameter;
one the sensors cannot tell apart from the others is written as NaN (``CalibrationResult``).
A ``<q>_hat`` column that is NaN in *every* row of the table is such a parameter: the groups
``theta_hat`` and ``theta`` leave it out (:func:`unobservable_columns`). A column NaN in only
some rows is not dropped: :func:`check_table` names its first NaN, since a network cannot read
a parameter observable in one unit and not in another.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from engine_model.channels import THETA_NAMES, W_NAMES, XS_NAMES, XV_NAMES
from engine_model.datasets.cmapss import CMAPSS_SENSORS
from engine_model.validation import InputError

KEYS = ("unit", "cycle")
TARGET = "RUL"

GROUPS = ("w", "xs", "xs_hat", "xv", "xv_hat", "theta_hat", "theta", "cmapss", "health",
          "theta_rel", "health_true", "mode")
#: health index and normalised margins (:mod:`.flights`), column stems
HEALTH_STEMS = ("HI", "margin_fan", "margin_lpc", "margin_hpc", "margin_egt")
HEALTH_GROUPS = ("health", "theta_rel", "health_true", "mode")

INPUT_SETS: dict[str, tuple[str, ...]] = {
    "data-driven": ("w", "xs"),
    "denoised": ("w", "xs", "xs_hat"),
    "virtual": ("w", "xs", "xs_hat", "xv_hat"),
    "hybrid": ("w", "xs", "xs_hat", "xv_hat", "theta_hat"),
    "truth-theta": ("w", "xs", "xs_hat", "xv_hat", "theta"),
    "physics": ("health", "theta_rel"),
    "hybrid-health": ("w", "xs", "xs_hat", "xv_hat", "theta_hat", "health", "theta_rel"),
    "physics-mode": ("health", "theta_rel", "mode"),
    "health-mode": ("health", "mode"),
}


def health_groups_of(spec: str) -> list[str]:
    """The groups of :data:`HEALTH_GROUPS` that the input specification ``spec`` names,
    directly or through a set of :data:`INPUT_SETS` (columns of a flight table: they are
    computed from θ̂ by :func:`prognostics.flights.flight_table`, not written by
    ``hyprog calibrate``)."""
    out: list[str] = []
    for term in (t.strip() for t in spec.split("+")):
        for g in INPUT_SETS.get(term, (term,)):
            if g in HEALTH_GROUPS and g not in out:
                out.append(g)
    return out


def unobservable_columns(df: pd.DataFrame) -> list[str]:
    """The ``<q>_hat`` health-parameter columns of ``df`` that are NaN in every row (the
    calibration found ``q`` unobservable in every unit; module docstring)."""
    return [q + "_hat" for q in THETA_NAMES
            if q + "_hat" in df.columns and len(df) and bool(df[q + "_hat"].isna().all())]


def group_columns(group: str, columns: Sequence[str],
                  unobservable: Sequence[str] = ()) -> list[str]:
    """The columns of ``group`` (module docstring) that ``columns`` has, in canonical order;
    the health parameters whose ``<q>_hat`` is in ``unobservable`` are left out of
    ``theta_hat`` and ``theta``."""
    have = set(columns) - set(unobservable)
    if group == "w":
        cand = list(W_NAMES)
    elif group == "xs":
        cand = list(XS_NAMES)
    elif group == "xs_hat":
        cand = [c + "_hat" for c in XS_NAMES]
    elif group == "xv":
        cand = list(XV_NAMES)
    elif group == "xv_hat":
        cand = [c + "_hat" for c in XV_NAMES]
    elif group == "theta_hat":
        cand = [q + "_hat" for q in THETA_NAMES]
    elif group == "cmapss":
        cand = list(CMAPSS_SENSORS)
    elif group == "health":
        cand = [h + "_hat" for h in HEALTH_STEMS]
    elif group == "health_true":
        cand = list(HEALTH_STEMS)
    elif group == "theta_rel":
        cand = [q + "_hat_rel" for q in THETA_NAMES if q + "_hat" in have] + ["HI_hat_rel"]
    elif group == "mode":
        cand = [q + "_mode" for q in THETA_NAMES if q + "_hat" in have]
    elif group == "theta":
        estimated = [q for q in THETA_NAMES if q + "_hat" in have]
        cand = estimated or list(THETA_NAMES)
    else:
        raise InputError(f"unknown input group {group!r}; one of {', '.join(GROUPS)}")
    return [c for c in cand if c in have]


def resolve_inputs(spec: str, columns: Sequence[str], source: str = "table",
                   unobservable: Sequence[str] = ()) -> list[str]:
    """Resolve an input specification (module docstring) against a table's ``columns``;
    ``unobservable`` (:func:`unobservable_columns`) is left out of the health groups."""
    spec = spec.strip()
    if not spec:
        raise InputError("inputs: empty specification")
    out: list[str] = []
    for term in (t.strip() for t in spec.split("+")):
        if not term:
            raise InputError(f"inputs {spec!r}: empty term between '+'")
        if term in INPUT_SETS or term in GROUPS:
            groups = INPUT_SETS.get(term, (term,))
            for g in groups:
                cols = group_columns(g, columns, unobservable)
                if not cols:
                    hint = ""
                    if g.endswith("_hat"):
                        hint = " (run hyprog calibrate first)"
                    elif g in HEALTH_GROUPS:
                        hint = (" (computed in flight tables: the models tcn and trend, or any "
                                "model on a table with one row per cycle)")
                    raise InputError(f"{source}: inputs {term!r} need the {g} columns, and the "
                                     f"table has none{hint}")
                out += cols
            continue
        names = [c.strip() for c in term.split(",") if c.strip()]
        missing = [c for c in names if c not in set(columns)]
        if missing:
            known = ", ".join([*INPUT_SETS, *GROUPS])
            raise InputError(f"{source}: no input column(s) {', '.join(missing)} (an input "
                             f"term is a set or group name - {known} - or table columns)")
        out += names
    bad = [c for c in out if c in (*KEYS, TARGET)]
    if bad:
        raise InputError(f"inputs {spec!r}: {', '.join(bad)} cannot be an input")
    return list(dict.fromkeys(out))


def check_table(df: pd.DataFrame, columns: Sequence[str], source: str = "table",
                target: bool = True) -> None:
    """``df`` has ``unit``, ``cycle``, the input ``columns`` (and ``RUL`` when ``target``),
    all finite and within a 32-bit float's range (the networks compute in float32), ``RUL``
    not negative, and no two rows of a unit at the same ``cycle`` and ``t`` (when the table
    has ``t``); the first offending unit, cycle and column are named."""
    need = [*KEYS, *columns, *([TARGET] if target else [])]
    missing = [c for c in need if c not in df.columns]
    if missing:
        raise InputError(f"{source}: missing column(s) {', '.join(missing)}")

    def where(i: int) -> str:
        return f"{source}: unit {int(df['unit'].iloc[i])}, cycle {int(df['cycle'].iloc[i])}"

    big = float(np.finfo(np.float32).max)
    for c in [*columns, *([TARGET] if target else [])]:
        v = df[c].to_numpy()
        if not np.issubdtype(v.dtype, np.number):
            raise InputError(f"{source}: column {c} is not numeric ({v.dtype})")
        v = v.astype(float, copy=False)
        bad = ~np.isfinite(v)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise InputError(f"{where(i)}, column {c}: value is {v[i]} (NaN or infinite)")
        bad = np.abs(v) > big
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise InputError(f"{where(i)}, column {c}: value {v[i]:g} is beyond a 32-bit "
                             "float's range (the networks compute in float32)")
    if target:
        neg = df[TARGET].to_numpy(float) < 0
        if neg.any():
            i = int(np.flatnonzero(neg)[0])
            raise InputError(f"{where(i)}, column {TARGET}: value {df[TARGET].iloc[i]:g} is "
                             "negative (the remaining useful life counts cycles to failure)")
    if "t" in df.columns:
        dup = df.duplicated(["unit", "cycle", "t"], keep=False).to_numpy()
        if dup.any():
            i = int(np.flatnonzero(dup)[0])
            raise InputError(f"{where(i)}: {int(dup.sum())} rows share their time stamp t = "
                             f"{df['t'].iloc[i]:g} with another row (duplicated samples)")


def sort_table(df: pd.DataFrame) -> pd.DataFrame:
    """Rows ordered by unit, cycle (and ``t`` when present), index reset; a table already in
    that order is returned as is (no copy)."""
    keys = [k for k in ("unit", "cycle", "t") if k in df.columns]
    idx = pd.MultiIndex.from_frame(df[keys]) if len(keys) > 1 else pd.Index(df[keys[0]])
    if idx.is_monotonic_increasing and isinstance(df.index, pd.RangeIndex) \
            and df.index.start == 0 and df.index.step == 1:
        return df
    return df.sort_values(keys, kind="stable").reset_index(drop=True)

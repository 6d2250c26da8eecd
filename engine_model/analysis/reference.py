"""The engine model against a reference table of operating points (C-MAPSS FD002 by default).

Reference table (CSV, one row per operating point, header required)
-------------------------------------------------------------------
``alt_kft`` [kft], ``Mach`` [-], ``TRA`` [%], ``T2`` [degR] (all required, numeric, inside the
flight envelope) and any of :data:`REFERENCE_CHANNELS` (numeric; empty cells are allowed and
give NaN errors). Other columns are ignored. Rows are numbered from 1, header excluded, in
every message. The default table, ``data_samples/cmapss-fd002-operating-points.csv``, holds
the early-life means of C-MAPSS FD002 at its six operating points.

``Ps30`` and ``phi`` are not compared: in the C-MAPSS files they do not follow their stated
definitions (``Ps30`` is not a static pressure below ``P30``; ``phi`` is not ``Wf / Ps30``).

Comparison: the model runs at ``alt = alt_kft * FT_PER_KFT``, ``Mach``, ``TRA``, ``T2`` with
theta = 0; per channel the error is ``100 (model - reference) / reference`` [%].
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from data_samples import REFERENCE_CSV, sample_path
from engine_model.channels import W_NAMES
from engine_model.units import FT_PER_KFT
from engine_model.validation import InputError, check_columns, check_w

REFERENCE_W = ("alt_kft", "Mach", "TRA", "T2")
REFERENCE_CHANNELS = (
    "T24", "T30", "T50", "P2", "P15", "P30", "Nf", "Nc", "epr", "NRf", "NRc", "BPR", "W31", "W32",
)
def default_reference_path() -> Path:
    """The C-MAPSS FD002 reference table packaged with hyprog
    (:func:`data_samples.sample_path`)."""
    return sample_path(REFERENCE_CSV)


def load_reference(path: str | os.PathLike) -> pd.DataFrame:
    """Read and check a reference table (module doc): the columns of :data:`REFERENCE_W`
    and the present :data:`REFERENCE_CHANNELS` as float, indexed by row number from 1.
    InputError names the file and the row / column (missing, not a number, missing value,
    outside the envelope)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file" if not path.exists() else
                         f"{path}: is a directory, expected a CSV file")
    try:
        df = pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read as CSV ({str(exc).splitlines()[0]})") from None
    with open(path, newline="", encoding="utf-8", errors="replace") as f:
        header = [h.strip() for h in next(csv.reader(f), [])]  # read_csv renames repeats
    twice = sorted({h for h in header if header.count(h) > 1})
    if twice:
        raise InputError(f"{path}: column(s) {', '.join(twice)} appear more than once")
    df.columns = [str(c).strip() for c in df.columns]
    check_columns(list(df.columns), REFERENCE_W, what=str(path))
    channels = [c for c in REFERENCE_CHANNELS if c in df.columns]
    if not channels:
        raise InputError(f"{path}: no channel to compare; expected some of"
                         f" {', '.join(REFERENCE_CHANNELS)}")
    if df.empty:
        raise InputError(f"{path}: the table has no rows")
    df.index = pd.RangeIndex(1, len(df) + 1)
    for c in (*REFERENCE_W, *channels):
        num = pd.to_numeric(df[c], errors="coerce")
        bad = num.isna() & df[c].notna()
        if bad.any():
            i = bad.idxmax()
            raise InputError(f"{path}: row {i}, column {c}: {df.at[i, c]!r} is not a number")
        if c in REFERENCE_W and num.isna().any():
            raise InputError(f"{path}: row {num.isna().idxmax()}, column {c}: value is missing")
        df[c] = num.astype(float)
    ref = df[[*REFERENCE_W, *channels]]
    values = ref[channels].to_numpy()
    if not (np.isfinite(values) & (values != 0)).any():
        raise InputError(f"{path}: nothing to compare: every value of {', '.join(channels)} "
                         "is missing or 0 (an error in % needs a non-zero reading)")
    check_w(reference_w(ref).to_numpy(), row_labels=ref.index.to_numpy(), source=str(path))
    return ref


def reference_w(ref: pd.DataFrame) -> pd.DataFrame:
    """The operating points ``alt [ft], Mach, TRA, T2`` of a reference table."""
    w = pd.DataFrame({"alt": ref["alt_kft"] * FT_PER_KFT, "Mach": ref["Mach"],
                      "TRA": ref["TRA"], "T2": ref["T2"]}, index=ref.index)
    return w[list(W_NAMES)]


def compared_channels(ref: pd.DataFrame) -> list[str]:
    """The channels of :data:`REFERENCE_CHANNELS` present in ``ref``, in that order."""
    return [c for c in REFERENCE_CHANNELS if c in ref.columns]


def compare_reference(model: Any, ref: pd.DataFrame) -> list[dict[str, Any]]:
    """The model at every row of the reference table (from :func:`load_reference`).

    One record per row: ``row``, the four ``REFERENCE_W`` values, ``converged``, and per
    compared channel ``<c>_ref``, ``<c>_model``, ``<c>_err_pct`` (``100 (model - ref) / ref``,
    NaN when the reference is missing or 0), and ``max_abs_err_pct`` over the channels.
    ``model`` is anything with the :meth:`engine_model.EngineModel.evaluate` signature.
    """
    out = model.evaluate(reference_w(ref))
    channels = compared_channels(ref)
    records = []
    for i in ref.index:
        rec = {"row": int(i), **{c: float(ref.at[i, c]) for c in REFERENCE_W},
               "converged": bool(out.at[i, "converged"])}
        for c in channels:
            r, m = float(ref.at[i, c]), float(out.at[i, c])
            err = 100.0 * (m - r) / r if math.isfinite(r) and r != 0.0 else math.nan
            rec[f"{c}_ref"], rec[f"{c}_model"], rec[f"{c}_err_pct"] = r, m, err
        errs = [abs(rec[f"{c}_err_pct"]) for c in channels if math.isfinite(rec[f"{c}_err_pct"])]
        rec["max_abs_err_pct"] = max(errs) if errs else math.nan
        records.append(rec)
    return records


def error_table(records: list[dict[str, Any]]) -> pd.DataFrame:
    """Error [%] per row (index: the row's operating point) and compared channel (columns)."""
    channels = [c for c in REFERENCE_CHANNELS if records and f"{c}_err_pct" in records[0]]
    index = [f"{r['alt_kft']:g} kft M{r['Mach']:g} TRA{r['TRA']:g}" for r in records]
    return pd.DataFrame(np.array([[r[f"{c}_err_pct"] for c in channels] for r in records],
                                 dtype=float).reshape(len(records), len(channels)),
                        index=pd.Index(index, name="point"), columns=channels)

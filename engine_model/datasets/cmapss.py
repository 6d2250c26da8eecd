"""The C-MAPSS (2008) text data sets read into the hyprog table, with N-CMAPSS names.

Files (NASA Prognostics Data Repository, "Turbofan Engine Degradation Simulation Data Set",
subsets FD001-FD004): ``train_FD00x.txt`` (run-to-failure trajectories), ``test_FD00x.txt``
(trajectories cut off some time before failure) and ``RUL_FD00x.txt`` (the true remaining
useful life of each test unit at its last cycle).

Layout of ``train``/``test``: one line per cycle, 26 whitespace-separated numbers (trailing
spaces are common and blank lines are skipped): unit, cycle, three operational settings, 21
sensors. ``RUL``: one number per line, line ``k`` for the ``k``-th test unit in increasing
unit order (units 1..N in the published files).

Column mapping (Saxena, Goebel, Simon & Eklund, "Damage propagation modeling for aircraft
engine run-to-failure simulation", PHM 2008, Table 2; the sensor order checked against the
same table reprinted in Int. J. Aerospace Eng. 2021, article 5876299, Table 3):

=============  ===========================================================================
C-MAPSS        hyprog column [unit]
=============  ===========================================================================
setting 1      ``alt`` [ft]: C-MAPSS gives altitude in kft, multiplied by ``FT_PER_KFT``
setting 2      ``Mach`` [-]
setting 3      ``TRA`` [%] (throttle-resolver angle)
sensors 1-21   ``T2 T24 T30 T50`` [degR], ``P2 P15 P30`` [psia], ``Nf Nc`` [rpm], ``epr`` [-],
               ``Ps30`` [psia], ``phi`` [pps/psi] (fuel flow / Ps30), ``NRf NRc`` [rpm],
               ``BPR`` [-], ``farB`` [-], ``htBleed`` [-], ``Nf_dmd`` [rpm], ``PCNfR_dmd``
               [%], ``W31 W32`` [lbm/s]
=============  ===========================================================================

Bookkeeping added: ``t`` = 0.0 (one sample per cycle: a cycle is one snapshot, so there is no
time within a flight and no sample rate; ``sample_rate_hz`` is not recorded) and ``RUL``
[cycles]: for a train unit ``last cycle - cycle``; for a test unit ``RUL_file[unit] + last
cycle - cycle`` (the trajectory stops ``RUL_file[unit]`` cycles before failure). There is no
``Fc``, ``hs`` or health parameter in C-MAPSS.

Units: train units keep their numbers; test unit ``u`` becomes ``offset + u`` so that both
splits live in one table, where ``offset`` (``test_unit_offset`` in the metadata) is the
smallest multiple of ``TEST_UNIT_STEP`` (1000) above every train unit: 1000 for every
published subset, so test unit 7 of FD002 is unit 1007.

Metadata: ``source_format = "cmapss-text"``, ``dev_units`` (the train units), ``test_units``
(renumbered), ``test_unit_offset``, ``source_files`` (``{"train", "test", "rul"}`` file
names) and ``cmapss_subset`` (``"FD002"``, when the train file's name says).
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..units import FT_PER_KFT
from ..validation import InputError
from .paths import existing_path
from .schema import canonical_columns

CMAPSS_SOURCE = "cmapss-text"
CMAPSS_SETTINGS = ("alt", "Mach", "TRA")
CMAPSS_SENSORS = (
    "T2", "T24", "T30", "T50", "P2", "P15", "P30", "Nf", "Nc", "epr", "Ps30", "phi", "NRf",
    "NRc", "BPR", "farB", "htBleed", "Nf_dmd", "PCNfR_dmd", "W31", "W32",
)
CMAPSS_COLUMNS = ("unit", "cycle", *CMAPSS_SETTINGS, *CMAPSS_SENSORS)  # the 26 of a line
TEST_UNIT_STEP = 1000
_SUBSET = re.compile(r"FD\d{3}", re.IGNORECASE)



#: C-MAPSS channels that do not follow their stated definition, so that no physics-based
#: model can match them; recorded in the metadata as ``not_physical`` and left out of the
#: default sensor set of a calibration (``CalibrationSetup.exclude_sensors``). C-MAPSS's
#: ``Ps30`` ("HPC outlet static pressure", psia) is about 1/12 of its total ``P30`` at every
#: operating point (47.5 against 554 psia at sea-level take-off in FD001), which no static
#: pressure behind a compressor can be; see README, "Model versus C-MAPSS".
NOT_PHYSICAL = {"Ps30": "about 1/12 of P30 at every point: not a static pressure in psia"}

def _lines(path: Path) -> list[tuple[int, list[str]]]:
    """(1-based line number, tokens) of every non-blank line of a text file."""
    try:
        text = path.read_text(encoding="ascii")
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a C-MAPSS text file (byte {exc.start} is not ASCII)"
                         ) from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, expected a C-MAPSS text file") from None
    return [(n, line.split()) for n, line in enumerate(text.splitlines(), 1) if line.strip()]


def _numbers(path: Path, rows: list[tuple[int, list[str]]],
             names: Sequence[str]) -> np.ndarray:
    """The tokens of ``rows`` as a float array (len(rows), len(names)); an InputError names
    the line and column of the first token that is not a finite number."""
    flat = [tok for _, tokens in rows for tok in tokens]
    try:
        values = np.array(flat, dtype=np.float64)
    except ValueError:
        values = pd.to_numeric(pd.Series(flat, dtype=object), errors="coerce").to_numpy(
            dtype=np.float64)
    bad = ~np.isfinite(values)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        line, name, token = rows[i // len(names)][0], names[i % len(names)], flat[i]
        try:
            what = f"value is {float(token)} (NaN or infinite)"
        except ValueError:
            what = f"{token!r} is not a number"
        raise InputError(f"{path}: line {line}, column {name}: {what}")
    return values.reshape(len(rows), len(names))


def _check_integers(path: Path, rows: list[tuple[int, list[str]]], values: np.ndarray,
                    names: Sequence[str], minimum: int) -> None:
    for j, name in enumerate(names):
        col = values[:, j]
        bad = (col != np.round(col)) | (col < minimum)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise InputError(f"{path}: line {rows[i][0]}, column {name}: {rows[i][1][j]} is"
                             f" not an integer >= {minimum}")


def read_cmapss_text(path: str | os.PathLike) -> pd.DataFrame:
    """One ``train_FD00x.txt`` / ``test_FD00x.txt`` file as a table in file order: ``unit``
    and ``cycle`` (int64), ``alt`` [ft], ``Mach``, ``TRA`` and the 21 sensors (module doc).
    Raises InputError naming the file, line and column of a line with the wrong number of
    columns, a token that is not a number, a NaN, or a unit / cycle that is not a positive
    integer, and for a file without data lines."""
    p = existing_path(path)
    rows = _lines(p)
    if not rows:
        raise InputError(f"{p}: no data lines (expected {len(CMAPSS_COLUMNS)} numbers a line)")
    for line, tokens in rows:
        if len(tokens) != len(CMAPSS_COLUMNS):
            raise InputError(f"{p}: line {line}: {len(tokens)} columns, expected"
                             f" {len(CMAPSS_COLUMNS)} (unit, cycle, 3 settings, 21 sensors)")
    values = _numbers(p, rows, CMAPSS_COLUMNS)
    _check_integers(p, rows, values[:, :2], CMAPSS_COLUMNS[:2], minimum=1)
    df = pd.DataFrame(values, columns=list(CMAPSS_COLUMNS))
    df["unit"] = df["unit"].astype(np.int64)
    df["cycle"] = df["cycle"].astype(np.int64)
    df["alt"] = df["alt"] * FT_PER_KFT
    return df


def read_rul_file(path: str | os.PathLike) -> np.ndarray:
    """``RUL_FD00x.txt``: the true RUL [cycles] of each test unit at its last cycle, one
    non-negative integer a line, as int64 in file order."""
    p = existing_path(path)
    rows = _lines(p)
    if not rows:
        raise InputError(f"{p}: no data lines (expected one RUL a line)")
    for line, tokens in rows:
        if len(tokens) != 1:
            raise InputError(f"{p}: line {line}: {len(tokens)} columns, expected 1 (RUL)")
    values = _numbers(p, rows, ("RUL",))
    _check_integers(p, rows, values, ("RUL",), minimum=0)
    return values[:, 0].astype(np.int64)


def _rul_to_failure(df: pd.DataFrame, rul_at_end: pd.Series | None = None) -> np.ndarray:
    """RUL of every row: last cycle of its unit - cycle (+ the unit's RUL at its last cycle)."""
    last = df.groupby("unit")["cycle"].transform("max").to_numpy()
    rul = last - df["cycle"].to_numpy()
    if rul_at_end is not None:
        rul = rul + df["unit"].map(rul_at_end).to_numpy()
    return rul.astype(np.int64)


def _check_unique_cycles(df: pd.DataFrame, path: Path) -> None:
    dup = df.duplicated(["unit", "cycle"])
    if dup.any():
        i = int(np.flatnonzero(dup.to_numpy())[0])
        raise InputError(f"{path}: unit {df.at[i, 'unit']}, cycle {df.at[i, 'cycle']} appears"
                         " twice")


def offset_for_test_units(train_units: Sequence[int]) -> int:
    """The number added to every test unit: the smallest multiple of ``TEST_UNIT_STEP``
    greater than every train unit (1000 for every published subset)."""
    top = max((int(u) for u in train_units), default=0)
    return TEST_UNIT_STEP * (top // TEST_UNIT_STEP + 1)


def read_cmapss(train: str | os.PathLike, test: str | os.PathLike | None = None,
                rul: str | os.PathLike | None = None) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Read a C-MAPSS subset: the train file and, optionally, the test file with its RUL
    file (both or neither) -> ``(df, metadata)`` in the hyprog schema (module doc), sorted by
    unit and cycle. Train units are ``dev_units``; test units, renumbered to
    ``test_unit_offset + unit``, are ``test_units``."""
    if (test is None) != (rul is None):
        given, missing = ("test", "RUL") if rul is None else ("RUL", "test")
        raise InputError(f"{test if rul is None else rul}: a C-MAPSS {given} file needs its"
                         f" {missing} file")
    train_path = existing_path(train)
    dev = read_cmapss_text(train_path)
    _check_unique_cycles(dev, train_path)
    dev.insert(2, "RUL", _rul_to_failure(dev))
    frames = [dev]
    offset = offset_for_test_units(dev["unit"].unique())
    files = {"train": train_path.name}
    test_units: list[int] = []
    if test is not None:
        test_path, rul_path = existing_path(test), existing_path(rul)
        tst = read_cmapss_text(test_path)
        _check_unique_cycles(tst, test_path)
        at_end = read_rul_file(rul_path)
        units = np.sort(tst["unit"].unique())
        if len(at_end) != len(units):
            raise InputError(f"{rul_path}: {len(at_end)} RUL values, but {test_path.name} has"
                             f" {len(units)} test units (one value a unit, in unit order)")
        tst.insert(2, "RUL", _rul_to_failure(tst, pd.Series(at_end, index=units)))
        tst["unit"] = tst["unit"] + offset
        test_units = [int(u) for u in units + offset]
        frames.append(tst)
        files.update(test=test_path.name, rul=rul_path.name)
    df = pd.concat(frames, ignore_index=True)
    df.insert(2, "t", 0.0)
    df = df.sort_values(["unit", "cycle"], kind="stable", ignore_index=True)
    df = df[canonical_columns(df.columns)]
    meta: dict[str, Any] = {
        "source_format": CMAPSS_SOURCE,
        "dev_units": sorted(int(u) for u in dev["unit"].unique()),
        "test_units": test_units,
        "test_unit_offset": offset,
        "source_files": files,
        "not_physical": NOT_PHYSICAL,
    }
    subset = _SUBSET.search(train_path.name)
    if subset:
        meta["cmapss_subset"] = subset.group(0).upper()
    return df, meta
